"""The callbacks that drive preference-based learning; ``PEBBLE.learn()`` attaches them itself."""

import time
from typing import TYPE_CHECKING

import numpy as np
from stable_baselines3.common.callbacks import BaseCallback

from sb3_pride.common.queries import sample_segment_pairs, select_queries

if TYPE_CHECKING:
    from sb3_pride.pebble.pebble import PEBBLE
    from sb3_pride.pride.pride import PRIDE


class UnsupervisedPretrainingCallback(BaseCallback):
    """
    PEBBLE's unsupervised pre-training (Algorithm 1, line 3): until the first feedback session, SAC's critic
    target uses the state-entropy reward r_int (Eq. 3) in place of r̂.
    """

    model: "PEBBLE"

    def _on_training_start(self) -> None:
        self._update()

    def _on_step(self) -> bool:
        self._update()
        return True

    def _update(self) -> None:
        self.model.update_reward_source()


class FeedbackCallback(BaseCallback):
    """
    Feedback sessions (Algorithm 1, lines 6–21): the first when pre-training ends, then every
    ``feedback_interval`` steps while fewer than ``max_feedback`` queries were asked. A session asks
    ``min(queries_per_session, max_feedback - asked)`` queries, trains the reward model and relabels the buffer.
    After the first session the critic is reset and trained ``critic_reset_updates`` steps on r̂, as PEBBLE does.
    """

    model: "PEBBLE"

    def _on_step(self) -> bool:
        model = self.model
        if model.feedback_asked >= model.max_feedback or model.num_timesteps < model.next_feedback_step:
            return True
        first = model.feedback_sessions == 0
        if not self.feedback_session():
            # not one segment fits in the stored episodes yet: try again a segment later
            model.next_feedback_step = model.num_timesteps + model.segment_length
            return True
        model.next_feedback_step = model.num_timesteps + model.feedback_interval
        # pre-training ended with this session: from the reset updates on (and this step's own update), the
        # critic learns from r̂, not r_int (B-Pref's update_after_reset)
        model.update_reward_source()
        if first:
            model.reset_critic()
            model.train(gradient_steps=model.critic_reset_updates, batch_size=model.batch_size)
            model.policy.set_training_mode(False)  # back to rollout mode
        return True

    def feedback_session(self) -> bool:
        """Ask, label, learn r̂, relabel. :return: False when no segment could be sampled."""
        model = self.model
        n_queries = min(model.queries_per_session, model.max_feedback - model.feedback_asked)
        # the first session is uniform: the reward model knows nothing yet
        selection = "uniform" if model.feedback_sessions == 0 else model.query_selection
        n_candidates = n_queries if selection == "uniform" else n_queries * model.candidates_multiplier
        candidates = sample_segment_pairs(
            model.real_buffer, n_candidates, model.segment_length, model.max_query_episodes, model.preference_rng
        )
        if candidates is None:
            model.check_episodes_fit_segments()
            return False
        inputs = np.concatenate([candidates.observations, candidates.actions], axis=-1)
        if selection != "uniform":
            chosen = select_queries(model.reward_model.member_segment_returns(inputs), n_queries, selection)
            candidates, inputs = candidates[chosen], inputs[chosen]

        labels = model.ask_teacher(candidates)
        labeled = ~np.isnan(labels)
        model.preferences.add(inputs[labeled], labels[labeled])
        # skipped queries count as asked (they cost the teacher's time) but not as labels
        model.feedback_asked += n_queries
        model.feedback_labeled += int(labeled.sum())
        model.feedback_sessions += 1
        self.logger.record("feedback/asked", model.feedback_asked)
        self.logger.record("feedback/labeled", model.feedback_labeled)
        self.logger.record("feedback/sessions", model.feedback_sessions)
        if len(model.preferences) == 0:
            return True

        loss, accuracy, epochs = model.reward_model.train_epochs(
            model.preferences, model.reward_epochs, model.reward_batch_size, rng=model.preference_rng
        )
        model.relabel()
        correlation = model.reward_correlation()
        self.logger.record("reward_model/loss", loss)
        self.logger.record("reward_model/accuracy", accuracy)
        self.logger.record("reward_model/epochs", epochs)
        self.logger.record("reward_model/true_reward_corr", correlation)
        if self.verbose > 0:
            print(
                f"feedback session {model.feedback_sessions} at step {model.num_timesteps}: "
                f"{model.feedback_labeled}/{model.feedback_asked} labeled, reward-model accuracy {accuracy:.3f}, "
                f"corr(r_hat, r_true) {correlation:.3f}"
            )
        return True


class DiffusionCallback(BaseCallback):
    """
    PRIDE's diffusion phase (Algorithm 1, lines 22–30): every ``diffusion_interval`` steps, once a reward model
    exists (so synthetic data never carries an untrained reward) and from ``synthetic_start`` on, fit the diffusion
    model on the real transitions (s, a, s'), generate, and replace the synthetic buffer with ``synthetic_samples``
    new transitions (the ``synthetic_keep_quantile`` share the filter trusts most), rewarded by r̂.

    Logs under ``diffusion/``: the loss, train / generate / fidelity seconds, samples per second, samples dropped;
    with ``fidelity_check``, ``dynamics_error_ratio`` (synthetic next-state error under a one-step dynamics ensemble
    fitted on the real transitions, over that of real held-out transitions: 1.0 = as consistent as real data),
    ``dynamics_error``, ``real_dynamics_error``, ``novelty_ratio`` (nearest-real-neighbour distance over real-to-real:
    ~0 = copies), ``kept_dynamics_error_ratio`` (after filtering) and the marginal ``mean_gap`` / ``std_gap``
    (blind to the dynamics: for reference only).
    """

    model: "PRIDE"

    def _on_step(self) -> bool:
        model = self.model
        if model.in_pretraining or model.synthetic_ratio == 0 or model.num_timesteps < model.next_diffusion_step:
            return True
        model.next_diffusion_step = model.num_timesteps + model.diffusion_interval
        real = model.transition_vectors()
        fit = model.diffusion.fit(model.encode(real))
        start = time.perf_counter()
        n_draw = int(np.ceil(model.synthetic_samples / model.synthetic_keep_quantile))
        generated, dropped = model.sanitize(model.generate(real, n_draw))
        generate_seconds = time.perf_counter() - start
        start = time.perf_counter()
        fidelity = model.fidelity(real, generated) if model.fidelity_check else None
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
            if len(kept) < len(generated):
                # under the ensemble already fitted (optimistic under the dynamics filter, which chose them by it)
                kept_error = model.dynamics.errors(*model.split(kept)).mean()
                self.logger.record("diffusion/kept_dynamics_error_ratio", kept_error / max(fidelity.real_dynamics_error, 1e-12))
            summary = f", dynamics error ratio {fidelity.dynamics_error_ratio:.2f}, novelty {fidelity.novelty_ratio:.2f}"
        if self.verbose > 0:
            print(
                f"diffusion retrain {model.diffusion_retrains} at step {model.num_timesteps}: loss {fit.loss:.3f}, "
                f"fit {fit.seconds:.1f} s, {len(kept)} samples in {generate_seconds:.1f} s ({dropped} dropped){summary}"
            )
        return True

