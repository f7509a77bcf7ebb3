"""r̂ on its own: saved and loaded apart from the agent, fitted from journals, given to SB3 algorithms, shown in figures."""

import subprocess
import sys

import gymnasium as gym
import numpy as np
import pytest
from stable_baselines3 import PPO, SAC, TD3
from stable_baselines3.common.env_util import make_vec_env
from stable_baselines3.common.evaluation import evaluate_policy
from stable_baselines3.common.monitor import Monitor

from sb3_pride import PEBBLE
from sb3_pride.common.journal import PreferenceJournal
from sb3_pride.reward import (
    LearnedReward,
    LearnedRewardWrapper,
    VecLearnedReward,
    episode_rewards,
    fit_reward,
    preference_accuracy,
    reward_report,
)


@pytest.fixture(scope="module")
def trained(tmp_path_factory):
    """A tiny PEBBLE run on Pendulum with its journal, and its r̂ saved apart."""
    from conftest import TINY

    folder = tmp_path_factory.mktemp("trained")
    model = PEBBLE("MlpPolicy", "Pendulum-v1", seed=0, preference_journal=folder / "preferences.jsonl", **TINY).learn(1000)
    model.save_reward_model(folder / "reward.pt")
    return model, folder


def pendulum_reward(observations: np.ndarray, actions: np.ndarray) -> np.ndarray:
    """Pendulum-v1's own reward of (s_t, a_t), the actions scaled to [-1, 1] as r̂ reads them."""
    angle = np.arctan2(observations[..., 1], observations[..., 0])
    torque = 2.0 * actions[..., 0]
    return -(angle**2 + 0.1 * observations[..., 2] ** 2 + 0.001 * torque**2)


class KnownReward(LearnedReward):
    """A reward model whose r̂ is ``sign`` × the true reward: +1 a perfect one, -1 a deliberately wrong one."""

    def __init__(self, sign: float):
        reward = LearnedReward.new(gym.make("Pendulum-v1").observation_space, gym.make("Pendulum-v1").action_space, 10)
        super().__init__(reward.learner, reward.observation_space, reward.action_space, 10)
        self.sign = sign

    def predict(self, observations, actions):
        return self.sign * pendulum_reward(observations, actions)

    def spread(self, observations, actions):
        return np.zeros(observations.shape[:-1])


def test_the_reward_model_saved_apart_predicts_as_the_agents(trained):
    model, folder = trained
    reward = LearnedReward.load(folder / "reward.pt")
    rng = np.random.default_rng(0)
    observations, actions = rng.normal(size=(50, 3)).astype(np.float32), rng.uniform(-1, 1, (50, 1)).astype(np.float32)
    np.testing.assert_allclose(reward.predict(observations, actions), model.reward_learner.predict(observations, actions))
    assert reward.env_id == "Pendulum-v1" and reward.segment_length == 10
    assert reward.observation_space.shape == (3,) and reward.action_space.high.tolist() == [2.0]
    assert reward.reward_kwargs == model.reward_kwargs
    assert [entry["session"] for entry in reward.learner.history] == [1, 2, 3]


def test_a_file_that_is_not_a_reward_model_is_refused(tmp_path, trained):
    _, folder = trained
    with pytest.raises(ValueError, match=r"missing.pt does not exist"):
        LearnedReward.load(tmp_path / "missing.pt")
    (tmp_path / "other.pt").write_bytes(b"not a model")
    with pytest.raises(ValueError, match=r"other.pt is not a reward model saved by sb3_pride"):
        LearnedReward.load(tmp_path / "other.pt")
    with pytest.raises(ValueError, match=r"preferences.jsonl is not a reward model") as refused:
        LearnedReward.load(folder / "preferences.jsonl")
    assert "\n" not in str(refused.value)  # one line, not torch's page about weights_only


def test_the_wrapper_gives_r_hat_and_keeps_the_true_reward_for_monitor(trained):
    _, folder = trained
    reward = LearnedReward.load(folder / "reward.pt")
    env = LearnedRewardWrapper(Monitor(gym.make("Pendulum-v1")), folder / "reward.pt")
    observation, _ = env.reset(seed=0)
    true_return, learned = 0.0, []
    for _ in range(200):
        action = env.action_space.sample()
        expected = reward.predict(observation[None], reward.scale_actions(action)[None])[0]
        observation, r_hat, terminated, truncated, info = env.step(action)
        assert r_hat == pytest.approx(float(expected), abs=1e-6)
        true_return += info["true_reward"]
        learned.append(r_hat)
        if terminated or truncated:
            break
    # Monitor, inside, saw the true reward: the episode's return is the env's
    assert info["episode"]["r"] == pytest.approx(true_return, rel=1e-5)
    assert not np.allclose(learned, info["episode"]["r"] / 200)


