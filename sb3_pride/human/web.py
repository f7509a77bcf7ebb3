"""
``WebTeacher``: people label segment pairs in a browser while the agent trains.

At each feedback session the run renders every queried pair as two H.264 clips (re-rendered from the states recorded
beside the transitions, or cut from the frames the env rendered: ``sb3_pride.human.showing``), serves them on a web
page and waits until every query has its answers.
One person on this machine needs nothing more; several annotators each open a secret link, are handed queries no one
else is answering (or, with ``answers_per_query=k``, the same query as ``k - 1`` others), and may be checked with
known-answer questions mixed into what they see. Answers go to the run's preference journal the moment they are given
(``PEBBLE(preference_journal=...)``), each with who gave it and when, so a run killed mid-session loses none.
``WebTeacher`` is an ``InteractiveTeacher``: the model gives it its env and replay buffer when it is attached, and each
session's pairs with a ``FeedbackContext``; never the model itself.

The teacher is a facade over its parts, each a public attribute: ``store`` (``AnswerStore``: the open session, who is
handed what, answers and undos), ``quality`` (``Quality``: known answers and agreement), ``clips`` (``Clips``: the
folder, the renderer and its thread) and ``server`` (``WebServer``: the Flask app of ``create_app`` and the tokens).
"""

import socket
import uuid
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any, ClassVar

import numpy as np

from sb3_pride.common.queries import SegmentPairs
from sb3_pride.common.teachers import FeedbackContext, InteractiveTeacher, register_teacher
from sb3_pride.human import showing
from sb3_pride.human.clips import Clips
from sb3_pride.human.quality import (
    FLAG_BELOW,
    FLAG_MIN_KNOWN,
    HIDDEN_DURING_SESSION,
    KNOWN_POOL_SIZE,
    MIN_RETURN_SCALE,
    Quality,
)
from sb3_pride.human.questions import Question, Session
from sb3_pride.human.render import use_headless_gl
from sb3_pride.human.recording import check_recording_settings
from sb3_pride.human.server import WebServer
from sb3_pride.human.settings import (
    ANNOTATOR_NAME,
    ANONYMOUS,
    GENERIC_INSTRUCTIONS,
    HAND_OVER_AFTER,
    LOCAL_HOSTS,
    READ_TIMEOUT,
    TASK_INSTRUCTIONS,
    check_settings,
    default_instructions,
    is_local,
)
from sb3_pride.human.store import ALLOWED_LABELS, QUEUE_LENGTH, RELEASE_AFTER, AnswerStore

if TYPE_CHECKING:
    from stable_baselines3.common.vec_env import VecEnv

    from sb3_pride.common.buffers import PreferenceReplayBuffer

# the constants and helpers of the parts, where they have always been imported from
__all__ = [
    "ALLOWED_LABELS",
    "ANNOTATOR_NAME",
    "ANONYMOUS",
    "FLAG_BELOW",
    "FLAG_MIN_KNOWN",
    "GENERIC_INSTRUCTIONS",
    "HIDDEN_DURING_SESSION",
    "KNOWN_POOL_SIZE",
    "LOCAL_HOSTS",
    "MIN_RETURN_SCALE",
    "QUEUE_LENGTH",
    "RELEASE_AFTER",
    "TASK_INSTRUCTIONS",
    "WebTeacher",
    "default_instructions",
    "is_local",
    "shared_web_teacher",
]


