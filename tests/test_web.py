"""WebTeacher: the HTTP boundary (one person, several annotators with tokens, known answers), and people's keys in
real headless Chromium during a PEBBLE run."""

import json
import math
import os
import pickle
import socket
import threading
import time
import urllib.error
import urllib.request
from pathlib import Path

import numpy as np
import pytest
from conftest import skip_unless

from sb3_pride import PEBBLE
from sb3_pride.common.journal import PreferenceJournal, query_id
from sb3_pride.common.queries import SegmentPairs
from sb3_pride.common.teachers import FeedbackContext
from sb3_pride.human.web import GENERIC_INSTRUCTIONS, WebTeacher, _Known, _Query, _Session, default_instructions

pytest.importorskip("flask")
CHROMIUM, CHROMEDRIVER = "/usr/bin/chromium", "/usr/bin/chromedriver"


def request(url: str, body: dict | bytes | None = None, headers: dict | None = None) -> tuple[int, dict, bytes]:
    data = body if isinstance(body, bytes) or body is None else json.dumps(body).encode()
    req = urllib.request.Request(url, data=data, headers={"Content-Type": "application/json", **(headers or {})})
    try:
        with urllib.request.urlopen(req, timeout=10) as response:
            return response.status, dict(response.headers), response.read()
    except urllib.error.HTTPError as error:
        return error.code, dict(error.headers), error.read()


class Page:
    """An annotator's page, through the HTTP API (what the browser sends)."""

    def __init__(self, teacher: WebTeacher, name: str | None = None):
        self.url, self.name = teacher.url, name
        self.headers = {} if name is None else {"X-Annotator-Token": teacher.links[name].split("token=")[1]}

    def state(self) -> dict:
        status, _, body = request(self.url + "api/state", headers=self.headers)
        assert status == 200, body
        return json.loads(body)

    def shown(self) -> str | None:
        query = self.state()["query"]
        return None if query is None else query["id"]

    def answer(self, question: str | None, label) -> int:
        return request(self.url + "api/answer", {"id": question, "label": label}, self.headers)[0]

    def undo(self) -> int:
        return request(self.url + "api/undo", {}, self.headers)[0]


class Run:
    """What a model gives an interactive teacher: its preference journal and its logger."""

    def __init__(self, path: Path):
        self.journal = PreferenceJournal(path)
        self.logged: dict[str, float] = {}

    def context(self, session: int = 1) -> FeedbackContext:
        return FeedbackContext(session, 0, 100, self.journal.append, self.journal.append_undo, self.logged.__setitem__)


class FakeRenderer:
    """Black frames: the HTTP tests need clips, not pictures."""

    env_id, fps = "sb3_pride/walker-walk-v0", 10.0

    def render(self, states: np.ndarray) -> np.ndarray:
        return np.zeros((len(states), 16, 16, 3), np.uint8)

    def close(self) -> None:
        pass


def make_pairs(n: int, seed: int = 0, k: int = 4) -> SegmentPairs:
    """``n`` pairs whose segments earn a constant true reward in [0, 1) per step."""
    rng = np.random.default_rng(seed)
    rewards = np.repeat(rng.random((n, 2, 1)), k, axis=-1)
    return SegmentPairs(rng.normal(size=(n, 2, k, 3)), rng.normal(size=(n, 2, k, 1)), rewards, 0.5 * k, np.zeros((n, 2, k, 1)))


def true_answer(pairs: SegmentPairs, inputs: np.ndarray) -> float:
    index = next(i for i, pair in enumerate(pairs.inputs) if np.array_equal(pair, inputs))
    returns = pairs.true_rewards[index].sum(axis=-1)
    return float(returns[1] > returns[0])


@pytest.fixture
def serve(tmp_path):
    """Makes WebTeachers that serve and render black clips without an env (closed at the end)."""
    teachers = []

    def make(**kwargs) -> WebTeacher:
        teacher = WebTeacher(port=0, clip_dir=tmp_path / "clips", **kwargs)
        teacher._attached, teacher._renderer = True, FakeRenderer()
        teacher._start_server()
        teachers.append(teacher)
        return teacher

    yield make
    for teacher in teachers:
        teacher.close()


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
    _wait(lambda: teacher._session is not None and all(query.ready for query in teacher._session.queries), timeout=30)
    return thread, result


