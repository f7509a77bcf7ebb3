"""PEBBLE and PRIDE on a CUDA device. Skipped where torch sees none (as in CI): run the suite on a GPU machine too,
where every test that does not name a device builds its models on CUDA ("auto")."""

import gymnasium as gym
import pytest
import torch as th
from test_contract import TINY_DIFFUSION

from sb3_pride import PEBBLE, PRIDE
from sb3_pride.pride.diffusion import ElucidatedDiffusion
from sb3_pride.pride.fidelity import DynamicsEnsemble
from sb3_pride.common.utils import merge_kwargs

pytestmark = pytest.mark.skipif(not th.cuda.is_available(), reason="needs a CUDA device")

#: every reward-learning option at once
OPTIONS = dict(
    reward_kwargs=dict(
        temporal_crop=(6, 10), pseudo_labels=True, robust_labels=True, dynamics_consistency=True, exploration_bonus=True
    ),
    query_kwargs=dict(hybrid_replay=0.5),
    query_selection="kcenter_disagreement",
)


def on(device: str, *modules: th.nn.Module) -> bool:
    return all(p.device.type == device for module in modules for p in module.parameters())


@pytest.mark.slow
@pytest.mark.parametrize("options", [{}, OPTIONS], ids=["defaults", "every option"])
@pytest.mark.parametrize("algo", [PEBBLE, PRIDE])
def test_learns_saves_and_loads_on_cuda(algo, options, tiny_kwargs, tmp_path):
    extra = TINY_DIFFUSION if algo is PRIDE else {}
    model = algo("MlpPolicy", "Pendulum-v1", seed=0, device="cuda", **merge_kwargs(tiny_kwargs, options), **extra)
    model.learn(700)  # pre-training, two feedback sessions (PRIDE: a generation)
    assert model.phase.labeled > 0 and on("cuda", model.policy, model.reward_model)
    if algo is PRIDE:
        assert model.replay_buffer.synthetic.size() > 0
        assert on("cuda", model.generator.diffusion, model.generator.dynamics)
    model.save(tmp_path / "model")
    for device in ("cuda", "cpu"):
        loaded = algo.load(tmp_path / "model", env=gym.make("Pendulum-v1"), device=device)
        assert on(device, loaded.policy, loaded.reward_model)
        loaded.learn(200, reset_num_timesteps=False)


def test_the_generators_models_leave_the_global_rngs_as_they_were():
    cpu_state, cuda_state = th.get_rng_state(), th.cuda.get_rng_state()
    ElucidatedDiffusion(3, width=16, n_blocks=1, seed=0, device="cuda")
    DynamicsEnsemble(3, 1, width=8, seed=0, device="cuda")
    assert th.equal(cpu_state, th.get_rng_state()) and th.equal(cuda_state, th.cuda.get_rng_state())


def test_a_seed_fixes_the_cuda_rng_of_a_new_model():
    """Building PRIDE (whose argument checks build throwaway models without a seed) leaves CUDA's RNG as the seed set
    it, so that a CUDA run repeats from its seed."""
    cuda_states = []
    for _ in range(2):
        PRIDE("MlpPolicy", "Pendulum-v1", seed=0, device="cuda", **TINY_DIFFUSION)
        cuda_states.append(th.cuda.get_rng_state())
    assert th.equal(*cuda_states)
