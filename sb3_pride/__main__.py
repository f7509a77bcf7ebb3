"""
A short preference-based training run that shows the whole loop on a CPU:

    python -m sb3_pride --algo pride --env sb3_pride/walker-walk-v0 --timesteps 20000

It shows SB3's progress bar and prints its progress table (feedback, reward-model accuracy and its correlation with
the true reward,
true episode returns) and, at the end, the true return of the deterministic policy over a few episodes.
"""

import argparse
import os
import time

import torch as th
import yaml
from stable_baselines3.common.evaluation import evaluate_policy

import sb3_pride
from sb3_pride.human.render import use_headless_gl
from sb3_pride.zoo import hyperparams_dir, model_kwargs

#: the demo is shorter than a CPU-tier run (hyperparams/cpu/): less pre-training, feedback sessions every 4000 steps
#: (PRIDE's front-loaded schedule asks in five), half the tier's budget
DEMO_OVERRIDES = dict(unsupervised_steps=2000, feedback_interval=4000)


def demo_kwargs(algo: str, env: str) -> dict:
    """The CPU tier's settings of ``algo`` for ``env`` (walker-walk's for an env the tier has no entry for), shortened."""
    config = hyperparams_dir() / "cpu" / f"{algo}.yml"
    with open(config) as file:
        key = env if env in yaml.safe_load(file) else "sb3_pride/walker-walk-v0"
    _, kwargs = model_kwargs(config, key)
    return {**kwargs, **DEMO_OVERRIDES, "max_feedback": kwargs["max_feedback"] // 2}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--algo", choices=["pride", "pebble"], default="pride")
    parser.add_argument("--env", default="sb3_pride/walker-walk-v0")
    parser.add_argument("--timesteps", type=int, default=20_000)
    parser.add_argument(
        "--teacher",
        default="oracle",
        help="a scripted teacher (oracle, mistake, noisy, skip, myopic, equal) or web: you label in a browser at "
        "http://127.0.0.1:8000/ (the [human] extra; see the README's 'Labeling by hand')",
    )
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--eval-episodes", type=int, default=3)
    parser.add_argument("--threads", type=int, default=1, help="torch threads (small networks: 1 is fastest)")
    parser.add_argument("--preference-journal", default=None, help="a JSON-lines file that keeps every answer (see README)")
    parser.add_argument("--no-progress-bar", action="store_true", help="no progress bar (SB3's, with tqdm and rich)")
    args = parser.parse_args()
    # before the env is made (MuJoCo reads MUJOCO_GL once): a person's clips need headless EGL where no display is;
    # a scripted teacher renders nothing (and dm_control must not try to open a display)
    if args.teacher == "web":
        use_headless_gl()
    os.environ.setdefault("MUJOCO_GL", "disable")
    th.set_num_threads(args.threads)

    kwargs = demo_kwargs(args.algo, args.env)
    kwargs.update(buffer_size=args.timesteps, teacher=args.teacher, preference_journal=args.preference_journal)
    algo = {"pride": sb3_pride.PRIDE, "pebble": sb3_pride.PEBBLE}[args.algo]
    model = algo("MlpPolicy", args.env, seed=args.seed, verbose=1, **kwargs)
    start = time.time()
    model.learn(args.timesteps, log_interval=5, progress_bar=not args.no_progress_bar)
    mean, std = evaluate_policy(model, model.get_env(), n_eval_episodes=args.eval_episodes, deterministic=True)
    print(
        f"{args.algo} on {args.env}: {args.timesteps} steps in {time.time() - start:.0f} s, "
        f"{model.phase.labeled}/{model.phase.asked} preferences labeled; "
        f"true return of the final policy: {mean:.1f} ± {std:.1f} over {args.eval_episodes} episodes"
    )


if __name__ == "__main__":
    main()
