"""
The paper's figures re-drawn from ``benchmarks/run.py`` results, plus an rliable aggregate.

    python benchmarks/plot.py --runs benchmarks/results/runs --out benchmarks/results/figures

``--runs`` takes several folders and pools their runs (the same configuration's seeds from each); ``--only`` keeps
the configurations named (labels as in ``summary.md``), e.g. a default against PEBBLE in a figure of its own.

For every task: learning curves (mean ± std over seeds, shaded) of every configuration at u = 0.5 (or at the one u a
PRIDE variant ran at, such as a task's CPU setting) and of SAC (the paper's Figures 2–4: equal feedback, and PRIDE
at reduced feedback), the synthetic-ratio sweep of PRIDE (Figure 5) and, for Meta-World, success rates (Figure 3).
The aggregate is the interquartile mean (IQM) of the final evaluation with 95% stratified-bootstrap intervals
(rliable), scores normalized per task by the best configuration's mean, over the seeds every task of a configuration
has (configurations with one seed are left out). The paper's pairwise claims get rliable's probability of
improvement P(X > Y) (Mann-Whitney over seeds) with a 95% bootstrap interval: every PRIDE configuration of a task
against PEBBLE at that task's largest budget, and PRIDE at u = 0.5 against the other synthetic ratios.
``summary.md`` lists every configuration with its number of seeds, those comparisons, and diagnostics read from
each run's SB3 log (``progress.csv``): the reward model's correlation with the true reward, the critic loss and
−(actor loss) ≈ Q at the end of training.
"""

import argparse
import json
from collections import defaultdict
from pathlib import Path
from typing import TypedDict

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

COLORS = {"pride": "tab:red", "pebble": "tab:blue", "sac": "tab:gray"}


class Aggregate(TypedDict):
    """A configuration's entry in the aggregate: the IQM, its 95% interval and the number of runs."""

    iqm: float
    ci95: list[float]
    runs: int


def variant(settings: dict) -> str:
    """The run's variant tag, "" when untagged (older runs have no "tag" key, newer ones an empty one)."""
    return settings.get("tag") or ""


def label(settings: dict) -> str:
    if settings["algo"] == "sac":
        return "SAC (true reward)"
    text = f"{settings['algo'].upper()} ({settings['feedback']} queries"
    if settings["algo"] == "pride":
        text += f", u={settings['ratio']}"
    if settings.get("tag"):
        text += f", {settings['tag']}"
    return text + ")"


def load_run(folder: Path, progress: bool = True) -> dict:
    """A finished run's folder: its settings, curve arrays and (``progress=True``, when present) SB3 log columns."""
    settings = json.loads((folder / "settings.json").read_text())
    curve = np.atleast_1d(np.genfromtxt(folder / "curve.csv", delimiter=",", names=True))
    columns = None
    if progress and (folder / "progress.csv").exists():
        table = np.genfromtxt(folder / "progress.csv", delimiter=",", names=True, deletechars="", dtype=float)
        assert table.dtype.names is not None  # names=True: the header's columns
        columns = {key: np.atleast_1d(table[key]) for key in table.dtype.names}
    return {"settings": settings, "curve": curve, "progress": columns}


def load_runs(folder: Path) -> dict[tuple[str, str], list[dict]]:
    """{(task, configuration label): [run, ...]}, each run with its settings and curve arrays."""
    groups: dict[tuple[str, str], list[dict]] = defaultdict(list)
    for result in sorted(folder.glob("*/result.json")):
        run = load_run(result.parent)
        groups[(run["settings"]["task"], label(run["settings"]))].append(run)
    return groups


def stack(runs: list[dict], column: str) -> tuple[np.ndarray, np.ndarray]:
    """Steps common to all runs and the (runs, steps) values of ``column``."""
    length = min(len(run["curve"]) for run in runs)
    steps = runs[0]["curve"]["step"][:length]
    return steps, np.stack([run["curve"][column][:length] for run in runs])


#: the primary metric averages a run's last evaluations: steadier than the last one alone
LAST_EVALUATIONS = 3


def final_returns(runs: list[dict]) -> np.ndarray:
    """The last evaluation's true return of every run."""
    return np.array([run["curve"]["true_return"][-1] for run in runs])


