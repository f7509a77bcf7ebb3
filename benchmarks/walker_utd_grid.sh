#!/usr/bin/env bash
# Issue 9, session 4: completes the 200-query cell (PRIDE faithful seeds 2-4, PEBBLE seeds 0-4) and screens UTD 2
# (gradient_steps=2) for both algorithms at 400 queries, with everything else identical (fair UTD comparison).
# Two queues, one run per core, interleaved so that a cut-off grid still has matching seeds in each cell.
# Resumable: finished runs are skipped.
set -euo pipefail
cd "$(dirname "$0")/.."
OUT=${OUT:-benchmarks/results/runs}
. benchmarks/faithful.sh  # FAITHFUL: the --set pairs of the "faithful" variant
RUN="python benchmarks/run.py --tier cpu --tasks walker-walk --out $OUT"
# shellcheck disable=SC2086
(
  for seed in 2 0 3 1 4 2; do
    $RUN --algos pride --feedback 200 --seeds "$seed" --tag faithful --set $FAITHFUL
    $RUN --algos pride --feedback 400 --seeds "$seed" --tag faithful_utd2 --set $FAITHFUL gradient_steps=2
  done
) &
# shellcheck disable=SC2086
(
  for seed in 0 1 2 3 4; do
    $RUN --algos pebble --feedback 400 --seeds "$seed" --tag utd2 --set gradient_steps=2
    $RUN --algos pebble --feedback 200 --seeds "$seed"
  done
) &
wait
