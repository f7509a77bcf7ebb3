"""benchmarks/run.py and plot.py: the grid a user gets from the command line follows the shipped YAML unless told
otherwise; pooled comparisons do not depend on the order of the folders."""

import importlib.util
import json
import os
import re
import sys
from pathlib import Path

import numpy as np
import pytest
import torch as th

from sb3_pride.pebble.earlier_versions import RENAMED_GENERATOR_SETTINGS as RENAMED_SETTINGS
from sb3_pride.pebble.earlier_versions import RENAMED_PEBBLE_SETTINGS
from sb3_pride.pebble.checks import STRUCTURED_SETTINGS as STRUCTURED

from sb3_pride.zoo import hyperparams_dir, model_kwargs

ROOT = Path(__file__).resolve().parent.parent


def load_script(name: str):
    """A script of benchmarks/ (not a package) imported as a module."""
    spec = importlib.util.spec_from_file_location(f"benchmarks_{name}", ROOT / "benchmarks" / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.fixture(scope="module")
def run():
    return load_script("run")


def names(run, *argv: str) -> list[str]:
    """The run names ``run.py argv`` would run, without running them."""
    return [run.run_name(spec) for spec in run.grid(run.make_parser().parse_args(argv))]


@pytest.mark.parametrize("task", ["walker-walk", "cheetah-run", "button-press-v3"])
def test_budget_and_ratio_default_to_each_tasks_yaml_entry(run, task):
    """Without --feedback and --ratios, every task runs with its own YAML's max_feedback and synthetic_ratio (u = 0.25
    on every task, 1200 queries for PEBBLE on Meta-World), not with one value for all tasks."""
    _, pride = model_kwargs(hyperparams_dir() / "cpu" / "pride.yml", run.env_id(task))
    _, pebble = model_kwargs(hyperparams_dir() / "cpu" / "pebble.yml", run.env_id(task))
    assert names(run, "--tasks", task, "--algos", "pride", "pebble", "sac") == [
        f"pride_{task}_s0_fb{pride['max_feedback']}_u{pride['synthetic_ratio']}",
        f"pebble_{task}_s0_fb{pebble['max_feedback']}",
        f"sac_{task}_s0",
    ]


def test_explicit_budget_and_ratios_span_the_grid(run):
    argv = "--tasks cheetah-run --algos pride pebble --feedback 400 200 --ratios 0.5 1.0 --seeds 0 1".split()
    assert names(run, *argv)[:5] == [
        "pride_cheetah-run_s0_fb400_u0.5",
        "pride_cheetah-run_s0_fb400_u1.0",
        "pride_cheetah-run_s0_fb200_u0.5",
        "pride_cheetah-run_s0_fb200_u1.0",
        "pebble_cheetah-run_s0_fb400",
    ]


@pytest.mark.parametrize(
    "argv, message",
    [(["--tasks", "no-such-task"], "--tasks"), (["--tier", "no-such-tier"], "--tier")],
)
def test_unknown_task_or_tier_is_named(run, argv, message):
    with pytest.raises(SystemExit, match=message):
        names(run, *argv)


@pytest.mark.parametrize(
    "argv, message",
    [
        (
            "--algos pride pebble --set synthetic_on_top=false",
            "synthetic_on_top: not an argument of PEBBLE; run --algos pride",
        ),
        ("--algos pride --set synthetic_on_tpo=false", "synthetic_on_tpo: not an argument of PRIDE"),
        ("--algos sac --set max_feedback=200", "max_feedback: set by the grid itself .use --feedback"),
        ("--algos pride --set synthetic_ratio=0.25", "synthetic_ratio: set by the grid itself .use --ratios"),
        ("--algos pebble --set seed=3", "seed: set by the grid itself .use --seeds"),
    ],
)
def test_a_set_key_an_algorithm_does_not_take_fails_before_any_run(run, argv, message):
    """--set goes to every algorithm of the grid: one that does not take the key (or a misspelt key) stops the grid
    before it starts, instead of failing in a worker later."""
    with pytest.raises(SystemExit, match=message):
        names(run, "--tasks", "walker-walk", "--tag", "x", *argv.split())
    assert (
        len(names(run, "--tasks", "walker-walk", "--tag", "x", "--algos", "pride", "pebble", "--set", "batch_size=512")) == 2
    )


@pytest.fixture(scope="module")
def plot():
    return load_script("plot")


def write_run(folder: Path, algo: str, seed: int, final_return: float, ratio: float = 0.5) -> None:
    """A finished run folder as run.py leaves it (the files plot.py reads)."""
    run = folder / f"{algo}_walker-walk_s{seed}_fb400{f'_u{ratio}' if algo == 'pride' else ''}"
    run.mkdir(parents=True)
    settings = {"algo": algo, "task": "walker-walk", "seed": seed, "feedback": 400, "ratio": ratio, "tag": ""}
    (run / "settings.json").write_text(json.dumps(settings))
    (run / "curve.csv").write_text(f"step,true_return,success\n5000,10.0,\n10000,{final_return},\n")
    (run / "result.json").write_text(json.dumps({"final_return": final_return}))


@pytest.mark.parametrize("ratios", [(0.25,), (0.5, 0.25)])
def test_the_curves_show_pride_at_u_half_or_at_the_one_u_it_ran_at(plot, tmp_path, monkeypatch, ratios):
    """A task whose PRIDE runs all have another u (cheetah-run's CPU setting, 0.25) still gets PRIDE's curve beside
    PEBBLE's; where PRIDE ran at several u, the curves show u = 0.5 and the others have the ratio figure."""
    for ratio in ratios:
        write_run(tmp_path / "runs", "pride", 0, 300.0, ratio)
    write_run(tmp_path / "runs", "pebble", 0, 250.0)
    shown = {}

    def record(groups, task, keep, column, ylabel, title, path):
        shown[path.name] = sorted(name for (_, name), runs in groups.items() if keep(runs[0]["settings"]))
        return True

    monkeypatch.setattr(plot, "plot_curves", record)
    monkeypatch.setattr(plot, "summary", lambda groups: "")
    monkeypatch.setattr(plot, "aggregate", lambda groups, out: {})
    monkeypatch.setattr(sys, "argv", ["plot.py", "--runs", str(tmp_path / "runs"), "--out", str(tmp_path / "figures")])
    plot.main()
    pride = f"PRIDE (400 queries, u={0.5 if 0.5 in ratios else 0.25})"
    assert shown["curves_walker-walk.png"] == ["PEBBLE (400 queries)", pride]
    assert ("ratio_walker-walk.png" in shown) == (len(ratios) > 1)


@pytest.mark.slow
def test_pooled_comparison_does_not_depend_on_the_order_of_the_folders(plot, tmp_path, monkeypatch, capsys):
    """plot.py --runs A B and --runs B A pool the same seeds: the bootstrap interval of P(X > Y) must be the same."""
    returns = {"pride": [303.6, 382.0, 342.0, 384.1, 415.6, 271.1], "pebble": [362.7, 411.2, 335.1, 309.5, 387.6, 362.7]}
    for algo, values in returns.items():
        for seed, value in enumerate(values):
            write_run(tmp_path / ("a" if seed in (0, 2, 3) else "b"), algo, seed, value)
    printed = []
    for folders in (["a", "b"], ["b", "a"]):  # without the sort by seed: [0.11, 0.81] and [0.11, 0.78]
        argv = ["plot.py", "--runs", *(str(tmp_path / f) for f in folders),
                "--compare", "walker-walk", "PRIDE (400 queries, u=0.5)", "PEBBLE (400 queries)"]  # fmt: skip
        monkeypatch.setattr(sys, "argv", argv)
        plot.main()
        printed.append(capsys.readouterr().out)
    assert "6 vs 6" in printed[0] and printed[0] == printed[1]


def test_only_keeps_the_named_configurations_and_names_an_unknown_one(plot, tmp_path, monkeypatch, capsys):
    """--only restricts the figures and the summary to the labels given; a label no run has is an error that lists
    the labels there are, before anything is written."""
    for seed in range(2):
        write_run(tmp_path / "runs", "pride", seed, 300.0 + seed)
        write_run(tmp_path / "runs", "pebble", seed, 250.0 + seed)
    out = tmp_path / "figures"
    argv = ["plot.py", "--runs", str(tmp_path / "runs"), "--out", str(out), "--only", "PEBBLE (400 queries)"]
    monkeypatch.setattr(sys, "argv", argv)
    plot.main()
    summary = (out / "summary.md").read_text()
    assert "PEBBLE (400 queries)" in summary and "PRIDE" not in summary
    assert (out / "curves_walker-walk.png").exists()
    monkeypatch.setattr(sys, "argv", [*argv[:-1], "PRIDE (400 queries)", "--out", str(tmp_path / "never")])
    with pytest.raises(SystemExit):
        plot.main()
    assert "--only: no runs labeled ['PRIDE (400 queries)']" in capsys.readouterr().err
    assert not (tmp_path / "never").exists()


# --- grid files, variants, provenance and the results page ---------------------------------------------------------


@pytest.fixture(scope="module")
def grid():
    return load_script("grid")


@pytest.fixture(scope="module")
def page():
    return load_script("results_page")


def write_grid(folder: Path, text: str) -> Path:
    path = folder / "grid.yml"
    path.write_text(text)
    return path


def test_a_grid_file_expands_to_run_py_specs_with_its_variants_tags(grid, tmp_path):
    """Configurations × tasks × seeds × budgets × ratios, seeds outermost; a variant's runs carry its tag (the names of
    the committed run folders), a plain algorithm's none; PEBBLE ignores the ratio."""
    path = write_grid(tmp_path, """
runs:
  - configurations: [pebble, rows_in_place, rows_on_top]
    tasks: [walker-walk]
    seeds: 0-1
    feedback: [400]
    ratios: [0.5, 0.25]
""")  # fmt: skip
    specs = grid.expand(grid.load_grid(path))
    assert [grid.run.run_name(spec) for spec in specs] == [
        "pebble_walker-walk_s0_fb400",
        "pride_walker-walk_s0_fb400_u0.5_faithful_steps4000",
        "pride_walker-walk_s0_fb400_u0.25_faithful_steps4000",
        "pride_walker-walk_s0_fb400_u0.5_on_top2",
        "pride_walker-walk_s0_fb400_u0.25_on_top2",
        "pebble_walker-walk_s1_fb400",
        "pride_walker-walk_s1_fb400_u0.5_faithful_steps4000",
        "pride_walker-walk_s1_fb400_u0.25_faithful_steps4000",
        "pride_walker-walk_s1_fb400_u0.5_on_top2",
        "pride_walker-walk_s1_fb400_u0.25_on_top2",
    ]
    in_place = specs[1]
    assert in_place["configuration"] == "rows_in_place" and in_place["tier"] == "cpu" and in_place["eval_freq"] == 5000
    assert in_place["overrides"]["generator_kwargs"]["train_steps"] == 4000
    assert specs[3]["overrides"] == {"synthetic_on_top": True}


def test_the_arms_of_a_grid_in_blocks_of_their_own_interleave_by_seed(grid, tmp_path):
    text = (
        "runs:\n  - {configurations: [pebble], tasks: [walker-walk], seeds: 0-1, feedback: [400]}\n"
        "  - {configurations: [pebble], tasks: [walker-walk], seeds: 0-1, feedback: [200]}\n"
    )
    specs = grid.expand(grid.load_grid(write_grid(tmp_path, text)))
    assert [grid.run.run_name(spec) for spec in specs] == [
        "pebble_walker-walk_s0_fb400",
        "pebble_walker-walk_s0_fb200",
        "pebble_walker-walk_s1_fb400",
        "pebble_walker-walk_s1_fb200",
    ]


def test_sac_on_each_budgets_saved_reward_is_a_run_per_budget_that_starts_from_that_runs_reward(grid, tmp_path):
    text = (
        "tier: label-response\nout: runs\nruns:\n"
        "  - {configurations: [sac_on_pebble_reward], tasks: [Pendulum-v1], seeds: [0], feedback: [16, 64]}\n"
    )
    specs = grid.expand(grid.load_grid(write_grid(tmp_path, text)))
    names = [grid.run.run_name(spec) for spec in specs]
    assert names == ["sac_Pendulum-v1_s0_on_pebble_fb16_reward", "sac_Pendulum-v1_s0_on_pebble_fb64_reward"]
    starts_from = [grid.run.needed_runs(spec, tmp_path / "runs") for spec in specs]
    assert starts_from == [
        [tmp_path / "runs" / "pebble_Pendulum-v1_s0_fb16"],
        [tmp_path / "runs" / "pebble_Pendulum-v1_s0_fb64"],
    ]


def test_budget_and_ratio_left_out_of_a_grid_are_each_tasks_yaml_values(grid, tmp_path):
    path = write_grid(
        tmp_path, "runs:\n  - {configurations: [pride, pebble], tasks: [cheetah-run, button-press-v3], seeds: [3]}\n"
    )
    names = [grid.run.run_name(spec) for spec in grid.expand(grid.load_grid(path))]
    assert names == [
        "pride_cheetah-run_s3_fb200_u0.25",
        "pebble_cheetah-run_s3_fb400",
        "pride_button-press-v3_s3_fb600_u0.25",
        "pebble_button-press-v3_s3_fb1200",
    ]


@pytest.mark.parametrize(
    "text, message",
    [
        ("runs:\n  - {configurations: [no_such_variant], tasks: [walker-walk], seeds: [0]}\n",
         "runs.0.: unknown configuration 'no_such_variant': neither an algorithm"),
        ("runs:\n  - {configurations: [pebble], tasks: [walker-walk], seeds: [0], colour: red}\n",
         "runs.0.: unknown key colour .a block takes"),
        ("jobs: 2\nruns:\n  - {configurations: [pebble], tasks: [walker-walk], seeds: [0]}\n",
         "grid.yml: unknown key jobs .a grid file takes"),
        ("runs:\n  - {configurations: [pebble], tasks: [walker-walk]}\n", "runs.0.: missing seeds"),
        ("pride_settings: {max_feedback: 100}\nruns:\n  - {configurations: [pride], tasks: [walker-walk], seeds: [0]}\n",
         "pride_settings is a mapping of PRIDE's arguments other than those its blocks set"),
        ("runs:\n  - {configurations: [pebble], tasks: [walker-walk], seeds: first}\n", "seeds must be a list"),
        ("tasks: [walker-walk]\n", "a 'runs' list of blocks"),
        ("ladder: [pebble]\nruns:\n  - {configurations: [pebble], tasks: [walker-walk], seeds: [0]}\n",
         "ladder is true, false, or a mapping of arm names"),
    ],
)  # fmt: skip
def test_a_bad_grid_file_names_the_file_and_what_is_wrong(grid, tmp_path, text, message):
    path = write_grid(tmp_path, text)
    with pytest.raises(SystemExit, match=message):
        grid.expand(grid.load_grid(path))


def test_a_variant_with_an_argument_its_algorithm_does_not_take_is_named_before_any_run(grid, tmp_path):
    path = write_grid(tmp_path, "runs:\n  - {configurations: [odd], tasks: [walker-walk], seeds: [0]}\n")
    variants = {"odd": {"algo": "pebble", "tag": "odd", "overrides": {"synthetic_ratio_typo": 1}, "description": ""}}
    specs = grid.expand(grid.load_grid(path), variants)
    with pytest.raises(SystemExit, match="variant 'odd': --set synthetic_ratio_typo: not an argument of PEBBLE"):
        grid.check(specs)


def test_every_variant_is_well_formed_and_every_committed_grid_file_expands():
    """variants.yml loads (known keys, a known algorithm each); every grid file of benchmarks/grids/ expands, and so
    does each one waiting in pending/ for its runs."""
    grid = load_script("grid")
    variants = grid.run.load_variants("cpu")
    assert {"rows_in_place", "rows_on_top", "paper", "pebble_utd2"} <= set(variants)
    assert variants["rows_in_place"]["tag"] == "faithful_steps4000" and variants["paper"]["tag"] == "paper"
    grids = ROOT / "benchmarks" / "grids"
    files = sorted(grids.glob("*.yml")) + sorted(grids.glob("pending/*.yml")) + sorted(grids.glob("repeats/*.yml"))
    assert files
    for path in files:
        assert grid.expand(grid.load_grid(path)), path


@pytest.mark.parametrize("entry", ["{algo: pride, reference: true}", "{algo: pebble, reference: yes please}"])
def test_a_reference_mark_on_a_pride_variant_or_not_a_boolean_is_refused(grid, tmp_path, monkeypatch, entry):
    """``reference`` marks PEBBLE's reference or SAC's ceiling: on a PRIDE variant, or as anything but true or false,
    it would be ignored, so variants.yml is refused, naming the variant."""
    (tmp_path / "cpu").mkdir()
    (tmp_path / "cpu" / "variants.yml").write_text(f"odd: {entry}\n")
    monkeypatch.setattr("sb3_pride.zoo.hyperparams_dir", lambda: tmp_path)
    with pytest.raises(SystemExit, match="variant 'odd': reference is true or false, on a pebble or sac variant"):
        grid.run.load_variants("cpu")


def test_the_committed_grid_files_have_all_their_runs_done(grid, capsys):
    """Each committed table's runs are in benchmarks/results/runs/ under the names the grid gives them: re-running a
    grid file finds nothing to do (and with more seeds, runs only the new ones)."""
    for path in sorted((ROOT / "benchmarks" / "grids").glob("*.yml")):
        grid.main([str(path), "--dry-run"])
        last = capsys.readouterr().out.strip().splitlines()[-1]
        assert " 0 to run" in last, f"{path.name}: {last}"


def test_the_committed_repeats_repeat_their_runs(grid, capsys):
    """Each grid of benchmarks/grids/repeats/ has its runs done, and each re-run's curve is the same, evaluation by
    evaluation, as the committed run of the same name in the folder it repeats (``benchmarks/same_seed.py``)."""
    same_seed = load_script("same_seed")
    paths = sorted((ROOT / "benchmarks" / "grids" / "repeats").glob("*.yml"))
    assert paths
    for path in paths:
        spec_grid = grid.load_grid(path)
        grid.main([str(path), "--dry-run"])
        assert " 0 to run" in capsys.readouterr().out.strip().splitlines()[-1], path.name
        out = grid.out_folder(spec_grid)
        rows = same_seed.compare(ROOT / spec_grid["repeats"], out, "*")
        assert sorted(row["name"] for row in rows) == sorted(p.name for p in out.iterdir() if p.is_dir()), path.name
        assert all(row["same"] for row in rows), [row["name"] for row in rows if not row["same"]]


#: the generator's arguments before they moved into generator_kwargs: committed runs record these names
GENERATOR_OLD_NAMES = {new: old for old, new in RENAMED_SETTINGS.items()}


#: PEBBLE's structured settings' entries and their older flat names: committed runs record these names
PEBBLE_OLD_NAMES = {place: old for old, place in RENAMED_PEBBLE_SETTINGS.items()}


def flat_kwargs(kwargs: dict) -> dict:
    """
    Constructor kwargs in one namespace: generator_kwargs, and PEBBLE's reward_kwargs, query_kwargs and
    pretraining_kwargs, spread out under the older flat names.
    """
    flat = dict(kwargs)
    for key, value in (flat.pop("generator_kwargs", None) or {}).items():
        flat[GENERATOR_OLD_NAMES.get(key, key)] = value
    for setting in ("reward_kwargs", "query_kwargs", "pretraining_kwargs"):
        for key, value in (flat.pop(setting, None) or {}).items():
            flat[PEBBLE_OLD_NAMES.get((setting, key), key)] = value
    if isinstance(flat.get("policy_kwargs"), dict):  # SB3 adds use_sde=False to what it was given
        flat["policy_kwargs"] = {k: v for k, v in flat["policy_kwargs"].items() if k != "use_sde"}
    return flat


#: what a run that does not record its algorithm's defaults ran with, where today's default differs from it (none so
#: far): {algo: {argument: the default it ran with}}
DEFAULTS_BEFORE_RECORDED: dict[str, dict] = {}


def as_before_it_existed(run, algo: str) -> dict:
    """How a PRIDE run that recorded none of these defaults ran: PEBBLE's label schedule and reward learning, the
    generator's 4000 diffusion steps per retrain."""
    if algo != "pride":
        return {}
    generator = {**run.algorithm_defaults("pride")["generator_kwargs"], "train_steps": 4000}
    reward = run.algorithm_defaults("pebble")["reward_kwargs"]
    return {"feedback_schedule": "constant", "reward_kwargs": reward, "generator_kwargs": generator}


def recorded_defaults(run, settings: dict) -> dict:
    """The defaults a committed run was made with, for today's arguments: those it recorded, else the older values
    above; today's for an argument it knew nothing of."""
    today = {**run.algorithm_defaults(settings["algo"]), **as_before_it_existed(run, settings["algo"])}
    if "defaults" in settings:
        # a structured setting recorded as None (its parts' defaults not spelled out yet) ran with its parts' defaults
        recorded = {k: v for k, v in settings["defaults"].items() if k in today and not (k in STRUCTURED and v is None)}
        return {**today, **recorded}
    return {**today, **DEFAULTS_BEFORE_RECORDED.get(settings["algo"], {})}


def as_json(value):
    """A setting as settings.json holds it (tuples as lists, anything else JSON lacks as its str)."""
    return json.loads(json.dumps(value, default=str))


def what_ran(defaults: dict, kwargs: dict) -> dict:
    """The settings a run takes from these defaults and kwargs, in one namespace: each option that is on (True, or a
    dict of some settings) spelled out whole, the settings it leaves out at their defaults."""
    options = defaults.get("option_settings", {})
    merged = {**flat_kwargs({k: v for k, v in defaults.items() if k != "option_settings"}), **flat_kwargs(kwargs)}
    for name, settings in options.items():
        given = merged.get(name)
        if given is True or isinstance(given, dict):
            merged[name] = {**settings, **(given if isinstance(given, dict) else {})}
    return as_json(merged)


@pytest.mark.slow
def in_repository(value):
    """``value`` with every absolute path into a checkout's benchmarks/results/ cut to start there."""
    if isinstance(value, str) and "/benchmarks/results/" in value:
        return value[value.index("benchmarks/results/") :]
    if isinstance(value, list):
        return [in_repository(item) for item in value]
    if isinstance(value, dict):
        return {key: in_repository(item) for key, item in value.items()}
    return value


def test_the_committed_runs_were_made_with_the_settings_their_grid_runs_today(grid):
    """For every run of every committed grid file, the settings the run recorded equal what the grid would run today
    (the task's YAML entry, the variant's overrides merged in, the algorithm's defaults for the rest): a grid re-run
    makes the same configuration, and a variant label means what the committed table's runs were."""
    mismatches = []
    for path in sorted((ROOT / "benchmarks" / "grids").glob("*.yml")):
        spec_grid = grid.load_grid(path)
        for spec in grid.expand(spec_grid):
            settings = json.loads((grid.out_folder(spec_grid) / grid.run.run_name(spec) / "settings.json").read_text())
            # a path a template named ({out}/...) is compared from benchmarks/results/ on: the checkout it ran in differs
            _, kwargs = grid.run.run_kwargs(grid.run.run_templates(spec, grid.out_folder(spec_grid)))
            kwargs = in_repository(kwargs)
            now = what_ran(grid.run.algorithm_defaults(spec["algo"]), kwargs)
            then = what_ran(recorded_defaults(grid.run, settings), in_repository(settings["kwargs"]))
            differ = {k: (now.get(k), then.get(k)) for k in {*now, *then} if now.get(k) != then.get(k)}
            if differ:
                mismatches.append(f"{grid.run.run_name(spec)}: {differ}")
    assert not mismatches, "\n".join(mismatches[:20])


def instant_workers(grid, monkeypatch, out: Path, check=None) -> list[str]:
    """Worker processes replaced by ones that write their run's result at once; returns the names started, in order."""
    started: list[str] = []

    class FakeProcess:
        returncode = 0
        pid = os.getpid()

        def __init__(self, command, **_):
            name = grid.run.run_name(json.loads(command[command.index("--worker") + 1]))
            started.append(name)
            if check is not None:
                check(name)
            (out / name / "result.json").write_text(json.dumps({"final_return": 1.0, "final_success": None}))

        def poll(self):
            return 0

    monkeypatch.setattr(grid.run.subprocess, "Popen", FakeProcess)
    monkeypatch.setattr(grid.run.time, "sleep", lambda seconds: None)
    return started


def test_a_grid_runs_only_the_runs_without_a_result(grid, tmp_path, monkeypatch):
    """Resumable: a run folder with result.json is skipped; the others start, one process each."""
    path = write_grid(tmp_path, "runs:\n  - {configurations: [pebble], tasks: [walker-walk], seeds: 0-2, feedback: [400]}\n")
    out = tmp_path / "runs"
    (out / "pebble_walker-walk_s1_fb400").mkdir(parents=True)
    (out / "pebble_walker-walk_s1_fb400" / "result.json").write_text("{}")
    started = instant_workers(grid, monkeypatch, out)
    grid.main([str(path), "--out", str(out), "--jobs", "2"])
    assert started == ["pebble_walker-walk_s0_fb400", "pebble_walker-walk_s2_fb400"]
    started.clear()
    grid.main([str(path), "--out", str(out)])
    assert started == []


def test_a_second_grid_process_leaves_the_runs_another_live_process_claimed(grid, tmp_path, monkeypatch):
    """Two grid processes on one grid share its runs: a live claim is left alone, a dead process's claim taken over."""
    import subprocess

    path = write_grid(tmp_path, "runs:\n  - {configurations: [pebble], tasks: [walker-walk], seeds: 0-2, feedback: [400]}\n")
    out = tmp_path / "runs"
    alive = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])
    gone = subprocess.Popen([sys.executable, "-c", "pass"])
    gone.wait()
    try:
        for seed, holder in ((0, alive), (1, gone)):
            (out / f"pebble_walker-walk_s{seed}_fb400").mkdir(parents=True)
            (out / f"pebble_walker-walk_s{seed}_fb400" / grid.run.CLAIM).write_text(str(holder.pid))

        def held_while_it_runs(name: str) -> None:
            assert (out / name / grid.run.CLAIM).read_text() == str(os.getpid())

        started = instant_workers(grid, monkeypatch, out, held_while_it_runs)
        grid.main([str(path), "--out", str(out), "--jobs", "2"])
        assert started == ["pebble_walker-walk_s1_fb400", "pebble_walker-walk_s2_fb400"]
        assert not (out / "pebble_walker-walk_s1_fb400" / grid.run.CLAIM).exists()  # released when done
        assert (out / "pebble_walker-walk_s0_fb400" / grid.run.CLAIM).read_text() == str(alive.pid)
    finally:
        alive.kill()
        alive.wait()
    assert grid.run.claim_run(out / "pebble_walker-walk_s0_fb400")  # its process is gone: taken over


