"""
r̂ and how it learns: PEBBLE's reward ensemble, trained on the preference dataset D after each feedback session, with
the reward-learning options from the literature. One object, given to ``PEBBLE`` as ``reward_kwargs``.
"""

import inspect
from types import SimpleNamespace
from typing import Any

import numpy as np
import torch as th
from stable_baselines3.common.type_aliases import ReplayBufferSamples
from stable_baselines3.common.vec_env import VecNormalize

from sb3_pride.common.buffers import PreferenceReplayBuffer
from sb3_pride.reward.consistency import ConsistencyModel, DynamicsConsistency
from sb3_pride.common.queries import QuerySampler
from sb3_pride.reward.ensemble import PreferenceDataset, RewardEnsemble, check_temporal_crop
from sb3_pride.reward.options import (
    REWARD_OPTIONS,
    ExplorationBonus,
    LearningData,
    PseudoLabels,
    RewardOption,
    RobustLabels,
    register_reward_option,
)
from sb3_pride.common.utils import check_positive_ints, check_real, make_option


class RewardLearningReport(SimpleNamespace):
    """
    What one feedback session's reward learning did, logged under ``reward_model/``: ``loss``, ``accuracy`` and
    ``epochs``, and what each option on reports (``RewardOption.finish``: e.g. ``consistency_loss``,
    ``trusted_labels``, ``flipped_labels``).
    """

    loss: float
    accuracy: float
    epochs: int