def finish(thread: threading.Thread, result: dict) -> np.ndarray:
    thread.join(timeout=10)
    assert not thread.is_alive() and "error" not in result, result
    return result["labels"]


# one person on this machine ------------------------------------------------------------------------------------------
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
    context = FeedbackContext(1, 0, 60, model.record_answers, model.retract_answer)
    teacher._session = _Session(1, queries, 0, context)
    teacher.model = model  # the journal's owner, for the assertions
    yield teacher
    teacher.close()


def test_bad_posts_are_refused_and_record_nothing(open_session):
    teacher = open_session
    assert teacher.state()["query"]["id"] == "a"  # the page shows "a"
    for body in ({"id": "zzz", "label": 1}, {"id": "a", "label": 0.7}, {"id": "a", "label": "left"},
                 {"id": "a", "label": True}, {"id": 3, "label": 1}, {"id": "a"}, {"label": 1}):  # fmt: skip
        status, _, reply = request(teacher.url + "api/answer", body)
        assert status in (400, 404) and json.loads(reply)["error"], body
    status, _, _ = request(teacher.url + "api/answer", b"not json")
    assert status == 400
    status, _, _ = request(teacher.url + "api/undo", {})
    assert status == 409  # nothing to undo yet
    assert teacher.state()["answered"] == 0 and teacher.model.journal_history() == []

    status, _, _ = request(teacher.url + "api/answer", {"id": "a", "label": 0.5})
    assert status == 200 and teacher.state()["answered"] == 1
    status, _, _ = request(teacher.url + "api/answer", {"id": "a", "label": 1})
    assert status == 409  # answered already
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
    ):
        with pytest.raises(ValueError, match=name):
            WebTeacher(**kwargs)
    for host in ("localhost", "::1", "127.0.0.2"):  # this machine only: no token needed
        assert WebTeacher(host=host).links == {}


def test_a_timeout_skips_the_rest(open_session, capsys):
    teacher = open_session
    teacher.timeout, session = 0.3, teacher._session
    teacher.state()
    assert teacher.answer("a", 1) == (200, "recorded")
    teacher._wait_for_answers()
    assert teacher._session is None
    assert session.queries[0].label() == 1 and np.isnan(session.queries[1].label())
    assert len(teacher.model.journal_history()) == 2  # the skip is journaled too: the counts stay in step
    assert "timeout, 1 queries skipped" in capsys.readouterr().out


def test_while_answers_are_awaited_the_console_says_so_with_the_url(open_session, capsys):
    teacher = open_session
    teacher.reminder_interval, teacher.timeout = 0.1, 0.45
    teacher._wait_for_answers()  # nobody answers: the page was never opened
    reminders = [line for line in capsys.readouterr().out.splitlines() if "still waiting" in line]
    assert len(reminders) >= 3 and all(teacher.url in line and "page last seen: never" in line for line in reminders)


def test_only_the_question_shown_is_answered_and_nothing_reaches_a_closed_session(open_session):
    teacher = open_session
    assert teacher.state()["query"]["id"] == "a"
    status, _, reply = request(teacher.url + "api/answer", {"id": "b", "label": 1})  # "a" is shown, "b" preloaded
    assert status == 403 and "not the one shown to you" in json.loads(reply)["error"]
    assert teacher.answer("a", 0)[0] == 200
    assert teacher.answer("b", 1)[0] == 200
    session = teacher._session
    teacher._wait_for_answers()  # all answered: the session closes
    assert [q.label() for q in session.queries] == [0, 1] and teacher._session is None
    status, _, _ = request(teacher.url + "api/undo", {})  # a late Backspace
    assert status == 409
    assert teacher.answer("b", 0)[0] == 409
    assert [entry.label for entry in teacher.model.journal_history()] == [0, 1]


def test_clips_being_written_are_not_served(open_session):
    (open_session._clips_folder() / "a-left.mp4.part").write_bytes(b"half a clip")
    status, _, _ = request(open_session.url + "clips/a-left.mp4.part")
    assert status == 404


