"""
A ``WebTeacher``'s clips: the folder they are written to, the renderer that draws them (``SegmentRenderer``,
``StateRenderer`` or ``RecordedRenderer``, chosen when the teacher is attached: ``sb3_pride.human.showing``), and the
one thread that does all of its rendering work.
"""

import atexit
import queue
import shutil
import tempfile
import threading
from collections.abc import Callable
from concurrent.futures import Future
from pathlib import Path
from typing import Any

import numpy as np

from sb3_pride.human import render
from sb3_pride.human.questions import Session
from sb3_pride.human.store import AnswerStore


class RenderThread:
    """
    The one thread that does all of a teacher's MuJoCo work: an OpenGL (EGL) context belongs to the thread that made
    it, and ``ask()`` may be called from any thread. Started on first use; a daemon, so it never holds up an exit.
    """

    def __init__(self) -> None:
        self._jobs: queue.SimpleQueue = queue.SimpleQueue()
        self._thread: threading.Thread | None = None
        self._lock = threading.Lock()

    def submit(self, function: Callable[..., Any], *args: Any, **kwargs: Any) -> Future:
        """Run ``function(*args, **kwargs)`` in the thread, after the jobs before it; its result comes in the future."""
        future: Future = Future()
        with self._lock:
            if self._thread is None:
                self._thread = threading.Thread(target=self._loop, name="WebTeacher-render", daemon=True)
                self._thread.start()
            self._jobs.put((future, function, args, kwargs))
        return future

    def call(self, function: Callable[..., Any], *args: Any, **kwargs: Any) -> Any:
        """``submit``, then wait for its result (its exception is raised here)."""
        return self.submit(function, *args, **kwargs).result()

    def stop(self) -> None:
        """End the thread once the jobs given before are done (a later ``submit`` starts a new one)."""
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


class Clips:
    """
    Where a teacher's clips are written, and what writes them: ``renderer`` (a ``SegmentRenderer``, or anything with
    ``render(states) -> frames``, ``fps`` and ``close()``, and optionally ``prepare(render_states)``, called in
    ``render()``'s thread before any clip is drawn), used and closed in ``thread``.

    A clip's file is named after the question it was rendered for (``<id>-left.mp4``, ``<id>-right.mp4``); the web
    server finds the file of an address through the open session (``AnswerStore.clip_file``), so that a known-answer
    question's clips, which are an older question's files, are served under its own addresses.

    :param clip_dir: the folder (None: a temporary folder, removed by ``close()`` or at exit)
    :param width: clip width in pixels
    :param height: clip height in pixels
    :param camera: the MuJoCo camera (None: the family's default, see ``SegmentRenderer``)
    """

    def __init__(self, clip_dir: Path | None = None, width: int = 320, height: int = 240, camera: str | int | None = None):
        self.clip_dir, self.width, self.height, self.camera = clip_dir, width, height, camera
        self.renderer: Any = None
        self.thread = RenderThread()
        self._temporary: str | None = None

    def folder(self) -> Path:
        """The clips' folder (made on first use)."""
        if self.clip_dir is not None:
            self.clip_dir.mkdir(parents=True, exist_ok=True)
            return self.clip_dir
        if self._temporary is None:
            self._temporary = tempfile.mkdtemp(prefix="sb3_pride_clips_")
            atexit.register(shutil.rmtree, self._temporary, ignore_errors=True)
        return Path(self._temporary)

    def use(self, env_id: str) -> Any:
        """The MuJoCo renderer of ``env_id``: made (in the render thread) unless the one there renders it already."""
        if getattr(self.renderer, "layout", None) is None or self.renderer.env_id != env_id:  # not a MuJoCo renderer
            self.use_renderer(
                self.thread.call(render.SegmentRenderer, env_id, width=self.width, height=self.height, camera=self.camera)
            )
        return self.renderer

    def use_renderer(self, renderer: Any) -> None:
        """Draw the clips with ``renderer`` from now on; the one used before is closed (in the render thread)."""
        if renderer is not self.renderer and self.renderer is not None:
            self.thread.call(self.renderer.close)
        self.renderer = renderer

    def render(self, store: AnswerStore, session: Session, render_states: np.ndarray, known: list[float | None]) -> None:
        """
        Render and encode each query's two clips in order, in the render thread; each query is handed out (``ready``)
        as soon as its clips are written, the page showing the first while the rest are rendered. Returns when all
        are written, or the session was cancelled.

        :param known: per query, its answer where the true reward makes it clear (``Quality.known_from_reward``)
        """
        prepare = getattr(self.renderer, "prepare", None)  # recorded frames: read them all now, before the agent moves on
        self.thread.call(self._render, store, session, render_states if prepare is None else prepare(render_states), known)

    def _render(self, store: AnswerStore, session: Session, render_states: Any, known: list[float | None]) -> None:
        folder = self.folder()
        for query, states, answer in zip(session.queries, render_states, known, strict=True):
            if session.cancelled:
                return
            for file, segment_states in zip(query.files, states, strict=True):
                render.encode_mp4(self.renderer.render(segment_states), self.renderer.fps, folder / file)
            store.ready(query, answer)

    def close(self) -> None:
        """Close the renderer's env, stop the render thread, remove a temporary folder."""
        if self.renderer is not None:
            self.thread.call(self.renderer.close)
            self.renderer = None
        self.thread.stop()
        if self._temporary is not None:
            shutil.rmtree(self._temporary, ignore_errors=True)
            self._temporary = None
