"""
Named PRIDE configurations, written once and used by the class, the hyperparameter files (``recipe: paper``), the
docs and the tests alike.

``PRIDE()``'s own defaults are the configuration chosen at the CPU tier to keep half the labels; ``PAPER_RECIPE`` is
the algorithm as the paper (Feng et al., 2025) and SynthER (Lu et al., 2023) describe it, at whatever diffusion sizes
and label budget are given beside it (``SYNTHER_SIZES`` for theirs); combine it with other settings through
``merge_kwargs(PAPER_RECIPE, {...})`` (``sb3_pride.common.utils``), which merges the structured ones entry by entry.
"""

import copy
from typing import Any

import numpy as np

from sb3_pride.pride.generator import TransitionGenerator
from sb3_pride.common.utils import check_real, merge_kwargs
from sb3_pride.pebble.earlier_versions import RENAMED_GENERATOR_SETTINGS, renamed_settings_error

#: PRIDE()'s reward learning on top of PEBBLE's: REED's consistency pre-training (Metcalf et al., 2023), five passes over
#: the stored transitions per feedback session (``reward_kwargs`` given to PRIDE() go on top of these)
PRIDE_REWARD_DEFAULTS: dict[str, Any] = dict(dynamics_consistency=dict(epochs=5))


def with_reward_defaults(reward_kwargs: Any) -> Any:
    """
    PRIDE's ``reward_kwargs``: a copy of ``PRIDE_REWARD_DEFAULTS`` with the given ones merged on top, entry by entry
    (``{"dynamics_consistency": {"batch_size": 64}}`` keeps the five passes; ``True`` is REED's published settings);
    anything but a dict or None is left for PEBBLE's check to refuse.
    """
    if reward_kwargs is not None and not isinstance(reward_kwargs, dict):
        return reward_kwargs
    return merge_kwargs(copy.deepcopy(PRIDE_REWARD_DEFAULTS), reward_kwargs or {})


#: the paper's PRIDE: PEBBLE's reward learning and label schedule, synthetic data from the first reward model on at
#: u = 0.5, in place of real rows in each minibatch, from an unconditional diffusion model of [s, a, s'] refitted
#: from scratch on all real transitions every 10k steps, every sample kept
PAPER_RECIPE: dict[str, Any] = dict(
    feedback_schedule="constant",
    reward_kwargs=dict(dynamics_consistency=False),
    synthetic_ratio=0.5,
    synthetic_start=0,
    synthetic_ramp=0,
    synthetic_on_top=False,
    diffusion_interval=10_000,
    generator_kwargs=dict(
        model_state_change=False,
        generation="unconditional",
        warm_start=False,
        window=None,
        keep_quantile=1.0,
    ),
)

#: SynthER's diffusion model and sampler (its online configuration), as ``generator_kwargs``
SYNTHER_SIZES: dict[str, Any] = dict(
    width=1024,
    n_blocks=6,
    train_steps=100_000,
    sample_steps=128,
    diffusion_kwargs=dict(dim_t=256, batch_size=256, learning_rate=3e-4, sample_batch_size=100_000),
)

#: the paper's PRIDE at the paper's scale: SynthER's diffusion, 200k samples per generation (``hyperparams/pride.yml``)
PAPER_SCALE_RECIPE: dict[str, Any] = merge_kwargs(
    PAPER_RECIPE, dict(synthetic_samples=200_000, generator_kwargs=SYNTHER_SIZES)
)

#: the configurations a hyperparameter entry names with ``recipe:`` (``"default"``: PRIDE()'s own defaults)
RECIPES: dict[str, dict[str, Any]] = {"default": {}, "paper": PAPER_RECIPE, "paper_scale": PAPER_SCALE_RECIPE}


def recipe(name: str) -> dict[str, Any]:
    """The PRIDE keyword arguments of a named configuration (a copy); ValueError naming the known ones otherwise."""
    if name not in RECIPES:
        raise ValueError(f"recipe must be one of {sorted(RECIPES)}, got {name!r}")
    return copy.deepcopy(RECIPES[name])


def expand_recipe(entry: dict[str, Any]) -> dict[str, Any]:
    """
    A hyperparameter entry with its ``recipe:`` key (if any) replaced by the named configuration, the entry's own
    settings on top (``generator_kwargs`` merged, not replaced).
    """
    if "recipe" not in entry:
        return dict(entry)
    settings = dict(entry)
    return merge_kwargs(recipe(settings.pop("recipe")), settings)


def check_generator_kwargs(generator_kwargs: Any, other_kwargs: dict[str, Any]) -> None:
    """
    Fail at construction, not at the first retrain: ``generator_kwargs`` must be ``TransitionGenerator`` arguments
    other than the run's seed and device (PRIDE's), and no generator setting may come as a keyword of its own (as in
    version 0.1: a ``TypeError`` names its new place).
    """
    old = {name: other_kwargs[name] for name in other_kwargs if name in RENAMED_GENERATOR_SETTINGS}
    if old:
        raise renamed_settings_error("PRIDE", old)
    if generator_kwargs is None:
        return
    if not isinstance(generator_kwargs, dict) or {"seed", "device"} & set(generator_kwargs):
        raise ValueError(
            "generator_kwargs must be a dict of TransitionGenerator arguments (the run's seed and device are PRIDE's), "
            f"got {generator_kwargs!r}"
        )
    try:
        TransitionGenerator(1, 1, **{**generator_kwargs, "device": "cpu"})
    except TypeError as error:
        raise ValueError(f"generator_kwargs must be valid TransitionGenerator arguments: {error}") from None


def check_synthetic_settings(synthetic_ratio: Any, synthetic_on_top: Any) -> None:
    """PRIDE's synthetic share u in [0, 1], and the rows on top only with u < 1."""
    check_real("synthetic_ratio", synthetic_ratio, lambda u: 0.0 <= u <= 1.0, "in [0, 1]")
    if not isinstance(synthetic_on_top, (bool, np.bool_)):
        raise ValueError(f"synthetic_on_top must be True or False, got {synthetic_on_top!r}")
    if synthetic_on_top and synthetic_ratio == 1.0:
        raise ValueError(
            "synthetic_on_top=True needs synthetic_ratio < 1 (each minibatch holds batch_size / (1 - u) rows, "
            "batch_size of them real), got synthetic_ratio=1.0; for minibatches of synthetic rows only, set "
            "synthetic_on_top=False"
        )
