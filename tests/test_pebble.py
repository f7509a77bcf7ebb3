import gymnasium as gym
import numpy as np
import pytest
import torch as th
from stable_baselines3.common.env_util import make_vec_env
from stable_baselines3.common.vec_env import VecNormalize

from sb3_pride import PEBBLE, PRIDE, PreferenceReplayBuffer
from sb3_pride.common.utils import merge_kwargs
from sb3_pride.pebble.pebble import reset_critic


class NaNReward(gym.Wrapper):
    """The true reward is NaN: if it ever reached SAC, the losses would be NaN."""

    def step(self, action):
        obs, _, terminated, truncated, info = self.env.step(action)
        return obs, float("nan"), terminated, truncated, info


@pytest.mark.slow
def test_short_run_on_dm_control(tiny_kwargs):
    model = PEBBLE("MlpPolicy", "sb3_pride/walker-walk-v0", seed=0, **tiny_kwargs)
    model.learn(1200)
    # sessions at 300 (end of pre-training), 600, 900: 20 queries each, the oracle labels all of them
    assert model.phase.sessions == 3
    assert model.phase.asked == model.phase.labeled == 60 == len(model.preferences)
    assert model.phase.next_step == 1200
    # SAC learned from r̂: every stored reward is r̂ of the final reward model
    buffer = model.replay_buffer
    n = buffer.pos
    np.testing.assert_allclose(
        buffer.rewards[:n, 0], model.reward_model.predict(buffer.observations[:n, 0], buffer.actions[:n, 0]), atol=1e-5
    )
    assert not np.allclose(buffer.rewards[:n], buffer.true_rewards[:n])
    # Monitor still reports the true return of the finished episode
    assert len(model.ep_info_buffer) == 1
    assert model.ep_info_buffer[0]["r"] == pytest.approx(buffer.true_rewards[:1000, 0].sum(), rel=1e-4)


@pytest.mark.slow
def test_short_run_on_metaworld_reports_success(tiny_kwargs):
    tiny_kwargs.update(max_feedback=40)
    model = PEBBLE("MlpPolicy", "sb3_pride/button-press-v3", seed=0, **tiny_kwargs)
    model.learn(1100)
    assert model.phase.sessions == 2 and model.phase.asked == 40
    assert len(model.ep_success_buffer) == 2  # 500-step episodes, is_success read at each end
    assert np.isfinite(model.reward_learner.correlation(model.real_buffer, np.random.default_rng(0)))


@pytest.mark.slow
def test_learner_never_sees_the_true_reward(tiny_kwargs):
    env = make_vec_env("Pendulum-v1", n_envs=2, seed=0, wrapper_class=NaNReward)
    model = PEBBLE("MlpPolicy", env, seed=0, **tiny_kwargs)
    model.learn(800)
    assert model.phase.sessions >= 1 and np.all(np.isnan(model.replay_buffer.true_rewards[:10]))
    assert np.all(np.isfinite(model.replay_buffer.rewards))
    for parameter in model.policy.parameters():
        assert th.isfinite(parameter).all()


@pytest.mark.slow
def test_pretraining_uses_state_entropy_then_r_hat(tiny_kwargs):
    model = PEBBLE("MlpPolicy", "Pendulum-v1", seed=0, **tiny_kwargs)
    model.learn(250)  # inside pre-training (ends at 300)
    assert model.replay_buffer.reward_source is model.replay_rewards
    assert model.phase.pretraining and model.replay_rewards.pretraining
    assert model.state_entropy.stats.count > 100  # r_int was computed for the SAC minibatches
    model.learn(100, reset_num_timesteps=False)
    assert not model.phase.pretraining and not model.replay_rewards.pretraining
    samples = model.replay_buffer.sample(32)
    expected = model.reward_model.predict(samples.observations.cpu().numpy(), samples.actions.cpu().numpy())
    np.testing.assert_allclose(samples.rewards.cpu().numpy().ravel(), expected, atol=1e-5)


