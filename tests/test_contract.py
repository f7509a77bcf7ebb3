"""SB3's contract, checked with environments this project did not write: float64 gymnasium MuJoCo envs,
early-terminating envs, SB3's buffer attributes, the critic reset, SAC's arguments, set_env/load checks, episode ends."""

import os
import subprocess
import sys

import gymnasium as gym
import numpy as np
import pytest
import torch as th
from gymnasium import spaces
from stable_baselines3.common.env_util import make_vec_env
from stable_baselines3.common.torch_layers import BaseFeaturesExtractor
from stable_baselines3.common.vec_env import DummyVecEnv, VecNormalize

from sb3_pride import PEBBLE, PRIDE, DualReplayBuffer
from sb3_pride.common.utils import merge_kwargs
from sb3_pride.pebble.pebble import reset_critic
from tests.test_pride import PAPER_MIXING

#: a diffusion phase small enough for tests, retraining from the first feedback session on
TINY_DIFFUSION = merge_kwargs(
    PAPER_MIXING,
    dict(
        diffusion_interval=200,
        synthetic_samples=500,
        generator_kwargs=dict(
            width=32, n_blocks=1, train_steps=50, sample_steps=4, dynamics_kwargs=dict(width=16, train_steps=20)
        ),
    ),
)


@pytest.mark.slow
@pytest.mark.parametrize("algo", [PEBBLE, PRIDE])
def test_float64_mujoco_env_through_several_sessions(tiny_kwargs, algo):
    """gymnasium's MuJoCo envs observe float64: the query selection and the diffusion must take it."""
    env = gym.make("HalfCheetah-v5")
    assert env.observation_space.dtype == np.float64
    tiny_kwargs.update(feedback_interval=100, max_feedback=40, queries_per_session=10, feedback_schedule="constant")
    extra = TINY_DIFFUSION if algo is PRIDE else {}
    model = algo("MlpPolicy", env, seed=0, **tiny_kwargs, **extra)
    model.learn(650)
    assert model.phase.sessions == 4 and len(model.preferences) == 40
    if algo is PRIDE:
        assert model.diffusion_retrains >= 2 and model.replay_buffer.synthetic.size() == 500


@pytest.mark.slow
def test_early_terminating_env_waits_for_episodes_that_hold_a_segment(tiny_kwargs):
    """Hopper's random episodes last ~25 steps: no segment of 100 fits yet, but longer episodes may come."""
    tiny_kwargs.update(segment_length=100)
    model = PEBBLE("MlpPolicy", "Hopper-v5", seed=0, **tiny_kwargs)
    with pytest.warns(UserWarning, match="segment_length=100 is longer than every episode so far"):
        model.learn(500)
    assert model.phase.sessions == 0 and model.phase.next_step > 300  # tried again a segment later
    # an episode that holds a segment turns up: the session takes segments from it
    buffer = model.replay_buffer
    rows = slice(buffer.pos - 120, buffer.pos)
    buffer.dones[rows] = 0
    model.learn(100, reset_num_timesteps=False)
    assert model.phase.sessions == 1


def test_env_whose_step_limit_is_shorter_than_a_segment_is_refused():
    with pytest.raises(ValueError, match="segment_length=50 is longer than an episode of this env"):
        PEBBLE("MlpPolicy", gym.make("Pendulum-v1", max_episode_steps=30))


@pytest.mark.slow
def test_dual_buffer_has_sb3_storage_attributes_and_round_trips(tiny_kwargs, tmp_path):
    """Code written for SB3's ReplayBuffer (SB3's own save/load-replay-buffer test) reads the real transitions."""
    model = PRIDE("MlpPolicy", "Pendulum-v1", seed=0, **tiny_kwargs, **TINY_DIFFUSION)
    model.learn(400)
    buffer = model.replay_buffer
    assert isinstance(buffer, DualReplayBuffer) and buffer.synthetic.size() > 0
    for name in ("observations", "next_observations", "actions", "rewards", "dones", "timeouts"):
        assert getattr(buffer, name) is getattr(buffer.real, name), name
    assert buffer.size() == 400
    model.save_replay_buffer(tmp_path / "buffer.pkl")
    other = PRIDE("MlpPolicy", "Pendulum-v1", seed=1, **tiny_kwargs, **TINY_DIFFUSION)
    other.load_replay_buffer(tmp_path / "buffer.pkl")
    for name in ("observations", "next_observations", "actions", "rewards", "dones", "timeouts"):
        np.testing.assert_array_equal(getattr(other.replay_buffer, name), getattr(buffer, name))


class LinearExtractor(BaseFeaturesExtractor):
    """A features extractor with weights of its own (SAC's default FlattenExtractor has none)."""

    def __init__(self, observation_space: spaces.Box, features_dim: int = 8):
        super().__init__(observation_space, features_dim)
        self.linear = th.nn.Linear(int(np.prod(observation_space.shape)), features_dim)

    def forward(self, observations: th.Tensor) -> th.Tensor:
        return th.relu(self.linear(observations))


def parameters(module: th.nn.Module) -> list[th.Tensor]:
    return [parameter.detach().clone() for parameter in module.parameters()]


