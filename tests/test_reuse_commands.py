"""
The reuse commands (``python -m sb3_pride.reward fit|report``) as a user types them: nothing they read is written
over, a saved model is reported from any folder, and each mistake gets one line naming what the user typed.
"""

import os
import subprocess
import sys

import pytest

from sb3_pride import PEBBLE
from sb3_pride.reward.__main__ import main


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    """A tiny PEBBLE run on Pendulum made as a user makes one: a journal path relative to the run's folder."""
    from conftest import TINY

    folder = tmp_path_factory.mktemp("project")
    here = os.getcwd()
    os.chdir(folder)
    try:
        model = PEBBLE("MlpPolicy", "Pendulum-v1", seed=0, preference_journal="run/pend.jsonl", **TINY).learn(1000)
        model.save("run/model.zip")
        model.save_reward_model("run/reward.pt")
    finally:
        os.chdir(here)
    return folder / "run"


def refused(capsys, *argv: str) -> str:
    """Run the command; it must fail with one line on stderr, no traceback; that line."""
    code = main([str(arg) for arg in argv])
    err = capsys.readouterr().err
    assert code != 0, err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in err, err
    return lines[0]


def test_fit_refuses_to_write_over_a_journal_it_reads(run, tmp_path, capsys):
    journal = tmp_path / "pend.jsonl"
    journal.write_bytes((run / "pend.jsonl").read_bytes())
    before = journal.read_bytes()
    (tmp_path / "sub").mkdir()
    os.link(journal, tmp_path / "hard.jsonl")
    for out in (journal, tmp_path / "sub" / ".." / "pend.jsonl", tmp_path / "hard.jsonl"):
        message = refused(capsys, "fit", journal, "--out", out, "--reward-kwargs", '{"epochs": 1}')
        assert "--out" in message and "reads" in message, message
    assert journal.read_bytes() == before
    # a file the command does not read but that is not a reward file either (another run's journal) is kept too
    other = tmp_path / "other.jsonl"
    other.write_bytes(before)
    message = refused(capsys, "fit", journal, "--out", other, "--reward-kwargs", '{"epochs": 1}')
    assert "--out" in message and "not a reward file" in message, message
    assert other.read_bytes() == before


def test_the_real_command_line_refuses_to_write_over_its_journal(run, tmp_path):
    journal = tmp_path / "pend.jsonl"
    journal.write_bytes((run / "pend.jsonl").read_bytes())
    before = journal.read_bytes()
    command = [sys.executable, "-m", "sb3_pride.reward", "fit", str(journal), "--out", str(journal)]
    result = subprocess.run(command, capture_output=True, text=True)
    assert result.returncode != 0 and "Traceback" not in result.stderr
    assert len(result.stderr.strip().splitlines()) == 1 and "--out" in result.stderr, result.stderr
    assert journal.read_bytes() == before


def test_report_refuses_to_write_over_what_it_reads(run, tmp_path, capsys):
    model = tmp_path / "model.zip"
    model.write_bytes((run / "model.zip").read_bytes())
    before = model.read_bytes()
    message = refused(capsys, "report", model, "--env", "Pendulum-v1", "--out", model)
    assert "--out" in message, message
    assert model.read_bytes() == before


def test_a_model_is_reported_from_any_folder_with_or_without_its_journal(run, tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)  # the run's journal path, run/pend.jsonl, resolves to nothing here
    assert main(["report", str(run / "model.zip"), "--env", "Pendulum-v1", "--out", "figures", "--episodes", "1"]) == 0
    assert sorted(path.name for path in (tmp_path / "figures").iterdir()) == ["episode_0.png", "sessions.png"]
    # report needs r̂ only: a model whose journal is gone is reported all the same
    moved = tmp_path / "moved"
    moved.mkdir()
    (moved / "model.zip").write_bytes((run / "model.zip").read_bytes())
    assert main(["report", str(moved / "model.zip"), "--env", "Pendulum-v1", "--out", "again", "--episodes", "1"]) == 0
    assert (tmp_path / "again" / "episode_0.png").exists()
    capsys.readouterr()


