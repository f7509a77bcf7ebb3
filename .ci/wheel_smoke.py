"""Run from outside the source tree against the installed wheel: every public name imports, PEBBLE and PRIDE train."""

import os

os.environ.setdefault("MUJOCO_GL", "disable")

import sb3_pride

if not os.environ.get("SB3_PRIDE_SMOKE_FROM_SOURCE"):  # the test suite runs this script against the source tree
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

# labels and rewards that outlive the run: a journal, r̂ on its own, SB3's PPO on it, the command line's fit
import subprocess  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402

from stable_baselines3 import PPO  # noqa: E402
from stable_baselines3.common.env_util import make_vec_env  # noqa: E402

from sb3_pride.reward import LearnedReward, VecLearnedReward  # noqa: E402

folder = tempfile.mkdtemp()
earlier = sb3_pride.PEBBLE("MlpPolicy", "Pendulum-v1", seed=0, preference_journal=f"{folder}/a.jsonl", **tiny).learn(400)
earlier.save_reward_model(f"{folder}/reward.pt")
reusing = sb3_pride.PEBBLE("MlpPolicy", "Pendulum-v1", seed=1, prior_preferences=[f"{folder}/a.jsonl"], **tiny)
assert len(reusing.preferences) == earlier.phase.labeled > 0
venv = VecLearnedReward(make_vec_env("Pendulum-v1", n_envs=2), LearnedReward.load(f"{folder}/reward.pt"))
PPO("MlpPolicy", venv, n_steps=32, batch_size=32, n_epochs=1).learn(64)
fit = [sys.executable, "-m", "sb3_pride.reward", "fit", f"{folder}/a.jsonl", "--out", f"{folder}/fit.pt"]
assert "held-out preference accuracy" in subprocess.run(fit, capture_output=True, text=True, check=True).stdout
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