@pytest.mark.parametrize("share", [False, True])
def test_critic_reset_renews_the_critics_own_features_extractor(tiny_kwargs, share):
    policy_kwargs = dict(net_arch=[16], features_extractor_class=LinearExtractor, share_features_extractor=share)
    tiny_kwargs.update(policy_kwargs=policy_kwargs)
    model = PEBBLE("MlpPolicy", "Pendulum-v1", seed=0, **tiny_kwargs)
    model.learn(250)  # pre-training: the critic (and its extractor) learned r_int
    critic_extractor, actor = parameters(model.critic.features_extractor), parameters(model.actor)
    reset_critic(model)
    renewed = [
        not th.equal(before, after)
        for before, after in zip(critic_extractor, parameters(model.critic.features_extractor), strict=True)
    ]
    assert all(renewed) is not share  # its own extractor is renewed; the actor's (shared) one is kept
    for before, after in zip(actor, parameters(model.actor), strict=True):
        assert th.equal(before, after)
    for critic, target in zip(model.critic.state_dict().values(), model.critic_target.state_dict().values(), strict=True):
        assert th.equal(critic, target)


def test_sac_arguments_that_cannot_work_are_refused():
    with pytest.raises(ValueError, match="n_steps must be 1, got 3: n-step returns"):
        PEBBLE("MlpPolicy", "Pendulum-v1", n_steps=3)
    PEBBLE("MlpPolicy", "Pendulum-v1", n_steps=1)  # SAC's default is accepted
    image = spaces.Box(0, 255, (16, 16, 3), np.uint8)
    env = gym.wrappers.TransformObservation(gym.make("Pendulum-v1"), lambda obs: np.zeros((16, 16, 3), np.uint8), image)
    with pytest.raises(ValueError, match=r"image observations .* not supported"):
        PRIDE("MlpPolicy", env)


def test_set_env_and_load_check_the_env_as_the_constructor_does(tiny_kwargs, tmp_path):
    model = PEBBLE("MlpPolicy", "Pendulum-v1", **tiny_kwargs)
    leaky = VecNormalize(DummyVecEnv([lambda: gym.make("Pendulum-v1")]), norm_reward=True)
    with pytest.raises(ValueError, match="norm_reward=True"):
        model.set_env(leaky)
    model.set_env(VecNormalize(DummyVecEnv([lambda: gym.make("Pendulum-v1")]), norm_reward=False))
    model.save(tmp_path / "model")
    with pytest.raises(ValueError, match="norm_reward=True"):
        PEBBLE.load(tmp_path / "model", env=leaky)
    # the saved segment_length (10), not the constructor's default (50), decides whether episodes hold a segment
    short = gym.make("Pendulum-v1", max_episode_steps=30)
    assert PEBBLE.load(tmp_path / "model", env=short).segment_length == 10


def test_a_new_learn_ends_the_interrupted_episode_in_the_buffer(tiny_kwargs):
    model = PEBBLE("MlpPolicy", "Pendulum-v1", seed=0, **tiny_kwargs)
    model.learn(300)  # Pendulum's episodes last 200 steps: the second is at step 100 when learn() returns
    buffer = model.replay_buffer
    assert buffer.dones[299, 0] == 0
    model.learn(50, reset_num_timesteps=True)  # SB3 resets the env
    # the interrupted episode ends at row 299, as a truncation (the critic still bootstraps from it)
    assert buffer.dones[299, 0] == 1 and buffer.timeouts[299, 0] == 1
    assert buffer.dones[199, 0] == 1 and buffer.timeouts[199, 0] == 1  # Pendulum's own time limit, untouched
    model.learn(50, reset_num_timesteps=False)  # the env is not reset: nothing marked
    assert buffer.dones[349, 0] == 0


def test_episode_ends_of_two_envs_and_true_terminations_are_kept():
    env = make_vec_env("Pendulum-v1", n_envs=2, seed=0)
    model = PEBBLE("MlpPolicy", env, learning_starts=50, policy_kwargs=dict(net_arch=[16]))
    model.learn(60)
    buffer = model.replay_buffer
    last = buffer.pos - 1
    buffer.dones[last, 1], buffer.timeouts[last, 1] = 1, 0  # as if env 1 had terminated there
    buffer.end_episodes()
    assert list(buffer.dones[last]) == [1, 1] and list(buffer.timeouts[last]) == [1, 0]


@pytest.mark.slow
def test_the_demo_shows_a_progress_bar(tmp_path):
    result = subprocess.run(
        [sys.executable, "-m", "sb3_pride", "--algo", "pebble", "--env", "Pendulum-v1", "--timesteps", "300",
         "--eval-episodes", "1"],
        cwd=tmp_path, capture_output=True, text=True, env={**os.environ, "MUJOCO_GL": "disable"},
    )  # fmt: skip
    assert result.returncode == 0, result.stderr[-2000:]
    assert "300/300" in result.stdout + result.stderr  # SB3's progress bar (tqdm + rich), at its end
    assert "true return of the final policy" in result.stdout


@pytest.mark.slow
def test_metaworld_runs_repeat_from_their_seed():
    # MT1 draws its task variations from numpy's global RNG when built and picks one before the reset's seed takes
    # effect: without SeededTasks two runs with the same seed saw different objects and goals
    def first_steps(seed):
        env = make_vec_env("sb3_pride/button-press-v3", n_envs=2, seed=seed)
        env.action_space.seed(seed)
        key, position = np.random.get_state()[1].copy(), np.random.get_state()[2]
        rows = [env.reset()]
        # the seeded reset leaves numpy's global RNG as it was
        np.testing.assert_array_equal(np.random.get_state()[1], key)
        assert np.random.get_state()[2] == position
        for _ in range(5):
            rows.append(env.step(np.stack([env.action_space.sample() for _ in range(2)]))[0])
        return np.stack(rows)

    first = first_steps(0)
    np.testing.assert_array_equal(first_steps(0), first)
    assert not np.array_equal(first_steps(1), first)
    assert not np.array_equal(first[:, 0], first[:, 1])  # the two envs (seeds 0 and 1) differ too
