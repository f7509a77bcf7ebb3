"""WebTeacher's curve of corr(r̂, r) per feedback session: the reward history in the page's state (through the Flask
app's test client) and as headless Chromium draws it, for a sound reward model and a deliberately wrong one (r̂ = -r),
both measured on the true rewards of a real Pendulum-v1 rollout."""

import json
import math
import re
from collections.abc import Callable

import gymnasium as gym
import numpy as np
import pytest
from test_web import FakeBuffer, FakeEnv, black_clip_teachers, request, wait
from test_web_browser import chromium

from sb3_pride.human import WebTeacher
from tests.test_web import page_state

pytest.importorskip("flask")

#: a learned reward: r̂ of the transitions whose true rewards are ``r``
Learned = Callable[[np.ndarray, np.random.Generator], np.ndarray]


def sound(r: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """A reward model that learned the task: r plus a little noise."""
    return r + rng.normal(scale=0.1 * r.std(), size=r.shape)


def wrong(r: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """A reward model that learned the task backwards: r̂ = -r."""
    return -r


def pendulum_rewards(steps: int = 300, seed: int = 0) -> np.ndarray:
    """The true rewards of a real Pendulum-v1 rollout with random actions."""
    env = gym.make("Pendulum-v1")
    env.reset(seed=seed)
    env.action_space.seed(seed)
    rewards = []
    for _ in range(steps):
        _, reward, terminated, truncated, _ = env.step(env.action_space.sample())
        rewards.append(float(reward))
        if terminated or truncated:
            env.reset()
    env.close()
    return np.array(rewards)


def reward_history(learned: Learned, sessions: int = 3, queries: int = 40, seed: int = 0) -> list[dict]:
    """
    What PEBBLE gives a teacher after ``sessions`` reward updates of ``learned``: per session, corr(r̂, r) and the
    share of transition pairs r̂ ranks as r does, on the rollout's transitions stored by then. NumPy numbers, as a
    learner may report them.
    """
    r = pendulum_rewards(seed=seed)
    rng = np.random.default_rng(seed)
    history = []
    for session in range(1, sessions + 1):
        stored = r[: len(r) * session // sessions]
        predicted = learned(stored, rng)
        first, second = rng.integers(len(stored), size=(2, 200))
        accuracy = np.mean(np.sign(predicted[first] - predicted[second]) == np.sign(stored[first] - stored[second]))
        history.append(
            dict(
                session=np.int64(session),
                step=len(stored),
                labels=queries * session,
                accuracy=accuracy,
                correlation=np.corrcoef(predicted, stored)[0, 1],
            )
        )
    return history


def strict_state(teacher: WebTeacher) -> dict:
    """The page's state as the browser reads it, refused if it carries NaN or Infinity (which JSON has not)."""
    status, _, body = request(teacher, "/api/state")
    assert status == 200, body

    def refuse(constant: str) -> None:
        raise AssertionError(f"the state carries {constant}: {body!r}")

    return json.loads(body, parse_constant=refuse)


# through HTTP --------------------------------------------------------------------------------------------------------
def test_the_state_carries_the_reward_history_nan_as_null(tmp_path):
    with black_clip_teachers(tmp_path / "clips") as make:
        teacher = make()
        assert strict_state(teacher)["reward_history"] == []  # no reward update yet: the page shows no curve
        history = reward_history(sound)
        history.append(dict(session=4, step=300, labels=160, accuracy=float("nan"), correlation=np.float32("nan")))
        teacher.show_reward_history(history)
        shown = strict_state(teacher)["reward_history"]
        assert [entry["session"] for entry in shown] == [1, 2, 3, 4]
        assert [entry["labels"] for entry in shown] == [40, 80, 120, 160]
        np.testing.assert_allclose([entry["correlation"] for entry in shown[:3]], [e["correlation"] for e in history[:3]])
        assert all(entry["correlation"] > 0.9 for entry in shown[:3])
        assert shown[3]["correlation"] is None and shown[3]["accuracy"] is None  # NaN arrives as null
        assert page_state(teacher)["reward_history"] == shown


def test_the_teacher_keeps_a_copy_of_the_history(tmp_path):
    with black_clip_teachers(tmp_path / "clips") as make:
        teacher = make(annotators=["ana"])
        history = reward_history(wrong)
        teacher.show_reward_history(history)
        before = page_state(teacher, "ana")["reward_history"]
        history[0]["correlation"] = 0.5  # the caller's list changes afterwards: the page does not
        history.append(dict(session=4, step=300, labels=160, accuracy=1.0, correlation=1.0))
        page_state(teacher, "ana")["reward_history"][0]["labels"] = -1  # nor does a state that was handed out
        headers = {"X-Annotator-Token": teacher.links["ana"].split("token=")[1]}
        status, _, body = request(teacher, "/api/state", headers=headers)
        assert status == 200 and json.loads(body)["reward_history"] == before
        assert len(before) == 3 and all(math.isclose(entry["correlation"], -1.0) for entry in before)


# in a real browser ---------------------------------------------------------------------------------------------------
@pytest.mark.browser
def test_the_page_draws_corr_of_r_hat_with_r_for_a_sound_and_a_wrong_reward_model(tmp_path):
    """The curve and its text say which way r̂ goes: above the zero line for a sound model, below it for r̂ = -r."""
    with black_clip_teachers(tmp_path / "clips") as make:
        teacher = make()
        teacher.attach(FakeEnv(), FakeBuffer())  # serves on a free port of this machine
        driver = chromium()
        try:
            driver.get(teacher.url)
            for learned, sign in ((sound, 1), (wrong, -1)):
                history = reward_history(learned)
                teacher.show_reward_history(history)
                expected = f"{history[-1]['correlation']:.2f}"
                wait(lambda e=expected: driver.find_element("id", "reward-corr").text == e, timeout=20)
                assert driver.find_element("id", "reward-curve").is_displayed()
                summary = driver.find_element("id", "reward-summary").text
                assert re.fullmatch(r"corr\(r̂, r\) = -?\d\.\d\d after 3 sessions \(120 labels\)", summary), summary
                assert expected.startswith("-") == (sign < 0)
                zero = float(driver.find_element("id", "reward-zero").get_attribute("y1"))
                points = driver.find_elements("css selector", "#reward-curve .reward-point")
                last = driver.find_element("id", "reward-last")
                assert len(points) == 3 and points[-1] == last
                # SVG's y grows downwards: below the zero line is a larger y
                assert sign * (zero - float(last.get_attribute("cy"))) > 0, (learned.__name__, zero, last.get_attribute("cy"))
            # an update whose correlation is undefined (NaN): "n/a", and no point for it
            teacher.show_reward_history([*history, dict(session=4, step=300, labels=160, accuracy=0.5, correlation=math.nan)])
            wait(lambda: driver.find_element("id", "reward-corr").text == "n/a", timeout=20)
            assert driver.find_element("id", "reward-summary").text == "corr(r̂, r) = n/a after 4 sessions (160 labels)"
            assert len(driver.find_elements("css selector", "#reward-curve .reward-point")) == 3
            assert not driver.find_elements("id", "reward-last")
        finally:
            driver.quit()