class WebTeacher(InteractiveTeacher):
    """
    An ``InteractiveTeacher`` that asks people, on a web page (``http://host:port/``), which of two segments is better.

    The page plays both segments of a pair side by side as looping clips that restart together, with a playback
    speed control, buttons and the task's instructions; keys: ArrowLeft = left preferred (μ = 0), ArrowRight = right
    preferred (μ = 1), ArrowDown = equally good (μ = 0.5), s = skip, Backspace = undo your last answer of this
    session. Everything is served by the training process (no internet needed). Use it as
    ``PEBBLE(..., teacher=WebTeacher(port=8000))`` or ``teacher="web"``; needs the ``[human]`` extra and an env that can
    be shown: any env made with ``render_mode="rgb_array"`` (how it is shown is decided when the teacher is attached,
    printed and kept in ``shown_from``: ``sb3_pride.human.showing``). Below the pair, a curve of corr(r̂, r) after each
    feedback session (``show_reward_history``) tells the team whether its labels teach r̂ the task.

    Several annotators: ``WebTeacher(annotators=["ana", "ben"])`` gives each a secret token; ``links`` (printed when
    the server starts) maps each name to the URL that carries it, and every request of the page must carry one. Each
    open query is handed to one annotator at a time (to ``answers_per_query`` different ones in all), and the model is
    given the mean μ of a query's answers that are not skips. Each answer is journaled with its annotator and time. The
    tokens live as long as the teacher: a saved model keeps the settings, and a loaded one makes new tokens (new links,
    printed again; the old ones stop working).

    Known-answer questions (``known_answer_rate > 0``) are pairs whose answer is known, shown again as extra questions
    that only measure the annotator (their answers are neither journaled nor given to the model): pairs whose true
    segment returns differ by at least ``known_answer_margin × return_scale`` (the pairs' own true rewards; the answer
    is the higher return; the spread of the returns stands in for a ``return_scale`` of about 0), and queries on which
    at least two annotators formed a majority for left or right. ``agreement()`` reports, per annotator, the share of
    known answers they matched and how often they agreed with the others on the pairs several answered; it is shown on
    the page between feedback sessions (never during one: nothing there moves differently on a known-answer question),
    logged (``annotators/<name>/...``) and written to ``report_path`` after every feedback session. A known-answer
    question is scored by its first answer (an undo lets the annotator change what they see, not the score). With
    ``annotators``, nobody is shown a known pair they answered (nor a majority they were part of); one person alone is
    shown true-reward pairs of earlier sessions again.

    The teacher holds its settings and hands the work to its parts, public attributes made with it (and anew when a
    saved model is loaded): ``store`` (``AnswerStore``), ``quality`` (``Quality``), ``clips`` (``Clips``) and
    ``server`` (``WebServer``, whose ``app`` is the page's Flask app, ``create_app``).

    :param port: the TCP port of the page (0: any free port, read it back from ``.port``)
    :param host: the address to bind: 127.0.0.1 (this machine only; use ssh port forwarding from another one), or
        e.g. 0.0.0.0 (every interface: needs ``annotators``)
    :param timeout: seconds to wait for a session's answers; the rest are then skipped (asked, not labeled).
        None: wait as long as it takes
    :param width: clip width in pixels
    :param height: clip height in pixels
    :param clip_dir: where the clips are written (None: a temporary folder removed at exit)
    :param reminder_interval: seconds between console reminders (with the URL) while answers are awaited
    :param camera: the MuJoCo camera of the clips, by name or id (None: dm_control's first camera, Meta-World's
        "corner3", the free camera for other MuJoCo envs)
    :param annotators: the annotators' names (letters, digits, ``_``, ``-``, ``.``), each given a secret link; None:
        one person on this machine, no token (only on 127.0.0.1, localhost or ::1)
    :param instructions: the plain text shown above the clips (None: a sentence for the task, ``TASK_INSTRUCTIONS``,
        picked from the env id at ``attach()``)
    :param answers_per_query: how many different annotators answer each query (at most ``len(annotators)``)
    :param known_answer_rate: the share of an annotator's questions that are known-answer questions, in [0, 1)
        (a target: none is shown while no known pair is available to them)
    :param known_answer_margin: a pair's answer is known from the true reward when its two undiscounted segment
        returns differ by at least this many ``return_scale`` (None: only majorities of annotators make known answers)
    :param report_path: a JSON file that receives ``agreement()`` (written whole) after every feedback session and on
        ``close()`` (its folder is made now; a failed write is warned about, never raised); None: none
    :param seed: the seed of the draws that mix the known-answer questions in
    :param read_timeout: seconds a connection may stay open, its request received and its answer sent, however slowly
        the bytes come: a request sent half-way or slowly (or an answer never read) is dropped then, its thread freed
    :param hand_over_after: seconds a query may stay shown to an annotator who does not answer it (while their page
        still polls) before an annotator who has nothing left to answer is handed it
    :param recorded_episodes: for an env shown from recorded frames, the episodes kept (over all envs, the running ones
        included, as ``query_kwargs["max_query_episodes"]`` counts those queries come from: keep the two equal)
    :param recording_bytes: for an env shown from recorded frames, the most bytes of compressed frames kept on disk
    :param recording_dir: the folder in which recorded frames are kept, in a folder of the run's own removed by
        ``close()`` or at exit (None: the system's temporary folder)
    """

    # the settings (constructor parameters), saved with a model; and the parts, made anew when it is loaded
    port: int
    host: str
    timeout: float | None
    width: int
    height: int
    clip_dir: Path | None
    reminder_interval: float
    camera: str | int | None
    annotators: list[str] | None
    instructions: str | None
    answers_per_query: int
    known_answer_rate: float
    known_answer_margin: float | None
    report_path: Path | None
    seed: int | None
    read_timeout: float
    hand_over_after: float
    recorded_episodes: int
    recording_bytes: int
    recording_dir: Path | None
    env_id: str | None
    shown_from: str | None
    quality: Quality
    store: AnswerStore
    clips: Clips
    server: WebServer

    def __init__(
        self,
        port: int = 8000,
        host: str = "127.0.0.1",
        timeout: float | None = None,
        width: int = 320,
        height: int = 240,
        clip_dir: str | Path | None = None,
        reminder_interval: float = 60.0,
        camera: str | int | None = None,
        annotators: Sequence[str] | None = None,
        instructions: str | None = None,
        answers_per_query: int = 1,
        known_answer_rate: float = 0.0,
        known_answer_margin: float | None = 0.5,
        report_path: str | Path | None = None,
        seed: int | None = None,
        read_timeout: float = READ_TIMEOUT,
        hand_over_after: float = HAND_OVER_AFTER,
        recorded_episodes: int = 100,
        recording_bytes: int = 1 << 30,
        recording_dir: str | Path | None = None,
    ):
        settings = check_settings({name: value for name, value in locals().items() if name in self._SETTINGS})
        settings["recording_dir"] = check_recording_settings(recorded_episodes, recording_bytes, recording_dir)
        use_headless_gl()  # before the first env is made: MuJoCo reads MUJOCO_GL once
        self.__setstate__(settings)

    # a saved model keeps the settings, not the server, the tokens or the answers
    _SETTINGS = (
        "port",
        "host",
        "timeout",
        "width",
        "height",
        "clip_dir",
        "reminder_interval",
        "camera",
        "annotators",
        "instructions",
        "answers_per_query",
        "known_answer_rate",
        "known_answer_margin",
        "report_path",
        "seed",
        "read_timeout",
        "hand_over_after",
        "recorded_episodes",
        "recording_bytes",
        "recording_dir",
    )
    _DEFAULTS: ClassVar[dict[str, Any]] = dict(
        annotators=None,
        instructions=None,
        answers_per_query=1,
        known_answer_rate=0.0,
        known_answer_margin=0.5,
        report_path=None,
        seed=None,
        read_timeout=READ_TIMEOUT,
        hand_over_after=HAND_OVER_AFTER,
        recorded_episodes=100,
        recording_bytes=1 << 30,
        recording_dir=None,
    )

    def __getstate__(self) -> dict:
        return {name: self.__dict__[name] for name in self._SETTINGS}

    def __setstate__(self, state: dict) -> None:
        """The settings (a teacher saved before a setting existed gets its default), and new parts: new tokens."""
        self.__dict__.update({**self._DEFAULTS, **state})
        self.env_id = None  # the env id seen by attach(): it picks the default instructions
        self.shown_from = None  # how attach() shows the env: showing.MUJOCO_STATES, RENDER_STATES or RECORDED_FRAMES
        self.quality = Quality(
            self.annotators,
            self.answers_per_query,
            self.known_answer_rate,
            self.known_answer_margin,
            self.report_path,
            self.seed,
        )
        self.store = AnswerStore(self.quality, self.annotators, self.answers_per_query, self.hand_over_after)
        self.clips = Clips(self.clip_dir, self.width, self.height, self.camera)
        self.quality.clips = self.clips  # known-answer questions' copies of clips are made there
        self.server = WebServer(self.store, self.clips, self.annotators, lambda: self.page_instructions, self.read_timeout)

    @property
    def url(self) -> str:
        """The page's address (with ``annotators``, each opens their own link instead: ``links``)."""
        host = socket.gethostname() if self.host in ("0.0.0.0", "::", "") else self.host
        return f"http://[{host}]:{self.port}/" if ":" in host else f"http://{host}:{self.port}/"

    @property
    def links(self) -> dict[str, str]:
        """Each annotator's personal link (the page's URL with their secret token); empty without ``annotators``."""
        return {name: f"{self.url}?token={token}" for name, token in self.server.tokens.items()}

    @property
    def page_instructions(self) -> str:
        """The instructions the page shows: ``instructions``, or the task's own (``default_instructions``)."""
        return self.instructions if self.instructions is not None else default_instructions(self.env_id)

    def attach(self, env: "VecEnv", buffer: "PreferenceReplayBuffer") -> None:
        """
        Called by the model when it is made, loaded or given a new env: decide how ``env`` is shown (``showing.show``:
        MuJoCo states, the env's render states or recorded frames; an env that cannot be shown is refused), switch on
        what that records beside the transitions of ``buffer``, start the web server (and print the annotators' links
        the first time).
        """
        recording = dict(episodes=self.recorded_episodes, max_bytes=self.recording_bytes, parent=self.recording_dir)
        self.shown_from, self.env_id = showing.show(self.clips, env, buffer, recording)
        self.clips.folder()  # made now, not by two threads at once
        serving = self.server.running
        self.port = self.server.start(self.host, self.port)
        if self.links and not serving:
            lines = "\n".join(f"  {name}: {link}" for name, link in self.links.items())
            print(f"WebTeacher: serving {self.url}; each annotator opens their own (secret) link:\n{lines}", flush=True)

    def show_progress(self, asked: int, budget: int) -> None:
        """The run's queries asked so far and its budget, shown on the page between sessions."""
        self.store.show_progress(asked, budget)

    def show_reward_history(self, history: list[dict]) -> None:
        """
        Every reward update so far, shown on the page as a curve of corr(r̂, r) per feedback session with its latest
        value: whether the team's labels teach r̂ the task. A copy of plain values is kept (a NaN becomes None).

        :param history: one dict per reward update, oldest first: ``session``, ``step``, ``labels``, ``accuracy`` and
            ``correlation`` (Pearson's, of r̂ with the env's reward; NaN where it is undefined)
        """
        self.store.show_reward_history(history)

    def ask(self, pairs: SegmentPairs, context: FeedbackContext) -> np.ndarray:
        """
        Show every pair on the page and wait for its answers: μ per pair (the mean of its answers that are not skips),
        NaN when all are skips (or a timeout came first). Each answer (and undo) is journaled through ``context`` the
        moment it is given. May be called from any thread, one feedback session at a time.
        """
        if self.clips.renderer is None:
            raise RuntimeError("WebTeacher was not attached to an env (PEBBLE/PRIDE attach their teacher themselves)")
        if pairs.render_states is None:
            raise ValueError("WebTeacher needs pairs with render_states (recorded once it is attached to the model)")
        session = Session(
            context.session,
            [Question(uuid.uuid4().hex[:12], inputs) for inputs in pairs.inputs],
            context.asked_before,
            context,
        )
        known = self.quality.known_from_reward(pairs)
        self.store.begin(session)
        where = f"{self.url} (each annotator through their own link)" if self.links else self.url
        print(
            f"WebTeacher: feedback session {session.number}, {len(session.queries)} queries: answer them at {where}",
            flush=True,
        )
        try:
            self.clips.render(self.store, session, pairs.render_states, known)  # the page shows the first ones meanwhile
            self.store.wait(self.timeout, self.reminder_interval, self.url)
        except BaseException:
            self.store.cancel(session)
            raise
        labels = np.array([query.label() for query in session.queries])
        self.quality.session_over(session)
        return labels

    def close(self) -> None:
        """
        Write the agreement report (a failed write is only warned about), stop the web server, close the renderer's env
        and remove the temporary clips.
        """
        self.quality.write_report()
        self.clips.close()
        self.server.stop()

    def agreement(self) -> dict[str, dict[str, Any]]:
        """Per annotator, over every answer given to this teacher: ``Quality.agreement()``."""
        return self.quality.agreement()


_shared: WebTeacher | None = None


def shared_web_teacher() -> WebTeacher:
    """
    The teacher of ``teacher="web"``: one ``WebTeacher()`` (port 8000) per process, attached to the last model made
    or loaded with it, so that a second model in the same process (a resumed run) finds the port its own.
    """
    global _shared
    if _shared is None:
        _shared = WebTeacher()
    return _shared


register_teacher("web", lambda seed: shared_web_teacher())
