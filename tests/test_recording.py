"""Envs that cannot be re-rendered from a MuJoCo state: shown from the frames they render, recorded while the agent
collects, or from their own render states (the render-state protocol). No GL needed: classic control draws with pygame."""

import os
import subprocess
import sys
from pathlib import Path
from typing import ClassVar

import gymnasium as gym
import numpy as np
import pytest
from stable_baselines3.common.vec_env import DummyVecEnv

from sb3_pride import PEBBLE
from sb3_pride.common.queries import sample_segment_pairs
from sb3_pride.human import FrameRecording, RecordRenders, WebTeacher, encode_mp4
from sb3_pride.human.recording import CHUNK_FRAMES, FOLDER_PREFIX, KEPT_EVICTED, RECORD
from sb3_pride.human.showing import RECORDED_FRAMES, RENDER_STATES

pytest.importorskip("pygame", reason="classic control renders with pygame (the [human] extra)")
pytestmark = pytest.mark.filterwarnings("ignore:the budget cannot be asked")  # runs too short for feedback, on purpose
NO_FEEDBACK = dict(learning_starts=50, unsupervised_steps=10**6, segment_length=10, batch_size=32,
                   policy_kwargs=dict(net_arch=[16]), train_freq=(50, "step"), gradient_steps=1)  # fmt: skip


class KeepFrames(gym.Wrapper):
    """Keeps every frame the env renders, in order: what a person must be shown."""

    def __init__(self, env: gym.Env):
        super().__init__(env)
        self.frames: list[np.ndarray] = []

    def render(self):
        frame = self.env.render()
        self.frames.append(np.array(frame))
        return frame


class Dot(gym.Env):
    """A dot pushed along a line toward the middle; drawn as a 40 x 60 picture. Steps of 0.1 s, 30-step episodes."""

    metadata: ClassVar[dict] = {"render_modes": ["rgb_array"], "render_fps": 10}

    def __init__(self, render_mode: str | None = None):
        self.render_mode = render_mode
        self.observation_space = gym.spaces.Box(-1.0, 1.0, (1,), np.float32)
        self.action_space = gym.spaces.Box(-1.0, 1.0, (1,), np.float32)
        self.position, self.steps = 0.0, 0

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        self.position, self.steps = float(self.np_random.uniform(-1, 1)), 0
        return np.array([self.position], np.float32), {}

    def step(self, action):
        self.position = float(np.clip(self.position + 0.2 * float(action[0]), -1, 1))
        self.steps += 1
        return np.array([self.position], np.float32), -abs(self.position), False, self.steps >= 30, {}

    def draw(self, position: float) -> np.ndarray:
        frame = np.full((40, 60, 3), 255, dtype=np.uint8)
        column = round((position + 1) / 2 * 55)
        frame[15:25, column : column + 5] = (200, 30, 30)
        return frame

    def render(self):
        return self.draw(self.position)


class DotWithRenderStates(Dot):
    """The same env with the render-state protocol: shown exactly from its recorded states, no frames recorded."""

    def get_render_state(self) -> np.ndarray:
        return np.array([self.position])

    def render_from_state(self, state: np.ndarray) -> np.ndarray:
        return self.draw(float(state[0]))


def frames_by_key(model: PEBBLE, frames: list[np.ndarray]) -> dict[tuple, np.ndarray]:
    """The frame the env rendered after each stored step (one env, no wrap-around), by the key stored beside it."""
    states = model.replay_buffer.render_states[: len(frames), 0]
    return {tuple(key): frame for key, frame in zip(states, frames, strict=True) if np.isfinite(key).all()}


