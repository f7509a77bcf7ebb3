"""The label-response study's reading: the screen's plateau rule and labels to the target, each shown to fail on a
curve that should fail it."""

import math

import numpy as np
import pytest

from tests.test_benchmarks import load_script


@pytest.fixture(scope="module")
def study():
    return load_script("label_response")


LADDER = [8, 16, 32, 64, 128]


def test_labels_to_target_interpolates_on_the_log_budget_axis(study):
    budgets = np.array(LADDER, dtype=float)
    returns = np.array([0.0, 50.0, 90.0, 100.0, 100.0])
    assert study.labels_to_target(budgets, returns, 90.0) == pytest.approx(32)
    assert study.labels_to_target(budgets, returns, 70.0) == pytest.approx(2**4.5)  # half way from 16 to 32 in log2
    assert study.labels_to_target(budgets, returns, -1.0) == 8  # already there at the ladder's bottom
    assert study.labels_to_target(budgets, returns, 101.0) == math.inf  # never: more than the ladder holds


def seeds_along(curve: list[float], rng: np.random.Generator, n: int = 10) -> list[np.ndarray]:
    return [value + rng.normal(0, 3, size=n) for value in curve]


def test_an_arm_that_needs_half_the_labels_reads_a_ratio_near_a_half_and_one_that_needs_twice_reads_two(study):
    rng = np.random.default_rng(1)
    pebble = [10, 40, 70, 90, 100]
    half = [40, 70, 90, 100, 100]  # the same curve, one rung earlier: half the labels
    twice = [0, 10, 40, 70, 90]  # one rung later: the bad case, twice the labels
    read = study.bootstrap_labels(LADDER, seeds_along(pebble, rng), seeds_along(half, rng), floor=0.0, reps=2000)
    assert read["target"] == pytest.approx(90, abs=3)
    assert read["ratio"]["value"] == pytest.approx(0.5, abs=0.1)
    assert read["ratio"]["interval"][1] < 0.75  # the paper's claim (ratio <= 0.5) can be read where it holds
    worse = study.bootstrap_labels(LADDER, seeds_along(pebble, rng), seeds_along(twice, rng), floor=0.0, reps=2000)
    assert worse["ratio"]["value"] > 1.5 and worse["ratio"]["interval"][0] > 1
    flat = [5, 5, 5, 5, 5]  # an arm that does not respond to labels never reaches the target
    never = study.bootstrap_labels(LADDER, seeds_along(pebble, rng), seeds_along(flat, rng), floor=0.0, reps=500)
    assert never["arm"]["labels"] == math.inf and never["ratio"]["interval"][0] == math.inf


def test_the_screen_rule_takes_a_plateau_and_refuses_a_curve_still_rising(study):
    plateau = np.array([0, 300, 600, 800, 900, 920, 910, 915, 905])
    rising = np.linspace(0, 900, 9)
    assert study.plateau_gap(plateau) <= study.PLATEAU_GAP
    assert study.plateau_gap(rising) > study.PLATEAU_GAP
    negative = np.array([-1400, -900, -300, -160, -150, -155, -152, -149, -151])  # Pendulum's returns are negative
    assert study.plateau_gap(negative) <= study.PLATEAU_GAP


def test_the_screen_selects_the_cheapest_qualifying_tasks_with_one_from_dm_control(study):
    def entry(minutes: float, qualifies: bool, dmc: bool) -> dict:
        return {"seeds": 3, "planned": 3, "minutes": {"mean": minutes}, "qualifies": qualifies, "dm_control": dmc}

    tasks = {
        "Pendulum-v1": entry(5, True, False),
        "Reacher-v5": entry(10, True, False),
        "InvertedDoublePendulum-v5": entry(12, True, False),
        "cartpole-swingup": entry(14, True, True),
        "reacher-easy": entry(13, False, True),
        "point_mass-easy": entry(20, True, True),
    }
    selection = study.select(tasks)
    assert selection["studied"] == ["Pendulum-v1", "Reacher-v5", "cartpole-swingup"]
    assert selection["held_out"] == ["InvertedDoublePendulum-v5"]
    tasks["Reacher-v5"]["seeds"] = 2
    assert study.select(tasks)["studied"] is None  # no selection before every seed is in
