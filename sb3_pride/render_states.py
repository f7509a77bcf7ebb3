"""
Simulator states recorded beside the transitions, so that segments can be re-rendered later (by a teacher that shows
them to a person): ``RenderStates`` puts the MuJoCo state after each step into ``info["render_state"]`` — qpos, qvel,
act, the mocap bodies' poses (Meta-World's hand) and the model fields that a reset re-draws (Meta-World's object and
goal positions; dm_control's targets in reacher, finger, fish, swimmer, manipulator) — and ``PreferenceReplayBuffer``
keeps it beside each stored transition. Recording is off until a teacher switches it on: scripted teachers pay nothing.

Any other env can give exact clips the same way through the render-state protocol (``RenderStateEnv``): a method
``get_render_state()`` that returns a flat float array describing what the env would draw now, and a method
``render_from_state(state)`` that draws the frame of such an array. A teacher then records the states, not frames, and
re-renders them in a copy of the env of its own.
"""

from typing import Any, Protocol, runtime_checkable

import gymnasium as gym
import numpy as np


@runtime_checkable
class RenderStateEnv(Protocol):
    """
    The render-state protocol: an env (or any wrapper of it) with these two methods is shown to a person from states
    recorded beside the transitions, exactly, without recording frames.
    """

    def get_render_state(self) -> np.ndarray:
        """A flat array of numbers (stored as float64) from which ``render_from_state`` draws what the env shows now."""
        ...

    def render_from_state(self, state: np.ndarray) -> np.ndarray:
        """The (height, width, 3) uint8 frame of ``state``, as ``render()`` draws it after the step that produced it."""
        ...


def has_render_state_protocol(env: gym.Env) -> bool:
    """Whether ``env`` or one of its wrappers has the render-state protocol's two methods (``RenderStateEnv``)."""
    for name in ("get_render_state", "render_from_state"):
        try:
            if not callable(env.get_wrapper_attr(name)):
                return False
        except AttributeError:
            return False
    return True


#: model fields a reset may re-draw, recorded with the state when they do (small per-element arrays)
MODEL_FIELDS = (
    "body_pos",
    "body_quat",
    "geom_pos",
    "geom_quat",
    "geom_size",
    "geom_rgba",
    "site_pos",
    "site_quat",
    "site_size",
    "site_rgba",
    "cam_pos",
    "cam_quat",
    "light_pos",
    "light_dir",
    "mat_rgba",
)
#: model fields too large to record per transition: a task that re-draws them is refused
UNRECORDABLE_FIELDS = ("hfield_data", "tex_data", "mesh_vert")
#: resets of the renderer's own env (distinct seeds) that find which model fields a reset re-draws
PROBE_RESETS = 6


def mujoco_handles(env: gym.Env) -> tuple[Any, Any]:
    """The ``(MjModel, MjData)`` behind a dm_control (shimmy) or Meta-World env; ValueError for any other env."""
    import mujoco

    unwrapped = env.unwrapped
    physics = getattr(getattr(unwrapped, "_env", None), "physics", None)  # shimmy's dm_control compatibility env
    if physics is not None:
        return physics.model.ptr, physics.data.ptr
    model, data = getattr(unwrapped, "model", None), getattr(unwrapped, "data", None)
    if isinstance(model, mujoco.MjModel) and isinstance(data, mujoco.MjData):
        return model, data
    raise ValueError(
        f"{env.spec.id if env.spec else type(unwrapped).__name__} is not a MuJoCo env that can be re-rendered from "
        "its states: WebTeacher supports dm_control and Meta-World ('sb3_pride/<domain>-<task>-v0', 'sb3_pride/<task>-v3')"
    )


#: what one recorded state holds besides the model fields: positions, velocities, activations, mocap poses
def _state_spec() -> int:
    import mujoco

    kinds = mujoco.mjtState
    return int(
        kinds.mjSTATE_QPOS | kinds.mjSTATE_QVEL | kinds.mjSTATE_ACT | kinds.mjSTATE_MOCAP_POS | kinds.mjSTATE_MOCAP_QUAT
    )


#: (field name, flat indices into it) of the model entries a reset re-draws
Layout = tuple[tuple[str, np.ndarray], ...]