def primary_returns(runs: list[dict]) -> np.ndarray:
    """The primary metric of every run: the mean true return of its last ``LAST_EVALUATIONS`` evaluations."""
    return np.array([np.mean(run["curve"]["true_return"][-LAST_EVALUATIONS:]) for run in runs])


def bootstrap(score_dict: dict, func) -> tuple[dict, dict]:
    """
    rliable's point estimates and 95% stratified-bootstrap intervals, each entry's drawn on its own from NumPy seed 0
    (rliable draws from NumPy's global RNG): an entry's interval depends on its own scores only, not on which other
    runs the folder holds.
    """
    from rliable import library as rly

    point, intervals = {}, {}
    for key, scores in score_dict.items():
        np.random.seed(0)
        one_point, one_interval = rly.get_interval_estimates({key: scores}, func, reps=2000)
        point[key], intervals[key] = one_point[key], one_interval[key]
    return point, intervals


def plot_curves(groups, task: str, keep, column: str, ylabel: str, title: str, path: Path) -> bool:
    selected = {
        name: runs
        for (t, name), runs in groups.items()
        if t == task and keep(runs[0]["settings"]) and not np.all(np.isnan(stack(runs, column)[1]))
    }
    if not selected:
        return False
    fig, ax = plt.subplots(figsize=(6, 4))
    for i, (name, runs) in enumerate(sorted(selected.items())):
        steps, values = stack(runs, column)
        mean, std = np.nanmean(values, axis=0), np.nanstd(values, axis=0)
        settings = runs[0]["settings"]
        if len(selected) <= 4:  # few configurations (e.g. with --only): one colour each, PRIDE variants included
            color = f"C{i}"
        elif settings["algo"] != "pride" or settings["ratio"] == 0.5:
            color = COLORS[settings["algo"]]
        else:
            color = f"C{i + 3}"
        style = (
            "--"
            if settings["algo"] == "pride"
            and settings["feedback"] < max(r[0]["settings"]["feedback"] for r in selected.values())
            else "-"
        )
        ax.plot(steps, mean, style, color=color, label=f"{name}, n={len(runs)}")
        ax.fill_between(steps, mean - std, mean + std, color=color, alpha=0.2)
    ax.set_xlabel("environment steps")
    ax.set_ylabel(ylabel)
    ax.set_title(title)
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return True


def aggregate(groups, out: Path) -> dict:
    """IQM of the primary returns (last 3 evaluations), normalized per task by the best configuration's mean, 95% CIs."""
    from rliable import metrics

    finals: dict[str, dict[str, np.ndarray]] = defaultdict(dict)
    for (task, name), runs in groups.items():
        finals[name][task] = primary_returns(runs)
    tasks = sorted({task for task, _ in groups})
    best = {task: max(np.mean(finals[name][task]) for name in finals if task in finals[name]) for task in tasks}
    scores = {}
    for name, per_task in finals.items():
        n = min(len(v) for v in per_task.values())
        if n < 2:
            continue  # no interval from one seed
        # (runs, tasks) over the tasks this configuration was run on
        scores[name] = np.stack([per_task[task][:n] / best[task] for task in sorted(per_task)], axis=1)
    if not scores:
        return {}
    point, intervals = bootstrap(scores, lambda x: np.array([metrics.aggregate_iqm(x)]))
    result: dict[str, Aggregate] = {
        name: {
            "iqm": float(point[name][0]),
            "ci95": [float(intervals[name][0, 0]), float(intervals[name][1, 0])],
            "runs": len(scores[name]),
        }
        for name in scores
    }
    names = sorted(result, key=lambda name: result[name]["iqm"])
    fig, ax = plt.subplots(figsize=(6, 0.5 + 0.45 * len(names)))
    for y, name in enumerate(names):
        low, high = result[name]["ci95"]
        ax.plot([low, high], [y, y], color="k", linewidth=3, alpha=0.4)
        ax.plot(result[name]["iqm"], y, "o", color="k")
    ax.set_yticks(range(len(names)), [f"{name}, n={result[name]['runs']}" for name in names], fontsize=7)
    ax.set_xlabel("IQM of return (last 3 evaluations) / best configuration's mean (95% bootstrap CI)")
    fig.tight_layout()
    fig.savefig(out / "aggregate_iqm.png", dpi=120)
    plt.close(fig)
    return result


