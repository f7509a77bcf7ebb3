"""
``WebTeacher``: a person labels segment pairs in a browser while the agent trains.

At each feedback session the run renders every queried pair as two H.264 clips (re-rendered from the simulator
states recorded beside the transitions), serves them on a local web page and waits until every query is answered.
Answers go to the run's preference journal the moment they are given (``PEBBLE(preference_journal=...)``), so a
run killed mid-session loses none. ``WebTeacher`` is an ``InteractiveTeacher``: the model gives it its env and replay
buffer when it is attached, and each session's pairs with a ``FeedbackContext``; never the model itself.
"""

import atexit
import shutil
import tempfile
import threading
import time
import uuid
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from sb3_pride.common.journal import JournalEntry
from sb3_pride.common.queries import SegmentPairs
from sb3_pride.common.render_states import enable_render_states
from sb3_pride.common.teachers import FeedbackContext, InteractiveTeacher, register_teacher

if TYPE_CHECKING:
    from stable_baselines3.common.vec_env import VecEnv

    from sb3_pride.common.buffers import PreferenceReplayBuffer

#: the answers the page may send: μ = P[right segment preferred]; None is a skip
ALLOWED_LABELS = (0.0, 0.5, 1.0, None)


@dataclass
class _Query:
    id: str
    inputs: np.ndarray
    clips: tuple[str, str]
    label: float | None = None  # NaN: skipped
    answered: bool = False
    ready: bool = False  # its clips are written: the page may show it


@dataclass
class _Session:
    number: int
    queries: list[_Query]
    asked_before: int
    record: Any  # FeedbackContext.record / .retract: the run's journal
    retract: Any
    answer_order: list[str] = field(default_factory=list)

    @property
    def n_answered(self) -> int:
        return len(self.answer_order)

    def unanswered(self) -> list[_Query]:
        return [query for query in self.queries if not query.answered]


