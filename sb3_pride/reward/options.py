"""
Reward-learning options: ways to learn more from each label, or to explore where r̂ is unsure, that plug into the
reward learner's training loop (``RewardLearner``). An option is a class of its settings (a dataclass) with the hooks
it needs, registered by name with :func:`register_reward_option`; ``reward_kwargs[name]`` turns it on: ``True`` (its
published settings), a dict of its settings, or ``False`` (off, the default). The built-ins (REED's
``dynamics_consistency``, SURF's ``pseudo_labels``, RIME's ``robust_labels``, RUNE's ``exploration_bonus``) are
registered the same way as a user's own.
"""

import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, ClassVar

import numpy as np
import torch as th

from sb3_pride.common.utils import check_real

if TYPE_CHECKING:
    from sb3_pride.common.buffers import PreferenceReplayBuffer
    from sb3_pride.common.queries import QuerySampler
    from sb3_pride.reward.learner import RewardLearner
    from sb3_pride.reward.ensemble import PreferenceDataset, RewardEnsemble


@dataclass(frozen=True)
class LearningData:
    """
    What the options are given before a feedback session's training: D, the agent's replay buffer and the query
    sampler (both None where r̂ is fitted from journals alone, which an option with ``needs_transitions`` refuses), and
    the learner's random generator.
    """

    preferences: "PreferenceDataset"
    buffer: "PreferenceReplayBuffer | None"
    queries: "QuerySampler | None"
    rng: np.random.Generator


class RewardOption:
    """
    The hooks of the reward learner's training loop an option may fill; each does nothing by default. The options on
    are called in the order they were registered, at every feedback session:

    - ``setup(learner)``: once, when the learner is made (e.g. REED's heads on the ensemble's encoder);
    - ``prepare(learner, data)``: before the session's training, with what the learner has (``LearningData``: D, the
      agent's replay buffer and the query sampler, the learner's random generator);
    - ``choose_labels(ensemble, inputs, labels, given)``: before each epoch, which pairs it trains on and with which
      labels (RIME): ``(rows of D, labels of every pair)``, or None to leave them as they are;
    - ``extra_loss(ensemble, n_pairs, rng, temporal_crop)``: at each minibatch of ``n_pairs`` pairs per member, a loss
      added to the Bradley–Terry loss (Eq. 2), or None (SURF's pseudo-labels);
    - ``finish()``: after the session's training, the figures to log under ``reward_model/``.
    """

    #: True: it learns from the agent's stored transitions, which r̂ fitted from preferences alone does not have
    needs_transitions: ClassVar[bool] = False
    #: a dataclass's fields (an option is a dataclass of its settings)
    __dataclass_fields__: ClassVar[dict[str, Any]]

    def setup(self, learner: "RewardLearner") -> None:
        pass

    def prepare(self, learner: "RewardLearner", data: "LearningData") -> None:
        pass

    def choose_labels(
        self, ensemble: "RewardEnsemble", inputs: th.Tensor, labels: th.Tensor, given: np.ndarray
    ) -> tuple[np.ndarray, th.Tensor] | None:
        return None

    def extra_loss(
        self, ensemble: "RewardEnsemble", n_pairs: int, rng: np.random.Generator, temporal_crop: tuple[int, int] | None
    ) -> th.Tensor | None:
        return None

    def finish(self) -> dict[str, Any]:
        return {}


