"""Crash-safe runs: the preference journal, checkpoints written whole, and a real SIGKILL + resume."""

import json
import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import numpy as np
import pytest
import gymnasium as gym
from stable_baselines3.common import base_class, off_policy_algorithm

from sb3_pride import PEBBLE, PRIDE
from sb3_pride.common.journal import JournalEntry, PreferenceJournal
from sb3_pride.common.teachers import make_teacher

from test_contract import TINY_DIFFUSION


class CountingTeacher:
    """The oracle, counting the queries it is asked."""

    def __init__(self):
        self.oracle, self.asked = make_teacher("oracle"), 0

    def __call__(self, pairs):
        self.asked += len(pairs)
        return self.oracle(pairs)


def journal_labels(path) -> np.ndarray:
    labels = np.array([entry.label for entry in PreferenceJournal(path).read()])
    return labels[~np.isnan(labels)]


@pytest.mark.slow
def test_a_new_model_takes_the_journals_answers_back_instead_of_asking(tiny_kwargs, tmp_path):
    journal = tmp_path / "run" / "preferences.jsonl"
    tiny_kwargs.update(teacher="skip", feedback_interval=100, max_feedback=40, queries_per_session=10)
    first = PEBBLE("MlpPolicy", "Pendulum-v1", seed=0, preference_journal=journal, **tiny_kwargs)
    first.learn(450)  # sessions at 300 and 400; the "skip" teacher skips some queries
    entries = PreferenceJournal(journal).read()
    assert [entry.session for entry in entries] == [1] * 10 + [2] * 10
    assert first.feedback.journal.included == 20 and first.phase.asked == 20
    np.testing.assert_array_equal(first.preferences.labels, journal_labels(journal))
    assert first.phase.labeled == len(journal_labels(journal)) < 20  # skips are journaled, not labeled

    teacher = CountingTeacher()
    tiny_kwargs.update(teacher=teacher)
    again = PEBBLE("MlpPolicy", "Pendulum-v1", seed=1, preference_journal=journal, **tiny_kwargs)
    again.learn(650)  # feedback sessions 1-2 from the journal, 3-4 asked
    assert teacher.asked == 20 and again.phase.asked == 40 and again.feedback.journal.included == 40
    np.testing.assert_array_equal(again.preferences.labels, journal_labels(journal))
    ids = [entry.id for entry in PreferenceJournal(journal).read()]
    assert len(set(ids)) == len(ids) == 40  # never the same query twice


def test_a_journal_that_does_not_fit_is_refused_when_the_model_is_made(tiny_kwargs, tmp_path):
    journal = PreferenceJournal(tmp_path / "other.jsonl")
    journal.append([JournalEntry(1, np.zeros((2, 7, 4), np.float32), 1.0)])
    with pytest.raises(ValueError, match=r"preference_journal .* holds pairs of shape"):
        PEBBLE("MlpPolicy", "Pendulum-v1", preference_journal=journal.path, **tiny_kwargs)


def test_a_torn_last_line_is_dropped_and_cut_before_the_next_append(tmp_path):
    journal = PreferenceJournal(tmp_path / "preferences.jsonl")
    pair = np.ones((2, 3, 2), np.float32)
    journal.append([JournalEntry(1, pair, 0.0), JournalEntry(1, 2 * pair, float("nan"))])
    with open(journal.path, "a") as file:
        file.write('{"session": 1, "id": "abc", "lab')  # a writer killed mid-line
    assert [entry.label for entry in journal.read()][:1] == [0.0] and len(journal.read()) == 2
    journal.append([JournalEntry(2, 3 * pair, 1.0)])
    entries = journal.read()
    assert [entry.session for entry in entries] == [1, 1, 2] and np.isnan(entries[1].label)
    np.testing.assert_array_equal(entries[2].inputs, 3 * pair)
    assert all(json.loads(line) for line in journal.path.read_text().splitlines())


@pytest.mark.parametrize(
    "line, reason",
    [
        ('{"a": 1}', "no session, label, shape, inputs"),
        ("[1, 2]", "not an answer"),
        ('{"session": 1, "label": 1.0, "shape": [2, 3, 2], "inputs": "AAAAAA=="}', "cannot reshape"),
        ('{"session": 1, "label": 1.0, "shape": [1], "inputs": "not base64!"}', "base64|Non-base64|Invalid"),
        ('{"session": 1, "label": "left", "shape": [1], "inputs": "AAAAAA=="}', "could not convert"),
    ],
)
def test_a_line_that_is_not_an_answer_is_refused_naming_its_file_and_line(tmp_path, line, reason):
    journal = PreferenceJournal(tmp_path / "preferences.jsonl")
    journal.append([JournalEntry(1, np.ones((2, 3, 2), np.float32), 0.0)])
    with open(journal.path, "a") as file:
        file.write(line + "\n")
    with pytest.raises(
        ValueError, match=rf"preference_journal .*preferences.jsonl: line 2 is not a journal entry \(.*({reason})"
    ):
        journal.read()
    with pytest.raises(ValueError, match=r"^journal .*preferences.jsonl: line 2 is not a journal entry"):
        PreferenceJournal(journal.path, name="journal").read(strict=True)


