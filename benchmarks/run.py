"""
A grid of training runs — algorithm × task × seed × feedback budget × synthetic ratio — each in its own process,
``--jobs`` at a time, resumable: a run whose ``result.json`` exists is skipped, so a grid can grow run by run.

    python benchmarks/run.py --tier cpu --tasks walker-walk --algos pride pebble --seeds 0 1 2 3 4 \\
        --feedback 400 200 --ratios 0.5 --jobs 2 --out benchmarks/results/runs

Settings come from ``hyperparams/<tier>/<algo>.yml`` (``--tier paper`` uses ``hyperparams/<algo>.yml``);
``--set KEY=VALUE`` changes a constructor argument (a dotted key, ``generator_kwargs.train_steps=2000``, changes one
entry of a nested dict and keeps the others); ``--feedback`` overrides ``max_feedback`` and ``--ratios`` overrides PRIDE's ``synthetic_ratio``; left out, each
task gets its YAML entry's own value (e.g. u = 0.25 on cheetah-run, 2000 queries on Meta-World). SAC on the true
reward ignores both. Each run folder holds ``settings.json``, ``evaluations.npz`` (SB3's
EvalCallback: deterministic true return, and success for Meta-World), ``curve.csv``, ``result.json`` and
``progress.csv`` (SB3's logger: feedback counts, reward-model accuracy and true-reward correlation, diffusion
fidelity and timings, SAC losses).

``settings.json`` records the run's settings, the algorithm's defaults and where the run came from:

- ``version`` (``provenance()``, of ``benchmarks/provenance.py``): the ``sb3_pride`` version (its ``__version__``,
  the one source of it), the folder it was imported from, the git commit of the checkout and whether the checkout had
  uncommitted changes, and the code of the package itself: ``code_tree``, the git tree hash of ``sb3_pride/`` at that
  commit, and ``code_dirty``, whether ``sb3_pride/`` had changes of its own. Two runs with the same ``code_tree`` and
  no ``code_dirty`` ran the same package code, whatever else (results, prose) their commits differ by;
  ``benchmarks/results_page.py`` compares them.
- ``time``: ``started`` (when the worker began) and ``finished`` (when the run's last file was written), in UTC,
  ISO 8601; ``finished`` is ``null`` until the run ends, so a run cut off shows as unfinished. The worker writes
  ``settings.json`` at the start and rewrites it, with ``finished``, at the end.
- ``system`` (``system_info()``, of ``benchmarks/provenance.py``): the CPU model and the versions of Python, torch,
  SB3, Gymnasium, MuJoCo, dm_control, Meta-World and shimmy.

Named configurations (``hyperparams/<tier>/variants.yml``) and grids of them (``benchmarks/grids/*.yml``) are run by
``benchmarks/grid.py``, which uses this module's functions. Several grid processes may run the same grid: each run
folder is claimed by the process that runs it (``benchmarks/run_claims.py``).
"""

import argparse
import dataclasses
import inspect
import itertools
import json
import os
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

os.environ.setdefault("MUJOCO_GL", "disable")
sys.path.insert(0, str(Path(__file__).resolve().parent))

from provenance import provenance, system_info, utc_now
from run_claims import CLAIM, claim_run, claimed_elsewhere

#: what this module takes from provenance.py and run_claims.py, which other benchmarks and the tests reach through it
__all__ = [
    "CLAIM",
    "claim_run",
    "claimed_elsewhere",
    "provenance",
    "system_info",
    "utc_now",
]

ROOT = Path(__file__).resolve().parent.parent
DMC_TASKS = {"walker-walk", "cheetah-run", "quadruped-walk", "walker-run", "finger-spin", "hopper-stand"}
ALGOS = ("pride", "pebble", "sac")


def env_id(task: str) -> str:
    """A task's gymnasium id: ``sb3_pride/<task>-v0`` for DMC, ``sb3_pride/<task>`` for Meta-World, else the id itself."""
    import gymnasium as gym

    from sb3_pride.envs import DM_CONTROL_TASKS

    if task in DMC_TASKS or task in DM_CONTROL_TASKS:
        return f"sb3_pride/{task}-v0"
    return task if task in gym.registry else f"sb3_pride/{task}"


