from sb3_pride.pride.pride import PRIDE
from sb3_pride.pride.recipes import PAPER_RECIPE, PAPER_SCALE_RECIPE, RECIPES, SYNTHER_SIZES, recipe

__all__ = ["PAPER_RECIPE", "PAPER_SCALE_RECIPE", "PRIDE", "RECIPES", "SYNTHER_SIZES", "recipe"]
