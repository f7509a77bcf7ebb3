import numpy as np
import pytest

from sb3_pride import TEACHER_PRESETS, ScriptedTeacher
from sb3_pride.common.queries import SegmentPairs
from sb3_pride.common.teachers import make_teacher


def random_pairs(n, k=10, scale=1.0, seed=0):
    rng = np.random.default_rng(seed)
    rewards = rng.random((n, 2, k))
    return SegmentPairs(np.zeros((n, 2, k, 3)), np.zeros((n, 2, k, 1)), rewards, return_scale=scale)


def rational_labels(pairs):
    returns = pairs.true_rewards.sum(-1)
    return (returns[:, 1] > returns[:, 0]).astype(float)


def test_oracle_prefers_larger_return():
    pairs = random_pairs(1000)
    assert np.array_equal(ScriptedTeacher.from_preset("oracle")(pairs), rational_labels(pairs))


def test_mistake_rate_is_epsilon():
    pairs = random_pairs(40_000)
    labels = ScriptedTeacher.from_preset("mistake", seed=1)(pairs)
    rate = np.mean(labels != rational_labels(pairs))
    assert abs(rate - 0.1) < 0.01


def test_noisy_teacher_follows_bradley_terry():
    # every pair has return gap exactly 1: P[σ1 ≻ σ0] = sigmoid(β · 1) with β = 1
    n, k = 40_000, 4
    rewards = np.zeros((n, 2, k))
    rewards[:, 1, 0] = 1.0
    pairs = SegmentPairs(np.zeros((n, 2, k, 1)), np.zeros((n, 2, k, 1)), rewards)
    labels = ScriptedTeacher.from_preset("noisy", seed=2)(pairs)
    assert abs(labels.mean() - 1 / (1 + np.exp(-1.0))) < 0.01


def test_myopic_weights_and_decision():
    teacher = ScriptedTeacher.from_preset("myopic")
    np.testing.assert_allclose(teacher.step_weights(4), [0.9**3, 0.9**2, 0.9, 1.0])
    # σ0 earns 1.0 at the first step, σ1 0.95 at the last: the oracle prefers σ0, the myopic teacher σ1
    rewards = np.zeros((1, 2, 5))
    rewards[0, 0, 0], rewards[0, 1, -1] = 1.0, 0.95
    pairs = SegmentPairs(np.zeros((1, 2, 5, 1)), np.zeros((1, 2, 5, 1)), rewards)
    assert ScriptedTeacher.from_preset("oracle")(pairs)[0] == 0.0
    assert teacher(pairs)[0] == 1.0


def test_skip_threshold_scales_with_return_scale():
    n, k = 200, 5
    best = np.linspace(0.0, 2.0, n)  # the better segment's return
    rewards = np.zeros((n, 2, k))
    rewards[:, 0, 0] = best
    rewards[:, 1, 0] = best / 2
    teacher = ScriptedTeacher.from_preset("skip")  # ε_skip = 0.1
    labels = teacher(SegmentPairs(np.zeros((n, 2, k, 1)), np.zeros((n, 2, k, 1)), rewards, return_scale=10.0))
    # threshold = 0.1 × 10 = 1.0, applied once (B-Pref applies ε twice after the first session)
    np.testing.assert_array_equal(np.isnan(labels), best <= 1.0)
    assert np.all(labels[~np.isnan(labels)] == 0.0)


def test_equal_threshold_gives_half():
    n, k = 200, 5
    gap = np.linspace(0.0, 1.0, n)
    rewards = np.zeros((n, 2, k))
    rewards[:, 0, 0] = 5.0
    rewards[:, 1, 0] = 5.0 + gap
    labels = ScriptedTeacher.from_preset("equal")(
        SegmentPairs(np.zeros((n, 2, k, 1)), np.zeros((n, 2, k, 1)), rewards, return_scale=4.0)
    )
    np.testing.assert_array_equal(labels == 0.5, gap < 0.4)
    assert np.all(labels[gap >= 0.4] == 1.0)


def test_presets_and_bad_input():
    assert set(TEACHER_PRESETS) == {"oracle", "mistake", "noisy", "skip", "myopic", "equal"}
    with pytest.raises(ValueError, match="teacher"):
        make_teacher("perfect")
    with pytest.raises(ValueError, match="eps_mistake"):
        ScriptedTeacher(eps_mistake=1.5)
    with pytest.raises(ValueError, match="beta"):
        ScriptedTeacher(beta=0.0)


def test_a_registered_teacher_is_made_from_its_name_and_saved_as_a_name(tiny_kwargs, tmp_path):
    """A teacher registered by name (here one that cannot be pickled: it holds a lock) is made again when loaded."""
    import threading

    from sb3_pride import PEBBLE
    from sb3_pride.common.teachers import TEACHERS, register_teacher

    class Judge:
        def __init__(self, seed):
            self.lock, self.seed = threading.Lock(), seed

        def __call__(self, pairs):
            return (pairs.true_rewards.sum(-1)[:, 1] > pairs.true_rewards.sum(-1)[:, 0]).astype(float)

    register_teacher("judge", Judge)
    try:
        model = PEBBLE("MlpPolicy", "Pendulum-v1", seed=4, teacher="judge", **tiny_kwargs).learn(400)
        assert model.phase.labeled > 0 and model.feedback.resolve(model.teacher, model.seed).seed == 4
        model.save(tmp_path / "model")
        loaded = PEBBLE.load(tmp_path / "model")
        assert loaded.teacher == "judge" and isinstance(loaded.feedback.resolve(loaded.teacher, loaded.seed), Judge)
    finally:
        TEACHERS.pop("judge")
    with pytest.raises(ValueError, match="factory must be callable"):
        register_teacher("judge", "not a factory")


def test_only_a_subclass_is_an_interactive_teacher(tiny_kwargs):
    """A callable that happens to have `attach` and `ask` attributes is a plain Teacher: called, and journaled."""
    from sb3_pride import PEBBLE
    from sb3_pride.common.teachers import InteractiveTeacher, make_teacher

    oracle = make_teacher("oracle")

    class Lookalike:
        attach = ask = None

        def __call__(self, pairs):
            return oracle(pairs)

    assert not isinstance(Lookalike(), InteractiveTeacher)
    model = PEBBLE("MlpPolicy", "Pendulum-v1", seed=0, teacher=Lookalike(), **tiny_kwargs).learn(400)
    assert model.phase.asked > 0
    with pytest.raises(TypeError):
        InteractiveTeacher()  # abstract: attach and ask must be written
