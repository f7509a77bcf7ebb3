"""
Does the in-run yardstick leak? ``DynamicsEnsemble.fit`` draws a new random held-out 20% at every refit, and PRIDE
warm-starts the ensemble across retrains, so rows held out now were mostly trained on at earlier refits. If it
memorized them, its held-out error (the denominator of ``diffusion/dynamics_error_ratio``) reads too low and every
ratio too high.

Two ensembles with PRIDE's in-run settings (3 members, 200 units, 500 Adam steps per refit, same seed) are refit like
the CPU YAML does: on a window of the last 20k real transitions, every 5k steps from 10k to 50k. ``redrawn`` is the
code as it is; ``stable`` always holds out the same rows (global index % 5 == 0), so it never trains on them. For
each: the error on its own held-out rows, and on the next 5k transitions, which neither has seen. Data: walker-walk
under smooth random actions (``generator.collect``).

    python benchmarks/holdout_split.py --seeds 0 1 --out benchmarks/results/holdout_split_walker-walk.json
"""

import argparse
import json
from pathlib import Path

import numpy as np
import torch as th

from generator import collect  # benchmarks/generator.py, beside this script
from sb3_pride.pride.fidelity import DynamicsEnsemble, split_transitions


class StableHoldout:
    """Stands in for the ensemble's random generator: ``permutation`` lists the rows whose global index (``offset`` +
    position in the window) is a multiple of 5 first, so ``fit`` holds out the same transitions at every refit."""

    def __init__(self, rng: np.random.Generator):
        self.rng, self.offset = rng, 0

    def permutation(self, n: int) -> np.ndarray:
        held = (np.arange(n) + self.offset) % 5 == 0
        return np.concatenate([np.flatnonzero(held), self.rng.permutation(np.flatnonzero(~held))])

    def integers(self, *args, **kwargs):
        return self.rng.integers(*args, **kwargs)


def measure(seed: int, window: int, interval: int, first: int, last: int) -> list[dict]:
    rows, action_dim = collect("walker-walk", last + interval, seed)
    obs_dim = (rows.shape[1] - action_dim) // 2
    redrawn = DynamicsEnsemble(obs_dim, action_dim, train_steps=500, seed=seed, device="cpu")
    stable = DynamicsEnsemble(obs_dim, action_dim, train_steps=500, seed=seed, device="cpu")
    stable.rng = StableHoldout(stable.rng)  # type: ignore[assignment]
    results = []
    for step in range(first, last + 1, interval):
        start = max(0, step - window)
        real, unseen = rows[start:step], rows[step : step + interval]
        stable.rng.offset = start  # type: ignore[attr-defined]
        row: dict = {"seed": seed, "step": step}
        for name, model in (("redrawn", redrawn), ("stable", stable)):
            model.fit(*split_transitions(real, obs_dim, action_dim))
            row[f"{name}_heldout"] = float(model.errors(*split_transitions(real[model.holdout], obs_dim, action_dim)).mean())
            row[f"{name}_unseen"] = float(model.errors(*split_transitions(unseen, obs_dim, action_dim)).mean())
        print(" | ".join(f"{v:.3f}" if isinstance(v, float) else str(v) for v in row.values()), flush=True)
        results.append(row)
    return results


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--seeds", nargs="+", type=int, default=[0])
    parser.add_argument("--window", type=int, default=20_000, help="real transitions per refit (diffusion_window)")
    parser.add_argument("--interval", type=int, default=5000, help="steps between refits (diffusion_interval)")
    parser.add_argument("--first", type=int, default=10_000, help="step of the first refit (synthetic_start)")
    parser.add_argument("--last", type=int, default=50_000, help="step of the last refit")
    parser.add_argument("--out", type=Path, default=Path("benchmarks/results/holdout_split_walker-walk.json"))
    args = parser.parse_args()
    th.set_num_threads(1)
    print("seed | step | redrawn: held-out | redrawn: unseen | stable: held-out | stable: unseen")
    rows = [row for seed in args.seeds for row in measure(seed, args.window, args.interval, args.first, args.last)]
    gap = [r["stable_heldout"] / r["redrawn_heldout"] - 1 for r in rows]
    print(f"stable / redrawn held-out error - 1: mean {np.mean(gap):+.3f}, range [{min(gap):+.3f}, {max(gap):+.3f}]")
    args.out.write_text(json.dumps({"settings": vars(args) | {"out": str(args.out)}, "rows": rows}, indent=1))


if __name__ == "__main__":
    main()
