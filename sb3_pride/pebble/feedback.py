"""
A feedback session's way from queries to answers (Algorithm 1, lines 6–15): publish the queries to the teacher,
synchronously or in a thread of its own, take the answers in once they are all given, check them, journal them.
"""

import os
import threading
import warnings
import time
from collections import deque
from collections.abc import Callable, Sequence
from concurrent.futures import Future
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from stable_baselines3.common.logger import Logger

from sb3_pride.common.journal import JournalBook, JournalEntry, merge_answers
from sb3_pride.common.priors import read_prior_preferences
from sb3_pride.common.queries import SegmentPairs
from sb3_pride.common.utils import caller_stacklevel
from sb3_pride.common.teachers import FeedbackContext, InteractiveTeacher, ScriptedTeacher, Teacher, make_teacher

if TYPE_CHECKING:
    from stable_baselines3.common.vec_env import VecEnv

    from sb3_pride.common.buffers import PreferenceReplayBuffer
    from sb3_pride.reward.ensemble import PreferenceDataset


@dataclass
class PendingFeedback:
    """
    A published feedback session: the answers the journal already had (``inputs``/``labels``), the teacher's answers
    to the new queries (``answers``: a finished future in blocking feedback) and when it was published.
    """

    session: int
    inputs: np.ndarray
    labels: np.ndarray
    n_journal_entries: int
    journal_length: int
    new_inputs: np.ndarray
    answers: "Future[np.ndarray]"
    published_step: int
    published_time: float


@dataclass
class SessionAnswers:
    """A closed feedback session: every pair asked (the journal's answers first) and its label μ (NaN: skipped)."""

    session: int
    inputs: np.ndarray
    labels: np.ndarray
    published_step: int
    published_time: float


def check_labels(answer: object, n_pairs: int) -> np.ndarray:
    """A teacher's answer as labels μ, checked: one per pair, each in [0, 1] or NaN (skipped)."""
    try:
        labels = np.asarray(answer)
    except ValueError as error:  # ragged nesting
        raise ValueError(f"teacher must return one number per segment pair, got {answer!r}: {error}") from None
    if labels.dtype.kind not in "biuf":  # None, strings, objects: np.asarray(dtype=float) would make None a NaN
        raise ValueError(f"teacher must return numbers (NaN to skip a pair), got {answer!r}")
    labels = labels.astype(np.float64).reshape(-1)
    if len(labels) != n_pairs:
        raise ValueError(f"teacher returned {len(labels)} labels for {n_pairs} segment pairs")
    finite = labels[~np.isnan(labels)]
    if np.any((finite < 0) | (finite > 1)):
        raise ValueError("teacher labels must be in [0, 1] (P[second segment preferred]) or NaN (skipped)")
    return labels


#: the named feedback schedules (``FeedbackSchedule``)
FEEDBACK_SCHEDULES = ("constant", "shrinking", "growing", "front_loaded")


