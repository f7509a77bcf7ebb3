"""
Argument checks shared by the algorithms and models (errors name the parameter and what was expected), and the
seeding of their layers and draws.
"""

import contextlib
import dataclasses
import math
import os
import sys
from collections.abc import Callable, Iterator
from typing import Any

import numpy as np
import torch as th


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


def check_choice(name: str, value: Any, choices: tuple[str, ...]) -> None:
    """Raise ``ValueError`` naming ``name`` unless ``value`` is one of ``choices``."""
    if value not in choices:
        raise ValueError(f"{name} must be one of {choices}, got {value!r}")


def check_real(name: str, value: Any, accepted: Callable[[float], bool], expected: str) -> None:
    """
    Raise ``ValueError`` naming ``name`` unless ``value`` is a real number (not a bool, not NaN) that ``accepted``
    takes; ``expected`` says which, e.g. ``"in [0, 1]"``.
    """
    is_real = isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(value, (bool, np.bool_))
    if not is_real or np.isnan(value) or not accepted(value):
        raise ValueError(f"{name} must be {expected}, got {value!r}")


def merge_kwargs(base: dict[str, Any], overrides: dict[str, Any]) -> dict[str, Any]:
    """
    ``base`` updated with ``overrides``, where both hold a dict under the same key (a ``*_kwargs`` argument) merged
    the same way instead of replaced: ``merge_kwargs(recipe, {"generator_kwargs": {"train_steps": 2000}})`` keeps the
    recipe's other generator settings. Neither argument is changed.
    """
    merged = dict(base)
    for key, value in overrides.items():
        if isinstance(value, dict) and isinstance(merged.get(key), dict):
            merged[key] = merge_kwargs(merged[key], value)
        else:
            merged[key] = value
    return merged


def make_option(name: str, value: Any, settings_class: Callable[..., Any]) -> Any:
    """
    An option given as ``False`` (off: None), ``True`` (``settings_class()``, the published settings) or a dict of
    ``settings_class``'s settings; anything else, or a setting it does not have, raises ``ValueError`` naming ``name``.
    """
    if isinstance(value, (bool, np.bool_)):
        return settings_class() if value else None
    if not isinstance(value, dict):
        raise ValueError(f"{name} must be True, False or a dict of {settings_class.__name__}'s settings, got {value!r}")
    known = {field.name for field in dataclasses.fields(settings_class) if field.init}  # type: ignore[arg-type]
    unknown = sorted(set(value) - known)
    if unknown:
        raise ValueError(f"{name}: unknown settings {unknown}; {settings_class.__name__} takes {sorted(known)}")
    return settings_class(**value)


@contextlib.contextmanager
def seeded(seed: int, device: th.device | None = None) -> Iterator[None]:
    """
    Inside, torch's global RNGs draw from ``seed``: the CPU's default generator (layers are built on the CPU), and
    ``device``'s own generator when it is a CUDA device; afterwards every global RNG is as it was. Not
    ``th.manual_seed``: it would reseed every CUDA generator, which the fork does not restore.
    """
    on_cuda = device is not None and device.type == "cuda"
    with th.random.fork_rng(devices=[device] if on_cuda else []):
        th.random.default_generator.manual_seed(seed)
        if on_cuda:
            with th.cuda.device(device):
                th.cuda.manual_seed(seed)
        yield


def caller_stacklevel(skipped: tuple[str, ...] = ("sb3_pride", "stable_baselines3")) -> int:
    """
    The ``stacklevel`` for ``warnings.warn`` (called by the function that calls this one) that names the user's line:
    the first frame outside the packages ``skipped``. Python shows a ``DeprecationWarning`` only where it names
    ``__main__``'s code, so a fixed level would hide it behind the algorithm's own frames.
    """
    modules = [sys.modules.get(name) for name in skipped]
    folders = [os.path.dirname(module.__file__) for module in modules if module is not None and module.__file__]
    frame, level = sys._getframe(2), 2  # the caller of the function that warns: stacklevel 2
    while frame.f_back is not None and any(frame.f_code.co_filename.startswith(folder + os.sep) for folder in folders):
        frame, level = frame.f_back, level + 1
    return level


def plain(value: Any, nan_as_none: bool = False) -> Any:
    """
    ``value`` with NumPy scalars and arrays made Python numbers and lists, in dicts, lists and tuples at any depth: what
    ``torch.load(weights_only=True)`` reads back, and (``nan_as_none``: a NaN or infinite float as None) what JSON
    carries.
    """
    if isinstance(value, np.ndarray):
        value = value.tolist()
    elif isinstance(value, np.generic):
        value = value.item()
    if isinstance(value, dict):
        return {plain(key): plain(item, nan_as_none) for key, item in value.items()}
    if isinstance(value, (list, tuple)):
        return type(value)(plain(item, nan_as_none) for item in value)
    if nan_as_none and isinstance(value, float) and not math.isfinite(value):
        return None
    return value
