import numpy as np
import pytest
import torch as th

from sb3_pride import PEBBLE, PRIDE
from sb3_pride.reward.consistency import ConsistencyModel, DynamicsConsistency
from sb3_pride.common.queries import stored_transitions
from sb3_pride.reward.ensemble import RewardEnsemble
from sb3_pride.common.utils import merge_kwargs

OBS, ACT = 8, 2


def with_consistency(kwargs: dict, settings) -> dict:
    """``kwargs`` (a test's, with TINY's ``reward_kwargs``) with REED's ``dynamics_consistency`` on."""
    return merge_kwargs(kwargs, dict(reward_kwargs=dict(dynamics_consistency=settings)))


def transitions(n: int, seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(s, a, s') of a fixed nonlinear dynamics: s' = tanh(s A + a B)."""
    rng = np.random.default_rng(seed)
    mixing = np.random.default_rng(123)
    a_matrix, b_matrix = mixing.normal(size=(OBS, OBS)) * 0.6, mixing.normal(size=(ACT, OBS))
    s = rng.normal(size=(n, OBS)).astype(np.float32)
    a = rng.uniform(-1, 1, size=(n, ACT)).astype(np.float32)
    return s, a, np.tanh(s @ a_matrix + a @ b_matrix).astype(np.float32)


def consistency_loss(model: ConsistencyModel, s: np.ndarray, a: np.ndarray, s_next: np.ndarray) -> float:
    n = model.next_state_predictor.weights[0].shape[0]
    columns = [th.as_tensor(column).unsqueeze(0).expand(n, -1, -1) for column in (s, a, s_next)]
    with th.no_grad():
        return model.loss(*columns).item() / n


def trained(s: np.ndarray, a: np.ndarray, s_next: np.ndarray) -> tuple[RewardEnsemble, ConsistencyModel]:
    th.manual_seed(0)
    reward_model = RewardEnsemble(OBS, ACT, n_members=2, net_arch=(64, 64), device="cpu")
    model = ConsistencyModel(reward_model, OBS, DynamicsConsistency(epochs=8, batch_size=64, hidden_size=64))
    model.train_epochs(s, a, s_next, np.random.default_rng(0))
    return reward_model, model


def test_consistency_learns_the_dynamics_and_a_shuffled_one_does_not():
    """After REED's pre-training on true transitions, held-out true next states are predicted far better than
    mismatched ones (shuffled s'); trained on transitions whose next states were shuffled, the encoder learns no such
    thing: the gap is the test's yardstick, and it fails on the corrupted case."""
    s, a, s_next = transitions(4000, seed=0)
    test_s, test_a, test_next = transitions(1000, seed=1)
    shuffled = test_next[np.random.default_rng(2).permutation(len(test_next))]

    _, model = trained(s, a, s_next)
    gap = consistency_loss(model, test_s, test_a, shuffled) - consistency_loss(model, test_s, test_a, test_next)

    corrupted = s_next[np.random.default_rng(3).permutation(len(s_next))]
    _, bad_model = trained(s, a, corrupted)
    bad_gap = consistency_loss(bad_model, test_s, test_a, shuffled) - consistency_loss(bad_model, test_s, test_a, test_next)
    print(f"gap {gap:.3f}, with corrupted next states {bad_gap:.3f}")
    assert gap > 0.05 and bad_gap < gap / 4, (gap, bad_gap)


def test_consistency_trains_the_encoder_never_the_reward_head_and_does_not_collapse():
    s, a, s_next = transitions(2000, seed=0)
    th.manual_seed(0)
    reward_model = RewardEnsemble(OBS, ACT, n_members=2, net_arch=(64, 64), device="cpu")
    head, first = reward_model.members.weights[-1].detach().clone(), reward_model.members.weights[0].detach().clone()
    model = ConsistencyModel(reward_model, OBS, DynamicsConsistency(epochs=2, batch_size=64))
    stepped = {id(p) for group in model.optimizer.param_groups for p in group["params"]}
    members = reward_model.members
    assert {id(p) for p in [*members.weights[:-1], *members.biases[:-1]]} <= stepped  # the encoder r̂ uses
    assert not {id(members.weights[-1]), id(members.biases[-1])} & stepped  # never the reward head
    model.train_epochs(s, a, s_next, np.random.default_rng(0))
    assert th.equal(head, reward_model.members.weights[-1])
    assert not th.equal(first, reward_model.members.weights[0])
    # the target is held fixed: no gradient reaches s' (SimSiam's stop-gradient)
    target = th.as_tensor(s_next[:64]).expand(2, -1, -1).clone().requires_grad_(True)
    model.loss(th.as_tensor(s[:64]).expand(2, -1, -1), th.as_tensor(a[:64]).expand(2, -1, -1), target).backward()
    assert target.grad is None
    with th.no_grad():  # the targets' projections still differ between states (no collapse to one point)
        embedding = reward_model.members.hidden_activation(
            th.baddbmm(reward_model.members.biases[0], th.as_tensor(s_next[:500]).expand(2, -1, -1),
                       reward_model.members.weights[0][:, :OBS])
        )  # fmt: skip
        projected = model.project(embedding)
    assert projected.std(dim=1).mean() > 0.1


@pytest.mark.parametrize(
    "bad, match",
    [
        ({"epochs": 0}, "epochs"),
        ({"optimizer": "rmsprop"}, "optimizer"),
        ({"learning_rate": -1.0}, "learning_rate"),
        ({"max_transitions": 1.5}, "max_transitions"),
        ({"steps": 3}, "unknown settings"),
        ("reed", "dynamics_consistency"),
    ],
)
def test_bad_dynamics_consistency_names_the_setting(bad, match):
    with pytest.raises(ValueError, match=match):
        PEBBLE("MlpPolicy", "Pendulum-v1", reward_kwargs=dict(dynamics_consistency=bad))


def test_pebble_with_dynamics_consistency_logs_saves_and_loads(tiny_kwargs, tmp_path):
    from stable_baselines3.common.logger import configure

    off = PEBBLE("MlpPolicy", "Pendulum-v1", **tiny_kwargs)
    assert off.reward_learner.consistency is None  # off: PEBBLE as published
    model = PEBBLE("MlpPolicy", "Pendulum-v1", seed=0, **with_consistency(tiny_kwargs, {"max_transitions": 300}))
    model.set_logger(configure(str(tmp_path), ["csv"]))
    model.learn(400, log_interval=1)
    assert model.phase.sessions == 1
    s, a, s_next = stored_transitions(model.real_buffer, np.random.default_rng(0))
    assert s.shape == s_next.shape == (400, 3) and a.shape == (400, 1)
    model.save(tmp_path / "model")
    loaded = PEBBLE.load(tmp_path / "model")
    heads, loaded_heads = model.reward_learner.consistency, loaded.reward_learner.consistency
    assert loaded_heads.members[0] is loaded.reward_model.members  # still one encoder
    for saved, kept in zip(heads.parameters(), loaded_heads.parameters(), strict=True):
        assert th.equal(saved, kept)
    # the optimizer's moments came back, and it steps the loaded encoder
    saved_state, loaded_state = (m.optimizer.state_dict()["state"] for m in (heads, loaded_heads))
    assert saved_state.keys() == loaded_state.keys() and len(saved_state) > 0
    for key in saved_state:
        assert th.equal(saved_state[key]["exp_avg"], loaded_state[key]["exp_avg"])
    # its settings may change when loading, but it cannot be turned off (nor on, for a model saved without it), nor
    # change its optimizer
    saved_kwargs = loaded.reward_kwargs

    def load_with(consistency, path="model"):
        return PEBBLE.load(tmp_path / path, reward_kwargs=dict(saved_kwargs, dynamics_consistency=consistency))

    assert load_with({"epochs": 3}).reward_learner.consistency.settings.epochs == 3
    changed = load_with({"learning_rate": 1e-4}).reward_learner.consistency  # the saved Adam had 3e-4
    changed.train_epochs(s[:10], a[:10], s_next[:10], np.random.default_rng(0))
    assert {group["lr"] for group in changed.optimizer.param_groups} == {1e-4}
    with pytest.raises(ValueError, match=r"saved with dynamics_consistency=DynamicsConsistency\(.* on or off .*\(got None\)"):
        load_with(False)
    with pytest.raises(ValueError, match=r"optimizer='adam'.* nor change its optimizer \(got .*optimizer='sgd'"):
        load_with({"optimizer": "sgd"})  # Adam's state into SGD
    PEBBLE("MlpPolicy", "Pendulum-v1", **tiny_kwargs).save(tmp_path / "plain")
    with pytest.raises(ValueError, match=r"saved with dynamics_consistency=None, and loading cannot turn it on or off"):
        load_with(True, "plain")
    stepped = {id(p) for group in loaded_heads.optimizer.param_groups for p in group["params"]}
    assert id(loaded.reward_model.members.weights[0]) in stepped
    import pandas as pd

    assert pd.read_csv(tmp_path / "progress.csv")["reward_model/consistency_loss"].notna().any()


def test_prides_consistency_pass_takes_the_real_transitions_only(tiny_kwargs):
    model = PRIDE(
        "MlpPolicy", "Pendulum-v1", seed=0,
        synthetic_start=0, synthetic_ramp=0, synthetic_samples=100, diffusion_interval=100,
        generator_kwargs=dict(width=32, n_blocks=1, train_steps=20, keep_quantile=1.0, fidelity_check=False),
        **with_consistency(tiny_kwargs, True),
    )  # fmt: skip
    model.learn(400)
    assert model.replay_buffer.synthetic.size() == 100
    passes = []
    consistency = model.reward_learner.consistency
    train_epochs = consistency.train_epochs

    def recording(s, a, s_next, rng):
        passes.append((s, s_next))
        return train_epochs(s, a, s_next, rng)

    consistency.train_epochs = recording
    model.learn_reward()  # a reward update, its consistency pass first
    [(s, s_next)] = passes
    real = model.real_buffer.size()
    assert len(s) == real  # the generator's samples teach SAC, not r̂'s encoder
    np.testing.assert_array_equal(s_next, model.real_buffer.next_observations[:real, 0])


def test_consistency_transitions_keep_each_envs_transitions_together(tiny_kwargs):
    from stable_baselines3.common.env_util import make_vec_env

    model = PEBBLE("MlpPolicy", make_vec_env("Pendulum-v1", n_envs=2, seed=0), seed=0, **with_consistency(tiny_kwargs, True))
    model.learn(200)
    s, a, s_next = stored_transitions(model.real_buffer, np.random.default_rng(0))
    buffer = model.replay_buffer
    assert len(s) == 2 * buffer.pos
    np.testing.assert_array_equal(s[1], buffer.observations[0, 1])  # row 0 of env 1
    np.testing.assert_array_equal(s_next[1], buffer.next_observations[0, 1])
    np.testing.assert_array_equal(a[1], buffer.actions[0, 1])
    # a limit draws that many (s, a, s') of them, each a stored transition whole
    s, a, s_next = stored_transitions(model.real_buffer, np.random.default_rng(0), limit=50)
    assert s.shape == (50, 3) and len(np.unique(s, axis=0)) == 50
    stored = np.concatenate([buffer.observations[: buffer.pos, e] for e in range(2)])
    stored_next = np.concatenate([buffer.next_observations[: buffer.pos, e] for e in range(2)])
    stored_actions = np.concatenate([buffer.actions[: buffer.pos, e] for e in range(2)])
    for i in range(50):
        (j,) = np.flatnonzero((stored == s[i]).all(axis=1))
        np.testing.assert_array_equal(stored_next[j], s_next[i])
        np.testing.assert_array_equal(stored_actions[j], a[i])