def test_a_clip_of_recorded_frames_is_the_frames_pendulum_rendered_at_those_steps(tmp_path):
    env = KeepFrames(gym.make("Pendulum-v1", render_mode="rgb_array"))
    teacher = WebTeacher(port=0)
    model = PEBBLE("MlpPolicy", env, teacher=teacher, seed=0, **NO_FEEDBACK)
    assert teacher.shown_from == RECORDED_FRAMES and teacher.env_id == "Pendulum-v1"
    model.learn(300)
    rendered = frames_by_key(model, env.frames)
    assert len(env.frames) == 300 and len(rendered) == 300  # one frame per step, each kept (300 of 100 episodes' worth)
    pairs = sample_segment_pairs(model.replay_buffer, 8, 10, 100, np.random.default_rng(0))
    renderer = teacher.clips.renderer
    prepared = renderer.prepare(pairs.render_states)
    for pair, held in zip(pairs.render_states, prepared, strict=True):
        for keys, records in zip(pair, held, strict=True):
            expected = np.stack([rendered[tuple(key)] for key in keys])
            np.testing.assert_array_equal(renderer.render(keys), expected)  # lossless: pixel-identical
            np.testing.assert_array_equal(renderer.render(records), expected)
    # the check can fail: the frames of the next steps are not those
    keys, shifted = model.replay_buffer.render_states[20:30, 0], model.replay_buffer.render_states[21:31, 0]
    assert not np.array_equal(renderer.render(keys), np.stack([rendered[tuple(key)] for key in shifted]))
    # the clip the page plays is H.264 yuv420p: within a few levels of the frames on average
    av = pytest.importorskip("av")
    encode_mp4(renderer.render(keys), renderer.fps, tmp_path / "clip.mp4")
    with av.open(str(tmp_path / "clip.mp4")) as container:
        played = np.stack([frame.to_ndarray(format="rgb24") for frame in container.decode(video=0)])
    error = np.abs(played.astype(int) - np.stack([rendered[tuple(k)] for k in keys]).astype(int))
    assert played.shape == (10, 500, 500, 3) and error.mean() < 2.0 and renderer.fps == 20  # Pendulum: dt = 0.05 s
    teacher.close()


@pytest.mark.slow
def test_a_segment_crossing_the_windows_edge_is_never_offered():
    """The recording keeps 2 episodes; the sampler may draw from 100: no sampled segment holds a frame it dropped."""
    env = gym.make("Pendulum-v1", render_mode="rgb_array", max_episode_steps=25)
    teacher = WebTeacher(port=0, recorded_episodes=2)
    model = PEBBLE("MlpPolicy", env, teacher=teacher, seed=0, **NO_FEEDBACK)
    model.learn(240)  # 9.6 episodes
    buffer, recording = model.replay_buffer, teacher.clips.renderer.recording
    assert np.isnan(buffer.render_states[:200, 0]).all() and np.isfinite(buffer.render_states[200:240, 0]).all()
    with pytest.warns(UserWarning, match="recorded_episodes >= max_query_episodes"):  # said, not silently fewer
        pairs = sample_segment_pairs(buffer, 200, 10, 100, np.random.default_rng(0))
    assert pairs is not None
    episodes = set(pairs.render_states[..., 1].ravel())
    assert episodes == {8.0, 9.0}  # the last finished episode and the running one
    recording.frames(pairs.render_states.reshape(-1, 3))  # every frame is there
    teacher.close()


def test_the_byte_limit_evicts_the_oldest_frames_within_a_running_episode_and_they_are_never_offered():
    env = gym.make("Pendulum-v1", render_mode="rgb_array")  # 200-step episodes
    teacher = WebTeacher(port=0, recording_bytes=1 << 20)
    model = PEBBLE("MlpPolicy", env, teacher=teacher, seed=0, **NO_FEEDBACK)
    model.learn(400)
    recording = teacher.clips.renderer.recording
    largest = RECORD.size + 500 * 500 * 3 + 1000  # a frame's record, incompressible at worst
    assert 0 < recording.bytes <= 1 << 20
    assert recording.disk_bytes() <= (1 << 20) + (KEPT_EVICTED + 1) * CHUNK_FRAMES * largest
    kept = np.isfinite(model.replay_buffer.render_states[:400, 0, 0])
    assert 0 < kept.sum() < 400 and not kept[:100].any() and kept[-1]  # the oldest frames went first
    pairs = sample_segment_pairs(model.replay_buffer, 100, 10, 100, np.random.default_rng(1))
    recording.frames(pairs.render_states.reshape(-1, 3))
    teacher.close()


