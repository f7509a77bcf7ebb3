"""
The recount: ``results.json``'s data, read from the run folders of the grid files (``benchmarks/grids/*.yml``). Each
row states the budget its runs *asked* (``result.json``'s ``feedback_asked``), the code of ``sb3_pride/`` its runs ran
on (:func:`code_of`), its returns (the primary return: the mean of each run's last three evaluations), its P against
PEBBLE at the task's largest budget (``results_statistics.py``), and the claims and checks of the grid files read by
their rules. :func:`uncounted_runs` lists the run folders no row counts (a test holds the list empty).
"""

import functools
import json
import re
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

import grid
import plot
import run
from results_statistics import (
    BOOTSTRAP_SEED,
    CONFIDENCE,
    RESAMPLES,
    WITHOUT_BEST,
    bootstrap_improvement,
    improvement,
    rounded,
    spread,
)
from results_render import check_rule_text, label_of

ROOT = run.ROOT
GRIDS = ROOT / "benchmarks" / "grids"
TASK_ORDER = ["walker-walk", "cheetah-run", "quadruped-walk", "walker-run"]
#: characters of a tree hash shown and stored: git's short form
SHORT = 7
#: a run's code where it recorded a commit this checkout does not have (its tree cannot be read)
COMMIT_NOT_HERE = "unknown commit"


def relative(path: Path) -> str:
    """A path as the pages write it: relative to the repository (as it is, for a path outside it)."""
    resolved = Path(path).resolve()
    return str(resolved.relative_to(ROOT)) if resolved.is_relative_to(ROOT) else str(path)


def row_key(spec: dict[str, Any]) -> tuple:
    """
    Runs that differ only by seed form one row: task, configuration, budget (not SAC's, unless it learns from the r̂
    a run of that budget saved) and u (PRIDE's only).
    """
    budget_counts = spec["algo"] != "sac" or "{feedback}" in (spec.get("learned_reward") or "")
    return (
        spec["task"],
        spec["configuration"],
        spec["feedback"] if budget_counts else None,
        spec["ratio"] if spec["algo"] == "pride" else None,
    )


def configuration_name(label: str, algo: str, variants: dict[str, dict[str, Any]]) -> str:
    """The configuration as a reader reads it: its variant's description, or the plain algorithm's."""
    if label not in variants:
        return {"pebble": "PEBBLE", "pride": "PRIDE (the tier's YAML settings)", "sac": "SAC on the true reward"}[algo]
    return variants[label]["name"]


def collect(grid_files: list[Path], runs_folder: Path | None = None) -> tuple[dict[tuple, dict], list[dict], list[dict]]:
    """
    ``({row key: row}, comparisons, claims)`` of the grid files: each row with its specs, grid file and command, in
    the order of the files and their blocks; a grid file's ``comparisons`` as ``{"grid", "x", "y"}``; its ``claims``
    as written, with ``"grid"`` added.
    """
    rows: dict[tuple, dict] = {}
    comparisons, claims = [], []
    for path in grid_files:
        spec_grid = grid.load_grid(path)
        variants = run.load_variants(spec_grid.get("tier", "cpu"))
        out = grid.out_folder(spec_grid, runs_folder)
        for spec in grid.expand(spec_grid, variants):
            key = row_key(spec)
            if key in rows and rows[key]["grid"] != relative(path):
                raise SystemExit(f"{relative(path)}: the row {key} is also made by {rows[key]['grid']}: keep it in one")
            row = rows.setdefault(
                key,
                {
                    "task": spec["task"],
                    "configuration": spec["configuration"],
                    "algo": spec["algo"],
                    "name": configuration_name(spec["configuration"], spec["algo"], variants)
                    + ("" if spec_grid.get("tier", "cpu") == "cpu" else f" ({spec_grid['tier']} tier)"),
                    "description": variants[spec["configuration"]]["description"] if spec["variant"] else "",
                    "feedback": key[2],
                    "ratio": key[3],
                    "tag": spec["tag"],
                    "grid": relative(path),
                    "command": f"python benchmarks/grid.py {relative(path)}",
                    "summary": bool(spec_grid.get("summary")),
                    "reference": bool(spec["variant"] and variants[spec["variant"]].get("reference")),
                    "specs": [],
                    "out": out,
                },
            )
            row["specs"].append(spec)
        tasks = {task for block in spec_grid["runs"] for task in grid.as_list(block["tasks"], relative(path), "tasks")}
        for x, y in spec_grid.get("comparisons", []):
            comparisons.append({"grid": relative(path), "x": x, "y": y, "tasks": tasks})
        claims += [{**claim, "grid": relative(path)} for claim in spec_grid.get("claims") or []]
    return rows, comparisons, claims


