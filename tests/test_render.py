"""Segments that can be shown: recorded states, re-rendered pixel-identical, encoded for browsers."""

import gymnasium as gym
import numpy as np
import pytest
from conftest import skip_unless

from sb3_pride import PEBBLE
from sb3_pride.human import WebTeacher
from sb3_pride.human.render import SegmentRenderer, egl_available, encode_mp4, render_live

W, H = 64, 48


@pytest.fixture(scope="module", autouse=True)
def headless_gl():
    skip_unless(egl_available(), "headless EGL (MUJOCO_GL=egl) to render")


def live_episodes(env_id: str, renderer: SegmentRenderer, seeds=(11, 12), steps: int = 12):
    """Step a live env of ``env_id`` through one short episode per seed: the recorded states and live frames."""
    env = gym.make(env_id)
    env.get_wrapper_attr("enable_render_states")(renderer.layout)
    env.action_space.seed(0)
    states, frames = [], []
    for seed in seeds:
        _, info = env.reset(seed=seed)
        states.append(info["render_state"])
        frames.append(render_live(env, W, H, renderer.camera))
        for _ in range(steps):
            info = env.step(env.action_space.sample())[-1]
            states.append(info["render_state"])
            frames.append(render_live(env, W, H, renderer.camera))
    env.close()
    return np.array(states), np.array(frames)


@pytest.mark.parametrize(
    ("env_id", "randomized"),
    [
        ("sb3_pride/walker-walk-v0", {}),
        ("sb3_pride/button-press-v3", {"body_pos": 2}),  # the button box's position, re-drawn at each reset
        ("sb3_pride/reacher-easy-v0", {"geom_pos": 2}),  # dm_control's target, re-drawn at each reset
    ],
)
@pytest.mark.slow
def test_recorded_states_re_render_pixel_identical_across_resets(env_id, randomized):
    renderer = SegmentRenderer(env_id, width=W, height=H)
    assert {name: len(index) for name, index in renderer.layout} == randomized
    states, live = live_episodes(env_id, renderer)
    frames = renderer.render(states)
    assert frames.shape == live.shape == (len(states), H, W, 3) and frames.std() > 1  # a picture, not a blank
    np.testing.assert_array_equal(frames, live)
    # the check can fail: a segment shifted by one step, or (where a reset re-draws the model) states without the
    # model fields, rendered in a model left as its own last reset drew it, are not the live frames
    assert not np.array_equal(renderer.render(states[1:]), live[:-1])
    if randomized:
        n_fields = sum(randomized.values())
        layout, renderer.layout = renderer.layout, ()
        try:
            assert not np.array_equal(renderer.render(states[:, :-n_fields]), live)
        finally:
            renderer.layout = layout
    renderer.close()


def test_a_task_that_re_draws_its_terrain_is_refused_when_the_teacher_is_attached():
    with pytest.raises(ValueError, match="quadruped-escape-v0 re-draws its model's hfield_data at every reset"):
        PEBBLE("MlpPolicy", "sb3_pride/quadruped-escape-v0", teacher=WebTeacher(port=0), segment_length=10)


def test_scripted_teachers_record_no_states(tiny_kwargs):
    model = PEBBLE("MlpPolicy", "sb3_pride/walker-walk-v0", **tiny_kwargs)
    model.learn(150)
    assert model.replay_buffer.render_states is None and not model.replay_buffer.record_render_states


def test_a_web_teacher_records_one_state_per_stored_transition(tiny_kwargs):
    tiny_kwargs.update(buffer_size=120, unsupervised_steps=10**6)  # no feedback session: nobody answers here
    teacher = WebTeacher(port=0)
    model = PEBBLE("MlpPolicy", "sb3_pride/walker-walk-v0", teacher=teacher, **tiny_kwargs)
    model.learn(150)  # wraps around the 120-row buffer
    teacher.close()
    states = model.replay_buffer.render_states
    assert states is not None and states.shape == (120, 1, 18) and states.dtype == np.float64  # walker: 9 qpos + 9 qvel
    # each row holds the state that produced its transition's next observation: walker's observed velocity (the
    # last 9 entries) is qvel, the state's last 9
    np.testing.assert_allclose(model.replay_buffer.next_observations[:, 0, -9:], states[:, 0, 9:], rtol=1e-6, atol=1e-6)


def test_clips_are_h264_yuv420p_fast_start_at_the_env_frame_rate(tmp_path):
    av = pytest.importorskip("av")
    frames = np.random.default_rng(0).integers(0, 255, size=(30, 47, 63, 3), dtype=np.uint8)  # odd sizes
    path = tmp_path / "clip.mp4"
    encode_mp4(frames, 40.0, path)
    data = path.read_bytes()
    assert data.index(b"moov") < data.index(b"mdat")  # the index first: plays while it loads
    with av.open(str(path)) as container:
        stream = container.streams.video[0]
        assert stream.codec_context.name == "h264" and stream.codec_context.pix_fmt == "yuv420p"
        assert stream.average_rate == 40 and (stream.width, stream.height) == (64, 48)
        assert sum(1 for _ in container.decode(stream)) == 30
    assert not list(tmp_path.glob("*.part"))


@pytest.mark.slow
def test_pride_records_states_in_its_real_buffer_and_a_saved_web_teacher_comes_back(tiny_kwargs, tmp_path):
    from sb3_pride import PRIDE

    tiny_kwargs.update(buffer_size=200, unsupervised_steps=10**6, synthetic_samples=64)
    model = PRIDE("MlpPolicy", "sb3_pride/button-press-v3", teacher=WebTeacher(port=0), **tiny_kwargs)
    model.learn(120)
    states = model.real_buffer.render_states
    assert states is not None and states.shape == (200, 1, 29) and np.all(states[:120].any(axis=-1))
    model.teacher.close()
    model.save(tmp_path / "model.zip")
    loaded = PRIDE.load(tmp_path / "model.zip", env=model.get_env())  # the teacher's settings, a new server
    assert isinstance(loaded.teacher, WebTeacher) and loaded.teacher.server.running
    assert loaded.real_buffer.record_render_states
    loaded.teacher.close()


@pytest.mark.slow
def test_buffers_from_the_other_kind_of_teacher(tiny_kwargs, tmp_path):
    """A scripted run's buffer has no states to show: a WebTeacher refuses it. A WebTeacher run's buffer resumed with a
    scripted teacher records nothing more (its saved flag is reset), and trains."""
    tiny_kwargs.update(buffer_size=200, unsupervised_steps=10**6)
    scripted = PEBBLE("MlpPolicy", "sb3_pride/walker-walk-v0", **tiny_kwargs)
    scripted.learn(50)
    scripted.save_replay_buffer(tmp_path / "scripted.pkl")
    web = PEBBLE("MlpPolicy", "sb3_pride/walker-walk-v0", teacher=WebTeacher(port=0), **tiny_kwargs)
    with pytest.raises(ValueError, match="50 transitions recorded without simulator states"):
        web.load_replay_buffer(tmp_path / "scripted.pkl")
    web.teacher.close()

    web = PEBBLE("MlpPolicy", "sb3_pride/walker-walk-v0", teacher=WebTeacher(port=0), **tiny_kwargs)
    web.learn(50)
    web.save_replay_buffer(tmp_path / "web.pkl")
    web.teacher.close()
    scripted.load_replay_buffer(tmp_path / "web.pkl")
    assert not scripted.replay_buffer.record_render_states
    scripted.learn(20, reset_num_timesteps=False)
