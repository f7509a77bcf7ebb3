"""WebTeacher: the HTTP boundary, and a person's keys in real headless Chromium during a PEBBLE run."""

import json
import os
import socket
import threading
import time
import urllib.error
import urllib.request

import numpy as np
import pytest
from conftest import skip_unless

from sb3_pride import PEBBLE
from sb3_pride.common.journal import PreferenceJournal
from sb3_pride.human.web import WebTeacher, _Query, _Session

pytest.importorskip("flask")
CHROMIUM, CHROMEDRIVER = "/usr/bin/chromium", "/usr/bin/chromedriver"


def request(url: str, body: dict | None = None, headers: dict | None = None) -> tuple[int, dict, bytes]:
    data = None if body is None else json.dumps(body).encode()
    req = urllib.request.Request(url, data=data, headers={"Content-Type": "application/json", **(headers or {})})
    try:
        with urllib.request.urlopen(req, timeout=10) as response:
            return response.status, dict(response.headers), response.read()
    except urllib.error.HTTPError as error:
        return error.code, dict(error.headers), error.read()


@pytest.fixture
def open_session(tiny_kwargs, tmp_path):
    """A WebTeacher serving one open session of two queries, answered into a real model's journal."""
    model = PEBBLE("MlpPolicy", "Pendulum-v1", preference_journal=tmp_path / "preferences.jsonl", **tiny_kwargs)
    teacher = WebTeacher(port=0, clip_dir=tmp_path / "clips")
    (tmp_path / "clips").mkdir()
    (tmp_path / "clips" / "a-left.mp4").write_bytes(bytes(range(256)) * 40)
    teacher._attached = True
    teacher._start_server()
    inputs = np.zeros((2, tiny_kwargs["segment_length"], 4), np.float32)
    clips = {name: (f"/clips/{name}-left.mp4", f"/clips/{name}-right.mp4") for name in "ab"}
    queries = [_Query(name, inputs + i, clips[name], ready=True) for i, name in enumerate("ab")]
    teacher._session = _Session(1, queries, 0, model.record_answers, model.retract_answer)
    teacher.model = model  # the journal's owner, for the assertions
    yield teacher
    teacher.close()


def test_bad_posts_are_refused_and_record_nothing(open_session):
    teacher = open_session
    for body in ({"id": "zzz", "label": 1}, {"id": "a", "label": 0.7}, {"id": "a", "label": "left"},
                 {"id": "a", "label": True}, {"id": "a"}, {"label": 1}):  # fmt: skip
        status, _, reply = request(teacher.url + "api/answer", body)
        assert status == 400 and json.loads(reply)["error"], body
    status, _, _ = request(teacher.url + "api/undo", {})
    assert status == 400  # nothing to undo yet
    assert teacher.state()["answered"] == 0 and teacher.model.journal_history() == []

    status, _, _ = request(teacher.url + "api/answer", {"id": "a", "label": 0.5})
    assert status == 200 and teacher.state()["answered"] == 1
    status, _, _ = request(teacher.url + "api/answer", {"id": "a", "label": 1})
    assert status == 400  # answered already
    assert [entry.label for entry in PreferenceJournal(teacher.model.preference_journal).read()] == [0.5]


def test_clips_are_served_with_range_requests(open_session):
    teacher = open_session
    status, headers, body = request(teacher.url + "clips/a-left.mp4", headers={"Range": "bytes=100-199"})
    assert status == 206 and headers["Content-Range"] == "bytes 100-199/10240" and body == (bytes(range(256)) * 40)[100:200]
    assert headers["Content-Type"] == "video/mp4" and headers.get("Accept-Ranges") == "bytes"
    status, _, _ = request(teacher.url + "clips/missing.mp4")
    assert status == 404


def test_a_port_in_use_is_named():
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        with pytest.raises(ValueError, match=f"port {port} on 127.0.0.1 is in use"):
            WebTeacher(port=port)._start_server()


def test_bad_settings_name_the_parameter():
    for kwargs, name in (({"port": 70000}, "port"), ({"timeout": 0}, "timeout"), ({"width": 8}, "width")):
        with pytest.raises(ValueError, match=name):
            WebTeacher(**kwargs)


def test_a_timeout_skips_the_rest(open_session, capsys):
    teacher = open_session
    teacher.timeout, session = 0.3, teacher._session
    teacher.answer("a", 1)
    assert teacher._wait_for_answers() is session and teacher._session is None
    assert session.queries[0].label == 1 and np.isnan(session.queries[1].label)
    assert len(teacher.model.journal_history()) == 2  # the skip is journaled too: the counts stay in step
    assert "timeout, 1 queries skipped" in capsys.readouterr().out


