"""
Segments a person can watch: the simulator states recorded beside the transitions, re-rendered later in an env of
the renderer's own, and encoded as clips any browser plays.

- ``RenderStates`` (``sb3_pride.render_states``, on every ``sb3_pride/...`` env, off until a teacher needs
  pictures) records the MuJoCo state after each step beside the transition.
- ``SegmentRenderer`` restores those states one by one in its own env and renders them headless (``MUJOCO_GL=egl``),
  pixel-identical to frames rendered from the live env.
- ``encode_mp4`` writes H.264 mp4 (yuv420p, fast start) at the env's real frame rate with PyAV, which ships its own
  encoder (the ``[human]`` extra; no system ffmpeg).
"""

import ctypes.util
import os
import sys
from fractions import Fraction
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np

from sb3_pride.render_states import (
    capture_state,
    mujoco_handles,
    randomized_model_fields,
    restore_state,
)

#: scene effects left out of every frame (live ones too, for comparisons): Mesa's software EGL renders Meta-World
#: 4x faster without them (0.15 -> 0.04 s per 320 x 240 frame on this project's 2-core machine)
SCENE_FLAGS_OFF = ("mjRND_SHADOW", "mjRND_REFLECTION")
#: the camera of each family: dm_control's first (the task's own view, e.g. walker's tracking "side"), and a
#: Meta-World view that shows the hand, the object and the goal
METAWORLD_CAMERA = "corner3"


def use_headless_gl() -> None:
    """
    Headless rendering needs ``MUJOCO_GL=egl``, read once when MuJoCo is imported. Where it is not set, no display
    is, MuJoCo is not imported yet and Mesa's (or a GPU driver's) libEGL is installed, set it: a WebTeacher does when
    it is created (``teacher="web"`` and the demo's ``--teacher web`` too). Nothing else in the package changes
    ``MUJOCO_GL``: dm_control refuses to import where it names an EGL that cannot start.
    """
    if "MUJOCO_GL" in os.environ or os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"):
        return
    if "mujoco" not in sys.modules and ctypes.util.find_library("EGL"):
        os.environ["MUJOCO_GL"] = "egl"


def egl_available() -> bool:
    """Whether MuJoCo can render here (headless EGL, or whatever ``MUJOCO_GL`` names)."""
    use_headless_gl()
    try:
        import mujoco

        renderer = mujoco.Renderer(mujoco.MjModel.from_xml_string("<mujoco><worldbody/></mujoco>"), 16, 16)
        renderer.render()
        renderer.close()
        return True
    except Exception:
        return False


def frame_rate(env: gym.Env) -> float:
    """
    Frames per second of a clip played at the env's real speed: one frame per env step of ``dt`` seconds (dm_control's
    ``control_timestep``), else the env's ``metadata["render_fps"]``.
    """
    unwrapped = env.unwrapped
    control = getattr(getattr(unwrapped, "_env", None), "control_timestep", None)
    dt = control() if callable(control) else getattr(unwrapped, "dt", None)
    if not dt and (env.metadata or {}).get("render_fps"):
        return float(env.metadata["render_fps"])
    if not dt:
        raise ValueError(
            f"cannot tell the duration of one step of {env.spec.id if env.spec else env} (no control_timestep, dt or "
            "metadata['render_fps']): WebTeacher plays clips at the env's real speed; give the env a dt attribute"
        )
    return 1.0 / float(dt)


class StateRenderer:
    """
    Renders states recorded through the render-state protocol (``get_render_state``/``render_from_state`` of
    ``sb3_pride.render_states.RenderStateEnv``) in a copy of the env of its own: made again from its spec
    (``gymnasium.make``) when it has one, else a deep copy of the unwrapped env.

    :param env: the model's env (one of its ``DummyVecEnv``)
    """

    def __init__(self, env: gym.Env):
        spec = env.unwrapped.spec
        self.env_id = spec.id if spec is not None else type(env.unwrapped).__name__
        self.fps = frame_rate(env)
        self.env = copy_env(env)

    def render(self, states: np.ndarray) -> np.ndarray:
        """(k, height, width, 3) uint8 frames of ``states`` (k, state_dim)."""
        draw_state = self.env.get_wrapper_attr("render_from_state")
        frames = [np.asarray(draw_state(state)) for state in states]
        if any(frame.dtype != np.uint8 or frame.ndim != 3 or frame.shape != frames[0].shape for frame in frames):
            raise ValueError(f"{self.env_id}.render_from_state must return (height, width, 3) uint8 frames of one size")
        return np.stack(frames)[..., :3]

    def close(self) -> None:
        """Close the renderer's own env."""
        self.env.close()


def copy_env(env: gym.Env) -> gym.Env:
    """An env of its own like ``env``: ``gymnasium.make`` of its spec (``render_mode="rgb_array"``), else a deep copy."""
    import copy

    spec = env.unwrapped.spec
    if spec is not None and spec.id in gym.registry:
        try:
            return gym.make(spec, render_mode="rgb_array")
        except TypeError:  # an env that takes no render_mode
            return gym.make(spec)
    try:
        return copy.deepcopy(env.unwrapped)
    except Exception as error:
        raise ValueError(
            f"cannot copy {type(env.unwrapped).__name__} to re-render its states ({type(error).__name__}: {error}): "
            "register it (gymnasium.register) and make it with gymnasium.make, so that the teacher can make its own"
        ) from error


