"""
Run a grid file: configurations × tasks × seeds × feedback budgets (× PRIDE's synthetic ratios), resumably.

    python benchmarks/grid.py benchmarks/grids/walker-walk-15-seeds.yml            # one run per core
    python benchmarks/grid.py benchmarks/grids/walker-walk-15-seeds.yml --dry-run  # list the runs, and which are done

A grid file (YAML) holds a few settings and one or more blocks, each a product:

    description: what the grid measures
    tier: cpu                          # hyperparams/<tier>/ (default: cpu)
    out: benchmarks/results/runs       # run folders, relative to the repository (default: this one)
    eval_freq: 5000                    # optional: evaluation every so many steps (default 5000)
    eval_episodes: 5                   # optional (default 5)
    timesteps: 0                       # optional: 0 keeps each task's n_timesteps
    summary: true                      # optional: its rows go into the README's summary table
    comparisons: [[rows_on_top, rows_in_place]]   # optional: P(X > Y) of two configurations of a block's task
    pride_settings: {feedback_schedule: constant}  # optional: every PRIDE run's arguments on top of the tier's YAML,
                                                   # beneath its variant's (a grid made before a default changed)
    sessions: 5                        # optional: the budget asked in this many feedback sessions at every budget of a
                                       # ladder (queries_per_session = ceil(budget / sessions): PEBBLE's constant
                                       # schedule; PRIDE's front-loaded one asks it in five sessions at any budget)
    ladder: true                       # optional: a label-response ladder, read by benchmarks/label_response.py into
                                       # the pages' "How many labels" section (SAC: the ceiling; sac_on_*: r̂ alone);
                                       # or {pebble: pebble_steps30k, ...}: the arms' names where the configurations'
                                       # labels differ (the arm named pebble sets the target)
    repeats: benchmarks/results/runs  # optional: runs of the same names it re-runs (benchmarks/grids/repeats/), to
                                       # check with benchmarks/same_seed.py that they repeat evaluation by evaluation
    claims:                            # optional: rules written before the runs, read by benchmarks/results_page.py
      - name: half the labels
        tasks: [walker-walk]
        x: [rows_in_place, 200]        # a configuration and the budget it was set (null for SAC)
        y: [pebble, 400]
        metric: return                 # return (P(X > Y), its 95% interval) or last_corr (mean last corr(r̂, r))
        p: 0.75                        # return: X holds if P(X > Y) >= p ... (null: reported whatever it reads)
        lower: 0.5                     # ... and the interval's lower end is above this (optional)
        seeds: 10                      # no verdict until each arm has this many finished seeds
    check:                             # optional: whether each run learns its task (a task checked before it is held
      metric: success                  # out), read by benchmarks/results_page.py: curve.csv's true_return or success;
      rise: 0.2                        # a run passes where it asked its whole budget and the mean of its last three
      at_least: 0.2                    # evaluations is at least rise above its first three's, and at least at_least
                                       # (optional); the check passes where every run of the grid passes
    runs:
      - configurations: [pebble, rows_in_place]   # a variant label of hyperparams/<tier>/variants.yml or an algo
        tasks: [walker-walk]
        seeds: 0-14                    # a list, or "first-last"
        feedback: [400]                # optional: each task's YAML max_feedback when left out
        ratios: [0.5]                  # optional: PRIDE's synthetic_ratio, each task's YAML value when left out

Each run is ``benchmarks/run.py``'s: its folder is named by ``run_name()`` and a run whose ``result.json`` exists is
skipped, so a grid cut off half way picks up where it stopped, and the committed runs of a grid count as done. Seeds
are outermost, across blocks too: every cell gets its first seed before any gets its second. A run folder being run holds a ``claim``
(the grid process's id and its worker's), so a second ``grid.py`` started on the same grid leaves those runs and adds its
workers, also where the first ``grid.py`` was stopped and its running workers left to finish.
"""

import argparse
import itertools
import math
import os
import sys
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent))

import run

