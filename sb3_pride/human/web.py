"""
``WebTeacher``: people label segment pairs in a browser while the agent trains.

At each feedback session the run renders every queried pair as two H.264 clips (re-rendered from the simulator
states recorded beside the transitions), serves them on a web page and waits until every query has its answers.
One person on this machine needs nothing more; several annotators each open a secret link, are handed queries no one
else is answering (or, with ``answers_per_query=k``, the same query as ``k - 1`` others), and may be checked with
known-answer questions mixed into what they see. Answers go to the run's preference journal the moment they are given
(``PEBBLE(preference_journal=...)``), each with who gave it and when, so a run killed mid-session loses none.
``WebTeacher`` is an ``InteractiveTeacher``: the model gives it its env and replay buffer when it is attached, and each
session's pairs with a ``FeedbackContext``; never the model itself.
"""

import atexit
import ipaddress
import json
import math
import queue
import random
import re
import secrets
import shutil
import socket
import tempfile
import threading
import time
import uuid
from collections import Counter
from collections.abc import Callable, Sequence
from concurrent.futures import Future
from dataclasses import dataclass, field
from datetime import datetime, timezone
from importlib import resources
from pathlib import Path
from typing import TYPE_CHECKING, Any, ClassVar

import numpy as np

from sb3_pride.common.journal import JournalEntry, atomic_write_path, query_id
from sb3_pride.common.queries import SegmentPairs
from sb3_pride.common.render_states import enable_render_states
from sb3_pride.common.teachers import FeedbackContext, InteractiveTeacher, register_teacher

if TYPE_CHECKING:
    from stable_baselines3.common.vec_env import VecEnv

    from sb3_pride.common.buffers import PreferenceReplayBuffer

#: the answers the page may send: μ = P[right segment preferred]; None is a skip
ALLOWED_LABELS = (0.0, 0.5, 1.0, None)
#: the addresses that only this machine reaches: the one place a page may be served without annotators' tokens
LOCAL_HOSTS = ("127.0.0.1", "localhost", "::1")
#: how an annotator is named: it becomes part of logger keys (``annotators/<name>/...``) and of the report
ANNOTATOR_NAME = re.compile(r"[A-Za-z0-9_.-]{1,40}")
#: the name of the one person of ``annotators=None`` in the agreement report and the logger keys
ANONYMOUS = "anonymous"
#: questions handed to an annotator at a time: the one shown and the next, whose clips the page preloads
QUEUE_LENGTH = 2
#: seconds after which the questions handed to an annotator whose page stopped asking for the state (it asks every
#: second; a browser tab hidden for minutes, once a minute) are handed to others
RELEASE_AFTER = 90.0
#: known-answer questions kept to draw from (the oldest are dropped beyond it)
KNOWN_POOL_SIZE = 1000
#: what the page's team table leaves out during a feedback session (it would change only on known-answer questions)
HIDDEN_DURING_SESSION = ("known_answers", "known_answer_agreement", "compared_answers", "pairwise_agreement", "flagged")
#: a true-reward known answer needs a return scale above this (``return_scale``, or the spread of the pairs' returns)
MIN_RETURN_SCALE = 1e-8
#: an annotator is flagged when fewer than this share of their known-answer questions agree with the known answer...
FLAG_BELOW = 0.7
#: ...over at least this many of them
FLAG_MIN_KNOWN = 8

#: what the page asks for on the bundled tasks (by task name: the env id without its namespace and version)
TASK_INSTRUCTIONS: dict[str, str] = {
    "walker-walk": "Prefer the walker that moves forward faster while staying upright (torso high, not falling).",
    "walker-run": "Prefer the walker that runs forward faster while staying upright (torso high, not falling).",
    "walker-stand": "Prefer the walker that stands upright with its torso high and steady.",
    "cheetah-run": "Prefer the cheetah that runs forward (to the right) faster; flipping over or standing still is worse.",
    "hopper-hop": "Prefer the hopper that hops forward faster while staying upright.",
    "hopper-stand": "Prefer the hopper that stands upright with its torso high.",
    "humanoid-stand": "Prefer the humanoid that stands upright with its head high.",
    "humanoid-walk": "Prefer the humanoid that walks forward while staying upright.",
    "humanoid-run": "Prefer the humanoid that runs forward faster while staying upright.",
    "quadruped-walk": "Prefer the quadruped that walks forward faster while staying upright.",
    "quadruped-run": "Prefer the quadruped that runs forward faster while staying upright.",
    "cartpole-swingup": "Prefer the cart-pole whose pole is swung up and kept balanced upright, the cart near the centre.",
    "cartpole-balance": "Prefer the cart-pole whose pole stays balanced upright, the cart near the centre.",
    "pendulum-swingup": "Prefer the pendulum that is swung up and kept pointing straight up.",
    "acrobot-swingup": "Prefer the acrobot whose tip is swung up higher and kept there.",
    "reacher-easy": "Prefer the arm whose fingertip reaches the target sooner and stays on it.",
    "reacher-hard": "Prefer the arm whose fingertip reaches the target sooner and stays on it.",
    "finger-spin": "Prefer the finger that spins the hinged body faster.",
    "ball_in_cup-catch": "Prefer the segment in which the ball is swung into the cup and stays there.",
    "point_mass-easy": "Prefer the point mass that moves to the target and stays on it.",
    "button-press": "Prefer the robot arm that presses the button further in (reaching it first, then pushing straight).",
    "door-open": "Prefer the robot arm that opens the door wider (grabbing the handle and pulling the door round).",
    "drawer-open": "Prefer the robot arm that pulls the drawer further open (hooking the handle first).",
    "window-open": "Prefer the robot arm that slides the window further open (pushing its handle sideways).",
    "sweep-into": "Prefer the robot arm that sweeps the puck closer to the hole, and into it.",
    "hammer": "Prefer the robot arm that grasps the hammer and drives the nail further in.",
}
#: what the page asks for on any other task
GENERIC_INSTRUCTIONS = (
    "Prefer the segment in which the agent does its task better: more progress toward the goal, fewer falls or failures."
)


def default_instructions(env_id: str | None) -> str:
    """
    The instructions shown for ``env_id`` when none are given: the task's sentence of ``TASK_INSTRUCTIONS`` (matched
    by the id's task name, e.g. ``"sb3_pride/walker-walk-v0"`` -> ``"walker-walk"``), else ``GENERIC_INSTRUCTIONS``.
    """
    if env_id is None:
        return GENERIC_INSTRUCTIONS
    task = re.sub(r"-v\d+$", "", env_id.rsplit("/", 1)[-1])
    return TASK_INSTRUCTIONS.get(task, GENERIC_INSTRUCTIONS)