class RecordedRenderer:
    """
    Cuts clips from the frames a ``FrameRecording`` holds: ``prepare(keys)`` reads a session's (compressed) frames at
    once, ``render`` decodes them; ``close()`` removes the recording.

    :param recording: the recording of the model's env
    :param env_id: the env's id (or class name)
    :param fps: its frame rate
    """

    def __init__(self, recording: Any, env_id: str, fps: float):
        self.recording, self.env_id, self.fps = recording, env_id, fps

    def prepare(self, keys: np.ndarray) -> list[list[list[bytes]]]:
        """The stored frames of a session's ``keys`` (n, 2, k, 3), read now (the agent may drop them meanwhile)."""
        return [[self.recording.records(segment) for segment in pair] for pair in keys]

    def render(self, segment: np.ndarray | list[bytes]) -> np.ndarray:
        """(k, h, w, 3) uint8 frames of a segment's keys (k, 3) or of what ``prepare`` read for it."""
        records = self.recording.records(segment) if isinstance(segment, np.ndarray) else segment
        return self.recording.decode(records)

    def close(self) -> None:
        """Remove the recording (its envs record NaN keys from now on)."""
        self.recording.close()


class SegmentRenderer:
    """
    Renders recorded states (``RenderStates``) of env ``env_id`` headless, in an env of its own.

    :param env_id: a registered gymnasium id (dm_control or Meta-World, e.g. ``"sb3_pride/walker-walk-v0"``)
    :param width: frame width in pixels
    :param height: frame height in pixels
    :param camera: MuJoCo camera name or id (None: the family's default)
    """

    def __init__(self, env_id: str, width: int = 320, height: int = 240, camera: str | int | None = None):
        use_headless_gl()
        self.env_id, self.width, self.height = env_id, width, height
        self.env = gym.make(env_id)
        try:
            self._set_up(camera)
        except BaseException:
            # freed here, in the thread that made them: the GL contexts a reset may have made (quadruped-escape's
            # terrain) cannot be freed from another thread at exit
            self.env.close()
            raise

    def _set_up(self, camera: str | int | None) -> None:
        self.model, self.data = mujoco_handles(self.env)
        self.fps = frame_rate(self.env)
        #: the model fields a reset of this task re-draws, recorded with every state
        self.layout = randomized_model_fields(self.env)
        if camera is None:
            cameras = [self.model.camera(i).name for i in range(self.model.ncam)]
            if hasattr(self.env.unwrapped, "_env"):  # dm_control: the task's own first camera
                camera = 0 if cameras else -1
            else:
                camera = METAWORLD_CAMERA if METAWORLD_CAMERA in cameras else -1  # -1: MuJoCo's free camera
        self.camera = camera
        #: the length of one recorded state of this env
        self.state_size = len(capture_state(self.model, self.data, self.layout))
        try:  # fail now (no GL, a bad camera), not at the first feedback session
            self.render(capture_state(self.model, self.data, self.layout)[None])
        except ValueError:
            raise
        except Exception as error:
            raise ValueError(
                f"cannot render {self.env_id} headless ({type(error).__name__}: {error}); on a machine without a display "
                "set MUJOCO_GL=egl before the first env is made (and install Mesa's EGL: libegl1 libgl1-mesa-dri)"
            ) from error

    def render(self, states: np.ndarray) -> np.ndarray:
        """(k, height, width, 3) uint8 frames of ``states`` (k, state_dim)."""
        import mujoco

        frames = np.empty((len(states), self.height, self.width, 3), dtype=np.uint8)
        # a GL context per call, freed at its end: it belongs to the calling thread (training runs in any thread)
        with mujoco.Renderer(self.model, self.height, self.width) as renderer:
            for i, state in enumerate(states):
                restore_state(self.model, self.data, self.layout, state)
                frames[i] = draw(renderer, self.data, self.camera)
        return frames

    def close(self) -> None:
        """Close the renderer's own env."""
        self.env.close()


def render_live(env: gym.Env, width: int, height: int, camera: str | int) -> np.ndarray:
    """A frame of ``env`` as it is now, rendered as ``SegmentRenderer`` does (for comparisons)."""
    import mujoco

    model, data = mujoco_handles(env)
    with mujoco.Renderer(model, height, width) as renderer:
        return draw(renderer, data, camera)


def draw(renderer: Any, data: Any, camera: str | int) -> np.ndarray:
    """One frame of ``data`` seen from ``camera``, without the effects of ``SCENE_FLAGS_OFF``."""
    import mujoco

    renderer.update_scene(data, camera=camera)
    for flag in SCENE_FLAGS_OFF:
        renderer.scene.flags[getattr(mujoco.mjtRndFlag, flag)] = False
    return renderer.render()


def encode_mp4(frames: np.ndarray, fps: float, path: str | Path) -> None:
    """
    Write ``frames`` (k, h, w, 3) uint8 as an H.264 mp4 any browser plays: yuv420p, the index up front ("fast
    start", so it plays while loading), odd sizes padded to even ones. Written next to ``path``, then renamed.
    """
    import av

    path = Path(path)
    height, width = frames.shape[1] + frames.shape[1] % 2, frames.shape[2] + frames.shape[2] % 2
    padded = np.zeros((len(frames), height, width, 3), dtype=np.uint8)
    padded[:, : frames.shape[1], : frames.shape[2]] = frames
    partial = path.with_name(path.name + ".part")
    with av.open(str(partial), mode="w", format="mp4", options={"movflags": "faststart"}) as container:
        stream = container.add_stream("libx264", rate=Fraction(fps).limit_denominator(1000))
        stream.width, stream.height, stream.pix_fmt = width, height, "yuv420p"
        stream.options = {"crf": "20", "preset": "veryfast"}
        for frame in padded:
            container.mux(stream.encode(av.VideoFrame.from_ndarray(frame, format="rgb24")))
        container.mux(stream.encode())
    os.replace(partial, path)