def test_the_vectorised_wrapper_with_several_envs_normalizes_and_trains_ppo_sac_and_td3(trained):
    _, folder = trained
    reward = LearnedReward.load(folder / "reward.pt")
    venv = VecLearnedReward(make_vec_env("Pendulum-v1", n_envs=3, seed=0), reward)
    observations = venv.reset()
    actions = np.stack([venv.action_space.sample() for _ in range(3)])
    _, rewards, _, infos = venv.step(actions)
    np.testing.assert_allclose(rewards, reward.predict(observations, reward.scale_actions(actions)), atol=1e-6)
    assert all("true_reward" in info for info in infos)
    normalized = VecLearnedReward(make_vec_env("Pendulum-v1", n_envs=2, seed=0), reward, normalize=True)
    normalized.reset()
    for _ in range(50):
        normalized.step(np.stack([normalized.action_space.sample() for _ in range(2)]))
    assert normalized.normalizer is not None and normalized.normalizer.statistics.count > 50
    PPO("MlpPolicy", venv, n_steps=64, batch_size=64, n_epochs=1, seed=0).learn(192)
    SAC("MlpPolicy", venv, learning_starts=50, seed=0).learn(150)
    TD3("MlpPolicy", normalized, learning_starts=50, seed=0).learn(100)


def test_a_wrapper_on_an_env_of_other_spaces_is_refused(trained, tmp_path):
    _, folder = trained
    with pytest.raises(ValueError, match=r"has the observation space Box\(\[-1.2.*\(2,\).*the reward model reads Box.*\(3,\)"):
        LearnedRewardWrapper(gym.make("MountainCarContinuous-v0"), folder / "reward.pt")
    with pytest.raises(ValueError, match=r"has the observation space"):
        VecLearnedReward(make_vec_env("MountainCarContinuous-v0", n_envs=2), folder / "reward.pt")
    # a reward file of other spaces: the wrapper names the space
    other = PEBBLE("MlpPolicy", "MountainCarContinuous-v0", learning_starts=10, segment_length=10)
    other.save_reward_model(tmp_path / "other.pt")
    with pytest.raises(ValueError, match=r"env .*Pendulum.* has the observation space Box.*\(3,\).*reads Box.*\(2,\)"):
        LearnedRewardWrapper(gym.make("Pendulum-v1"), tmp_path / "other.pt")


def test_fit_from_journals_ranks_held_out_pairs_and_a_flipped_teacher_reads_below_chance(trained, tmp_path):
    _, folder = trained
    reward, report = fit_reward([folder / "preferences.jsonl"], held_out=0.25, reward_kwargs=dict(net_arch=(32, 32)))
    assert report.train_pairs == 45 and report.held_out_pairs == 15
    assert report.held_out_accuracy >= 0.7, report
    pairs = PreferenceJournal(folder / "preferences.jsonl").read()
    inputs, labels = np.stack([entry.inputs for entry in pairs]), np.array([entry.label for entry in pairs])
    # the deliberately bad case: the same r̂ judged against flipped labels
    assert preference_accuracy(reward, inputs, 1.0 - labels) <= 0.3
    with pytest.raises(ValueError, match=r"dynamics_consistency.*learn from the agent's stored transitions"):
        fit_reward([folder / "preferences.jsonl"], reward_kwargs=dict(dynamics_consistency=True))
    with pytest.raises(ValueError, match=r"other.jsonl is about other pairs: its env id 'Pendulum-v1' \(this fit: 'Mountain"):
        (tmp_path / "other.jsonl").write_text((folder / "preferences.jsonl").read_text())
        fit_reward([tmp_path / "other.jsonl"], env="MountainCarContinuous-v0")


@pytest.mark.slow
def test_the_command_line_fits_and_reports(trained, tmp_path):
    model, folder = trained
    fitted = subprocess.run(
        [sys.executable, "-m", "sb3_pride.reward", "fit", str(folder / "preferences.jsonl"), "--out", str(tmp_path / "r.pt")],
        capture_output=True, text=True, check=True,
    )  # fmt: skip
    assert "held-out preference accuracy" in fitted.stdout and (tmp_path / "r.pt").exists()
    model.save(tmp_path / "model.zip")
    report = subprocess.run(
        [sys.executable, "-m", "sb3_pride.reward", "report", str(tmp_path / "model.zip"), "--env", "Pendulum-v1",
         "--out", str(tmp_path / "report"), "--episodes", "2"],
        capture_output=True, text=True, check=True,
    )  # fmt: skip
    figures = sorted(path.name for path in (tmp_path / "report").iterdir())
    assert figures == ["episode_0.png", "episode_1.png", "sessions.png"], report.stdout
    assert all((tmp_path / "report" / name).read_bytes()[:4] == b"\x89PNG" for name in figures)
    refused = subprocess.run(
        [sys.executable, "-m", "sb3_pride.reward", "fit", str(tmp_path / "missing.jsonl"), "--out", str(tmp_path / "x.pt")],
        capture_output=True, text=True,
    )  # fmt: skip
    assert refused.returncode == 2 and "missing.jsonl is not a file" in refused.stderr and not (tmp_path / "x.pt").exists()


