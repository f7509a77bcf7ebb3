import numpy as np
import pytest
import torch as th
from gymnasium import spaces
from stable_baselines3.common.env_util import make_vec_env

from sb3_pride import PEBBLE, PRIDE, DualReplayBuffer
from sb3_pride.common.utils import merge_kwargs
from sb3_pride.pride import PAPER_RECIPE, PRIDE_REWARD_DEFAULTS

# the paper's mixing (PRIDE()'s defaults delay it to step 10k): synthetic data from the first reward model on, every
# sample kept, fitted on all real transitions
PAPER_MIXING = dict(
    synthetic_ratio=0.5,
    synthetic_on_top=False,
    synthetic_start=0,
    synthetic_ramp=0,
    generator_kwargs=dict(window=None, keep_quantile=1.0),
)
#: PRIDE with a diffusion model small enough for tests
TINY_DIFFUSION = merge_kwargs(
    PAPER_MIXING,
    dict(
        diffusion_interval=300,
        synthetic_samples=2000,
        generator_kwargs=dict(width=64, n_blocks=2, train_steps=200, sample_steps=8),
    ),
)


def tiny_pride(**changes):
    """``TINY_DIFFUSION`` with ``changes`` (``generator_kwargs`` merged, not replaced)."""
    return merge_kwargs(TINY_DIFFUSION, changes)


def with_prides_reward_learning(kwargs):
    """PEBBLE's ``kwargs`` with PRIDE's label schedule and reward learning (REED's consistency), PRIDE's defaults."""
    return {
        **kwargs,
        "feedback_schedule": "front_loaded",
        "reward_kwargs": {**kwargs["reward_kwargs"], **PRIDE_REWARD_DEFAULTS},
    }


def marked_dual_buffer(n_envs=2, ratio=0.25):
    """Real observations are +1, synthetic ones -1, so a minibatch tells where each row came from."""
    space = spaces.Box(-np.inf, np.inf, (3,), np.float32)
    buffer = DualReplayBuffer(
        200, space, spaces.Box(-1, 1, (2,)), n_envs=n_envs, synthetic_buffer_size=500, synthetic_ratio=ratio
    )
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


@pytest.mark.slow
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
    assert loaded.diffusion_retrains == 3  # the retrain due at step 1200, the last of this learn(), waits for the next
    loaded.learn(2, reset_num_timesteps=False)
    assert loaded.diffusion_retrains == 4 and loaded.next_diffusion_step == 1502


@pytest.mark.slow
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


def test_prides_defaults_are_pebbles_with_half_the_labels_front_loaded_and_reeds_consistency():
    pride, pebble = PRIDE("MlpPolicy", "Pendulum-v1"), PEBBLE("MlpPolicy", "Pendulum-v1")
    assert 2 * pride.max_feedback == pebble.max_feedback
    assert (pride.feedback_schedule, pebble.feedback_schedule) == ("front_loaded", "constant")
    assert pride.reward_kwargs == PRIDE_REWARD_DEFAULTS and pride.reward_learner.consistency.settings.epochs == 5
    assert pebble.reward_learner.consistency is None
    assert pride.synthetic_ratio == 0.25 and pride.generator.diffusion_options["train_steps"] == 2000
    # a setting given goes on top of PRIDE's reward learning; the paper's recipe is PEBBLE's reward learning
    given = PRIDE("MlpPolicy", "Pendulum-v1", reward_kwargs=dict(epochs=10))
    assert given.reward_kwargs == {**PRIDE_REWARD_DEFAULTS, "epochs": 10}
    paper = PRIDE("MlpPolicy", "Pendulum-v1", **PAPER_RECIPE)
    assert paper.reward_learner.consistency is None and paper.feedback_schedule == "constant"
    assert paper.synthetic_ratio == 0.5
    # entry by entry: a consistency setting given keeps the five passes; the defaults are never shared
    partial = PRIDE("MlpPolicy", "Pendulum-v1", reward_kwargs=dict(dynamics_consistency=dict(batch_size=64)))
    assert partial.reward_learner.consistency.settings.epochs == 5
    assert partial.reward_learner.consistency.settings.batch_size == 64
    assert PRIDE_REWARD_DEFAULTS == {"dynamics_consistency": {"epochs": 5}}
    # SB3's load() builds with _init_setup_model=False, then restores the saved schedule
    assert PRIDE("MlpPolicy", "Pendulum-v1", feedback_schedule="shrinking", _init_setup_model=False).feedback_schedule == (
        "shrinking"
    )


