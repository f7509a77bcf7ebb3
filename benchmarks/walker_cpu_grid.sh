#!/usr/bin/env bash
# The CPU-tier walker-walk grid of benchmarks/results/README.md, one seed at a time across all cells:
# PRIDE vs PEBBLE at equal feedback (400), PRIDE at half feedback (200), and the u sweep {0.3, 0.5, 1.0}.
# Resumable: re-running skips finished runs. JOBS=2 runs two at a time.
set -euo pipefail
cd "$(dirname "$0")/.."
JOBS=${JOBS:-1}
OUT=${OUT:-benchmarks/results/runs}
for seed in ${SEEDS:-0 1 2 3 4}; do
  python benchmarks/run.py --tier cpu --tasks walker-walk --algos pride pebble --feedback 400 --seeds "$seed" --jobs "$JOBS" --out "$OUT"
  python benchmarks/run.py --tier cpu --tasks walker-walk --algos pride --feedback 200 --seeds "$seed" --jobs "$JOBS" --out "$OUT"
  python benchmarks/run.py --tier cpu --tasks walker-walk --algos pride --feedback 400 --ratios 0.3 --seeds "$seed" --jobs "$JOBS" --out "$OUT"
  # u = 1.0 (every row synthetic) exists only with the synthetic rows in place of real ones
  python benchmarks/run.py --tier cpu --tasks walker-walk --algos pride --feedback 400 --ratios 1.0 --seeds "$seed" --jobs "$JOBS" \
    --out "$OUT" --tag in_place --set synthetic_on_top=false
done
