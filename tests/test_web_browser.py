"""WebTeacher in real headless Chromium during PEBBLE runs: a person's keys over two feedback sessions, two annotators
labeling one session together in two browsers, and two annotators labeling envs that are not MuJoCo (Pendulum-v1 from
recorded frames, an env of this file from its render states) while the agent trains."""

import os
import threading
import time
from typing import ClassVar

import gymnasium as gym
import numpy as np
import pytest
from conftest import skip_unless
from test_web import label_or_skip, wait

from sb3_pride import PEBBLE
from sb3_pride.common.journal import PreferenceJournal, query_id
from sb3_pride.human import WebTeacher
from tests.test_web import page_state

pytest.importorskip("flask")
CHROMIUM, CHROMEDRIVER = "/usr/bin/chromium", "/usr/bin/chromedriver"


# in a real browser ---------------------------------------------------------------------------------------------------
def chromium():
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service

    skip_unless(os.path.exists(CHROMIUM) and os.path.exists(CHROMEDRIVER), "Debian's chromium and chromium-driver")
    options = webdriver.ChromeOptions()
    options.binary_location = CHROMIUM  # Debian's browser and driver: Selenium downloads nothing
    for argument in ("--headless=new", "--no-sandbox", "--disable-gpu", "--autoplay-policy=no-user-gesture-required"):
        options.add_argument(argument)
    return webdriver.Chrome(service=Service(CHROMEDRIVER), options=options)


@pytest.mark.slow
@pytest.mark.browser
def test_a_person_labels_two_sessions_in_headless_chromium(tiny_kwargs, tmp_path):
    from selenium.webdriver.common.keys import Keys

    from sb3_pride.human.render import egl_available

    skip_unless(egl_available(), "headless EGL (MUJOCO_GL=egl) to render the clips")
    journal = tmp_path / "preferences.jsonl"
    teacher = WebTeacher(port=0, width=96, height=64)
    tiny_kwargs.update(queries_per_session=3, max_feedback=6, feedback_interval=100, segment_length=10)
    model = PEBBLE("MlpPolicy", "sb3_pride/walker-walk-v0", teacher=teacher, preference_journal=journal, seed=0, **tiny_kwargs)
    errors: list[BaseException] = []
    training = threading.Thread(target=lambda: _learn(model, 500, errors), daemon=True)
    training.start()

    driver = chromium()
    try:
        driver.get(teacher.url)
        body = driver.find_element("tag name", "body")

        def press(key: str, answered: int, session: int) -> None:
            shown = wait(lambda: _shown_query(driver, teacher, session))
            body.send_keys(key)
            wait(lambda: (page_state(teacher)["answered"] == answered and page_state(teacher)["session"] == session)
                  or (answered == 3 and page_state(teacher)["session"] != session))  # fmt: skip
            assert shown is not None

        # feedback session 1: left, right, undo (takes the "right" back), equal, skip
        keys = ((Keys.ARROW_LEFT, 1), (Keys.ARROW_RIGHT, 2), (Keys.BACKSPACE, 1), (Keys.ARROW_DOWN, 2), ("s", 3))
        for key, answered in keys:
            press(key, answered, session=1)
        # feedback session 2, picked up without a reload: right, left, equal
        for key, answered in ((Keys.ARROW_RIGHT, 1), (Keys.ARROW_LEFT, 2), (Keys.ARROW_DOWN, 3)):
            press(key, answered, session=2)
        # r̂ learned from both sessions' labels: the page shows corr(r̂, r) after each
        summary = driver.find_element("id", "reward-summary")
        wait(lambda: summary.text.endswith("after 2 sessions (5 labels)"))
        assert driver.find_element("id", "reward-curve").is_displayed()
    finally:
        driver.quit()
    training.join(timeout=120)
    teacher.close()
    assert not errors, errors
    assert model.phase.sessions == 2 and model.phase.asked == 6 and model.phase.labeled == 5
    np.testing.assert_array_equal(model.preferences.labels, [0, 0.5, 1, 0, 0.5])
    labels = [entry.label for entry in PreferenceJournal(journal).read()]
    np.testing.assert_array_equal(labels, [0, 0.5, np.nan, 1, 0, 0.5])
    assert model.feedback.journal.included == 6  # every line of the journal is in the model's preferences
    shown = page_state(teacher)["reward_history"]
    assert [(entry["session"], entry["labels"]) for entry in shown] == [(1, 2), (2, 5)]


