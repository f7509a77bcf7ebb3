"""
Fixed-seed PEBBLE and PRIDE runs give the weights recorded in ``tests/data/reference_weights.npz`` (policy and reward
ensemble, and PRIDE's first synthetic states) on the CPU: a change of the code's structure must not change what it
learns (a GPU draws other random numbers and runs other kernels, so the runs are pinned to the CPU). Another torch
build can round differently, which PRIDE's diffusion path amplifies. The file is re-recorded only for a change that is
meant to change behaviour (``python tests/test_reference.py``).
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
    generator = dict(window=500, **TINY_GENERATOR)
    model = PRIDE("MlpPolicy", "Pendulum-v1", seed=3, device="cpu", generator_kwargs=generator, **TINY_PRIDE, **TINY)
    runs["pride_default"] = weights(model.learn(900))
    synthetic = model.replay_buffer.synthetic
    runs["pride_default_synthetic"] = synthetic.observations[: synthetic.size()].ravel()[:500]
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
    model = PRIDE("MlpPolicy", "Pendulum-v1", seed=3, device="cpu", **paper, **TINY)
    runs["pride_paper_like"] = weights(model.learn(900))
    return runs


@pytest.mark.slow
def test_fixed_seed_runs_learn_the_recorded_weights():
    recorded = np.load(REFERENCE)
    runs = reference_runs()
    assert set(runs) == set(recorded.files)
    for name, values in runs.items():
        np.testing.assert_allclose(values, recorded[name], rtol=1e-4, atol=1e-5, err_msg=name)


if __name__ == "__main__":
    sys.path.insert(0, str(Path(__file__).parent))
    np.savez_compressed(REFERENCE, **reference_runs())
