"""The callbacks that drive PEBBLE's preference-based learning; ``PEBBLE.learn()`` attaches them itself."""

from typing import TYPE_CHECKING

from stable_baselines3.common.callbacks import BaseCallback

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
    Feedback sessions (Algorithm 1, lines 6–21): the first when pre-training ends, then every ``feedback_interval``
    steps while fewer than ``max_feedback`` queries were asked, each by ``PEBBLE.feedback_session()`` (ask, label,
    learn r̂, relabel). The first one ends pre-training (``PEBBLE.end_pretraining()``: critic reset and
    ``critic_reset_updates`` steps on r̂). When no segment fits in the stored episodes yet, the session is tried
    again a segment later.
    """

    model: "PEBBLE"

    def _on_step(self) -> bool:
        model = self.model
        if model.feedback_asked >= model.max_feedback or model.num_timesteps < model.next_feedback_step:
            return True
        first = model.in_pretraining
        if not model.feedback_session():
            model.next_feedback_step = model.num_timesteps + model.segment_length
            return True
        model.next_feedback_step = model.num_timesteps + model.feedback_interval
        if first:
            model.end_pretraining()
        return True
