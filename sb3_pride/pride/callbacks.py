"""PRIDE's diffusion phase, beside PEBBLE's callbacks; ``PRIDE.learn()`` attaches it itself."""

import time
from typing import TYPE_CHECKING

import numpy as np
from stable_baselines3.common.callbacks import BaseCallback

if TYPE_CHECKING:
    from sb3_pride.pride.pride import PRIDE


class DiffusionCallback(BaseCallback):
    """
    PRIDE's diffusion phase (Algorithm 1, lines 22–30): every ``diffusion_interval`` steps, once a reward model
    exists (so synthetic data never carries an untrained reward) and from ``synthetic_start`` on, fit the diffusion
    model on the real transitions (s, a, s'), generate, and replace the synthetic buffer with ``synthetic_samples``
    new transitions (the ``synthetic_keep_quantile`` share the filter trusts most), rewarded by r̂. A retrain due at
    the last step of a ``learn()`` call (not its only step) is made at the first step of the next one instead, and
    any retrain waits while the real buffer holds fewer than ``batch_size`` transitions (a run resumed without its
    replay buffer).

    Logs under ``diffusion/``: the loss, train / generate / fidelity seconds, samples per second, samples dropped;
    with ``fidelity_check``, ``dynamics_error_ratio`` (synthetic next-state error under a one-step dynamics ensemble
    fitted on the real transitions, over that of real held-out transitions: 1.0 = as consistent as real data),
    ``dynamics_error``, ``real_dynamics_error``, ``novelty_ratio`` (nearest-real-neighbour distance over real-to-real:
    ~0 = copies), ``heldout_anchor_error_ratio`` (near-real generation: the ratio of the samples anchored on real
    transitions the ensemble held out, compared like with like with held-out real ones),
    ``kept_dynamics_error_ratio`` (after filtering) and the marginal ``mean_gap`` / ``std_gap``
    (blind to the dynamics: for reference only).
    """

    model: "PRIDE"
    first_step: int = 0  # the first env step of the current learn()

    def _on_training_start(self) -> None:
        self.first_step = self.model.num_timesteps + self.model.n_envs  # a learn() of one step retrains when due

    def _on_step(self) -> bool:
        model = self.model
        if model.in_pretraining or model.synthetic_ratio == 0 or model.num_timesteps < model.next_diffusion_step:
            return True
        if model.num_timesteps >= model._total_timesteps and model.num_timesteps > self.first_step:
            # past the last env step this learn() asked for: its data would feed only the updates of the rollout's
            # end, so the retrain waits for the first step of the next learn() (a CPU-tier run saves one retrain,
            # ~25 s, and evaluates the same policy)
            return True
        if model.real_buffer.size() < model.batch_size:
            # fewer real transitions than one SAC minibatch (a run resumed without its replay buffer): the retrain
            # waits until there are enough to fit on and to hold some out for the fidelity check
            return True
        model.next_diffusion_step = model.num_timesteps + model.diffusion_interval
        real = model.transition_vectors()
        assert model.diffusion is not None  # built by the first transition_vectors(), once the terminal flag is known
        fit = model.diffusion.fit(model.encode(real))
        start = time.perf_counter()
        n_draw = int(np.ceil(model.synthetic_samples / model.synthetic_keep_quantile))
        generation = model.generate(real, n_draw)
        if not (isinstance(generation, tuple) and len(generation) == 2):
            raise TypeError("PRIDE.generate must return (vectors, the row of real each was generated near, or None)")
        generated, anchors = model.sanitize(*generation)
        dropped = len(generation[0]) - len(generated)
        generate_seconds = time.perf_counter() - start
        start = time.perf_counter()
        fidelity = model.fidelity(real, generated, anchors) if model.fidelity_check else None
        kept = model.filter_synthetic(generated, model.synthetic_samples)
        fidelity_seconds = time.perf_counter() - start
        model.store_synthetic(kept)
        if model.first_generation_step is None:
            model.first_generation_step = model.num_timesteps
        model.diffusion_retrains += 1
        self.logger.record("diffusion/loss", fit.loss)
        self.logger.record("diffusion/train_seconds", fit.seconds)
        self.logger.record("diffusion/generate_seconds", generate_seconds)
        self.logger.record("diffusion/fidelity_seconds", fidelity_seconds)
        self.logger.record("diffusion/samples_per_second", n_draw / max(generate_seconds, 1e-9))
        self.logger.record("diffusion/samples_dropped", dropped)
        self.logger.record("diffusion/retrains", model.diffusion_retrains)
        summary = ""
        if fidelity is not None:
            for key, value in vars(fidelity).items():
                self.logger.record(f"diffusion/{key}", value)
            if len(kept) < len(generated) and model.dynamics is not None:
                # under the ensemble already fitted (optimistic under the dynamics filter, which chose them by it)
                kept_error = model.dynamics.errors(*model.split(kept)).mean()
                self.logger.record(
                    "diffusion/kept_dynamics_error_ratio", kept_error / max(fidelity.real_dynamics_error, 1e-12)
                )
            summary = f", dynamics error ratio {fidelity.dynamics_error_ratio:.2f}"
            if anchors is not None:
                summary += f" ({fidelity.heldout_anchor_error_ratio:.2f} near held-out anchors)"
            summary += f", novelty {fidelity.novelty_ratio:.2f}"
        if self.verbose > 0:
            print(
                f"diffusion retrain {model.diffusion_retrains} at step {model.num_timesteps}: loss {fit.loss:.3f}, "
                f"fit {fit.seconds:.1f} s, {len(kept)} samples in {generate_seconds:.1f} s ({dropped} dropped){summary}"
            )
        return True
