"""
How many labels does a policy need? The label-response study's reading of its runs.

    python benchmarks/label_response.py screen            # which candidate tasks qualify, by the screen's rule
    python benchmarks/label_response.py ladders GRID...   # print ladders' tables (e.g. a grid still in pending/)
    python benchmarks/label_response.py provenance        # does every run's commit hold the rule it is read by?

``screen`` is ``label_response_screen.py``'s reading: which candidate tasks qualify and which the study selects.

The ladders (grid files with ``ladder: true``) are read by ``benchmarks/results_page.py`` through
:func:`read_ladders` into ``results.json``, the README, the results README, the docs' results page and
``docs/_generated/label_response.png``: per task and arm, the share of SAC's return at each budget, (R - R_random) /
(R_SAC - R_random) with ``R_random`` a uniformly random policy's return, with a 95% bootstrap interval over seeds
and the mean last corr(r̂, r); SAC from scratch on the final r̂ where a grid ran it; and the labels to the target
(:func:`labels_to_target`, :func:`bootstrap_labels`): the target is ``TARGET_SHARE`` of what PEBBLE reaches at the
ladder's top budget, the labels an arm needs are interpolated on the log-budget axis where its mean return first
reaches it (``inf``: not within the ladder), and the ratio of each arm's labels to PEBBLE's.
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
import run
from grid import load_grid
from label_response_screen import SCREEN_PAGE, held_out_tasks, no_ladder_text, read_screen, render_screen
from results_recount import GRIDS, ROOT, collect, last_correlations, relative, runs_before_their_rule, runs_of

#: labels to the target: this share of what PEBBLE reaches at the ladder's top budget
TARGET_SHARE = 0.9
#: what the ladders' arms are, for the tables' note and the figure's legend
ARM_NAMES = {
    "pebble": "PEBBLE()",
    "pride": "PRIDE()",
    "pebble_like_pride": "PEBBLE with PRIDE's reward learning and label schedule",
}


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


def deciding_budgets(budgets: list[int], labels: float) -> list[int]:
    """The budgets a reading of ``labels`` turns on (the ladder grids' rule, part 3): the two either side of it, the
    lowest two where it is reached at the lowest budget, none where the ladder does not reach it."""
    if not math.isfinite(labels):
        return []
    above = next(i for i, budget in enumerate(budgets) if budget >= labels)
    return list(budgets[max(above - 1, 0) : max(above - 1, 0) + 2])


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
    the return of a random policy) and reads both arms on it. A ratio whose PEBBLE misses the target (arm ÷ ∞) is
    left out of its interval, and counted (``undefined``), as the point ratio is then undefined. An arm whose mean
    reaches the target at the ladder's lowest budget needs at most that many labels (``at_most``): its ratio is then
    an upper bound, and where PEBBLE's is, the ratio is not read (``nan``).

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
        ratios = np.where(np.isinf(labels_reference), np.nan, labels_arm / labels_reference)  # as the point ratio
    defined = ratios[~np.isnan(ratios)]
    tails = [(1 - confidence) / 2, 1 - (1 - confidence) / 2]

    def interval(values: np.ndarray) -> list[float]:  # no interpolation: an end may be inf
        return [float(v) for v in np.quantile(values, tails, method="inverted_cdf")] if values.size else [math.nan] * 2

    reference_labels = labels_to_target(ladder, point_reference, target)
    arm_labels = labels_to_target(ladder, point_arm, target)
    # reached at the ladder's lowest budget: the arm needs at most that many, and its ratio is an upper bound
    at_most_reference, at_most_arm = bool(point_reference[0] >= target), bool(point_arm[0] >= target)
    ratio = arm_labels / reference_labels if math.isfinite(reference_labels) and not at_most_reference else math.nan
    return {
        "target": float(target),
        "reference": {"labels": reference_labels, "interval": interval(labels_reference), "at_most": at_most_reference},
        "arm": {"labels": arm_labels, "interval": interval(labels_arm), "at_most": at_most_arm},
        "ratio": {
            "value": ratio,
            "interval": interval(defined),
            "undefined": int(np.isnan(ratios).sum()),
            "at_most": at_most_arm,
        },
        "resamples": reps,
        "seed": seed,
    }


FLOORS = ROOT / "benchmarks" / "results" / "label_response_floors.json"


def random_return(task: str, episodes: int = 10, seed: int = 0) -> float:
    """The mean true return of a uniformly random policy on ``task``: where a share of the ceiling starts."""
    import gymnasium as gym

    import sb3_pride  # noqa: F401 (registers the sb3_pride/... envs)

    env = gym.make(run.env_id(task))
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


def ladder_grids(files: list[Path]) -> list[Path]:
    """The grid files among ``files`` that are label-response ladders (``ladder: true`` or a mapping of arms)."""
    return [path for path in files if load_grid(path).get("ladder")]


def arm_of(configuration: str, arms: dict[str, str]) -> str:
    """The arm a configuration runs in its ladder: the name its grid's ``ladder`` mapping gives it, else its label;
    SAC on an arm's final r̂ (``sac_on_<configuration>_reward``) as ``sac_on_<arm>_reward``."""
    by_configuration = {configuration: arm for arm, configuration in arms.items()}
    if configuration.startswith("sac_on_") and configuration.endswith("_reward"):
        inner = configuration[len("sac_on_") : -len("_reward")]
        return f"sac_on_{by_configuration.get(inner, inner)}_reward"
    return by_configuration.get(configuration, configuration)


def read_ladders(grid_files: list[Path], reference: str = "pebble", runs_folder: Path | None = None) -> dict[str, Any]:
    """
    Per task (JSON-ready, for ``results.json``): SAC's ceiling and a random policy's floor; each arm's points, budget
    by budget (seeds, share of the ceiling with its 95% interval, mean last corr(r̂, r)); SAC from scratch on the
    final r̂ of the runs of a budget where the grid ran it (a variant named ``sac_on_<arm>_reward``); the labels to the
    target of each arm run at every budget of PEBBLE's, beside PEBBLE's; how many of the task's planned runs are in
    (``runs``: a ladder is read whole); and whether the screen's selection held the task out (``held_out``).
    """
    rows, _, _ = collect(grid_files, runs_folder)
    ladders = {relative(path): load_grid(path).get("ladder") for path in grid_files}
    found: dict[str, dict[str, Any]] = {}
    for row in rows.values():
        ladder = ladders[row["grid"]]
        arm = arm_of(row["configuration"], ladder if isinstance(ladder, dict) else {})
        task = found.setdefault(row["task"], {"arms": {}, "on_final_reward": {}, "ceiling": None, "runs": [0, 0]})
        runs = runs_of(row)
        task["runs"] = [task["runs"][0] + len(runs), task["runs"][1] + len(row["specs"])]
        if not runs:
            continue
        returns = plot.primary_returns(runs)
        learns_from = row["specs"][0].get("learned_reward")
        if row["algo"] == "sac" and not learns_from:  # SAC on the true reward: the ceiling
            if task["ceiling"] is not None:
                raise SystemExit(f"{row['task']}: two SAC rows on the true reward in the ladders; keep one ceiling")
            task["ceiling"] = returns
        elif row["algo"] == "sac":  # SAC learning from the r̂ a ladder run saved
            task["on_final_reward"].setdefault(arm, {})[int(row["feedback"])] = returns
        else:
            corr = last_correlations(runs)
            task["arms"].setdefault(arm, {})[int(row["feedback"])] = (returns, corr)

    def share(returns: np.ndarray, floor: float, ceiling: float | None) -> list[float] | None:
        if ceiling is None or ceiling == floor:
            return None
        return [round(v, 4) for v in mean_interval((returns - floor) / (ceiling - floor))]

    tasks, held_out = {}, held_out_tasks()
    for name, task in found.items():
        floor = floor_of(name)
        ceiling = None if task["ceiling"] is None else float(task["ceiling"].mean())

        arms = {
            arm: [
                {
                    "labels": b,
                    "seeds": len(r),
                    "share": share(r, floor, ceiling),
                    "corr": None if c is None else round(float(c.mean()), 4),
                }
                for b, (r, c) in sorted(points.items())
            ]
            for arm, points in task["arms"].items()
        }
        on_final = {
            arm: [{"labels": b, "seeds": len(r), "share": share(r, floor, ceiling)} for b, r in sorted(points.items())]
            for arm, points in task["on_final_reward"].items()
        }
        labels = {}
        pebble = task["arms"].get(reference, {})
        for arm, points in task["arms"].items():
            budgets = sorted(pebble)
            if len(budgets) >= 2 and set(budgets) <= set(points):  # an arm run at a few budgets only has no curve
                labels[arm] = bootstrap_labels(
                    budgets, [pebble[b][0] for b in budgets], [points[b][0] for b in budgets], floor
                )
                labels[arm]["deciding"] = deciding_budgets(budgets, labels[arm]["arm"]["labels"])
        tasks[name] = {
            "floor": floor,
            "ceiling": ceiling,
            "ceiling_seeds": 0 if task["ceiling"] is None else len(task["ceiling"]),
            "runs": task["runs"],
            "arms": arms,
            "on_final_reward": on_final,
            "labels": labels,
            "held_out": name in held_out,
        }
    return {"reference": reference, "target_share": TARGET_SHARE, "tasks": tasks}


def number_text(value: float, at_most: bool = False, count: bool = False) -> str:
    """A ratio, or a ``count`` of labels, as the tables write it: ∞ where the ladder does not reach, — where undefined,
    ≤ where it is an upper bound (reached at the ladder's lowest budget)."""
    if value == math.inf or math.isnan(value):
        text = "∞" if value == math.inf else "—"
    elif count:
        text = f"{value:.0f}" if value >= 10 or value == round(value) else f"{value:.1f}"
    else:
        text = f"{value:.2f}" if value < 10 else f"{value:.0f}"
    return f"≤ {text}" if at_most and math.isfinite(value) else text


def interval_text(values: list[float], count: bool = False) -> str:
    return "[" + ", ".join(number_text(v, count=count) for v in values) + "]"


def ratio_text(ratio: dict[str, Any]) -> str:
    """An arm's ratio to PEBBLE's labels with its interval."""
    return f"{number_text(ratio['value'], ratio.get('at_most', False))} {interval_text(ratio['interval'])}"


def labels_text(labels: dict[str, Any]) -> str:
    """An arm's labels to the target with their interval."""
    return f"{number_text(labels['labels'], labels.get('at_most', False), count=True)} {interval_text(labels['interval'], count=True)}"


def share_text(share: list[float] | None) -> str:
    return "—" if share is None else f"{share[0]:.2f} {interval_text(share[1:])}"


def seeds_text(count: int) -> str:
    return f"{count} seed" if count == 1 else f"{count} seeds"


def task_text(name: str, task: dict[str, Any]) -> str:
    """A task as the tables name it: held out or not, and how many of its runs are in until all are."""
    done, planned = task["runs"]
    shown = f"{name} (held out)" if task.get("held_out") else name
    return shown if done == planned else f"{shown} ({done} of {planned} runs in: not a reading yet)"


def render_labels_table(data: dict[str, Any]) -> str:
    """The number users need, task by task: each arm's labels to the target and its ratio to PEBBLE's."""
    reference = data["reference"]
    lines = [
        f"| task | arm | labels to the target [95% CI] | ÷ {reference} [95% CI] | share of SAC at the top budget |",
        "|---|---|---|---|---|",
    ]
    for name, task in data["tasks"].items():
        shown = task_text(name, task)
        for arm, read in task["labels"].items():
            labels, ratio = read["arm"], read["ratio"]
            top = task["arms"][arm][-1]
            lines.append(
                f"| {shown} | {arm} | {labels_text(labels)} | {ratio_text(ratio)} | {share_text(top['share'])} "
                f"({top['labels']} labels) |"
            )
    if len(lines) == 2:
        return no_ladder_text()
    note = (
        f"\nThe target is {data['target_share']:.0%} of the share of SAC's return that {reference} reaches at the "
        "ladder's top budget; labels are interpolated on log2(budget) where an arm's mean first reaches it (∞: not "
        "within the ladder; ≤: reached at its lowest budget, so at most that many, and the ratio at most that; — where "
        f"{reference} itself reaches it there); intervals are 95% percentile bootstraps over seeds. "
        + "; ".join(
            f"{arm}: {name}" for arm, name in ARM_NAMES.items() if any(arm in t["labels"] for t in data["tasks"].values())
        )
        + ".\n"
    )
    return "\n".join(lines) + "\n" + note


def render_labels_summary(data: dict[str, Any]) -> str:
    """The README's short form of :func:`render_labels_table`: a row per task, each arm's labels to the target and,
    beside every arm but PEBBLE, its ratio to PEBBLE's."""
    reference = data["reference"]
    arms = list(dict.fromkeys(arm for task in data["tasks"].values() for arm in task["labels"]))
    if not arms:
        return no_ladder_text()
    others = [arm for arm in arms if arm != reference]
    name = ARM_NAMES.get(reference, reference)
    header = [f"{name}: labels [95% CI]"] + [f"{ARM_NAMES.get(arm, arm)}: labels; ÷ {name}" for arm in others]
    lines = ["| task | " + " | ".join(header) + " |", "|---" * (len(header) + 1) + "|"]
    for task_name, task in data["tasks"].items():
        cells = []
        for arm in arms:
            read = task["labels"].get(arm)
            if read is None:
                cells.append("—")
                continue
            text = labels_text(read["arm"])
            if arm != reference:
                text += f"; {ratio_text(read['ratio'])}"
            cells.append(text)
        lines.append(f"| {task_text(task_name, task)} | " + " | ".join(cells) + " |")
    return (
        "\n".join(lines)
        + f"\n\nThe target: {data['target_share']:.0%} of the share of SAC's return {name} reaches at the ladder's top "
        "budget; labels interpolated on log2(budget), 95% bootstrap intervals over seeds; the paper's claim reads the "
        f"ratio ÷ {name} as at most 0.5.\n"
    )


def render_ladders(data: dict[str, Any]) -> str:
    """Every point of every ladder: seeds, share of SAC's return, last corr(r̂, r); SAC on the final r̂ beside."""
    lines = []
    for name, task in data["tasks"].items():
        ceiling = "not run" if task["ceiling"] is None else f"{task['ceiling']:.1f} ({seeds_text(task['ceiling_seeds'])})"
        deciding = "; ".join(
            f"{arm} {', '.join(map(str, read.get('deciding', []))) or 'none'}" for arm, read in task["labels"].items()
        )
        lines += [
            f"### {name}",
            "",
            f"SAC on the true reward: {ceiling}; a random policy: {task['floor']:.1f}.",
            "",
            f"The budgets each arm's labels to the target turn on (either side of it): {deciding or 'not read yet'}.",
            "",
            "| arm | labels | seeds | share of SAC [95% CI] | corr(r̂, r), last | SAC on the final r̂ [95% CI] |",
            "|---|---|---|---|---|---|",
        ]
        for arm, points in task["arms"].items():
            finals = {p["labels"]: p for p in task["on_final_reward"].get(f"sac_on_{arm}_reward", [])}
            for point in points:
                corr = "—" if point["corr"] is None else f"{point['corr']:.2f}"
                final = finals.get(point["labels"])
                final_text = "—" if final is None else f"{share_text(final['share'])} ({seeds_text(final['seeds'])})"
                lines.append(
                    f"| {arm} | {point['labels']} | {point['seeds']} | {share_text(point['share'])} | {corr} | {final_text} |"
                )
        lines.append("")
    return "\n".join(lines)


def draw_ladders(data: dict[str, Any], path: Path) -> None:
    """Share of the ceiling against labels (log axis), one panel per task, each arm with its 95% interval and the
    target line."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    tasks = data["tasks"]
    figure, axes = plt.subplots(1, max(len(tasks), 1), figsize=(5 * max(len(tasks), 1), 3.8), squeeze=False)
    for axis, (name, task) in zip(axes[0], tasks.items(), strict=False):
        for arm, points in task["arms"].items():
            shown = [p for p in points if p["share"] is not None]
            shares = np.array([p["share"] for p in shown]).reshape(-1, 3)
            budgets = [p["labels"] for p in shown]
            axis.plot(budgets, shares[:, 0], marker="o", label=ARM_NAMES.get(arm, arm))
            axis.fill_between(budgets, shares[:, 1], shares[:, 2], alpha=0.2)
        top = task["arms"].get(data["reference"], [{}])[-1].get("share")
        if top is not None:
            axis.axhline(data["target_share"] * top[0], color="grey", linestyle="--", linewidth=1, label="target")
        axis.set_xscale("log", base=2)
        axis.set(title=name, xlabel="labels", ylabel="share of SAC's return")
        axis.legend(fontsize="x-small")
    path.parent.mkdir(parents=True, exist_ok=True)
    figure.tight_layout()
    figure.savefig(path, dpi=120)


def study_grids() -> list[Path]:
    """The study's grid files, the screen's looks and the ladders, committed or pending."""
    return sorted(GRIDS.glob("label-response*.yml")) + sorted(GRIDS.glob("pending/label-response*.yml"))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("what", choices=["screen", "ladders", "provenance"])
    parser.add_argument(
        "grids", nargs="*", type=Path, help="ladders: the ladder grid files; provenance: the grid files (default: the study's)"
    )
    parser.add_argument("--reference", default="pebble", help="ladders: the arm whose top budget sets the target")
    parser.add_argument(
        "--runs-folder",
        type=Path,
        help="ladders, provenance: read the runs from this folder (a worktree's) in place of the grids' out",
    )
    parser.add_argument("--print", action="store_true", help="screen: print the page, write no file")
    args = parser.parse_args()
    if args.what == "ladders":
        if not args.grids:
            parser.error("ladders needs the ladder grid files")
        data = read_ladders(args.grids, args.reference, args.runs_folder)
        print(render_labels_table(data) + "\n" + render_ladders(data))
        return
    if args.what == "provenance":
        files = args.grids or study_grids()
        late, read = runs_before_their_rule(files, args.runs_folder)
        print(
            f"{read} runs of {len(files)} grid files read; "
            + (f"run before their rule: {', '.join(late)}" if late else "each ran on a commit that holds its grid file's rule")
        )
        sys.exit(1 if late else 0)
    data = read_screen()
    text = render_screen(data)
    if args.print:
        print(text)
        return
    SCREEN_PAGE.write_text(text)
    SCREEN_PAGE.with_suffix(".json").write_text(json.dumps(data, indent=1) + "\n")
    print(f"wrote {relative(SCREEN_PAGE)} and its .json")


if __name__ == "__main__":
    main()