def is_local(host: str) -> bool:
    """Whether ``host`` is reached from this machine only (a loopback address or ``localhost``)."""
    if host in LOCAL_HOSTS:
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


@dataclass(eq=False)
class _Query:
    """A question on the page: one of the model's queries, or a known-answer question (``known`` set)."""

    id: str
    inputs: np.ndarray
    clips: tuple[str, str]
    known: float | None = None  # a known-answer question: the answer it is checked against
    ready: bool = False  # its clips are written: it may be handed out
    answers: dict[str, float] = field(default_factory=dict)  # annotator -> μ (NaN: skipped)
    scored: dict[str, "_Answer"] = field(default_factory=dict)  # known-answer question: annotator -> their first answer
    holders: set[str] = field(default_factory=set)  # annotators it is handed to who have not answered it yet
    pair: str = ""  # the journal's id of its inputs (query_id)

    def __post_init__(self) -> None:
        if not self.pair:
            self.pair = query_id(self.inputs)

    @property
    def taken(self) -> int:
        """The annotators who answered it or are answering it."""
        return len(self.answers) + len(self.holders)

    def label(self) -> float:
        """μ for the model: the mean of its answers that are not skips (NaN when all are, or when it has none)."""
        given = [value for value in self.answers.values() if not math.isnan(value)]
        return float(np.mean(given)) if given else math.nan


@dataclass(eq=False)
class _Answer:
    """One answer of an annotator (the model's query or a known-answer question), kept for the agreement report."""

    annotator: str
    pair: str
    label: float
    known: float | None


@dataclass(eq=False)
class _Known:
    """A pair whose answer is known, with its clips: the stuff of known-answer questions."""

    pair: str
    inputs: np.ndarray
    clips: tuple[str, str]  # the clip files
    answer: float
    source: str  # "true reward" or "majority"
    voters: frozenset[str] = frozenset()  # a majority's: the annotators who made it (never shown it as known)


@dataclass(eq=False)
class _Session:
    number: int
    queries: list[_Query]  # the model's queries, in the order of its pairs
    asked_before: int
    context: FeedbackContext
    known: dict[str, _Query] = field(default_factory=dict)  # known-answer questions handed out, by id
    queues: dict[str, list[_Query]] = field(default_factory=dict)  # annotator -> questions handed to them, shown first
    history: dict[str, list[tuple[_Query, _Answer]]] = field(default_factory=dict)  # annotator -> answers, oldest first
    known_shown: dict[str, set[str]] = field(default_factory=dict)  # annotator -> pairs shown as known-answer questions
    cancelled: bool = False

    def __post_init__(self) -> None:
        self.by_id = {query.id: query for query in self.queries}
        self.by_pair = {query.pair: query for query in self.queries}

    def find(self, question_id: str) -> _Query | None:
        return self.by_id.get(question_id) or self.known.get(question_id)

    def open(self, answers_per_query: int) -> list[_Query]:
        """The model's queries that still lack answers."""
        return [query for query in self.queries if len(query.answers) < answers_per_query]

    def answers_given(self) -> int:
        """The answers given in this session by everyone (known-answer questions and skips included, undone ones not)."""
        return sum(len(answers) for answers in self.history.values())


class _RenderThread:
    """
    The one thread that does all of a teacher's MuJoCo work: an OpenGL (EGL) context belongs to the thread that made
    it, and ``ask()`` may be called from any thread. Started on first use; a daemon, so it never holds up an exit.
    """

    def __init__(self) -> None:
        self._jobs: queue.SimpleQueue = queue.SimpleQueue()
        self._thread: threading.Thread | None = None
        self._lock = threading.Lock()

    def submit(self, function: Callable[..., Any], *args: Any, **kwargs: Any) -> Future:
        future: Future = Future()
        with self._lock:
            if self._thread is None:
                self._thread = threading.Thread(target=self._loop, name="WebTeacher-render", daemon=True)
                self._thread.start()
            self._jobs.put((future, function, args, kwargs))
        return future

    def call(self, function: Callable[..., Any], *args: Any, **kwargs: Any) -> Any:
        return self.submit(function, *args, **kwargs).result()

    def stop(self) -> None:
        with self._lock:
            if self._thread is not None:
                self._jobs.put(None)
                self._thread = None

    def _loop(self) -> None:
        while (job := self._jobs.get()) is not None:
            future, function, args, kwargs = job
            if not future.set_running_or_notify_cancel():
                continue
            try:
                future.set_result(function(*args, **kwargs))
            except BaseException as error:  # handed to the waiting thread
                future.set_exception(error)


