"""
Labels from earlier runs: the answers of their preference journals, read whole and checked against the pairs a new
run (or a reward fitted from journals alone) is about.
"""

import hashlib
import json
import os
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from sb3_pride.common.journal import JournalEntry, PreferenceJournal, merge_answers

#: what a journal's header says about its pairs, and the setting each must match
HEADER_FIELDS = {
    "env_id": "env id",
    "observation_shape": "observation shape",
    "action_shape": "action shape",
    "segment_length": "segment_length",
}


@dataclass
class PriorPreferences:
    """
    The answers of earlier runs' journals, for a run to start from: their pairs' inputs, labels μ (skips left out,
    several annotators' answers to one query merged) and query ids, and where they came from.
    """

    inputs: np.ndarray
    labels: np.ndarray
    ids: list[str] = field(default_factory=list)
    #: one dict per journal: its path, SHA-1 and number of labels
    sources: list[dict] = field(default_factory=list)


def read_prior_preferences(
    paths: Sequence[str | os.PathLike],
    header: dict,
    entry_shape: tuple[int, ...],
    own_journal: str | None = None,
    name: str = "prior_preferences",
    reader: str = "this run",
) -> PriorPreferences:
    """
    Read earlier runs' journals whole, as each run read its own (skips and undos applied), and refuse any that is not
    about this run's pairs: the run's own journal, a missing file, one that holds no answers (empty, or a header
    alone), a line that is not JSON or not a journal entry (a last line cut in the middle of a write included), a
    header whose env id, observation or action shape or segment length differs from ``header``'s, or pairs of another
    shape than ``entry_shape`` (a journal without a header is checked on its pairs' shape only).

    :param paths: the journals, e.g. ``["runs/a/preferences.jsonl"]``
    :param header: this run's journal header (``PreferenceJournal``)
    :param entry_shape: (2, segment_length, obs_dim + action_dim)
    :param own_journal: the run's own journal (its answers are taken back as the run's, not as priors)
    :param name: what the errors call the journals: the setting or argument the user gave them by
    :param reader: what the errors call the side whose ``header`` the journals must match
    """
    if isinstance(paths, (str, os.PathLike)) or not all(isinstance(path, (str, os.PathLike)) for path in paths):
        raise ValueError(f"{name} must be a list of journal paths, got {paths!r}")
    entries: list[JournalEntry] = []
    sources = []
    for path in paths:
        journal, where = PreferenceJournal(path, name), f"{name} {os.fspath(path)}"
        if own_journal is not None and os.path.realpath(path) == os.path.realpath(own_journal):
            raise ValueError(f"{where} is this run's own preference_journal")
        if not journal.path.is_file():
            raise ValueError(f"{where} is not a file")
        theirs = journal.header() or {}
        different = [
            f"{field_name} {theirs[key]!r} ({reader}: {header[key]!r})"
            for key, field_name in HEADER_FIELDS.items()
            if theirs.get(key) is not None and header.get(key) is not None and _plain(theirs[key]) != _plain(header[key])
        ]
        if different:
            raise ValueError(f"{where} is about other pairs: its " + ", its ".join(different))
        own = journal.read(strict=True)
        if not own:
            raise ValueError(f"{where} holds no answers (an empty journal, or its header alone)")
        for entry in own:
            if entry.inputs.shape != tuple(entry_shape):
                raise ValueError(
                    f"{where} holds pairs of shape {entry.inputs.shape}, {reader}'s are {tuple(entry_shape)} "
                    "(2, segment_length, obs_dim + action_dim)"
                )
        entries += own
        digest = hashlib.sha1(journal.path.read_bytes()).hexdigest()
        labelled = {entry.id for entry in merge_answers(own) if not np.isnan(entry.label)}
        sources.append({"path": os.fspath(path), "sha1": digest, "labels": len(labelled)})
    # a query answered in several journals (or one journal given twice) is one preference: its answers' mean μ
    merged = merge_answers(entries)
    answered = [entry for entry in merged if not np.isnan(entry.label)]
    inputs = np.stack([entry.inputs for entry in answered]).astype(np.float32) if answered else np.zeros((0, *entry_shape))
    labels = np.array([entry.label for entry in answered], dtype=np.float32)
    return PriorPreferences(inputs.astype(np.float32), labels, [entry.id for entry in merged], sources)


def _plain(value: object) -> object:
    """A header value as JSON reads it back (tuples become lists)."""
    return json.loads(json.dumps(value))
