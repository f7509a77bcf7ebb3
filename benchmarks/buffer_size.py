"""
What a saved replay buffer weighs: the pickle ``save_replay_buffer`` writes (the filled rows only) against the whole
preallocated arrays, after a few hundred steps at the CPU tier's walker-walk settings.

    python benchmarks/buffer_size.py --out benchmarks/results/buffer_size.md
"""

import argparse
import os
import pickle
import sys
import tempfile
from pathlib import Path

os.environ.setdefault("MUJOCO_GL", "disable")
sys.path.insert(0, str(Path(__file__).resolve().parent))

import run


def whole_arrays(buffer) -> int:
    """Bytes of the buffer's state pickled as it is, every preallocated row included (the parts' for PRIDE's)."""
    parts = [buffer.real, buffer.synthetic] if hasattr(buffer, "real") else [buffer]
    return sum(len(pickle.dumps({k: v for k, v in vars(part).items() if k != "reward_source"})) for part in parts)


def measure(algo: str, buffer_size: int, steps: int) -> tuple[int, int]:
    """(bytes saved, bytes of the whole arrays) of a run of ``steps`` env steps."""
    _, kwargs = run.yaml_entry("cpu", algo, "walker-walk")
    kwargs["buffer_size"] = buffer_size
    model = run.algorithm_class(algo)("MlpPolicy", run.env_id("walker-walk"), seed=0, **kwargs)
    model.learn(steps)
    with tempfile.TemporaryDirectory() as folder:
        model.save_replay_buffer(Path(folder) / "buffer.pkl")
        saved = (Path(folder) / "buffer.pkl").stat().st_size
    return saved, whole_arrays(model.replay_buffer)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--steps", type=int, default=500)
    parser.add_argument("--out", type=Path)
    args = parser.parse_args()
    lines = [
        "# Saved replay buffers",
        "",
        f"    python benchmarks/buffer_size.py --steps {args.steps} --out benchmarks/results/buffer_size.md",
        "",
        f"After {args.steps} env steps at the CPU tier's walker-walk settings, sb3_pride {run.provenance()['sb3_pride']}.",
        "",
        "| algorithm | buffer_size | saved (MB) | the whole arrays (MB) |",
        "|---|---|---|---|",
    ]
    for algo in ("pebble", "pride"):
        for size in (50_000, 500_000):
            saved, whole = measure(algo, size, args.steps)
            lines.append(f"| {algo} | {size} | {saved / 1e6:.3f} | {whole / 1e6:.1f} |")
    text = "\n".join(lines) + "\n"
    print(text)
    if args.out:
        args.out.write_text(text)


if __name__ == "__main__":
    main()
