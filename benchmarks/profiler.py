"""
Where the time goes: wall seconds per 1k env steps split into env stepping, SAC updates, the state-entropy reward,
reward learning, REED's consistency passes (where on), relabeling, diffusion training and generation, for SAC,
PEBBLE and PRIDE; each algorithm in its own process so that its peak memory (max RSS) is its own.

    python benchmarks/profiler.py --env sb3_pride/walker-walk-v0 --timesteps 12000 --out benchmarks/results/profile.json

Settings are the CPU tier's (``hyperparams/cpu/``) with pre-training shortened to 2k steps so that feedback and
diffusion happen inside a short run. Buckets nest as they run: "SAC update" excludes the state-entropy reward
computed while sampling its minibatches; "other" is the rest (callbacks, logging, storing transitions, r̂ of new
transitions).
"""

import argparse
import json
import os
import resource
import subprocess
import sys
import time
from collections import defaultdict
from typing import Any
from collections.abc import Callable

os.environ.setdefault("MUJOCO_GL", "disable")

BUCKETS = (
    "env",
    "sac_update",
    "state_entropy",
    "reward_learning",
    "consistency",
    "relabel",
    "diffusion_training",
    "generation",
)
OVERRIDES = dict(unsupervised_steps=2000, max_feedback=200)


class Timer:
    """Accumulates the wall time of wrapped calls into buckets; time inside a nested bucket is not counted twice."""

    def __init__(self) -> None:
        self.seconds: dict[str, float] = defaultdict(float)
        self._stack: list[list[float]] = []

    def wrap(self, function: Callable, bucket: str) -> Callable:
        def timed(*args, **kwargs):
            self._stack.append([time.perf_counter(), 0.0])
            try:
                return function(*args, **kwargs)
            finally:
                start, nested = self._stack.pop()
                elapsed = time.perf_counter() - start
                self.seconds[bucket] += elapsed - nested
                if self._stack:
                    self._stack[-1][1] += elapsed

        return timed


class TimedCallable:
    """A callable object (the state-entropy reward) whose calls are timed."""

    def __init__(self, target: Any, timer: Timer, bucket: str):
        self.target = target
        self.call = timer.wrap(target.__call__, bucket)

    def __call__(self, *args, **kwargs):
        return self.call(*args, **kwargs)


def instrument(model: Any, timer: Timer) -> None:
    """Wrap the model's costly parts so that ``timer`` sees them."""
    model.env.step = timer.wrap(model.env.step, "env")
    model.train = timer.wrap(model.train, "sac_update")
    if not hasattr(model, "reward_model"):
        return
    model.replay_rewards.state_entropy = TimedCallable(model.replay_rewards.state_entropy, timer, "state_entropy")
    model.reward_model.train_epochs = timer.wrap(model.reward_model.train_epochs, "reward_learning")
    consistency = model.reward_learner.consistency
    if consistency is not None:  # REED's passes, before each reward update
        consistency.train_epochs = timer.wrap(consistency.train_epochs, "consistency")
    model.relabel = timer.wrap(model.relabel, "relabel")
    if hasattr(model, "generator"):  # PRIDE: the generator's two costly steps (sampling includes the filter's draws)
        model.generator.fit = timer.wrap(model.generator.fit, "diffusion_training")
        model.generator.generate = timer.wrap(model.generator.generate, "generation")


def profile_one(algo: str, env_id: str, timesteps: int, seed: int) -> dict:
    import torch as th
    from stable_baselines3 import SAC

    import sb3_pride
    from sb3_pride.zoo import hyperparams_dir, model_kwargs

    th.set_num_threads(1)
    _, kwargs = model_kwargs(hyperparams_dir() / "cpu" / f"{algo}.yml", env_id)
    if algo != "sac":
        kwargs.update(OVERRIDES)
    cls = {"sac": SAC, "pebble": sb3_pride.PEBBLE, "pride": sb3_pride.PRIDE}[algo]
    model = cls("MlpPolicy", env_id, seed=seed, **kwargs)
    timer = Timer()
    instrument(model, timer)
    start = time.perf_counter()
    model.learn(timesteps)
    total = time.perf_counter() - start
    per_1k = {bucket: timer.seconds[bucket] * 1000 / timesteps for bucket in BUCKETS}
    per_1k["other"] = total * 1000 / timesteps - sum(per_1k.values())
    return {
        "algo": algo,
        "total_seconds": total,
        "seconds_per_1k_steps": per_1k,
        "total_per_1k_steps": total * 1000 / timesteps,
        "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--env", default="sb3_pride/walker-walk-v0")
    parser.add_argument("--timesteps", type=int, default=12_000)
    parser.add_argument("--algos", nargs="+", default=["sac", "pebble", "pride"])
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", default=None)
    parser.add_argument("--one", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.one:
        print(json.dumps(profile_one(args.one, args.env, args.timesteps, args.seed)))
        return
    results = []
    for algo in args.algos:
        command = [
            sys.executable,
            __file__,
            "--one",
            algo,
            "--env",
            args.env,
            "--timesteps",
            str(args.timesteps),
            "--seed",
            str(args.seed),
        ]
        output = subprocess.run(command, capture_output=True, text=True, check=True).stdout
        results.append(json.loads(output.strip().splitlines()[-1]))
    header = f"{'seconds per 1k steps':22s}" + "".join(f"{r['algo']:>10s}" for r in results)
    print(header)
    for bucket in (*BUCKETS, "other"):
        print(f"{bucket:22s}" + "".join(f"{r['seconds_per_1k_steps'][bucket]:10.2f}" for r in results))
    print(f"{'total':22s}" + "".join(f"{r['total_per_1k_steps']:10.2f}" for r in results))
    print(f"{'peak memory (MB)':22s}" + "".join(f"{r['peak_rss_mb']:10.0f}" for r in results))
    if args.out:
        with open(args.out, "w") as file:
            json.dump(
                {"env": args.env, "timesteps": args.timesteps, "overrides": OVERRIDES, "results": results}, file, indent=2
            )


if __name__ == "__main__":
    main()
