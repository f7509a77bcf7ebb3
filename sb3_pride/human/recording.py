"""
What an env renders, recorded while the agent collects, for a teacher that shows segments of envs that cannot be
re-rendered from a stored state (classic control, Box2D, a user's own simulator without the render-state protocol).

- ``RecordRenders`` wraps each env of the model's ``DummyVecEnv`` (put there by the teacher when it is attached, never
  before: a scripted run records nothing). After every step it puts into ``info["render_state"]`` either the env's own
  render state (``get_render_state()``, the render-state protocol of ``sb3_pride.render_states``) or the key of
  the frame it rendered, which ``FrameRecording`` stores; ``PreferenceReplayBuffer`` keeps it beside the transition.
- ``FrameRecording`` keeps each rendered frame losslessly compressed (zlib) in files of ``CHUNK_FRAMES`` frames, in a
  folder of its own, for a rolling window of each env's most recent episodes (the running one included, as the query
  sampler counts them), and at most ``max_bytes`` bytes of frames. What leaves the window is marked in the buffer
  (NaN render states), so that no segment crossing the window's edge is ever sampled for a person.
"""

import atexit
import os
import re
import secrets
import shutil
import struct
import tempfile
import threading
import zlib
from array import array
from collections import OrderedDict, deque
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np

#: frames per file: the unit in which the byte limit evicts (a running episode longer than the limit included)
CHUNK_FRAMES = 64
#: evicted chunks whose files are kept a little longer (never sampled again): the last session may be reading them
KEPT_EVICTED = 4
#: each stored frame: height, width, channels, compressed length, then the zlib bytes
RECORD = struct.Struct("<HHHI")
#: the folder of a recording: ``<prefix><pid>_<token>`` (a folder of a process that is gone is removed)
FOLDER_PREFIX = "sb3_pride_recording_"
#: the smallest byte limit: a few chunks of full-HD frames
MIN_BYTES = 1 << 20


@dataclass
class Chunk:
    """One file of frames of one episode: frames ``first`` to ``first + len(offsets) - 1``."""

    episode: int
    env: int
    first: int
    path: Path
    offsets: array = field(default_factory=lambda: array("q"))  # 8 bytes per frame
    size: int = 0


