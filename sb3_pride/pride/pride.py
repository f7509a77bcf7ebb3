from collections.abc import Sequence
from typing import Any, ClassVar

import numpy as np
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.preprocessing import get_action_dim, get_flattened_obs_dim
from stable_baselines3.common.type_aliases import GymEnv
from stable_baselines3.sac.policies import SACPolicy

from sb3_pride.common.buffers import PreferenceReplayBuffer
from sb3_pride.pride.buffers import DualReplayBuffer
from sb3_pride.common.env_checks import check_episode_length
from sb3_pride.pride.generator import GenerationReport, TransitionGenerator
from sb3_pride.common.queries import chronological_rows
from sb3_pride.common.utils import check_non_negative_ints, check_positive_ints
from sb3_pride.pebble.pebble import PEBBLE
from sb3_pride.pride.callbacks import GeneratorCallback
from sb3_pride.pride.recipes import check_generator_kwargs, check_synthetic_settings, with_reward_defaults


class PRIDE(PEBBLE):
    """
    PRIDE: Preference-based Reinforcement learning using dIffusion moDEL (Feng, Tenytska, Wang & Peng, 2025).

    PEBBLE plus a generator (Algorithm 1, lines 22–37): every ``diffusion_interval`` (R) env steps, once the first
    reward model exists and from ``synthetic_start`` on, a ``TransitionGenerator`` (an EDM diffusion model, as
    SynthER) is fitted on the real transitions (s, a, s') and fills a separate synthetic buffer with
    ``synthetic_samples`` new ones; every SAC minibatch of B rows then holds round(u · B) synthetic transitions and
    the rest real ones (with ``synthetic_on_top``, B real ones and synthetic ones on top).

    Synthetic rewards are r̂(s, a) of the current reward model: set at generation and relabeled together with the
    real buffer after every reward update (the paper relabels the real buffer only, which leaves synthetic rewards
    stale until the next generation). Terminal flags are modelled only if the real buffer holds a true termination by
    the first retrain (never on DMC or Meta-World, whose episodes only time out).

    Every other parameter is PEBBLE's (and SAC's), with the same defaults, except three of PEBBLE's that PRIDE sets for
    its purpose, feedback efficiency (the paper's "half the labels"): half PEBBLE's budget, asked front-loaded, and r̂
    learned with REED's consistency pre-training (Metcalf et al., 2023). PRIDE's own defaults are the configuration
    chosen at the CPU tier; ``PRIDE(..., **PAPER_RECIPE)`` (``sb3_pride.pride.PAPER_RECIPE``) is the paper's
    algorithm, and ``hyperparams/pride.yml`` runs it at the paper's scale. Step counts are for 50k-step runs: scale
    them with the run.

    :param synthetic_ratio: u, the synthetic share of each SAC minibatch, in [0, 1] (paper: 0.5). With 0 the
        generator is never trained and PRIDE trains exactly as PEBBLE
    :param synthetic_start: the schedule of u, first part: no synthetic data is generated or mixed before this env
        step (besides waiting for the first reward model, which always holds; paper: 0)
    :param synthetic_ramp: the schedule of u, second part: env steps over which u grows linearly from 0 to
        ``synthetic_ratio`` after the first generation (paper: 0, at once)
    :param synthetic_on_top: add the synthetic rows to ``batch_size`` real ones instead of putting them in place of
        some (paper: False). Each minibatch then holds M = round(B / (1 − u)) rows of which round(u · M) synthetic,
        u as ramped so far: B real rows, as many as PEBBLE's, and about u · B / (1 − u) synthetic ones on top. Until the
        first generation it trains exactly as PEBBLE (M = B). Needs u < 1; the cost of an update grows with M
    :param diffusion_interval: R, env steps between retrain-and-generate (paper: 10k)
    :param synthetic_samples: transitions generated (and kept) per retrain; they replace the synthetic buffer
    :param synthetic_buffer_size: capacity of the synthetic buffer (default: ``synthetic_samples``)
    :param generator_kwargs: ``TransitionGenerator`` arguments: the diffusion's sizes (``width``, ``n_blocks``,
        ``train_steps``, ``sample_steps``), ``warm_start``, ``normalization``, ``model_state_change``, ``generation``,
        ``anchor_noise``, ``window``, ``keep_quantile``, ``filter``, ``fidelity_check``, ``diffusion_kwargs``,
        ``dynamics_kwargs``; those not given keep the generator's defaults
    :param max_feedback: Q, the total query budget, as PEBBLE's: by default half PEBBLE's (500)
    :param feedback_schedule: the label schedule, as PEBBLE's; None: "front_loaded" (half the budget in the first
        feedback session, the other half in the next four), where PEBBLE's is "constant"
    :param reward_kwargs: the ``RewardLearner`` settings, as PEBBLE's, merged entry by entry on top of PRIDE's
        ``PRIDE_REWARD_DEFAULTS`` (``sb3_pride.pride.recipes``: REED's consistency pre-training, five passes per
        session); turn it off with ``reward_kwargs=dict(dynamics_consistency=False)``
    """

    buffer_class: ClassVar[type[PreferenceReplayBuffer]] = DualReplayBuffer  # type: ignore[assignment]
    phase_callbacks: ClassVar[tuple[type[BaseCallback], ...]] = (*PEBBLE.phase_callbacks, GeneratorCallback)
    replay_buffer: DualReplayBuffer  # type: ignore[assignment]
    generator: TransitionGenerator

    def __init__(
        self,
        policy: str | type[SACPolicy],
        env: GymEnv | str,
        synthetic_ratio: float = 0.25,
        synthetic_start: int = 10_000,
        synthetic_ramp: int = 5000,
        synthetic_on_top: bool = False,
        diffusion_interval: int = 5000,
        synthetic_samples: int = 10_000,
        synthetic_buffer_size: int | None = None,
        generator_kwargs: dict[str, Any] | None = None,
        max_feedback: int = 500,
        feedback_schedule: str | Sequence[int] | None = None,
        reward_kwargs: dict[str, Any] | None = None,
        _init_setup_model: bool = True,
        **pebble_kwargs: Any,
    ):
        check_synthetic_settings(synthetic_ratio, synthetic_on_top)
        check_positive_ints(diffusion_interval=diffusion_interval, synthetic_samples=synthetic_samples)
        if synthetic_buffer_size is not None:
            check_positive_ints(synthetic_buffer_size=synthetic_buffer_size)
        check_non_negative_ints(synthetic_start=synthetic_start, synthetic_ramp=synthetic_ramp)
        check_generator_kwargs(generator_kwargs, pebble_kwargs)
        replay_buffer_kwargs = dict(pebble_kwargs.pop("replay_buffer_kwargs", None) or {})
        replay_buffer_kwargs.setdefault("synthetic_buffer_size", synthetic_buffer_size or synthetic_samples)
        replay_buffer_kwargs.setdefault("synthetic_ratio", synthetic_ratio)
        # PRIDE's schedule and reward learning (SB3's load() then restores the saved ones)
        feedback_schedule = "front_loaded" if feedback_schedule is None else feedback_schedule
        reward_kwargs = with_reward_defaults(reward_kwargs)
        pebble_kwargs.update(max_feedback=max_feedback, feedback_schedule=feedback_schedule, reward_kwargs=reward_kwargs)
        super().__init__(policy, env, replay_buffer_kwargs=replay_buffer_kwargs, _init_setup_model=False, **pebble_kwargs)
        if _init_setup_model and self.env is not None:  # PEBBLE skipped it, as it does for load()
            check_episode_length(self.env, self.segment_length)
        self.synthetic_ratio = synthetic_ratio
        self.synthetic_start = synthetic_start
        self.synthetic_ramp = synthetic_ramp
        self.synthetic_on_top = bool(synthetic_on_top)
        self.diffusion_interval = diffusion_interval
        self.synthetic_samples = synthetic_samples
        self.synthetic_buffer_size = synthetic_buffer_size
        self.generator_kwargs = dict(generator_kwargs or {})
        # learning state, saved with the model; whether transitions hold a terminal flag is known at the first retrain
        self.model_terminals: bool | None = None
        self.first_generation_step: int | None = None
        self.diffusion_retrains = 0
        # the first retrain comes right after the first reward learning (or at synthetic_start, if later)
        self.next_diffusion_step = max(self.phase.next_step, synthetic_start)

        if _init_setup_model:
            self._setup_model()

    def _setup_model(self) -> None:
        super()._setup_model()
        obs_dim, action_dim = get_flattened_obs_dim(self.observation_space), get_action_dim(self.action_space)
        options = dict(seed=self.seed, device=self.device)
        self.generator = TransitionGenerator(obs_dim, action_dim, **{**options, **self.generator_kwargs})
        if self.model_terminals is not None:  # loading a model that was retrained: rebuild before its weights load
            self.generator.build(self.model_terminals)

    def attach_parts(self) -> None:
        super().attach_parts()
        self.replay_buffer.ratio_source = self.current_synthetic_ratio  # u as ramped, asked at each minibatch

    def _shift_schedules(self, steps: int) -> None:
        super()._shift_schedules(steps)
        self.next_diffusion_step = max(0, self.next_diffusion_step + steps)
        if self.first_generation_step is not None:
            self.first_generation_step += steps

    @property
    def real_buffer(self) -> PreferenceReplayBuffer:
        """B_real, the agent's own transitions with their true rewards aside."""
        return self.replay_buffer.real

    def train(self, gradient_steps: int, batch_size: int = 64) -> None:
        # Algorithm 1, lines 34–37: each SAC minibatch of M rows holds round(u·M) synthetic and M − round(u·M) real
        # transitions (DualReplayBuffer.sample); real only until the first generation, then u ramps up over
        # synthetic_ramp steps (the buffer asks current_synthetic_ratio). M = B (the paper) or, with synthetic_on_top,
        # B / (1 − u) with u as ramped so far
        minibatch_size = self.minibatch_size(batch_size)
        super().train(gradient_steps, minibatch_size)
        self.logger.record("train/synthetic_per_batch", self.replay_buffer.n_synthetic(minibatch_size))

    def minibatch_size(self, batch_size: int) -> int:
        """
        Rows M of each SAC minibatch: ``batch_size`` (B, the paper), or with ``synthetic_on_top`` round(B / (1 − u))
        for u as ramped so far; M = B while there is no synthetic data yet.
        """
        if not self.synthetic_on_top or self.replay_buffer.synthetic.size() == 0:
            return batch_size
        return round(batch_size / (1.0 - self.current_synthetic_ratio()))

    def current_synthetic_ratio(self) -> float:
        """u now: ``synthetic_ratio``, ramped linearly from 0 over ``synthetic_ramp`` steps after the first generation."""
        if self.first_generation_step is None or self.synthetic_ramp == 0:
            return self.synthetic_ratio
        return self.synthetic_ratio * min(1.0, (self.num_timesteps - self.first_generation_step) / self.synthetic_ramp)

    def relabel(self) -> None:
        """Relabel B_real (Algorithm 1, line 20) and, unlike the paper, B_syn too: r̂ is never stale."""
        super().relabel()
        self.replay_buffer.synthetic.relabel(self.reward_model.predict)

    # retrain-and-generate (Algorithm 1, lines 22–30) ----------------------------------------------------------------
    def generator_due(self) -> bool:
        """
        Whether a retrain is due now: u > 0, a reward model exists (synthetic data never carries an untrained reward),
        ``next_diffusion_step`` is reached, and the real buffer holds at least ``batch_size`` transitions (a run
        resumed without its replay buffer waits until there are enough to fit on).
        """
        return (
            self.synthetic_ratio > 0
            and not self.phase.pretraining
            and self.num_timesteps >= self.next_diffusion_step
            and self.real_buffer.size() >= self.batch_size
        )

    def real_transitions(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """
        (s, a, s', terminal) of the real transitions the generator learns from, oldest first: the most recent
        ``window`` of them (whole rows of ``n_envs`` transitions), or all of B_real.
        """
        buffer = self.real_buffer
        rows = chronological_rows(buffer)
        if self.generator.window is not None:
            rows = rows[-int(np.ceil(self.generator.window / buffer.n_envs)) :]
        terminals = buffer.dones[rows] * (1.0 - buffer.timeouts[rows])
        return buffer.observations[rows], buffer.actions[rows], buffer.next_observations[rows], terminals

    def retrain_generator(self) -> GenerationReport:
        """
        Fit the generator on the real transitions, generate, and replace B_syn with the ``synthetic_samples`` it keeps,
        rewarded by r̂; schedule the next retrain ``diffusion_interval`` steps on. Logs under ``diffusion/``.
        """
        obs, actions, next_obs, terminals = self.real_transitions()
        if self.model_terminals is None:
            self.model_terminals = bool(terminals.any())
        if self.generator.diffusion is None:
            self.generator.build(self.model_terminals)
        real = self.generator.transition_vectors(obs, actions, next_obs, terminals)
        report = self.generator.update(real, self.synthetic_samples, reward_doubt=self.reward_model.disagreement)
        self.store_synthetic(report.vectors)
        self.next_diffusion_step = self.num_timesteps + self.diffusion_interval
        if self.first_generation_step is None:
            self.first_generation_step = self.num_timesteps
        self.diffusion_retrains += 1
        self._log_generation(report)
        return report

    def store_synthetic(self, vectors: np.ndarray) -> None:
        """Replace B_syn with generated transition vectors, rewarded by r̂(s, a)."""
        obs, actions, next_obs = self.generator.split(vectors)
        rewards = self.reward_model.predict(obs, actions)
        self.replay_buffer.synthetic.replace(obs, actions, next_obs, self.generator.terminals(vectors), rewards)

    def _log_generation(self, report: GenerationReport) -> None:
        self.logger.record("diffusion/loss", report.fit.loss)
        self.logger.record("diffusion/train_seconds", report.fit.seconds)
        self.logger.record("diffusion/generate_seconds", report.generate_seconds)
        self.logger.record("diffusion/fidelity_seconds", report.fidelity_seconds)
        self.logger.record("diffusion/samples_per_second", report.drawn / max(report.generate_seconds, 1e-9))
        self.logger.record("diffusion/samples_dropped", report.dropped)
        self.logger.record("diffusion/retrains", self.diffusion_retrains)
        if report.fidelity is not None:
            for key, value in vars(report.fidelity).items():
                self.logger.record(f"diffusion/{key}", value)
        if report.kept_dynamics_error_ratio is not None:
            self.logger.record("diffusion/kept_dynamics_error_ratio", report.kept_dynamics_error_ratio)

    def _get_torch_save_params(self) -> tuple[list[str], list[str]]:
        state_dicts, variables = super()._get_torch_save_params()
        return ([*state_dicts, "generator.diffusion"] if self.generator.diffusion is not None else state_dicts), variables

    def _excluded_save_params(self) -> list[str]:
        # rebuilt from generator_kwargs; the dynamics ensemble is a yardstick refit at every retrain: not worth saving
        return [*super()._excluded_save_params(), "generator"]
