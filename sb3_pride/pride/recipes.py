"""
Named PRIDE configurations, written once and used by the class, the hyperparameter files (``recipe: paper``), the
docs and the tests alike.

``PRIDE()``'s own defaults are the best configuration measured at the CPU tier; ``PAPER_RECIPE`` is the algorithm as
the paper (Feng et al., 2025) and SynthER (Lu et al., 2023) describe it, at whatever diffusion sizes are given beside
it (``SYNTHER_SIZES`` for theirs).
"""

import copy
from typing import Any

from sb3_pride.common.utils import merge_kwargs

#: the paper's PRIDE: synthetic data from the first reward model on at full u, in place of real rows in each
#: minibatch, from an unconditional diffusion model of [s, a, s'] refitted from scratch on all real transitions
#: every 10k steps, every sample kept
PAPER_RECIPE: dict[str, Any] = dict(
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
