"""The label-response study's reading: the screen's plateau rule and labels to the target, each shown to fail on a
curve that should fail it."""

import json
import math
import subprocess

import numpy as np
import pytest

from tests.test_benchmarks import load_script


@pytest.fixture(scope="module")
def study():
    return load_script("label_response")


@pytest.fixture(scope="module")
def screen():
    return load_script("label_response_screen")


@pytest.fixture(scope="module")
def recount():
    return load_script("results_recount")


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
    assert not (read["arm"]["at_most"] or read["ratio"]["at_most"] or read["reference"]["at_most"])


def test_the_deciding_budgets_are_the_two_either_side_of_the_labels_to_the_target(study):
    assert study.deciding_budgets(LADDER, 2**4.5) == [16, 32]
    assert study.deciding_budgets(LADDER, 32.0) == [16, 32]  # reached exactly at a rung: it and the one below
    assert study.deciding_budgets(LADDER, 8.0) == [8, 16]  # at the lowest budget: the lowest two
    assert study.deciding_budgets(LADDER, math.inf) == []  # not within the ladder: its part (4) decides


def test_an_arm_at_the_target_from_the_lowest_budget_reads_at_most_that_many_labels(study):
    rng = np.random.default_rng(2)
    pebble, early = [10, 40, 70, 90, 100], [100, 100, 100, 100, 100]
    read = study.bootstrap_labels(LADDER, seeds_along(pebble, rng), seeds_along(early, rng), floor=0.0, reps=500)
    assert read["arm"]["labels"] == LADDER[0] and read["arm"]["at_most"] and read["ratio"]["at_most"]
    assert study.number_text(read["ratio"]["value"], read["ratio"]["at_most"]).startswith("≤ 0.")
    backwards = study.bootstrap_labels(LADDER, seeds_along(early, rng), seeds_along(pebble, rng), floor=0.0, reps=500)
    assert backwards["reference"]["at_most"] and math.isnan(backwards["ratio"]["value"])  # PEBBLE's own is a bound
    assert study.number_text(backwards["ratio"]["value"]) == "—"


def test_the_screen_rule_takes_a_plateau_and_refuses_a_curve_still_rising(screen):
    plateau = np.array([0, 300, 600, 800, 900, 920, 910, 915, 905])
    rising = np.linspace(0, 900, 9)
    assert screen.plateau_gap(plateau) <= screen.PLATEAU_GAP
    assert screen.plateau_gap(rising) > screen.PLATEAU_GAP
    negative = np.array([-1400, -900, -300, -160, -150, -155, -152, -149, -151])  # Pendulum's returns are negative
    assert screen.plateau_gap(negative) <= screen.PLATEAU_GAP


def test_the_screen_selects_the_cheapest_qualifying_tasks_with_one_from_dm_control(screen):
    def entry(minutes: float, qualifies: bool, dmc: bool) -> dict:
        return {"seeds": 3, "planned": 3, "minutes": {"median": minutes}, "qualifies": qualifies, "dm_control": dmc}

    tasks = {
        "Pendulum-v1": entry(5, True, False),
        "Reacher-v5": entry(10, True, False),
        "InvertedDoublePendulum-v5": entry(12, True, False),
        "cartpole-swingup": entry(14, True, True),
        "reacher-easy": entry(13, False, True),
        "point_mass-easy": entry(20, True, True),
    }
    selection = screen.select(tasks)
    assert selection["studied"] == ["Pendulum-v1", "Reacher-v5", "cartpole-swingup"]
    assert selection["held_out"] == ["InvertedDoublePendulum-v5"]
    tasks["Reacher-v5"]["seeds"] = 2
    assert screen.select(tasks)["studied"] is None  # no selection before every seed is in


def write_ladder_run(out, algo: str, seed: int, budget: int | None, primary: float, tag: str = "") -> None:
    """A finished run as benchmarks/run.py leaves it, whose last three evaluations average ``primary``."""
    name = f"{algo}_Pendulum-v1_s{seed}" + ("" if budget is None else f"_fb{budget}") + ("_u0.25" if algo == "pride" else "")
    name += tag
    folder = out / name
    folder.mkdir(parents=True)
    settings = {"algo": algo, "task": "Pendulum-v1", "seed": seed, "feedback": budget, "ratio": None, "tag": ""}
    (folder / "settings.json").write_text(json.dumps(settings))
    rows = "".join(f"{step},{primary},\n" for step in (5000, 10000, 15000))
    (folder / "curve.csv").write_text("step,true_return,success\n" + rows)
    (folder / "result.json").write_text(json.dumps({"final_return": primary, "feedback_asked": budget}))


