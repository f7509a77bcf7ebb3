"""
A ``WebTeacher``'s page on the network: its Flask app (``create_app``) served by werkzeug's threaded server in a
daemon thread, with the annotators' secret tokens, a read timeout on every connection and a console that never shows
a token.
"""

import re
import secrets
import threading
from collections.abc import Callable
from functools import cached_property
from typing import TYPE_CHECKING, Any

from sb3_pride.human.app import create_app
from sb3_pride.human.clips import Clips
from sb3_pride.human.settings import GENERIC_INSTRUCTIONS, READ_TIMEOUT, refuse_anonymous_beyond_this_machine
from sb3_pride.human.store import AnswerStore

if TYPE_CHECKING:
    from flask import Flask

#: a token in a logged request line: ``token=...`` in its query string
TOKEN_IN_URL = re.compile(r"(token=)[^&\s\"']*")


def quiet_request_handler(read_timeout: float = READ_TIMEOUT) -> type:
    """
    werkzeug's request handler without a console line per request (the page polls every second), tokens masked in
    the lines it does print, and ``read_timeout`` seconds for each read or write of a connection: a client that
    stops half-way through its request (or never reads the answer) is dropped then, and its thread freed.
    """
    from werkzeug.serving import WSGIRequestHandler

    class QuietRequestHandler(WSGIRequestHandler):
        timeout = read_timeout  # socketserver sets it on the connection before the request is read

        def log_request(self, code: Any = "-", size: Any = "-") -> None:
            if isinstance(code, int) and code < 400:  # an HTTPStatus is an int
                return
            # werkzeug builds the line from self.path: masked there for the call, then put back
            path = getattr(self, "path", None)
            if path is not None:
                self.path = TOKEN_IN_URL.sub(r"\1...", path)
            try:
                super().log_request(code, size)
            finally:
                if path is not None:
                    self.path = path

        def log(self, type: str, message: str, *args: Any) -> None:  # every line (errors too), masked as a whole
            line = message % args if args else message
            super().log(type, "%s", TOKEN_IN_URL.sub(r"\1...", line))

    return QuietRequestHandler


class WebServer:
    """
    The page's server: made with the teacher (the tokens exist from then on), started by ``start()``.

    :param store: what the page shows and takes
    :param clips: where its clips are
    :param annotators: the annotators' names, each given a new secret token (None: one person, no token)
    :param instructions: gives the instructions the page shows
    :param read_timeout: seconds each read or write of a connection may take (``quiet_request_handler``)
    """

    def __init__(
        self,
        store: AnswerStore,
        clips: Clips,
        annotators: list[str] | None = None,
        instructions: Callable[[], str] = lambda: GENERIC_INSTRUCTIONS,
        read_timeout: float = READ_TIMEOUT,
    ):
        self.store, self.clips, self.instructions, self.read_timeout = store, clips, instructions, read_timeout
        #: annotator -> their secret token: made with the server, never saved (a loaded teacher makes new ones)
        self.tokens = {name: secrets.token_urlsafe(18) for name in annotators or ()}
        #: the port it serves on, once started (None before)
        self.port: int | None = None
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
        from werkzeug.serving import make_server

        try:
            self._server = make_server(
                host, port, self.app, threaded=True, request_handler=quiet_request_handler(self.read_timeout)
            )
        except (OSError, SystemExit) as error:  # werkzeug exits (SystemExit) on a port in use, after saying so
            raise ValueError(
                f"port {port} on {host} is in use or cannot be bound: pass another, WebTeacher(port=...)"
            ) from error
        self.port = self._server.server_port
        threading.Thread(target=self._server.serve_forever, args=(0.1,), name="WebTeacher", daemon=True).start()
        return self.port

    def stop(self) -> None:
        """Stop serving (the port is freed)."""
        if self._server is not None:
            self._server.shutdown()
            self._server.server_close()
            self._server = None
