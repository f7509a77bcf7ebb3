"""sb3_pride: preference-based RL for Stable-Baselines3 — PEBBLE and PRIDE (PEBBLE + a diffusion model)."""

from sb3_pride.common.buffers import PreferenceReplayBuffer
from sb3_pride.pride.buffers import DualReplayBuffer, SyntheticReplayBuffer
from sb3_pride.pride.diffusion import ElucidatedDiffusion
from sb3_pride.common.teachers import TEACHER_PRESETS, ScriptedTeacher, Teacher
from sb3_pride.envs import register_envs
from sb3_pride.human import WebTeacher
from sb3_pride.pebble import PEBBLE
from sb3_pride.pride import PRIDE

__version__ = "0.3.0"

register_envs()

__all__ = [
    "PEBBLE",
    "PRIDE",
    "TEACHER_PRESETS",
    "DualReplayBuffer",
    "ElucidatedDiffusion",
    "PreferenceReplayBuffer",
    "ScriptedTeacher",
    "SyntheticReplayBuffer",
    "Teacher",
    "WebTeacher",
    "__version__",
]
