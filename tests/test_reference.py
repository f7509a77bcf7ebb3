"""
Fixed-seed PEBBLE and PRIDE runs give the weights recorded in ``tests/data/reference_weights.npz`` (policy and reward
ensemble, and PRIDE's first synthetic states) on the CPU: a change of the code's structure must not change what it
learns (a GPU draws other random numbers and runs other kernels, so the runs are pinned to the CPU). Another torch
build, or MKL on another CPU kind, rounds differently, which PRIDE's diffusion path amplifies over a run: the file may
hold one recording per CPU kind under ``name``, ``name.1``, ... and a run must match one of its name's recordings
(with the same code, each CPU kind matches its own to the last bit). The file is re-recorded only for a change that is
meant to change behaviour (``python tests/test_reference.py --new``); ``python tests/test_reference.py`` adds this
machine's recording of each run that matches none of its recordings.
"""

import sys
from pathlib import Path

import numpy as np
import pytest

from sb3_pride import PEBBLE, PRIDE
from sb3_pride.pride import PAPER_RECIPE
from sb3_pride.common.utils import merge_kwargs

REFERENCE = Path(__file__).parent / "data" / "reference_weights.npz"
#: a generator small enough for tests, with every stage on: near-real generation, a window, the dynamics filter
TINY_GENERATOR = dict(width=64, n_blocks=2, train_steps=100, sample_steps=4, dynamics_kwargs=dict(train_steps=50, width=32))
TINY_PRIDE = dict(diffusion_interval=300, synthetic_samples=600, synthetic_start=400, synthetic_ramp=200)


def weights(model: PEBBLE) -> np.ndarray:
    parts = [p.detach().cpu().numpy().ravel() for p in model.policy.parameters()]
    parts += [p.detach().cpu().numpy().ravel() for p in model.reward_model.parameters()]
    return np.concatenate(parts)


def reference_runs() -> dict[str, np.ndarray]:
    from conftest import TINY

    runs = {}
    model = PEBBLE("MlpPolicy", "Pendulum-v1", seed=3, device="cpu", **TINY)
    runs["pebble"] = weights(model.learn(900))
    # PRIDE's generator and mixing, with PEBBLE's label schedule and reward learning at u = 0.5
    generator = dict(window=500, **TINY_GENERATOR)
    pebbles = dict(synthetic_ratio=0.5, feedback_schedule="constant", reward_kwargs=dict(dynamics_consistency=False))
    near_real = merge_kwargs(TINY, dict(generator_kwargs=generator, **TINY_PRIDE, **pebbles))
    model = PRIDE("MlpPolicy", "Pendulum-v1", seed=3, device="cpu", **near_real)
    runs["pride_near_real"] = weights(model.learn(900))
    synthetic = model.replay_buffer.synthetic
    runs["pride_near_real_synthetic"] = synthetic.observations[: synthetic.size()].ravel()[:500]
    # the paper's recipe, with the rows on top, a whitened model and the reward filter: every other branch
    paper = merge_kwargs(
        PAPER_RECIPE,
        dict(
            synthetic_on_top=True,
            diffusion_interval=300,
            synthetic_samples=600,
            generator_kwargs=dict(keep_quantile=0.5, filter="reward", normalization="whiten", **TINY_GENERATOR),
        ),
    )
    model = PRIDE("MlpPolicy", "Pendulum-v1", seed=3, device="cpu", **merge_kwargs(TINY, paper))
    runs["pride_paper_like"] = weights(model.learn(900))
    return runs


def recordings(recorded: dict[str, np.ndarray], name: str) -> list[np.ndarray]:
    """Every recording of the run ``name``: one per CPU kind it was recorded on."""
    return [values for key, values in recorded.items() if key.split(".")[0] == name]


def matches(values: np.ndarray, recording: np.ndarray) -> bool:
    return values.shape == recording.shape and np.allclose(values, recording, rtol=1e-4, atol=1e-5)


@pytest.mark.slow
def test_fixed_seed_runs_learn_the_recorded_weights():
    recorded = dict(np.load(REFERENCE))
    runs = reference_runs()
    assert set(runs) == {key.split(".")[0] for key in recorded}
    for name, values in runs.items():
        if not any(matches(values, recording) for recording in recordings(recorded, name)):
            for recording in recordings(recorded, name):  # each CPU kind's recording, to show how far off the run is
                np.testing.assert_allclose(values, recording, rtol=1e-4, atol=1e-5, err_msg=name)


if __name__ == "__main__":
    sys.path.insert(0, str(Path(__file__).parent))
    runs = reference_runs()
    if "--new" in sys.argv or not REFERENCE.exists():
        np.savez_compressed(REFERENCE, **runs)
    else:
        recorded = dict(np.load(REFERENCE))
        for name, values in runs.items():
            known = recordings(recorded, name)
            if not any(matches(values, recording) for recording in known):
                recorded[f"{name}.{len(known)}"] = values
                print(f"{name}: this machine's recording added beside {len(known)}")
        np.savez_compressed(REFERENCE, **recorded)
