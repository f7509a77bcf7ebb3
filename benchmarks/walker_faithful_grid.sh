#!/usr/bin/env bash
# Issue 9's walker-walk ablation at the CPU tier, after the critic-reset fix: PEBBLE at 400 queries against PRIDE
# with faithful synthetic data ("faithful": [s, a, s' − s] modelled, samples generated near real transitions
# (SDEdit, σ = 0.25), 256 × 3 blocks / 2000 warm-started steps / 8 sampler steps, half of the drawn samples
# dropped by the dynamics filter, fitted on the 20k most recent transitions, mixing from step 10k with u ramped to
# 0.5 over 5k steps). Two queues, one run per core. Resumable: finished runs are skipped.
set -euo pipefail
cd "$(dirname "$0")/.."
OUT=${OUT:-benchmarks/results/runs}
SEEDS=${SEEDS:-0 1 2 3 4}
. benchmarks/faithful.sh  # FAITHFUL: the --set pairs of the "faithful" variant
python benchmarks/run.py --tier cpu --tasks walker-walk --algos pebble --feedback 400 --seeds $SEEDS --out "$OUT" &
# shellcheck disable=SC2086
python benchmarks/run.py --tier cpu --tasks walker-walk --algos pride --feedback 400 --seeds $SEEDS --out "$OUT" \
  --tag faithful --set $FAITHFUL &
wait
