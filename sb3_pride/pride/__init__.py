from sb3_pride.pride.pride import PRIDE
from sb3_pride.pride.recipes import (
    PAPER_RECIPE,
    PAPER_SCALE_RECIPE,
    PRIDE_REWARD_DEFAULTS,
    RECIPES,
    SYNTHER_SIZES,
    recipe,
)

__all__ = ["PAPER_RECIPE", "PAPER_SCALE_RECIPE", "PRIDE", "PRIDE_REWARD_DEFAULTS", "RECIPES", "SYNTHER_SIZES", "recipe"]
