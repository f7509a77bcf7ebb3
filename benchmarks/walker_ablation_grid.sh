#!/usr/bin/env bash
# Issue 9: the paper's own PRIDE recipe re-run after the critic-reset fix, and an ablation that separates the
# faithful generator from the faithful mixing. walker-walk, CPU tier, 400 queries, seeds 0-2; everything else is
# hyperparams/cpu/pride.yml, identical to PEBBLE's (compare with the walker grid's PEBBLE and "faithful" PRIDE).
#   paper:          SynthER's form, [s, a, s'] generated from pure noise with 32 Heun steps, u = 0.5 from the first
#                   feedback session, no window, no filter (the fidelity check still logs dynamics_error_ratio)
#   generator_only: the faithful generator ([s, a, s' - s] near real transitions, sigma 0.25, 8 steps) with the
#                   paper's mixing (u = 0.5 from the first feedback session, no window, no filter)
# The CPU sizes (256 x 3 blocks, 2000 warm-started steps) are the YAML's for both. Each run starts when a core is free
# (fewer than two benchmark workers running), so the queue can wait behind another grid. Resumable.
set -euo pipefail
cd "$(dirname "$0")/.."
OUT=${OUT:-benchmarks/results/runs}
PAPER_MIXING="synthetic_start=0 synthetic_ramp=0 diffusion_window=null synthetic_keep_quantile=1.0"
declare -A VARIANTS=(
  [paper]="model_state_change=false generation=unconditional diffusion_sample_steps=32 $PAPER_MIXING"
  [generator_only]="$PAPER_MIXING"
)
busy() { [ "$(pgrep -fc -- '--worker' || true)" -ge 2 ]; }
for tag in ${TAGS:-paper generator_only}; do
  for seed in ${SEEDS:-0 1 2}; do
    [ -f "$OUT/pride_walker-walk_s${seed}_fb400_u0.5_$tag/result.json" ] && continue
    # a core is free when fewer than two workers run twice, 20 s apart (a queue starts its next run within seconds)
    while busy || { sleep 20; busy; }; do sleep 30; done
    # shellcheck disable=SC2086
    python benchmarks/run.py --tier cpu --tasks walker-walk --algos pride --feedback 400 --seeds "$seed" --tag "$tag" \
      --set ${VARIANTS[$tag]} --out "$OUT" &
    sleep 60 # let the worker start before counting again
  done
done
wait
