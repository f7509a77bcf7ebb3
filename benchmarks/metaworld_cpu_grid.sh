#!/usr/bin/env bash
# The CPU-tier Meta-World grid of benchmarks/results/README.md: PRIDE vs PEBBLE on button-press at the tier's
# feedback budget (2000), success rate. Resumable: re-running skips finished runs.
set -euo pipefail
cd "$(dirname "$0")/.."
JOBS=${JOBS:-1}
OUT=${OUT:-benchmarks/results/runs}
for seed in ${SEEDS:-0 1 2 3 4}; do
  python benchmarks/run.py --tier cpu --tasks button-press-v3 --algos pride pebble --feedback 2000 --ratios 0.5 --seeds "$seed" --jobs "$JOBS" --out "$OUT"
done