@pytest.mark.slow
def test_ratio_zero_trains_exactly_like_pebble_with_prides_reward_learning(tiny_kwargs):
    """u = 0: PRIDE is PEBBLE with PRIDE's label schedule and reward learning (REED's consistency), weight for weight."""
    pebble = PEBBLE("MlpPolicy", "Pendulum-v1", seed=3, **with_prides_reward_learning(tiny_kwargs)).learn(700)
    pride = PRIDE("MlpPolicy", "Pendulum-v1", seed=3, **tiny_kwargs, **tiny_pride(synthetic_ratio=0.0)).learn(700)
    assert pride.diffusion_retrains == 0 and pride.replay_buffer.synthetic.size() == 0
    for p, q in zip(pebble.policy.parameters(), pride.policy.parameters(), strict=True):
        assert th.equal(p, q)
    np.testing.assert_array_equal(pebble.replay_buffer.rewards, pride.replay_buffer.real.rewards)


@pytest.mark.slow
def test_save_load_predict_identical(tiny_kwargs, tmp_path):
    model = PRIDE("MlpPolicy", "Pendulum-v1", seed=0, **tiny_kwargs, **TINY_DIFFUSION).learn(400)
    model.save(tmp_path / "pride")
    loaded = PRIDE.load(tmp_path / "pride")
    obs = np.random.default_rng(0).normal(size=(32, 3)).astype(np.float32)
    np.testing.assert_array_equal(loaded.predict(obs, deterministic=True)[0], model.predict(obs, deterministic=True)[0])
    for name, tensor in model.generator.diffusion.state_dict().items():
        assert th.equal(tensor, loaded.generator.diffusion.state_dict()[name]), name
    assert loaded.synthetic_ratio == 0.5 and loaded.diffusion_interval == 300
    assert loaded.reward_learner.consistency is not None and loaded.feedback_schedule == "front_loaded"


@pytest.mark.slow
def test_short_run_on_metaworld_with_a_whitened_diffusion(tiny_kwargs, tmp_path):
    tiny_kwargs.update(max_feedback=40)
    model = PRIDE("MlpPolicy", "sb3_pride/button-press-v3", seed=0, **tiny_kwargs,
                  **tiny_pride(generator_kwargs=dict(normalization="whiten")))  # fmt: skip
    model.learn(700)
    assert model.diffusion_retrains == 2 and model.replay_buffer.synthetic.size() == 2000
    assert len(model.ep_success_buffer) == 1
    rotation = model.generator.diffusion.rotation
    assert th.allclose(rotation @ rotation.T, th.eye(len(rotation), device=rotation.device), atol=1e-4)  # orthonormal
    # the observation's previous frame: s' holds s's current frame exactly, and whitened samples keep that identity
    # (a zero-variance direction); per-dimension normalization breaks it (here by up to 0.37)
    synthetic = model.replay_buffer.synthetic
    size = synthetic.size()
    next_obs, obs = synthetic.next_observations[:size, 0], synthetic.observations[:size, 0]
    np.testing.assert_allclose(next_obs[:, 18:36], obs[:, :18], atol=1e-3)
    model.save(tmp_path / "pride")
    loaded = PRIDE.load(tmp_path / "pride")
    assert loaded.generator.diffusion.normalization == "whiten" and th.equal(loaded.generator.diffusion.rotation, rotation)


def test_bad_input_names_the_parameter():
    with pytest.raises(ValueError, match="synthetic_ratio"):
        PRIDE("MlpPolicy", "Pendulum-v1", synthetic_ratio=1.5)
    with pytest.raises(ValueError, match=r"set the generator's normalization, not diffusion_kwargs\['normalization'\]"):
        PRIDE("MlpPolicy", "Pendulum-v1", generator_kwargs=dict(diffusion_kwargs=dict(normalization="whiten")))
    for name in ("diffusion_interval", "synthetic_samples"):
        with pytest.raises(ValueError, match=name):
            PRIDE("MlpPolicy", "Pendulum-v1", **{name: 0})
    with pytest.raises(ValueError, match="train_steps"):
        PRIDE("MlpPolicy", "Pendulum-v1", generator_kwargs=dict(train_steps=0))
    with pytest.raises(ValueError, match="generator_kwargs must be valid TransitionGenerator arguments"):
        PRIDE("MlpPolicy", "Pendulum-v1", generator_kwargs=dict(diffusion_width=64))


#: a dynamics ensemble small enough for tests
TINY_DYNAMICS = dict(width=64, train_steps=200)


