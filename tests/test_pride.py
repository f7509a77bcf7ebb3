import numpy as np
import pytest
import torch as th
from gymnasium import spaces
from stable_baselines3.common.env_util import make_vec_env

from sb3_pride import PEBBLE, PRIDE, DualReplayBuffer

#: a diffusion model small enough for tests
TINY_DIFFUSION = dict(
    diffusion_interval=300,
    synthetic_samples=2000,
    diffusion_width=64,
    diffusion_blocks=2,
    diffusion_train_steps=200,
    diffusion_sample_steps=8,
)


def marked_dual_buffer(n_envs=2, ratio=0.25):
    """Real observations are +1, synthetic ones -1, so a minibatch tells where each row came from."""
    space = spaces.Box(-np.inf, np.inf, (3,), np.float32)
    buffer = DualReplayBuffer(200, space, spaces.Box(-1, 1, (2,)), n_envs=n_envs, synthetic_buffer_size=500, synthetic_ratio=ratio)
    for _ in range(50):
        obs = np.ones((n_envs, 3), np.float32)
        buffer.add(obs, obs, np.zeros((n_envs, 2)), np.ones(n_envs), np.zeros(n_envs), [{}] * n_envs)
    return buffer


def test_dual_buffer_mixes_exact_counts_and_falls_back_to_real():
    buffer = marked_dual_buffer()
    assert (buffer.sample(64).observations[:, 0] == 1).all()  # synthetic part empty: all real
    n = 300
    buffer.synthetic.replace(-np.ones((n, 3)), np.zeros((n, 2)), -np.ones((n, 3)), np.zeros(n), np.full(n, 7.0))
    for batch_size in (64, 100, 7, 1):
        marks = buffer.sample(batch_size).observations[:, 0]
        assert int((marks == -1).sum()) == round(0.25 * batch_size) and len(marks) == batch_size
    buffer.synthetic_ratio = 1.0
    assert (buffer.sample(32).observations[:, 0] == -1).all()
    assert buffer.size() == 50 and buffer.pos == 50 and buffer.real.size() == 50


def test_synthetic_replace_and_extend_wrap_the_ring():
    buffer = marked_dual_buffer()
    synthetic = buffer.synthetic
    rows = np.arange(700, dtype=np.float32)[:, None].repeat(3, axis=1)
    synthetic.replace(rows, np.zeros((700, 2)), rows, np.zeros(700), np.zeros(700))
    assert synthetic.full and synthetic.size() == 500
    assert set(synthetic.observations[:, 0, 0]) == set(range(200, 700))  # the last 500 kept
    synthetic.replace(rows[:10], np.zeros((10, 2)), rows[:10], np.zeros(10), np.zeros(10))
    assert synthetic.size() == 10 and not synthetic.full


def test_short_run_on_dm_control_with_two_envs(tiny_kwargs, tmp_path):
    env = make_vec_env("sb3_pride/walker-walk-v0", n_envs=2, seed=0)
    model = PRIDE("MlpPolicy", env, seed=0, gradient_steps=2, **tiny_kwargs, **TINY_DIFFUSION)
    model.learn(1000)
    # retrains right after the first reward learning (step 300), then every 300 steps
    assert model.diffusion_retrains == 3 and model.next_diffusion_step == 1200
    buffer = model.replay_buffer
    assert buffer.synthetic.size() == 2000
    assert buffer.n_synthetic(model.batch_size) == 32  # u = 0.5 of 64
    # synthetic rewards are r̂ of the current reward model, actions within bounds
    synthetic = buffer.synthetic
    np.testing.assert_allclose(
        synthetic.rewards[:, 0],
        model.reward_model.predict(synthetic.observations[:, 0], synthetic.actions[:, 0]),
        atol=1e-5,
    )
    assert np.abs(synthetic.actions).max() <= 1.0 and model.model_terminals is False

    # the replay buffer round-trips through SB3's save/load_replay_buffer
    model.save(tmp_path / "pride")
    model.save_replay_buffer(tmp_path / "buffer")
    loaded = PRIDE.load(tmp_path / "pride", env=make_vec_env("sb3_pride/walker-walk-v0", n_envs=2))
    loaded.load_replay_buffer(tmp_path / "buffer")
    assert isinstance(loaded.replay_buffer, DualReplayBuffer)
    np.testing.assert_array_equal(loaded.replay_buffer.synthetic.observations, synthetic.observations)
    np.testing.assert_array_equal(loaded.replay_buffer.real.true_rewards, buffer.real.true_rewards)
    loaded.learn(200, reset_num_timesteps=False)
    assert loaded.diffusion_retrains == 4


def test_synthetic_rewards_follow_each_relabel(tiny_kwargs):
    model = PRIDE("MlpPolicy", "Pendulum-v1", seed=0, **tiny_kwargs, **TINY_DIFFUSION)
    model.learn(400)
    synthetic = model.replay_buffer.synthetic
    before = synthetic.rewards.copy()
    with th.no_grad():  # a reward update
        for parameter in model.reward_model.parameters():
            parameter.add_(0.1)
    model.relabel()
    assert not np.allclose(before, synthetic.rewards)
    np.testing.assert_allclose(
        synthetic.rewards[:, 0], model.reward_model.predict(synthetic.observations[:, 0], synthetic.actions[:, 0]), atol=1e-5
    )


def test_ratio_zero_trains_exactly_like_pebble(tiny_kwargs):
    pebble = PEBBLE("MlpPolicy", "Pendulum-v1", seed=3, **tiny_kwargs).learn(700)
    pride = PRIDE("MlpPolicy", "Pendulum-v1", seed=3, synthetic_ratio=0.0, **tiny_kwargs, **TINY_DIFFUSION).learn(700)
    assert pride.diffusion_retrains == 0 and pride.replay_buffer.synthetic.size() == 0
    for p, q in zip(pebble.policy.parameters(), pride.policy.parameters()):
        assert th.equal(p, q)
    np.testing.assert_array_equal(pebble.replay_buffer.rewards, pride.replay_buffer.real.rewards)


def test_save_load_predict_identical(tiny_kwargs, tmp_path):
    model = PRIDE("MlpPolicy", "Pendulum-v1", seed=0, **tiny_kwargs, **TINY_DIFFUSION).learn(400)
    model.save(tmp_path / "pride")
    loaded = PRIDE.load(tmp_path / "pride")
    obs = np.random.default_rng(0).normal(size=(32, 3)).astype(np.float32)
    np.testing.assert_array_equal(loaded.predict(obs, deterministic=True)[0], model.predict(obs, deterministic=True)[0])
    for name, tensor in model.diffusion.state_dict().items():
        assert th.equal(tensor, loaded.diffusion.state_dict()[name]), name
    assert loaded.synthetic_ratio == 0.5 and loaded.diffusion_interval == 300


def test_short_run_on_metaworld(tiny_kwargs):
    tiny_kwargs.update(max_feedback=40)
    model = PRIDE("MlpPolicy", "sb3_pride/button-press-v3", seed=0, **tiny_kwargs, **TINY_DIFFUSION)
    model.learn(700)
    assert model.diffusion_retrains == 2 and model.replay_buffer.synthetic.size() == 2000
    assert len(model.ep_success_buffer) == 1


def test_bad_input_names_the_parameter():
    with pytest.raises(ValueError, match="synthetic_ratio"):
        PRIDE("MlpPolicy", "Pendulum-v1", synthetic_ratio=1.5)
    for name in ("diffusion_interval", "synthetic_samples", "diffusion_train_steps"):
        with pytest.raises(ValueError, match=name):
            PRIDE("MlpPolicy", "Pendulum-v1", **{name: 0})