@pytest.mark.slow
@pytest.mark.parametrize("algo", ["pebble", "pride"])
def test_critic_reset_trains_on_r_hat(tiny_kwargs, algo):
    """The reset updates after the first session (and every later update) use r̂, never r_int (B-Pref's
    update_after_reset). r_int is made 1000 per step: any of it reaching the reset would show."""
    from sb3_pride import PRIDE
    from tests.test_pride import PAPER_MIXING

    if algo == "pride":
        generator = dict(train_steps=5, sample_steps=2, width=16, n_blocks=1)
        kwargs = merge_kwargs(PAPER_MIXING, dict(synthetic_samples=256, generator_kwargs=generator))
        model = PRIDE("MlpPolicy", "Pendulum-v1", seed=0, **kwargs, **tiny_kwargs)
    else:
        model = PEBBLE("MlpPolicy", "Pendulum-v1", seed=0, **tiny_kwargs)

    def r_int(obs, all_obs, update_stats=True):
        return th.full((len(obs), 1), 1000.0, device=obs.device)

    model.replay_rewards.state_entropy = r_int  # what the replay buffer's minibatches take while pre-training
    model.diagnostic_interval = 10**9  # the critic diagnostics draw minibatches too: count SAC's updates only
    sampled: list[tuple[int, float]] = []
    sample = model.replay_buffer.sample

    def recording_sample(batch_size, env=None):
        batch = sample(batch_size, env=env)
        sampled.append((model.phase.sessions, float(batch.rewards.abs().max())))
        return batch

    model.replay_buffer.sample = recording_sample
    model.learn(350)  # the first session at step 300, then 50 more steps
    pretraining = [reward for sessions, reward in sampled if sessions == 0]
    after = [reward for sessions, reward in sampled if sessions > 0]
    assert pretraining and min(pretraining) == 1000.0
    # 10 reset updates + the session step's own update + 50 later ones, all on r̂ (tanh-bounded)
    assert len(after) == tiny_kwargs["pretraining_kwargs"]["critic_reset_updates"] + 51
    assert max(after) <= 1.0
    with th.no_grad():
        batch = sample(64)
        q_values = th.cat(model.critic(batch.observations, batch.actions))
    assert q_values.abs().max() < 50  # r_int would have pushed Q far above r̂'s scale


def test_critic_reset_keeps_actor(tiny_kwargs):
    model = PEBBLE("MlpPolicy", "Pendulum-v1", seed=0, **tiny_kwargs)
    model.learn(250)
    actor = [p.clone() for p in model.actor.parameters()]
    critic = [p.clone() for p in model.critic.parameters()]
    reset_critic(model)
    assert all(th.equal(a, b) for a, b in zip(actor, model.actor.parameters(), strict=True))
    assert not any(th.equal(a, b) for a, b in zip(critic, model.critic.parameters(), strict=True))
    for p, q in zip(model.critic.parameters(), model.critic_target.parameters(), strict=True):
        assert th.equal(p, q)
    assert len(model.critic.optimizer.state) == 0


@pytest.mark.slow
def test_save_load_round_trip_and_continue(tiny_kwargs, tmp_path):
    model = PEBBLE("MlpPolicy", "Pendulum-v1", seed=0, **tiny_kwargs)
    model.learn(700)
    model.save(tmp_path / "pebble")
    model.save_replay_buffer(tmp_path / "buffer")
    loaded = PEBBLE.load(tmp_path / "pebble", env=make_vec_env("Pendulum-v1", n_envs=1))
    obs = np.random.default_rng(0).normal(size=(64, 3)).astype(np.float32)
    actions = np.random.default_rng(1).uniform(-1, 1, size=(64, 1)).astype(np.float32)
    np.testing.assert_array_equal(loaded.reward_model.predict(obs, actions), model.reward_model.predict(obs, actions))
    np.testing.assert_array_equal(loaded.preferences.inputs, model.preferences.inputs)
    np.testing.assert_array_equal(loaded.preferences.labels, model.preferences.labels)
    assert (loaded.phase.asked, loaded.phase.sessions) == (model.phase.asked, model.phase.sessions)
    np.testing.assert_array_equal(loaded.predict(obs, deterministic=True)[0], model.predict(obs, deterministic=True)[0])

    loaded.load_replay_buffer(tmp_path / "buffer")
    assert isinstance(loaded.replay_buffer, PreferenceReplayBuffer)
    assert loaded.replay_buffer.reward_source is loaded.replay_rewards and loaded.replay_rewards.learned
    loaded.learn(300, reset_num_timesteps=False)
    assert loaded.num_timesteps == 1000
    assert loaded.phase.sessions == 3 and loaded.phase.asked == 60


