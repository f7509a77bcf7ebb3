"""rl-zoo3 integration: shipped YAML entries, the CLI in a subprocess, enjoy, -i resume, -optimize with sqlite."""

import argparse
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml

from conftest import skip_unless

from sb3_pride import PEBBLE, PRIDE
from sb3_pride.common.checkpoints import latest_checkpoint
from sb3_pride.common.journal import PreferenceJournal
from sb3_pride.zoo import hyperparams_dir, register, resume_arguments

HYPERPARAMS = hyperparams_dir()
FILES = ["sac.yml", "pebble.yml", "pride.yml", "cpu/sac.yml", "cpu/pebble.yml", "cpu/pride.yml"]
PEBBLE_KEYS = {"teacher", "max_feedback", "feedback_interval", "queries_per_session", "segment_length",
               "query_selection", "unsupervised_steps", "reward_kwargs"}  # fmt: skip
TASKS = {"walker-walk", "cheetah-run", "quadruped-walk", "button-press-v3", "door-open-v3", "sweep-into-v3", "drawer-open-v3",
         "window-open-v3", "walker-run", "finger-spin", "hopper-stand"}  # fmt: skip
#: tiny settings for CLI runs of a few hundred steps
TINY = (
    "learning_starts:100 unsupervised_steps:100 feedback_interval:200 queries_per_session:10 max_feedback:30 "
    "segment_length:20 batch_size:64 diffusion_interval:200 synthetic_samples:500 synthetic_start:0 synthetic_ramp:100 "
    "generator_kwargs:dict(train_steps=50,sample_steps=4,window=400,dynamics_kwargs=dict(width=16,train_steps=20)) "
    "policy_kwargs:dict(net_arch=[32,32]) buffer_size:5000"
).split()
TINY_PEBBLE = [param for param in TINY if not param.startswith(("diffusion", "synthetic", "generator"))]


def entries(name):
    with open(HYPERPARAMS / name) as file:
        return yaml.safe_load(file)


def zoo(*args, cwd, gl="disable"):
    env = {**os.environ, "MUJOCO_GL": gl, "OMP_NUM_THREADS": "1"}  # tiny networks: threads only add contention
    result = subprocess.run([sys.executable, "-m", "sb3_pride.zoo", *args], cwd=cwd, env=env, capture_output=True, text=True)
    assert result.returncode == 0, result.stdout[-3000:] + result.stderr[-3000:]
    return result.stdout


def egl_renders() -> bool:
    """Whether MuJoCo can render off-screen here (record_video needs it)."""
    code = (
        "import gymnasium as gym, sb3_pride; "
        "e = gym.make('sb3_pride/walker-walk-v0', render_mode='rgb_array'); e.reset(); e.render()"
    )
    env = {**os.environ, "MUJOCO_GL": "egl"}
    return subprocess.run([sys.executable, "-c", code], env=env, capture_output=True).returncode == 0


def test_files_cover_the_papers_tasks_and_pride_is_pebble_plus_diffusion():
    for prefix in ("", "cpu/"):
        sac, pebble, pride = (entries(prefix + name) for name in ("sac.yml", "pebble.yml", "pride.yml"))
        assert set(sac) == set(pebble) == set(pride)
        assert {key.split("/")[1].removesuffix("-v0") for key in pebble} == TASKS
        for key in pebble:
            # a fair comparison: identical SAC and PEBBLE settings, PRIDE only adds its own keys; at the CPU tier it
            # asks half PEBBLE's labels
            shared = {k: v for k, v in pride[key].items() if k in pebble[key]}
            if prefix == "cpu/":
                assert 2 * shared["max_feedback"] == pebble[key]["max_feedback"]
                shared["max_feedback"] = pebble[key]["max_feedback"]
            assert shared == pebble[key]
            assert "synthetic_ratio" in set(pride[key]) - set(pebble[key])
            assert {k: v for k, v in pebble[key].items() if k not in PEBBLE_KEYS} == sac[key]


