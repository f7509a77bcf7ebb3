"""
How far a ``WebTeacher``'s annotators can be trusted: known-answer questions (pairs whose answer is known, shown again
as extra questions that only measure the annotator, each with a copy of the pair's clips of its own) and the agreement
report.
"""

import json
import math
import random
import threading
import time
import uuid
from collections import Counter
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from sb3_pride.common.checkpoints import atomic_write_path
from sb3_pride.common.queries import SegmentPairs
from sb3_pride.human.questions import Answer, KnownPair, Question, Session
from sb3_pride.human.settings import ANONYMOUS

if TYPE_CHECKING:
    from sb3_pride.human.clips import Clips

#: known-answer pairs kept to draw from (the oldest are dropped beyond it)
KNOWN_POOL_SIZE = 1000
#: what the page's team table leaves out during a feedback session (it would change only on known-answer questions)
HIDDEN_DURING_SESSION = ("known_answers", "known_answer_agreement", "compared_answers", "pairwise_agreement", "flagged")
#: a true-reward known answer needs a return scale above this (``return_scale``, or the spread of the pairs' returns)
MIN_RETURN_SCALE = 1e-8
#: an annotator is flagged when fewer than this share of their known-answer questions agree with the known answer...
FLAG_BELOW = 0.7
#: ...over at least this many of them
FLAG_MIN_KNOWN = 8
#: what the logger records of each annotator after every feedback session (``annotators/<name>/<key>``)
LOGGED = ("answers", "known_answers", "known_answer_agreement", "compared_answers", "pairwise_agreement")
#: a copy of a known-answer clip: the share of its 16 x 16 blocks shifted by one level, in each frame
DITHERED_BLOCKS = 0.25
#: known pairs whose clips are copied ahead of need (one copy each; another is made as one is shown): what copying
#: costs is bounded by the questions shown, not by the pairs known
COPIES_AHEAD = 32


