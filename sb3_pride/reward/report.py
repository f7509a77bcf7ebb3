"""
What r̂ learned: r̂ beside the true reward along evaluation episodes of the agent, with the ensemble's spread, and
corr(r̂, r) over the run's feedback sessions, as PNG figures.
"""

import os
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import gymnasium as gym
import numpy as np

from sb3_pride.reward.learned_reward import LearnedReward

#: ``policy(observation) -> action``: how the episodes are played (e.g. a model's deterministic ``predict``)
Policy = Callable[[np.ndarray], np.ndarray]


@dataclass
class EpisodeRewards:
    """One episode's per-step true rewards r, r̂ (the ensemble's mean) and the members' spread."""

    true: np.ndarray
    learned: np.ndarray
    spread: np.ndarray

    @property
    def correlation(self) -> float:
        """Pearson's corr(r̂, r) along the episode (NaN when either is constant)."""
        if np.std(self.true) == 0 or np.std(self.learned) == 0:
            return float("nan")
        return float(np.corrcoef(self.learned, self.true)[0, 1])


def episode_rewards(
    reward: LearnedReward, env: gym.Env, policy: Policy | None = None, episodes: int = 3, seed: int = 0
) -> list[EpisodeRewards]:
    """
    Play ``episodes`` episodes of ``env`` with ``policy`` (None: random actions) and record, step by step, the env's
    reward and r̂(s_t, a_t) with its spread, read as PEBBLE's replay buffer reads them.
    """
    reward.check_spaces(env.observation_space, env.action_space, f"env {env}")
    env.action_space.seed(seed)
    results = []
    for episode in range(episodes):
        observation, _ = env.reset(seed=seed + episode)
        observations, actions, true = [], [], []
        done = False
        while not done:
            action = env.action_space.sample() if policy is None else policy(observation)
            observations.append(np.asarray(observation, dtype=np.float32).ravel())
            actions.append(reward.scale_actions(np.asarray(action)).ravel())
            observation, true_reward, terminated, truncated, _ = env.step(action)
            true.append(float(true_reward))
            done = terminated or truncated
        stacked_obs, stacked_actions = np.stack(observations), np.stack(actions)
        results.append(
            EpisodeRewards(
                np.array(true),
                reward.predict(stacked_obs, stacked_actions),
                reward.spread(stacked_obs, stacked_actions),
            )
        )
    return results


def pyplot():
    """matplotlib's pyplot, drawing to files (no display)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def plot_episode(rewards: EpisodeRewards, path: str | os.PathLike, title: str = "") -> Path:
    """One episode's r̂ (with ± the members' spread, on its own axis: r̂'s scale is arbitrary) beside the true reward."""
    plt = pyplot()
    steps = np.arange(len(rewards.true))
    figure, true_axis = plt.subplots(figsize=(8, 3.5))
    true_axis.plot(steps, rewards.true, color="tab:gray", label="true reward r")
    true_axis.set_xlabel("step")
    true_axis.set_ylabel("r")
    learned_axis = true_axis.twinx()
    learned_axis.plot(steps, rewards.learned, color="tab:blue", label="r̂ (ensemble mean)")
    low, high = rewards.learned - rewards.spread, rewards.learned + rewards.spread
    learned_axis.fill_between(steps, low, high, color="tab:blue", alpha=0.25, label="± members' spread")
    learned_axis.set_ylabel("r̂")
    figure.legend(loc="upper right", fontsize="small")
    true_axis.set_title(f"{title}corr(r̂, r) = {rewards.correlation:.3f}")
    figure.tight_layout()
    figure.savefig(path, dpi=100)
    plt.close(figure)
    return Path(path)


def plot_history(history: list[dict], path: str | os.PathLike) -> Path:
    """corr(r̂, r) on the stored transitions after each feedback session (``RewardLearner.history``)."""
    plt = pyplot()
    figure, axis = plt.subplots(figsize=(6, 3.5))
    labels = [entry["labels"] for entry in history]
    axis.plot(labels, [entry["correlation"] for entry in history], marker="o")
    axis.axhline(0.0, color="tab:gray", linewidth=0.8)
    axis.set_ylim(-1.05, 1.05)
    axis.set_xlabel("labels learned from")
    axis.set_ylabel("corr(r̂, r)")
    axis.set_title("r̂ after each feedback session")
    figure.tight_layout()
    figure.savefig(path, dpi=100)
    plt.close(figure)
    return Path(path)


def reward_report(
    reward: LearnedReward,
    env: gym.Env,
    out: str | os.PathLike,
    policy: Policy | None = None,
    history: list[dict] | None = None,
    episodes: int = 3,
    seed: int = 0,
) -> list[Path]:
    """
    Write the figures of what r̂ learned into the folder ``out``: ``episode_<n>.png`` per episode (r̂ beside r along
    it) and, given the run's ``history``, ``sessions.png`` (corr(r̂, r) after each feedback session). An ``out`` that
    is a file, or an env whose spaces r̂ cannot read, is refused before the folder is made.

    :return: the figures written
    """
    folder = Path(out)
    if folder.exists() and not folder.is_dir():
        raise ValueError(f"out {folder} is a file: give a folder for the figures")
    reward.check_spaces(env.observation_space, env.action_space, f"env {env}")  # before anything is made
    folder.mkdir(parents=True, exist_ok=True)
    figures = [
        plot_episode(rewards, folder / f"episode_{number}.png", f"episode {number}: ")
        for number, rewards in enumerate(episode_rewards(reward, env, policy, episodes, seed))
    ]
    if history:
        figures.append(plot_history(history, folder / "sessions.png"))
    return figures