def record_draws(buffer: DualReplayBuffer) -> list[tuple[str, int]]:
    """Record (part, rows) of every draw from the buffer's real and synthetic parts from now on (the real part's
    transitions as stored: the minibatch's rewards are rewritten once, whole)."""
    drawn: list[tuple[str, int]] = []

    def recording(part, sample):
        def sample_and_record(n, env=None):
            drawn.append((part, n))
            return sample(n, env)

        return sample_and_record

    buffer.real.sample_transitions = recording("real", buffer.real.sample_transitions)
    buffer.synthetic.sample = recording("synthetic", buffer.synthetic.sample)
    return drawn


@pytest.mark.slow
@pytest.mark.parametrize("on_top", [False, True])
def test_gradient_steps_update_on_mixed_minibatches(tiny_kwargs, on_top):
    """The paper's argument for synthetic data, a higher update-to-data ratio: with gradient_steps=2 every env step
    makes two SAC updates, each on its own minibatch of round(u·B) synthetic and B − round(u·B) real transitions, or
    with synthetic_on_top of B real ones and B·u/(1 − u) synthetic ones on top."""
    kwargs = {**tiny_kwargs, **TINY_DIFFUSION, "synthetic_on_top": on_top}
    model = PRIDE("MlpPolicy", "Pendulum-v1", seed=0, gradient_steps=2, **kwargs)
    model.diagnostic_interval = 10**9  # the critic diagnostics draw minibatches too
    model.learn(350)  # synthetic data from step 300
    assert model.replay_buffer.synthetic.size() > 0
    drawn = record_draws(model.replay_buffer)
    updates = model._n_updates
    model.learn(10, reset_num_timesteps=False)
    assert model._n_updates - updates == 20  # two updates per env step
    rows = model.batch_size if on_top else model.batch_size // 2  # u = 0.5
    assert drawn == [("synthetic", rows), ("real", rows)] * 20


@pytest.mark.slow
@pytest.mark.parametrize(("ratio", "n_synthetic"), [(0.5, 64), (0.25, 21)])
def test_synthetic_on_top_keeps_batch_size_real_rows(tiny_kwargs, ratio, n_synthetic):
    """With synthetic_on_top the synthetic rows come on top of batch_size real ones (B = 64 here), as many real rows
    as PEBBLE's updates see at the same batch_size; without it they take the place of real ones."""
    kwargs = dict(**tiny_kwargs, **tiny_pride(synthetic_ratio=ratio))
    on_top = PRIDE("MlpPolicy", "Pendulum-v1", seed=0, **{**kwargs, "synthetic_on_top": True})
    on_top.diagnostic_interval = 10**9  # the critic diagnostics draw minibatches too
    on_top.learn(350)  # synthetic data from step 300
    drawn = record_draws(on_top.replay_buffer)
    on_top.learn(5, reset_num_timesteps=False)
    assert drawn == [("synthetic", n_synthetic), ("real", 64)] * 5
    assert on_top.minibatch_size(64) == 64 + n_synthetic and on_top.batch_size == 64  # what the user set stays

    replacing = PRIDE("MlpPolicy", "Pendulum-v1", seed=0, **kwargs)
    replacing.diagnostic_interval = 10**9
    replacing.learn(350)
    drawn = record_draws(replacing.replay_buffer)
    replacing.learn(5, reset_num_timesteps=False)
    assert drawn == [("synthetic", round(ratio * 64)), ("real", 64 - round(ratio * 64))] * 5


@pytest.mark.slow
def test_synthetic_on_top_trains_as_pebble_until_the_first_generation(tiny_kwargs):
    """With synthetic_on_top every minibatch holds batch_size real rows: until the first generation (step 600 here)
    PRIDE trains exactly as PEBBLE (bit-identical weights), the first feedback session and critic reset (step 300)
    included, not on a larger minibatch of real rows."""
    pebble = PEBBLE("MlpPolicy", "Pendulum-v1", seed=4, **with_prides_reward_learning(tiny_kwargs)).learn(599)
    kwargs = {**tiny_kwargs, **TINY_DIFFUSION, "synthetic_on_top": True, "synthetic_start": 600}
    on_top = PRIDE("MlpPolicy", "Pendulum-v1", seed=4, **kwargs).learn(599)
    assert on_top.replay_buffer.synthetic.size() == 0 and on_top.minibatch_size(64) == 64
    for p, q in zip(pebble.policy.parameters(), on_top.policy.parameters(), strict=True):
        assert th.equal(p, q)


