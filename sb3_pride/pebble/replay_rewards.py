"""The rewards SAC learns from in PEBBLE, as its replay buffer asks for them: r_int while pre-training, then r̂."""

from typing import Any, Protocol

import numpy as np
from stable_baselines3.common.type_aliases import ReplayBufferSamples
from stable_baselines3.common.vec_env import VecNormalize

from sb3_pride.common.buffers import PreferenceReplayBuffer
from sb3_pride.common.entropy import StateEntropyReward
from sb3_pride.common.queries import QuerySampler
from sb3_pride.reward.learner import RewardLearner


class TrainingState(Protocol):
    """What ``ReplayRewards`` reads of the algorithm it serves (PEBBLE): its env step, its preference phase (whether it
    pre-trains, whether r̂ has learned, the queries asked), its budget, its query sampler and its replay buffer."""

    num_timesteps: int
    max_feedback: int
    phase: Any
    query_sampler: QuerySampler
    _vec_normalize_env: VecNormalize | None

    @property
    def real_buffer(self) -> PreferenceReplayBuffer: ...


class ReplayRewards:
    """
    The rewards SAC learns from, as the replay buffer asks for them (its ``reward_source``): r_int, the k-NN state
    entropy (Eq. 3), while pre-training; then r̂ of ``learner`` (Eq. 1), stored with each new transition and relabeled
    after each reward update, plus RUNE's bonus on each minibatch where it is on; and the rows QPA's hybrid replay
    draws its share of each minibatch from. It reads where training stands from ``algorithm`` when asked.

    :param learner: r̂
    :param state_entropy: r_int
    :param algorithm: the algorithm whose buffer asks (its phase, env step, query sampler)
    """

    def __init__(self, learner: RewardLearner, state_entropy: StateEntropyReward, algorithm: TrainingState):
        self.learner, self.state_entropy, self.algorithm = learner, state_entropy, algorithm
        #: the recent rows and the buffer position they were read at: read again only once the buffer has moved
        self._recent: tuple[tuple[int, int, bool], np.ndarray] | None = None

    @property
    def pretraining(self) -> bool:
        """r_int until the first feedback session is closed."""
        return self.algorithm.phase.pretraining

    @property
    def learned(self) -> bool:
        """Whether r̂ has learned from labels (before that, new transitions store 0, overwritten by the first relabel)."""
        return self.algorithm.phase.learned

    @property
    def bonus_active(self) -> bool:
        """RUNE's bonus is on and r̂ has learned."""
        return self.learner.exploration_bonus is not None and self.learned

    @property
    def recent_share(self) -> float:
        """QPA's hybrid replay: the share of each minibatch from ``recent_rows`` while queries remain (0: uniform)."""
        algorithm = self.algorithm
        share = algorithm.query_sampler.hybrid_replay
        on = share > 0 and not algorithm.phase.pretraining and algorithm.phase.asked < algorithm.max_feedback
        return share if on else 0.0

    @property
    def recent_rows(self) -> np.ndarray | None:
        """The rows of the most recent episodes (the queries' episodes) while the hybrid replay is on, else None."""
        if self.recent_share == 0:
            return None
        buffer = self.algorithm.real_buffer
        where = (id(buffer), buffer.pos, buffer.full)  # the same for every gradient step of one train() call
        if self._recent is None or self._recent[0] != where:
            self._recent = where, self.algorithm.query_sampler.recent_rows(buffer)
        return self._recent[1]

    def new_rewards(self, observations: np.ndarray, actions: np.ndarray) -> np.ndarray:
        """r̂ of transitions being added, or 0 before r̂ has learned from labels (the first relabel overwrites it)."""
        if not self.learned:
            return np.zeros(len(observations), dtype=np.float32)
        return self.learner.predict(observations, actions)

    def rewrite(
        self, samples: ReplayBufferSamples, buffer: PreferenceReplayBuffer, env: VecNormalize | None
    ) -> ReplayBufferSamples:
        """A sampled minibatch with SAC's rewards: r_int while pre-training, else r̂ (plus RUNE's bonus where it is on)."""
        if self.pretraining:
            # the critic target uses r_int(s) (Eq. 3), computed in the space the policy sees
            stored = buffer.to_torch(buffer.stored_observations(env), copy=False)
            return samples._replace(rewards=self.state_entropy(samples.observations, stored).to(samples.rewards.dtype))
        if self.bonus_active:
            step, vec_normalize = self.algorithm.num_timesteps, self.algorithm._vec_normalize_env
            return samples._replace(rewards=samples.rewards + self.learner.bonus(samples, step, vec_normalize))
        return samples
