"""
The learned reward on the command line:

    python -m sb3_pride.reward fit runs/a/preferences.jsonl runs/b/preferences.jsonl --out reward.pt
    python -m sb3_pride.reward report runs/a/model.zip --env sb3_pride/walker-walk-v0 --out report/

``fit`` trains r̂ on the answers of preference journals alone (some held out) and prints its held-out preference
accuracy; ``report`` plays a saved PEBBLE or PRIDE model in the env and writes figures of its r̂ beside the true
reward, per episode and over its feedback sessions. A reward file (``fit``'s, ``PEBBLE.save_reward_model``'s) can be
reported with ``--reward`` (random actions, or a model's with ``--model``).
"""

import argparse
import json
import os
import sys

import gymnasium as gym
from stable_baselines3.common.save_util import load_from_zip_file

import sb3_pride  # noqa: F401 (registers the sb3_pride/... envs)
from sb3_pride.common.learned_reward import LearnedReward
from sb3_pride.reward.fit import fit_reward
from sb3_pride.reward.report import reward_report


def load_model(path: str, env: gym.Env | None = None):
    """A saved ``PEBBLE`` or ``PRIDE`` (told apart by the settings it saved)."""
    from sb3_pride import PEBBLE, PRIDE

    try:
        data, _, _ = load_from_zip_file(path, device="cpu")
    except (OSError, ValueError) as error:
        raise ValueError(f"model {path} is not a saved model: {error}") from None
    algorithm = PRIDE if data is not None and "generator_kwargs" in data else PEBBLE
    return algorithm.load(path, device="cpu")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m sb3_pride.reward", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)  # fmt: skip
    commands = parser.add_subparsers(dest="command", required=True)
    fit = commands.add_parser("fit", help="fit r̂ on preference journals alone")
    fit.add_argument("journals", nargs="+", help="preference journals (JSON lines)")
    fit.add_argument("--out", required=True, help="the reward file to write (e.g. reward.pt)")
    fit.add_argument("--env", default=None, help="the env whose spaces r̂ reads (default: the journals' env id)")
    fit.add_argument("--held-out", type=float, default=0.2, help="share of the pairs held out (default 0.2)")
    fit.add_argument("--seed", type=int, default=0)
    fit.add_argument("--reward-kwargs", default="{}", help="RewardLearner settings as JSON, e.g. '{\"epochs\": 200}'")
    report = commands.add_parser("report", help="figures of r̂ beside the true reward")
    report.add_argument("model", nargs="?", default=None, help="a saved PEBBLE or PRIDE model (.zip)")
    report.add_argument("--env", required=True, help="the env to play, e.g. sb3_pride/walker-walk-v0")
    report.add_argument("--reward", default=None, help="a reward file to show instead of the model's r̂")
    report.add_argument("--out", default="reward_report", help="folder of the figures (default reward_report/)")
    report.add_argument("--episodes", type=int, default=3)
    report.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    os.environ.setdefault("MUJOCO_GL", "disable")  # nothing is rendered

    try:
        if args.command == "fit":
            reward_kwargs = json.loads(args.reward_kwargs)
            if not isinstance(reward_kwargs, dict):
                raise ValueError(f"--reward-kwargs must be a JSON object of RewardLearner settings, got {args.reward_kwargs}")
            reward, result = fit_reward(args.journals, args.env, reward_kwargs, args.held_out, args.seed, device="cpu")
            reward.save(args.out)
            print(
                f"r̂ fitted on {result.train_pairs} pairs ({result.epochs} epochs): training accuracy "
                f"{result.train_accuracy:.3f}, held-out preference accuracy {result.held_out_accuracy:.3f} "
                f"on {result.held_out_pairs} pairs; written to {args.out}"
            )
            return 0
        try:
            env = gym.make(args.env)
        except gym.error.Error as error:
            raise ValueError(f"--env {args.env!r} cannot be made: {error}") from None
        model = None if args.model is None else load_model(args.model)
        if args.reward is not None:
            reward = LearnedReward.load(args.reward, device="cpu")
        elif model is not None:
            reward = LearnedReward.of_model(model)
        else:
            parser.error("report needs a model, a --reward file, or both")
        policy = None if model is None else (lambda observation: model.predict(observation, deterministic=True)[0])
        figures = reward_report(reward, env, args.out, policy, reward.learner.history, args.episodes, args.seed)
        env.close()
        print("\n".join(str(figure) for figure in figures))
        return 0
    except (ValueError, json.JSONDecodeError) as error:
        print(f"error: {error}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
