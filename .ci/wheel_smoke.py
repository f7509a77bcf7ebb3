"""Run from outside the source tree against the installed wheel: every public name imports, PEBBLE and PRIDE train."""

import os

os.environ.setdefault("MUJOCO_GL", "disable")

import sb3_pride

assert "site-packages" in sb3_pride.__file__, f"not the installed wheel: {sb3_pride.__file__}"
for name in sb3_pride.__all__:
    getattr(sb3_pride, name)
from sb3_pride.zoo import hyperparams_dir  # noqa: E402

assert (hyperparams_dir() / "cpu" / "pride.yml").exists()
tiny = dict(
    learning_starts=100,
    unsupervised_steps=100,
    feedback_interval=200,
    max_feedback=20,
    queries_per_session=10,
    segment_length=10,
    batch_size=32,
    reward_kwargs=dict(net_arch=(16,)),
    pretraining_kwargs=dict(critic_reset_updates=5),
    policy_kwargs=dict(net_arch=[16]),
)
sb3_pride.PEBBLE("MlpPolicy", "sb3_pride/walker-walk-v0", seed=0, **tiny).learn(400)
model = sb3_pride.PRIDE(
    "MlpPolicy",
    "Pendulum-v1",
    seed=0,
    diffusion_interval=200,
    synthetic_start=0,  # PRIDE()'s default, 10k, is sized for 50k-step runs
    synthetic_ramp=0,
    synthetic_samples=256,
    generator_kwargs=dict(width=16, n_blocks=1, train_steps=20, dynamics_kwargs=dict(width=16, train_steps=20)),
    **tiny,
)
model.learn(400)
assert model.diffusion_retrains >= 1
print(f"wheel OK: {sb3_pride.__file__}, {len(sb3_pride.__all__)} public names")
