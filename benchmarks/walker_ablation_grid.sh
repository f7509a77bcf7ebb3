#!/usr/bin/env bash
# Issue 9: the paper's own PRIDE recipe re-run after the critic-reset fix, and an ablation that separates the
# faithful generator from the faithful mixing. walker-walk, CPU tier, 400 queries, seeds 0-2; everything else is
# hyperparams/cpu/pride.yml, identical to PEBBLE's (compare with the walker grid's PEBBLE and "faithful" PRIDE).
#   paper:          SynthER's form, [s, a, s'] generated from pure noise with 32 Heun steps, u = 0.5 from the first
#                   feedback session, no window, no filter (the fidelity check still logs dynamics_error_ratio)
#   generator_only: the faithful generator ([s, a, s' - s] near real transitions, sigma 0.25, 8 steps) with the
#                   paper's mixing (u = 0.5 from the first feedback session, no window, no filter)
#   no_ramp, no_window, no_filter: "faithful" (benchmarks/faithful.sh) with one mixing option turned off each:
#                   u = 0.5 from the first feedback session / the diffusion fitted on the whole buffer / every
#                   generated sample kept (10k drawn instead of 20k)
#   faithful:       "faithful" itself; with RATIOS="0.25 0.75" it is the u sweep re-run after the fix
#   faithful_whiten: "faithful" with a whitened diffusion (diffusion_normalization=whiten), for Meta-World:
#                   TASK=button-press-v3 FEEDBACK=2000 TAGS=faithful_whiten benchmarks/walker_ablation_grid.sh
# The CPU sizes (256 x 3 blocks, 2000 warm-started steps) are the YAML's for both. Each run starts when a core is free
# (fewer than two benchmark workers running), so the queue can wait behind another grid. Resumable.
set -euo pipefail
cd "$(dirname "$0")/.."
OUT=${OUT:-benchmarks/results/runs}
TASK=${TASK:-walker-walk}
FEEDBACK=${FEEDBACK:-400}
source benchmarks/faithful.sh
PAPER_MIXING="synthetic_start=0 synthetic_ramp=0 diffusion_window=null synthetic_keep_quantile=1.0"
declare -A VARIANTS=(
  [paper]="model_state_change=false generation=unconditional diffusion_sample_steps=32 $PAPER_MIXING"
  [generator_only]="$PAPER_MIXING"
  [no_ramp]="$FAITHFUL synthetic_start=0 synthetic_ramp=0"
  [no_window]="$FAITHFUL diffusion_window=null"
  [no_filter]="$FAITHFUL synthetic_keep_quantile=1.0"
  [faithful]="$FAITHFUL"
  [faithful_whiten]="$FAITHFUL diffusion_normalization=whiten"
)
busy() { [ "$(pgrep -fc -- '--worker' || true)" -ge 2 ]; }
for ratio in ${RATIOS:-0.5}; do
  for tag in ${TAGS:-paper generator_only}; do
    for seed in ${SEEDS:-0 1 2}; do
      [ -f "$OUT/pride_${TASK}_s${seed}_fb${FEEDBACK}_u${ratio}_$tag/result.json" ] && continue
      # a core is free when fewer than two workers run twice, 20 s apart (a queue starts its next run within seconds)
      while busy || { sleep 20; busy; }; do sleep 30; done
      # shellcheck disable=SC2086
      python benchmarks/run.py --tier cpu --tasks "$TASK" --algos pride --feedback "$FEEDBACK" --ratios "$ratio" \
        --seeds "$seed" --tag "$tag" --set ${VARIANTS[$tag]} --out "$OUT" &
      sleep 60 # let the worker start before counting again
    done
  done
done
wait
