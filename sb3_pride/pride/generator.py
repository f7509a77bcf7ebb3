"""
The transition generator PRIDE owns (Feng et al., 2025, §3.4 and Algorithm 1, lines 22–30): a diffusion model of the
agent's transitions (``ElucidatedDiffusion``, as SynthER), how transitions are laid out for it, how new ones are
drawn, which of them are kept, and how faithful they are. It works on plain arrays, so it can be built, fitted and
judged on its own:

    generator = TransitionGenerator(obs_dim, action_dim, train_steps=2000)
    generator.build(model_terminals=False)
    report = generator.update(generator.transition_vectors(obs, actions, next_obs), n_samples=10_000)
    obs, actions, next_obs = generator.split(report.vectors)
"""

import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch as th

from sb3_pride.pride.diffusion import FitInfo, ElucidatedDiffusion
from sb3_pride.pride.fidelity import DynamicsEnsemble, Fidelity, check_anchors, measure_fidelity, split_transitions
from sb3_pride.common.utils import check_choice, check_positive_ints, check_real

#: how synthetic transitions are generated (``generation``)
GENERATIONS = ("unconditional", "near_real")
#: what judges which synthetic transitions to keep (``filter``)
FILTERS = ("dynamics", "reward")
#: arguments of ``ElucidatedDiffusion`` that the generator sets itself (its own parameters, or its data layout)
_OWN_DIFFUSION_ARGUMENTS = ("width", "n_blocks", "train_steps", "sample_steps", "warm_start", "normalization")
_SET_BY_THE_GENERATOR = ("dim", "skip_normalization", "seed", "device")

#: scores transitions (s, a): higher is less trusted (e.g. the reward ensemble's disagreement)
DoubtFn = Callable[[np.ndarray, np.ndarray], np.ndarray]


def add_states_to_next_states(vectors: np.ndarray, obs_dim: int, action_dim: int, sign: float) -> np.ndarray:
    """
    A copy of transition vectors [s, a, s', ...] with s' + sign·s in place of s': sign −1 gives [s, a, s' − s],
    +1 undoes it.
    """
    changed = vectors.copy()
    changed[:, obs_dim + action_dim : 2 * obs_dim + action_dim] += sign * changed[:, :obs_dim]
    return changed


@dataclass
class GenerationReport:
    """
    What one ``TransitionGenerator.update`` did.

    :param vectors: the transitions kept, [s, a, s'(, terminal)]
    :param fit: the diffusion fit (loss, steps, seconds)
    :param drawn: transitions generated before sanitizing and filtering
    :param dropped: generated transitions dropped as non-finite
    :param generate_seconds: time spent generating
    :param fidelity_seconds: time spent judging and filtering
    :param fidelity: how faithful the generated transitions are (None without ``fidelity_check``)
    :param kept_dynamics_error_ratio: the dynamics error ratio of the kept transitions alone, when the filter dropped
        some (judged by the ensemble already fitted: optimistic under the dynamics filter, which chose them by it)
    :param anchors: for ``generation="near_real"``, the row of the (windowed) real data each generated transition was
        generated near, before filtering (the anchors of ``fidelity``)
    """

    vectors: np.ndarray
    fit: FitInfo
    drawn: int
    dropped: int
    generate_seconds: float
    fidelity_seconds: float
    fidelity: Fidelity | None = None
    kept_dynamics_error_ratio: float | None = None
    anchors: np.ndarray | None = None


