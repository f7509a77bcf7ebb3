import functools
import os
import threading
import time
import warnings
from collections.abc import Iterable
from collections import deque
from concurrent.futures import Future
from dataclasses import dataclass
from typing import Any, ClassVar, TypeVar

import numpy as np
import torch as th
from gymnasium import spaces
from stable_baselines3 import SAC
from stable_baselines3.common.buffers import ReplayBuffer
from stable_baselines3.common.callbacks import BaseCallback, ConvertCallback
from stable_baselines3.common.base_class import BaseAlgorithm, maybe_make_env
from stable_baselines3.common.noise import ActionNoise
from stable_baselines3.common.preprocessing import get_action_dim, get_flattened_obs_dim, is_image_space
from stable_baselines3.common.save_util import load_from_zip_file
from stable_baselines3.common.type_aliases import GymEnv, MaybeCallback, ReplayBufferSamples, Schedule
from stable_baselines3.common.vec_env import VecEnv, unwrap_vec_normalize
from stable_baselines3.sac.policies import SACPolicy

from sb3_pride.common.buffers import PreferenceReplayBuffer, with_reward_bonus
from sb3_pride.common.consistency import ConsistencyModel, DynamicsConsistency
from sb3_pride.pebble.callbacks import FeedbackCallback, UnsupervisedPretrainingCallback
from sb3_pride.common.entropy import StateEntropyReward
from sb3_pride.common.journal import JournalEntry, PreferenceJournal, atomic_write_path, merge_answers, query_id, undone_index
from sb3_pride.common.queries import (
    QUERY_SELECTIONS,
    SegmentPairs,
    chronological_rows,
    pair_features,
    recent_rows,
    sample_segment_pairs,
    select_queries,
)
from sb3_pride.common.reward_model import (
    ExplorationBonus,
    PreferenceDataset,
    PseudoLabels,
    RewardEnsemble,
    RobustLabels,
    check_temporal_crop,
)
from sb3_pride.common.teachers import FeedbackContext, InteractiveTeacher, ScriptedTeacher, Teacher, make_teacher
from sb3_pride.common.utils import check_choice, check_non_negative_ints, check_positive_ints, check_real, make_option, seeded

SelfPEBBLE = TypeVar("SelfPEBBLE", bound="PEBBLE")


@dataclass
class PendingFeedback:
    """
    A published feedback session: the answers the journal already had (``inputs``/``labels``), the teacher's answers
    to the new queries (``answers``: a finished future in blocking feedback) and when it was published.
    """

    session: int
    inputs: np.ndarray
    labels: np.ndarray
    n_journal_entries: int
    journal_length: int
    new_inputs: np.ndarray
    answers: "Future[np.ndarray]"
    published_step: int
    published_time: float


def _belongs_to(module: th.nn.Module, owner: th.nn.Module | None) -> bool:
    return owner is not None and any(module is part for part in owner.modules())


