import inspect
import io
import os
import pathlib
import time
from collections.abc import Sequence
from typing import Any, ClassVar

import numpy as np
import torch as th
from stable_baselines3 import SAC
from stable_baselines3.common.buffers import ReplayBuffer
from stable_baselines3.common.callbacks import BaseCallback, ConvertCallback
from stable_baselines3.common.noise import ActionNoise
from stable_baselines3.common.preprocessing import get_action_dim, get_flattened_obs_dim
from stable_baselines3.common.type_aliases import GymEnv, MaybeCallback, Schedule
from stable_baselines3.sac.policies import SACPolicy

from sb3_pride.common.buffers import PreferenceReplayBuffer
from sb3_pride.common.entropy import StateEntropyReward
from sb3_pride.common.env_checks import check_env, env_id
from sb3_pride.common.checkpoints import AtomicSaves
from sb3_pride.common.journal import JournalBook, journal_header
from sb3_pride.reward.learned_reward import LearnedReward
from sb3_pride.common.queries import QuerySampler
from sb3_pride.pebble.replay_rewards import ReplayRewards
from sb3_pride.reward.learner import RewardLearner
from sb3_pride.reward.ensemble import PreferenceDataset, RewardEnsemble
from sb3_pride.common.teachers import InteractiveTeacher, Teacher
from sb3_pride.pebble.callbacks import FeedbackCallback
from sb3_pride.pebble.feedback import FeedbackLoop, FeedbackSchedule
from sb3_pride.pebble.phase import PreferencePhase
from sb3_pride.pebble.earlier_versions import renamed_settings_error
from sb3_pride.pebble.checks import (
    STRUCTURED_SETTINGS,
    check_feedback_settings,
    check_sac_arguments,
    load_kwargs,
    preference_settings,
)

#: the constructor arguments PEBBLE passes on to SAC as they are
SAC_ARGUMENTS = set(inspect.signature(SAC.__init__).parameters) - {"self", "env", "replay_buffer_class", "_init_setup_model"}


def reset_critic(model: SAC) -> None:
    """
    PEBBLE's reset after pre-training (B-Pref re-creates the critic): fresh Q-networks and, unless it is the
    actor's (``share_features_extractor=True``), a fresh features extractor; the target copied from them;
    fresh Adam state. The actor and the entropy coefficient keep what pre-training taught them.
    """
    shared = model.critic.features_extractor if model.critic.share_features_extractor else None
    kept = set() if shared is None else {id(module) for module in shared.modules()}
    for module in model.critic.modules():
        reset_parameters = getattr(module, "reset_parameters", None)
        if callable(reset_parameters) and id(module) not in kept:
            reset_parameters()
    model.critic_target.load_state_dict(model.critic.state_dict())
    model.critic.optimizer.state.clear()


