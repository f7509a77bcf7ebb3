"""
Checks on the repository itself, not on the package's behaviour.

- The product speaks of what is true of this version: no tracked file outside ``CHANGELOG.md`` and
  ``benchmarks/results/archive/`` names a work session ("session 19", "sessions 16–18", ``speed_session19.json``),
  a ticket ("issue 9", "issue #12", ``speed_issue9.json``) or a commit (a hash in backticks or after the word
  "commit"). A *feedback* session is part of the algorithm and may be numbered ("feedback session 3").
  References to other projects' tickets are written as ``owner/repo#N`` or as a URL (``.../issues/N``); neither
  contains the word "issue" followed by a number, so both pass. A run's recorded provenance (a ``"commit":`` field in
  a run's ``settings.json``) is data, not prose, and passes too.
- The README stays short: a newcomer's page, the rest is in ``docs/``.
- ``sb3_pride.common`` depends on nothing above it: no module under ``sb3_pride/common/`` imports
  ``sb3_pride.pebble``, ``sb3_pride.pride``, ``sb3_pride.human`` or the top-level ``sb3_pride`` package.
"""

import ast
import re
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
README_MAX_LINES = 150
#: tracked paths where history belongs (a path equal to an entry, or under a folder entry)
HISTORY_ALLOWED = ("CHANGELOG.md", "benchmarks/results/archive/")
#: tracked paths not searched: data, not text written by people; and this file, whose examples are the patterns' own tests
HISTORY_SKIPPED = ("tests/data/", "tests/test_repository.py")

_HEX = r"(?=[0-9a-f]*[0-9])(?=[0-9a-f]*[a-f])[0-9a-f]{7,40}"  # at least one digit and one letter: not a plain number
HISTORY_PATTERNS = {
    # a work session, numbered: "session 19", "Sessions 16–18", "session-16", speed_session19.json; "feedback session 3"
    # (and feedback_session, feedback-session, the logger's feedback/sessions) is the algorithm's and passes
    "work session": re.compile(r"(?<![A-Za-z])(?<![Ff]eedback[\s_/-])[Ss]essions?[\s_-]*\d"),
    # a ticket: "issue 9", "Issues 9 and 11", "issue #12", speed_issue9.json
    "issue": re.compile(r"(?<![A-Za-z])[Ii]ssues?[\s_-]*#?\d"),
    # a commit: a hash in backticks, or after "commit" / "commits" (optionally "at", or an opening parenthesis)
    "commit hash": re.compile(rf"`{_HEX}`|\b[Cc]ommits?\s+(?:at\s+)?\(?{_HEX}\b"),
}


def history_mentions(text: str) -> list[tuple[str, int, str]]:
    """
    ``(kind, line number, line)`` for every mention of a work session, an issue or a commit in ``text``. The whole
    text is searched, not line by line, so that a mention wrapped across lines ("session\\n19") is found and a
    wrapped "feedback\\nsession 3" is not taken for a work session.
    """
    lines = text.splitlines()
    found = []
    for kind, pattern in HISTORY_PATTERNS.items():
        for match in pattern.finditer(text):
            number = text.count("\n", 0, match.start()) + 1
            found.append((kind, number, lines[number - 1].strip() if number <= len(lines) else ""))
    return sorted(set(found), key=lambda mention: (mention[1], mention[0]))


@pytest.mark.parametrize(
    "text, kinds",
    [
        ("as measured in session 19", {"work session"}),
        ("Sessions 16–18 used it", {"work session"}),
        ("the session-16 default", {"work session"}),
        ("see speed_session19.json", {"work session"}),
        ("in the\nsession\n19 runs", {"work session"}),
        ("the first feedback session 1 asks uniformly", set()),
        ("feedback sessions 2-5", set()),
        ("feedback_session 3", set()),
        ("asked at each feedback\nsession 3 of the run", set()),
        ("each feedback session asks K queries", set()),
        ("self.feedback_sessions = 0", set()),
        ("time/fps,feedback/sessions\n3,120", set()),
        ("JournalEntry(session=1, label=0.5)", set()),
        ("within issue 9's bound", {"issue"}),
        ("Issue 11 defects", {"issue"}),
        ("fixes issue #12", {"issue"}),
        ("speed_issue9.log", {"issue"}),
        ("as SB3 counts it (DLR-RM/stable-baselines3#2158)", set()),
        ("https://github.com/DLR-RM/stable-baselines3/issues/2158", set()),
        ("a known issue with MuJoCo 4", set()),
        ("until commit fac6b44 the reset", {"commit hash"}),
        ("run at commit dd3fad5, when", {"commit hash"}),
        ("the fix (commit fac6b44)", {"commit hash"}),
        ("the results of `a746db1`", {"commit hash"}),
        ('"commit": "a746db1c0ffee"', set()),
        ("commit every label to disk", set()),
        ("`1000000` steps, `deadbeef`", set()),
        ("the hash 0x7f3a9c1 of a buffer", set()),
        ("a decade of faced facades", set()),
    ],
)
def test_history_patterns(text: str, kinds: set[str]) -> None:
    """The patterns catch what they must and pass what they must (their own examples)."""
    assert {kind for kind, _, _ in history_mentions(text)} == kinds