class FeedbackSchedule:
    """
    How many queries each feedback session asks, before the cut to what remains of the budget: the label schedule.

    - "constant": K every session (PEBBLE);
    - "shrinking": B-Pref's ``reward_schedule=1``, K · (T − t) / T at step t of a run of T steps (``learn()``'s
      ``total_timesteps``): the budget front-loaded, its tail thinning, so that r̂ goes on learning later in the run;
    - "growing": B-Pref's ``reward_schedule=2``, K · T / (T − t + 1);
    - "front_loaded": half the budget Q (``max_feedback``, rounded up) in the first session and the other half in
      sessions of a quarter of it, rounded up (four, fewer below Q = 8), K not used: r̂ learns the first policy from
      many labels and goes on learning, on fewer, from the states later policies reach;
    - a sequence of positive ints: the sizes of the first sessions, one each (K for every session after them).

    "shrinking" and "growing" truncate their sizes to an int, as B-Pref does, and ask at least 1.

    :param schedule: one of ``FEEDBACK_SCHEDULES`` or a sequence of session sizes
    :param queries_per_session: K
    :param max_feedback: Q, the budget ("front_loaded" sizes its sessions from it)
    """

    def __init__(self, schedule: "str | Sequence[int]", queries_per_session: int, max_feedback: int):
        if isinstance(schedule, str):
            if schedule not in FEEDBACK_SCHEDULES:
                raise ValueError(
                    f"feedback_schedule must be one of {FEEDBACK_SCHEDULES} or a list of session sizes, got {schedule!r}"
                )
        elif not (
            isinstance(schedule, (list, tuple))
            and len(schedule) > 0
            and all(isinstance(n, (int, np.integer)) and not isinstance(n, bool) and n > 0 for n in schedule)
        ):
            raise ValueError(f"feedback_schedule: a list of session sizes must hold positive ints, got {schedule!r}")
        self.schedule = schedule if isinstance(schedule, str) else tuple(int(n) for n in schedule)
        self.queries_per_session, self.max_feedback = queries_per_session, max_feedback

    def size(self, session: int, step: int, total_steps: int) -> int:
        """Queries of feedback session ``session`` (1 for the first) published at env step ``step`` of ``total_steps``."""
        k, schedule = self.queries_per_session, self.schedule
        if isinstance(schedule, tuple):
            return schedule[:session][-1] if session <= len(schedule) else k  # sessions count from 1
        if schedule == "shrinking":
            return max(1, int(k * max(total_steps - step, 0) / max(total_steps, 1)))
        if schedule == "growing":
            return max(1, int(k * total_steps / max(total_steps - step + 1, 1)))
        if schedule == "front_loaded":
            first = (self.max_feedback + 1) // 2
            return first if session == 1 else max(1, -(-(self.max_feedback - first) // 4))  # ceil((Q - first) / 4)
        return k

    def plan(self, session: int, step: int, interval: int, total_steps: int, remaining: int) -> list[tuple[int, int]]:
        """
        ``(step, queries)`` of the sessions still to come in a run of ``total_steps``, the next being ``session`` at
        ``step`` and one every ``interval`` steps after it while ``remaining`` queries of the budget are left (a
        session whose episodes hold no segment yet, or whose answers are late, comes later than planned).
        """
        planned = []
        while remaining > 0 and step <= total_steps:  # a session due at the last step is asked: SB3 counts it first
            queries = min(self.size(session, step, total_steps), remaining)
            planned.append((step, queries))
            remaining, session, step = remaining - queries, session + 1, step + interval
        return planned

    def check(self, session: int, step: int, interval: int, total_steps: int, remaining: int) -> None:
        """``check_plan`` of the ``plan()`` of a run of ``total_steps``: is the budget asked within it?"""
        check_plan(self.plan(session, step, interval, total_steps, remaining), remaining, self.schedule)


def check_plan(plan: list[tuple[int, int]], remaining: int, schedule: "str | Sequence[int]") -> None:
    """
    A run whose planned sessions cannot ask the budget: refused for a schedule that spreads the budget over the run
    ("shrinking", "growing", a list of sizes), a warning for the defaults ("constant", PEBBLE's, and "front_loaded",
    PRIDE's: a short run, a smoke test, ends before its budget is asked).
    """
    asked = sum(queries for _, queries in plan)
    if asked >= remaining:
        return
    message = (
        f"the budget cannot be asked within the run: {remaining} queries remain of max_feedback, but the sessions "
        f"planned before learn()'s total_timesteps ask {asked} ({len(plan)} session{'' if len(plan) == 1 else 's'}"
        + (f", the last at step {plan[-1][0]})" if plan else ")")
        + "; lengthen the run, shorten feedback_interval"
        + ("" if schedule == "front_loaded" else " or give a larger queries_per_session or schedule")
    )
    if schedule in ("constant", "front_loaded"):
        warnings.warn(message, stacklevel=caller_stacklevel())  # the user's learn()
    else:
        raise ValueError(f"feedback_schedule={schedule!r}: {message}")


def warn_short_session(session: int, n_queries: int, n_asked: int) -> None:
    """Say so when a feedback session finds fewer pairs never asked before than it was to ask."""
    if n_asked < n_queries:
        warnings.warn(
            f"feedback session {session} asks {n_asked} of its {n_queries} queries: the recent episodes hold no other "
            f"pairs never asked before (this run's journal, prior_preferences): {n_queries - n_asked} queries of "
            "max_feedback are not asked in it (later sessions of a long enough run ask them; a larger "
            "query_kwargs max_query_episodes draws from more episodes)",
            stacklevel=caller_stacklevel(),
        )


class FeedbackLoop:
    """
    The teacher's side of PEBBLE's feedback sessions. ``publish()`` gives a session's queries to the teacher: answers
    of that session already in the journal (given before a crash) are taken from it, the teacher is asked only for
    the rest, either at once or in a thread of its own (asynchronous feedback: training goes on meanwhile).
    ``take()`` waits for the answers if they are not all in, checks and journals them (an ``InteractiveTeacher``
    journals each answer itself, as it is given, through its ``FeedbackContext``) and returns them.

    :param journal: the run's preference journal
    """

    def __init__(self, journal: JournalBook):
        self.journal = journal
        #: (name, teacher) of a teacher given by name (a scripted one is saved with its random state)
        self.named_teacher: tuple[str, Teacher | InteractiveTeacher] | None = None
        #: the teacher object (``resolve()``)
        self.teacher: Teacher | InteractiveTeacher | None = None
        #: the published session whose answers are awaited (None: no session is open); never saved
        self.pending: PendingFeedback | None = None
        self._records: deque[tuple[str, float]] = deque()  # what the teacher asked to log (thread-safe appends)

    def __getstate__(self) -> dict:
        # a session in progress is not saved (the journal keeps its answers); of the teachers given by name, only
        # B-Pref's scripted ones are, with their random state: any other is made again from its name
        named = self.named_teacher if self.named_teacher and isinstance(self.named_teacher[1], ScriptedTeacher) else None
        return {**self.__dict__, "named_teacher": named, "teacher": None, "pending": None, "_records": deque()}

    def resolve(self, teacher: str | Teacher | InteractiveTeacher, seed: int | None) -> Teacher | InteractiveTeacher:
        """The teacher object: a registered name is made into one once (``make_teacher``), with the run's seed."""
        if isinstance(teacher, str):
            if self.named_teacher is None or self.named_teacher[0] != teacher:
                self.named_teacher = (teacher, make_teacher(teacher, seed=seed))
            self.teacher = self.named_teacher[1]
        else:
            self.teacher = make_teacher(teacher)  # checked: a callable or an InteractiveTeacher
        return self.teacher

    def attach(
        self,
        teacher: str | Teacher | InteractiveTeacher,
        seed: int | None,
        env: "VecEnv | None",
        buffer: "PreferenceReplayBuffer | None",
        progress: tuple[int, int],
        history: list[dict],
    ) -> None:
        """
        Resolve the teacher; an ``InteractiveTeacher`` is attached to the env and the replay buffer (so that an env it
        cannot show fails now, not at the first feedback session) and shown ``progress`` (asked, budget) and the
        reward learner's ``history`` so far; any other teacher records nothing beside the transitions.
        """
        resolved = self.resolve(teacher, seed)
        if isinstance(resolved, InteractiveTeacher):
            if env is not None and buffer is not None:
                resolved.attach(env, buffer)
                resolved.show_progress(*progress)
                if history:  # a loaded model's page shows what r̂ learned so far
                    self.show_reward_history(history)
        elif buffer is not None:  # a resumed buffer may say otherwise
            buffer.record_render_states = False

    def show_reward_history(self, history: list[dict]) -> None:
        """Show an ``InteractiveTeacher`` the reward learner's ``history``; any other teacher: nothing."""
        if isinstance(self.teacher, InteractiveTeacher):
            self.teacher.show_reward_history(history)

    def open_journal(
        self,
        path: str | None,
        header: dict,
        included: int,
        preferences: "PreferenceDataset",
        prior_paths: "Sequence[str | os.PathLike] | None",
    ) -> None:
        """
        The run's journal (``JournalBook``): what its pairs are about (``header``), how many of its entries the
        run includes, and, for a new run (``preferences`` empty) given ``prior_paths``, the earlier runs' answers it
        starts from, added to ``preferences`` and named in the header (``read_prior_preferences``); a loaded run keeps
        the header and priors it was saved with. A journal that does not fit the run fails now, not at a session.
        """
        header, prior_ids = self.journal.header or header, self.journal.prior_ids
        entry_shape = (2, *preferences.inputs.shape[2:])
        if prior_paths and len(preferences) == 0 and "prior_preferences" not in header:
            priors = read_prior_preferences(prior_paths, header, entry_shape, own_journal=path)
            preferences.add(priors.inputs, priors.labels)
            header, prior_ids = {**header, "prior_preferences": priors.sources}, set(priors.ids)
        self.journal = JournalBook(path, entry_shape, included, header, prior_ids)
        self.journal.history()

    @property
    def ready(self) -> bool:
        """Whether the teacher has answered every query of the open session (``take()`` won't wait)."""
        return self.pending is not None and self.pending.answers.done()

    def publish(
        self,
        context: FeedbackContext,
        n_queries: int,
        choose: Callable[[int, set[str]], SegmentPairs | None],
        step: int,
        asynchronous: bool,
    ) -> bool:
        """
        Open feedback session ``context.session`` of ``n_queries`` queries.

        :param context: what the teacher is told (its ``record``, ``retract`` and ``log`` are this loop's)
        :param choose: ``choose(n, asked_before)``: n new pairs, none of whose ``query_id`` is in ``asked_before``
            (None when no segment fits in the stored episodes yet)
        :param step: the env step it is published at
        :param asynchronous: True: the teacher answers in a thread of its own and this returns at once
        :return: False when no segment fits in the stored episodes yet (nothing was asked)
        """
        if self.pending is not None:
            raise RuntimeError(f"feedback session {self.pending.session} is still open: take_answers() before publishing more")
        assert self.teacher is not None, "resolve() the teacher first"
        # several annotators' answers to one query are one answer: their mean μ (journal.merge_answers)
        raw = self.journal.new_answers(context.session)
        journal_length = len(self.journal.history())  # before the teacher journals this session's new answers
        journaled = merge_answers(raw)[:n_queries]
        kept = {entry.id for entry in journaled}
        candidates = choose(n_queries - len(journaled), self.journal.asked_ids())
        if candidates is None:
            return False
        warn_short_session(context.session, n_queries, len(journaled) + len(candidates))
        answers: Future[np.ndarray] = Future()
        if len(candidates) == 0:
            answers.set_result(np.zeros(0))
        elif asynchronous:
            # a daemon thread: a person who never answers does not keep the process alive after an interrupt
            threading.Thread(target=self._answer, args=(candidates, context, answers), name="teacher", daemon=True).start()
        else:
            answers.set_result(self.ask(candidates, context))  # a teacher's error is raised here: nothing recorded
        self.pending = PendingFeedback(
            session=context.session,
            inputs=np.stack([entry.inputs for entry in journaled]) if journaled else candidates.inputs[:0],
            labels=np.array([entry.label for entry in journaled], dtype=np.float64),
            n_journal_entries=sum(entry.id in kept for entry in raw),
            journal_length=journal_length,
            new_inputs=candidates.inputs,
            answers=answers,
            published_step=step,
            published_time=time.monotonic(),
        )
        return True

    def context(self, session: int, asked_before: int, budget: int) -> FeedbackContext:
        """What an interactive teacher is told: answers go straight to the journal, log records to this loop."""
        return FeedbackContext(
            session=session,
            asked_before=asked_before,
            budget=budget,
            record=self.journal.record,
            retract=self.journal.retract,
            log=lambda key, value: self._records.append((key, value)),  # logged later, by the model's thread
        )

    def ask(self, pairs: SegmentPairs, context: FeedbackContext) -> np.ndarray:
        """The teacher's labels μ for ``pairs``, checked (``check_labels``)."""
        teacher = self.teacher
        assert teacher is not None, "resolve() the teacher first"
        answer = teacher.ask(pairs, context) if isinstance(teacher, InteractiveTeacher) else teacher(pairs)
        return check_labels(answer, len(pairs))

    def _answer(self, pairs: SegmentPairs, context: FeedbackContext, answers: "Future[np.ndarray]") -> None:
        """The teacher's thread (asynchronous feedback): its labels, or its error, go into ``answers``."""
        answers.set_running_or_notify_cancel()
        try:
            answers.set_result(self.ask(pairs, context))
        except BaseException as error:  # raised by take() in the model's thread
            answers.set_exception(error)

    def take(self, logger: Logger) -> SessionAnswers:
        """
        Close the open session, waiting for its answers: journal them (a scripted teacher's; an interactive teacher
        journaled each as it was given) and return them. A teacher's error is raised here, with nothing of the session
        recorded; what the teacher asked to log goes to ``logger``.
        """
        pending = self.pending
        if pending is None:
            raise RuntimeError("no feedback session is open: publish_queries() first")
        try:
            new_labels = pending.answers.result()
        except BaseException:
            if pending.answers.done():  # the teacher failed: the session is over, nothing of it recorded
                self.pending = None
            raise  # an interrupt while waiting leaves the session open: the teacher may still answer
        finally:
            while self._records:
                logger.record(*self._records.popleft())
        self.pending = None
        interactive = isinstance(self.teacher, InteractiveTeacher)
        # the journal is written before the answers are used: a crash from here on loses none of them
        if not interactive:
            pairs = zip(pending.new_inputs, new_labels, strict=True)
            self.journal.record([JournalEntry(pending.session, pair, label) for pair, label in pairs])
        if interactive and self.journal.path is not None:
            # every answer the teacher journaled during the session (several per query from several annotators)
            self.journal.included += pending.n_journal_entries + len(self.journal.history()) - pending.journal_length
        else:
            self.journal.included += pending.n_journal_entries + len(new_labels)
        inputs = np.concatenate([pending.inputs, pending.new_inputs])
        labels = np.concatenate([pending.labels, new_labels])
        return SessionAnswers(pending.session, inputs, labels, pending.published_step, pending.published_time)