GRID_KEYS = {
    "description",
    "tier",
    "out",
    "eval_freq",
    "eval_episodes",
    "timesteps",
    "summary",
    "comparisons",
    "pride_settings",
    "sessions",
    "ladder",
    "claims",
    "check",
    "repeats",
    "runs",
}
#: what a claim of a grid file takes, and the metrics it can be read on
CLAIM_KEYS = {"name", "tasks", "x", "y", "metric", "p", "lower", "seeds"}
CLAIM_METRICS = ("return", "last_corr")
#: what a grid file's check takes, and the columns of a run's curve.csv it can be read on
CHECK_KEYS = {"metric", "rise", "at_least"}
CHECK_METRICS = ("true_return", "success")
BLOCK_KEYS = {"configurations", "tasks", "seeds", "feedback", "ratios"}


class GridError(SystemExit):
    """A grid file that cannot be run, with the file and what is wrong in the message."""


def parse_seeds(value: Any, where: str) -> list[int]:
    """``[0, 1, 2]``, ``3`` or ``"0-14"`` into a list of seeds."""
    if isinstance(value, int):
        return [value]
    if isinstance(value, str):
        first, sep, last = value.partition("-")
        if sep and first.strip().isdigit() and last.strip().isdigit():
            return list(range(int(first), int(last) + 1))
    elif isinstance(value, list) and value and all(isinstance(seed, int) for seed in value):
        return value
    raise GridError(f"{where}: seeds must be a list of integers or 'first-last', got {value!r}")


def as_list(value: Any, where: str, key: str) -> list:
    values = value if isinstance(value, list) else [value]
    if not values:
        raise GridError(f"{where}: {key} is empty")
    return values


def load_grid(path: Path) -> dict[str, Any]:
    """A grid file, its keys checked: an unknown key or a block without configurations, tasks or seeds fails here."""
    import yaml

    try:
        grid = yaml.safe_load(Path(path).read_text())
    except FileNotFoundError:
        raise GridError(f"no grid file {path}") from None
    if not isinstance(grid, dict) or "runs" not in grid:
        raise GridError(f"{path}: a grid file is a mapping with a 'runs' list of blocks")
    unknown = sorted(set(grid) - GRID_KEYS)
    if unknown:
        raise GridError(f"{path}: unknown key {', '.join(unknown)} (a grid file takes {', '.join(sorted(GRID_KEYS))})")
    for i, block in enumerate(as_list(grid["runs"], str(path), "runs")):
        where = f"{path}, runs[{i}]"
        if not isinstance(block, dict):
            raise GridError(f"{where}: a block is a mapping of {', '.join(sorted(BLOCK_KEYS))}")
        unknown = sorted(set(block) - BLOCK_KEYS)
        if unknown:
            raise GridError(f"{where}: unknown key {', '.join(unknown)} (a block takes {', '.join(sorted(BLOCK_KEYS))})")
        missing = sorted({"configurations", "tasks", "seeds"} - set(block))
        if missing:
            raise GridError(f"{where}: missing {', '.join(missing)}")
    settings = grid.get("pride_settings", {})
    if not isinstance(settings, dict) or {"max_feedback", "synthetic_ratio"} & set(settings):
        raise GridError(
            f"{path}: pride_settings is a mapping of PRIDE's arguments other than those its blocks set "
            "(max_feedback, synthetic_ratio: feedback, ratios)"
        )
    sessions = grid.get("sessions")
    if sessions is not None and not (type(sessions) is int and sessions >= 1):
        raise GridError(f"{path}: sessions is a positive integer (the feedback sessions that ask a budget), got {sessions!r}")
    ladder = grid.get("ladder", False)
    names_arms = isinstance(ladder, dict) and all(isinstance(v, str) for v in [*ladder, *ladder.values()])
    if ladder not in (True, False) and not names_arms:
        raise GridError(
            f"{path}: ladder is true, false, or a mapping of arm names to the configurations that run them "
            f"(pebble: pebble_steps30k, ...), got {ladder!r}"
        )
    if not isinstance(grid.get("claims", []), list):
        raise GridError(f"{path}: claims is a list of claims, each a mapping of {', '.join(sorted(CLAIM_KEYS))}")
    for i, claim in enumerate(grid.get("claims") or []):
        check_claim(claim, f"{path}, claims[{i}]")
    if "check" in grid:
        check_task_check(grid["check"], f"{path}, check")
    grid["path"] = Path(path)
    return grid