@pytest.mark.slow
@pytest.mark.browser
def test_a_person_labels_two_sessions_in_headless_chromium(tiny_kwargs, tmp_path):
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service
    from selenium.webdriver.common.keys import Keys

    from sb3_pride.human.render import egl_available

    skip_unless(os.path.exists(CHROMIUM) and os.path.exists(CHROMEDRIVER), "Debian's chromium and chromium-driver")
    skip_unless(egl_available(), "headless EGL (MUJOCO_GL=egl) to render the clips")
    journal = tmp_path / "preferences.jsonl"
    teacher = WebTeacher(port=0, width=96, height=64)
    tiny_kwargs.update(queries_per_session=3, max_feedback=6, feedback_interval=100, segment_length=10)
    model = PEBBLE("MlpPolicy", "sb3_pride/walker-walk-v0", teacher=teacher, preference_journal=journal, seed=0, **tiny_kwargs)
    errors: list[BaseException] = []
    training = threading.Thread(target=lambda: _learn(model, 500, errors), daemon=True)
    training.start()

    options = webdriver.ChromeOptions()
    options.binary_location = CHROMIUM  # Debian's browser and driver: Selenium downloads nothing
    for argument in ("--headless=new", "--no-sandbox", "--disable-gpu", "--autoplay-policy=no-user-gesture-required"):
        options.add_argument(argument)
    driver = webdriver.Chrome(service=Service(CHROMEDRIVER), options=options)
    try:
        driver.get(teacher.url)
        body = driver.find_element("tag name", "body")

        def press(key: str, answered: int, session: int) -> None:
            shown = _wait(lambda: _shown_query(driver, teacher, session))
            body.send_keys(key)
            _wait(lambda: (teacher.state()["answered"] == answered and teacher.state()["session"] == session)
                  or (answered == 3 and teacher.state()["session"] != session))  # fmt: skip
            assert shown is not None

        # feedback session 1: left, right, undo (takes the "right" back), equal, skip
        keys = ((Keys.ARROW_LEFT, 1), (Keys.ARROW_RIGHT, 2), (Keys.BACKSPACE, 1), (Keys.ARROW_DOWN, 2), ("s", 3))
        for key, answered in keys:
            press(key, answered, session=1)
        # feedback session 2, picked up without a reload: right, left, equal
        for key, answered in ((Keys.ARROW_RIGHT, 1), (Keys.ARROW_LEFT, 2), (Keys.ARROW_DOWN, 3)):
            press(key, answered, session=2)
    finally:
        driver.quit()
    training.join(timeout=120)
    teacher.close()
    assert not errors, errors
    assert model.feedback_sessions == 2 and model.feedback_asked == 6 and model.feedback_labeled == 5
    np.testing.assert_array_equal(model.preferences.labels, [0, 0.5, 1, 0, 0.5])
    labels = [entry.label for entry in PreferenceJournal(journal).read()]
    np.testing.assert_array_equal(labels, [0, 0.5, np.nan, 1, 0, 0.5])
    assert model.journal_entries == 6


def _learn(model: PEBBLE, steps: int, errors: list) -> None:
    try:
        model.learn(steps)
    except BaseException as error:  # reported by the test's main thread
        errors.append(error)


def _shown_query(driver, teacher: WebTeacher, session: int) -> str | None:
    """The query the page shows, once it is an open query of ``session`` and its left clip is playing."""
    state = teacher.state()
    if state["session"] != session:
        return None
    shown = driver.execute_script(
        "const v = document.getElementById('left');"
        "return v.readyState >= 2 && v.videoWidth > 0 ? document.body.dataset.query : null;"
    )
    open_ids = [query["id"] for query in state["queries"] if not query["answered"]]
    return shown if shown in open_ids[:1] else None


def _wait(condition, timeout: float = 60.0):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        value = condition()
        if value:
            return value
        time.sleep(0.05)
    raise AssertionError("timed out waiting for the page")


def test_while_answers_are_awaited_the_console_says_so_with_the_url(open_session, capsys):
    teacher = open_session
    teacher.reminder_interval, teacher.timeout = 0.1, 0.45
    teacher._wait_for_answers()  # nobody answers: the page was never opened
    reminders = [line for line in capsys.readouterr().out.splitlines() if "still waiting" in line]
    assert len(reminders) >= 3 and all(teacher.url in line and "page last seen: never" in line for line in reminders)


def test_answers_come_in_order_and_nothing_reaches_a_closed_session(open_session):
    teacher = open_session
    status, _, reply = request(teacher.url + "api/answer", {"id": "b", "label": 1})  # "a" comes first
    assert status == 400 and "in order" in json.loads(reply)["error"]
    teacher.answer("a", 0)
    teacher.answer("b", 1)
    session = teacher._wait_for_answers()  # all answered: the session closes
    assert [q.label for q in session.queries] == [0, 1] and teacher._session is None
    status, _, _ = request(teacher.url + "api/undo", {})  # a late Backspace
    assert status == 400
    assert [entry.label for entry in teacher.model.journal_history()] == [0, 1]


def test_clips_being_written_are_not_served(open_session):
    (open_session._clips_folder() / "a-left.mp4.part").write_bytes(b"half a clip")
    status, _, _ = request(open_session.url + "clips/a-left.mp4.part")
    assert status == 404
