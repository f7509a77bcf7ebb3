"""
Wall time of PEBBLE (and later PRIDE) against plain SB3 SAC on the true reward, identical networks, one process.

    python benchmarks/speed.py --env sb3_pride/walker-walk-v0 --timesteps 15000 --repeats 2

The algorithms run in turns (SAC, PEBBLE, SAC, PEBBLE, ...) so that machine noise hits them alike; the report
gives each one's median time and its ratio to SAC's, plus where PEBBLE's extra time goes.
"""

import argparse
import json
import os
import time
from collections import defaultdict

os.environ.setdefault("MUJOCO_GL", "disable")

import numpy as np  # noqa: E402
import torch as th  # noqa: E402
from stable_baselines3 import SAC  # noqa: E402

import sb3_pride  # noqa: E402
from sb3_pride.common.callbacks import FeedbackCallback  # noqa: E402

#: the CPU tier: 256 × 2 networks, batch 256, one update per step
SAC_KWARGS = dict(batch_size=256, learning_starts=1000, policy_kwargs=dict(net_arch=[256, 256]))
PEBBLE_KWARGS = dict(unsupervised_steps=2000, feedback_interval=5000, queries_per_session=50, max_feedback=200)


class TimedFeedback(FeedbackCallback):
    """The feedback callback, timed (sessions include reward learning, relabeling and the critic reset)."""

    seconds = 0.0

    def _on_step(self) -> bool:
        start = time.perf_counter()
        result = super()._on_step()
        TimedFeedback.seconds += time.perf_counter() - start
        return result


def run(algo: str, env_id: str, timesteps: int, seed: int) -> dict:
    th.set_num_threads(1)
    if algo == "sac":
        model = SAC("MlpPolicy", env_id, seed=seed, **SAC_KWARGS)
    else:
        model = sb3_pride.PEBBLE("MlpPolicy", env_id, seed=seed, **SAC_KWARGS, **PEBBLE_KWARGS)
        model._preference_callbacks = lambda: [  # type: ignore[method-assign]
            sb3_pride.common.callbacks.UnsupervisedPretrainingCallback(),
            TimedFeedback(),
        ]
    TimedFeedback.seconds = 0.0
    start = time.perf_counter()
    model.learn(timesteps)
    return {"seconds": time.perf_counter() - start, "feedback_seconds": TimedFeedback.seconds}


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--env", default="sb3_pride/walker-walk-v0")
    parser.add_argument("--timesteps", type=int, default=15_000)
    parser.add_argument("--repeats", type=int, default=2)
    parser.add_argument("--algos", nargs="+", default=["sac", "pebble"])
    parser.add_argument("--out", default=None, help="write the results as JSON here")
    args = parser.parse_args()

    results: dict[str, list[dict]] = defaultdict(list)
    for repeat in range(args.repeats):
        for algo in args.algos:
            results[algo].append(run(algo, args.env, args.timesteps, seed=repeat))
            print(f"repeat {repeat} {algo}: {results[algo][-1]['seconds']:.1f} s", flush=True)
    sac = float(np.median([r["seconds"] for r in results["sac"]]))
    report = {"env": args.env, "timesteps": args.timesteps, "repeats": args.repeats, "sac_kwargs": SAC_KWARGS,
              "pebble_kwargs": PEBBLE_KWARGS, "algos": {}}  # fmt: skip
    for algo, runs in results.items():
        seconds = float(np.median([r["seconds"] for r in runs]))
        feedback = float(np.median([r["feedback_seconds"] for r in runs]))
        report["algos"][algo] = {"median_seconds": seconds, "ratio_to_sac": seconds / sac, "feedback_seconds": feedback}
        print(f"{algo:8s} {seconds:7.1f} s  ×{seconds / sac:.3f} of SAC  (feedback sessions {feedback:.1f} s)")
    if args.out:
        with open(args.out, "w") as file:
            json.dump(report, file, indent=2)


if __name__ == "__main__":
    main()
