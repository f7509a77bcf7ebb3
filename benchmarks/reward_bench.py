"""
A reward-learning bench that needs no RL run: how well does PEBBLE's reward model r̂ learn from a given number of
labels, under each reward-learning configuration?

    # once (6 to 12 minutes on one core): PEBBLE on walker-walk (hyperparams/cpu/pebble.yml, oracle teacher, seed 0),
    # its replay buffer up to 30k env steps (--checkpoint 10000 screens on its first 10k)
    python benchmarks/reward_bench.py --record
    # the screen: every configuration × seed (about 15 minutes per seed on one busy core; --configs picks some)
    python benchmarks/reward_bench.py --screen --seeds 0 1 2 3 4

``--record`` writes ``<data>/buffer.npz`` (float32 observations, actions and true rewards, uint8 episode ends, in
the order the steps were taken; the buffer never wraps, so the buffer at an earlier checkpoint is the first rows of
it: ``checkpoints`` says how many) and ``<data>/provenance.json`` (the code version and the library versions).

``--screen`` trains, for each configuration and seed, fresh ``RewardEnsemble``s with the package's own classes and
loss: uniform segment pairs of the training episodes (80% of the episodes; the other 20% are held out and never give a
training pair), drawn and labelled by the teacher in feedback sessions of ``queries_per_session``, and
``RewardEnsemble.train_epochs`` with the YAML's reward settings (3 members, 256 × 3, lr 3e-4, batch 128, up to 50
epochs, 97% early stop). By default each budget (50, 100, 200, 400 labels) is trained in one go, a fresh model on the
budget's first labels (the budgets share their pairs); ``--sessions`` trains as PEBBLE does, one model after each
session on every label so far (closer to the algorithm, about 3× the compute). At each budget it reports, on the
held-out episodes, the Pearson correlation of r̂ with the true reward over every transition, and the preference
accuracy over fixed segment pairs (does the sign of R̂1 − R̂0 match that of the true returns R1 − R0). Every
configuration sees the same split and pairs for a given seed. Results: ``<out>.json`` and ``<out>.md``, rewritten
after every seed (``--markdown <out>.json`` rewrites the table from the JSON file). The decision rules, the verdicts,
the Markdown page and ``--merge`` are ``benchmarks/reward_bench_report.py``'s.
"""

import argparse
import inspect
import json
import os
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

os.environ.setdefault("MUJOCO_GL", "disable")

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "benchmarks"))

from provenance import provenance, system_info  # noqa: E402
from reward_bench_report import (  # noqa: E402
    DECISION_RULE,
    INCUMBENT_RULE,
    decide,
    decide_against,
    markdown,
    merge,
    summarize,
    verdict_of,
)
from run import env_id, yaml_entry  # noqa: E402

from sb3_pride.common.utils import make_option  # noqa: E402

#: the report's parts (reward_bench_report.py) that the tests reach through this module, the bench's entry point
__all__ = [
    "DECISION_RULE",
    "INCUMBENT_RULE",
    "decide",
    "decide_against",
    "markdown",
    "merge",
    "summarize",
    "verdict_of",
]

DATA = ROOT / "benchmarks" / "results" / "reward_bench_data"
OUT = ROOT / "benchmarks" / "results" / "reward_bench"
TASK = "walker-walk"

