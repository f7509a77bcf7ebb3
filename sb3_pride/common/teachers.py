"""Teachers label segment pairs: the ``Teacher`` protocol, and B-Pref's scripted teachers."""

from typing import Protocol, runtime_checkable

import numpy as np

from sb3_pride.common.queries import SegmentPairs


@runtime_checkable
class Teacher(Protocol):
    """
    Anything that labels pairs of segments (a person behind a UI, a script, a learned judge).

    Called with ``SegmentPairs``; returns one float per pair, the paper's μ: the probability that σ1 is
    preferred to σ0, i.e. 0.0 (σ0 ≻ σ1), 1.0 (σ1 ≻ σ0), 0.5 ("equally preferable") or NaN (skipped: no label).
    A teacher for people reads ``pairs.observations`` / ``pairs.actions`` (and must not need ``true_rewards``).
    """

    def __call__(self, pairs: SegmentPairs) -> np.ndarray: ...


#: B-Pref's simulated teachers (README of rll-research/BPref); ``beta=None`` is perfectly rational
TEACHER_PRESETS: dict[str, dict[str, float | None]] = {
    "oracle": dict(beta=None, gamma=1.0, eps_mistake=0.0, eps_skip=0.0, eps_equal=0.0),
    "mistake": dict(beta=None, gamma=1.0, eps_mistake=0.1, eps_skip=0.0, eps_equal=0.0),
    "noisy": dict(beta=1.0, gamma=1.0, eps_mistake=0.0, eps_skip=0.0, eps_equal=0.0),
    "skip": dict(beta=None, gamma=1.0, eps_mistake=0.0, eps_skip=0.1, eps_equal=0.0),
    "myopic": dict(beta=None, gamma=0.9, eps_mistake=0.0, eps_skip=0.0, eps_equal=0.0),
    "equal": dict(beta=None, gamma=1.0, eps_mistake=0.0, eps_skip=0.0, eps_equal=0.1),
}


class ScriptedTeacher:
    """
    B-Pref's simulated human (Lee et al., 2021), labelling pairs from the true reward. In order:

    1. skip: pairs whose better undiscounted segment return is ``<= eps_skip × return_scale`` get no label;
    2. equal: pairs whose undiscounted returns differ by less than ``eps_equal × return_scale`` get 0.5;
    3. myopic: step t of a k-step segment weighs ``gamma ** (k - 1 - t)`` (later steps matter more);
    4. rational (``beta=None``): the segment with the larger return is preferred; stochastic (``beta > 0``):
       σ1 is preferred with probability ``sigmoid(beta × (R1 - R0))`` (Bradley–Terry);
    5. mistake: each label is flipped with probability ``eps_mistake``.

    ``return_scale`` comes with the pairs: the mean true return of a segment in recent episodes (B-Pref: the mean
    of recent episode returns × segment length / episode length). B-Pref multiplies its thresholds by ε twice
    after the first session; here they are ε × scale every time.

    :param beta: rationality (None: perfectly rational)
    :param gamma: myopic discount
    :param eps_mistake: probability of flipping a label
    :param eps_skip: skip threshold, as a fraction of ``return_scale``
    :param eps_equal: equal threshold, as a fraction of ``return_scale``
    :param seed: seed of the teacher's own random generator
    """

    def __init__(
        self,
        beta: float | None = None,
        gamma: float = 1.0,
        eps_mistake: float = 0.0,
        eps_skip: float = 0.0,
        eps_equal: float = 0.0,
        seed: int | None = None,
    ):
        if beta is not None and beta <= 0:
            raise ValueError(f"beta must be None (perfectly rational) or > 0, got {beta}")
        if not 0.0 < gamma <= 1.0:
            raise ValueError(f"gamma must be in (0, 1], got {gamma}")
        for name, value in (("eps_mistake", eps_mistake), ("eps_skip", eps_skip), ("eps_equal", eps_equal)):
            if not 0.0 <= value <= 1.0:
                raise ValueError(f"{name} must be in [0, 1], got {value}")
        self.beta = beta
        self.gamma = gamma
        self.eps_mistake = eps_mistake
        self.eps_skip = eps_skip
        self.eps_equal = eps_equal
        self.rng = np.random.default_rng(seed)

    @classmethod
    def from_preset(cls, name: str, seed: int | None = None) -> "ScriptedTeacher":
        """One of B-Pref's teachers: ``oracle``, ``mistake``, ``noisy``, ``skip``, ``myopic``, ``equal``."""
        if name not in TEACHER_PRESETS:
            raise ValueError(
                f'teacher must be a Teacher, "web" (a person, in a browser) or one of {sorted(TEACHER_PRESETS)}, got {name!r}'
            )
        return cls(**TEACHER_PRESETS[name], seed=seed)  # type: ignore[arg-type]

    def step_weights(self, segment_length: int) -> np.ndarray:
        """Myopic weight of each step: ``gamma ** (k - 1 - t)``."""
        return self.gamma ** np.arange(segment_length - 1, -1, -1, dtype=np.float64)

    def __call__(self, pairs: SegmentPairs) -> np.ndarray:
        returns = pairs.true_rewards.sum(axis=-1, dtype=np.float64)  # (n, 2), undiscounted
        scale = abs(pairs.return_scale)
        skipped = (returns.max(axis=1) <= self.eps_skip * scale) if self.eps_skip > 0 else np.zeros(len(pairs), bool)
        equal = np.abs(returns[:, 0] - returns[:, 1]) < self.eps_equal * scale

        weighted = (pairs.true_rewards * self.step_weights(pairs.true_rewards.shape[-1])).sum(axis=-1)
        if self.beta is None:
            labels = (weighted[:, 1] > weighted[:, 0]).astype(np.float64)
        else:
            p_second = 1.0 / (1.0 + np.exp(-self.beta * (weighted[:, 1] - weighted[:, 0])))
            labels = (self.rng.random(len(pairs)) < p_second).astype(np.float64)
        flips = self.rng.random(len(pairs)) < self.eps_mistake
        labels[flips] = 1.0 - labels[flips]
        labels[equal] = 0.5
        labels[skipped] = np.nan
        return labels


def make_teacher(teacher: str | Teacher, seed: int | None = None) -> Teacher:
    """A preset name becomes a ``ScriptedTeacher``; a ``Teacher`` is returned as is."""
    if isinstance(teacher, str):
        return ScriptedTeacher.from_preset(teacher, seed=seed)
    if not callable(teacher):
        raise ValueError(f"teacher must be a preset name or a callable Teacher, got {type(teacher).__name__}")
    return teacher
