"""The callbacks that drive PEBBLE's preference-based learning; ``PEBBLE.learn()`` attaches them itself."""

from typing import TYPE_CHECKING

import numpy as np
from stable_baselines3.common.callbacks import BaseCallback

from sb3_pride.common.journal import JournalEntry, query_id
from sb3_pride.common.queries import sample_segment_pairs, select_queries

if TYPE_CHECKING:
    from sb3_pride.pebble.pebble import PEBBLE


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
        """
        Ask, label, learn r̂, relabel. Answers of this session already in the preference journal (given before a
        crash) are taken from it; the teacher is asked only for the rest, never for a query it answered.

        :return: False when no segment could be sampled
        """
        model = self.model
        session = model.feedback_sessions + 1
        n_queries = min(model.queries_per_session, model.max_feedback - model.feedback_asked)
        journaled = model.journaled_answers(session)[:n_queries]
        inputs, labels = self.ask_new_queries(n_queries - len(journaled))
        if inputs is None:
            return False
        # the journal is written before the answers are used (a teacher that hears them one at a time, a person,
        # has written each as it came): a crash from here on loses none of them
        if not getattr(model.resolve_teacher(), "journals_answers", False):
            model.record_answers([JournalEntry(session, pair, label) for pair, label in zip(inputs, labels, strict=True)])
        model.journal_entries += len(journaled) + len(labels)
        if journaled:
            inputs = np.concatenate([np.stack([entry.inputs for entry in journaled]), inputs])
            labels = np.concatenate([[entry.label for entry in journaled], labels])
        labeled = ~np.isnan(labels)
        model.preferences.add(inputs[labeled], labels[labeled])
        # skipped queries count as asked (they cost the teacher's time) but not as labels
        model.feedback_asked += len(labels)
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

    def ask_new_queries(self, n_queries: int) -> tuple[np.ndarray | None, np.ndarray]:
        """
        Sample candidate pairs, select ``n_queries`` of them and ask the teacher (``ask_teacher`` checks the answers
        before anything is recorded). Pairs the journal already holds are never asked again.

        :return: the pairs' reward-model inputs (n, 2, k, obs_dim + action_dim) and their labels μ (NaN: skipped),
            or (None, _) when no segment fits in the stored episodes yet
        """
        model = self.model
        no_inputs = np.zeros((0, 2, model.segment_length, model.preferences.inputs.shape[-1]), dtype=np.float32)
        if n_queries == 0:
            return no_inputs, np.zeros(0)
        # the first session is uniform: the reward model knows nothing yet
        selection = "uniform" if model.feedback_sessions == 0 else model.query_selection
        n_candidates = n_queries if selection == "uniform" else n_queries * model.candidates_multiplier
        candidates = sample_segment_pairs(
            model.real_buffer, n_candidates, model.segment_length, model.max_query_episodes, model.preference_rng
        )
        if candidates is None:
            model.warn_short_episodes()
            return None, np.zeros(0)
        inputs = candidates.inputs
        asked_before = {entry.id for entry in model.journal_history()}
        if asked_before:
            fresh = np.array([query_id(pair) not in asked_before for pair in inputs])
            candidates, inputs = candidates[fresh], inputs[fresh]
        if len(inputs) == 0:
            return no_inputs, np.zeros(0)
        if selection != "uniform":
            chosen = select_queries(model.reward_model.member_segment_returns(inputs), min(n_queries, len(inputs)), selection)
            candidates, inputs = candidates[chosen], inputs[chosen]
        return inputs, model.ask_teacher(candidates)