def runs_of(row: dict) -> list[dict]:
    """
    The row's finished runs, by seed (a run without result.json is left out: the grid is not complete), each as
    ``plot.load_run`` reads it with its ``result.json`` as ``"result"``.
    """
    found = []
    for spec in sorted(row["specs"], key=lambda spec: spec["seed"]):
        folder = row["out"] / run.run_name(spec)
        if (folder / "result.json").exists():
            found.append(
                {
                    **plot.load_run(folder, progress=False),
                    "folder": folder,
                    "result": json.loads((folder / "result.json").read_text()),
                }
            )
    return found


@functools.cache
def tree_at(commit: str) -> str | None:
    """The git tree hash of ``sb3_pride/`` at ``commit`` (``None`` where this checkout lacks the commit, or git)."""
    try:
        done = subprocess.run(
            ["git", "rev-parse", "--verify", "--quiet", f"{commit}^{{commit}}:sb3_pride"],
            cwd=ROOT,
            capture_output=True,
            text=True,
            timeout=30,
        )
    except (OSError, subprocess.TimeoutExpired):
        return None
    tree = done.stdout.strip()
    return tree if done.returncode == 0 and tree else None


def code_of(settings: dict) -> str | None:
    """
    The code of ``sb3_pride/`` a run ran on, as its git tree hash's short form, with ``+dirty`` where the package had
    uncommitted changes; :data:`COMMIT_NOT_HERE` where the run recorded a commit this checkout does not have; ``None``
    where the run recorded no commit.

    A run records ``code_tree`` and ``code_dirty`` itself (``run.provenance``). An older run records only its commit
    and whether the whole checkout was dirty: its tree is read from git at that commit, and a dirty checkout counts as
    dirty code (what the changes touched was not recorded). Runs at two commits that differ only outside
    ``sb3_pride/`` (results, prose, benchmarks) have the same tree: the same code.
    """
    version = settings.get("version") or {}
    tree, dirty = version.get("code_tree"), version.get("code_dirty")
    if tree is None and version.get("commit"):
        tree, dirty = tree_at(version["commit"]), version.get("dirty")
        if tree is None:
            return COMMIT_NOT_HERE
    if tree is None:
        return None
    return tree[:SHORT] + ("+dirty" if dirty or dirty is None else "")


def code_differs(*arms: list[str | None]) -> bool:
    """
    Whether the runs of the arms did not all run on one recorded, clean code of ``sb3_pride/``: a run whose code is
    unrecorded, unknown or dirty, or two codes among the runs (within an arm or across the two), make a comparison's
    code differ.
    """
    codes = {code for arm in arms for code in arm}
    known = all(code is not None and re.fullmatch(f"[0-9a-f]{{{SHORT}}}", code) for code in codes)
    return len(codes) != 1 or not known


def cpu_differs(*arms: list[str | None]) -> bool:
    """
    Whether the runs of the arms ran on more than one CPU kind (settings.json's ``system["CPU"]``): seeds repeat a
    run only on one kind, so such a comparison mixes kinds as one across code versions mixes code. Runs that recorded
    no CPU are not counted (their code is unrecorded too, and marked for that).
    """
    return len({cpu for arm in arms for cpu in arm if cpu is not None}) > 1


