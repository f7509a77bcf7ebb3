"""WebTeacher through its public parts, without a socket: the HTTP boundary through the Flask app's test client (one
person, several annotators with tokens, known answers, what other sites and malformed bodies may send), the state
store, the quality checks and the settings. Real sockets: test_web_server.py; real browsers: test_web_browser.py."""

import contextlib
import io
import json
import logging
import math
import pickle
import re
import socket
import threading
import time
from pathlib import Path

import numpy as np
import pytest
from conftest import skip_unless

from sb3_pride import PEBBLE
from sb3_pride.common.journal import PreferenceJournal, query_id
from sb3_pride.common.queries import SegmentPairs
from sb3_pride.common.teachers import FeedbackContext
from sb3_pride.human import KnownPair, Question, Session, WebTeacher
from sb3_pride.human.app import MAX_BODY
from sb3_pride.human.web import GENERIC_INSTRUCTIONS, default_instructions

pytest.importorskip("flask")


def token(teacher: WebTeacher, name: str) -> str:
    return teacher.links[name].split("token=")[1]


def request(teacher: WebTeacher, path: str, body: dict | bytes | None = None, headers: dict | None = None) -> tuple:
    """(status, headers, body) of a GET (no ``body``) or a JSON POST to the teacher's app."""
    data = body if isinstance(body, bytes) or body is None else json.dumps(body).encode()
    response = teacher.server.app.test_client().open(
        path,
        method="GET" if data is None else "POST",
        data=data,
        headers={"Content-Type": "application/json", **(headers or {})},
    )
    return response.status_code, dict(response.headers), response.get_data()


def page_state(teacher: WebTeacher, annotator: str | None = None) -> dict:
    """What ``annotator``'s page shows (it hands them questions), through the HTTP API as the browser asks it."""
    headers = {} if annotator is None else {"X-Annotator-Token": token(teacher, annotator)}
    status, _, body = request(teacher, "/api/state", headers=headers)
    assert status == 200, body
    return json.loads(body)


def answer(teacher: WebTeacher, question, label, annotator: str | None = None) -> tuple[int, str]:
    """(status, "recorded" or why not) of ``annotator``'s answer, sent as the page sends it."""
    headers = {} if annotator is None else {"X-Annotator-Token": token(teacher, annotator)}
    status, _, body = request(teacher, "/api/answer", {"id": question, "label": label}, headers)
    return status, "recorded" if status == 200 else json.loads(body)["error"]


def undo(teacher: WebTeacher, annotator: str | None = None) -> tuple[int, str]:
    """(status, the question taken back or why not) of ``annotator``'s undo, sent as the page sends it."""
    headers = {} if annotator is None else {"X-Annotator-Token": token(teacher, annotator)}
    status, _, body = request(teacher, "/api/undo", {}, headers)
    return status, json.loads(body)["undone" if status == 200 else "error"]


class Page:
    """An annotator's page, through the HTTP API (what the browser sends)."""

    def __init__(self, teacher: WebTeacher, name: str | None = None):
        self.teacher, self.name = teacher, name
        self.headers = {} if name is None else {"X-Annotator-Token": token(teacher, name)}

    def state(self) -> dict:
        status, _, body = request(self.teacher, "/api/state", headers=self.headers)
        assert status == 200, body
        return json.loads(body)

    def shown(self) -> str | None:
        query = self.state()["query"]
        return None if query is None else query["id"]

    def answer(self, question: str | None, label) -> int:
        return request(self.teacher, "/api/answer", {"id": question, "label": label}, self.headers)[0]

    def undo(self) -> int:
        return request(self.teacher, "/api/undo", {}, self.headers)[0]


class Run:
    """What a model gives an interactive teacher: its preference journal and its logger."""

    def __init__(self, path: Path, record_delay: float = 0.0):
        self.journal = PreferenceJournal(path)
        self.logged: dict[str, float] = {}
        self.record_delay = record_delay

    def record(self, entries: list) -> None:
        time.sleep(self.record_delay)  # a slow disk
        self.journal.append(entries)

    def context(self, session: int = 1) -> FeedbackContext:
        return FeedbackContext(session, 0, 100, self.record, self.journal.append_undo, self.logged.__setitem__)

    def labels(self) -> list[float]:
        return [entry.label for entry in self.journal.read()]


class FakeRenderer:
    """Black frames: the HTTP tests need clips, not pictures."""

    env_id, fps, layout, state_size = "sb3_pride/walker-walk-v0", 10.0, (), 4

    def render(self, states: np.ndarray) -> np.ndarray:
        return np.zeros((len(states), 16, 16, 3), np.uint8)

    def close(self) -> None:
        pass


class FakeEnv:
    """What ``attach()`` asks of a VecEnv of a re-renderable task."""

    def get_attr(self, name: str) -> list:
        return [FakeRenderer.env_id]

    def env_method(self, name: str, *args) -> list:
        return [FakeRenderer.state_size]


class FakeBuffer:
    render_states, record_render_states = None, False

    def size(self) -> int:
        return 0


def make_pairs(n: int, seed: int = 0, k: int = 4) -> SegmentPairs:
    """``n`` pairs whose segments earn a constant true reward in [0, 1) per step."""
    rng = np.random.default_rng(seed)
    rewards = np.repeat(rng.random((n, 2, 1)), k, axis=-1)
    return SegmentPairs(rng.normal(size=(n, 2, k, 3)), rng.normal(size=(n, 2, k, 1)), rewards, 0.5 * k, np.zeros((n, 2, k, 1)))


def true_answer(pairs: SegmentPairs, inputs: np.ndarray) -> float:
    index = next(i for i, pair in enumerate(pairs.inputs) if np.array_equal(pair, inputs))
    returns = pairs.true_rewards[index].sum(axis=-1)
    return float(returns[1] > returns[0])


def label_or_skip(entry) -> float | str:
    return "skip" if math.isnan(entry.label) else entry.label


