"""A query selection written outside the package: registered by name, given what the built-ins are given, and the
pairs it picks are the ones the teacher is asked."""

import numpy as np
import pytest

from sb3_pride import PEBBLE
from sb3_pride.common.query_selection import QUERY_SELECTIONS, QueryCandidates, register_query_selection


class LargestGap:
    """A user's selection: the candidates whose two segments r̂'s members, on average, rank furthest apart."""

    def __init__(self):
        self.seen: list[QueryCandidates] = []
        self.picked: list[np.ndarray] = []

    def __call__(self, candidates: QueryCandidates) -> np.ndarray:
        self.seen.append(candidates)
        gap = (candidates.member_returns[..., 1] - candidates.member_returns[..., 0]).mean(dim=0).abs()
        chosen = gap.argsort(descending=True)[: candidates.n_queries].numpy()
        self.picked.append(candidates.pairs.inputs[chosen])
        return chosen


@pytest.fixture
def largest_gap():
    selection = LargestGap()
    register_query_selection("largest_gap", selection)
    yield selection
    del QUERY_SELECTIONS["largest_gap"]


def test_a_query_selection_of_the_users_own_picks_the_pairs_the_teacher_is_asked(largest_gap, tiny_kwargs):
    model = PEBBLE("MlpPolicy", "Pendulum-v1", seed=0, query_selection="largest_gap", **tiny_kwargs)
    model.learn(1000)
    assert len(largest_gap.seen) + 1 == model.phase.sessions >= 3  # every feedback round but the first, uniform
    multiplier, queries = model.query_sampler.candidates_multiplier, tiny_kwargs["queries_per_session"]
    for candidates in largest_gap.seen:  # what every built-in is given
        assert candidates.member_returns.shape == (3, multiplier * queries, 2) and candidates.n_queries == queries
        assert candidates.features.shape[0] == len(candidates.pairs) == multiplier * queries
        assert candidates.labeled_features is not None and len(candidates.labeled_features) >= queries
    asked = model.preferences.inputs
    for picked in largest_gap.picked:  # the pairs it picked were asked, in the order it gave
        matches = [np.flatnonzero((asked == pair).all(axis=(1, 2, 3))) for pair in picked]
        assert all(len(match) == 1 for match in matches)
        assert np.all(np.diff([match[0] for match in matches]) == 1)


def test_bad_registrations_are_refused_and_an_unregistered_name_is_named():
    with pytest.raises(TypeError, match="must be a function of QueryCandidates"):
        register_query_selection("mine", "not a function")  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="'disagreement' is already registered"):
        register_query_selection("disagreement", lambda candidates: np.arange(candidates.n_queries))
    with pytest.raises(ValueError, match=r"query_selection must be one of .*'kcenter_entropy'\), got 'mine'"):
        PEBBLE("MlpPolicy", "Pendulum-v1", query_selection="mine")
