"""
The report of ``benchmarks/reward_bench.py``'s screens: the decision rules, written before the screens ran
(:data:`DECISION_RULE` against plain learning, :data:`INCUMBENT_RULE` against an incumbent configuration), the
summary over seeds (:func:`summarize`), the verdicts (:func:`decide`, :func:`decide_against`), the Markdown page
(:func:`markdown`) and one screen made of several (:func:`merge`).
"""

import json
from pathlib import Path
from typing import Any

import numpy as np

DECISION_RULE = (
    "Written before the screen ran. Primary metric: mean held-out corr(r̂, r) over seeds. A configuration is a "
    "**finalist** if (a) at 100 labels its mean corr exceeds plain's at 100 labels by more than the larger of the two "
    "standard deviations, and (b) at 200 labels its mean corr is at least plain's at 400 labels minus 0.02. Among "
    "finalists the one with the highest mean corr at 100 labels is **chosen**; it **reaches** plain at 400 if its mean "
    "corr at 100 labels is at least plain's at 400 labels (otherwise the gap is reported). Held-out pair accuracy "
    "must not be lower than plain's at the same budget by more than 0.02 (a sanity check, not a ranking). The "
    "flipped-label row must read a negative corr and an accuracy below 0.5 at every budget, or the bench is broken."
)


INCUMBENT_RULE = (
    "Written before the screen ran, for a screen against an incumbent (--incumbent), on the same seeds and labels. "
    "Primary metric: mean held-out corr(r̂, r) over seeds at 200 labels (half the tier's 400). A configuration "
    "**replaces** the incumbent if (a) at 200 labels its mean corr exceeds the incumbent's by more than the larger of "
    "the two standard deviations and (b) at 100 labels its mean corr is not below the incumbent's; among those, the "
    "highest mean corr at 200 labels is **chosen**. A configuration is a **cheaper equal** if at 100 and at 200 labels "
    "its mean corr is at least the incumbent's minus 0.02 and its mean fit time at 200 labels (consistency passes and "
    "reward training, one process, configurations in turns) is below the incumbent's; the cheapest cheaper equal is "
    "**chosen as cheaper**. Held-out pair accuracy must not be lower than the incumbent's at the same budget by more "
    "than 0.02 (a sanity check, not a ranking)."
)


def summarize(runs: dict[str, dict[int, dict[int, dict[str, float]]]], budgets: list[int]) -> dict[str, Any]:
    """Mean and std over seeds of each metric, per configuration and budget."""
    table: dict[str, Any] = {}
    for name, by_seed in runs.items():
        table[name] = {}
        for budget in budgets:
            cell = {}
            for metric in ("corr", "pair_accuracy", "epochs", "seconds"):
                values = np.array([by_seed[seed][budget][metric] for seed in by_seed])
                cell[metric] = {"mean": float(values.mean()), "std": float(values.std())}
            table[name][str(budget)] = cell
    return table


def decide(table: dict[str, Any], budgets: list[int]) -> dict[str, Any]:
    """Apply ``DECISION_RULE`` to the summary."""

    def corr(name: str, budget: int) -> tuple[float, float]:
        cell = table[name][str(budget)]["corr"]
        return cell["mean"], cell["std"]

    if not {100, 200, 400} <= set(budgets) or "plain" not in table:
        return {"note": "the rule needs plain at 100, 200 and 400 labels"}
    plain100, plain100_std = corr("plain", 100)
    plain400, _ = corr("plain", 400)
    finalists = []
    for name in table:
        if name == "plain" or "flipped" in name:
            continue
        mean100, std100 = corr(name, 100)
        mean200, _ = corr(name, 200)
        if mean100 - plain100 > max(std100, plain100_std) and mean200 >= plain400 - 0.02:
            finalists.append(name)
    chosen = max(finalists, key=lambda name: corr(name, 100)[0]) if finalists else None
    verdict: dict[str, Any] = {"finalists": finalists, "chosen": chosen, "plain_corr_at_400": plain400}
    if chosen is not None:
        verdict["chosen_corr_at_100"] = corr(chosen, 100)[0]
        verdict["reaches_plain_at_400_with_100_labels"] = corr(chosen, 100)[0] >= plain400
        verdict["gap_at_100_to_plain_at_400"] = plain400 - corr(chosen, 100)[0]
    for name in table:
        verdict.setdefault("gap_at_100_to_plain_at_400_by_config", {})[name] = plain400 - corr(name, 100)[0]
    flipped = [name for name in table if "flipped" in name]
    verdict["flipped_reads_bad"] = all(
        table[name][str(b)]["corr"]["mean"] < 0 and table[name][str(b)]["pair_accuracy"]["mean"] < 0.5
        for name in flipped
        for b in budgets
    )
    return verdict


