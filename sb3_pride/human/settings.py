"""
A ``WebTeacher``'s settings: the values it accepts (checked when it is made, each refusal naming its parameter), the
addresses it serves without tokens, and the instructions its page shows by default.
"""

import ipaddress
import math
import re
from collections.abc import Sequence
from pathlib import Path
from typing import Any

#: the addresses that only this machine reaches: the one place a page may be served without annotators' tokens
LOCAL_HOSTS = ("127.0.0.1", "localhost", "::1")
#: how an annotator is named: it becomes part of logger keys (``annotators/<name>/...``) and of the report
ANNOTATOR_NAME = re.compile(r"[A-Za-z0-9_.-]{1,40}")
#: the name of the one person of ``annotators=None`` in the agreement report and the logger keys
ANONYMOUS = "anonymous"
#: seconds a connection may stay open, its request received and its answer sent: a request sent half-way or slowly is
#: dropped then (``read_timeout``)
READ_TIMEOUT = 30.0
#: the most connections the page's server keeps open at once: the oldest is closed for a new one (``WebServer``)
MAX_CONNECTIONS = 100
#: seconds a query may stay shown to an annotator who does not answer it before an idle annotator is handed it
#: (``hand_over_after``)
HAND_OVER_AFTER = 300.0
#: what the page asks for on the bundled tasks (by task name: the env id without its namespace and version)
TASK_INSTRUCTIONS: dict[str, str] = {
    "walker-walk": "Prefer the walker that moves forward faster while staying upright (torso high, not falling).",
    "walker-run": "Prefer the walker that runs forward faster while staying upright (torso high, not falling).",
    "walker-stand": "Prefer the walker that stands upright with its torso high and steady.",
    "cheetah-run": "Prefer the cheetah that runs forward (to the right) faster; flipping over or standing still is worse.",
    "hopper-hop": "Prefer the hopper that hops forward faster while staying upright.",
    "hopper-stand": "Prefer the hopper that stands upright with its torso high.",
    "humanoid-stand": "Prefer the humanoid that stands upright with its head high.",
    "humanoid-walk": "Prefer the humanoid that walks forward while staying upright.",
    "humanoid-run": "Prefer the humanoid that runs forward faster while staying upright.",
    "quadruped-walk": "Prefer the quadruped that walks forward faster while staying upright.",
    "quadruped-run": "Prefer the quadruped that runs forward faster while staying upright.",
    "cartpole-swingup": "Prefer the cart-pole whose pole is swung up and kept balanced upright, the cart near the centre.",
    "cartpole-balance": "Prefer the cart-pole whose pole stays balanced upright, the cart near the centre.",
    "pendulum-swingup": "Prefer the pendulum that is swung up and kept pointing straight up.",
    "acrobot-swingup": "Prefer the acrobot whose tip is swung up higher and kept there.",
    "reacher-easy": "Prefer the arm whose fingertip reaches the target sooner and stays on it.",
    "reacher-hard": "Prefer the arm whose fingertip reaches the target sooner and stays on it.",
    "finger-spin": "Prefer the finger that spins the hinged body faster.",
    "ball_in_cup-catch": "Prefer the segment in which the ball is swung into the cup and stays there.",
    "point_mass-easy": "Prefer the point mass that moves to the target and stays on it.",
    "button-press": "Prefer the robot arm that presses the button further in (reaching it first, then pushing straight).",
    "door-open": "Prefer the robot arm that opens the door wider (grabbing the handle and pulling the door round).",
    "drawer-open": "Prefer the robot arm that pulls the drawer further open (hooking the handle first).",
    "window-open": "Prefer the robot arm that slides the window further open (pushing its handle sideways).",
    "sweep-into": "Prefer the robot arm that sweeps the puck closer to the hole, and into it.",
    "hammer": "Prefer the robot arm that grasps the hammer and drives the nail further in.",
}
#: what the page asks for on any other task
GENERIC_INSTRUCTIONS = (
    "Prefer the segment in which the agent does its task better: more progress toward the goal, fewer falls or failures."
)


def default_instructions(env_id: str | None) -> str:
    """
    The instructions shown for ``env_id`` when none are given: the task's sentence of ``TASK_INSTRUCTIONS`` (matched
    by the id's task name, e.g. ``"sb3_pride/walker-walk-v0"`` -> ``"walker-walk"``), else ``GENERIC_INSTRUCTIONS``.
    """
    if env_id is None:
        return GENERIC_INSTRUCTIONS
    task = re.sub(r"-v\d+$", "", env_id.rsplit("/", 1)[-1])
    return TASK_INSTRUCTIONS.get(task, GENERIC_INSTRUCTIONS)


def is_local(host: str) -> bool:
    """Whether ``host`` is reached from this machine only (a loopback address or ``localhost``)."""
    if host in LOCAL_HOSTS:
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def host_name(host: str) -> str:
    """The name of a ``Host`` header without its port: ``"127.0.0.1:8000"`` -> ``"127.0.0.1"``, ``"[::1]:80"`` -> ``"::1"``."""
    if host.startswith("["):
        return host[1 : host.find("]")] if "]" in host else host
    return host.rsplit(":", 1)[0] if host.count(":") == 1 else host


