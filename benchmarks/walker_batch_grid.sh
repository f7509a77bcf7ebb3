#!/usr/bin/env bash
# Issue 9, session 15: synthetic data on top of a full real minibatch. At UTD 1 and batch B, u = 0.5 puts B/2
# synthetic rows in place of B/2 real ones (the issue: "synthetic data can only displace real data"). With
# batch_size=2B and u = 0.5, PRIDE's updates see B real rows, as PEBBLE's at batch B do, plus B synthetic ones.
# PEBBLE at batch 2B is the control that tells synthetic rows from a larger batch alone (every setting that is not
# about synthetic data identical). walker-walk, 400 queries, the CPU YAML otherwise (PRIDE: u = 0.5, 4000 diffusion
# steps). Two queues, one run per core, PRIDE and PEBBLE of the same seed side by side. Resumable.
# Since session 16 the CPU YAML does this itself at batch_size=256 (synthetic_on_top: true, exactly the same
# training); synthetic_on_top=false keeps this grid what it was.
set -euo pipefail
cd "$(dirname "$0")/.."
OUT=${OUT:-benchmarks/results/runs}
RUN="python benchmarks/run.py --tier cpu --tasks walker-walk --feedback 400 --out $OUT"
for seed in ${SEEDS:-0 1 2}; do
  $RUN --algos pride --seeds "$seed" --tag batch512 --set batch_size=512 synthetic_on_top=false &
  $RUN --algos pebble --seeds "$seed" --tag batch512 --set batch_size=512 &
  wait
done