def decide_against(table: dict[str, Any], incumbent: str) -> dict[str, Any]:
    """Apply ``INCUMBENT_RULE`` to the summary."""

    def cell(name: str, budget: int, metric: str) -> tuple[float, float]:
        values = table[name][str(budget)][metric]
        return values["mean"], values["std"]

    if incumbent not in table or not {"100", "200"} <= set(table[incumbent]):
        return {"note": f"the rule needs the incumbent {incumbent!r} at 100 and 200 labels"}
    base200, base200_std = cell(incumbent, 200, "corr")
    base100, _ = cell(incumbent, 100, "corr")
    base_seconds = cell(incumbent, 200, "seconds")[0]
    better, cheaper, sane = [], [], {}
    for name in table:
        if name == incumbent:
            continue
        mean200, std200 = cell(name, 200, "corr")
        mean100, _ = cell(name, 100, "corr")
        if mean200 - base200 > max(std200, base200_std) and mean100 >= base100:
            better.append(name)
        if mean100 >= base100 - 0.02 and mean200 >= base200 - 0.02 and cell(name, 200, "seconds")[0] < base_seconds:
            cheaper.append(name)
        sane[name] = all(
            cell(name, b, "pair_accuracy")[0] >= cell(incumbent, b, "pair_accuracy")[0] - 0.02 for b in (100, 200)
        )
    return {
        "incumbent": incumbent,
        "replaces": better,
        "chosen": max(better, key=lambda name: cell(name, 200, "corr")[0]) if better else None,
        "cheaper_equals": cheaper,
        "chosen_as_cheaper": min(cheaper, key=lambda name: cell(name, 200, "seconds")[0]) if cheaper else None,
        "corr_at_200_minus_incumbent": {name: cell(name, 200, "corr")[0] - base200 for name in table},
        "seconds_at_200_over_incumbent": {name: cell(name, 200, "seconds")[0] / base_seconds for name in table},
        "pair_accuracy_sane": sane,
    }


def verdict_of(table: dict[str, Any], budgets: list[int], incumbent: str | None) -> tuple[str, dict[str, Any]]:
    """The rule a screen is judged by and its verdict: against plain, or against an incumbent."""
    if incumbent is None:
        return DECISION_RULE, decide(table, budgets)
    return INCUMBENT_RULE, decide_against(table, incumbent)


