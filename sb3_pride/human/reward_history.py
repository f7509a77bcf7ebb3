"""
The reward model's history as a ``WebTeacher``'s page shows it: one entry per reward update (``session``, ``step``,
``labels``, ``accuracy``, ``correlation``), copied into plain values that JSON carries as they are.
"""

import math
import numbers
from collections.abc import Iterable, Mapping
from typing import Any

import numpy as np


def plain_value(value: Any) -> Any:
    """
    ``value`` as JSON carries it: None, a bool, an int, a str, a finite float, or None for a NaN or infinite one (JSON
    has no NaN); anything else as its text.

    :param value: a value of a history entry (NumPy's numbers included)
    """
    if value is None or isinstance(value, (bool, str)):
        return value
    if isinstance(value, np.bool_):
        return bool(value)
    if isinstance(value, numbers.Integral):
        return int(value)
    if isinstance(value, numbers.Real):
        number = float(value)
        return number if math.isfinite(number) else None
    return str(value)


def plain_history(history: Iterable[Mapping[str, Any]]) -> list[dict[str, Any]]:
    """
    A copy of ``history`` that shares nothing with it: a list of new dicts of plain values (``plain_value``).

    :param history: one mapping per reward update, oldest first
    """
    return [{str(key): plain_value(value) for key, value in entry.items()} for entry in history]