class WebTeacher(InteractiveTeacher):
    """
    An ``InteractiveTeacher`` that asks people, on a web page (``http://host:port/``), which of two segments is better.

    The page plays both segments of a pair side by side as looping clips that restart together, with a playback
    speed control, buttons and the task's instructions; keys: ArrowLeft = left preferred (μ = 0), ArrowRight = right
    preferred (μ = 1), ArrowDown = equally good (μ = 0.5), s = skip, Backspace = undo your last answer of this
    session. Everything is served by the training process (no internet needed). Use it as
    ``PEBBLE(..., teacher=WebTeacher(port=8000))`` or ``teacher="web"``; needs the ``[human]`` extra and an env that can
    be re-rendered (every ``sb3_pride/...`` env).

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
    """

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
    ):
        if isinstance(port, bool) or not isinstance(port, int) or not 0 <= port <= 65535:
            raise ValueError(f"port must be an integer in [0, 65535], got {port!r}")
        if timeout is not None and not timeout > 0:
            raise ValueError(f"timeout must be > 0 seconds or None, got {timeout!r}")
        if reminder_interval <= 0:
            raise ValueError(f"reminder_interval must be > 0 seconds, got {reminder_interval!r}")
        for name, value in (("width", width), ("height", height)):
            if isinstance(value, bool) or not isinstance(value, int) or value < 16:
                raise ValueError(f"{name} must be an integer >= 16 pixels, got {value!r}")
        if not isinstance(host, str) or not host:
            raise ValueError(f"host must be an address to bind, e.g. '127.0.0.1' or '0.0.0.0', got {host!r}")
        names = self._check_annotators(annotators, host)
        if instructions is not None and not isinstance(instructions, str):
            raise ValueError(f"instructions must be a string (plain text) or None (the task's own), got {instructions!r}")
        most = 1 if names is None else len(names)
        if isinstance(answers_per_query, bool) or not isinstance(answers_per_query, int) or not 1 <= answers_per_query <= most:
            raise ValueError(
                f"answers_per_query must be an integer in [1, {most}] (different annotators answer each query; "
                f"{most} annotator(s) given), got {answers_per_query!r}"
            )
        rate = known_answer_rate
        if isinstance(rate, bool) or not isinstance(rate, (int, float)) or not 0 <= rate < 1:
            raise ValueError(f"known_answer_rate must be a number in [0, 1), got {known_answer_rate!r}")
        if known_answer_margin is not None and not (
            isinstance(known_answer_margin, (int, float)) and 0 < known_answer_margin < math.inf
        ):
            raise ValueError(f"known_answer_margin must be a number > 0 (return_scales) or None, got {known_answer_margin!r}")
        if seed is not None and (isinstance(seed, bool) or not isinstance(seed, int)):
            raise ValueError(f"seed must be an integer or None, got {seed!r}")
        report_file = None if report_path is None else self._check_report_path(report_path)
        from sb3_pride.human.render import use_headless_gl

        use_headless_gl()  # before the first env is made: MuJoCo reads MUJOCO_GL once
        self.port, self.host, self.timeout = port, host, timeout
        self.width, self.height, self.reminder_interval = width, height, reminder_interval
        self.clip_dir = None if clip_dir is None else Path(clip_dir)
        self.camera = camera
        self.annotators = names
        self.instructions = instructions
        self.answers_per_query = answers_per_query
        self.known_answer_rate = float(known_answer_rate)
        self.known_answer_margin = None if known_answer_margin is None else float(known_answer_margin)
        self.report_path = report_file
        self.seed = seed
        self._init_runtime()

    @staticmethod
    def _check_report_path(report_path: str | Path) -> Path:
        """``report_path`` as a ``Path``, once its folder exists (made here) and it is not a folder itself."""
        if not isinstance(report_path, (str, Path)) or str(report_path) == "":
            raise ValueError(f"report_path must be a file path (str or Path) or None, got {report_path!r}")
        path = Path(report_path)
        if path.is_dir():
            raise ValueError(f"report_path must be a file, got the folder {str(path)!r}")
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
        except OSError as error:
            raise ValueError(f"report_path {str(path)!r} cannot be written: its folder cannot be made ({error})") from None
        return path

    @staticmethod
    def _check_annotators(annotators: Sequence[str] | None, host: str) -> list[str] | None:
        if annotators is None:
            if not is_local(host):
                raise ValueError(
                    f"annotators must be given to serve on {host!r}: beyond this machine ({', '.join(LOCAL_HOSTS)}) each "
                    f"person needs a secret link, e.g. WebTeacher(host={host!r}, annotators=['ana', 'ben'])"
                )
            return None
        if isinstance(annotators, str) or not isinstance(annotators, Sequence) or len(annotators) == 0:
            raise ValueError(f"annotators must be a non-empty list of names or None (one person), got {annotators!r}")
        names = list(annotators)
        for name in names:
            if not isinstance(name, str) or not ANNOTATOR_NAME.fullmatch(name):
                raise ValueError(
                    "annotators must be names of 1 to 40 letters, digits, '_', '-' or '.' (they name logger keys), "
                    f"got {name!r}"
                )
        if len(set(names)) != len(names):
            raise ValueError(f"annotators must be distinct names, got {names}")
        return names

    def _init_runtime(self) -> None:
        self._attached = False
        self._env_id: str | None = None
        self._budget: dict[str, int | None] = {"max": None, "asked": None}
        self._renderer: Any = None
        self._render_thread = _RenderThread()
        self._server: Any = None
        self._session: _Session | None = None
        self._condition = threading.Condition()
        self._report_lock = threading.Lock()
        self._last_seen: dict[str, float] = {}  # annotator -> when their page last asked for the state
        self._temporary_dir: str | None = None
        # a new teacher (a loaded model's too) makes new tokens: they are never saved
        self._tokens = {name: secrets.token_urlsafe(18) for name in self.annotators or ()}
        self._known: list[_Known] = []  # known-answer pairs, oldest first
        self._answers: list[_Answer] = []  # every answer given to this teacher, oldest first
        self._seen: dict[str, set[str]] = {}  # pair -> annotators who answered it
        self._clip_alias: dict[str, str] = {}  # a known-answer question's clip name -> the file it shows
        self._rng = random.Random(self.seed)
        self._stats: dict[str, dict[str, Any]] | None = None  # agreement(), until the next answer
        self._flagged: set[str] = set()  # annotators already warned about on the console

    # a saved model keeps the settings, not the server, the tokens or the answers
    _SETTINGS = (
        "port", "host", "timeout", "width", "height", "clip_dir", "reminder_interval", "camera", "annotators",
        "instructions", "answers_per_query", "known_answer_rate", "known_answer_margin", "report_path", "seed",
    )  # fmt: skip
    _DEFAULTS: ClassVar[dict[str, Any]] = dict(
        annotators=None, instructions=None, answers_per_query=1, known_answer_rate=0.0, known_answer_margin=0.5,
        report_path=None, seed=None,
    )  # fmt: skip

    def __getstate__(self) -> dict:
        return {name: self.__dict__[name] for name in self._SETTINGS}

    def __setstate__(self, state: dict) -> None:
        self.__dict__.update({**self._DEFAULTS, **state})  # a teacher saved before a setting existed gets its default
        self._init_runtime()

    @property
    def url(self) -> str:
        """The page's address (with ``annotators``, each opens their own link instead: ``links``)."""
        host = socket.gethostname() if self.host in ("0.0.0.0", "::", "") else self.host
        return f"http://[{host}]:{self.port}/" if ":" in host else f"http://{host}:{self.port}/"

    @property
    def links(self) -> dict[str, str]:
        """Each annotator's personal link (the page's URL with their secret token); empty without ``annotators``."""
        return {name: f"{self.url}?token={token}" for name, token in self._tokens.items()}

    @property
    def page_instructions(self) -> str:
        """The instructions the page shows: ``instructions``, or the task's own (``default_instructions``)."""
        return self.instructions if self.instructions is not None else default_instructions(self._env_id)

    # attaching --------------------------------------------------------------------------------------------------
    def attach(self, env: "VecEnv", buffer: "PreferenceReplayBuffer") -> None:
        """
        Called by the model when it is made, loaded or given a new env: check that ``env`` can be re-rendered,
        switch on the recording of simulator states beside the transitions of ``buffer``, start the web server.
        """
        from sb3_pride.human.render import SegmentRenderer

        try:
            env_id = env.get_attr("render_env_id")[0]
        except AttributeError:
            raise ValueError(
                "WebTeacher re-renders segments from the simulator states that RenderStates records: make the env as "
                "'sb3_pride/<domain>-<task>-v0' (dm_control) or 'sb3_pride/<task>-v3' (Meta-World), or wrap a MuJoCo env "
                "with sb3_pride.human.RenderStates(env, env_id=...)"
            ) from None
        if buffer.size() > 0 and buffer.render_states is None:
            raise ValueError(
                f"the replay buffer holds {buffer.size()} transitions recorded without simulator states (by a scripted "
                "teacher's run): a WebTeacher could not show segments of them. Resume a WebTeacher run's buffer, or start "
                "from an empty one"
            )
        if self._renderer is None or self._renderer.env_id != env_id:
            # made (and later used and closed) in the render thread, which owns every GL context of this teacher
            renderer = self._render_thread.call(
                SegmentRenderer, env_id, width=self.width, height=self.height, camera=self.camera
            )
            if self._renderer is not None:
                self._render_thread.call(self._renderer.close)
            self._renderer = renderer
        state_size = enable_render_states(env, self._renderer.layout)
        if state_size != self._renderer.state_size:
            raise ValueError(
                f"the env records states of {state_size} numbers but a fresh {env_id!r} has {self._renderer.state_size}: "
                "RenderStates(env, env_id=...) must name an id that makes this same env"
            )
        buffer.record_render_states = True
        self._env_id = env_id
        self._attached = True
        self._clips_folder()  # made now, not by two threads at once
        self._start_server()

    def _start_server(self) -> None:
        if self._server is not None:
            return
        if not self._tokens and not is_local(self.host):  # host set after construction, or an unpickled teacher
            raise ValueError(
                f"annotators must be given to serve on {self.host!r}: beyond this machine ({', '.join(LOCAL_HOSTS)}) "
                f"each person needs a secret link, e.g. WebTeacher(host={self.host!r}, annotators=['ana', 'ben'])"
            )
        from werkzeug.serving import make_server

        try:
            self._server = make_server(
                self.host, self.port, self._make_app(), threaded=True, request_handler=_quiet_request_handler()
            )
        except (OSError, SystemExit) as error:  # werkzeug exits (SystemExit) on a port in use, after saying so
            raise ValueError(
                f"port {self.port} on {self.host} is in use or cannot be bound: pass another, WebTeacher(port=...)"
            ) from error
        self.port = self._server.server_port
        threading.Thread(target=self._server.serve_forever, args=(0.1,), name="WebTeacher", daemon=True).start()
        if self._tokens:
            lines = "\n".join(f"  {name}: {link}" for name, link in self.links.items())
            print(f"WebTeacher: serving {self.url}; each annotator opens their own (secret) link:\n{lines}", flush=True)

    def close(self) -> None:
        """
        Write the agreement report (a failed write is only warned about), stop the web server, close the renderer's env
        and remove the temporary clips.
        """
        self._write_report()
        if self._renderer is not None:
            self._render_thread.call(self._renderer.close)
            self._renderer = None
        self._render_thread.stop()
        if self._server is not None:
            self._server.shutdown()
            self._server.server_close()
            self._server = None
        if self._temporary_dir is not None:
            shutil.rmtree(self._temporary_dir, ignore_errors=True)
            self._temporary_dir = None

    def _clips_folder(self) -> Path:
        if self.clip_dir is not None:
            self.clip_dir.mkdir(parents=True, exist_ok=True)
            return self.clip_dir
        if self._temporary_dir is None:
            self._temporary_dir = tempfile.mkdtemp(prefix="sb3_pride_clips_")
            atexit.register(shutil.rmtree, self._temporary_dir, ignore_errors=True)
        return Path(self._temporary_dir)

    def show_progress(self, asked: int, budget: int) -> None:
        """The run's queries asked so far and its budget, shown on the page between sessions."""
        with self._condition:
            self._budget = {"max": budget, "asked": asked}

    # a feedback session -----------------------------------------------------------------------------------------
    def ask(self, pairs: SegmentPairs, context: FeedbackContext) -> np.ndarray:
        """
        Show every pair on the page and wait for its answers: μ per pair (the mean of its answers that are not skips),
        NaN when all are skips (or a timeout came first). Each answer (and undo) is journaled through ``context`` the
        moment it is given. May be called from any thread, one feedback session at a time.
        """
        if not self._attached:
            raise RuntimeError("WebTeacher was not attached to an env (PEBBLE/PRIDE attach their teacher themselves)")
        if pairs.render_states is None:
            raise ValueError("WebTeacher needs pairs with render_states (recorded once it is attached to the model)")
        queries = []
        for inputs in pairs.inputs:
            question_id = uuid.uuid4().hex[:12]
            queries.append(_Query(question_id, inputs, self._clip_urls(question_id)))
        known = self._known_from_reward(pairs)
        session = _Session(context.session, queries, context.asked_before, context)
        with self._condition:
            if self._session is not None:
                raise RuntimeError(
                    f"WebTeacher asks one feedback session at a time: session {self._session.number} is still open"
                )
            self._session = session
            # the session's queries count as asked from its start: a budget that moved with each answer would tell
            # the model's queries from known-answer questions
            self._budget = {"max": context.budget, "asked": context.asked_before + len(queries)}
            self._condition.notify_all()
        where = f"{self.url} (each annotator through their own link)" if self._tokens else self.url
        print(f"WebTeacher: feedback session {session.number}, {len(queries)} queries: answer them at {where}", flush=True)
        try:
            # the clips are rendered in order (in the render thread) while the page already shows the first ones
            self._render_thread.call(self._render_clips, session, pairs.render_states, known)
            self._wait_for_answers()
        except BaseException:
            with self._condition:
                session.cancelled = True
                if self._session is session:
                    self._session = None
                self._condition.notify_all()
            raise
        labels = np.array([query.label() for query in session.queries])
        self._session_over(session)
        return labels

    @staticmethod
    def _clip_urls(question_id: str) -> tuple[str, str]:
        return f"/clips/{question_id}-left.mp4", f"/clips/{question_id}-right.mp4"

    @staticmethod
    def _clip_files(query: _Query) -> tuple[str, str]:
        """The names of the files of ``query``'s clips."""
        return Path(query.clips[0]).name, Path(query.clips[1]).name

    def _known_from_reward(self, pairs: SegmentPairs) -> list[float | None]:
        """
        Per pair, its answer when the true reward makes it clear (the higher return), else None. The scale of the
        margin is ``return_scale``, but at least the spread (std) of the pairs' segment returns: a ``return_scale`` of
        about 0 would otherwise make any difference, however small, clear. None at all when both are about 0.
        """
        if self.known_answer_rate == 0 or self.known_answer_margin is None or pairs.true_rewards is None:
            return [None] * len(pairs)
        returns = np.asarray(pairs.true_rewards, dtype=np.float64).sum(axis=-1)
        spread = float(np.std(returns)) if np.isfinite(returns).all() else 0.0
        scale = max(abs(float(pairs.return_scale)), spread)
        if not scale > MIN_RETURN_SCALE:
            return [None] * len(pairs)
        difference = returns[:, 1] - returns[:, 0]
        clear = np.abs(difference) >= self.known_answer_margin * scale
        clear &= (difference != 0) & np.isfinite(difference)
        return [float(d > 0) if is_clear else None for d, is_clear in zip(difference, clear, strict=True)]

    def _render_clips(self, session: _Session, render_states: np.ndarray, known: list[float | None]) -> None:
        """Render and encode each query's two clips, in order (runs in the render thread)."""
        from sb3_pride.human.render import encode_mp4

        folder = self._clips_folder()
        for query, states, answer in zip(session.queries, render_states, known, strict=True):
            if session.cancelled:
                return
            for clip, segment_states in zip(query.clips, states, strict=True):
                encode_mp4(self._renderer.render(segment_states), self._renderer.fps, folder / Path(clip).name)
            with self._condition:
                query.ready = True
                if answer is not None:
                    self._add_known(_Known(query.pair, query.inputs, self._clip_files(query), answer, "true reward"))
                self._condition.notify_all()

    def _add_known(self, known: _Known) -> None:
        """Keep a known-answer pair (once; the oldest are dropped beyond ``KNOWN_POOL_SIZE``). Holds the lock."""
        if any(entry.pair == known.pair for entry in self._known):
            return
        self._known.append(known)
        del self._known[:-KNOWN_POOL_SIZE]

    def _wait_for_answers(self) -> None:
        """Wait until every query has its answers (or the timeout skips the rest), then close the session."""
        start = last_reminder = time.monotonic()
        k = self.answers_per_query
        with self._condition:
            session = self._session
            assert session is not None
            while session.open(k):
                now = time.monotonic()
                if self.timeout is not None and now - start >= self.timeout:
                    # queries nobody answered are skipped: asked, not labeled, and journaled as such
                    skipped = [query for query in session.open(k) if not query.answers]
                    session.context.record(
                        [JournalEntry(session.number, query.inputs, math.nan, time=time.time()) for query in skipped]
                    )
                    partial = len(session.open(k)) - len(skipped)
                    short = f", {partial} with fewer than {k} answers" if partial else ""
                    print(f"WebTeacher: timeout, {len(skipped)} queries skipped{short}", flush=True)
                    break
                if now - last_reminder >= self.reminder_interval:
                    last_reminder = now
                    print(
                        f"WebTeacher: still waiting for {len(session.open(k))} queries of feedback session "
                        f"{session.number} at {self.url} (page last seen: {self._seen_summary(now)})",
                        flush=True,
                    )
                wait = self.reminder_interval - (now - last_reminder)
                if self.timeout is not None:
                    wait = min(wait, self.timeout - (now - start))
                self._condition.wait(timeout=max(wait, 0.01))
            # closed in the same locked block: no answer or undo can reach it once it is over
            self._session = None
            self._condition.notify_all()

    def _seen_summary(self, now: float) -> str:
        def ago(name: str) -> str:
            seen = self._last_seen.get(name)
            return "never" if seen is None else f"{now - seen:.0f} s ago"

        if not self._tokens:
            return ago(ANONYMOUS)
        return ", ".join(f"{name} {ago(name)}" for name in self._tokens)

    def _session_over(self, session: _Session) -> None:
        """After a session: majorities become known answers; the agreement is logged, reported and checked."""
        with self._condition:
            for query in session.queries:
                self._learn_majority(query)
            report = self._agreement()
        for name, stats in report.items():
            for key in ("answers", "known_answers", "known_answer_agreement", "compared_answers", "pairwise_agreement"):
                if stats[key] is not None:
                    session.context.log(f"annotators/{name}/{key}", float(stats[key]))
            if stats["flagged"] and name not in self._flagged:
                self._flagged.add(name)
                print(
                    f"WebTeacher: {name} matched only {stats['known_answer_agreement']:.0%} of {stats['known_answers']} "
                    "known answers: check their labels",
                    flush=True,
                )
        self._write_report(report)

    def _learn_majority(self, query: _Query) -> None:
        """A query on which at least two annotators, a majority of those who did not skip, chose one side becomes known."""
        if self.known_answer_rate == 0:
            return
        given = [value for value in query.answers.values() if not math.isnan(value)]
        if len(given) < 2:
            return
        label, count = Counter(given).most_common(1)[0]
        if count >= 2 and 2 * count > len(given) and label in (0.0, 1.0):
            voters = frozenset(name for name, value in query.answers.items() if value == label)
            self._add_known(_Known(query.pair, query.inputs, self._clip_files(query), label, "majority", voters))

    # who answers what -------------------------------------------------------------------------------------------
    def _person(self, annotator: str | None) -> str | None:
        """The annotator behind a call: the one person without ``annotators``; None for nobody (an overview)."""
        if not self._tokens:
            return ANONYMOUS
        if annotator is not None and annotator not in self._tokens:
            raise ValueError(f"annotator must be one of {list(self._tokens)}, got {annotator!r}")
        return annotator

    def _journal_name(self, name: str) -> str | None:
        return None if not self._tokens else name

    def _hand_out(self, session: _Session, name: str) -> list[_Query]:
        """The questions handed to ``name`` (the first is shown), topped up to ``QUEUE_LENGTH``. Holds the lock."""
        self._release_stale(session, name)
        handed = session.queues.setdefault(name, [])
        while len(handed) < QUEUE_LENGTH:
            question = self._next_question(session, name, first=not handed)
            if question is None:
                break
            handed.append(question)
            if question.known is None:
                question.holders.add(name)
        return handed

    def _release_stale(self, session: _Session, name: str) -> None:
        """Questions handed to annotators whose page went quiet (``RELEASE_AFTER``) go back to the others."""
        now = time.monotonic()
        for other, handed in session.queues.items():
            if other != name and handed and now - self._last_seen.get(other, now) > RELEASE_AFTER:
                for question in handed:
                    question.holders.discard(other)
                handed.clear()

    def _next_question(self, session: _Session, name: str, first: bool) -> _Query | None:
        """
        The next question for ``name``: a ready query they have not answered that still needs answers (those others
        already answer first: they finish sooner), else (for the one shown) one preloaded for someone else; in
        place of it, a known-answer question at ``known_answer_rate``.
        """
        k = self.answers_per_query
        candidates = [
            query
            for query in session.queries
            if query.ready and name not in query.answers and name not in query.holders and query.taken < k
        ]
        real = max(candidates, key=lambda q: q.taken) if candidates else None  # max: the first of the most taken
        preloaded: tuple[str, _Query] | None = None
        if real is None and first:
            preloaded = next(
                (
                    (other, handed[1])
                    for other, handed in session.queues.items()
                    if other != name and len(handed) > 1 and handed[1].known is None and name not in handed[1].answers
                ),
                None,
            )
        if real is None and preloaded is None:
            return None  # nothing left for them: no known-answer question either, the session is nearly over
        if self.known_answer_rate > 0 and self._rng.random() < self.known_answer_rate:
            known = self._known_question(session, name)
            if known is not None:
                return known
        if real is None and preloaded is not None:
            other, real = preloaded
            session.queues[other].remove(real)
            real.holders.discard(other)
        return real

    def _known_question(self, session: _Session, name: str) -> _Query | None:
        """
        A known-answer question for ``name``: a known pair they have not answered, never one of this session's queries
        that may still be handed to them, never a majority they were part of. Only one person alone (no
        ``annotators``) is shown, when no other is left, a true-reward pair they answered in an earlier session.
        """
        shown = session.known_shown.setdefault(name, set())
        fresh: list[_Known] = []
        again: list[_Known] = []
        for known in self._known:
            if known.pair in shown or name in known.voters:
                continue
            live = session.by_pair.get(known.pair)
            if live is not None and (name in live.answers or name in live.holders or live.taken < self.answers_per_query):
                continue
            if name not in self._seen.get(known.pair, ()):
                fresh.append(known)
            elif not self._tokens and known.source == "true reward" and live is None:
                again.append(known)
        if not (fresh or again):
            return None
        known = self._rng.choice(fresh or again)
        shown.add(known.pair)
        question_id = uuid.uuid4().hex[:12]  # its own id and clip names: nothing on the page tells it apart
        question = _Query(question_id, known.inputs, self._clip_urls(question_id), known.answer, True, pair=known.pair)
        for url, file in zip(question.clips, known.clips, strict=True):
            self._clip_alias[Path(url).name] = file
        session.known[question_id] = question
        return question

    # answers ----------------------------------------------------------------------------------------------------
    def answer(self, question_id: Any, label: Any, annotator: str | None = None) -> tuple[int, str]:
        """
        Record ``annotator``'s answer to question ``question_id`` (the one shown to them); a refusal records nothing.
        A known-answer question is scored by the first answer the annotator gives it: after an undo, their new
        answer is shown as theirs but changes no count of ``agreement()``.

        :param question_id: the id of the question shown (``state()["query"]["id"]``)
        :param label: μ: 0 (left preferred), 1 (right), 0.5 (equally good) or None (skip)
        :param annotator: who answers (None without ``annotators``: the one person)
        :return: (HTTP status as an int, message as a str): 200 when recorded; 400 for a malformed label or id; 404
            for a question that is not in the open session; 409 for no open session, a question the annotator already
            answered or a query that has all its answers; 403 for a question not shown to the annotator
        """
        if not (
            label is None or (isinstance(label, (int, float)) and not isinstance(label, bool) and label in ALLOWED_LABELS)
        ):
            return 400, f"label must be 0 (left), 1 (right), 0.5 (equal) or null (skip), got {label!r}"
        if not isinstance(question_id, str):
            return 400, f"id must be the string id of the question shown, got {question_id!r}"
        with self._condition:
            name = self._person(annotator)
            if name is None:
                return 400, "name the annotator who answers"
            self._last_seen[name] = time.monotonic()
            session = self._session
            if session is None:
                return 409, "no feedback session is open (it is over, or the next one has not begun)"
            question = session.find(question_id)
            if question is None:
                return 404, f"no question {question_id!r} in feedback session {session.number}"
            if name in question.answers:
                return 409, f"question {question_id!r} is answered already by you (undo first)"
            if question.known is None and len(question.answers) >= self.answers_per_query:
                return 409, f"query {question_id!r} has all its answers already"
            handed = session.queues.get(name, [])
            if not handed or handed[0] is not question:
                return 403, f"question {question_id!r} is not the one shown to you"
            value = math.nan if label is None else float(label)
            if question.known is None:
                # journaled (flushed to disk) first, then kept, so that a failed write changes nothing
                annotator_name = self._journal_name(name)
                session.context.record([JournalEntry(session.number, question.inputs, value, annotator_name, time.time())])
            handed.pop(0)
            question.holders.discard(name)
            question.answers[name] = value
            given = question.scored.get(name)  # a known-answer question answered again after an undo: the first counts
            if given is None:
                given = _Answer(name, question.pair, value, question.known)
                self._answers.append(given)
                if question.known is not None:
                    question.scored[name] = given
            self._seen.setdefault(question.pair, set()).add(name)
            session.history.setdefault(name, []).append((question, given))
            self._changed()
            return 200, "recorded"

    def undo(self, annotator: str | None = None) -> tuple[int, str]:
        """
        Take back ``annotator``'s last answer of this session (and say so in the journal); the question is shown to
        them again. An undone known-answer question keeps its score: the first answer given to it counts.

        :param annotator: whose answer (None without ``annotators``: the one person)
        :return: (HTTP status as an int, the question's id or why not as a str): 200 when taken back, 409 when there
            is none to take back
        """
        with self._condition:
            name = self._person(annotator)
            session = self._session
            if name is None or session is None or not session.history.get(name):
                return 409, "no answer of yours in this feedback session to undo"
            question, given = session.history[name][-1]
            if question.known is None:
                session.context.retract(session.number, entry_id=question.pair, annotator=self._journal_name(name))
            session.history[name].pop()
            del question.answers[name]
            if question.known is None:
                self._answers.remove(given)
                if not any(other.annotator == name and other.pair == question.pair for other in self._answers):
                    self._seen.get(question.pair, set()).discard(name)  # no answer of theirs to this pair is left
            handed = session.queues.setdefault(name, [])
            handed.insert(0, question)
            if question.known is None:
                question.holders.add(name)
            while len(handed) > QUEUE_LENGTH:
                handed.pop().holders.discard(name)
            self._changed()
            return 200, question.id

    def _changed(self) -> None:
        """After an answer or an undo: agreement is recounted, the waiting session hears of it."""
        self._stats = None
        self._condition.notify_all()

    # agreement --------------------------------------------------------------------------------------------------
    def agreement(self) -> dict[str, dict[str, Any]]:
        """
        Per annotator (``"anonymous"`` without ``annotators``), over every answer given to this teacher:

        - ``answers``, ``skips``: questions answered (known-answer ones included), and how many of them were skips;
        - ``known_answers``, ``known_answer_agreement``: known-answer questions answered (not skipped), and the share
          whose answer was the known one (None before the first);
        - ``compared_answers``, ``pairwise_agreement``: (pair, other annotator) comparisons on the pairs both answered
          (not skipped), and the share on which they gave the same answer (None before the first);
        - ``flagged``: whether ``known_answer_agreement`` is below ``FLAG_BELOW`` over at least ``FLAG_MIN_KNOWN``
          known answers.
        """
        with self._condition:
            return {name: dict(stats) for name, stats in self._agreement().items()}

    def _agreement(self) -> dict[str, dict[str, Any]]:
        """``agreement()``, computed once per change. Holds the lock."""
        if self._stats is not None:
            return self._stats
        names = list(self._tokens) or [ANONYMOUS]
        counts: dict[str, Counter[str]] = {name: Counter() for name in names}
        latest: dict[str, dict[str, float]] = {}  # pair -> annotator -> their latest answer that is not a skip
        for given in self._answers:
            count = counts[given.annotator]
            count["answers"] += 1
            if math.isnan(given.label):
                count["skips"] += 1
                continue
            if given.known is not None:
                count["known"] += 1
                count["known_right"] += given.label == given.known
            latest.setdefault(given.pair, {})[given.annotator] = given.label
        for labels in latest.values():
            for name, label in labels.items():
                for other, other_label in labels.items():
                    if other != name:
                        counts[name]["compared"] += 1
                        counts[name]["agreed"] += label == other_label
        stats = {}
        for name, count in counts.items():
            known_agreement = count["known_right"] / count["known"] if count["known"] else None
            stats[name] = {
                "answers": count["answers"],
                "skips": count["skips"],
                "known_answers": count["known"],
                "known_answer_agreement": known_agreement,
                "compared_answers": count["compared"],
                "pairwise_agreement": count["agreed"] / count["compared"] if count["compared"] else None,
                "flagged": known_agreement is not None and count["known"] >= FLAG_MIN_KNOWN and known_agreement < FLAG_BELOW,
            }
        self._stats = stats
        return stats

    def _write_report(self, report: dict[str, dict[str, Any]] | None = None) -> None:
        """``agreement()`` to ``report_path``, written whole (a reader never sees half of it); a failure is warned about."""
        if self.report_path is None:
            return
        with self._condition:
            report = report if report is not None else self._agreement()
            payload = {"time": time.time(), "known_answer_pairs": len(self._known), "annotators": report}
        try:
            with self._report_lock, atomic_write_path(self.report_path) as temporary:
                temporary.write_text(json.dumps(payload, indent=2) + "\n")
        except OSError as error:  # the session's answers are in: a report that cannot be written fails nothing else
            print(f"WebTeacher: warning: the agreement report could not be written to {self.report_path}: {error}", flush=True)

    # the web page -----------------------------------------------------------------------------------------------
    def state(self, annotator: str | None = None) -> dict[str, Any]:
        """
        What ``annotator``'s page shows (handing them questions): the question shown and the next, the session's and
        the budget's progress, their answers and the team's, the instructions.

        Nothing in it moves differently on a known-answer question: ``answered`` counts the session's answers (known
        ones and skips included) out of ``total`` (with ``known_answer_rate > 0`` an estimate, ``estimate`` true, never
        below ``answered``), the budget counts the session's queries as asked from its start, and the team's
        agreement (``known_answer*``, ``compared_answers``, ``pairwise_agreement``, ``flagged``) is only shown between
        feedback sessions (None during one; ``agreement()`` always has it).

        :param annotator: whose page (None without ``annotators``: the one person; with them, None is an overview
            that hands nothing out)
        """
        with self._condition:
            name = self._person(annotator)
            if name is not None:
                self._last_seen[name] = time.monotonic()
            session = self._session
            handed = self._hand_out(session, name) if session is not None and name is not None else []
            if session is None:
                waiting = "waiting for the next feedback session"
            elif handed:
                waiting = ""
            elif any(not query.ready for query in session.open(self.answers_per_query)):
                waiting = "rendering the next clips…"
            elif session.open(self.answers_per_query):
                waiting = "the others are answering the last queries of this session"
            else:
                waiting = "all answered"
            stats = self._agreement()
            team = []
            for other, row in stats.items():
                row = dict(row)
                if session is not None:  # during a session agreement would tell known-answer questions apart
                    row.update({key: None for key in HIDDEN_DURING_SESSION})
                team.append({"name": other, "session": len(session.history.get(other, [])) if session else 0, **row})
            answered, total = (0, 0) if session is None else self._progress(session)
            return {
                "session": None if session is None else session.number,
                "you": annotator if self._tokens else None,
                "query": None if not handed else {"id": handed[0].id, "left": handed[0].clips[0], "right": handed[0].clips[1]},
                "next": None if len(handed) < 2 else {"left": handed[1].clips[0], "right": handed[1].clips[1]},
                "waiting": waiting,
                "answered": answered,
                "total": total,
                "estimate": self.known_answer_rate > 0,
                "answers_per_query": self.answers_per_query,
                "team": team,
                "budget": dict(self._budget),
                "instructions": self.page_instructions,
            }

    def _progress(self, session: _Session) -> tuple[int, int]:
        """
        (answers given, answers expected) in ``session``: every answer counts, a known-answer question's too; the
        expected ones are the queries' answers plus, at ``known_answer_rate``, known-answer questions in proportion.
        Holds the lock.
        """
        answered = session.answers_given()
        expected = math.ceil(len(session.queries) * self.answers_per_query / (1 - self.known_answer_rate))
        return answered, max(expected, answered)

    def _token_owner(self, token: str) -> tuple[bool, str | None]:
        """(True, whose token) when ``token`` is an annotator's, (True, None) when none is needed, else (False, None)."""
        if not self._tokens:
            return True, None
        for name, secret in self._tokens.items():
            if secrets.compare_digest(token.encode(), secret.encode()):
                return True, name
        return False, None

    def _guard(self, app: Any) -> None:
        """Answer errors as JSON, and refuse what no page of this teacher sends (other sites' requests)."""
        from flask import jsonify, request
        from werkzeug.exceptions import HTTPException

        @app.errorhandler(HTTPException)
        def http_error(error: HTTPException) -> Any:  # an unknown route, a wrong method, a body too large: JSON too
            return jsonify(error=error.description), error.code

        @app.errorhandler(Exception)
        def server_error(error: Exception) -> Any:  # a bug, or a journal that cannot be written: the page says so
            app.logger.exception("WebTeacher: a request failed")
            return jsonify(error=f"the training run failed to handle this request: {type(error).__name__}: {error}"), 500

        @app.before_request
        def guard() -> Any:
            # without tokens, only this machine's names: a page of another site whose name resolves to 127.0.0.1
            # (DNS rebinding) is refused
            if not self._tokens and not is_local(_host_name(request.host)):
                return jsonify(error=f"this page is served to this machine only: open {self.url}, not {request.host}"), 403
            # a POST must be JSON, which another site's page cannot send without the browser asking first (CSRF)
            if request.method == "POST" and not request.is_json:
                return jsonify(error="a POST must carry a JSON body (Content-Type: application/json)"), 415
            return None

    def _make_app(self) -> Any:
        from flask import Flask, jsonify, request, send_from_directory

        app = Flask("sb3_pride.human", static_folder=None)
        app.config["MAX_CONTENT_LENGTH"] = 64 * 1024  # an answer is a few bytes: a larger body is refused (413)
        page = resources.files("sb3_pride.human").joinpath("static/index.html").read_text()
        # every clip is served with this date and no ETag: a known-answer question's clips are the files of an older
        # pair, and neither header may tell that
        clip_date = datetime.now(timezone.utc).replace(microsecond=0)

        self._guard(app)

        def annotator() -> tuple[bool, str | None]:
            """(True, who) for a request that carries a valid token or needs none, (False, None) otherwise."""
            return self._token_owner(request.headers.get("X-Annotator-Token") or request.args.get("token") or "")

        def refused(status: int, message: str) -> Any:
            return jsonify(error=message), status

        no_token = "this needs an annotator's token: open your personal link (…/?token=…) from whoever runs the training"

        @app.get("/")
        def index() -> Any:
            return page, 200, {"Content-Type": "text/html; charset=utf-8", "Cache-Control": "no-store"}

        @app.get("/api/state")
        def state() -> Any:
            ok, name = annotator()
            return jsonify(self.state(name)) if ok else refused(401, no_token)

        @app.post("/api/answer")
        def answer() -> Any:
            ok, name = annotator()
            if not ok:
                return refused(401, no_token)
            body = request.get_json(silent=True)
            if not isinstance(body, dict) or "id" not in body or "label" not in body:
                return refused(400, 'expected a JSON object {"id": ..., "label": 0 | 0.5 | 1 | null}')
            status, message = self.answer(body["id"], body["label"], name)
            return (jsonify(state=self.state(name)), 200) if status == 200 else refused(status, message)

        @app.post("/api/undo")
        def undo() -> Any:
            ok, name = annotator()
            if not ok:
                return refused(401, no_token)
            if not isinstance(request.get_json(silent=True), dict):
                return refused(400, "expected a JSON object ({})")
            status, message = self.undo(name)
            return (jsonify(undone=message, state=self.state(name)), 200) if status == 200 else refused(status, message)

        @app.get("/clips/<name>")
        def clip(name: str) -> Any:
            if not annotator()[0]:
                return refused(401, no_token)
            if not name.endswith(".mp4"):  # not a clip being written (.part)
                return refused(404, f"no clip {name!r}")
            file = self._clip_alias.get(name, name)
            # conditional=True: HTTP Range requests (seeking and looping video need them) and 304s
            return send_from_directory(
                self._clips_folder(), file, mimetype="video/mp4", conditional=True, etag=False, last_modified=clip_date
            )

        return app


