"""benchmarks/run.py and plot.py: the grid a user gets from the command line follows the shipped YAML unless told
otherwise; pooled comparisons do not depend on the order of the folders."""

import importlib.util
import json
import sys
from pathlib import Path

import pytest

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
    on cheetah-run, 2000 queries on Meta-World), not with one value for all tasks."""
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


def write_run(folder: Path, algo: str, seed: int, final_return: float) -> None:
    """A finished run folder as run.py leaves it (the files plot.py reads)."""
    run = folder / f"{algo}_walker-walk_s{seed}_fb400"
    run.mkdir(parents=True)
    settings = {"algo": algo, "task": "walker-walk", "seed": seed, "feedback": 400, "ratio": 0.5, "tag": ""}
    (run / "settings.json").write_text(json.dumps(settings))
    (run / "curve.csv").write_text(f"step,true_return,success\n5000,10.0,\n10000,{final_return},\n")
    (run / "result.json").write_text(json.dumps({"final_return": final_return}))


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
