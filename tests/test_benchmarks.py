"""benchmarks/run.py: the grid a user gets from the command line follows the shipped YAML unless told otherwise."""

import importlib.util
from pathlib import Path

import pytest

from sb3_pride.zoo import hyperparams_dir, model_kwargs

ROOT = Path(__file__).resolve().parent.parent


@pytest.fixture(scope="module")
def run():
    spec = importlib.util.spec_from_file_location("benchmarks_run", ROOT / "benchmarks" / "run.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


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
