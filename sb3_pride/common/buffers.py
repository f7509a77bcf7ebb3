"""Replay buffers: the true reward kept aside for the teacher, r̂ (or r_int) for the learner."""

from collections.abc import Callable
from typing import Protocol

import numpy as np
import torch as th
from gymnasium import spaces
from stable_baselines3.common.buffers import ReplayBuffer
from stable_baselines3.common.type_aliases import ReplayBufferSamples
from stable_baselines3.common.vec_env import VecNormalize

#: r̂(observations, actions) -> rewards, numpy in and out, any leading batch shape
RewardFn = Callable[[np.ndarray, np.ndarray], np.ndarray]


class RewardSource(Protocol):
    """
    What a ``PreferenceReplayBuffer`` asks about rewards, one object (the algorithm's): the reward stored with a new
    transition, the rewards of a sampled minibatch, and the rows a share of each minibatch is drawn from.
    """

    @property
    def recent_share(self) -> float:
        """The share of each minibatch drawn from ``recent_rows`` (QPA's hybrid replay; 0: uniform, as SB3 samples)."""

    @property
    def recent_rows(self) -> np.ndarray | None:
        """Buffer rows of the most recent episodes, or None."""

    def new_rewards(self, observations: np.ndarray, actions: np.ndarray) -> np.ndarray:
        """The rewards stored with transitions being added, (n_envs,): r̂, or 0 before the first reward model."""
        ...

    def rewrite(
        self, samples: ReplayBufferSamples, buffer: "PreferenceReplayBuffer", env: VecNormalize | None
    ) -> ReplayBufferSamples:
        """A sampled minibatch with the rewards SAC learns from (e.g. r_int while pre-training, r̂ plus a bonus)."""
        ...


def relabel_rewards(buffer: ReplayBuffer, reward_fn: RewardFn, batch_size: int = 16_384) -> None:
    """Rewrite every stored reward of ``buffer`` with ``reward_fn(obs, action)``, ``batch_size`` transitions at a time."""
    n_rows = buffer.size()  # rows in use, each holding n_envs transitions
    flat_obs = buffer.observations[:n_rows].reshape(-1, *buffer.obs_shape)
    flat_actions = buffer.actions[:n_rows].reshape(-1, buffer.action_dim)
    flat_rewards = buffer.rewards[:n_rows].reshape(-1)  # a view: writes land in buffer.rewards
    for start in range(0, len(flat_rewards), batch_size):
        stop = start + batch_size
        flat_rewards[start:stop] = reward_fn(flat_obs[start:stop], flat_actions[start:stop])


def filled_rows_state(buffer: ReplayBuffer) -> dict:
    """
    What a buffer pickles: its attributes, with every per-row array (``buffer_size`` rows) cut to the rows filled so
    far while the buffer is not full, so that a saved replay buffer is as large as what it holds, not as its
    preallocated arrays; ``full_size_state`` grows them back.
    """
    state = dict(buffer.__dict__)
    rows = buffer.size()
    if rows < buffer.buffer_size:
        cut = [
            name
            for name, value in state.items()
            if isinstance(value, np.ndarray) and value.ndim > 0 and len(value) == buffer.buffer_size
        ]
        state.update({name: state[name][:rows] for name in cut}, _filled_rows_only=cut)
    return state


def full_size_state(state: dict) -> dict:
    """
    A pickled buffer's attributes (``filled_rows_state``) with the per-row arrays grown back to ``buffer_size`` rows,
    so the loaded buffer goes on exactly where the saved one was (rows past the filled ones, which no sample, relabel
    or query reads, are zeros). A buffer pickled whole passes unchanged.
    """
    state = dict(state)
    for name in state.pop("_filled_rows_only", ()):
        filled = state[name]
        state[name] = np.zeros((state["buffer_size"], *filled.shape[1:]), dtype=filled.dtype)
        state[name][: len(filled)] = filled
    return state


def concatenate_samples(first: ReplayBufferSamples, second: ReplayBufferSamples) -> ReplayBufferSamples:
    """Two minibatches as one, field by field, ``first``'s rows first; a field SB3 leaves None (n-step) stays None."""
    fields = [th.cat([a, b]) if a is not None and b is not None else None for a, b in zip(first, second, strict=True)]
    return ReplayBufferSamples(*fields)  # type: ignore[arg-type]