@pytest.mark.slow
@pytest.mark.browser
def test_two_annotators_label_one_session_together_in_headless_chromium(tiny_kwargs, tmp_path):
    """Two browsers, two links: each is shown its own queries, and each answer is journaled with who gave it."""
    from selenium.webdriver.common.keys import Keys

    from sb3_pride.human.render import egl_available

    skip_unless(egl_available(), "headless EGL (MUJOCO_GL=egl) to render the clips")
    journal = tmp_path / "preferences.jsonl"
    teacher = WebTeacher(port=0, width=96, height=64, annotators=["ana", "ben"], instructions="Prefer <b>upright</b> walkers.")
    tiny_kwargs.update(queries_per_session=4, max_feedback=4, feedback_interval=100, segment_length=10)
    model = PEBBLE("MlpPolicy", "sb3_pride/walker-walk-v0", teacher=teacher, preference_journal=journal, seed=0, **tiny_kwargs)
    errors: list[BaseException] = []
    training = threading.Thread(target=lambda: _learn(model, 300, errors), daemon=True)
    training.start()
    drivers = {}
    try:
        for name in ("ana", "ben"):
            drivers[name] = chromium()
            drivers[name].get(teacher.links[name])
        shown = {name: wait(lambda d=driver: _playing(d)) for name, driver in drivers.items()}
        assert shown["ana"] != shown["ben"]  # two people, two different queries
        instructions = drivers["ana"].find_element("id", "instructions")
        assert instructions.text == "Prefer <b>upright</b> walkers." and not instructions.find_elements("tag name", "b")
        # ana: left, then undo and right; ben: equal, skip; then whatever is left
        for name, key in (("ana", Keys.ARROW_LEFT), ("ben", Keys.ARROW_DOWN), ("ana", Keys.BACKSPACE),
                          ("ana", Keys.ARROW_RIGHT), ("ben", "s")):  # fmt: skip
            before = wait(lambda n=name: _playing(drivers[n]) or model.phase.sessions == 1)
            drivers[name].find_element("tag name", "body").send_keys(key)
            wait(lambda n=name, b=before: _playing(drivers[n]) != b or model.phase.sessions == 1)
        while training.is_alive() and model.phase.sessions == 0:
            for driver in drivers.values():
                if _playing(driver):
                    driver.find_element("tag name", "body").send_keys(Keys.ARROW_LEFT)
            time.sleep(0.3)
        team = drivers["ana"].find_element("id", "team").text
        assert "ana" in team and "ben" in team
    finally:
        for driver in drivers.values():
            driver.quit()
    training.join(timeout=120)
    teacher.close()
    assert not errors, errors
    assert model.phase.sessions == 1 and model.phase.asked == 4
    entries = PreferenceJournal(journal).read()
    assert len(entries) == 4 and len({entry.id for entry in entries}) == 4  # no query answered twice
    assert {entry.annotator for entry in entries} == {"ana", "ben"} and all(entry.time for entry in entries)
    by_annotator = {name: [label_or_skip(e) for e in entries if e.annotator == name] for name in ("ana", "ben")}
    assert by_annotator["ana"][0] == 1 and by_annotator["ben"][:2] == [0.5, "skip"]  # ana's undo took back her "left"


def draw_lamp(brightness: float) -> np.ndarray:
    """A 48 x 64 picture of the lamp: a lit square that grows with its brightness."""
    frame = np.zeros((48, 64, 3), dtype=np.uint8)
    half = 4 + int(18 * brightness)
    frame[24 - half : 24 + half, 32 - half : 32 + half] = (255, 220, int(255 * brightness))
    return frame


class Lamp(gym.Env):
    """A lamp whose brightness the action turns up or down (reward: brightness), drawn by ``draw_lamp``: a custom env
    that only renders, as most do, so a teacher records its frames as it plays."""

    metadata: ClassVar[dict] = {"render_modes": ["rgb_array"], "render_fps": 20}

    def __init__(self, render_mode: str | None = "rgb_array"):
        self.render_mode = render_mode
        self.observation_space = gym.spaces.Box(0.0, 1.0, (1,), np.float32)
        self.action_space = gym.spaces.Box(-1.0, 1.0, (1,), np.float32)
        self.brightness, self.steps = 0.5, 0

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        self.brightness, self.steps = float(self.np_random.uniform(0, 1)), 0
        return np.array([self.brightness], np.float32), {}

    def step(self, action):
        self.brightness = float(np.clip(self.brightness + 0.1 * float(action[0]), 0, 1))
        self.steps += 1
        return np.array([self.brightness], np.float32), self.brightness, False, self.steps >= 40, {}

    def render(self):
        return draw_lamp(self.brightness)