def improvements(groups) -> dict:
    """
    P(X > Y) on the primary return (mean of the last 3 evaluations), with 95% bootstrap CIs (rliable), for the paper's pairwise claims: every
    PRIDE configuration of a task against every PEBBLE configuration (each UTD) at the task's largest budget and at
    its own (Figs. 2 and 4), PRIDE at u = 0.5 against every other u of the same variant and budget (Fig. 5), each tagged PRIDE
    variant against "faithful" PRIDE at the same u and budget (the ablation), each tagged
    PEBBLE variant against plain PEBBLE at its budget, and plain PEBBLE at a smaller budget against the largest. Pairs where either side has fewer than two seeds are left out.
    """

    pairs = {}
    for (task, name), runs in groups.items():
        settings = runs[0]["settings"]
        pebbles = [(n, r) for (t, n), r in groups.items() if t == task and r[0]["settings"]["algo"] == "pebble"]
        if settings["algo"] == "pebble":  # a PEBBLE variant (another UTD, a smaller budget) against plain PEBBLE
            largest = max(r[0]["settings"]["feedback"] for _, r in pebbles)
            budget = settings["feedback"] if settings.get("tag") else largest
            if settings.get("tag") or settings["feedback"] < largest:
                rivals = [
                    (n, r) for n, r in pebbles if not r[0]["settings"].get("tag") and r[0]["settings"]["feedback"] == budget
                ]
                for rival_name, rival in rivals:
                    if min(len(runs), len(rival)) >= 2:
                        pairs[f"{task}: {name} > {rival_name}"] = [primary_returns(g)[:, None] for g in (runs, rival)]
            continue
        if settings["algo"] != "pride":
            continue
        # every PEBBLE at the task's largest budget (each UTD), and at this configuration's own budget
        budgets = {max((r[0]["settings"]["feedback"] for _, r in pebbles), default=None), settings["feedback"]}
        rivals = [(n, r) for n, r in pebbles if r[0]["settings"]["feedback"] in budgets]
        if settings["ratio"] == 0.5:  # Fig. 5: u = 0.5 against the other ratios of the same variant (tag)
            rivals += [
                (n, r)
                for (t, n), r in groups.items()
                if t == task
                and r[0]["settings"]["algo"] == "pride"
                and r[0]["settings"]["feedback"] == settings["feedback"]
                and r[0]["settings"]["ratio"] != 0.5
                and variant(r[0]["settings"]) == variant(settings)
            ]
        if variant(settings) not in ("", "faithful"):  # an ablation: a variant against "faithful" PRIDE
            rivals += [
                (n, r)
                for (t, n), r in groups.items()
                if t == task
                and r[0]["settings"]["algo"] == "pride"
                and variant(r[0]["settings"]) == "faithful"
                and r[0]["settings"]["ratio"] == settings["ratio"]
                and r[0]["settings"]["feedback"] == settings["feedback"]
            ]
        for rival_name, rival in rivals:
            if min(len(runs), len(rival)) >= 2:
                pairs[f"{task}: {name} > {rival_name}"] = [
                    primary_returns(group)[:, None] for group in (runs, rival)
                ]  # (runs, 1 task)
    return probabilities_of_improvement(pairs)


def probabilities_of_improvement(pairs: dict) -> dict:
    """{"X > Y": [X's returns, Y's]} -> rliable's P(X > Y), its 95% interval and the seeds of each side."""
    from rliable import metrics

    if not pairs:
        return {}
    point, intervals = bootstrap(pairs, metrics.probability_of_improvement)
    return {
        key: {
            "p": float(np.ravel(point[key])[0]),
            "ci95": [float(np.ravel(bound)[0]) for bound in intervals[key]],
            "seeds": [len(pairs[key][0]), len(pairs[key][1])],
        }
        for key in sorted(pairs)
    }


def improvement_row(key: str, value: dict) -> str:
    low, high = value["ci95"]
    return f"| {key} | {value['seeds'][0]} vs {value['seeds'][1]} | {value['p']:.2f} | [{low:.2f}, {high:.2f}] |"


