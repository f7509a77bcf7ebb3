"""
The results page, generated from the committed runs of the grid files (``benchmarks/grids/*.yml``).

    python benchmarks/results_page.py                 # recount from the run folders and write every file below
    python benchmarks/results_page.py --from-json     # re-render the pages from results.json (no recount)
    python benchmarks/results_page.py --grids benchmarks/grids/pending/x.yml --print   # a grid's tables so far, written nowhere

Every number shown anywhere comes from one data file, ``benchmarks/results/results.json``, written here from the run
folders with ``plot.py``'s statistics (the primary return: the mean of each run's last three evaluations, mean ± std
over seeds, with the final return and the area under the curve beside it; rliable's probability of improvement
with a 95% stratified-bootstrap interval, :data:`RESAMPLES` resamples, each pair drawn from NumPy seed
:data:`BOOTSTRAP_SEED`, see :func:`improvement`; beside it the one-sided Mann–Whitney p, and what P reads without the
better arm's best one and two seeds). Each row states the budget its runs *asked* (``result.json``'s
``feedback_asked``), and the budget it was set where that differs. It is rendered into:

- ``benchmarks/results/benchmark.md``: one table per task, a row per configuration, budget and synthetic ratio,
  each with the ``benchmarks/grid.py`` command that re-creates its runs;
- ``docs/_generated/results.md``: the same tables for the documentation site;
- the summary table of ``README.md``, between ``<!-- results:start -->`` and ``<!-- results:end -->`` (the rows of the
  grid files marked ``summary: true``); nothing outside the markers is touched.
- the label-response study (grid files marked ``ladder: true``, read by ``benchmarks/label_response.py``): labels to
  the target and the figure between ``<!-- labels:start -->`` and ``<!-- labels:end -->`` of the README (a row per
  task) and the results README (a row per task and arm), and every point of every ladder in
  ``docs/_generated/label_response.md``.

Each row is compared with PEBBLE at its task's largest budget set (400 queries on DMC, 2000 on Meta-World, where the
tier's 60k steps ask 1200 of them); a grid file's
``comparisons`` add pairs of its own. A row made by two grid files is an error: a row has one command.

Each row shows the code of ``sb3_pride/`` its runs ran on (the ``code`` column: the short git tree hash of the
package, see :func:`code_of`; "unrecorded" for a run that recorded no commit, "unknown commit" for one whose commit
this checkout does not have), and every comparison whose two arms did not all run on one and the same recorded code
is flagged (``code_differs`` in ``results.json``, a † beside its P on the pages). :func:`uncounted_runs` lists the run folders no row counts: each finished run is counted in a row or moved to
``benchmarks/results/archive/`` with a line saying why (a test holds the list empty).
"""

import argparse
import json
import os
import sys
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent))

import grid
import label_response
import run
from results_recount import COMMIT_NOT_HERE, GRIDS, ROOT, SHORT, code_of, collect, recount, relative, runs_of, uncounted_runs
from results_render import (
    CODE_MARK,
    CODE_NOTE,
    EARLIER_NOTE,
    budget_text,
    checks_section,
    claims_section,
    label_of,
    p_text,
    render_checks,
    render_claims,
    render_docs,
    render_page,
    render_summary,
    render_tables,
    share_text,
    without_best_text,
)
from results_statistics import BOOTSTRAP_SEED, RESAMPLES, bootstrap_improvement, improvement

#: the parts' names the benchmarks and tests reach through this module, the pages' entry point
__all__ = [
    "BOOTSTRAP_SEED",
    "CODE_MARK",
    "CODE_NOTE",
    "COMMIT_NOT_HERE",
    "EARLIER_NOTE",
    "GRIDS",
    "RESAMPLES",
    "ROOT",
    "SHORT",
    "bootstrap_improvement",
    "budget_text",
    "checks_section",
    "claims_section",
    "code_of",
    "collect",
    "improvement",
    "label_of",
    "p_text",
    "recount",
    "relative",
    "render_checks",
    "render_claims",
    "render_docs",
    "render_page",
    "render_summary",
    "render_tables",
    "run",
    "runs_of",
    "share_text",
    "uncounted_runs",
    "without_best_text",
]

RESULTS = ROOT / "benchmarks" / "results" / "results.json"
PAGE = ROOT / "benchmarks" / "results" / "benchmark.md"
DOCS_PAGE = ROOT / "docs" / "_generated" / "results.md"
README = ROOT / "README.md"
START, END = "<!-- results:start -->", "<!-- results:end -->"
#: the claims' table goes between these markers, in each of :data:`CLAIM_PAGES` that has them
CLAIMS_START, CLAIMS_END = "<!-- claims:start -->", "<!-- claims:end -->"
CLAIM_PAGES = [README, ROOT / "benchmarks" / "results" / "README.md"]
#: the checks' table goes between these markers, in each of :data:`CLAIM_PAGES` that has them
CHECKS_START, CHECKS_END = "<!-- checks:start -->", "<!-- checks:end -->"
#: the label-response study's labels-to-target table and figure (:data:`LABELS_FIGURE`) go between these markers, in
#: each of :data:`CLAIM_PAGES` that has them; every point of its ladders goes into :data:`LABELS_PAGE`
LABELS_START, LABELS_END = "<!-- labels:start -->", "<!-- labels:end -->"
LABELS_PAGE = ROOT / "docs" / "_generated" / "label_response.md"
LABELS_FIGURE = ROOT / "docs" / "_generated" / "label_response.png"