def no_mp4(monkeypatch) -> None:
    """Clips of a few bytes: the tests that answer many questions need files, not video (a known-answer question's copy
    of its pair's clips too)."""
    monkeypatch.setattr("sb3_pride.human.render.encode_mp4", lambda frames, fps, path: Path(path).write_bytes(b"mp4"))
    monkeypatch.setattr(
        "sb3_pride.human.quality.recode_clip", lambda source, target, rng: Path(target).write_bytes(rng.bytes(4))
    )


@contextlib.contextmanager
def black_clip_teachers(clip_dir: Path):
    """Makes WebTeachers that render black clips without an env, as if attached (no port: pages use the app); each is
    closed at the end."""
    made: list[WebTeacher] = []

    def make(**kwargs) -> WebTeacher:
        teacher = WebTeacher(port=0, clip_dir=clip_dir, **kwargs)
        teacher.clips.renderer = FakeRenderer()
        made.append(teacher)
        return teacher

    try:
        yield make
    finally:
        for teacher in made:
            teacher.close()


@pytest.fixture
def serve(tmp_path):
    with black_clip_teachers(tmp_path / "clips") as make:
        yield make


def wait(condition, timeout: float = 60.0):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        value = condition()
        if value:
            return value
        time.sleep(0.05)
    raise AssertionError("timed out waiting")


def ask_in_thread(teacher: WebTeacher, pairs: SegmentPairs, context: FeedbackContext) -> tuple[threading.Thread, dict]:
    """``teacher.ask`` in a thread of its own (as a model answered asynchronously calls it), once its clips are ready."""
    result: dict = {}

    def ask() -> None:
        try:
            result["labels"] = teacher.ask(pairs, context)
        except BaseException as error:  # reported by the test's thread
            result["error"] = error

    thread = threading.Thread(target=ask, daemon=True)
    thread.start()
    wait(lambda: (session := teacher.store.session) is not None and all(query.ready for query in session.queries), 30)
    return thread, result


def finish(thread: threading.Thread, result: dict) -> np.ndarray:
    thread.join(timeout=10)
    assert not thread.is_alive() and "error" not in result, result
    return result["labels"]


def time_passes(teacher: WebTeacher, name: str, seconds: float) -> None:
    """What ``name`` is shown has been shown ``seconds`` longer: hand-over time without sleeping on a loaded machine."""
    session = teacher.store.session
    assert session is not None
    shown, since = session.shown_since[name]
    session.shown_since[name] = (shown, since - seconds)


def find(teacher: WebTeacher, question_id: str) -> Question:
    session = teacher.store.session
    assert session is not None
    question = session.find(question_id)
    assert question is not None
    return question


# one person on this machine ------------------------------------------------------------------------------------------
@pytest.fixture
def open_session(tmp_path):
    """A WebTeacher with one open session of two queries, "a" and "b", answered into a run's journal."""
    teacher = WebTeacher(port=0, clip_dir=tmp_path / "clips")
    (tmp_path / "clips").mkdir()
    (tmp_path / "clips" / "a-left.mp4").write_bytes(bytes(range(256)) * 40)
    queries = [Question(name, np.zeros((2, 10, 4), np.float32) + i, ready=True) for i, name in enumerate("ab")]
    teacher.run = Run(tmp_path / "preferences.jsonl")  # the journal, for the assertions
    teacher.store.begin(Session(1, queries, 0, teacher.run.context()))
    yield teacher
    teacher.close()


def test_bad_posts_are_refused_and_record_nothing(open_session):
    teacher = open_session
    assert page_state(teacher)["query"]["id"] == "a"  # the page shows "a"
    for body in ({"id": "zzz", "label": 1}, {"id": "a", "label": 0.7}, {"id": "a", "label": "left"},
                 {"id": "a", "label": True}, {"id": 3, "label": 1}, {"id": "a"}, {"label": 1}):  # fmt: skip
        status, _, reply = request(teacher, "/api/answer", body)
        assert status in (400, 404) and json.loads(reply)["error"], body
    assert request(teacher, "/api/answer", b"not json")[0] == 400
    assert request(teacher, "/api/undo", {})[0] == 409  # nothing to undo yet
    assert page_state(teacher)["answered"] == 0 and teacher.run.labels() == []

    assert request(teacher, "/api/answer", {"id": "a", "label": 0.5})[0] == 200 and page_state(teacher)["answered"] == 1
    assert request(teacher, "/api/answer", {"id": "a", "label": 1})[0] == 409  # answered already
    assert teacher.run.labels() == [0.5]


def test_bodies_too_large_or_too_deep_are_refused_and_record_nothing(open_session, caplog):
    """A body over 64 KiB, announced or streamed in chunks (werkzeug's server terminates a chunked body itself), and
    JSON nested past the parser's depth: refused as the docs say, nothing journaled, no traceback on the console."""
    teacher = open_session
    page_state(teacher)  # the page shows "a"
    padded = b'{"id": "a", "label": 1}' + b" " * MAX_BODY
    client = teacher.server.app.test_client()
    with caplog.at_level(logging.INFO):
        assert request(teacher, "/api/answer", padded)[0] == 413
        chunked = client.post(
            "/api/answer", input_stream=io.BytesIO(padded), content_type="application/json",
            headers={"Transfer-Encoding": "chunked"}, environ_overrides={"wsgi.input_terminated": True},
        )  # fmt: skip
        assert chunked.status_code == 413 and chunked.json["error"]
        for depth in (1000, 5000, MAX_BODY):
            status, _, reply = request(teacher, "/api/answer", b"[" * depth)
            assert status == 400 and "JSON" in json.loads(reply)["error"], depth
    assert teacher.run.labels() == [] and page_state(teacher)["answered"] == 0
    assert not [record for record in caplog.records if record.levelno >= logging.ERROR]
    whole = b'{"id": "a", "label": 1}'.ljust(MAX_BODY)  # the limit itself is allowed, streamed or not
    streamed = client.post(
        "/api/answer", input_stream=io.BytesIO(whole), content_type="application/json",
        headers={"Transfer-Encoding": "chunked"}, environ_overrides={"wsgi.input_terminated": True},
    )  # fmt: skip
    assert streamed.status_code == 200 and teacher.run.labels() == [1]


