"""Segment pairs for preference queries: where segments may start, how candidates are chosen."""

import inspect
import warnings
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch as th

from sb3_pride.common.buffers import PreferenceReplayBuffer
from sb3_pride.common.journal import query_id
from sb3_pride.common.query_selection import QUERY_SELECTIONS, pair_features, select_queries
from sb3_pride.common.utils import check_choice, check_positive_ints, check_real

#: said once when some segments queries may be drawn from cannot be shown (their recorded frames were dropped)
HIDDEN_SEGMENTS = (
    "some segments of the episodes queries are drawn from can no longer be shown (the teacher dropped their recorded "
    "frames): queries come from the others; give WebTeacher recorded_episodes >= max_query_episodes and enough "
    "recording_bytes"
)
#: how many times, at most, a session draws again when its candidates were asked before (``QuerySampler.fresh_pairs``)
REDRAWS = 10


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


def concatenate_pairs(parts: list[SegmentPairs]) -> SegmentPairs:
    """The pairs of ``parts``, one after the other (drawn from one buffer: the first's return scale)."""
    states = [part.render_states for part in parts if part.render_states is not None]
    observations, actions, true_rewards = (
        np.concatenate([getattr(part, name) for part in parts]) for name in ("observations", "actions", "true_rewards")
    )
    render_states = np.concatenate(states) if len(states) == len(parts) else None
    return SegmentPairs(observations, actions, true_rewards, parts[0].return_scale, render_states)


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


