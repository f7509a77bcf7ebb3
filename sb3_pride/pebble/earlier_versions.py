"""
Versions 0.1 and 0.2 gave PEBBLE's reward-learning, query and pre-training settings flat and PRIDE's generator
settings flat (0.1); this version takes them in ``reward_kwargs``, ``query_kwargs``, ``pretraining_kwargs`` and
``generator_kwargs`` only. An old name given to a constructor raises a ``TypeError`` that names its new place, and a
model saved by those versions is refused with a message naming the version that reads it (0.2.0): its answers are
not lost, its preference journal is read by this version as it is (``prior_preferences``).
"""

import json
import os
import zipfile
from typing import Any

#: the version that reads models saved by 0.1 and 0.2
READS_EARLIER_MODELS = "0.2.0"

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


def renamed_settings_error(algorithm: str, given: dict[str, Any]) -> TypeError:
    """The error for keywords ``algorithm`` does not take, naming the new place of each that an earlier version took."""
    hints = []
    for name in sorted(given):
        if name in RENAMED_PEBBLE_SETTINGS:
            setting, key = RENAMED_PEBBLE_SETTINGS[name]
            hints.append(f"{name} is now {setting}={{{key!r}: ...}}")
        elif name in RENAMED_GENERATOR_SETTINGS:
            hints.append(f"{name} is now generator_kwargs={{{RENAMED_GENERATOR_SETTINGS[name]!r}: ...}}")
    unknown = sorted(set(given) - set(RENAMED_PEBBLE_SETTINGS) - set(RENAMED_GENERATOR_SETTINGS))
    if unknown:
        hints.append(f"{algorithm} takes no {', '.join(unknown)}")
    return TypeError(f"{algorithm} got unexpected keyword arguments: {'; '.join(hints)}")


def refuse_earlier_versions(path: Any) -> None:
    """
    Refuse a model file saved by 0.1 or 0.2 (its settings flat, no ``reward_kwargs``) before anything of it is loaded,
    naming the version that reads it. A file that cannot be read is left to SB3's ``load`` to report.
    """
    if not isinstance(path, (str, os.PathLike)):
        return
    for candidate in (os.fspath(path), f"{os.fspath(path)}.zip"):
        if os.path.isfile(candidate):
            try:
                with zipfile.ZipFile(candidate) as archive:
                    saved = json.loads(archive.read("data"))
            except (OSError, KeyError, ValueError, zipfile.BadZipFile):
                return
            if isinstance(saved, dict) and "reward_kwargs" not in saved and "segment_length" in saved:
                raise ValueError(
                    f"{candidate} was saved by sb3_pride 0.1 or 0.2, whose settings this version no longer reads: load "
                    f"it with sb3_pride {READS_EARLIER_MODELS} (pip install 'sb3_pride=={READS_EARLIER_MODELS}'); its "
                    "preference journal is read by this version as it is (prior_preferences)"
                )
            return