def test_minus_zero_is_journaled_as_zero(open_session):
    teacher = open_session
    page_state(teacher)  # the page shows "a", then "b"
    assert request(teacher, "/api/answer", b'{"id": "a", "label": -0.0}')[0] == 200
    assert answer(teacher, "b", -0.0) == (200, "recorded")
    assert teacher.run.labels() == [0, 0] and all(math.copysign(1, label) == 1 for label in teacher.run.labels())
    assert "-0.0" not in teacher.run.journal.path.read_text()


def test_clips_are_served_with_range_requests(open_session):
    teacher = open_session
    page_state(teacher)
    status, headers, body = request(teacher, "/clips/a-left.mp4", headers={"Range": "bytes=100-199"})
    assert status == 206 and headers["Content-Range"] == "bytes 100-199/10240" and body == (bytes(range(256)) * 40)[100:200]
    assert headers["Content-Type"] == "video/mp4" and headers.get("Accept-Ranges") == "bytes"
    assert request(teacher, "/clips/missing.mp4")[0] == 404
    (teacher.clips.folder() / "a-left.mp4.part").write_bytes(b"half a clip")  # a clip being written is not served
    assert request(teacher, "/clips/a-left.mp4.part")[0] == 404


def test_a_timeout_skips_the_rest(open_session, capsys):
    teacher = open_session
    session = teacher.store.session
    page_state(teacher)
    assert answer(teacher, "a", 1) == (200, "recorded")
    teacher.store.wait(timeout=0.3, reminder_interval=60, url=teacher.url)
    assert teacher.store.session is None
    assert session.queries[0].label() == 1 and np.isnan(session.queries[1].label())
    assert len(teacher.run.labels()) == 2  # the skip is journaled too: the counts stay in step
    assert "timeout, 1 queries skipped" in capsys.readouterr().out


def test_while_answers_are_awaited_the_console_says_so_with_the_url(open_session, capsys):
    teacher = open_session
    teacher.store.wait(timeout=1.5, reminder_interval=0.1, url=teacher.url)  # nobody answers: the page was never opened
    reminders = [line for line in capsys.readouterr().out.splitlines() if "still waiting" in line]
    assert len(reminders) >= 3 and all(teacher.url in line and "page last seen: never" in line for line in reminders)


def test_only_the_question_shown_is_answered_and_nothing_reaches_a_closed_session(open_session):
    teacher = open_session
    assert page_state(teacher)["query"]["id"] == "a"
    status, _, reply = request(teacher, "/api/answer", {"id": "b", "label": 1})  # "a" is shown, "b" preloaded
    assert status == 403 and "not the one shown to you" in json.loads(reply)["error"]
    assert answer(teacher, "a", 0)[0] == 200
    assert answer(teacher, "b", 1)[0] == 200
    session = teacher.store.session
    teacher.store.wait(timeout=None, reminder_interval=60, url=teacher.url)  # all answered: the session closes
    assert [q.label() for q in session.queries] == [0, 1] and teacher.store.session is None
    assert request(teacher, "/api/undo", {})[0] == 409  # a late Backspace
    assert answer(teacher, "b", 0)[0] == 409
    assert teacher.run.labels() == [0, 1]


def test_other_sites_cannot_post_or_rebind(open_session):
    """A form of another site (no JSON), a page reached under another name (DNS rebinding): refused, nothing recorded."""
    teacher = open_session
    assert page_state(teacher)["query"]["id"] == "a"
    form = {"Content-Type": "application/x-www-form-urlencoded"}
    assert request(teacher, "/api/answer", b"id=a&label=1", form)[0] == 415
    assert request(teacher, "/api/answer", b'{"id": "a", "label": 1}', {"Content-Type": "text/plain"})[0] == 415
    assert request(teacher, "/api/answer", {"id": "a", "label": 1})[0] == 200
    assert request(teacher, "/api/undo", b"", form)[0] == 415
    assert request(teacher, "/api/undo", b"")[0] == 400  # JSON, but no object
    rebound = {"Host": "evil.example:8000"}
    for path, body in (("/api/undo", {}), ("/api/state", None), ("/clips/a-left.mp4", None), ("/", None)):
        assert request(teacher, path, body, rebound)[0] == 403, path
    assert teacher.run.labels() == [1]  # the one JSON answer, not undone
    for host in ("localhost:8000", "[::1]:8000", "127.0.0.1"):
        assert request(teacher, "/api/state", None, {"Host": host})[0] == 200, host


def test_no_site_can_frame_the_page(open_session):
    """Every answer forbids framing (X-Frame-Options and CSP frame-ancestors): another site cannot show the page under
    its own buttons, which one person alone (no token needed) would otherwise click for it."""
    teacher = open_session
    page_state(teacher)
    for path, body in (("/", None), ("/api/state", None), ("/api/answer", {"id": "zzz", "label": 1}),
                       ("/clips/a-left.mp4", None), ("/clips/missing.mp4", None), ("/nowhere", None)):  # fmt: skip
        status, headers, _ = request(teacher, path, body)
        assert headers.get("X-Frame-Options") == "DENY", (path, status)
        assert headers.get("Content-Security-Policy") == "frame-ancestors 'none'", (path, status)


def test_an_error_in_a_route_is_a_json_500(open_session, monkeypatch):
    def broken(annotator=None, instructions=""):
        raise RuntimeError("broken")

    monkeypatch.setattr(open_session.store, "page_state", broken)
    status, _, body = request(open_session, "/api/state")
    assert status == 500 and "RuntimeError: broken" in json.loads(body)["error"]