def test_a_worker_keeps_its_claim_after_its_grid_process_is_stopped(grid, tmp_path, monkeypatch):
    """A started worker's id joins its run's claim, so that stopping the grid process that started it (its worker goes
    on) does not let another grid process start the same run again into the same folder."""
    import subprocess

    path = write_grid(tmp_path, "runs:\n  - {configurations: [pebble], tasks: [walker-walk], seeds: 0-1, feedback: [400]}\n")
    out = tmp_path / "runs"
    worker = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])
    stopped_grid = subprocess.Popen([sys.executable, "-c", "pass"])
    stopped_grid.wait()
    claims: list[str] = []

    class Process:  # a worker that writes its result at once, reading its claim while it runs
        returncode = 0
        pid = worker.pid

        def __init__(self, command, **_):
            self.name = grid.run.run_name(json.loads(command[command.index("--worker") + 1]))

        def poll(self):
            claims.append((out / self.name / grid.run.CLAIM).read_text())
            (out / self.name / "result.json").write_text(json.dumps({"final_return": 1.0, "final_success": None}))
            return 0

    monkeypatch.setattr(grid.run.subprocess, "Popen", Process)
    monkeypatch.setattr(grid.run.time, "sleep", lambda seconds: None)
    try:
        (out / "pebble_walker-walk_s0_fb400").mkdir(parents=True)
        (out / "pebble_walker-walk_s0_fb400" / grid.run.CLAIM).write_text(f"{stopped_grid.pid} {worker.pid}")
        grid.main([str(path), "--out", str(out)])
        assert not (out / "pebble_walker-walk_s0_fb400" / "result.json").exists()  # its worker lives: left to it
        assert claims == [f"{os.getpid()} {worker.pid}"]  # seed 1, run here: the worker's id beside the grid's
    finally:
        worker.kill()
        worker.wait()
    assert grid.run.claim_run(out / "pebble_walker-walk_s0_fb400")  # neither process lives: taken over


