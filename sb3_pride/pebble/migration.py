"""
Settings and saved models of earlier versions, brought to this one in one place: PEBBLE's flat reward-learning,
query and pre-training settings (0.1.0, 0.2.0) moved into ``reward_kwargs``, ``query_kwargs`` and
``pretraining_kwargs``; PRIDE's flat generator settings (0.1.0) into ``generator_kwargs``; the state saved models hold
under old names moved to the parts that own it now.
"""

import warnings
from typing import Any

from sb3_pride.common.utils import caller_stacklevel

#: PEBBLE's settings of versions 0.1.0 and 0.2.0 that are now entries of a structured setting: (setting, key)
RENAMED_PEBBLE_SETTINGS: dict[str, tuple[str, str]] = {
    "ensemble_size": ("reward_kwargs", "ensemble_size"),
    "reward_net_arch": ("reward_kwargs", "net_arch"),
    "reward_learning_rate": ("reward_kwargs", "learning_rate"),
    "reward_batch_size": ("reward_kwargs", "batch_size"),
    "reward_epochs": ("reward_kwargs", "epochs"),
    "reward_early_stop": ("reward_kwargs", "early_stop"),
    "temporal_crop": ("reward_kwargs", "temporal_crop"),
    "robust_labels": ("reward_kwargs", "robust_labels"),
    "pseudo_labels": ("reward_kwargs", "pseudo_labels"),
    "dynamics_consistency": ("reward_kwargs", "dynamics_consistency"),
    "exploration_bonus": ("reward_kwargs", "exploration_bonus"),
    "candidates_multiplier": ("query_kwargs", "candidates_multiplier"),
    "max_query_episodes": ("query_kwargs", "max_query_episodes"),
    "hybrid_replay": ("query_kwargs", "hybrid_replay"),
    "entropy_k": ("pretraining_kwargs", "entropy_k"),
    "critic_reset_updates": ("pretraining_kwargs", "critic_reset_updates"),
}

#: PEBBLE's structured settings
STRUCTURED_SETTINGS = ("reward_kwargs", "query_kwargs", "pretraining_kwargs")

#: PRIDE's settings of version 0.1.0 and their place in ``generator_kwargs``
RENAMED_GENERATOR_SETTINGS: dict[str, str] = {
    "diffusion_width": "width",
    "diffusion_blocks": "n_blocks",
    "diffusion_train_steps": "train_steps",
    "diffusion_sample_steps": "sample_steps",
    "diffusion_warm_start": "warm_start",
    "diffusion_normalization": "normalization",
    "diffusion_kwargs": "diffusion_kwargs",
    "model_state_change": "model_state_change",
    "generation": "generation",
    "anchor_noise": "anchor_noise",
    "diffusion_window": "window",
    "synthetic_keep_quantile": "keep_quantile",
    "synthetic_filter": "filter",
    "fidelity_check": "fidelity_check",
    "dynamics_kwargs": "dynamics_kwargs",
}

#: torch state dicts saved under other names: a PRIDE of 0.1.0 (its diffusion)
RENAMED_PARAMETERS: dict[str, str] = {
    "diffusion": "generator.diffusion",
}

#: attributes of models saved by 0.1.0 and 0.2.0 that hold nothing this version reads
OBSOLETE_ATTRIBUTES = ("_web_teacher", "_journal_cache", "_pending_feedback", "_teacher_records", "_warned_short_episodes")


def move_renamed_settings(given: dict[str, Any], structured: dict[str, dict[str, Any] | None]) -> dict[str, dict[str, Any]]:
    """
    The structured settings (``reward_kwargs``, ...) with the flat keywords of earlier versions in ``given`` moved into
    them, each with a ``DeprecationWarning`` that names its new place. A setting given both ways, or a keyword PEBBLE
    never had, is refused.

    :param given: the flat keywords given (their names must be in ``RENAMED_PEBBLE_SETTINGS``)
    :param structured: each structured setting as given (None: not given)
    """
    unknown = sorted(set(given) - set(RENAMED_PEBBLE_SETTINGS))
    if unknown:
        raise TypeError(f"PEBBLE got unexpected keyword arguments {unknown}")
    for name, value in structured.items():
        if value is not None and not isinstance(value, dict):
            raise ValueError(f"{name} must be a dict of settings or None, got {value!r}")
    moved = {name: dict(value or {}) for name, value in structured.items()}
    for old, value in given.items():
        setting, key = RENAMED_PEBBLE_SETTINGS[old]
        if key in moved[setting]:
            raise ValueError(f"{old} is given twice: as a keyword and as {setting}[{key!r}]; give it in {setting} only")
        message = f"{old} is deprecated: give it as {setting}={{{key!r}: ...}}"
        warnings.warn(message, DeprecationWarning, stacklevel=caller_stacklevel())
        moved[setting][key] = value
    return moved


def migrate_saved_model(state: dict[str, Any]) -> None:
    """
    Bring the attributes of a model saved by 0.1.0 or 0.2.0 (``state``, its ``__dict__`` before ``_setup_model``) to
    this version, in place: flat settings into their structured settings, the journal count and the teacher into the
    feedback loop's places (``migrated_*`` entries, read by ``PEBBLE._setup_model``); a model of this version is left
    as it is.
    """
    if "_scripted_teacher" in state:  # 0.1.0: its scripted teacher, random state kept
        saved = state.pop("_scripted_teacher")
        if saved is not None:
            state["_named_teacher"] = saved
    for old, (setting, key) in RENAMED_PEBBLE_SETTINGS.items():
        if old in state:
            value = state.pop(old)
            if key == "net_arch":
                value = tuple(value)
            state.setdefault(setting, {})[key] = value
    if "label_selection" in state:  # RIME's running selection, now the reward learner's
        state["migrated_label_selection"] = state.pop("label_selection")
    if "journal_entries" in state:
        state["migrated_journal_entries"] = state.pop("journal_entries")
    if "_named_teacher" in state:
        state["migrated_named_teacher"] = state.pop("_named_teacher")
    for name in OBSOLETE_ATTRIBUTES:
        state.pop(name, None)


def migrate_generator_settings(saved: dict[str, Any]) -> dict[str, Any]:
    """
    The ``generator_kwargs`` of a PRIDE saved by version 0.1.0, from the flat settings it holds (removed from
    ``saved``, a model's ``__dict__``), with the diffusion steps of 0.1.0 and 0.2.0 (4000) where it gives none; an
    empty dict for a model saved by a later version. A development model's
    ``synthetic_consistency`` (the generator's transitions in REED's consistency passes, not kept) is dropped, with a
    warning where it was on.
    """
    if saved.pop("synthetic_consistency", 0.0):
        warnings.warn(
            "this model was saved with synthetic_consistency, which PRIDE no longer offers (the generator's transitions "
            "did not help reward learning): its consistency passes now take the real transitions only",
            stacklevel=2,
        )
    settings = {new: saved.pop(old) for old, new in RENAMED_GENERATOR_SETTINGS.items() if old in saved}
    if any(name in saved for name in RENAMED_PEBBLE_SETTINGS):  # saved by 0.1.0 or 0.2.0, whose default was 4000
        settings.setdefault("train_steps", 4000)
    return settings


def migrate_parameters(parameters: Any) -> Any:
    """A saved model's torch state dicts, by the names this version saves them under."""
    if not isinstance(parameters, dict):
        return parameters
    return {RENAMED_PARAMETERS.get(name, name): value for name, value in parameters.items()}
