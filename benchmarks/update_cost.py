"""
What one SAC update costs at a given minibatch size, with the CPU tier's networks, on one torch thread: the price of
``PRIDE(synthetic_on_top=True)``, whose minibatch holds B real rows plus B·u/(1 − u) synthetic ones (512 rows at
B = 256, u = 0.5) where PEBBLE's holds B.

    python benchmarks/update_cost.py --batch-sizes 256 384 512 --updates 300 --rounds 2

The sizes are timed in turns (256, 384, 512, 256, ...) so that machine noise hits them alike; the report gives each
size's median milliseconds per update and its ratio to the first size.
"""

import argparse
import json
import os
import time

os.environ.setdefault("MUJOCO_GL", "disable")

import numpy as np
import torch as th
from stable_baselines3 import SAC

import sb3_pride  # noqa: F401  (registers the sb3_pride/ env ids)
from sb3_pride.zoo import hyperparams_dir, model_kwargs


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--env", default="sb3_pride/walker-walk-v0")
    parser.add_argument("--batch-sizes", type=int, nargs="+", default=[256, 384, 512])
    parser.add_argument("--updates", type=int, default=300, help="updates timed per size and round")
    parser.add_argument("--rounds", type=int, default=2)
    parser.add_argument("--out", default=None, help="write the results as JSON here")
    args = parser.parse_args()
    th.set_num_threads(1)
    _, kwargs = model_kwargs(hyperparams_dir() / "cpu" / "sac.yml", args.env)  # PEBBLE's SAC settings at this tier
    model = SAC("MlpPolicy", args.env, seed=0, **{**kwargs, "learning_starts": 0})
    model.learn(max(args.batch_sizes) * 4)  # a buffer to draw from (and SB3's logger set up)
    times: dict[int, list[float]] = {size: [] for size in args.batch_sizes}
    for _ in range(args.rounds):
        for size in args.batch_sizes:
            start = time.perf_counter()
            model.train(args.updates, size)
            times[size].append(1000 * (time.perf_counter() - start) / args.updates)
    medians = {size: float(np.median(ms)) for size, ms in times.items()}
    base = args.batch_sizes[0]
    for size, ms in medians.items():
        print(f"batch {size:5d}: {ms:6.2f} ms per update  x{ms / medians[base]:.2f} of batch {base}  (rounds: {times[size]})")
    if args.out:
        with open(args.out, "w") as file:
            json.dump({"env": args.env, "updates": args.updates, "ms_per_update": times, "medians": medians}, file, indent=2)


if __name__ == "__main__":
    main()