def test_bad_input_names_the_parameter(tiny_kwargs):
    import shimmy

    gym.register_envs(shimmy)
    with pytest.raises(ValueError, match=r"Dict observation space.*flatten"):
        PEBBLE("MlpPolicy", gym.make("dm_control/cartpole-balance-v0"))
    with pytest.raises(ValueError, match="action space"):
        PEBBLE("MlpPolicy", "CartPole-v1")
    with pytest.raises(ValueError, match="segment_length=300"):
        PEBBLE("MlpPolicy", "Pendulum-v1", segment_length=300)
    for name in ("max_feedback", "feedback_interval", "queries_per_session", "segment_length"):
        for bad in (0, -5):
            with pytest.raises(ValueError, match=name):
                PEBBLE("MlpPolicy", "Pendulum-v1", **{name: bad})
    for bad in (1.5, "1", True):
        with pytest.raises(ValueError, match="gradient_steps must be an integer"):
            PEBBLE("MlpPolicy", "Pendulum-v1", gradient_steps=bad)
    with pytest.raises(ValueError, match="query_selection"):
        PEBBLE("MlpPolicy", "Pendulum-v1", query_selection="random")
    with pytest.raises(ValueError, match="teacher"):
        PEBBLE("MlpPolicy", "Pendulum-v1", teacher="perfect")
    with pytest.raises(ValueError, match="norm_reward"):
        PEBBLE("MlpPolicy", VecNormalize(make_vec_env("Pendulum-v1"), norm_reward=True))
    PEBBLE("MlpPolicy", VecNormalize(make_vec_env("Pendulum-v1"), norm_reward=False), **tiny_kwargs)


def test_the_reward_learner_holds_each_options_settings(tiny_kwargs):
    from sb3_pride.reward.consistency import DynamicsConsistency

    kwargs = merge_kwargs(tiny_kwargs, dict(reward_kwargs=dict(dynamics_consistency={"epochs": 3})))
    model = PEBBLE("MlpPolicy", "Pendulum-v1", **kwargs)
    learner = model.reward_learner
    assert isinstance(learner.consistency.settings, DynamicsConsistency) and learner.consistency.settings.epochs == 3
    assert learner.label_selection is None and learner.pseudo_labels is None and learner.exploration_bonus is None
    assert learner.ensemble is model.reward_model
    # {}: on, at its defaults
    model = PEBBLE("MlpPolicy", "Pendulum-v1", **merge_kwargs(tiny_kwargs, dict(reward_kwargs=dict(dynamics_consistency={}))))
    assert model.reward_learner.consistency.settings == DynamicsConsistency()
    with pytest.raises(ValueError, match=r"reward_kwargs: unknown settings \['consistency'\].*dynamics_consistency"):
        PEBBLE("MlpPolicy", "Pendulum-v1", **merge_kwargs(tiny_kwargs, dict(reward_kwargs=dict(consistency={}))))


def test_a_name_of_earlier_versions_is_a_type_error_that_names_its_new_place(tiny_kwargs):
    """The flat names of 0.1.0 and 0.2.0 are refused by the constructor, each error naming the setting's new place; a
    keyword PEBBLE never had is named as unknown."""
    with pytest.raises(TypeError, match=r"reward_epochs is now reward_kwargs=\{'epochs': \.\.\.\}"):
        PEBBLE("MlpPolicy", "Pendulum-v1", reward_epochs=7, learning_starts=100)
    with pytest.raises(TypeError, match=r"hybrid_replay is now query_kwargs=\{'hybrid_replay': \.\.\.\}"):
        PEBBLE("MlpPolicy", "Pendulum-v1", hybrid_replay=0.5, **tiny_kwargs)
    with pytest.raises(TypeError, match="PEBBLE takes no reward_epoch"):
        PEBBLE("MlpPolicy", "Pendulum-v1", reward_epoch=7)
    with pytest.raises(TypeError, match=r"diffusion_width is now generator_kwargs=\{'width': \.\.\.\}"):
        PRIDE("MlpPolicy", "Pendulum-v1", diffusion_width=64)


@pytest.mark.parametrize("algo, name", [(PEBBLE, "pebble_0.2.0.zip"), (PRIDE, "pride_0.1.0.zip")])
def test_a_model_saved_by_an_earlier_version_is_refused_naming_the_version_that_reads_it(algo, name, tmp_path):
    """Models saved by 0.1.0 and 0.2.0 hold their settings flat: load() refuses them before anything is made, with a
    message naming the version that reads them; their journals are read by this version (prior_preferences)."""
    from pathlib import Path

    path = Path(__file__).parent / "data" / name
    with pytest.raises(ValueError, match=r"saved by sb3_pride 0\.1 or 0\.2.*sb3_pride==0\.2\.0.*prior_preferences"):
        algo.load(path, env=gym.make("Pendulum-v1"))
    with pytest.raises(ValueError, match=r"saved by sb3_pride 0\.1 or 0\.2"):
        algo.load(str(path).removesuffix(".zip"))  # as SB3 finds it, ".zip" added