def test_recorded_frames_are_removed_when_the_teacher_is_closed_and_a_crashed_runs_by_the_next(tmp_path):
    crashed = subprocess.run(
        [sys.executable, "-c", "import os, numpy as np; from sb3_pride.human import FrameRecording; "
         f"r = FrameRecording(1, parent={str(tmp_path)!r}); r.add(0, np.zeros((8, 8, 3), np.uint8)); os._exit(1)"],
        check=False,
    )  # fmt: skip
    assert crashed.returncode == 1
    left = list(tmp_path.glob(f"{FOLDER_PREFIX}*"))
    assert len(left) == 1 and list(left[0].glob("*.frames"))  # a crash leaves its folder
    teacher = WebTeacher(port=0, recording_dir=tmp_path)
    PEBBLE("MlpPolicy", "Pendulum-v1", teacher=teacher, seed=0, **NO_FEEDBACK).learn(60)
    folder = teacher.clips.renderer.recording.folder
    assert list(tmp_path.glob(f"{FOLDER_PREFIX}*")) == [folder]  # the crashed run's folder was removed
    assert folder.name.startswith(f"{FOLDER_PREFIX}{os.getpid()}_") and list(folder.glob("*.frames"))
    teacher.close()
    assert not list(tmp_path.iterdir())


def test_a_resumed_buffers_frames_from_another_run_are_never_offered(tmp_path):
    first = WebTeacher(port=0)
    model = PEBBLE("MlpPolicy", "Pendulum-v1", teacher=first, seed=0, **NO_FEEDBACK)
    model.learn(100)
    model.save_replay_buffer(tmp_path / "buffer.pkl")
    first.close()  # its frames are gone (as after a crash)
    second = WebTeacher(port=0)
    resumed = PEBBLE("MlpPolicy", "Pendulum-v1", teacher=second, seed=1, **NO_FEEDBACK)
    resumed.load_replay_buffer(tmp_path / "buffer.pkl")
    assert np.isnan(resumed.replay_buffer.render_states[:100]).all()  # marked: never sampled for a person
    assert sample_segment_pairs(resumed.replay_buffer, 4, 10, 100, np.random.default_rng(0)) is None
    resumed.learn(60, reset_num_timesteps=False)
    pairs = sample_segment_pairs(resumed.replay_buffer, 4, 10, 100, np.random.default_rng(0))
    assert pairs is not None and second.clips.renderer.render(pairs.render_states[0, 0]).shape == (10, 500, 500, 3)
    second.close()


def test_an_env_with_the_render_state_protocol_is_shown_exactly_from_its_states_without_frames(tmp_path):
    env = KeepFrames(DotWithRenderStates(render_mode="rgb_array"))
    teacher = WebTeacher(port=0, recording_dir=tmp_path)
    model = PEBBLE("MlpPolicy", env, teacher=teacher, seed=0, **NO_FEEDBACK)
    assert teacher.shown_from == RENDER_STATES and teacher.env_id == "DotWithRenderStates"
    model.learn(90)
    assert not env.frames and not list(tmp_path.iterdir())  # nothing rendered, nothing recorded while collecting
    states = model.replay_buffer.render_states[:90, 0]
    np.testing.assert_allclose(states[:, 0], model.replay_buffer.next_observations[:90, 0, 0], rtol=1e-6)
    live = DotWithRenderStates()
    frames = teacher.clips.renderer.render(states)
    np.testing.assert_array_equal(frames, [live.draw(position) for position in states[:, 0]])
    assert teacher.clips.renderer.fps == 10 and teacher.clips.renderer.env is not env.unwrapped  # a copy of its own
    teacher.close()


def test_a_custom_env_without_the_protocol_is_shown_from_its_frames():
    env = KeepFrames(Dot(render_mode="rgb_array"))
    teacher = WebTeacher(port=0)
    model = PEBBLE("MlpPolicy", env, teacher=teacher, seed=0, **NO_FEEDBACK)
    assert teacher.shown_from == RECORDED_FRAMES and teacher.env_id == "Dot"
    model.learn(90)
    rendered = frames_by_key(model, env.frames)
    keys = model.replay_buffer.render_states[30:40, 0]
    np.testing.assert_array_equal(teacher.clips.renderer.render(keys), [rendered[tuple(key)] for key in keys])
    teacher.close()


