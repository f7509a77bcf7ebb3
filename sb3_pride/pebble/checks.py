"""PEBBLE's settings checked before anything is made, each error naming the setting and what it expects."""

import json
import os
import zipfile
from typing import Any

import numpy as np
from stable_baselines3.common.buffers import ReplayBuffer
from stable_baselines3.common.save_util import load_from_zip_file

from sb3_pride.reward.consistency import DynamicsConsistency
from sb3_pride.common.journal import find_journal
from sb3_pride.common.queries import QuerySampler
from sb3_pride.reward.learner import RewardLearner
from sb3_pride.common.utils import check_non_negative_ints, check_positive_ints, make_option
from sb3_pride.pebble.feedback import FeedbackSchedule
from sb3_pride.pebble.earlier_versions import RENAMED_PEBBLE_SETTINGS, refuse_earlier_versions, renamed_settings_error

#: PEBBLE's structured settings
STRUCTURED_SETTINGS = ("reward_kwargs", "query_kwargs", "pretraining_kwargs")

#: ``pretraining_kwargs``: k of the k-NN state entropy (PEBBLE: 5), gradient steps on r̂ after the critic reset (100)
PRETRAINING_DEFAULTS = {"entropy_k": 5, "critic_reset_updates": 100}


def preference_settings(
    segment_length: int,
    query_selection: str,
    reward_kwargs: dict[str, Any] | None,
    query_kwargs: dict[str, Any] | None,
    pretraining_kwargs: dict[str, Any] | None,
) -> dict[str, dict[str, Any]]:
    """
    ``reward_kwargs``, ``query_kwargs`` and ``pretraining_kwargs`` as the model keeps them (copies), checked (the
    latter with its defaults filled in).
    """
    given = dict(reward_kwargs=reward_kwargs, query_kwargs=query_kwargs, pretraining_kwargs=pretraining_kwargs)
    for name, value in given.items():
        if value is not None and not isinstance(value, dict):
            raise ValueError(f"{name} must be a dict of settings or None, got {value!r}")
    structured = {name: dict(value or {}) for name, value in given.items()}
    QuerySampler.from_settings(segment_length, query_selection, structured["query_kwargs"])
    RewardLearner.check_kwargs(structured["reward_kwargs"], segment_length)
    unknown = sorted(set(structured["pretraining_kwargs"]) - set(PRETRAINING_DEFAULTS))
    if unknown:
        raise ValueError(f"pretraining_kwargs: unknown settings {unknown}; it takes {sorted(PRETRAINING_DEFAULTS)}")
    pretraining = structured["pretraining_kwargs"] = {**PRETRAINING_DEFAULTS, **structured["pretraining_kwargs"]}
    check_positive_ints(entropy_k=pretraining["entropy_k"])
    check_non_negative_ints(critic_reset_updates=pretraining["critic_reset_updates"])
    return structured


def check_feedback_settings(
    max_feedback: Any,
    feedback_interval: Any,
    queries_per_session: Any,
    feedback_schedule: Any,
    unsupervised_steps: Any,
    asynchronous_feedback: Any,
) -> None:
    """
    Q, M and K positive ints, a label schedule ``FeedbackSchedule`` takes, pre-training steps >= 0, True or False.
    """
    check_positive_ints(max_feedback=max_feedback, feedback_interval=feedback_interval)
    check_positive_ints(queries_per_session=queries_per_session)
    FeedbackSchedule(feedback_schedule, queries_per_session, max_feedback)
    check_non_negative_ints(unsupervised_steps=unsupervised_steps)
    if not isinstance(asynchronous_feedback, (bool, np.bool_)):
        raise ValueError(f"asynchronous_feedback must be True or False, got {asynchronous_feedback!r}")


