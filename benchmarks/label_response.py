"""
How many labels does a policy need? The label-response study's reading of its runs.

    python benchmarks/label_response.py screen    # which candidate tasks qualify, by the rule of the screen's grid file
    python benchmarks/label_response.py ladders GRID...   # label-response curves, labels to the target, the figure

``screen`` reads the SAC runs of ``benchmarks/grids/pending/label-response-screen.yml`` (pending until its runs are in) and applies the rule its description
states (written before its runs): per task, the mean curve over seeds; its plateau gap, (best - mean of the last third
of the evaluations) / (best - first evaluation), must be at most ``PLATEAU_GAP``, and the median of its runs' wall
times must be at most ``MAX_MINUTES`` (runs on a shared machine also time their neighbours); of the qualifying tasks the three cheapest are studied (at least one from dm_control)
and the next is held out. It writes ``benchmarks/results/label_response_screen.md`` and ``.json``.

The ladders' reading (labels to the target, with a bootstrap interval over seeds) is :func:`labels_to_target` and
:func:`bootstrap_labels`: the target is ``TARGET_SHARE`` of what PEBBLE reaches at the ladder's top budget, the labels
an arm needs are interpolated on the log-budget axis where its mean return first reaches the target, and an arm that
never reaches it within the ladder needs more than the ladder holds (``inf``). ``ladders`` reads ladder grids (one
configuration at several budgets, SAC on the true reward beside it) into ``benchmarks/results/label_response.md``
and ``figures/label_response.png``: per task and arm, the share of SAC's return at each budget, (R - R_random) /
(R_SAC - R_random) with ``R_random`` a uniformly random policy's return, with a 95% bootstrap interval over seeds and
the mean last corr(r̂, r); the labels each arm needs to reach the target; and the ratio of each arm's labels to
PEBBLE's.
"""

import argparse
import json
import math
import sys
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

import plot
import results_page as page
from results_recount import last_correlations

SCREEN = page.GRIDS / "pending" / "label-response-screen.yml"
SCREEN_PAGE = page.ROOT / "benchmarks" / "results" / "label_response_screen.md"
#: the screen's rule (the grid file's description states it in words)
PLATEAU_GAP = 0.05
MAX_MINUTES = 30
STUDIED, HELD_OUT = 3, 1
#: labels to the target: this share of what PEBBLE reaches at the ladder's top budget
TARGET_SHARE = 0.9


def plateau_gap(curve: np.ndarray) -> float:
    """(best - mean of the last third of the evaluations) / (best - first evaluation): 0 at a plateau at the best."""
    last = curve[-math.ceil(len(curve) / 3) :]
    rise = curve.max() - curve[0]
    return float((curve.max() - last.mean()) / rise) if rise > 0 else math.inf


def is_dm_control(task: str) -> bool:
    from sb3_pride.envs import DM_CONTROL_TASKS

    return task in DM_CONTROL_TASKS


def read_screen(grid_file: Path = SCREEN, runs_folder: Path | None = None) -> dict[str, Any]:
    """Each task of the screen with its seeds' curves read by the rule, and the selection the rule makes."""
    rows, _, _ = page.collect([grid_file], runs_folder)
    tasks: dict[str, dict[str, Any]] = {}
    for row in rows.values():
        runs = page.runs_of(row)
        if not runs:
            tasks[row["task"]] = {"seeds": 0, "planned": len(row["specs"])}
            continue
        length = min(len(found["curve"]) for found in runs)
        curve = np.mean([found["curve"]["true_return"][:length] for found in runs], axis=0)
        minutes = [found["result"]["seconds"] / 60 for found in runs]
        gap = plateau_gap(curve)
        tasks[row["task"]] = {
            "seeds": len(runs),
            "planned": len(row["specs"]),
            "steps": int(runs[0]["curve"]["step"][length - 1]),
            "best": round(float(curve.max()), 2),
            "last_third": round(float(curve[-math.ceil(length / 3) :].mean()), 2),
            "first": round(float(curve[0]), 2),
            "plateau_gap": round(gap, 4),
            "minutes": {"median": round(float(np.median(minutes)), 1), "max": round(float(np.max(minutes)), 1)},
            "qualifies": bool(gap <= PLATEAU_GAP and np.median(minutes) <= MAX_MINUTES),
            "dm_control": is_dm_control(row["task"]),
        }
    return {"tasks": tasks, "selection": select(tasks)}