def diagnostics(runs: list[dict]) -> dict[str, float]:
    """
    Means over seeds of the last logged value of a few SB3 logger keys, and of the mean over all retrains of the
    synthetic data's fidelity (runs without progress.csv, or without the key, are skipped).
    """
    # the last retrain's ratios too: the dynamics ensemble that judges them is warm-started and improves over a run,
    # and a weaker judge reads every ratio closer to 1, so the mean over retrains is flattered by the early ones
    last = {
        "corr": "reward_model/true_reward_corr",
        "critic": "train/critic_loss",
        "actor": "train/actor_loss",
        "critic_real": "train/critic_loss_real",
        "q_real": "train/q_real",
        "dynamics_last": "diffusion/dynamics_error_ratio",
        "heldout_last": "diffusion/heldout_anchor_error_ratio",
    }
    over_retrains = {
        "dynamics": "diffusion/dynamics_error_ratio",
        "kept": "diffusion/kept_dynamics_error_ratio",
        "heldout": "diffusion/heldout_anchor_error_ratio",
        "novelty": "diffusion/novelty_ratio",
    }
    values: dict[str, list[float]] = defaultdict(list)
    for run in runs:
        if run["progress"] is None:
            continue
        for short, key in [*last.items(), *over_retrains.items()]:
            column = run["progress"].get(key, np.array([]))
            column = column[~np.isnan(column)]
            if len(column):
                values[short].append(float(column[-1] if short in last else column.mean()))
    return {short: float(np.mean(v)) for short, v in values.items()} | {"n": max(map(len, values.values()), default=0)}


