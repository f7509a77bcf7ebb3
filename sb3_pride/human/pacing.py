"""
Answers whose timing tells nothing: an answer to a known-answer question (never journaled) takes as long as an answer
to one of the model's queries (journaled and flushed to disk), so response times do not tell the two apart.
"""

import os
import random
import tempfile
import time
from collections import deque
from collections.abc import Callable
from typing import Any

#: how many of the latest journal writes a known-answer question's answer draws its wait from
PACE_SAMPLES = 32


class JournalPace:
    """
    Times an ``AnswerStore``'s journal writes, and makes what stands in for one (a known-answer question's answer or
    undo) take as long. Not locked: the store calls it under its own lock.

    :param samples: how many of the latest journal writes the wait is drawn from
    """

    def __init__(self, samples: int = PACE_SAMPLES):
        #: the latest journal writes, in seconds
        self.durations: deque[float] = deque(maxlen=samples)
        self._rng = random.Random()

    def write(self, write: Callable[..., None], *args: Any, **kwargs: Any) -> None:
        """
        A journal write (``FeedbackContext.record`` or ``retract``), timed.

        :param write: the write, called with ``args`` and ``kwargs``
        """
        start = time.perf_counter()
        write(*args, **kwargs)
        self.durations.append(time.perf_counter() - start)

    def wait(self) -> None:
        """
        What a known-answer question's answer or undo does in place of a journal write, so that it takes as long: wait
        as long as one of the latest journal writes took; before the first, make a durable write of its own.
        """
        if self.durations:
            time.sleep(self._rng.choice(self.durations))
            return
        with tempfile.TemporaryFile() as file:
            file.write(b'{"session": 0, "label": 0.5}\n')
            file.flush()
            os.fsync(file.fileno())