def test_a_custom_teacher_is_checked(tiny_kwargs):
    def teacher(pairs):
        return np.full(len(pairs), 2.0)

    model = PEBBLE("MlpPolicy", "Pendulum-v1", teacher=teacher, **tiny_kwargs)
    with pytest.raises(ValueError, match="teacher labels"):
        model.learn(400)


@pytest.mark.slow
@pytest.mark.parametrize("algo", ["pebble", "pride"])
def test_gradient_steps_zero_collects_and_a_users_loop_trains(tiny_kwargs, algo):
    """SB3's gradient_steps=0: learn() collects and runs the feedback sessions but never calls train(); the user's own
    loop does, through the same public methods the callbacks use."""
    from sb3_pride import PRIDE
    from tests.test_pride import TINY_DIFFUSION

    extra = TINY_DIFFUSION if algo == "pride" else {}
    model = (PRIDE if algo == "pride" else PEBBLE)("MlpPolicy", "Pendulum-v1", seed=0, gradient_steps=0, **tiny_kwargs,
                                                    **extra)  # fmt: skip
    actor = [p.detach().clone() for p in model.actor.parameters()]
    model.learn(400)
    assert model.phase.sessions == 1 and model._n_updates == 0  # the critic reset's updates only touch the critic
    assert all(th.equal(p, q) for p, q in zip(actor, model.actor.parameters(), strict=True))
    model.train(gradient_steps=5, batch_size=32)
    assert model._n_updates == 5 and not all(th.equal(p, q) for p, q in zip(actor, model.actor.parameters(), strict=True))
    assert model.publish_queries(asynchronous=False)  # a session called from the user's loop
    model.take_answers()
    assert model.phase.sessions == 2
    if algo == "pride":
        retrains = model.diffusion_retrains
        report = model.retrain_generator()
        assert model.diffusion_retrains == retrains + 1 and model.replay_buffer.synthetic.size() == len(report.vectors)


def test_structured_settings_given_to_load_change_the_saved_ones_entry_by_entry(tiny_kwargs, tmp_path):
    """load(reward_kwargs=...) keeps the saved entries it does not name; an old flat name is refused, naming its place."""
    kwargs = merge_kwargs(tiny_kwargs, dict(reward_kwargs=dict(dynamics_consistency=dict(epochs=1, max_transitions=100))))
    PEBBLE("MlpPolicy", "Pendulum-v1", seed=0, **kwargs).save(tmp_path / "model")
    loaded = PEBBLE.load(tmp_path / "model", reward_kwargs=dict(epochs=7))
    assert loaded.reward_kwargs["epochs"] == 7 and tuple(loaded.reward_kwargs["net_arch"]) == (32, 32)
    assert loaded.reward_learner.consistency is not None
    with pytest.raises(ValueError, match="loading cannot turn it on or off"):
        PEBBLE.load(tmp_path / "model", reward_kwargs=dict(dynamics_consistency=False))
    with pytest.raises(TypeError, match=r"dynamics_consistency is now reward_kwargs"):
        PEBBLE.load(tmp_path / "model", dynamics_consistency=False)


def test_robust_labels_and_consistency_both_survive_a_save_and_load(tiny_kwargs, tmp_path):
    """RIME's running selection is the reward learner's data and REED's heads its weights: both are saved."""
    options = dict(
        robust_labels=True, dynamics_consistency=dict(epochs=1, max_transitions=100, projection_size=8, hidden_size=8)
    )
    model = PEBBLE("MlpPolicy", "Pendulum-v1", seed=0, **merge_kwargs(tiny_kwargs, dict(reward_kwargs=options)))
    model.learn(650)
    selection = model.reward_learner.label_selection
    assert selection.epochs > 0
    model.save(tmp_path / "model")
    loaded = PEBBLE.load(tmp_path / "model")
    assert loaded.reward_learner.label_selection.epochs == selection.epochs
    assert loaded.reward_learner.label_selection.beta == selection.beta
    for saved, restored in zip(model.consistency_model.parameters(), loaded.consistency_model.parameters(), strict=True):
        assert th.equal(saved, restored)
