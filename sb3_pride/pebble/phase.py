"""Where PEBBLE's preference phase stands: one object, written by the model and read by the parts that need it."""

from dataclasses import dataclass, field
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from sb3_pride.reward.ensemble import PreferenceDataset


@dataclass
class PreferencePhase:
    """
    The state of PEBBLE's preference-based learning (Algorithm 1): the feedback sessions closed, the queries asked and
    labeled in them, the env step of the next session, whether SAC still learns from the state-entropy reward
    (pre-training lasts until the first session is closed) and whether r̂ has learned from labels. The model writes it
    when a session is closed (``close_session``) and when ``learn()`` restarts its step count (``shift``); the feedback
    callback, the replay rewards and PRIDE's generator read it. Saved with the model.

    :param next_step: the env step of the first feedback session (``learning_starts + unsupervised_steps``)
    """

    next_step: int
    #: feedback sessions closed
    sessions: int = 0
    #: queries asked (skipped ones included: they cost the teacher's time)
    asked: int = 0
    #: queries labeled (asked and not skipped)
    labeled: int = 0
    #: D, the preferences r̂ learns from (set by the model once it is made; prior answers in it from the start)
    preferences: "PreferenceDataset | None" = field(default=None, repr=False)

    @property
    def pretraining(self) -> bool:
        """True until the first feedback session is closed: SAC learns from the state-entropy reward (Eq. 3)."""
        return self.sessions == 0

    @property
    def learned(self) -> bool:
        """Whether r̂ has learned from labels: after the first session, with any (its own or prior ones) in D."""
        return not self.pretraining and self.preferences is not None and len(self.preferences) > 0

    def __getstate__(self) -> dict:
        return {**self.__dict__, "preferences": None}  # D is the model's, saved once; given back by the model

    def close_session(self, asked: int, labeled: int) -> None:
        """A feedback session closed, ``asked`` queries asked and ``labeled`` of them labeled."""
        self.sessions += 1
        self.asked += asked
        self.labeled += labeled

    def shift(self, steps: int) -> None:
        """The env step count moved by ``steps`` (``learn(reset_num_timesteps=True)``): the next session keeps its distance."""
        self.next_step = max(0, self.next_step + steps)
