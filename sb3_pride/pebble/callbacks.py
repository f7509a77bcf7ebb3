"""The callbacks that drive PEBBLE's preference-based learning; ``PEBBLE.learn()`` attaches them itself."""

from typing import TYPE_CHECKING

from stable_baselines3.common.callbacks import BaseCallback

if TYPE_CHECKING:
    from sb3_pride.pebble.pebble import PEBBLE


class FeedbackCallback(BaseCallback):
    """
    Feedback sessions (Algorithm 1, lines 6–21): the first when pre-training ends, then every ``feedback_interval``
    steps while fewer than ``max_feedback`` queries were asked. Each is published (``PEBBLE.publish_queries()``) and
    its answers taken in (``PEBBLE.take_answers()``: label, learn r̂, relabel) at once, or, with
    ``asynchronous_feedback``, at the first step after the teacher has answered, training going on meanwhile; the next
    session is not published before. The first one ends pre-training (``PEBBLE.end_pretraining()``: critic reset and
    ``pretraining_kwargs["critic_reset_updates"]`` steps on r̂); until then SAC learns from the state-entropy reward.
    When no segment fits in the stored episodes yet, the session is tried again a segment later. A session still
    open when ``learn()`` ends is waited for.
    """

    model: "PEBBLE"

    def _on_step(self) -> bool:
        model = self.model
        bonus = model.reward_learner.exploration_bonus
        if bonus is not None and model.replay_rewards.bonus_active:  # RUNE's β_t counts num_timesteps (learn() resets it)
            model.logger.record("train/exploration_beta", bonus.beta(model.num_timesteps))
        if model.feedback.pending is not None:
            if model.feedback.ready:
                self._take_answers()
            return True
        phase = model.phase
        if phase.asked >= model.max_feedback or model.num_timesteps < phase.next_step:
            return True
        if not model.publish_queries():
            phase.next_step = model.num_timesteps + model.segment_length
            return True
        if not model.asynchronous_feedback:
            phase.next_step = model.num_timesteps + model.feedback_interval
            self._take_answers()
        return True

    def _on_training_end(self) -> None:
        if self.model.feedback.pending is not None:  # a teacher's answers are never dropped
            self._take_answers()

    def _take_answers(self) -> None:
        model = self.model
        pending = model.feedback.pending
        first, published = model.phase.pretraining, None if pending is None else pending.published_step
        model.take_answers()
        if model.asynchronous_feedback and published is not None:
            # scheduled from the session's publication, once it is answered: a checkpoint taken while a session is
            # open (which does not hold it) publishes it again at once when resumed
            model.phase.next_step = published + model.feedback_interval
        if first:
            model.end_pretraining()
