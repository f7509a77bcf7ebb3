"""
The state of a ``WebTeacher``'s page, without HTTP: the open feedback session, who is handed which question, the
answers and undos (journaled through the session's ``FeedbackContext`` the moment they are given). One lock, a
``threading.Condition``, guards it all: the web server's threads answer while the model's thread waits.
"""

import math
import threading
import time
from typing import Any

from sb3_pride.common.journal import JournalEntry
from sb3_pride.common.utils import plain
from sb3_pride.human.pacing import JournalPace
from sb3_pride.human.questions import ALLOWED_LABELS, Answer, KnownPair, Question, Refused, Session
from sb3_pride.human.quality import HIDDEN_DURING_SESSION, Quality
from sb3_pride.human.settings import ANONYMOUS, HAND_OVER_AFTER

#: questions handed to an annotator at a time: the one shown and the next, whose clips the page preloads
QUEUE_LENGTH = 2
#: seconds after which the questions handed to an annotator whose page stopped asking for the state (it asks every
#: second; a browser tab hidden for minutes, once a minute) are handed to others
RELEASE_AFTER = 90.0


class AnswerStore:
    """
    The open feedback session and its answers, shared by the web server's threads and the thread of ``ask()``.

    An annotator is handed ``QUEUE_LENGTH`` questions at a time (the one shown and the next); the questions of an
    annotator whose page went quiet for ``RELEASE_AFTER`` seconds go to others, and a query shown for longer than
    ``hand_over_after`` seconds to an annotator who does not answer it is handed to one who has nothing left to answer.
    An answer to a known-answer question takes as long as a journaled one (it waits as long as one of the latest
    journal writes took, or, before the first, for a durable write of its own): response times do not tell them apart.

    :param quality: the known-answer pairs and the agreement (``Quality``), told of every answer
    :param annotators: the annotators' names (None: one person, ``"anonymous"``)
    :param answers_per_query: how many different annotators answer each query
    :param hand_over_after: seconds a query may stay shown to an annotator who does not answer it while another has
        nothing to answer
    """

    def __init__(
        self,
        quality: Quality,
        annotators: list[str] | None = None,
        answers_per_query: int = 1,
        hand_over_after: float = HAND_OVER_AFTER,
    ):
        self.quality, self.annotators = quality, annotators
        self.answers_per_query, self.hand_over_after = answers_per_query, hand_over_after
        #: guards everything below; notified on every change
        self.condition = threading.Condition()
        #: the open feedback session (None between sessions)
        self.session: Session | None = None
        #: the run's queries asked so far and its budget, as the page shows them
        self.budget: dict[str, int | None] = {"max": None, "asked": None}
        #: every reward update so far (``show_reward_history``), plain values (a NaN as None), as the page shows it
        self.reward_history: list[dict[str, Any]] = []
        #: annotator -> when (``time.monotonic()``) their page last asked for the state or answered
        self.last_seen: dict[str, float] = {}
        #: times the journal writes; a known-answer question's answer or undo waits as long as one took
        self.pace = JournalPace()

    # the session ------------------------------------------------------------------------------------------------
    def show_progress(self, asked: int, budget: int) -> None:
        """The run's queries asked so far and its budget, shown on the page between sessions."""
        with self.condition:
            self.budget = {"max": budget, "asked": asked}

    def show_reward_history(self, history: list[dict]) -> None:
        """
        Every reward update so far, shown on the page: ``WebTeacher.show_reward_history()``. A copy of plain values is
        kept (``plain``: NumPy's numbers as Python's, a NaN as None), nothing of ``history`` itself.

        :param history: one dict per reward update, oldest first
        """
        with self.condition:
            self.reward_history = [plain(dict(entry), nan_as_none=True) for entry in history]

    def begin(self, session: Session) -> None:
        """Open ``session``: its queries count as asked from now on. Raises ``RuntimeError`` while another is open."""
        with self.condition:
            if self.session is not None:
                raise RuntimeError(
                    f"WebTeacher asks one feedback session at a time: session {self.session.number} is still open"
                )
            self.session = session
            # the session's queries count as asked from its start: a budget that moved with each answer would tell
            # the model's queries from known-answer questions
            self.budget = {"max": session.context.budget, "asked": session.asked_before + len(session.queries)}
            self.condition.notify_all()

    def ready(self, query: Question, known: float | None = None) -> None:
        """``query``'s clips are written: it may be handed out; with ``known``, it becomes a known-answer pair."""
        with self.condition:
            query.ready = True
            if known is not None:
                self.quality.add_known(KnownPair(query.pair, query.inputs, query.files, known, "true reward"))
            self.condition.notify_all()

    def cancel(self, session: Session) -> None:
        """Close ``session`` without its answers (``ask()`` failed or was interrupted)."""
        with self.condition:
            session.cancelled = True
            if self.session is session:
                self.session = None
            self.condition.notify_all()

    def wait(self, timeout: float | None, reminder_interval: float, url: str) -> None:
        """
        Wait until every query of the open session has its answers, or ``timeout`` seconds (the rest are then skipped,
        and journaled as such), reminding the console of ``url`` every ``reminder_interval`` seconds; then close it.
        """
        start = last_reminder = time.monotonic()
        k = self.answers_per_query
        with self.condition:
            session = self.session
            assert session is not None, "no feedback session is open"
            while session.open(k):
                now = time.monotonic()
                if timeout is not None and now - start >= timeout:
                    # queries nobody answered are skipped: asked, not labeled, and journaled as such
                    skipped = [query for query in session.open(k) if not query.answers]
                    session.context.record(
                        [JournalEntry(session.number, query.inputs, math.nan, time=time.time()) for query in skipped]
                    )
                    partial = len(session.open(k)) - len(skipped)
                    short = f", {partial} with fewer than {k} answers" if partial else ""
                    print(f"WebTeacher: timeout, {len(skipped)} queries skipped{short}", flush=True)
                    break
                if now - last_reminder >= reminder_interval:
                    last_reminder = now
                    print(
                        f"WebTeacher: still waiting for {len(session.open(k))} queries of feedback session "
                        f"{session.number} at {url} (page last seen: {self._seen_summary(now)})",
                        flush=True,
                    )
                wait = reminder_interval - (now - last_reminder)
                if timeout is not None:
                    wait = min(wait, timeout - (now - start))
                self.condition.wait(timeout=max(wait, 0.01))
            # closed in the same locked block: no answer or undo can reach it once it is over
            self.session = None
            self.condition.notify_all()

    def _seen_summary(self, now: float) -> str:
        def ago(name: str) -> str:
            seen = self.last_seen.get(name)
            return "never" if seen is None else f"{now - seen:.0f} s ago"

        return ", ".join(f"{name} {ago(name)}" for name in self.annotators) if self.annotators else ago(ANONYMOUS)

    def person(self, annotator: str | None) -> str | None:
        """The annotator behind a call: the one person without ``annotators``; None for nobody (an overview)."""
        if not self.annotators:
            return ANONYMOUS
        if annotator is not None and annotator not in self.annotators:
            raise ValueError(f"annotator must be one of {self.annotators}, got {annotator!r}")
        return annotator

    def clip_file(self, name: str) -> str | None:
        """The file shown by the open session's clip ``name`` (the last part of its address), or None."""
        with self.condition:
            return None if self.session is None else self.session.clip_file(name)

    # what a page shows ------------------------------------------------------------------------------------------
    def page_state(self, annotator: str | None = None, instructions: str = "") -> dict[str, Any]:
        """
        What ``annotator``'s page shows (handing them questions): ``WebTeacher.state()``.

        :param annotator: whose page (None without ``annotators``: the one person; with them, an overview)
        :param instructions: the instructions the page shows
        """
        with self.condition:
            name = self.person(annotator)
            if name is not None:
                self.last_seen[name] = time.monotonic()
            session = self.session
            handed = self._hand_out(session, name) if session is not None and name is not None else []
            if session is None:
                waiting = "waiting for the next feedback session"
            elif handed:
                waiting = ""
            elif any(not query.ready for query in session.open(self.answers_per_query)):
                waiting = "rendering the next clips…"
            elif session.open(self.answers_per_query):
                waiting = "the others are answering the last queries of this session"
            else:
                waiting = "all answered"
            team = []
            for other, row in self.quality.agreement().items():
                if session is not None:  # during a session agreement would tell known-answer questions apart
                    row.update({key: None for key in HIDDEN_DURING_SESSION})
                team.append({"name": other, "session": len(session.history.get(other, [])) if session else 0, **row})
            answered, total = (0, 0) if session is None else self._progress(session)
            return {
                "session": None if session is None else session.number,
                "you": annotator if self.annotators else None,
                "query": None if not handed else {"id": handed[0].id, "left": handed[0].clips[0], "right": handed[0].clips[1]},
                "next": None if len(handed) < 2 else {"left": handed[1].clips[0], "right": handed[1].clips[1]},
                "waiting": waiting,
                "answered": answered,
                "total": total,
                "estimate": self.quality.known_answer_rate > 0,
                "answers_per_query": self.answers_per_query,
                "team": team,
                "budget": dict(self.budget),
                "reward_history": [dict(entry) for entry in self.reward_history],
                "instructions": instructions,
            }

    def _progress(self, session: Session) -> tuple[int, int]:
        """
        (answers given, answers expected) in ``session``: every answer counts, a known-answer question's too; the
        expected ones are the queries' answers plus, at ``known_answer_rate``, known-answer questions in proportion.
        """
        answered = session.answers_given()
        expected = math.ceil(len(session.queries) * self.answers_per_query / (1 - self.quality.known_answer_rate))
        return answered, max(expected, answered)

    # who answers what -------------------------------------------------------------------------------------------
    def _hand_out(self, session: Session, name: str) -> list[Question]:
        """The questions handed to ``name`` (the first is shown), topped up to ``QUEUE_LENGTH``."""
        self._release_stale(session, name)
        handed = session.queues.setdefault(name, [])
        while len(handed) < QUEUE_LENGTH:
            question = self._next_question(session, name, first=not handed)
            if question is None:
                break
            handed.append(question)
            if question.known is None:
                question.holders.add(name)
        if not handed:
            session.shown_since.pop(name, None)
        elif session.shown_since.get(name, (None, 0.0))[0] is not handed[0]:
            session.shown_since[name] = (handed[0], time.monotonic())
        return handed

    def _release_stale(self, session: Session, name: str) -> None:
        """Questions handed to annotators whose page went quiet (``RELEASE_AFTER``) go back to the others."""
        now = time.monotonic()
        for other, handed in session.queues.items():
            if other != name and handed and now - self.last_seen.get(other, now) > RELEASE_AFTER:
                for question in handed:
                    question.holders.discard(other)
                handed.clear()
                session.shown_since.pop(other, None)

    def _next_question(self, session: Session, name: str, first: bool) -> Question | None:
        """
        The next question for ``name``: a ready query they have not answered that still needs answers (those others
        already answer first: they finish sooner), else (for the one shown) one preloaded for someone else, or one
        shown to someone else for more than ``hand_over_after`` seconds (a known-answer question too, if its pair may
        be shown to them); in place of it, a known-answer question at ``known_answer_rate``.
        """
        k = self.answers_per_query
        candidates = [
            query
            for query in session.queries
            if query.ready and name not in query.answers and name not in query.holders and query.taken < k
        ]
        real = max(candidates, key=lambda q: q.taken) if candidates else None  # max: the first of the most taken
        taken: tuple[str, Question] | None = None
        if real is None and first:
            now = time.monotonic()
            preloaded = ((other, handed[1]) for other, handed in session.queues.items() if len(handed) > 1)
            overdue = (
                (other, shown)
                for other, (shown, since) in session.shown_since.items()
                if now - since > self.hand_over_after and session.queues.get(other, [])[:1] == [shown]
            )
            # a known-answer question goes over as a query does, when its pair may be shown to them: one that never
            # went would tell itself apart
            taken = next(
                (
                    (other, q)
                    for other, q in (*preloaded, *overdue)
                    if other != name and name not in q.answers and (q.known is None or self.quality.may_take(session, name, q))
                ),
                None,
            )
        if real is None and taken is None:
            return None  # nothing left for them: no known-answer question either, the session is nearly over
        known = self.quality.draw_known(session, name)
        if known is not None:
            return known
        if real is None and taken is not None:
            other, real = taken
            session.queues[other].remove(real)
            real.holders.discard(other)
            if real.known is not None:
                session.known_shown.setdefault(name, set()).add(real.pair)
        return real

    # answers ----------------------------------------------------------------------------------------------------
    def answer(self, question_id: Any, label: Any, annotator: str | None = None) -> None:
        """
        Record ``annotator``'s answer to question ``question_id`` (the one shown to them): ``WebTeacher.answer()``.
        ``-0.0`` is taken as 0.

        :raises Refused: ``"malformed"`` label or id, ``"unknown"`` question, ``"conflict"`` (no open session, answered
            already, a query with all its answers), ``"not shown"`` (not the question shown to the annotator)
        """
        if not (
            label is None or (isinstance(label, (int, float)) and not isinstance(label, bool) and label in ALLOWED_LABELS)
        ):
            raise Refused("malformed", f"label must be 0 (left), 1 (right), 0.5 (equal) or null (skip), got {label!r}")
        if not isinstance(question_id, str):
            raise Refused("malformed", f"id must be the string id of the question shown, got {question_id!r}")
        with self.condition:
            name = self.person(annotator)
            if name is None:
                raise Refused("malformed", "name the annotator who answers")
            self.last_seen[name] = time.monotonic()
            session = self.session
            if session is None:
                raise Refused("conflict", "no feedback session is open (it is over, or the next one has not begun)")
            question = session.find(question_id)
            if question is None:
                raise Refused("unknown", f"no question {question_id!r} in feedback session {session.number}")
            if name in question.answers:
                raise Refused("conflict", f"question {question_id!r} is answered already by you (undo first)")
            # a question shown to someone else is refused alike whatever it is: a query, one with all its answers, or a
            # known-answer question (two annotators comparing refusals would tell them apart)
            handed = session.queues.get(name, [])
            if not handed or handed[0] is not question:
                raise Refused("not shown", f"question {question_id!r} is not the one shown to you")
            if question.known is None and len(question.answers) >= self.answers_per_query:
                raise Refused("conflict", f"question {question_id!r} has all its answers already")
            value = math.nan if label is None else float(label) + 0.0  # + 0.0: -0.0 becomes 0.0
            if question.known is None:
                # journaled (flushed to disk) first, then kept, so that a failed write changes nothing
                entry = JournalEntry(session.number, question.inputs, value, self._journal_name(name), time.time())
                self.pace.write(session.context.record, [entry])
            else:
                self.pace.wait()
            handed.pop(0)
            question.holders.discard(name)
            question.answers[name] = value
            given = question.scored.get(name)  # a known-answer question answered again after an undo: the first counts
            if given is None:
                given = Answer(name, question.pair, value, question.known)
                self.quality.count(given)
                if question.known is not None:
                    question.scored[name] = given
            session.history.setdefault(name, []).append((question, given))
            self.condition.notify_all()

    def undo(self, annotator: str | None = None) -> str:
        """
        Take back ``annotator``'s last answer of this session (and say so in the journal): ``WebTeacher.undo()``.

        :return: the id of the question, shown to them again
        :raises Refused: ``"conflict"`` when there is none to take back
        """
        with self.condition:
            name = self.person(annotator)
            session = self.session
            if name is None or session is None or not session.history.get(name):
                raise Refused("conflict", "no answer of yours in this feedback session to undo")
            question, given = session.history[name][-1]
            if question.known is None:
                self.pace.write(
                    session.context.retract, session.number, entry_id=question.pair, annotator=self._journal_name(name)
                )
            else:
                self.pace.wait()
            session.history[name].pop()
            del question.answers[name]
            if question.known is None:
                self.quality.take_back(given)
            handed = session.queues.setdefault(name, [])
            handed.insert(0, question)
            if question.known is None:
                question.holders.add(name)
            while len(handed) > QUEUE_LENGTH:
                handed.pop().holders.discard(name)
            self.condition.notify_all()
            return question.id

    def _journal_name(self, name: str) -> str | None:
        return name if self.annotators else None