def recent_rows(buffer: PreferenceReplayBuffer, max_episodes: int) -> np.ndarray:
    """
    Buffer rows of the ``max_episodes`` most recent episodes (each environment's ``ceil(max_episodes / n_envs)``, the
    running one included), from the oldest of them to the newest row: where queries come from, and QPA's hybrid
    replay draws its share of each minibatch.
    """
    rows = chronological_rows(buffer)
    episodes_per_env = -(-max_episodes // buffer.n_envs)
    first = len(rows)
    for env_idx in range(buffer.n_envs):
        ends = np.flatnonzero(buffer.dones[rows, env_idx] > 0)
        ends = ends[ends < len(rows) - 1]  # an episode that ended at the last row is done: the next one is running
        # the recent episodes start after the end of episode number -(episodes_per_env) counting the running one
        first = min(first, int(ends[-episodes_per_env]) + 1 if len(ends) >= episodes_per_env else 0)
    return rows[first:]


def sample_segment_pairs(
    buffer: PreferenceReplayBuffer,
    n_pairs: int,
    segment_length: int,
    max_episodes: int,
    rng: np.random.Generator,
    render_states: bool = True,
) -> SegmentPairs | None:
    """
    ``n_pairs`` pairs of segments drawn uniformly (with replacement) from the valid starts of ``segment_starts``.

    :param render_states: copy the simulator states recorded beside the transitions, if any (a teacher that watches
        the segments needs them; pairs no one will see do not); a segment holding a NaN state, one the teacher can no
        longer show (its recorded frames were dropped), is then never drawn

    :return: the pairs, or ``None`` when no segment fits in the stored episodes yet
    """
    starts, envs = segment_starts(buffer, segment_length, max_episodes)
    if len(starts) == 0:
        return None
    rows = chronological_rows(buffer)
    # mean true reward per step over the window queries come from (B-Pref: recent returns × segment / horizon)
    window_rewards = buffer.true_rewards[rows[starts.min() :]]
    if render_states and buffer.render_states is not None:
        # a teacher marks the transitions it can no longer show (NaN states): no segment holding one is drawn
        hidden = np.cumsum(np.isnan(buffer.render_states[rows, :, 0]), axis=0)
        hidden = np.vstack([np.zeros((1, buffer.n_envs), dtype=hidden.dtype), hidden])
        showable = hidden[starts + segment_length, envs] == hidden[starts, envs]
        if not showable.all():
            warnings.warn(HIDDEN_SEGMENTS, stacklevel=2)
        starts, envs = starts[showable], envs[showable]
        if len(starts) == 0:
            return None
    pick = rng.integers(0, len(starts), size=(n_pairs, 2))
    steps = rows[starts[pick][..., None] + np.arange(segment_length)]  # (n, 2, k) buffer rows
    env_idx = np.broadcast_to(envs[pick][..., None], steps.shape)
    return SegmentPairs(
        observations=buffer.observations[steps, env_idx],
        actions=buffer.actions[steps, env_idx],
        true_rewards=buffer.true_rewards[steps, env_idx],
        return_scale=float(np.mean(window_rewards) * segment_length),
        render_states=None if buffer.render_states is None or not render_states else buffer.render_states[steps, env_idx],
    )


def stored_transitions(
    buffer: PreferenceReplayBuffer, rng: np.random.Generator, limit: int | None = None
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """
    (s, a, s') of the transitions stored in ``buffer``: every one, oldest first, or a random choice of ``limit`` of
    them, drawn before any is copied (REED's consistency pre-training learns from them).
    """
    rows = chronological_rows(buffer)
    n = len(rows) * buffer.n_envs
    chosen = np.arange(n) if limit is None or n <= limit else rng.choice(n, limit, replace=False)
    row, env = rows[chosen // buffer.n_envs], chosen % buffer.n_envs
    return buffer.observations[row, env], buffer.actions[row, env], buffer.next_observations[row, env]


def episode_lengths(buffer: PreferenceReplayBuffer) -> list[int]:
    """The lengths of the finished episodes stored in ``buffer``, each environment's, oldest first."""
    rows = chronological_rows(buffer)
    lengths = []
    for env_idx in range(buffer.n_envs):
        ends = np.flatnonzero(buffer.dones[rows, env_idx] > 0)
        lengths.extend(np.diff(np.concatenate([[-1], ends])).tolist())
    return lengths


class QuerySampler:
    """
    Where queries come from and which are asked (PEBBLE; B-Pref's sampling schemes): ``candidates_multiplier`` × K
    random segment pairs of the ``max_query_episodes`` most recent episodes, of which the K most informative by
    ``selection`` are asked. Also the rows QPA's hybrid replay draws from (the same recent episodes).

    :param segment_length: steps per segment; a segment never crosses an episode end
    :param selection: a name of ``QUERY_SELECTIONS``: "uniform", "disagreement", "entropy", "kcenter",
        "kcenter_disagreement", "kcenter_entropy" or one registered with ``register_query_selection``
        (``select_queries``); the first feedback session is always uniform (r̂ knows nothing yet)
    :param candidates_multiplier: candidate pairs per query for the non-uniform selections (PEBBLE: 10)
    :param max_query_episodes: segments are drawn from this many most recent episodes (PEBBLE: 100; QPA: 10)
    :param hybrid_replay: QPA's hybrid experience replay (Hu et al., ICLR 2024): this share of each SAC minibatch is
        drawn from the ``max_query_episodes`` most recent episodes while queries remain to be asked (0: uniform)
    """

    @classmethod
    def from_settings(cls, segment_length: int, selection: str, query_kwargs: Any) -> "QuerySampler":
        """A sampler of PEBBLE's ``query_kwargs``; a dict of other entries is refused, naming ``query_kwargs``."""
        taken = [
            name for name in inspect.signature(cls.__init__).parameters if name not in ("self", "segment_length", "selection")
        ]
        if not isinstance(query_kwargs, dict) or set(query_kwargs) - set(taken):
            raise ValueError(f"query_kwargs must be a dict of QuerySampler's settings {list(taken)}, got {query_kwargs!r}")
        return cls(segment_length, selection, **query_kwargs)

    def __init__(
        self,
        segment_length: int,
        selection: str = "disagreement",
        candidates_multiplier: int = 10,
        max_query_episodes: int = 100,
        hybrid_replay: float = 0.0,
    ):
        check_positive_ints(
            segment_length=segment_length, candidates_multiplier=candidates_multiplier, max_query_episodes=max_query_episodes
        )
        check_choice("query_selection", selection, tuple(QUERY_SELECTIONS))
        check_real("hybrid_replay", hybrid_replay, lambda share: 0 <= share <= 1, "in [0, 1]")
        self.segment_length, self.selection = segment_length, selection
        self.candidates_multiplier, self.max_query_episodes = candidates_multiplier, max_query_episodes
        self.hybrid_replay = float(hybrid_replay)
        self.warned_short_episodes = False

    def choose(
        self,
        buffer: PreferenceReplayBuffer,
        n_queries: int,
        rng: np.random.Generator,
        member_returns: Callable[[np.ndarray], th.Tensor],
        labeled_inputs: np.ndarray,
        asked_before: set[str],
        first: bool,
        selection: str | None = None,
    ) -> SegmentPairs | None:
        """
        ``n_queries`` pairs to ask about; pairs whose ``query_id`` is in ``asked_before`` are never chosen again.

        :param member_returns: the ensemble members' segment returns of candidate pairs' inputs (members, n, 2)
        :param labeled_inputs: the inputs of the pairs labelled so far (the k-center selections' covered points)
        :param first: the first feedback session, always uniform
        :param selection: the selection of this session (None: the sampler's ``selection``)
        :return: the chosen pairs, all different (fewer only where the recent episodes hold no more never asked), or
            None when no segment fits in the stored episodes yet (a warning, once, when every finished episode is
            shorter than a segment)
        """
        if n_queries == 0:
            shape = (0, 2, self.segment_length)
            return SegmentPairs(np.zeros((*shape, *buffer.obs_shape)), np.zeros((*shape, buffer.action_dim)), np.zeros(shape))
        selection = "uniform" if first else (selection or self.selection)
        n_candidates = n_queries if selection == "uniform" else n_queries * self.candidates_multiplier
        candidates = self.fresh_pairs(buffer, n_candidates, n_queries, rng, asked_before)
        if candidates is None:
            self.warn_short_episodes(buffer)
            return None
        if selection != "uniform" and len(candidates) > 0:
            n_obs = candidates.observations.shape[-1]
            chosen = select_queries(
                member_returns(candidates.inputs),
                min(n_queries, len(candidates)),
                selection,
                features=pair_features(candidates.observations),
                labeled_features=pair_features(labeled_inputs[..., :n_obs]),
                pairs=candidates,
            )
            candidates = candidates[chosen]
        return candidates

    def fresh_pairs(
        self, buffer: PreferenceReplayBuffer, n_pairs: int, n_needed: int, rng: np.random.Generator, asked_before: set[str]
    ) -> SegmentPairs | None:
        """
        Up to ``n_pairs`` random pairs, all different, none in ``asked_before``, drawn again (``REDRAWS`` times at most)
        while fewer than ``n_needed`` are left: a session whose draw repeats earlier answers (an earlier run's, same
        seed) still asks in full. None when no segment fits in the stored episodes yet.
        """
        parts: list[SegmentPairs] = []
        seen = set(asked_before)
        for _ in range(1 + REDRAWS):
            drawn = sample_segment_pairs(buffer, n_pairs, self.segment_length, self.max_query_episodes, rng)
            if drawn is None:
                return None
            last = {query_id(pair): index for index, pair in enumerate(drawn.inputs)}  # one of each pair drawn twice
            fresh = sorted(index for identity, index in last.items() if identity not in seen)
            seen.update(last)
            parts.append(drawn[np.array(fresh, dtype=np.int64)])
            if sum(len(part) for part in parts) >= n_needed:
                break
        return concatenate_pairs(parts)[:n_pairs]

    def unlabeled_pairs(self, buffer: PreferenceReplayBuffer, n_pairs: int, rng: np.random.Generator) -> np.ndarray | None:
        """The inputs of ``n_pairs`` pairs drawn as queries are, for nobody to label (SURF's unlabelled pairs)."""
        pairs = sample_segment_pairs(buffer, n_pairs, self.segment_length, self.max_query_episodes, rng, render_states=False)
        return None if pairs is None else pairs.inputs

    def recent_rows(self, buffer: PreferenceReplayBuffer) -> np.ndarray:
        """The buffer rows of the episodes queries come from (QPA's hybrid replay draws its share from them)."""
        return recent_rows(buffer, self.max_query_episodes)

    def warn_short_episodes(self, buffer: PreferenceReplayBuffer) -> None:
        """
        Warn once when every finished episode is shorter than a segment (early-terminating envs, e.g. Hopper's falls).
        Not an error: longer episodes may come, and the session is tried again a segment later; an env whose step
        limit is shorter than a segment is refused when it is attached.
        """
        if self.warned_short_episodes:
            return
        lengths = episode_lengths(buffer)
        if not lengths or max(lengths) >= self.segment_length:
            return
        self.warned_short_episodes = True
        warnings.warn(
            f"segment_length={self.segment_length} is longer than every episode so far (longest: {max(lengths)} steps): "
            "the feedback session waits until an episode holds a segment and is tried again every segment_length "
            "steps. If episodes end early for long (e.g. falls), choose a smaller segment_length.",
            stacklevel=3,
        )
