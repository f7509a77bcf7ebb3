"""
Is the diffusion generator worth its cost on a CPU? Dynamics error of synthetic walker-walk transitions against wall
time, for the generator's size, training budget, warm starts across retrains, sampler steps, samples per
generation, and ways of anchoring generation to real data.

    python benchmarks/generator.py --representation next_state --out benchmarks/results/generator_next_state.json
    python benchmarks/generator.py --representation delta --out benchmarks/results/generator_delta.json
    python benchmarks/generator.py --table benchmarks/results/generator_*.json   # the markdown table

Resumable: configurations already in ``--out`` are skipped (``--only NAME ...`` measures just those).

Data: ``--transitions`` walker-walk transitions under smooth random actions (a_t = clip(0.9 a_{t-1} + 0.45 ε)).
The generators train on all of them; the yardstick holds out a random 20% to measure real data's own error.
Yardstick: one ``DynamicsEnsemble`` (sb3_pride.pride.fidelity) fitted once on the real transitions; every
configuration's samples are judged by it (``dynamics_error_ratio``: error of synthetic s' over the error of real
held-out s'; 1.0 = as consistent as real data) and by their novelty (nearest real neighbour, over real-to-real).
Samples generated from real transitions are also judged on those whose anchor the yardstick held out ("ratio,
held-out anchors"): the yardstick fits its training rows better than held-out ones, which flatters samples near them.
Sanity rows: real held-out transitions (ratio 1 by construction), and real transitions with shuffled s' and with s'
moved by two typical steps (must read far above 1). One torch thread; seconds are for this machine.
"""

import argparse
import json
import os
import time
from pathlib import Path

os.environ.setdefault("MUJOCO_GL", "disable")

import gymnasium as gym
import numpy as np
import torch as th

import sb3_pride  # noqa: F401  (registers the environments)
from run import env_id  # benchmarks/run.py, beside this script
from sb3_pride.pride.diffusion import NORMALIZATIONS, ElucidatedDiffusion
from sb3_pride.pride.fidelity import DynamicsEnsemble, measure_fidelity, split_transitions
from sb3_pride.pride.generator import add_states_to_next_states


def collect(task: str, n: int, seed: int) -> tuple[np.ndarray, int]:
    """``n`` transition vectors [s, a, s'] of ``task`` under smooth random actions, and the action dimension."""
    env = gym.make(env_id(task))
    rng = np.random.default_rng(seed)
    obs, _ = env.reset(seed=seed)
    assert env.action_space.shape is not None  # a Box
    action = np.zeros(env.action_space.shape, dtype=np.float32)
    rows: list[np.ndarray] = []
    while len(rows) < n:
        action = np.clip(0.9 * action + 0.45 * rng.normal(size=action.shape), -1, 1).astype(np.float32)
        next_obs, _, terminated, truncated, _ = env.step(action)
        rows.append(np.concatenate([obs, action, next_obs]))
        obs = next_obs
        if terminated or truncated:
            obs, _ = env.reset()
    return np.asarray(rows, dtype=np.float32), action.shape[0]


#: the generators' (width, blocks, training steps)
SIZES = [(256, 2, 1000), (256, 3, 2000), (256, 3, 4000), (256, 3, 5000), (512, 3, 2000), (512, 3, 5000)]
#: samples drawn per generation for the filtered rows, of which --samples are kept
DRAWN = (20_000, 40_000)


def kept_name(width: int, blocks: int, steps: int, drawn: int, kept: int) -> str:
    return (
        f"near real (SDEdit sigma 0.25) {width}x{blocks} {steps} steps, {kept // 1000}k of {drawn // 1000}k kept by dynamics"
    )


