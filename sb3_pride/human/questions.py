"""
What a ``WebTeacher`` keeps of its questions, answers and feedback sessions: plain data, no HTTP and no locks (the
``AnswerStore`` that holds them guards them with its lock); and the answers it takes or refuses.
"""

import math
from dataclasses import dataclass, field

import numpy as np

from sb3_pride.common.journal import query_id
from sb3_pride.common.teachers import FeedbackContext

#: the answers the page may send: μ = P[right segment preferred]; None is a skip
ALLOWED_LABELS = (0.0, 0.5, 1.0, None)
#: why the store refuses an answer or an undo (``Refused.reason``)
REASONS = ("malformed", "not shown", "unknown", "conflict")


class Refused(Exception):
    """
    An answer or an undo that the store refuses: nothing was recorded.

    :param reason: one of ``REASONS``: a malformed label or id, a question not shown to the annotator, one not in the
        open session, or a conflict (no open session, answered already, all answers given, nothing to undo)
    :param message: what the person is told
    """

    def __init__(self, reason: str, message: str):
        assert reason in REASONS, reason
        super().__init__(message)
        self.reason = reason


def clip_urls(question_id: str) -> tuple[str, str]:
    """The addresses of a question's two clips: the same shape for every question, known-answer ones included."""
    return f"/clips/{question_id}-left.mp4", f"/clips/{question_id}-right.mp4"


@dataclass(eq=False)
class Question:
    """
    A question on the page: one of the model's queries, or a known-answer question (``known`` set).

    :param id: its id on the page (random; a known-answer question has its own, never the id of the pair it shows)
    :param inputs: the pair's (2, segment_length, input_dim) reward-model inputs
    :param files: the names of the files its two clips show, in the teacher's clip folder (a known-answer question
        shows a copy of an older question's, made for it)
    :param known: a known-answer question's known answer; None for the model's queries
    :param ready: its clips are written: it may be handed out
    :param pair: the journal's id of its inputs (``query_id``; computed when not given)
    """

    id: str
    inputs: np.ndarray
    files: tuple[str, str] = ("", "")
    known: float | None = None
    ready: bool = False
    answers: dict[str, float] = field(default_factory=dict)  # annotator -> μ (NaN: skipped)
    scored: dict[str, "Answer"] = field(default_factory=dict)  # known-answer question: annotator -> their first answer
    holders: set[str] = field(default_factory=set)  # annotators it is handed to who have not answered it yet
    pair: str = ""

    def __post_init__(self) -> None:
        if not self.pair:
            self.pair = query_id(self.inputs)
        if self.files == ("", ""):
            self.files = (f"{self.id}-left.mp4", f"{self.id}-right.mp4")

    @property
    def clips(self) -> tuple[str, str]:
        """The addresses the page loads its clips from (``clip_urls``)."""
        return clip_urls(self.id)

    @property
    def taken(self) -> int:
        """The annotators who answered it or are answering it."""
        return len(self.answers) + len(self.holders)

    def label(self) -> float:
        """μ for the model: the mean of its answers that are not skips (NaN when all are, or when it has none)."""
        given = [value for value in self.answers.values() if not math.isnan(value)]
        return float(np.mean(given)) if given else math.nan


@dataclass(eq=False)
class Answer:
    """One answer of an annotator (to the model's query or a known-answer question), kept for the agreement report."""

    annotator: str
    pair: str
    label: float
    known: float | None


@dataclass(eq=False)
class KnownPair:
    """
    A pair whose answer is known, with its clips: the stuff of known-answer questions.

    :param source: ``"true reward"`` or ``"majority"``
    :param voters: a majority's annotators (never shown it as a known-answer question)
    :param copies: copies of its clips ready to show (``recode_clip``), by the id of the question each is made for
    """

    pair: str
    inputs: np.ndarray
    files: tuple[str, str]
    answer: float
    source: str
    voters: frozenset[str] = frozenset()
    copies: list[str] = field(default_factory=list)


@dataclass(eq=False)
class Session:
    """
    One feedback session on the page.

    :param number: the feedback session's number (``FeedbackContext.session``)
    :param queries: the model's queries, in the order of its pairs
    :param asked_before: the queries the run asked before this session
    :param context: where its answers are journaled and its numbers logged
    """

    number: int
    queries: list[Question]
    asked_before: int
    context: FeedbackContext
    known: dict[str, Question] = field(default_factory=dict)  # known-answer questions handed out, by id
    queues: dict[str, list[Question]] = field(default_factory=dict)  # annotator -> questions handed to them, shown first
    history: dict[str, list[tuple[Question, Answer]]] = field(default_factory=dict)  # annotator -> answers, oldest first
    known_shown: dict[str, set[str]] = field(default_factory=dict)  # annotator -> pairs shown as known-answer questions
    shown_since: dict[str, tuple[Question, float]] = field(default_factory=dict)  # annotator -> (shown, since when)
    cancelled: bool = False

    def __post_init__(self) -> None:
        self.by_id = {query.id: query for query in self.queries}
        self.by_pair = {query.pair: query for query in self.queries}

    def find(self, question_id: str) -> Question | None:
        """The query or known-answer question ``question_id`` of this session, or None."""
        return self.by_id.get(question_id) or self.known.get(question_id)

    def open(self, answers_per_query: int) -> list[Question]:
        """The model's queries that still lack answers."""
        return [query for query in self.queries if len(query.answers) < answers_per_query]

    def answers_given(self) -> int:
        """The answers given in this session by everyone (known-answer questions and skips included, undone ones not)."""
        return sum(len(answers) for answers in self.history.values())

    def clip_file(self, name: str) -> str | None:
        """The file that clip ``name`` (the last part of its address) of a ready question shows, or None."""
        question_id, _, side = name.rpartition("-")
        question = self.find(question_id)
        if question is None or not question.ready or side not in ("left.mp4", "right.mp4"):
            return None
        return question.files[0 if side == "left.mp4" else 1]
