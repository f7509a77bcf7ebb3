"""Asynchronous feedback: training goes on while the teacher answers; no answer is lost or used twice."""

import threading
import time

import numpy as np
import pytest
from stable_baselines3.common.callbacks import BaseCallback

from sb3_pride import PEBBLE
from sb3_pride.common.journal import JournalEntry, PreferenceJournal
from sb3_pride.common.teachers import InteractiveTeacher, ScriptedTeacher


class WatchingTeacher:
    """An oracle that takes ``seconds`` per session (with ``steps``: until the model has taken that many steps more, at
    most ``seconds``, whatever the machine's speed) and notes the model's step count when it starts and ends."""

    def __init__(self, seconds: float, steps: int | None = None):
        self.oracle = ScriptedTeacher.from_preset("oracle", seed=0)
        self.seconds, self.wait_steps = seconds, steps
        self.model: PEBBLE | None = None
        self.steps: list[tuple[int, int]] = []
        self.threads: set[str] = set()
        self.answers: dict[bytes, float] = {}

    def __call__(self, pairs):
        start, deadline = self.model.num_timesteps, time.monotonic() + self.seconds
        if self.wait_steps is None:
            threading.Event().wait(self.seconds)
        else:
            while self.model.num_timesteps < start + self.wait_steps and time.monotonic() < deadline:
                time.sleep(0.01)
        labels = self.oracle(pairs)
        self.steps.append((start, self.model.num_timesteps))
        self.threads.add(threading.current_thread().name)
        for inputs, label in zip(pairs.inputs, labels, strict=True):
            self.answers[inputs.tobytes()] = label
        return labels


@pytest.mark.parametrize("asynchronous", [False, True])
def test_training_goes_on_while_a_slow_teacher_answers(tiny_kwargs, tmp_path, asynchronous):
    # answered 50 steps later while training goes on (the next session falls within the run on any machine); blocking
    # the main thread for a second otherwise
    teacher = WatchingTeacher(seconds=60, steps=50) if asynchronous else WatchingTeacher(seconds=1.0)
    journal = tmp_path / "journal.jsonl"
    model = PEBBLE(
        "MlpPolicy", "Pendulum-v1", seed=0, teacher=teacher, asynchronous_feedback=asynchronous,
        preference_journal=journal, **tiny_kwargs,
    )  # fmt: skip
    teacher.model = model
    model.learn(1000)
    assert len(teacher.steps) == 3 and model.phase.sessions == 3 and model.feedback.pending is None
    if asynchronous:
        # each session's answers took 50 steps: the agent kept stepping meanwhile, on the older reward
        assert all(end > start for start, end in teacher.steps)
        assert teacher.threads == {"teacher"}
        # the next session is published only once the previous one is answered
        assert all(teacher.steps[i][1] <= teacher.steps[i + 1][0] for i in range(2))
    else:
        assert all(end == start for start, end in teacher.steps) and teacher.threads == {"MainThread"}
    # every answer used once: journaled once, in the preferences once, with the label the teacher gave
    entries = PreferenceJournal(journal).read()
    assert len(entries) == model.phase.asked == model.feedback.journal.included == 60
    assert len({entry.id for entry in entries}) == 60
    assert len(model.preferences) == model.phase.labeled == 60
    stored = model.preferences.inputs[: len(model.preferences)]
    labels = model.preferences.labels[: len(model.preferences)]
    assert len({inputs.tobytes() for inputs in stored}) == 60
    for inputs, label in zip(stored, labels, strict=True):
        assert teacher.answers[inputs.tobytes()] == label


def test_a_session_open_when_learn_ends_is_waited_for(tiny_kwargs):
    teacher = WatchingTeacher(seconds=0.5)
    model = PEBBLE("MlpPolicy", "Pendulum-v1", seed=0, teacher=teacher, asynchronous_feedback=True, **tiny_kwargs)
    teacher.model = model
    model.learn(302)  # the first session is published at step 300
    assert model.phase.sessions == 1 and model.phase.asked == 20 and model.feedback.pending is None
    assert not model.phase.pretraining and model.real_buffer.reward_source is model.replay_rewards
    assert model.replay_rewards.learned and not model.replay_rewards.pretraining


def test_a_teachers_bad_answer_from_its_thread_is_raised_and_nothing_recorded(tiny_kwargs, tmp_path):
    def teacher(pairs):
        return np.full(len(pairs), 2.0)

    journal = tmp_path / "journal.jsonl"
    model = PEBBLE(
        "MlpPolicy", "Pendulum-v1", teacher=teacher, asynchronous_feedback=True, preference_journal=journal, **tiny_kwargs
    )
    with pytest.raises(ValueError, match="teacher labels"):
        model.learn(400)
    assert len(model.preferences) == 0 and model.phase.asked == 0 and not journal.exists()
    assert model.feedback.pending is None