def run_name(spec: dict[str, Any]) -> str:
    name = f"{spec['algo']}_{spec['task']}_s{spec['seed']}"
    if spec["algo"] != "sac":
        name += f"_fb{spec['feedback']}"
    if spec["algo"] == "pride":
        name += f"_u{spec['ratio']}"
    if spec.get("tag"):  # a tag may name the budget ({feedback}): one SAC run per budget's r̂
        name += "_" + spec["tag"].format(feedback=spec["feedback"])
    return name


def parse_overrides(pairs: list[str]) -> dict[str, Any]:
    """
    ``key=value`` strings (value read as YAML: numbers, booleans, lists) into keyword arguments; a dotted key
    (``generator_kwargs.train_steps=2000``) becomes a nested dict, merged into the YAML entry's by :func:`merge`.
    """
    import yaml

    overrides: dict[str, Any] = {}
    for pair in pairs:
        key, sep, value = pair.partition("=")
        if not sep or not key or "" in key.split("."):
            raise SystemExit(f"--set takes key=value, got {pair!r}")
        *parents, leaf = key.split(".")
        node = overrides
        for parent in parents:
            node = node.setdefault(parent, {})
            if not isinstance(node, dict):
                raise SystemExit(f"--set {key}: {parent} is given a value and nested keys both")
        node[leaf] = yaml.safe_load(value)
    return overrides


def merge(base: dict[str, Any], overrides: dict[str, Any]) -> dict[str, Any]:
    """
    ``base`` with ``overrides`` applied, neither changed: a dict value merges key by key into the dict ``base`` holds
    under the same key (``generator_kwargs``, ``policy_kwargs``); any other value replaces it.
    """
    from sb3_pride.common.utils import merge_kwargs

    return merge_kwargs(base, overrides)


def load_variants(tier: str = "cpu") -> dict[str, dict[str, Any]]:
    """
    The named variants of a tier, ``hyperparams/<tier>/variants.yml`` (``hyperparams/variants.yml`` for ``paper``):
    ``{label: {"algo", "name", "description", "overrides", "tag"}}``, the name and tag defaulting to the label ({}
    without the file), ``seconds_per_answer`` where the variant's teacher answers at a person's pace
    (``PacedTeacher``), and ``learned_reward`` where the variant's agent learns from the r̂ a run saved
    (``VecLearnedReward``), ``reference: true`` where the variant is run beside the arms it judges (PEBBLE: the
    reference its task's rows are compared with; SAC: the ceiling they are a share of). Strings of ``overrides`` and
    ``learned_reward`` may name ``{out}`` (the grid's run folder), ``{task}``, ``{feedback}``, ``{seed}`` and
    ``{next_seed}`` (the next seed of the grid block's seeds, cyclically).
    """
    import yaml

    from sb3_pride.zoo import hyperparams_dir

    path = hyperparams_dir() / ("" if tier == "paper" else tier) / "variants.yml"
    if not path.exists():
        return {}
    variants = yaml.safe_load(path.read_text()) or {}
    for label, entry in variants.items():
        unknown = sorted(
            set(entry)
            - {"algo", "name", "description", "overrides", "tag", "seconds_per_answer", "learned_reward", "reference"}
        )
        if unknown or entry.get("algo") not in ALGOS:
            problem = f"unknown keys {unknown}" if unknown else f"algo must be one of {ALGOS}, got {entry.get('algo')!r}"
            raise SystemExit(f"{path}: variant {label!r}: {problem}")
        if "reference" in entry and (type(entry["reference"]) is not bool or entry["algo"] == "pride"):
            raise SystemExit(
                f"{path}: variant {label!r}: reference is true or false, on a pebble or sac variant (the "
                f"task's reference or ceiling), got {entry['reference']!r} on {entry['algo']}"
            )
        entry.setdefault("overrides", {})
        entry.setdefault("tag", label)
        entry.setdefault("description", "")
        entry.setdefault("name", label)
    return variants


def algorithm_class(algo: str) -> type:
    from stable_baselines3 import SAC

    import sb3_pride

    return {"sac": SAC, "pebble": sb3_pride.PEBBLE, "pride": sb3_pride.PRIDE}[algo]


def constructor_parameters(algo: str) -> list[inspect.Parameter]:
    """
    The keyword parameters the algorithm's constructor takes: its own and, through ``**kwargs``, its parents' (a
    parent's after its child's, so a subclass's default comes first).
    """
    found: list[inspect.Parameter] = []
    for cls in algorithm_class(algo).__mro__:
        if "__init__" not in vars(cls):
            continue
        parameters = inspect.signature(vars(cls)["__init__"]).parameters.values()
        found += [p for p in parameters if p.kind in (p.POSITIONAL_OR_KEYWORD, p.KEYWORD_ONLY) and p.name != "self"]
        if not any(p.kind == p.VAR_KEYWORD for p in parameters):
            break
    return found


