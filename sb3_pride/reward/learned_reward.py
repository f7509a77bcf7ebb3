"""
r̂ on its own: a learned reward model saved apart from the agent, with the spaces it reads and the settings it was
built with, so that another run, another algorithm or a figure can use it.
"""

import os
from typing import Any

import numpy as np
import torch as th
from gymnasium import spaces

from sb3_pride.common.env_checks import env_id
from sb3_pride.common.checkpoints import atomic_write_path
from sb3_pride.reward.learner import RewardLearner
from sb3_pride.common.utils import plain

#: what a reward file says it is (``LearnedReward.save``)
FILE_FORMAT = "sb3_pride.learned_reward/1"


def space_record(space: spaces.Box) -> dict[str, Any]:
    """A Box space as plain values a reward file holds (and ``torch.load(weights_only=True)`` reads back)."""
    record = {"shape": list(space.shape), "low": th.as_tensor(space.low), "high": th.as_tensor(space.high)}
    return {**record, "dtype": str(space.dtype)}


def space_from_record(record: dict[str, Any]) -> spaces.Box:
    dtype = np.dtype(record.get("dtype", "float32"))
    return spaces.Box(record["low"].numpy().astype(dtype), record["high"].numpy().astype(dtype), tuple(record["shape"]), dtype)


class LearnedReward:
    """
    PEBBLE's reward model r̂(s, a) (Lee, Smith & Abbeel, ICML 2021, Eq. 1) as a thing of its own: a ``RewardLearner``
    with the observation and action spaces it reads, the segment length and env id of the pairs it learned from, and
    the ``reward_kwargs`` it was built with. ``predict`` is r̂, the ensemble's mean; ``spread`` the members' standard
    deviation. Actions are read as the replay buffer stores them: scaled to [-1, 1] from the action space's bounds
    (``scale_actions`` turns the env's actions into them).

    :param learner: the reward learner (its ensemble is r̂)
    :param observation_space: the 1-D Box observations r̂ reads
    :param action_space: the Box actions r̂ reads
    :param segment_length: steps per segment of the pairs it learned from
    :param reward_kwargs: the ``RewardLearner`` settings it was built with (those not given keep their defaults)
    :param env_id: the id of the env it learned on (None: unknown)
    """

    def __init__(
        self,
        learner: RewardLearner,
        observation_space: spaces.Box,
        action_space: spaces.Box,
        segment_length: int,
        reward_kwargs: dict[str, Any] | None = None,
        env_id: str | None = None,
    ):
        self.learner, self.observation_space, self.action_space = learner, observation_space, action_space
        self.segment_length, self.reward_kwargs, self.env_id = segment_length, dict(reward_kwargs or {}), env_id

    @classmethod
    def of_model(cls, model: Any) -> "LearnedReward":
        """The r̂ of a ``PEBBLE`` or ``PRIDE`` model (shared with it, not copied)."""
        spaces_ = (model.observation_space, model.action_space)
        journal_header = model.feedback.journal.header or {}  # a model loaded without an env: its journal's env id
        name = env_id(model.env) or journal_header.get("env_id")
        return cls(model.reward_learner, *spaces_, model.segment_length, model.reward_kwargs, name)

    @classmethod
    def new(
        cls,
        observation_space: spaces.Box,
        action_space: spaces.Box,
        segment_length: int,
        reward_kwargs: dict[str, Any] | None = None,
        env_id: str | None = None,
        device: th.device | str = "auto",
    ) -> "LearnedReward":
        """An untrained r̂ for these spaces (``reward_kwargs`` checked as ``PEBBLE`` checks them)."""
        obs_dim, action_dim = int(np.prod(observation_space.shape)), int(np.prod(action_space.shape))
        RewardLearner.check_kwargs(reward_kwargs or {}, segment_length)
        learner = RewardLearner(obs_dim, action_dim, segment_length, device=device, **(reward_kwargs or {}))
        return cls(learner, observation_space, action_space, segment_length, reward_kwargs, env_id)

    def predict(self, observations: np.ndarray, actions: np.ndarray) -> np.ndarray:
        """r̂(s, a), the ensemble's mean, of (..., obs_dim) observations and (..., action_dim) scaled actions."""
        return self.learner.predict(observations, actions)

    def spread(self, observations: np.ndarray, actions: np.ndarray) -> np.ndarray:
        """The members' standard deviation of r̂(s, a): how unsure the ensemble is."""
        return self.learner.ensemble.disagreement(observations, actions)

    def scale_actions(self, actions: np.ndarray) -> np.ndarray:
        """The env's actions as the replay buffer stores them: scaled from the bounds to [-1, 1] (SB3's ``scale_action``)."""
        low, high = self.action_space.low, self.action_space.high
        scaled = 2.0 * (np.asarray(actions, dtype=np.float32) - low) / (high - low) - 1.0
        return np.clip(scaled, -1.0, 1.0)

    def check_spaces(self, observation_space: spaces.Space, action_space: spaces.Space, where: str) -> None:
        """Refuse spaces r̂ cannot read, naming the space and ``where`` it came from."""
        for name, theirs, ours in (
            ("observation space", observation_space, self.observation_space),
            ("action space", action_space, self.action_space),
        ):
            same = isinstance(theirs, spaces.Box) and theirs.shape == ours.shape
            if name == "action space" and isinstance(theirs, spaces.Box) and same:
                same = bool(np.allclose(theirs.low, ours.low) and np.allclose(theirs.high, ours.high))
            if not same:
                raise ValueError(f"{where} has the {name} {theirs}, the reward model reads {ours}")

    def save(self, path: str | os.PathLike) -> None:
        """Write r̂ to ``path`` (one file, replaced whole or not at all): its weights, spaces and settings."""
        record = {
            "format": FILE_FORMAT,
            "observation_space": space_record(self.observation_space),
            "action_space": space_record(self.action_space),
            "segment_length": int(self.segment_length),
            "reward_kwargs": plain(self.reward_kwargs),
            "env_id": self.env_id,
            "history": plain(self.learner.history),
            "ensemble": self.learner.ensemble.state_dict(),
        }
        with atomic_write_path(path) as temporary:
            th.save(record, temporary)

    @classmethod
    def load(cls, path: str | os.PathLike, device: th.device | str = "auto") -> "LearnedReward":
        """Read a reward file written by ``save`` (weights only: nothing in it is run)."""
        try:
            record = th.load(path, map_location="cpu", weights_only=True)
        except FileNotFoundError:
            raise ValueError(f"reward file {os.fspath(path)} does not exist") from None
        except Exception as error:
            why = (str(error).strip().splitlines() or [type(error).__name__])[0]  # torch's own message runs to a page
            raise ValueError(f"reward file {os.fspath(path)} is not a reward model saved by sb3_pride: {why}") from None
        if not isinstance(record, dict) or record.get("format") != FILE_FORMAT:
            raise ValueError(f"reward file {os.fspath(path)} is not a reward model saved by sb3_pride ({FILE_FORMAT})")
        reward = cls.new(
            space_from_record(record["observation_space"]),
            space_from_record(record["action_space"]),
            record["segment_length"],
            record["reward_kwargs"],
            record["env_id"],
            device,
        )
        reward.learner.ensemble.load_state_dict(record["ensemble"])
        reward.learner.history = list(record.get("history", []))
        return reward
