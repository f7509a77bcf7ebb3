"""
Wall time of PEBBLE and PRIDE against plain SB3 SAC on the true reward, identical networks, one process.

    python benchmarks/speed.py --env sb3_pride/walker-walk-v0 --repeats 2
    python benchmarks/speed.py --algos pebble pride --variant rows_on_top --timesteps 25000
    python benchmarks/speed.py --algos pebble pride --variant wide generator_kwargs.width=512 --timesteps 25000
    python benchmarks/speed.py --tier label-response --env Pendulum-v1 --as-tier --algos pebble pride --repeats 3
    python benchmarks/speed.py --algos pebble --variant blocking_paced seconds_per_answer=0.5 \
        --variant asynchronous_paced seconds_per_answer=0.5 --timesteps 12000 --repeats 2

PRIDE's settings are those of ``hyperparams/cpu/pride.yml`` (its CPU defaults), with a shorter pre-training and
feedback budget for the shorter run; ``--as-tier`` runs the tier's own run instead (50k steps on walker-walk, the
YAML unchanged), and ``--algos pebble`` and ``--algos pride`` (or ``--algos --variant LABEL``, a variant alone) can
then run side by side, one per core. The algorithms run in turns (SAC, PEBBLE, PRIDE, SAC, ...) so that machine
noise hits them alike; the report gives each one's median time, its ratio to SAC's and to PEBBLE's, and where the
extra time goes: feedback sessions (reward learning, relabeling, critic reset), diffusion training, generation
(samples per second).
"""

import argparse
import json
import os
import time
from collections import defaultdict
from typing import Any

os.environ.setdefault("MUJOCO_GL", "disable")

import numpy as np
import torch as th
from provenance import provenance, utc_now
from paced_teacher import PacedTeacher
from run import load_variants, merge, parse_overrides
from stable_baselines3 import SAC

import sb3_pride
from sb3_pride.common.teachers import InteractiveTeacher, make_teacher
from sb3_pride.pebble.callbacks import FeedbackCallback
from sb3_pride.pride.callbacks import GeneratorCallback
from sb3_pride.zoo import hyperparams_dir, model_kwargs

#: the CPU tier (hyperparams/cpu/): 256 × 2 networks, batch 256, one update per step; this benchmark's run is
#: shorter than the tier's, so pre-training is shorter and the budget smaller
OVERRIDES = dict(unsupervised_steps=2000, max_feedback=200)


def tier_kwargs(algo: str, env_id: str, as_tier: bool = False, tier: str = "cpu") -> dict:
    _, kwargs = model_kwargs(hyperparams_dir() / tier / f"{algo}.yml", env_id)
    return {**kwargs, **(OVERRIDES if algo != "sac" and not as_tier else {})}


def tier_timesteps(env_id: str, tier: str = "cpu") -> int:
    """The tier's run length for this env (its YAML entry's n_timesteps)."""
    n_timesteps, _ = model_kwargs(hyperparams_dir() / tier / "pebble.yml", env_id)
    return n_timesteps


class TimedFeedback(FeedbackCallback):
    """The feedback callback, timed (sessions include reward learning, relabeling and the critic reset)."""

    def _on_step(self) -> bool:
        start = time.perf_counter()
        result = super()._on_step()
        TIMES["feedback_seconds"] += time.perf_counter() - start
        return result


class TimedDiffusion(GeneratorCallback):
    """The generator callback, its training and generation times read from what it logs."""

    def _on_step(self) -> bool:
        retrains = self.model.diffusion_retrains
        result = super()._on_step()
        if self.model.diffusion_retrains > retrains:
            values = self.logger.name_to_value
            TIMES["diffusion_train_seconds"] += values["diffusion/train_seconds"]
            TIMES["generate_seconds"] += values["diffusion/generate_seconds"]
            TIMES["fidelity_seconds"] += values["diffusion/fidelity_seconds"]
            # vectors drawn (synthetic_samples / synthetic_keep_quantile), not only the synthetic_samples kept
            TIMES["drawn"] += round(values["diffusion/samples_per_second"] * values["diffusion/generate_seconds"])
        return result


TIMES: dict[str, float] = defaultdict(float)


def parse_variant(words: list[str], variants: dict[str, dict[str, Any]] | None = None) -> tuple[str, str, dict[str, Any]]:
    """
    ``--variant LABEL [KEY=VALUE ...]`` into ``("algo[LABEL]", algo, overrides)``: a label of
    the tier's ``variants.yml`` (default: ``hyperparams/cpu/``) brings its algorithm and overrides (KEY=VALUE pairs change them further); any other
    label is PRIDE with the KEY=VALUE pairs (values read as YAML, dotted keys into nested dicts).
    """
    variants = load_variants("cpu") if variants is None else variants
    if not words:
        raise SystemExit("--variant takes a label and key=value pairs")
    label, pairs = words[0], words[1:]
    if label in variants:
        own = dict(variants[label]["overrides"])
        if "seconds_per_answer" in variants[label]:  # a teacher at a person's pace (a pair may change it)
            own["seconds_per_answer"] = variants[label]["seconds_per_answer"]
        algo, overrides = variants[label]["algo"], merge(own, parse_overrides(pairs))
    elif pairs:
        algo, overrides = "pride", parse_overrides(pairs)
    else:
        known = ", ".join(sorted(variants))
        raise SystemExit(f"--variant {label}: not a variant of the tier's variants.yml ({known}); give key=value pairs")
    return f"{algo}[{label}]", algo, overrides


