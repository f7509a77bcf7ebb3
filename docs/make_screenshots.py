"""
Screenshots of the WebTeacher's page, taken by headless Chromium mid-play during a real PEBBLE run.

    MUJOCO_GL=egl python docs/make_screenshots.py        # writes docs/web_teacher_<task>.png
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
    segment_length=50, batch_size=64, reward_net_arch=(32, 32), reward_epochs=5, critic_reset_updates=5,
    policy_kwargs=dict(net_arch=[32, 32]),
)  # fmt: skip


def screenshot(env_id: str, path: Path) -> None:
    teacher = WebTeacher(port=0)
    model = PEBBLE("MlpPolicy", env_id, teacher=teacher, seed=0, **TINY)
    training = threading.Thread(target=model.learn, args=(300,), daemon=True)
    training.start()
    options = webdriver.ChromeOptions()
    options.binary_location = CHROMIUM
    for argument in ("--headless=new", "--no-sandbox", "--window-size=1100,720", "--autoplay-policy=no-user-gesture-required"):
        options.add_argument(argument)
    driver = webdriver.Chrome(service=Service(CHROMEDRIVER), options=options)
    try:
        driver.get(teacher.url)
        deadline = time.monotonic() + 300
        playing = "const v = document.getElementById('left'); return v.readyState >= 2 && v.currentTime > 0.6;"
        while not driver.execute_script(playing):
            assert time.monotonic() < deadline, "the page never played a clip"
            time.sleep(0.1)
        driver.find_element("tag name", "body").send_keys("\ue012")  # ArrowLeft: the first answer, shown in the progress
        time.sleep(1.5)
        while not driver.execute_script(playing):
            time.sleep(0.1)
        driver.save_screenshot(str(path))
        print(f"wrote {path}")
        for query in teacher.state()["queries"]:  # let the run finish
            while not teacher.state()["queries"][[q["id"] for q in teacher.state()["queries"]].index(query["id"])]["ready"]:
                time.sleep(0.1)
            teacher.answer(query["id"], 0.5)
    finally:
        driver.quit()
    training.join(timeout=120)
    teacher.close()


if __name__ == "__main__":
    folder = Path(__file__).parent
    screenshot("sb3_pride/walker-walk-v0", folder / "web_teacher_walker-walk.png")
    screenshot("sb3_pride/button-press-v3", folder / "web_teacher_button-press.png")
