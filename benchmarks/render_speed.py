"""
What showing a segment pair to a person costs.

MuJoCo tasks (``--envs``, walker-walk and button-press): seconds to re-render one pair of 50-step segments from recorded
states (``SegmentRenderer``, 320 x 240, headless EGL) and to encode it as two H.264 clips (``encode_mp4``), and the
memory the recorded states add to the replay buffer per 100k transitions.

Envs shown from the frames they render (``--recorded-envs``, Pendulum-v1 and a Box2D task): the cost per env step of
recording (rendering the frame, compressing and writing it: ``RecordRenders`` with a ``FrameRecording``), the bytes per
frame and per 100 episodes (the default window), the seconds to cut and encode a pair of clips from the recording, and
the wall time of a short PEBBLE run with and without a ``WebTeacher`` attached (no feedback session: the difference is
the recording).

    MUJOCO_GL=egl OMP_NUM_THREADS=1 taskset -c 0 python benchmarks/render_speed.py --out benchmarks/results/render_speed.md
"""

import argparse
import os
import platform
import tempfile
import time
from pathlib import Path

os.environ.setdefault("MUJOCO_GL", "egl")

import gymnasium as gym
import numpy as np

import sb3_pride  # noqa: F401  (registers the sb3_pride/... envs)
from sb3_pride.human.recording import FrameRecording, RecordRenders
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


def cpu_model() -> str:
    """The CPU's model name (Linux), else the platform's processor."""
    try:
        lines = Path("/proc/cpuinfo").read_text().splitlines()
        return next(line.split(":", 1)[1].strip() for line in lines if line.startswith("model name"))
    except (OSError, StopIteration):
        return platform.processor() or "CPU"


def seconds_per_step(env: gym.Env, steps: int) -> float:
    """Wall seconds per ``env.step`` under random actions (episodes reset as they end)."""
    env.action_space.seed(0)
    env.reset(seed=0)
    start = time.perf_counter()
    for _ in range(steps):
        if any(env.step(env.action_space.sample())[2:4]):
            env.reset()
    return (time.perf_counter() - start) / steps


class RenderEveryStep(gym.Wrapper):
    """Renders after each step and drops the frame: the rendering part of what recording costs."""

    def step(self, action):
        result = self.env.step(action)
        self.env.render()
        return result


def recorded_row(env_id: str, steps: int, repeats: int, segment_length: int, run_steps: int) -> dict:
    """What showing ``env_id`` from recorded frames costs (see the module's docstring)."""
    with tempfile.TemporaryDirectory() as folder:
        recording = FrameRecording(1, parent=Path(folder))
        env = RecordRenders(gym.make(env_id, render_mode="rgb_array"))
        env.record_frames(recording)
        plain = gym.make(env_id, render_mode="rgb_array")
        rendering = RenderEveryStep(gym.make(env_id, render_mode="rgb_array"))
        passes = [
            (seconds_per_step(plain, steps), seconds_per_step(rendering, steps), seconds_per_step(env, steps))
            for _ in range(repeats)
        ]
        bare, rendered, recorded = np.median(passes, axis=0)
        frame_bytes = recording.bytes / (steps * repeats)
        episode_steps = env.spec.max_episode_steps if env.spec is not None and env.spec.max_episode_steps else steps
        env.action_space.seed(1)
        env.reset(seed=1)
        keys = np.array([env.step(env.action_space.sample())[-1]["render_state"] for _ in range(2 * segment_length)])
        start = time.perf_counter()
        frames = [recording.frames(segment) for segment in keys.reshape(2, segment_length, 3)]
        cut = time.perf_counter() - start
        start = time.perf_counter()
        for side, clip in zip(("left", "right"), frames, strict=True):
            encode_mp4(clip, 30.0, Path(folder) / f"{side}.mp4")
        encode = time.perf_counter() - start
        shape = frames[0].shape[1:]
        recording.close()
    return dict(
        env=env_id,
        frame=f"{shape[1]} x {shape[0]}",
        bare_ms=bare * 1e3,
        render_ms=(rendered - bare) * 1e3,
        record_ms=(recorded - bare) * 1e3,
        frame_kib=frame_bytes / 1024,
        ratio=shape[0] * shape[1] * 3 / frame_bytes,
        window_mib=frame_bytes * episode_steps * 100 / 2**20,
        episode_steps=episode_steps,
        cut=cut,
        encode=encode,
        **run_wall_times(env_id, run_steps),
    )