# several annotators --------------------------------------------------------------------------------------------------
def test_links_carry_secret_tokens_printed_once_and_a_loaded_teacher_makes_new_ones(serve, capsys):
    teacher = serve(annotators=["ana", "ben"])
    out = capsys.readouterr().out
    assert set(teacher.links) == {"ana", "ben"} and len(set(teacher.links.values())) == 2
    assert all(link.startswith(teacher.url + "?token=") and link in out for link in teacher.links.values())
    teacher._start_server()  # attached again (a new env): the same server, the links are not printed again
    assert capsys.readouterr().out == ""
    loaded = pickle.loads(pickle.dumps(teacher))
    assert loaded.annotators == ["ana", "ben"] and loaded._server is None
    assert not set(loaded._tokens.values()) & set(teacher._tokens.values())  # tokens are never saved
    older = WebTeacher.__new__(WebTeacher)  # as pickle makes a teacher saved before several annotators existed
    older.__setstate__(_settings_of_an_old_teacher())
    assert older.annotators is None and older.known_answer_rate == 0 and older.links == {}


def _settings_of_an_old_teacher() -> dict:
    """What a model saved before several annotators existed holds of its WebTeacher."""
    return dict(port=0, host="127.0.0.1", timeout=None, width=320, height=240, clip_dir=None, reminder_interval=60.0,
                camera=None)  # fmt: skip


def test_serving_beyond_localhost_with_annotators(serve):
    teacher = serve(annotators=["ana"], host="0.0.0.0")
    assert teacher.url == f"http://{socket.gethostname()}:{teacher.port}/"
    status, _, _ = request(f"http://127.0.0.1:{teacher.port}/api/state")
    assert status == 401
    status, _, body = request(f"http://127.0.0.1:{teacher.port}/api/state?token=" + teacher.links["ana"].split("token=")[1])
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
    clip = teacher.url + ana.state()["query"]["left"].lstrip("/")
    for url, body, headers in (
        (teacher.url + "api/state", None, {}),
        (teacher.url + "api/state", None, {"X-Annotator-Token": "guess"}),
        (teacher.url + "api/state?token=", None, {}),
        (teacher.url + "api/answer", {"id": first_of_ana, "label": 1}, {}),
        (teacher.url + "api/undo", {}, {"X-Annotator-Token": "guess"}),
        (clip, None, {}),
    ):
        status, _, reply = request(url, body, headers)
        assert status == 401 and "token" in json.loads(reply)["error"], url
    assert request(clip + "?token=" + ana.headers["X-Annotator-Token"])[0] == 200
    status, _, page = request(teacher.url)  # the page itself holds nothing: it asks for the token
    assert status == 200 and b"X-Annotator-Token" in page
    # malformed, a label outside {0, 0.5, 1, null}, another's query, an unknown one
    for body in (b"{", b"[1, 2]", {"label": 1}, {"id": first_of_ana}):
        assert request(teacher.url + "api/answer", body, ana.headers)[0] == 400, body
    status, _, reply = request(teacher.url + "api/answer", {"id": first_of_ana, "label": 1, "pad": "x" * 70_000}, ana.headers)
    assert status == 413 and json.loads(reply)["error"]
    for label in (0.7, "left", True, -1, 2):
        assert ana.answer(first_of_ana, label) == 400, label
    assert ana.answer(first_of_ben, 1) == 403  # handed to ben, not to ana
    assert ana.answer("nonexistent", 1) == 404
    assert ana.undo() == 409  # nothing to undo yet
    nothing_recorded()
    # replays: the same answer again, and a query that has its answer
    assert ana.answer(first_of_ana, 1) == 200
    answered = teacher._session.find(first_of_ana).pair
    assert ana.answer(first_of_ana, 1) == 409 and ana.answer(first_of_ana, 0) == 409
    assert ben.answer(first_of_ana, 0) == 409
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
    ids = [query.id for query in teacher._session.queries]
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
    assert [(entry.id, entry.annotator, _label(entry)) for entry in entries] == [
        (pair[0], "ana", 1), (pair[0], "ben", 0), (pair[1], "ana", 0), (pair[1], "ben", "skip"), (pair[2], "ana", 1),
        (pair[2], "ben", 1),
    ]  # fmt: skip
    agreement = teacher.agreement()
    assert agreement["ana"]["pairwise_agreement"] == 0.5 and agreement["ana"]["compared_answers"] == 2
    assert agreement["ben"]["answers"] == 3 and agreement["ben"]["skips"] == 1
    assert run.logged["annotators/ana/pairwise_agreement"] == 0.5 and run.logged["annotators/ben/answers"] == 3
    assert json.loads((tmp_path / "report.json").read_text())["annotators"] == agreement


