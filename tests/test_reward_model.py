import copy

import numpy as np
import pytest
import torch as th
from scipy.stats import spearmanr

from sb3_pride import PEBBLE, ScriptedTeacher
from sb3_pride.common.queries import SegmentPairs
from sb3_pride.reward.ensemble import (
    PreferenceDataset,
    RewardEnsemble,
    check_temporal_crop,
    crop_pairs,
    preference_loss,
)
from sb3_pride.reward.options import PseudoLabels, RobustLabels
from sb3_pride.common.utils import merge_kwargs


def with_rewards(kwargs: dict, **settings) -> dict:
    """``kwargs`` (a test's, with TINY's ``reward_kwargs``) with these ``reward_kwargs`` settings too."""
    return merge_kwargs(kwargs, dict(reward_kwargs=settings))


def test_bradley_terry_loss_by_hand():
    returns = th.tensor([[1.0, 3.0], [2.0, -1.0], [0.5, 0.5]])
    labels = th.tensor([1.0, 1.0, 0.5])
    p1 = np.exp([3.0, -1.0, 0.5]) / (np.exp([3.0, -1.0, 0.5]) + np.exp([1.0, 2.0, 0.5]))
    expected = -np.mean([np.log(p1[0]), np.log(p1[1]), 0.5 * np.log(p1[2]) + 0.5 * np.log(1 - p1[2])])
    assert abs(preference_loss(returns, labels).item() - expected) < 1e-6


def true_reward(obs, actions):
    return np.tanh(obs[..., 0] - 0.5 * obs[..., 1] + 0.3 * actions[..., 0])


def test_ensemble_trained_on_200_oracle_labels_ranks_held_out_transitions():
    rng = np.random.default_rng(0)
    th.manual_seed(0)
    n, k, obs_dim, act_dim = 200, 10, 4, 2
    obs = rng.normal(size=(n, 2, k, obs_dim)).astype(np.float32)
    actions = rng.uniform(-1, 1, size=(n, 2, k, act_dim)).astype(np.float32)
    pairs = SegmentPairs(obs, actions, true_reward(obs, actions))
    labels = ScriptedTeacher.from_preset("oracle")(pairs)
    dataset = PreferenceDataset(k, obs_dim + act_dim)
    dataset.add(np.concatenate([obs, actions], axis=-1), labels)

    model = RewardEnsemble(obs_dim, act_dim, n_members=3, net_arch=(64, 64), learning_rate=1e-3, device="cpu")
    _loss, accuracy, epochs = model.train_epochs(dataset, max_epochs=300, batch_size=64, rng=rng)
    assert accuracy > 0.9 and epochs < 300  # early stop at 97% training accuracy

    held_obs = rng.normal(size=(2000, obs_dim)).astype(np.float32)
    held_actions = rng.uniform(-1, 1, size=(2000, act_dim)).astype(np.float32)
    rho = spearmanr(model.predict(held_obs, held_actions), true_reward(held_obs, held_actions)).statistic
    assert rho > 0.9


def test_untrained_members_disagree_and_predict_is_their_mean():
    model = RewardEnsemble(3, 1, n_members=3, net_arch=(16,), device="cpu")
    obs, actions = np.random.randn(50, 3).astype(np.float32), np.random.randn(50, 1).astype(np.float32)
    per_member = model(th.as_tensor(np.concatenate([obs, actions], -1))).detach().numpy()[..., 0]
    assert per_member.std(axis=0).mean() > 1e-3
    np.testing.assert_allclose(model.predict(obs, actions), per_member.mean(axis=0), rtol=1e-5, atol=1e-6)
    assert np.all(np.abs(per_member) <= 1.0)  # tanh output


def test_temporal_crop_keeps_each_pair_and_its_label_and_crops_both_segments_to_one_length():
    rng = np.random.default_rng(0)
    members, b, k, d = 3, 64, 20, 2
    # step t of segment j of pair i holds (t, 1000 i + j): every gathered row says where it came from
    steps = np.broadcast_to(np.arange(k)[None, None, None, :], (members, b, 2, k)).astype(np.float32)
    ids = np.broadcast_to((1000 * np.arange(b)[None, :, None] + np.arange(2)[None, None, :])[..., None], (members, b, 2, k))
    inputs = th.as_tensor(np.stack([steps, ids.astype(np.float32)], axis=-1))
    labels = th.as_tensor(rng.integers(0, 2, size=(members, b)).astype(np.float32))
    cropped, mask, cropped_labels = crop_pairs(inputs, labels, (5, 12), rng)

    assert cropped.shape == (members, b, 2, 12, d) and mask.shape == (members, b, 2, 12)
    assert th.equal(cropped_labels, labels)  # the pair keeps its label
    assert th.equal(cropped[..., 1], inputs[..., :12, 1])  # every crop comes from its own pair and segment
    lengths = mask.sum(dim=-1)
    assert th.equal(lengths[..., 0], lengths[..., 1])  # one length per pair
    assert lengths.min() == 5 and lengths.max() == 12  # the whole range is drawn
    assert th.all(mask[..., :5] == 1)  # the kept steps come first
    kept_steps = cropped[..., 0]
    first = kept_steps[..., 0]
    # consecutive steps of the segment, inside it, with a start of its own in each segment
    offsets = th.arange(12, dtype=th.float32)
    assert th.all(((kept_steps - first[..., None]) == offsets) | (mask == 0))
    assert th.all((first + lengths - 1) <= k - 1)
    assert (first[..., 0] != first[..., 1]).float().mean() > 0.5


