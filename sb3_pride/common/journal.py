"""
Crash safety for labels: an append-only journal of the teacher's answers.

A preference label costs a person's time; a run may be killed at any moment. ``PreferenceJournal`` appends every
answer (the pair's reward-model inputs and μ, or a skip) to a JSON-lines file and flushes it to disk before the
answer is used, so a run resumed from an older checkpoint gets it back instead of asking again.
Earlier runs' journals are read for a new run to start from by ``sb3_pride.common.priors``.
"""

import base64
import binascii
import hashlib
import json
import os
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np


def query_id(inputs: np.ndarray) -> str:
    """A query's identity: the SHA-1 of its (2, k, input_dim) float32 reward-model inputs."""
    return hashlib.sha1(np.ascontiguousarray(inputs, dtype=np.float32).tobytes()).hexdigest()


@dataclass
class JournalEntry:
    """
    One answered query: the feedback session (1-based) it was asked in, its inputs and μ (NaN: skipped), and, when
    the teacher says so, who answered (an annotator's name) and when (Unix time).
    """

    session: int
    inputs: np.ndarray
    label: float
    annotator: str | None = None
    time: float | None = None

    @property
    def id(self) -> str:
        return query_id(self.inputs)


def undone_index(
    entries: list[JournalEntry], session: int, entry_id: str | None = None, annotator: str | None = None
) -> int | None:
    """
    The index of the entry an undo of ``session`` takes back: the session's latest answer to ``entry_id`` by
    ``annotator`` where they are given, else the last entry if it is of ``session``; None when there is none.
    """
    if entry_id is None and annotator is None:
        return len(entries) - 1 if entries and entries[-1].session == session else None
    for index in range(len(entries) - 1, -1, -1):
        entry = entries[index]
        if (
            entry.session == session
            and (entry_id is None or entry.id == entry_id)
            and (annotator is None or entry.annotator == annotator)
        ):
            return index
    return None


def merge_answers(entries: list[JournalEntry]) -> list[JournalEntry]:
    """
    One entry per query, in the order queries were first answered: several annotators' answers to one query become
    their mean μ over those that are not skips (NaN when all are).
    """
    by_id: dict[str, list[JournalEntry]] = {}
    for entry in entries:
        by_id.setdefault(entry.id, []).append(entry)
    merged = []
    for answers in by_id.values():
        if len(answers) == 1:
            merged.append(answers[0])
            continue
        labels = np.array([answer.label for answer in answers], dtype=np.float64)
        label = float(np.mean(labels[~np.isnan(labels)])) if (~np.isnan(labels)).any() else float("nan")
        merged.append(JournalEntry(answers[0].session, answers[0].inputs, label))
    return merged


def journal_entry(record: object, where: str) -> JournalEntry:
    """One answer line of a journal, read back; anything else is refused, naming ``where`` it is."""
    try:
        if not isinstance(record, dict) or "journal" in record:
            raise ValueError("not an answer")
        missing = [key for key in ("session", "label", "shape", "inputs") if key not in record]
        if missing:
            raise ValueError(f"no {', '.join(missing)}")
        inputs = np.frombuffer(base64.b64decode(record["inputs"], validate=True), dtype=np.float32)
        inputs = inputs.reshape(record["shape"]).copy()
        label = float("nan") if record["label"] is None else float(record["label"])
        return JournalEntry(int(record["session"]), inputs, label, record.get("annotator"), record.get("time"))
    except (TypeError, ValueError, binascii.Error) as error:
        raise ValueError(
            f"{where} is not a journal entry ({error}): each answer line holds session, label, shape and inputs"
        ) from None


