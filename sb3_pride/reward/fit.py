"""
r̂ from journals alone: the answers of one or more preference journals, read as ``PEBBLE(prior_preferences=...)``
reads them, fitted into a ``LearnedReward`` with part of them held out to say how well it ranks pairs it never saw.
"""

import os
from dataclasses import dataclass
from typing import Any

import gymnasium as gym
import numpy as np
import torch as th
from gymnasium import spaces

from sb3_pride.common.journal import PreferenceJournal, journal_header
from sb3_pride.reward.learned_reward import LearnedReward
from sb3_pride.common.priors import read_prior_preferences
from sb3_pride.reward.ensemble import PreferenceDataset


#: the most epochs of a fit from journals alone, unless ``reward_kwargs`` says
FIT_EPOCHS = 1000


@dataclass
class FitReport:
    """How a fit went: pairs learned from and held out, and the share of strict labels r̂ ranks the teacher's way."""

    train_pairs: int
    held_out_pairs: int
    train_accuracy: float
    held_out_accuracy: float
    epochs: int


def preference_accuracy(reward: LearnedReward, inputs: np.ndarray, labels: np.ndarray) -> float:
    """
    The share of pairs with a strict label (0 or 1) whose segment r̂ gives the larger return (the ensemble's mean
    summed over the segment, Eq. 1) is the one the teacher preferred; NaN when there is none.
    """
    strict = (labels == 0) | (labels == 1)
    if not strict.any():
        return float("nan")
    k = inputs.shape[2]
    obs_dim = int(np.prod(reward.observation_space.shape))
    pairs = inputs[strict]
    returns = reward.predict(pairs[..., :obs_dim], pairs[..., obs_dim:]).reshape(len(pairs), 2, k).sum(axis=-1)
    return float(np.mean((returns[:, 1] > returns[:, 0]) == (labels[strict] == 1)))


def journal_spaces(journals: list[str], env: str | gym.Env | None) -> tuple[spaces.Box, spaces.Box, str | None]:
    """The spaces r̂ reads: ``env``'s, or those of the env the journals' headers name (which must agree)."""
    ids = sorted({str((PreferenceJournal(path).header() or {}).get("env_id")) for path in journals} - {"None"})
    if env is None and len(ids) != 1:
        found = f"name {ids}" if ids else "name no env id (no header)"
        raise ValueError(f"journals {journals} {found}: give the env (--env) whose spaces r̂ reads")
    try:
        made: gym.Env = gym.make(env or ids[0]) if not isinstance(env, gym.Env) else env
    except gym.error.Error as error:
        raise ValueError(f"env {env or ids[0]!r} cannot be made: {error}") from None
    try:
        observation_space, action_space = made.observation_space, made.action_space
        env_id = made.spec.id if made.spec is not None else None
    finally:
        if made is not env:
            made.close()
    if not isinstance(observation_space, spaces.Box) or not isinstance(action_space, spaces.Box):
        raise ValueError(f"env {env}: r̂ reads Box observations and actions, got {observation_space} and {action_space}")
    return observation_space, action_space, env_id


def fit_reward(
    journals: list[str | os.PathLike],
    env: str | gym.Env | None = None,
    reward_kwargs: dict[str, Any] | None = None,
    held_out: float = 0.2,
    seed: int = 0,
    device: str = "auto",
) -> tuple[LearnedReward, FitReport]:
    """
    Fit PEBBLE's reward model (Lee, Smith & Abbeel, ICML 2021, Eqs. 1–2) on the answers of ``journals`` alone: read
    and checked as ``PEBBLE(prior_preferences=...)`` reads them (skips and undos applied; a journal of other pairs, one
    without answers, or one with a line that is not an answer refused, the error naming the file), a random
    ``held_out`` share kept apart to measure the fit.

    :param journals: preference journals (``PEBBLE(preference_journal=...)``, a ``WebTeacher`` team's)
    :param env: the env (an id or a gymnasium env) whose spaces r̂ reads; None: the one the journals' headers name
    :param reward_kwargs: ``RewardLearner`` settings (the ensemble, ``epochs``, ``early_stop``, ``temporal_crop``,
        ``robust_labels``); the options that learn from stored transitions are refused. ``epochs`` defaults to
        ``FIT_EPOCHS`` (B-Pref's early stop at 97% training accuracy ends it sooner): one fit from scratch stands for
        a run's many sessions of up to 50 epochs each
    :param held_out: the share of the pairs held out, in [0, 1)
    :param seed: seeds the split and the training
    :param device: where the networks live
    :return: r̂ and how the fit went
    """
    paths = [os.fspath(path) for path in journals]
    if not paths:
        raise ValueError("fit_reward needs at least one journal")
    if not 0 <= held_out < 1:
        raise ValueError(f"held_out must be in [0, 1), got {held_out}")
    for path in paths:
        if not os.path.isfile(path):
            raise ValueError(f"journal {path} is not a file")
    observation_space, action_space, env_id = journal_spaces(paths, env)
    segment_length = 0
    for path in paths:  # from the first header that says, else the first answer's pair
        journal = PreferenceJournal(path, "journal")
        segment_length = (journal.header() or {}).get("segment_length") or 0
        if not segment_length:
            entries = journal.read(strict=True)
            if not entries:
                raise ValueError(f"journal {path} holds no answers (an empty journal, or its header alone)")
            segment_length = entries[0].inputs.shape[1]
        if segment_length:
            break
    header = journal_header(env_id, observation_space.shape, action_space.shape, segment_length)
    input_dim = int(np.prod(observation_space.shape)) + int(np.prod(action_space.shape))
    priors = read_prior_preferences(paths, header, (2, segment_length, input_dim), name="journal", reader="this fit")
    if len(priors.labels) == 0:
        raise ValueError(f"journals {paths} hold no labelled answers")
    rng = np.random.default_rng(seed)
    order = rng.permutation(len(priors.labels))
    n_held_out = min(round(held_out * len(order)), len(order) - 1)  # at least one pair to learn from
    held, kept = order[:n_held_out], order[n_held_out:]
    th.manual_seed(seed)
    reward_kwargs = {"epochs": FIT_EPOCHS, **(reward_kwargs or {})}
    reward = LearnedReward.new(observation_space, action_space, segment_length, reward_kwargs, env_id, device)
    dataset = PreferenceDataset(segment_length, input_dim)
    dataset.add(priors.inputs[kept], priors.labels[kept])
    result = reward.learner.learn(dataset, None, None, rng)
    report = FitReport(
        train_pairs=len(kept),
        held_out_pairs=len(held),
        train_accuracy=preference_accuracy(reward, priors.inputs[kept], priors.labels[kept]),
        held_out_accuracy=preference_accuracy(reward, priors.inputs[held], priors.labels[held]),
        epochs=result.epochs,
    )
    return reward, report