def test_temporal_crop_trains_and_member_returns_take_any_segment_length():
    rng = np.random.default_rng(0)
    th.manual_seed(0)
    n, k, obs_dim, act_dim = 200, 10, 4, 2
    obs = rng.normal(size=(n, 2, k, obs_dim)).astype(np.float32)
    actions = rng.uniform(-1, 1, size=(n, 2, k, act_dim)).astype(np.float32)
    labels = ScriptedTeacher.from_preset("oracle")(SegmentPairs(obs, actions, true_reward(obs, actions)))
    dataset = PreferenceDataset(k, obs_dim + act_dim)
    dataset.add(np.concatenate([obs, actions], axis=-1), labels)
    model = RewardEnsemble(obs_dim, act_dim, n_members=3, net_arch=(64, 64), learning_rate=1e-3, device="cpu")
    _loss, accuracy, _epochs = model.train_epochs(dataset, 100, batch_size=64, rng=rng, temporal_crop=(6, 8))
    assert accuracy > 0.8
    held_obs = rng.normal(size=(2000, obs_dim)).astype(np.float32)
    held_actions = rng.uniform(-1, 1, size=(2000, act_dim)).astype(np.float32)
    assert spearmanr(model.predict(held_obs, held_actions), true_reward(held_obs, held_actions)).statistic > 0.8

    # a segment of any length: the sum of r̂ over its steps
    short = np.concatenate([obs, actions], axis=-1)[:5, :, :7]
    returns = model.member_segment_returns(short).numpy()
    per_step = model(th.as_tensor(short)).detach().numpy()[..., 0]
    np.testing.assert_allclose(returns, per_step.sum(axis=-1), rtol=1e-5, atol=1e-5)


@pytest.mark.parametrize(
    "bad", [5, (5,), (5, 6, 7), (5.0, 6), ("5", 6), (True, 6), (0, 5), (-1, 5), (6, 5), (5, 11), (11, 11)]
)
def test_bad_temporal_crop_names_the_parameter(bad):
    with pytest.raises(ValueError, match="temporal_crop"):
        check_temporal_crop(bad, segment_length=10)
    dataset = PreferenceDataset(10, 3)
    dataset.add(np.zeros((4, 2, 10, 3)), np.ones(4))
    with pytest.raises(ValueError, match="temporal_crop"):
        RewardEnsemble(2, 1, net_arch=(8,), device="cpu").train_epochs(dataset, 1, temporal_crop=bad)
    with pytest.raises(ValueError, match="temporal_crop"):
        PEBBLE("MlpPolicy", "Pendulum-v1", segment_length=10, reward_kwargs=dict(temporal_crop=bad))


def test_check_temporal_crop_accepts_none_and_pairs():
    assert check_temporal_crop(None, 50) is None
    assert check_temporal_crop([35, 45], 50) == (35, 45)
    assert check_temporal_crop((np.int64(50), 50), 50) == (50, 50)
    assert check_temporal_crop((1, 1)) == (1, 1)


def test_pebble_with_temporal_crop_trains_in_a_short_run(tiny_kwargs):
    model = PEBBLE("MlpPolicy", "Pendulum-v1", seed=0, **with_rewards(tiny_kwargs, temporal_crop=(6, 8), early_stop=None))
    assert model.reward_learner.temporal_crop == (6, 8)
    assert PEBBLE("MlpPolicy", "Pendulum-v1").reward_learner.temporal_crop is None
    calls, epochs_run = [], []
    train_epochs = model.reward_model.train_epochs

    def spy(*args, **kwargs):
        calls.append((kwargs.get("temporal_crop"), kwargs.get("target_accuracy")))
        result = train_epochs(*args, **kwargs)
        epochs_run.append(result[2])
        return result

    model.reward_model.train_epochs = spy  # type: ignore[method-assign]
    model.learn(700)
    # sessions at 300 (end of pre-training) and 600, each training r̂ on the cropped pairs, every epoch
    assert model.phase.sessions == 2 and calls == [((6, 8), 1.0), ((6, 8), 1.0)]
    assert epochs_run == [tiny_kwargs["reward_kwargs"]["epochs"]] * 2
    assert len(model.preferences) == 40 and model.preferences.inputs.shape[2] == 10  # D keeps whole segments
    buffer = model.replay_buffer
    n = buffer.pos
    np.testing.assert_allclose(
        buffer.rewards[:n, 0], model.reward_model.predict(buffer.observations[:n, 0], buffer.actions[:n, 0]), atol=1e-5
    )
    assert np.isfinite(model.reward_learner.correlation(model.real_buffer, np.random.default_rng(0)))


