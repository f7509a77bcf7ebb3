"""
Human feedback: ``WebTeacher`` asks people in a browser (one on this machine, or several annotators with secret links)
which of two segments is better, while the agent trains.
Needs the ``[human]`` extra (Flask for the page, PyAV for the clips); MuJoCo envs render headless (``MUJOCO_GL=egl``),
any other env is shown from its render states or from the frames it renders (``sb3_pride.human.showing``).

Its parts: ``AnswerStore`` (the open feedback session, who is handed what, answers and undos; no HTTP), ``Quality``
(known-answer questions and agreement), ``create_app`` (the page's Flask app and its request guard), ``WebServer``
(serving it, with tokens and a read timeout), ``Clips`` (the clips' folder, renderer and render thread) and
``FrameRecording`` (the frames of envs that cannot be re-rendered, recorded while the agent collects).
"""

from sb3_pride.render_states import RenderStateEnv, RenderStates
from sb3_pride.human.app import create_app
from sb3_pride.human.clips import Clips, RenderThread
from sb3_pride.human.quality import Quality
from sb3_pride.human.questions import Answer, KnownPair, Question, Refused, Session
from sb3_pride.human.recording import FrameRecording, RecordRenders
from sb3_pride.human.render import RecordedRenderer, SegmentRenderer, StateRenderer, encode_mp4
from sb3_pride.human.server import WebServer
from sb3_pride.human.store import AnswerStore
from sb3_pride.human.web import WebTeacher, shared_web_teacher

__all__ = [
    "Answer",
    "AnswerStore",
    "Clips",
    "FrameRecording",
    "KnownPair",
    "Quality",
    "Question",
    "RecordRenders",
    "RecordedRenderer",
    "Refused",
    "RenderStateEnv",
    "RenderStates",
    "RenderThread",
    "SegmentRenderer",
    "Session",
    "StateRenderer",
    "WebServer",
    "WebTeacher",
    "create_app",
    "encode_mp4",
    "shared_web_teacher",
]