def tracked_files() -> list[str]:
    try:
        listing = subprocess.run(["git", "ls-files", "-z"], cwd=ROOT, capture_output=True, check=True).stdout
    except (OSError, subprocess.CalledProcessError):
        pytest.skip("not a git checkout (an installed copy): the repository checks need git ls-files")
    return [path for path in listing.decode().split("\0") if path]


def read_text(path: Path) -> str | None:
    """The file's text, or None for a binary file (a NUL byte or not UTF-8) or one missing from the work tree."""
    try:
        data = path.read_bytes()
    except (FileNotFoundError, IsADirectoryError):
        return None
    if b"\0" in data[:8192]:
        return None
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError:
        return None


def _under(path: str, prefixes: tuple[str, ...]) -> bool:
    return any(path == prefix or (prefix.endswith("/") and path.startswith(prefix)) for prefix in prefixes)


def test_no_history_in_tracked_files() -> None:
    """No tracked text file outside the changelog and the archive names a work session, an issue or a commit."""
    offending = []
    for path in tracked_files():
        if _under(path, HISTORY_ALLOWED + HISTORY_SKIPPED):
            continue
        text = read_text(ROOT / path)
        if text is None:
            continue
        offending.extend(f"{path}:{number}: {kind}: {line[:160]}" for kind, number, line in history_mentions(text))
    assert not offending, "history outside CHANGELOG.md and benchmarks/results/archive/:\n" + "\n".join(offending)


def test_readme_is_short() -> None:
    lines = (ROOT / "README.md").read_text(encoding="utf-8").splitlines()
    assert len(lines) <= README_MAX_LINES, f"README.md has {len(lines)} lines; the rest belongs in docs/"


FORBIDDEN_IN_COMMON = ("sb3_pride.pebble", "sb3_pride.pride", "sb3_pride.human")


