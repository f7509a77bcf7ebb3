"""RUNE's exploration bonus: r̂ + β_t · σ on SAC's minibatches, from the first feedback session on."""

import math

import gymnasium as gym
import numpy as np
import pytest
import torch as th
from stable_baselines3.common.save_util import load_from_pkl

from sb3_pride import PEBBLE, PRIDE
from sb3_pride.reward.options import ExplorationBonus
from sb3_pride.common.utils import merge_kwargs


def with_bonus(kwargs: dict, settings) -> dict:
    """``kwargs`` (a test's, with TINY's ``reward_kwargs``) with RUNE's ``exploration_bonus`` on."""
    return merge_kwargs(kwargs, dict(reward_kwargs=dict(exploration_bonus=settings)))


def test_settings_are_runes_and_decay_with_the_steps():
    bonus = ExplorationBonus()
    assert (bonus.beta_init, bonus.beta_decay) == (0.05, 1e-5)
    assert bonus.beta(0) == 0.05
    assert bonus.beta(100_000) == pytest.approx(0.05 * math.exp(-1), rel=1e-4)
    assert ExplorationBonus(beta_decay=0.0).beta(10**6) == 0.05


@pytest.mark.parametrize(
    "bad, name",
    [
        (0.0, "exploration_bonus must be True, False or a dict"),
        ({"beta_init": 0.0}, "beta_init"),
        ({"beta_init": float("nan")}, "beta_init"),
        ({"beta_init": True}, "beta_init"),
        ({"beta_decay": 1.0}, "beta_decay"),
        ({"beta_decay": -1e-5}, "beta_decay"),
        ({"beta": 0.1}, "unknown settings"),
    ],
)
def test_bad_settings_are_refused_by_name(bad, name):
    with pytest.raises(ValueError, match=name):
        PEBBLE("MlpPolicy", "Pendulum-v1", reward_kwargs=dict(exploration_bonus=bad))


def test_one_member_has_no_disagreement_to_explore():
    with pytest.raises(ValueError, match="exploration_bonus needs ensemble_size >= 2"):
        PEBBLE("MlpPolicy", "Pendulum-v1", reward_kwargs=dict(exploration_bonus=True, ensemble_size=1))
    PEBBLE("MlpPolicy", "Pendulum-v1", reward_kwargs=dict(ensemble_size=1))  # without it, one member is PEBBLE's business


def sampled_rewards(model, batch_size=64, seed=0, bonus=True):
    """A minibatch as SAC draws it, with RUNE's bonus where it is on, or without it (``bonus=False``)."""
    state, options = np.random.get_state(), model.reward_learner.options
    np.random.seed(seed)
    off = None if bonus else options.pop("exploration_bonus", None)  # the option off for this minibatch
    samples = model.replay_buffer.sample(batch_size, env=model._vec_normalize_env)
    if off is not None:
        options["exploration_bonus"] = off
    np.random.set_state(state)
    return samples


def expected_bonus(model, samples):
    """β_t times RUNE's σ: NumPy's std over the members' r̂ (divided by the number of members)."""
    obs, actions = samples.observations.cpu().numpy(), samples.actions.cpu().numpy()
    inputs = th.as_tensor(np.concatenate([obs, actions], axis=-1), device=model.device)
    members = np.stack([model.reward_model(inputs)[m].detach().cpu().numpy() for m in range(model.reward_model.n_members)])
    option = model.reward_kwargs["exploration_bonus"]
    settings = option if isinstance(option, dict) else {}
    return th.as_tensor(ExplorationBonus(**settings).beta(model.num_timesteps) * members.std(axis=0), device=model.device)


