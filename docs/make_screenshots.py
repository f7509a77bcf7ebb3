"""
Screenshots of the WebTeacher's page, taken by headless Chromium mid-play during real PEBBLE runs: one person's page
on walker-walk and button-press, and an annotator's page with the team's progress and the task's instructions.

    MUJOCO_GL=egl python docs/make_screenshots.py        # writes docs/web_teacher_<task>.png and docs/web_teacher_team.png
"""

import os
import threading
import time
from pathlib import Path

os.environ.setdefault("MUJOCO_GL", "egl")

from selenium import webdriver
from selenium.webdriver.chrome.service import Service

from sb3_pride import PEBBLE, WebTeacher

CHROMIUM, CHROMEDRIVER = "/usr/bin/chromium", "/usr/bin/chromedriver"
TINY = dict(
    learning_starts=100, unsupervised_steps=100, feedback_interval=10**6, max_feedback=4, queries_per_session=4,
    segment_length=50, batch_size=64, reward_kwargs=dict(net_arch=(32, 32), epochs=5),
    pretraining_kwargs=dict(critic_reset_updates=5), policy_kwargs=dict(net_arch=[32, 32]),
)  # fmt: skip


def page_state(teacher: WebTeacher, name: str | None = None) -> dict:
    """What ``name``'s page shows, asked as the page asks it."""
    headers = {} if name is None else {"X-Annotator-Token": teacher.links[name].split("token=")[1]}
    return teacher.server.app.test_client().get("/api/state", headers=headers).get_json()


def answer(teacher: WebTeacher, question: str, label: float, name: str | None = None) -> None:
    """``name``'s answer, sent as the page sends it."""
    headers = {} if name is None else {"X-Annotator-Token": teacher.links[name].split("token=")[1]}
    teacher.server.app.test_client().post("/api/answer", json={"id": question, "label": label}, headers=headers)


#: the question the page shows, once its clips play (None before)
PLAYING = (
    "const v = document.getElementById('left');"
    "return !document.getElementById('labeling').classList.contains('hidden') && v.readyState >= 2 && v.currentTime > 0.6"
    " ? document.body.dataset.query : null;"
)


def chromium(height: int = 800) -> webdriver.Chrome:
    options = webdriver.ChromeOptions()
    options.binary_location = CHROMIUM
    for argument in (
        "--headless=new",
        "--no-sandbox",
        f"--window-size=1100,{height}",
        "--autoplay-policy=no-user-gesture-required",
    ):
        options.add_argument(argument)
    return webdriver.Chrome(service=Service(CHROMEDRIVER), options=options)


def wait_until_playing(driver: webdriver.Chrome, after: str | None = None) -> str:
    """The question the page plays, once it plays one (other than ``after``)."""
    deadline = time.monotonic() + 300
    while (shown := driver.execute_script(PLAYING)) in (None, after):
        assert time.monotonic() < deadline, "the page never played a clip"
        time.sleep(0.1)
    return shown


def answer_the_rest(teacher: WebTeacher, training: threading.Thread, names: list[str | None]) -> None:
    """Let the run finish: every question left is answered 'equally good' through the page's API."""
    while training.is_alive():
        for name in names:
            query = page_state(teacher, name)["query"]
            if query is not None:
                answer(teacher, query["id"], 0.5, name)
        time.sleep(0.1)


def screenshot(env_id: str, path: Path) -> None:
    teacher = WebTeacher(port=0)
    model = PEBBLE("MlpPolicy", env_id, teacher=teacher, seed=0, **TINY)
    training = threading.Thread(target=model.learn, args=(300,), daemon=True)
    training.start()
    driver = chromium()
    try:
        driver.get(teacher.url)
        first = wait_until_playing(driver)
        driver.find_element("tag name", "body").send_keys("\ue012")  # ArrowLeft: the first answer, shown in the progress
        wait_until_playing(driver, after=first)
        driver.save_screenshot(str(path))
        print(f"wrote {path}")
    finally:
        driver.quit()
    answer_the_rest(teacher, training, [None])
    training.join(timeout=120)
    teacher.close()


def team_screenshot(env_id: str, path: Path) -> None:
    """
    ana's page while ben and cleo answer through the teacher's API: each query is answered by two of them, and a
    share of their questions are known-answer ones; the table compares them.
    """
    names = ["ana", "ben", "cleo"]
    teacher = WebTeacher(port=0, annotators=names, answers_per_query=2, known_answer_rate=0.3, seed=0)
    settings = dict(TINY, max_feedback=10, queries_per_session=10)
    model = PEBBLE("MlpPolicy", env_id, teacher=teacher, seed=0, **settings)
    training = threading.Thread(target=model.learn, args=(300,), daemon=True)
    training.start()
    driver = chromium(height=940)
    try:
        driver.get(teacher.links["ana"])
        shown = wait_until_playing(driver)
        while page_state(teacher)["waiting"].startswith("rendering"):  # every pair's clips, so that all three have questions
            time.sleep(0.2)
        for key, labels in (("\ue012", (0, 1)), ("\ue014", (1, 1)), ("\ue012", (1, 0))):  # ArrowLeft, ArrowRight, ArrowLeft
            driver.find_element("tag name", "body").send_keys(key)
            for label, name in zip(labels, ("ben", "cleo"), strict=True):
                query = page_state(teacher, name)["query"]
                if query is not None:
                    answer(teacher, query["id"], label, name)
            shown = wait_until_playing(driver, after=shown)
        time.sleep(1.5)  # a poll of the page: the team's latest numbers
        driver.save_screenshot(str(path))
        print(f"wrote {path}")
    finally:
        driver.quit()
    answer_the_rest(teacher, training, names)
    training.join(timeout=120)
    teacher.close()


if __name__ == "__main__":
    folder = Path(__file__).parent
    screenshot("sb3_pride/walker-walk-v0", folder / "web_teacher_walker-walk.png")
    screenshot("sb3_pride/button-press-v3", folder / "web_teacher_button-press.png")
    team_screenshot("sb3_pride/walker-walk-v0", folder / "web_teacher_team.png")
