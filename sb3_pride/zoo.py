"""
rl-zoo3 with PRIDE and PEBBLE registered:

    python -m sb3_pride.zoo train --algo pride --env dm_control/walker-walk-v0
    python -m sb3_pride.zoo enjoy --algo pride --env dm_control/walker-walk-v0 -f logs/
    sb3-pride-zoo train --algo pebble --env sb3_pride/button-press-v3 -conf hyperparams/cpu/pebble.yml

``train --resume`` goes on from the newest complete checkpoint of the latest run (``--save-freq``), replay buffer
included. Every rl-zoo3 subcommand works (``train``, ``enjoy``, ``record_video``, ``plot_train``, ``plot_from_file``,
``all_plots``). rl-zoo3 has no plugin hook, so this patches its ``ALGOS`` table (one dict shared by all its
modules) and its optuna samplers, then runs rl-zoo3's own entry point. Our hyperparameter files
(``hyperparams/{pride,pebble,sac}.yml``) are used when ``-conf`` is not given and they have an entry for the env.
"""

import os
import re
import runpy
import sys
from pathlib import Path
from typing import Any, ClassVar

import yaml
from stable_baselines3.common import callbacks

from sb3_pride.pebble import PEBBLE
from sb3_pride.pride import PRIDE
from sb3_pride.common.checkpoints import CheckpointCallback, checkpoint_path, clean_leftovers, latest_checkpoint
from sb3_pride.common.utils import merge_kwargs
from sb3_pride.pride.recipes import expand_recipe

ZOO_ALGOS = {"pride": PRIDE, "pebble": PEBBLE}


def hyperparams_dir() -> Path:
    """The shipped hyperparameter files: the repository's ``hyperparams/`` or, installed, ``share/sb3_pride``."""
    for candidate in (
        Path(__file__).resolve().parent.parent / "hyperparams",
        Path(sys.prefix) / "share" / "sb3_pride" / "hyperparams",
    ):
        if candidate.is_dir():
            return candidate
    raise FileNotFoundError("sb3_pride's hyperparams/ folder was not found; pass -conf explicitly")


#: rl-zoo3 keys that are not constructor arguments
ZOO_ONLY_KEYS = (
    "n_timesteps",
    "env_wrapper",
    "monitor_kwargs",
    "normalize",
    "n_envs",
    "frame_stack",
    "callback",
    "vec_env_wrapper",
)


def model_kwargs(config: Path, env_id: str) -> tuple[int, dict[str, Any]]:
    """``(n_timesteps, constructor kwargs)`` of a hyperparameter file's entry, for use without rl-zoo3
    (``policy_kwargs`` strings evaluated as rl-zoo3 does; a ``recipe`` expanded; the ``policy`` key dropped)."""
    with open(config) as file:
        entry = expand_recipe(yaml.safe_load(file)[env_id])
    n_timesteps = int(entry["n_timesteps"])
    kwargs = {key: value for key, value in entry.items() if key not in (*ZOO_ONLY_KEYS, "policy")}
    if isinstance(kwargs.get("policy_kwargs"), str):
        kwargs["policy_kwargs"] = eval(kwargs["policy_kwargs"], {"dict": dict})
    return n_timesteps, kwargs


# optuna samplers: PEBBLE's and PRIDE's own knobs (the feedback budget stays fixed: it is the experiment's cost)
def sample_pebble_params(trial: Any, n_actions: int, n_envs: int, additional_args: dict) -> dict[str, Any]:
    """Optuna sampler for PEBBLE: SAC's step size plus the feedback schedule, query selection and pre-training."""
    return {
        "learning_rate": trial.suggest_float("learning_rate", 1e-4, 1e-3, log=True),
        "feedback_interval": trial.suggest_categorical("feedback_interval", [2000, 5000, 10_000, 20_000]),
        "queries_per_session": trial.suggest_categorical("queries_per_session", [10, 25, 50, 100]),
        "query_selection": trial.suggest_categorical("query_selection", ["uniform", "disagreement", "entropy"]),
        "unsupervised_steps": trial.suggest_categorical("unsupervised_steps", [0, 2000, 5000, 9000]),
        "reward_kwargs": {"epochs": trial.suggest_categorical("reward_epochs", [10, 50, 100])},
    }