def run_folders(grid_files: list[Path], runs_folder: Path | None = None) -> set[Path]:
    """The folders the grid files' runs go to (``benchmarks/results/runs`` for every committed grid file)."""
    return {grid.out_folder(grid.load_grid(path), runs_folder) for path in grid_files}


def uncounted_runs(grid_files: list[Path], runs_folder: Path | None = None) -> list[Path]:
    """
    The run folders (finished or not) in the grid files' run folders that no row of the grid files counts. Each is
    to be counted in a row (a grid file's block) or moved to ``benchmarks/results/archive/`` with a line in its
    README saying why: a result the pages do not show is a result nobody reads.
    """
    rows, _, _ = collect(grid_files, runs_folder)
    counted = {(row["out"] / run.run_name(spec)).resolve() for row in rows.values() for spec in row["specs"]}
    found = [folder for out in run_folders(grid_files, runs_folder) if out.is_dir() for folder in out.iterdir()]
    return sorted(folder for folder in found if folder.is_dir() and folder.resolve() not in counted)


#: marks a comparison with the earlier PEBBLE reference (:func:`earlier_reference_key`) among the pairs
EARLIER = "earlier reference"


def reference_key(rows: dict[tuple, dict], task: str) -> tuple | None:
    """
    Plain PEBBLE at the task's largest budget: what every configuration of the task is compared with; the PEBBLE run
    beside the arms it judges (a variant marked ``reference: true``, e.g. ``pebble_reference``) where the task has one.
    """
    for beside in (True, False):
        pebbles = [
            key
            for key, row in rows.items()
            if key[0] == task and row["algo"] == "pebble" and (row["reference"] if beside else key[1] == "pebble")
        ]
        if pebbles:
            return max(pebbles, key=lambda key: key[2])
    return None


def earlier_reference_key(rows: dict[tuple, dict], task: str) -> tuple | None:
    """
    Plain PEBBLE at the budget and run length of the task's reference run beside the arms it judges (a variant marked
    ``reference: true``), where the task has both and older rows: the reference those rows were judged against before
    PEBBLE was re-run beside the arms it judges. A task whose only row outside the reference's grid is that PEBBLE (a
    check that the tier learns the task) has none.
    """
    reference = reference_key(rows, task)
    if reference is None or not rows[reference]["reference"]:
        return None
    length = rows[reference]["specs"][0]["timesteps"]
    earlier = next(
        (
            key
            for key, row in rows.items()
            if key[0] == task and key[1] == "pebble" and key[2] == reference[2] and row["specs"][0]["timesteps"] == length
        ),
        None,
    )
    older = [key for key in rows if key[0] == task and key != earlier and rows[key]["grid"] != rows[reference]["grid"]]
    return earlier if older else None


def last_correlations(runs: list[dict]) -> np.ndarray | None:
    """Each run's last corr(r̂, r) (``reward_model/true_reward_corr``), for the runs that logged one; None: none did."""
    import csv

    values = []
    for found in runs:
        path = found["folder"] / "progress.csv"
        if not path.exists():
            continue
        with open(path, newline="") as file:
            logged = [line.get("reward_model/true_reward_corr") or "" for line in csv.DictReader(file)]
        logged = [value for value in logged if value not in ("", "nan")]
        if logged:
            values.append(float(logged[-1]))
    return np.array(values) if values else None


def ceiling_key(rows: dict[tuple, dict], task: str, timesteps: int) -> tuple | None:
    """
    SAC on the true reward for the task, with runs of this length: the ceiling each row is a share of; the SAC run
    beside the arms it judges (a variant marked ``reference: true``, e.g. ``sac_reference``) where the task has one.
    """
    sacs = [
        key
        for key, row in rows.items()
        if key[0] == task
        and row["algo"] == "sac"
        and row["specs"][0]["timesteps"] == timesteps
        and not row["specs"][0].get("learned_reward")  # SAC on a learned r̂ is a row, not the ceiling
    ]
    sacs.sort(key=lambda key: not rows[key]["reference"])  # stable: otherwise the first in the grid files' order
    return sacs[0] if sacs else None