def test_a_save_that_fails_midway_leaves_the_previous_checkpoint(tiny_kwargs, tmp_path, monkeypatch):
    model = PEBBLE("MlpPolicy", "Pendulum-v1", seed=0, **tiny_kwargs)
    model.learn(150)
    model.save(tmp_path / "checkpoint")
    model.save_replay_buffer(tmp_path / "buffer")
    model.learn(50, reset_num_timesteps=False)

    def killed_midway(path, *args, **kwargs):
        Path(path).write_bytes(b"the first bytes of a checkpoint")
        raise KeyboardInterrupt("killed while writing")

    monkeypatch.setattr(base_class, "save_to_zip_file", killed_midway)
    monkeypatch.setattr(off_policy_algorithm, "save_to_pkl", killed_midway)
    with pytest.raises(KeyboardInterrupt):
        model.save(tmp_path / "checkpoint")
    with pytest.raises(KeyboardInterrupt):
        model.save_replay_buffer(tmp_path / "buffer")
    monkeypatch.undo()
    assert sorted(path.name for path in tmp_path.iterdir()) == ["buffer.pkl", "checkpoint.zip"]  # no temporary left
    loaded = PEBBLE.load(tmp_path / "checkpoint")
    loaded.load_replay_buffer(tmp_path / "buffer")
    assert loaded.num_timesteps == 150 and loaded.replay_buffer.size() == 150


#: a run with a journal and SB3's CheckpointCallback (every 150 steps, replay buffer included); the teacher of the
#: fifth session (step 600) never answers, as a person gone home: the run is killed while it waits
WORKER = """
import time, sys
import torch
from stable_baselines3.common.callbacks import CheckpointCallback
from sb3_pride import {algo}
from sb3_pride.common.teachers import make_teacher
oracle, sessions = make_teacher("oracle"), []
torch.set_num_threads(1)  # tiny networks: threads only add contention (as in the tests' own process)

def teacher(pairs):
    sessions.append(len(pairs))
    if len(sessions) == 5:
        time.sleep(600)
    return oracle(pairs)

model = {algo}("MlpPolicy", "Pendulum-v1", seed=0, teacher=teacher, preference_journal="{folder}/preferences.jsonl",
               **{kwargs})
model.learn(700, callback=CheckpointCallback(150, "{folder}", save_replay_buffer=True))
"""


@pytest.mark.slow
@pytest.mark.parametrize("algo", [PEBBLE, PRIDE])
def test_sigkill_then_resume_loses_no_answer_and_asks_none_twice(tiny_kwargs, tmp_path, algo):
    tiny_kwargs.update(learning_starts=100, unsupervised_steps=100, feedback_interval=100, max_feedback=50,
                       queries_per_session=10, feedback_schedule="constant")  # fmt: skip
    if algo is PRIDE:
        tiny_kwargs.update(TINY_DIFFUSION)
    script = WORKER.format(algo=algo.__name__, folder=tmp_path, kwargs=repr(tiny_kwargs))
    child = subprocess.Popen([sys.executable, "-c", textwrap.dedent(script)], stderr=subprocess.PIPE, text=True)
    journal = tmp_path / "preferences.jsonl"
    deadline = time.monotonic() + 300
    # feedback sessions at steps 200, 300, 400, 500; checkpoints at 150, 300, 450: the fourth is journaled, not
    # checkpointed
    while len(PreferenceJournal(journal).read()) < 40:
        assert child.poll() is None, child.stderr.read()
        assert time.monotonic() < deadline, "the worker never reached its fourth feedback session"
        time.sleep(0.2)
    time.sleep(1.0)  # let it run on towards the fifth feedback session, which never gets its answers
    os.kill(child.pid, signal.SIGKILL)
    child.wait()
    checkpoints = sorted(tmp_path.glob("rl_model_*_steps.zip"), key=lambda path: int(path.stem.split("_")[2]))
    assert [path.name for path in checkpoints] == [f"rl_model_{step}_steps.zip" for step in (150, 300, 450)]

    teacher = CountingTeacher()
    model = algo.load(checkpoints[-1], env=gym.make("Pendulum-v1"), teacher=teacher)
    model.load_replay_buffer(tmp_path / "rl_model_replay_buffer_450_steps.pkl")
    assert model.feedback.journal.included == 30 and len(model.preferences) == 30 and model.num_timesteps == 450
    model.learn(250, reset_num_timesteps=False)
    # feedback session 4 (step 500) came back from the journal; only the fifth (step 600) was asked
    assert teacher.asked == 10
    assert model.phase.sessions == 5 and model.phase.asked == 50 and model.feedback.journal.included == 50
    np.testing.assert_array_equal(model.preferences.labels, journal_labels(journal))
    ids = [entry.id for entry in PreferenceJournal(journal).read()]
    assert len(set(ids)) == len(ids) == 50
    if algo is PRIDE:
        assert model.diffusion_retrains >= 3  # the diffusion schedule went on too


def test_a_models_journal_is_found_from_its_own_folder_before_the_working_folders(tmp_path, monkeypatch):
    """Loading a model from another folder that holds another run's journal of the same name takes the model's own."""
    from sb3_pride.common.journal import find_journal

    run, other = tmp_path / "run", tmp_path / "other"
    run.mkdir(), other.mkdir()
    (run / "preferences.jsonl").write_text("the model's\n")
    (other / "preferences.jsonl").write_text("another run's\n")
    monkeypatch.chdir(other)
    assert Path(find_journal("preferences.jsonl", run / "model.zip")).read_text() == "the model's\n"
    monkeypatch.chdir(tmp_path)  # resumed where it ran: the path it was given, from the model's folder's parents
    assert Path(find_journal("run/preferences.jsonl", "run/model.zip")).read_text() == "the model's\n"
    assert find_journal("gone.jsonl", run / "model.zip") == "gone.jsonl"  # missing: said missing by its caller
