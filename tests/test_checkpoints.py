"""Checkpoints as one unit (a model and its replay buffer), a real SIGKILL mid-save, resume; buffers saved by their rows."""

import os
import pickle
import signal
import subprocess
import sys
import textwrap
import time

import gymnasium as gym
import numpy as np
import pytest
from gymnasium import spaces
from stable_baselines3.common import callbacks

from sb3_pride import PEBBLE
from sb3_pride.common.buffers import PreferenceReplayBuffer, full_size_state
from sb3_pride.pride.buffers import DualReplayBuffer
from sb3_pride.common.checkpoints import CheckpointCallback, clean_leftovers, latest_checkpoint, resume
from sb3_pride.common.journal import PreferenceJournal
from tests.test_journal import CountingTeacher

OBSERVATIONS, ACTIONS = spaces.Box(-1, 1, (3,), np.float32), spaces.Box(-1, 1, (2,), np.float32)


def add_transitions(buffer, n: int, seed: int) -> None:
    rng = np.random.default_rng(seed)
    for step in range(n):
        obs, next_obs = rng.normal(size=(2, 1, 3)).astype(np.float32)
        done = np.array([step % 7 == 6])
        infos = [{"render_state": rng.normal(size=4), "TimeLimit.truncated": bool(step % 13 == 12)}]
        buffer.add(obs, next_obs, rng.uniform(-1, 1, (1, 2)), rng.normal(size=1), done, infos)


def stored(buffer: PreferenceReplayBuffer) -> dict:
    names = ("observations", "next_observations", "actions", "rewards", "dones", "timeouts", "true_rewards", "render_states")
    return {"pos": buffer.pos, "full": buffer.full, **{name: getattr(buffer, name) for name in names}}


def assert_same(first: dict, second: dict) -> None:
    assert first.keys() == second.keys()
    for name, value in first.items():
        np.testing.assert_array_equal(value, second[name], err_msg=name)


def dead_pid() -> int:
    """The id of a process that has ended."""
    return int(subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True).stdout)


def test_a_saved_buffer_holds_its_filled_rows_and_goes_on_exactly():
    buffer = PreferenceReplayBuffer(1000, OBSERVATIONS, ACTIONS)
    buffer.record_render_states = True
    add_transitions(buffer, 100, seed=0)
    small = len(pickle.dumps(buffer))
    add_transitions(buffer, 200, seed=1)
    larger = len(pickle.dumps(buffer))
    row = (larger - small) / 200  # obs, next obs, actions, reward, done, timeout, true reward, render state
    assert row == pytest.approx(4 * (3 + 3 + 2 + 4) + 8 * 4, abs=0.5)
    assert small < 100 * row + 10_000  # the rows it holds, not the 1000 it has room for

    restored = pickle.loads(pickle.dumps(buffer))
    assert restored.buffer_size == 1000 and restored.observations.shape == (1000, 1, 3)
    assert_same(stored(restored), stored(buffer))
    for each in (buffer, restored):  # both go on past the end of the ring
        add_transitions(each, 900, seed=2)
    assert restored.full and restored.pos == 200
    assert_same(stored(restored), stored(buffer))
    assert abs(len(pickle.dumps(restored)) - 1000 * row) < 10_000  # a full buffer is saved whole
    state = dict(buffer.__dict__)  # a buffer pickled whole (before its rows were cut) loads as it was
    assert full_size_state(state).keys() == state.keys()


def test_prides_buffer_saves_both_parts_by_their_rows():
    buffer = DualReplayBuffer(1000, OBSERVATIONS, ACTIONS, synthetic_buffer_size=2000, synthetic_ratio=0.5)
    add_transitions(buffer, 50, seed=0)
    rng = np.random.default_rng(1)
    buffer.synthetic.extend(*(rng.normal(size=(30, size)).astype(np.float32) for size in (3, 2, 3, 1, 1)))
    assert len(pickle.dumps(buffer)) < 20_000  # 80 rows of about 60 bytes, not 3000
    restored = pickle.loads(pickle.dumps(buffer))
    assert_same(stored(restored.real), stored(buffer.real))
    assert restored.synthetic.observations.shape == (2000, 1, 3) and restored.synthetic.pos == 30
    np.testing.assert_array_equal(restored.synthetic.rewards, buffer.synthetic.rewards)
    np.random.seed(0)
    first = buffer.sample(16)
    np.random.seed(0)
    np.testing.assert_array_equal(restored.sample(16).observations, first.observations)


