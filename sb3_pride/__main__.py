"""
A short preference-based training run that shows the whole loop on a CPU:

    python -m sb3_pride --algo pebble --env sb3_pride/walker-walk-v0 --timesteps 20000

It prints SB3's progress table (feedback, reward-model accuracy and its correlation with the true reward,
true episode returns) and, at the end, the true return of the deterministic policy over a few episodes.
"""

import argparse
import os
import time

os.environ.setdefault("MUJOCO_GL", "disable")

from stable_baselines3.common.evaluation import evaluate_policy  # noqa: E402

import sb3_pride  # noqa: E402

#: small enough for 2 CPU cores: 256 × 2 nets, short pre-training, feedback every 5k steps
CPU_TIER = dict(
    learning_starts=1000,
    unsupervised_steps=2000,
    feedback_interval=5000,
    queries_per_session=50,
    max_feedback=200,
    batch_size=256,
    policy_kwargs=dict(net_arch=[256, 256]),
)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--algo", choices=["pebble"], default="pebble")
    parser.add_argument("--env", default="sb3_pride/walker-walk-v0")
    parser.add_argument("--timesteps", type=int, default=20_000)
    parser.add_argument("--teacher", default="oracle")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--eval-episodes", type=int, default=3)
    args = parser.parse_args()

    algo = {"pebble": sb3_pride.PEBBLE}[args.algo]
    model = algo("MlpPolicy", args.env, teacher=args.teacher, seed=args.seed, verbose=1, **CPU_TIER)
    start = time.time()
    model.learn(args.timesteps, log_interval=5)
    mean, std = evaluate_policy(model, model.get_env(), n_eval_episodes=args.eval_episodes, deterministic=True)
    print(
        f"{args.algo} on {args.env}: {args.timesteps} steps in {time.time() - start:.0f} s, "
        f"{model.feedback_labeled}/{model.feedback_asked} preferences labeled; "
        f"true return of the final policy: {mean:.1f} ± {std:.1f} over {args.eval_episodes} episodes"
    )


if __name__ == "__main__":
    main()
