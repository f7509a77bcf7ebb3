"""
A ``WebTeacher``'s page on the network: its Flask app (``create_app``) served by werkzeug's threaded server in a
daemon thread, with the annotators' secret tokens, a deadline on every connection, a cap on open connections, no body
read past a refusal, and a console that never shows a token.

werkzeug answers one request per connection (``Connection: close``), so a connection's deadline is its request's:
``read_timeout`` seconds from its ``accept`` to its close, however slowly the bytes come (a timeout on each read alone
lets a client that sends a byte every few seconds hold a thread forever). A production WSGI server (waitress, cheroot)
was weighed: their timeouts are per read or for idle connections, and their connection limits stop accepting, so
neither bounds such a client; the limits here are a few lines over werkzeug's own server.
"""

import re
import secrets
import socket
import threading
import time
from collections.abc import Callable, Iterable
from functools import cached_property
from http.server import BaseHTTPRequestHandler
from typing import TYPE_CHECKING, Any

from sb3_pride.human.app import MAX_BODY, create_app
from sb3_pride.human.clips import Clips
from sb3_pride.human.settings import GENERIC_INSTRUCTIONS, MAX_CONNECTIONS, READ_TIMEOUT, refuse_anonymous_beyond_this_machine
from sb3_pride.human.store import AnswerStore

if TYPE_CHECKING:
    from flask import Flask


def spelled(text: str) -> str:
    """A pattern of ``text`` however an address may spell it: each character as itself or percent-encoded (also twice
    or more, ``%2574``); match it with ``re.IGNORECASE`` for any case."""
    return "".join(f"(?:{re.escape(char)}|%(?:25)*{ord(char):02x})" for char in text)


#: a token in a logged line: ``token=...`` in any case, its name or its ``=`` percent-encoded (``?TOKEN=``,
#: ``?token%3D``, ``?%74oken=``)
TOKEN_IN_URL = re.compile(rf"({spelled('token')}{spelled('=')})[^&;\s\"']*", re.IGNORECASE)


def mask_tokens(line: str, tokens: Iterable[str] = ()) -> str:
    """``line`` with every token masked (``...``): after a ``token=`` however spelled (``TOKEN_IN_URL``), and each of
    ``tokens`` wherever it is (a token typed into the path, or under another parameter's name)."""
    line = TOKEN_IN_URL.sub(r"\1...", line)
    for token in tokens:
        line = line.replace(token, "...")
    return line


class Connections:
    """
    A server's open connections, each with when it was accepted: at most ``limit`` of them (the oldest is closed for
    each new one, so that clients who hold connections cannot lock others out) and none open longer than ``deadline``
    seconds (``expire()``). A connection is closed by shutting its socket down: the thread reading or writing it wakes
    at once and ends.

    :param limit: the most connections open at once
    :param deadline: seconds a connection may stay open: its request received and its answer sent
    """

    def __init__(self, limit: int = MAX_CONNECTIONS, deadline: float = READ_TIMEOUT):
        self.limit, self.deadline = limit, deadline
        self._open: dict[socket.socket, float] = {}  # in the order they were accepted
        self._shut_down: set[socket.socket] = set()  # closed by this class, their threads not yet over
        self._lock = threading.Lock()

    def __len__(self) -> int:
        return len(self._open)

    def admit(self, connection: socket.socket) -> None:
        """Count in a new connection; beyond ``limit``, close the oldest."""
        with self._lock:
            while len(self._open) >= self.limit:
                self._shut(next(iter(self._open)))
            self._open[connection] = time.monotonic()

    def expire(self) -> None:
        """Close the connections open longer than ``deadline``."""
        now = time.monotonic()
        with self._lock:
            for connection in [c for c, since in self._open.items() if now - since > self.deadline]:
                self._shut(connection)

    def was_shut(self, connection: socket.socket) -> bool:
        """Whether ``connection`` was closed here (its deadline, or the limit): what it sent is not a request."""
        return connection in self._shut_down

    def release(self, connection: socket.socket, close: Callable[[], None]) -> None:
        """``close()`` the ``connection`` whose request is over (no shutdown of this class races it), and forget it."""
        with self._lock:
            self._open.pop(connection, None)
            self._shut_down.discard(connection)
            close()

    def close_all(self) -> None:
        """Close every open connection (the server stops)."""
        with self._lock:
            for connection in list(self._open):
                self._shut(connection)

    def _shut(self, connection: socket.socket) -> None:
        del self._open[connection]
        self._shut_down.add(connection)
        try:
            connection.shutdown(socket.SHUT_RDWR)
        except OSError:  # closed by the client already
            pass


