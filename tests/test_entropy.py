import numpy as np
import torch as th

from sb3_pride.common.entropy import StateEntropyReward, knn_distances


def brute_force_kth(queries, points, k):
    dists = np.linalg.norm(queries[:, None, :] - points[None, :, :], axis=-1)
    return np.sort(dists, axis=1)[:, k - 1]


def test_knn_matches_brute_force_across_chunks():
    rng = np.random.default_rng(0)
    points = rng.normal(size=(1000, 7)).astype(np.float32)
    queries = np.concatenate([points[:20], rng.normal(size=(20, 7)).astype(np.float32)])
    for k in (1, 3, 6):
        fast = knn_distances(th.as_tensor(queries), th.as_tensor(points), k, chunk_size=64).numpy()
        np.testing.assert_allclose(fast, brute_force_kth(queries, points, k), rtol=1e-4, atol=2e-3)
    # a point sampled from the set is its own nearest neighbour
    assert np.all(knn_distances(th.as_tensor(points[:20]), th.as_tensor(points), 1).numpy() < 2e-3)


def test_state_entropy_reward_skips_self_and_divides_by_running_std():
    rng = np.random.default_rng(1)
    points = rng.normal(size=(500, 4)).astype(np.float32)
    batch = points[:64]
    reward = StateEntropyReward(k=5, chunk_size=100)
    r = reward(th.as_tensor(batch), th.as_tensor(points)).numpy().ravel()
    raw = brute_force_kth(batch, points, 6)  # the 5th neighbour other than the point itself
    assert reward.stats.count > 60
    np.testing.assert_allclose(r, raw / np.sqrt(reward.stats.var + 1e-8), rtol=1e-3)
    # no mean subtraction: the reward keeps the sign of a distance
    assert np.all(r > 0)