class PreferenceReplayBuffer(ReplayBuffer):
    """
    SB3 ``ReplayBuffer`` for preference-based RL (PEBBLE).

    The environment's reward never reaches the learner: ``add()`` stores it in ``true_rewards``, which only the
    teacher and the diagnostics read, and stores r̂ of the current reward model in ``rewards`` (0 before the
    first reward model exists). ``relabel()`` rewrites every stored reward with r̂ after a reward update. The
    algorithm's ``reward_source`` says what new transitions store, what each sampled minibatch's rewards are (r_int
    while pre-training, r̂ with RUNE's bonus) and which rows a share of it comes from (QPA's hybrid replay). It is
    pickled (``save_replay_buffer``) with its filled rows only and loaded back at full size (``filled_rows_state``).

    Same constructor as SB3's ``ReplayBuffer``.
    """

    true_rewards: np.ndarray
    #: the algorithm's answers about rewards (None: every reward 0, minibatches uniform, as SB3's); never pickled
    reward_source: RewardSource | None = None

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
        #: True while a teacher needs pictures: ``add()`` then keeps ``info["render_state"]`` of every transition
        self.record_render_states = False
        #: (buffer_size, n_envs, state_dim) float64, the simulator state after each stored step (the frame of its
        #: next observation), allocated at the first recorded transition; None while nothing was recorded
        self.render_states: np.ndarray | None = None

    def __getstate__(self) -> dict:
        # the filled rows only; the reward source belongs to the algorithm, which attaches it again
        return {**filled_rows_state(self), "reward_source": None}

    def __setstate__(self, state: dict) -> None:
        self.__dict__.update(full_size_state(state))

    def add(self, obs, next_obs, action, reward, done, infos) -> None:  # type: ignore[override]
        self.true_rewards[self.pos] = np.asarray(reward, dtype=np.float32).reshape(self.n_envs)
        if self.record_render_states:
            self._record_render_states(infos)
        if self.reward_source is not None:
            observations, actions = np.asarray(obs).reshape(self.n_envs, -1), np.asarray(action).reshape(self.n_envs, -1)
            learned = self.reward_source.new_rewards(observations, actions)
        else:
            learned = np.zeros(self.n_envs, dtype=np.float32)
        super().add(obs, next_obs, action, learned, done, infos)

    def relabel(self, reward_fn: RewardFn, batch_size: int = 16_384) -> None:
        """Rewrite every stored reward with r̂ (PEBBLE's relabeling)."""
        relabel_rewards(self, reward_fn, batch_size)

    def _record_render_states(self, infos: list[dict]) -> None:
        if any(info.get("render_state") is None for info in infos):
            raise ValueError(
                "the teacher needs pictures but the env's step info has no 'render_state': record it with "
                "sb3_pride.render_states.RenderStates (every sb3_pride/... env has it)"
            )
        states = np.stack([np.asarray(info["render_state"], dtype=np.float64) for info in infos])
        if self.render_states is None:
            self.render_states = np.zeros((self.buffer_size, self.n_envs, states.shape[1]), dtype=np.float64)
        self.render_states[self.pos] = states

    def end_episodes(self) -> None:
        """
        Mark the last stored transition of every environment as an episode end, when the env is reset in the middle
        of an episode (``learn(reset_num_timesteps=True)``, a new env, a resumed run), so that no query segment
        spans two episodes. It is recorded as a time-limit truncation (``timeouts``), as SB3 records one, so the
        critic still bootstraps from it; without ``handle_timeout_termination`` it reads as a termination.
        """
        if self.size() == 0:
            return
        last = (self.pos - 1) % self.buffer_size
        running = self.dones[last] == 0  # an episode that ended by itself keeps its termination
        self.dones[last, running] = 1
        if self.handle_timeout_termination:
            self.timeouts[last, running] = 1

    def sample(self, batch_size: int, env: VecNormalize | None = None) -> ReplayBufferSamples:
        samples = self.sample_transitions(batch_size, env)
        return samples if self.reward_source is None else self.reward_source.rewrite(samples, self, env)

    def sample_transitions(self, batch_size: int, env: VecNormalize | None = None) -> ReplayBufferSamples:
        """A minibatch with the stored rewards (``sample()`` without the reward source's rewrite)."""
        source = self.reward_source
        rows = None if source is None else source.recent_rows
        n_recent = round(source.recent_share * batch_size) if source is not None and rows is not None and len(rows) else 0
        if rows is None or n_recent == 0:
            return super().sample(batch_size, env=env)
        # QPA's hybrid replay: a share of the minibatch from the most recent episodes, the rest uniform
        recent = self._get_samples(rows[np.random.randint(0, len(rows), size=n_recent)], env=env)
        if n_recent == batch_size:
            return recent
        return concatenate_samples(recent, super().sample(batch_size - n_recent, env=env))

    def stored_observations(self, env: VecNormalize | None = None) -> np.ndarray:
        """Every stored observation, as the policy sees them (normalized under ``VecNormalize``): ``(n, *obs_shape)``."""
        observations = self._normalize_obs(self.observations[: self.size()].reshape(-1, *self.obs_shape), env)
        assert isinstance(observations, np.ndarray)  # flat Box observations (PEBBLE checks the env)
        return observations

    def transition_sample(self, n: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``n`` stored transitions drawn uniformly: (observations, actions, true rewards), for diagnostics."""
        rows = rng.integers(0, self.size(), size=n)
        cols = rng.integers(0, self.n_envs, size=n)
        return self.observations[rows, cols], self.actions[rows, cols], self.true_rewards[rows, cols]
