import numpy as np
import pytest
import torch as th

from sb3_pride import ElucidatedDiffusion


def energy_distance(x, y):
    def mean_dist(a, b):
        return np.linalg.norm(a[:, None, :] - b[None, :, :], axis=-1).mean()

    return 2 * mean_dist(x, y) - mean_dist(x, x) - mean_dist(y, y)


def mixture(n, rng):
    centers = np.array([[np.cos(t), np.sin(t)] for t in np.linspace(0, 2 * np.pi, 8, endpoint=False)]) * 4
    return centers[rng.integers(0, 8, n)] + 0.3 * rng.normal(size=(n, 2))


@pytest.mark.slow
def test_fits_a_mixture_of_gaussians_far_better_than_one_gaussian():
    rng = np.random.default_rng(0)
    train, held_out = mixture(4000, rng), mixture(800, rng)
    model = ElucidatedDiffusion(2, width=64, n_blocks=2, dim_t=32, train_steps=1500, sample_steps=24, seed=0)
    model.fit(train)
    samples = model.sample(800)
    gaussian = rng.multivariate_normal(train.mean(0), np.cov(train.T), size=800)
    diffusion_distance, gaussian_distance = energy_distance(samples, held_out), energy_distance(gaussian, held_out)
    assert diffusion_distance < 0.25 * gaussian_distance, (diffusion_distance, gaussian_distance)


@pytest.mark.slow
def test_samples_obey_known_linear_dynamics():
    rng = np.random.default_rng(1)
    A = np.array([[0.9, 0.2, 0.0], [-0.1, 0.95, 0.1], [0.0, 0.3, 0.8]])
    B = np.array([[0.5, 0.0], [0.3, 0.2], [0.0, -0.4]])
    s = rng.normal(size=(6000, 3))
    a = rng.uniform(-1, 1, size=(6000, 2))
    data = np.concatenate([s, a, s @ A.T + a @ B.T], axis=1)
    model = ElucidatedDiffusion(8, width=128, n_blocks=2, dim_t=64, train_steps=1200, sample_steps=24, seed=1)
    model.fit(data)
    x = model.sample(2000)
    residual = x[:, 5:] - (x[:, :3] @ A.T + x[:, 3:5] @ B.T)
    assert np.all(residual.std(axis=0) < 0.1 * data[:, 5:].std(axis=0))
    # and they are spread like the data, not collapsed onto a few points
    np.testing.assert_allclose(x.std(axis=0), data.std(axis=0), rtol=0.15)


def test_global_rng_untouched_and_bad_data_rejected():
    state = th.get_rng_state()
    model = ElucidatedDiffusion(3, width=16, n_blocks=1, train_steps=5, sample_steps=4, seed=0)
    model.fit(np.random.default_rng(0).normal(size=(100, 3)))
    model.sample(10)
    assert th.equal(state, th.get_rng_state())
    with pytest.raises(ValueError, match=r"shape \(N, 3\)"):
        model.fit(np.zeros((10, 4)))
    with pytest.raises(ValueError, match="non-finite"):
        model.fit(np.full((10, 3), np.nan))


def test_sample_near_and_sample_given_stay_anchored():
    rng = np.random.default_rng(0)
    train = mixture(2000, rng)
    model = ElucidatedDiffusion(2, width=32, n_blocks=1, dim_t=16, train_steps=300, sample_steps=6, seed=0)
    model.fit(train)
    levels = model.noise_levels(0.25)
    assert float(levels[0]) == pytest.approx(0.25) and bool(th.all(levels[1:] < levels[:-1]))
    anchors = train[:200]
    near = model.sample_near(anchors, start_sigma=0.01)
    far = model.sample_near(anchors, start_sigma=80.0)
    near_gap = np.linalg.norm(near - anchors, axis=1).mean()
    assert near_gap < 0.1 < np.linalg.norm(far - anchors, axis=1).mean()
    given = model.sample_given(anchors, known=[0])
    np.testing.assert_allclose(given[:, 0], anchors[:, 0], atol=1e-4)  # the known dimension comes back exactly
    assert np.linalg.norm(given[:, 1] - anchors[:, 1]) > 0  # the other one is generated
    with pytest.raises(ValueError, match="start_sigma"):
        model.sample_near(anchors, start_sigma=0.0)
    with pytest.raises(ValueError, match="anchors"):
        model.sample_near(anchors[:, :1], start_sigma=0.5)