def task_order(task: str) -> tuple[int, str]:
    """DMC's tasks first, in the paper's order, then the others by name."""
    return (TASK_ORDER.index(task), "") if task in TASK_ORDER else (len(TASK_ORDER), task)


def recount(grid_files: list[Path], runs_folder: Path | None = None) -> dict[str, Any]:
    """The data of the page: every row's statistics and every comparison, from the run folders."""
    rows, extra, claims = collect(grid_files, runs_folder)
    finals: dict[tuple, np.ndarray | None] = {}  # the primary return of each run, which the comparisons use
    runs_found: dict[tuple, list[dict]] = {}  # each row's finished runs, which the checks read
    for key, row in rows.items():
        found = runs_found[key] = runs_of(row)
        finals[key] = plot.primary_returns(found) if found else None
        last = plot.final_returns(found) if found else None
        successes = [r["curve"]["success"][-1] for r in found]
        has_success = found and not all(value != value for value in successes)  # NaN: no success column
        row["seeds"] = [r["settings"]["seed"] for r in found]
        row["code"] = [code_of(r["settings"]) for r in found]  # seed by seed, as "seeds"
        row["cpu"] = [(r["settings"].get("system") or {}).get("CPU") for r in found]
        row["feedback_asked"] = [r["result"].get("feedback_asked") for r in found]  # seed by seed, as "seeds"
        row["runs"] = [run.run_name(spec) for spec in sorted(row["specs"], key=lambda spec: spec["seed"])]
        row["primary_return"] = spread(finals[key])
        row["final_return"] = spread(last)
        row["area_under_curve"] = (
            None if not found else round(float(sum(r["curve"]["true_return"].mean() for r in found) / len(found)), 4)
        )
        row["final_success"] = round(float(sum(successes) / len(successes)), 4) if has_success else None
        row["last_corr"] = spread(last_correlations(found))
    tasks_found = dict.fromkeys(key[0] for key in rows)
    references = {task: reference_key(rows, task) for task in tasks_found}
    earliers = {task: earlier_reference_key(rows, task) for task in tasks_found}
    pairs: dict[str, list[np.ndarray]] = {}
    names: dict[str, tuple[tuple, tuple, str | None]] = {}
    # P against the task's reference, and against the reference its older rows were first judged by where it has two
    for against, marker, suffix in ((references, None, ""), (earliers, EARLIER, ", the earlier reference")):
        for key, row in rows.items():
            other = against[row["task"]]
            if other is None or key == other:
                continue
            if row["specs"][0]["timesteps"] != rows[other]["specs"][0]["timesteps"]:
                continue  # runs of another length than the reference's: a P between them would say nothing
            final, final_other = finals[key], finals[other]
            if final is not None and final_other is not None and min(len(final), len(final_other)) >= 2:
                pair = f"{row['task']}: {label_of(row)} > {label_of(rows[other])}{suffix}"
                pairs[pair], names[pair] = [final, final_other], (key, other, marker)
    for comparison in extra:
        matched = False
        for key_x, x in rows.items():
            for key_y, y in rows.items():
                if (x["configuration"], y["configuration"]) != (comparison["x"], comparison["y"]) or key_x[0] != key_y[0]:
                    continue
                if key_x[0] not in comparison["tasks"]:
                    continue
                if x["feedback"] != y["feedback"] or (
                    x["ratio"] is not None and y["ratio"] is not None and x["ratio"] != y["ratio"]
                ):
                    continue
                matched = True
                final_x, final_y = finals[key_x], finals[key_y]
                if final_x is not None and final_y is not None and min(len(final_x), len(final_y)) >= 2:
                    pair = f"{x['task']}: {label_of(x)} > {label_of(y)}"
                    if pair in pairs:
                        continue
                    pairs[pair], names[pair] = [final_x, final_y], (key_x, key_y, comparison["grid"])
        if not matched:
            raise SystemExit(
                f"{comparison['grid']}: comparison {comparison['x']} > {comparison['y']}: no two rows of "
                "the same task, budget and u"
            )
    comparisons: list[dict[str, Any]] = []
    for pair in sorted(pairs):
        key_x, key_y, from_grid = names[pair]
        scores_x, scores_y = pairs[pair]
        value = improvement(scores_x, scores_y, seeds_x=rows[key_x]["seeds"])
        entry = {
            "task": key_x[0],
            "x": label_of(rows[key_x]),
            "y": label_of(rows[key_y]),
            **value,
            "code_differs": code_differs(rows[key_x]["code"], rows[key_y]["code"]),
            "cpu_differs": cpu_differs(rows[key_x]["cpu"], rows[key_y]["cpu"]),
        }
        if from_grid is None:
            rows[key_x]["against_pebble"] = entry
        elif from_grid is EARLIER:
            rows[key_x]["against_earlier_pebble"] = entry
        else:
            grids = list(dict.fromkeys([from_grid, rows[key_x]["grid"], rows[key_y]["grid"]]))  # its runs' grid files
            command = " && ".join(f"python benchmarks/grid.py {path}" for path in grids)
            comparisons.append({**entry, "grid": from_grid, "command": command})
    for key, row in rows.items():
        # each row's primary return as a share of SAC's on the true reward (runs of the same length), the ceiling
        ceiling = ceiling_key(rows, row["task"], row["specs"][0]["timesteps"])
        own, top = finals[key], None if ceiling is None else finals[ceiling]
        share = None if own is None or top is None or top.mean() == 0 else own.mean() / top.mean()
        row["share_of_ceiling"] = None if share is None else round(float(share), 3)
    verdicts = [verdict(claim, task, rows, finals) for claim in claims for task in claim["tasks"]]
    checks = [read_check(path, check, rows, runs_found) for path in grid_files if (check := grid.load_grid(path).get("check"))]
    tasks: dict[str, list[dict]] = {}
    # each task's PEBBLE reference first, then its rows in the order of the grid files
    for key, row in sorted(rows.items(), key=lambda item: (task_order(item[0][0]), item[0] != references[item[0][0]])):
        reference = references[key[0]]
        row.setdefault("against_pebble", None)
        row.setdefault("against_earlier_pebble", None)
        row["task_reference"] = key == reference
        tasks.setdefault(row["task"], []).append({k: v for k, v in row.items() if k not in ("specs", "out")})
    return {
        "generated_by": "python benchmarks/results_page.py",
        "statistics": f"return: the mean true return of each run's last {plot.LAST_EVALUATIONS} evaluations (5 deterministic "
        "episodes each), mean ± std over seeds, with the final return (the last evaluation) and the area under the curve "
        "(the mean over evaluations) beside it; P(X > Y) on the return: rliable's probability of improvement, "
        f"{CONFIDENCE:.0%} stratified-bootstrap interval, {RESAMPLES:,} resamples, NumPy seed {BOOTSTRAP_SEED} per pair; "
        "p: the one-sided Mann–Whitney U test of X > Y; without best 1 / 2: P and its interval with X's best one and "
        "two seeds (by the return) left out; queries: the budget the runs asked (result.json's feedback_asked), with "
        "the budget set beside it where that differs",
        "bootstrap": {
            "resamples": RESAMPLES,
            "seed": BOOTSTRAP_SEED,
            "confidence": CONFIDENCE,
            "method": "rliable's StratifiedIndependentBootstrap, percentile interval",
            "mann_whitney": "scipy.stats.mannwhitneyu, alternative='greater'",
            "without_best": list(WITHOUT_BEST),
        },
        "tasks": tasks,
        "comparisons": comparisons,
        "claims": verdicts,
        "checks": checks,
    }


