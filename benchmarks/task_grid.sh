#!/usr/bin/env bash
# Issue 9: the best PRIDE (faithful generator + delayed, ramped, filtered mixing, UTD 1; the walker grid's
# configuration) against PEBBLE on another task at the CPU tier, seeds 0-2. Two queues, one run per core,
# interleaved so that a cut-off grid still has matching seeds. Resumable: finished runs are skipped.
#   TASK=cheetah-run FEEDBACK=400 benchmarks/task_grid.sh         (the default)
#   TASK=button-press-v3 FEEDBACK=2000 benchmarks/task_grid.sh    (Meta-World: the tier's feedback budget)
# WAIT_FOR=<pid> delays the second queue until that process ends (a core still busy with another run).
set -euo pipefail
cd "$(dirname "$0")/.."
OUT=${OUT:-benchmarks/results/runs}
TASK=${TASK:-cheetah-run}
FEEDBACK=${FEEDBACK:-400}
RATIO=${RATIO:-0.5}  # PRIDE's u (the grids of sessions 6-8 ran 0.5; the CPU YAML now has 0.25 on cheetah and Meta-World)
. benchmarks/faithful.sh  # FAITHFUL: the --set pairs of the "faithful" variant
RUN="python benchmarks/run.py --tier cpu --tasks $TASK --feedback $FEEDBACK --ratios $RATIO --out $OUT"
# shellcheck disable=SC2086
(
  $RUN --algos pebble --seeds 0
  $RUN --algos pride --seeds 1 --tag faithful --set $FAITHFUL
  $RUN --algos pebble --seeds 2
) &
# shellcheck disable=SC2086
(
  while [ -n "${WAIT_FOR:-}" ] && kill -0 "$WAIT_FOR" 2> /dev/null; do sleep 20; done
  $RUN --algos pride --seeds 0 --tag faithful --set $FAITHFUL
  $RUN --algos pebble --seeds 1
  $RUN --algos pride --seeds 2 --tag faithful --set $FAITHFUL
) &
wait