class RewardLearner:
    """
    PEBBLE's reward learning (Lee, Smith & Abbeel, ICML 2021): an ensemble of MLPs r̂(s, a) trained on the teacher's
    preferences with the Bradley–Terry loss (Eqs. 1–2), up to ``epochs`` epochs per feedback session, stopping at
    ``early_stop`` training accuracy (B-Pref's 97%). The options below learn more from each label or explore where r̂
    is unsure; all are off by default (the published PEBBLE).

    :param obs_dim: size of the flat observations
    :param action_dim: size of the actions
    :param segment_length: steps per segment of the pairs it learns from
    :param ensemble_size: members of the ensemble (PEBBLE: 3)
    :param net_arch: hidden layers of each member (PEBBLE: 3 × 256)
    :param learning_rate: Adam step size (PEBBLE: 3e-4)
    :param batch_size: preference pairs per minibatch (PEBBLE: 128)
    :param epochs: most epochs over D per feedback session (PEBBLE: 50 on DMC, 10 on Meta-World)
    :param early_stop: a session's training ends after the first epoch whose training accuracy exceeds it (B-Pref's
        0.97). None: every one of ``epochs`` runs (at low budgets the early stop under-trains r̂)
    :param temporal_crop: SURF's temporal cropping (Park et al., ICLR 2022): each pair cropped to one random length in
        ``(min_length, max_length)`` at every minibatch, with its own start in each segment; ``max_length <=
        segment_length``: (35, 45) at segment 50 is QPA's S−15..S−5. None: whole segments
    :param device: where the networks live
    :param options: the reward-learning options, by name (below)

    Options (``reward_kwargs[name]``: ``False``, the default, off; ``True``, the published settings; a dict of the
    option's settings), each a ``RewardOption`` registered by name (``register_reward_option``: a user's own plugs in
    the same way), called in the order they were registered:

    - ``dynamics_consistency``: REED's self-supervised pre-training of the members' encoder (Metcalf et al., CoRL
      2023) on the stored transitions before each session's reward learning (``DynamicsConsistency``);
    - ``pseudo_labels``: SURF's semi-supervised reward learning: unlabelled pairs from the replay buffer beside each
      labelled minibatch, each member learning from its own confident pseudo-labels (``PseudoLabels``);
    - ``robust_labels``: RIME's robust reward learning for noisy teachers (Cheng et al., ICML 2024): each epoch trains
      on the labels the ensemble finds plausible and flips those it is confident are wrong (``RobustLabels``);
    - ``exploration_bonus``: RUNE's exploration bonus (Liang et al., ICLR 2022): SAC learns from r̂ + β_t · σ, σ the
      members' disagreement (``ExplorationBonus``); needs ``ensemble_size >= 2``.
    """

    def __init__(
        self,
        obs_dim: int,
        action_dim: int,
        segment_length: int,
        ensemble_size: int = 3,
        net_arch: list[int] | tuple[int, ...] = (256, 256, 256),
        learning_rate: float = 3e-4,
        batch_size: int = 128,
        epochs: int = 50,
        early_stop: float | None = 0.97,
        temporal_crop: tuple[int, int] | None = None,
        device: th.device | str = "auto",
        **options: bool | dict[str, Any],
    ):
        self.check_kwargs(
            {name: value for name, value in locals().items() if name in self.own_settings()} | options, segment_length
        )
        self.obs_dim = obs_dim
        self.batch_size, self.epochs, self.early_stop = batch_size, epochs, early_stop
        self.temporal_crop = check_temporal_crop(temporal_crop, segment_length)
        #: r̂, the ensemble
        self.ensemble = RewardEnsemble(
            obs_dim, action_dim, n_members=ensemble_size, net_arch=tuple(net_arch), learning_rate=learning_rate, device=device
        )
        #: REED's consistency heads on the members' encoder (None: off; made by ``DynamicsConsistency.setup``)
        self.consistency: ConsistencyModel | None = None
        #: the options on, by name, in the order they were registered; saved with the model (RIME's running values)
        self.options: dict[str, RewardOption] = {}
        for name, option_class in REWARD_OPTIONS.items():
            option = make_option(name, options.get(name, False), option_class)
            if option is not None:
                self.options[name] = option
                option.setup(self)
        #: one dict per reward update (``record``): session, step, labels, accuracy, corr(r̂, r); saved with the model
        self.history: list[dict[str, float]] = []

    @classmethod
    def own_settings(cls) -> dict[str, Any]:
        """The learner's own settings (the ensemble's and its training's), with their defaults."""
        parameters = inspect.signature(cls.__init__).parameters
        return {
            name: p.default
            for name, p in parameters.items()
            if p.default is not p.empty and p.kind != p.VAR_KEYWORD and name != "device"
        }

    @classmethod
    def settings(cls) -> dict[str, Any]:
        """The settings ``reward_kwargs`` may give, with their defaults: the learner's own, then every option (off)."""
        return {**cls.own_settings(), **dict.fromkeys(REWARD_OPTIONS, False)}

    @property
    def label_selection(self) -> RobustLabels | None:
        """RIME's running selection of trusted labels (None: every label as given)."""
        return self.options.get("robust_labels")  # type: ignore[return-value]

    @label_selection.setter
    def label_selection(self, selection: RobustLabels) -> None:
        self.options["robust_labels"] = selection

    @property
    def pseudo_labels(self) -> PseudoLabels | None:
        return self.options.get("pseudo_labels")  # type: ignore[return-value]

    @property
    def exploration_bonus(self) -> ExplorationBonus | None:
        return self.options.get("exploration_bonus")  # type: ignore[return-value]

    @classmethod
    def check_kwargs(cls, reward_kwargs: Any, segment_length: int) -> None:
        """
        Refuse bad settings before anything is made, naming the setting: an unknown name, a value out of range, an
        option that is not True, False or a dict of its settings.
        """
        if not isinstance(reward_kwargs, dict):
            raise ValueError(f"reward_kwargs must be a dict of RewardLearner's settings, got {reward_kwargs!r}")
        unknown = sorted(set(reward_kwargs) - set(cls.settings()))
        if unknown:
            raise ValueError(f"reward_kwargs: unknown settings {unknown}; RewardLearner takes {sorted(cls.settings())}")
        settings = {**cls.settings(), **reward_kwargs}
        check_positive_ints(**{f"reward_kwargs: {name}": settings[name] for name in ("ensemble_size", "batch_size", "epochs")})
        check_real("reward_kwargs: learning_rate", settings["learning_rate"], lambda lr: 0 < lr < np.inf, "> 0 and finite")
        if settings["early_stop"] is not None:
            check_real(
                "reward_kwargs: early_stop", settings["early_stop"], lambda a: 0 < a < 1, "None (no early stop) or in (0, 1)"
            )
        check_temporal_crop(settings["temporal_crop"], segment_length)
        for name, option_class in REWARD_OPTIONS.items():
            make_option(name, settings[name], option_class)
        if settings["exploration_bonus"] is not False and settings["ensemble_size"] < 2:
            raise ValueError(
                f"exploration_bonus needs ensemble_size >= 2 (its σ is the members' spread), got {settings['ensemble_size']}"
            )

    def learn(
        self,
        preferences: PreferenceDataset,
        buffer: PreferenceReplayBuffer | None,
        queries: QuerySampler | None,
        rng: np.random.Generator,
    ) -> RewardLearningReport:
        """
        Train r̂ on every preference so far (Eqs. 1–2); with ``dynamics_consistency`` its encoder first learns from the
        transitions stored in ``buffer`` (REED), with ``pseudo_labels`` it also learns from unlabelled pairs drawn from
        ``buffer`` as ``queries`` draws queries (SURF). Without a buffer (r̂ fitted from journals alone) neither can be on.
        """
        on = [name for name, option in self.options.items() if option.needs_transitions]
        if (buffer is None or queries is None) and on:
            raise ValueError(
                f"reward_kwargs: {on} learn from the agent's stored transitions, which r̂ fitted from preferences alone "
                "does not have: turn them off"
            )
        data = LearningData(preferences, buffer, queries, rng)
        for option in self.options.values():
            option.prepare(self, data)
        loss, accuracy, epochs = self.ensemble.train_epochs(
            preferences,
            self.epochs,
            self.batch_size,
            target_accuracy=1.0 if self.early_stop is None else self.early_stop,  # no training accuracy exceeds 1
            rng=rng,
            temporal_crop=self.temporal_crop,
            options=list(self.options.values()),
        )
        figures = {key: value for option in self.options.values() for key, value in option.finish().items()}
        return RewardLearningReport(loss=loss, accuracy=accuracy, epochs=epochs, **figures)

    def record(self, session: int, step: int, labels: int, report: RewardLearningReport, correlation: float) -> None:
        """Add a reward update to ``history`` (what the reward report and a teacher's page show)."""
        self.history.append(dict(session=session, step=step, labels=labels, accuracy=report.accuracy, correlation=correlation))

    def predict(self, observations: np.ndarray, actions: np.ndarray) -> np.ndarray:
        """r̂(s, a), the members' mean, NumPy in and out."""
        return self.ensemble.predict(observations, actions)

    def correlation(self, buffer: PreferenceReplayBuffer, rng: np.random.Generator, n_samples: int = 10_000) -> float:
        """Pearson correlation of r̂ with the true reward on ``n_samples`` stored transitions: the reward model's health."""
        observations, actions, true_rewards = buffer.transition_sample(n_samples, rng)
        predicted = self.predict(observations, actions)
        if np.std(predicted) == 0 or np.std(true_rewards) == 0:
            return float("nan")
        return float(np.corrcoef(predicted, true_rewards)[0, 1])

    @th.no_grad()
    def bonus(self, samples: ReplayBufferSamples, step: int, vec_normalize: VecNormalize | None = None) -> th.Tensor:
        """
        RUNE's β_t · σ(s, a) of a minibatch, σ the members' standard deviation of r̂_m(s, a). Under ``VecNormalize`` the
        observations are un-normalized first (r̂ reads them as stored; values VecNormalize clipped stay clipped).
        """
        assert self.exploration_bonus is not None, "exploration_bonus is off"
        observations = samples.observations
        if vec_normalize is not None:
            raw = vec_normalize.unnormalize_obs(observations.cpu().numpy())
            observations = th.as_tensor(raw, dtype=th.float32, device=samples.rewards.device)
        inputs = th.cat([observations.float(), samples.actions.float()], dim=-1).to(self.ensemble.device)
        sigma = self.ensemble(inputs).std(dim=0, correction=0)  # (B, 1), like the rewards
        return (self.exploration_bonus.beta(step) * sigma).to(samples.rewards.device, samples.rewards.dtype)

    def __getstate__(self) -> dict:
        # the networks are saved by the algorithm as state dicts (``reward_model``, ``reward_learner.consistency``)
        return {**self.__dict__, "ensemble": None, "consistency": None}


# the built-ins, in the order their hooks run (REED's pre-training before SURF's draw, as their papers order them)
for _name, _option in (
    ("dynamics_consistency", DynamicsConsistency),
    ("pseudo_labels", PseudoLabels),
    ("robust_labels", RobustLabels),
    ("exploration_bonus", ExplorationBonus),
):
    register_reward_option(_name, _option)