def process_alive(pid: int) -> bool:
    """Whether process ``pid`` exists (one of another user counts)."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def remove_stale_recordings(parent: Path) -> list[Path]:
    """Remove the recordings in ``parent`` left by processes that are gone (a crash); returns the folders removed."""
    removed = []
    for folder in parent.glob(f"{FOLDER_PREFIX}*"):
        match = re.fullmatch(rf"{FOLDER_PREFIX}(\d+)_[0-9a-f]+", folder.name)
        if match and folder.is_dir() and int(match[1]) != os.getpid() and not process_alive(int(match[1])):
            shutil.rmtree(folder, ignore_errors=True)
            removed.append(folder)
    return removed


def check_recording_settings(episodes: Any, max_bytes: Any, parent: Any) -> Path | None:
    """The recording settings of a ``WebTeacher`` checked (each refusal names its parameter); ``parent`` as a path."""
    if isinstance(episodes, bool) or not isinstance(episodes, int) or episodes < 1:
        raise ValueError(f"recorded_episodes must be an integer >= 1 (episodes kept to show), got {episodes!r}")
    if isinstance(max_bytes, bool) or not isinstance(max_bytes, int) or max_bytes < MIN_BYTES:
        raise ValueError(f"recording_bytes must be an integer >= {MIN_BYTES} (1 MiB), got {max_bytes!r}")
    if parent is None:
        return None
    if not isinstance(parent, (str, Path)) or str(parent) == "" or Path(parent).is_file():
        raise ValueError(f"recording_dir must be a folder path (str or Path) or None (the temporary folder), got {parent!r}")
    return Path(parent)


class FrameRecording:
    """
    Frames rendered by the ``n_envs`` envs of a vectorized env, keyed ``(token, episode, frame)`` (``add``), kept for
    each env's ``ceil(episodes / n_envs)`` most recent episodes (the running one included) and at most ``max_bytes``
    bytes of compressed frames (the oldest chunk goes first), in ``<parent>/<FOLDER_PREFIX><pid>_<token>``, removed by
    ``close()`` or at exit; a folder left by a crashed process is removed when the next recording starts in ``parent``.
    Thread-safe: the agent adds frames while the teacher reads them.

    :param n_envs: the number of envs recorded
    :param episodes: episodes kept, over all envs (as the query sampler's ``max_query_episodes`` counts them)
    :param max_bytes: the most bytes of frames kept (files awaiting removal and the chunks being written aside)
    :param parent: the folder that holds the recording's folder (None: the system's temporary folder)
    """

    def __init__(self, n_envs: int, episodes: int = 100, max_bytes: int = 1 << 30, parent: Path | None = None):
        check_recording_settings(episodes, max_bytes, parent)
        self.n_envs, self.max_bytes = n_envs, max_bytes
        self.episodes_per_env = -(-episodes // n_envs)
        #: identifies this recording's keys (exact in float64): keys of another recording are never shown
        self.token = secrets.randbits(52)
        parent = Path(parent) if parent is not None else Path(tempfile.gettempdir())
        parent.mkdir(parents=True, exist_ok=True)
        remove_stale_recordings(parent)
        self.folder = parent / f"{FOLDER_PREFIX}{os.getpid()}_{self.token:x}"
        self.folder.mkdir()
        self.buffer: Any = None  # the replay buffer whose render states hold this recording's keys
        self.bytes = 0
        self.closed = False
        self._lock = threading.Lock()
        self._chunks: OrderedDict[tuple[int, int], Chunk] = OrderedDict()  # (episode, first frame), oldest first
        self._episodes: list[deque[int]] = [deque() for _ in range(n_envs)]
        self._running: list[int | None] = [None] * n_envs  # None: the next frame starts an episode
        self._frames = [0] * n_envs  # frames of the running episode
        self._files: list[Any] = [None] * n_envs
        self._writing: list[Chunk | None] = [None] * n_envs
        self._evicted: OrderedDict[tuple[int, int], Chunk] = OrderedDict()  # files not removed yet
        self._next_episode = 0
        atexit.register(self.close)

    def new_episode(self, env: int) -> None:
        """Env ``env`` was reset: its next frame starts an episode (an episode without frames never counts)."""
        with self._lock:
            self._running[env] = None

    def add(self, env: int, frame: np.ndarray) -> np.ndarray:
        """Store ``frame`` (h, w, 3) uint8 of env ``env``; returns its key ``[token, episode, frame]`` (NaN once closed)."""
        frame = np.ascontiguousarray(frame)
        if frame.dtype != np.uint8 or frame.ndim != 3 or frame.shape[2] not in (3, 4):
            raise ValueError(f"env.render() must return an (height, width, 3) uint8 array, got {frame.dtype} {frame.shape}")
        data = zlib.compress(frame.data, 1)
        with self._lock:
            if self.closed:
                return np.full(3, np.nan)
            if self._running[env] is None:
                self._start_episode(env)
            episode, index = self._running[env], self._frames[env]
            assert episode is not None
            if index % CHUNK_FRAMES == 0:
                self._open_chunk(env, episode, index)
            chunk = self._writing[env]
            assert chunk is not None
            record = RECORD.pack(*frame.shape, len(data)) + data
            self._files[env].write(record)
            self._files[env].flush()  # readable by the teacher's thread now
            chunk.offsets.append(chunk.size)
            chunk.size += len(record)
            self.bytes += len(record)
            self._frames[env] += 1
            if self.bytes > self.max_bytes:
                writing = {id(chunk) for chunk in self._writing}
                self._evict([key for key, chunk in self._chunks.items() if id(chunk) not in writing], limit=True)
            return np.array([self.token, episode, index], dtype=np.float64)

    def _start_episode(self, env: int) -> None:
        self._running[env], self._frames[env] = self._next_episode, 0
        self._next_episode += 1
        self._episodes[env].append(self._next_episode - 1)
        while len(self._episodes[env]) > self.episodes_per_env:
            old = self._episodes[env].popleft()
            self._evict([key for key in self._chunks if key[0] == old])

    def _open_chunk(self, env: int, episode: int, first: int) -> None:
        if self._files[env] is not None:
            self._files[env].close()
        path = self.folder / f"{episode:09d}-{first:09d}.frames"
        self._files[env] = open(path, "ab")  # kept open while the chunk is written
        self._writing[env] = self._chunks[(episode, first)] = Chunk(episode, env, first, path)

    def _evict(self, keys: list[tuple[int, int]], limit: bool = False) -> None:
        """
        Forget chunks ``keys`` (oldest first; with ``limit``, only until the bytes kept are within ``max_bytes``):
        their rows in the buffer are marked unshowable at once, their files removed ``KEPT_EVICTED`` evictions later.
        """
        for key in keys:
            if limit and self.bytes <= self.max_bytes:
                return
            chunk = self._chunks.pop(key)
            self.bytes -= chunk.size
            self._mask(chunk.episode, chunk.first, chunk.first + len(chunk.offsets))
            self._evicted[key] = chunk
            while len(self._evicted) > KEPT_EVICTED:
                self._evicted.popitem(last=False)[1].path.unlink(missing_ok=True)

    def _mask(self, episode: int, first: int, stop: int) -> None:
        states = getattr(self.buffer, "render_states", None)
        if states is None or states.shape[-1] != 3:
            return
        rows = np.flatnonzero(states[..., 1] == episode)
        keys = states.reshape(-1, 3)[rows]
        hit = rows[(keys[:, 0] == self.token) & (keys[:, 2] >= first) & (keys[:, 2] < stop)]
        states.reshape(-1, 3)[hit] = np.nan

    def use_buffer(self, buffer: Any) -> int:
        """
        Mark the rows of ``buffer`` whose frames this recording does not hold (another run's, another teacher's) as
        unshowable, and keep marking the rows of the frames it drops; returns how many rows were marked.
        """
        with self._lock:
            self.buffer = buffer
            states = getattr(buffer, "render_states", None)
            if states is None:
                return 0
            if states.shape[-1] != 3:
                raise ValueError(
                    f"the replay buffer holds render states of {states.shape[-1]} numbers, recorded from another kind of "
                    "env or teacher: a WebTeacher that records frames cannot show them. Start from an empty buffer"
                )
            flat = states.reshape(-1, 3)
            foreign = np.isfinite(flat[:, 0]) & (flat[:, 0] != self.token)
            flat[foreign] = np.nan
            return int(foreign.sum())

    def in_window(self, keys: np.ndarray) -> np.ndarray:
        """Per key of ``keys`` (k, 3), whether its frame is in the window (a frame that left it is never offered)."""
        with self._lock:
            return np.array(
                [
                    token == self.token and (int(episode), int(index) - int(index) % CHUNK_FRAMES) in self._chunks
                    for token, episode, index in np.nan_to_num(np.asarray(keys, dtype=np.float64), nan=-1.0)
                ],
                dtype=bool,
            )

    def records(self, keys: np.ndarray) -> list[bytes]:
        """The stored (compressed) frames of ``keys`` (k, 3), read now: what ``decode`` turns into frames."""
        with self._lock:
            out = []
            for token, episode, index in np.asarray(keys, dtype=np.float64):
                first = int(index) - int(index) % CHUNK_FRAMES if np.isfinite(index) else -1
                key = (int(episode), first)
                chunk = self._chunks.get(key, self._evicted.get(key)) if token == self.token and not self.closed else None
                if chunk is None or int(index) - first >= len(chunk.offsets):
                    raise ValueError(
                        f"frame {index:.0f} of episode {episode:.0f} is not in the recording (it left the window of "
                        "recorded_episodes / recording_bytes, or was recorded by another run): it cannot be shown"
                    )
                with open(chunk.path, "rb") as file:
                    file.seek(chunk.offsets[int(index) - first])
                    head = file.read(RECORD.size)
                    out.append(head + file.read(RECORD.unpack(head)[3]))
            return out

    @staticmethod
    def decode(records: list[bytes]) -> np.ndarray:
        """(k, h, w, 3) uint8 frames of ``records`` (a 4-channel frame loses its alpha)."""
        frames = []
        for record in records:
            height, width, channels, _ = RECORD.unpack_from(record)
            pixels = np.frombuffer(zlib.decompress(record[RECORD.size :]), dtype=np.uint8)
            frames.append(pixels.reshape(height, width, channels)[..., :3])
        return np.stack(frames)

    def frames(self, keys: np.ndarray) -> np.ndarray:
        """(k, h, w, 3) uint8 frames of ``keys`` (k, 3)."""
        return self.decode(self.records(keys))

    def disk_bytes(self) -> int:
        """Bytes of the recording's folder on disk now (files awaiting removal included)."""
        return sum(path.stat().st_size for path in self.folder.glob("*.frames")) if self.folder.exists() else 0

    def close(self) -> None:
        """Stop recording (later frames get NaN keys) and remove the folder."""
        with self._lock:
            self.closed = True
            for index, file in enumerate(self._files):
                if file is not None:
                    file.close()
                    self._files[index] = None
            self._chunks.clear()
            self._evicted.clear()
            self._writing = [None] * self.n_envs
            self.bytes = 0
            shutil.rmtree(self.folder, ignore_errors=True)
        atexit.unregister(self.close)