# settings ------------------------------------------------------------------------------------------------------------
def test_bad_settings_name_the_parameter():
    for kwargs, name in (
        ({"port": 70000}, "port"),
        ({"timeout": 0}, "timeout"),
        ({"width": 8}, "width"),
        ({"host": "0.0.0.0"}, "annotators"),  # beyond this machine: tokens or nothing
        ({"host": "192.168.1.7"}, "annotators"),
        ({"annotators": []}, "annotators"),
        ({"annotators": "ana"}, "annotators"),
        ({"annotators": ["ana", "ana"]}, "annotators"),
        ({"annotators": ["ana smith"]}, "annotators"),
        ({"annotators": ["ana"], "answers_per_query": 2}, "answers_per_query"),
        ({"answers_per_query": 0}, "answers_per_query"),
        ({"known_answer_rate": 1.0}, "known_answer_rate"),
        ({"known_answer_rate": -0.1}, "known_answer_rate"),
        ({"known_answer_margin": 0}, "known_answer_margin"),
        ({"instructions": 3}, "instructions"),
        ({"seed": 1.5}, "seed"),
        ({"read_timeout": 0}, "read_timeout"),
        ({"hand_over_after": -1}, "hand_over_after"),
        ({"reminder_interval": math.inf}, "reminder_interval"),
    ):
        with pytest.raises(ValueError, match=name):
            WebTeacher(**kwargs)
    for host in ("localhost", "::1", "127.0.0.2"):  # this machine only: no token needed
        assert WebTeacher(host=host).links == {}


def test_a_saved_teacher_keeps_its_settings_and_makes_new_tokens():
    teacher = WebTeacher(port=0, annotators=["ana", "ben"], read_timeout=5, hand_over_after=60)
    assert set(teacher.links) == {"ana", "ben"} and len(set(teacher.links.values())) == 2
    assert all(link.startswith(teacher.url + "?token=") for link in teacher.links.values())
    loaded = pickle.loads(pickle.dumps(teacher))
    assert loaded.annotators == ["ana", "ben"] and not loaded.server.running
    assert (loaded.read_timeout, loaded.hand_over_after) == (5, 60)
    assert not set(loaded.links.values()) & set(teacher.links.values())  # tokens are never saved
    older = WebTeacher.__new__(WebTeacher)  # as pickle makes a teacher saved before several annotators existed
    older.__setstate__(dict(port=0, host="127.0.0.1", timeout=None, width=320, height=240, clip_dir=None,
                            reminder_interval=60.0, camera=None))  # fmt: skip
    assert older.annotators is None and older.known_answer_rate == 0 and older.links == {}
    assert older.read_timeout > 0 and older.hand_over_after > 0  # the settings it did not know get their defaults


def test_tokens_are_required_beyond_localhost_whenever_the_server_starts():
    teacher = WebTeacher(port=0)
    teacher.host = "0.0.0.0"  # set after construction
    teacher.clips.renderer = FakeRenderer()
    with pytest.raises(ValueError, match="annotators"):
        teacher.attach(FakeEnv(), FakeBuffer())
    assert not teacher.server.running
    loaded = pickle.loads(pickle.dumps(WebTeacher(port=0)))
    loaded.__setstate__({**loaded.__getstate__(), "host": "0.0.0.0"})  # as a teacher saved with another host
    loaded.clips.renderer = FakeRenderer()
    with pytest.raises(ValueError, match="annotators"):
        loaded.attach(FakeEnv(), FakeBuffer())


def test_a_port_in_use_is_named():
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        teacher = WebTeacher(port=port)
        teacher.clips.renderer = FakeRenderer()
        with pytest.raises(ValueError, match=f"port {port} on 127.0.0.1 is in use"):
            teacher.attach(FakeEnv(), FakeBuffer())


def test_instructions_default_to_the_task(serve):
    assert "walker" in default_instructions("sb3_pride/walker-walk-v0")
    assert "cheetah" in default_instructions("sb3_pride/cheetah-run-v0")
    assert "button" in default_instructions("sb3_pride/button-press-v3")
    assert "door" in default_instructions("sb3_pride/door-open-v3")
    assert default_instructions("sb3_pride/unknown-task-v0") == default_instructions(None) == GENERIC_INSTRUCTIONS
    teacher = serve()
    assert Page(teacher).state()["instructions"] == GENERIC_INSTRUCTIONS  # no env seen yet
    teacher.env_id = "sb3_pride/walker-walk-v0"  # as attach() sees it
    assert Page(teacher).state()["instructions"] == default_instructions("sb3_pride/walker-walk-v0")
    teacher.instructions = "Prefer <b>faster</b> walkers."
    assert Page(teacher).state()["instructions"] == "Prefer <b>faster</b> walkers."


# several annotators --------------------------------------------------------------------------------------------------
def test_serving_beyond_localhost_with_annotators(serve):
    teacher = serve(annotators=["ana"], host="0.0.0.0")
    assert teacher.url == f"http://{socket.gethostname()}:0/"
    assert request(teacher, "/api/state", headers={"Host": "annotators.example"})[0] == 401
    status, _, body = request(teacher, "/api/state?token=" + token(teacher, "ana"), headers={"Host": "annotators.example"})
    assert status == 200 and json.loads(body)["you"] == "ana"


