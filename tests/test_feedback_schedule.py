"""The label schedule: how a budget of queries is spread over a run's feedback sessions (``feedback_schedule``)."""

import warnings

import pytest
import torch as th
from stable_baselines3.common.callbacks import BaseCallback

from sb3_pride import PEBBLE
from sb3_pride.pebble.feedback import FeedbackSchedule


def test_each_schedule_sizes_its_sessions_as_b_pref_does():
    constant, shrinking, growing = (FeedbackSchedule(name, 50, 400) for name in ("constant", "shrinking", "growing"))
    assert [constant.size(i, step, 50_000) for i, step in ((1, 5000), (2, 10_000))] == [50, 50]
    # B-Pref's reward_schedule 1 and 2: int(K (T - t) / T) and int(K T / (T - t + 1))
    assert [shrinking.size(1, step, 50_000) for step in (5000, 25_000, 49_999, 50_000)] == [45, 25, 1, 1]
    assert [growing.size(1, step, 50_000) for step in (0, 25_000, 45_000)] == [49, 99, 499]
    listed = FeedbackSchedule([100, 30], 50, 400)
    assert [listed.size(i, 0, 50_000) for i in (1, 2, 3, 4)] == [100, 30, 50, 50]


def test_a_shrinking_schedule_spreads_half_the_labels_with_a_thinning_tail():
    """200 labels, K = 50 every 5k steps from 5k in a 50k-step run: asked until 35k instead of 20k."""
    plan = FeedbackSchedule("shrinking", 50, 200).plan(1, 5000, 5000, 50_000, 200)
    assert plan == [(5000, 45), (10_000, 40), (15_000, 35), (20_000, 30), (25_000, 25), (30_000, 20), (35_000, 5)]
    constant = FeedbackSchedule("constant", 50, 200).plan(1, 5000, 5000, 50_000, 200)
    assert constant[-1] == (20_000, 50) and sum(n for _, n in constant) == 200


def test_front_loaded_asks_half_the_budget_first_and_the_rest_in_four_sessions():
    """PRIDE's CPU tier, 200 labels every 5k steps from 5k: 100 at once, then four sessions of 25, whatever K is."""
    plan = FeedbackSchedule("front_loaded", 50, 200).plan(1, 5000, 5000, 50_000, 200)
    assert plan == [(5000, 100), (10_000, 25), (15_000, 25), (20_000, 25), (25_000, 25)]
    assert plan == FeedbackSchedule([100], 25, 200).plan(1, 5000, 5000, 50_000, 200)
    # any budget: half of it (rounded up) first, the rest in four sessions (rounded up, the last cut to the budget)
    assert [n for _, n in FeedbackSchedule("front_loaded", 50, 1200).plan(1, 0, 1, 10, 1200)] == [600, 150, 150, 150, 150]
    assert [n for _, n in FeedbackSchedule("front_loaded", 50, 101).plan(1, 0, 1, 10, 101)] == [51, 13, 13, 13, 11]
    assert [n for _, n in FeedbackSchedule("front_loaded", 50, 1).plan(1, 0, 1, 10, 1)] == [1]


@pytest.mark.slow
def test_front_loaded_trains_exactly_as_the_list_it_names(tiny_kwargs):
    """``"front_loaded"`` at a budget of 60 is the list [30, 8, 8, 8]: the same sessions, the same model."""
    models, sizes = [], []
    for schedule in ("front_loaded", [30, 8, 8, 8]):  # each made and trained in turn: SB3 seeds torch when a model is made
        sizes.append(SessionSizes())
        models.append(PEBBLE("MlpPolicy", "Pendulum-v1", seed=0, feedback_schedule=schedule, **tiny_kwargs))
        models[-1].learn(1600, callback=sizes[-1])
    named, listed = models
    assert sizes[0].sizes == sizes[1].sizes == [30, 8, 8, 8, 6]
    for a, b in zip(named.policy.parameters(), listed.policy.parameters(), strict=True):
        assert th.equal(a, b)
    assert named.preferences.labels.tolist() == listed.preferences.labels.tolist()


class SessionSizes(BaseCallback):
    """The queries each feedback session asked, read from the model's counters."""

    def __init__(self) -> None:
        super().__init__()
        self.sizes: list[int] = []
        self.asked = 0

    def _on_step(self) -> bool:
        if self.model.phase.asked != self.asked:
            self.sizes.append(self.model.phase.asked - self.asked)
            self.asked = self.model.phase.asked
        return True


@pytest.mark.slow
def test_a_run_asks_the_sessions_its_schedule_lists(tiny_kwargs):
    sizes = SessionSizes()
    model = PEBBLE("MlpPolicy", "Pendulum-v1", seed=0, feedback_schedule=[30, 20], **tiny_kwargs)  # budget 60, K 20
    model.learn(1000, callback=sizes)  # sessions at steps 300, 600, 900
    assert sizes.sizes == [30, 20, 10]  # the third is K = 20, cut to what remains of the budget
    assert model.phase.asked == model.max_feedback == 60