def sample_pride_params(trial: Any, n_actions: int, n_envs: int, additional_args: dict) -> dict[str, Any]:
    """Optuna sampler for PRIDE: PEBBLE's knobs and the label schedule (K counts only with "constant"), plus u, R and
    the diffusion budget."""
    return {
        **sample_pebble_params(trial, n_actions, n_envs, additional_args),
        "feedback_schedule": trial.suggest_categorical("feedback_schedule", ["front_loaded", "constant"]),
        "synthetic_ratio": trial.suggest_float("synthetic_ratio", 0.1, 0.9),
        # on top of batch_size real rows, a minibatch holds batch_size / (1 - u) rows
        "synthetic_on_top": trial.suggest_categorical("synthetic_on_top", [False, True]),
        "diffusion_interval": trial.suggest_categorical("diffusion_interval", [2000, 5000, 10_000, 20_000]),
        "synthetic_samples": trial.suggest_categorical("synthetic_samples", [5000, 20_000, 100_000]),
        "generator_kwargs": {"train_steps": trial.suggest_categorical("train_steps", [500, 1000, 2000, 5000])},
    }


#: trial parameters that are entries of a structured setting: (setting, key)
STRUCTURED_TRIAL_PARAMS = {"train_steps": ("generator_kwargs", "train_steps"), "reward_epochs": ("reward_kwargs", "epochs")}


def convert_params(sampled: dict[str, Any]) -> dict[str, Any]:
    """A trial's sampled values as constructor arguments (used by ``--trial-id`` to reload a trial)."""
    kwargs = {key: value for key, value in sampled.items() if key not in STRUCTURED_TRIAL_PARAMS}
    for name, value in sampled.items():
        if name in STRUCTURED_TRIAL_PARAMS:
            setting, key = STRUCTURED_TRIAL_PARAMS[name]
            kwargs.setdefault(setting, {})[key] = value
    return kwargs


class _InferenceLoader:
    """``load`` with a one-row replay buffer: rl-zoo3's enjoy/record_video shrink only the buffers of the
    off-policy algorithms they know by name, and loading is all they do."""

    def __init__(self, algo: type[PEBBLE]):
        self.algo = algo

    def load(self, path, **kwargs) -> PEBBLE:
        kwargs.setdefault("buffer_size", 1)
        if issubclass(self.algo, PRIDE):
            kwargs.setdefault("replay_buffer_kwargs", {"synthetic_buffer_size": 1})
        return self.algo.load(path, **kwargs)


class _ContinuingModel:
    """What rl-zoo3's ``learn`` is given to go on with a model: the model, its ``learn()`` continuing the step count."""

    def __init__(self, model: Any):
        self.model = model

    def learn(self, *args: Any, **kwargs: Any) -> Any:
        return self.model.learn(*args, reset_num_timesteps=False, **kwargs)

    def __getattr__(self, name: str) -> Any:
        return getattr(self.model, name)