def constructor_arguments(algo: str) -> set[str]:
    """The keyword arguments the algorithm's constructor takes: its own and, through ``**kwargs``, its parents'."""
    return {p.name for p in constructor_parameters(algo)}


def algorithm_defaults(algo: str) -> dict[str, Any]:
    """
    The defaults of the algorithm's constructor arguments (PRIDE's ``generator_kwargs`` spelled out as the
    generator's, PEBBLE's ``reward_kwargs``, ``query_kwargs`` and ``pretraining_kwargs`` as their parts', and under
    ``option_settings`` the settings an option turned on with True takes): a run records them beside the arguments it
    was given, so that what it ran stays known when a default changes.
    """
    defaults: dict[str, Any] = {}
    for p in reversed(constructor_parameters(algo)):  # a subclass's default overrides its parent's
        if p.default is not p.empty and not p.name.startswith("_"):
            defaults[p.name] = p.default
    if algo == "pride":
        from sb3_pride.pride.generator import TransitionGenerator

        parameters = inspect.signature(TransitionGenerator.__init__).parameters.values()
        defaults["generator_kwargs"] = {p.name: p.default for p in parameters if p.default is not p.empty}
    if algo != "sac":  # the structured settings spelled out, and what True (or a partial dict) means for each option
        from sb3_pride.common.queries import QuerySampler
        from sb3_pride.reward.learner import RewardLearner
        from sb3_pride.pebble.checks import PRETRAINING_DEFAULTS

        parameters = inspect.signature(QuerySampler.__init__).parameters.values()
        defaults["reward_kwargs"] = RewardLearner.settings()
        if algo == "pride":  # PRIDE's reward learning beneath the given reward_kwargs
            from sb3_pride.pride.recipes import PRIDE_REWARD_DEFAULTS

            defaults["reward_kwargs"].update(PRIDE_REWARD_DEFAULTS)
        defaults["query_kwargs"] = {
            p.name: p.default for p in parameters if p.default is not p.empty and p.name != "selection"
        }
        defaults["pretraining_kwargs"] = dict(PRETRAINING_DEFAULTS)
        from sb3_pride.reward.options import REWARD_OPTIONS

        defaults["option_settings"] = {name: dataclasses.asdict(cls()) for name, cls in REWARD_OPTIONS.items()}
    return defaults


#: constructor arguments a run sets itself (the run name records the budget and u): --set must not change them
SET_BY_THE_GRID = {
    "policy": "the grid uses MlpPolicy",
    "env": "use --tasks",
    "seed": "use --seeds",
    "verbose": "runs log to progress.csv",
    "_init_setup_model": "the grid builds the model",
    "max_feedback": "use --feedback, which the run name records",
    "synthetic_ratio": "use --ratios, which the run name records",
}


def check_overrides(overrides: dict[str, Any], algos: list[str]) -> None:
    """Fail before any run starts if an algorithm of the grid does not take a --set key (e.g. PEBBLE and u)."""
    for key in overrides:
        if key in SET_BY_THE_GRID:
            raise SystemExit(f"--set {key}: set by the grid itself ({SET_BY_THE_GRID[key]})")
    for algo in algos:
        unknown = sorted(set(overrides) - constructor_arguments(algo))
        if unknown:
            takers = [other for other in algos if not set(unknown) - constructor_arguments(other)]
            hint = f"; run --algos {' '.join(takers)} on its own" if takers else ""
            raise SystemExit(f"--set {', '.join(unknown)}: not an argument of {algo.upper()}{hint}")


def yaml_entry(tier: str, algo: str, task: str) -> tuple[int, dict[str, Any]]:
    """``(n_timesteps, constructor kwargs)`` of the task's entry in ``hyperparams/<tier>/<algo>.yml``."""
    from sb3_pride.zoo import hyperparams_dir, model_kwargs

    config = hyperparams_dir() / ("" if tier == "paper" else tier) / f"{algo}.yml"
    if not config.exists():
        raise SystemExit(f"--tier {tier!r}: no hyperparameter file {config}")
    try:
        return model_kwargs(config, env_id(task))
    except KeyError:
        raise SystemExit(f"--tasks: {config} has no entry for {env_id(task)!r}") from None