def test_whitening_keeps_the_small_difference_of_two_correlated_coordinates():
    # Meta-World's observation holds the previous frame beside the current one: a velocity is the small difference
    # of two coordinates with a large spread. Per-dimension noise of sigma = 0.25 wipes it out; after whitening it is
    # a direction of its own and the noise along it is in proportion.
    rng = np.random.default_rng(0)
    position, velocity = rng.normal(size=3000), 0.01 * rng.normal(size=3000)
    flag = (rng.random(3000) < 0.5).astype(float)
    data = np.stack([position, position - velocity, flag], axis=1)
    spreads = {}
    for normalization in ("per_dimension", "whiten"):
        model = ElucidatedDiffusion(3, width=32, n_blocks=1, dim_t=16, train_steps=300, sample_steps=6,
                                    skip_normalization=(2,), normalization=normalization, seed=0)  # fmt: skip
        model.fit(data)
        normalized = model.normalize(th.as_tensor(data, dtype=th.float32, device=model.device_))
        np.testing.assert_allclose(model.unnormalize(normalized).cpu().numpy(), data, atol=1e-4)  # an exact inverse
        np.testing.assert_array_equal(normalized[:, 2].cpu().numpy(), flag)  # the skipped dimension is left as it is
        near = model.sample_near(data[:1000], start_sigma=0.25)
        spreads[normalization] = (near[:, 0] - near[:, 1]).std() / velocity.std()
    assert spreads["whiten"] < 2.0 < 10.0 < spreads["per_dimension"], spreads
    with pytest.raises(ValueError, match="sample_given needs normalization='per_dimension'"):
        model.sample_given(data[:10], known=[0])
    with pytest.raises(ValueError, match="normalization must be"):
        ElucidatedDiffusion(3, normalization="pca")
    with pytest.raises(ValueError, match="skip_normalization"):
        ElucidatedDiffusion(3, skip_normalization=(3,))


def test_whitening_is_zca_and_survives_refits():
    # ZCA's map is the symmetric Σ^(-1/2), whatever sign or order eigh gives the eigenvectors, so refits on
    # overlapping data give nearly the same map and a warm-started model keeps its meaning (PCA's rotation can flip
    # axes between refits)
    rng = np.random.default_rng(0)
    data = rng.normal(size=(4000, 4)) @ rng.normal(size=(4, 4))
    data[:, 3] = 0.5  # a constant dimension, and a skipped last one given as -1
    data = np.concatenate([data, (rng.random((4000, 1)) < 0.5)], axis=1)
    model = ElucidatedDiffusion(5, width=16, n_blocks=1, train_steps=1, normalization="whiten",
                                skip_normalization=(-1,), seed=0, device="cpu")  # fmt: skip
    for part in (data[:3000], data[1000:]):
        model.fit(part)
        whitening = (model.normalize(th.eye(5) + model.mean) - model.normalize(model.mean[None])).numpy()[:3, :3]
        eigenvalues, eigenvectors = np.linalg.eigh(np.cov(part[:, :3], rowvar=False, bias=True))
        inverse_root = eigenvectors @ np.diag(eigenvalues**-0.5) @ eigenvectors.T
        np.testing.assert_allclose(whitening, inverse_root, rtol=1e-3, atol=1e-4 * np.abs(inverse_root).max())
        whitened = model.normalize(th.as_tensor(part, dtype=th.float32)).numpy()
        np.testing.assert_allclose(np.cov(whitened[:, :3], rowvar=False, bias=True), np.eye(3), atol=1e-3)
        np.testing.assert_array_equal(whitened[:, 4], part[:, 4])
