"""What preference-based learning needs of an environment, checked when an algorithm is given one."""

from gymnasium import spaces
from stable_baselines3.common.base_class import BaseAlgorithm, maybe_make_env
from stable_baselines3.common.preprocessing import is_image_space
from stable_baselines3.common.type_aliases import GymEnv
from stable_baselines3.common.vec_env import VecEnv, unwrap_vec_normalize


def check_env(env: GymEnv | str, segment_length: int | None, verbose: int = 0) -> VecEnv:
    """
    The env, made and wrapped as SB3 does (``Monitor``, ``DummyVecEnv``), once it is known to have flat Box
    observations and Box actions (the error says how to get them), no reward normalization, and episodes that can hold
    a segment. The algorithms run it in their constructor, ``set_env()`` and ``load()``.

    :param segment_length: steps per query segment; None: skip the episode-length check
    """
    env = BaseAlgorithm._wrap_env(maybe_make_env(env, verbose), verbose)
    obs_space, action_space = env.observation_space, env.action_space
    if is_image_space(obs_space, normalized_image=True):
        raise ValueError(
            f"env has image observations {obs_space}: not supported. The reward model, the state entropy and the "
            "diffusion model take one flat vector of states; use the env's proprioceptive states (dm_control and "
            "Meta-World provide them: e.g. 'sb3_pride/walker-walk-v0', 'sb3_pride/button-press-v3')"
        )
    if isinstance(obs_space, spaces.Dict):
        raise ValueError(
            "env has a Dict observation space (dm_control's default); the reward model and the state entropy "
            "need one flat vector: wrap it with sb3_pride.envs.flatten_observations(env) (or gymnasium's "
            "FlattenObservation), or make it as 'sb3_pride/<domain>-<task>-v0', e.g. 'sb3_pride/walker-walk-v0'"
        )
    if not isinstance(obs_space, spaces.Box) or len(obs_space.shape) != 1:
        raise ValueError(f"env must have a 1-D Box observation space, got {obs_space}")
    if not isinstance(action_space, spaces.Box):
        raise ValueError(f"env must have a Box (continuous) action space, got {action_space}")
    normalization = unwrap_vec_normalize(env)
    if normalization is not None and normalization.norm_reward:
        raise ValueError(
            "env is a VecNormalize with norm_reward=True: it would scale r̂ by statistics of the true return "
            "(a leak, and the wrong scale); use VecNormalize(..., norm_reward=False)"
        )
    if segment_length is not None:
        check_episode_length(env, segment_length)
    return env


def check_episode_length(env: VecEnv, segment_length: int) -> None:
    """Refuse a segment longer than the env's own step limit (episodes that end earlier only warn, later)."""
    specs = env.get_attr("spec")
    limits = [spec.max_episode_steps for spec in specs if spec is not None and spec.max_episode_steps]
    if limits and min(limits) < segment_length:
        raise ValueError(f"segment_length={segment_length} is longer than an episode of this env ({min(limits)} steps)")


def env_id(env: VecEnv | None) -> str | None:
    """The gymnasium id of ``env``'s first env (None: no env, or one made without an id)."""
    if env is None:
        return None
    spec = env.get_attr("spec", indices=0)[0]
    return None if spec is None else spec.id
