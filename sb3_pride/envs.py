"""
Environments for preference-based RL benchmarks, registered with gymnasium on ``import sb3_pride``:

- ``sb3_pride/<domain>-<task>-v0``: every DeepMind Control suite task (through shimmy) with its Dict observation
  flattened into one float32 vector, e.g. ``sb3_pride/walker-walk-v0`` (obs 24, act 6, 1000-step episodes).
- ``sb3_pride/<task>-v3``: Meta-World v3 tasks (MT1: the goal is observable and re-drawn each reset), 500-step
  episodes, float32 observations and ``info["is_success"]`` = success at any step so far, which SB3 and rl-zoo3
  read at episode end to report a success rate, e.g. ``sb3_pride/button-press-v3``.

Both record the simulator state of every step in ``info["render_state"]`` once a ``WebTeacher`` asks for it
(``sb3_pride.render_states.RenderStates``), so that a person can watch the segments.

dm_control and Meta-World are imported only when an environment is made.
"""

import functools
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from sb3_pride.render_states import RenderStates

NAMESPACE = "sb3_pride"

#: the DMC suite tasks (shimmy's list, copied so that registration needs no dm_control import)
DM_CONTROL_TASKS = (
    "acrobot-swingup",
    "acrobot-swingup_sparse",
    "ball_in_cup-catch",
    "cartpole-balance",
    "cartpole-balance_sparse",
    "cartpole-swingup",
    "cartpole-swingup_sparse",
    "cheetah-run",
    "finger-spin",
    "finger-turn_easy",
    "finger-turn_hard",
    "fish-upright",
    "fish-swim",
    "hopper-stand",
    "hopper-hop",
    "humanoid-stand",
    "humanoid-walk",
    "humanoid-run",
    "manipulator-bring_ball",
    "pendulum-swingup",
    "point_mass-easy",
    "reacher-easy",
    "reacher-hard",
    "swimmer-swimmer6",
    "swimmer-swimmer15",
    "walker-stand",
    "walker-walk",
    "walker-run",
    "quadruped-walk",
    "quadruped-run",
    "quadruped-escape",
    "quadruped-fetch",
    "dog-stand",
    "dog-walk",
    "dog-trot",
    "dog-run",
    "dog-fetch",
)

#: Meta-World tasks of the paper (and PEBBLE's) experiments; any other v3 name works with ``make_metaworld``
METAWORLD_TASKS = (
    "button-press-v3",
    "door-open-v3",
    "sweep-into-v3",
    "drawer-open-v3",
    "window-open-v3",
    "hammer-v3",
)

METAWORLD_EPISODE_STEPS = 500


def flatten_observations(env: gym.Env) -> gym.Env:
    """Flatten a Dict observation into one float32 vector (usable as an rl-zoo3 ``env_wrapper``)."""
    if isinstance(env.observation_space, spaces.Dict):
        env = gym.wrappers.FlattenObservation(env)
    return Float32Observation(env)


class Float32Observation(gym.ObservationWrapper):
    """Cast observations to float32 (halves replay memory next to dm_control/Meta-World's float64)."""

    def __init__(self, env: gym.Env):
        super().__init__(env)
        space = env.observation_space
        assert isinstance(space, spaces.Box), f"expected a Box observation space, got {space}"
        # unbounded: Meta-World declares [0, 0] bounds for the goal it then reports
        self.observation_space = spaces.Box(-np.inf, np.inf, shape=space.shape, dtype=np.float32)

    def observation(self, observation: np.ndarray) -> np.ndarray:
        return np.asarray(observation, dtype=np.float32)


class EpisodeSuccess(gym.Wrapper):
    """``info["is_success"]`` = 1.0 once ``info["success"]`` was 1 at any step of the episode (Meta-World's metric)."""

    def __init__(self, env: gym.Env):
        super().__init__(env)
        self._succeeded = False

    def reset(self, **kwargs) -> tuple[Any, dict]:
        self._succeeded = False
        return self.env.reset(**kwargs)

    def step(self, action):
        obs, reward, terminated, truncated, info = self.env.step(action)
        self._succeeded = self._succeeded or bool(info.get("success", 0.0))
        info["is_success"] = float(self._succeeded)
        return obs, reward, terminated, truncated, info