class RecordRenders(gym.Wrapper):
    """
    ``info["render_state"]`` after each step, while a teacher asks for it (``record_frames``, ``record_render_states``):
    the key of the frame ``env.render()`` drew, stored in a ``FrameRecording``, or the env's own render state
    (``get_render_state()``). Off (nothing rendered, nothing added) until then.

    :param env: an env of the model's ``DummyVecEnv``
    :param index: its index there
    """

    def __init__(self, env: gym.Env, index: int = 0):
        super().__init__(env)
        self.index = index
        self.recording: FrameRecording | None = None
        self._render_state: Any = None

    def record_frames(self, recording: FrameRecording) -> None:
        """From now on, store every frame the env renders in ``recording``; its episode starts at the next step."""
        self.recording, self._render_state = recording, None
        recording.new_episode(self.index)

    def record_render_states(self) -> None:
        """From now on, put the env's ``get_render_state()`` after each step."""
        self.recording, self._render_state = None, self.env.get_wrapper_attr("get_render_state")

    def reset(self, **kwargs) -> tuple[Any, dict]:
        obs, info = self.env.reset(**kwargs)
        if self.recording is not None:
            self.recording.new_episode(self.index)
        return obs, info

    def step(self, action):
        obs, reward, terminated, truncated, info = self.env.step(action)
        if self.recording is not None:
            info["render_state"] = self.recording.add(self.index, self.env.render())  # type: ignore[arg-type]
        elif self._render_state is not None:
            info["render_state"] = np.asarray(self._render_state(), dtype=np.float64).reshape(-1)
        return obs, reward, terminated, truncated, info


def record_renders(vec_env: Any) -> list[RecordRenders]:
    """
    The ``RecordRenders`` of each env of ``vec_env`` (its ``DummyVecEnv`` under any ``VecEnvWrapper``), put there
    around each env now where they are not yet. Another vectorized env (``SubprocVecEnv``) is refused: its envs run in
    other processes, out of the teacher's reach.
    """
    from stable_baselines3.common.vec_env import DummyVecEnv, VecEnvWrapper

    base = vec_env
    while isinstance(base, VecEnvWrapper):
        base = base.venv
    if not isinstance(base, DummyVecEnv):
        raise ValueError(
            f"WebTeacher records what the env renders in this process, but the model's env is a {type(base).__name__}: "
            "use a DummyVecEnv (SB3's default: make_vec_env(..., vec_env_cls=DummyVecEnv)) or an env that RenderStates "
            "re-renders (every sb3_pride/... MuJoCo env)"
        )
    for index, env in enumerate(base.envs):
        if not isinstance(env, RecordRenders):
            base.envs[index] = RecordRenders(env, index)
    return list(base.envs)  # type: ignore[arg-type]