def claim_row(rows: dict[tuple, dict], task: str, side: list[str | int | None], where: str) -> tuple:
    """The row a claim names on a task: its configuration at the budget set (``[label, budget]``); an error where the
    grid files make no such row, or several (one per u: a claim names one)."""
    label, budget = side
    keys = [key for key, row in rows.items() if key[0] == task and key[1] == label and row["feedback"] == budget]
    if len(keys) != 1:
        found = "no such row" if not keys else f"rows at u = {', '.join(str(key[3]) for key in keys)}"
        raise SystemExit(f"{where}: names {label} at {budget} queries on {task}, and the grid files make {found}")
    return keys[0]


def rule_text(claim: dict) -> str:
    """A claim's rule as the pages write it."""
    if claim.get("metric", "return") == "last_corr":
        rule = "X's mean last corr(r̂, r) ≥ Y's"
    elif claim["p"] is None:
        return f"none: reported whatever it reads, {claim['seeds']} seeds each"
    else:
        rule = f"P(X > Y) ≥ {claim['p']}" + (f", lower end above {claim['lower']}" if "lower" in claim else "")
    return f"{rule}, {claim['seeds']} seeds each"


def verdict(claim: dict, task: str, rows: dict[tuple, dict], finals: dict[tuple, np.ndarray | None]) -> dict[str, Any]:
    """
    One claim of a grid file read on one task by the rule it states. On the return: P(X > Y) with its interval
    (:func:`improvement`), holding where P reaches ``p`` and the interval's lower end is above ``lower``; on
    ``last_corr``: the two rows' mean last corr(r̂, r), holding where X's is at least Y's. ``holds`` is ``None`` (no
    verdict) until each arm has ``seeds`` finished runs; what the runs read so far is kept beside it.
    """
    where = f"{claim['grid']}, claim {claim['name']!r}"
    key_x, key_y = (claim_row(rows, task, claim[side], where) for side in ("x", "y"))
    x, y = rows[key_x], rows[key_y]
    metric = claim.get("metric", "return")
    entry: dict[str, Any] = {
        "claim": claim["name"],
        "task": task,
        "x": label_of(x),
        "y": label_of(y),
        "metric": metric,
        "configurations": [x["configuration"], y["configuration"]],
        "rule": rule_text(claim),
        "needs_seeds": claim["seeds"],
        "seeds": [len(x["seeds"]), len(y["seeds"])],
        "code_differs": code_differs(x["code"], y["code"]),
        "cpu_differs": cpu_differs(x["cpu"], y["cpu"]),
        "grid": claim["grid"],
        "reading": metric == "return" and claim["p"] is None,  # no threshold: reported whatever it reads
    }
    if metric == "return":
        scores_x, scores_y = finals[key_x], finals[key_y]
        if scores_x is not None and scores_y is not None and min(len(scores_x), len(scores_y)) >= 2:
            p, interval = bootstrap_improvement(scores_x, scores_y, RESAMPLES, BOOTSTRAP_SEED)  # judged unrounded
            entry.update(rounded(scores_x, scores_y, p, interval))
            low = interval[0]
    else:
        # a run that logged no corr(r̂, r) counts as a seed the arm lacks
        entry["seeds"] = [0 if row["last_corr"] is None else len(row["last_corr"]["per_seed"]) for row in (x, y)]
        entry["means"] = [None if row["last_corr"] is None else row["last_corr"]["mean"] for row in (x, y)]
    if min(entry["seeds"]) < claim["seeds"] or entry["reading"]:
        entry["holds"] = None  # no verdict yet, or a reading without a threshold
    elif metric == "return":
        entry["holds"] = p >= claim["p"] and ("lower" not in claim or low > claim["lower"])
    else:
        entry["holds"] = entry["means"][0] >= entry["means"][1]
    return entry


