"""Argument checks shared by the algorithms and models: errors name the parameter and what was expected."""

from typing import Any

import numpy as np


def check_positive_ints(**params: Any) -> None:
    """Raise ``ValueError`` naming the first parameter that is not an integer > 0."""
    for name, value in params.items():
        if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value <= 0:
            raise ValueError(f"{name} must be a positive integer, got {value!r}")


def check_non_negative_ints(**params: Any) -> None:
    """Raise ``ValueError`` naming the first parameter that is not an integer >= 0."""
    for name, value in params.items():
        if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 0:
            raise ValueError(f"{name} must be a non-negative integer, got {value!r}")