def select(tasks: dict[str, dict]) -> dict[str, Any]:
    """The rule's choice among the tasks whose every planned seed is in: the three cheapest qualifying tasks (one of
    them from dm_control) and the next one, held out; ``None`` until every candidate has all its seeds."""
    if any(entry["seeds"] < entry["planned"] for entry in tasks.values()):
        return {
            "studied": None,
            "held_out": None,
            "waiting_for": sorted(t for t, e in tasks.items() if e["seeds"] < e["planned"]),
        }
    ranked = sorted((task for task, entry in tasks.items() if entry["qualifies"]), key=lambda t: tasks[t]["minutes"]["median"])
    studied = ranked[:STUDIED]
    if studied and not any(tasks[task]["dm_control"] for task in studied):
        dmc = [task for task in ranked if tasks[task]["dm_control"]]
        if dmc:
            studied = studied[: STUDIED - 1] + dmc[:1]
    rest = [task for task in ranked if task not in studied]
    return {"studied": studied, "held_out": rest[:HELD_OUT], "waiting_for": []}


def render_screen(data: dict[str, Any]) -> str:
    lines = [
        "# The label-response screen",
        "",
        "Generated by `python benchmarks/label_response.py screen` from the runs of "
        f"`{page.relative(SCREEN)}` (SAC on the true reward, the tier's settings); the rule is that grid file's "
        f"description: a task qualifies where its mean curve's plateau gap is at most {PLATEAU_GAP} and its median run "
        f"took at most {MAX_MINUTES} minutes (the machine is shared: a run's time also measures its neighbours).",
        "",
        "| task | seeds | steps | first | best | last third | plateau gap | minutes per run (median / max) | qualifies |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for task, entry in data["tasks"].items():
        if not entry["seeds"]:
            lines.append(f"| {task} | 0 of {entry['planned']} | — | — | — | — | — | — | not run |")
            continue
        minutes = entry["minutes"]
        lines.append(
            f"| {task} | {entry['seeds']} of {entry['planned']} | {entry['steps']} | {entry['first']:.1f} | "
            f"{entry['best']:.1f} | {entry['last_third']:.1f} | {entry['plateau_gap']:.3f} | "
            f"{minutes['median']:.1f} / {minutes['max']:.1f} | {'yes' if entry['qualifies'] else 'no'}"
            f"{' so far' if entry['seeds'] < entry['planned'] else ''} |"
        )
    selection = data["selection"]
    lines.append("")
    if selection["studied"] is None:
        lines.append(f"No selection yet: waiting for every seed of {', '.join(selection['waiting_for'])}.")
    else:
        lines.append(
            f"Studied: {', '.join(selection['studied']) or 'none'}; held out: {', '.join(selection['held_out']) or 'none'}."
        )
    return "\n".join(lines) + "\n"


def labels_to_target(budgets: np.ndarray, returns: np.ndarray, target: float) -> float:
    """
    The labels an arm needs to reach ``target``: where its mean return per budget first reaches it, interpolated
    linearly on log2(budget) between the two budgets around the crossing; the ladder's lowest budget where that one
    already reaches it; ``inf`` where no budget of the ladder does.

    :param budgets: the ladder, ascending
    :param returns: the arm's mean return at each budget
    """
    reached = np.flatnonzero(returns >= target)
    if not reached.size:
        return math.inf
    i = int(reached[0])
    if i == 0:
        return float(budgets[0])
    low, high = math.log2(budgets[i - 1]), math.log2(budgets[i])
    fraction = (target - returns[i - 1]) / (returns[i] - returns[i - 1])
    return float(2 ** (low + fraction * (high - low)))


def resampled_means(per_budget: list[np.ndarray], rng: np.random.Generator, reps: int) -> np.ndarray:
    """(reps, budgets): the mean over seeds of each budget's runs, the seeds of each budget drawn with replacement."""
    return np.stack(
        [values[rng.integers(0, len(values), size=(reps, len(values)))].mean(axis=1) for values in per_budget], axis=1
    )


def bootstrap_labels(
    budgets: list[int],
    reference: list[np.ndarray],
    arm: list[np.ndarray],
    floor: float,
    reps: int = 10_000,
    seed: int = 0,
    confidence: float = 0.95,
) -> dict[str, Any]:
    """
    Labels to the target for PEBBLE (``reference``) and an ``arm``, and the ratio arm ÷ PEBBLE, each with a
    percentile bootstrap interval: every resample draws each budget's seeds of both arms with replacement, sets the
    target from the resampled PEBBLE at the top budget (``floor + TARGET_SHARE × (its return - floor)``, ``floor``
    the return of a random policy) and reads both arms on it. A ratio whose two arms both miss the target is left
    out of its interval, and counted (``undefined``).

    :param reference: PEBBLE's returns, one array of seeds per budget
    :param arm: the other arm's, per budget
    """
    ladder = np.asarray(budgets, dtype=float)

    def target_of(top: float) -> float:
        return floor + TARGET_SHARE * (top - floor)

    point_reference = np.array([values.mean() for values in reference])
    point_arm = np.array([values.mean() for values in arm])
    target = target_of(point_reference[-1])
    rng = np.random.default_rng(seed)
    draws_reference, draws_arm = resampled_means(reference, rng, reps), resampled_means(arm, rng, reps)
    labels_reference = np.array([labels_to_target(ladder, row, target_of(row[-1])) for row in draws_reference])
    labels_arm = np.array(
        [labels_to_target(ladder, a, target_of(r[-1])) for a, r in zip(draws_arm, draws_reference, strict=True)]
    )
    with np.errstate(invalid="ignore", divide="ignore"):
        ratios = labels_arm / labels_reference
    defined = ratios[~np.isnan(ratios)]
    tails = [(1 - confidence) / 2, 1 - (1 - confidence) / 2]

    def interval(values: np.ndarray) -> list[float]:  # no interpolation: an end may be inf
        return [float(v) for v in np.quantile(values, tails, method="inverted_cdf")] if values.size else [math.nan] * 2

    reference_labels = labels_to_target(ladder, point_reference, target)
    arm_labels = labels_to_target(ladder, point_arm, target)
    ratio = arm_labels / reference_labels if math.isfinite(reference_labels) else math.nan
    return {
        "target": float(target),
        "reference": {"labels": reference_labels, "interval": interval(labels_reference)},
        "arm": {"labels": arm_labels, "interval": interval(labels_arm)},
        "ratio": {"value": ratio, "interval": interval(defined), "undefined": int(np.isnan(ratios).sum())},
        "resamples": reps,
        "seed": seed,
    }


FLOORS = page.ROOT / "benchmarks" / "results" / "label_response_floors.json"
LADDER_PAGE = page.ROOT / "benchmarks" / "results" / "label_response.md"
LADDER_FIGURE = page.ROOT / "benchmarks" / "results" / "figures" / "label_response.png"


def random_return(task: str, episodes: int = 10, seed: int = 0) -> float:
    """The mean true return of a uniformly random policy on ``task``: where a share of the ceiling starts."""
    import gymnasium as gym

    import sb3_pride  # noqa: F401 (registers the sb3_pride/... envs)

    env = gym.make(page.run.env_id(task))
    env.action_space.seed(seed)
    total = 0.0
    for episode in range(episodes):
        env.reset(seed=seed + episode)
        done = False
        while not done:
            _, reward, terminated, truncated, _ = env.step(env.action_space.sample())
            total, done = total + float(reward), terminated or truncated
    return total / episodes


def floor_of(task: str) -> float:
    """``random_return``, measured once per task and kept in ``label_response_floors.json``."""
    floors = json.loads(FLOORS.read_text()) if FLOORS.exists() else {}
    if task not in floors:
        floors[task] = round(random_return(task), 3)
        FLOORS.write_text(json.dumps(floors, indent=1, sort_keys=True) + "\n")
    return floors[task]


def mean_interval(values: np.ndarray, reps: int = 10_000, seed: int = 0) -> tuple[float, float, float]:
    """The mean of ``values`` and its 95% percentile bootstrap interval."""
    draws = values[np.random.default_rng(seed).integers(0, len(values), size=(reps, len(values)))].mean(axis=1)
    low, high = np.quantile(draws, [0.025, 0.975])
    return float(values.mean()), float(low), float(high)


def read_ladders(grid_files: list[Path], reference: str = "pebble") -> dict[str, Any]:
    """Each task's arms, budget by budget (shares of the ceiling, last corr), and each arm's labels to the target."""
    rows, _, _ = page.collect(grid_files)
    tasks: dict[str, dict[str, Any]] = {}
    for row in rows.values():
        runs = page.runs_of(row)
        if not runs:
            continue
        task = tasks.setdefault(row["task"], {"arms": {}, "ceiling": None})
        returns = plot.primary_returns(runs)
        if row["algo"] == "sac":
            task["ceiling"] = float(returns.mean())
            continue
        corr = last_correlations(runs)
        task["arms"].setdefault(row["configuration"], {})[int(row["feedback"])] = {
            "returns": returns,
            "corr": None if corr is None else float(corr.mean()),
        }
    for name, task in tasks.items():
        floor, ceiling = floor_of(name), task["ceiling"]
        for points in task["arms"].values():
            for point in points.values():
                if ceiling is not None and ceiling != floor:
                    point["share"] = mean_interval((point["returns"] - floor) / (ceiling - floor))
        pebble = task["arms"].get(reference)
        task["labels"] = {}
        for arm, points in task["arms"].items():
            budgets = sorted(set(points) & set(pebble or {}))
            if pebble is None or len(budgets) < 2:
                continue
            task["labels"][arm] = bootstrap_labels(
                budgets, [pebble[b]["returns"] for b in budgets], [points[b]["returns"] for b in budgets], floor
            )
    return tasks


def interval_text(values: list[float]) -> str:
    return "[" + ", ".join("∞" if v == math.inf else f"{v:.2f}" if v < 10 else f"{v:.0f}" for v in values) + "]"


def render_ladders(tasks: dict[str, Any], reference: str = "pebble") -> str:
    lines = ["# How many labels a policy needs", "", "Generated by `python benchmarks/label_response.py ladders ...`."]
    for name, task in tasks.items():
        lines += [
            "",
            f"## {name}",
            "",
            "| arm | labels | seeds | share of SAC [95% CI] | corr(r̂, r), last |",
            "|---|---|---|---|---|",
        ]
        for arm, points in task["arms"].items():
            for budget in sorted(points):
                point = points[budget]
                share = point.get("share")
                share_text = "—" if share is None else f"{share[0]:.2f} {interval_text(list(share[1:]))}"
                corr = "—" if point["corr"] is None else f"{point['corr']:.2f}"
                lines.append(f"| {arm} | {budget} | {len(point['returns'])} | {share_text} | {corr} |")
        if task["labels"]:
            lines += ["", f"Labels to the target ({TARGET_SHARE:.0%} of {reference} at the ladder's top budget):", ""]
            lines += ["| arm | labels [95% CI] | ÷ " + reference + " [95% CI] |", "|---|---|---|"]
            for arm, read in task["labels"].items():
                labels, ratio = read["arm"], read["ratio"]
                lines.append(
                    f"| {arm} | {labels['labels']:.0f} {interval_text(labels['interval'])} | "
                    f"{ratio['value']:.2f} {interval_text(ratio['interval'])} |"
                )
    return "\n".join(lines) + "\n"


def draw_ladders(tasks: dict[str, Any], path: Path) -> None:
    """Share of the ceiling against labels (log axis), one panel per task, each arm with its 95% interval."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    figure, axes = plt.subplots(1, max(len(tasks), 1), figsize=(4.5 * max(len(tasks), 1), 3.5), squeeze=False)
    for axis, (name, task) in zip(axes[0], tasks.items(), strict=False):
        for arm, points in task["arms"].items():
            budgets = [b for b in sorted(points) if "share" in points[b]]
            shares = np.array([points[b]["share"] for b in budgets]).reshape(-1, 3)
            axis.plot(budgets, shares[:, 0], marker="o", label=arm)
            axis.fill_between(budgets, shares[:, 1], shares[:, 2], alpha=0.2)
        axis.set_xscale("log", base=2)
        axis.set(title=name, xlabel="labels", ylabel="share of SAC's return")
        axis.legend(fontsize="small")
    path.parent.mkdir(parents=True, exist_ok=True)
    figure.tight_layout()
    figure.savefig(path, dpi=120)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("what", choices=["screen", "ladders"])
    parser.add_argument("grids", nargs="*", type=Path, help="ladders: the ladder grid files")
    parser.add_argument("--reference", default="pebble", help="ladders: the arm whose top budget sets the target")
    parser.add_argument("--print", action="store_true", help="print the page, write no file")
    args = parser.parse_args()
    if args.what == "ladders":
        if not args.grids:
            parser.error("ladders needs the ladder grid files")
        tasks = read_ladders(args.grids, args.reference)
        text = render_ladders(tasks, args.reference)
        if not args.print:
            LADDER_PAGE.write_text(text)
            draw_ladders(tasks, LADDER_FIGURE)
        print(text if args.print else f"wrote {page.relative(LADDER_PAGE)} and {page.relative(LADDER_FIGURE)}")
        return
    data = read_screen()
    text = render_screen(data)
    if args.print:
        print(text)
        return
    SCREEN_PAGE.write_text(text)
    SCREEN_PAGE.with_suffix(".json").write_text(json.dumps(data, indent=1) + "\n")
    print(f"wrote {page.relative(SCREEN_PAGE)} and its .json")


if __name__ == "__main__":
    main()