class RequestInput:
    """
    A connection's input as its request handler reads it. The app reads its request's body through it, and an
    ``Expect: 100-continue`` is answered only then: a request refused before its body is read is not sent the body.
    Once the answer has begun, at most ``leftover`` more bytes are read (werkzeug reads what the app left of a body
    before it closes the connection, up to 10 GB): the rest of a body of at most ``MAX_BODY`` bytes, so that its client
    sees the answer, and nothing of a longer or chunked one, whose connection is closed unread instead.

    :param stream: the connection's buffered input
    :param send_continue: writes the ``100 Continue`` interim answer
    """

    def __init__(self, stream: Any, send_continue: Callable[[], None]):
        self._stream, self._send_continue = stream, send_continue
        #: an ``Expect: 100-continue`` waits for the app's first read of the body
        self.expect_continue = False
        #: the answer has begun: the app has read all it will
        self.answered = False
        #: bytes that may still be read once ``answered``
        self.leftover = 0
        #: the last line read was a blank one (a request's head ends with it; a connection closed before has none)
        self.blank_line = False

    def _body(self) -> None:
        if self.expect_continue:
            self.expect_continue = False
            self._send_continue()

    def read(self, size: int | None = -1) -> bytes:
        if not self.answered:
            self._body()
            return self._stream.read(size)
        size = self.leftover if size is None or size < 0 else min(size, self.leftover)
        data = self._stream.read1(size) if size > 0 else b""  # read1: what has come, never waiting for more
        self.leftover -= len(data)
        return data

    def readinto(self, buffer: Any) -> int:
        if not self.answered:
            self._body()
            return self._stream.readinto(buffer)
        data = self.read(len(buffer))
        buffer[: len(data)] = data
        return len(data)

    def readline(self, size: int | None = -1) -> bytes:
        if self.answered:
            return b""
        self._body()
        line = self._stream.readline(size)
        self.blank_line = line in (b"\r\n", b"\n")
        return line

    def __getattr__(self, name: str) -> Any:  # close, closed, ...: the stream's own
        return getattr(self._stream, name)


class GuardedRequests(BaseHTTPRequestHandler):
    """
    What ``quiet_request_handler`` adds to werkzeug's request handler (put before it): its input read through
    ``RequestInput`` (no body read past a refusal, ``Expect: 100-continue`` answered when the app reads the body), a
    request whose head was cut short refused unanswered (the connection closed before the blank line that ends it:
    http.server would take what came as the whole head), and no console line for a request under 400.
    """

    rfile: Any
    server: Any

    def setup(self) -> None:
        super().setup()
        self.rfile = RequestInput(self.rfile, self._send_continue)

    def _send_continue(self) -> None:
        self.wfile.write(b"HTTP/1.1 100 Continue\r\n\r\n")
        self.wfile.flush()

    def handle_expect_100(self) -> bool:  # http.server would answer it before the app has seen the request
        return True

    def parse_request(self) -> bool:
        if not super().parse_request():
            return False
        if not self.rfile.blank_line:  # cut short: not a request
            self.close_connection = True
            return False
        return True

    def read_body_through_input(self) -> None:
        """Before the app runs: what ``RequestInput`` needs of the request's head."""
        body = self.rfile
        body.expect_continue = self.headers.get("Expect", "").lower().strip(" \t") == "100-continue"
        del self.headers["Expect"]  # werkzeug would answer it too
        length = self.headers.get("Content-Length", "").strip()
        chunked = "chunked" in self.headers.get("Transfer-Encoding", "").lower()
        body.leftover = int(length) if length.isdigit() and int(length) <= MAX_BODY and not chunked else 0

    def shut_by_server(self) -> bool:
        """Whether the server closed this connection (its ``connections``): what came is not a request."""
        connections = getattr(self.server, "connections", None)
        return connections is not None and connections.was_shut(self.connection)

    def send_response(self, code: int, message: str | None = None) -> None:
        self.rfile.answered = True
        super().send_response(code, message)

    def log_request(self, code: Any = "-", size: Any = "-") -> None:
        if isinstance(code, int) and code < 400:  # an HTTPStatus is an int
            return
        super().log_request(code, size)


def quiet_request_handler(read_timeout: float = READ_TIMEOUT) -> type:
    """
    werkzeug's request handler with ``GuardedRequests``, tokens masked in the lines it prints (``mask_tokens``, with
    the server's ``tokens``), ``read_timeout`` seconds for each read or write of a connection, and nothing answered
    or logged on a connection the server closed (its deadline, or the limit on open connections).
    """
    from werkzeug.serving import WSGIRequestHandler

    class QuietRequestHandler(GuardedRequests, WSGIRequestHandler):
        timeout = read_timeout  # socketserver sets it on the connection before the request is read

        def run_wsgi(self) -> None:
            if self.shut_by_server():
                self.close_connection = True
                return
            self.read_body_through_input()
            super().run_wsgi()

        def log(self, type: str, message: str, *args: Any) -> None:  # every line (errors too), masked as a whole
            if self.shut_by_server():
                return
            line = message % args if args else message
            super().log(type, "%s", mask_tokens(line, getattr(self.server, "tokens", ())))

    return QuietRequestHandler