def capture_state(model: Any, data: Any, layout: Layout) -> np.ndarray:
    """The compact float64 state that re-renders the current frame: ``mj_getState`` and the ``layout``'s fields."""
    import mujoco

    spec = _state_spec()
    state = np.empty(mujoco.mj_stateSize(model, spec), dtype=np.float64)
    mujoco.mj_getState(model, data, state, spec)
    return np.concatenate([state, *(getattr(model, name).reshape(-1)[index] for name, index in layout)])


def restore_state(model: Any, data: Any, layout: Layout, state: np.ndarray) -> None:
    """Put a ``capture_state`` vector back (model fields included) and recompute positions (``mj_forward``)."""
    import mujoco

    spec = _state_spec()
    size = mujoco.mj_stateSize(model, spec)
    mujoco.mj_setState(model, data, np.ascontiguousarray(state[:size], dtype=np.float64), spec)
    offset = size
    for name, index in layout:
        getattr(model, name).reshape(-1)[index] = state[offset : offset + len(index)]
        offset += len(index)
    mujoco.mj_forward(model, data)


def randomized_model_fields(env: gym.Env, resets: int = PROBE_RESETS) -> Layout:
    """
    Which model entries a reset of ``env`` re-draws: reset it ``resets`` times (seeds 0, 1, ...) and compare. A task
    that re-draws a field too large to record (a terrain's height field, a texture) is refused with a ValueError.
    """
    model, _ = mujoco_handles(env)
    fields = [name for name in (*MODEL_FIELDS, *UNRECORDABLE_FIELDS) if getattr(model, name, np.zeros(0)).size]
    snapshots = []
    for seed in range(resets):
        env.reset(seed=seed)
        snapshots.append({name: getattr(model, name).reshape(-1).copy() for name in fields})
    layout = []
    for name in fields:
        values = np.stack([snapshot[name] for snapshot in snapshots])
        changed = np.flatnonzero(np.any(values != values[0], axis=0))
        if len(changed) and name in UNRECORDABLE_FIELDS:
            raise ValueError(
                f"{env.spec.id if env.spec else env} re-draws its model's {name} at every reset ({len(changed)} values): "
                "it cannot be re-rendered from recorded states, so a WebTeacher cannot show it; use a task that does not"
            )
        if len(changed):
            layout.append((name, changed))
    return tuple(layout)


class RenderStates(gym.Wrapper):
    """
    ``info["render_state"]``: the float64 MuJoCo state after each step (and after a reset), enough to re-render
    that frame later (``capture_state``). Off until ``enable_render_states`` is called (by a ``WebTeacher``, through
    ``VecEnv.env_method``): scripted teachers pay nothing.

    :param env: a dm_control (shimmy) or Meta-World env
    :param env_id: the registered id that makes this env again, for the renderer's own copy (None: ``env.spec``'s)
    """

    def __init__(self, env: gym.Env, env_id: str | None = None):
        super().__init__(env)
        if env_id is None and env.spec is None:
            raise ValueError("RenderStates needs env_id: the registered id that makes this env (gymnasium.make(env_id))")
        #: what ``SegmentRenderer`` makes to re-render this env's states
        self.render_env_id: str = env_id or env.spec.id  # type: ignore[union-attr]
        self.render_layout: Layout | None = None  # None: off

    def enable_render_states(self, layout: Layout) -> int:
        """Record from now on, with the model fields of ``layout``; returns the length of one state."""
        self.render_layout = tuple((name, np.asarray(index, dtype=np.int64)) for name, index in layout)
        return len(self._capture())

    def _capture(self) -> np.ndarray:
        assert self.render_layout is not None
        model, data = mujoco_handles(self.env)
        return capture_state(model, data, self.render_layout)

    def reset(self, **kwargs) -> tuple[Any, dict]:
        obs, info = self.env.reset(**kwargs)
        if self.render_layout is not None:
            info["render_state"] = self._capture()
        return obs, info

    def step(self, action):
        obs, reward, terminated, truncated, info = self.env.step(action)
        if self.render_layout is not None:
            info["render_state"] = self._capture()
        return obs, reward, terminated, truncated, info


def enable_render_states(vec_env: Any, layout: Layout) -> int:
    """Switch on ``RenderStates`` in every env of ``vec_env``; returns the length of one state."""
    try:
        sizes = vec_env.env_method("enable_render_states", layout)
    except AttributeError:
        raise ValueError(
            "the env does not record render states: make it with gymnasium.make('sb3_pride/...') (RenderStates is "
            "on every sb3_pride env) or wrap it with sb3_pride.render_states.RenderStates"
        ) from None
    return int(sizes[0])