def test_a_checkpoint_taken_while_answers_are_awaited_loads_and_goes_on(tiny_kwargs, tmp_path):
    class SaveWhileOpen(BaseCallback):
        saved = False

        def _on_step(self) -> bool:
            if self.model.feedback.pending is not None and not self.saved:
                self.model.save(tmp_path / "open")
                self.saved = True
            return True

    oracle = ScriptedTeacher.from_preset("oracle", seed=0)

    def slow_oracle(pairs):  # a person's pace: the session stays open for a few steps
        time.sleep(0.02 * len(pairs))
        return oracle(pairs)

    kwargs = dict(tiny_kwargs, teacher=slow_oracle)
    model = PEBBLE("MlpPolicy", "Pendulum-v1", seed=0, asynchronous_feedback=True, **kwargs)
    saver = SaveWhileOpen()
    model.learn(400, callback=saver)
    assert saver.saved
    loaded = PEBBLE.load(tmp_path / "open", env=model.get_env())
    # the open session was not saved: the loaded model asks it again at once (a journal would give its answers back)
    assert loaded.asynchronous_feedback and loaded.feedback.pending is None and loaded.phase.sessions == 0
    assert loaded.phase.next_step <= loaded.num_timesteps
    loaded.learn(400, reset_num_timesteps=False)
    assert loaded.phase.sessions >= 1 and loaded.feedback.pending is None


def test_bad_settings_name_the_parameter():
    with pytest.raises(ValueError, match="asynchronous_feedback"):
        PEBBLE("MlpPolicy", "Pendulum-v1", asynchronous_feedback="yes")


class LoggingTeacher(InteractiveTeacher):
    """An interactive teacher (as a person's UI is) that journals its answers itself and logs a number per session."""

    def __init__(self):
        self.oracle = ScriptedTeacher.from_preset("oracle", seed=0)
        self.asked: list[int] = []

    def attach(self, env, buffer) -> None:
        pass

    def ask(self, pairs, context):
        self.asked.append(len(pairs))
        labels = self.oracle(pairs)
        answers = zip(pairs.inputs, labels, strict=True)
        context.record([JournalEntry(context.session, inputs, label, annotator="ana") for inputs, label in answers])
        context.log("annotators/ana/answers", float(len(pairs)))
        return labels


def test_an_interactive_teachers_log_and_journal_reach_the_model_from_its_thread(tiny_kwargs, tmp_path):
    import pandas as pd
    from stable_baselines3.common.logger import configure

    journal = tmp_path / "journal.jsonl"
    model = PEBBLE(
        "MlpPolicy", "Pendulum-v1", seed=0, teacher=LoggingTeacher(), asynchronous_feedback=True,
        preference_journal=journal, **tiny_kwargs,
    )  # fmt: skip
    model.set_logger(configure(str(tmp_path), ["csv"]))
    model.learn(700, log_interval=1)
    entries = PreferenceJournal(journal).read()
    assert model.feedback.journal.included == len(entries) == model.phase.asked == 40
    assert {entry.annotator for entry in entries} == {"ana"}
    assert pd.read_csv(tmp_path / "progress.csv")["annotators/ana/answers"].dropna().tolist()[-1] == 20.0


@pytest.mark.parametrize("asynchronous", [False, True])
def test_a_new_model_takes_an_interactive_teachers_journaled_answers_back(tiny_kwargs, tmp_path, asynchronous):
    """Answers a person gave (journaled by the teacher itself) are never asked again by a model resumed from an older
    checkpoint: every session the journal holds is taken from it, in blocking and asynchronous feedback alike."""
    journal = tmp_path / "journal.jsonl"
    kwargs = dict(seed=0, asynchronous_feedback=asynchronous, preference_journal=journal, **tiny_kwargs)
    first = PEBBLE("MlpPolicy", "Pendulum-v1", teacher=LoggingTeacher(), **kwargs)
    first.learn(700)
    assert first.phase.sessions == 2 and len(PreferenceJournal(journal).read()) == 40
    teacher = LoggingTeacher()
    again = PEBBLE("MlpPolicy", "Pendulum-v1", teacher=teacher, **kwargs)
    again.learn(700)
    assert teacher.asked == [] and again.phase.asked == 40 and again.feedback.journal.included == 40
    assert len(PreferenceJournal(journal).read()) == 40
    again.learn(400, reset_num_timesteps=False)  # the third session is new: asked, journaled after the others
    assert teacher.asked == [20] and again.feedback.journal.included == len(PreferenceJournal(journal).read()) == 60
    # an undo that would take back nothing is refused before the journal is written
    with pytest.raises(ValueError, match="no answer of feedback session 9"):
        again.feedback.journal.retract(9)
    with pytest.raises(ValueError, match="to take back"):
        again.feedback.journal.retract(3)  # the third session's answers are taken in already
    assert len(PreferenceJournal(journal).read()) == 60


class ShownHistoryTeacher(LoggingTeacher):
    """Keeps what it is shown of r̂'s history, as a person's page does."""

    def __init__(self):
        super().__init__()
        self.shown: list[list[dict]] = []

    def show_reward_history(self, history):
        self.shown.append([dict(entry) for entry in history])


def test_an_interactive_teacher_is_shown_r_hats_history_after_each_update_and_when_a_model_is_loaded(tiny_kwargs, tmp_path):
    import gymnasium as gym

    teacher = ShownHistoryTeacher()
    model = PEBBLE("MlpPolicy", "Pendulum-v1", seed=0, teacher=teacher, **tiny_kwargs).learn(700)
    assert [[entry["session"] for entry in shown] for shown in teacher.shown] == [[1], [1, 2]]
    assert teacher.shown[-1] == model.reward_learner.history
    model.save(tmp_path / "model.zip")
    again = ShownHistoryTeacher()
    PEBBLE.load(tmp_path / "model.zip", env=gym.make("Pendulum-v1"), teacher=again)
    assert again.shown == [model.reward_learner.history]
