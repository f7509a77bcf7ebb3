import ctypes.util
import os

# no display: dm_control must not try to open one. Headless EGL where Mesa's libEGL is installed (the WebTeacher's
# clips, rendering tests); MuJoCo reads MUJOCO_GL once, at its import
os.environ.setdefault("MUJOCO_GL", "egl" if ctypes.util.find_library("EGL") else "disable")

import pytest
import torch as th

th.set_num_threads(1)  # tiny networks: threads only add contention

#: a PEBBLE small enough for tests: tiny networks, short phases
TINY = dict(
    learning_starts=100,
    unsupervised_steps=200,
    feedback_interval=300,
    max_feedback=60,
    queries_per_session=20,
    segment_length=10,
    batch_size=64,
    reward_kwargs=dict(net_arch=(32, 32), epochs=20),
    pretraining_kwargs=dict(critic_reset_updates=10),
    policy_kwargs=dict(net_arch=[32, 32]),
)


def skip_unless(condition: bool, reason: str) -> None:
    """Skip where the machine lacks it (a browser, EGL), except in CI (.ci/run sets SB3_PRIDE_REQUIRE_BROWSER)."""
    if not condition:
        assert not os.environ.get("SB3_PRIDE_REQUIRE_BROWSER"), reason
        pytest.skip(reason)


@pytest.fixture
def tiny_kwargs():
    return dict(TINY)