@pytest.mark.slow
def test_synthetic_on_top_rows_grow_with_the_ramp_of_u(tiny_kwargs):
    """While u ramps up, the synthetic rows on top grow from 0 to B·u/(1 − u) and the real rows stay batch_size."""
    kwargs = {**tiny_kwargs, **tiny_pride(generator_kwargs=dict(dynamics_kwargs=TINY_DYNAMICS)), "synthetic_ramp": 100,
              "synthetic_on_top": True}  # fmt: skip
    model = PRIDE("MlpPolicy", "Pendulum-v1", seed=0, **kwargs)
    model.diagnostic_interval = 10**9  # the critic diagnostics draw minibatches too
    drawn = record_draws(model.replay_buffer)
    model.learn(450)  # the first generation at step 300, u = 0.5 from step 400
    assert model.first_generation_step == 300
    assert {rows for part, rows in drawn if part == "real"} == {64}
    synthetic = [rows for part, rows in drawn if part == "synthetic"]
    assert synthetic == sorted(synthetic) and synthetic[0] == 1 and synthetic[-1] == 64
    assert len(synthetic) == 450 - 301  # none before the first generation; at steps 300 and 301 round(u·M) is 0


@pytest.mark.slow
def test_delayed_start_and_ramp_of_u(tiny_kwargs):
    model = PRIDE("MlpPolicy", "Pendulum-v1", seed=0, **tiny_kwargs,
                  **tiny_pride(synthetic_start=600, synthetic_ramp=300,
                               generator_kwargs=dict(dynamics_kwargs=TINY_DYNAMICS)))  # fmt: skip
    model.learn(500)  # reward model since 300, but no synthetic data before step 600
    assert model.diffusion_retrains == 0 and model.replay_buffer.synthetic.size() == 0
    model.learn(250, reset_num_timesteps=False)
    assert model.diffusion_retrains == 1 and model.first_generation_step == 600
    # u ramps from 0 at step 600 to 0.5 at step 900: a quarter of the batch at step 750
    assert model.current_synthetic_ratio() == pytest.approx(0.25)
    assert model.replay_buffer.n_synthetic(model.batch_size) == 16
    model.learn(200, reset_num_timesteps=False)
    assert model.current_synthetic_ratio() == 0.5
    # a new learn() that restarts the step count keeps the distances: the ramp stays over, the next retrain stays
    # 250 steps away
    model.learn(10, reset_num_timesteps=True)
    assert model.first_generation_step == 600 - 950 and model.next_diffusion_step == 1200 - 950


@pytest.mark.slow
def test_diffusion_window_takes_the_most_recent_transitions(tiny_kwargs):
    model = PRIDE(
        "MlpPolicy",
        "Pendulum-v1",
        seed=0,
        **tiny_kwargs,
        **tiny_pride(generator_kwargs=dict(window=200, dynamics_kwargs=TINY_DYNAMICS)),
    )
    model.learn(450)
    vectors = model.generator.transition_vectors(*model.real_transitions())
    buffer = model.real_buffer
    assert vectors.shape == (200, 7)
    np.testing.assert_array_equal(vectors[:, :3], buffer.observations[250:450, 0])
    np.testing.assert_array_equal(vectors[:, 4:], buffer.next_observations[250:450, 0])


@pytest.mark.slow
@pytest.mark.parametrize("synthetic_filter", ["dynamics", "reward"])
def test_keep_quantile_keeps_what_the_filter_trusts(tiny_kwargs, synthetic_filter):
    generator = dict(filter=synthetic_filter, keep_quantile=0.5, dynamics_kwargs=TINY_DYNAMICS)
    model = PRIDE("MlpPolicy", "Pendulum-v1", seed=0, **tiny_kwargs, **tiny_pride(generator_kwargs=generator))
    model.learn(400)
    assert model.replay_buffer.synthetic.size() == TINY_DIFFUSION["synthetic_samples"]
    real = model.generator.transition_vectors(*model.real_transitions())
    rng = np.random.default_rng(0)
    vectors = real[rng.integers(0, len(real), size=400)]
    if synthetic_filter == "dynamics":  # the second half: next states off by five typical steps
        step_std = (real[:, 4:] - real[:, :3]).std(axis=0)
        vectors[200:, 4:] += 5 * step_std * rng.choice([-1, 1], size=(200, 3))
        kept = model.generator.select(vectors, 200)
        honest = {row.tobytes() for row in vectors[:200]}
        assert np.mean([row.tobytes() in honest for row in kept]) > 0.9
    else:  # the half the reward members agree on most
        doubt = model.reward_model.disagreement(vectors[:, :3], vectors[:, 3:4])
        kept = model.generator.select(vectors, 200, reward_doubt=model.reward_model.disagreement)
        np.testing.assert_array_equal(kept, vectors[np.argsort(doubt, kind="stable")[:200]])
        assert model.reward_model.disagreement(kept[:, :3], kept[:, 3:4]).max() <= np.sort(doubt)[200]