def imported_modules(source: str, module: str) -> list[tuple[int, str]]:
    """
    ``(line, module)`` for every import in ``source`` (at any depth: in functions, under ``TYPE_CHECKING``), relative
    imports resolved against ``module``, the dotted name of the file itself; ``from X import y`` yields ``X.y`` too,
    so that ``from sb3_pride import pebble`` is seen as ``sb3_pride.pebble``.
    """
    package = module.rsplit(".", 1)[0]
    found = []
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Import):
            found.extend((node.lineno, alias.name) for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.rsplit(".", node.level - 1)[0] if node.level > 1 else package
                name = f"{base}.{node.module}" if node.module else base
            else:
                name = node.module or ""
            found.append((node.lineno, name))
            found.extend((node.lineno, f"{name}.{alias.name}") for alias in node.names)
    return found


def forbidden_import(name: str) -> bool:
    """An import ``common/`` must not make: the algorithms, the human UI, or the top-level package (which imports them)."""
    return name == "sb3_pride" or any(name == prefix or name.startswith(prefix + ".") for prefix in FORBIDDEN_IN_COMMON)


@pytest.mark.parametrize(
    "source, forbidden",
    [
        ("from sb3_pride.pebble.pebble import PEBBLE", True),
        ("import sb3_pride.pride", True),
        ("from sb3_pride import PEBBLE", True),
        ("from sb3_pride import human", True),
        ("def f():\n    from ..human.web import WebTeacher", True),
        ("from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    from sb3_pride.pebble import PEBBLE", True),
        ("from sb3_pride.common.queries import SegmentPairs", False),
        ("from .queries import SegmentPairs", False),
        ("import numpy as np", False),
    ],
)
def test_forbidden_import_detection(source: str, forbidden: bool) -> None:
    names = [name for _, name in imported_modules(source, "sb3_pride.common.example")]
    assert any(forbidden_import(name) for name in names) == forbidden


def test_common_imports_nothing_above_it() -> None:
    """``sb3_pride.common`` is the bottom layer: PEBBLE, PRIDE and the human UI import it, never the reverse."""
    offending = []
    for path in sorted((ROOT / "sb3_pride" / "common").rglob("*.py")):
        module = ".".join(path.relative_to(ROOT).with_suffix("").parts)
        for line, name in imported_modules(path.read_text(encoding="utf-8"), module):
            if forbidden_import(name):
                offending.append(f"{path.relative_to(ROOT)}:{line}: imports {name}")
    assert not offending, "sb3_pride/common/ imports from above it:\n" + "\n".join(offending)


# -- the algorithms' shape -----------------------------------------------------------------------------------------
def test_pride_is_pebble_plus_a_few_settings() -> None:
    """PRIDE's own constructor parameters (beyond PEBBLE's and SB3's conventions) stay few, and pride.py short."""
    import inspect

    from sb3_pride import PEBBLE, PRIDE

    pebble = set(inspect.signature(PEBBLE.__init__).parameters)
    own = [name for name in inspect.signature(PRIDE.__init__).parameters if name not in pebble | {"pebble_kwargs"}]
    assert len(own) <= 10, own
    assert len((ROOT / "sb3_pride/pride/pride.py").read_text().splitlines()) <= 250


@pytest.mark.parametrize("path", ["sb3_pride/pebble/callbacks.py", "sb3_pride/pride/callbacks.py"])
def test_callbacks_use_the_models_public_interface(path: str) -> None:
    """The callbacks drive the phases through public methods and attributes: no `model._...`, no SB3 privates."""
    private = re.findall(r"\bmodel\._\w+", (ROOT / path).read_text())
    assert not private, private


# -- PEBBLE's shape: SAC plus composed parts -------------------------------------------------------------------------
def class_node(path: str, name: str) -> ast.ClassDef:
    tree = ast.parse((ROOT / path).read_text(encoding="utf-8"))
    return next(node for node in ast.walk(tree) if isinstance(node, ast.ClassDef) and node.name == name)


def methods(node: ast.ClassDef) -> list[ast.FunctionDef]:
    """The functions defined in a class body (properties, class and static methods included)."""
    return [item for item in node.body if isinstance(item, (ast.FunctionDef, ast.AsyncFunctionDef))]  # type: ignore[misc]


def test_pebble_stays_sac_sized() -> None:
    """pebble.py, the PEBBLE class's methods and its constructor stay within the budgets of a SAC-shaped algorithm."""
    import inspect

    from stable_baselines3 import SAC

    from sb3_pride import PEBBLE

    assert len((ROOT / "sb3_pride/pebble/pebble.py").read_text().splitlines()) <= 400
    pebble = class_node("sb3_pride/pebble/pebble.py", "PEBBLE")
    assert len(methods(pebble)) <= 18, [f.name for f in methods(pebble)]
    init = next(f for f in methods(pebble) if f.name == "__init__")
    assert init.end_lineno is not None and init.end_lineno - init.lineno + 1 <= 80
    sac = set(inspect.signature(SAC.__init__).parameters)
    own = [
        name
        for name, p in inspect.signature(PEBBLE.__init__).parameters.items()
        if name not in sac and not name.startswith("_") and p.kind != p.VAR_KEYWORD
    ]
    assert len(own) <= 14, own


def test_the_model_sets_one_object_on_the_replay_buffer(tiny_kwargs) -> None:
    """The replay buffer asks one object about rewards: a trained model's buffer holds one attribute a fresh one lacks."""
    from sb3_pride import PEBBLE
    from sb3_pride.common.buffers import PreferenceReplayBuffer

    model = PEBBLE("MlpPolicy", "Pendulum-v1", seed=0, **tiny_kwargs).learn(450)
    buffer = model.replay_buffer
    fresh = PreferenceReplayBuffer(buffer.buffer_size, buffer.observation_space, buffer.action_space, device="cpu")
    assert sorted(set(vars(buffer)) - set(vars(fresh))) == ["reward_source"]


def test_a_labels_way_passes_through_few_pebble_methods(tiny_kwargs) -> None:
    """From the teacher's answer to SAC's next minibatch (take the answers, learn r̂, relabel, train), ≤ 6 methods."""
    import sys

    from sb3_pride import PEBBLE

    model = PEBBLE("MlpPolicy", "Pendulum-v1", seed=0, **tiny_kwargs).learn(350)  # pre-training, then the first feedback
    assert model.publish_queries(asynchronous=False)
    called: set[str] = set()

    def trace(frame, event, arg):  # type: ignore[no-untyped-def]
        if event == "call" and frame.f_code.co_filename.endswith("sb3_pride/pebble/pebble.py"):
            called.add(frame.f_code.co_name)

    sys.setprofile(trace)
    try:
        model.take_answers()
        model.train(gradient_steps=1, batch_size=model.batch_size)
    finally:
        sys.setprofile(None)
    assert "take_answers" in called and "train" not in called  # SAC's train(), on the rewards replay_rewards gives
    assert len(called) <= 6, sorted(called)


def test_size_budgets_hold_on_the_code_as_ruff_formats_it() -> None:
    """Budgets are met by design, measured on the code as ``ruff format`` lays it out (CI checks that it does) with no
    ``fmt: skip``: every module of sb3_pride/ ≤ 400 lines, no class of it over 20 methods, every file of benchmarks/
    ≤ 600 lines."""
    package, scripts = sorted((ROOT / "sb3_pride").rglob("*.py")), sorted((ROOT / "benchmarks").glob("*.py"))
    assert not [path.name for path in package + scripts if "fmt: skip" in path.read_text()]
    sizes = {str(path.relative_to(ROOT)): len(path.read_text().splitlines()) for path in package}
    assert max(sizes.values()) <= 400, {name: size for name, size in sizes.items() if size > 400}
    assert all(len(path.read_text().splitlines()) <= 600 for path in scripts), [
        (path.name, len(path.read_text().splitlines())) for path in scripts if len(path.read_text().splitlines()) > 600
    ]
    classes = [
        (path.name, node.name, len(methods(node)))
        for path in package
        for node in ast.walk(ast.parse(path.read_text()))
        if isinstance(node, ast.ClassDef)
    ]
    assert max(count for *_, count in classes) <= 20, [entry for entry in classes if entry[2] > 20]


def test_the_web_teacher_stays_a_facade() -> None:
    """WebTeacher a facade of ≤ 15 methods."""
    teacher = next(
        node
        for path in (ROOT / "sb3_pride/human").glob("*.py")
        for node in ast.walk(ast.parse(path.read_text()))
        if isinstance(node, ast.ClassDef) and node.name == "WebTeacher"
    )
    assert len(methods(teacher)) <= 15, [f.name for f in methods(teacher)]


def private_names(package: Path) -> set[str]:
    """
    The private names a package defines: functions, classes and module variables named ``_x``, methods ``_x`` and
    attributes set as ``self._x`` (dunders aside).
    """
    names = set()
    for path in package.rglob("*.py"):
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
                names.add(node.name)
            elif isinstance(node, ast.Attribute) and isinstance(node.ctx, ast.Store):
                names.add(node.attr)
            elif isinstance(node, ast.Name) and isinstance(node.ctx, ast.Store):
                names.add(node.id)
    return {name for name in names if name.startswith("_") and not name.startswith("__")}


def private_uses(source: str, names: set[str]) -> list[str]:
    """Uses of ``names`` in ``source``: as an attribute (``x._name``) or imported (``from m import _name``)."""
    found = []
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Attribute) and node.attr in names:
            found.append(f"{node.lineno}: .{node.attr}")
        elif isinstance(node, ast.ImportFrom) and (node.module or "").startswith("sb3_pride"):
            found.extend(f"{node.lineno}: import {alias.name}" for alias in node.names if alias.name in names)
    return found