def test_annotators_refusals_are_http_errors_that_record_nothing(serve, tmp_path):
    teacher = serve(annotators=["ana", "ben"])
    run, pairs = Run(tmp_path / "preferences.jsonl"), make_pairs(4)
    thread, result = ask_in_thread(teacher, pairs, run.context())
    ana, ben = Page(teacher, "ana"), Page(teacher, "ben")
    first_of_ana, first_of_ben = ana.shown(), ben.shown()
    assert first_of_ana and first_of_ben and first_of_ana != first_of_ben  # nobody is shown a query another answers

    def nothing_recorded() -> None:
        assert run.journal.read() == [] and teacher.agreement()["ana"]["answers"] == 0
        assert ana.shown() == first_of_ana and ben.shown() == first_of_ben

    # without a valid token: every API route and the clips
    clip = ana.state()["query"]["left"]
    for path, body, headers in (
        ("/api/state", None, {}),
        ("/api/state", None, {"X-Annotator-Token": "guess"}),
        ("/api/state?token=", None, {}),
        ("/api/answer", {"id": first_of_ana, "label": 1}, {}),
        ("/api/undo", {}, {"X-Annotator-Token": "guess"}),
        (clip, None, {}),
    ):
        status, _, reply = request(teacher, path, body, headers)
        assert status == 401 and "token" in json.loads(reply)["error"], path
    assert request(teacher, clip + "?token=" + token(teacher, "ana"))[0] == 200
    status, _, page = request(teacher, "/")  # the page itself holds nothing: it asks for the token
    assert status == 200 and b"X-Annotator-Token" in page
    # malformed, a label outside {0, 0.5, 1, null}, another's query, an unknown one
    for body in (b"{", b"[1, 2]", {"label": 1}, {"id": first_of_ana}):
        assert request(teacher, "/api/answer", body, ana.headers)[0] == 400, body
    status, _, reply = request(teacher, "/api/answer", {"id": first_of_ana, "label": 1, "pad": "x" * 70_000}, ana.headers)
    assert status == 413 and json.loads(reply)["error"]
    for label in (0.7, "left", True, -1, 2, float("nan")):
        assert ana.answer(first_of_ana, label) == 400, label
    assert ana.answer(first_of_ben, 1) == 403  # handed to ben, not to ana
    assert ana.answer("nonexistent", 1) == 404
    assert ana.undo() == 409  # nothing to undo yet
    nothing_recorded()
    # replays: the same answer again, and a query that has its answer
    assert ana.answer(first_of_ana, 1) == 200
    answered = find(teacher, first_of_ana).pair
    assert ana.answer(first_of_ana, 1) == 409 and ana.answer(first_of_ana, 0) == 409
    assert ben.answer(first_of_ana, 0) == 403  # not shown to ben: refused as a known-answer question would be
    assert len(run.journal.read()) == 1 and teacher.agreement()["ben"]["answers"] == 0

    while ana.state()["session"] is not None:
        for page in (ana, ben):
            if (shown := page.shown()) is not None:
                assert page.answer(shown, 0.5) == 200
    labels = finish(thread, result)
    np.testing.assert_array_equal(labels, [1 if query_id(inputs) == answered else 0.5 for inputs in pairs.inputs])
    entries = run.journal.read()
    assert len(entries) == 4 and len({entry.id for entry in entries}) == 4  # no query answered twice
    assert {entry.annotator for entry in entries} == {"ana", "ben"} and all(entry.time > 0 for entry in entries)
    assert ana.state()["session"] is None and ana.answer(first_of_ben, 1) == 409  # the session is over


def test_two_answers_per_query_are_averaged_and_undo_takes_back_ones_own(serve, tmp_path):
    teacher = serve(annotators=["ana", "ben"], answers_per_query=2, report_path=tmp_path / "report.json")
    run, pairs = Run(tmp_path / "preferences.jsonl"), make_pairs(3)
    thread, result = ask_in_thread(teacher, pairs, run.context())
    ana, ben = Page(teacher, "ana"), Page(teacher, "ben")
    ids = [query.id for query in teacher.store.session.queries]
    assert ana.shown() == ids[0] and ben.shown() == ids[0]  # both answer the first query
    assert ana.answer(ids[0], 1) == 200 and ben.answer(ids[0], 0) == 200  # they disagree: μ = 0.5
    assert ana.answer(ids[1], 1) == 200
    assert ana.state()["team"][0]["session"] == 2
    assert ana.undo() == 200 and ana.shown() == ids[1]  # ana takes hers back: shown to her again
    assert ben.undo() == 200 and ben.shown() == ids[0]  # ben's own last answer, not ana's
    assert ben.answer(ids[0], 0) == 200
    assert ana.answer(ids[1], 0) == 200 and ben.answer(ids[1], None) == 200  # a skip: μ is ana's
    assert ana.answer(ids[2], 1) == 200 and ben.answer(ids[2], 1) == 200
    np.testing.assert_array_equal(finish(thread, result), [0.5, 0, 1])
    entries = run.journal.read()  # each answer its own entry, the undone ones removed
    pair = [query_id(inputs) for inputs in pairs.inputs]
    assert [(entry.id, entry.annotator, label_or_skip(entry)) for entry in entries] == [
        (pair[0], "ana", 1), (pair[0], "ben", 0), (pair[1], "ana", 0), (pair[1], "ben", "skip"), (pair[2], "ana", 1),
        (pair[2], "ben", 1),
    ]  # fmt: skip
    agreement = teacher.agreement()
    assert agreement["ana"]["pairwise_agreement"] == 0.5 and agreement["ana"]["compared_answers"] == 2
    assert agreement["ben"]["answers"] == 3 and agreement["ben"]["skips"] == 1
    assert run.logged["annotators/ana/pairwise_agreement"] == 0.5 and run.logged["annotators/ben/answers"] == 3
    assert json.loads((tmp_path / "report.json").read_text())["annotators"] == agreement


def test_a_query_shown_too_long_goes_to_an_idle_annotator(serve, tmp_path):
    """ben's page keeps polling but he never answers: after hand_over_after, ana, who has nothing left, is handed it."""
    teacher = serve(annotators=["ana", "ben"], hand_over_after=30)
    run = Run(tmp_path / "preferences.jsonl")
    thread, result = ask_in_thread(teacher, make_pairs(1), run.context())
    ana, ben = Page(teacher, "ana"), Page(teacher, "ben")
    held = ben.shown()
    assert held is not None and ana.shown() is None  # the only query is ben's, and it is not overdue yet
    time_passes(teacher, "ben", 31)
    assert ben.shown() == held  # still polling: his page is not quiet, only slow
    assert ana.shown() == held and ben.shown() is None  # handed over
    assert ben.answer(held, 0) == 403 and ana.answer(held, 1) == 200
    np.testing.assert_array_equal(finish(thread, result), [1])
    assert [(entry.annotator, entry.label) for entry in run.journal.read()] == [("ana", 1)]