class PEBBLE(AtomicSaves, SAC):
    """
    PEBBLE: unsupervised Pre-training and preference-Based learning via relaBeLing Experience
    (Lee, Smith & Abbeel, ICML 2021), the preference-based SAC that PRIDE builds on
    (Feng et al., 2025, §3.3 and Algorithm 1 without its diffusion lines).

    The environment's reward never reaches SAC (Monitor and EvalCallback still report it): SAC learns from r̂ (a
    ``RewardLearner``: an ensemble trained on the teacher's preferences between segment pairs, Bradley–Terry, Eqs.
    1–2), every stored reward relabeled after each reward update. After ``learning_starts`` random steps, SAC is
    pre-trained for ``unsupervised_steps`` on the k-NN state-entropy reward (Eq. 3); at the first feedback the critic
    is reset and trained on r̂. The parts: a ``FeedbackLoop`` (the teacher's side of a session), a ``QuerySampler``,
    a ``RewardLearner`` and the ``ReplayRewards`` the replay buffer asks.

    Parameters not listed here are SAC's, with the same meaning and defaults except ``learning_starts`` (PEBBLE: 1000)
    and ``n_steps``, which must stay 1 (n-step sums of rewards that relabeling rewrites). Saves are ``AtomicSaves``.

    :param teacher: who labels: a ``Teacher`` (a callable), an ``InteractiveTeacher`` (e.g. ``WebTeacher``) or a name
        in ``sb3_pride.common.teachers.TEACHERS``: a B-Pref scripted teacher ("oracle", "mistake", ...) or "web"
    :param max_feedback: Q, the total query budget
    :param feedback_interval: M, env steps between feedback sessions
    :param queries_per_session: K, queries asked per session (the last session is cut to the budget)
    :param feedback_schedule: the label schedule (``FeedbackSchedule``): "constant" (K each session), B-Pref's
        "shrinking" or "growing" (K scaled by the step within ``learn()``'s run), "front_loaded" (half the budget in
        the first session, the other half in the next four), or a list of the first sessions' sizes
    :param segment_length: steps per segment (PEBBLE: 50); a segment never crosses an episode end
    :param query_selection: how the K queries are picked among random candidate pairs (``QuerySampler``'s
        ``selection``: "uniform", "disagreement", "entropy", "kcenter", ...); the first session is always uniform
    :param unsupervised_steps: env steps of state-entropy pre-training after ``learning_starts`` (PEBBLE: 9000)
    :param preference_journal: a JSON-lines file to which every answer is appended and flushed the moment it is given;
        a run made or loaded with it takes back the answers it lacks (a crash) instead of asking again. None: none
    :param asynchronous_feedback: True: the teacher answers in a thread of its own while training goes on with the
        reward model it has; the answers are taken in at the first step after the last is given. False: training waits
    :param prior_preferences: earlier runs' preference journals whose answers r̂ learns from, with the run's own, from
        the first feedback session on: not counted in ``max_feedback``, never asked again (``read_prior_preferences``)
    :param reward_kwargs: ``RewardLearner`` settings: the ensemble (``ensemble_size``, ``net_arch``, ``learning_rate``,
        ``batch_size``, ``epochs``, ``early_stop``) and the options (``temporal_crop``, ``robust_labels``, ...)
    :param query_kwargs: ``QuerySampler`` settings: ``candidates_multiplier`` (PEBBLE: 10), ``max_query_episodes``
        (100) and QPA's ``hybrid_replay`` share (0)
    :param pretraining_kwargs: ``entropy_k`` (k of the k-NN state entropy, PEBBLE: 5) and ``critic_reset_updates``
        (gradient steps on r̂ right after the critic reset, PEBBLE: 100)
    """

    policy_aliases: ClassVar[dict[str, type[SACPolicy]]] = SAC.policy_aliases  # type: ignore[assignment]
    #: the replay buffer class this algorithm needs (a user's ``replay_buffer_class`` must subclass it)
    buffer_class: ClassVar[type[PreferenceReplayBuffer]] = PreferenceReplayBuffer
    #: the callbacks that drive the algorithm's phases, before the user's
    phase_callbacks: ClassVar[tuple[type[BaseCallback], ...]] = (FeedbackCallback,)
    replay_buffer: PreferenceReplayBuffer
    reward_learner: RewardLearner
    #: r̂, the reward learner's ensemble
    reward_model: RewardEnsemble
    #: D, the teacher's answers (made by ``_setup_model``, once the input size is known)
    preferences: PreferenceDataset

    def __init__(
        self,
        policy: str | type[SACPolicy],
        env: GymEnv | str,
        learning_rate: float | Schedule = 3e-4,
        buffer_size: int = 1_000_000,
        learning_starts: int = 1000,
        batch_size: int = 256,
        tau: float = 0.005,
        gamma: float = 0.99,
        train_freq: int | tuple[int, str] = 1,
        gradient_steps: int = 1,
        action_noise: ActionNoise | None = None,
        replay_buffer_class: type[ReplayBuffer] | None = None,
        replay_buffer_kwargs: dict[str, Any] | None = None,
        optimize_memory_usage: bool = False,
        n_steps: int = 1,
        ent_coef: str | float = "auto",
        target_update_interval: int = 1,
        target_entropy: str | float = "auto",
        use_sde: bool = False,
        sde_sample_freq: int = -1,
        use_sde_at_warmup: bool = False,
        stats_window_size: int = 100,
        tensorboard_log: str | None = None,
        policy_kwargs: dict[str, Any] | None = None,
        verbose: int = 0,
        seed: int | None = None,
        device: th.device | str = "auto",
        teacher: str | Teacher | InteractiveTeacher = "oracle",
        max_feedback: int = 1000,
        feedback_interval: int = 20_000,
        queries_per_session: int = 100,
        feedback_schedule: str | Sequence[int] = "constant",
        segment_length: int = 50,
        query_selection: str = "disagreement",
        unsupervised_steps: int = 9000,
        preference_journal: str | os.PathLike | None = None,
        asynchronous_feedback: bool = False,
        prior_preferences: Sequence[str | os.PathLike] | None = None,
        reward_kwargs: dict[str, Any] | None = None,
        query_kwargs: dict[str, Any] | None = None,
        pretraining_kwargs: dict[str, Any] | None = None,
        _init_setup_model: bool = True,
        **unexpected: Any,
    ):
        if unexpected:  # a name of 0.1 or 0.2: the error names its new place
            raise renamed_settings_error(type(self).__name__, unexpected)
        check_feedback_settings(
            max_feedback, feedback_interval, queries_per_session, feedback_schedule, unsupervised_steps, asynchronous_feedback
        )
        check_sac_arguments(n_steps, gradient_steps, replay_buffer_class, self.buffer_class)
        settings = preference_settings(segment_length, query_selection, reward_kwargs, query_kwargs, pretraining_kwargs)
        # resolved before the env is made: a teacher that renders (a person's) may set up headless rendering first
        self.feedback = FeedbackLoop(JournalBook(None, ()))
        self.feedback.resolve(teacher, seed)
        if env is not None:
            # rl-zoo3 and SB3's load() build the model with _init_setup_model=False before restoring its
            # segment_length: load() checks the episode length itself, once the saved value is back
            env = check_env(env, segment_length if _init_setup_model else None, verbose)
        sac_arguments = {name: value for name, value in locals().items() if name in SAC_ARGUMENTS}
        sac_arguments["replay_buffer_class"] = replay_buffer_class or self.buffer_class
        super().__init__(env=env, **sac_arguments, _init_setup_model=False)
        self.teacher = teacher  # as given: a registered name stays a name, so that rl-zoo3 can pass it again on resume
        self.max_feedback, self.feedback_interval = max_feedback, feedback_interval
        self.queries_per_session, self.feedback_schedule = queries_per_session, feedback_schedule
        self.segment_length, self.query_selection = segment_length, query_selection
        self.unsupervised_steps, self.asynchronous_feedback = unsupervised_steps, bool(asynchronous_feedback)
        self.preference_journal = None if preference_journal is None else os.fspath(preference_journal)
        self.prior_preferences = prior_preferences
        self.reward_kwargs, self.query_kwargs, self.pretraining_kwargs = (settings[name] for name in STRUCTURED_SETTINGS)
        #: where the preference phase stands (sessions, queries asked and labeled, the next session's step), saved
        self.phase = PreferencePhase(next_step=learning_starts + unsupervised_steps)
        self.preference_rng = np.random.default_rng(seed)
        self.state_entropy = StateEntropyReward(k=self.pretraining_kwargs["entropy_k"])
        if _init_setup_model:
            self._setup_model()

    def _setup_model(self) -> None:
        super()._setup_model()
        obs_dim, action_dim = get_flattened_obs_dim(self.observation_space), get_action_dim(self.action_space)
        previous = self.__dict__.get("reward_learner")  # a loaded model's: RIME's selection and the history go on
        carried = getattr(previous, "label_selection", None)
        self.reward_learner = RewardLearner(obs_dim, action_dim, self.segment_length, device=self.device, **self.reward_kwargs)
        self.reward_learner.history = list(getattr(previous, "history", []))
        if carried is not None and self.reward_learner.label_selection is not None:
            self.reward_learner.label_selection = carried
        # r̂ and REED's heads: state dicts under names of their own (the learner's data is saved apart)
        self.reward_model, self.consistency_model = self.reward_learner.ensemble, self.reward_learner.consistency
        self.query_sampler = QuerySampler.from_settings(self.segment_length, self.query_selection, self.query_kwargs)
        if getattr(self, "preferences", None) is None:  # a loaded model has its own, its priors included
            self.preferences = PreferenceDataset(self.segment_length, obs_dim + action_dim)
        self.phase.preferences = self.preferences
        header = journal_header(env_id(self.env), self.observation_space.shape, self.action_space.shape, self.segment_length)
        included = self.feedback.journal.included
        self.feedback.open_journal(self.preference_journal, header, included, self.preferences, self.prior_preferences)
        self.replay_rewards = ReplayRewards(self.reward_learner, self.state_entropy, self)
        self.attach_parts()

    def set_env(self, env: GymEnv, force_reset: bool = True) -> None:
        """SB3's ``set_env``, after the constructor's checks of ``env`` (spaces, reward normalization, episode length)."""
        super().set_env(check_env(env, self.segment_length, self.verbose), force_reset=force_reset)
        self.attach_parts()

    def attach_parts(self) -> None:
        """
        The parts that work on the replay buffer and the env, attached to the current ones (after the model is made,
        its env changed or its buffer loaded): the buffer asks ``replay_rewards`` for SAC's rewards, and an interactive
        teacher records or re-renders what the env shows.
        """
        self.real_buffer.reward_source = self.replay_rewards
        progress, history = (self.phase.asked, self.max_feedback), self.reward_learner.history
        self.feedback.attach(self.teacher, self.seed, self.env, self.real_buffer, progress, history)

    @classmethod
    def load(
        cls,
        path: str | pathlib.Path | io.BufferedIOBase,
        env: GymEnv | None = None,
        device: th.device | str = "auto",
        custom_objects: dict[str, Any] | None = None,
        print_system_info: bool = False,
        force_reset: bool = True,
        **kwargs: Any,
    ):
        """
        SB3's ``load``; a new ``env`` gets the constructor's checks with the saved ``segment_length``, a structured
        setting given (``reward_kwargs``, ...) changes the saved one entry by entry, and the journal is found from
        wherever the model is loaded (``load_kwargs``); ``preference_journal=None`` loads it without its journal.
        """
        kwargs = load_kwargs(path, kwargs, device, custom_objects)
        model = super().load(path, env, device, custom_objects, print_system_info, force_reset, **kwargs)
        if env is not None and model.env is not None:
            check_env(model.env, model.segment_length, model.verbose)
        return model

    @property
    def real_buffer(self) -> PreferenceReplayBuffer:
        """Where the agent's own transitions and their true rewards are (the whole replay buffer in PEBBLE)."""
        return self.replay_buffer

    def _setup_learn(
        self,
        total_timesteps: int,
        callback: MaybeCallback = None,
        reset_num_timesteps: bool = True,
        tb_log_name: str = "run",
        progress_bar: bool = False,
    ) -> tuple[int, BaseCallback]:
        if reset_num_timesteps:  # a whole run: its budget must be asked within it (a run in parts is not checked)
            schedule = FeedbackSchedule(self.feedback_schedule, self.queries_per_session, self.max_feedback)
            remaining = self.max_feedback - self.phase.asked
            next_step = max(0, self.phase.next_step - self.num_timesteps)
            schedule.check(self.phase.sessions + 1, next_step, self.feedback_interval, total_timesteps, remaining)
            if self.num_timesteps > 0:
                self._shift_schedules(-self.num_timesteps)  # the step count restarts at 0: keep the remaining distances
        if reset_num_timesteps or self._last_obs is None:
            # SB3 resets the env now: the episode in progress ends here, or a query segment could span two episodes
            self.real_buffer.end_episodes()
        tb_log_name = type(self).__name__ if tb_log_name == "SAC" else tb_log_name  # "PEBBLE" or "PRIDE", not SAC's
        return super()._setup_learn(total_timesteps, callback, reset_num_timesteps, tb_log_name, progress_bar)

    def _shift_schedules(self, steps: int) -> None:
        self.phase.shift(steps)
        if self.feedback.pending is not None:
            self.feedback.pending.published_step += steps

    def _init_callback(self, callback: MaybeCallback, progress_bar: bool = False) -> BaseCallback:
        # the algorithm's own callbacks run first, then the user's
        if callback is None:
            user_callbacks = []
        elif isinstance(callback, list):
            user_callbacks = callback
        else:
            user_callbacks = [callback if isinstance(callback, BaseCallback) else ConvertCallback(callback)]
        phases: list[BaseCallback] = [phase(verbose=self.verbose) for phase in self.phase_callbacks]
        return super()._init_callback(phases + user_callbacks, progress_bar)

    # a feedback session (Algorithm 1, lines 6–21) ------------------------------------------------------------------
    def publish_queries(self, asynchronous: bool | None = None) -> bool:
        """
        Open a feedback session: choose its queries (as many as ``feedback_schedule`` says, at most what remains of
        ``max_feedback``) and give them to the teacher (``FeedbackLoop.publish``); none the journal holds is asked again.

        :param asynchronous: True: the teacher answers in a thread of its own and this returns at once; False: it
            returns once the teacher has answered; None: ``asynchronous_feedback``
        :return: False when no segment fits in the stored episodes yet (nothing was asked)
        """
        self.feedback.resolve(self.teacher, self.seed)
        sampler, session = self.query_sampler, self.phase.sessions + 1
        returns, labeled = self.reward_model.member_segment_returns, self.preferences.inputs
        schedule = FeedbackSchedule(self.feedback_schedule, self.queries_per_session, self.max_feedback)
        size, selection = schedule.size(session, self.num_timesteps, self._total_timesteps), self.query_selection
        return self.feedback.publish(
            self.feedback.context(session, self.phase.asked, self.max_feedback),
            n_queries=min(size, self.max_feedback - self.phase.asked),
            choose=lambda n, asked: sampler.choose(
                self.real_buffer, n, self.preference_rng, returns, labeled, asked, first=session == 1, selection=selection
            ),
            step=self.num_timesteps,
            asynchronous=self.asynchronous_feedback if asynchronous is None else asynchronous,
        )

    def take_answers(self) -> None:
        """
        Close the open feedback session (waiting for its answers if they are not all in): the labeled answers join the
        preferences, then r̂ learns and the buffer is relabeled (``learn_reward()``). A teacher's error is raised here,
        with nothing of the session recorded.
        """
        answers = self.feedback.take(self.logger)
        labeled = ~np.isnan(answers.labels)
        self.preferences.add(answers.inputs[labeled], answers.labels[labeled])
        # skipped queries count as asked (they cost the teacher's time) but not as labels
        self.phase.close_session(len(answers.labels), int(labeled.sum()))
        for key, value in (("asked", self.phase.asked), ("labeled", self.phase.labeled), ("sessions", self.phase.sessions)):
            self.logger.record(f"feedback/{key}", value)
        if self.asynchronous_feedback:  # how long the agent trained on the older reward while the session was answered
            self.logger.record("feedback/steps_awaiting", self.num_timesteps - answers.published_step)
            self.logger.record("feedback/seconds_awaiting", time.monotonic() - answers.published_time)
        if isinstance(self.feedback.teacher, InteractiveTeacher):
            self.feedback.teacher.show_progress(self.phase.asked, self.max_feedback)
        if self.phase.learned:  # r̂ has labels to learn from (this session's, or earlier runs')
            self.learn_reward()

    def learn_reward(self) -> None:
        """Train r̂ on every preference so far (``RewardLearner.learn``, Eqs. 1–2), then relabel the buffer with it."""
        report = self.reward_learner.learn(self.preferences, self.real_buffer, self.query_sampler, self.preference_rng)
        self.relabel()
        correlation = self.reward_learner.correlation(self.real_buffer, self.preference_rng)
        for key, value in vars(report).items():
            if value is not None:
                self.logger.record(f"reward_model/{key}", value)
        self.logger.record("reward_model/true_reward_corr", correlation)
        self.reward_learner.record(self.phase.sessions, self.num_timesteps, len(self.preferences), report, correlation)
        self.feedback.show_reward_history(self.reward_learner.history)
        if self.verbose > 0:
            print(
                f"feedback session {self.phase.sessions} at step {self.num_timesteps}: "
                f"{self.phase.labeled}/{self.phase.asked} labeled, reward-model accuracy {report.accuracy:.3f}, "
                f"corr(r_hat, r_true) {correlation:.3f}"
            )

    def relabel(self) -> None:
        """Every stored reward becomes r̂ of the current reward model (Algorithm 1, line 20)."""
        self.real_buffer.relabel(self.reward_learner.predict)

    def end_pretraining(self) -> None:
        """
        After the first feedback session: the critic learns from r̂ from now on (this step's update included, as
        B-Pref's update_after_reset); it is reset and trained ``critic_reset_updates`` steps on r̂, as PEBBLE does
        (with ``gradient_steps=0``, where ``learn()`` makes no gradient step at all, it is only reset).
        """
        reset_critic(self)
        updates = self.pretraining_kwargs["critic_reset_updates"]
        if self.gradient_steps != 0 and updates > 0:
            self.train(gradient_steps=updates, batch_size=self.batch_size)
            self.policy.set_training_mode(False)  # back to rollout mode

    # saving and loading ------------------------------------------------------------------------------------------------
    def save_reward_model(self, path: str | os.PathLike) -> None:
        """r̂ on its own (``LearnedReward``): its weights with the spaces it reads, for ``LearnedReward.load``."""
        LearnedReward.of_model(self).save(path)

    def load_replay_buffer(self, path, truncate_last_traj: bool = True) -> None:
        super().load_replay_buffer(path, truncate_last_traj)
        if not isinstance(self.replay_buffer, self.buffer_class):
            raise ValueError(f"{path} holds a {type(self.replay_buffer).__name__}, not a {self.buffer_class.__name__}")
        self.attach_parts()

    def _excluded_save_params(self) -> list[str]:
        # the parts are made again from the settings; the networks are saved as state dicts
        return [*super()._excluded_save_params(), "reward_model", "consistency_model", "query_sampler", "replay_rewards"]

    def _get_torch_save_params(self) -> tuple[list[str], list[str]]:
        state_dicts, variables = super()._get_torch_save_params()
        state_dicts = [*state_dicts, "reward_model", "reward_model.optimizer"]
        if self.consistency_model is not None:
            state_dicts += ["consistency_model", "consistency_model.optimizer"]
        return state_dicts, variables