#: reward-learning configurations: ``train_epochs`` keyword arguments (the label flip is the teacher's, not r̂'s)
CONFIGS: dict[str, dict[str, Any]] = {
    "plain": {},
    "crop": {"temporal_crop": (35, 45)},
    "no early stop": {"target_accuracy": 1.0},
    "crop + no early stop": {"temporal_crop": (35, 45), "target_accuracy": 1.0},
    "plain, flipped labels": {"flip_labels": True},
    # B-Pref's "mistake" teacher (10% of labels flipped at random), without and with RIME's robust label selection
    "mistake teacher": {"teacher": "mistake"},
    "mistake teacher, robust labels": {"teacher": "mistake", "robust_labels": True},
    # SURF's pseudo-labels on unlabelled pairs of the training episodes (SURF's walker settings)
    "pseudo-labels": {"pseudo_labels": True},
    "crop + pseudo-labels": {"temporal_crop": (35, 45), "pseudo_labels": True},
    "crop + pseudo-labels + no early stop": {"temporal_crop": (35, 45), "pseudo_labels": True, "target_accuracy": 1.0},
    # query selection, in --sessions mode only (each session chooses among 10x candidates with the model so far)
    "disagreement queries": {"query_selection": "disagreement"},
    # REED's self-supervised consistency pre-training of r̂'s encoder on the training episodes' transitions, with
    # Adam (the package's default) and with REED's SGD; "+ synthetic" adds as many transitions made by PRIDE's
    # generator (fitted on the training episodes) to each pass, which this bench tried and PRIDE does not offer. Every
    # pass takes all the training transitions (in a run, the pass of session i sees the steps so far)
    "consistency": {"dynamics_consistency": True},
    "consistency (sgd)": {"dynamics_consistency": {"optimizer": "sgd"}},
    "consistency, 2 epochs": {"dynamics_consistency": {"epochs": 2}},  # the SSL steps of "+ synthetic" (2x data)
    "consistency, 5 epochs": {"dynamics_consistency": {"epochs": 5}},
    "consistency, 10 epochs": {"dynamics_consistency": {"epochs": 10}},
    "crop + consistency, 5 epochs + no early stop": {
        "temporal_crop": (35, 45),
        "dynamics_consistency": {"epochs": 5},
        "target_accuracy": 1.0,
    },
    "consistency + synthetic": {"dynamics_consistency": True, "synthetic_consistency": 0.5},
    "crop + consistency + no early stop": {"temporal_crop": (35, 45), "dynamics_consistency": True, "target_accuracy": 1.0},
    "kcenter + disagreement queries": {"query_selection": "kcenter_disagreement"},
    # the two ways to learn more from unlabelled data together: SURF's pseudo-labels on REED's pre-trained encoder
    "pseudo-labels + consistency, 5 epochs": {"pseudo_labels": True, "dynamics_consistency": {"epochs": 5}},
    "crop + pseudo-labels + consistency, 5 epochs": {
        "temporal_crop": (35, 45),
        "pseudo_labels": True,
        "dynamics_consistency": {"epochs": 5},
    },
    # longer reward training per session on the pre-trained encoder: every epoch (no early stop), and SURF-like
    # many updates (200 epochs: 400 minibatches at 200 labels)
    "consistency, 5 epochs + no early stop": {"dynamics_consistency": {"epochs": 5}, "target_accuracy": 1.0},
    "consistency, 5 epochs + 200 epochs": {
        "dynamics_consistency": {"epochs": 5},
        "target_accuracy": 1.0,
        "max_epochs": 200,
    },
    # cheaper consistency passes: a random 10k of the transitions per pass, with REED's batch and a larger one
    "consistency, 5 epochs over 10k": {"dynamics_consistency": {"epochs": 5, "max_transitions": 10_000}},
    "consistency, 5 epochs over 10k, batch 512": {
        "dynamics_consistency": {"epochs": 5, "max_transitions": 10_000, "batch_size": 512}
    },
}