def markdown(result: dict[str, Any]) -> str:
    budgets = result["budgets"]
    lines = [
        "# Reward-learning bench: walker-walk",
        "",
        f"Made by `{result['command']}` in {result['seconds']:.0f} s "
        f"on one CPU thread ({result['system'].get('CPU')}); sb3_pride {result['version'].get('sb3_pride')}, "
        f"uncommitted changes: {result['version'].get('dirty')} (the git revision of the code and of the data's "
        f"recording: `version` and `data` in the JSON file). Data: the first {result['data']['steps']} steps of PEBBLE "
        f"seed {result['data'].get('seed')}, recorded by `{result['data'].get('command')}`.",
        "",
        f"Seeds {result['seeds']}; uniform {result['reward_kwargs']['segment_length']}-step pairs of the training "
        f"episodes (80%), drawn and labelled in sessions of {result['reward_kwargs']['queries_per_session']}; "
        + (
            "one model trained after each session on every label so far, as PEBBLE does"
            if result["sessions"]
            else "each budget trained in one go (a fresh model on the budget's first labels)"
        )
        + " with `RewardEnsemble.train_epochs` (3 members, 256×3, lr 3e-4, batch 128, ≤ 50 epochs, 97% early stop "
        "unless said otherwise); each seed draws its own held-out episodes (20%) and pairs, "
        "the same for every configuration. Held-out corr(r̂, r) over every held-out transition; pair accuracy over "
        f"{result['n_test_pairs']} held-out segment pairs; mean ± std over seeds.",
        "",
        *([f"**Note:** {result['note']}", ""] if result.get("note") else []),
        *(
            [
                "Seeds per configuration (merged from "
                + ", ".join(f"`{p['file']}`" for p in result["parts"])
                + "): "
                + "; ".join(f"{name}: {sorted(int(s) for s in by_seed)}" for name, by_seed in result["runs"].items()),
                "",
            ]
            if result.get("parts")
            else []
        ),
        "## Decision rule",
        "",
        result.get("decision_rule", DECISION_RULE),
        "",
        "## corr(r̂, r) on held-out transitions",
        "",
        "| configuration | " + " | ".join(f"{b} labels" for b in budgets) + " |",
        "|---|" + "---|" * len(budgets),
    ]
    table = result["table"]

    def row(metric: str, digits: int = 2) -> list[str]:
        out = []
        for name, cells in table.items():
            values = [
                f"{cells[str(b)][metric]['mean']:.{digits}f} ± {cells[str(b)][metric]['std']:.{digits}f}" for b in budgets
            ]
            out.append(f"| {name} | " + " | ".join(values) + " |")
        return out

    lines += row("corr")
    lines += ["", "## Preference accuracy on held-out segment pairs", ""]
    lines += ["| configuration | " + " | ".join(f"{b} labels" for b in budgets) + " |", "|---|" + "---|" * len(budgets)]
    lines += row("pair_accuracy")
    lines += ["", "## Epochs of training (all sessions so far with --sessions): the cost, mean ± std", ""]
    lines += ["| configuration | " + " | ".join(f"{b} labels" for b in budgets) + " |", "|---|" + "---|" * len(budgets)]
    lines += row("epochs", 0)
    lines += ["", "## Verdict", "", "```json", json.dumps(result["verdict"], indent=2), "```", ""]
    lines += ["Configurations: " + "; ".join(f"{name}: `{config}`" for name, config in result["configs"].items()), ""]
    return "\n".join(lines)


def merge(paths: list[Path], out: Path) -> dict[str, Any]:
    """
    One screen from several made on the same data and settings (a screen split across processes, one per core): the
    runs of every configuration and seed, the table and the verdict recomputed; each part's command and version kept.
    """
    parts = [json.loads(path.read_text()) for path in paths]
    first = parts[0]
    for path, part in zip(paths, parts, strict=True):
        for key in ("budgets", "sessions", "reward_kwargs", "n_test_pairs", "data", "incumbent"):
            if part.get(key) != first.get(key):
                raise SystemExit(f"--merge: {path} differs from {paths[0]} in {key!r}")
    runs: dict[str, dict[int, dict[int, dict[str, float]]]] = {}
    configs: dict[str, Any] = {}
    for part in parts:
        configs.update(part["configs"])
        for name, by_seed in part["runs"].items():
            for seed, cells in by_seed.items():
                if int(seed) in runs.setdefault(name, {}):
                    raise SystemExit(f"--merge: {name!r} seed {seed} is in more than one file")
                runs[name][int(seed)] = {int(budget): cell for budget, cell in cells.items()}
    budgets = first["budgets"]
    table = summarize(runs, budgets)
    rule, verdict = verdict_of(table, budgets, first.get("incumbent"))
    result = {
        **{key: first[key] for key in ("budgets", "sessions", "n_test_pairs", "reward_kwargs", "data", "system")},
        "command": " + ".join(part["command"] for part in parts),
        "seconds": sum(part["seconds"] for part in parts),
        "seeds": sorted({int(seed) for by_seed in runs.values() for seed in by_seed}),
        "configs": configs,
        "decision_rule": rule,
        "incumbent": first.get("incumbent"),
        "table": table,
        "verdict": verdict,
        "runs": runs,
        "version": first["version"],
        "parts": [
            {"file": path.name, "command": part["command"], "version": part["version"]}
            for path, part in zip(paths, parts, strict=True)
        ],
    }
    out.with_suffix(".json").write_text(json.dumps(result, indent=2, default=str))
    out.with_suffix(".md").write_text(markdown(result))
    return result