def refuse_anonymous_beyond_this_machine(host: str) -> None:
    """Raise ``ValueError`` for a ``host`` beyond this machine: serving there needs annotators' tokens."""
    if not is_local(host):
        raise ValueError(
            f"annotators must be given to serve on {host!r}: beyond this machine ({', '.join(LOCAL_HOSTS)}) each "
            f"person needs a secret link, e.g. WebTeacher(host={host!r}, annotators=['ana', 'ben'])"
        )


def _number(name: str, value: Any, low: float, high: float = math.inf, integer: bool = False) -> None:
    """Raise ``ValueError`` naming ``name`` unless ``value`` is a number (an int where ``integer``) in [low, high]."""
    kinds = int if integer else (int, float)
    if isinstance(value, bool) or not isinstance(value, kinds) or not low <= value <= high:
        kind = "an integer" if integer else "a number"
        raise ValueError(f"{name} must be {kind} in [{low}, {high}], got {value!r}")


def check_annotators(annotators: Sequence[str] | None, host: str) -> list[str] | None:
    """``annotators`` as a list of distinct valid names (None: one person, only on this machine's addresses)."""
    if annotators is None:
        refuse_anonymous_beyond_this_machine(host)
        return None
    if isinstance(annotators, str) or not isinstance(annotators, Sequence) or len(annotators) == 0:
        raise ValueError(f"annotators must be a non-empty list of names or None (one person), got {annotators!r}")
    names = list(annotators)
    for name in names:
        if not isinstance(name, str) or not ANNOTATOR_NAME.fullmatch(name):
            raise ValueError(
                f"annotators must be names of 1 to 40 letters, digits, '_', '-' or '.' (they name logger keys), got {name!r}"
            )
    if len(set(names)) != len(names):
        raise ValueError(f"annotators must be distinct names, got {names}")
    return names


def check_report_path(report_path: str | Path) -> Path:
    """``report_path`` as a ``Path``, once its folder exists (made here) and it is not a folder itself."""
    if not isinstance(report_path, (str, Path)) or str(report_path) == "":
        raise ValueError(f"report_path must be a file path (str or Path) or None, got {report_path!r}")
    path = Path(report_path)
    if path.is_dir():
        raise ValueError(f"report_path must be a file, got the folder {str(path)!r}")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
    except OSError as error:
        raise ValueError(f"report_path {str(path)!r} cannot be written: its folder cannot be made ({error})") from None
    return path


def check_settings(settings: dict[str, Any]) -> dict[str, Any]:
    """
    The settings of a ``WebTeacher`` (its constructor's parameters, by name) checked, each refusal a ``ValueError``
    that names its parameter, and normalised: ``annotators`` a list, ``clip_dir`` and ``report_path`` paths, the
    rates and margins floats.
    """
    s = dict(settings)
    _number("port", s["port"], 0, 65535, integer=True)
    if s["timeout"] is not None and not (isinstance(s["timeout"], (int, float)) and s["timeout"] > 0):
        raise ValueError(f"timeout must be > 0 seconds or None, got {s['timeout']!r}")
    for name in ("reminder_interval", "read_timeout", "hand_over_after"):
        if isinstance(s[name], bool) or not isinstance(s[name], (int, float)) or not 0 < s[name] < math.inf:
            raise ValueError(f"{name} must be a number of seconds > 0, got {s[name]!r}")
    _number("width", s["width"], 16, integer=True)
    _number("height", s["height"], 16, integer=True)
    if not isinstance(s["host"], str) or not s["host"]:
        raise ValueError(f"host must be an address to bind, e.g. '127.0.0.1' or '0.0.0.0', got {s['host']!r}")
    s["annotators"] = check_annotators(s["annotators"], s["host"])
    if s["instructions"] is not None and not isinstance(s["instructions"], str):
        raise ValueError(f"instructions must be a string (plain text) or None (the task's own), got {s['instructions']!r}")
    most = 1 if s["annotators"] is None else len(s["annotators"])
    try:
        _number("answers_per_query", s["answers_per_query"], 1, most, integer=True)
    except ValueError as error:
        raise ValueError(f"{error} (different annotators answer each query; {most} annotator(s) given)") from None
    _number("known_answer_rate", s["known_answer_rate"], 0, 1)
    if s["known_answer_rate"] == 1:
        raise ValueError("known_answer_rate must be a number in [0, 1) (1: no query of the model would be asked)")
    margin = s["known_answer_margin"]
    if margin is not None and not (
        isinstance(margin, (int, float)) and not isinstance(margin, bool) and 0 < margin < math.inf
    ):
        raise ValueError(f"known_answer_margin must be a number > 0 (return_scales) or None, got {margin!r}")
    if s["seed"] is not None and (isinstance(s["seed"], bool) or not isinstance(s["seed"], int)):
        raise ValueError(f"seed must be an integer or None, got {s['seed']!r}")
    s["clip_dir"] = None if s["clip_dir"] is None else Path(s["clip_dir"])
    s["report_path"] = None if s["report_path"] is None else check_report_path(s["report_path"])
    s["known_answer_rate"] = float(s["known_answer_rate"])
    s["known_answer_margin"] = None if margin is None else float(margin)
    return s
