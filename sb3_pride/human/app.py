"""
A ``WebTeacher``'s page as a Flask app: ``create_app`` builds it over an ``AnswerStore`` (what the page shows and
takes) and the teacher's ``Clips`` (what it plays). Flask is imported when an app is made (the ``[human]`` extra).

Every request passes one guard (a ``before_request`` hook) before its route: a request addressed to another name than
this machine's is refused when no tokens are needed (403, DNS rebinding), a ``POST`` that is not JSON (415, another
site's form), an ``/api/`` route or a clip without a valid token when there are annotators (401), and a ``POST`` body
over ``MAX_BODY`` bytes (413, with a ``Content-Length`` or streamed in chunks) or that is not JSON (400, too deeply
nested included). A refused request records nothing; every error is answered as JSON ``{"error": ...}``.
"""

import json
import secrets
from collections.abc import Callable, Mapping
from datetime import datetime, timezone
from importlib import resources
from typing import TYPE_CHECKING, Any

from sb3_pride.human.clips import Clips
from sb3_pride.human.settings import GENERIC_INSTRUCTIONS, host_name, is_local
from sb3_pride.human.questions import Refused
from sb3_pride.human.store import AnswerStore

if TYPE_CHECKING:
    from flask import Flask

#: the largest body a ``POST`` may carry: an answer is a few bytes
MAX_BODY = 64 * 1024
#: the HTTP status of each reason the store refuses an answer or an undo for (``Refused.reason``)
REFUSAL_STATUS = {"malformed": 400, "not shown": 403, "unknown": 404, "conflict": 409}
#: headers of every answer: no other site may frame the page (and overlay its buttons, which one person alone, who
#: needs no token, would click for it)
FRAMING_REFUSED = {"X-Frame-Options": "DENY", "Content-Security-Policy": "frame-ancestors 'none'"}
#: what a request without a valid token is told
NO_TOKEN = "this needs an annotator's token: open your personal link (…/?token=…) from whoever runs the training"


def token_owner(tokens: Mapping[str, str], token: str) -> tuple[bool, str | None]:
    """
    (True, whose token) when ``token`` is one of ``tokens`` (annotator -> token), (True, None) when there are none to
    check, else (False, None). Compared in constant time: the answer's timing tells nothing of a token.
    """
    if not tokens:
        return True, None
    for name, secret in tokens.items():
        if secrets.compare_digest(token.encode(), secret.encode()):
            return True, name
    return False, None


def read_json(request: Any) -> Any:
    """
    The JSON body of ``request``: a ``RequestEntityTooLarge`` (413) past ``MAX_BODY`` bytes, whether the size was
    announced (``Content-Length``) or not (a chunked body, of which the app reads at most ``MAX_BODY + 1`` bytes); a
    ``BadRequest`` (400) for anything that is not JSON, a body nested too deeply for the parser included.
    """
    from werkzeug.exceptions import BadRequest, RequestEntityTooLarge

    data = request.get_data(cache=True)
    if len(data) > MAX_BODY:
        raise RequestEntityTooLarge(f"a body must be at most {MAX_BODY} bytes")
    try:
        return json.loads(data)
    except (ValueError, RecursionError):
        raise BadRequest("the body is not JSON (or nested too deeply)") from None


def error_response(status: int, message: str) -> Any:
    """A JSON ``{"error": message}`` answer with ``status``."""
    from flask import jsonify

    return jsonify(error=message), status


