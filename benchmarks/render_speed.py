"""
What showing a segment pair to a person costs. For walker-walk and button-press, seconds to re-render one
pair of 50-step segments from recorded states (``SegmentRenderer``, 320 x 240, headless EGL) and to encode it as two
H.264 clips (``encode_mp4``), and the memory the recorded states add to the replay buffer per 100k transitions.

    MUJOCO_GL=egl python benchmarks/render_speed.py --out benchmarks/results/render_speed.md
"""

import argparse
import os
import tempfile
import time
from pathlib import Path

os.environ.setdefault("MUJOCO_GL", "egl")

import gymnasium as gym
import numpy as np

import sb3_pride  # noqa: F401  (registers the sb3_pride/... envs)
from sb3_pride.human.render import SegmentRenderer, encode_mp4


def recorded_pair(env_id: str, renderer: SegmentRenderer, segment_length: int) -> np.ndarray:
    """Two segments of recorded states from a live env under random actions: (2, segment_length, state_dim)."""
    env = gym.make(env_id)
    env.get_wrapper_attr("enable_render_states")(renderer.layout)
    env.action_space.seed(0)
    env.reset(seed=0)
    states = [env.step(env.action_space.sample())[-1]["render_state"] for _ in range(2 * segment_length)]
    env.close()
    return np.array(states).reshape(2, segment_length, -1)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--envs", nargs="+", default=["sb3_pride/walker-walk-v0", "sb3_pride/button-press-v3"])
    parser.add_argument("--segment-length", type=int, default=50)
    parser.add_argument("--width", type=int, default=320)
    parser.add_argument("--height", type=int, default=240)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--out", type=Path, default=None)
    args = parser.parse_args()

    rows = []
    for env_id in args.envs:
        start = time.perf_counter()
        renderer = SegmentRenderer(env_id, width=args.width, height=args.height)
        setup = time.perf_counter() - start
        pair = recorded_pair(env_id, renderer, args.segment_length)
        render_times, encode_times, sizes = [], [], []
        with tempfile.TemporaryDirectory() as folder:
            for repeat in range(args.repeats):
                start = time.perf_counter()
                clips = [renderer.render(states) for states in pair]
                render_times.append(time.perf_counter() - start)
                start = time.perf_counter()
                for side, frames in zip(("left", "right"), clips, strict=True):
                    encode_mp4(frames, renderer.fps, Path(folder) / f"{repeat}-{side}.mp4")
                encode_times.append(time.perf_counter() - start)
                sizes.append(sum((Path(folder) / f"{repeat}-{side}.mp4").stat().st_size for side in ("left", "right")))
        renderer.close()
        state_dim = pair.shape[-1]
        rows.append(
            dict(
                env=env_id,
                state_dim=state_dim,
                model_fields=", ".join(f"{name}[{len(index)}]" for name, index in renderer.layout) or "none",
                fps=renderer.fps,
                setup=setup,
                render=float(np.median(render_times)),
                encode=float(np.median(encode_times)),
                kb=float(np.median(sizes)) / 1024,
                mb_per_100k=state_dim * 8 * 100_000 / 2**20,
            )
        )
        print(rows[-1], flush=True)

    lines = [
        f"One pair = two {args.segment_length}-step segments at {args.width} x {args.height}; median of {args.repeats}. "
        "Command: `MUJOCO_GL=egl python benchmarks/render_speed.py --out benchmarks/results/render_speed.md` "
        "(this 2-core CPU machine, Mesa EGL software rendering, while two benchmark runs used both cores).",
        "",
        "| env | state floats (float64) | model fields recorded | clip fps | render a pair (s) | encode a pair (s) "
        "| two clips (KiB) | recorded states per 100k transitions (MiB) | renderer setup (s) |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for row in rows:
        lines.append(
            f"| {row['env']} | {row['state_dim']} | {row['model_fields']} | {row['fps']:.0f} | {row['render']:.2f} "
            f"| {row['encode']:.2f} | {row['kb']:.0f} | {row['mb_per_100k']:.1f} | {row['setup']:.1f} |"
        )
    text = "\n".join(lines) + "\n"
    print(text)
    if args.out is not None:
        args.out.write_text(text)


if __name__ == "__main__":
    main()
