"""benchmarks/reward_bench.py: held-out episodes stay out of training, labels teach r̂, a flipping teacher is caught."""

import importlib.util
import json
from pathlib import Path

import numpy as np
import pytest
import torch as th

from sb3_pride.common.queries import sample_segment_pairs

ROOT = Path(__file__).resolve().parent.parent
_spec = importlib.util.spec_from_file_location("benchmarks_reward_bench", ROOT / "benchmarks" / "reward_bench.py")
assert _spec is not None and _spec.loader is not None
reward_bench = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(reward_bench)

TINY_REWARD = dict(
    segment_length=10,
    queries_per_session=20,
    ensemble_size=3,
    reward_net_arch=(32, 32),
    reward_learning_rate=1e-3,
    reward_batch_size=64,
    reward_epochs=30,
)


def recorded_steps(n_episodes: int = 20, length: int = 60, seed: int = 0) -> dict[str, np.ndarray]:
    """Steps as ``--record`` saves them: a smooth random walk, its reward a known function of (s, a)."""
    rng = np.random.default_rng(seed)
    n = n_episodes * length
    observations = np.cumsum(rng.normal(scale=0.3, size=(n, 3)), axis=0).astype(np.float32)
    observations -= observations.mean(axis=0)
    observations /= observations.std(axis=0)
    actions = rng.uniform(-1, 1, size=(n, 1)).astype(np.float32)
    rewards = np.tanh(observations[:, 0] - 0.5 * observations[:, 1] + 0.3 * actions[:, 0]).astype(np.float32)
    dones = np.zeros(n, dtype=np.uint8)
    dones[length - 1 :: length] = 1
    return {"observations": observations, "actions": actions, "true_rewards": rewards, "dones": dones}


def test_held_out_episodes_never_give_a_training_pair():
    steps = recorded_steps()
    episodes = reward_bench.episode_bounds(steps["dones"])
    assert len(episodes) == 20 and episodes[0] == (0, 60) and episodes[-1] == (1140, 1200)
    train, held = reward_bench.split_episodes(episodes, 0.2, seed=3)
    assert len(held) == 4 and not set(train) & set(held) and sorted(train + held) == episodes
    buffer = reward_bench.episodes_buffer(steps, train)
    rows = np.concatenate([np.arange(start, end) for start, end in train])
    np.testing.assert_array_equal(buffer.observations[:, 0], steps["observations"][rows])
    assert buffer.dones[:, 0].sum() == len(train)
    held_obs = {tuple(o) for start, end in held for o in steps["observations"][start:end]}
    pairs = sample_segment_pairs(buffer, 200, 10, len(train), np.random.default_rng(0))
    assert not any(tuple(o) in held_obs for o in pairs.observations.reshape(-1, 3))


@pytest.mark.parametrize(
    "config, sessions",
    [
        ({}, False),
        ({"temporal_crop": (6, 9)}, False),
        ({}, True),
        ({"pseudo_labels": True}, False),
        ({"dynamics_consistency": {"max_transitions": 200}}, False),
    ],
)
def test_screen_learns_from_oracle_labels_and_a_flipping_teacher_reads_far_worse(config, sessions):
    th.set_num_threads(1)
    steps = recorded_steps()
    good = reward_bench.screen_one(steps, config, 0, [20, 60], TINY_REWARD, sessions=sessions)
    bad = reward_bench.screen_one(steps, {**config, "flip_labels": True}, 0, [20, 60], TINY_REWARD, sessions=sessions)
    assert set(good) == set(bad) == {20, 60}
    assert good[60]["corr"] > 0.7 and good[60]["pair_accuracy"] > 0.8
    # every label flipped: r̂ learns -r
    assert bad[60]["corr"] < -0.5 and bad[60]["pair_accuracy"] < 0.3


