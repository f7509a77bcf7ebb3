import numpy as np
import torch as th
from scipy.stats import spearmanr

from sb3_pride import ScriptedTeacher
from sb3_pride.common.queries import SegmentPairs
from sb3_pride.common.reward_model import PreferenceDataset, RewardEnsemble, preference_loss


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

    model = RewardEnsemble(obs_dim, act_dim, n_members=3, net_arch=(64, 64), learning_rate=1e-3)
    _loss, accuracy, epochs = model.train_epochs(dataset, max_epochs=300, batch_size=64, rng=rng)
    assert accuracy > 0.9 and epochs < 300  # early stop at 97% training accuracy

    held_obs = rng.normal(size=(2000, obs_dim)).astype(np.float32)
    held_actions = rng.uniform(-1, 1, size=(2000, act_dim)).astype(np.float32)
    rho = spearmanr(model.predict(held_obs, held_actions), true_reward(held_obs, held_actions)).statistic
    assert rho > 0.9


def test_untrained_members_disagree_and_predict_is_their_mean():
    model = RewardEnsemble(3, 1, n_members=3, net_arch=(16,))
    obs, actions = np.random.randn(50, 3).astype(np.float32), np.random.randn(50, 1).astype(np.float32)
    per_member = model(th.as_tensor(np.concatenate([obs, actions], -1))).detach().numpy()[..., 0]
    assert per_member.std(axis=0).mean() > 1e-3
    np.testing.assert_allclose(model.predict(obs, actions), per_member.mean(axis=0), rtol=1e-5, atol=1e-6)
    assert np.all(np.abs(per_member) <= 1.0)  # tanh output