def summary(groups) -> str:
    lines = [
        "| task | configuration | seeds | return, last 3 evaluations (mean ± std) | final return (mean ± std) | best return (mean) | area under curve (mean) | final success | success, area under curve |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for (task, name), runs in sorted(groups.items()):
        primary, finals = primary_returns(runs), final_returns(runs)
        bests = np.array([np.max(run["curve"]["true_return"]) for run in runs])
        areas = np.array([np.mean(run["curve"]["true_return"]) for run in runs])  # mean over evaluations
        success = [run["curve"]["success"][-1] for run in runs]
        success_area = [np.mean(run["curve"]["success"]) for run in runs]
        success_text = "| " if np.all(np.isnan(success)) else f"{np.nanmean(success):.2f} | {np.nanmean(success_area):.2f}"
        lines.append(
            f"| {task} | {name} | {len(runs)} | {primary.mean():.1f} ± {primary.std():.1f} | {finals.mean():.1f} ± {finals.std():.1f} | {bests.mean():.1f} | {areas.mean():.1f} | {success_text} |"
        )
    lines += [
        "",
        "Probability of improvement (return, mean of the last 3 evaluations; rliable, 95% bootstrap CI):",
        "",
        "| comparison | seeds | P(X > Y) | 95% CI |",
        "|---|---|---|---|",
    ]
    lines += [improvement_row(key, value) for key, value in improvements(groups).items()]
    lines += [
        "",
        "At the end of training (means over the runs that have progress.csv):",
        "",
        "| task | configuration | runs | corr(r̂, r) | critic loss | critic loss, real batch | Q, real batch | −actor loss (≈ Q) "
        "| dynamics error ratio (all retrains) | kept after filter | held-out anchors | novelty "
        "| dynamics error ratio, last retrain | held-out anchors, last retrain |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]

    def cell(d: dict, key: str, digits: int, sign: float = 1.0) -> str:
        return f"{sign * d[key]:.{digits}f}" if key in d else ""

    for (task, name), runs in sorted(groups.items()):
        d = diagnostics(runs)
        if d["n"]:
            lines.append(
                f"| {task} | {name} | {d['n']} | {cell(d, 'corr', 2)} | {cell(d, 'critic', 3)} | {cell(d, 'critic_real', 3)} | "
                f"{cell(d, 'q_real', 1)} | {cell(d, 'actor', 1, -1.0)} | {cell(d, 'dynamics', 2)} | {cell(d, 'kept', 2)} | "
                f"{cell(d, 'heldout', 2)} | {cell(d, 'novelty', 2)} | {cell(d, 'dynamics_last', 2)} | "
                f"{cell(d, 'heldout_last', 2)} |"
            )
    return "\n".join(lines) + "\n"


def compare(groups, pairs: list[list[str]], parser: argparse.ArgumentParser) -> None:
    """P(X > Y) on the primary return (rliable, as in summary.md) for pairs that the summary does not make."""
    for task, *names in pairs:
        for name in names:
            if (task, name) not in groups:
                known = sorted(n for t, n in groups if t == task)
                parser.error(f"--compare: no runs of {name!r} on {task!r}; configurations there: {known}")
    scores = {
        f"{task}: {x} > {y}": [primary_returns(groups[(task, name)])[:, None] for name in (x, y)] for task, x, y in pairs
    }
    for key, value in probabilities_of_improvement(scores).items():
        print(improvement_row(key, value))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument(
        "--runs",
        type=Path,
        nargs="+",
        default=[Path("benchmarks/results/runs")],
        help="folders of runs, pooled (e.g. runs/ and a folder of extra seeds)",
    )
    parser.add_argument("--out", type=Path, default=Path("benchmarks/results/figures"))
    parser.add_argument(
        "--only",
        nargs="+",
        metavar="LABEL",
        default=None,
        help="figures and summary of these configurations only (labels as in summary.md), e.g. the default against PEBBLE",
    )
    parser.add_argument(
        "--compare",
        nargs=3,
        action="append",
        metavar=("TASK", "X", "Y"),
        help="print P(X > Y) for these two configurations (labels as in summary.md) and nothing else; may be repeated",
    )
    args = parser.parse_args()
    groups: dict[tuple[str, str], list[dict]] = defaultdict(list)
    for folder in args.runs:
        for key, runs in load_runs(folder).items():
            seeds = {run["settings"]["seed"] for run in groups[key]} & {run["settings"]["seed"] for run in runs}
            if seeds:
                parser.error(f"--runs: {key[0]} {key[1]} has seeds {sorted(seeds)} in {folder} and in an earlier folder")
            groups[key].extend(runs)
    for runs in groups.values():  # seed order: a pooled bootstrap interval must not depend on the order of --runs
        runs.sort(key=lambda run: run["settings"]["seed"])
    if args.only:
        unknown = sorted(set(args.only) - {name for _, name in groups})
        if unknown:
            parser.error(f"--only: no runs labeled {unknown}; the labels are {sorted({name for _, name in groups})}")
        groups = defaultdict(list, {key: runs for key, runs in groups.items() if key[1] in args.only})
    if args.compare:
        compare(groups, args.compare, parser)
        return
    args.out.mkdir(parents=True, exist_ok=True)
    for task in sorted({task for task, _ in groups}):
        ratios: dict[str, set[float]] = {}  # the u each PRIDE variant (tag) ran at
        for (t, _), runs in groups.items():
            if t == task and runs[0]["settings"]["algo"] == "pride":
                ratios.setdefault(variant(runs[0]["settings"]), set()).add(runs[0]["settings"]["ratio"])
        # PRIDE at u = 0.5, or at the one u a variant ran at (a task's CPU setting)
        plot_curves(
            groups,
            task,
            lambda s, us=ratios: s["algo"] != "pride" or s["ratio"] == 0.5 or us[variant(s)] == {s["ratio"]},
            "true_return",
            "true return",
            f"{task} (dashed: PRIDE with less feedback)",
            args.out / f"curves_{task}.png",
        )
        # Fig. 5: each PRIDE variant run at more than one u
        for tag in (tag for tag, us in ratios.items() if len(us) > 1):
            plot_curves(
                groups,
                task,
                lambda s, tag=tag: s["algo"] == "pride" and variant(s) == tag,
                "true_return",
                "true return",
                f"{task}: PRIDE's synthetic ratio u" + (f" ({tag})" if tag else ""),
                args.out / f"ratio_{task}{'_' + tag if tag else ''}.png",
            )
        plot_curves(
            groups, task, lambda s: True, "success", "success rate", f"{task}: success", args.out / f"success_{task}.png"
        )
    text = summary(groups)
    (args.out / "summary.md").write_text(text)
    (args.out / "aggregate.json").write_text(json.dumps(aggregate(groups, args.out), indent=2))
    print(text)


if __name__ == "__main__":
    main()