def test_a_careless_annotator_is_flagged_by_known_answers(serve, tmp_path, monkeypatch, capsys):
    """ana answers from the true reward, ben at random: the known-answer questions tell them apart."""
    no_mp4(monkeypatch)
    teacher = serve(annotators=["ana", "ben"], known_answer_rate=0.4, seed=0, report_path=tmp_path / "report.json")
    run, pairs = Run(tmp_path / "preferences.jsonl"), make_pairs(60)
    thread, result = ask_in_thread(teacher, pairs, run.context())
    pages, coin = [Page(teacher, "ana"), Page(teacher, "ben")], np.random.default_rng(1)
    while thread.is_alive():
        for page in pages:
            shown, session = page.shown(), teacher.store.session
            if shown is not None and session is not None:
                careful = true_answer(pairs, session.find(shown).inputs)
                assert page.answer(shown, careful if page.name == "ana" else float(coin.integers(2))) == 200
    labels = finish(thread, result)
    entries = run.journal.read()
    assert len(entries) == 60  # the known-answer questions are extra: neither journaled nor given to the model
    for entry in entries:
        if entry.annotator == "ana":
            label = labels[[query_id(inputs) for inputs in pairs.inputs].index(entry.id)]
            assert label == true_answer(pairs, entry.inputs)
    report = json.loads((tmp_path / "report.json").read_text())["annotators"]
    ana, ben = report["ana"], report["ben"]
    assert ana["known_answers"] >= 8 and ana["known_answer_agreement"] == 1.0 and not ana["flagged"]
    assert ben["known_answers"] >= 8 and ben["known_answer_agreement"] < 0.7 and ben["flagged"]
    assert ana["answers"] + ben["answers"] == 60 + ana["known_answers"] + ben["known_answers"]
    assert run.logged["annotators/ben/known_answer_agreement"] == ben["known_answer_agreement"]
    assert "ben matched only" in capsys.readouterr().out


# known-answer questions ----------------------------------------------------------------------------------------------
def answer_first_session(teacher: WebTeacher, run: Run, pairs: SegmentPairs) -> None:
    """One person answers feedback session 1 from the true reward: its clear pairs become known answers."""
    thread, result = ask_in_thread(teacher, pairs, run.context(1))
    page = Page(teacher)
    while (shown := page.shown()) is not None:
        assert page.answer(shown, true_answer(pairs, find(teacher, shown).inputs)) == 200
    finish(thread, result)
    # known pairs now, but none was shown in the first feedback session: none was known before it
    assert teacher.quality.known and teacher.agreement()["anonymous"]["known_answers"] == 0


def test_known_answer_questions_look_like_any_other_and_their_first_answer_counts(serve, tmp_path, monkeypatch):
    """One person, true-reward known answers of feedback session 1 shown again in the next: nothing on the page moves
    differently on them, their clips are served alike (the address's shape and every header), and an undo does not
    change their score."""
    no_mp4(monkeypatch)
    teacher = serve(known_answer_rate=0.6, seed=0)
    run, page = Run(tmp_path / "preferences.jsonl"), Page(teacher)
    answer_first_session(teacher, run, make_pairs(8))
    second = make_pairs(8, seed=1)
    thread, result = ask_in_thread(teacher, second, run.context(2))
    known_seen, served = 0, {True: [], False: []}
    while (state := page.state())["query"] is not None:
        shown = state["query"]["id"]
        assert state["budget"] == {"max": 100, "asked": 8}  # fixed for the session
        assert all(row[key] is None for row in state["team"] for key in ("known_answers", "known_answer_agreement"))
        question = find(teacher, shown)
        for url in (state["query"]["left"], state["query"]["right"]):
            assert re.fullmatch(rf"/clips/{shown}-(left|right)\.mp4", url) and re.fullmatch(r"[0-9a-f]{12}", shown)
            status, headers, _ = request(teacher, url)
            assert status == 200 and not any(".mp4" in value for value in headers.values()), headers
            served[question.known is not None].append(headers)
        if question.known is None:
            assert page.answer(shown, true_answer(second, question.inputs)) == 200
        else:
            known_seen += 1
            assert page.answer(shown, 1 - question.known) == 200  # wrong first...
            assert page.state()["answered"] == state["answered"] + 1
            assert page.undo() == 200 and page.shown() == shown
            assert page.answer(shown, question.known) == 200  # ...then right: the first answer is the one scored
        after = page.state()
        assert after["answered"] == state["answered"] + 1 or after["session"] is None
    labels = finish(thread, result)
    assert known_seen >= 1 and not np.isnan(labels).any()
    for headers in served[True] + served[False]:  # the same headers, the same date, no ETag, no file name
        assert set(headers) == set(served[False][0]) and "Content-Disposition" not in headers and "ETag" not in headers
        assert headers["Last-Modified"] == served[False][0]["Last-Modified"]
    stats = teacher.agreement()["anonymous"]
    assert stats["known_answers"] == known_seen and stats["known_answer_agreement"] == 0
    assert stats["answers"] == 16 + known_seen and len(run.journal.read()) == 16  # known ones are not journaled
    between = page.state()["team"][0]
    assert between["known_answers"] == known_seen and between["session"] == 0  # shown once the session is over


def answer_as_a_team(
    teacher: WebTeacher, pages: list[Page], pairs: SegmentPairs, context: FeedbackContext, before=None, after=None
) -> np.ndarray:
    """Every page answers what it is shown (a known answer, or the true reward's) until the session is over; ``before``
    and ``after`` are called with the page and the question before and after each answer."""
    thread, result = ask_in_thread(teacher, pairs, context)
    while thread.is_alive():
        for page in pages:
            shown, session = page.shown(), teacher.store.session
            if shown is None or session is None or (question := session.find(shown)) is None:
                continue
            label = question.known if question.known is not None else true_answer(pairs, question.inputs)
            if before is not None:
                before(page, question)
            assert page.answer(shown, label) == 200
            if after is not None:
                after(page, question)
    return finish(thread, result)