@pytest.mark.parametrize(
    ("make", "shown"),
    [(lambda: gym.make("Pendulum-v1"), "Pendulum-v1"), (lambda: Dot(), "Dot")],
)
def test_an_env_that_renders_no_frames_is_refused_naming_the_render_mode_it_needs(make, shown):
    with pytest.raises(ValueError, match=rf"cannot show {shown}: it was made with render_mode=None.*render_mode='rgb_array'"):
        PEBBLE("MlpPolicy", make(), teacher=WebTeacher(port=0), segment_length=10)


def test_the_way_an_env_is_shown_is_printed_when_the_teacher_is_attached(capsys):
    teacher = WebTeacher(port=0, recorded_episodes=30)
    PEBBLE("MlpPolicy", "MountainCarContinuous-v0", teacher=teacher, segment_length=10)
    out = capsys.readouterr().out
    assert "WebTeacher: MountainCarContinuous-v0 is shown from the frames it renders" in out
    assert "each env's last 30 episodes, at most 1024 MiB" in out
    assert teacher.clips.renderer.fps == 30  # no dt: the env's metadata["render_fps"]
    teacher.close()


def test_a_recording_wrapper_is_put_once_around_each_env_of_the_dummy_vec_env():
    env = DummyVecEnv([lambda: gym.make("Pendulum-v1", render_mode="rgb_array")] * 1)
    teacher = WebTeacher(port=0)
    model = PEBBLE("MlpPolicy", env, teacher=teacher, seed=0, **NO_FEEDBACK)
    model.set_env(env)  # attached again: the same wrapper, the same recording
    assert isinstance(env.envs[0], RecordRenders) and not isinstance(env.envs[0].env, RecordRenders)
    assert env.envs[0].recording is teacher.clips.renderer.recording
    teacher.close()
    model.learn(60)  # a closed teacher's recording takes no more frames: their keys are NaN
    assert np.isnan(model.replay_buffer.render_states[:60]).all()


def test_envs_in_other_processes_are_refused_for_recording():
    from stable_baselines3.common.vec_env import SubprocVecEnv

    env = SubprocVecEnv([lambda: gym.make("Pendulum-v1", render_mode="rgb_array")], start_method="fork")
    try:
        with pytest.raises(ValueError, match="the model's env is a SubprocVecEnv: use a DummyVecEnv"):
            PEBBLE("MlpPolicy", env, teacher=WebTeacher(port=0), segment_length=10)
    finally:
        env.close()


@pytest.mark.parametrize(
    ("setting", "message"),
    [
        (dict(recorded_episodes=0), "recorded_episodes must be an integer >= 1"),
        (dict(recorded_episodes=2.5), "recorded_episodes must be an integer >= 1"),
        (dict(recording_bytes=1000), r"recording_bytes must be an integer >= 1048576 \(1 MiB\), got 1000"),
        (dict(recording_dir=""), "recording_dir must be a folder path"),
    ],
)
def test_recording_settings_are_checked(setting, message):
    with pytest.raises(ValueError, match=message):
        WebTeacher(port=0, **setting)


def test_a_recording_of_a_file_path_is_refused(tmp_path):
    (tmp_path / "file").write_text("")
    with pytest.raises(ValueError, match="recording_dir must be a folder path"):
        WebTeacher(port=0, recording_dir=tmp_path / "file")


def test_frames_recorded_directly_come_back_identical_and_the_disk_stays_bounded(tmp_path):
    rng = np.random.default_rng(0)
    recording = FrameRecording(1, episodes=3, max_bytes=1 << 20, parent=tmp_path)
    frames = rng.integers(0, 255, size=(300, 40, 30, 3), dtype=np.uint8)  # incompressible: the worst case
    keys = []
    for index, frame in enumerate(frames):
        if index % 100 == 0:
            recording.new_episode(0)
        keys.append(recording.add(0, frame))
        assert recording.bytes <= 1 << 20
    kept = list(np.flatnonzero(recording.in_window(np.array(keys))))
    assert kept and kept[-1] == 299 and kept[0] > 0  # a window of the newest frames
    np.testing.assert_array_equal(recording.frames(np.array([keys[i] for i in kept])), frames[kept])
    recording.close()
    assert not any(tmp_path.iterdir()) and np.isnan(recording.add(0, frames[0])).all()
    assert Path(tmp_path).exists()
