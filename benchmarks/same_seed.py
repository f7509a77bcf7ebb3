"""
Whether a re-run repeats a run: the runs of the same name in two run folders, evaluation by evaluation.

    python benchmarks/same_seed.py benchmarks/results/runs benchmarks/results/runs_half_the_labels_by_default \
        --pattern "pebble_*_fb400"

A run is seeded end to end, so two runs of the same settings on the same code and the same CPU model give the same
true return at every evaluation; on another CPU model the floating-point sums differ and the runs part. For every
name in both folders (``--pattern``: a glob on the run folder's name) it prints whether the two curves are the same,
the CPU each recorded (``settings.json`` ``system``; "unrecorded" for runs made before it was kept), the code of
``sb3_pride/`` each ran on (as the results page names it) and both primary returns (the mean of the last
``plot.LAST_EVALUATIONS`` evaluations), then, per task, the mean primary return of each folder's runs over the seeds
that repeated and over those that parted.
"""

import argparse
import json
import sys
from collections import defaultdict
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

import plot
from results_page import code_of


def describe(folder: Path) -> dict:
    """A finished run's CPU, code tree, curve of true returns and primary return."""
    settings = json.loads((folder / "settings.json").read_text())
    curve = plot.load_run(folder, progress=False)["curve"]
    return {
        "task": settings["task"],
        "cpu": (settings.get("system") or {}).get("CPU", "unrecorded"),
        "code": code_of(settings) or "unrecorded",
        "returns": np.asarray(curve["true_return"]),
        "primary": float(plot.primary_returns([{"curve": curve}])[0]),
    }


def compare(first: Path, second: Path, pattern: str) -> list[dict]:
    """One row per run name finished in both folders: whether the curves are the same, and each run's description."""
    rows = []
    for result in sorted(first.glob(f"{pattern}/result.json")):
        name = result.parent.name
        if not (second / name / "result.json").exists():
            continue
        a, b = describe(first / name), describe(second / name)
        same = a["returns"].shape == b["returns"].shape and bool(np.array_equal(a["returns"], b["returns"]))
        rows.append({"name": name, "task": a["task"], "same": same, "first": a, "second": b})
    return rows


def render(rows: list[dict], first: Path, second: Path) -> str:
    """The rows of :func:`compare` as two Markdown tables: run by run, then per task and outcome."""
    lines = [
        f"first: `{first}`, second: `{second}`",
        "",
        "| run | curves | CPU (first / second) | code (first / second) | primary return (first / second) |",
        "|---|---|---|---|---|",
    ]
    for row in rows:
        a, b = row["first"], row["second"]
        lines.append(
            f"| {row['name']} | {'the same' if row['same'] else 'parted'} | {a['cpu']} / {b['cpu']} | "
            f"{a['code']} / {b['code']} | {a['primary']:.1f} / {b['primary']:.1f} |"
        )
    groups: dict[tuple[str, bool], list[dict]] = defaultdict(list)
    for row in rows:
        groups[(row["task"], row["same"])].append(row)
    lines += ["", "| task | curves | runs | mean primary return (first / second) |", "|---|---|---|---|"]
    for (task, same), members in sorted(groups.items()):
        first_mean = np.mean([m["first"]["primary"] for m in members])
        second_mean = np.mean([m["second"]["primary"] for m in members])
        lines.append(
            f"| {task} | {'the same' if same else 'parted'} | {len(members)} | {first_mean:.1f} / {second_mean:.1f} |"
        )
    return "\n".join(lines) + "\n"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("first", type=Path, help="a run folder")
    parser.add_argument("second", type=Path, help="another run folder, with runs of the same names")
    parser.add_argument("--pattern", default="*", help="a glob on the run folders' names (default: every run)")
    parser.add_argument("--out", type=Path, help="also write the tables to this Markdown file")
    args = parser.parse_args()
    for folder in (args.first, args.second):
        if not folder.is_dir():
            parser.error(f"{folder}: expected a folder of runs")
    rows = compare(args.first, args.second, args.pattern)
    if not rows:
        parser.error(f"no finished run named {args.pattern!r} is in both {args.first} and {args.second}")
    text = render(rows, args.first, args.second)
    print(text, end="")
    if args.out:
        args.out.write_text(text)


if __name__ == "__main__":
    main()