def test_recipes_are_named_not_copied():
    """The paper-scale file names the paper's recipe; the CPU file leaves PRIDE's own settings to its defaults."""
    from sb3_pride.common.utils import merge_kwargs
    from sb3_pride.pride.recipes import PAPER_SCALE_RECIPE, expand_recipe
    from sb3_pride.zoo import model_kwargs

    for env_id, entry in entries("pride.yml").items():
        assert entry["recipe"] == "paper_scale"
        _, kwargs = model_kwargs(HYPERPARAMS / "pride.yml", env_id)
        assert merge_kwargs(kwargs, PAPER_SCALE_RECIPE) == kwargs  # the recipe's settings, the entry's on top
        assert expand_recipe(entry)["generator_kwargs"]["generation"] == "unconditional"
    for entry in entries("cpu/pride.yml").values():
        assert "recipe" not in entry and "generator_kwargs" not in entry and "feedback_schedule" not in entry


@pytest.mark.slow
@pytest.mark.parametrize("name", FILES)
def test_every_shipped_entry_builds_a_model(name, tmp_path):
    register()
    from rl_zoo3.train import ExperimentManager  # with recipes expanded (register() extends rl-zoo3's)

    algo = Path(name).stem
    for env_id in entries(name):
        manager = ExperimentManager(
            argparse.Namespace(), algo, env_id, str(tmp_path), config=str(HYPERPARAMS / name), eval_freq=0,
            hyperparams={"buffer_size": 1000}, verbose=0,
        )  # fmt: skip
        model, _ = manager.setup_experiment()
        assert model.observation_space.dtype == np.float32 and len(model.observation_space.shape) == 1
        if algo != "sac":
            expected = entries(name)[env_id]
            assert (model.max_feedback, model.feedback_interval) == (expected["max_feedback"], expected["feedback_interval"])
        model.get_env().close()


@pytest.mark.slow
def test_cli_trains_enjoys_and_resumes_pride_on_dm_control(tmp_path):
    conf = str(HYPERPARAMS / "cpu/pride.yml")
    zoo("train", "--algo", "pride", "--env", "dm_control/walker-walk-v0", "-n", "400", "-f", "logs", "-conf", conf,
        "--eval-freq", "0", "-params", *TINY, cwd=tmp_path)  # fmt: skip
    run = tmp_path / "logs/pride/dm_control-walker-walk-v0_1"
    model = PRIDE.load(run / "dm_control-walker-walk-v0.zip")
    # the retrain due at step 400, the last of this learn(), waits for the first step of the next one
    assert model.num_timesteps == 400 and model.phase.sessions == 2 and model.diffusion_retrains == 1

    out = zoo("enjoy", "--algo", "pride", "--env", "dm_control/walker-walk-v0", "-f", "logs", "--exp-id", "1",
              "-n", "50", "--no-render", cwd=tmp_path)  # fmt: skip
    assert "Loading" in out
    if egl_renders():
        zoo("record_video", "--algo", "pride", "--env", "dm_control/walker-walk-v0", "-f", "logs", "--exp-id", "1",
            "-n", "20", cwd=tmp_path, gl="egl")  # fmt: skip
        assert list((run / "videos").glob("*.mp4"))

    zoo("train", "--algo", "pride", "--env", "dm_control/walker-walk-v0", "-n", "200", "-f", "logs", "-conf", conf,
        "--eval-freq", "0", "-i", str(run / "dm_control-walker-walk-v0.zip"), "-params", *TINY, cwd=tmp_path)  # fmt: skip
    resumed = PRIDE.load(tmp_path / "logs/pride/dm_control-walker-walk-v0_2/dm_control-walker-walk-v0.zip")
    assert resumed.num_timesteps == 600 and resumed.phase.sessions == 3 and resumed.diffusion_retrains == 2
    # resumed without its replay buffer: the waiting retrain is made once B_real holds a minibatch (64 rows, step 465)
    assert resumed.next_diffusion_step == 665


@pytest.mark.slow
def test_cli_trains_pebble_on_metaworld_with_default_hyperparams(tmp_path):
    # no -conf: the shipped pebble.yml is found for sb3_pride/button-press-v3
    zoo("train", "--algo", "pebble", "--env", "sb3_pride/button-press-v3", "-n", "600", "-f", "logs",
              "--eval-freq", "600", "--eval-episodes", "1", "-params", *TINY_PEBBLE, cwd=tmp_path)  # fmt: skip
    with open(tmp_path / "logs/pebble/sb3_pride-button-press-v3_1/sb3_pride-button-press-v3/config.yml") as file:
        config = dict(yaml.load(file, Loader=yaml.UnsafeLoader))
    assert config["reward_kwargs"]["epochs"] == 10 and config["learning_rate"] == 3e-4 and config["ent_coef"] == "auto_0.1"
    model = PEBBLE.load(tmp_path / "logs/pebble/sb3_pride-button-press-v3_1/sb3_pride-button-press-v3.zip")
    assert model.num_timesteps == 600 and model.phase.asked == 30
    evaluations = np.load(tmp_path / "logs/pebble/sb3_pride-button-press-v3_1/evaluations.npz")
    assert "successes" in evaluations and evaluations["results"].shape == (1, 1)


