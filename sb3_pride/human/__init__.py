"""
Human feedback: ``WebTeacher`` asks people in a browser (one on this machine, or several annotators with secret links)
which of two segments is better, while the agent trains.
Needs the ``[human]`` extra (Flask for the page, PyAV for the clips) and headless MuJoCo rendering (``MUJOCO_GL=egl``).
"""

from sb3_pride.common.render_states import RenderStates
from sb3_pride.human.render import SegmentRenderer, encode_mp4
from sb3_pride.human.web import WebTeacher

__all__ = ["RenderStates", "SegmentRenderer", "WebTeacher", "encode_mp4"]