def check_keys(value: Any, where: str, what: str, keys: set[str], required: set[str]) -> None:
    """``value`` is a mapping of ``keys`` holding every one of ``required``; else an error naming ``where``."""
    if not isinstance(value, dict):
        raise GridError(f"{where}: a {what} is a mapping of {', '.join(sorted(keys))}, got {value!r}")
    unknown = sorted(set(value) - keys)
    if unknown:
        raise GridError(f"{where}: unknown key {', '.join(unknown)} (a {what} takes {', '.join(sorted(keys))})")
    missing = sorted(required - set(value))
    if missing:
        raise GridError(f"{where}: missing {', '.join(missing)}")


def check_task_check(check: Any, where: str) -> None:
    """A grid file's check (see the module's docstring), its keys and values checked."""
    check_keys(check, where, "check", CHECK_KEYS, {"metric", "rise"})
    if check["metric"] not in CHECK_METRICS:
        raise GridError(f"{where}: metric must be one of {', '.join(CHECK_METRICS)}, got {check['metric']!r}")
    for key in ("rise", "at_least"):
        if key in check and not (type(check[key]) in (int, float) and math.isfinite(check[key])):
            raise GridError(f"{where}: {key} is a number (in the metric's units), got {check[key]!r}")
    if check["rise"] < 0:
        raise GridError(
            f"{where}: rise is how far the last evaluations must rise above the first: 0 or more, got {check['rise']!r}"
        )


def check_claim(claim: Any, where: str) -> None:
    """A claim of a grid file (see the module's docstring), its keys and values checked."""
    check_keys(claim, where, "claim", CLAIM_KEYS, {"name", "tasks", "x", "y", "seeds"})
    for side in ("x", "y"):
        value = claim[side]
        budget = value[1] if isinstance(value, list) and len(value) == 2 else None
        if not (
            isinstance(value, list)
            and len(value) == 2
            and isinstance(value[0], str)
            and (budget is None or (type(budget) is int and budget > 0))
        ):
            raise GridError(f"{where}: {side} is [configuration, budget set] (the budget null for SAC), got {value!r}")
    tasks = claim["tasks"]
    if not (isinstance(tasks, list) and tasks and all(isinstance(task, str) for task in tasks)):
        raise GridError(f"{where}: tasks is a non-empty list of task names, got {tasks!r}")
    metric = claim.get("metric", "return")
    if metric not in CLAIM_METRICS:
        raise GridError(f"{where}: metric must be one of {', '.join(CLAIM_METRICS)}, got {metric!r}")
    if metric == "return" and "p" not in claim:
        raise GridError(
            f"{where}: a claim on the return needs p, the least P(X > Y) that holds (null: no threshold, "
            "reported whatever it reads)"
        )
    if metric == "last_corr" and ({"p", "lower"} & set(claim)):
        raise GridError(f"{where}: a claim on last_corr compares the means; it takes no p or lower")
    if claim.get("p", 0) is None and "lower" in claim:
        raise GridError(f"{where}: a reading without p (null) takes no lower either")
    for key in ("p", "lower"):
        if claim.get(key) is not None and not (type(claim[key]) in (int, float) and 0 <= claim[key] <= 1):
            raise GridError(f"{where}: {key} is a probability between 0 and 1, got {claim[key]!r}")
    if not (type(claim["seeds"]) is int and claim["seeds"] >= 2):
        raise GridError(f"{where}: seeds is the number of finished seeds each arm needs (at least 2), got {claim['seeds']!r}")


def configuration(label: str, variants: dict[str, dict[str, Any]], where: str) -> dict[str, Any]:
    """``{"algo", "tag", "overrides", "variant"}`` of a configuration label: a variant, or a plain algorithm."""
    if label in variants:
        entry = variants[label]
        config = {"algo": entry["algo"], "tag": entry["tag"], "overrides": entry["overrides"], "variant": label}
        for key in ("seconds_per_answer", "learned_reward"):
            if key in entry:
                config[key] = entry[key]
        return config
    if label in run.ALGOS:
        return {"algo": label, "tag": "", "overrides": {}, "variant": None}
    raise GridError(
        f"{where}: unknown configuration {label!r}: neither an algorithm ({', '.join(run.ALGOS)}) nor a variant "
        f"of the tier's variants.yml ({', '.join(sorted(variants)) or 'none'})"
    )