def test_the_newest_complete_checkpoint_and_a_killed_saves_leftovers(tmp_path):
    for step in (150, 300, 450):
        (tmp_path / f"rl_model_{step}_steps.zip").write_bytes(b"model")
    for step in (150, 300):
        (tmp_path / f"rl_model_replay_buffer_{step}_steps.pkl").write_bytes(b"buffer")
    # SB3's CheckpointCallback killed while writing the buffer at 450: a model without its buffer, a temporary file
    leftover = tmp_path / f".rl_model_replay_buffer_450_steps.pkl.{dead_pid()}.tmp"
    leftover.write_bytes(b"half a buffer")
    running = tmp_path / f".rl_model_replay_buffer_600_steps.pkl.{os.getppid()}.tmp"  # a writer still at work
    ours = tmp_path / f".rl_model_600_steps.zip.{os.getpid()}.tmp"  # a killed writer's id, which this process has now
    report = tmp_path / f".report.json.{os.getpid()}.tmp"  # may be written by another thread of this process
    orphan = tmp_path / "rl_model_replay_buffer_600_steps.pkl"  # this module's order killed before the model's rename
    for path in (running, ours, report, orphan):
        path.write_bytes(b"bytes")

    assert sorted(clean_leftovers(tmp_path)) == sorted([leftover, ours, orphan])
    assert running.exists() and report.exists() and not (leftover.exists() or ours.exists() or orphan.exists())
    checkpoint = latest_checkpoint(tmp_path)
    assert checkpoint is not None and checkpoint.step == 300
    assert (checkpoint.model.name, checkpoint.replay_buffer.name) == (
        "rl_model_300_steps.zip",
        "rl_model_replay_buffer_300_steps.pkl",
    )

    models_only = tmp_path / "models"
    models_only.mkdir()
    for step in (100, 200):
        (models_only / f"rl_model_{step}_steps.zip").write_bytes(b"model")
    assert latest_checkpoint(models_only).step == 200 and latest_checkpoint(models_only).replay_buffer is None
    assert latest_checkpoint(tmp_path / "missing") is None
    with pytest.raises(FileNotFoundError, match=r"resume: no checkpoint rl_model_N_steps\.zip in .*missing"):
        resume(PEBBLE, tmp_path / "missing")


#: a run with a journal and checkpoints every 150 steps, replay buffer included; the replay buffer of the third
#: checkpoint (step 450) is written so slowly that the run is killed in the middle of it
WORKER = """
import time
import torch
import stable_baselines3.common.off_policy_algorithm as off_policy
from stable_baselines3.common import callbacks
from sb3_pride import PEBBLE
from sb3_pride.common import checkpoints
torch.set_num_threads(1)
save_to_pkl, saves = off_policy.save_to_pkl, []

def slow_save(path, obj, verbose=0):
    saves.append(path)
    if len(saves) == 3:
        with open(path, "wb") as file:
            file.write(b"the first bytes of a replay buffer")
        time.sleep(600)
    save_to_pkl(path, obj, verbose)

off_policy.save_to_pkl = slow_save
model = PEBBLE("MlpPolicy", "Pendulum-v1", seed=0, preference_journal="{folder}/preferences.jsonl", **{kwargs})
model.learn(700, callback={callback}.CheckpointCallback(150, "{folder}", save_replay_buffer=True))
"""


@pytest.mark.slow
@pytest.mark.parametrize("callback", ["checkpoints", "callbacks"])
def test_sigkill_during_a_checkpoint_save_then_resume_from_the_newest_complete(tiny_kwargs, tmp_path, callback):
    """Killed while the buffer of its third checkpoint is written, with this package's CheckpointCallback or SB3's
    (which writes the model first): ``resume`` loads the second with its buffer, removes the leftovers, and the run goes
    on with every label of the journal, none asked twice."""
    tiny_kwargs.update(
        learning_starts=100, unsupervised_steps=100, feedback_interval=100, max_feedback=50, queries_per_session=10
    )
    tiny_kwargs.update(feedback_schedule="constant")
    script = WORKER.format(folder=tmp_path, kwargs=repr(tiny_kwargs), callback=callback)
    child = subprocess.Popen([sys.executable, "-c", textwrap.dedent(script)], stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 300
    while not list(tmp_path.glob(".rl_model_replay_buffer_450_steps.pkl.*.tmp")):
        assert child.poll() is None, child.stderr.read()
        assert time.monotonic() < deadline, "the worker never reached its third checkpoint"
        time.sleep(0.2)
    os.kill(child.pid, signal.SIGKILL)
    child.wait()
    # SB3's callback wrote the model first: a model without its buffer; this package's writes the model last
    assert (tmp_path / "rl_model_450_steps.zip").exists() == (callback == "callbacks")
    assert not (tmp_path / "rl_model_replay_buffer_450_steps.pkl").exists()
    journal = tmp_path / "preferences.jsonl"
    assert len(PreferenceJournal(journal).read()) == 30  # feedback sessions at 200, 300 and 400

    teacher = CountingTeacher()
    model = resume(PEBBLE, tmp_path, env=gym.make("Pendulum-v1"), teacher=teacher)
    assert not list(tmp_path.glob(".*.tmp"))  # the killed save's temporary file is gone
    # SB3 calls the callbacks of step 300 before storing its transition
    assert model.num_timesteps == 300 and model.replay_buffer.size() == 299
    assert model.feedback.journal.included == 20 and len(model.preferences) == 20
    model.learn(400, callback=CheckpointCallback(150, tmp_path, save_replay_buffer=True), reset_num_timesteps=False)
    # feedback session 3 (step 400) came back from the journal; only those at 500 and 600 were asked
    assert teacher.asked == 20 and model.phase.sessions == 5 and model.phase.asked == 50
    labels = np.array([entry.label for entry in PreferenceJournal(journal).read()])
    np.testing.assert_array_equal(model.preferences.labels, labels[~np.isnan(labels)])
    ids = [entry.id for entry in PreferenceJournal(journal).read()]
    assert len(set(ids)) == len(ids) == 50
    assert latest_checkpoint(tmp_path).step == 600  # the resumed run's checkpoints at 450 and 600, whole
    assert (tmp_path / "rl_model_replay_buffer_450_steps.pkl").exists()
    assert isinstance(CheckpointCallback(1, tmp_path), callbacks.CheckpointCallback)