@pytest.mark.slow
def test_optimize_two_trials_with_sqlite_storage(tmp_path):
    import optuna

    storage = f"sqlite:///{tmp_path / 'study.db'}"
    zoo("train", "--algo", "pebble", "--env", "sb3_pride/walker-walk-v0", "-n", "300", "-f", "logs",
        "-conf", str(HYPERPARAMS / "cpu/pebble.yml"), "-optimize", "--n-trials", "2", "--n-jobs", "1", "--seed", "0",
        "--sampler", "random", "--pruner", "none", "--n-evaluations", "1", "--eval-episodes", "1",
        "--storage", storage, "--study-name", "pebble-walker", "-params", *TINY_PEBBLE, cwd=tmp_path)  # fmt: skip
    study = optuna.load_study(study_name="pebble-walker", storage=storage)
    finished = [t for t in study.trials if t.state == optuna.trial.TrialState.COMPLETE]
    assert len(finished) == 2 and "feedback_interval" in finished[0].params


@pytest.mark.slow
def test_zoo_checkpoints_carry_the_replay_buffer_and_resume_with_the_journal(tmp_path):
    """--save-freq with --save-replay-buffer saves the buffer with every checkpoint; -i from a checkpoint loads it, and
    the preference journal gives back the answers given after that checkpoint instead of asking again."""
    journal = tmp_path / "preferences.jsonl"
    params = [*TINY_PEBBLE, f"preference_journal:'{journal}'"]
    conf = str(HYPERPARAMS / "cpu/pebble.yml")
    zoo("train", "--algo", "pebble", "--env", "dm_control/walker-walk-v0", "-n", "400", "-f", "logs", "-conf", conf,
        "--eval-freq", "0", "--save-freq", "150", "--save-replay-buffer", "-params", *params, cwd=tmp_path)  # fmt: skip
    run = tmp_path / "logs/pebble/dm_control-walker-walk-v0_1"
    assert (run / "rl_model_replay_buffer_300_steps.pkl").exists()
    answers = PreferenceJournal(journal).read()
    assert [entry.session for entry in answers] == [1] * 10 + [2] * 10  # sessions at steps 200 and 400

    (run / "replay_buffer.pkl").unlink()  # as if the run had been killed before its end
    out = zoo("train", "--algo", "pebble", "--env", "dm_control/walker-walk-v0", "-n", "100", "-f", "logs", "-conf", conf,
              "--eval-freq", "0", "-i", str(run / "rl_model_300_steps.zip"), "-params", *params, cwd=tmp_path)  # fmt: skip
    assert "Loading the checkpoint's replay buffer" in out
    resumed = PEBBLE.load(tmp_path / "logs/pebble/dm_control-walker-walk-v0_2/dm_control-walker-walk-v0.zip")
    assert resumed.num_timesteps == 400 and resumed.phase.sessions == 2 and resumed.feedback.journal.included == 20
    assert len(PreferenceJournal(journal).read()) == 20  # feedback session 2 came back from the journal: nothing asked again
    np.testing.assert_array_equal(resumed.preferences.labels, [entry.label for entry in answers])


