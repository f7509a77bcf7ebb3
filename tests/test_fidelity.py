"""The fidelity measures must pass real data and fail broken data: a number that cannot fail tells nobody anything."""

import gymnasium as gym
import numpy as np
import pandas as pd
import pytest
from stable_baselines3.common.logger import configure

from sb3_pride import PRIDE
from sb3_pride.pride.fidelity import DynamicsEnsemble, measure_fidelity
from tests.test_pride import tiny_pride

#: a dynamics ensemble small enough for tests
TINY_DYNAMICS = dict(width=64, train_steps=300)


def pendulum_transitions(n: int, seed: int) -> np.ndarray:
    """[s, a, s'] of Pendulum under smooth random actions."""
    env = gym.make("Pendulum-v1")
    rng = np.random.default_rng(seed)
    obs, _ = env.reset(seed=seed)
    action, rows = np.zeros(1, dtype=np.float32), []
    while len(rows) < n:
        action = np.clip(0.9 * action + 0.5 * rng.normal(size=1), -1, 1).astype(np.float32)
        next_obs, _, terminated, truncated, _ = env.step(2 * action)
        rows.append(np.concatenate([obs, action, next_obs]))
        obs = next_obs if not (terminated or truncated) else env.reset()[0]
    return np.asarray(rows, dtype=np.float32)


def corrupt_next_states(vectors: np.ndarray, steps: float, rng: np.random.Generator) -> np.ndarray:
    """s' moved by ``steps`` typical steps (std of s' − s) in a random direction per dimension."""
    corrupted = vectors.copy()
    step_std = (vectors[:, 4:] - vectors[:, :3]).std(axis=0)
    corrupted[:, 4:] += steps * step_std * rng.choice([-1, 1], size=(len(vectors), 3))
    return corrupted


@pytest.fixture(scope="module")
def fitted():
    real = pendulum_transitions(3000, seed=0)
    dynamics = DynamicsEnsemble(3, 1, seed=0, **TINY_DYNAMICS)
    measure_fidelity(dynamics, real, real[:10], 3, 1)  # fits the ensemble
    return real, dynamics


def test_real_passes_and_corrupted_next_states_fail(fitted):
    real, dynamics = fitted
    rng = np.random.default_rng(1)
    fresh = pendulum_transitions(1000, seed=1)
    honest = measure_fidelity(dynamics, real, fresh, 3, 1, refit=False)
    corrupted = measure_fidelity(dynamics, real, corrupt_next_states(fresh, 2.0, rng), 3, 1, refit=False)
    assert honest.dynamics_error_ratio < 1.5
    assert corrupted.dynamics_error_ratio > 2.5
    # the marginal gaps barely move: they cannot see wrong dynamics (why they are not the verdict)
    assert corrupted.mean_gap < 0.2


def test_copies_of_the_buffer_are_not_novel(fitted):
    real, dynamics = fitted
    copies = real[dynamics.train_indices[:500]]
    fresh = pendulum_transitions(500, seed=2)
    assert measure_fidelity(dynamics, real, copies, 3, 1, refit=False).novelty_ratio < 0.05
    assert measure_fidelity(dynamics, real, fresh, 3, 1, refit=False).novelty_ratio > 0.5


@pytest.mark.slow
def test_heldout_anchors_are_judged_like_heldout_reals():
    """
    Near-real samples sit beside their anchors, and the ensemble fits its training rows better than held-out ones:
    copies of every real row read a dynamics_error_ratio below 1 from that alone. Samples anchored on held-out
    rows are compared like with like: copies read 1, corrupted next states still fail.
    """
    real = pendulum_transitions(150, seed=0)
    overfit = DynamicsEnsemble(3, 1, seed=0, width=128, train_steps=1000)  # few rows, many steps: over-fitted
    rows = np.arange(len(real))
    copies = measure_fidelity(overfit, real, real, 3, 1, anchors=rows)
    assert copies.dynamics_error_ratio < 0.8  # flattered by the training rows
    assert copies.heldout_anchor_error_ratio == pytest.approx(1.0, rel=1e-4)
    corrupted = corrupt_next_states(real, 2.0, np.random.default_rng(0))
    assert measure_fidelity(overfit, real, corrupted, 3, 1, refit=False, anchors=rows).heldout_anchor_error_ratio > 2.5
    assert np.isnan(measure_fidelity(overfit, real, real, 3, 1, refit=False).heldout_anchor_error_ratio)
    for bad in (rows[:10], rows + 0.5, rows + 1):  # one per sample, integers, rows of real
        with pytest.raises(ValueError, match="anchors"):
            measure_fidelity(overfit, real, real, 3, 1, refit=False, anchors=bad)