@functools.lru_cache(maxsize=32)
def metaworld_tasks(env_name: str, seed: int) -> list:
    """MT1's 50 task variations of ``env_name`` drawn from ``seed`` (numpy's global RNG is left as it was)."""
    import metaworld

    return metaworld.MT1(env_name, seed=seed).train_tasks


class SeededTasks(gym.Wrapper):
    """
    Makes a Meta-World MT1 env repeatable from ``reset(seed=...)``, as SB3's ``make_vec_env(..., seed=...)`` and
    every gymnasium env expect. MT1 draws its 50 task variations (object and goal positions) from numpy's global
    RNG when the env is built, picks one at each reset, and its env ignores the reset's seed (Meta-World seeds through
    ``seed()``), so two runs with the same seed saw different tasks. On a seeded reset this wrapper takes the
    variations drawn from that seed and seeds the env (its task picker, action and observation spaces) through
    Meta-World's ``seed()``; unseeded resets pass through unchanged.

    :param env: a Meta-World env made by ``gym.make("Meta-World/MT1", ...)``
    :param env_name: its task, e.g. ``"button-press-v3"``
    """

    def __init__(self, env: gym.Env, env_name: str):
        super().__init__(env)
        self.env_name = env_name

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[Any, dict]:
        if seed is not None:
            picker = self.env
            while not hasattr(picker, "tasks"):  # Meta-World's task-select wrapper, wherever it sits
                assert isinstance(picker, gym.Wrapper), "no Meta-World task-select wrapper found"
                picker = picker.env
            picker.tasks = metaworld_tasks(self.env_name, seed)  # type: ignore[attr-defined]
            self.unwrapped.seed(seed)  # type: ignore[attr-defined]
        return self.env.reset(seed=seed, options=options)


def make_dm_control(domain_task: str, **kwargs) -> gym.Env:
    """A DMC suite task, e.g. ``"walker-walk"``, with flattened float32 observations."""
    import shimmy

    gym.register_envs(shimmy)
    env = flatten_observations(gym.make(f"dm_control/{domain_task}-v0", **kwargs))
    return RenderStates(env, env_id=f"{NAMESPACE}/{domain_task}-v0")


def make_metaworld(env_name: str, seed: int | None = None, **kwargs) -> gym.Env:
    """A Meta-World v3 MT1 task, e.g. ``"button-press-v3"``: 500 steps, float32 obs, ``is_success`` in info."""
    import metaworld

    gym.register_envs(metaworld)
    env = gym.make(
        "Meta-World/MT1",
        env_name=env_name,
        seed=seed,
        max_episode_steps=METAWORLD_EPISODE_STEPS,
        disable_env_checker=True,  # it flags the goal that Meta-World declares in [0, 0]
        **kwargs,
    )
    return RenderStates(Float32Observation(EpisodeSuccess(SeededTasks(env, env_name))), env_id=f"{NAMESPACE}/{env_name}")


def register_envs() -> None:
    """Register the ``sb3_pride/...`` ids (idempotent)."""
    for task in DM_CONTROL_TASKS:
        env_id = f"{NAMESPACE}/{task}-v0"
        if env_id not in gym.registry:
            gym.register(env_id, entry_point=make_dm_control, kwargs={"domain_task": task})  # type: ignore[arg-type]
    for task in METAWORLD_TASKS:
        env_id = f"{NAMESPACE}/{task}"
        if env_id not in gym.registry:
            gym.register(
                env_id,
                entry_point=make_metaworld,  # type: ignore[arg-type]
                kwargs={"env_name": task},
                max_episode_steps=METAWORLD_EPISODE_STEPS,
            )