class PEBBLE(SAC):
    """
    PEBBLE: unsupervised Pre-training and preference-Based learning via relaBeLing Experience
    (Lee, Smith & Abbeel, ICML 2021), the preference-based SAC that PRIDE builds on
    (Feng et al., 2025, §3.3 and Algorithm 1 without its diffusion lines).

    The environment's reward never reaches SAC: it is kept beside the replay buffer for the teacher and for
    reporting (Monitor, EvalCallback and ``rollout/ep_rew_mean`` still show the true return). SAC learns from
    r̂, an ensemble of MLPs trained on the teacher's preferences between segment pairs (Bradley–Terry, Eqs. 1–2),
    with every stored reward relabeled after each reward update. Before the first feedback, after
    ``learning_starts`` random steps, SAC is pre-trained for ``unsupervised_steps`` on the k-NN state-entropy
    reward (Eq. 3); the critic is then reset and trained ``critic_reset_updates`` steps on r̂.

    Parameters not listed here are SAC's, with the same meaning and defaults except ``learning_starts``
    (PEBBLE: 1000) and ``n_steps``, which must stay 1 (n-step sums of rewards that relabeling rewrites).
    ``target_update_interval`` counts gradient steps within one ``train()`` call, as in SB3
    (DLR-RM/stable-baselines3#2158): at ``gradient_steps=1`` the target follows every update whatever its value.
    Saves (``save()``, ``save_replay_buffer()``, SB3's ``CheckpointCallback``) write a temporary file and rename it,
    so a run killed mid-save leaves the previous checkpoint readable.

    :param teacher: who labels the queries: a ``Teacher`` (a callable), an ``InteractiveTeacher`` (a person behind a
        UI, e.g. ``sb3_pride.human.WebTeacher``), or a name registered in ``sb3_pride.common.teachers.TEACHERS``: a
        B-Pref scripted teacher ("oracle", "mistake", "noisy", "skip", "myopic", "equal") or "web" (a person, in a
        browser: one ``WebTeacher()`` on port 8000 per process)
    :param max_feedback: Q, the total query budget
    :param feedback_interval: M, env steps between feedback sessions
    :param queries_per_session: K, queries asked per session (the last session is cut to the budget)
    :param segment_length: steps per segment (PEBBLE: 50); a segment never crosses an episode end
    :param query_selection: how queries are picked among ``candidates_multiplier`` × K random pairs:
        "uniform", "disagreement" (std of the members' P[σ1 ≻ σ0]) or "entropy" (their mean entropy), or B-Pref's
        coverage-based ones: "kcenter" (greedy k-center on the pairs' observations, the labelled pairs counting as
        covered), "kcenter_disagreement" and "kcenter_entropy" (k-center among the more uncertain half);
        the first session is always uniform
    :param candidates_multiplier: candidate pairs per query for the non-uniform selections (PEBBLE: 10)
    :param max_query_episodes: segments are drawn from this many most recent episodes (PEBBLE: 100)
    :param unsupervised_steps: env steps of state-entropy pre-training after ``learning_starts`` (PEBBLE: 9000)
    :param entropy_k: k of the k-NN state entropy (PEBBLE: 5)
    :param ensemble_size: members of the reward ensemble (PEBBLE: 3)
    :param reward_net_arch: hidden layers of each member (PEBBLE: 3 × 256)
    :param reward_learning_rate: Adam step size of the reward model (PEBBLE: 3e-4)
    :param reward_batch_size: preference pairs per reward minibatch (PEBBLE: 128)
    :param reward_epochs: most epochs over the preference dataset per session, stopping early at
        ``reward_early_stop`` training accuracy (PEBBLE: 50 on DMC, 10 on Meta-World)
    :param reward_early_stop: PEBBLE's early stop of reward learning (Lee et al., 2021; B-Pref's 97%): a feedback
        session's training ends after the first epoch whose training accuracy exceeds it. None: every one of
        ``reward_epochs`` runs (at low budgets the early stop under-trains r̂: ``benchmarks/reward_bench.py``)
    :param temporal_crop: temporal cropping of labelled pairs, from SURF (Park et al., ICLR 2022): at every reward
        minibatch each pair is cropped to one random length L in ``(min_length, max_length)`` (inclusive) with its own
        random start in each segment, and keeps its label; the loss compares the cropped returns. SURF crops 45–55
        steps out of 60 stored around each 50-step labelled segment; crops here lie inside the labelled segment, so
        ``max_length <= segment_length``: (35, 45) at segment 50 is QPA's S−15..S−5 (Hu et al., ICLR 2024).
        None: whole segments (PEBBLE)
    :param robust_labels: RIME's robust reward learning for noisy teachers (Cheng et al., ICML 2024): each epoch
        trains on the labels the ensemble finds plausible, flips those it is confident are wrong and leaves out the
        rest (``sb3_pride.common.reward_model.RobustLabels``). True: RIME's settings; a dict: ``RobustLabels``'
        settings (``alpha``, ``beta_init``, ``beta_min``, ``beta_decay_epochs``, ``flip_probability``). False: every
        label as given (PEBBLE)
    :param pseudo_labels: SURF's semi-supervised reward learning (Park et al., ICLR 2022): unlabelled segment pairs
        from the replay buffer beside each labelled minibatch, each member learning from its own confident
        pseudo-labels (``sb3_pride.common.reward_model.PseudoLabels``). True: SURF's walker-walk settings; a dict:
        ``PseudoLabels``' settings (``threshold``, ``ratio``, ``weight``, ``unlabeled_per_label``, ``max_unlabeled``).
        False: labels only (PEBBLE)
    :param hybrid_replay: QPA's hybrid experience replay (Hu et al., ICLR 2024): after pre-training and while queries
        remain to be asked, this share of each SAC minibatch is drawn from the ``max_query_episodes`` most recent
        episodes, where the queries come from, so that the policy learns most where r̂ is being taught (QPA: 0.5,
        with ``max_query_episodes=10``: its policy-aligned queries). 0: uniform sampling (PEBBLE)
    :param dynamics_consistency: REED's self-supervised pre-training of the reward model's encoder (Metcalf et al.,
        CoRL 2023): before each feedback session's reward learning, the members' hidden layers learn from the stored
        transitions (s, a, s') to predict the next state's representation, with SimSiam's loss
        (``sb3_pride.common.consistency.DynamicsConsistency``). True: REED's settings with Adam; a dict:
        ``DynamicsConsistency``' settings (``epochs``, ``batch_size``, ``learning_rate``, ``optimizer``,
        ``projection_size``, ``hidden_size``, ``max_transitions``). False: labels only (PEBBLE)
    :param exploration_bonus: RUNE's exploration bonus (Liang et al., ICLR 2022): from the first feedback session on,
        SAC learns from r̂ + β_t · σ, σ the reward ensemble's disagreement on each (s, a) and β_t decaying with the env
        steps (``sb3_pride.common.reward_model.ExplorationBonus``). True: RUNE's settings; a dict: ``ExplorationBonus``'
        settings (``beta_init``, ``beta_decay``). False: r̂ alone (PEBBLE)
    :param critic_reset_updates: gradient steps on r̂ right after the critic reset (PEBBLE: 100)
    :param preference_journal: a JSON-lines file to which every answer of the teacher (the pair's inputs and μ,
        or a skip) is appended and flushed to disk the moment it is given. A model created or loaded with a journal
        that holds answers it does not have (a run killed after its last checkpoint) takes them back in the
        sessions they were given in, asking the teacher only for the rest: no answer is lost, none asked twice.
        None: no journal
    :param asynchronous_feedback: False: training waits while the teacher answers a feedback session (PEBBLE).
        True: a session's queries are published, its teacher answers them in a thread of its own (a person in a
        browser, a slow labeler), and training goes on meanwhile with the reward model it has: the answers are taken
        in (preferences added, r̂ retrained, buffer relabeled) at the first step after the last of them is in, and the
        next session is published only then, at the earliest. Pre-training goes on until the first session's answers
        are in. ``learn()`` waits for a session still open when it ends. The steps made on the older reward are
        logged (``feedback/steps_awaiting``). The step at which answers are taken in depends on the teacher's pace,
        so runs are not reproducible from their seed alone
    """

    policy_aliases: ClassVar[dict[str, type[SACPolicy]]] = SAC.policy_aliases  # type: ignore[assignment]
    #: the replay buffer class this algorithm needs (a user's ``replay_buffer_class`` must subclass it)
    buffer_class: ClassVar[type[PreferenceReplayBuffer]] = PreferenceReplayBuffer
    #: the options given as False (off), True (the published settings) or a dict, and the class of their settings
    option_settings: ClassVar[dict[str, type]] = {
        "robust_labels": RobustLabels,
        "pseudo_labels": PseudoLabels,
        "dynamics_consistency": DynamicsConsistency,
        "exploration_bonus": ExplorationBonus,
    }
    replay_buffer: PreferenceReplayBuffer
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
        teacher: str | Teacher = "oracle",
        max_feedback: int = 1000,
        feedback_interval: int = 20_000,
        queries_per_session: int = 100,
        segment_length: int = 50,
        query_selection: str = "disagreement",
        candidates_multiplier: int = 10,
        max_query_episodes: int = 100,
        unsupervised_steps: int = 9000,
        entropy_k: int = 5,
        ensemble_size: int = 3,
        reward_net_arch: list[int] | tuple[int, ...] = (256, 256, 256),
        reward_learning_rate: float = 3e-4,
        reward_batch_size: int = 128,
        reward_epochs: int = 50,
        reward_early_stop: float | None = 0.97,
        temporal_crop: tuple[int, int] | None = None,
        robust_labels: bool | dict[str, Any] = False,
        pseudo_labels: bool | dict[str, Any] = False,
        hybrid_replay: float = 0.0,
        dynamics_consistency: bool | dict[str, Any] = False,
        exploration_bonus: bool | dict[str, Any] = False,
        critic_reset_updates: int = 100,
        preference_journal: str | os.PathLike | None = None,
        asynchronous_feedback: bool = False,
        _init_setup_model: bool = True,
    ):
        check_positive_ints(
            max_feedback=max_feedback,
            feedback_interval=feedback_interval,
            queries_per_session=queries_per_session,
            segment_length=segment_length,
            candidates_multiplier=candidates_multiplier,
            max_query_episodes=max_query_episodes,
            entropy_k=entropy_k,
            ensemble_size=ensemble_size,
            reward_batch_size=reward_batch_size,
            reward_epochs=reward_epochs,
        )
        check_non_negative_ints(unsupervised_steps=unsupervised_steps, critic_reset_updates=critic_reset_updates)
        if isinstance(gradient_steps, bool) or not isinstance(gradient_steps, (int, np.integer)):
            # SB3's: -1 as many updates as env steps collected, 0 none (a user's own loop calls train())
            raise ValueError(f"gradient_steps must be an integer, got {gradient_steps!r}")
        check_choice("query_selection", query_selection, QUERY_SELECTIONS)
        if not isinstance(asynchronous_feedback, (bool, np.bool_)):
            raise ValueError(f"asynchronous_feedback must be True or False, got {asynchronous_feedback!r}")
        check_real("reward_learning_rate", reward_learning_rate, lambda lr: 0 < lr < np.inf, "> 0 and finite")
        temporal_crop = check_temporal_crop(temporal_crop, segment_length)
        # checked before anything is made
        options = dict(robust_labels=robust_labels, pseudo_labels=pseudo_labels,
                       dynamics_consistency=dynamics_consistency, exploration_bonus=exploration_bonus)  # fmt: skip
        settings = {name: make_option(name, value, self.option_settings[name]) for name, value in options.items()}
        label_selection: RobustLabels | None = settings["robust_labels"]
        check_real("hybrid_replay", hybrid_replay, lambda share: 0 <= share <= 1, "in [0, 1]")
        if settings["exploration_bonus"] is not None and ensemble_size < 2:
            raise ValueError(f"exploration_bonus needs ensemble_size >= 2 (its σ is the members' spread), got {ensemble_size}")

        if reward_early_stop is not None:
            check_real("reward_early_stop", reward_early_stop, lambda a: 0 < a < 1, "None (no early stop) or in (0, 1)")
        if n_steps != 1:
            raise ValueError(
                f"n_steps must be 1, got {n_steps}: n-step returns sum stored rewards along a trajectory, but PEBBLE "
                "relabels every stored reward with r̂ after each reward update (and r_int is computed per minibatch), "
                "so the sums would mix rewards of different models"
            )
        if replay_buffer_class is not None and not issubclass(replay_buffer_class, self.buffer_class):
            raise ValueError(
                f"replay_buffer_class must subclass {self.buffer_class.__name__} (true rewards kept aside), "
                f"got {replay_buffer_class.__name__}"
            )
        # resolved before the env is made: a teacher that renders (a person's) may set up headless rendering first
        resolved_teacher = make_teacher(teacher, seed=seed)
        if env is not None:
            # rl-zoo3 and SB3's load() build the model with _init_setup_model=False before restoring its
            # segment_length: load() checks the episode length itself, once the saved value is back
            env = self._check_env(env, segment_length if _init_setup_model else None, verbose)

        super().__init__(
            policy,
            env,
            learning_rate=learning_rate,
            buffer_size=buffer_size,
            learning_starts=learning_starts,
            batch_size=batch_size,
            tau=tau,
            gamma=gamma,
            train_freq=train_freq,
            gradient_steps=gradient_steps,
            action_noise=action_noise,
            replay_buffer_class=replay_buffer_class or self.buffer_class,
            replay_buffer_kwargs=replay_buffer_kwargs,
            optimize_memory_usage=optimize_memory_usage,
            ent_coef=ent_coef,
            target_update_interval=target_update_interval,
            target_entropy=target_entropy,
            use_sde=use_sde,
            sde_sample_freq=sde_sample_freq,
            use_sde_at_warmup=use_sde_at_warmup,
            stats_window_size=stats_window_size,
            tensorboard_log=tensorboard_log,
            policy_kwargs=policy_kwargs,
            verbose=verbose,
            seed=seed,
            device=device,
            _init_setup_model=False,
        )
        # kept as given (a registered name stays a name, so that rl-zoo3 can pass it again on resume)
        self.teacher = teacher
        #: (name, teacher) of a teacher given by name (a scripted one is saved with its random state)
        self._named_teacher: tuple[str, Teacher | InteractiveTeacher] | None = None
        if isinstance(teacher, str):
            self._named_teacher = (teacher, resolved_teacher)
        self.max_feedback = max_feedback
        self.feedback_interval = feedback_interval
        self.queries_per_session = queries_per_session
        self.segment_length = segment_length
        self.query_selection = query_selection
        self.candidates_multiplier = candidates_multiplier
        self.max_query_episodes = max_query_episodes
        self.unsupervised_steps = unsupervised_steps
        self.entropy_k = entropy_k
        self.ensemble_size = ensemble_size
        self.reward_net_arch = tuple(reward_net_arch)
        self.reward_learning_rate = reward_learning_rate
        self.reward_batch_size = reward_batch_size
        self.reward_epochs = reward_epochs
        self.reward_early_stop = reward_early_stop
        self.temporal_crop = temporal_crop
        self.robust_labels = robust_labels if isinstance(robust_labels, dict) else bool(robust_labels)
        #: RIME's running selection of trusted labels (None: every label as given), saved with the model
        self.label_selection = label_selection
        self.pseudo_labels = pseudo_labels if isinstance(pseudo_labels, dict) else bool(pseudo_labels)
        self.hybrid_replay = float(hybrid_replay)
        self.dynamics_consistency = (
            dynamics_consistency if isinstance(dynamics_consistency, dict) else bool(dynamics_consistency)
        )
        self.exploration_bonus = exploration_bonus if isinstance(exploration_bonus, dict) else bool(exploration_bonus)
        self.critic_reset_updates = critic_reset_updates
        self.preference_journal = None if preference_journal is None else os.fspath(preference_journal)
        self.asynchronous_feedback = bool(asynchronous_feedback)
        #: the published feedback session whose answers are awaited (asynchronous feedback; never saved)
        self._pending_feedback: PendingFeedback | None = None
        self._teacher_records: deque[tuple[str, float]] = deque()  # what the teacher asked to log (thread-safe appends)
        #: env steps the agent made while a published session's answers were awaited, over the run
        self.steps_awaiting_feedback = 0
        # learning state, saved with the model
        self.feedback_asked = 0
        self.feedback_labeled = 0
        self.feedback_sessions = 0
        #: how many entries of the preference journal this model's preference dataset and counters include
        self.journal_entries = 0
        self._journal_cache: tuple[str, list[JournalEntry]] | None = None
        self.next_feedback_step = learning_starts + unsupervised_steps
        self.preference_rng = np.random.default_rng(seed)
        self.state_entropy = StateEntropyReward(k=entropy_k)
        #: train() calls between two critic diagnostics (train/critic_loss_real, train/q_real, train/q)
        self.diagnostic_interval = 100
        self._train_calls = 0
        self._warned_short_episodes = False
        self._diagnostic_rng = np.random.default_rng(None if seed is None else seed + 1)

        if _init_setup_model:
            self._setup_model()

    @staticmethod
    def _check_env(env: GymEnv | str, segment_length: int | None, verbose: int) -> GymEnv:
        """
        Preference learning needs flat Box observations and Box actions (say how to get them), no reward
        normalization, and episodes that can hold a segment. Run by the constructor, ``set_env()`` and ``load()``.

        :param segment_length: None: skip the episode-length check
        """
        env = BaseAlgorithm._wrap_env(maybe_make_env(env, verbose), verbose)
        obs_space, action_space = env.observation_space, env.action_space
        if is_image_space(obs_space, normalized_image=True):
            raise ValueError(
                f"env has image observations {obs_space}: not supported. The reward model, the state entropy and the "
                "diffusion model take one flat vector of states; use the env's proprioceptive states (dm_control and "
                "Meta-World provide them: e.g. 'sb3_pride/walker-walk-v0', 'sb3_pride/button-press-v3')"
            )
        if isinstance(obs_space, spaces.Dict):
            raise ValueError(
                "env has a Dict observation space (dm_control's default); the reward model and the state entropy "
                "need one flat vector: wrap it with sb3_pride.envs.flatten_observations(env) (or gymnasium's "
                "FlattenObservation), or make it as 'sb3_pride/<domain>-<task>-v0', e.g. 'sb3_pride/walker-walk-v0'"
            )
        if not isinstance(obs_space, spaces.Box) or len(obs_space.shape) != 1:
            raise ValueError(f"env must have a 1-D Box observation space, got {obs_space}")
        if not isinstance(action_space, spaces.Box):
            raise ValueError(f"env must have a Box (continuous) action space, got {action_space}")
        normalization = unwrap_vec_normalize(env)
        if normalization is not None and normalization.norm_reward:
            raise ValueError(
                "env is a VecNormalize with norm_reward=True: it would scale r̂ by statistics of the true return "
                "(a leak, and the wrong scale); use VecNormalize(..., norm_reward=False)"
            )
        if segment_length is not None:
            PEBBLE._check_episode_length(env, segment_length)
        return env

    @staticmethod
    def _check_episode_length(env: VecEnv, segment_length: int) -> None:
        """Refuse a segment longer than the env's own step limit (episodes that end earlier only warn, later)."""
        specs = env.get_attr("spec")
        limits = [spec.max_episode_steps for spec in specs if spec is not None and spec.max_episode_steps]
        if limits and min(limits) < segment_length:
            raise ValueError(f"segment_length={segment_length} is longer than an episode of this env ({min(limits)} steps)")

    def set_env(self, env: GymEnv, force_reset: bool = True) -> None:
        """SB3's ``set_env``, after the constructor's checks of ``env`` (spaces, reward normalization, episode length)."""
        super().set_env(self._check_env(env, self.segment_length, self.verbose), force_reset=force_reset)
        self._attach_teacher()

    @classmethod
    def load(cls, path, env: GymEnv | None = None, device: th.device | str = "auto", custom_objects=None,
             print_system_info: bool = False, force_reset: bool = True, **kwargs):  # fmt: skip
        """
        SB3's ``load``; a new ``env`` gets the constructor's checks with the saved ``segment_length``, and
        ``dynamics_consistency`` may change its settings but not turn it on or off (its heads are saved with the model)
        nor change its optimizer (whose state is saved too).
        """
        if "dynamics_consistency" in kwargs:
            saved, _, _ = load_from_zip_file(path, device=device, custom_objects=custom_objects)
            was, now = (
                make_option("dynamics_consistency", value, cls.option_settings["dynamics_consistency"])
                for value in ((saved or {}).get("dynamics_consistency", False), kwargs["dynamics_consistency"])
            )
            if (was is None) != (now is None):
                raise ValueError(
                    f"dynamics_consistency: the model at {path} was saved with it {'off' if was is None else 'on'}, "
                    "and loading cannot turn it " + ("on" if was is None else "off") + "; leave dynamics_consistency "
                    "out, or give settings that keep it " + ("off" if was is None else "on")
                )
            if was is not None and now is not None and was.optimizer != now.optimizer:
                raise ValueError(
                    f"dynamics_consistency: the model at {path} was saved with optimizer={was.optimizer!r}, whose "
                    f"state it holds, and cannot load into optimizer={now.optimizer!r}; leave optimizer out"
                )
        model = super().load(path, env, device, custom_objects, print_system_info, force_reset, **kwargs)
        if env is not None and model.env is not None:
            model._check_env(model.env, model.segment_length, model.verbose)
        return model

    def option(self, name: str) -> Any:
        """
        The settings one of the options of ``option_settings`` was given, made anew from the constructor's value.
        For ``robust_labels`` these are the settings only: the running selection is ``label_selection``.

        :param name: the option's constructor argument, e.g. ``"dynamics_consistency"``
        :return: a ``RobustLabels``, ``PseudoLabels``, ``DynamicsConsistency`` or ``ExplorationBonus``; None where the
            option is off
        """
        check_choice("name", name, tuple(self.option_settings))
        # models saved before an option existed have no attribute for it: off
        return make_option(name, getattr(self, name, False), self.option_settings[name])

    def _setup_model(self) -> None:
        if "_scripted_teacher" in self.__dict__:  # a model saved by version 0.1.0: its scripted teacher, random state kept
            saved = self.__dict__.pop("_scripted_teacher")
            self._named_teacher = saved if saved is not None else self._named_teacher
            self.__dict__.pop("_web_teacher", None)
        super()._setup_model()
        obs_dim, action_dim = get_flattened_obs_dim(self.observation_space), get_action_dim(self.action_space)
        self.reward_model = RewardEnsemble(
            obs_dim,
            action_dim,
            n_members=self.ensemble_size,
            net_arch=self.reward_net_arch,
            learning_rate=self.reward_learning_rate,
            device=self.device,
        )
        settings = self.option("dynamics_consistency")
        #: REED's consistency heads on r̂'s encoder (None: off), saved with the model
        self.consistency_model = None if settings is None else ConsistencyModel(self.reward_model, obs_dim, settings)
        if getattr(self, "preferences", None) is None:  # a loaded model has its own
            self.preferences = PreferenceDataset(self.segment_length, obs_dim + action_dim)
        self._attach_reward_model()
        self._journal_cache = None
        self.journal_history()  # a journal that does not fit this model fails now, not at the next session
        self._attach_teacher()

    def _attach_reward_model(self) -> None:
        """New transitions get r̂ once a reward model was learned (0 before, overwritten by the first relabel)."""
        self.real_buffer.reward_fn = self.reward_model.predict if len(self.preferences) > 0 else None

    @property
    def real_buffer(self) -> PreferenceReplayBuffer:
        """Where the agent's own transitions and their true rewards are (the whole replay buffer in PEBBLE)."""
        return self.replay_buffer

    @property
    def in_pretraining(self) -> bool:
        """True until the first feedback session: SAC then learns from the state-entropy reward."""
        return self.feedback_sessions == 0

    def train(self, gradient_steps: int, batch_size: int = 64) -> None:
        self.update_hybrid_replay()
        self.update_exploration_bonus()
        super().train(gradient_steps, batch_size)
        self._train_calls += 1
        if not self.in_pretraining and self._train_calls % self.diagnostic_interval == 0:
            critic_loss, q_value = self.critic_diagnostics(batch_size, real_only=True)
            self.logger.record_mean("train/critic_loss_real", critic_loss)
            self.logger.record_mean("train/q_real", q_value)
            # beside SB3's train/critic_loss: Q on a minibatch drawn as SAC draws it (mixed in PRIDE, real in PEBBLE)
            self.logger.record_mean("train/q", self.critic_diagnostics(batch_size, real_only=False)[1])

    @th.no_grad()
    def critic_diagnostics(self, batch_size: int, real_only: bool = True) -> tuple[float, float]:
        """
        SAC's critic loss (r̂ + γ(1 − d)(min Q_target(s', a') − α log π(a'|s'))) and the mean Q(s, a) on a minibatch
        of real transitions only (``real_only``: PEBBLE's and PRIDE's critics compared like for like, whatever PRIDE
        mixes in), or on one drawn from the replay buffer as SAC's updates draw it. Draws from its own random
        generators (NumPy's and torch's global states are restored), so logging it changes no training run.
        """
        numpy_state = np.random.get_state()  # SB3's sample() and _get_samples draw from NumPy's global RNG
        with seeded(int(self._diagnostic_rng.integers(2**62)), self.device):
            np.random.seed(int(self._diagnostic_rng.integers(2**32)))
            if real_only:
                rows = self._diagnostic_rng.integers(0, self.real_buffer.size(), size=batch_size)
                data = with_reward_bonus(
                    self.real_buffer._get_samples(rows, env=self._vec_normalize_env), self.replay_buffer.reward_bonus
                )
            else:
                data = self.replay_buffer.sample(batch_size, env=self._vec_normalize_env)
            next_actions, next_log_prob = self.actor.action_log_prob(data.next_observations)
            next_q = th.min(th.cat(self.critic_target(data.next_observations, next_actions), dim=1), dim=1, keepdim=True)[0]
            ent_coef = self.ent_coef_tensor if self.log_ent_coef is None else th.exp(self.log_ent_coef)
            target = data.rewards + (1 - data.dones) * self.gamma * (next_q - ent_coef * next_log_prob.reshape(-1, 1))
            current = self.critic(data.observations, data.actions)
        np.random.set_state(numpy_state)
        critic_loss = 0.5 * sum(th.nn.functional.mse_loss(q, target) for q in current)
        return float(critic_loss), float(th.cat(current, dim=1).mean())

    def update_hybrid_replay(self) -> None:
        """
        QPA's hybrid replay (``hybrid_replay``): after pre-training and while queries remain to be asked, that share of
        each SAC minibatch comes from the ``max_query_episodes`` most recent episodes (where the queries come from);
        otherwise SAC samples uniformly.
        """
        share = getattr(self, "hybrid_replay", 0.0)  # models saved by 0.1.0 have none
        active = share > 0 and not self.in_pretraining and self.feedback_asked < self.max_feedback
        self.real_buffer.recent_share = share if active else 0.0
        self.real_buffer.recent_rows = recent_rows(self.real_buffer, self.max_query_episodes) if active else None

    def update_exploration_bonus(self) -> None:
        """
        RUNE's bonus (``exploration_bonus``) on SAC's minibatches once r̂ has learned from labels (after pre-training);
        logs β_t. β_t counts ``num_timesteps``, so ``learn(reset_num_timesteps=True)`` starts it again at β_0.
        """
        settings = self.option("exploration_bonus")
        active = settings is not None and not self.in_pretraining and len(self.preferences) > 0
        self.replay_buffer.reward_bonus = (
            functools.partial(self.exploration_bonus_rewards, settings=settings) if active else None
        )
        if active:
            self.logger.record("train/exploration_beta", settings.beta(self.num_timesteps))

    @th.no_grad()
    def exploration_bonus_rewards(self, samples: ReplayBufferSamples, settings: ExplorationBonus) -> th.Tensor:
        """
        RUNE's β_t · σ(s, a) of a minibatch, σ the members' standard deviation of r̂_m(s, a) (divided by the number of
        members, as RUNE's). Under ``VecNormalize`` the observations are un-normalized first (r̂ reads them as stored;
        values VecNormalize clipped stay clipped).
        """
        observations = samples.observations
        if self._vec_normalize_env is not None:
            raw = self._vec_normalize_env.unnormalize_obs(observations.cpu().numpy())
            observations = th.as_tensor(raw, dtype=th.float32, device=samples.rewards.device)
        inputs = th.cat([observations.float(), samples.actions.float()], dim=-1).to(self.reward_model.device)
        sigma = self.reward_model(inputs).std(dim=0, correction=0)  # (B, 1), like the rewards
        return (settings.beta(self.num_timesteps) * sigma).to(samples.rewards.device, samples.rewards.dtype)

    def update_reward_source(self) -> None:
        """SAC's reward: r_int (Eq. 3) while pre-training, r̂ (Eq. 1) from the first feedback session on."""
        self.real_buffer.intrinsic_reward = self.state_entropy if self.in_pretraining else None

    def _setup_learn(
        self,
        total_timesteps: int,
        callback: MaybeCallback = None,
        reset_num_timesteps: bool = True,
        tb_log_name: str = "run",
        progress_bar: bool = False,
    ) -> tuple[int, BaseCallback]:
        if reset_num_timesteps and self.num_timesteps > 0:
            # the step count restarts at 0: keep the schedules' remaining distances
            self._shift_schedules(-self.num_timesteps)
        if reset_num_timesteps or self._last_obs is None:
            # SB3 resets the env now: the episode in progress ends here, or a query segment could span two episodes
            self.real_buffer.end_episodes()
        return super()._setup_learn(total_timesteps, callback, reset_num_timesteps, tb_log_name, progress_bar)

    def _shift_schedules(self, steps: int) -> None:
        self.next_feedback_step = max(0, self.next_feedback_step + steps)
        if self._pending_feedback is not None:
            self._pending_feedback.published_step += steps

    def _init_callback(self, callback: MaybeCallback, progress_bar: bool = False) -> BaseCallback:
        # the algorithm's own callbacks run first, then the user's
        if callback is None:
            user_callbacks = []
        elif isinstance(callback, list):
            user_callbacks = callback
        elif isinstance(callback, BaseCallback):
            user_callbacks = [callback]
        else:
            user_callbacks = [ConvertCallback(callback)]
        return super()._init_callback(self._preference_callbacks() + user_callbacks, progress_bar)

    def _preference_callbacks(self) -> list[BaseCallback]:
        return [UnsupervisedPretrainingCallback(), FeedbackCallback(verbose=self.verbose)]

    def resolve_teacher(self) -> Teacher | InteractiveTeacher:
        """The teacher object: a registered name is made into one once (``make_teacher``), with the run's seed."""
        if not isinstance(self.teacher, str):
            return self.teacher
        if self._named_teacher is None or self._named_teacher[0] != self.teacher:
            self._named_teacher = (self.teacher, make_teacher(self.teacher, seed=self.seed))
        return self._named_teacher[1]

    def _attach_teacher(self) -> None:
        """
        An ``InteractiveTeacher`` is attached to the env and the replay buffer (it checks that the env can be shown
        and switches on the recording of what it needs, so that an env it cannot show fails now, not at the first
        feedback session); any other teacher records nothing beside the transitions.
        """
        teacher = self.resolve_teacher()
        if isinstance(teacher, InteractiveTeacher):
            if self.env is not None:
                teacher.attach(self.env, self.real_buffer)
                teacher.show_progress(self.feedback_asked, self.max_feedback)
        elif getattr(self, "replay_buffer", None) is not None:  # a resumed buffer may say otherwise
            self.real_buffer.record_render_states = False

    def ask_teacher(self, pairs: SegmentPairs) -> np.ndarray:
        """
        The teacher's labels μ for ``pairs``, checked: one per pair, each in [0, 1] or NaN (skipped). An
        ``InteractiveTeacher`` journals its answers itself, as they come (``FeedbackContext``).
        """
        teacher = self.resolve_teacher()
        if isinstance(teacher, InteractiveTeacher):
            context = FeedbackContext(
                session=self.feedback_sessions + 1,
                asked_before=self.feedback_asked,
                budget=self.max_feedback,
                record=self.record_answers,
                retract=self.retract_answer,
                log=lambda key, value: self._teacher_records.append((key, value)),  # logged later, by the model's thread
            )
            answer = teacher.ask(pairs, context)
        else:
            answer = teacher(pairs)
        try:
            labels = np.asarray(answer)
        except ValueError as error:  # ragged nesting
            raise ValueError(f"teacher must return one number per segment pair, got {answer!r}: {error}") from None
        if labels.dtype.kind not in "biuf":  # None, strings, objects: np.asarray(dtype=float) would make None a NaN
            raise ValueError(f"teacher must return numbers (NaN to skip a pair), got {answer!r}")
        labels = labels.astype(np.float64).reshape(-1)
        if len(labels) != len(pairs):
            raise ValueError(f"teacher returned {len(labels)} labels for {len(pairs)} segment pairs")
        finite = labels[~np.isnan(labels)]
        if np.any((finite < 0) | (finite > 1)):
            raise ValueError("teacher labels must be in [0, 1] (P[second segment preferred]) or NaN (skipped)")
        return labels

    # a feedback session (Algorithm 1, lines 6–21) ------------------------------------------------------------------
    def feedback_session(self) -> bool:
        """
        Ask, label, learn r̂, relabel, waiting for the teacher: ``publish_queries(asynchronous=False)``, then
        ``take_answers()``.

        :return: False when no segment fits in the stored episodes yet (nothing was asked)
        """
        if not self.publish_queries(asynchronous=False):
            return False
        self.take_answers()
        return True

    @property
    def feedback_open(self) -> bool:
        """Whether a published feedback session's answers are still to be taken in (``take_answers()``)."""
        return self._pending_feedback is not None

    @property
    def answers_ready(self) -> bool:
        """Whether the teacher has answered every query of the open feedback session (``take_answers()`` won't wait)."""
        return self._pending_feedback is not None and self._pending_feedback.answers.done()

    def publish_queries(self, asynchronous: bool | None = None) -> bool:
        """
        Open a feedback session: choose its ``min(queries_per_session, max_feedback - asked)`` queries and give them to
        the teacher. Answers of this session already in the preference journal (given before a crash) are taken from
        it; the teacher is asked only for the rest, never for a query it answered.

        :param asynchronous: True: the teacher answers in a thread of its own and this returns at once; False: it
            returns once the teacher has answered; None: ``asynchronous_feedback``
        :return: False when no segment fits in the stored episodes yet (nothing was asked)
        """
        if self._pending_feedback is not None:
            raise RuntimeError(
                f"feedback session {self._pending_feedback.session} is still open: take_answers() before publishing more"
            )
        asynchronous = self.asynchronous_feedback if asynchronous is None else asynchronous
        session = self.feedback_sessions + 1
        n_queries = min(self.queries_per_session, self.max_feedback - self.feedback_asked)
        # several annotators' answers to one query are one answer: their mean μ (journal.merge_answers)
        raw = self.journaled_answers(session)
        journal_length = len(self.journal_history())  # before the teacher journals this session's new answers
        journaled = merge_answers(raw)[:n_queries]
        kept = {entry.id for entry in journaled}
        candidates = self.choose_queries(n_queries - len(journaled))
        if candidates is None:
            return False
        answers: Future[np.ndarray] = Future()
        if len(candidates) == 0:
            answers.set_result(np.zeros(0))
        elif asynchronous:
            # a daemon thread: a person who never answers does not keep the process alive after an interrupt
            threading.Thread(target=self._answer_in_thread, args=(candidates, answers), name="teacher", daemon=True).start()
        else:
            answers.set_result(self.ask_teacher(candidates))  # a teacher's error is raised here: nothing recorded
        self._pending_feedback = PendingFeedback(
            session=session,
            inputs=np.stack([entry.inputs for entry in journaled]) if journaled else candidates.inputs[:0],
            labels=np.array([entry.label for entry in journaled], dtype=np.float64),
            n_journal_entries=sum(entry.id in kept for entry in raw),
            journal_length=journal_length,
            new_inputs=candidates.inputs,
            answers=answers,
            published_step=self.num_timesteps,
            published_time=time.monotonic(),
        )
        return True

    def _answer_in_thread(self, candidates: SegmentPairs, answers: "Future[np.ndarray]") -> None:
        """The teacher's thread (asynchronous feedback): its labels, or its error, go into ``answers``."""
        answers.set_running_or_notify_cancel()
        try:
            answers.set_result(self.ask_teacher(candidates))
        except BaseException as error:  # raised by take_answers() in the model's thread
            answers.set_exception(error)

    @property
    def feedback_published_step(self) -> int | None:
        """The env step at which the open feedback session was published (None: no session is open)."""
        return None if self._pending_feedback is None else self._pending_feedback.published_step

    def take_answers(self) -> None:
        """
        Close the open feedback session (waiting for its answers if they are not all in): journal them (a scripted
        teacher's; an interactive teacher journals each as it is given), add the labeled ones to the preferences,
        learn r̂ and relabel. A teacher's error is raised here, with nothing of the session recorded.
        """
        pending = self._pending_feedback
        if pending is None:
            raise RuntimeError("no feedback session is open: publish_queries() first")
        try:
            new_labels = pending.answers.result()
        except BaseException:
            if pending.answers.done():  # the teacher failed: the session is over, nothing of it recorded
                self._pending_feedback = None
            raise  # an interrupt while waiting leaves the session open: the teacher may still answer
        finally:
            self._log_teacher_records()
        self._pending_feedback = None
        interactive = isinstance(self.resolve_teacher(), InteractiveTeacher)
        # the journal is written before the answers are used: a crash from here on loses none of them
        if not interactive:
            self.record_answers(
                [
                    JournalEntry(pending.session, pair, label)
                    for pair, label in zip(pending.new_inputs, new_labels, strict=True)
                ]
            )
        if interactive and self.preference_journal is not None:
            # every answer the teacher journaled during the session (several per query from several annotators)
            self.journal_entries += pending.n_journal_entries + len(self.journal_history()) - pending.journal_length
        else:
            self.journal_entries += pending.n_journal_entries + len(new_labels)
        inputs = np.concatenate([pending.inputs, pending.new_inputs])
        labels = np.concatenate([pending.labels, new_labels])
        labeled = ~np.isnan(labels)
        self.preferences.add(inputs[labeled], labels[labeled])
        # skipped queries count as asked (they cost the teacher's time) but not as labels
        self.feedback_asked += len(labels)
        self.feedback_labeled += int(labeled.sum())
        self.feedback_sessions += 1
        self.logger.record("feedback/asked", self.feedback_asked)
        self.logger.record("feedback/labeled", self.feedback_labeled)
        self.logger.record("feedback/sessions", self.feedback_sessions)
        if self.asynchronous_feedback:
            # how long the agent trained on the older reward while this session was answered
            self.steps_awaiting_feedback += self.num_timesteps - pending.published_step
            self.logger.record("feedback/steps_awaiting", self.num_timesteps - pending.published_step)
            self.logger.record("feedback/seconds_awaiting", time.monotonic() - pending.published_time)
        teacher = self.resolve_teacher()
        if isinstance(teacher, InteractiveTeacher):
            teacher.show_progress(self.feedback_asked, self.max_feedback)
        if len(self.preferences) > 0:
            self.learn_reward()

    def choose_queries(self, n_queries: int) -> SegmentPairs | None:
        """
        Sample candidate pairs and select ``n_queries`` of them (``query_selection``; the first session uniform).
        Pairs the journal already holds are never chosen again.

        :return: the chosen pairs (fewer when the journal held candidates), or None when no segment fits in the
            stored episodes yet
        """
        if n_queries == 0:
            obs_dim, action_dim = get_flattened_obs_dim(self.observation_space), get_action_dim(self.action_space)
            shape = (0, 2, self.segment_length)
            return SegmentPairs(np.zeros((*shape, obs_dim)), np.zeros((*shape, action_dim)), np.zeros(shape))
        # the first session is uniform: the reward model knows nothing yet
        selection = "uniform" if self.feedback_sessions == 0 else self.query_selection
        n_candidates = n_queries if selection == "uniform" else n_queries * self.candidates_multiplier
        candidates = sample_segment_pairs(
            self.real_buffer, n_candidates, self.segment_length, self.max_query_episodes, self.preference_rng
        )
        if candidates is None:
            self.warn_short_episodes()
            return None
        asked_before = {entry.id for entry in self.journal_history()}
        if asked_before:
            candidates = candidates[np.array([query_id(pair) not in asked_before for pair in candidates.inputs])]
        if selection != "uniform" and len(candidates) > 0:
            returns = self.reward_model.member_segment_returns(candidates.inputs)
            n_obs = candidates.observations.shape[-1]
            chosen = select_queries(
                returns,
                min(n_queries, len(candidates)),
                selection,
                features=pair_features(candidates.observations),
                labeled_features=pair_features(self.preferences.inputs[..., :n_obs]),
            )
            candidates = candidates[chosen]
        return candidates

    def ask_new_queries(self, n_queries: int) -> tuple[np.ndarray | None, np.ndarray]:
        """
        Choose ``n_queries`` pairs (``choose_queries``) and ask the teacher (``ask_teacher`` checks the answers).

        :return: the pairs' reward-model inputs (n, 2, k, obs_dim + action_dim) and their labels μ (NaN: skipped),
            or (None, _) when no segment fits in the stored episodes yet
        """
        candidates = self.choose_queries(n_queries)
        if candidates is None:
            return None, np.zeros(0)
        return candidates.inputs, self.ask_teacher(candidates) if len(candidates) else np.zeros(0)

    def unlabeled_pairs(self, pseudo_labels: PseudoLabels) -> np.ndarray | None:
        """SURF's unlabelled pairs for a feedback session's training: ``unlabeled_per_label`` per label, drawn as queries."""
        n = min(pseudo_labels.unlabeled_per_label * len(self.preferences), pseudo_labels.max_unlabeled)
        pairs = sample_segment_pairs(
            self.real_buffer, n, self.segment_length, self.max_query_episodes, self.preference_rng, render_states=False
        )
        return None if pairs is None else pairs.inputs

    def consistency_transitions(self, limit: int | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """
        (s, a, s') of the real transitions stored, for REED's consistency pre-training (``dynamics_consistency``):
        every one, oldest first, or a random choice of ``limit`` of them, drawn before any is copied.
        """
        buffer = self.real_buffer
        rows = chronological_rows(buffer)
        n = len(rows) * buffer.n_envs
        chosen = np.arange(n) if limit is None or n <= limit else self.preference_rng.choice(n, limit, replace=False)
        row, env = rows[chosen // buffer.n_envs], chosen % buffer.n_envs
        return tuple(column[row, env] for column in (buffer.observations, buffer.actions, buffer.next_observations))  # type: ignore[return-value]

    def learn_reward(self) -> None:
        """
        Train the reward ensemble on every preference so far (Eqs. 1–2), then relabel the buffer with r̂; with
        ``dynamics_consistency``, its encoder is first trained on the stored transitions (REED).
        """
        consistency_model = getattr(self, "consistency_model", None)  # models saved by 0.1.0 have none
        if consistency_model is not None:
            transitions = self.consistency_transitions(consistency_model.settings.max_transitions)
            loss = consistency_model.train_epochs(*transitions, self.preference_rng)
            self.logger.record("reward_model/consistency_loss", loss)
        pseudo_labels = self.option("pseudo_labels")
        loss, accuracy, epochs = self.reward_model.train_epochs(
            self.preferences,
            self.reward_epochs,
            self.reward_batch_size,
            # no early stop: no training accuracy exceeds 1
            target_accuracy=1.0 if self.reward_early_stop is None else self.reward_early_stop,
            rng=self.preference_rng,
            temporal_crop=self.temporal_crop,
            robust_labels=getattr(self, "label_selection", None),  # models saved by 0.1.0 have none
            unlabeled=None if pseudo_labels is None else self.unlabeled_pairs(pseudo_labels),
            pseudo_labels=pseudo_labels,
        )
        self.relabel()
        correlation = self.reward_correlation()
        self.logger.record("reward_model/loss", loss)
        self.logger.record("reward_model/accuracy", accuracy)
        self.logger.record("reward_model/epochs", epochs)
        selection = getattr(self, "label_selection", None)
        if selection is not None:
            self.logger.record("reward_model/trusted_labels", selection.trusted)
            self.logger.record("reward_model/flipped_labels", selection.flipped)
        self.logger.record("reward_model/true_reward_corr", correlation)
        if self.verbose > 0:
            print(
                f"feedback session {self.feedback_sessions} at step {self.num_timesteps}: "
                f"{self.feedback_labeled}/{self.feedback_asked} labeled, reward-model accuracy {accuracy:.3f}, "
                f"corr(r_hat, r_true) {correlation:.3f}"
            )

    def end_pretraining(self) -> None:
        """
        After the first feedback session: the critic learns from r̂ from now on (this step's update included, as
        B-Pref's update_after_reset); it is reset and trained ``critic_reset_updates`` steps on r̂, as PEBBLE does
        (with ``gradient_steps=0``, where ``learn()`` makes no gradient step at all, it is only reset).
        """
        self.update_reward_source()
        self.reset_critic()
        if self.gradient_steps != 0 and self.critic_reset_updates > 0:
            self.train(gradient_steps=self.critic_reset_updates, batch_size=self.batch_size)
            self.policy.set_training_mode(False)  # back to rollout mode

    def journal_history(self) -> list[JournalEntry]:
        """Every entry of the preference journal (read once, then kept in step with what this model appends)."""
        if self.preference_journal is None:
            return []
        if self._journal_cache is None or self._journal_cache[0] != self.preference_journal:
            entries = PreferenceJournal(self.preference_journal).read()
            expected = (2, self.segment_length, self.preferences.inputs.shape[-1])
            for entry in entries:
                if entry.inputs.shape != expected:
                    raise ValueError(
                        f"preference_journal {self.preference_journal} holds pairs of shape {entry.inputs.shape}, "
                        f"this model's are {expected} (segment_length, obs_dim + action_dim): not this run's journal"
                    )
            if len(entries) < self.journal_entries:
                raise ValueError(
                    f"preference_journal {self.preference_journal} holds {len(entries)} answers, but this model "
                    f"already includes {self.journal_entries}: not this run's journal"
                )
            self._journal_cache = (self.preference_journal, entries)
        return self._journal_cache[1]

    def journaled_answers(self, session: int) -> list[JournalEntry]:
        """The journal's answers of feedback session ``session`` that this model does not have yet."""
        answers = []
        for entry in self.journal_history()[self.journal_entries :]:
            if entry.session != session:
                break
            answers.append(entry)
        return answers

    def record_answers(self, entries: list[JournalEntry]) -> None:
        """
        Append new answers to the preference journal (flushed to disk before returning). The feedback session calls
        it with the teacher's answers; a teacher that hears them one at a time (a person) calls it for each.
        """
        if self.preference_journal is None or not entries:
            return
        PreferenceJournal(self.preference_journal).append(entries)
        self.journal_history().extend(entries)

    def retract_answer(self, session: int, entry_id: str | None = None, annotator: str | None = None) -> None:
        """
        Record in the journal that an answer of ``session`` was taken back (a person's undo): the latest answer to
        query ``entry_id`` by ``annotator`` where they are given, else the session's last answer.
        """
        if self.preference_journal is None:
            return
        history = self.journal_history()
        undone = undone_index(history, session, entry_id, annotator)
        if undone is None or undone < self.journal_entries:  # an undo line that undoes nothing would break the journal
            raise ValueError(f"no answer of feedback session {session} to take back (query {entry_id}, annotator {annotator})")
        PreferenceJournal(self.preference_journal).append_undo(session, entry_id, annotator)
        del history[undone]

    def _log_teacher_records(self) -> None:
        """What the teacher asked to log (``FeedbackContext.log``), into the model's logger."""
        while self._teacher_records:
            key, value = self._teacher_records.popleft()
            self.logger.record(key, value)

    def save(self, path, exclude: Iterable[str] | None = None, include: Iterable[str] | None = None) -> None:
        """SB3's ``save``, written to a temporary file renamed over ``path`` once complete."""
        if not isinstance(path, (str, os.PathLike)):
            return super().save(path, exclude, include)
        with atomic_write_path(path, suffix="zip") as temporary:
            super().save(temporary, exclude, include)

    def save_replay_buffer(self, path) -> None:
        """SB3's ``save_replay_buffer``, written to a temporary file renamed over ``path`` once complete."""
        if not isinstance(path, (str, os.PathLike)):
            return super().save_replay_buffer(path)
        with atomic_write_path(path, suffix="pkl") as temporary:
            super().save_replay_buffer(temporary)

    def relabel(self) -> None:
        """Every stored reward becomes r̂ of the current reward model (Algorithm 1, line 20)."""
        self._attach_reward_model()
        self.real_buffer.relabel(self.reward_model.predict)

    def reward_correlation(self, n_samples: int = 10_000) -> float:
        """Pearson correlation of r̂ with the true reward on stored transitions: the reward model's health."""
        obs, actions, true_rewards = self.real_buffer.transition_sample(n_samples, self.preference_rng)
        predicted = self.reward_model.predict(obs, actions)
        if np.std(predicted) == 0 or np.std(true_rewards) == 0:
            return float("nan")
        return float(np.corrcoef(predicted, true_rewards)[0, 1])

    def reset_critic(self) -> None:
        """
        PEBBLE's reset after pre-training (B-Pref re-creates the critic): fresh Q-networks and, unless it is the
        actor's (``share_features_extractor=True``), a fresh features extractor; the target copied from them;
        fresh Adam state. The actor and the entropy coefficient keep what pre-training taught them.
        """
        shared = self.critic.features_extractor if self.critic.share_features_extractor else None
        for module in self.critic.modules():
            reset_parameters = getattr(module, "reset_parameters", None)
            if callable(reset_parameters) and not _belongs_to(module, shared):
                reset_parameters()
        self.critic_target.load_state_dict(self.critic.state_dict())
        self.critic.optimizer.state.clear()

    def warn_short_episodes(self) -> None:
        """
        Called when no segment fits in the stored episodes: warn once if the finished ones are all shorter than
        ``segment_length`` (early-terminating envs, e.g. Hopper's falls). Not an error: longer episodes may come, and
        the session is tried again a segment later; an env whose step limit is shorter than a segment is refused
        when it is attached.
        """
        if self._warned_short_episodes:
            return
        buffer = self.real_buffer
        rows = chronological_rows(buffer)
        lengths = []
        for env_idx in range(buffer.n_envs):
            ends = np.flatnonzero(buffer.dones[rows, env_idx] > 0)
            lengths.extend(np.diff(np.concatenate([[-1], ends])).tolist())
        if lengths and max(lengths) < self.segment_length:
            self._warned_short_episodes = True
            warnings.warn(
                f"segment_length={self.segment_length} is longer than every episode so far (longest: {max(lengths)} "
                f"steps, at step {self.num_timesteps}): the feedback session waits until an episode holds a segment "
                "and is tried again every segment_length steps. If episodes end early for long (e.g. falls), choose a "
                "smaller segment_length.",
                stacklevel=2,
            )

    def load_replay_buffer(self, path, truncate_last_traj: bool = True) -> None:
        super().load_replay_buffer(path, truncate_last_traj)
        if not isinstance(self.replay_buffer, self.buffer_class):
            raise ValueError(f"{path} holds a {type(self.replay_buffer).__name__}, not a {self.buffer_class.__name__}")
        self._attach_reward_model()
        self._attach_teacher()

    def _excluded_save_params(self) -> list[str]:
        excluded = [*super()._excluded_save_params(), "reward_model", "consistency_model", "_journal_cache"]
        excluded += ["_pending_feedback", "_teacher_records"]  # a session in progress: the journal keeps it
        if self._named_teacher is not None and not isinstance(self._named_teacher[1], ScriptedTeacher):
            # made again from its name when loaded (a person's page and port, a client): only B-Pref's scripted
            # teachers are saved, with their random state
            excluded.append("_named_teacher")
        return excluded

    def _get_torch_save_params(self) -> tuple[list[str], list[str]]:
        state_dicts, variables = super()._get_torch_save_params()
        state_dicts = [*state_dicts, "reward_model", "reward_model.optimizer"]
        if getattr(self, "consistency_model", None) is not None:
            state_dicts += ["consistency_model", "consistency_model.optimizer"]
        return state_dicts, variables

    def learn(
        self: SelfPEBBLE,
        total_timesteps: int,
        callback: MaybeCallback = None,
        log_interval: int = 4,
        tb_log_name: str | None = None,
        reset_num_timesteps: bool = True,
        progress_bar: bool = False,
    ) -> SelfPEBBLE:
        return super().learn(
            total_timesteps=total_timesteps,
            callback=callback,
            log_interval=log_interval,
            tb_log_name=tb_log_name or type(self).__name__,  # "PEBBLE" or "PRIDE"
            reset_num_timesteps=reset_num_timesteps,
            progress_bar=progress_bar,
        )