def test_ladders_read_shares_labels_to_the_target_and_the_ratio_from_run_folders(study, tmp_path, monkeypatch):
    """A ladder grid's runs: PEBBLE reaching the ceiling at 64 labels, an arm one rung earlier (half the labels): the
    page shows each point's share of SAC's return, each arm's labels to the target and the ratio near 0.5."""
    out = tmp_path / "runs"
    pebble, early = [100, 400, 700, 900, 1000], [400, 700, 900, 1000, 1000]
    for seed in range(4):
        write_ladder_run(out, "sac", seed, None, 1000 + seed)
        for budget, a, b in zip(LADDER, pebble, early, strict=True):
            write_ladder_run(out, "pebble", seed, budget, a + 5 * seed)
            write_ladder_run(out, "pride", seed, budget, b + 5 * seed)
        for budget, value in ((8, 200), (128, 950)):  # SAC from scratch on the final r̂ of PEBBLE's runs at 8 and 128
            write_ladder_run(out, "sac", seed, None, value, tag=f"_on_pebble_fb{budget}_reward")
            write_ladder_run(out, "pebble", seed, budget, value, tag="_like_pride")  # an arm at two budgets only
    grid = tmp_path / "ladder.yml"
    grid.write_text(
        f"tier: label-response\nout: {out}\nladder: true\nruns:\n"
        f"  - {{configurations: [pebble, pride], tasks: [Pendulum-v1], seeds: 0-3, feedback: {LADDER}}}\n"
        "  - {configurations: [sac], tasks: [Pendulum-v1], seeds: 0-3}\n"
        "  - {configurations: [sac_on_pebble_reward, pebble_like_pride], tasks: [Pendulum-v1], seeds: 0-3,"
        " feedback: [8, 128]}\n"
    )
    assert study.ladder_grids([grid, tmp_path / "other.yml"][:1]) == [grid]
    monkeypatch.setattr(study, "floor_of", lambda task: 0.0)
    data = json.loads(json.dumps(study.read_ladders([grid])))  # as results.json keeps it
    walker = data["tasks"]["Pendulum-v1"]
    assert walker["ceiling"] == pytest.approx(1001.5) and walker["ceiling_seeds"] == 4  # r̂'s own SAC runs are not it
    assert walker["runs"] == [4 * (1 + 2 * len(LADDER) + 2 + 2)] * 2
    assert len(walker["arms"]["pebble_like_pride"]) == 2 and "pebble_like_pride" not in walker["labels"]  # no curve
    on_final = {point["labels"]: point["share"][0] for point in walker["on_final_reward"]["sac_on_pebble_reward"]}
    assert on_final == {8: pytest.approx(200 / 1001.5, abs=1e-4), 128: pytest.approx(950 / 1001.5, abs=1e-4)}
    first = walker["arms"]["pebble"][0]
    assert (first["labels"], first["seeds"], first["corr"]) == (8, 4, None)
    share, low, high = first["share"]
    assert share == pytest.approx((100 + 7.5) / 1001.5, abs=1e-4) and low < share < high
    assert walker["labels"]["pride"]["ratio"]["value"] == pytest.approx(0.5, abs=0.1)
    assert walker["labels"]["pebble"]["ratio"]["value"] == pytest.approx(1.0)
    table = study.render_labels_table(data)
    assert "| Pendulum-v1 | pride |" in table and "÷ pebble" in table
    short = study.render_labels_summary(data)  # the README's: a row per task, every arm's labels, the ratios beside
    assert "| task | PEBBLE(): labels [95% CI] | PRIDE(): labels; ÷ PEBBLE() |" in short
    assert short.count("| Pendulum-v1 | ") == 1 and "| Pendulum-v1 | 64 [" in short and "; 0.50 [" in short
    assert "| pride | 8 | 4 |" in study.render_ladders(data)
    assert walker["labels"]["pride"]["deciding"] == [16, 32] and "pride 16, 32" in study.render_ladders(data)
    assert "| pebble | 128 | 4 | 1.01 [1.00, 1.01] | — | 0.95 [0.95, 0.95] (4 seeds) |" in study.render_ladders(data)
    study.draw_ladders(data, tmp_path / "figure.png")
    assert (tmp_path / "figure.png").stat().st_size > 0
    assert walker["held_out"] is False
    monkeypatch.setattr(study, "held_out_tasks", lambda: ["Pendulum-v1"])  # the screen's selection held it out
    assert "| Pendulum-v1 (held out) | pride |" in study.render_labels_table(study.read_ladders([grid]))
    monkeypatch.setattr(study, "held_out_tasks", lambda: [])
    (out / "pride_Pendulum-v1_s3_fb128_u0.25" / "result.json").unlink()  # a ladder not all in is not read as one
    partial = study.render_labels_table(study.read_ladders([grid]))
    assert "Pendulum-v1 (59 of 60 runs in: not a reading yet)" in partial
    page = load_script("results_page")
    block = page.labels_block(data, page.ROOT / "benchmarks" / "results")
    assert "(../../docs/_generated/label_response.png)" in block  # the figure, linked from the results README
    assert "| pride |" in block and "| pride |" not in page.labels_block(data, page.ROOT, short=True)
    assert page.labels_block({"tasks": {}}, page.ROOT).endswith("No label-response ladder has all its runs in yet.\n")


