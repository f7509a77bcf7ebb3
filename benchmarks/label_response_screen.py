"""
The label-response study's screen: which candidate tasks qualify, by the rule its grid files state (written before
their runs), and which the study selects. Read by ``python benchmarks/label_response.py screen``.

It reads the SAC runs of the screen's grid files (in ``pending/`` until their runs are in): per task, the mean curve
over seeds; its plateau gap, (best - mean of the last third of the evaluations) / (best - first evaluation), must be
at most ``PLATEAU_GAP``, and the median of its runs' wall times must be at most ``MAX_MINUTES`` (runs on a shared
machine also time their neighbours); of the qualifying tasks the three cheapest are studied (at least one from
dm_control) and the next is held out. It writes ``benchmarks/results/label_response_screen.md`` and ``.json``.
"""

import json
import math
import sys
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

import run
from results_recount import GRIDS, ROOT, collect, relative, runs_of

SCREEN = GRIDS / "label-response-screen.yml"
#: the second look, at 100k steps, at the candidates the first one did not qualify (the rule's part 3)
RESCREEN = GRIDS / "label-response-rescreen.yml"
#: the third look, at new dm_control candidates, where the second one leaves the selection short
THIRD_LOOK = GRIDS / "label-response-third-look.yml"
#: the screen's looks in their order, named by their grid files (each committed or pending)
LOOKS = (SCREEN.name, RESCREEN.name, THIRD_LOOK.name)
SCREEN_PAGE = ROOT / "benchmarks" / "results" / "label_response_screen.md"
#: the screen's rule (the grid file's description states it in words)
PLATEAU_GAP = 0.05
MAX_MINUTES = 30
STUDIED, HELD_OUT = 3, 1


def plateau_gap(curve: np.ndarray) -> float:
    """(best - mean of the last third of the evaluations) / (best - first evaluation): 0 at a plateau at the best."""
    last = curve[-math.ceil(len(curve) / 3) :]
    rise = curve.max() - curve[0]
    return float((curve.max() - last.mean()) / rise) if rise > 0 else math.inf


def is_dm_control(task: str) -> bool:
    from sb3_pride.envs import DM_CONTROL_TASKS

    return task in DM_CONTROL_TASKS


def screen_grids() -> list[Path]:
    """The screen's grid files, in the order of its looks (where committed or pending)."""
    return [path for name in LOOKS for path in (GRIDS / name, GRIDS / "pending" / name) if path.exists()]


def read_screen(grid_files: list[Path] | None = None, runs_folder: Path | None = None) -> dict[str, Any]:
    """
    Each task of the screen with its seeds' curves read by the rule, and the selection the rule makes. A task a later
    grid screens again (longer) is read by its last look; the earlier one is kept beside it (``earlier``).
    """
    tasks: dict[str, dict[str, Any]] = {}
    for position, grid_file in enumerate(grid_files or screen_grids()):
        look = LOOKS.index(grid_file.name) if grid_file.name in LOOKS else position
        if look >= 2 and not needs_another_look(tasks):  # a third look runs only where the selection is short
            break
        for task, entry in read_look(grid_file, runs_folder).items():
            entry["look"] = look
            if task in tasks:
                entry["earlier"] = [*tasks[task].pop("earlier", []), tasks[task]]
            tasks[task] = entry
    return {"tasks": tasks, "selection": select(tasks)}


def read_look(grid_file: Path, runs_folder: Path | None = None) -> dict[str, dict[str, Any]]:
    """One grid of the screen: each task's entry as the rule reads it."""
    rows, _, _ = collect([grid_file], runs_folder)
    tasks: dict[str, dict[str, Any]] = {}
    for row in rows.values():
        runs = runs_of(row)
        if not runs:
            planned = run.run_kwargs(row["specs"][0])[0]
            tasks[row["task"]] = {"seeds": 0, "planned": len(row["specs"]), "steps": planned}
            continue
        length = min(len(found["curve"]) for found in runs)
        curve = np.mean([found["curve"]["true_return"][:length] for found in runs], axis=0)
        minutes = [found["result"]["seconds"] / 60 for found in runs]
        gap = plateau_gap(curve)
        qualifies = bool(gap <= PLATEAU_GAP and np.median(minutes) <= MAX_MINUTES)
        tasks[row["task"]] = {
            "seeds": len(runs),
            "planned": len(row["specs"]),
            "steps": int(runs[0]["curve"]["step"][length - 1]),
            "best": round(float(curve.max()), 2),
            "last_third": round(float(curve[-math.ceil(length / 3) :].mean()), 2),
            "first": round(float(curve[0]), 2),
            "plateau_gap": round(gap, 4),
            "minutes": {"median": round(float(np.median(minutes)), 1), "max": round(float(np.max(minutes)), 1)},
            "qualifies": qualifies,
            # the rule as first written read the slowest run: a task that qualifies only by the median says so
            "by_median_only": qualifies and bool(np.max(minutes) > MAX_MINUTES),
            "dm_control": is_dm_control(row["task"]),
        }
    return tasks


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
    dmc = [task for task in ranked if tasks[task]["dm_control"]]
    if studied and dmc and not set(studied) & set(dmc):
        studied = studied[: STUDIED - 1] + dmc[:1]
    rest = [task for task in ranked if task not in studied]
    dm_control_missing = not set(studied) & set(dmc)
    return {"studied": studied, "held_out": rest[:HELD_OUT], "waiting_for": [], "dm_control_missing": dm_control_missing}


