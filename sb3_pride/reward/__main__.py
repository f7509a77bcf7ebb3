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
import zipfile

import gymnasium as gym
from stable_baselines3.common.save_util import load_from_zip_file

import sb3_pride  # noqa: F401 (registers the sb3_pride/... envs)
from sb3_pride.reward.learned_reward import LearnedReward
from sb3_pride.reward.fit import fit_reward
from sb3_pride.reward.report import reward_report


def same_file(first: str | os.PathLike, second: str | os.PathLike) -> bool:
    """Whether two paths name one file: the same path once resolved (links followed), or one file under two names."""
    if os.path.realpath(first) == os.path.realpath(second):
        return True
    try:
        return os.path.samefile(first, second)
    except OSError:  # one of them does not exist
        return False


def check_writes(option: str, writes: list[str], reads: list[tuple[str, str | None]]) -> None:
    """Refuse to write any of ``writes`` (given by ``option``) over a file the command reads (``reads``: what, path)."""
    for written in writes:
        for what, path in reads:
            if path is not None and same_file(written, path):
                raise ValueError(f"{option} {written} is {what} {path}, which this command reads: give another path")


def is_reward_file(path: str) -> bool:
    """Whether ``path`` is a reward file (``LearnedReward.save``)."""
    try:
        LearnedReward.load(path, device="cpu")
    except ValueError:
        return False
    return True


def load_model(path: str, env: gym.Env | None = None):
    """
    A saved ``PEBBLE`` or ``PRIDE`` (told apart by the settings it saved), loaded without its preference journal:
    r̂ and the policy are in the model file.
    """
    from sb3_pride import PEBBLE, PRIDE

    if not os.path.isfile(path) and not os.path.isfile(f"{path}.zip"):  # SB3 adds ".zip" to a path it cannot open
        raise ValueError(
            f"model {path} is a folder: give the model file (.zip)" if os.path.isdir(path) else f"model {path} does not exist"
        )
    try:
        data, _, _ = load_from_zip_file(path, device="cpu")
    except (OSError, ValueError, RuntimeError, zipfile.BadZipFile) as error:
        raise ValueError(f"model {path} is not a saved model: {error}") from None
    if not data or "segment_length" not in data:  # a reward file (a torch zip), another algorithm's model
        hint = ": it is a reward file, give it with --reward" if is_reward_file(path) else " (it holds no r̂)"
        raise ValueError(f"model {path} is not a saved PEBBLE or PRIDE model{hint}")
    algorithm = PRIDE if "generator_kwargs" in data else PEBBLE
    return algorithm.load(path, device="cpu", preference_journal=None)


def fit_command(args: argparse.Namespace) -> int:
    """``fit``: every argument checked, and nothing the command reads written over, before anything is fitted."""
    try:
        reward_kwargs = json.loads(args.reward_kwargs)
    except json.JSONDecodeError as error:
        raise ValueError(f"--reward-kwargs is not JSON ({error}): give an object, e.g. '{{\"epochs\": 200}}'") from None
    if not isinstance(reward_kwargs, dict):
        raise ValueError(f"--reward-kwargs must be a JSON object of RewardLearner settings, got {args.reward_kwargs}")
    if not 0 <= args.held_out < 1:
        raise ValueError(f"--held-out must be in [0, 1), got {args.held_out}")
    check_writes("--out", [args.out], [("the journal", path) for path in args.journals])
    if os.path.isdir(args.out):
        raise ValueError(f"--out {args.out} is a folder: give the reward file to write, e.g. reward.pt")
    if os.path.exists(args.out) and not is_reward_file(args.out):
        raise ValueError(f"--out {args.out} exists and is not a reward file: fit writes over reward files only")
    try:
        reward, result = fit_reward(args.journals, args.env, reward_kwargs, args.held_out, args.seed, device="cpu")
    except ValueError as error:  # RewardLearner's checks name reward_kwargs: on the command line it is --reward-kwargs
        message = str(error)
        if message.startswith("reward_kwargs"):
            message = "--reward-kwargs" + message.removeprefix("reward_kwargs")
        raise ValueError(message) from None
    reward.save(args.out)
    print(
        f"r̂ fitted on {result.train_pairs} pairs ({result.epochs} epochs): training accuracy "
        f"{result.train_accuracy:.3f}, held-out preference accuracy {result.held_out_accuracy:.3f} "
        f"on {result.held_out_pairs} pairs; written to {args.out}"
    )
    return 0


def report_command(args: argparse.Namespace) -> int:
    """``report``: the model, the reward, the env and the folder checked before the folder is made."""
    if args.episodes < 1:
        raise ValueError(f"--episodes must be a positive integer, got {args.episodes}")
    if os.path.exists(args.out) and not os.path.isdir(args.out):
        raise ValueError(f"--out {args.out} is a file: give a folder for the figures")
    figures = [os.path.join(args.out, f"episode_{number}.png") for number in range(args.episodes)]
    check_writes(
        "--out",
        [*figures, os.path.join(args.out, "sessions.png")],
        [("the model", args.model), ("the reward file", args.reward)],
    )
    try:
        env = gym.make(args.env)
    except gym.error.Error as error:
        raise ValueError(f"--env {args.env!r} cannot be made: {error}") from None
    try:
        model = None if args.model is None else load_model(args.model)
        reward = LearnedReward.load(args.reward, device="cpu") if args.reward is not None else LearnedReward.of_model(model)
        for checked in (reward, None if model is None else LearnedReward.of_model(model)):
            if checked is not None:
                checked.check_spaces(env.observation_space, env.action_space, f"--env {args.env!r}")
        policy = None if model is None else (lambda observation: model.predict(observation, deterministic=True)[0])
        written = reward_report(reward, env, args.out, policy, reward.learner.history, args.episodes, args.seed)
    finally:
        env.close()
    print("\n".join(str(figure) for figure in written))
    return 0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m sb3_pride.reward", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    commands = parser.add_subparsers(dest="command", required=True)
    fit = commands.add_parser("fit", help="fit r̂ on preference journals alone")
    fit.add_argument("journals", nargs="+", help="preference journals (JSON lines)")
    fit.add_argument("--out", required=True, help="the reward file to write (e.g. reward.pt); never a journal it reads")
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
    if args.command == "report" and args.model is None and args.reward is None:
        parser.error("report needs a model, a --reward file, or both")
    os.environ.setdefault("MUJOCO_GL", "disable")  # nothing is rendered
    try:
        return fit_command(args) if args.command == "fit" else report_command(args)
    except (ValueError, OSError) as error:
        print(f"error: {error}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