def test_a_careless_annotator_is_flagged_by_known_answers(serve, tmp_path, monkeypatch, capsys):
    """ana answers from the true reward, ben at random: the known-answer questions tell them apart."""
    monkeypatch.setattr("sb3_pride.human.render.encode_mp4", lambda frames, fps, path: Path(path).write_bytes(b"mp4"))
    teacher = serve(annotators=["ana", "ben"], known_answer_rate=0.4, seed=0, report_path=tmp_path / "report.json")
    run, pairs = Run(tmp_path / "preferences.jsonl"), make_pairs(60)
    thread, result = ask_in_thread(teacher, pairs, run.context())
    pages, coin = [Page(teacher, "ana"), Page(teacher, "ben")], np.random.default_rng(1)
    while thread.is_alive():
        for page in pages:
            shown = page.shown()
            if shown is not None and teacher._session is not None:
                careful = true_answer(pairs, teacher._session.find(shown).inputs)
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


def test_instructions_default_to_the_task(serve):
    assert "walker" in default_instructions("sb3_pride/walker-walk-v0")
    assert "cheetah" in default_instructions("sb3_pride/cheetah-run-v0")
    assert "button" in default_instructions("sb3_pride/button-press-v3")
    assert "door" in default_instructions("sb3_pride/door-open-v3")
    assert default_instructions("sb3_pride/unknown-task-v0") == default_instructions(None) == GENERIC_INSTRUCTIONS
    teacher = serve()
    assert Page(teacher).state()["instructions"] == GENERIC_INSTRUCTIONS  # no env seen yet
    teacher._env_id = "sb3_pride/walker-walk-v0"  # as attach() sees it
    assert Page(teacher).state()["instructions"] == default_instructions("sb3_pride/walker-walk-v0")
    teacher.instructions = "Prefer <b>faster</b> walkers."
    assert Page(teacher).state()["instructions"] == "Prefer <b>faster</b> walkers."


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
        first = teacher.state()["query"]
        for label in (0, 1):
            assert teacher.answer(teacher.state()["query"]["id"], label)[0] == 200
        np.testing.assert_array_equal(finish(thread, result), [0, 1])
    finally:
        teacher.close()
    with av.open(str(tmp_path / "clips" / Path(first["left"]).name)) as container:
        frames = [frame.to_ndarray(format="rgb24") for frame in container.decode(video=0)]
    assert len(frames) == 10 and frames[0].shape == (24, 32, 3) and frames[0].std() > 5  # a picture, not a blank


# known-answer questions, the log, what other sites may send ----------------------------------------------------------
def test_known_answer_questions_look_like_any_other_and_their_first_answer_counts(serve, tmp_path, monkeypatch):
    """One person, true-reward known answers of feedback session 1 shown again in the next: nothing on the page moves
    differently on them, their clips carry no ETag of their own, and an undo does not change their score."""
    monkeypatch.setattr("sb3_pride.human.render.encode_mp4", lambda frames, fps, path: Path(path).write_bytes(b"mp4"))
    teacher = serve(known_answer_rate=0.6, seed=0)
    run, page = Run(tmp_path / "preferences.jsonl"), Page(teacher)
    first = make_pairs(8)
    thread, result = ask_in_thread(teacher, first, run.context(1))
    while (shown := page.shown()) is not None:
        assert page.answer(shown, true_answer(first, teacher._session.find(shown).inputs)) == 200
    finish(thread, result)
    assert (
        teacher._known and teacher.agreement()["anonymous"]["known_answers"] == 0
    )  # none shown in the first feedback session
    second = make_pairs(8, seed=1)
    thread, result = ask_in_thread(teacher, second, run.context(2))
    known_seen = 0
    while (state := page.state())["query"] is not None:
        shown = state["query"]["id"]
        assert state["budget"] == {"max": 100, "asked": 8}  # fixed for the session
        assert all(row[key] is None for row in state["team"] for key in ("known_answers", "known_answer_agreement"))
        question = teacher._session.find(shown)
        clip = request(teacher.url + state["query"]["left"].lstrip("/"))
        assert clip[0] == 200 and "ETag" not in clip[1] and clip[1]["Last-Modified"]
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
    stats = teacher.agreement()["anonymous"]
    assert stats["known_answers"] == known_seen and stats["known_answer_agreement"] == 0
    assert stats["answers"] == 16 + known_seen and len(run.journal.read()) == 16  # known ones are not journaled
    between = page.state()["team"][0]
    assert between["known_answers"] == known_seen and between["session"] == 0  # shown once the session is over