class TransitionGenerator:
    """
    PRIDE's generator of synthetic transitions: an EDM diffusion model (SynthER's, Lu et al., 2023) fitted on real
    transition vectors [s, a, s'] (plus a terminal flag for envs that terminate), sampled, cleaned, filtered and
    judged. ``update`` does all of it once; the steps are public methods too.

    The paper's generator is ``model_state_change=False, generation="unconditional", warm_start=False, window=None,
    keep_quantile=1.0`` at SynthER's sizes (``sb3_pride.pride.PAPER_RECIPE``). The defaults are PRIDE's own: the
    diffusion models [s, a, s' − s], generates near real transitions (SDEdit), continues its last fit, learns from the
    most recent transitions and keeps the half that a one-step dynamics ensemble judges most consistent.

    :param obs_dim: state dimension
    :param action_dim: action dimension (actions are clipped to [-1, 1], SB3's rescaled action space)
    :param width: width of the denoiser's residual blocks (SynthER: 1024)
    :param n_blocks: residual blocks of the denoiser (SynthER: 6)
    :param train_steps: diffusion gradient steps per fit (SynthER: 100k)
    :param sample_steps: Heun sampler steps (SynthER: 128)
    :param warm_start: start each fit from the previous model (SynthER starts from scratch)
    :param normalization: "per_dimension" (z-scores, as SynthER) or "whiten" (ZCA whitening, for observations whose
        dimensions are strongly correlated, e.g. Meta-World's, which hold the previous frame)
    :param model_state_change: model [s, a, s' − s] instead of the paper's [s, a, s'], so that the loss weighs
        next-state errors in units of a typical step rather than of the state's whole range
    :param generation: "unconditional" (the paper, SynthER: from pure noise) or "near_real": each sample starts from
        a random real transition noised to ``anchor_noise`` and denoised from there (SDEdit, Meng et al., 2022)
    :param anchor_noise: σ (the diffusion's normalized units) to which real transitions are noised for
        ``generation="near_real"``; small stays close to the data, large forgets it
    :param window: fit (and anchor) on the most recent this-many real transitions only (None: all, as the paper)
    :param keep_quantile: draw ``n / keep_quantile`` transitions and keep the ``n`` the ``filter`` trusts most
        (1.0: keep all, as the paper)
    :param filter: "dynamics" (the error of s' under the one-step dynamics ensemble) or "reward" (a doubt score given
        to ``update``, e.g. the reward ensemble's disagreement on r̂(s, a))
    :param fidelity_check: at every update, fit a one-step dynamics ensemble on the real transitions and report how
        consistent the synthetic next states are and how novel the samples are (``Fidelity``); needed by
        ``filter="dynamics"``
    :param diffusion_kwargs: any other ``ElucidatedDiffusion`` argument (``dim_t``, ``batch_size``,
        ``learning_rate``, ``sample_batch_size``, ``ema_decay``, ...)
    :param dynamics_kwargs: ``DynamicsEnsemble`` arguments (``n_members``, ``width``, ``train_steps``, ...)
    :param seed: seed of the generator's own random generators
    :param device: torch device
    """

    diffusion: ElucidatedDiffusion | None
    dynamics: DynamicsEnsemble | None

    def __init__(
        self,
        obs_dim: int,
        action_dim: int,
        width: int = 256,
        n_blocks: int = 3,
        train_steps: int = 2000,
        sample_steps: int = 8,
        warm_start: bool = True,
        normalization: str = "per_dimension",
        model_state_change: bool = True,
        generation: str = "near_real",
        anchor_noise: float = 0.25,
        window: int | None = 20_000,
        keep_quantile: float = 0.5,
        filter: str = "dynamics",
        fidelity_check: bool = True,
        diffusion_kwargs: dict[str, Any] | None = None,
        dynamics_kwargs: dict[str, Any] | None = None,
        seed: int | None = None,
        device: th.device | str = "auto",
    ):
        check_positive_ints(obs_dim=obs_dim, action_dim=action_dim)
        diffusion_kwargs = dict(diffusion_kwargs or {})
        for name in diffusion_kwargs:
            if name in _OWN_DIFFUSION_ARGUMENTS:
                raise ValueError(f"set the generator's {name}, not diffusion_kwargs[{name!r}]")
            if name in _SET_BY_THE_GENERATOR:
                raise ValueError(f"diffusion_kwargs[{name!r}] is set by the generator itself")
        diffusion_options = dict(
            width=width,
            n_blocks=n_blocks,
            train_steps=train_steps,
            sample_steps=sample_steps,
            warm_start=warm_start,
            normalization=normalization,
            **diffusion_kwargs,
        )
        check_choice("generation", generation, GENERATIONS)
        sigma_min, sigma_max = diffusion_kwargs.get("sigma_min", 0.002), diffusion_kwargs.get("sigma_max", 80.0)
        check_real(
            "anchor_noise",
            anchor_noise,
            lambda sigma: sigma_min < sigma <= sigma_max,
            f"in (sigma_min={sigma_min}, sigma_max={sigma_max}]",
        )
        if window is not None:
            check_positive_ints(window=window)
        check_real("keep_quantile", keep_quantile, lambda q: 0.0 < q <= 1.0, "in (0, 1]")
        check_choice("filter", filter, FILTERS)
        if keep_quantile < 1.0 and filter == "dynamics" and not fidelity_check:
            raise ValueError(
                f"filter='dynamics' with keep_quantile={keep_quantile} needs fidelity_check=True (the dynamics ensemble "
                "it uses); set keep_quantile=1.0 to keep every sample, or filter='reward'"
            )
        # fail now, not at the first fit: build both once, tiny, with every argument they will get
        try:
            ElucidatedDiffusion(1, **{**diffusion_options, "device": "cpu"})
        except (TypeError, ValueError) as error:
            raise ValueError(
                f"the generator's diffusion settings are not valid ElucidatedDiffusion arguments: {error}"
            ) from None
        self.dynamics_options = {"train_steps": 500, **(dynamics_kwargs or {})}
        try:
            DynamicsEnsemble(1, 1, **{**self.dynamics_options, "device": "cpu"})
        except (TypeError, ValueError) as error:
            raise ValueError(f"dynamics_kwargs must be valid DynamicsEnsemble arguments: {error}") from None
        self.obs_dim, self.action_dim = obs_dim, action_dim
        self.diffusion_options = diffusion_options
        self.model_state_change = model_state_change
        self.generation = generation
        self.anchor_noise = anchor_noise
        self.window = window
        self.keep_quantile = keep_quantile
        self.filter = filter
        self.fidelity_check = fidelity_check
        self.seed = seed
        self.device = device
        #: whether a transition holds a terminal flag; None until ``build``
        self.model_terminals: bool | None = None
        self.diffusion = None
        self.dynamics = None

    def build(self, model_terminals: bool) -> None:
        """
        Make the diffusion model, once it is known whether transitions hold a terminal flag (a last dimension of 0/1,
        left unnormalized and rounded at generation).
        """
        self.model_terminals = bool(model_terminals)
        dim = 2 * self.obs_dim + self.action_dim + int(self.model_terminals)
        skip = (dim - 1,) if self.model_terminals else ()
        self.diffusion = ElucidatedDiffusion(
            dim, **{**self.diffusion_options, "skip_normalization": skip, "seed": self.seed, "device": self.device}
        )

    # the data: flat transition vectors [s, a, s'(, terminal)] ---------------------------------------------------
    def transition_vectors(
        self, obs: np.ndarray, actions: np.ndarray, next_obs: np.ndarray, terminals: np.ndarray | None = None
    ) -> np.ndarray:
        """Transitions as the vectors the generator works on: [s, a, s'] (and the terminal flag, if modelled)."""
        columns = [obs, actions, next_obs]
        if self.model_terminals:
            if terminals is None:
                raise ValueError("this generator models terminal flags: pass terminals")
            columns.append(np.asarray(terminals)[..., None])
        vectors = np.concatenate(columns, axis=-1, dtype=np.float32)
        return vectors.reshape(-1, vectors.shape[-1])

    def split(self, vectors: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(s, a, s') of transition vectors."""
        return split_transitions(vectors, self.obs_dim, self.action_dim)

    def terminals(self, vectors: np.ndarray) -> np.ndarray:
        """The terminal flags of transition vectors (zeros where none are modelled)."""
        return vectors[:, -1] if self.model_terminals else np.zeros(len(vectors), dtype=np.float32)

    def encode(self, vectors: np.ndarray) -> np.ndarray:
        """Transition vectors as the diffusion models them: [s, a, s' − s] with ``model_state_change``."""
        if not self.model_state_change:
            return vectors
        return add_states_to_next_states(vectors, self.obs_dim, self.action_dim, -1.0)

    def decode(self, vectors: np.ndarray) -> np.ndarray:
        """The inverse of ``encode``: back to [s, a, s']."""
        if not self.model_state_change:
            return vectors
        return add_states_to_next_states(vectors, self.obs_dim, self.action_dim, 1.0)

    # the steps of an update -------------------------------------------------------------------------------------
    def _diffusion(self) -> ElucidatedDiffusion:
        if self.diffusion is None:
            raise RuntimeError("the generator is not built yet: call build(model_terminals) first")
        return self.diffusion

    def fit(self, real: np.ndarray) -> FitInfo:
        """Fit the diffusion model on real transition vectors (encoded first)."""
        return self._diffusion().fit(self.encode(real))

    def generate(self, real: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray | None]:
        """
        ``n`` synthetic transition vectors by ``generation`` from the fitted diffusion.

        :param real: the real transition vectors the diffusion was fitted on
        :param n: how many to generate
        :return: the vectors, and for ``generation="near_real"`` the row of ``real`` each was generated from (else None)
        """
        diffusion = self._diffusion()
        if self.generation == "near_real":
            anchors = diffusion.rng.integers(0, len(real), size=n)
            return self.decode(diffusion.sample_near(self.encode(real[anchors]), self.anchor_noise)), anchors
        return self.decode(diffusion.sample(n)), None

    def sanitize(self, generated: np.ndarray, anchors: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray | None]:
        """
        Non-finite vectors dropped, actions clipped to [-1, 1], terminal flags rounded at 0.5.

        :param generated: transition vectors from ``generate``
        :param anchors: the row of the real data each vector was generated near (``generate``'s second output), or None
        :return: the vectors kept, and the anchors of those (None if ``anchors`` is None)
        """
        if anchors is not None:
            anchors = check_anchors(anchors, len(generated))
        finite = np.all(np.isfinite(generated), axis=1)
        kept = generated[finite].copy()
        actions = slice(self.obs_dim, self.obs_dim + self.action_dim)
        np.clip(kept[:, actions], -1.0, 1.0, out=kept[:, actions])
        if self.model_terminals:
            kept[:, -1] = (kept[:, -1] > 0.5).astype(np.float32)
        return kept, None if anchors is None else anchors[finite]

    def measure_fidelity(self, real: np.ndarray, synthetic: np.ndarray, anchors: np.ndarray | None = None) -> Fidelity:
        """
        Refit the dynamics ensemble on ``real`` and judge ``synthetic`` with it (``measure_fidelity``).

        :param real: real transition vectors
        :param synthetic: synthetic transition vectors
        :param anchors: the row of ``real`` each synthetic vector was generated near, if any
        """
        if self.dynamics is None:
            options = dict(seed=self.seed, device=self.device)
            self.dynamics = DynamicsEnsemble(self.obs_dim, self.action_dim, **{**options, **self.dynamics_options})
        return measure_fidelity(self.dynamics, real, synthetic, self.obs_dim, self.action_dim, anchors=anchors)

    def select(self, vectors: np.ndarray, n_keep: int, reward_doubt: DoubtFn | None = None) -> np.ndarray:
        """
        The ``n_keep`` vectors the ``filter`` trusts most: lowest dynamics error (under the ensemble of the last
        ``measure_fidelity``), or lowest ``reward_doubt(s, a)``.
        """
        if len(vectors) <= n_keep:
            return vectors
        obs, actions, next_obs = self.split(vectors)
        if self.filter == "dynamics":
            if self.dynamics is None:
                raise RuntimeError("filter='dynamics' needs a fitted dynamics ensemble: call measure_fidelity first")
            doubt = self.dynamics.errors(obs, actions, next_obs)
        else:
            if reward_doubt is None:
                raise ValueError("filter='reward' needs reward_doubt, a function of (s, a) such as r̂'s disagreement")
            doubt = reward_doubt(obs, actions)
        return vectors[np.argsort(doubt, kind="stable")[:n_keep]]

    def update(self, real: np.ndarray, n_samples: int, reward_doubt: DoubtFn | None = None) -> GenerationReport:
        """
        One retrain-and-generate (Algorithm 1, lines 22–30): fit on the last ``window`` of ``real``, draw
        ``n_samples / keep_quantile`` transitions, drop non-finite ones, judge them (``fidelity_check``) and keep the
        ``n_samples`` the filter trusts most.

        :param real: real transition vectors, oldest first (``transition_vectors``)
        :param n_samples: transitions to keep
        :param reward_doubt: for ``filter="reward"``, a score of (s, a) where higher is less trusted
        """
        check_positive_ints(n_samples=n_samples)
        if self.window is not None:
            real = real[-self.window :]
        fit = self.fit(real)
        start = time.perf_counter()
        n_draw = int(np.ceil(n_samples / self.keep_quantile))
        generation = self.generate(real, n_draw)
        generated, anchors = self.sanitize(*generation)
        dropped = len(generation[0]) - len(generated)
        generate_seconds = time.perf_counter() - start
        start = time.perf_counter()
        fidelity = self.measure_fidelity(real, generated, anchors) if self.fidelity_check else None
        kept = self.select(generated, n_samples, reward_doubt)
        fidelity_seconds = time.perf_counter() - start
        kept_ratio = None
        if fidelity is not None and len(kept) < len(generated) and self.dynamics is not None:
            kept_error = self.dynamics.errors(*self.split(kept)).mean()
            kept_ratio = float(kept_error / max(fidelity.real_dynamics_error, 1e-12))
        return GenerationReport(
            vectors=kept,
            fit=fit,
            drawn=n_draw,
            dropped=dropped,
            generate_seconds=generate_seconds,
            fidelity_seconds=fidelity_seconds,
            fidelity=fidelity,
            kept_dynamics_error_ratio=kept_ratio,
            anchors=anchors,
        )