# ----------------------------------------------------------------------------------------------------------- record
def record(data: Path, checkpoints: list[int], seed: int, command: str) -> None:
    """Run PEBBLE (the CPU YAML's walker-walk entry) and save its replay buffer once the last checkpoint is reached."""
    import torch as th
    from stable_baselines3.common.callbacks import BaseCallback
    from stable_baselines3.common.env_util import make_vec_env

    from sb3_pride import PEBBLE

    th.set_num_threads(1)
    _, kwargs = yaml_entry("cpu", "pebble", TASK)
    env = make_vec_env(env_id(TASK), n_envs=1, seed=seed)
    model = PEBBLE("MlpPolicy", env, seed=seed, verbose=1, **kwargs)
    corr: dict[int, float] = {}

    class Probe(BaseCallback):
        def _on_step(self) -> bool:
            if self.num_timesteps in checkpoints:
                corr[self.num_timesteps] = (
                    model.reward_learner.correlation(model.real_buffer, model.preference_rng)
                    if len(model.preferences)
                    else float("nan")
                )
                print(f"checkpoint {self.num_timesteps}: {model.phase.labeled} labels so far", flush=True)
            return True

    start = time.time()
    model.learn(max(checkpoints), callback=Probe())
    seconds = time.time() - start
    buffer = model.real_buffer
    if buffer.full:
        raise SystemExit("the replay buffer wrapped: record fewer steps or a larger buffer_size")
    n = buffer.pos
    data.mkdir(parents=True, exist_ok=True)
    np.savez_compressed(
        data / "buffer.npz",
        observations=buffer.observations[:n, 0].astype(np.float32),
        actions=buffer.actions[:n, 0].astype(np.float32),
        true_rewards=buffer.true_rewards[:n, 0].astype(np.float32),
        dones=(buffer.dones[:n, 0] > 0).astype(np.uint8),
        checkpoints=np.array(checkpoints),
    )
    info = {
        "command": command,
        "task": env_id(TASK),
        "seed": seed,
        "kwargs": kwargs,
        "checkpoints": checkpoints,
        "pebble_reward_corr_at_checkpoints": corr,
        "feedback_labeled": model.phase.labeled,
        "seconds": seconds,
        "version": provenance(),
        "system": system_info(),
    }
    (data / "provenance.json").write_text(json.dumps(info, indent=2, default=str))
    print(f"saved {n} steps to {data} in {seconds:.0f} s")


# ----------------------------------------------------------------------------------------------------------- screen
def load_data(data: Path, checkpoint: int | None) -> tuple[dict[str, np.ndarray], int]:
    """The recorded steps up to ``checkpoint`` (None: all of them), and the checkpoint."""
    path = data / "buffer.npz"
    if not path.exists():
        raise SystemExit(f"no recorded data at {path}: run `python benchmarks/reward_bench.py --record` first")
    with np.load(path) as file:
        arrays = {key: file[key] for key in file.files}
    n = int(checkpoint if checkpoint is not None else arrays["checkpoints"].max())
    if n > len(arrays["dones"]):
        raise SystemExit(f"--checkpoint {n}: only {len(arrays['dones'])} steps were recorded")
    return {key: value[:n] for key, value in arrays.items() if key != "checkpoints"}, n


def episode_bounds(dones: np.ndarray) -> list[tuple[int, int]]:
    """``[start, end)`` of each complete episode (a step with ``done`` ends one)."""
    ends = np.flatnonzero(dones) + 1
    return list(zip(np.concatenate([[0], ends[:-1]]).tolist(), ends.tolist(), strict=True))


def episodes_buffer(steps: dict[str, np.ndarray], episodes: list[tuple[int, int]]):
    """A ``PreferenceReplayBuffer`` holding these episodes one after the other, each ended by ``done``."""
    from gymnasium import spaces

    from sb3_pride.common.buffers import PreferenceReplayBuffer

    rows = np.concatenate([np.arange(start, end) for start, end in episodes])
    obs, actions = steps["observations"][rows], steps["actions"][rows]
    buffer = PreferenceReplayBuffer(
        len(rows),
        spaces.Box(-np.inf, np.inf, obs.shape[1:], np.float32),
        spaces.Box(-1.0, 1.0, actions.shape[1:], np.float32),
        device="cpu",
    )
    buffer.observations[:, 0] = obs
    buffer.actions[:, 0] = actions
    buffer.true_rewards[:, 0] = steps["true_rewards"][rows]
    buffer.dones[:, 0] = 0
    buffer.dones[np.cumsum([end - start for start, end in episodes]) - 1, 0] = 1
    buffer.pos, buffer.full = 0, True
    return buffer


