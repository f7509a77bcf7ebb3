"""
How a ``WebTeacher`` shows an env's segments, decided when it is attached to the model's env (and printed):

- ``MUJOCO_STATES``: an env that ``RenderStates`` wraps (every ``sb3_pride/...`` env) records its MuJoCo state after
  each step, and the teacher re-renders the states headless, pixel-identical (``SegmentRenderer``);
- ``RENDER_STATES``: an env with the render-state protocol (``get_render_state``/``render_from_state``) records its
  own render state after each step, and the teacher draws it again in a copy of the env of its own (``StateRenderer``);
- ``RECORDED_FRAMES``: any other env made with ``render_mode="rgb_array"`` renders a frame after each step while the
  teacher is attached, stored losslessly for the episodes queries may come from (``FrameRecording``), and a query's
  clips are cut from it (``RecordedRenderer``).

An env with none of these is refused, naming the ``render_mode`` it needs.
"""

from typing import TYPE_CHECKING, Any

from sb3_pride.render_states import RenderStates, enable_render_states, has_render_state_protocol
from sb3_pride.human import render
from sb3_pride.human.clips import Clips
from sb3_pride.human.recording import FrameRecording, record_renders

if TYPE_CHECKING:
    from stable_baselines3.common.vec_env import VecEnv

    from sb3_pride.common.buffers import PreferenceReplayBuffer

MUJOCO_STATES, RENDER_STATES, RECORDED_FRAMES = "mujoco_states", "render_states", "recorded_frames"


def check_buffer(buffer: "PreferenceReplayBuffer", what: str) -> None:
    """Refuse a buffer of transitions stored without ``what`` (a scripted teacher's run): none could be shown."""
    if buffer.size() > 0 and buffer.render_states is None:
        raise ValueError(
            f"the replay buffer holds {buffer.size()} transitions recorded without {what} (by a scripted teacher's run): "
            "a WebTeacher could not show segments of them. Resume a WebTeacher run's buffer, or start from an empty one"
        )


def show(clips: Clips, env: "VecEnv", buffer: "PreferenceReplayBuffer", recording: dict[str, Any]) -> tuple[str, str]:
    """
    Get ``clips`` ready to show segments of ``env`` stored in ``buffer``, and switch on what that needs beside the
    buffer's transitions; print the way chosen.

    :param recording: the ``FrameRecording`` settings (``episodes``, ``max_bytes``, ``parent``), for recorded frames
    :return: (the way: ``MUJOCO_STATES``, ``RENDER_STATES`` or ``RECORDED_FRAMES``; the env's id or class name)
    """
    try:  # asked first: a SubprocVecEnv's worker dies of a get_attr that fails
        wrapped = all(env.env_is_wrapped(RenderStates))
    except AttributeError:  # an env-like object without env_is_wrapped: its get_attr tells
        wrapped = True
    try:
        env_id = env.get_attr("render_env_id")[0] if wrapped else None
    except AttributeError:
        env_id = None
    if env_id is None:
        return _show_other(clips, env, buffer, recording)
    check_buffer(buffer, "simulator states")
    renderer = clips.use(env_id)
    state_size = enable_render_states(env, renderer.layout)
    if state_size != renderer.state_size:
        raise ValueError(
            f"the env records states of {state_size} numbers but a fresh {env_id!r} has {renderer.state_size}: "
            "RenderStates(env, env_id=...) must name an id that makes this same env"
        )
    buffer.record_render_states = True
    print(f"WebTeacher: {env_id} is shown by re-rendering the MuJoCo states recorded beside its transitions", flush=True)
    return MUJOCO_STATES, env_id


def _show_other(clips: Clips, env: "VecEnv", buffer: "PreferenceReplayBuffer", recording: dict[str, Any]) -> tuple[str, str]:
    first = _first_env(env)
    name = first.unwrapped.spec.id if first.unwrapped.spec is not None else type(first.unwrapped).__name__
    if has_render_state_protocol(first):
        check_buffer(buffer, "render states")
        clips.use_renderer(clips.thread.call(render.StateRenderer, first))
        for wrapper in record_renders(env):
            wrapper.record_render_states()
        buffer.record_render_states = True
        print(f"WebTeacher: {name} is shown by drawing again the render states it records (render_from_state)", flush=True)
        return RENDER_STATES, name
    if first.render_mode != "rgb_array":
        raise ValueError(
            f"WebTeacher cannot show {name}: it was made with render_mode={first.render_mode!r}, and a person is shown "
            "what it renders: make it with render_mode='rgb_array' (gymnasium.make(id, render_mode='rgb_array'); SB3 "
            "does for an env given by id), or give it get_render_state() and render_from_state(state)"
        )
    check_buffer(buffer, "recorded frames")
    wrappers = record_renders(env)
    current = clips.renderer
    if isinstance(current, render.RecordedRenderer) and all(wrapper.recording is current.recording for wrapper in wrappers):
        frames = current.recording  # attached again to the same env: its frames are kept
    else:
        frames = FrameRecording(len(wrappers), **recording)
        clips.use_renderer(render.RecordedRenderer(frames, name, render.frame_rate(first)))
        for wrapper in wrappers:
            wrapper.record_frames(frames)
    marked = frames.use_buffer(buffer)
    buffer.record_render_states = True
    print(
        f"WebTeacher: {name} is shown from the frames it renders, recorded while the agent collects (lossless, each "
        f"env's last {frames.episodes_per_env} episodes, at most {frames.max_bytes / 2**20:.0f} MiB, in {frames.folder})"
        + (f"; {marked} stored transitions recorded before cannot be shown" if marked else ""),
        flush=True,
    )
    return RECORDED_FRAMES, name


def _first_env(env: "VecEnv") -> Any:
    """The first env of ``env``'s ``DummyVecEnv`` (another vectorized env is refused by ``record_renders``)."""
    from stable_baselines3.common.vec_env import DummyVecEnv, VecEnvWrapper

    base = env
    while isinstance(base, VecEnvWrapper):
        base = base.venv
    if not isinstance(base, DummyVecEnv):
        record_renders(env)  # raises, naming the kind of env
    return base.envs[0]  # type: ignore[attr-defined]