class PreferenceJournal:
    """
    An append-only JSON-lines file of the teacher's answers. Its first line says what the answers are about:
    ``{"journal": {"env_id": ..., "observation_shape": [...], "action_shape": [...], "segment_length": k,
    "prior_preferences": [...]}}`` (the earlier journals the run started from, with their SHA-1 and labels); then one
    line per query: ``{"session": n, "id": sha1, "label": μ or null, "shape": [2, k, d], "inputs": base64 float32}``
    (with ``"annotator"`` and ``"time"`` when the teacher gives them), and one line ``{"session": n, "undo": true}`` for
    each answer taken back (a person's undo), which removes the session's last answer, or the session's last answer
    to query ``"id"`` (by ``"annotator"``) when the line names them.

    :param path: the file (created with its folder on the first answer)
    :param name: what its errors call it: the setting or argument the user gave it by
    """

    def __init__(self, path: str | os.PathLike, name: str = "preference_journal"):
        self.path, self.name = Path(path), name

    def header(self) -> dict | None:
        """What the answers are about (the first line's ``"journal"``), None when the file has no such line."""
        if not self.path.exists():
            return None
        with open(self.path) as file:
            first = file.readline()
        try:
            record = json.loads(first)
        except json.JSONDecodeError:
            return None
        return record.get("journal") if isinstance(record, dict) and isinstance(record.get("journal"), dict) else None

    def read(self, strict: bool = False) -> list[JournalEntry]:
        """
        Every entry, oldest first, skips and undos applied as the run applied them.

        :param strict: False: a last line cut by a crash in the middle of a write is ignored (the run's own journal,
            resumed); True: it is refused (an earlier run's journal, read whole or not at all)
        """
        if not self.path.exists():
            return []
        entries: list[JournalEntry] = []
        lines = self.path.read_text().split("\n")
        for number, line in enumerate(lines, start=1):
            if not line.strip():
                continue
            where = f"{self.name} {self.path}: line {number}"
            try:
                record = json.loads(line)
            except json.JSONDecodeError:
                if number == len(lines) and not strict:  # the torn last line of a killed writer (no newline yet)
                    break
                torn = " (a last line cut in the middle of a write)" if number == len(lines) else ""
                raise ValueError(f"{where} is not JSON{torn}") from None
            if number == 1 and isinstance(record, dict) and "journal" in record:
                continue  # the header
            if isinstance(record, dict) and record.get("undo"):
                session = record.get("session")
                undone = undone_index(entries, session, record.get("id"), record.get("annotator")) if session else None
                if undone is None:
                    raise ValueError(f"{where} undoes no answer of its session")
                del entries[undone]
                continue
            entries.append(journal_entry(record, where))
        return entries

    def _cut_torn_line(self) -> None:
        """Cut off a last line that a writer killed mid-line left without its newline."""
        if not self.path.exists() or self.path.stat().st_size == 0:
            return
        with open(self.path, "r+b") as file:
            file.seek(-1, os.SEEK_END)
            if file.read(1) != b"\n":
                file.seek(0)
                file.truncate(file.read().rfind(b"\n") + 1)

    def append(self, entries: list[JournalEntry], header: dict | None = None) -> None:
        """
        Append ``entries`` and flush them to disk (fsync) before returning; ``header`` (what the answers are about)
        goes first, in the same write, when the file holds nothing yet: a write cut short leaves neither.
        """
        records: list[dict] = []
        for entry in entries:
            inputs = np.ascontiguousarray(entry.inputs, dtype=np.float32)
            records.append(
                {
                    "session": entry.session,
                    "id": query_id(inputs),
                    "label": None if np.isnan(entry.label) else float(entry.label),
                    "shape": list(inputs.shape),
                    "inputs": base64.b64encode(inputs.tobytes()).decode("ascii"),
                    **({} if entry.annotator is None else {"annotator": entry.annotator}),
                    **({} if entry.time is None else {"time": entry.time}),
                }
            )
        self._write(records, header)

    def append_undo(self, session: int, entry_id: str | None = None, annotator: str | None = None) -> None:
        """
        Record that an answer of ``session`` was taken back (flushed to disk before returning): its latest answer to
        query ``entry_id`` by ``annotator`` where they are given, else its last answer.
        """
        record: dict = {"session": session, "undo": True}
        if entry_id is not None:
            record["id"] = entry_id
        if annotator is not None:
            record["annotator"] = annotator
        self._write([record])

    def _write(self, records: list[dict], header: dict | None = None) -> None:
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._cut_torn_line()  # a header cut short by a crash goes too: the header is written again below
        if header is not None and (not self.path.exists() or self.path.stat().st_size == 0):
            records = [{"journal": header}, *records]
        with open(self.path, "a") as file:
            file.writelines(json.dumps(record) + "\n" for record in records)
            file.flush()
            os.fsync(file.fileno())


def find_journal(journal: str, model_path: str | os.PathLike) -> str:
    """
    Where the preference journal of a model saved at ``model_path`` is now, found from the model's own folder first:
    ``journal`` as the run gave it when it is absolute and there; for a relative path, the first file it names from
    the model file's folder or one of that folder's parents (the folder the run was made in); else a file of its name
    beside the model file (a run's folder moved whole); else ``journal`` from the working folder. ``journal`` itself
    when none is found. Another run's journal of the same name in the working folder is never taken before the
    model's own.
    """
    if os.path.isabs(journal) and os.path.isfile(journal):
        return journal
    folder = Path(os.path.abspath(model_path)).parent
    bases = [] if os.path.isabs(journal) else [folder, *folder.parents]
    for candidate in [*(base / journal for base in bases), folder / Path(journal).name]:
        if candidate.is_file():
            return str(candidate)
    return journal


