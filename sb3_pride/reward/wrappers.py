"""
Any SB3 algorithm on r̂: a gymnasium wrapper and an SB3 ``VecEnvWrapper`` that give the agent r̂(s, a) of a
``LearnedReward`` in place of the environment's reward, which stays in ``info["true_reward"]``.
"""

import os
from typing import Any, SupportsFloat

import gymnasium as gym
import numpy as np
from stable_baselines3.common.running_mean_std import RunningMeanStd
from stable_baselines3.common.vec_env import VecEnv, VecEnvWrapper
from stable_baselines3.common.vec_env.base_vec_env import VecEnvStepReturn

from sb3_pride.reward.learned_reward import LearnedReward


def as_learned_reward(reward: LearnedReward | str | os.PathLike) -> LearnedReward:
    """A ``LearnedReward``, or the one saved at a path (``PEBBLE.save_reward_model``, ``python -m sb3_pride.reward fit``)."""
    if isinstance(reward, LearnedReward):
        return reward
    if isinstance(reward, (str, os.PathLike)):
        return LearnedReward.load(reward, device="cpu")
    raise ValueError(f"reward must be a LearnedReward or the path of a saved one, got {reward!r}")


class RewardNormalizer:
    """
    r̂ scaled as ``VecNormalize`` scales rewards: divided by the running standard deviation of the discounted return
    (not centred), then clipped.

    :param n_envs: envs stepped together
    :param gamma: discount of the return whose spread is tracked
    :param clip: the scaled rewards are clipped to [-clip, clip]
    :param epsilon: added to the variance
    """

    def __init__(self, n_envs: int, gamma: float = 0.99, clip: float = 10.0, epsilon: float = 1e-8):
        self.statistics = RunningMeanStd(shape=())
        self.returns = np.zeros(n_envs)
        self.gamma, self.clip, self.epsilon = gamma, clip, epsilon
        #: False: the statistics stay as they are (evaluation, or a trained agent's)
        self.training = True

    def __call__(self, rewards: np.ndarray, dones: np.ndarray) -> np.ndarray:
        if self.training:
            self.returns = self.returns * self.gamma + rewards
            self.statistics.update(self.returns)
        self.returns[dones] = 0.0
        return np.clip(rewards / np.sqrt(self.statistics.var + self.epsilon), -self.clip, self.clip)


class LearnedRewardWrapper(gym.Wrapper):
    """
    A gymnasium env whose reward is r̂(s_t, a_t) of a learned reward model (PEBBLE's Eq. 1, the ensemble's mean), read
    as PEBBLE's replay buffer reads it: the observation the action was taken in, the action scaled to [-1, 1]. The
    env's own reward goes to ``info["true_reward"]``; wrap ``Monitor`` inside this wrapper (``make_vec_env``'s
    ``wrapper_class`` does) so that ``Monitor`` and ``EvalCallback`` still report the true return.

    :param env: a gymnasium env with the spaces the reward model reads
    :param reward: a ``LearnedReward`` or the path of a saved one
    :param normalize: scale r̂ by the running spread of its discounted return, as ``VecNormalize`` does
    :param gamma: the discount of that return
    """

    def __init__(self, env: gym.Env, reward: LearnedReward | str | os.PathLike, normalize: bool = False, gamma: float = 0.99):
        super().__init__(env)
        self.reward = as_learned_reward(reward)
        self.reward.check_spaces(env.observation_space, env.action_space, f"env {env}")
        self.normalizer = RewardNormalizer(1, gamma) if normalize else None
        self._observation: np.ndarray | None = None

    def reset(self, **kwargs: Any) -> tuple[Any, dict[str, Any]]:
        observation, info = self.env.reset(**kwargs)
        self._observation = np.asarray(observation, dtype=np.float32)
        return observation, info

    def step(self, action: Any) -> tuple[Any, SupportsFloat, bool, bool, dict[str, Any]]:
        if self._observation is None:
            raise RuntimeError("LearnedRewardWrapper: step() before reset()")
        observation, true_reward, terminated, truncated, info = self.env.step(action)
        learned = self.reward.predict(self._observation[None], self.reward.scale_actions(np.asarray(action))[None])
        if self.normalizer is not None:
            learned = self.normalizer(learned, np.array([terminated or truncated]))
        self._observation = np.asarray(observation, dtype=np.float32)
        return observation, float(learned[0]), terminated, truncated, {**info, "true_reward": float(true_reward)}


class VecLearnedReward(VecEnvWrapper):
    """
    An SB3 ``VecEnv`` whose rewards are r̂(s_t, a_t) of a learned reward model (PEBBLE's Eq. 1, the ensemble's mean),
    read as PEBBLE's replay buffer reads it, for every env at once; each env's own reward goes to its
    ``info["true_reward"]``, and ``Monitor`` (inside, as ``make_vec_env`` puts it) still reports the true return. Wrap
    it directly around the envs, under ``VecNormalize``: r̂ reads raw observations.

    :param venv: the envs, with the spaces the reward model reads
    :param reward: a ``LearnedReward`` or the path of a saved one
    :param normalize: scale r̂ by the running spread of its discounted return, as ``VecNormalize`` does
    :param gamma: the discount of that return
    """

    def __init__(self, venv: VecEnv, reward: LearnedReward | str | os.PathLike, normalize: bool = False, gamma: float = 0.99):
        super().__init__(venv)
        self.reward = as_learned_reward(reward)
        self.reward.check_spaces(venv.observation_space, venv.action_space, f"venv {venv}")
        self.normalizer = RewardNormalizer(venv.num_envs, gamma) if normalize else None
        self._observations: np.ndarray | None = None
        self._actions: np.ndarray | None = None

    def reset(self) -> Any:
        observations = self.venv.reset()
        self._observations = np.asarray(observations, dtype=np.float32).reshape(self.num_envs, -1)
        return observations

    def step_async(self, actions: np.ndarray) -> None:
        self._actions = self.reward.scale_actions(np.asarray(actions).reshape(self.num_envs, -1))
        self.venv.step_async(actions)

    def step_wait(self) -> VecEnvStepReturn:
        if self._observations is None or self._actions is None:
            raise RuntimeError("VecLearnedReward: step() before reset()")
        observations, true_rewards, dones, infos = self.venv.step_wait()
        learned = self.reward.predict(self._observations, self._actions).astype(np.float32)
        if self.normalizer is not None:
            learned = self.normalizer(learned, dones).astype(np.float32)
        for info, true_reward in zip(infos, true_rewards, strict=True):
            info["true_reward"] = float(true_reward)
        # after an episode's end the VecEnv returns the next episode's first observation: the next step's s_t
        self._observations = np.asarray(observations, dtype=np.float32).reshape(self.num_envs, -1)
        return observations, learned, dones, infos