def test_report_names_the_mistake_and_creates_nothing(run, tmp_path, capsys):
    out = tmp_path / "figures"
    # a reward file given as a model
    message = refused(capsys, "report", run / "reward.pt", "--env", "Pendulum-v1", "--out", out)
    assert "reward.pt" in message and "--reward" in message, message
    # another algorithm's model holds no r̂
    from stable_baselines3 import SAC

    SAC("MlpPolicy", "Pendulum-v1", policy_kwargs=dict(net_arch=[8])).save(tmp_path / "sac.zip")
    message = refused(capsys, "report", tmp_path / "sac.zip", "--env", "Pendulum-v1", "--out", out)
    assert "sac.zip is not a saved PEBBLE or PRIDE model" in message, message
    # a missing model is named as typed
    message = refused(capsys, "report", tmp_path / "missing.zip", "--env", "Pendulum-v1", "--out", out)
    assert "missing.zip" in message and "missing.zip.zip" not in message and "does not exist" in message, message
    # an env of other spaces
    message = refused(capsys, "report", run / "model.zip", "--env", "MountainCarContinuous-v0", "--out", out)
    assert "--env" in message and "observation space" in message, message
    message = refused(capsys, "report", "--reward", run / "reward.pt", "--env", "MountainCarContinuous-v0", "--out", out)
    assert "--env" in message and "observation space" in message, message
    message = refused(capsys, "report", run / "model.zip", "--env", "Pendulum-v1", "--out", out, "--episodes", "0")
    assert "--episodes" in message, message
    assert not out.exists()
    # an existing file as the folder of the figures
    taken = tmp_path / "taken"
    taken.write_text("mine")
    message = refused(capsys, "report", run / "model.zip", "--env", "Pendulum-v1", "--out", taken)
    assert "--out" in message and "taken" in message, message
    assert taken.read_text() == "mine"


def test_fit_names_the_file_and_option_the_user_typed(run, tmp_path, capsys):
    journal = run / "pend.jsonl"
    message = refused(capsys, "fit", journal, "--out", tmp_path / "r.pt", "--reward-kwargs", "{bad")
    assert message.startswith("error: --reward-kwargs") and "JSON" in message, message
    message = refused(capsys, "fit", journal, "--out", tmp_path / "r.pt", "--reward-kwargs", '{"bogus": 1}')
    assert "--reward-kwargs" in message and "bogus" in message, message
    message = refused(capsys, "fit", journal, "--out", tmp_path / "r.pt", "--held-out", "1.5")
    assert "--held-out" in message, message
    torn = tmp_path / "torn.jsonl"
    torn.write_text(journal.read_text()[:-40])
    empty, header_only, foreign = tmp_path / "empty.jsonl", tmp_path / "header.jsonl", tmp_path / "foreign.jsonl"
    empty.write_text("")
    header_only.write_text(journal.read_text().splitlines(keepends=True)[0])
    foreign.write_text('{"a": 1}\n')
    for arguments, expected in (
        ([torn], "torn.jsonl: line 61 is not JSON"),
        ([journal, "--env", "MountainCarContinuous-v0"], "pend.jsonl is about other pairs"),
        ([empty, "--env", "Pendulum-v1"], "empty.jsonl holds no answers"),
        ([header_only], "header.jsonl holds no answers"),
        ([foreign, "--env", "Pendulum-v1"], "foreign.jsonl: line 1 is not a journal entry"),
    ):
        message = refused(capsys, "fit", *arguments, "--out", tmp_path / "r.pt")
        assert expected in message, message
        assert "prior_preferences" not in message and "preference_journal" not in message, message
    assert not (tmp_path / "r.pt").exists()