@pytest.mark.slow
def test_zoo_resume_goes_on_from_the_newest_complete_checkpoint_after_a_killed_save(tmp_path):
    """--resume finds the newest checkpoint of the latest run that has its replay buffer, removes what a save killed
    midway left, and trains on to the run's n_timesteps with the journal's answers taken back, none asked again."""
    journal = tmp_path / "preferences.jsonl"
    params = [*TINY_PEBBLE, f"preference_journal:'{journal}'"]
    conf = str(HYPERPARAMS / "cpu/pebble.yml")
    train = ["train", "--algo", "pebble", "--env", "dm_control/walker-walk-v0", "-n", "400", "-f", "logs", "-conf", conf]
    train += ["--eval-freq", "0", "--save-freq", "150", "--save-replay-buffer"]
    zoo(*train, "-params", *params, cwd=tmp_path)
    run = tmp_path / "logs/pebble/dm_control-walker-walk-v0_1"
    answers = PreferenceJournal(journal).read()
    assert len(answers) == 20  # feedback sessions at steps 200 and 400
    # as if killed while its checkpoint at 300 was written: the buffer renamed into place, the model not yet, and
    # before the run's end (no final model)
    dead = int(subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True).stdout)
    (run / "rl_model_300_steps.zip").rename(run / f".rl_model_300_steps.zip.{dead}.tmp")
    (run / "replay_buffer.pkl").unlink()
    (run / "dm_control-walker-walk-v0.zip").unlink()

    out = zoo(*train, "--resume", "-params", *params, cwd=tmp_path)
    assert f"Resuming from {Path('logs/pebble/dm_control-walker-walk-v0_1/rl_model_150_steps.zip')}" in out
    assert "Loading the checkpoint's replay buffer" in out
    assert sorted(path.name for path in run.glob("*_steps*")) == [
        "rl_model_150_steps.zip",
        "rl_model_replay_buffer_150_steps.pkl",
    ]
    resumed = PEBBLE.load(tmp_path / "logs/pebble/dm_control-walker-walk-v0_2/dm_control-walker-walk-v0.zip")
    assert resumed.num_timesteps == 400  # on to the run's -n, not 400 more
    assert resumed.phase.sessions == 2 and resumed.feedback.journal.included == 20
    assert len(PreferenceJournal(journal).read()) == 20  # both sessions came back from the journal
    np.testing.assert_array_equal(resumed.preferences.labels, [entry.label for entry in answers])
    checkpoint = latest_checkpoint(tmp_path / "logs/pebble/dm_control-walker-walk-v0_2")
    assert checkpoint.step == 300 and checkpoint.replay_buffer is not None  # the resumed run's own, whole


def test_resume_finds_the_latest_run_with_a_checkpoint_or_says_there_is_none(tmp_path):
    logs = tmp_path / "logs/pebble"
    for run, steps in (("walker_1", (100, 200)), ("walker_2", (300,)), ("walker_3", ()), ("walker_10_x", ())):
        (logs / run).mkdir(parents=True)
        for step in steps:
            (logs / run / f"rl_model_{step}_steps.zip").write_bytes(b"model")
    where = ["--algo", "pebble", "--env", "walker", "-f", str(tmp_path / "logs")]
    arguments, resuming = resume_arguments([*where, "--resume", "-n", "10"])
    assert resuming and arguments == [*where, "-n", "10", "-i", str(logs / "walker_2/rl_model_300_steps.zip")]
    arguments, _ = resume_arguments([*where, f"--resume={logs / 'walker_1'}"])
    assert arguments[-1] == str(logs / "walker_1/rl_model_200_steps.zip")
    assert resume_arguments(where) == (where, False)
    with pytest.raises(SystemExit, match=r"--resume: no checkpoint rl_model_N_steps\.zip in .*walker_3"):
        resume_arguments([*where, "--resume", str(logs / "walker_3")])
    with pytest.raises(SystemExit, match=r"--resume: no checkpoint .* in .*logs/sac/walker_N"):
        resume_arguments(["--algo", "sac", "--env", "walker", "-f", str(tmp_path / "logs"), "--resume"])
    with pytest.raises(SystemExit, match="not both"):
        resume_arguments([*where, "--resume", "-i", "model.zip"])


@pytest.mark.slow
def test_zoo_takes_the_web_teacher_and_records_render_states(tmp_path):
    """`teacher:'web'` through the CLI: a WebTeacher is attached (it serves its page) and the buffer records states."""
    skip_unless(egl_renders(), "headless EGL (MUJOCO_GL=egl) to render the clips")
    params = [p for p in TINY_PEBBLE if not p.startswith("unsupervised_steps")]
    out = zoo("train", "--algo", "pebble", "--env", "sb3_pride/walker-walk-v0", "-n", "150", "-f", "logs",
              "--eval-freq", "0", "--save-replay-buffer", "-params", *params, "unsupervised_steps:1000000",
              "teacher:'web'", cwd=tmp_path, gl="egl")  # fmt: skip
    run = tmp_path / "logs/pebble/sb3_pride-walker-walk-v0_1"
    model = PEBBLE.load(run / "sb3_pride-walker-walk-v0.zip")
    assert model.teacher == "web", out
    model.load_replay_buffer(run / "replay_buffer.pkl")
    assert model.replay_buffer.render_states is not None and model.replay_buffer.render_states.shape[1:] == (1, 18)
