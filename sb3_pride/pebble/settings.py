"""PEBBLE's settings checked before anything is made, each error naming the setting and what it expects."""

from typing import Any

import numpy as np
from stable_baselines3.common.buffers import ReplayBuffer

from sb3_pride.common.queries import QuerySampler
from sb3_pride.common.reward_learner import RewardLearner
from sb3_pride.common.utils import check_non_negative_ints, check_positive_ints
from sb3_pride.pebble.migration import move_renamed_settings

#: ``pretraining_kwargs``: k of the k-NN state entropy (PEBBLE: 5), gradient steps on r̂ after the critic reset (100)
PRETRAINING_DEFAULTS = {"entropy_k": 5, "critic_reset_updates": 100}


def preference_settings(
    renamed: dict[str, Any],
    segment_length: int,
    query_selection: str,
    reward_kwargs: dict[str, Any] | None,
    query_kwargs: dict[str, Any] | None,
    pretraining_kwargs: dict[str, Any] | None,
) -> dict[str, dict[str, Any]]:
    """
    ``reward_kwargs``, ``query_kwargs`` and ``pretraining_kwargs`` as the model keeps them, checked (the latter with
    its defaults filled in), the flat settings of earlier versions in ``renamed`` moved into them with a
    ``DeprecationWarning``.
    """
    structured = move_renamed_settings(
        renamed, dict(reward_kwargs=reward_kwargs, query_kwargs=query_kwargs, pretraining_kwargs=pretraining_kwargs)
    )
    QuerySampler(segment_length, query_selection, **structured["query_kwargs"])
    RewardLearner.check_kwargs(structured["reward_kwargs"], segment_length)
    unknown = sorted(set(structured["pretraining_kwargs"]) - set(PRETRAINING_DEFAULTS))
    if unknown:
        raise ValueError(f"pretraining_kwargs: unknown settings {unknown}; it takes {sorted(PRETRAINING_DEFAULTS)}")
    pretraining = structured["pretraining_kwargs"] = {**PRETRAINING_DEFAULTS, **structured["pretraining_kwargs"]}
    check_positive_ints(entropy_k=pretraining["entropy_k"])
    check_non_negative_ints(critic_reset_updates=pretraining["critic_reset_updates"])
    return structured


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