def test_tokens_never_reach_the_server_log(serve, caplog, capfd):
    teacher = serve(annotators=["ana"])
    token = teacher.links["ana"].split("token=")[1]
    capfd.readouterr()
    with caplog.at_level("INFO", logger="werkzeug"):
        assert request(teacher.url + f"clips/missing.mp4?token={token}")[0] == 404
        assert request(teacher.url + f"api/answer?token={token}", {"id": "x"})[0] == 400
        assert request(teacher.url + f"clips/x.mp4?other=1&token={token}&b=2")[0] == 404
    time.sleep(0.2)  # the server's thread logs after it answered
    out, err = capfd.readouterr()
    logged = caplog.text + out + err
    assert "clips/missing.mp4?token=..." in logged and " 404 " in logged
    assert token not in logged


def test_tokens_are_required_beyond_localhost_whenever_the_server_starts(tmp_path):
    teacher = WebTeacher(port=0)
    teacher.host = "0.0.0.0"  # set after construction
    with pytest.raises(ValueError, match="annotators"):
        teacher._start_server()
    assert teacher._server is None
    loaded = pickle.loads(pickle.dumps(WebTeacher(port=0)))
    loaded.__setstate__({**loaded.__getstate__(), "host": "0.0.0.0"})  # as a teacher saved with another host
    with pytest.raises(ValueError, match="annotators"):
        loaded._start_server()


def test_true_reward_known_answers_need_a_return_scale():
    teacher = WebTeacher(port=0, known_answer_rate=0.5)
    rewards = np.array([[1.0, 1.0], [1.0, 1.001], [0.0, 3.0], [2.0, 0.0]])[..., None].repeat(4, axis=-1)

    def pairs(rewards: np.ndarray, return_scale: float) -> SegmentPairs:
        return SegmentPairs(np.zeros((4, 2, 4, 3)), np.zeros((4, 2, 4, 1)), rewards, return_scale, np.zeros((4, 2, 4, 1)))

    # return_scale ~ 0: the margin is measured in the spread of the pairs' returns instead, so 0.004 is not clear
    assert teacher._known_from_reward(pairs(rewards, 1e-12)) == [None, None, 1.0, 0.0]
    assert teacher._known_from_reward(pairs(rewards, 1e-3)) == [None, None, 1.0, 0.0]
    flat = np.ones_like(rewards) + 1e-15 * rewards
    assert teacher._known_from_reward(pairs(flat, 0.0)) == [None] * 4  # no scale at all: no known answer


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
    pairs = make_pairs(2)
    thread, result = ask_in_thread(teacher, pairs, run.context())
    while (shown := page.shown()) is not None:
        assert page.answer(shown, 1) == 200
    np.testing.assert_array_equal(finish(thread, result), [1, 1])  # the session's answers are given to the model
    assert "could not be written" in capsys.readouterr().out
    teacher.close()  # warns again, and stops the server all the same
    assert teacher._server is None and "could not be written" in capsys.readouterr().out


def test_other_sites_cannot_post_or_rebind(open_session):
    """A form of another site (no JSON), a page reached under another name (DNS rebinding): refused, nothing recorded."""
    teacher = open_session
    assert teacher.state()["query"]["id"] == "a"
    form = {"Content-Type": "application/x-www-form-urlencoded"}
    assert request(teacher.url + "api/answer", b"id=a&label=1", form)[0] == 415
    assert request(teacher.url + "api/answer", b'{"id": "a", "label": 1}', {"Content-Type": "text/plain"})[0] == 415
    assert request(teacher.url + "api/answer", {"id": "a", "label": 1})[0] == 200
    assert request(teacher.url + "api/undo", b"", form)[0] == 415
    assert request(teacher.url + "api/undo", b"")[0] == 400  # JSON, but no object
    rebound = {"Host": f"evil.example:{teacher.port}"}
    assert request(teacher.url + "api/undo", {}, rebound)[0] == 403
    assert request(teacher.url + "api/state", None, rebound)[0] == 403
    assert request(teacher.url + "clips/a-left.mp4", None, rebound)[0] == 403
    assert [entry.label for entry in teacher.model.journal_history()] == [1]  # the one JSON answer, not undone
    for host in (f"localhost:{teacher.port}", f"[::1]:{teacher.port}", "127.0.0.1"):
        assert request(teacher.url + "api/state", None, {"Host": host})[0] == 200, host


