"""k-NN state-entropy reward for PEBBLE's unsupervised pre-training (Eq. 3 of the PRIDE paper)."""

import numpy as np
import torch as th
from stable_baselines3.common.running_mean_std import RunningMeanStd


def knn_distances(queries: th.Tensor, points: th.Tensor, k: int, chunk_size: int = 4096) -> th.Tensor:
    """
    Euclidean distance from each query to its ``k``-th nearest neighbour among ``points``.

    ``points`` are visited in chunks and only the ``k`` smallest distances seen so far are kept per query,
    so memory is O(len(queries) × (chunk_size + k)), never O(len(queries) × len(points)).
    A query that is itself one of ``points`` counts as its own first neighbour (distance 0);
    callers that sample queries from ``points`` ask for ``k + 1``, as PEBBLE does.

    :param queries: (B, D) tensor
    :param points: (N, D) tensor, N >= k
    :param k: rank of the neighbour (1 = nearest)
    :param chunk_size: number of points compared at once
    :return: (B,) tensor of distances
    """
    if k < 1 or k > len(points):
        raise ValueError(f"k must be in [1, len(points)={len(points)}], got {k}")
    best = th.full((len(queries), 0), float("inf"), dtype=queries.dtype, device=queries.device)
    for start in range(0, len(points), chunk_size):
        chunk = points[start : start + chunk_size].to(queries.dtype)
        # the matrix-product form (3× faster here); its float32 rounding (~1e-3 on near-zero distances)
        # does not matter for a k-th neighbour that is not the point itself
        dists = th.cdist(queries, chunk)
        candidates = th.cat([best, dists], dim=1)
        best = th.topk(candidates, k=min(k, candidates.shape[1]), dim=1, largest=False).values
    return best[:, k - 1]


class StateEntropyReward:
    """
    PEBBLE's intrinsic reward: r_int(s) = ||s - s^k|| (Eq. 3), the distance from ``s`` to its k-th nearest
    neighbour among all stored observations, divided by a running standard deviation of that distance
    (no mean subtraction, as in B-Pref; unlike B-Pref the running statistics are updated correctly).

    Eq. 3 of the paper writes the log of the distance; PEBBLE's code (and this class) use the distance itself.

    :param k: which neighbour (PEBBLE: 5)
    :param chunk_size: stored observations compared at once (bounds memory)
    """

    def __init__(self, k: int = 5, chunk_size: int = 4096):
        if k < 1:
            raise ValueError(f"entropy_k must be >= 1, got {k}")
        self.k = k
        self.chunk_size = chunk_size
        self.stats = RunningMeanStd(shape=())

    def __call__(self, observations: th.Tensor, all_observations: th.Tensor, update_stats: bool = True) -> th.Tensor:
        """
        :param observations: (B, D) minibatch, drawn from ``all_observations``
        :param all_observations: (N, D) every stored observation
        :param update_stats: update the running std with this batch
        :return: (B, 1) normalized intrinsic reward
        """
        # k + 1: the sampled observation is itself among the stored ones, at distance 0
        k = min(self.k + 1, len(all_observations))
        dists = knn_distances(observations.float(), all_observations.float(), k, self.chunk_size)
        if update_stats:
            self.stats.update(dists.detach().cpu().numpy().astype(np.float64))
        return (dists / float(np.sqrt(self.stats.var + 1e-8))).reshape(-1, 1)