def replace_block(text: str, block: str, where: str, start: str = START, end: str = END) -> str:
    """``text`` with the part between the markers (the results table's) replaced by ``block``; an error if a marker is
    missing."""
    if text.count(start) != 1 or text.count(end) != 1 or text.index(start) > text.index(end):
        raise SystemExit(f"{where}: needs one {start} line and one {end} line after it, around the generated table")
    head, rest = text.split(start)
    _, tail = rest.split(end)
    return f"{head}{start}\n{block}{end}{tail}"


def labels_block(ladders: dict[str, Any], folder: Path, short: bool = False) -> str:
    """The labels-to-target table (``short``: a row per task, as the README shows it) and, once a ladder is in, the
    figure, linked from a page in ``folder``."""
    if not ladders["tasks"]:
        return label_response.no_ladder_text()
    figure = os.path.relpath(LABELS_FIGURE, folder)
    table = label_response.render_labels_summary(ladders) if short else label_response.render_labels_table(ladders)
    return table + f"\n![Share of SAC's return against labels]({figure})\n"


def write_all(data: dict[str, Any], readme: Path = README, claim_pages: list[Path] | None = None) -> None:
    """The page, the documentation's page, the README's summary, and the claims' and the checks' tables in each of
    ``claim_pages`` (default :data:`CLAIM_PAGES`) that has their markers."""
    PAGE.write_text(render_page(data))
    DOCS_PAGE.parent.mkdir(parents=True, exist_ok=True)
    DOCS_PAGE.write_text(render_docs(data))
    readme.write_text(replace_block(readme.read_text(), render_summary(data), relative(readme)))
    ladders = data.get("label_response") or {"tasks": {}}
    if ladders["tasks"]:
        label_response.draw_ladders(ladders, LABELS_FIGURE)
    LABELS_PAGE.write_text(labels_block(ladders, LABELS_PAGE.parent) + "\n" + label_response.render_ladders(ladders))
    blocks = [
        (CLAIMS_START, CLAIMS_END, render_claims(data) or "No grid file states a claim.\n"),
        (CHECKS_START, CHECKS_END, render_checks(data) or "No grid file states a check.\n"),
    ]
    for path in CLAIM_PAGES if claim_pages is None else claim_pages:
        labels = labels_block(ladders, path.parent, short=path == readme)
        for start, end, table in [*blocks, (LABELS_START, LABELS_END, labels)]:
            text = path.read_text()
            if start in text or end in text:
                path.write_text(replace_block(text, table, relative(path), start, end))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument(
        "--grids",
        type=Path,
        nargs="+",
        default=None,
        help="grid files to print (with --print; the pages are written from benchmarks/grids/*.yml)",
    )
    parser.add_argument("--from-json", action="store_true", help="re-render the pages from results.json, no recount")
    parser.add_argument(
        "--print",
        action="store_true",
        help="print the tables and claims, write no file (a grid's runs so far, e.g. one waiting in pending/)",
    )
    args = parser.parse_args()
    if args.grids and not args.print:
        # The pages and results.json hold every grid; written from a subset they would lose the others' rows.
        parser.error(
            "--grids needs --print: the pages are written from every grid file, never from a subset "
            "(leave --grids out to write them)"
        )
    if args.from_json:
        data = json.loads(RESULTS.read_text())
    else:
        files = args.grids or sorted(GRIDS.glob("*.yml"))
        summary_first = sorted(files, key=lambda path: not grid.load_grid(path).get("summary"))
        data = recount(summary_first)
        if args.print:
            print(render_tables(data) + claims_section(data, level=2) + checks_section(data, level=2))
            return
        data["label_response"] = label_response.read_ladders(label_response.ladder_grids(files))
        RESULTS.write_text(json.dumps(data, indent=1) + "\n")
    write_all(data)
    for folder in uncounted_runs(sorted(GRIDS.glob("*.yml"))):
        print(f"counted in no row: {relative(folder)} (add it to a grid file, or move it to the archive)", file=sys.stderr)
    print(f"wrote {relative(RESULTS)}, {relative(PAGE)}, {relative(DOCS_PAGE)} and the summary of {relative(README)}")


if __name__ == "__main__":
    main()