def needs_another_look(tasks: dict[str, dict]) -> bool:
    """Whether the looks read so far, every seed of them in, leave the selection short: fewer than the tasks it
    studies and holds out, or none from dm_control (the condition a third look runs on)."""
    selection = select(tasks)
    return selection["studied"] is not None and (too_few(selection) or bool(selection["dm_control_missing"]))


def too_few(selection: dict[str, Any]) -> bool:
    """Whether a read selection holds fewer tasks than the rule studies and holds out."""
    return len(selection["studied"]) + len(selection["held_out"]) < STUDIED + HELD_OUT


def render_screen(data: dict[str, Any]) -> str:
    lines = [
        "# The label-response screen",
        "",
        "Generated by `python benchmarks/label_response.py screen` from the runs of "
        f"`{relative(SCREEN)}` (SAC on the true reward, the tier's settings), for the tasks it screened again at "
        f"100k steps `{relative(RESCREEN)}` and, for new candidates where the looks before left the selection short, "
        f"`{relative(THIRD_LOOK)}`; the rule is the first grid file's description: a "
        f"task qualifies where its mean curve's plateau gap is at most {PLATEAU_GAP} and its median run took at most "
        f"{MAX_MINUTES} minutes (the machine is shared: a run's time also measures its neighbours).",
        "",
        "| task | seeds | steps | first | best | last third | plateau gap | minutes per run (median / max) | qualifies |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    looks = [(task, look) for task, entry in data["tasks"].items() for look in [*entry.get("earlier", []), entry]]
    for task, entry in looks:
        if not entry["seeds"]:
            lines.append(f"| {task} | 0 of {entry['planned']} | {entry['steps']} | — | — | — | — | — | not run |")
            continue
        minutes = entry["minutes"]
        lines.append(
            f"| {task} | {entry['seeds']} of {entry['planned']} | {entry['steps']} | {entry['first']:.1f} | "
            f"{entry['best']:.1f} | {entry['last_third']:.1f} | {entry['plateau_gap']:.3f} | "
            f"{minutes['median']:.1f} / {minutes['max']:.1f} | {'yes' if entry['qualifies'] else 'no'}"
            f"{' (by the median run only)' if entry.get('by_median_only') else ''}"
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
    failed = [  # failed at the first look and not yet screened again
        task
        for task, entry in data["tasks"].items()
        if not entry.get("qualifies") and "earlier" not in entry and not entry.get("look", 0)
    ]
    if selection["studied"] is not None and selection.get("dm_control_missing"):
        lines.append("No dm_control task qualifies: the selection holds none, where the rule asks for one.")
    if selection["studied"] is not None and too_few(selection):
        lines.append(
            f"Fewer than {STUDIED + HELD_OUT} tasks qualify: by the rule's part (3), "
            + (
                f"{', '.join(failed)}: screened again at 100k steps before the selection is final."
                if failed
                else "every task that failed at 50k steps was screened again at 100k steps"
                + (
                    ", and new candidates in a third look; the selection above is final."
                    if any(entry.get("look", 0) == 2 for entry in data["tasks"].values())
                    else "; new candidates are screened next."
                )
            )
        )
    return "\n".join(lines) + "\n"


#: what the pages say where no ladder has a reading
NO_LADDER = "No label-response ladder has all its runs in yet.\n"


def written_selection(page: Path = SCREEN_PAGE) -> dict[str, Any]:
    """The screen's selection as its page's ``.json`` holds it (empty before the screen is read)."""
    path = page.with_suffix(".json")
    return json.loads(path.read_text())["selection"] if path.exists() else {}


def held_out_tasks(page: Path = SCREEN_PAGE) -> list[str]:
    """The tasks the screen's selection holds out, none before the selection is read."""
    return written_selection(page).get("held_out") or []


def no_ladder_text(page: Path = SCREEN_PAGE) -> str:
    """What the pages say where no ladder has a reading: the tasks the screen selected, once it has."""
    selection = written_selection(page)
    if not selection.get("studied"):
        return NO_LADDER
    held_out = f", with {' and '.join(selection['held_out'])} held out" if selection.get("held_out") else ""
    studied = selection["studied"]
    named = ", ".join(studied[:-1]) + f" and {studied[-1]}" if len(studied) > 1 else studied[0]
    return f"The screen selected {named}{held_out}. " + NO_LADDER