def test_private_name_detection() -> None:
    names = {"_session", "_helper"}
    assert private_uses("teacher._session.queries", names) == ["1: ._session"]
    assert private_uses("from sb3_pride.human.web import _helper", names) == ["1: import _helper"]
    assert private_uses("model._last_obs\nteacher.session", names) == []


def test_tests_use_only_public_names_of_the_package() -> None:
    """Tests use what a user can: no private name of sb3_pride (SB3's and gymnasium's own, which it overrides, aside)."""
    import gymnasium
    import stable_baselines3

    ours = private_names(ROOT / "sb3_pride")
    theirs = private_names(Path(stable_baselines3.__file__).parent) | private_names(Path(gymnasium.__file__).parent)
    names = ours - theirs
    offending = [
        f"{path.name}:{use}"
        for path in sorted((ROOT / "tests").glob("*.py"))
        if path.name != "test_repository.py"
        for use in private_uses(path.read_text(encoding="utf-8"), names)
    ]
    assert not offending, "tests use private names of sb3_pride:\n" + "\n".join(offending)


@pytest.mark.slow
def test_the_wheel_smoke_script_runs_against_this_tree(tmp_path) -> None:
    """
    CI's last step runs ``.ci/wheel_smoke.py`` against the installed wheel; the suite runs the same script against the
    source tree, from outside it, so a public name it uses that was renamed fails here and not only after the wheel.
    """
    import os
    import sys

    env = {**os.environ, "SB3_PRIDE_SMOKE_FROM_SOURCE": "1", "PYTHONPATH": str(ROOT)}
    done = subprocess.run(
        [sys.executable, str(ROOT / ".ci" / "wheel_smoke.py")], cwd=tmp_path, env=env, capture_output=True, text=True
    )
    assert done.returncode == 0, done.stderr[-3000:]
    assert "wheel OK" in done.stdout
