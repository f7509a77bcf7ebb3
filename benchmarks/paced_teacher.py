"""
A teacher at a person's pace, simulated: what waiting for answers costs is measured with it
(``benchmarks/run.py``'s ``seconds_per_answer``, ``benchmarks/speed.py --pace``), not in the package.
"""

import time

import numpy as np

from sb3_pride.common.queries import SegmentPairs
from sb3_pride.common.teachers import Teacher


class PacedTeacher:
    """
    A teacher that takes ``seconds_per_answer`` per query, then answers as ``teacher`` does: a person's pace,
    simulated, to measure what waiting for answers costs (``PEBBLE(asynchronous_feedback=...)``).

    :param teacher: the teacher that gives the answers (a ``Teacher``, e.g. ``ScriptedTeacher.from_preset("oracle")``)
    :param seconds_per_answer: the time each answer takes
    """

    def __init__(self, teacher: Teacher, seconds_per_answer: float):
        if not callable(teacher):
            raise ValueError(f"teacher must be a Teacher (a callable), got {type(teacher).__name__}")
        if not (isinstance(seconds_per_answer, (int, float)) and 0 <= seconds_per_answer < float("inf")):
            raise ValueError(f"seconds_per_answer must be a finite number >= 0, got {seconds_per_answer!r}")
        self.teacher = teacher
        self.seconds_per_answer = float(seconds_per_answer)

    def __call__(self, pairs: SegmentPairs) -> np.ndarray:
        time.sleep(self.seconds_per_answer * len(pairs))
        return self.teacher(pairs)
