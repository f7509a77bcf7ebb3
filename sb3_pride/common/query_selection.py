"""
How a feedback session's queries are picked among its candidate pairs: the query selections, registered by name.
Each is a function of the ``QueryCandidates`` (the ensemble members' predicted returns of each candidate, the
candidates' and the labelled pairs' features, the pairs themselves) that returns the indices of the pairs to ask.
The built-ins are B-Pref's; :func:`register_query_selection` adds one of a user's own the same way, and
``PEBBLE(query_selection=name)`` uses it.
"""

from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
import torch as th

if TYPE_CHECKING:
    from sb3_pride.common.queries import SegmentPairs


@dataclass(frozen=True)
class QueryCandidates:
    """
    What a query selection receives: every built-in receives the same.

    :param member_returns: (members, n_candidates, 2) the ensemble members' predicted segment returns
    :param n_queries: how many to pick, at most the number of candidates
    :param features: (n_candidates, dim) the candidates' features (``pair_features``), or None
    :param labeled_features: (n_labeled, dim) the labelled pairs' features (what is covered already), or None
    :param pairs: the candidate pairs themselves (observations, actions, ...), or None where only returns are known
    """

    member_returns: th.Tensor
    n_queries: int
    features: np.ndarray | None = None
    labeled_features: np.ndarray | None = None
    pairs: "SegmentPairs | None" = None


#: a query selection: the indices, into the candidates, of the pairs to ask
QuerySelection = Callable[[QueryCandidates], np.ndarray]
#: every query selection ``query_selection`` may name, built-ins first
QUERY_SELECTIONS: dict[str, QuerySelection] = {}


def register_query_selection(name: str, selection: QuerySelection) -> None:
    """
    Make ``query_selection=name`` pick a session's queries with ``selection`` (PEBBLE's first session stays uniform).
    A selection other than "uniform" chooses among ``candidates_multiplier`` random candidate pairs per query.

    :param name: the name ``query_selection`` gives
    :param selection: a function of ``QueryCandidates`` returning ``n_queries`` distinct indices into the candidates
    """
    if not isinstance(name, str) or not name:
        raise ValueError(f"register_query_selection: name must be a non-empty string, got {name!r}")
    if not callable(selection):
        raise TypeError(f"register_query_selection: {name!r} must be a function of QueryCandidates, got {selection!r}")
    if name in QUERY_SELECTIONS and QUERY_SELECTIONS[name] is not selection:
        raise ValueError(f"register_query_selection: {name!r} is already registered")
    QUERY_SELECTIONS[name] = selection


def preference_probabilities(member_returns: th.Tensor) -> th.Tensor:
    """P[σ1 ≻ σ0] per ensemble member (Eq. 1) from segment returns of shape (members, n, 2)."""
    return th.softmax(member_returns, dim=-1)[..., 1]


def kcenter_greedy(candidates: np.ndarray, centers: np.ndarray, n: int) -> np.ndarray:
    """
    Greedy k-center (Sener & Savarese, ICLR 2018; B-Pref's ``KCenterGreedy``): ``n`` candidates picked one at a time,
    each the one farthest (Euclidean) from its nearest center, the centers being ``centers`` and the candidates picked
    before it. Queries so chosen cover the space of segments instead of crowding where the reward model is unsure.

    :param candidates: (n_candidates, dim) features
    :param centers: (n_centers, dim) features of what is covered already (the labelled pairs); may be empty
    :param n: how many to pick, ``<= n_candidates``
    :return: the picked indices, in the order picked
    """
    points = th.as_tensor(candidates, dtype=th.float32)
    if len(centers):
        nearest = th.cdist(points, th.as_tensor(centers, dtype=th.float32)).min(dim=1).values
    else:
        nearest = th.full((len(points),), float("inf"))
    picked: list[int] = []
    for _ in range(n):
        # without centers, the first pick is the first candidate (they are random already)
        index = int(th.argmax(nearest)) if th.isfinite(nearest).any() or picked else 0
        picked.append(index)
        nearest = th.minimum(nearest, th.cdist(points, points[index : index + 1]).squeeze(1))
        nearest[index] = -1.0  # never picked twice
    return np.array(picked, dtype=np.int64)


def pair_features(observations: np.ndarray) -> np.ndarray:
    """A pair's k-center features, as in B-Pref: the observations of both segments, flattened: (n, 2, k, d) -> (n, 2kd)."""
    return observations.reshape(len(observations), int(np.prod(observations.shape[1:])))


def uniform(candidates: QueryCandidates) -> np.ndarray:
    """The first ``n_queries`` candidates (they are random already): B-Pref's ``feed_type`` 0."""
    return np.arange(candidates.n_queries)


def disagreement(candidates: QueryCandidates) -> np.ndarray:
    """The largest std over members of P[σ1 ≻ σ0] (Eq. 1): B-Pref's ``feed_type`` 1."""
    p = preference_probabilities(candidates.member_returns)
    score = p.std(dim=0) if len(p) > 1 else th.zeros(p.shape[1])
    return th.topk(score, k=candidates.n_queries).indices.cpu().numpy()


def entropy(candidates: QueryCandidates) -> np.ndarray:
    """The largest mean over members of the entropy of P[σ1 ≻ σ0]: B-Pref's ``feed_type`` 2."""
    p, eps = preference_probabilities(candidates.member_returns), 1e-8
    score = -(p * th.log(p + eps) + (1 - p) * th.log(1 - p + eps)).mean(dim=0)
    return th.topk(score, k=candidates.n_queries).indices.cpu().numpy()


def kcenter_among(prefilter: QuerySelection | None) -> QuerySelection:
    """
    Greedy k-center on the candidates' features, the labelled pairs counting as centers (B-Pref's ``feed_type`` 3),
    among every candidate (``prefilter`` None) or among the half that ``prefilter`` scores highest (4 and 5).
    """

    def kcenter(candidates: QueryCandidates) -> np.ndarray:
        features, n = candidates.features, candidates.n_queries
        if features is None:
            raise ValueError("query_selection: a k-center selection needs the candidates' features")
        labeled = candidates.labeled_features
        centers = np.zeros((0, features.shape[1])) if labeled is None else labeled
        pool = np.arange(len(features))
        if prefilter is not None:  # B-Pref: the most uncertain half of the candidates, then k-center among them
            half = QueryCandidates(candidates.member_returns, max(n, len(pool) // 2))
            pool = np.sort(prefilter(half))
        return pool[kcenter_greedy(features[pool], centers, n)]

    return kcenter


for _name, _selection in (
    ("uniform", uniform),
    ("disagreement", disagreement),
    ("entropy", entropy),
    ("kcenter", kcenter_among(None)),
    ("kcenter_disagreement", kcenter_among(disagreement)),
    ("kcenter_entropy", kcenter_among(entropy)),
):
    register_query_selection(_name, _selection)


def select_queries(
    member_returns: th.Tensor,
    n_queries: int,
    method: str,
    features: np.ndarray | None = None,
    labeled_features: np.ndarray | None = None,
    pairs: "SegmentPairs | None" = None,
) -> np.ndarray:
    """
    Indices of the ``n_queries`` candidate pairs to ask about, picked by the query selection named ``method``
    (``QUERY_SELECTIONS``; the arguments are ``QueryCandidates``' fields).
    """
    if method not in QUERY_SELECTIONS:
        raise ValueError(f"query_selection must be one of {tuple(QUERY_SELECTIONS)}, got {method!r}")
    return QUERY_SELECTIONS[method](QueryCandidates(member_returns, n_queries, features, labeled_features, pairs))
