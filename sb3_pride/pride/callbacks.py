"""PRIDE's retrain-and-generate phase, beside PEBBLE's callbacks; ``PRIDE.learn()`` attaches it itself."""

from typing import TYPE_CHECKING

from stable_baselines3.common.callbacks import BaseCallback

if TYPE_CHECKING:
    from sb3_pride.pride.pride import PRIDE


class GeneratorCallback(BaseCallback):
    """
    PRIDE's generator phase (Algorithm 1, lines 22–30): whenever ``PRIDE.generator_due()``, ``PRIDE.retrain_generator()``
    fits the generator on the real transitions and replaces the synthetic buffer with new ones, rewarded by r̂. A
    retrain due at the last step of a ``learn()`` call (not its only step) is made at the first step of the next one
    instead: its data would feed only the updates of the rollout's end.

    ``retrain_generator`` logs under ``diffusion/``: the loss, train / generate / fidelity seconds, samples per
    second, samples dropped; with the generator's ``fidelity_check``, ``dynamics_error_ratio`` (synthetic next-state
    error under a one-step dynamics ensemble fitted on the real transitions, over that of real held-out transitions:
    1.0 = as consistent as real data), ``dynamics_error``, ``real_dynamics_error``, ``novelty_ratio``
    (nearest-real-neighbour distance over real-to-real: ~0 = copies), ``heldout_anchor_error_ratio`` (near-real
    generation: the samples anchored on transitions the ensemble held out, compared like with like),
    ``kept_dynamics_error_ratio`` (after filtering) and the marginal ``mean_gap`` / ``std_gap`` (blind to the
    dynamics: for reference only).
    """

    model: "PRIDE"
    first_step: int = 0  # the first env step of the current learn()
    last_step: int = 0  # the env step at which the current learn() ends

    def _on_training_start(self) -> None:
        self.first_step = self.model.num_timesteps + self.model.n_envs  # a learn() of one step retrains when due
        self.last_step = int(self.locals.get("total_timesteps", 2**62))  # outside SB3's learn(): no end to wait for

    def _on_step(self) -> bool:
        model = self.model
        if not model.generator_due() or (model.num_timesteps >= self.last_step and model.num_timesteps > self.first_step):
            return True
        report = model.retrain_generator()
        if self.verbose > 0:
            summary = ""
            if report.fidelity is not None:
                summary = f", dynamics error ratio {report.fidelity.dynamics_error_ratio:.2f}"
                if report.anchors is not None:
                    summary += f" ({report.fidelity.heldout_anchor_error_ratio:.2f} near held-out anchors)"
                summary += f", novelty {report.fidelity.novelty_ratio:.2f}"
            print(
                f"diffusion retrain {model.diffusion_retrains} at step {model.num_timesteps}: loss {report.fit.loss:.3f}, "
                f"fit {report.fit.seconds:.1f} s, {len(report.vectors)} samples in {report.generate_seconds:.1f} s "
                f"({report.dropped} dropped){summary}"
            )
        return True