def grid(args: argparse.Namespace) -> list[dict[str, Any]]:
    specs, seen = [], set()
    overrides = parse_overrides(args.set)
    check_overrides(overrides, args.algos)
    # seeds outermost: every cell gets its first seed before any gets its second
    for seed, task, algo in itertools.product(args.seeds, args.tasks, args.algos):
        _, kwargs = yaml_entry(args.tier, algo, task)
        # left out, the budget and u are the YAML entry's own (SAC has neither: its run names ignore them)
        feedbacks = args.feedback or [kwargs.get("max_feedback")]
        ratios = args.ratios or [kwargs.get("synthetic_ratio")]
        for feedback, ratio in itertools.product(feedbacks, ratios):
            spec = dict(
                algo=algo,
                task=task,
                seed=seed,
                feedback=feedback,
                ratio=ratio,
                tier=args.tier,
                eval_freq=args.eval_freq,
                eval_episodes=args.eval_episodes,
                timesteps=args.timesteps,
                tag=args.tag,
                overrides=overrides,
            )
            if run_name(spec) not in seen:  # SAC ignores feedback and ratio; PEBBLE ignores ratio
                seen.add(run_name(spec))
                specs.append(spec)
    return specs


def run_kwargs(spec: dict[str, Any]) -> tuple[int, dict[str, Any]]:
    """``(n_timesteps, constructor kwargs)`` of a run: its YAML entry, the grid's budget, sessions and u, its overrides."""
    n_timesteps, kwargs = yaml_entry(spec["tier"], spec["algo"], spec["task"])
    if spec["algo"] != "sac":
        kwargs["max_feedback"] = spec["feedback"]
        if spec.get("sessions"):  # one schedule shape at every budget of a ladder: the budget in this many sessions
            kwargs["queries_per_session"] = -(-spec["feedback"] // spec["sessions"])
    if spec["algo"] == "pride":
        kwargs["synthetic_ratio"] = spec["ratio"]
    return spec["timesteps"] or n_timesteps, merge(kwargs, spec.get("overrides") or {})


def worker(spec: dict[str, Any], folder: Path) -> None:
    """One run, in this process."""
    import numpy as np
    import torch as th
    from stable_baselines3.common.callbacks import EvalCallback
    from stable_baselines3.common.env_util import make_vec_env
    from stable_baselines3.common.logger import configure

    started = utc_now()
    th.set_num_threads(1)
    spec = run_templates(spec, folder.parent)
    n_timesteps, kwargs = run_kwargs(spec)
    algo = algorithm_class(spec["algo"])
    env = make_vec_env(env_id(spec["task"]), n_envs=1, seed=spec["seed"])
    if spec.get("learned_reward"):  # the agent learns from a saved r̂; the evaluations still read the true return
        from sb3_pride.reward import VecLearnedReward

        env = VecLearnedReward(env, spec["learned_reward"])
    eval_env = make_vec_env(env_id(spec["task"]), n_envs=1, seed=spec["seed"] + 10_000)
    model_kwargs = dict(kwargs)
    for stale in ("preferences.jsonl", "reward.pt"):  # a failed attempt's: a fresh run must not take its answers back
        (folder / stale).unlink(missing_ok=True)
    if spec["algo"] != "sac":  # the run's answers, for a later run to start from (prior_preferences)
        model_kwargs.setdefault("preference_journal", str(folder / "preferences.jsonl"))
    if spec.get("seconds_per_answer"):  # the teacher answers at a person's pace
        from paced_teacher import PacedTeacher

        from sb3_pride.common.teachers import InteractiveTeacher, make_teacher

        name = kwargs.get("teacher", algorithm_defaults(spec["algo"])["teacher"])
        teacher = make_teacher(name, seed=spec["seed"])
        if isinstance(teacher, InteractiveTeacher):
            raise SystemExit(f"seconds_per_answer paces a scripted teacher, and teacher={name!r} is a person")
        model_kwargs["teacher"] = PacedTeacher(teacher, spec["seconds_per_answer"])
    model = algo("MlpPolicy", env, seed=spec["seed"], verbose=0, **model_kwargs)
    folder.mkdir(parents=True, exist_ok=True)
    # SB3's logger to progress.csv: reward-model accuracy and true-reward correlation, diffusion fidelity, losses
    model.set_logger(configure(str(folder), ["csv"]))
    settings = {
        **spec,
        "n_timesteps": n_timesteps,
        "kwargs": kwargs,
        "defaults": algorithm_defaults(spec["algo"]),
        "version": provenance(),
        "time": {"started": started, "finished": None},
        "system": system_info(),
    }
    (folder / "settings.json").write_text(json.dumps(settings, indent=2, default=str))
    evaluation = EvalCallback(
        eval_env,
        eval_freq=spec["eval_freq"],
        n_eval_episodes=spec["eval_episodes"],
        log_path=str(folder),
        deterministic=True,
        verbose=0,
    )
    callbacks: list[Any] = [evaluation]
    if spec["algo"] != "sac":  # beside the run: SAC's critic on real rows, the steps made while answers were awaited
        from diagnostics import AwaitingFeedback, CriticDiagnostics

        awaiting = AwaitingFeedback()
        callbacks += [CriticDiagnostics(seed=spec["seed"] + 1), awaiting]
    start = time.time()
    model.learn(n_timesteps, callback=callbacks)
    seconds = time.time() - start
    if hasattr(model, "save_reward_model"):
        model.save_reward_model(folder / "reward.pt")  # r̂ on its own, for an agent to learn from (learned_reward)
    data = np.load(folder / "evaluations.npz")
    returns = data["results"].mean(axis=1)
    successes = data["successes"].mean(axis=1) if "successes" in data and data["successes"].size else None
    with open(folder / "curve.csv", "w") as file:
        file.write("step,true_return,success\n")
        for i, step in enumerate(data["timesteps"]):
            file.write(f"{step},{returns[i]:.3f},{'' if successes is None else f'{successes[i]:.3f}'}\n")
    result = {
        "seconds": seconds,
        "final_return": float(returns[-1]),
        "best_return": float(returns.max()),
        "final_success": None if successes is None else float(successes[-1]),
        "feedback_asked": model.phase.asked if hasattr(model, "phase") else None,
        "feedback_labeled": model.phase.labeled if hasattr(model, "phase") else None,
    }
    if getattr(model, "asynchronous_feedback", False):
        result["steps_awaiting_feedback"] = awaiting.steps
    (folder / "result.json").write_text(json.dumps(result, indent=2))
    settings["time"]["finished"] = utc_now()  # the run's end, beside its start
    (folder / "settings.json").write_text(json.dumps(settings, indent=2, default=str))


def run_templates(spec: dict[str, Any], out: Path) -> dict[str, Any]:
    """
    ``spec`` with ``{out}``, ``{task}``, ``{feedback}``, ``{seed}`` and ``{next_seed}`` filled in the strings of its
    overrides and ``learned_reward``.
    """
    fields = {"out": str(out), "task": spec["task"], "feedback": spec["feedback"], "seed": spec["seed"]}
    fields["next_seed"] = spec.get("next_seed", spec["seed"])

    def fill(value: Any) -> Any:
        if isinstance(value, str):
            return value.format(**fields)
        if isinstance(value, list):
            return [fill(item) for item in value]
        if isinstance(value, dict):
            return {key: fill(item) for key, item in value.items()}
        return value

    return {**spec, "overrides": fill(spec.get("overrides") or {}), "learned_reward": fill(spec.get("learned_reward"))}


def needed_runs(spec: dict[str, Any], out: Path) -> list[Path]:
    """The run folders of ``out`` whose files ``spec`` starts from (its ``prior_preferences`` and ``learned_reward``)."""
    filled = run_templates(spec, out)
    paths = [*(filled["overrides"].get("prior_preferences") or []), *filter(None, [filled["learned_reward"]])]
    return [Path(path).parent for path in paths if Path(path).parent.parent == out]


def run_specs(specs: list[dict[str, Any]], out: Path, jobs: int) -> int:
    """
    Run every spec whose folder under ``out`` has no ``result.json`` yet, ``jobs`` at a time, each in its own process
    (this script with ``--worker``); return the number of runs that failed. A run another grid process has claimed
    (``claim_run``) is left to it, so that a second process on the same grid adds workers to it.
    """
    todo = [spec for spec in specs if not (out / run_name(spec) / "result.json").exists()]
    total = len(specs)
    print(f"{total} runs in the grid, {total - len(todo)} done, {len(todo)} to run, {jobs} at a time", flush=True)
    running: list[tuple[subprocess.Popen, dict, float]] = []
    finished, failed = total - len(todo), 0
    while todo or running:
        # a run that starts from another run's journal or r̂ waits until that run is done
        ready = [spec for spec in todo if all((folder / "result.json").exists() for folder in needed_runs(spec, out))]
        waiting_elsewhere = any(claimed_elsewhere(folder) for spec in todo for folder in needed_runs(spec, out))
        if todo and not ready and not running and not waiting_elsewhere:  # what they start from failed
            for spec in todo:
                missing = [folder.name for folder in needed_runs(spec, out) if not (folder / "result.json").exists()]
                print(f"{run_name(spec)}: NOT RUN, it starts from runs without a result: {missing}", flush=True)
            return failed + len(todo)
        while ready and len(running) < jobs:
            spec = ready.pop(0)
            todo.remove(spec)
            if not claim_run(out / run_name(spec)):
                print(f"left {run_name(spec)} to the grid process that runs it", flush=True)
                continue
            if (out / run_name(spec) / "result.json").exists():  # done by another process since this one looked
                (out / run_name(spec) / CLAIM).unlink(missing_ok=True)
                continue
            with open(out / run_name(spec) / "log.txt", "w") as log:
                command = [sys.executable, __file__, "--out", str(out), "--worker", json.dumps(spec)]
                process = subprocess.Popen(command, stdout=log, stderr=subprocess.STDOUT)
            # the worker holds the claim too: it goes on if this process is stopped, and no other grid may start it again
            with open(out / run_name(spec) / CLAIM, "a") as claim:
                claim.write(f" {process.pid}")
            running.append((process, spec, time.time()))
            print(f"started {run_name(spec)}", flush=True)
        time.sleep(2)
        for process, spec, started in list(running):
            if process.poll() is None:
                continue
            running.remove((process, spec, started))
            (out / run_name(spec) / CLAIM).unlink(missing_ok=True)
            finished += 1
            result_path = out / run_name(spec) / "result.json"
            if process.returncode == 0 and result_path.exists():
                result = json.loads(result_path.read_text())
                success = "" if result["final_success"] is None else f", success {result['final_success']:.2f}"
                print(
                    f"[{finished}/{total}] {run_name(spec)}: {time.time() - started:.0f} s, "
                    f"final return {result['final_return']:.1f}{success}",
                    flush=True,
                )
            else:
                failed += 1
                print(f"[{finished}/{total}] {run_name(spec)}: FAILED (rc {process.returncode}), see its log.txt", flush=True)
    return failed


def make_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--algos", nargs="+", default=["pride", "pebble"], choices=list(ALGOS))
    parser.add_argument("--tasks", nargs="+", default=["walker-walk"])
    parser.add_argument("--seeds", nargs="+", type=int, default=[0])
    parser.add_argument("--feedback", nargs="+", type=int, help="max_feedback values (default: each task's YAML value)")
    parser.add_argument(
        "--ratios", nargs="+", type=float, help="PRIDE's synthetic_ratio values (default: each task's YAML value)"
    )
    parser.add_argument("--tier", default="cpu", help="'paper' or a folder under hyperparams/ (default: cpu)")
    parser.add_argument("--timesteps", type=int, default=0, help="override n_timesteps of the YAML (0: keep)")
    parser.add_argument("--eval-freq", type=int, default=5000)
    parser.add_argument("--eval-episodes", type=int, default=5)
    parser.add_argument(
        "--set",
        nargs="*",
        default=[],
        metavar="KEY=VALUE",
        help="override any constructor argument of the YAML, e.g. gradient_steps=2 or generator_kwargs.train_steps=2000 "
        "(a dotted key changes one entry of a nested dict; applied to every algo; each must take it)",
    )
    parser.add_argument("--tag", default="", help="suffix of the run names: tells variants made with --set apart")
    parser.add_argument("--jobs", type=int, default=1, help="runs in parallel (one process each)")
    parser.add_argument("--out", type=Path, default=ROOT / "benchmarks/results/runs")
    parser.add_argument("--worker", help=argparse.SUPPRESS)
    return parser


def main() -> None:
    parser = make_parser()
    args = parser.parse_args()
    if args.set and not args.tag:
        parser.error("--set needs --tag: a variant must not share its run names with the YAML's configuration")
    if args.worker:
        spec = json.loads(args.worker)
        worker(spec, args.out / run_name(spec))
        return

    run_specs(grid(args), args.out, args.jobs)


if __name__ == "__main__":
    main()