def _continue_step_count(manager_class: type) -> type:
    """
    rl-zoo3's ExperimentManager, with what a crash-safe PRIDE/PEBBLE run needs: ``-i`` continues the step count
    (rl-zoo3 restarts it at 0) so that the feedback and diffusion schedules go on where they were;
    ``--save-freq`` writes each checkpoint as one unit (``sb3_pride.common.checkpoints.CheckpointCallback``), with
    ``--save-replay-buffer`` its replay buffer included (rl-zoo3 saves it only at the end of a run), and
    ``-i path/rl_model_N_steps.zip`` loads that checkpoint's buffer, after removing what a killed save left there.
    """

    class ExperimentManager(manager_class):  # type: ignore[misc, valid-type]
        #: ``--resume``: the step count goes on for every algorithm, up to the run's ``n_timesteps``
        resuming: ClassVar[bool] = False
        n_timesteps: int

        def objective(self, trial: Any) -> float:
            # rl-zoo3 updates the entry with the sampled values key by key: a sampled generator_kwargs (reward_kwargs)
            # would replace the entry's (a recipe's generator) instead of changing one of its settings: merged here
            import rl_zoo3.hyperparams_opt as hpo

            sampler = hpo.HYPERPARAMS_SAMPLER[self.algo]
            base = {key: self._hyperparams[key] for key in ("generator_kwargs", "reward_kwargs") if self._hyperparams.get(key)}

            def merged(*args: Any) -> dict[str, Any]:
                return merge_kwargs(base, sampler(*args))

            hpo.HYPERPARAMS_SAMPLER[self.algo] = merged  # type: ignore[assignment]
            try:
                return super().objective(trial)
            finally:
                hpo.HYPERPARAMS_SAMPLER[self.algo] = sampler

        def read_hyperparameters(self) -> tuple[dict[str, Any], dict[str, Any]]:
            # a `recipe:` (sb3_pride.pride.recipes) becomes the settings it names, the entry's own on top
            hyperparams, saved = super().read_hyperparameters()
            if self.algo in ZOO_ALGOS and "recipe" in hyperparams:
                hyperparams = expand_recipe(hyperparams)
                saved = type(saved)((key, hyperparams[key]) for key in sorted(hyperparams))
            return hyperparams, saved

        def create_callbacks(self) -> None:
            # checkpoints written as one unit (the replay buffer, then the model), with the buffer if asked for
            super().create_callbacks()
            for index, callback in enumerate(self.callbacks):
                if type(callback) is callbacks.CheckpointCallback:
                    self.callbacks[index] = CheckpointCallback(
                        callback.save_freq,
                        callback.save_path,
                        callback.name_prefix,
                        save_replay_buffer=callback.save_replay_buffer or self.save_replay_buffer,
                        save_vecnormalize=callback.save_vecnormalize,
                        verbose=callback.verbose,
                    )

        def _load_pretrained_agent(self, hyperparams: dict[str, Any], env: Any) -> Any:
            folder = os.path.dirname(self.trained_agent)
            clean_leftovers(folder)  # what a save killed midway left beside the checkpoint
            checkpoint = re.fullmatch(r"(.*)_(\d+)_steps\.zip", os.path.basename(self.trained_agent))
            buffer = checkpoint and checkpoint_path(folder, checkpoint[1], int(checkpoint[2]), "replay_buffer_")
            if not (buffer and buffer.is_file()):
                return super()._load_pretrained_agent(hyperparams, env)
            # rl-zoo3's, with the checkpoint's own replay buffer rather than the one its run saved at its end
            import rl_zoo3

            print("Loading pretrained agent")
            for key in ("policy", "policy_kwargs"):
                hyperparams.pop(key, None)
            model: Any = rl_zoo3.ALGOS[self.algo].load(
                self.trained_agent,
                env=env,
                seed=self.seed,
                tensorboard_log=self.tensorboard_log,
                verbose=self.verbose,
                device=self.device,
                **hyperparams,
            )
            print(f"Loading the checkpoint's replay buffer {buffer}")
            model.load_replay_buffer(buffer, truncate_last_traj=self.truncate_last_trajectory)
            return model

        def learn(self, model) -> None:
            resuming = self.continue_training and type(self).resuming
            if not resuming and not (self.continue_training and isinstance(model, PEBBLE)):
                return super().learn(model)
            if resuming:  # --resume: the run goes on to its n_timesteps
                self.n_timesteps = max(self.n_timesteps - model.num_timesteps, 0)
            # not a learn() set on the model: a checkpoint saved during the run would try to pickle it
            super().learn(_ContinuingModel(model))

    return ExperimentManager


def register(inference: bool = False) -> None:
    """Put PRIDE and PEBBLE in rl-zoo3's ``ALGOS`` and optuna sampler tables (idempotent)."""
    import gymnasium as gym
    import rl_zoo3
    import rl_zoo3.hyperparams_opt as hpo
    import shimmy

    import sb3_pride  # noqa: F401  (registers the sb3_pride/... env ids)

    gym.register_envs(shimmy)  # the dm_control/... ids
    for name, algo in ZOO_ALGOS.items():
        rl_zoo3.ALGOS[name] = _InferenceLoader(algo) if inference else algo  # type: ignore[assignment,arg-type]
    hpo.HYPERPARAMS_SAMPLER.update(pebble=sample_pebble_params, pride=sample_pride_params)
    hpo.HYPERPARAMS_CONVERTER.update(pebble=convert_params, pride=convert_params)  # type: ignore[arg-type]
    import rl_zoo3.train

    if not getattr(rl_zoo3.train.ExperimentManager, "continues_step_count", False):
        rl_zoo3.train.ExperimentManager = _continue_step_count(rl_zoo3.train.ExperimentManager)  # type: ignore[misc,assignment]
        rl_zoo3.train.ExperimentManager.continues_step_count = True  # type: ignore[attr-defined]