def run(algo: str, env_id: str, timesteps: int, seed: int, as_tier: bool = False, tier: str = "cpu", **overrides: Any) -> dict:
    th.set_num_threads(1)
    TIMES.clear()
    cls = {"sac": SAC, "pebble": sb3_pride.PEBBLE, "pride": sb3_pride.PRIDE}[algo]
    pace = overrides.pop("seconds_per_answer", None)
    kwargs = merge(tier_kwargs(algo, env_id, as_tier, tier), overrides)
    if pace:  # the teacher answers at a person's pace: PacedTeacher
        teacher = make_teacher(kwargs["teacher"], seed=seed)
        if isinstance(teacher, InteractiveTeacher):
            raise SystemExit(f"seconds_per_answer paces a scripted teacher, got the interactive {teacher!r}")
        kwargs["teacher"] = PacedTeacher(teacher, pace)
    model = cls("MlpPolicy", env_id, seed=seed, **kwargs)
    if algo != "sac":
        model.phase_callbacks = (TimedFeedback, TimedDiffusion) if algo == "pride" else (TimedFeedback,)  # type: ignore[misc]
    start = time.perf_counter()
    model.learn(timesteps)
    return {"seconds": time.perf_counter() - start, **TIMES}


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--env", default="sb3_pride/walker-walk-v0")
    parser.add_argument(
        "--timesteps",
        type=int,
        default=None,
        help="25000 (long enough to ask the shortened budget), or with --as-tier the tier's n_timesteps",
    )
    parser.add_argument("--repeats", type=int, default=2)
    parser.add_argument(
        "--algos", nargs="*", default=["sac", "pebble", "pride"], help="none (--algos alone): the variants only"
    )
    parser.add_argument(
        "--as-tier",
        action="store_true",
        help="the CPU tier's own run: its n_timesteps, pre-training and feedback budget (no shortening)",
    )
    parser.add_argument("--seed", type=int, default=0, help="seed of the first repeat (repeat i uses seed + i)")
    parser.add_argument(
        "--tier", default="cpu", help="the settings' folder under hyperparams/ (default: cpu), e.g. label-response"
    )
    parser.add_argument(
        "--variant",
        nargs="+",
        action="append",
        default=[],
        metavar="LABEL [KEY=VALUE]",
        help="also run a variant of the tier's variants.yml, or PRIDE with these settings changed, reported as "
        "algo[LABEL] (repeatable)",
    )
    parser.add_argument("--out", default=None, help="write the results as JSON here")
    args = parser.parse_args()
    tier_variants = load_variants(args.tier)
    variants = {
        name: (algo, overrides) for name, algo, overrides in (parse_variant(words, tier_variants) for words in args.variant)
    }
    algos = args.algos + list(variants)
    if not algos:
        raise SystemExit("nothing to time: give --algos or a --variant")
    if args.timesteps is None:
        args.timesteps = tier_timesteps(args.env, args.tier) if args.as_tier else 25_000

    version, started = provenance(), utc_now()  # the code timed, as it was when the timing began
    results: dict[str, list[dict]] = defaultdict(list)
    for repeat in range(args.repeats):
        for algo in algos:  # a variant's label runs its algorithm with its settings changed
            seed = args.seed + repeat
            kind, changed = variants.get(algo, (algo, {}))
            results[algo].append(run(kind, args.env, args.timesteps, seed, args.as_tier, args.tier, **changed))
            print(f"repeat {repeat} {algo}: {results[algo][-1]['seconds']:.1f} s", flush=True)
    medians = {
        algo: {key: float(np.median([r.get(key, 0.0) for r in runs])) for key in runs[0]} for algo, runs in results.items()
    }
    kwargs = {algo: tier_kwargs(algo, args.env, args.as_tier, args.tier) for algo in args.algos}
    kwargs.update(
        {
            name: merge(tier_kwargs(algo, args.env, args.as_tier, args.tier), changed)
            for name, (algo, changed) in variants.items()
        }
    )
    report = {
        "env": args.env,
        "timesteps": args.timesteps,
        "repeats": args.repeats,
        "as_tier": args.as_tier,
        "tier": args.tier,
        "seed": args.seed,
        "version": version,
        "started": started,
        "ended": utc_now(),
        "kwargs": kwargs,
        "runs": results,
        "medians": medians,
    }
    for algo, median in medians.items():
        line = f"{algo:16s} {median['seconds']:7.1f} s"
        for base in ("sac", "pebble"):
            if base in medians and base != algo:
                line += f"  x{median['seconds'] / medians[base]['seconds']:.3f} of {base.upper()}"
        line += f"  | feedback sessions {median.get('feedback_seconds', 0):.1f} s"
        if median.get("drawn"):
            line += (
                f", diffusion training {median['diffusion_train_seconds']:.1f} s, generation "
                f"{median['generate_seconds']:.1f} s ({median['drawn'] / median['generate_seconds']:.0f} samples drawn/s), "
                f"fidelity check and filter {median['fidelity_seconds']:.1f} s"
            )
        print(line)
    if args.out:
        with open(args.out, "w") as file:
            json.dump(report, file, indent=2)


if __name__ == "__main__":
    main()
