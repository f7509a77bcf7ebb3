"""sb3_pride: preference-based RL for Stable-Baselines3 — PEBBLE and PRIDE (PEBBLE + a diffusion model)."""

from sb3_pride.common.buffers import PreferenceReplayBuffer
from sb3_pride.common.teachers import TEACHER_PRESETS, ScriptedTeacher, Teacher
from sb3_pride.envs import register_envs
from sb3_pride.pebble import PEBBLE

__version__ = "0.1.0"

register_envs()

__all__ = ["PEBBLE", "PreferenceReplayBuffer", "ScriptedTeacher", "TEACHER_PRESETS", "Teacher", "__version__"]
