import numpy as np
import pytest
import torch as th
from gymnasium import spaces

from sb3_pride import PreferenceReplayBuffer
from sb3_pride.common.queries import sample_segment_pairs, segment_starts
from sb3_pride.common.query_selection import select_queries


def filled_buffer(n_envs, size, steps, seed=0):
    """A buffer filled by n_envs streams of episodes of random lengths; obs = (episode id, step in episode)."""
    rng = np.random.default_rng(seed)
    buffer = PreferenceReplayBuffer(size * n_envs, spaces.Box(-np.inf, np.inf, (2,)), spaces.Box(-1, 1, (1,)), n_envs=n_envs)
    episode = np.arange(n_envs) * 1000
    t = np.zeros(n_envs, dtype=int)
    length = rng.integers(5, 40, size=n_envs)
    for _ in range(steps):
        obs = np.stack([episode, t], axis=1).astype(np.float32)
        done = t == length - 1
        buffer.add(obs, obs, np.zeros((n_envs, 1)), np.ones(n_envs), done, [{} for _ in range(n_envs)])
        t += 1
        episode = np.where(done, episode + 1, episode)
        t = np.where(done, 0, t)
        length = np.where(done, rng.integers(5, 40, size=n_envs), length)
    return buffer


def assert_segments_within_episodes(pairs, k):
    episode, step = pairs.observations[..., 0], pairs.observations[..., 1]
    assert np.all(episode == episode[..., :1]), "a segment crossed an episode end"
    assert np.all(np.diff(step, axis=-1) == 1), "a segment is not consecutive"
    assert pairs.observations.shape[2] == k


def test_segments_never_cross_episode_ends_single_and_two_envs_with_wraparound():
    for n_envs, steps in ((1, 300), (2, 300), (2, 1000)):  # 1000 steps wrap the 400-row ring
        buffer = filled_buffer(n_envs, size=400, steps=steps)
        pairs = sample_segment_pairs(buffer, 2000, 12, max_episodes=100, rng=np.random.default_rng(1))
        assert_segments_within_episodes(pairs, 12)
        if n_envs == 2:
            episodes = pairs.observations[..., 0, 0]
            assert (episodes < 1000).any() and (episodes >= 1000).any(), "both envs' streams are used"


def test_only_recent_episodes_are_queried():
    buffer = filled_buffer(1, size=5000, steps=3000)
    newest = buffer.observations[: buffer.pos, 0, 0].max()
    pairs = sample_segment_pairs(buffer, 500, 5, max_episodes=3, rng=np.random.default_rng(0))
    assert pairs.observations[..., 0].min() >= newest - 2


def test_no_segment_when_episodes_are_too_short():
    buffer = filled_buffer(1, size=500, steps=300)
    starts, _ = segment_starts(buffer, 60, max_episodes=100)
    assert len(starts) == 0
    assert sample_segment_pairs(buffer, 10, 60, 100, np.random.default_rng(0)) is None


def test_query_selection_picks_most_uncertain_pairs():
    # members agree on pairs 0-2, disagree on pair 3 (disagreement) and are 50/50 on pair 4 (entropy)
    returns = th.tensor(
        [
            [[0.0, 5.0], [0.0, 5.0], [5.0, 0.0], [0.0, 9.0], [0.0, 0.0]],
            [[0.0, 5.0], [0.0, 5.0], [5.0, 0.0], [9.0, 0.0], [0.0, 0.0]],
        ]
    )
    assert set(select_queries(returns, 1, "disagreement")) == {3}
    assert set(select_queries(returns, 1, "entropy")) == {4}
    assert list(select_queries(returns, 2, "uniform")) == [0, 1]


def test_relabel_writes_reward_model_output_everywhere():
    buffer = filled_buffer(2, size=300, steps=500)

    def reward_fn(obs, actions):
        return np.sin(obs[..., 0]) + obs[..., 1] * 0.01 + actions[..., 0]

    buffer.relabel(reward_fn, batch_size=77)
    expected = reward_fn(buffer.observations, buffer.actions)
    np.testing.assert_allclose(buffer.rewards, expected, rtol=1e-5)
    assert np.all(buffer.true_rewards == 1.0)  # the true reward is untouched