def test_two_annotators_are_refused_alike_on_known_answers_and_queries(serve, tmp_path, monkeypatch):
    """ana and ben compare notes: once one has answered a question, the other answers it too. A known-answer question
    and a query of the model are refused alike, the same status and the same message."""
    no_mp4(monkeypatch)
    teacher = serve(annotators=["ana", "ben"], known_answer_rate=0.5, seed=0)
    run = Run(tmp_path / "preferences.jsonl")
    pages = [Page(teacher, "ana"), Page(teacher, "ben")]
    answer_as_a_team(teacher, pages, make_pairs(12), run.context(1))  # the clear pairs become known answers
    refusals: dict[bool, set] = {True: set(), False: set()}

    def the_other_answers_too(page: Page, question: Question) -> None:
        other = pages[1] if page is pages[0] else pages[0]
        status, _, reply = request(teacher, "/api/answer", {"id": question.id, "label": 1}, other.headers)
        message = json.loads(reply)["error"]
        if "no feedback session is open" not in message:  # the last answer closed the session, whatever it was
            refusals[question.known is not None].add((status, message.replace(question.id, "<id>")))

    answer_as_a_team(teacher, pages, make_pairs(12, seed=1), run.context(2), after=the_other_answers_too)
    assert refusals[True] and refusals[False], refusals
    assert refusals[True] == refusals[False] == {(403, "question '<id>' is not the one shown to you")}


def test_a_known_answer_question_shown_too_long_goes_over_as_a_query_would(serve, tmp_path, monkeypatch):
    """ana is shown a known-answer question and does not answer it; ben, who has nothing left, is handed it after
    hand_over_after, as he would be a query: one that never went over would tell itself apart."""
    teacher = serve(annotators=["ana", "ben"], known_answer_rate=0.5, hand_over_after=30)
    teacher.quality.clips = None  # no clips to copy: the pair's own files
    inputs = np.zeros((2, 4, 3))
    teacher.quality.add_known(KnownPair(query_id(inputs), inputs, ("k-left.mp4", "k-right.mp4"), 1.0, "true reward"))
    draws = iter([True])  # ana's first question is the known-answer one, then none
    monkeypatch.setattr(
        teacher.quality,
        "draw_known",
        lambda session, name: teacher.quality.known_question(session, name) if next(draws, False) else None,
    )
    query = Question("q", np.ones((2, 4, 3)), ready=True)
    teacher.store.begin(Session(1, [query], 0, Run(tmp_path / "preferences.jsonl").context()))
    ana, ben = Page(teacher, "ana"), Page(teacher, "ben")
    known = ana.shown()
    assert known != "q" and find(teacher, known).known == 1.0
    assert ben.shown() == "q" and ben.answer("q", 1) == 200  # the query preloaded for ana went to ben
    assert ben.shown() is None
    time_passes(teacher, "ana", 31)
    assert ana.shown() == known  # still polling, not answering
    assert ben.shown() == known and ana.shown() is None  # handed over
    assert ana.answer(known, 1) == 403 and ben.answer(known, 1) == 200
    assert teacher.agreement()["ben"]["known_answers"] == 1


class PaintedRenderer(FakeRenderer):
    """Frames painted from the states (a colour per step over a ramp): each segment's clips are its own."""

    def render(self, states: np.ndarray) -> np.ndarray:
        colours = (np.asarray(states)[:, :3] * 200).astype(np.int64)
        ramp = np.add.outer(np.arange(16), np.arange(16)) * 3
        return ((colours[:, None, None, :] + ramp[None, :, :, None]) % 256).astype(np.uint8)


def test_no_two_questions_serve_the_same_clip_bytes(serve, tmp_path):
    """One person answers two feedback sessions; the second shows known-answer questions, pairs of the first. Each is a
    copy of its pair's clips encoded anew: it shows the same frames (but for a dither of a level and the loss of a second
    encoding), yet no question's clip is byte for byte another's."""
    av = pytest.importorskip("av")
    teacher = serve(known_answer_rate=0.6, seed=0)
    teacher.clips.renderer = PaintedRenderer()
    run, page = Run(tmp_path / "preferences.jsonl"), Page(teacher)
    served: dict[str, bytes] = {}  # question id + side -> the bytes served

    def fetch_clips(page: Page, question: Question) -> None:
        for side, url in zip(("left", "right"), question.clips, strict=True):
            status, _, body = request(teacher, url)
            assert status == 200
            served[f"{question.id}-{side}"] = body

    def pairs(n: int, seed: int) -> SegmentPairs:
        plain = make_pairs(n, seed)
        states = np.random.default_rng(seed + 100).random((n, 2, 4, 4))
        return SegmentPairs(plain.observations, plain.actions, plain.true_rewards, plain.return_scale, states)

    answer_as_a_team(teacher, [page], pairs(6, 0), run.context(1), before=fetch_clips)
    sources = {query.pair: query.files for query in teacher.quality.known}
    known: list[Question] = []
    answer_as_a_team(
        teacher,
        [page],
        pairs(6, 1),
        run.context(2),
        before=lambda p, q: (fetch_clips(p, q), q.known is None or known.append(q)),
    )
    assert known, "no known-answer question was shown"
    assert len(set(served.values())) == len(served), "two questions served the same clip"
    folder = teacher.clips.folder()
    for question in known:
        for side, source in zip(("left", "right"), sources[question.pair], strict=True):
            original, copy = (folder / source).read_bytes(), served[f"{question.id}-{side}"]
            frames = []
            for data in (original, copy):
                with av.open(io.BytesIO(data)) as container:
                    frames.append(np.stack([f.to_ndarray(format="rgb24") for f in container.decode(video=0)]).astype(int))
            assert frames[0].shape == frames[1].shape and np.abs(frames[0] - frames[1]).mean() < 8