def split_episodes(
    episodes: list[tuple[int, int]], held_out_fraction: float, seed: int
) -> tuple[list[tuple[int, int]], list[tuple[int, int]]]:
    """(training episodes, held-out episodes): a random ``held_out_fraction`` of them (at least one) held out."""
    order = np.random.default_rng(seed).permutation(len(episodes))
    n_held = max(1, round(held_out_fraction * len(episodes)))
    if n_held >= len(episodes):
        raise SystemExit(f"{len(episodes)} episodes: too few to hold {n_held} out")
    return [episodes[i] for i in sorted(order[n_held:])], [episodes[i] for i in sorted(order[:n_held])]


def pair_accuracy(model, inputs: np.ndarray, true_returns: np.ndarray) -> float:
    """How often the ensemble's mean segment returns order a pair as its true returns do (ties left out)."""
    predicted = model.member_segment_returns(inputs).mean(dim=0).numpy()
    strict = true_returns[:, 1] != true_returns[:, 0]
    agree = (predicted[:, 1] > predicted[:, 0]) == (true_returns[:, 1] > true_returns[:, 0])
    return float(agree[strict].mean())


def screen_one(
    steps: dict[str, np.ndarray],
    config: dict[str, Any],
    seed: int,
    budgets: list[int],
    reward_kwargs: dict[str, Any],
    sessions: bool = False,
    held_out_fraction: float = 0.2,
    n_test_pairs: int = 2000,
) -> dict[int, dict[str, float]]:
    """
    One seed of one configuration: uniform pairs of the training episodes, drawn and labelled in feedback sessions of
    ``queries_per_session``; r̂ trained on the first ``budget`` labels in one go (a fresh model per budget), or with
    ``sessions`` as PEBBLE does (one model, trained after each session); the held-out metrics at each budget.
    """
    import torch as th

    from sb3_pride.reward.consistency import ConsistencyModel, DynamicsConsistency
    from sb3_pride.common.queries import sample_segment_pairs
    from sb3_pride.common.query_selection import pair_features, select_queries
    from sb3_pride.reward.ensemble import PreferenceDataset, RewardEnsemble
    from sb3_pride.reward.options import PseudoLabels, RobustLabels
    from sb3_pride.common.teachers import InteractiveTeacher, make_teacher

    config = dict(config)
    flip = config.pop("flip_labels", False)
    teacher_name = config.pop("teacher", "oracle")
    robust = config.pop("robust_labels", False)
    pseudo = PseudoLabels() if config.pop("pseudo_labels", False) else None
    selection = config.pop("query_selection", "uniform")
    consistency = make_option("dynamics_consistency", config.pop("dynamics_consistency", False), DynamicsConsistency)
    synthetic_share = config.pop("synthetic_consistency", 0.0)
    max_epochs = config.pop("max_epochs", reward_kwargs["reward_epochs"])
    if selection != "uniform" and not sessions:
        raise SystemExit("a query_selection configuration needs --sessions (queries chosen with the model so far)")
    k, per_session = reward_kwargs["segment_length"], reward_kwargs["queries_per_session"]
    # the split and the labelled pairs depend on the seed only: every configuration sees the same ones
    train, held = split_episodes(episode_bounds(steps["dones"]), held_out_fraction, seed)
    train_buffer, held_buffer = episodes_buffer(steps, train), episodes_buffer(steps, held)
    test = sample_segment_pairs(held_buffer, n_test_pairs, k, len(held), np.random.default_rng([seed, 1]))
    assert test is not None
    test_inputs, test_returns = test.inputs, test.true_rewards.sum(axis=-1)
    held_rows = np.concatenate([np.arange(start, end) for start, end in held])
    held_obs, held_actions = steps["observations"][held_rows], steps["actions"][held_rows]
    held_rewards = steps["true_rewards"][held_rows]

    transitions = None
    if consistency is not None:  # (s, a, s') inside the training episodes, their last steps left out
        rows = np.concatenate([np.arange(start, end - 1) for start, end in train])
        transitions = [steps["observations"][rows], steps["actions"][rows], steps["observations"][rows + 1]]
        if synthetic_share > 0:
            transitions = with_synthetic(transitions, synthetic_share, seed)

    teacher = make_teacher(teacher_name, seed=seed)
    if isinstance(teacher, InteractiveTeacher):
        raise SystemExit(f"teacher: the bench labels pairs with a scripted teacher, got the interactive {teacher!r}")
    pair_rng, train_rng = np.random.default_rng([seed, 2]), np.random.default_rng([seed, 3])
    # the labelled pairs, in feedback sessions of queries_per_session: a budget's pairs are the first ones
    chunks = []
    for _ in range(-(-max(budgets) // per_session)):
        pairs = sample_segment_pairs(train_buffer, per_session, k, len(train), pair_rng)
        assert pairs is not None
        labels = teacher(pairs)
        chunks.append((pairs.inputs, 1.0 - labels if flip else labels))

    selections: dict[int, RobustLabels] = {}  # each model's own running selection (RIME)
    consistency_models: dict[int, Any] = {}  # each model's own consistency heads (REED)

    def new_model() -> RewardEnsemble:
        th.manual_seed(seed)
        model = RewardEnsemble(
            held_obs.shape[1],
            held_actions.shape[1],
            n_members=reward_kwargs["ensemble_size"],
            net_arch=tuple(reward_kwargs["reward_net_arch"]),
            learning_rate=reward_kwargs["reward_learning_rate"],
            device="cpu",
        )
        if robust:
            selections[id(model)] = RobustLabels()
        if consistency is not None:
            consistency_models[id(model)] = ConsistencyModel(model, held_obs.shape[1], consistency)
        return model

    unlabeled_rng = np.random.default_rng([seed, 4])

    def fit(model: RewardEnsemble, dataset: PreferenceDataset, passes: int = 1) -> tuple[float, int]:
        if transitions is not None:  # REED: the encoder first, one pass per feedback session so far
            for _ in range(passes):
                consistency_models[id(model)].train_epochs(*transitions, train_rng)
        options: list[Any] = [selections[id(model)]] if id(model) in selections else []
        if pseudo is not None:  # SURF: its unlabelled pairs drawn from the training episodes, as PEBBLE draws queries
            n = min(pseudo.unlabeled_per_label * len(dataset), pseudo.max_unlabeled)
            drawn = sample_segment_pairs(train_buffer, n, k, len(train), unlabeled_rng)
            assert drawn is not None
            pseudo.unlabeled = th.as_tensor(drawn.inputs) if len(drawn.inputs) > 0 else None
            options.append(pseudo)
        _, accuracy, epochs = model.train_epochs(
            dataset, max_epochs, reward_kwargs["reward_batch_size"], rng=train_rng, options=options, **config
        )
        return accuracy, epochs

    def evaluate(model: RewardEnsemble, accuracy: float, epochs: int, seconds: float) -> dict[str, float]:
        predicted = model.predict(held_obs, held_actions)
        return {
            "corr": float(np.corrcoef(predicted, held_rewards)[0, 1]),
            "pair_accuracy": pair_accuracy(model, test_inputs, test_returns),
            "train_accuracy": float(accuracy),
            "epochs": epochs,
            "seconds": seconds,
        }

    results: dict[int, dict[str, float]] = {}
    input_dim = held_obs.shape[1] + held_actions.shape[1]
    if sessions:
        # as PEBBLE: one model, trained on every label so far after each session
        model, dataset = new_model(), PreferenceDataset(k, input_dim)
        epochs_run, start = 0, time.time()
        for session, (inputs, labels) in enumerate(chunks):
            if selection != "uniform" and session > 0:  # PEBBLE's: among 10x candidates, with the model so far
                candidates = sample_segment_pairs(train_buffer, 10 * per_session, k, len(train), pair_rng)
                assert candidates is not None
                n_obs = candidates.observations.shape[-1]
                chosen = select_queries(
                    model.member_segment_returns(candidates.inputs),
                    per_session,
                    selection,
                    features=pair_features(candidates.observations),
                    labeled_features=pair_features(dataset.inputs[..., :n_obs]),
                )
                inputs, labels = candidates[chosen].inputs, teacher(candidates[chosen])
                labels = 1.0 - labels if flip else labels
            dataset.add(inputs, labels)
            accuracy, epochs = fit(model, dataset)
            epochs_run += epochs
            if len(dataset) in budgets:
                results[len(dataset)] = evaluate(model, accuracy, epochs_run, time.time() - start)
    else:
        # each budget in one go: a fresh model trained on the budget's first labels
        inputs, labels = np.concatenate([c[0] for c in chunks]), np.concatenate([c[1] for c in chunks])
        for budget in budgets:
            start = time.time()
            model, dataset = new_model(), PreferenceDataset(k, input_dim)
            dataset.add(inputs[:budget], labels[:budget])
            accuracy, epochs = fit(model, dataset, passes=-(-budget // per_session))
            results[budget] = evaluate(model, accuracy, epochs, time.time() - start)
    return results


def with_synthetic(transitions: list[np.ndarray], share: float, seed: int) -> list[np.ndarray]:
    """
    The real (s, a, s') and, making up ``share`` of the result, transitions drawn by PRIDE's generator (its CPU
    defaults) fitted on them.
    """
    from sb3_pride.pride.generator import TransitionGenerator

    obs, actions, next_obs = transitions
    generator = TransitionGenerator(obs.shape[1], actions.shape[1], seed=seed, device="cpu")
    generator.build(model_terminals=False)
    n_synthetic = round(share * len(obs) / (1.0 - share))
    report = generator.update(generator.transition_vectors(obs, actions, next_obs), n_synthetic)
    synthetic = generator.split(report.vectors)
    return [np.concatenate([real, made]).astype(np.float32) for real, made in zip(transitions, synthetic, strict=True)]


def screen(args: argparse.Namespace) -> dict[str, Any]:
    import torch as th

    th.set_num_threads(1)
    steps, n = load_data(args.data, args.checkpoint)
    provenance_file = args.data / "provenance.json"
    recorded = json.loads(provenance_file.read_text()) if provenance_file.exists() else {}
    _, kwargs = yaml_entry("cpu", "pebble", TASK)
    from sb3_pride import PEBBLE
    from sb3_pride.reward.learner import RewardLearner

    defaults = {p.name: p.default for p in inspect.signature(PEBBLE.__init__).parameters.values()}
    learner = {**RewardLearner.settings(), **(kwargs.get("reward_kwargs") or {})}
    # the bench's record keeps PEBBLE's flat names of these settings
    reward_kwargs = {key: kwargs.get(key, defaults[key]) for key in ("segment_length", "queries_per_session")}
    reward_kwargs.update({f"reward_{key}": learner[key] for key in ("net_arch", "learning_rate", "batch_size", "epochs")})
    reward_kwargs["ensemble_size"] = learner["ensemble_size"]
    budgets = sorted(args.budgets)
    if any(b % reward_kwargs["queries_per_session"] for b in budgets):
        raise SystemExit(f"--budgets must be multiples of queries_per_session ({reward_kwargs['queries_per_session']})")
    configs = {name: CONFIGS[name] for name in args.configs}
    runs: dict[str, dict[int, dict[int, dict[str, float]]]] = {name: {} for name in configs}
    start = time.time()
    result: dict[str, Any] = {}
    for seed in args.seeds:
        for name, config in configs.items():
            runs[name][seed] = screen_one(steps, config, seed, budgets, reward_kwargs, sessions=args.sessions)
            print(
                f"seed {seed} {name}: "
                + ", ".join(
                    f"{b}: corr {runs[name][seed][b]['corr']:.3f} acc {runs[name][seed][b]['pair_accuracy']:.3f}"
                    f" ({runs[name][seed][b]['seconds']:.0f} s)"
                    for b in budgets
                ),
                flush=True,
            )
        # written after every seed: a screen stopped early keeps the seeds it finished
        table = summarize(runs, budgets)
        rule, verdict = verdict_of(table, budgets, args.incumbent)
        result = {
            "decision_rule": rule,
            "verdict": verdict,
            "command": args.command,
            "seconds": time.time() - start,
            "budgets": budgets,
            "seeds": [s for s in args.seeds if s in runs[next(iter(runs))]],
            "sessions": args.sessions,
            "n_test_pairs": 2000,
            "configs": {
                name: {k: list(v) if isinstance(v, tuple) else v for k, v in c.items()} for name, c in configs.items()
            },
            "reward_kwargs": reward_kwargs,
            "incumbent": args.incumbent,
            "table": table,
            "runs": runs,
            "data": {
                "steps": n,
                "seed": recorded.get("seed"),
                "command": recorded.get("command"),
                "commit": recorded.get("version", {}).get("commit"),
            },
            "version": provenance(),
            "system": system_info(),
        }
        out = Path(args.out)
        out.parent.mkdir(parents=True, exist_ok=True)
        out.with_suffix(".json").write_text(json.dumps(result, indent=2, default=str))
        out.with_suffix(".md").write_text(markdown(result))
    print(markdown(result))
    return result


def make_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    mode = parser.add_mutually_exclusive_group(required=True)
    mode.add_argument("--record", action="store_true", help="run PEBBLE once and save its replay buffer")
    mode.add_argument("--screen", action="store_true", help="train reward models on the recorded data")
    mode.add_argument("--markdown", type=Path, default=None, help="rewrite the markdown table of a screen's JSON file")
    mode.add_argument("--merge", type=Path, nargs="+", default=None, help="one screen (--out) from screens' JSON files")
    parser.add_argument("--data", type=Path, default=DATA, help="the recorded data's folder")
    parser.add_argument("--checkpoints", type=int, nargs="+", default=[10_000, 20_000, 30_000])
    parser.add_argument("--record-seed", type=int, default=0)
    parser.add_argument("--checkpoint", type=int, default=None, help="screen on the first N steps (default: all)")
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2, 3, 4])
    parser.add_argument("--budgets", type=int, nargs="+", default=[50, 100, 200, 400])
    parser.add_argument("--configs", nargs="+", default=list(CONFIGS), choices=list(CONFIGS))
    parser.add_argument("--sessions", action="store_true", help="train as PEBBLE does: one model, after each session (slower)")
    parser.add_argument("--out", type=Path, default=OUT, help="the result files' path, without suffix")
    parser.add_argument(
        "--incumbent", default=None, choices=list(CONFIGS), help="judge the screen against this configuration (INCUMBENT_RULE)"
    )
    return parser


def main(argv: list[str] | None = None) -> None:
    args = make_parser().parse_args(argv)
    if args.markdown is not None:
        result = json.loads(args.markdown.read_text())
        args.markdown.with_suffix(".md").write_text(markdown(result))
        return
    if args.merge is not None:
        merge(args.merge, args.out)
        return
    args.command = " ".join(["python", "benchmarks/reward_bench.py", *(sys.argv[1:] if argv is None else argv)])
    if args.record:
        record(args.data, sorted(args.checkpoints), args.record_seed, args.command)
    else:
        screen(args)


if __name__ == "__main__":
    main()