@pytest.mark.slow
def test_pride_flags_a_generator_with_corrupted_next_states(tiny_kwargs, tmp_path):
    """Every retrain logs the ratio; a generator whose s' are off by two typical steps reads far above 1."""
    ratios = {}
    for name, steps in (("faithful", 0.0), ("corrupted", 2.0)):
        kwargs = tiny_pride(generator_kwargs=dict(dynamics_kwargs=TINY_DYNAMICS))
        model = PRIDE("MlpPolicy", "Pendulum-v1", seed=0, **tiny_kwargs, **kwargs)
        rng = np.random.default_rng(0)

        def generator(real, n, steps=steps, rng=rng):  # real transitions, next states corrupted by `steps`
            anchors = rng.integers(0, len(real), size=n)
            return corrupt_next_states(real[anchors], steps, rng), anchors

        model.generator.generate = generator  # type: ignore[method-assign]
        model.set_logger(configure(str(tmp_path / name), ["csv"]))
        model.learn(800, log_interval=1)  # retrains at 300 and 600
        progress = pd.read_csv(tmp_path / name / "progress.csv")
        for key in ("dynamics_error_ratio", "heldout_anchor_error_ratio"):
            logged = progress[f"diffusion/{key}"].dropna()
            assert model.diffusion_retrains == 2 and len(logged) == 2
            ratios[name, key] = logged.to_numpy()
    # real transitions drawn back (copies) are at most as inconsistent as held-out real ones
    assert np.all(ratios["faithful", "dynamics_error_ratio"] < 1.5)
    assert np.all(ratios["corrupted", "dynamics_error_ratio"] > 2.5)
    # copies of held-out rows (drawn with replacement) read as the held-out rows do, up to sampling noise
    np.testing.assert_allclose(ratios["faithful", "heldout_anchor_error_ratio"], 1.0, rtol=0.2)
    assert np.all(ratios["corrupted", "heldout_anchor_error_ratio"] > 2.5)


def test_dimensions_that_never_change_are_left_out():
    # Meta-World's goal coordinates and zero padding: s' = s exactly. Generator noise there of 1e-6 must not read
    # as dozens of typical steps; wrong next states in the dimensions that move must still be flagged.
    rng = np.random.default_rng(3)
    goal = lambda vectors: np.insert(np.insert(vectors, 3, 0.7, axis=1), 8, 0.7, axis=1)  # noqa: E731
    real = goal(pendulum_transitions(3000, seed=0))
    dynamics = DynamicsEnsemble(4, 1, seed=0, **TINY_DYNAMICS)
    measure_fidelity(dynamics, real, real[:10], 4, 1)
    fresh = goal(pendulum_transitions(1000, seed=1))
    jittered = fresh.copy()
    jittered[:, 8] += 1e-6 * rng.normal(size=len(fresh))
    corrupted = fresh.copy()
    corrupted[:, 5:8] += 2.0 * (fresh[:, 5:8] - fresh[:, :3]).std(axis=0) * rng.choice([-1, 1], size=(len(fresh), 3))
    assert dynamics.changing.tolist() == [True, True, True, False]
    honest, jitter = (measure_fidelity(dynamics, real, x, 4, 1, refit=False) for x in (fresh, jittered))
    assert jitter.dynamics_error_ratio < 1.5
    # novelty and the marginal gaps leave the constant column out too (z-scored, the jitter would read as 1 std)
    assert jitter.novelty_ratio == pytest.approx(honest.novelty_ratio, rel=0.05) and jitter.std_gap < 0.1
    assert measure_fidelity(dynamics, real, corrupted, 4, 1, refit=False).dynamics_error_ratio > 2.5
    dynamics.changing[:] = True  # the bad case: every dimension counted, the jitter reads as a broken generator
    assert measure_fidelity(dynamics, real, jittered, 4, 1, refit=False).dynamics_error_ratio > 2.5
