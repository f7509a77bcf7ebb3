"""Replay buffers: the true reward kept aside for the teacher, r̂ (or r_int) for the learner."""

from typing import Callable, Optional

import numpy as np
import torch as th
from gymnasium import spaces
from stable_baselines3.common.buffers import ReplayBuffer
from stable_baselines3.common.type_aliases import ReplayBufferSamples
from stable_baselines3.common.vec_env import VecNormalize

#: r̂(observations, actions) -> rewards, numpy in and out, any leading batch shape
RewardFn = Callable[[np.ndarray, np.ndarray], np.ndarray]
#: r_int(minibatch observations, all stored observations) -> (B, 1) rewards
IntrinsicRewardFn = Callable[[th.Tensor, th.Tensor], th.Tensor]


class PreferenceReplayBuffer(ReplayBuffer):
    """
    SB3 ``ReplayBuffer`` for preference-based RL (PEBBLE).

    The environment's reward never reaches the learner: ``add()`` stores it in ``true_rewards``, which only the
    teacher and the diagnostics read, and stores r̂ of the current reward model in ``rewards`` (0 before the
    first reward model exists). ``relabel()`` rewrites every stored reward with r̂ after a reward update.
    While ``intrinsic_reward`` is set (unsupervised pre-training), sampled rewards are r_int instead.

    Same constructor as SB3's ``ReplayBuffer``.
    """

    true_rewards: np.ndarray

    def __init__(
        self,
        buffer_size: int,
        observation_space: spaces.Space,
        action_space: spaces.Space,
        device: th.device | str = "auto",
        n_envs: int = 1,
        optimize_memory_usage: bool = False,
        handle_timeout_termination: bool = True,
    ):
        if optimize_memory_usage:
            raise ValueError("optimize_memory_usage=True is not supported by preference-based replay buffers")
        super().__init__(
            buffer_size,
            observation_space,
            action_space,
            device=device,
            n_envs=n_envs,
            optimize_memory_usage=False,
            handle_timeout_termination=handle_timeout_termination,
        )
        self.true_rewards = np.zeros((self.buffer_size, self.n_envs), dtype=np.float32)
        self.reward_fn: Optional[RewardFn] = None
        self.intrinsic_reward: Optional[IntrinsicRewardFn] = None

    def __getstate__(self) -> dict:
        # The reward model and the entropy estimator belong to the algorithm, which re-attaches them
        state = self.__dict__.copy()
        state["reward_fn"] = None
        state["intrinsic_reward"] = None
        return state

    @property
    def n_stored(self) -> int:
        """Number of rows in use (each row holds ``n_envs`` transitions)."""
        return self.buffer_size if self.full else self.pos

    def add(self, obs, next_obs, action, reward, done, infos) -> None:  # type: ignore[override]
        self.true_rewards[self.pos] = np.asarray(reward, dtype=np.float32).reshape(self.n_envs)
        if self.reward_fn is not None:
            learned = self.reward_fn(np.asarray(obs).reshape(self.n_envs, -1), np.asarray(action).reshape(self.n_envs, -1))
        else:
            learned = np.zeros(self.n_envs, dtype=np.float32)
        super().add(obs, next_obs, action, learned, done, infos)

    def relabel(self, reward_fn: RewardFn, batch_size: int = 16_384) -> None:
        """Rewrite every stored reward with r̂ (PEBBLE's relabeling), ``batch_size`` transitions at a time."""
        flat_obs = self.observations[: self.n_stored].reshape(-1, *self.obs_shape)
        flat_actions = self.actions[: self.n_stored].reshape(-1, self.action_dim)
        flat_rewards = self.rewards[: self.n_stored].reshape(-1)  # a view: writes land in self.rewards
        for start in range(0, len(flat_rewards), batch_size):
            stop = start + batch_size
            flat_rewards[start:stop] = reward_fn(flat_obs[start:stop], flat_actions[start:stop])

    def sample(self, batch_size: int, env: Optional[VecNormalize] = None) -> ReplayBufferSamples:
        samples = super().sample(batch_size, env=env)
        if self.intrinsic_reward is None:
            return samples
        # Unsupervised pre-training: the critic target uses r_int(s) (Eq. 3), computed in the space the policy sees
        all_obs = self._normalize_obs(self.observations[: self.n_stored].reshape(-1, *self.obs_shape), env)
        rewards = self.intrinsic_reward(samples.observations, self.to_torch(all_obs, copy=False))
        return samples._replace(rewards=rewards.to(samples.rewards.dtype))

    def transition_sample(self, n: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``n`` stored transitions drawn uniformly: (observations, actions, true rewards), for diagnostics."""
        rows = rng.integers(0, self.n_stored, size=n)
        cols = rng.integers(0, self.n_envs, size=n)
        return self.observations[rows, cols], self.actions[rows, cols], self.true_rewards[rows, cols]