def read_check(
    path: Path, check: dict[str, Any], rows: dict[tuple, dict], runs_found: dict[tuple, list[dict]]
) -> dict[str, Any]:
    """
    The check of the grid file ``path`` (whether PEBBLE alone learns a task, before the task is held out) read on each
    of its finished runs (``runs_found``: :func:`runs_of` each row): a run passes where it asked the budget it was set
    (``result.json``'s ``feedback_asked``) and the mean of its last :data:`plot.LAST_EVALUATIONS` evaluations of the
    check's metric is at least ``rise`` above that of its first ones, and at least ``at_least`` where the check sets it
    (both means rounded to four decimals first, as the pages show them: a success rate of 0.2 is not missed by a
    rounding error). The check ``passes`` where every run of the grid
    is finished and passes, fails as soon as one finished run fails, and has no verdict (``None``) before. A run whose
    curve lacks the metric, or holds fewer than twice :data:`plot.LAST_EVALUATIONS` evaluations of it, is an error.
    """
    n, where = plot.LAST_EVALUATIONS, relative(path)
    read, planned = [], 0
    for key, row in rows.items():
        if row["grid"] != where:
            continue
        planned += len(row["specs"])
        for found in runs_found[key]:
            names = found["curve"].dtype.names or ()
            values = np.asarray(found["curve"][check["metric"]] if check["metric"] in names else [], dtype=float)
            if np.isnan(values).any() or len(values) < 2 * n:
                raise SystemExit(
                    f"{where}: check on {check['metric']}: the run {found['folder'].name} has "
                    f"{int((~np.isnan(values)).sum())} evaluations of it, the check needs {2 * n} or more"
                )
            first, last = round(float(values[:n].mean()), 4), round(float(values[-n:].mean()), 4)
            asked = found["result"].get("feedback_asked")
            passes = (row["feedback"] is None or asked == row["feedback"]) and round(last - first, 4) >= check["rise"]
            passes = passes and last >= check.get("at_least", -np.inf)
            read.append(
                {
                    "run": found["folder"].name,
                    "task": row["task"],
                    "seed": found["settings"]["seed"],
                    "set": row["feedback"],
                    "asked": asked,
                    "first": first,
                    "last": last,
                    "passes": bool(passes),
                }
            )
    passes = False if any(not r["passes"] for r in read) else (True if read and len(read) == planned else None)
    return {
        "grid": where,
        "metric": check["metric"],
        "rule": check_rule_text(check),
        "runs": read,
        "planned": planned,
        "passes": passes,
    }