def _host_name(host: str) -> str:
    """The name of a ``Host`` header without its port: ``"127.0.0.1:8000"`` -> ``"127.0.0.1"``, ``"[::1]:80"`` -> ``"::1"``."""
    if host.startswith("["):
        return host[1 : host.find("]")] if "]" in host else host
    return host.rsplit(":", 1)[0] if host.count(":") == 1 else host


#: a token in a logged request line: ``token=...`` in its query string
_TOKEN_IN_URL = re.compile(r"(token=)[^&\s\"']*")


def _quiet_request_handler() -> type:
    """werkzeug's request handler without a console line per request (the page polls every second); tokens masked."""
    from werkzeug.serving import WSGIRequestHandler

    class QuietRequestHandler(WSGIRequestHandler):
        def log_request(self, code: Any = "-", size: Any = "-") -> None:
            if isinstance(code, int) and code < 400:  # an HTTPStatus is an int
                return
            # werkzeug builds the line from self.path: masked there for the call, then put back
            path = getattr(self, "path", None)
            if path is not None:
                self.path = _TOKEN_IN_URL.sub(r"\1...", path)
            try:
                super().log_request(code, size)
            finally:
                if path is not None:
                    self.path = path

        def log(self, type: str, message: str, *args: Any) -> None:  # every line (errors too), masked as a whole
            line = message % args if args else message
            super().log(type, "%s", _TOKEN_IN_URL.sub(r"\1...", line))

    return QuietRequestHandler


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
