"""
Teachers label segment pairs: the ``Teacher`` protocol, the ``InteractiveTeacher`` protocol of teachers that watch
the segments (a person), B-Pref's scripted teachers, and the registry that resolves a teacher by name.
"""

import functools
from collections.abc import Callable
from dataclasses import dataclass, field
from abc import ABC, abstractmethod
from typing import TYPE_CHECKING, Any, Protocol, runtime_checkable

import numpy as np

from sb3_pride.common.journal import JournalEntry
from sb3_pride.common.queries import SegmentPairs

if TYPE_CHECKING:
    from stable_baselines3.common.vec_env import VecEnv

    from sb3_pride.common.buffers import PreferenceReplayBuffer


@runtime_checkable
class Teacher(Protocol):
    """
    Anything that labels pairs of segments (a person behind a UI, a script, a learned judge).

    Called with ``SegmentPairs``; returns one float per pair, the paper's μ: the probability that σ1 is
    preferred to σ0, i.e. 0.0 (σ0 ≻ σ1), 1.0 (σ1 ≻ σ0), 0.5 ("equally preferable") or NaN (skipped: no label).
    A teacher for people reads ``pairs.observations`` / ``pairs.actions`` (and must not need ``true_rewards``).
    """

    def __call__(self, pairs: SegmentPairs) -> np.ndarray: ...


@dataclass
class FeedbackContext:
    """
    What an ``InteractiveTeacher`` is told of the feedback session it answers.

    :param session: the number of this feedback session (1 for the first)
    :param asked_before: queries asked in the earlier sessions
    :param budget: Q, the run's total query budget (``max_feedback``)
    :param record: journals answers the moment they are given (flushed to disk before it returns)
    :param retract: ``retract(session, entry_id=None, annotator=None)`` journals that an answer of a session was
        taken back: its latest answer to query ``entry_id`` (``JournalEntry.id``) by ``annotator``, or its last answer
    :param log: ``log(key, value)`` records a number in the model's logger (e.g. an annotator's agreement)
    """

    session: int
    asked_before: int
    budget: int
    record: Callable[[list[JournalEntry]], None]
    retract: Callable[..., None]
    log: Callable[[str, float], None] = field(default=lambda key, value: None)


class InteractiveTeacher(ABC):
    """
    A teacher that watches the segments and answers over time (a person behind a UI). Subclass it: the algorithms
    treat a teacher as interactive only if it is one (a plain callable is a ``Teacher``). It is never given the model,
    only what it needs:

    - ``attach(env, buffer)``, when the model is made, loaded or given a new env: check that ``env`` can be shown and
      switch on the recording of what it needs to show it beside the transitions of ``buffer`` (e.g. simulator
      states: ``SegmentPairs.render_states``); raise ``ValueError`` if it cannot;
    - ``ask(pairs, context)``, at each feedback session: one μ per pair (0, 1, 0.5, or NaN for a skip), every
      answer journaled by ``context.record`` as it is given (a crash mid-session loses none);
    - ``show_progress(asked, budget)``, when attached and after every feedback session: the run's queries asked so
      far and its budget, for a UI to show (optional);
    - ``show_reward_history(history)``, after every reward update: one dict per update so far (``session``, ``step``,
      ``labels``, ``accuracy`` and ``correlation``, corr(r̂, r) on stored transitions), for a UI to show whether the
      labels teach r̂ anything (optional).
    """

    @abstractmethod
    def attach(self, env: "VecEnv", buffer: "PreferenceReplayBuffer") -> None: ...

    @abstractmethod
    def ask(self, pairs: SegmentPairs, context: FeedbackContext) -> np.ndarray: ...

    def show_progress(self, asked: int, budget: int) -> None:  # noqa: B027 (optional: nothing to show by default)
        """The run's queries asked so far and its budget (``max_feedback``)."""

    def show_reward_history(self, history: list[dict]) -> None:  # noqa: B027 (optional: nothing to show by default)
        """Every reward update so far (``RewardLearner.history``): its session, step, labels, accuracy, corr(r̂, r)."""


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
            raise ValueError(f"name must be one of B-Pref's teachers {sorted(TEACHER_PRESETS)}, got {name!r}")
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


#: makes a teacher from the run's seed
TeacherFactory = Callable[[int | None], Any]
#: teachers by name: B-Pref's presets, and those registered by ``register_teacher`` (``"web"``, by
#: ``sb3_pride.human``)
TEACHERS: dict[str, TeacherFactory] = {name: functools.partial(ScriptedTeacher.from_preset, name) for name in TEACHER_PRESETS}


def register_teacher(name: str, factory: TeacherFactory) -> None:
    """
    Make ``teacher=name`` mean ``factory(seed)`` in ``PEBBLE``/``PRIDE`` and the hyperparameter files. A name is
    registered once: registering it again replaces it.
    """
    if not isinstance(name, str) or not name:
        raise ValueError(f"name must be a non-empty string, got {name!r}")
    if not callable(factory):
        raise ValueError(f"factory must be callable (seed -> teacher), got {factory!r}")
    TEACHERS[name] = factory


def make_teacher(teacher: "str | Teacher | InteractiveTeacher", seed: int | None = None) -> "Teacher | InteractiveTeacher":
    """A registered name becomes its teacher (a B-Pref preset a seeded ``ScriptedTeacher``); a teacher is returned as is."""
    if isinstance(teacher, str):
        if teacher not in TEACHERS:
            raise ValueError(f"teacher must be a Teacher or one of {sorted(TEACHERS)}, got {teacher!r}")
        return TEACHERS[teacher](seed)
    if not (callable(teacher) or isinstance(teacher, InteractiveTeacher)):
        raise ValueError(f"teacher must be a registered name or a Teacher (a callable), got {type(teacher).__name__}")
    return teacher