def test_the_episode_figures_read_a_wrong_reward_model_as_negatively_correlated(tmp_path):
    env = gym.make("Pendulum-v1")
    right = episode_rewards(KnownReward(+1.0), env, episodes=2)
    wrong = episode_rewards(KnownReward(-1.0), env, episodes=2)
    assert all(episode.correlation > 0.99 for episode in right)
    assert all(episode.correlation < -0.99 for episode in wrong)  # r̂ = -r
    figures = reward_report(KnownReward(-1.0), env, tmp_path, history=[{"labels": 20, "correlation": -0.9}], episodes=1)
    assert [figure.name for figure in figures] == ["episode_0.png", "sessions.png"]


@pytest.mark.slow
def test_sac_from_scratch_on_a_pebble_runs_r_hat_comes_within_20_percent_of_that_pebble(tmp_path):
    settings = dict(
        learning_starts=500, unsupervised_steps=500, feedback_interval=1000, max_feedback=200, queries_per_session=50,
        segment_length=25, reward_kwargs=dict(net_arch=(64, 64)), policy_kwargs=dict(net_arch=[64, 64]),
    )  # fmt: skip
    pebble = PEBBLE("MlpPolicy", "Pendulum-v1", seed=0, **settings).learn(5000)
    pebble.save_reward_model(tmp_path / "reward.pt")
    evaluation = Monitor(gym.make("Pendulum-v1"))
    pebble_return, _ = evaluate_policy(pebble, evaluation, n_eval_episodes=10)
    env = LearnedRewardWrapper(Monitor(gym.make("Pendulum-v1")), tmp_path / "reward.pt")
    sac = SAC("MlpPolicy", env, seed=1, learning_starts=500, policy_kwargs=dict(net_arch=[64, 64])).learn(5000)
    sac_return, _ = evaluate_policy(sac, evaluation, n_eval_episodes=10)
    assert sac_return >= pebble_return - 0.2 * abs(pebble_return), (sac_return, pebble_return)
    # the deliberately bad case: the same SAC on a reward model that is wrong (r̂ = -r) falls far short
    wrong = LearnedRewardWrapper(Monitor(gym.make("Pendulum-v1")), KnownReward(-1.0))
    misled = SAC("MlpPolicy", wrong, seed=1, learning_starts=500, policy_kwargs=dict(net_arch=[64, 64])).learn(5000)
    misled_return, _ = evaluate_policy(misled, evaluation, n_eval_episodes=10)
    assert misled_return < pebble_return - 0.2 * abs(pebble_return), (misled_return, pebble_return)


def test_numpy_settings_are_saved_as_plain_numbers_and_read_back(tmp_path):
    from conftest import TINY

    settings = dict(TINY, segment_length=np.int64(10), reward_kwargs=dict(net_arch=(32, 32), learning_rate=np.float64(1e-3)))
    PEBBLE("MlpPolicy", "Pendulum-v1", **settings).save_reward_model(tmp_path / "r.pt")
    reward = LearnedReward.load(tmp_path / "r.pt")
    assert reward.segment_length == 10 and reward.reward_kwargs["learning_rate"] == 1e-3


def test_fit_keeps_a_pair_to_learn_from_and_the_command_line_names_bad_input(trained, tmp_path):
    _, folder = trained
    _, report = fit_reward([folder / "preferences.jsonl"], held_out=0.99, reward_kwargs=dict(net_arch=(8,), epochs=1))
    assert report.train_pairs == 1 and report.held_out_pairs == 59
    with pytest.raises(ValueError, match=r"reward_kwargs: unknown settings \['bogus'\]"):
        fit_reward([folder / "preferences.jsonl"], reward_kwargs=dict(bogus=1))
    for extra, message in (
        (["--env", "NoSuchEnv-v0"], "env 'NoSuchEnv-v0' cannot be made"),
        (["--reward-kwargs", "[1]"], "--reward-kwargs must be a JSON object"),
    ):
        command = [sys.executable, "-m", "sb3_pride.reward", "fit", str(folder / "preferences.jsonl"), "--out",
                   str(tmp_path / "x.pt"), *extra]  # fmt: skip
        refused = subprocess.run(command, capture_output=True, text=True)
        assert refused.returncode == 2 and message in refused.stderr and "Traceback" not in refused.stderr
    assert not (tmp_path / "x.pt").exists()