def test_a_task_screened_again_is_read_by_its_longer_look_and_a_short_selection_says_so(screen):
    def entry(gap: float, steps: int) -> dict:
        qualifies = gap <= screen.PLATEAU_GAP
        minutes = {"median": 10.0, "max": 12.0}
        return {
            "seeds": 3,
            "planned": 3,
            "steps": steps,
            "first": 0.0,
            "best": 1.0,
            "last_third": 1 - gap,
            "plateau_gap": gap,
            "minutes": minutes,
            "qualifies": qualifies,
            "dm_control": True,
        }

    first = {"cartpole-swingup": entry(0.08, 50000), "reacher-easy": entry(0.4, 50000), "point_mass-easy": entry(0.0, 50000)}
    data = {"tasks": first, "selection": screen.select(first)}
    assert "reacher-easy: screened again at 100k steps" in screen.render_screen(data)
    assert "cartpole-swingup, reacher-easy" in screen.render_screen(data)
    again = {**first, "cartpole-swingup": {**entry(0.02, 100000), "earlier": [first["cartpole-swingup"]]}}
    data = {"tasks": again, "selection": screen.select(again)}
    text = screen.render_screen(data)
    assert "| cartpole-swingup | 3 of 3 | 50000 |" in text and "| cartpole-swingup | 3 of 3 | 100000 |" in text
    assert set(data["selection"]["studied"]) == {"point_mass-easy", "cartpole-swingup"}
    assert "reacher-easy: screened again" in text
    both = {**again, "reacher-easy": {**entry(0.3, 100000), "earlier": [first["reacher-easy"]], "look": 1}}
    assert "new candidates are screened next" in screen.render_screen({"tasks": both, "selection": screen.select(both)})
    third = {**both, "walker-stand": {**entry(0.3, 50000), "look": 2}}  # a new candidate that fails gets no longer look
    text = screen.render_screen({"tasks": third, "selection": screen.select(third)})
    assert "walker-stand: screened again" not in text and "new candidates in a third look; the selection" in text
    assert screen.needs_another_look(third) and not screen.needs_another_look(
        {**third, "walker-stand": {"seeds": 1, "planned": 3}}
    )
    enough = {**third, "walker-stand": {**entry(0.01, 50000), "look": 2}, "hopper-stand": {**entry(0.01, 50000), "look": 2}}
    assert not screen.needs_another_look(enough)  # four qualify, one from dm_control: no further look runs


def test_a_ladder_names_its_arms_where_its_configurations_labels_differ(study):
    arms = {"pebble": "pebble_steps30k", "pride": "pride_steps30k"}
    assert study.arm_of("pebble_steps30k", arms) == "pebble" and study.arm_of("pride_steps30k", arms) == "pride"
    assert study.arm_of("sac_on_pebble_steps30k_reward", arms) == "sac_on_pebble_reward"
    assert study.arm_of("pebble_like_pride", {}) == "pebble_like_pride"  # ladder: true keeps the labels


def test_the_held_out_task_is_the_one_the_written_selection_names(screen, tmp_path):
    page = tmp_path / "label_response_screen.md"
    assert screen.held_out_tasks(page) == []  # no selection written yet
    page.with_suffix(".json").write_text(json.dumps({"selection": {"studied": None, "held_out": None}}))
    assert screen.held_out_tasks(page) == []  # every seed not in yet
    page.with_suffix(".json").write_text(json.dumps({"selection": {"studied": ["a"], "held_out": ["cartpole-swingup"]}}))
    assert screen.held_out_tasks(page) == ["cartpole-swingup"]
    assert screen.no_ladder_text(page).startswith("The screen selected a, with cartpole-swingup held out. No label")
    assert screen.no_ladder_text(tmp_path / "missing.md") == screen.NO_LADDER


def test_a_run_on_code_older_than_its_rule_is_named(recount, screen, study, tmp_path):
    """Every run of the study's grids recorded a commit that holds its grid file's rule (the commit that first added
    the file); a run that recorded the commit before the rule was written is named."""
    shallow = subprocess.run(["git", "rev-parse", "--is-shallow-repository"], capture_output=True, text=True).stdout
    if shallow.strip() != "false":
        pytest.skip("the rule's commit needs the repository's whole history")
    late, read = recount.runs_before_their_rule(study.study_grids())
    assert late == [] and read > 0
    rule = recount.rule_commit(screen.SCREEN)
    before = subprocess.run(["git", "rev-parse", f"{rule}^"], capture_output=True, text=True, check=True).stdout.strip()
    for seed, commit in ((0, before), (1, rule)):
        folder = tmp_path / f"sac_Pendulum-v1_s{seed}"
        folder.mkdir()
        (folder / "settings.json").write_text(json.dumps({"version": {"commit": commit}}))
    assert recount.runs_before_their_rule([screen.SCREEN], tmp_path) == (["sac_Pendulum-v1_s0"], 2)