def _argument(argv: list[str], *names: str) -> str | None:
    for i, arg in enumerate(argv):
        for name in names:
            if arg == name and i + 1 < len(argv):
                return argv[i + 1]
            if arg.startswith(name + "="):
                return arg.split("=", 1)[1]
    return None


def default_config(argv: list[str]) -> str | None:
    """Our hyperparameter file for ``--algo`` if ``-conf`` is absent and the file has an entry for ``--env``."""
    if _argument(argv, "-conf", "--conf-file") is not None:
        return None
    algo, env = _argument(argv, "--algo"), _argument(argv, "--env")
    if algo is None:
        return None
    path = hyperparams_dir() / f"{algo}.yml"
    if not path.is_file():
        return None
    with open(path) as file:
        entries = yaml.safe_load(file) or {}
    return str(path) if env in entries or algo in ZOO_ALGOS else None


def resume_arguments(argv: list[str]) -> tuple[list[str], bool]:
    """
    ``train``'s arguments with ``--resume [FOLDER]`` replaced by ``-i`` the newest complete checkpoint of ``FOLDER``,
    or without a folder of the newest run of ``--algo`` on ``--env`` under ``-f`` that has one (``logs/pebble/
    dm_control-walker-walk-v0_N``, the highest N first), after removing what a killed save left
    (``sb3_pride.common.checkpoints``); and whether ``--resume`` was given.
    """
    index = next((i for i, arg in enumerate(argv) if arg == "--resume" or arg.startswith("--resume=")), None)
    if index is None:
        return argv, False
    folder: str | None = argv[index].partition("=")[2] or None
    given = folder is None and index + 1 < len(argv) and not argv[index + 1].startswith("-")
    folder = argv[index + 1] if given else folder
    rest = argv[:index] + argv[index + 1 + given :]
    if _argument(rest, "-i", "--trained-agent") is not None:
        raise SystemExit("--resume: give --resume or -i (--trained-agent), not both")
    if folder is not None:
        runs, where = [Path(folder)], folder
    else:
        from rl_zoo3.utils import EnvironmentName

        algo, env = _argument(rest, "--algo") or "ppo", EnvironmentName(_argument(rest, "--env") or "CartPole-v1")
        log = Path(_argument(rest, "-f", "--log-folder") or "logs", algo)
        numbered = [path for path in log.glob(f"{env}_*") if re.fullmatch(rf"{re.escape(env)}_\d+(_.+)?", path.name)]
        runs = sorted(numbered, key=lambda path: int(path.name[len(env) + 1 :].split("_")[0]), reverse=True)
        where = f"{log}/{env}_N"
    for run in runs:
        clean_leftovers(run)
        checkpoint = latest_checkpoint(run)
        if checkpoint is not None:
            print(f"Resuming from {checkpoint.model}, the newest complete checkpoint of {run}")
            return [*rest, "-i", str(checkpoint.model)], True
    raise SystemExit(f"--resume: no checkpoint rl_model_N_steps.zip in {where} (train with --save-freq N to make them)")


def main(argv: list[str] | None = None) -> None:
    argv = list(sys.argv[1:] if argv is None else argv)
    if not argv:
        print(__doc__)
        raise SystemExit(2)
    command, arguments = argv[0], argv[1:]
    register(inference=command in ("enjoy", "record_video"))
    if command == "train":
        config = default_config(arguments)
        if config is not None:
            arguments += ["-conf", config]
        arguments, resuming = resume_arguments(arguments)
        import rl_zoo3.train

        rl_zoo3.train.ExperimentManager.resuming = resuming  # type: ignore[attr-defined]
    sys.argv = [f"sb3_pride.zoo {command}", *arguments]
    if command == "record_video":  # a script with no function to call
        runpy.run_module("rl_zoo3.record_video", run_name="__main__")
        return
    import rl_zoo3.cli

    sys.argv = ["rl_zoo3", command, *arguments]
    rl_zoo3.cli.main()


if __name__ == "__main__":
    main()