def test_a_run_that_starts_from_another_waits_for_it_and_is_not_run_when_it_failed(grid, tmp_path, monkeypatch):
    """A run reading another run's journal starts only once that run has its result; never if that run failed."""
    text = (
        "runs:\n  - {configurations: [pebble], tasks: [walker-walk], seeds: 0-2, feedback: [200]}\n"
        "  - {configurations: [pebble_prior_labels], tasks: [walker-walk], seeds: 0-2, feedback: [200]}\n"
    )
    path = write_grid(tmp_path, text)
    out = tmp_path / "runs"
    events: list[str] = []

    class FakeProcess:
        """A worker that finishes at its second poll (so that runs overlap); seed 2's plain run fails."""

        pid = os.getpid()

        def __init__(self, command, **_):
            spec = json.loads(command[command.index("--worker") + 1])
            self.name, self.polls = grid.run.run_name(spec), 0
            for needed in grid.run.needed_runs(spec, out):
                assert (needed / "result.json").exists(), f"{self.name} started before {needed.name} was done"
            events.append(f"start {self.name}")

        @property
        def returncode(self):
            return 1 if self.name == "pebble_walker-walk_s2_fb200" else 0

        def poll(self):
            self.polls += 1
            if self.polls < 2:
                return None
            if self.returncode == 0 and not (out / self.name / "result.json").exists():
                (out / self.name / "result.json").write_text(json.dumps({"final_return": 1.0, "final_success": None}))
            return self.returncode

    monkeypatch.setattr(grid.run.subprocess, "Popen", FakeProcess)
    monkeypatch.setattr(grid.run.time, "sleep", lambda seconds: None)
    with pytest.raises(SystemExit, match="2 runs failed"):
        grid.main([str(path), "--out", str(out), "--jobs", "3"])
    started = [event.split()[1] for event in events]
    # seed 0's prior run reads seed 1's journal and seed 2's reads seed 0's; seed 1's reads seed 2's, which failed
    assert "pebble_walker-walk_s0_fb200_prior_labels" in started and "pebble_walker-walk_s1_fb200_prior_labels" not in started


def test_dotted_overrides_merge_into_the_yaml_entrys_nested_dict(run):
    overrides = run.parse_overrides(["generator_kwargs.train_steps=2000", "policy_kwargs.net_arch=[64, 64]", "batch_size=512"])
    assert overrides == {"generator_kwargs": {"train_steps": 2000}, "policy_kwargs": {"net_arch": [64, 64]}, "batch_size": 512}
    base = {"generator_kwargs": {"width": 256, "train_steps": 4000}, "policy_kwargs": {"net_arch": [256, 256]}, "tau": 0.005}
    merged = run.merge(base, overrides)
    assert merged == {"generator_kwargs": {"width": 256, "train_steps": 2000}, "policy_kwargs": {"net_arch": [64, 64]},
                      "tau": 0.005, "batch_size": 512}  # fmt: skip
    assert base["generator_kwargs"]["train_steps"] == 4000  # the YAML's dict is not changed
    run.check_overrides(run.parse_overrides(["policy_kwargs.net_arch=[64]"]), ["pebble"])  # the top key is checked
    with pytest.raises(SystemExit, match="--set takes key=value"):
        run.parse_overrides(["generator_kwargs.=3"])


