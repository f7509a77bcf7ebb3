"""Segment pairs for preference queries: where segments may start, how candidates are chosen."""

from dataclasses import dataclass

import numpy as np
import torch as th

from sb3_pride.common.buffers import PreferenceReplayBuffer

QUERY_SELECTIONS = ("uniform", "disagreement", "entropy")


@dataclass
class SegmentPairs:
    """
    ``n`` pairs of trajectory segments (σ0, σ1) of ``k`` steps each, as stored in the replay buffer.

    Arrays are indexed ``[pair, 0 or 1, step, ...]``. ``true_rewards`` are for the teacher only.

    :param observations: (n, 2, k, obs_dim)
    :param actions: (n, 2, k, action_dim)
    :param true_rewards: (n, 2, k)
    :param return_scale: the typical true return of one segment in recent episodes
        (mean true reward per step × k); the scripted teachers scale their skip/equal thresholds by it
    :param render_states: (n, 2, k, state_dim) simulator states after each step, for teachers that watch the
        segments (``PreferenceReplayBuffer.record_render_states``); None when not recorded
    """

    observations: np.ndarray
    actions: np.ndarray
    true_rewards: np.ndarray
    return_scale: float = 1.0
    render_states: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.observations)

    def __getitem__(self, index) -> "SegmentPairs":
        render_states = None if self.render_states is None else self.render_states[index]
        return SegmentPairs(
            self.observations[index], self.actions[index], self.true_rewards[index], self.return_scale, render_states
        )

    @property
    def inputs(self) -> np.ndarray:
        """The reward model's inputs: (n, 2, k, obs_dim + action_dim) float32 [s, a]."""
        return np.concatenate([self.observations, self.actions], axis=-1).astype(np.float32)


def chronological_rows(buffer: PreferenceReplayBuffer) -> np.ndarray:
    """Buffer rows from oldest to newest (the ring buffer's write position is where time restarts)."""
    if buffer.full:
        return np.concatenate([np.arange(buffer.pos, buffer.buffer_size), np.arange(0, buffer.pos)])
    return np.arange(buffer.pos)


def segment_starts(buffer: PreferenceReplayBuffer, segment_length: int, max_episodes: int) -> tuple[np.ndarray, np.ndarray]:
    """
    Every (row, env) where a segment of ``segment_length`` consecutive transitions of one environment may start
    without crossing an episode end, restricted to each environment's ``ceil(max_episodes / n_envs)`` most recent
    episodes (the running, unfinished one included).

    :return: (start positions in chronological order, env indices), with ``chronological_rows(buffer)`` mapping
        a chronological position to its buffer row
    """
    rows = chronological_rows(buffer)
    episodes_per_env = -(-max_episodes // buffer.n_envs)
    starts, envs = [], []
    for env_idx in range(buffer.n_envs):
        ends = buffer.dones[rows, env_idx] > 0
        # episode id of each step: how many episode ends came strictly before it
        episode = np.concatenate([[0], np.cumsum(ends[:-1])]) if len(ends) else np.zeros(0, dtype=int)
        if len(ends) < segment_length:
            continue
        first, last = episode[: len(ends) - segment_length + 1], episode[segment_length - 1 :]
        valid = (first == last) & (first > episode[-1] - episodes_per_env)
        positions = np.flatnonzero(valid)
        starts.append(positions)
        envs.append(np.full(len(positions), env_idx))
    if not starts:
        return np.zeros(0, dtype=int), np.zeros(0, dtype=int)
    return np.concatenate(starts), np.concatenate(envs)


def sample_segment_pairs(
    buffer: PreferenceReplayBuffer,
    n_pairs: int,
    segment_length: int,
    max_episodes: int,
    rng: np.random.Generator,
) -> SegmentPairs | None:
    """
    ``n_pairs`` pairs of segments drawn uniformly (with replacement) from the valid starts of ``segment_starts``.

    :return: the pairs, or ``None`` when no segment fits in the stored episodes yet
    """
    starts, envs = segment_starts(buffer, segment_length, max_episodes)
    if len(starts) == 0:
        return None
    rows = chronological_rows(buffer)
    pick = rng.integers(0, len(starts), size=(n_pairs, 2))
    steps = rows[starts[pick][..., None] + np.arange(segment_length)]  # (n, 2, k) buffer rows
    env_idx = np.broadcast_to(envs[pick][..., None], steps.shape)
    # mean true reward per step over the window queries come from (B-Pref: recent returns × segment / horizon)
    window_rewards = buffer.true_rewards[rows[starts.min() :]]
    return SegmentPairs(
        observations=buffer.observations[steps, env_idx],
        actions=buffer.actions[steps, env_idx],
        true_rewards=buffer.true_rewards[steps, env_idx],
        return_scale=float(np.mean(window_rewards) * segment_length),
        render_states=None if buffer.render_states is None else buffer.render_states[steps, env_idx],
    )


def preference_probabilities(member_returns: th.Tensor) -> th.Tensor:
    """P[σ1 ≻ σ0] per ensemble member (Eq. 1) from segment returns of shape (members, n, 2)."""
    return th.softmax(member_returns, dim=-1)[..., 1]


def select_queries(member_returns: th.Tensor, n_queries: int, method: str) -> np.ndarray:
    """
    Indices of the ``n_queries`` candidate pairs to ask about.

    :param member_returns: (members, n_candidates, 2) predicted segment returns of each ensemble member
    :param method: "uniform" (the first ``n_queries``, candidates being random already), "disagreement"
        (largest std over members of P[σ1 ≻ σ0]) or "entropy" (largest mean over members of the entropy of
        P[σ1 ≻ σ0]), as B-Pref's ``feed_type`` 0, 1 and 2
    """
    if method == "uniform":
        return np.arange(n_queries)
    p = preference_probabilities(member_returns)
    if method == "disagreement":
        score = p.std(dim=0) if len(p) > 1 else th.zeros(p.shape[1])
    elif method == "entropy":
        eps = 1e-8
        score = -(p * th.log(p + eps) + (1 - p) * th.log(1 - p + eps)).mean(dim=0)
    else:
        raise ValueError(f"query_selection must be one of {QUERY_SELECTIONS}, got {method!r}")
    return th.topk(score, k=n_queries).indices.cpu().numpy()
