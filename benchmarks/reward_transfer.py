"""
r̂ transfers to another algorithm: PEBBLE learns Pendulum-v1 from a scripted teacher's preferences and saves its r̂;
PPO then learns from scratch on that r̂ through ``VecLearnedReward`` (4 envs, rl-zoo3's tuned PPO settings for
Pendulum-v1), beside PPO with the same settings on the true reward. Every agent is evaluated on the true reward.

    python benchmarks/reward_transfer.py --seeds 0 1 2 --out benchmarks/results/reward_transfer_pendulum.json

Each seed's PEBBLE run, its PPO on r̂ and its PPO on the true reward are made in turn, one after the other; the
report gives each seed's true returns and the gap between PPO on r̂ and PPO on the true reward (Pendulum's returns
are negative, 0 the best: a ratio would read backwards).
"""

import argparse
import json
import os
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

os.environ.setdefault("MUJOCO_GL", "disable")

import numpy as np
import torch as th
import yaml
from stable_baselines3 import PPO
from stable_baselines3.common.env_util import make_vec_env
from stable_baselines3.common.evaluation import evaluate_policy

sys.path.insert(0, str(Path(__file__).resolve().parent))
from provenance import provenance, system_info, utc_now

from sb3_pride import PEBBLE
from sb3_pride.reward import VecLearnedReward

#: a PEBBLE that learns Pendulum-v1 in a few thousand steps from 200 scripted labels
PEBBLE_SETTINGS: dict[str, Any] = dict(
    learning_starts=500,
    unsupervised_steps=500,
    feedback_interval=1000,
    max_feedback=200,
    queries_per_session=50,
    segment_length=25,
    reward_kwargs=dict(net_arch=(64, 64)),
    policy_kwargs=dict(net_arch=[64, 64]),
)


def zoo_ppo_settings() -> tuple[int, int, dict]:
    """rl-zoo3's tuned PPO for Pendulum-v1: (n_envs, n_timesteps, constructor arguments)."""
    import rl_zoo3

    entry = dict(yaml.safe_load((Path(rl_zoo3.__file__).parent / "hyperparams" / "ppo.yml").read_text())["Pendulum-v1"])
    n_envs, n_timesteps = int(entry.pop("n_envs")), int(entry.pop("n_timesteps"))
    entry.pop("policy", None)
    return n_envs, n_timesteps, entry


def true_return(model, seed: int, episodes: int) -> float:
    env = make_vec_env("Pendulum-v1", n_envs=1, seed=seed + 10_000)  # Monitor inside: the true return
    mean, _ = evaluate_policy(model, env, n_eval_episodes=episodes, deterministic=True)
    return float(mean)  # type: ignore[arg-type]


def one_seed(seed: int, pebble_steps: int, ppo_steps: int | None, episodes: int, folder: Path) -> dict:
    n_envs, n_timesteps, ppo_settings = zoo_ppo_settings()
    n_timesteps = ppo_steps or n_timesteps
    start = time.time()
    pebble = PEBBLE("MlpPolicy", "Pendulum-v1", seed=seed, **PEBBLE_SETTINGS).learn(pebble_steps)
    pebble.save_reward_model(folder / f"reward_{seed}.pt")
    result = {"seed": seed, "pebble": true_return(pebble, seed, episodes), "pebble_seconds": time.time() - start}
    result["pebble_corr"] = pebble.reward_learner.history[-1]["correlation"]
    for arm in ("ppo_on_r_hat", "ppo_on_true_reward"):
        start = time.time()
        venv = make_vec_env("Pendulum-v1", n_envs=n_envs, seed=seed)
        if arm == "ppo_on_r_hat":
            venv = VecLearnedReward(venv, folder / f"reward_{seed}.pt")
        model = PPO("MlpPolicy", venv, seed=seed, **ppo_settings).learn(n_timesteps)
        result[arm], result[f"{arm}_seconds"] = true_return(model, seed, episodes), time.time() - start
    # Pendulum's returns are negative (0 is best): a ratio would read backwards, the gap does not
    result["gap"] = result["ppo_on_r_hat"] - result["ppo_on_true_reward"]
    return result


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    parser.add_argument("--pebble-steps", type=int, default=5000)
    parser.add_argument("--ppo-steps", type=int, default=None, help="PPO's steps (default: rl-zoo3's n_timesteps)")
    parser.add_argument("--episodes", type=int, default=10, help="evaluation episodes per agent")
    parser.add_argument("--out", default=None, help="write the results as JSON here")
    args = parser.parse_args()
    th.set_num_threads(1)
    started = utc_now()
    rows = []
    with tempfile.TemporaryDirectory() as folder:
        for seed in args.seeds:
            rows.append(one_seed(seed, args.pebble_steps, args.ppo_steps, args.episodes, Path(folder)))
            row = rows[-1]
            print(
                f"seed {seed}: PEBBLE {row['pebble']:.1f} (corr {row['pebble_corr']:.2f}), PPO on r̂ {row['ppo_on_r_hat']:.1f}, "
                f"PPO on r {row['ppo_on_true_reward']:.1f}",
                flush=True,
            )
    means = {arm: float(np.mean([row[arm] for row in rows])) for arm in ("pebble", "ppo_on_r_hat", "ppo_on_true_reward")}
    print("means: " + ", ".join(f"{arm} {value:.1f}" for arm, value in means.items()))
    if args.out:
        report = {
            "command": " ".join(sys.argv),
            "rows": rows,
            "means": means,
            "ppo_settings": zoo_ppo_settings(),
            "pebble_settings": PEBBLE_SETTINGS,
            "version": provenance(),
            "time": {"started": started, "finished": utc_now()},
            "system": system_info(),
        }
        Path(args.out).write_text(json.dumps(report, indent=2, default=str))


if __name__ == "__main__":
    main()