def test_kcenter_picks_the_uncovered_clusters_first():
    """Three tight clusters of candidates, one already covered by a labelled pair: k-center asks about one pair of
    each uncovered cluster before a second pair of any, and never about the covered one; disagreement alone would
    crowd into the cluster where the members disagree."""
    from sb3_pride.common.query_selection import kcenter_greedy

    rng = np.random.default_rng(0)
    centers = np.array([[0.0, 0.0], [10.0, 0.0], [0.0, 10.0]])
    features = np.concatenate([c + 0.1 * rng.normal(size=(20, 2)) for c in centers])
    cluster = np.repeat(np.arange(3), 20)
    picked = kcenter_greedy(features, centers[:1], 2)
    assert sorted(cluster[picked]) == [1, 2]
    assert len(set(cluster[kcenter_greedy(features, np.zeros((0, 2)), 3)])) == 3

    returns = th.zeros(3, 60, 2)
    returns[:, 40:, 1] = th.tensor([-3.0, 0.0, 3.0])[:, None]  # the members disagree on cluster 2 only
    assert set(cluster[select_queries(returns, 2, "disagreement")]) == {2}
    chosen = select_queries(returns, 2, "kcenter", features=features, labeled_features=centers[:1])
    assert sorted(cluster[chosen]) == [1, 2]
    # among the more uncertain half (cluster 2 and the first-ranked ties), still spread
    chosen = select_queries(returns, 2, "kcenter_disagreement", features=features, labeled_features=centers[:1])
    assert len(set(chosen)) == 2 and 2 in set(cluster[chosen])
    with pytest.raises(ValueError, match="features"):
        select_queries(returns, 2, "kcenter")
    with pytest.raises(ValueError, match="query_selection"):
        select_queries(returns, 2, "coverage")


def test_pebble_runs_with_kcenter_query_selection(tiny_kwargs):
    from sb3_pride import PEBBLE

    model = PEBBLE("MlpPolicy", "Pendulum-v1", seed=0, query_selection="kcenter_disagreement", **tiny_kwargs)
    model.learn(700)
    assert model.phase.sessions == 2 and model.phase.asked == 40


class RecentRows:
    """A reward source that keeps the stored rewards and draws ``recent_share`` of each minibatch from ``recent_rows``."""

    def __init__(self, recent_rows, recent_share):
        self.recent_rows, self.recent_share = recent_rows, recent_share

    def new_rewards(self, observations, actions):
        return np.zeros(len(observations), dtype=np.float32)

    def rewrite(self, samples, buffer, env):
        return samples


def test_hybrid_replay_draws_its_share_from_the_most_recent_episodes():
    """QPA's hybrid replay: recent_rows are the rows of the last episodes (across the ring buffer's wrap), and a
    minibatch with recent_share 0.5 holds that share from them on top of what uniform sampling gives them."""
    from sb3_pride.common.queries import recent_rows

    buffer = filled_buffer(1, 500, 800)  # wrapped around
    rows = recent_rows(buffer, 3)
    last = buffer.observations[(buffer.pos - 1) % 500, 0, 0]
    recent = [last - 2, last - 1, last]
    assert set(buffer.observations[rows, 0, 0]) == set(recent) and rows[-1] == (buffer.pos - 1) % 500
    assert np.isin(buffer.observations[:, 0, 0], recent).sum() == len(rows)  # all of their rows
    buffer.reward_source = RecentRows(rows, 0.5)
    np.random.seed(0)
    share = np.isin(buffer.sample(2000).observations[:, 0].cpu().numpy(), recent).mean()
    assert abs(share - (0.5 + 0.5 * len(rows) / 500)) < 0.05
    buffer.reward_source.recent_share = 0.0  # off: SB3's uniform sampling
    share = np.isin(buffer.sample(2000).observations[:, 0].cpu().numpy(), recent).mean()
    assert abs(share - len(rows) / 500) < 0.05


def test_pebble_hybrid_replay_is_on_while_queries_remain(tiny_kwargs):
    from sb3_pride import PEBBLE

    for bad in (-0.1, 1.5, "half"):
        with pytest.raises(ValueError, match="hybrid_replay"):
            PEBBLE("MlpPolicy", "Pendulum-v1", query_kwargs=dict(hybrid_replay=bad))
    model = PEBBLE("MlpPolicy", "Pendulum-v1", seed=0, query_kwargs=dict(hybrid_replay=0.5, max_query_episodes=2),
                   **tiny_kwargs)  # fmt: skip
    source = model.replay_rewards  # what the replay buffer asks
    assert model.real_buffer.reward_source is source
    model.learn(250)  # pre-training: uniform
    assert source.recent_share == 0.0 and source.recent_rows is None
    model.learn(450, reset_num_timesteps=False)  # after the first session, queries remain
    assert source.recent_share == 0.5 and 0 < len(source.recent_rows) <= 400
    model.max_feedback = model.phase.asked  # every query asked: uniform again
    model.learn(10, reset_num_timesteps=False)
    assert source.recent_share == 0.0