class JournalBook:
    """
    A run's side of its preference journal: the journal's history (read once, then kept in step with what this run
    appends), and how many of its entries the run's preferences include (``included``, saved with the model), so that
    a run resumed after a crash takes back the answers it lacks instead of asking again.

    :param path: the journal (None: no journal; every method then does nothing)
    :param entry_shape: (2, segment_length, obs_dim + action_dim), the shape of this run's pairs
    :param included: entries of the journal the run's preferences already include
    :param header: what the run's answers are about (``PreferenceJournal``), written first in a new journal
    :param prior_ids: the queries of the earlier runs' answers the run started from: never asked again
    """

    def __init__(
        self,
        path: str | os.PathLike | None,
        entry_shape: tuple[int, ...],
        included: int = 0,
        header: dict | None = None,
        prior_ids: Iterable[str] = (),
    ):
        self.path = None if path is None else os.fspath(path)
        self.entry_shape = tuple(entry_shape)
        self.included = included
        self.header = header
        self.prior_ids = set(prior_ids)
        self._history: list[JournalEntry] | None = None

    def __getstate__(self) -> dict:
        return {**self.__dict__, "_history": None}  # read again from the file

    def __setstate__(self, state: dict) -> None:
        self.__dict__.update({"header": None, "prior_ids": set(), **state})  # a book saved before it had them

    def history(self) -> list[JournalEntry]:
        """Every entry of the journal; one that does not fit this run (other pairs, fewer entries) is refused."""
        if self.path is None:
            return []
        if self._history is None:
            if self.included > 0 and not os.path.exists(self.path):
                raise ValueError(
                    f"preference_journal {self.path} is missing: this model includes {self.included} answers of it. "
                    "Give load() where it is now (preference_journal=...), or preference_journal=None to go on without one"
                )
            entries = PreferenceJournal(self.path).read()
            for entry in entries:
                if entry.inputs.shape != self.entry_shape:
                    raise ValueError(
                        f"preference_journal {self.path} holds pairs of shape {entry.inputs.shape}, this model's are "
                        f"{self.entry_shape} (segment_length, obs_dim + action_dim): not this run's journal"
                    )
            if len(entries) < self.included:
                raise ValueError(
                    f"preference_journal {self.path} holds {len(entries)} answers, but this model already includes "
                    f"{self.included}: not this run's journal"
                )
            self._history = entries
        return self._history

    def asked_ids(self) -> set[str]:
        """The queries never to ask again: every one the journal holds, and the earlier runs' answers given as priors."""
        return {entry.id for entry in self.history()} | self.prior_ids

    def new_answers(self, session: int) -> list[JournalEntry]:
        """The journal's answers of feedback session ``session`` that the run does not include yet."""
        answers = []
        for entry in self.history()[self.included :]:
            if entry.session != session:
                break
            answers.append(entry)
        return answers

    def record(self, entries: list[JournalEntry]) -> None:
        """Append answers to the journal, flushed to disk before returning (``FeedbackContext.record``)."""
        if self.path is None or not entries:
            return
        PreferenceJournal(self.path).append(entries, self.header)
        self.history().extend(entries)

    def retract(self, session: int, entry_id: str | None = None, annotator: str | None = None) -> None:
        """
        Record that an answer of ``session`` was taken back (a person's undo, ``FeedbackContext.retract``): the latest
        answer to query ``entry_id`` by ``annotator`` where they are given, else the session's last answer.
        """
        if self.path is None:
            return
        history = self.history()
        undone = undone_index(history, session, entry_id, annotator)
        if undone is None or undone < self.included:  # an undo line that undoes nothing would break the journal
            raise ValueError(f"no answer of feedback session {session} to take back (query {entry_id}, annotator {annotator})")
        PreferenceJournal(self.path).append_undo(session, entry_id, annotator)
        del history[undone]


def journal_header(env_id: str | None, observation_shape: Any, action_shape: Any, segment_length: int) -> dict:
    """A run's journal header (``PreferenceJournal``): what its pairs are about."""
    return {
        "env_id": env_id,
        "observation_shape": list(observation_shape),
        "action_shape": list(action_shape),
        "segment_length": segment_length,
    }
