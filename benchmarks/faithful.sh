# The "faithful" PRIDE settings of benchmarks/results/README.md (walker grid), as run.py --set pairs; sourced by the
# grid scripts so that every grid runs the same variant under the tag "faithful". synthetic_on_top=false: these
# runs put the synthetic rows in place of real ones (the CPU YAML adds them on top since session 16).
# shellcheck disable=SC2034
FAITHFUL="model_state_change=true generation=near_real anchor_noise=0.25 diffusion_blocks=3 diffusion_train_steps=2000
  diffusion_sample_steps=8 synthetic_keep_quantile=0.5 diffusion_window=20000 synthetic_start=10000 synthetic_ramp=5000
  synthetic_on_top=false"