def guard_requests(app: "Flask", tokens: Mapping[str, str]) -> None:
    """
    Install on ``app`` the guard every request passes before its route (a ``before_request`` hook: the Host check,
    JSON-only POSTs, the token, the body; see the module's docstring), answer every error as JSON, and add
    ``FRAMING_REFUSED`` to every answer. The guard
    leaves the annotator who sent the request in ``flask.g.annotator`` (None without tokens) and the parsed body of
    a ``POST`` in ``flask.g.body``.

    :param tokens: annotator -> secret token (empty: no token is needed, and only this machine's names are served)
    """
    from flask import g, request
    from werkzeug.exceptions import HTTPException

    @app.errorhandler(HTTPException)
    def http_error(error: HTTPException) -> Any:  # an unknown route, a wrong method, a body too large: JSON too
        return error_response(error.code or 500, str(error.description))

    @app.errorhandler(Refused)
    def refusal(error: Refused) -> Any:
        return error_response(REFUSAL_STATUS[error.reason], str(error))

    @app.errorhandler(Exception)
    def server_error(error: Exception) -> Any:  # a bug, or a journal that cannot be written: the page says so
        app.logger.exception("WebTeacher: a request failed")
        return error_response(500, f"the training run failed to handle this request: {type(error).__name__}: {error}")

    @app.after_request
    def refuse_framing(response: Any) -> Any:
        response.headers.update(FRAMING_REFUSED)
        return response

    @app.before_request
    def guard() -> Any:
        # without tokens, only this machine's names: a page of another site whose name resolves to 127.0.0.1
        # (DNS rebinding) is refused
        if not tokens and not is_local(host_name(request.host)):
            port = request.environ.get("SERVER_PORT", "")
            return error_response(
                403, f"this page is served to this machine only: open http://127.0.0.1:{port}/, not {request.host}"
            )
        # a POST must be JSON, which another site's page cannot send without the browser asking first (CSRF)
        if request.method == "POST" and not request.is_json:
            return error_response(415, "a POST must carry a JSON body (Content-Type: application/json)")
        if request.endpoint in (None, "index"):  # no such route (answered 404 or 405), or the page, which holds nothing
            return None
        ok, g.annotator = token_owner(tokens, request.headers.get("X-Annotator-Token") or request.args.get("token") or "")
        if not ok:
            return error_response(401, NO_TOKEN)
        g.body = read_json(request) if request.method == "POST" else None
        return None


def create_app(
    store: AnswerStore,
    clips: Clips,
    tokens: Mapping[str, str] | None = None,
    instructions: Callable[[], str] = lambda: GENERIC_INSTRUCTIONS,
) -> "Flask":
    """
    The page's Flask app: ``GET /`` (the page), ``GET /api/state``, ``POST /api/answer``, ``POST /api/undo`` and
    ``GET /clips/<name>`` (a clip of the open session, with HTTP range requests).

    Every clip is served alike: its question's own address (``/clips/<id>-left.mp4``), the same ``Last-Modified``, no
    ``ETag`` and no ``Content-Disposition`` (which would name the file a known-answer question's clip shows).

    :param store: the state the routes read and change
    :param clips: where the clips' files are
    :param tokens: annotator -> secret token; every ``/api/`` route and clip needs one (in the ``X-Annotator-Token``
        header or a ``token`` query parameter). None or empty: one person on this machine, no token
    :param instructions: gives the instructions the page shows (asked at every ``/api/state``)
    """
    from flask import Flask, g, jsonify, send_from_directory

    tokens = dict(tokens or {})
    app = Flask("sb3_pride.human", static_folder=None)
    # one byte past the limit: a streamed body is cut there, and read_json sees that it was longer
    app.config["MAX_CONTENT_LENGTH"] = MAX_BODY + 1
    page = resources.files("sb3_pride.human").joinpath("static/index.html").read_text()
    # every clip is served with this date and no ETag: a known-answer question's clips are the files of an older
    # question, and neither header may tell that
    clip_date = datetime.now(timezone.utc).replace(microsecond=0)

    guard_requests(app, tokens)

    @app.get("/", endpoint="index")
    def index() -> Any:
        return page, 200, {"Content-Type": "text/html; charset=utf-8", "Cache-Control": "no-store"}

    @app.get("/api/state")
    def state() -> Any:
        return jsonify(store.page_state(g.annotator, instructions()))

    @app.post("/api/answer")
    def answer() -> Any:
        if not isinstance(g.body, dict) or "id" not in g.body or "label" not in g.body:
            return error_response(400, 'expected a JSON object {"id": ..., "label": 0 | 0.5 | 1 | null}')
        store.answer(g.body["id"], g.body["label"], g.annotator)
        return jsonify(state=store.page_state(g.annotator, instructions()))

    @app.post("/api/undo")
    def undo() -> Any:
        if not isinstance(g.body, dict):
            return error_response(400, "expected a JSON object ({})")
        question = store.undo(g.annotator)
        return jsonify(undone=question, state=store.page_state(g.annotator, instructions()))

    @app.get("/clips/<name>")
    def clip(name: str) -> Any:
        file = store.clip_file(name)
        if file is None:
            return error_response(404, f"no clip {name!r}")
        # conditional=True: HTTP Range requests (seeking and looping video need them) and 304s
        response = send_from_directory(
            clips.folder(), file, mimetype="video/mp4", conditional=True, etag=False, last_modified=clip_date
        )
        response.headers.pop("Content-Disposition", None)
        return response

    return app