def expand(grid: dict[str, Any], variants: dict[str, dict[str, Any]] | None = None) -> list[dict[str, Any]]:
    """
    The run specs of a grid (``run.py``'s worker input), each with ``configuration`` (its label) and ``variant``
    added, in the order they run: by seed, then block by block; a run that two blocks both make (SAC ignores the
    budget, PEBBLE the ratio) is listed once.
    """
    tier = grid.get("tier", "cpu")
    variants = run.load_variants(tier) if variants is None else variants
    blocks = []
    for i, block in enumerate(grid["runs"]):
        where = f"{grid['path']}, runs[{i}]"
        configurations = [
            (label, configuration(label, variants, where))
            for label in as_list(block["configurations"], where, "configurations")
        ]
        blocks.append((block, where, configurations, parse_seeds(block["seeds"], where)))
    specs, seen = [], set()
    for block, where, configurations, seeds in blocks:
        for seed, task, (label, config) in itertools.product(seeds, as_list(block["tasks"], where, "tasks"), configurations):
            if config["algo"] == "pride" and grid.get("pride_settings"):
                config = {**config, "overrides": run.merge(grid["pride_settings"], config["overrides"])}
            needs_yaml = config["algo"] != "sac" and ("feedback" not in block or "ratios" not in block)
            _, kwargs = run.yaml_entry(tier, config["algo"], task) if needs_yaml else (0, {})
            feedbacks = as_list(block["feedback"], where, "feedback") if "feedback" in block else [kwargs.get("max_feedback")]
            ratios = as_list(block["ratios"], where, "ratios") if "ratios" in block else [kwargs.get("synthetic_ratio")]
            for feedback, ratio in itertools.product(feedbacks, ratios):
                spec = dict(
                    algo=config["algo"],
                    task=task,
                    seed=seed,
                    feedback=feedback,
                    ratio=ratio,
                    tier=tier,
                    eval_freq=grid.get("eval_freq", 5000),
                    eval_episodes=grid.get("eval_episodes", 5),
                    timesteps=grid.get("timesteps", 0),
                    sessions=grid.get("sessions"),
                    tag=config["tag"],
                    overrides=config["overrides"],
                    configuration=label,
                    variant=config["variant"],
                )
                for key in ("seconds_per_answer", "learned_reward"):
                    if key in config:
                        spec[key] = config[key]
                spec["next_seed"] = seeds[(seeds.index(seed) + 1) % len(seeds)]
                if run.run_name(spec) not in seen:
                    seen.add(run.run_name(spec))
                    specs.append(spec)
    # seeds outermost across the blocks too: the arms of a comparison, in blocks of their own, interleave by seed
    return sorted(specs, key=lambda spec: spec["seed"])


def check(specs: list[dict[str, Any]]) -> None:
    """Every configuration's overrides are arguments its algorithm takes, and none is one the grid sets itself."""
    checked = set()
    for spec in specs:
        if spec["configuration"] in checked:
            continue
        checked.add(spec["configuration"])
        try:
            run.check_overrides(spec["overrides"], [spec["algo"]])
        except SystemExit as error:
            raise GridError(f"variant {spec['configuration']!r}: {error}") from None


def out_folder(grid: dict[str, Any], out: Path | None = None) -> Path:
    """Where the grid's run folders go: ``out`` if given, else the file's ``out`` (relative to the repository)."""
    if out is not None:
        return out
    return run.ROOT / grid.get("out", "benchmarks/results/runs")


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("grid_file", type=Path, help="a grid file, e.g. benchmarks/grids/walker-walk-15-seeds.yml")
    parser.add_argument("--jobs", type=int, default=os.cpu_count() or 1, help="runs at a time (default: one per core)")
    parser.add_argument("--out", type=Path, default=None, help="run folders here instead of the grid file's out")
    parser.add_argument("--dry-run", action="store_true", help="list the runs (and which are done), run nothing")
    args = parser.parse_args(argv)
    grid = load_grid(args.grid_file)
    specs = expand(grid)
    out = out_folder(grid, args.out)
    if args.dry_run:
        for spec in specs:
            done = (out / run.run_name(spec) / "result.json").exists()
            print(f"{'done' if done else 'todo'}  {run.run_name(spec)}")
        n_done = sum((out / run.run_name(spec) / "result.json").exists() for spec in specs)
        print(f"{len(specs)} runs, {n_done} done, {len(specs) - n_done} to run, in {out}")
        return
    check(specs)
    failed = run.run_specs(specs, out, args.jobs)
    if failed:
        raise SystemExit(f"{failed} runs failed: see their log.txt")


if __name__ == "__main__":
    main()