def run_wall_times(env_id: str, steps: int) -> dict:
    """Wall seconds of ``steps`` PEBBLE steps (SAC 256 x 2, batch 256) with no teacher attached, then a WebTeacher."""
    import torch as th

    from sb3_pride import PEBBLE
    from sb3_pride.human import WebTeacher

    th.set_num_threads(1)
    times = {}
    for name in ("scripted", "web"):
        web = WebTeacher(port=0) if name == "web" else None
        model = PEBBLE("MlpPolicy", env_id, teacher=web or "oracle", learning_starts=100, unsupervised_steps=10**7, seed=0)
        start = time.perf_counter()
        model.learn(steps)
        times[f"{name}_s"] = time.perf_counter() - start
        if web is not None:
            web.close()
    return times


def recorded_table(rows: list[dict], args: argparse.Namespace) -> list[str]:
    lines = [
        "",
        f"Envs shown from the frames they render: recording is on only while a WebTeacher is attached. Per env step, median "
        f"of {args.repeats} passes of {args.steps} random-action steps, taken in turns; a short run is {args.run_steps} PEBBLE steps (SAC 256 x 2, "
        "batch 256, one update per step, no feedback session: the difference is the recording). The window is 100 "
        "episodes (`recorded_episodes`, PEBBLE's `max_query_episodes`); frames are zlib level 1, lossless.",
        "",
        "| env | frame | env step (ms) | + render (ms) | + record: render, compress, write (ms) | KiB per frame "
        "| compression | 100 episodes on disk (MiB) | cut a pair (s) | encode a pair (s) | run, no teacher (s) "
        "| run, WebTeacher attached (s) |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for row in rows:
        lines.append(
            f"| {row['env']} | {row['frame']} | {row['bare_ms']:.2f} | {row['render_ms']:.2f} | {row['record_ms']:.2f} "
            f"| {row['frame_kib']:.1f} | {row['ratio']:.0f}x | {row['window_mib']:.0f} ({row['episode_steps']}-step episodes) "
            f"| {row['cut']:.2f} | {row['encode']:.2f} | {row['scripted_s']:.1f} | {row['web_s']:.1f} |"
        )
    return lines


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--envs", nargs="*", default=["sb3_pride/walker-walk-v0", "sb3_pride/button-press-v3"])
    parser.add_argument("--recorded-envs", nargs="*", default=["Pendulum-v1", "LunarLanderContinuous-v3"])
    parser.add_argument("--steps", type=int, default=1000, help="env steps of each pass measuring recording's cost")
    parser.add_argument("--run-steps", type=int, default=1000, help="PEBBLE steps of each short run")
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

    recorded = []
    for env_id in args.recorded_envs:
        recorded.append(recorded_row(env_id, args.steps, args.repeats, args.segment_length, args.run_steps))
        print(recorded[-1], flush=True)

    lines = [
        "Command: `MUJOCO_GL=egl OMP_NUM_THREADS=1 taskset -c 0 python benchmarks/render_speed.py --out "
        f"benchmarks/results/render_speed.md` (pinned to one core of this 2-core machine, {cpu_model()}, which other "
        "jobs shared meanwhile: the times are upper bounds; Mesa EGL software rendering).",
        "",
        f"MuJoCo tasks, re-rendered from recorded states: one pair = two {args.segment_length}-step segments at "
        f"{args.width} x {args.height}; median of {args.repeats}.",
        "",
        "| env | state floats (float64) | model fields recorded | clip fps | render a pair (s) | encode a pair (s) "
        "| two clips (KiB) | recorded states per 100k transitions (MiB) | renderer setup (s) |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    if not rows:
        lines = lines[:2]
    for row in rows:
        lines.append(
            f"| {row['env']} | {row['state_dim']} | {row['model_fields']} | {row['fps']:.0f} | {row['render']:.2f} "
            f"| {row['encode']:.2f} | {row['kb']:.0f} | {row['mb_per_100k']:.1f} | {row['setup']:.1f} |"
        )
    if recorded:
        lines += recorded_table(recorded, args)
    text = "\n".join(lines) + "\n"
    print(text)
    if args.out is not None:
        args.out.write_text(text)


if __name__ == "__main__":
    main()