@pytest.mark.slow
def test_near_real_generation_of_state_changes(tiny_kwargs):
    generator = dict(generation="near_real", anchor_noise=0.3, model_state_change=True, dynamics_kwargs=TINY_DYNAMICS)
    model = PRIDE("MlpPolicy", "Pendulum-v1", seed=0, **tiny_kwargs, **tiny_pride(generator_kwargs=generator))
    real = np.random.default_rng(0).normal(size=(5, 7)).astype(np.float32)
    encoded = model.generator.encode(real)
    np.testing.assert_allclose(encoded[:, 4:], real[:, 4:] - real[:, :3])
    np.testing.assert_allclose(model.generator.decode(encoded), real, atol=1e-6)
    model.learn(400)
    synthetic = model.replay_buffer.synthetic
    assert model.diffusion_retrains == 1 and synthetic.size() == TINY_DIFFUSION["synthetic_samples"]
    assert np.all(np.isfinite(synthetic.next_observations[: synthetic.size()]))
    # each sample comes with the real row it was generated near, and stays near it
    real = model.generator.transition_vectors(*model.real_transitions())
    vectors, anchors = model.generator.generate(real, 100)
    assert vectors.shape == (100, 7) and anchors is not None and anchors.shape == (100,)
    assert np.abs(vectors - real[anchors]).mean() < np.abs(vectors - real[np.roll(anchors, 1)]).mean()
    # sanitize drops a non-finite vector together with its anchor, and rejects anchors that do not match
    vectors[3, 0] = np.nan
    kept, kept_anchors = model.generator.sanitize(vectors, anchors)
    assert len(kept) == 99 and kept_anchors is not None
    np.testing.assert_array_equal(kept_anchors, np.delete(anchors, 3))
    with pytest.raises(ValueError, match="anchors must be one integer row index per generated vector"):
        model.generator.sanitize(vectors, anchors[:-1])
    with pytest.raises(ValueError, match="anchors must be one integer row index"):  # row positions, not values
        model.generator.sanitize(vectors, anchors.astype(np.float32))


def test_bad_mixing_input_names_the_parameter():
    for name, value in dict(synthetic_start=-1, synthetic_ramp=1.5, synthetic_on_top="yes").items():
        with pytest.raises(ValueError, match=name):
            PRIDE("MlpPolicy", "Pendulum-v1", **{name: value})
    bad_generator = dict(generation="from_scratch", anchor_noise=0.0, window=0, keep_quantile=0.0, filter="value")
    for name, value in bad_generator.items():
        with pytest.raises(ValueError, match=name):
            PRIDE("MlpPolicy", "Pendulum-v1", generator_kwargs={name: value})
    with pytest.raises(ValueError, match="keep_quantile"):
        PRIDE("MlpPolicy", "Pendulum-v1", generator_kwargs=dict(keep_quantile=1.01))
    with pytest.raises(ValueError, match="anchor_noise"):
        PRIDE("MlpPolicy", "Pendulum-v1", generator_kwargs=dict(anchor_noise=2.0, diffusion_kwargs=dict(sigma_max=1.0)))
    with pytest.raises(ValueError, match="dynamics_kwargs"):
        PRIDE("MlpPolicy", "Pendulum-v1", generator_kwargs=dict(dynamics_kwargs=dict(depth=3)))
    with pytest.raises(ValueError, match="fidelity_check"):
        PRIDE("MlpPolicy", "Pendulum-v1", generator_kwargs=dict(keep_quantile=0.5, fidelity_check=False))
    with pytest.raises(ValueError, match="generator_kwargs must be a dict"):
        PRIDE("MlpPolicy", "Pendulum-v1", generator_kwargs="paper")
    with pytest.raises(ValueError, match="synthetic_on_top=True needs synthetic_ratio < 1"):
        PRIDE("MlpPolicy", "Pendulum-v1", synthetic_ratio=1.0, synthetic_on_top=True)
    PRIDE("MlpPolicy", "Pendulum-v1", synthetic_ratio=1.0, synthetic_on_top=False)  # every row synthetic: in place


def test_generator_settings_as_keywords_of_their_own_are_pointed_to_generator_kwargs():
    with pytest.raises(TypeError, match=r"diffusion_width is now generator_kwargs=\{'width': \.\.\.\}"):
        PRIDE("MlpPolicy", "Pendulum-v1", diffusion_width=64)
    for bad in (dict(seed=1), dict(device="cpu")):
        with pytest.raises(ValueError, match="seed and device are PRIDE's"):
            PRIDE("MlpPolicy", "Pendulum-v1", generator_kwargs=bad)