def saved_journal(path: Any) -> str | None:
    """
    The ``preference_journal`` a model file holds, read from its settings alone (None when it has none, or when the
    file cannot be read: SB3's ``load`` then says why). SB3 opens ``path``, else ``path`` with ".zip" added.
    """
    if not isinstance(path, (str, os.PathLike)):
        return None
    for candidate in (os.fspath(path), f"{os.fspath(path)}.zip"):
        if os.path.isfile(candidate):
            try:
                with zipfile.ZipFile(candidate) as archive:
                    journal = json.loads(archive.read("data")).get("preference_journal")
            except (OSError, KeyError, ValueError, zipfile.BadZipFile):
                return None
            return journal if isinstance(journal, str) else None
    return None


def load_kwargs(path: Any, kwargs: dict[str, Any], device: Any, custom_objects: dict[str, Any] | None) -> dict[str, Any]:
    """
    ``load()``'s keyword arguments: the run's ``preference_journal`` found wherever the model is loaded from
    (``find_journal``: from the model file's folder up, else beside it, else from the working folder) unless given,
    and the structured settings given merged into the saved ones (``loaded_settings``). A model saved by 0.1 or 0.2
    is refused (``refuse_earlier_versions``), and so is a name of theirs.
    """
    refuse_earlier_versions(path)
    renamed = {name: kwargs[name] for name in kwargs if name in RENAMED_PEBBLE_SETTINGS}
    if renamed:
        raise renamed_settings_error("load()", renamed)
    journal = None if "preference_journal" in kwargs else saved_journal(path)
    if journal is not None:
        kwargs = {**kwargs, "preference_journal": find_journal(journal, path)}
    if set(kwargs) & set(STRUCTURED_SETTINGS):
        saved, _, _ = load_from_zip_file(path, device=device, custom_objects=custom_objects)
        kwargs = loaded_settings(path, saved or {}, kwargs)
    return kwargs


def loaded_settings(path: Any, saved: dict[str, Any], kwargs: dict[str, Any]) -> dict[str, Any]:
    """
    ``load()``'s keyword arguments with each structured setting given (``reward_kwargs``, ...) merged into the saved
    one entry by entry. REED's ``dynamics_consistency`` may change its settings but not be turned on or off (its heads
    are saved with the model) nor change its optimizer (whose state is saved too).

    :param saved: the saved model's attributes (``load_from_zip_file``'s data)
    """
    for name in STRUCTURED_SETTINGS:
        given = kwargs.pop(name, None)
        if given is not None and not isinstance(given, dict):
            raise ValueError(f"{name} must be a dict of settings or None, got {given!r}")
        if given:
            kwargs[name] = {**(saved.get(name) or {}), **given}
    was, now = (
        make_option("dynamics_consistency", settings.get("dynamics_consistency", False), DynamicsConsistency)
        for settings in (saved.get("reward_kwargs") or {}, kwargs.get("reward_kwargs", saved.get("reward_kwargs")) or {})
    )
    if (was is None) != (now is None) or (was is not None and now is not None and was.optimizer != now.optimizer):
        raise ValueError(
            f"reward_kwargs: the model at {path} was saved with dynamics_consistency={was}, and loading cannot turn it "
            f"on or off nor change its optimizer (got {now}); leave dynamics_consistency out"
        )
    return kwargs


def check_sac_arguments(
    n_steps: int, gradient_steps: Any, replay_buffer_class: type[ReplayBuffer] | None, buffer_class: type[ReplayBuffer]
) -> None:
    """Refuse SAC's arguments that cannot work with relabeled rewards and the true rewards kept aside."""
    if isinstance(gradient_steps, bool) or not isinstance(gradient_steps, (int, np.integer)):
        # SB3's: -1 as many updates as env steps collected, 0 none (a user's own loop calls train())
        raise ValueError(f"gradient_steps must be an integer, got {gradient_steps!r}")
    if n_steps != 1:
        raise ValueError(
            f"n_steps must be 1, got {n_steps}: n-step returns sum stored rewards along a trajectory, but PEBBLE "
            "relabels every stored reward with r̂ after each reward update, so the sums would mix rewards of "
            "different models"
        )
    if replay_buffer_class is not None and not issubclass(replay_buffer_class, buffer_class):
        raise ValueError(
            f"replay_buffer_class must subclass {buffer_class.__name__} (true rewards kept aside), "
            f"got {replay_buffer_class.__name__}"
        )