def test_pebble_adds_the_ensembles_disagreement_after_pretraining(tiny_kwargs):
    plain = PEBBLE("MlpPolicy", "Pendulum-v1", seed=0, **tiny_kwargs)
    plain.learn(350)
    assert plain.reward_learner.exploration_bonus is None and not plain.replay_rewards.bonus_active  # off: as published

    model = PEBBLE("MlpPolicy", "Pendulum-v1", seed=0, **with_bonus(tiny_kwargs, {"beta_init": 0.5}))
    model.learn(250)  # still pre-training on the state entropy: no bonus
    assert model.phase.pretraining and not model.replay_rewards.bonus_active
    model.learn(200, reset_num_timesteps=False)
    assert not model.phase.pretraining and model.replay_rewards.bonus_active
    with_it = sampled_rewards(model)
    without = sampled_rewards(model, bonus=False)
    th.testing.assert_close(with_it.observations, without.observations)  # the same rows
    added = with_it.rewards - without.rewards
    th.testing.assert_close(added, expected_bonus(model, without))
    assert (added > 0).all() and added.shape == without.rewards.shape
    # the stored rewards stay r̂
    np.testing.assert_allclose(
        model.replay_buffer.rewards[:10, 0],
        model.reward_model.predict(model.replay_buffer.observations[:10, 0], model.replay_buffer.actions[:10, 0]),
        rtol=1e-5,
        atol=1e-6,
    )


def test_pride_adds_it_to_synthetic_rows_too_and_saves_without_it(tiny_kwargs, tmp_path):
    model = PRIDE(
        "MlpPolicy", "Pendulum-v1", seed=0, synthetic_start=0, synthetic_ramp=0,
        synthetic_samples=100, diffusion_interval=100,
        generator_kwargs=dict(width=32, n_blocks=1, train_steps=20, keep_quantile=1.0, fidelity_check=False),
        **with_bonus(tiny_kwargs, True),
    )  # fmt: skip
    model.learn(250)
    assert model.phase.pretraining and not model.replay_rewards.bonus_active
    model.learn(150, reset_num_timesteps=False)
    assert model.replay_buffer.synthetic.size() > 0 and model.replay_rewards.bonus_active
    # one reward source, the real part's: it rewrites the whole minibatch once, synthetic rows included
    assert model.replay_buffer.real.reward_source is model.replay_rewards
    with_it = sampled_rewards(model)
    without = sampled_rewards(model, bonus=False)
    n_synthetic = model.replay_buffer.n_synthetic(64)
    assert 0 < n_synthetic < 64
    th.testing.assert_close(with_it.rewards - without.rewards, expected_bonus(model, without))
    model.save(tmp_path / "model")
    model.save_replay_buffer(tmp_path / "buffer")
    assert load_from_pkl(tmp_path / "buffer").real.reward_source is None  # saved without it
    loaded = PRIDE.load(tmp_path / "model", env=gym.make("Pendulum-v1"))
    loaded.load_replay_buffer(tmp_path / "buffer")
    assert loaded.reward_kwargs["exploration_bonus"] is True and loaded.reward_learner.exploration_bonus is not None
    assert loaded.replay_buffer.real.reward_source is loaded.replay_rewards
    loaded.learn(10, reset_num_timesteps=False)
    assert loaded.replay_rewards.bonus_active


def test_buffers_pickled_before_the_reward_source_existed_still_sample(tiny_kwargs):
    import pickle

    model = PRIDE("MlpPolicy", "Pendulum-v1", seed=0, **tiny_kwargs)
    model.learn(150)
    real = model.replay_buffer.real
    # as an older version pickled them: hooks of their own, no reward_source
    real.__dict__.pop("reward_source", None)
    real.__dict__.update(reward_fn=None, intrinsic_reward=None, reward_bonus=None, recent_share=0.0, recent_rows=None)
    model.replay_buffer.__dict__["reward_bonus"] = None
    loaded = pickle.loads(pickle.dumps(model.replay_buffer))
    assert loaded.real.reward_source is None
    assert loaded.sample(8).rewards.shape == (8, 1) and loaded.real.sample(8).rewards.shape == (8, 1)