class StatefulLamp(Lamp):
    """The lamp with the render-state protocol (its brightness), so a teacher re-draws its frames exactly."""

    def get_render_state(self) -> np.ndarray:
        return np.array([self.brightness])

    def render_from_state(self, state: np.ndarray) -> np.ndarray:
        return draw_lamp(float(state[0]))


@pytest.mark.slow
@pytest.mark.browser
@pytest.mark.parametrize(
    ("make_env", "shown_from", "size"),
    [
        (lambda: "Pendulum-v1", "recorded_frames", (500, 500)),  # made by SB3 with render_mode="rgb_array"
        (lambda: StatefulLamp(), "render_states", (64, 48)),
        (lambda: Lamp(), "recorded_frames", (64, 48)),
    ],
    ids=["Pendulum-v1", "custom-env-render-states", "custom-env-recorded-frames"],
)
def test_two_annotators_label_an_env_that_is_not_mujoco_while_the_agent_trains(
    make_env, shown_from, size, tiny_kwargs, tmp_path
):
    """ana and ben each open their link; the agent goes on training while they answer (asynchronous feedback); ana
    prefers the left clip, ben the right one, through two feedback sessions: the journal holds exactly their answers."""
    from selenium.webdriver.common.keys import Keys

    journal = tmp_path / "preferences.jsonl"
    teacher = WebTeacher(port=0, annotators=["ana", "ben"], recording_dir=tmp_path / "frames")
    tiny_kwargs.update(queries_per_session=4, max_feedback=8, feedback_interval=100, segment_length=10)
    model = PEBBLE("MlpPolicy", make_env(), teacher=teacher, preference_journal=journal, asynchronous_feedback=True,
                   seed=0, **tiny_kwargs)  # fmt: skip
    assert teacher.shown_from == shown_from
    errors: list[BaseException] = []
    training = threading.Thread(target=lambda: _learn(model, 1500, errors), daemon=True)
    training.start()
    drivers, keys, pages_saw = {}, {"ana": Keys.ARROW_LEFT, "ben": Keys.ARROW_RIGHT}, set()
    try:
        for name in ("ana", "ben"):
            drivers[name] = chromium()
            drivers[name].get(teacher.links[name])
        while training.is_alive() and model.phase.sessions < 2:
            for name, driver in drivers.items():
                shown = _playing(driver)
                if shown:
                    pages_saw.add(tuple(driver.execute_script(
                        "const v = document.getElementById('left'); return [v.videoWidth, v.videoHeight];")))  # fmt: skip
                    driver.find_element("tag name", "body").send_keys(keys[name])
                    wait(lambda d=driver, s=shown: _playing(d) != s or model.phase.sessions >= 2 or not training.is_alive())
            time.sleep(0.1)
    finally:
        for driver in drivers.values():
            driver.quit()
    training.join(timeout=300)
    folder = teacher.recording_dir
    teacher.close()
    assert not errors, errors
    assert pages_saw == {size}  # the page played the env's own frames
    assert model.phase.sessions == 2 and model.phase.asked == 8
    entries = PreferenceJournal(journal).read()
    assert len(entries) == 8 and len({entry.id for entry in entries}) == 8  # each query answered once
    assert {entry.annotator for entry in entries} == {"ana", "ben"} and all(entry.time for entry in entries)
    assert all(entry.label == (0.0 if entry.annotator == "ana" else 1.0) for entry in entries)
    journaled = {entry.id: entry.label for entry in entries}
    labeled = zip(model.preferences.inputs, model.preferences.labels, strict=True)
    assert {query_id(inputs): label for inputs, label in labeled} == journaled
    assert model.feedback.journal.included == 8
    assert not folder.exists() or not any(folder.iterdir())  # recorded frames are removed with the teacher


def _playing(driver) -> str | None:
    """The question the page shows, once its left clip is playing."""
    return driver.execute_script(
        "const v = document.getElementById('left');"
        "return v.readyState >= 2 && v.videoWidth > 0 && !document.getElementById('labeling').classList.contains('hidden')"
        " ? document.body.dataset.query || null : null;"
    )


def _learn(model: PEBBLE, steps: int, errors: list) -> None:
    try:
        model.learn(steps)
    except BaseException as error:  # reported by the test's main thread
        errors.append(error)


def _shown_query(driver, teacher: WebTeacher, session: int) -> str | None:
    """The query the page shows, once it is the query handed to the person in ``session`` and its left clip is playing."""
    state = page_state(teacher)
    if state["session"] != session or state["query"] is None:
        return None
    shown = _playing(driver)
    return shown if shown == state["query"]["id"] else None