def table(paths: list[Path]) -> str:
    """One markdown row per configuration: task, what it models, normalization, dynamics error ratio, novelty, seconds."""
    lines = [
        "| task | generator | models | normalization | fit s | s per 10k samples | dynamics error | ratio to real | "
        "ratio, held-out anchors | novelty |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for path in paths:
        results = json.loads(path.read_text())
        task = results.get("task", "walker-walk")  # files written before --task: walker-walk
        for row in results["rows"]:
            models = {"next_state": "[s, a, s']", "delta": "[s, a, s' − s]"}.get(row.get("representation", ""), "—")
            normalization = row.get("normalization", "per_dimension" if "representation" in row else "—")
            heldout = row.get("heldout_anchor_error_ratio", float("nan"))  # only near-real rows measured after it existed
            lines.append(
                f"| {task} | {row['name']} | {models} | {normalization} | {row['fit_seconds']:.1f} | "
                f"{row['seconds_per_10k_samples']:.2f} | {row['dynamics_error']:.2f} | "
                f"{row['dynamics_error_ratio']:.2f} | {'—' if np.isnan(heldout) else f'{heldout:.2f}'} | "
                f"{row['novelty_ratio']:.2f} |"
            )
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument(
        "--task", default="walker-walk", help="a task of benchmarks/run.py (walker-walk, button-press-v3, ...)"
    )
    parser.add_argument(
        "--normalization",
        choices=NORMALIZATIONS,
        default="per_dimension",
        help="the generator's normalization (ElucidatedDiffusion's normalization)",
    )
    parser.add_argument("--transitions", type=int, default=20_000)
    parser.add_argument("--samples", type=int, default=10_000, help="synthetic transitions per configuration")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument(
        "--representation",
        choices=["next_state", "delta"],
        default="next_state",
        help="what the generator models: [s, a, s'] (SynthER) or [s, a, s' - s]",
    )
    parser.add_argument("--only", nargs="*", default=None, help="run only the configurations with these names")
    parser.add_argument("--out", type=Path, default=Path("benchmarks/results/generator_next_state.json"))
    parser.add_argument("--table", nargs="+", type=Path, help="print the markdown table of these result files and exit")
    args = parser.parse_args()
    if args.table:
        print(table(args.table))
        return
    th.set_num_threads(1)
    real, action_dim = collect(args.task, args.transitions, args.seed)
    obs_dim = (real.shape[1] - action_dim) // 2
    dim = real.shape[1]
    start = time.perf_counter()
    yardstick = DynamicsEnsemble(obs_dim, action_dim, train_steps=3000, seed=args.seed)
    yardstick.fit(*split_transitions(real, obs_dim, action_dim))
    yardstick_seconds = time.perf_counter() - start
    rng = np.random.default_rng(args.seed)
    # resumable: rows already in --out are kept and not measured again
    rows: list[dict] = json.loads(args.out.read_text())["rows"] if args.out.exists() else []
    done = {row["name"] for row in rows}

    def report(
        name: str,
        synthetic: np.ndarray,
        fit_seconds: float,
        generate_seconds: float,
        anchors: np.ndarray | None = None,
        **config,
    ) -> None:
        if config:
            config = dict(task=args.task, representation=args.representation, normalization=args.normalization, **config)
        fidelity = measure_fidelity(yardstick, real, synthetic, obs_dim, action_dim, refit=False, anchors=anchors)
        row = dict(
            name=name,
            **config,
            fit_seconds=round(fit_seconds, 2),
            generate_seconds=round(generate_seconds, 2),
            seconds_per_10k_samples=round(generate_seconds / max(len(synthetic), 1) * 10_000, 2),
            **{k: round(v, 4) for k, v in vars(fidelity).items()},
        )
        rows.append(row)
        print(json.dumps(row), flush=True)
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(
            json.dumps(
                dict(
                    task=args.task,
                    transitions=args.transitions,
                    samples=args.samples,
                    seed=args.seed,
                    yardstick_fit_seconds=round(yardstick_seconds, 2),
                    rows=rows,
                ),
                indent=1,
            )
        )

    def wanted(name: str) -> bool:
        return name not in done and (args.only is None or name in args.only)

    # sanity: the yardstick must pass real data and fail broken data
    heldout_rows = real[yardstick.holdout]
    if wanted("real held-out"):  # held-out anchors too: exactly 1 in both ratio columns
        report("real held-out", heldout_rows, 0, 0, yardstick.holdout)
    if wanted("shuffled s'"):
        shuffled = heldout_rows.copy()
        shuffled[:, obs_dim + action_dim :] = shuffled[rng.permutation(len(shuffled)), obs_dim + action_dim :]
        report("shuffled s'", shuffled, 0, 0)
    if wanted("s' off by 2 steps"):
        moved = heldout_rows.copy()
        delta_std = (real[:, obs_dim + action_dim :] - real[:, :obs_dim]).std(axis=0)
        moved[:, obs_dim + action_dim :] += 2 * delta_std * rng.choice([-1, 1], size=moved[:, :obs_dim].shape)
        report("s' off by 2 steps", moved, 0, 0)
    if wanted("copies of the buffer"):
        report("copies of the buffer", real[yardstick.train_indices[: args.samples]], 0, 0)

    state_changes = args.representation == "delta"

    def encode(vectors: np.ndarray) -> np.ndarray:
        """[s, a, s'] -> what the generator models: the same, or [s, a, s' − s]."""
        return add_states_to_next_states(vectors, obs_dim, action_dim, -1.0) if state_changes else vectors

    def decode(vectors: np.ndarray) -> np.ndarray:
        return add_states_to_next_states(vectors, obs_dim, action_dim, 1.0) if state_changes else vectors

    def model(width: int, blocks: int, train_steps: int, sample_steps: int, warm_start: bool = False) -> ElucidatedDiffusion:
        return ElucidatedDiffusion(
            dim,
            width=width,
            n_blocks=blocks,
            train_steps=train_steps,
            sample_steps=sample_steps,
            warm_start=warm_start,
            normalization=args.normalization,
            seed=args.seed,
        )

    # unconditional generation (the paper's and SynthER's), size x budget x sampler steps
    fitted: dict[tuple, tuple[ElucidatedDiffusion, float]] = {}
    for width, blocks, steps in SIZES:
        name = f"unconditional {width}x{blocks} {steps} steps"
        anchored = [f"near real (SDEdit sigma {sigma}) {width}x{blocks} {steps} steps" for sigma in (0.25, 0.5, 1.0, 2.0)]
        anchored.append(f"s' given real (s, a) {width}x{blocks} {steps} steps")
        anchored += [kept_name(width, blocks, steps, drawn, args.samples) for drawn in DRAWN]
        if not any(wanted(other) for other in [f"{name} {n} heun" for n in (8, 16, 32)] + anchored):
            continue
        diffusion = model(width, blocks, steps, 16)
        fit_seconds = diffusion.fit(encode(real)).seconds
        fitted[(width, blocks, steps)] = (diffusion, fit_seconds)
        for sample_steps in (8, 16, 32):
            if not wanted(f"{name} {sample_steps} heun"):
                continue
            diffusion.sample_steps = sample_steps
            start = time.perf_counter()
            synthetic = decode(diffusion.sample(args.samples))
            report(
                f"{name} {sample_steps} heun",
                synthetic,
                fit_seconds,
                time.perf_counter() - start,
                mode="unconditional",
                width=width,
                blocks=blocks,
                train_steps=steps,
                sample_steps=sample_steps,
            )

    # warm starts across retrains: data grows 10k -> 15k -> 20k, 1000 steps each, as PRIDE's retrains do
    for width, blocks in [(256, 2), (256, 3)]:
        name = f"warm start {width}x{blocks} 3 x 1000 steps"
        if not wanted(name):
            continue
        diffusion = model(width, blocks, 1000, 16, warm_start=True)
        fit_seconds = 0.0
        for n in (len(real) // 2, 3 * len(real) // 4, len(real)):
            fit_seconds = diffusion.fit(encode(real[:n])).seconds  # the cost of one retrain: the last one
        start = time.perf_counter()
        synthetic = decode(diffusion.sample(args.samples))
        report(
            name,
            synthetic,
            fit_seconds,
            time.perf_counter() - start,
            mode="unconditional, warm",
            width=width,
            blocks=blocks,
            train_steps=1000,
            sample_steps=16,
        )

    # anchored to real data: SDEdit from real transitions, and s' inpainted given a real (s, a)
    for (width, blocks, steps), (diffusion, fit_seconds) in fitted.items():
        anchor_indices = rng.integers(0, len(real), size=args.samples)  # ~20% are rows the yardstick held out
        anchor_rows = real[anchor_indices]
        for start_sigma in (0.25, 0.5, 1.0, 2.0):
            name = f"near real (SDEdit sigma {start_sigma}) {width}x{blocks} {steps} steps"
            if not wanted(name):
                continue
            diffusion.sample_steps = 8
            start = time.perf_counter()
            synthetic = decode(diffusion.sample_near(encode(anchor_rows), start_sigma))
            report(
                name,
                synthetic,
                fit_seconds,
                time.perf_counter() - start,
                anchor_indices,
                mode="sdedit",
                start_sigma=start_sigma,
                width=width,
                blocks=blocks,
                train_steps=steps,
                sample_steps=8,
            )
        name = f"s' given real (s, a) {width}x{blocks} {steps} steps"
        if wanted(name):
            diffusion.sample_steps = 16
            start = time.perf_counter()
            synthetic = decode(diffusion.sample_given(encode(anchor_rows), np.arange(obs_dim + action_dim)))
            report(
                name,
                synthetic,
                fit_seconds,
                time.perf_counter() - start,
                anchor_indices,
                mode="inpaint s'",
                width=width,
                blocks=blocks,
                train_steps=steps,
                sample_steps=16,
            )

    # samples per generation: draw more near-real samples (σ 0.25) than are kept and keep the --samples that a second
    # dynamics ensemble (another seed, PRIDE's own filter settings) trusts most, as synthetic_keep_quantile does; the
    # yardstick, not the filter's own ensemble, judges what is kept
    judge: DynamicsEnsemble | None = None
    for (width, blocks, steps), (diffusion, fit_seconds) in fitted.items():
        for drawn in DRAWN:
            name = kept_name(width, blocks, steps, drawn, args.samples)
            if not wanted(name):
                continue
            if judge is None:
                start = time.perf_counter()
                judge = DynamicsEnsemble(obs_dim, action_dim, seed=args.seed + 1)
                judge.fit(*split_transitions(real, obs_dim, action_dim))
                judge_seconds = time.perf_counter() - start
            anchor_indices = rng.integers(0, len(real), size=drawn)
            diffusion.sample_steps = 8
            start = time.perf_counter()
            synthetic = decode(diffusion.sample_near(encode(real[anchor_indices]), 0.25))
            kept = np.argsort(judge.errors(*split_transitions(synthetic, obs_dim, action_dim)), kind="stable")[: args.samples]
            report(
                name,
                synthetic[kept],
                fit_seconds,
                time.perf_counter() - start,
                anchor_indices[kept],
                mode="sdedit, filtered",
                start_sigma=0.25,
                width=width,
                blocks=blocks,
                train_steps=steps,
                sample_steps=8,
                drawn=drawn,
                filter_fit_seconds=round(judge_seconds, 2),
            )


if __name__ == "__main__":
    main()