def git_output(*argv: str) -> str:
    """``git argv`` in this checkout (the test is skipped outside one: an installed copy)."""
    import subprocess

    try:
        return subprocess.run(["git", *argv], cwd=ROOT, capture_output=True, text=True, check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        pytest.skip("not a git checkout: the code's provenance needs git")


@pytest.mark.slow
def test_a_run_records_the_package_version_the_code_the_times_and_the_libraries(run, tmp_path):
    """settings.json: the sb3_pride version (one source: __version__, in both blocks), the git commit and whether the
    tree was dirty, the tree hash of sb3_pride/ and whether the package itself was dirty, the start and end in UTC,
    the CPU and the library versions, and the algorithm's defaults beside the arguments given."""
    from datetime import datetime, timedelta, timezone

    import sb3_pride

    spec = dict(algo="sac", task="walker-walk", seed=0, feedback=None, ratio=None, tier="cpu", eval_freq=200,
                eval_episodes=1, timesteps=200, tag="", overrides={"policy_kwargs": {"net_arch": [32, 32]}})  # fmt: skip
    before = datetime.now(timezone.utc).replace(microsecond=0)
    run.worker(spec, tmp_path / "run")
    after = datetime.now(timezone.utc)
    settings = json.loads((tmp_path / "run" / "settings.json").read_text())
    version = settings["version"]
    assert version["sb3_pride"] == sb3_pride.__version__  # the code that ran, not stale install metadata
    assert settings["system"]["sb3_pride"] == sb3_pride.__version__  # the same source in both blocks
    assert version["sb3_pride_path"] == str(Path(sb3_pride.__file__).resolve().parent)
    assert version["commit"] == git_output("-C", version["sb3_pride_path"], "rev-parse", "HEAD")
    assert isinstance(version["dirty"], bool) and isinstance(version["code_dirty"], bool)
    assert version["code_tree"] == git_output("-C", version["sb3_pride_path"], "rev-parse", "HEAD:./")
    started, finished = (datetime.fromisoformat(settings["time"][key]) for key in ("started", "finished"))
    assert started.utcoffset() == finished.utcoffset() == timedelta(0)  # UTC
    assert before <= started <= finished <= after
    assert {"Stable-Baselines3", "PyTorch", "Gymnasium", "Numpy", "mujoco", "dm-control", "metaworld", "CPU"} <= set(
        settings["system"]
    )
    assert settings["system"]["CPU"]
    assert settings["kwargs"]["policy_kwargs"]["net_arch"] == [32, 32]
    assert settings["defaults"]["learning_rate"] == 3e-4 and settings["defaults"]["buffer_size"] == 1_000_000  # SAC's
    assert json.loads((tmp_path / "run" / "result.json").read_text())["final_return"] is not None


def test_a_run_that_recorded_only_its_commit_gets_the_package_tree_of_that_commit(page):
    """Older runs record a commit and a whole-checkout dirty flag: their code is sb3_pride/'s tree at that commit,
    dirty where the checkout was; a run with no commit, or one this checkout lacks, is unrecorded."""
    head, tree = git_output("rev-parse", "HEAD"), git_output("rev-parse", "HEAD:sb3_pride")
    assert page.code_of({"version": {"commit": head, "dirty": False}}) == tree[: page.SHORT]
    assert page.code_of({"version": {"commit": head, "dirty": True}}) == tree[: page.SHORT] + "+dirty"
    recorded = {"commit": "0" * 40, "dirty": True, "code_tree": "abcdef0123" + "0" * 30, "code_dirty": False}
    assert page.code_of({"version": recorded}) == "abcdef0"  # the run's own record wins
    assert page.code_of({"version": {"commit": "f" * 40, "dirty": False}}) == page.COMMIT_NOT_HERE
    assert page.code_of({}) is None and page.code_of({"version": {"commit": None, "dirty": None}}) is None


def test_speed_takes_a_variant_label(monkeypatch):
    monkeypatch.syspath_prepend(str(ROOT / "benchmarks"))
    speed = load_script("speed")
    assert speed.parse_variant(["rows_on_top"]) == ("pride[rows_on_top]", "pride", {"synthetic_on_top": True})
    name, algo, overrides = speed.parse_variant(["pebble_utd2", "batch_size=512"])
    assert (name, algo, overrides) == ("pebble[pebble_utd2]", "pebble", {"gradient_steps": 2, "batch_size": 512})
    assert speed.parse_variant(["wide", "generator_kwargs.width=512"])[2] == {"generator_kwargs": {"width": 512}}
    with pytest.raises(SystemExit, match="--variant nothing: not a variant"):
        speed.parse_variant(["nothing"])
    # another tier's settings, as the label-response study times them
    assert speed.tier_timesteps("Pendulum-v1", "label-response") == 20_000
    assert speed.tier_kwargs("pride", "Pendulum-v1", as_tier=True, tier="label-response")["synthetic_start"] == 4000


def test_the_generated_results_files_are_in_sync_with_results_json(page):
    """benchmark.md, docs/_generated/results.md and the README's summary are rendered from results.json, the one
    file every result number comes from (re-made with python benchmarks/results_page.py)."""
    data = json.loads(page.RESULTS.read_text())
    assert page.PAGE.read_text() == page.render_page(data)
    assert page.DOCS_PAGE.read_text() == page.render_docs(data)
    readme = page.README.read_text()
    assert page.replace_block(readme, page.render_summary(data), "README.md") == readme
    results_readme = (ROOT / "benchmarks/results/README.md").read_text()
    checks = page.replace_block(results_readme, page.render_checks(data), "README.md", page.CHECKS_START, page.CHECKS_END)
    assert checks == results_readme


def test_results_json_holds_every_run_of_the_grid_files(page):
    """The data file counts exactly the committed runs of the grid files (their final returns and the budgets they
    asked, seed by seed): a run added, removed or re-run without re-making the page fails here."""
    data = json.loads(page.RESULTS.read_text())
    rows, _, _ = page.collect(sorted(page.GRIDS.glob("*.yml")))
    recorded = {(row["task"], row["configuration"], row["feedback"], row["ratio"]): row for rows_ in data["tasks"].values()
                for row in rows_}  # fmt: skip
    assert set(recorded) == set(rows)
    for key, row in rows.items():
        finals = [round(float(run["curve"]["true_return"][-1]), 3) for run in page.runs_of(row)]
        assert (recorded[key]["final_return"] or {"per_seed": []})["per_seed"] == finals, key  # None: not run yet
        # the primary return: the mean of each run's last three evaluations
        primary = [round(float(np.mean(run["curve"]["true_return"][-3:])), 3) for run in page.runs_of(row)]
        assert (recorded[key]["primary_return"] or {"per_seed": []})["per_seed"] == primary, key
        asked = [run["result"].get("feedback_asked") for run in page.runs_of(row)]
        assert recorded[key]["feedback_asked"] == asked, key
        assert recorded[key]["command"] == f"python benchmarks/grid.py {row['grid']}"


def test_each_task_opens_with_its_pebble_reference(page):
    """Every configuration of a task is compared with plain PEBBLE at the task's largest budget (the one run beside
    PRIDE's defaults where the task has it); that row comes first in the tables, whichever grid file sorts first."""
    data = json.loads(page.RESULTS.read_text())
    for task, rows in data["tasks"].items():
        for beside in (True, False):
            pebbles = [row for row in rows if row["algo"] == "pebble"
                       and (row["reference"] if beside else row["configuration"] == "pebble")]  # fmt: skip
            if pebbles:
                assert rows[0]["configuration"] == pebbles[0]["configuration"], task
                assert rows[0]["feedback"] == max(row["feedback"] for row in pebbles), task
                break


def test_a_variant_marked_reference_judges_its_task_at_its_own_length(grid, page, tmp_path):
    """A variant marked ``reference: true`` in variants.yml (PEBBLE and SAC run beside the arms, here at 150k steps) is
    its task's reference and ceiling, whatever its label; a plain PEBBLE row of another length is not compared with it."""
    for name, header, labels, returns in (
        ("check", "", "[pebble]", {"pebble": 300.0}),
        ("held_out", "timesteps: 150000\n", "[pebble_reference_steps150k, sac_reference_steps150k]",
         {"pebble": 200.0, "sac": 400.0}),
    ):  # fmt: skip
        folder = tmp_path / name
        folder.mkdir()
        block = f"{{configurations: {labels}, tasks: [window-open-v3], seeds: 0-1, feedback: [1200]}}"
        path = write_grid(folder, f"out: {folder / 'runs'}\n{header}runs:\n  - {block}\n")
        for spec in grid.expand(grid.load_grid(path)):
            run_folder = folder / "runs" / page.run.run_name(spec)
            run_folder.mkdir(parents=True)
            settings = {key: spec[key] for key in ("algo", "task", "seed", "feedback", "ratio", "tag")}
            (run_folder / "settings.json").write_text(json.dumps(settings))
            value = returns[spec["algo"]] + spec["seed"]
            curve = "".join(f"{step},{value},0.0\n" for step in (5000, 10000, 15000))
            (run_folder / "curve.csv").write_text("step,true_return,success\n" + curve)
            (run_folder / "result.json").write_text(json.dumps({"final_return": value, "feedback_asked": spec["feedback"]}))
    rows = page.recount([tmp_path / "check" / "grid.yml", tmp_path / "held_out" / "grid.yml"], None)["tasks"]["window-open-v3"]
    by_label = {row["configuration"]: row for row in rows}
    assert rows[0]["configuration"] == "pebble_reference_steps150k" and rows[0]["reference"]
    assert by_label["pebble_reference_steps150k"]["share_of_ceiling"] == 0.501  # 200.5 over 400.5
    assert by_label["pebble"]["against_pebble"] is None and by_label["pebble"]["share_of_ceiling"] is None  # 60k
    assert by_label["sac_reference_steps150k"]["against_pebble"]["p"] == 1.0


def test_the_references_run_beside_the_arms_come_before_older_ones(page, tmp_path):
    """A task with PEBBLE and SAC run beside PRIDE's defaults (pebble_reference, sac_reference) compares every row with
    those and reads each as a share of that SAC, not of the older plain rows, whichever grid file sorts first."""
    grids = []
    for name, labels, pebble_return, sac_return in (("a_old", "[pebble, sac]", 300.0, 600.0),
                                                    ("b_new", "[pebble_reference, sac_reference]", 200.0, 400.0)):  # fmt: skip
        folder = tmp_path / name
        folder.mkdir()
        block = f"{{configurations: {labels}, tasks: [walker-walk], seeds: 0-1, feedback: [400]}}"
        grids.append(write_grid(folder, f"out: {folder / 'runs'}\nruns:\n  - {block}\n"))
        tag = "_reference" if name == "b_new" else ""
        for seed in (0, 1):
            write_coded_run(folder / "runs", "pebble", seed, pebble_return, "a")
            run_name = f"sac_walker-walk_s{seed}{tag}"
            (folder / "runs" / run_name).mkdir(parents=True)
            settings = {"algo": "sac", "task": "walker-walk", "seed": seed, "feedback": None, "ratio": None,
                        "tag": tag.strip("_")}  # fmt: skip
            (folder / "runs" / run_name / "settings.json").write_text(json.dumps(settings))
            (folder / "runs" / run_name / "curve.csv").write_text("step,true_return,success\n" + "".join(
                f"{step},{sac_return},\n" for step in (5000, 10000, 15000)))  # fmt: skip
            (folder / "runs" / run_name / "result.json").write_text(json.dumps({"final_return": sac_return}))
    rows = page.recount(grids, None)["tasks"]["walker-walk"]
    assert rows[0]["configuration"] == "pebble_reference"
    by_label = {row["configuration"]: row for row in rows}
    assert by_label["pebble"]["against_pebble"]["y"].startswith("pebble_reference")
    assert by_label["pebble_reference"]["share_of_ceiling"] == 0.5 and by_label["pebble"]["share_of_ceiling"] == 0.75
    # the older rows also read against the plain PEBBLE they were first judged by, in a column of their own
    assert by_label["pebble"]["against_earlier_pebble"] is None  # the earlier reference itself
    assert by_label["pebble_reference"]["against_earlier_pebble"]["p"] == 0.0  # 200 against 300
    assert by_label["sac"]["against_earlier_pebble"]["p"] == 1.0 and by_label["sac"]["against_pebble"]["p"] == 1.0
    data = page.recount(grids, None)
    assert "| P(> earlier PEBBLE) [95% CI] |" in page.render_tables(data) and page.EARLIER_NOTE in page.render_tables(data)
    alone = page.recount(grids[:1], None)  # a task whose only PEBBLE is the plain one: no second reference
    assert all(row["against_earlier_pebble"] is None for row in alone["tasks"]["walker-walk"])
    assert "earlier PEBBLE" not in page.render_tables(alone)
    check = tmp_path / "a_check"  # an older grid of plain PEBBLE alone (a check that the tier learns the task): it
    check.mkdir()  # judged no row, so it is no earlier reference
    block = "{configurations: [pebble], tasks: [walker-walk], seeds: 0-1, feedback: [400]}"
    only_pebble = write_grid(check, f"out: {check / 'runs'}\nruns:\n  - {block}\n")
    for seed in (0, 1):
        write_coded_run(check / "runs", "pebble", seed, 300.0, "a")
    checked = page.recount([only_pebble, grids[1]], None)
    assert all(row["against_earlier_pebble"] is None for row in checked["tasks"]["walker-walk"])
    assert "earlier PEBBLE" not in page.render_tables(checked)


def test_the_readme_summary_needs_its_markers(page):
    with pytest.raises(SystemExit, match="needs one <!-- results:start --> line"):
        page.replace_block("# README\n\nno markers here\n", "| table |\n", "README.md")
    assert page.replace_block("a\n<!-- results:start -->\nold\n<!-- results:end -->\nb\n", "new\n", "x") == (
        "a\n<!-- results:start -->\nnew\n<!-- results:end -->\nb\n"
    )


def write_coded_run(folder: Path, algo: str, seed: int, primary: float, code: str | None, asked: int = 400) -> None:
    """A finished walker-walk run set to 400 queries (PRIDE at u = 0.5) that ran on the sb3_pride/ tree ``code`` * 40
    (``"a+dirty"``: tree a…a with changes of its own; ``None``: a run that recorded no commit) and asked ``asked``."""
    name = f"{algo}_walker-walk_s{seed}_fb400{'_u0.5' if algo == 'pride' else ''}"
    (folder / name).mkdir(parents=True)
    version = {"commit": None, "dirty": None}
    if code is not None:
        tree, dirty = code.split("+")[0], code.endswith("+dirty")
        version = {"commit": "1" * 40, "dirty": dirty, "code_tree": tree * 40, "code_dirty": dirty}
    settings = {"algo": algo, "task": "walker-walk", "seed": seed, "feedback": 400, "ratio": 0.5, "tag": "",
                "version": version}  # fmt: skip
    (folder / name / "settings.json").write_text(json.dumps(settings))
    evaluations = "".join(f"{step},{primary},\n" for step in (5000, 10000, 15000))
    (folder / name / "curve.csv").write_text("step,true_return,success\n" + evaluations)
    (folder / name / "result.json").write_text(json.dumps({"final_return": primary, "feedback_asked": asked}))


@pytest.mark.parametrize(
    "pebble_codes, pride_codes, differs",
    [
        (["a", "a"], ["a", "a"], False),  # one code: the comparison stands
        (["a", "a"], ["b", "b"], True),  # the arms ran on different code
        (["a", "a"], ["a", "b"], True),  # one arm's seeds on two codes
        (["a", None], ["a", "a"], True),  # a run that recorded no code
        (["a+dirty", "a+dirty"], ["a+dirty", "a+dirty"], True),  # the package had uncommitted changes: code unknown
    ],
)
def test_a_comparison_whose_arms_ran_on_different_code_is_flagged(page, tmp_path, pebble_codes, pride_codes, differs):
    """P against the PEBBLE reference carries code_differs, and the pages mark it, unless every run of both arms ran on
    one recorded sb3_pride/ tree; each row lists its runs' code."""
    path = write_grid(tmp_path, "comparisons: [[pride, pebble]]\nruns:\n  - {configurations: [pebble, pride], "
                                "tasks: [walker-walk], seeds: 0-1, feedback: [400], ratios: [0.5]}\n")  # fmt: skip
    for seed, (pebble_code, pride_code) in enumerate(zip(pebble_codes, pride_codes, strict=True)):
        write_coded_run(tmp_path / "runs", "pebble", seed, 300.0 + seed, pebble_code)
        write_coded_run(tmp_path / "runs", "pride", seed, 320.0 + seed, pride_code)
    data = page.recount([path], tmp_path / "runs")
    pebble, pride = data["tasks"]["walker-walk"]
    assert pebble["code"] == [None if code is None else code[0] * page.SHORT + code[1:] for code in pebble_codes]
    assert pride["against_pebble"]["code_differs"] is differs
    tables = page.render_tables(data)
    assert (page.CODE_NOTE in tables) is differs
    pride_line = next(line for line in tables.splitlines() if line.startswith("| PRIDE"))
    assert pride_line.count(page.CODE_MARK) == int(differs)
    assert ("aaaaaaa ×1, unrecorded ×1 |" in tables) is (None in pebble_codes)


def test_same_seed_tells_a_repeated_run_from_one_that_parted(tmp_path, monkeypatch, capsys):
    """Runs of the same name in two folders: the same curve reads "the same", a curve that differs at one evaluation
    reads "parted", a run in one folder only is left out; nothing in common is refused."""
    same_seed = load_script("same_seed")
    write_coded_run(tmp_path / "old", "pebble", 0, 300.0, None)
    write_coded_run(tmp_path / "old", "pebble", 1, 300.0, None)
    write_coded_run(tmp_path / "old", "pebble", 2, 300.0, None)  # no re-run of seed 2
    write_coded_run(tmp_path / "new", "pebble", 0, 300.0, "a")
    write_coded_run(tmp_path / "new", "pebble", 1, 300.0, "a")
    curve = tmp_path / "new" / "pebble_walker-walk_s1_fb400" / "curve.csv"
    curve.write_text(curve.read_text().replace("15000,300.0", "15000,300.5"))  # the last evaluation differs
    rows = same_seed.compare(tmp_path / "old", tmp_path / "new", "pebble_*")
    assert [(row["name"], row["same"]) for row in rows] == [
        ("pebble_walker-walk_s0_fb400", True),
        ("pebble_walker-walk_s1_fb400", False),
    ]
    text = same_seed.render(rows, tmp_path / "old", tmp_path / "new")
    assert "| pebble_walker-walk_s1_fb400 | parted | unrecorded / unrecorded | unrecorded / aaaaaaa | 300.0 / 300.2 |" in text
    assert "| walker-walk | the same | 1 | 300.0 / 300.0 |" in text
    monkeypatch.setattr(sys, "argv", ["same_seed.py", str(tmp_path / "old"), str(tmp_path / "new"), "--pattern", "sac_*"])
    with pytest.raises(SystemExit):
        same_seed.main()
    assert "no finished run named 'sac_*' is in both" in capsys.readouterr().err


def test_every_run_folder_is_counted_by_a_row_or_archived(page, tmp_path):
    """Each run in benchmarks/results/runs/ is counted in a row of a grid file, finished or still in ``pending/``
    (or was moved to the archive with a line saying why); a stray folder beside a grid's runs is listed."""
    grids = sorted(page.GRIDS.glob("*.yml")) + sorted(page.GRIDS.glob("pending/*.yml"))
    assert [folder.name for folder in page.uncounted_runs(grids)] == []
    path = write_grid(tmp_path, "runs:\n  - {configurations: [pebble], tasks: [walker-walk], seeds: [0], feedback: [400]}\n")
    write_coded_run(tmp_path / "runs", "pebble", 0, 300.0, "a")
    write_coded_run(tmp_path / "runs", "pebble", 1, 300.0, "a")  # seed 1: in no block of the grid
    assert [folder.name for folder in page.uncounted_runs([path], tmp_path / "runs")] == ["pebble_walker-walk_s1_fb400"]


# --- the statistics of the page: budgets asked, P with 50,000 resamples, the Mann–Whitney p, the best seeds left out --


PAIR_GRID = ("comparisons: [[pride, pebble]]\nruns:\n  - {configurations: [pebble, pride], tasks: [walker-walk], "
             "seeds: 0-4, feedback: [400], ratios: [0.5]}\n")  # fmt: skip


def pair_of_rows(page, tmp_path, pebble: list[float], pride: list[float], pride_asked: list[int] | None = None) -> dict:
    """results.json's data for PEBBLE and PRIDE runs (walker-walk, set to 400 queries) with these primary returns,
    seed by seed, PRIDE's runs having asked ``pride_asked``."""
    tmp_path.mkdir(parents=True, exist_ok=True)
    path = write_grid(tmp_path, PAIR_GRID)
    asked = pride_asked or [400] * len(pride)
    for seed, (a, b, n) in enumerate(zip(pebble, pride, asked, strict=True)):
        write_coded_run(tmp_path / "runs", "pebble", seed, a, "a")
        write_coded_run(tmp_path / "runs", "pride", seed, b, "a", asked=n)
    return page.recount([path], tmp_path / "runs")


@pytest.mark.parametrize(
    "asked, shown",
    [
        ([400] * 5, "400"),  # asked all it was set: the number alone
        ([300] * 5, "300 asked (400 set)"),  # asked fewer (the run ended before its budget was spent)
        ([300, 400, 350, 400, 400], "300–400 asked (400 set)"),  # the seeds asked different numbers: the range
    ],
)
def test_a_rows_budget_is_what_its_runs_asked(page, tmp_path, asked, shown):
    """A row states the budget its runs asked (result.json's feedback_asked), not the one they were set: where they
    asked fewer, the row, its comparisons' labels and the README's summary say so, with the budget set beside it."""
    data = pair_of_rows(page, tmp_path, [300.0, 310.0, 320.0, 330.0, 340.0], [350.0] * 5, pride_asked=asked)
    pebble, pride = data["tasks"]["walker-walk"]
    assert pride["feedback"] == 400 and pride["feedback_asked"] == asked
    assert page.budget_text(pride) == shown and page.budget_text(pebble) == "400"
    pride_line = next(line for line in page.render_tables(data).splitlines() if line.startswith("| PRIDE"))
    assert pride_line.split(" | ")[1] == shown
    summary_line = next(line for line in page.render_summary({**data, "tasks": {"walker-walk": [
        {**row, "summary": True} for row in (pebble, pride)]}}).splitlines() if "| PRIDE" in line)  # fmt: skip
    assert f"| {shown} |" in summary_line
    if shown != "400":
        assert pride["against_pebble"]["x"] == f"pride, {shown.replace(' asked', ' queries asked')}, u = 0.5"
        assert "| 400 |" not in pride_line
    assert page.budget_text({**pride, "feedback_asked": []}) == "400 set, not run"
    assert page.budget_text({**pride, "feedback": None}) == "—"  # SAC has no budget


def test_p_and_the_mann_whitney_p_agree_in_direction_and_flip_with_the_arms(page, tmp_path):
    """Where PRIDE clearly ends above PEBBLE, P(PRIDE > PEBBLE) is above 0.5 and the one-sided Mann–Whitney p small;
    with the arms' returns swapped P reads below 0.5 and p large. Both are in results.json and the tables."""
    low, high = [300.0, 310.0, 320.0, 330.0, 340.0], [400.0, 410.0, 420.0, 430.0, 440.0]
    better = pair_of_rows(page, tmp_path / "better", pebble=low, pride=high)["tasks"]["walker-walk"][1]["against_pebble"]
    worse = pair_of_rows(page, tmp_path / "worse", pebble=high, pride=low)["tasks"]["walker-walk"][1]["against_pebble"]
    assert better["p"] == 1.0 and better["ci95"] == [1.0, 1.0] and better["mann_whitney_p"] < 0.01
    assert worse["p"] == 0.0 and worse["mann_whitney_p"] > 0.99
    # a mixed case: ahead on most seeds, not all; swapped, the same reading mirrored
    x, y = np.array([350.0, 420.0, 300.0, 390.0, 410.0, 360.0]), np.array([320.0, 340.0, 310.0, 380.0, 305.0, 330.0])
    ahead, behind = page.improvement(x, y), page.improvement(y, x)
    assert 0.5 < ahead["p"] < 1.0 and ahead["mann_whitney_p"] < 0.5
    assert behind["p"] == pytest.approx(1.0 - ahead["p"], abs=1e-4) and behind["p"] < 0.5 < behind["mann_whitney_p"]
    tables = page.render_tables(pair_of_rows(page, tmp_path / "mixed", pebble=list(y[:5]), pride=list(x[:5])))
    entry = page.improvement(x[:5], y[:5])
    assert f"| {page.p_text({**entry, 'code_differs': False})} | {entry['mann_whitney_p']:.3f} |" in tables


CLAIMS = """claims:
  - {name: better, tasks: [walker-walk], x: [pride, 400], y: [pebble, 400], p: 0.75, lower: 0.5, seeds: 5}
  - {name: r-hat, tasks: [walker-walk], x: [pride, 400], y: [pebble, 400], metric: last_corr, seeds: 5}
  - {name: share, tasks: [walker-walk], x: [pride, 400], y: [pebble, 400], p: null, seeds: 5}
"""


def claims_of(page, tmp_path, pebble: list[float], pride: list[float], corr: tuple[float, float] = (0.5, 0.4)) -> dict:
    """results.json's data of PAIR_GRID with CLAIMS, PEBBLE's and PRIDE's runs ending at these returns and each run's
    last corr(r̂, r) at ``corr`` (PRIDE's, PEBBLE's)."""
    tmp_path.mkdir(parents=True, exist_ok=True)
    path = write_grid(tmp_path, CLAIMS + PAIR_GRID)
    for seed, (a, b) in enumerate(zip(pebble, pride, strict=True)):
        for algo, primary, last in (("pebble", a, corr[1]), ("pride", b, corr[0])):
            write_coded_run(tmp_path / "runs", algo, seed, primary, "a")
            folder = tmp_path / "runs" / f"{algo}_walker-walk_s{seed}_fb400{'_u0.5' if algo == 'pride' else ''}"
            (folder / "progress.csv").write_text(f"reward_model/true_reward_corr\n0.1\n{last}\n")
    return page.recount([path], tmp_path / "runs")


def test_a_claim_is_read_by_its_rule_and_fails_where_the_arms_are_swapped(page, tmp_path, monkeypatch):
    """A grid file's claims are read on the runs by the rules they state: a clear lead holds; the same runs with the
    arms swapped do not; until each arm has its seeds there is no verdict, only what the runs read so far. The claims'
    table goes into each page with the claims' markers, and nowhere else."""
    low, high = [300.0, 310.0, 320.0, 330.0, 340.0], [400.0, 410.0, 420.0, 430.0, 440.0]
    ahead = claims_of(page, tmp_path / "ahead", pebble=low, pride=high)["claims"]
    assert [(c["claim"], c["holds"]) for c in ahead] == [("better", True), ("r-hat", True), ("share", None)]
    reading = "| 1.00 [1.00, 1.00] | none: reported whatever it reads, 5 seeds each | reported: all its seeds are in |"
    assert ahead[2]["p"] == 1.0 and reading in page.render_claims({"claims": ahead})
    assert ahead[0]["p"] == 1.0 and ahead[0]["seeds"] == [5, 5] and ahead[1]["means"] == [0.5, 0.4]
    behind = claims_of(page, tmp_path / "behind", pebble=high, pride=low, corr=(0.4, 0.5))["claims"]
    assert [(c["claim"], c["holds"]) for c in behind] == [("better", False), ("r-hat", False), ("share", None)]
    assert behind[0]["p"] == 0.0
    # P at 0.76 with an interval reaching below 0.5 does not hold: both thresholds count
    mixed = claims_of(page, tmp_path / "mixed", pebble=[300.0, 340.0, 380.0, 420.0, 460.0],
                      pride=[345.0, 385.0, 425.0, 465.0, 500.0])  # fmt: skip
    better = mixed["claims"][0]
    assert better["p"] >= 0.75 and better["ci95"][0] <= 0.5 and better["holds"] is False
    short = claims_of(page, tmp_path / "short", pebble=low[:3], pride=high[:3])
    assert [c["holds"] for c in short["claims"]] == [None] * 3 and short["claims"][0]["p"] == 1.0
    table = page.render_claims(short)
    assert "no verdict yet: 3 and 3 of the 5 seeds" in table and "1.00 [1.00, 1.00]" in table
    assert "**holds**" in page.render_claims({"claims": ahead})
    assert "**does not hold**" in page.render_claims({"claims": behind})
    assert page.render_claims({"claims": []}) == "" and "## Claims" not in page.render_page({**short, "claims": []})
    # the configurations a claim names are described beneath the table, those with no description left out
    described = {
        "walker-walk": [
            {"configuration": "pride", "description": "PRIDE as set"},
            {"configuration": "pebble", "description": ""},
        ]
    }
    legend = page.render_claims({**short, "tasks": described})
    assert "X and Y: `pride`, PRIDE as set." in legend and "`pebble`" not in legend.split("X and Y:")[1]
    # a run that logged no corr(r̂, r) is a seed its arm lacks: no verdict on r̂, whatever the others read
    (tmp_path / "ahead" / "runs" / "pride_walker-walk_s4_fb400_u0.5" / "progress.csv").write_text("step\n1\n")
    r_hat = page.recount([tmp_path / "ahead" / "grid.yml"], tmp_path / "ahead" / "runs")["claims"][1]
    assert r_hat["seeds"] == [4, 5] and r_hat["holds"] is None
    # a claim of two tasks holds only where it holds on both
    on = {"x": "x", "y": "y", "seeds": [5, 5], "needs_seeds": 5, "rule": "r", "metric": "return", "p": 1.0, "reading": False,
          "ci95": [1.0, 1.0], "code_differs": False}  # fmt: skip
    walker = {**on, "claim": "c", "task": "walker-walk", "holds": True}

    def overall(cheetah_holds: bool | None) -> str:
        return page.render_claims({"claims": [walker, {**on, "claim": "c", "task": "cheetah-run", "holds": cheetah_holds}]})

    assert "- c: **holds** on walker-walk and cheetah-run" in overall(True)
    assert "- c: **does not hold** (it fails on cheetah-run)" in overall(False)
    assert "- c: no verdict yet (no verdict on cheetah-run)" in overall(None)
    marked, plain = tmp_path / "marked.md", tmp_path / "plain.md"
    marked.write_text(f"a\n{page.CLAIMS_START}\nold\n{page.CLAIMS_END}\nb\n")
    plain.write_text("no markers\n")
    readme = tmp_path / "README.md"
    readme.write_text(f"{page.START}\n{page.END}\n")
    monkeypatch.setattr(page, "PAGE", tmp_path / "benchmark.md")
    monkeypatch.setattr(page, "DOCS_PAGE", tmp_path / "docs" / "results.md")
    page.write_all(short, readme=readme, claim_pages=[marked, plain])
    assert marked.read_text() == f"a\n{page.CLAIMS_START}\n{table}{page.CLAIMS_END}\nb\n"
    assert plain.read_text() == "no markers\n" and "## Claims" in (tmp_path / "benchmark.md").read_text()


@pytest.mark.parametrize(
    "claim, message",
    [
        ("{name: a, tasks: [walker-walk], x: [pride, 400], y: [pebble, 400], seeds: 5}", "needs p"),
        ("{name: a, tasks: [walker-walk], x: pride, y: [pebble, 400], p: 0.75, seeds: 5}", "x is .configuration, budget"),
        ("{name: a, tasks: [walker-walk], x: [pride, 400], y: [pebble, 400], p: 75, seeds: 5}", "p is a probability"),
        ("{name: a, tasks: [walker-walk], x: [pride, 400], y: [pebble, 400], metric: last_corr, p: 0.5, seeds: 5}",
         "takes no p or lower"),
        ("{name: a, tasks: [walker-walk], x: [pride, 400], y: [pebble, 400], metric: mean, p: 0.5, seeds: 5}",
         "metric must be one of return, last_corr"),
        ("{name: a, tasks: [walker-walk], x: [pride, 400], y: [pebble, 400], p: 0.5}", "missing seeds"),
        ("{name: a, tasks: [walker-walk], x: [pride, 400], y: [pebble, 400], p: 0.5, seeds: 5, n: 1}", "unknown key n"),
        ("{name: a, tasks: walker-walk, x: [pride, 400], y: [pebble, 400], p: 0.5, seeds: 5}", "tasks is a non-empty list"),
        ("{name: a, tasks: [walker-walk], x: [pride, 400], y: [pebble, 400], p: null, lower: 0.5, seeds: 5}", "no lower"),
        ("{name: a, tasks: [walker-walk], x: [pride, true], y: [pebble, 400], p: 0.5, seeds: 5}", "x is .configuration"),
    ],
)  # fmt: skip
def test_a_bad_claim_names_the_grid_file_and_what_is_wrong(grid, page, tmp_path, claim, message):
    path = write_grid(tmp_path, f"claims:\n  - {claim}\n" + PAIR_GRID)
    with pytest.raises(SystemExit, match=message):
        grid.load_grid(path)
    (tmp_path / "one").mkdir()
    with pytest.raises(SystemExit, match="claims is a list of claims"):
        grid.load_grid(write_grid(tmp_path / "one", f"claims: {claim}\n" + PAIR_GRID))


CHECK_GRID = ("check: {check}\nruns:\n  - {{configurations: [pebble], tasks: [window-open-v3], seeds: 0-1, "
              "feedback: [1200]}}\n")  # fmt: skip


def write_checked_run(folder: Path, seed: int, success: list[float], asked: int = 1200) -> None:
    """A finished PEBBLE run on window-open set to 1200 queries, with this success rate at its evaluations."""
    name = folder / f"pebble_window-open-v3_s{seed}_fb1200"
    name.mkdir(parents=True)
    settings = {"algo": "pebble", "task": "window-open-v3", "seed": seed, "feedback": 1200, "ratio": 0.5, "tag": "",
                "version": {"commit": None, "dirty": None}}  # fmt: skip
    (name / "settings.json").write_text(json.dumps(settings))
    evaluations = "".join(f"{5000 * (i + 1)},{100.0 * i},{rate}\n" for i, rate in enumerate(success))
    (name / "curve.csv").write_text("step,true_return,success\n" + evaluations)
    (name / "result.json").write_text(json.dumps({"final_return": 0.0, "feedback_asked": asked}))


def check_of(page, tmp_path, runs: dict[int, tuple[list[float], int]],
             check: str = "{metric: success, rise: 0.2, at_least: 0.2}") -> dict:  # fmt: skip
    """The ``check`` of CHECK_GRID read on runs ``{seed: (success rates, queries asked)}``."""
    tmp_path.mkdir(parents=True)
    path = write_grid(tmp_path, CHECK_GRID.format(check=check))
    for seed, (success, asked) in runs.items():
        write_checked_run(tmp_path / "runs", seed, success, asked)
    (check,) = page.recount([path], tmp_path / "runs")["checks"]
    return check


def test_a_check_is_read_on_each_run_and_fails_on_a_run_that_does_not_learn(page, tmp_path):
    """A grid file's check passes only where every run asked its whole budget and rose by the rule (a success rate of
    exactly 0.2 counts: the means are rounded first); one run that stays flat, or asks less, fails it; with runs still
    to come and none failing there is no verdict. The pages show each run's read and the verdict."""
    learns, flat = [0.0] * 9 + [0.2, 0.2, 0.2], [0.0] * 12
    passing = check_of(page, tmp_path / "passes", {0: (learns, 1200), 1: ([0.0] * 9 + [0.4, 0.0, 0.2], 1200)})
    assert passing["passes"] is True and [r["last"] for r in passing["runs"]] == [0.2, 0.2]
    failing = check_of(page, tmp_path / "flat", {0: (learns, 1200), 1: (flat, 1200)})
    assert failing["passes"] is False and [r["passes"] for r in failing["runs"]] == [True, False]
    short = check_of(page, tmp_path / "short", {0: (learns, 1200), 1: (learns, 1100)})
    assert short["passes"] is False and short["runs"][1]["passes"] is False
    low = check_of(page, tmp_path / "low", {0: ([0.2] * 9 + [0.2, 0.2, 0.2], 1200), 1: (learns, 1200)})
    assert low["passes"] is False  # at least 0.2 but no rise
    rounded = check_of(page, tmp_path / "rounded", {0: ([0.0] * 9 + [0.0, 0.0, 0.6], 1200), 1: (learns, 1200)})
    assert rounded["passes"] is True  # NumPy's mean of 0, 0 and 0.6 is 0.19999999999999998
    rising = {0: ([0.0] * 9 + [0.4] * 3, 1200), 1: ([0.0] * 9 + [0.6] * 3, 1200)}
    assert check_of(page, tmp_path / "reached", rising, "{metric: success, rise: 0.2, at_least: 0.4}")["passes"] is True
    below = check_of(page, tmp_path / "below", rising, "{metric: success, rise: 0.2, at_least: 0.5}")
    assert [r["passes"] for r in below["runs"]] == [False, True]  # seed 0 rose by 0.4 but ends below 0.5
    waiting = check_of(page, tmp_path / "waiting", {0: (learns, 1200)})
    assert waiting["passes"] is None and waiting["planned"] == 2
    assert check_of(page, tmp_path / "waiting_flat", {1: (flat, 1200)})["passes"] is False  # decided without seed 0
    table = page.render_checks({"checks": [passing, failing, waiting]})
    assert "| `grid.yml` | window-open-v3 | 1 | 1200 | success rate | 0.00 | 0.00 | no |" in table
    assert table.count("**passes** (2 of 2 runs read)") == 1 and "**fails** (2 of 2 runs read)" in table
    assert "no verdict yet: 1 of its 2 runs are in" in table
    assert "| 1100 (1200 set) |" in page.render_checks({"checks": [short]})
    too_short = "check on success: the run pebble_window-open-v3_s0_fb1200 has 3 evaluations of it, the check needs 6"
    with pytest.raises(SystemExit, match=re.escape(too_short)):
        check_of(page, tmp_path / "too_short", {0: ([0.0, 0.0, 0.2], 1200)})
    assert page.render_checks({"checks": []}) == "" and "## Checks" in page.render_page(
        {**page.recount([tmp_path / "passes" / "grid.yml"], tmp_path / "passes" / "runs"), "claims": []}
    )


@pytest.mark.parametrize(
    "check, message",
    [
        ("{metric: success}", "missing rise"),
        ("{metric: reward, rise: 0.2}", "metric must be one of true_return, success"),
        ("{metric: success, rise: high}", "rise is a number"),
        ("{metric: success, rise: 0.2, last: 3}", "unknown key last"),
        ("[success, 0.2]", "a check is a mapping"),
        ("{metric: success, rise: true}", "rise is a number"),
        ("{metric: success, rise: 0.2, at_least: null}", "at_least is a number"),
        ("{metric: success, rise: .nan}", "rise is a number"),
        ("{metric: success, rise: -0.2}", "rise is how far .* 0 or more"),
    ],
)
def test_a_bad_check_names_the_grid_file_and_what_is_wrong(grid, tmp_path, check, message):
    with pytest.raises(SystemExit, match=f"grid.yml, check: {message}"):
        grid.load_grid(write_grid(tmp_path, f"check: {check}\n" + PAIR_GRID))


def test_a_claim_naming_a_row_no_grid_makes_is_named(page, tmp_path):
    path = write_grid(tmp_path, "claims:\n  - {name: a, tasks: [walker-walk], x: [pride, 200], y: [pebble, 400], "
                                "p: 0.5, seeds: 2}\n" + PAIR_GRID)  # fmt: skip
    with pytest.raises(SystemExit, match=r"claim 'a': names pride at 200 queries on walker-walk, and the grid files make no"):
        page.recount([path], tmp_path / "runs")


def test_a_comparison_is_read_again_without_the_better_arms_best_seeds(page):
    """without_best: P with X's best seed, then its best two, left out, naming them; a lead that rests on one seed
    reads so (here the best seed carries it: without it, P falls to a half or below)."""
    x = np.array([300.0, 500.0, 305.0, 310.0])  # seed 11 carries the lead
    y = np.array([306.0, 309.0, 302.0, 308.0])
    entry = page.improvement(x, y, seeds_x=[10, 11, 12, 13])
    assert entry["p"] > 0.5
    best_one, best_two = entry["without_best"]
    assert best_one["left_out"] == [11] and best_one["seeds"] == [3, 4] and best_one["p"] < 0.5
    assert best_two["left_out"] == [11, 13] and best_two["seeds"] == [2, 4]
    assert best_one["p"] == page.improvement(x[[0, 2, 3]], y)["p"]
    assert [reduced["left_out"] for reduced in page.improvement(x[:2], y, seeds_x=[10, 11])["without_best"]] == [[11]]
    text = page.without_best_text({**entry, "code_differs": True})
    assert text == f"{page.p_text(best_one, mark=False)} / {page.p_text(best_two, mark=False)}" and page.CODE_MARK not in text


def test_p_is_drawn_from_50000_resamples_and_the_seed_is_recorded(page):
    """The evidence protocol's 50,000 resamples, one named constant; results.json records them and the seed."""
    assert page.RESAMPLES == 50_000
    data = json.loads(page.RESULTS.read_text())
    assert data["bootstrap"]["resamples"] == page.RESAMPLES and data["bootstrap"]["seed"] == page.BOOTSTRAP_SEED
    assert "50,000 resamples" in data["statistics"]
    assert "50,000 resamples" in page.README.read_text().split(page.START)[1].split(page.END)[0]


@pytest.mark.parametrize("sizes", [(5, 5), (4, 7), (3, 2), (1, 3)])
def test_the_bootstrap_draws_what_rliable_draws(page, sizes):
    """P and its interval equal rliable's get_interval_estimates with metrics.probability_of_improvement from the same
    NumPy seed, exactly (ties and unequal seed counts included): the page's vectorised bootstrap is rliable's."""
    from rliable import library as rly
    from rliable import metrics

    rng = np.random.default_rng(sum(sizes))
    x, y = (np.round(rng.normal(300.0, 40.0, size=n), -1) for n in sizes)  # rounded: some ties
    np.random.seed(7)
    point, interval = rly.get_interval_estimates({"k": [x[:, None], y[:, None]]}, metrics.probability_of_improvement,
                                                 reps=400)  # fmt: skip
    p, bounds = page.bootstrap_improvement(x, y, reps=400, seed=7)
    assert p == float(point["k"]) and bounds == [float(bound[0]) for bound in interval["k"]]


def test_every_committed_p_reads_what_its_rows_seeds_give(page):
    """Each P, interval and Mann–Whitney p in results.json is recomputed from the two rows' primary returns there, with
    the recorded resamples and seed: a stale or hand-edited number fails here."""
    data = json.loads(page.RESULTS.read_text())
    bootstrap = data["bootstrap"]
    for task, rows in data["tasks"].items():
        by_label = {page.label_of(row): row for row in rows}
        entries = [row["against_pebble"] for row in rows if row["against_pebble"]]
        for entry in entries + [c for c in data["comparisons"] if c["task"] == task]:
            x, y = (np.array(by_label[entry[side]]["primary_return"]["per_seed"]) for side in ("x", "y"))
            again = page.improvement(x, y, reps=bootstrap["resamples"], seed=bootstrap["seed"])
            assert {k: entry[k] for k in again} == again, (task, entry["x"], entry["y"])


def test_each_row_reads_as_a_share_of_the_sac_ceiling(page, tmp_path):
    """A row's return over SAC's on the true reward (the task's ceiling, runs of the same length); — without SAC runs.
    A share that cannot tell a row from the ceiling would read 1 for both: PEBBLE at half of SAC reads 0.5."""
    grid_text = "runs:\n  - {configurations: [pebble, sac], tasks: [walker-walk], seeds: 0-1, feedback: [400]}\n"
    path = write_grid(tmp_path, grid_text)
    for seed in (0, 1):
        write_coded_run(tmp_path / "runs", "pebble", seed, 300.0, "a")
        name = f"sac_walker-walk_s{seed}"
        (tmp_path / "runs" / name).mkdir(parents=True)
        settings = {"algo": "sac", "task": "walker-walk", "seed": seed, "feedback": None, "ratio": None, "tag": ""}
        (tmp_path / "runs" / name / "settings.json").write_text(json.dumps(settings))
        (tmp_path / "runs" / name / "curve.csv").write_text("step,true_return,success\n" + "".join(
            f"{step},600.0,\n" for step in (5000, 10000, 15000)))  # fmt: skip
        (tmp_path / "runs" / name / "result.json").write_text(json.dumps({"final_return": 600.0}))
    pebble, sac = page.recount([path], tmp_path / "runs")["tasks"]["walker-walk"]
    assert pebble["share_of_ceiling"] == 0.5 and sac["share_of_ceiling"] == 1.0
    assert page.share_text(pebble) == "0.50" and page.share_text({**pebble, "share_of_ceiling": None}) == "—"
    (tmp_path / "alone").mkdir()
    only_pebble = write_grid(tmp_path / "alone", "runs:\n  - {configurations: [pebble], tasks: [walker-walk], seeds: 0-1}\n")
    alone = page.recount([only_pebble], tmp_path / "runs")["tasks"]["walker-walk"][0]
    assert alone["share_of_ceiling"] is None


@pytest.mark.slow
def test_a_run_keeps_its_journal_and_r_hat_for_runs_that_start_from_them(run, tmp_path):
    """A PEBBLE run leaves preferences.jsonl and reward.pt; a run named by templates starts from the one, SAC the other."""
    tiny = {"learning_starts": 50, "unsupervised_steps": 50, "feedback_interval": 50, "queries_per_session": 5,
            "segment_length": 10, "batch_size": 32, "policy_kwargs": {"net_arch": [32, 32]},
            "reward_kwargs": {"net_arch": [32, 32], "epochs": 2}}  # fmt: skip
    base = dict(task="walker-walk", feedback=10, ratio=None, tier="cpu", eval_freq=200, eval_episodes=1, timesteps=200)
    donor = dict(base, algo="pebble", seed=1, tag="", overrides=tiny)
    run.worker(donor, tmp_path / run.run_name(donor))
    assert (tmp_path / "pebble_walker-walk_s1_fb10" / "preferences.jsonl").exists()
    prior = {"prior_preferences": ["{out}/pebble_{task}_s{next_seed}_fb{feedback}/preferences.jsonl"]}
    reusing = dict(base, algo="pebble", seed=0, next_seed=1, tag="prior", overrides={**tiny, **prior})
    run.worker(reusing, tmp_path / run.run_name(reusing))
    settings = json.loads((tmp_path / "pebble_walker-walk_s0_fb10_prior" / "settings.json").read_text())
    assert settings["kwargs"]["prior_preferences"] == [str(tmp_path / "pebble_walker-walk_s1_fb10" / "preferences.jsonl")]
    journal = (tmp_path / "pebble_walker-walk_s0_fb10_prior" / "preferences.jsonl").read_text()
    assert json.loads(journal.splitlines()[0])["journal"]["prior_preferences"][0]["labels"] == 10
    learner = dict(base, algo="sac", seed=0, tag="on_reward", overrides={"policy_kwargs": {"net_arch": [32, 32]}},
                   learned_reward="{out}/pebble_{task}_s1_fb{feedback}/reward.pt")  # fmt: skip
    learner["feedback"] = 10
    run.worker(learner, tmp_path / run.run_name(learner))
    assert json.loads((tmp_path / run.run_name(learner) / "result.json").read_text())["final_return"] is not None


def test_each_rows_last_corr_is_its_runs_last_logged_correlation(page):
    """The page's corr(r̂, r) of PEBBLE at 400 on walker-walk, recounted from each run's progress.csv."""
    import csv

    data = json.loads((ROOT / "benchmarks/results/results.json").read_text())
    row = next(r for r in data["tasks"]["walker-walk"] if r["configuration"] == "pebble" and r["feedback"] == 400)
    recounted = []
    for name in row["runs"]:
        with open(ROOT / "benchmarks/results/runs" / name / "progress.csv", newline="") as file:
            logged = [line["reward_model/true_reward_corr"] for line in csv.DictReader(file)]
        recounted.append(float([value for value in logged if value][-1]))
    assert row["last_corr"]["per_seed"] == [round(value, 3) for value in recounted]
    sac = next(r for r in data["tasks"]["walker-walk"] if r["algo"] == "sac")
    assert sac["last_corr"] is None  # SAC learns no r̂


def test_print_shows_a_grids_tables_and_claims_and_writes_nothing(page, tmp_path, monkeypatch, capsys):
    """``--grids … --print``: a grid's rows and claims as its runs read so far (one waiting in pending/), no file
    written."""
    path = write_grid(tmp_path, CLAIMS + PAIR_GRID.replace("seeds: 0-4", "seeds: 0-1"))
    written = {file: file.stat().st_mtime_ns for file in (page.RESULTS, page.PAGE, page.README)}
    monkeypatch.setattr(sys, "argv", ["results_page.py", "--grids", str(path), "--print"])
    page.main()
    shown = capsys.readouterr().out
    assert "## walker-walk" in shown and "## Claims" in shown and "| better | walker-walk |" in shown
    assert {file: file.stat().st_mtime_ns for file in written} == written


def test_grids_without_print_is_refused_and_writes_nothing(page, tmp_path, monkeypatch, capsys):
    """The pages hold every grid's rows: ``--grids`` alone would write them from a subset, so it is refused."""
    path = write_grid(tmp_path, CLAIMS + PAIR_GRID.replace("seeds: 0-4", "seeds: 0-1"))
    written = {file: file.stat().st_mtime_ns for file in (page.RESULTS, page.PAGE, page.README)}
    monkeypatch.setattr(sys, "argv", ["results_page.py", "--grids", str(path)])
    with pytest.raises(SystemExit):
        page.main()
    assert "--grids needs --print" in capsys.readouterr().err
    assert {file: file.stat().st_mtime_ns for file in written} == written


def test_speed_records_the_code_it_timed_and_when(monkeypatch, tmp_path):
    """speed.py's --out file holds the code of sb3_pride/ read when the timing began, and its start and end (UTC)."""
    monkeypatch.syspath_prepend(str(ROOT / "benchmarks"))
    speed = load_script("speed")
    out = tmp_path / "speed.json"
    monkeypatch.setattr(sys, "argv", ["speed.py", "--algos", "sac", "--timesteps", "200", "--repeats", "1", "--out", str(out)])
    speed.main()
    report = json.loads(out.read_text())
    assert report["started"] <= report["ended"] and report["started"].endswith("+00:00")
    assert set(report["version"]) >= {"sb3_pride", "commit", "code_tree", "code_dirty"}
    assert len(report["runs"]["sac"]) == 1


def test_a_paced_teacher_takes_its_time_and_refuses_bad_settings(monkeypatch):
    """benchmarks/paced_teacher.py: a scripted teacher at a person's pace, what waiting for answers costs is measured
    with; a bad pace or a teacher that is not callable is refused, naming it."""
    monkeypatch.syspath_prepend(str(ROOT / "benchmarks"))
    paced = load_script("paced_teacher")
    from sb3_pride.common.teachers import ScriptedTeacher

    oracle = ScriptedTeacher.from_preset("oracle")
    for bad in (-1.0, float("inf"), "3"):
        with pytest.raises(ValueError, match="seconds_per_answer"):
            paced.PacedTeacher(oracle, bad)
    with pytest.raises(ValueError, match="teacher must be a Teacher"):
        paced.PacedTeacher("oracle", 1.0)
    assert paced.PacedTeacher(oracle, 0.5).seconds_per_answer == 0.5


@pytest.mark.slow
@pytest.mark.parametrize("algo", ["pebble", "pride"])
def test_critic_diagnostics_are_logged_after_pretraining_and_change_no_training_run(tiny_kwargs, algo, tmp_path, monkeypatch):
    """benchmarks/diagnostics.py: train/critic_loss_real and train/q_real (the critic on real-only minibatches, so
    PRIDE's mixed batches and PEBBLE's real ones compare like for like) and train/q, logged from the first feedback
    session on, from the callback's own generators: a run that logs them trains exactly as one that does not."""
    import pandas as pd
    from stable_baselines3.common.logger import configure

    from sb3_pride import PEBBLE, PRIDE
    from tests.test_pride import TINY_DIFFUSION

    monkeypatch.syspath_prepend(str(ROOT / "benchmarks"))
    diagnostics = load_script("diagnostics")
    extra = TINY_DIFFUSION if algo == "pride" else {}

    def run(callbacks, folder):
        model = (PRIDE if algo == "pride" else PEBBLE)("MlpPolicy", "Pendulum-v1", seed=0, **tiny_kwargs, **extra)
        model.set_logger(configure(str(folder), ["csv"]))
        model.learn(600, callback=callbacks, log_interval=1)  # the first session at step 300
        return th.nn.utils.parameters_to_vector(model.critic.parameters()).detach()

    logged = run([diagnostics.CriticDiagnostics(interval=20, seed=1)], tmp_path / "on")
    th.testing.assert_close(logged, run([], tmp_path / "off"), rtol=0, atol=0)
    progress = pd.read_csv(tmp_path / "on" / "progress.csv")
    for key in ("train/critic_loss_real", "train/q_real", "train/q"):
        values = progress[[key, "time/total_timesteps"]].dropna()
        assert len(values) >= 1 and np.all(np.isfinite(values[key]))
        assert values["time/total_timesteps"].min() > 300  # never during pre-training, where r_int is the reward
    assert (progress["train/critic_loss_real"].dropna() >= 0).all()


def test_a_comparison_across_cpu_kinds_is_marked_as_one_across_code_versions(page):
    """Seeds repeat a run only on one CPU kind: a P whose arms ran on two kinds carries the mark of mixed code."""
    from results_recount import cpu_differs

    assert not cpu_differs(["AMD EPYC", "AMD EPYC"], ["AMD EPYC"]) and not cpu_differs(["AMD EPYC"], [None])
    assert cpu_differs(["AMD EPYC"], ["Intel(R) Xeon(R) Processor"]) and cpu_differs(["AMD EPYC", "Intel"], [])
    entry = {"p": 0.6, "ci95": [0.4, 0.8], "mann_whitney_p": 0.2, "code_differs": False, "cpu_differs": True}
    assert page.p_text(entry).endswith(page.CODE_MARK) and "more than one CPU kind" in page.CODE_NOTE
    assert not page.p_text({**entry, "cpu_differs": False}).endswith(page.CODE_MARK)


def test_a_ladder_asks_each_budget_in_the_same_number_of_sessions(grid, run, tmp_path):
    """A grid's ``sessions``: every budget of a ladder asked in that many feedback sessions (one schedule shape), its
    value checked; the worker sets queries_per_session = ceil(budget / sessions)."""
    path = write_grid(
        tmp_path,
        "sessions: 5\nruns:\n  - {configurations: [pebble], tasks: [walker-walk], seeds: 0, feedback: [8, 64, 100]}\n",
    )
    specs = grid.expand(grid.load_grid(path))
    assert [spec["sessions"] for spec in specs] == [5, 5, 5]
    assert [-(-spec["feedback"] // spec["sessions"]) for spec in specs] == [2, 13, 20]
    (tmp_path / "bad").mkdir()
    bad = write_grid(tmp_path / "bad", "sessions: 0\nruns:\n  - {configurations: [pebble], tasks: [walker-walk], seeds: 0}\n")
    with pytest.raises(grid.GridError, match="sessions is a positive integer"):
        grid.load_grid(bad)