def rule_commit(path: Path) -> str | None:
    """The commit that first added the grid file ``path`` (followed across moves): when its rule was written; None
    where git holds no such commit."""
    found = subprocess.run(
        ["git", "-C", str(ROOT), "log", "--follow", "--diff-filter=A", "--format=%H", "--", str(path.resolve())],
        capture_output=True,
        text=True,
    ).stdout.split()
    return found[-1] if found else None


@functools.cache
def holds(commit: str, ancestor: str) -> bool:
    """Whether ``commit``'s history holds ``ancestor`` (the same commit included)."""
    return not subprocess.run(["git", "-C", str(ROOT), "merge-base", "--is-ancestor", ancestor, commit]).returncode


def runs_before_their_rule(grid_files: list[Path], runs_folder: Path | None = None) -> tuple[list[str], int]:
    """
    The runs of the grid files whose code did not hold their grid file's rule: the commit each run recorded
    (``settings.json``) does not descend from the commit that first added the grid file, or it recorded none.
    Returns those runs' folder names and the number of runs read.
    """
    late, read = [], 0
    for path in grid_files:
        rule = rule_commit(path)
        rows, _, _ = collect([path], runs_folder)
        for row in rows.values():
            for spec in row["specs"]:
                settings = row["out"] / run.run_name(spec) / "settings.json"
                if not settings.exists():
                    continue
                read += 1
                commit = json.loads(settings.read_text()).get("version", {}).get("commit")
                if rule is None or not commit or not holds(commit, rule):
                    late.append(settings.parent.name)
    return late, read