def test_reward_early_stop_is_pebbles_97_percent_unless_told():
    assert PEBBLE("MlpPolicy", "Pendulum-v1").reward_learner.early_stop == 0.97
    assert PEBBLE("MlpPolicy", "Pendulum-v1", reward_kwargs=dict(early_stop=None)).reward_learner.early_stop is None
    for bad in (0, 1, 1.5, -0.1, float("nan"), "0.9", True):
        with pytest.raises(ValueError, match="reward_kwargs: early_stop"):
            PEBBLE("MlpPolicy", "Pendulum-v1", reward_kwargs=dict(early_stop=bad))


def noisy_preferences(n: int, eps_mistake: float, seed: int):
    """n segment pairs of a known reward, labelled by B-Pref's teacher that flips a share ``eps_mistake`` of them."""
    rng = np.random.default_rng(seed)
    k, obs_dim, act_dim = 10, 4, 2
    obs = rng.normal(size=(n, 2, k, obs_dim)).astype(np.float32)
    actions = rng.uniform(-1, 1, size=(n, 2, k, act_dim)).astype(np.float32)
    pairs = SegmentPairs(obs, actions, true_reward(obs, actions))
    truth = ScriptedTeacher.from_preset("oracle")(pairs)
    labels = ScriptedTeacher(eps_mistake=eps_mistake, seed=seed)(pairs)
    dataset = PreferenceDataset(k, obs_dim + act_dim)
    dataset.add(np.concatenate([obs, actions], axis=-1), labels)
    return dataset, labels != truth


def held_out_rank_correlation(model: RewardEnsemble) -> float:
    rng = np.random.default_rng(123)
    held_obs = rng.normal(size=(2000, 4)).astype(np.float32)
    held_actions = rng.uniform(-1, 1, size=(2000, 2)).astype(np.float32)
    return spearmanr(model.predict(held_obs, held_actions), true_reward(held_obs, held_actions)).statistic


def test_robust_labels_leave_out_the_flipped_labels_and_learn_a_better_reward():
    """RIME's selection against a teacher that flips 25% of its labels: by the last epoch, most flipped labels are
    left out or flipped back and few correct ones are, and r̂ ranks held-out transitions better than without it. The
    same selection on an oracle's labels trusts nearly all of them (it is not a filter that drops at random)."""
    dataset, wrong = noisy_preferences(300, eps_mistake=0.25, seed=0)
    scores = {}
    for robust in (False, True):
        th.manual_seed(0)
        model = RewardEnsemble(4, 2, n_members=3, net_arch=(64, 64), learning_rate=1e-3, device="cpu")
        selection = RobustLabels()
        options = [selection] if robust else []
        model.train_epochs(dataset, 60, 64, target_accuracy=1.0, rng=np.random.default_rng(0), options=options)
        scores[robust] = held_out_rank_correlation(model)
        if robust:
            inputs, labels = th.as_tensor(dataset.inputs), th.as_tensor(dataset.labels)
            trusted, _ = copy.deepcopy(selection).select(model.label_divergence(inputs, labels), dataset.labels)
            assert (~trusted[wrong]).mean() > 0.6 and (~trusted[~wrong]).mean() < 0.25
    assert scores[True] > scores[False] + 0.02, scores

    clean, _ = noisy_preferences(300, eps_mistake=0.0, seed=1)
    th.manual_seed(0)
    model, selection = RewardEnsemble(4, 2, n_members=3, net_arch=(64, 64), learning_rate=1e-3, device="cpu"), RobustLabels()
    model.train_epochs(clean, 60, 64, target_accuracy=1.0, rng=np.random.default_rng(0), options=[selection])
    assert selection.trusted >= 0.85 * len(clean) and selection.flipped <= 0.02 * len(clean)