def test_an_error_in_a_route_is_a_json_500(open_session, monkeypatch):
    def broken(annotator=None):
        raise RuntimeError("broken")

    monkeypatch.setattr(open_session, "state", broken)
    status, _, body = request(open_session.url + "api/state")
    assert status == 500 and "RuntimeError: broken" in json.loads(body)["error"]


def test_known_pairs_are_never_shown_to_who_made_them(serve):
    """A majority's pair is never a known-answer question for its voters, nor a pair one answered, with annotators."""
    teacher = serve(annotators=["ana", "ben", "cal"], answers_per_query=2, known_answer_rate=0.5)
    inputs = np.zeros((2, 4, 3))
    majority = _Known(query_id(inputs), inputs, ("m-left.mp4", "m-right.mp4"), 1.0, "majority", frozenset({"ana", "ben"}))
    teacher._known.append(majority)
    teacher._seen[majority.pair] = {"ana", "ben"}
    reward = _Known(query_id(inputs + 1), inputs + 1, ("r-left.mp4", "r-right.mp4"), 0.0, "true reward")
    teacher._known.append(reward)
    teacher._seen[reward.pair] = {"cal"}
    session = _Session(2, [], 0, Run(Path("/dev/null")).context(2))
    teacher._seen[majority.pair].discard("ana")  # even were her answer taken back
    assert teacher._known_question(session, "ana").pair == reward.pair
    assert teacher._known_question(session, "ana") is None  # each pair once a session, the majority never
    assert teacher._known_question(session, "cal").pair == majority.pair
    assert teacher._known_question(session, "cal") is None  # the true-reward pair is hers already: not shown again
    alone = serve(known_answer_rate=0.5)
    alone._known.append(reward)
    alone._seen[reward.pair] = {"anonymous"}
    assert alone._known_question(session, "anonymous").pair == reward.pair  # one person: shown again


# in a real browser ---------------------------------------------------------------------------------------------------
def _chromium():
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

    driver = _chromium()
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
            drivers[name] = _chromium()
            drivers[name].get(teacher.links[name])
        shown = {name: _wait(lambda d=driver: _playing(d)) for name, driver in drivers.items()}
        assert shown["ana"] != shown["ben"]  # two people, two different queries
        instructions = drivers["ana"].find_element("id", "instructions")
        assert instructions.text == "Prefer <b>upright</b> walkers." and not instructions.find_elements("tag name", "b")
        # ana: left, then undo and right; ben: equal, skip; then whatever is left
        for name, key in (("ana", Keys.ARROW_LEFT), ("ben", Keys.ARROW_DOWN), ("ana", Keys.BACKSPACE),
                          ("ana", Keys.ARROW_RIGHT), ("ben", "s")):  # fmt: skip
            before = _wait(lambda n=name: _playing(drivers[n]) or model.feedback_sessions == 1)
            drivers[name].find_element("tag name", "body").send_keys(key)
            _wait(lambda n=name, b=before: _playing(drivers[n]) != b or model.feedback_sessions == 1)
        while training.is_alive() and model.feedback_sessions == 0:
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
    assert model.feedback_sessions == 1 and model.feedback_asked == 4
    entries = PreferenceJournal(journal).read()
    assert len(entries) == 4 and len({entry.id for entry in entries}) == 4  # no query answered twice
    assert {entry.annotator for entry in entries} == {"ana", "ben"} and all(entry.time for entry in entries)
    by_annotator = {name: [_label(e) for e in entries if e.annotator == name] for name in ("ana", "ben")}
    assert by_annotator["ana"][0] == 1 and by_annotator["ben"][:2] == [0.5, "skip"]  # ana's undo took back her "left"


def _label(entry) -> float | str:
    return "skip" if math.isnan(entry.label) else entry.label


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
    state = teacher.state()
    if state["session"] != session or state["query"] is None:
        return None
    shown = _playing(driver)
    return shown if shown == state["query"]["id"] else None


def _wait(condition, timeout: float = 60.0):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        value = condition()
        if value:
            return value
        time.sleep(0.05)
    raise AssertionError("timed out waiting for the page")
