from typing import Any, ClassVar

import numpy as np
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.type_aliases import GymEnv
from stable_baselines3.sac.policies import SACPolicy

from sb3_pride.common.buffers import DualReplayBuffer, PreferenceReplayBuffer
from sb3_pride.pride.callbacks import DiffusionCallback
from sb3_pride.common.diffusion import NORMALIZATIONS, ElucidatedDiffusion
from sb3_pride.common.fidelity import DynamicsEnsemble, Fidelity, check_anchors, measure_fidelity, split_transitions
from sb3_pride.common.queries import chronological_rows
from sb3_pride.common.utils import check_choice, check_non_negative_ints, check_positive_ints, check_real
from sb3_pride.pebble.pebble import PEBBLE

#: how synthetic transitions are generated (``generation``)
GENERATIONS = ("unconditional", "near_real")
#: what judges which synthetic transitions to keep (``synthetic_filter``)
SYNTHETIC_FILTERS = ("dynamics", "reward")


def add_states_to_next_states(vectors: np.ndarray, obs_dim: int, action_dim: int, sign: float) -> np.ndarray:
    """
    A copy of transition vectors [s, a, s', ...] with s' + sign·s in place of s': sign −1 gives [s, a, s' − s],
    +1 undoes it.
    """
    changed = vectors.copy()
    changed[:, obs_dim + action_dim : 2 * obs_dim + action_dim] += sign * changed[:, :obs_dim]
    return changed