def test_decision_rule_picks_the_finalist_and_measures_the_gap():
    def cell(corr, accuracy=0.7):
        return {"corr": {"mean": corr, "std": 0.02}, "pair_accuracy": {"mean": accuracy, "std": 0.01}}

    table = {
        "plain": {"100": cell(0.15), "200": cell(0.2), "400": cell(0.3)},
        "crop": {"100": cell(0.25), "200": cell(0.31), "400": cell(0.4)},
        "slow": {"100": cell(0.16), "200": cell(0.35), "400": cell(0.4)},
        "plain, flipped labels": {"100": cell(-0.2, 0.3), "200": cell(-0.3, 0.2), "400": cell(-0.3, 0.2)},
    }
    verdict = reward_bench.decide(table, [100, 200, 400])
    assert verdict["finalists"] == ["crop"] and verdict["chosen"] == "crop"
    assert not verdict["reaches_plain_at_400_with_100_labels"]
    assert verdict["gap_at_100_to_plain_at_400"] == pytest.approx(0.05)
    assert verdict["flipped_reads_bad"]


def test_incumbent_rule_keeps_what_is_not_better_and_finds_the_cheaper_equal():
    def cell(corr, seconds, std=0.02, accuracy=0.75):
        return {
            "corr": {"mean": corr, "std": std},
            "pair_accuracy": {"mean": accuracy, "std": 0.01},
            "seconds": {"mean": seconds, "std": 1.0},
        }

    table = {
        "incumbent": {"100": cell(0.22, 10), "200": cell(0.31, 20)},
        "better": {"100": cell(0.23, 40), "200": cell(0.36, 50)},
        "noisy": {"100": cell(0.25, 40), "200": cell(0.36, 50, std=0.08)},  # within its spread: not better
        "worse at 100": {"100": cell(0.18, 40), "200": cell(0.40, 50)},
        "cheap": {"100": cell(0.21, 4), "200": cell(0.30, 8)},
        "cheap but worse": {"100": cell(0.15, 2), "200": cell(0.25, 3)},
    }
    verdict = reward_bench.decide_against(table, "incumbent")
    assert verdict["replaces"] == ["better"] and verdict["chosen"] == "better"
    assert verdict["cheaper_equals"] == ["cheap"] and verdict["chosen_as_cheaper"] == "cheap"
    rule, same = reward_bench.verdict_of(table, [100, 200], "incumbent")
    assert rule == reward_bench.INCUMBENT_RULE and same == verdict
    # nothing better than itself: the incumbent stays
    assert reward_bench.decide_against({"incumbent": table["incumbent"]}, "incumbent")["chosen"] is None


def test_merge_joins_screens_made_apart_and_refuses_a_seed_twice(tmp_path):
    th.set_num_threads(1)
    steps = recorded_steps()
    parts = []
    for seed in (0, 1):
        runs = {"plain": {seed: reward_bench.screen_one(steps, {}, seed, [20], TINY_REWARD)}}
        table = reward_bench.summarize(runs, [20])
        part = dict(command=f"screen seed {seed}", seconds=1.0, budgets=[20], seeds=[seed], sessions=False,
                    n_test_pairs=2000, configs={"plain": {}}, reward_kwargs=TINY_REWARD, decision_rule="",
                    table=table, verdict=reward_bench.decide(table, [20]), runs=runs, data={"steps": 1},
                    version={"commit": "x"}, system={"CPU": "test"})  # fmt: skip
        parts.append(tmp_path / f"part{seed}.json")
        parts[-1].write_text(json.dumps(part, default=str))
    merged = reward_bench.merge(parts, tmp_path / "merged")
    assert merged["seeds"] == [0, 1] and sorted(merged["runs"]["plain"]) == [0, 1]
    corr = [merged["runs"]["plain"][seed][20]["corr"] for seed in (0, 1)]
    assert merged["table"]["plain"]["20"]["corr"]["mean"] == pytest.approx(np.mean(corr))
    assert "merged from `part0.json`, `part1.json`" in (tmp_path / "merged.md").read_text()
    with pytest.raises(SystemExit, match="more than one file"):
        reward_bench.merge([parts[0], parts[0]], tmp_path / "twice")
