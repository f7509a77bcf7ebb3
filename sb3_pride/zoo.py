"""
rl-zoo3 with PRIDE and PEBBLE registered:

    python -m sb3_pride.zoo train --algo pride --env dm_control/walker-walk-v0
    python -m sb3_pride.zoo enjoy --algo pride --env dm_control/walker-walk-v0 -f logs/
    sb3-pride-zoo train --algo pebble --env sb3_pride/button-press-v3 -conf hyperparams/cpu/pebble.yml

Every rl-zoo3 subcommand works (``train``, ``enjoy``, ``record_video``, ``plot_train``, ``plot_from_file``,
``all_plots``). rl-zoo3 has no plugin hook, so this patches its ``ALGOS`` table (one dict shared by all its
modules) and its optuna samplers, then runs rl-zoo3's own entry point. Our hyperparameter files
(``hyperparams/{pride,pebble,sac}.yml``) are used when ``-conf`` is not given and they have an entry for the env.
"""

import functools
import os
import re
import runpy
import sys
from pathlib import Path
from typing import Any

import yaml
from stable_baselines3.common.callbacks import CheckpointCallback

from sb3_pride.pebble import PEBBLE
from sb3_pride.pride import PRIDE
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


def _continue_step_count(manager_class: type) -> type:
    """
    rl-zoo3's ExperimentManager, with what a crash-safe PRIDE/PEBBLE run needs: ``-i`` continues the step count
    (rl-zoo3 restarts it at 0) so that the feedback and diffusion schedules go on where they were;
    ``--save-freq`` with ``--save-replay-buffer`` saves the replay buffer with every checkpoint (rl-zoo3 saves it
    only at the end of a run), and ``-i path/rl_model_N_steps.zip`` loads that checkpoint's buffer.
    """

    class ExperimentManager(manager_class):  # type: ignore[misc, valid-type]
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
            super().create_callbacks()
            if self.algo in ZOO_ALGOS and self.save_replay_buffer:
                for callback in self.callbacks:
                    if isinstance(callback, CheckpointCallback):
                        callback.save_replay_buffer = True

        def _load_pretrained_agent(self, hyperparams: dict[str, Any], env: Any) -> Any:
            model = super()._load_pretrained_agent(hyperparams, env)
            checkpoint = re.fullmatch(r"(.*)_(\d+)_steps\.zip", os.path.basename(self.trained_agent))
            folder = os.path.dirname(self.trained_agent)
            if isinstance(model, PEBBLE) and checkpoint and not os.path.exists(os.path.join(folder, "replay_buffer.pkl")):
                buffer = os.path.join(folder, f"{checkpoint[1]}_replay_buffer_{checkpoint[2]}_steps.pkl")
                if os.path.exists(buffer):
                    print(f"Loading the checkpoint's replay buffer {buffer}")
                    model.load_replay_buffer(buffer)
            return model

        def learn(self, model) -> None:
            if not (self.continue_training and isinstance(model, PEBBLE)):
                return super().learn(model)
            model.learn = functools.partial(model.learn, reset_num_timesteps=False)  # type: ignore[method-assign]
            try:
                super().learn(model)
            finally:
                del model.learn  # an instance attribute would be saved with the model

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
    sys.argv = [f"sb3_pride.zoo {command}", *arguments]
    if command == "record_video":  # a script with no function to call
        runpy.run_module("rl_zoo3.record_video", run_name="__main__")
        return
    import rl_zoo3.cli

    sys.argv = ["rl_zoo3", command, *arguments]
    rl_zoo3.cli.main()


if __name__ == "__main__":
    main()