def recode_clip(source: Path, target: Path, rng: np.random.Generator) -> None:
    """
    Write at ``target`` the clip ``source`` encoded anew, each frame with a dither of its own: a random quarter of its
    16 x 16 blocks one level lighter or darker (``DITHERED_BLOCKS``). It shows what ``source`` shows, but its bytes and
    size are its own: no one who kept ``source``, or another copy, finds it among what they were served.
    """
    import av

    from sb3_pride.human import render

    with av.open(str(source)) as container:
        stream = container.streams.video[0]
        fps = float(stream.average_rate or 10)
        frames = np.stack([frame.to_ndarray(format="rgb24") for frame in container.decode(stream)]).astype(np.int16)
    k, height, width = frames.shape[:3]
    blocks = rng.choice(
        [-1, 0, 1],
        size=(k, -(-height // 16), -(-width // 16)),
        p=[DITHERED_BLOCKS / 2, 1 - DITHERED_BLOCKS, DITHERED_BLOCKS / 2],
    )
    shift = blocks.repeat(16, axis=1).repeat(16, axis=2)[:, :height, :width, None]
    render.encode_mp4(np.clip(frames + shift, 0, 255).astype(np.uint8), fps, target)


class Quality:
    """
    The known-answer pairs of a teacher and every answer given to it, for ``agreement()``. Thread-safe: it has a lock
    of its own, taken after the ``AnswerStore``'s when the store calls it (it never calls the store).

    :param annotators: the annotators' names (None: one person, ``"anonymous"``)
    :param answers_per_query: how many different annotators answer each query
    :param known_answer_rate: the share of an annotator's questions that are known-answer questions, in [0, 1)
    :param known_answer_margin: a pair's answer is known from the true reward when its two segment returns differ by
        at least this many ``return_scale`` (None: only majorities make known answers)
    :param report_path: the JSON file ``write_report()`` writes (None: none)
    :param seed: the seed of the draws that mix the known-answer questions in
    """

    def __init__(
        self,
        annotators: list[str] | None = None,
        answers_per_query: int = 1,
        known_answer_rate: float = 0.0,
        known_answer_margin: float | None = 0.5,
        report_path: Path | None = None,
        seed: int | None = None,
    ):
        self.annotators, self.answers_per_query = annotators, answers_per_query
        self.known_answer_rate, self.known_answer_margin = known_answer_rate, known_answer_margin
        self.report_path = report_path
        #: known-answer pairs, oldest first
        self.known: list[KnownPair] = []
        #: every answer given to the teacher, oldest first (undone answers to the model's queries removed)
        self.answers: list[Answer] = []
        #: pair id -> the annotators who answered it
        self.seen: dict[str, set[str]] = {}
        #: where known-answer questions' copies of their pairs' clips are made (``recode_clip``, in its render thread);
        #: None: a known-answer question shows its pair's own files
        self.clips: Clips | None = None
        self._rng = random.Random(seed)
        self._copies_rng = np.random.default_rng()  # dithers: fresh entropy, never the seed's (no copy is another's)
        self._copying: set[str] = set()  # pairs whose copy is being made
        self._uncopyable: set[str] = set()  # pairs whose clips could not be copied: never shown
        self._stock_rng = random.Random(seed)  # which pairs are copied ahead (the draws' own sequence left as it was)
        self._lock = threading.RLock()
        self._report_lock = threading.Lock()
        self._stats: dict[str, dict[str, Any]] | None = None  # agreement(), until the next answer
        self._flagged: set[str] = set()  # annotators already named on the console

    def known_from_reward(self, pairs: SegmentPairs) -> list[float | None]:
        """
        Per pair, its answer when the true reward makes it clear (the higher return), else None. The scale of the
        margin is ``return_scale``, but at least the spread (std) of the pairs' segment returns: a ``return_scale`` of
        about 0 would otherwise make any difference, however small, clear. None at all when both are about 0.
        """
        if self.known_answer_rate == 0 or self.known_answer_margin is None or pairs.true_rewards is None:
            return [None] * len(pairs)
        returns = np.asarray(pairs.true_rewards, dtype=np.float64).sum(axis=-1)
        spread = float(np.std(returns)) if np.isfinite(returns).all() else 0.0
        scale = max(abs(float(pairs.return_scale)), spread)
        if not scale > MIN_RETURN_SCALE:
            return [None] * len(pairs)
        difference = returns[:, 1] - returns[:, 0]
        clear = np.abs(difference) >= self.known_answer_margin * scale
        clear &= (difference != 0) & np.isfinite(difference)
        return [float(d > 0) if is_clear else None for d, is_clear in zip(difference, clear, strict=True)]

    def add_known(self, known: KnownPair) -> None:
        """
        Keep a known-answer pair (once; the oldest are dropped beyond ``KNOWN_POOL_SIZE``); with ``clips``, copies of
        clips are made ahead for up to ``COPIES_AHEAD`` pairs.
        """
        with self._lock:
            if any(entry.pair == known.pair for entry in self.known):
                return
            self.known.append(known)
            for dropped in self.known[:-KNOWN_POOL_SIZE]:
                self._remove_copies(dropped.copies)
                dropped.copies.clear()
            del self.known[:-KNOWN_POOL_SIZE]
            self._copy_ahead()

    def _copy_ahead(self) -> None:
        """Have copies made (in the clips' render thread, after the clips being rendered) until ``COPIES_AHEAD`` pairs
        have one ready or coming, for pairs drawn at random among those without."""
        if self.clips is None:
            return
        stocked = {known.pair for known in self.known if known.copies} | self._copying
        bare = [known for known in self.known if known.pair not in stocked and known.pair not in self._uncopyable]
        for known in self._stock_rng.sample(bare, min(len(bare), max(COPIES_AHEAD - len(stocked), 0))):
            self._copying.add(known.pair)
            self.clips.thread.submit(self._make_copy, known)

    def _make_copy(self, known: KnownPair) -> None:
        assert self.clips is not None
        try:
            self._copy_clips(known)
        finally:
            with self._lock:
                self._copying.discard(known.pair)

    def _copy_clips(self, known: KnownPair) -> None:
        assert self.clips is not None
        if self.clips.renderer is None:  # closed: its folder may be gone
            return
        folder, copy = self.clips.folder(), uuid.uuid4().hex[:12]
        try:
            for side, source in zip(("left", "right"), known.files, strict=True):
                recode_clip(folder / source, folder / f"{copy}-{side}.mp4", self._copies_rng)
        except Exception as error:  # the pair is not shown; the session goes on
            self._remove_copies([copy])
            with self._lock:
                self._uncopyable.add(known.pair)
            print(
                f"WebTeacher: warning: a known-answer pair's clips could not be copied, it is not shown: {error}", flush=True
            )
            return
        with self._lock:
            if any(entry is known for entry in self.known):
                known.copies.append(copy)
            else:  # dropped meanwhile
                self._remove_copies([copy])

    def _remove_copies(self, copies: list[str]) -> None:
        if self.clips is not None:
            for copy in copies:
                for side in ("left", "right"):
                    (self.clips.folder() / f"{copy}-{side}.mp4").unlink(missing_ok=True)

    def learn_majority(self, query: Question) -> None:
        """A query on which at least two annotators, a majority of those who did not skip, chose one side becomes known."""
        if self.known_answer_rate == 0:
            return
        given = [value for value in query.answers.values() if not math.isnan(value)]
        if len(given) < 2:
            return
        label, count = Counter(given).most_common(1)[0]
        if count >= 2 and 2 * count > len(given) and label in (0.0, 1.0):
            voters = frozenset(name for name, value in query.answers.items() if value == label)
            self.add_known(KnownPair(query.pair, query.inputs, query.files, label, "majority", voters))

    def draw_known(self, session: Session, name: str) -> Question | None:
        """In place of ``name``'s next question, at ``known_answer_rate``: a known-answer question, or None."""
        if self.known_answer_rate > 0 and self._rng.random() < self.known_answer_rate:
            return self.known_question(session, name)
        return None

    def _fits(self, session: Session, name: str, known: KnownPair) -> str | None:
        """
        Whether ``known`` may be shown to ``name`` in ``session``: ``"fresh"`` (a pair they have not answered), ``"again"``
        (one person alone, a true-reward pair of an earlier session) or None (shown to them in this session already, a
        majority they were part of, or one of this session's queries that may still be handed to them).
        """
        if known.pair in session.known_shown.get(name, ()) or name in known.voters:
            return None
        live = session.by_pair.get(known.pair)
        if live is not None and (name in live.answers or name in live.holders or live.taken < self.answers_per_query):
            return None
        if name not in self.seen.get(known.pair, ()):
            return "fresh"
        return "again" if not self.annotators and known.source == "true reward" and live is None else None

    def known_question(self, session: Session, name: str) -> Question | None:
        """
        A known-answer question for ``name`` in ``session``: a known pair they have not answered, never one of this
        session's queries that may still be handed to them, never a majority they were part of. Only one person alone
        (no ``annotators``) is shown, when no other is left, a true-reward pair they answered in an earlier session.
        Its id is its own, its clips' addresses have the shape of every other's, and (with ``clips``) its clips are a
        copy of the pair's made for it alone (``recode_clip``; only pairs with a copy ready are drawn,
        ``COPIES_AHEAD``): nothing on the page, nor in the bytes of its clips, tells it apart.
        """
        with self._lock:
            fits: dict[str, list[KnownPair]] = {"fresh": [], "again": []}
            for known in self.known:
                if (self.clips is None or known.copies) and (kind := self._fits(session, name, known)) is not None:
                    fits[kind].append(known)
            if not (fits["fresh"] or fits["again"]):
                return None
            known = self._rng.choice(fits["fresh"] or fits["again"])
            session.known_shown.setdefault(name, set()).add(known.pair)
            if self.clips is None:
                question = Question(uuid.uuid4().hex[:12], known.inputs, known.files, known.answer, True, pair=known.pair)
            else:  # its copy's files are named after it, as a query's are
                question = Question(known.copies.pop(0), known.inputs, known=known.answer, ready=True, pair=known.pair)
                self._copy_ahead()  # for the questions to come
            session.known[question.id] = question
            return question

    def may_take(self, session: Session, name: str, question: Question) -> bool:
        """Whether the known-answer question ``question``, handed to another annotator, may go to ``name`` instead."""
        with self._lock:
            known = next((entry for entry in self.known if entry.pair == question.pair), None)
            return known is not None and self._fits(session, name, known) is not None

    def count(self, answer: Answer) -> None:
        """Take ``answer`` into the agreement."""
        with self._lock:
            self.answers.append(answer)
            self.seen.setdefault(answer.pair, set()).add(answer.annotator)
            self._stats = None

    def take_back(self, answer: Answer) -> None:
        """Leave an undone answer to the model's query out of the agreement (a known-answer question keeps its score)."""
        with self._lock:
            self.answers.remove(answer)
            if not any(other.annotator == answer.annotator and other.pair == answer.pair for other in self.answers):
                self.seen.get(answer.pair, set()).discard(answer.annotator)  # no answer of theirs to this pair is left
            self._stats = None

    def agreement(self) -> dict[str, dict[str, Any]]:
        """
        Per annotator (``"anonymous"`` without ``annotators``), over every answer given to this teacher:

        - ``answers``, ``skips``: questions answered (known-answer ones included), and how many of them were skips;
        - ``known_answers``, ``known_answer_agreement``: known-answer questions answered (not skipped), and the share
          whose answer was the known one (None before the first);
        - ``compared_answers``, ``pairwise_agreement``: (pair, other annotator) comparisons on the pairs both answered
          (not skipped), and the share on which they gave the same answer (None before the first);
        - ``flagged``: whether ``known_answer_agreement`` is below ``FLAG_BELOW`` over at least ``FLAG_MIN_KNOWN``
          known answers.
        """
        with self._lock:
            if self._stats is None:
                self._stats = self._count()
            return {name: dict(stats) for name, stats in self._stats.items()}

    def _count(self) -> dict[str, dict[str, Any]]:
        names = list(self.annotators or [ANONYMOUS])
        counts: dict[str, Counter[str]] = {name: Counter() for name in names}
        latest: dict[str, dict[str, float]] = {}  # pair -> annotator -> their latest answer that is not a skip
        for given in self.answers:
            count = counts[given.annotator]
            count["answers"] += 1
            if math.isnan(given.label):
                count["skips"] += 1
                continue
            if given.known is not None:
                count["known"] += 1
                count["known_right"] += given.label == given.known
            latest.setdefault(given.pair, {})[given.annotator] = given.label
        for labels in latest.values():
            for name, label in labels.items():
                for other, other_label in labels.items():
                    if other != name:
                        counts[name]["compared"] += 1
                        counts[name]["agreed"] += label == other_label
        stats = {}
        for name, count in counts.items():
            known_agreement = count["known_right"] / count["known"] if count["known"] else None
            stats[name] = {
                "answers": count["answers"],
                "skips": count["skips"],
                "known_answers": count["known"],
                "known_answer_agreement": known_agreement,
                "compared_answers": count["compared"],
                "pairwise_agreement": count["agreed"] / count["compared"] if count["compared"] else None,
                "flagged": known_agreement is not None and count["known"] >= FLAG_MIN_KNOWN and known_agreement < FLAG_BELOW,
            }
        return stats

    def session_over(self, session: Session) -> None:
        """
        After a feedback session: majorities become known answers; the agreement is logged, reported and checked; the
        copies of clips its known-answer questions showed are removed.
        """
        with self._lock:
            for query in session.queries:
                self.learn_majority(query)
            report = self.agreement()
            if self.clips is not None:
                self._remove_copies(list(session.known))
        for name, stats in report.items():
            for key in LOGGED:
                if stats[key] is not None:
                    session.context.log(f"annotators/{name}/{key}", float(stats[key]))
            if stats["flagged"] and name not in self._flagged:
                self._flagged.add(name)
                print(
                    f"WebTeacher: {name} matched only {stats['known_answer_agreement']:.0%} of {stats['known_answers']} "
                    "known answers: check their labels",
                    flush=True,
                )
        self.write_report(report)

    def write_report(self, report: dict[str, dict[str, Any]] | None = None) -> None:
        """``agreement()`` to ``report_path``, written whole (a reader never sees half of it); a failure is warned about."""
        if self.report_path is None:
            return
        with self._lock:
            payload = {"time": time.time(), "known_answer_pairs": len(self.known), "annotators": report or self.agreement()}
        try:
            with self._report_lock, atomic_write_path(self.report_path) as temporary:
                temporary.write_text(json.dumps(payload, indent=2) + "\n")
        except OSError as error:  # the session's answers are in: a report that cannot be written fails nothing else
            print(f"WebTeacher: warning: the agreement report could not be written to {self.report_path}: {error}", flush=True)