@pytest.mark.slow
def test_a_schedule_that_cannot_ask_the_budget_within_the_run_is_refused_before_training(tiny_kwargs, tmp_path):
    journal = tmp_path / "preferences.jsonl"
    model = PEBBLE(
        "MlpPolicy", "Pendulum-v1", seed=0, feedback_schedule="shrinking", preference_journal=journal, **tiny_kwargs
    )
    # a 1500-step run: sessions at 300, 600, 900, 1200 and 1500 (its last step) ask 16 + 12 + 8 + 4 + 1 = 41 of the 60
    with pytest.raises(
        ValueError, match=r"feedback_schedule='shrinking': the budget cannot be asked within the run: 60 .* ask 41"
    ):
        model.learn(1500)
    assert model.num_timesteps == 0 and model.phase.asked == 0 and not journal.exists()
    # long enough: sessions at 300, 600, 900 and 1200 ask 19 + 18 + 17 + 6 of a 6000-step run
    assert sum(n for _, n in FeedbackSchedule("shrinking", 20, 60).plan(1, 300, 300, 6000, 60)) == 60
    model.learn(1300, reset_num_timesteps=False)  # a run in parts is not checked: it asks as its schedule says
    assert model.phase.asked == 15 + 10 + 6 + 1  # int(20 (1300 - t) / 1300) at t = 300, 600, 900, 1200


@pytest.mark.slow
@pytest.mark.parametrize("schedule", ["constant", "front_loaded"])
def test_the_default_schedules_warn_when_the_run_ends_before_its_budget(tiny_kwargs, schedule):
    """PEBBLE's and PRIDE's defaults: a short run (a smoke test) asks what it can; front_loaded asks 30 + 8."""
    model = PEBBLE("MlpPolicy", "Pendulum-v1", seed=0, feedback_schedule=schedule, **tiny_kwargs)
    asked, then = (40, 60) if schedule == "constant" else (38, 46)
    with pytest.warns(UserWarning, match=f"the budget cannot be asked within the run: 60 .* ask {asked}"):
        model.learn(700)  # sessions at 300 and 600 only
    assert model.phase.asked == asked
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # a run in parts is not checked: its later parts may ask the rest
        model.learn(300, reset_num_timesteps=False)
    assert model.phase.asked == then  # the session at 900


@pytest.mark.parametrize("schedule", ["linear", [], [10, 0], [10, 2.5], [True], None])
def test_a_bad_schedule_is_refused_naming_it(tiny_kwargs, schedule):
    with pytest.raises(ValueError, match="feedback_schedule"):
        PEBBLE("MlpPolicy", "Pendulum-v1", feedback_schedule=schedule, **tiny_kwargs)


def test_the_schedule_is_saved_with_the_model(tiny_kwargs, tmp_path):
    model = PEBBLE("MlpPolicy", "Pendulum-v1", feedback_schedule=[30, 20], **tiny_kwargs)
    model.save(tmp_path / "model")
    loaded = PEBBLE.load(tmp_path / "model")
    assert list(loaded.feedback_schedule) == [30, 20]


def test_a_session_due_at_the_last_step_counts_as_asked_within_the_run(tiny_kwargs):
    """SB3 counts a step before the callbacks run, so a session due at the run's last step is asked: no warning."""
    model = PEBBLE("MlpPolicy", "Pendulum-v1", seed=0, **{**tiny_kwargs, "max_feedback": 40})
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        model.learn(600)  # sessions at 300 and 600
    assert model.phase.asked == 40


def test_a_refused_run_leaves_the_schedule_where_it_was(tiny_kwargs):
    model = PEBBLE("MlpPolicy", "Pendulum-v1", seed=0, feedback_schedule=[20], **tiny_kwargs)
    model.learn(350, reset_num_timesteps=False)  # the first session at 300: the next at 600
    assert model.phase.next_step == 600
    for _ in range(2):  # a whole run of 50 steps cannot ask the 40 that remain
        with pytest.raises(ValueError, match="feedback_schedule"):
            model.learn(50)
        assert model.phase.next_step == 600 and model.num_timesteps == 350


def test_the_schedule_and_the_selection_are_read_when_a_session_is_asked(tiny_kwargs):
    """Settings changed on a built model take effect at the next session, as SB3's own attributes do."""
    model = PEBBLE("MlpPolicy", "Pendulum-v1", seed=0, **tiny_kwargs)
    model.queries_per_session = 5
    model.learn(350, reset_num_timesteps=False)
    assert model.phase.asked == 5


@pytest.mark.parametrize("algo", ["pebble", "pride"])
def test_the_demo_asks_its_whole_budget_in_its_run(algo):
    """``python -m sb3_pride`` (20k steps): PEBBLE's constant schedule and PRIDE's front-loaded one ask every query."""
    from sb3_pride import PRIDE
    from sb3_pride.__main__ import demo_kwargs

    model = {"pebble": PEBBLE, "pride": PRIDE}[algo]("MlpPolicy", "Pendulum-v1", **demo_kwargs(algo, "Pendulum-v1"))
    schedule = FeedbackSchedule(model.feedback_schedule, model.queries_per_session, model.max_feedback)
    plan = schedule.plan(1, model.phase.next_step, model.feedback_interval, 20_000, model.max_feedback)
    assert sum(queries for _, queries in plan) == model.max_feedback