def test_known_answers_take_as_long_as_journaled_ones(serve, tmp_path, monkeypatch):
    """The journal's durable write takes time; a known-answer question's answer and undo, which journal nothing, wait
    as long, so that response times do not tell them apart."""
    no_mp4(monkeypatch)
    teacher = serve(known_answer_rate=0.9, seed=0)
    run, page = Run(tmp_path / "preferences.jsonl", record_delay=0.2), Page(teacher)
    answer_first_session(teacher, run, make_pairs(4))
    second = make_pairs(4, seed=1)
    thread, result = ask_in_thread(teacher, second, run.context(2))
    took: dict[bool, list[float]] = {True: [], False: []}
    while (shown := page.shown()) is not None:
        question = find(teacher, shown)
        start = time.perf_counter()
        label = question.known if question.known is not None else true_answer(second, question.inputs)
        assert page.answer(shown, label) == 200
        took[question.known is not None].append(time.perf_counter() - start)
    finish(thread, result)
    assert took[True] and took[False] and min(took[True]) >= 0.18, took


def test_true_reward_known_answers_need_a_return_scale():
    teacher = WebTeacher(port=0, known_answer_rate=0.5)
    rewards = np.array([[1.0, 1.0], [1.0, 1.001], [0.0, 3.0], [2.0, 0.0]])[..., None].repeat(4, axis=-1)

    def pairs(rewards: np.ndarray, return_scale: float) -> SegmentPairs:
        return SegmentPairs(np.zeros((4, 2, 4, 3)), np.zeros((4, 2, 4, 1)), rewards, return_scale, np.zeros((4, 2, 4, 1)))

    # return_scale ~ 0: the margin is measured in the spread of the pairs' returns instead, so 0.004 is not clear
    assert teacher.quality.known_from_reward(pairs(rewards, 1e-12)) == [None, None, 1.0, 0.0]
    assert teacher.quality.known_from_reward(pairs(rewards, 1e-3)) == [None, None, 1.0, 0.0]
    flat = np.ones_like(rewards) + 1e-15 * rewards
    assert teacher.quality.known_from_reward(pairs(flat, 0.0)) == [None] * 4  # no scale at all: no known answer


def test_known_pairs_are_never_shown_to_who_made_them():
    """A majority's pair is never a known-answer question for its voters, nor a pair one answered, with annotators."""
    quality = WebTeacher(port=0, annotators=["ana", "ben", "cal"], answers_per_query=2, known_answer_rate=0.5).quality
    quality.clips = None  # no clips to copy: a known-answer question shows its pair's own files
    inputs = np.zeros((2, 4, 3))
    majority = KnownPair(query_id(inputs), inputs, ("m-left.mp4", "m-right.mp4"), 1.0, "majority", frozenset({"ana", "ben"}))
    reward = KnownPair(query_id(inputs + 1), inputs + 1, ("r-left.mp4", "r-right.mp4"), 0.0, "true reward")
    for known, answered_by in ((majority, {"ben"}), (reward, {"cal"})):  # ana's answer to the majority was taken back
        quality.add_known(known)
        quality.seen[known.pair] = answered_by
    session = Session(2, [], 0, Run(Path("/dev/null")).context(2))
    assert quality.known_question(session, "ana").pair == reward.pair
    assert quality.known_question(session, "ana") is None  # each pair once a session, the majority never
    assert quality.known_question(session, "cal").pair == majority.pair
    assert quality.known_question(session, "cal") is None  # the true-reward pair is hers already: not shown again
    alone = WebTeacher(port=0, known_answer_rate=0.5).quality
    alone.clips = None
    alone.add_known(reward)
    alone.seen[reward.pair] = {"anonymous"}
    question = alone.known_question(session, "anonymous")  # one person: shown again, under an address of its own
    assert (
        question.pair == reward.pair
        and question.files == reward.files
        and question.clips[0] == f"/clips/{question.id}-left.mp4"
    )


def test_a_report_that_cannot_be_written(serve, tmp_path, capsys):
    (tmp_path / "a_file").write_text("")
    for path in (tmp_path, tmp_path / "a_file" / "report.json"):
        with pytest.raises(ValueError, match="report_path"):
            WebTeacher(port=0, report_path=path)
    report = tmp_path / "new" / "report.json"
    teacher = serve(report_path=report)
    assert report.parent.is_dir()
    report.mkdir()  # taken by a folder after the teacher was made: the write fails
    run, page = Run(tmp_path / "preferences.jsonl"), Page(teacher)
    thread, result = ask_in_thread(teacher, make_pairs(2), run.context())
    while (shown := page.shown()) is not None:
        assert page.answer(shown, 1) == 200
    np.testing.assert_array_equal(finish(thread, result), [1, 1])  # the session's answers are given to the model
    assert "could not be written" in capsys.readouterr().out
    teacher.close()  # warns again, and closes all the same
    assert "could not be written" in capsys.readouterr().out and teacher.clips.renderer is None


def test_ask_from_a_worker_thread_renders_real_clips(tiny_kwargs, tmp_path):
    """MuJoCo's GL contexts belong to a thread: the render thread makes them whatever thread calls ask()."""
    av = pytest.importorskip("av")
    from sb3_pride.common.queries import sample_segment_pairs
    from sb3_pride.human.render import egl_available

    skip_unless(egl_available(), "headless EGL (MUJOCO_GL=egl) to render the clips")
    tiny_kwargs.update(unsupervised_steps=10**6)  # no feedback session of its own
    teacher = WebTeacher(port=0, width=32, height=24, clip_dir=tmp_path / "clips")
    model = PEBBLE("MlpPolicy", "sb3_pride/walker-walk-v0", teacher=teacher, seed=0, **tiny_kwargs)
    try:
        model.learn(60)
        pairs = sample_segment_pairs(model.real_buffer, 2, 10, 10, np.random.default_rng(0))
        thread, result = ask_in_thread(teacher, pairs, Run(tmp_path / "p.jsonl").context())
        first = find(teacher, page_state(teacher)["query"]["id"])
        for label in (0, 1):
            assert answer(teacher, page_state(teacher)["query"]["id"], label)[0] == 200
        np.testing.assert_array_equal(finish(thread, result), [0, 1])
    finally:
        teacher.close()
    with av.open(str(tmp_path / "clips" / first.files[0])) as container:
        frames = [frame.to_ndarray(format="rgb24") for frame in container.decode(video=0)]
    assert len(frames) == 10 and frames[0].shape == (24, 32, 3) and frames[0].std() > 5  # a picture, not a blank