def guarded_server(host: str, port: int, app: Any, handler: type, connections: Connections, tokens: Iterable[str] = ()) -> Any:
    """
    werkzeug's threaded server (a thread per connection) over ``connections``: each accepted connection is admitted
    there (the oldest closed beyond its limit), and the ones past their deadline are closed between two polls.

    :param tokens: masked wherever they appear in the console's lines
    :raises SystemExit: werkzeug's way of saying the port cannot be bound (it printed why)
    """
    from werkzeug.serving import ThreadedWSGIServer

    class GuardedServer(ThreadedWSGIServer):
        block_on_close = False  # stop() waits for no connection's thread: each is shut down
        tokens: tuple[str, ...] = ()  # masked in the console's lines
        connections: Connections  # read by the request handler

        def verify_request(self, request: Any, client_address: Any) -> bool:
            connections.admit(request)
            return True

        def shutdown_request(self, request: Any) -> None:
            connections.release(request, lambda: ThreadedWSGIServer.shutdown_request(self, request))

        def service_actions(self) -> None:  # between two polls of serve_forever
            connections.expire()

        def server_close(self) -> None:
            super().server_close()
            connections.close_all()

    server = GuardedServer(host, port, app, handler=handler)
    server.tokens, server.connections = tuple(tokens), connections
    return server


class WebServer:
    """
    The page's server: made with the teacher (the tokens exist from then on), started by ``start()``.

    :param store: what the page shows and takes
    :param clips: where its clips are
    :param annotators: the annotators' names, each given a new secret token (None: one person, no token)
    :param instructions: gives the instructions the page shows
    :param read_timeout: seconds a connection may stay open, its request received and its answer sent (and so each
        read or write of it): a client that sends its request slowly, half-way or never reads the answer is dropped
        then, and its thread freed
    :param max_connections: the most connections open at once (``Connections``); set before ``start()``
    """

    def __init__(
        self,
        store: AnswerStore,
        clips: Clips,
        annotators: list[str] | None = None,
        instructions: Callable[[], str] = lambda: GENERIC_INSTRUCTIONS,
        read_timeout: float = READ_TIMEOUT,
        max_connections: int = MAX_CONNECTIONS,
    ):
        self.store, self.clips, self.instructions, self.read_timeout = store, clips, instructions, read_timeout
        self.max_connections = max_connections
        #: annotator -> their secret token: made with the server, never saved (a loaded teacher makes new ones)
        self.tokens = {name: secrets.token_urlsafe(18) for name in annotators or ()}
        #: the port it serves on, once started (None before)
        self.port: int | None = None
        #: the open connections, once started (None before)
        self.connections: Connections | None = None
        self._server: Any = None

    @cached_property
    def app(self) -> "Flask":
        """The Flask app (``create_app``), made on first use: ``server.app.test_client()`` talks to it without a socket."""
        return create_app(self.store, self.clips, self.tokens, self.instructions)

    @property
    def running(self) -> bool:
        """Whether it serves (``start()`` was called, ``stop()`` was not)."""
        return self._server is not None

    def start(self, host: str, port: int) -> int:
        """
        Serve on ``host``:``port`` (0: any free port) in a daemon thread, unless it serves already.

        :return: the port it serves on
        :raises ValueError: for a port in use, or a ``host`` beyond this machine without annotators
        """
        if self._server is not None:
            return self._server.server_port
        if not self.tokens:  # a host set after the teacher was made, or a teacher saved with another one
            refuse_anonymous_beyond_this_machine(host)
        connections = Connections(self.max_connections, self.read_timeout)
        handler = quiet_request_handler(self.read_timeout)
        try:
            self._server = guarded_server(host, port, self.app, handler, connections, self.tokens.values())
        except (OSError, SystemExit) as error:  # werkzeug exits (SystemExit) on a port in use, after saying so
            raise ValueError(
                f"port {port} on {host} is in use or cannot be bound: pass another, WebTeacher(port=...)"
            ) from error
        self.port, self.connections = self._server.server_port, connections
        threading.Thread(target=self._server.serve_forever, args=(0.1,), name="WebTeacher", daemon=True).start()
        return self.port

    def stop(self) -> None:
        """Stop serving (the port is freed, every open connection closed)."""
        if self._server is not None:
            self._server.shutdown()
            self._server.server_close()
            self._server = None
