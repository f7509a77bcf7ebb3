"""WebTeacher's server on a real port of this machine: what only a socket shows (the links printed when it starts,
the console's masked tokens, the read timeout, a body streamed in chunks)."""

import json
import socket
import time
import urllib.error
import urllib.request

import pytest
from test_web import FakeBuffer, FakeEnv, Run, black_clip_teachers, make_pairs, wait

from sb3_pride.human import Question, Session, WebTeacher

pytest.importorskip("flask")


@pytest.fixture
def attached(tmp_path):
    """Makes WebTeachers attached to a stand-in env (black clips, no MuJoCo): their server serves on a free port."""
    with black_clip_teachers(tmp_path / "clips") as make:

        def attach(**kwargs) -> WebTeacher:
            teacher = make(**kwargs)
            teacher.attach(FakeEnv(), FakeBuffer())
            return teacher

        yield attach


def get(url: str, body: bytes | None = None) -> int:
    request = urllib.request.Request(url, data=body, headers={"Content-Type": "application/json"})
    try:
        with urllib.request.urlopen(request, timeout=10) as response:
            return response.status
    except urllib.error.HTTPError as error:
        return error.code


def exchange(port: int, data: bytes, timeout: float = 10.0) -> tuple[bytes, float]:
    """Send ``data`` on a new connection; (everything the server answers until it closes, seconds it took)."""
    with socket.create_connection(("127.0.0.1", port), timeout=timeout) as connection:
        connection.sendall(data)
        start, answer = time.monotonic(), b""
        while chunk := connection.recv(65536):
            answer += chunk
        return answer, time.monotonic() - start


def test_links_are_printed_once_when_the_server_starts(attached, capsys):
    teacher = attached(annotators=["ana", "ben"])
    out = capsys.readouterr().out
    assert teacher.server.running and teacher.port == teacher.server.port > 0
    assert all(link in out for link in teacher.links.values())
    teacher.attach(FakeEnv(), FakeBuffer())  # attached again (a new env): the same server, the links are not printed again
    assert capsys.readouterr().out == "" and teacher.port == teacher.server.port
    teacher.close()
    assert not teacher.server.running


def test_tokens_never_reach_the_server_log(attached, caplog, capfd):
    teacher = attached(annotators=["ana"])
    token = teacher.links["ana"].split("token=")[1]
    capfd.readouterr()
    with caplog.at_level("INFO", logger="werkzeug"):
        assert get(teacher.url + f"clips/missing.mp4?token={token}") == 404
        assert get(teacher.url + f"api/answer?token={token}", b'{"id": "x"}') == 400
        assert get(teacher.url + f"clips/x.mp4?other=1&token={token}&b=2") == 404
        time.sleep(0.2)  # the server's thread logs after it answered
    out, err = capfd.readouterr()
    logged = caplog.text + out + err
    assert "clips/missing.mp4?token=..." in logged and " 404 " in logged
    assert token not in logged


def test_a_half_sent_request_is_dropped_after_the_read_timeout(attached):
    """A client that sends part of its request and stops holds a server thread for read_timeout seconds, no more:
    with host="0.0.0.0" anyone who reaches the port could otherwise hold threads without a token."""
    teacher = attached(read_timeout=0.5)
    for half in (b"GET /api/state HTTP/1.1\r\nHost: 127.0.0.1\r\n",  # no blank line: the headers never end
                 b"POST /api/answer HTTP/1.1\r\nHost: 127.0.0.1\r\nContent-Type: application/json\r\n"
                 b"Content-Length: 100\r\n\r\n{\"id\": "):  # fmt: skip  # a body that stops short
        answer, took = exchange(teacher.port, half)
        assert 0.4 < took < 5 and not answer.startswith(b"HTTP/1.1 200"), (half, answer, took)
    assert get(teacher.url + "api/state") == 200  # the server goes on


def test_a_chunked_body_past_64_kib_is_refused(attached, tmp_path):
    """Streamed in chunks (no Content-Length), a padded answer is refused whole, not cut at 64 KiB and taken."""
    teacher = attached()
    run = Run(tmp_path / "preferences.jsonl")
    queries = [Question("a", make_pairs(1).inputs[0], ready=True)]
    teacher.store.begin(Session(1, queries, 0, run.context()))
    assert teacher.state()["query"]["id"] == "a"
    body = b'{"id": "a", "label": 1}' + b" " * 70_000
    chunks = b"".join(b"%x\r\n%s\r\n" % (len(part), part) for part in (body[:40_000], body[40_000:])) + b"0\r\n\r\n"
    head = (
        b"POST /api/answer HTTP/1.1\r\nHost: 127.0.0.1\r\nContent-Type: application/json\r\nTransfer-Encoding: chunked\r\n\r\n"
    )
    answer, _ = exchange(teacher.port, head + chunks)
    assert answer.startswith(b"HTTP/1.1 413") and json.loads(answer.split(b"\r\n\r\n", 1)[1])["error"], answer[:200]
    assert run.journal.read() == [] and wait(lambda: teacher.state()["answered"] == 0)