class PRIDE(PEBBLE):
    """
    PRIDE: Preference-based Reinforcement learning using dIffusion moDEL (Feng, Tenytska, Wang & Peng, 2025).

    PEBBLE plus a diffusion model (Algorithm 1, lines 22–37): every ``diffusion_interval`` (R) env steps, once the
    first reward model exists, an EDM diffusion model (as SynthER) is fitted on the real transitions (s, a, s')
    and generates ``synthetic_samples`` new ones into a separate synthetic buffer; every SAC minibatch is then
    ``round(synthetic_ratio · batch_size)`` synthetic transitions and the rest real ones (or, with
    ``synthetic_on_top``, ``batch_size`` real ones and synthetic ones on top, in the same share as u ramps up).

    Synthetic rewards are r̂(s, a) of the current reward model: set at generation and relabeled together with the
    real buffer after every reward update. (The paper relabels the real buffer only, which leaves synthetic
    rewards stale until the next generation.) Terminal flags are modelled only if the real buffer holds a true
    termination by the first retrain (never on DMC or Meta-World, whose episodes only time out).

    Every other parameter is PEBBLE's (and SAC's), with the same defaults. PRIDE's own defaults are the best
    configuration measured (``benchmarks/results/README.md``; ``hyperparams/cpu/pride.yml``'s walker-walk entry):
    the paper's generator (an unconditional model of [s, a, s'] at CPU sizes: 256 or 512 wide, 2 or 3 blocks,
    1000 to 5000 steps, 32 to 8 sampling steps) makes next states 2.4–9.8× as inconsistent with the dynamics as real
    held-out ones on walker-walk;
    modelling s' − s and generating near real transitions (σ = 0.25) brings that to 1.6× standalone, at a third of
    the sampling cost, and with 4000 warm-started steps per retrain it reads 1.41× at the last retrain of a CPU-tier
    run (1.54× with 2000 steps, 5 seeds each; 4000 costs ~7% more wall time). Every sample then has a real neighbour
    about as close as a fresh real transition has. The mixing defaults (synthetic data from step 10k, u ramped over
    5k steps, a 20k-transition window, the better-judged half of the samples kept) are on because with the paper's
    mixing the same generator ends below PEBBLE on walker-walk (275.3 against 349.4, P = 0.00, 3 and 5 seeds) while
    with them it ties or leads it; no one of them is needed once the other two are on. Their step counts were
    measured on 50k-step runs: scale them with the run. The synthetic rows take the place of real ones in each
    ``batch_size`` minibatch, as in the paper: on walker-walk at 400 queries PRIDE is then ahead of PEBBLE on the mean
    but not established (378.5 ± 112.9 against 346.3 ± 59.7, P = 0.65 [0.44, 0.85], 15 seeds each), at 1.34× its
    wall time. Putting the synthetic rows on top of ``batch_size`` real ones (``synthetic_on_top=True``) returned the
    same (406.3 ± 70.2, P = 0.51 [0.28, 0.72] against the rows in place, 15 seeds each) with a smaller spread, at
    1.58×. With 200 queries no variant matches PEBBLE at 400.
    Paper-scale diffusion settings (SynthER's: width 1024, 6 blocks, 100k training steps, 128 sampling steps; 200k
    samples per generation here) are in ``hyperparams/pride.yml`` with the paper's recipe.

    :param synthetic_ratio: u, the synthetic share of each SAC minibatch, in [0, 1] (paper: 0.5). With 0 the
        diffusion model is never trained and PRIDE trains exactly as PEBBLE
    :param synthetic_on_top: add the synthetic rows to ``batch_size`` real ones instead of putting them in place of
        some (default and paper: False, a minibatch of B rows of which round(u · B) synthetic, so that each update
        sees fewer real rows than PEBBLE's at the same ``batch_size``). Each minibatch then holds M = round(B / (1 − u))
        rows of which round(u · M) synthetic, u as ramped so far: B real rows, as many as PEBBLE's, and about
        u · B / (1 − u) synthetic ones on top (B at u = 0.5, B / 3 at u = 0.25). Until the first generation it trains
        exactly as PEBBLE (M = B). Needs u < 1; the cost of an update grows with M (10 B at u = 0.9). On walker-walk it
        returned the same as the rows in place over 15 seeds each, with a smaller spread, at 1.58× PEBBLE's wall time
        against 1.34×. (Session 16's variant, M = B / (1 − u) from the start with real rows where there are no
        synthetic ones yet, is the paper's mixing at ``batch_size`` B / (1 − u).)
    :param diffusion_interval: R, env steps between diffusion retrain-and-generate (paper: 10k)
    :param synthetic_samples: transitions generated (and kept) per retrain; they replace the synthetic buffer
    :param synthetic_buffer_size: capacity of the synthetic buffer (default: ``synthetic_samples``)
    :param diffusion_width: width of the denoiser's residual blocks
    :param diffusion_blocks: residual blocks of the denoiser
    :param diffusion_train_steps: gradient steps per retrain (warm-started: each retrain continues the last one).
        4000 rather than 2000 makes walker-walk's synthetic next states more consistent (``dynamics_error_ratio``
        1.41 against 1.54 at the last retrain) for ~7% more wall time
    :param diffusion_sample_steps: Heun sampler steps
    :param diffusion_warm_start: start each retrain from the previous model (SynthER starts from scratch; a warm
        start reaches the same fidelity in fewer steps, which is what makes PRIDE affordable on a CPU)
    :param diffusion_normalization: "per_dimension" (z-scores, as SynthER) or "whiten" (ZCA whitening, for
        observations whose dimensions are strongly correlated, e.g. Meta-World's, which hold the previous frame: a
        velocity is then the small difference of two coordinates, and per-dimension noise wipes it out)
    :param diffusion_kwargs: any other ``ElucidatedDiffusion`` argument (``dim_t``, ``batch_size``,
        ``learning_rate``, ``sample_batch_size``, ``ema_decay``, ...)
    :param model_state_change: the diffusion models [s, a, s' − s] instead of the paper's [s, a, s'], so that its
        loss weighs next-state errors in units of a typical step rather than of the state's whole range
    :param generation: "unconditional" (the paper, SynthER: from pure noise) or "near_real": each sample starts
        from a random real transition noised to ``anchor_noise`` and denoised from there (SDEdit)
    :param anchor_noise: σ (the diffusion's normalized units) to which real transitions are noised for
        ``generation="near_real"``; small stays close to the data, large forgets it
    :param synthetic_start: no synthetic data is generated or mixed before this env step (besides waiting for the
        first reward model, which always holds; paper: 0)
    :param synthetic_ramp: env steps over which u grows linearly from 0 to ``synthetic_ratio`` after the first
        generation (0: at once, as the paper)
    :param diffusion_window: fit the diffusion (and anchor generation) on the most recent this-many real
        transitions only (None: all of B_real, as the paper)
    :param synthetic_keep_quantile: draw ``synthetic_samples / q`` samples and keep the ``q`` share the
        ``synthetic_filter`` trusts most (1.0: keep all, as the paper)
    :param synthetic_filter: "dynamics" (the error of the sample's s' under the one-step dynamics ensemble) or
        "reward" (the reward ensemble's disagreement on r̂(s, a))
    :param fidelity_check: at every retrain, fit a one-step dynamics ensemble on the real transitions and log how
        consistent the synthetic next states are (``diffusion/dynamics_error_ratio``) and how novel the samples are
        (``diffusion/novelty_ratio``); needed by ``synthetic_filter="dynamics"``
    :param dynamics_kwargs: ``DynamicsEnsemble`` arguments (``n_members``, ``width``, ``train_steps``, ...)

    The paper's recipe: ``model_state_change=False, generation="unconditional", diffusion_warm_start=False,
    synthetic_on_top=False, diffusion_interval=10_000, synthetic_start=0, synthetic_ramp=0, diffusion_window=None,
    synthetic_keep_quantile=1.0`` with its diffusion sizes (``hyperparams/pride.yml``).
    """

    buffer_class: ClassVar[type[PreferenceReplayBuffer]] = DualReplayBuffer  # type: ignore[assignment]
    replay_buffer: DualReplayBuffer  # type: ignore[assignment]

    def __init__(
        self,
        policy: str | type[SACPolicy],
        env: GymEnv | str,
        synthetic_ratio: float = 0.5,
        synthetic_on_top: bool = False,
        diffusion_interval: int = 5000,
        synthetic_samples: int = 10_000,
        synthetic_buffer_size: int | None = None,
        diffusion_width: int = 256,
        diffusion_blocks: int = 3,
        diffusion_train_steps: int = 4000,
        diffusion_sample_steps: int = 8,
        diffusion_warm_start: bool = True,
        diffusion_normalization: str = "per_dimension",
        diffusion_kwargs: dict[str, Any] | None = None,
        model_state_change: bool = True,
        generation: str = "near_real",
        anchor_noise: float = 0.25,
        synthetic_start: int = 10_000,
        synthetic_ramp: int = 5000,
        diffusion_window: int | None = 20_000,
        synthetic_keep_quantile: float = 0.5,
        synthetic_filter: str = "dynamics",
        fidelity_check: bool = True,
        dynamics_kwargs: dict[str, Any] | None = None,
        replay_buffer_kwargs: dict[str, Any] | None = None,
        _init_setup_model: bool = True,
        **pebble_kwargs: Any,
    ):
        check_real("synthetic_ratio", synthetic_ratio, lambda u: 0.0 <= u <= 1.0, "in [0, 1]")
        if not isinstance(synthetic_on_top, (bool, np.bool_)):
            raise ValueError(f"synthetic_on_top must be True or False, got {synthetic_on_top!r}")
        if synthetic_on_top and synthetic_ratio == 1.0:
            raise ValueError(
                "synthetic_on_top=True needs synthetic_ratio < 1 (each minibatch holds batch_size / (1 - u) rows, "
                "batch_size of them real), got synthetic_ratio=1.0; for minibatches of synthetic rows only, set "
                "synthetic_on_top=False"
            )
        check_positive_ints(
            diffusion_interval=diffusion_interval,
            synthetic_samples=synthetic_samples,
            diffusion_width=diffusion_width,
            diffusion_blocks=diffusion_blocks,
            diffusion_train_steps=diffusion_train_steps,
            diffusion_sample_steps=diffusion_sample_steps,
        )
        if synthetic_buffer_size is not None:
            check_positive_ints(synthetic_buffer_size=synthetic_buffer_size)
        if diffusion_window is not None:
            check_positive_ints(diffusion_window=diffusion_window)
        check_non_negative_ints(synthetic_start=synthetic_start, synthetic_ramp=synthetic_ramp)
        check_choice("diffusion_normalization", diffusion_normalization, NORMALIZATIONS)
        if "normalization" in (diffusion_kwargs or {}):
            raise ValueError("set diffusion_normalization, not diffusion_kwargs['normalization']")
        check_choice("generation", generation, GENERATIONS)
        sigma_min = (diffusion_kwargs or {}).get("sigma_min", 0.002)
        sigma_max = (diffusion_kwargs or {}).get("sigma_max", 80.0)
        check_real(
            "anchor_noise",
            anchor_noise,
            lambda sigma: sigma_min < sigma <= sigma_max,
            f"in (sigma_min={sigma_min}, sigma_max={sigma_max}]",
        )
        # fail now, not at the first retrain: build both once, tiny, with every argument they will get
        try:
            ElucidatedDiffusion(
                1,
                width=diffusion_width,
                n_blocks=diffusion_blocks,
                train_steps=diffusion_train_steps,
                sample_steps=diffusion_sample_steps,
                **{"device": "cpu", "normalization": diffusion_normalization, **(diffusion_kwargs or {})},
            )
        except (TypeError, ValueError) as error:
            raise ValueError(f"diffusion_kwargs must be valid ElucidatedDiffusion arguments: {error}") from None
        try:
            DynamicsEnsemble(1, 1, **{"device": "cpu", **(dynamics_kwargs or {})})
        except (TypeError, ValueError) as error:
            raise ValueError(f"dynamics_kwargs must be valid DynamicsEnsemble arguments: {error}") from None
        check_real("synthetic_keep_quantile", synthetic_keep_quantile, lambda q: 0.0 < q <= 1.0, "in (0, 1]")
        check_choice("synthetic_filter", synthetic_filter, SYNTHETIC_FILTERS)
        if synthetic_keep_quantile < 1.0 and synthetic_filter == "dynamics" and not fidelity_check:
            raise ValueError(
                f"synthetic_filter='dynamics' with synthetic_keep_quantile={synthetic_keep_quantile} needs "
                "fidelity_check=True (the dynamics ensemble it uses); set synthetic_keep_quantile=1.0 to keep every "
                "sample, or synthetic_filter='reward'"
            )
        replay_buffer_kwargs = dict(replay_buffer_kwargs or {})
        replay_buffer_kwargs.setdefault("synthetic_buffer_size", synthetic_buffer_size or synthetic_samples)
        replay_buffer_kwargs.setdefault("synthetic_ratio", synthetic_ratio)
        super().__init__(policy, env, replay_buffer_kwargs=replay_buffer_kwargs, _init_setup_model=False, **pebble_kwargs)
        if _init_setup_model and self.env is not None:  # PEBBLE skipped it, as it does for load()
            self._check_episode_length(self.env, self.segment_length)
        self.synthetic_ratio = synthetic_ratio
        self.synthetic_on_top = bool(synthetic_on_top)
        self.diffusion_interval = diffusion_interval
        self.synthetic_samples = synthetic_samples
        self.synthetic_buffer_size = synthetic_buffer_size
        self.diffusion_width = diffusion_width
        self.diffusion_blocks = diffusion_blocks
        self.diffusion_train_steps = diffusion_train_steps
        self.diffusion_sample_steps = diffusion_sample_steps
        self.diffusion_warm_start = diffusion_warm_start
        self.diffusion_normalization = diffusion_normalization
        self.diffusion_kwargs = dict(diffusion_kwargs or {})
        self.model_state_change = model_state_change
        self.generation = generation
        self.anchor_noise = anchor_noise
        self.synthetic_start = synthetic_start
        self.synthetic_ramp = synthetic_ramp
        self.diffusion_window = diffusion_window
        self.synthetic_keep_quantile = synthetic_keep_quantile
        self.synthetic_filter = synthetic_filter
        self.fidelity_check = fidelity_check
        self.dynamics_kwargs = dict(dynamics_kwargs or {})
        self.dynamics: DynamicsEnsemble | None = None
        self.first_generation_step: int | None = None
        # learning state, saved with the model; the diffusion model is built at the first retrain, when it is
        # known whether terminal flags are part of a transition
        self.model_terminals: bool | None = None
        self.diffusion: ElucidatedDiffusion | None = None
        self.diffusion_retrains = 0
        # the first retrain comes right after the first reward learning (or at synthetic_start, if later)
        self.next_diffusion_step = max(self.next_feedback_step, synthetic_start)

        if _init_setup_model:
            self._setup_model()

    def _setup_model(self) -> None:
        super()._setup_model()
        if self.model_terminals is not None:  # loading a model that was retrained: rebuild before its weights load
            self._build_diffusion()

    def _shift_schedules(self, steps: int) -> None:
        super()._shift_schedules(steps)
        self.next_diffusion_step = max(0, self.next_diffusion_step + steps)
        if self.first_generation_step is not None:
            self.first_generation_step += steps

    @property
    def real_buffer(self) -> PreferenceReplayBuffer:
        """B_real, the agent's own transitions with their true rewards aside."""
        return self.replay_buffer.real

    def _preference_callbacks(self) -> list[BaseCallback]:
        return [*super()._preference_callbacks(), DiffusionCallback(verbose=self.verbose)]

    def train(self, gradient_steps: int, batch_size: int = 64) -> None:
        # Algorithm 1, lines 34–37: each SAC minibatch of M rows holds round(u·M) synthetic and M − round(u·M) real
        # transitions (DualReplayBuffer.sample); real only until the first generation, then u ramps up over
        # synthetic_ramp steps. M = B (the paper) or, with synthetic_on_top, B / (1 − u) with u as ramped so far
        self.replay_buffer.synthetic_ratio = self.current_synthetic_ratio()
        minibatch_size = self.minibatch_size(batch_size)
        super().train(gradient_steps, minibatch_size)  # PEBBLE's critic diagnostics too see minibatches of M rows
        self.logger.record("train/synthetic_per_batch", self.replay_buffer.n_synthetic(minibatch_size))

    def minibatch_size(self, batch_size: int) -> int:
        """
        Rows M of each SAC minibatch: ``batch_size`` (B, the paper), or with ``synthetic_on_top`` round(B / (1 − u))
        for u as ramped so far: B real rows, as many as PEBBLE's, plus M − B (about u · B / (1 − u)) synthetic ones on
        top; M = B while there is no synthetic data yet.
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

    # the diffusion model's data: flat transition vectors [s, a, s'(, terminal)] -----------------------------
    def _build_diffusion(self) -> None:
        obs_dim, action_dim = self.real_buffer.obs_shape[0], self.real_buffer.action_dim
        dim = 2 * obs_dim + action_dim + int(bool(self.model_terminals))
        options = dict(
            width=self.diffusion_width,
            n_blocks=self.diffusion_blocks,
            train_steps=self.diffusion_train_steps,
            sample_steps=self.diffusion_sample_steps,
            warm_start=self.diffusion_warm_start,
            normalization=self.diffusion_normalization,
            skip_normalization=(dim - 1,) if self.model_terminals else (),
            seed=self.seed,
            device=self.device,
        )
        self.diffusion = ElucidatedDiffusion(dim, **{**options, **self.diffusion_kwargs})

    def transition_vectors(self) -> np.ndarray:
        """
        The real transitions the diffusion learns from, as vectors [s, a, s'] (plus the terminal flag where the env
        terminates): the most recent ``diffusion_window`` of them, or all of B_real.
        """
        buffer = self.real_buffer
        rows = chronological_rows(buffer)
        if self.diffusion_window is not None:  # whole rows first (n_envs transitions each), then exactly the window
            rows = rows[-int(np.ceil(self.diffusion_window / buffer.n_envs)) :]
        terminals = buffer.dones[rows] * (1.0 - buffer.timeouts[rows])
        if self.model_terminals is None:
            self.model_terminals = bool(terminals.any())
            self._build_diffusion()
        columns = [buffer.observations[rows], buffer.actions[rows], buffer.next_observations[rows]]
        if self.model_terminals:
            columns.append(terminals[..., None])
        vectors = np.concatenate(columns, axis=-1, dtype=np.float32)
        vectors = vectors.reshape(-1, vectors.shape[-1])
        return vectors if self.diffusion_window is None else vectors[-self.diffusion_window :]

    def encode(self, vectors: np.ndarray) -> np.ndarray:
        """Transition vectors as the diffusion models them: [s, a, s' − s] with ``model_state_change``."""
        if not self.model_state_change:
            return vectors
        return add_states_to_next_states(vectors, self.real_buffer.obs_shape[0], self.real_buffer.action_dim, -1.0)

    def decode(self, vectors: np.ndarray) -> np.ndarray:
        """The inverse of ``encode``: back to [s, a, s']."""
        if not self.model_state_change:
            return vectors
        return add_states_to_next_states(vectors, self.real_buffer.obs_shape[0], self.real_buffer.action_dim, 1.0)

    def generate(self, real: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray | None]:
        """
        ``n`` synthetic transition vectors [s, a, s'(, terminal)] by ``generation`` from the fitted diffusion.

        :param real: the real transition vectors the diffusion was fitted on (``transition_vectors()``)
        :param n: how many to generate
        :return: the vectors, and for ``generation="near_real"`` the row of ``real`` each was generated from (else None)
        """
        assert self.diffusion is not None
        if self.generation == "near_real":
            anchors = self.diffusion.rng.integers(0, len(real), size=n)
            return self.decode(self.diffusion.sample_near(self.encode(real[anchors]), self.anchor_noise)), anchors
        return self.decode(self.diffusion.sample(n)), None

    def sanitize(self, generated: np.ndarray, anchors: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray | None]:
        """
        Non-finite vectors dropped, actions clipped to the action bounds, terminal flags rounded at 0.5.

        :param generated: transition vectors from ``generate``
        :param anchors: the row of the real data each vector was generated near (``generate``'s second output), or None
        :return: the vectors kept, and the anchors of those (None if ``anchors`` is None)
        """
        if anchors is not None:
            anchors = check_anchors(anchors, len(generated))
        finite = np.all(np.isfinite(generated), axis=1)
        kept = generated[finite].copy()
        obs_dim, action_dim = self.real_buffer.obs_shape[0], self.real_buffer.action_dim
        np.clip(kept[:, obs_dim : obs_dim + action_dim], -1.0, 1.0, out=kept[:, obs_dim : obs_dim + action_dim])
        if self.model_terminals:
            kept[:, -1] = (kept[:, -1] > 0.5).astype(np.float32)
        return kept, None if anchors is None else anchors[finite]

    def filter_synthetic(self, vectors: np.ndarray, n_keep: int) -> np.ndarray:
        """The ``n_keep`` vectors the ``synthetic_filter`` trusts most (lowest dynamics error or reward disagreement)."""
        if len(vectors) <= n_keep:
            return vectors
        obs, actions, next_obs = self.split(vectors)
        if self.synthetic_filter == "dynamics":
            assert self.dynamics is not None
            doubt = self.dynamics.errors(obs, actions, next_obs)
        else:
            doubt = self.reward_model.disagreement(obs, actions)
        return vectors[np.argsort(doubt, kind="stable")[:n_keep]]

    def split(self, vectors: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(s, a, s') of transition vectors."""
        return split_transitions(vectors, self.real_buffer.obs_shape[0], self.real_buffer.action_dim)

    def store_synthetic(self, vectors: np.ndarray) -> None:
        """Replace B_syn with sanitized vectors, rewarded by r̂(s, a)."""
        obs, actions, next_obs = self.split(vectors)
        dones = vectors[:, -1] if self.model_terminals else np.zeros(len(vectors), dtype=np.float32)
        self.replay_buffer.synthetic.replace(obs, actions, next_obs, dones, self.reward_model.predict(obs, actions))

    def fidelity(self, real: np.ndarray, synthetic: np.ndarray, anchors: np.ndarray | None = None) -> Fidelity:
        """
        Refit the dynamics ensemble on ``real`` and judge ``synthetic`` with it (``measure_fidelity``).

        :param real: real transition vectors
        :param synthetic: synthetic transition vectors
        :param anchors: the row of ``real`` each synthetic vector was generated near, if any
        """
        obs_dim, action_dim = self.real_buffer.obs_shape[0], self.real_buffer.action_dim
        if self.dynamics is None:
            options = dict(train_steps=500, seed=self.seed, device=self.device)
            self.dynamics = DynamicsEnsemble(obs_dim, action_dim, **{**options, **self.dynamics_kwargs})
        return measure_fidelity(self.dynamics, real, synthetic, obs_dim, action_dim, anchors=anchors)

    def _get_torch_save_params(self) -> tuple[list[str], list[str]]:
        state_dicts, variables = super()._get_torch_save_params()
        return ([*state_dicts, "diffusion"] if self.diffusion is not None else state_dicts), variables

    def _excluded_save_params(self) -> list[str]:
        # the dynamics ensemble is a yardstick refit at every retrain: not worth saving
        return [*super()._excluded_save_params(), "diffusion", "dynamics"]
