"""WebTeacher's server on a real port of this machine: what only a socket shows (the links printed when it starts,
the console's masked tokens, the deadline of a connection, the cap on open connections, bodies left unread). Everything
else of HTTP is tested through the app's test client."""

import select
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path
import urllib.error
import urllib.request

import pytest
from test_web import FakeBuffer, FakeEnv, black_clip_teachers, wait

from sb3_pride.human import WebTeacher

pytest.importorskip("flask")


@pytest.fixture
def attached(tmp_path):
    """Makes WebTeachers attached to a stand-in env (black clips, no MuJoCo): their server serves on a free port."""
    with black_clip_teachers(tmp_path / "clips") as make:

        def attach(max_connections: int | None = None, **kwargs) -> WebTeacher:
            teacher = make(**kwargs)
            if max_connections is not None:
                teacher.server.max_connections = max_connections
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


def exchange(port: int, data: bytes, timeout: float = 10.0, half_close: bool = False) -> tuple[bytes, float]:
    """Send ``data`` on a new connection (then close its sending side, with ``half_close``); (everything the server
    answers until it closes, seconds it took)."""
    start, answer = time.monotonic(), b""  # the server's deadline counts from its accept, after this
    with socket.create_connection(("127.0.0.1", port), timeout=timeout) as connection:
        connection.sendall(data)
        if half_close:
            connection.shutdown(socket.SHUT_WR)
        while chunk := connection.recv(65536):
            answer += chunk
        return answer, time.monotonic() - start


def test_links_are_printed_once_when_the_server_starts(attached, capsys):
    teacher = attached(annotators=["ana", "ben"])
    out = capsys.readouterr().out
    assert teacher.server.running and teacher.port == teacher.server.port > 0
    assert all(link in out for link in teacher.links.values())
    teacher.attach(FakeEnv(), FakeBuffer())  # attached again (a new env): the same server, the links are not printed again
    again = capsys.readouterr().out
    assert not any(link in again for link in teacher.links.values()) and teacher.port == teacher.server.port
    teacher.close()
    assert not teacher.server.running


def test_tokens_never_reach_the_server_log(attached, caplog, capfd):
    """Masked however the address spells it: any case, its name or its "=" percent-encoded, or where no parameter
    named token is (the token itself is masked wherever it is)."""
    teacher = attached(annotators=["ana"])
    token = teacher.links["ana"].split("token=")[1]
    capfd.readouterr()
    with caplog.at_level("INFO", logger="werkzeug"):
        assert get(teacher.url + f"clips/missing.mp4?token={token}") == 404
        assert get(teacher.url + f"api/answer?token={token}", b'{"id": "x"}') == 400
        assert get(teacher.url + f"clips/x.mp4?other=1&token={token}&b=2") == 404
        for spelled in ("TOKEN=", "Token=", "token%3D", "token%3d", "%74oken=", "%54OKEN%3D", "tok%2565n=", "t="):
            assert get(teacher.url + f"clips/missing.mp4?{spelled}{token}") in (401, 404), spelled  # both logged
        assert get(teacher.url + f"clips/{token}.mp4") == 401
        time.sleep(0.2)  # the server's thread logs after it answered
    out, err = capfd.readouterr()
    logged = caplog.text + out + err
    assert "clips/missing.mp4?token=..." in logged and " 404 " in logged
    assert "?TOKEN=..." in logged and "?token%3D..." in logged and "?tok%2565n=..." in logged and "clips/....mp4" in logged
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


def still_open(connection: socket.socket) -> bool:
    """Whether the server has not closed ``connection`` (nothing to read, or data but no end)."""
    readable, _, _ = select.select([connection], [], [], 0)
    if not readable:
        return True
    try:
        return connection.recv(65536, socket.MSG_PEEK) != b""
    except OSError:
        return False


def test_a_request_sent_byte_by_byte_is_dropped_at_its_deadline(attached, caplog, capfd):
    """read_timeout bounds a whole connection, not each read: clients that send a byte every 0.2 s (each read well
    within the timeout) are dropped read_timeout seconds after they connected, what they sent is neither answered nor
    logged (it is not a request), and the server goes on."""
    teacher = attached(read_timeout=1.0, annotators=["ana"])  # a request without a token would be logged (401)
    capfd.readouterr()
    connections, opened, closed = [], [], {}  # each timed from its own connect: the deadline counts from its accept
    for _ in range(5):
        opened.append(time.monotonic())
        connections.append(socket.create_connection(("127.0.0.1", teacher.port), timeout=5))
    try:
        for connection in connections:
            connection.sendall(b"GET /api/state HTTP/1.1\r\nHost: 127.0.0.1\r\nX-Slow: ")
        while time.monotonic() - opened[0] < 8.0 and len(closed) < len(connections):  # a deadline per read: never
            for i, connection in enumerate(connections):
                if i not in closed:
                    if still_open(connection):
                        try:
                            connection.sendall(b"a")
                        except OSError:
                            closed[i] = time.monotonic() - opened[i]
                    else:
                        closed[i] = time.monotonic() - opened[i]
            time.sleep(0.2)
    finally:
        for connection in connections:
            connection.close()
    assert len(closed) == len(connections) and all(0.9 < took < 5.0 for took in closed.values()), closed
    time.sleep(0.2)  # the server's threads would log after they answered
    assert "X-Slow" not in caplog.text and "GET /api/state" not in caplog.text + "".join(capfd.readouterr())
    assert get(teacher.url + "api/state") == 401  # the server goes on