class WebTeacher(InteractiveTeacher):
    """
    An ``InteractiveTeacher`` that asks a person, on a local web page (``http://host:port/``), which of two segments is better.

    The page plays both segments of a pair side by side as looping clips that restart together, with a playback
    speed control and buttons; keys: ArrowLeft = left preferred (μ = 0), ArrowRight = right preferred (μ = 1),
    ArrowDown = equally good (μ = 0.5), s = skip, Backspace = undo the last answer of this session. Everything is
    served locally (no internet needed). Use it as ``PEBBLE(..., teacher=WebTeacher(port=8000))`` or
    ``teacher="web"``; needs the ``[human]`` extra and an env that can be re-rendered (every ``sb3_pride/...`` env).

    :param port: the TCP port of the page (0: any free port, read it back from ``.port``)
    :param host: the address to bind: 127.0.0.1 (this machine only; use ssh port forwarding from another one)
    :param timeout: seconds to wait for a session's answers; the rest are then skipped (asked, not labeled).
        None: wait as long as it takes
    :param width: clip width in pixels
    :param height: clip height in pixels
    :param clip_dir: where the clips are written (None: a temporary folder removed at exit)
    :param reminder_interval: seconds between console reminders (with the URL) while answers are awaited
    :param camera: the MuJoCo camera of the clips, by name or id (None: dm_control's first camera, Meta-World's
        "corner3", the free camera for other MuJoCo envs)
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
        from sb3_pride.human.render import use_headless_gl

        use_headless_gl()  # before the first env is made: MuJoCo reads MUJOCO_GL once
        self.port, self.host, self.timeout = port, host, timeout
        self.width, self.height, self.reminder_interval = width, height, reminder_interval
        self.clip_dir = None if clip_dir is None else Path(clip_dir)
        self.camera = camera
        self._init_runtime()

    def _init_runtime(self) -> None:
        self._attached = False
        self._budget: dict[str, int | None] = {"max": None, "asked": None}
        self._renderer: Any = None
        self._server: Any = None
        self._session: _Session | None = None
        self._condition = threading.Condition()
        self._last_seen = 0.0  # when the page last asked for the state
        self._temporary_dir: str | None = None

    # a saved model keeps the settings, not the server
    def __getstate__(self) -> dict:
        keep = ("port", "host", "timeout", "width", "height", "clip_dir", "reminder_interval", "camera")
        return {name: self.__dict__[name] for name in keep}

    def __setstate__(self, state: dict) -> None:
        self.__dict__.update(state)
        self._init_runtime()

    @property
    def url(self) -> str:
        return f"http://{self.host}:{self.port}/"

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
            self._renderer = SegmentRenderer(env_id, width=self.width, height=self.height, camera=self.camera)
        state_size = enable_render_states(env, self._renderer.layout)
        if state_size != self._renderer.state_size:
            raise ValueError(
                f"the env records states of {state_size} numbers but a fresh {env_id!r} has {self._renderer.state_size}: "
                "RenderStates(env, env_id=...) must name an id that makes this same env"
            )
        buffer.record_render_states = True
        self._attached = True
        self._clips_folder()  # made now, not by two threads at once
        self._start_server()

    def _start_server(self) -> None:
        if self._server is not None:
            return
        from werkzeug.serving import make_server

        try:
            self._server = make_server(self.host, self.port, self._make_app(), threaded=True)
        except (OSError, SystemExit) as error:  # werkzeug exits (SystemExit) on a port in use, after saying so
            raise ValueError(
                f"port {self.port} on {self.host} is in use or cannot be bound: pass another, WebTeacher(port=...)"
            ) from error
        self.port = self._server.server_port
        threading.Thread(target=self._server.serve_forever, name="WebTeacher", daemon=True).start()

    def close(self) -> None:
        """Stop the web server, close the renderer's env and remove the temporary clips."""
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None
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
        Show every pair on the page and wait for its answer: μ per pair, NaN for a skip (or a timeout). Each answer
        (and undo) is journaled through ``context`` the moment it is given.
        """
        if not self._attached:
            raise RuntimeError("WebTeacher was not attached to an env (PEBBLE/PRIDE attach their teacher themselves)")
        if pairs.render_states is None:
            raise ValueError("WebTeacher needs pairs with render_states (recorded once it is attached to the model)")
        from sb3_pride.human.render import encode_mp4

        number = context.session
        folder = self._clips_folder()
        queries = []
        for inputs in pairs.inputs:
            query_id = uuid.uuid4().hex[:12]
            queries.append(_Query(query_id, inputs, (f"/clips/{query_id}-left.mp4", f"/clips/{query_id}-right.mp4")))
        with self._condition:
            self._session = _Session(number, queries, context.asked_before, context.record, context.retract)
            self._budget = {"max": context.budget, "asked": context.asked_before}
            self._condition.notify_all()
        print(f"WebTeacher: feedback session {number}, {len(queries)} queries: answer them at {self.url}", flush=True)
        try:
            # the clips are rendered in order while the page already shows the first ones
            for query, states in zip(queries, pairs.render_states, strict=True):
                for clip, segment_states in zip(query.clips, states, strict=True):
                    encode_mp4(self._renderer.render(segment_states), self._renderer.fps, folder / Path(clip).name)
                with self._condition:
                    query.ready = True
                    self._condition.notify_all()
            session = self._wait_for_answers()
        except BaseException:
            with self._condition:
                self._session = None
            raise
        return np.array([np.nan if query.label is None else query.label for query in session.queries])

    def _wait_for_answers(self) -> _Session:
        """Wait until every query is answered (or the timeout skips the rest), then close the session and return it."""
        start = last_reminder = time.monotonic()
        with self._condition:
            assert self._session is not None
            while self._session.unanswered():
                now = time.monotonic()
                if self.timeout is not None and now - start >= self.timeout:
                    # the rest are skipped: asked, not labeled, and journaled as such
                    skipped = self._session.unanswered()
                    for query in skipped:
                        self._record(query, None)
                    print(f"WebTeacher: timeout, {len(skipped)} queries skipped", flush=True)
                    break
                if now - last_reminder >= self.reminder_interval:
                    last_reminder = now
                    seen = "never" if self._last_seen == 0 else f"{now - self._last_seen:.0f} s ago"
                    print(
                        f"WebTeacher: still waiting for {len(self._session.unanswered())} answers of feedback session "
                        f"{self._session.number} at {self.url} (page last seen: {seen})",
                        flush=True,
                    )
                wait = self.reminder_interval - (now - last_reminder)
                if self.timeout is not None:
                    wait = min(wait, self.timeout - (now - start))
                self._condition.wait(timeout=max(wait, 0.01))
            # closed in the same locked block: no answer or undo can reach it once it is over
            session, self._session = self._session, None
            return session

    def _record(self, query: _Query, label: float | None) -> None:
        """An answer: journaled (flushed to disk) first, then kept, so that a failed write changes nothing. Holds the lock."""
        assert self._session is not None
        value = np.nan if label is None else float(label)
        self._session.record([JournalEntry(self._session.number, query.inputs, value)])
        query.label, query.answered = value, True
        self._session.answer_order.append(query.id)
        self._budget["asked"] = self._session.asked_before + self._session.n_answered
        self._condition.notify_all()

    # the web page -----------------------------------------------------------------------------------------------
    def state(self) -> dict[str, Any]:
        """What the page shows: the session's queries (clips, answered or not), progress and the budget."""
        with self._condition:
            self._last_seen = time.monotonic()
            session, budget = self._session, dict(self._budget)
            if session is None:
                return {"session": None, "queries": [], "answered": 0, "total": 0, "budget": budget}
            queries = [
                {"id": q.id, "left": q.clips[0], "right": q.clips[1], "answered": q.answered, "ready": q.ready}
                for q in session.queries
            ]
            return {
                "session": session.number,
                "queries": queries,
                "answered": session.n_answered,
                "total": len(session.queries),
                "budget": budget,
            }

    def answer(self, query_id: Any, label: Any) -> tuple[bool, str]:
        """Record the answer to ``query_id``; refused (nothing recorded) for an unknown query or label."""
        if not (
            label is None or (isinstance(label, (int, float)) and not isinstance(label, bool) and label in ALLOWED_LABELS)
        ):
            return False, f"label must be 0 (left), 1 (right), 0.5 (equal) or null (skip), got {label!r}"
        with self._condition:
            session = self._session
            query = next((q for q in session.queries if q.id == query_id), None) if session else None
            if session is None or query is None or not query.ready:
                return False, f"no open query {query_id!r} in this feedback session (or its clips are not ready)"
            if query.answered:
                return False, f"query {query_id!r} is already answered (undo first)"
            first_open = next(q for q in session.queries if not q.answered)
            if query is not first_open:  # in order: the journal and the preference dataset then agree on the order
                return False, f"answer the queries in order: the next one is {first_open.id!r}, not {query_id!r}"
            self._record(query, None if label is None else float(label))
            return True, "recorded"

    def undo(self) -> tuple[bool, str]:
        """Take back the last answer of this session (and say so in the journal)."""
        with self._condition:
            session = self._session
            if session is None or not session.answer_order:
                return False, "no answer of this feedback session to undo"
            session.retract(session.number)  # journaled first, as answers are
            last = session.answer_order.pop()
            self._budget["asked"] = session.asked_before + session.n_answered
            query = next(q for q in session.queries if q.id == last)
            query.label, query.answered = None, False
            return True, query.id

    def _make_app(self) -> Any:
        from flask import Flask, jsonify, request, send_from_directory

        app = Flask("sb3_pride.human", static_folder=None)
        page = resources.files("sb3_pride.human").joinpath("static/index.html").read_text()

        @app.get("/")
        def index() -> Any:
            return page, 200, {"Content-Type": "text/html; charset=utf-8", "Cache-Control": "no-store"}

        @app.get("/api/state")
        def state() -> Any:
            return jsonify(self.state())

        @app.post("/api/answer")
        def answer() -> Any:
            body = request.get_json(silent=True)
            if not isinstance(body, dict) or "id" not in body or "label" not in body:
                return jsonify(error='expected a JSON object {"id": ..., "label": 0 | 0.5 | 1 | null}'), 400
            ok, message = self.answer(body["id"], body["label"])
            return (jsonify(state=self.state()), 200) if ok else (jsonify(error=message), 400)

        @app.post("/api/undo")
        def undo() -> Any:
            ok, message = self.undo()
            return (jsonify(undone=message, state=self.state()), 200) if ok else (jsonify(error=message), 400)

        @app.get("/clips/<name>")
        def clip(name: str) -> Any:
            # conditional=True: HTTP Range requests (seeking and looping video need them), ETag, 304s
            if not name.endswith(".mp4"):  # not a clip being written (.part)
                return jsonify(error=f"no clip {name!r}"), 404
            return send_from_directory(self._clips_folder(), name, mimetype="video/mp4", conditional=True)

        return app


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
