"""WebTeacher's server on a real port of this machine: what only a socket shows (the links printed when it starts,
the console's masked tokens, the read timeout). Everything else of HTTP is tested through the app's test client."""

import socket
import time
import urllib.error
import urllib.request

import pytest
from test_web import FakeBuffer, FakeEnv, black_clip_teachers

from sb3_pride.human import WebTeacher

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