@dataclass
class RobustLabels(RewardOption):
    """
    RIME's sample selection for noisy preferences (Cheng et al., ICML 2024, §4.1): before each epoch, every label's
    divergence from the ensemble's prediction, ℓ = −[(1 − μ) ln(1 − P̂) − μ ln P̂] with P̂ the members' mean
    P[σ1 ≻ σ0], decides how it is used:

    - trusted (trained on as given) when ℓ < τ_lower = −ln ρ + α ρ + min(β_t s², 3), with ρ the largest divergence
      among the labels trusted so far and s² their variance (running averages over epochs, rate 0.1), and β_t
      decreasing linearly from ``beta_init`` to ``beta_min`` over ``beta_decay_epochs`` epochs;
    - flipped (trained on as 1 − μ) when ℓ > −ln ``flip_probability``: the ensemble is that sure of the opposite
      (never a 0.5 "equally good" label, which flipping leaves as it is);
    - left out of that epoch otherwise.

    The first epoch trusts every label (RIME starts ρ at 0: its first threshold is unbounded), so an untrained model
    flips nothing. An epoch that would keep no label trains on all of them as given. Defaults: RIME's DMC and
    Meta-World runs (α = 0.5, β from 3 to 1 over 60 epochs, flip below probability 0.001); RIME keeps the variance
    of all trusted divergences by count, here it is a running average like ρ. RIME also warm-starts the reward model
    on the pre-training phase's intrinsic reward; that part is not done here. The running values persist across
    feedback sessions (they are saved with the model).

    :param alpha: α, the weight of ρ in the base threshold
    :param beta_init: β at the first epoch
    :param beta_min: β after ``beta_decay_epochs``
    :param beta_decay_epochs: reward-learning epochs over which β decreases
    :param flip_probability: a label whose predicted probability is below this is flipped
    """

    alpha: float = 0.5
    beta_init: float = 3.0
    beta_min: float = 1.0
    beta_decay_epochs: int = 60
    flip_probability: float = 0.001
    # the running values (not settings)
    epochs: int = field(default=0, init=False)
    max_divergence: float | None = field(default=None, init=False)
    divergence_variance: float = field(default=0.0, init=False)
    #: how many labels the last epoch trusted and flipped
    trusted: int = field(default=0, init=False)
    flipped: int = field(default=0, init=False)

    def __post_init__(self) -> None:
        for name in ("alpha", "beta_init", "beta_min"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not 0 <= value < math.inf:
                raise ValueError(f"robust_labels: {name} must be a finite number >= 0, got {value!r}")
        if self.beta_min > self.beta_init:
            raise ValueError(f"robust_labels: beta_min must be <= beta_init, got {self.beta_min} > {self.beta_init}")
        decay = self.beta_decay_epochs
        if isinstance(decay, bool) or not isinstance(decay, int) or decay < 1:
            raise ValueError(f"robust_labels: beta_decay_epochs must be an integer >= 1, got {self.beta_decay_epochs!r}")
        if not (isinstance(self.flip_probability, float) and 0 < self.flip_probability < 0.5):
            raise ValueError(f"robust_labels: flip_probability must be a float in (0, 0.5), got {self.flip_probability!r}")

    @property
    def beta(self) -> float:
        """β_t: from ``beta_init`` down to ``beta_min``, linearly over ``beta_decay_epochs`` epochs."""
        return max(self.beta_min, self.beta_init - (self.beta_init - self.beta_min) * self.epochs / self.beta_decay_epochs)

    def select(self, divergence: np.ndarray, labels: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """
        One epoch's choice: (trusted, flipped) boolean masks of the labels μ ``labels`` with divergences
        ``divergence``; the running values are updated from the trusted ones.
        """
        if self.max_divergence is None:  # the first epoch trusts every label, and sets ρ from them
            trusted, flipped = np.ones(len(divergence), bool), np.zeros(len(divergence), bool)
            self.max_divergence = 0.0
        else:
            rho = max(self.max_divergence, 1e-8)
            lower = -np.log(rho) + self.alpha * rho + min(self.beta * self.divergence_variance, 3.0)
            flipped = (divergence > -np.log(self.flip_probability)) & (labels != 0.5)
            trusted = (divergence < lower) & ~flipped
            if not (trusted | flipped).any():  # nothing kept: this epoch trains on every label as given
                trusted = np.ones(len(divergence), bool)
        if trusted.any():
            self.max_divergence = 0.9 * self.max_divergence + 0.1 * float(divergence[trusted].max())
            self.divergence_variance = 0.9 * self.divergence_variance + 0.1 * float(divergence[trusted].var())
        self.epochs += 1
        self.trusted, self.flipped = int(trusted.sum()), int(flipped.sum())
        return trusted, flipped

    def choose_labels(
        self, ensemble: "RewardEnsemble", inputs: th.Tensor, labels: th.Tensor, given: np.ndarray
    ) -> tuple[np.ndarray, th.Tensor]:
        """The epoch's pairs: the trusted ones as given and the flipped ones as 1 − μ (``select``)."""
        trusted, flipped = self.select(ensemble.label_divergence(inputs, labels), given)
        return np.flatnonzero(trusted | flipped), th.where(th.as_tensor(flipped, device=ensemble.device), 1.0 - labels, labels)

    def finish(self) -> dict[str, Any]:
        return {"trusted_labels": self.trusted, "flipped_labels": self.flipped}


@dataclass
class PseudoLabels(RewardOption):
    """
    SURF's semi-supervised reward learning (Park et al., ICLR 2022, §4.1): beside each minibatch of labelled pairs,
    ``ratio`` × as many unlabelled pairs drawn from the replay buffer; each member labels them itself, ŷ = 1[P̂_m > 0.5],
    and learns from those it is confident about, max(P̂_m, 1 − P̂_m) > ``threshold``, with the Bradley–Terry loss
    weighted by ``weight`` (on cropped segments when ``temporal_crop`` is on, as SURF does). ``unlabeled_per_label``
    unlabelled pairs are drawn per label before each feedback session's training (at most ``max_unlabeled``).

    SURF's walker-walk settings: threshold 0.99, ratio 4, weight 1, 100 unlabelled pairs per label (10 on Meta-World).

    :param threshold: τ, the confidence above which a member's pseudo-label is used
    :param ratio: μ, unlabelled pairs per labelled pair in a minibatch
    :param weight: λ, the weight of the unlabelled loss
    :param unlabeled_per_label: unlabelled pairs drawn per label
    :param max_unlabeled: the most unlabelled pairs drawn for one feedback session
    """

    threshold: float = 0.99
    ratio: int = 4
    weight: float = 1.0
    unlabeled_per_label: int = 100
    max_unlabeled: int = 10_000

    def __post_init__(self) -> None:
        if isinstance(self.threshold, bool) or not isinstance(self.threshold, (int, float)) or not 0.5 <= self.threshold < 1:
            raise ValueError(f"pseudo_labels: threshold must be in [0.5, 1), got {self.threshold!r}")
        if isinstance(self.weight, bool) or not isinstance(self.weight, (int, float)) or not 0 < self.weight < math.inf:
            raise ValueError(f"pseudo_labels: weight must be a finite number > 0, got {self.weight!r}")
        for name in ("ratio", "unlabeled_per_label", "max_unlabeled"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise ValueError(f"pseudo_labels: {name} must be an integer >= 1, got {value!r}")

    needs_transitions: ClassVar[bool] = True

    def prepare(self, learner: "RewardLearner", data: "LearningData") -> None:
        """Draw ``unlabeled_per_label`` unlabelled pairs per label from the buffer, as the query sampler draws queries."""
        assert data.buffer is not None and data.queries is not None  # needs_transitions
        n = min(self.unlabeled_per_label * len(data.preferences), self.max_unlabeled)
        pairs = data.queries.unlabeled_pairs(data.buffer, n, data.rng)
        self.unlabeled = th.as_tensor(pairs, device=learner.ensemble.device) if pairs is not None and len(pairs) else None

    def extra_loss(
        self, ensemble: "RewardEnsemble", n_pairs: int, rng: np.random.Generator, temporal_crop: tuple[int, int] | None
    ) -> th.Tensor | None:
        unlabeled = getattr(self, "unlabeled", None)
        return None if unlabeled is None else ensemble.pseudo_label_loss(unlabeled, n_pairs, self, rng, temporal_crop)

    def finish(self) -> dict[str, Any]:
        self.unlabeled = None  # drawn again at the next session; never saved
        return {}


@dataclass
class ExplorationBonus(RewardOption):
    """
    RUNE's exploration bonus (Liang et al., *Reward Uncertainty for Exploration in Preference-based Reinforcement
    Learning*, ICLR 2022): from the first feedback session on, SAC learns from r̂(s, a) + β_t · σ(s, a), where σ is the
    standard deviation of the ensemble members' r̂_m(s, a) (where they disagree, a label would teach the most) and
    β_t = β_0 (1 − ρ)^t decays with the env steps t. The bonus is computed on each SAC minibatch with the current
    ensemble; the stored rewards stay r̂.

    RUNE's settings: β_0 = 0.05, ρ = 1e-5 (RIME's re-implementation uses ρ = 1e-3).

    :param beta_init: β_0, the bonus weight at step 0
    :param beta_decay: ρ, its decay per env step
    """

    beta_init: float = 0.05
    beta_decay: float = 1e-5

    def __post_init__(self) -> None:
        check_real("exploration_bonus: beta_init", self.beta_init, lambda beta: 0 < beta < math.inf, "> 0 and finite")
        check_real("exploration_bonus: beta_decay", self.beta_decay, lambda rho: 0 <= rho < 1, "in [0, 1)")

    def beta(self, step: int) -> float:
        """β_t = β_0 (1 − ρ)^t."""
        return self.beta_init * (1.0 - self.beta_decay) ** step


#: every option ``reward_kwargs`` may turn on, by name, in the order they were registered (the order they are called)
REWARD_OPTIONS: dict[str, type[RewardOption]] = {}


def register_reward_option(name: str, option_class: type[RewardOption]) -> None:
    """
    Make ``reward_kwargs[name]`` turn ``option_class`` on, for every reward learner made from now on.

    :param name: the setting's name in ``reward_kwargs`` (an identifier no other setting has)
    :param option_class: a dataclass of the option's settings (made with no argument for ``True``) deriving from
        ``RewardOption``
    """
    import dataclasses

    if not name.isidentifier():
        raise ValueError(f"register_reward_option: name must be an identifier, got {name!r}")
    if not (isinstance(option_class, type) and issubclass(option_class, RewardOption)):
        raise TypeError(f"register_reward_option: {name!r} must be a RewardOption subclass, got {option_class!r}")
    if not dataclasses.is_dataclass(option_class):
        raise TypeError(f"register_reward_option: {option_class.__name__} must be a dataclass of its settings")
    from sb3_pride.reward.learner import RewardLearner

    if name in RewardLearner.own_settings():
        raise ValueError(f"register_reward_option: {name!r} is a setting of RewardLearner itself")
    if name in REWARD_OPTIONS and REWARD_OPTIONS[name] is not option_class:
        raise ValueError(f"register_reward_option: {name!r} is already {REWARD_OPTIONS[name].__name__}")
    REWARD_OPTIONS[name] = option_class