def test_a_request_whose_head_never_ends_is_not_answered(attached, caplog, capfd):
    """A client that stops half-way through the head of its request and closes its side: what it sent is not a
    request (no blank line ended its head), so nothing is answered, run or logged."""
    teacher = attached(annotators=["ana"])
    capfd.readouterr()
    with caplog.at_level("INFO", logger="werkzeug"):
        for cut in (b"GET /api/state HTTP/1.1\r\nHost: 127.0.0.1\r\nX-Cut: aa", b"GET /api/state HTTP/1.1\r\nHost: 1"):
            answer, _ = exchange(teacher.port, cut, half_close=True)
            assert answer == b"", answer[:40]
        time.sleep(0.2)
    assert "GET /api/state" not in caplog.text + "".join(capfd.readouterr())


def handler_threads() -> list[threading.Thread]:
    return [thread for thread in threading.enumerate() if "process_request_thread" in thread.name]


def test_open_connections_are_capped_and_the_page_still_answers(attached):
    """Past max_connections open connections, the oldest is closed for each new one: 40 clients that connect and send
    nothing hold at most 8 threads, and a request of the page is still answered at once."""
    teacher = attached(max_connections=8)
    before = len(handler_threads())
    idle = [socket.create_connection(("127.0.0.1", teacher.port), timeout=5) for _ in range(40)]
    try:
        # the server accepts and closes them in its own time on a loaded machine
        wait(lambda: len(handler_threads()) - before <= 8 and sum(map(still_open, idle)) <= 8, timeout=10)
        assert len(handler_threads()) - before <= 8
        assert sum(still_open(connection) for connection in idle) <= 8
        start = time.monotonic()
        assert get(teacher.url + "api/state") == 200 and time.monotonic() - start < 10
    finally:
        for connection in idle:
            connection.close()


def send_until_refused(port: int, head: bytes, size: int) -> tuple[int, bytes]:
    """Send ``head`` then up to ``size`` bytes of body; (bytes of body the server let through, what it answered)."""
    with socket.create_connection(("127.0.0.1", port), timeout=5) as connection:
        connection.sendall(head)
        sent, chunk = 0, b"x" * 65536
        try:
            while sent < size:
                connection.sendall(chunk)
                sent += len(chunk)
        except OSError:  # closed by the server: a reset, a broken pipe, or the send timed out
            pass
        try:
            answer = connection.recv(65536)
        except OSError:
            answer = b""
        return sent, answer


def test_a_refused_body_is_not_read(attached):
    """A request refused before its body is read (no token) gets no body read after its answer either: the connection
    is closed instead, so a client announcing 200 MB pushes no more than the kernel's buffers take. An
    ``Expect: 100-continue`` is answered only when the app reads the body: a refused one is told so at once. A short
    body (the page's own, say with a token that expired) is still read, so that its refusal reaches the page."""
    teacher = attached(annotators=["ana"])
    head = (b"POST /api/answer HTTP/1.1\r\nHost: 127.0.0.1\r\nContent-Type: application/json\r\n"
            b"Content-Length: 200000000\r\n")  # fmt: skip
    sent, _ = send_until_refused(teacher.port, head + b"\r\n", 64 * 2**20)
    assert sent < 32 * 2**20, sent
    with socket.create_connection(("127.0.0.1", teacher.port), timeout=5) as connection:
        connection.sendall(head + b"Expect: 100-continue\r\n\r\n")
        answer = connection.recv(65536)
    assert answer.startswith(b"HTTP/1.1 401"), answer[:60]
    assert get(teacher.url + "api/answer", b'{"id": "x", "label": 1}') == 401
    token = teacher.links["ana"].split("token=")[1]
    assert get(teacher.url + f"api/answer?token={token}", b'{"id": "x"}') == 400


@pytest.mark.slow
def test_the_probe_reads_that_the_server_keeps_its_limits():
    """benchmarks/web_probe.py, small: two annotators comparing notes see known-answer questions and queries alike, the
    page refuses framing, refused bodies are not read, slow sockets are dropped at their deadline and the connections'
    threads stay within the limit."""
    probe = Path(__file__).resolve().parent.parent / "benchmarks" / "web_probe.py"
    settings = (
        "--dripping 5 --slow 100 --max-connections 10 --attack 1 --bodies 3 --pairs 6 --segment-length 4 --read-timeout 1"
    )
    done = subprocess.run([sys.executable, str(probe), *settings.split()], capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-2000:]
    rows = {}
    for line in done.stdout.splitlines():
        if line.startswith("| ") and not line.startswith("| |"):
            cells = [cell.strip() for cell in line.strip("|").split("|")]
            rows[cells[0]] = cells[1:]
    known, queries = rows["known-answer questions"], rows["the model's queries"]
    assert int(known[0]) > 0 and known[1] == queries[1] == "403 \"question '<id>' is not the one shown to you\""
    # no clip's bytes shared between questions, nor both clips' sizes (one clip's size may match another's by chance)
    assert known[2] == queries[2] == "0" and known[4] == queries[4] == "0"
    assert rows["`GET /`"][1:] == ["DENY", "frame-ancestors 'none'"]
    assert all(float(mb) < 8 for mb in rows["MB of body each could send before the server closed it"][0].split(","))
    epoll = next(cells for name, cells in rows.items() if name.startswith("child epoll descriptors"))[0]
    assert epoll.split(" / ")[1] == "0"
    assert rows["closed by the server"][0].startswith("5 of 5")
    before, peak, after = map(int, rows["child threads: before / peak / after"][0].split(" / "))
    assert peak <= before + 40 and after == before  # 10 open, some closed ones ending; 100 without the limit