@pytest.mark.parametrize(
    "bad, match",
    [
        ({"alpha": -1.0}, "alpha"),
        ({"beta_init": float("inf")}, "beta_init"),
        ({"beta_init": 0.5, "beta_min": 1.0}, "beta_min"),
        ({"beta_decay_epochs": 0}, "beta_decay_epochs"),
        ({"flip_probability": 0.7}, "flip_probability"),
    ],
)
def test_bad_robust_labels_name_the_setting(bad, match):
    with pytest.raises(ValueError, match=match):
        RobustLabels(**bad)
    with pytest.raises(ValueError, match=match):
        PEBBLE("MlpPolicy", "Pendulum-v1", reward_kwargs=dict(robust_labels=bad))


def test_pebble_with_robust_labels_logs_its_selection_and_saves_it(tiny_kwargs, tmp_path):
    from stable_baselines3.common.logger import configure

    with pytest.raises(ValueError, match="robust_labels"):
        PEBBLE("MlpPolicy", "Pendulum-v1", reward_kwargs=dict(robust_labels="rime"))
    off = PEBBLE("MlpPolicy", "Pendulum-v1", **tiny_kwargs)
    assert off.reward_learner.label_selection is None  # off: PEBBLE as published
    model = PEBBLE("MlpPolicy", "Pendulum-v1", seed=0, teacher="mistake", **with_rewards(tiny_kwargs, robust_labels=True))
    model.set_logger(configure(str(tmp_path), ["csv"]))
    model.learn(700, log_interval=1)
    selection = model.reward_learner.label_selection
    assert selection.epochs > 0 and selection.max_divergence is not None
    model.save(tmp_path / "model")
    loaded = PEBBLE.load(tmp_path / "model")
    assert loaded.reward_learner.label_selection == selection
    import pandas as pd

    progress = pd.read_csv(tmp_path / "progress.csv")
    assert progress["reward_model/trusted_labels"].notna().any()


def test_pseudo_labels_teach_each_member_its_own_confident_answers_and_nothing_else():
    """SURF's unlabelled loss: zero where no member is confident (an untrained ensemble at τ = 0.99); after training
    on labels, a step on it alone makes the members surer of the answers they were confident about (a loss that
    taught the opposite label, or every pair, would not)."""
    dataset, _ = noisy_preferences(200, eps_mistake=0.0, seed=0)
    unlabeled, _ = noisy_preferences(500, eps_mistake=0.0, seed=1)
    pairs = th.as_tensor(unlabeled.inputs)
    th.manual_seed(0)
    model = RewardEnsemble(4, 2, n_members=3, net_arch=(64, 64), learning_rate=1e-3, device="cpu")
    rng = np.random.default_rng(0)
    assert model.pseudo_label_loss(pairs, 64, PseudoLabels(threshold=0.99), rng, None).item() == 0.0

    model.train_epochs(dataset, max_epochs=30, batch_size=64, rng=rng)

    def confidence() -> th.Tensor:
        with th.no_grad():
            p = th.softmax(model(pairs).sum(dim=(-2, -1)), dim=-1)[..., 1]  # (members, n)
        return th.maximum(p, 1 - p)

    settings = PseudoLabels(threshold=0.9, ratio=8)
    before = confidence()
    confident = before > settings.threshold
    assert 0.2 < confident.float().mean() < 0.95  # some pairs are sure, some are not
    for _ in range(5):
        loss = model.pseudo_label_loss(pairs, 64, settings, rng, (7, 9))  # on crops, as with temporal_crop
        model.optimizer.zero_grad()
        loss.backward()
        model.optimizer.step()
    after = confidence()
    assert after[confident].mean() > before[confident].mean()


def test_pebble_with_pseudo_labels_trains_and_bad_settings_are_named(tiny_kwargs):
    for bad, match in (({"threshold": 1.0}, "threshold"), ({"ratio": 0}, "ratio"), ({"tau": 0.9}, "unknown settings")):
        with pytest.raises(ValueError, match=match):
            PEBBLE("MlpPolicy", "Pendulum-v1", reward_kwargs=dict(pseudo_labels=bad))
    with pytest.raises(ValueError, match="pseudo_labels"):
        PEBBLE("MlpPolicy", "Pendulum-v1", reward_kwargs=dict(pseudo_labels="surf"))
    kwargs = with_rewards(tiny_kwargs, pseudo_labels={"unlabeled_per_label": 5}, temporal_crop=(6, 9))
    model = PEBBLE("MlpPolicy", "Pendulum-v1", seed=0, **kwargs)
    assert model.reward_learner.pseudo_labels == PseudoLabels(unlabeled_per_label=5)
    drawn = []
    unlabeled_pairs = model.query_sampler.unlabeled_pairs

    def recording(buffer, n_pairs, rng):
        pairs = unlabeled_pairs(buffer, n_pairs, rng)
        drawn.append(len(pairs))
        return pairs

    model.query_sampler.unlabeled_pairs = recording
    model.learn(400)
    # the session's 20 labels, 5 unlabelled pairs each
    assert model.phase.sessions == 1 and drawn == [100]
