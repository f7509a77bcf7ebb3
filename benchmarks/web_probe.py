"""
A probe of a ``WebTeacher``'s server, on this machine's loopback only, bounded in time: what a slow or hostile client
costs the training process, and whether two annotators comparing notes can tell known-answer questions apart.

The server runs in a child process (the training process's stand-in: two annotators, ana and ben, known-answer
questions at rate 0.5, clips painted from the states at 320 x 240 and encoded as the page's are); the probe is its
clients, and reads the child's threads, file descriptors and memory from ``/proc``:

- slow clients: ``--dripping`` sockets that send a request one header byte every ``--drip`` seconds, timed to when
  the server closes them; then ``--slow`` such sockets, each re-opened when the server closes it, for ``--attack``
  seconds: the child's peak threads and descriptors, and how a page's requests fared meanwhile (answered, how fast);
- refused bodies: ``--bodies`` POSTs without a token, each announcing 200 MB and sending up to 8 MB, then left open;
  the bytes the server let through, the child's memory, epoll and other file descriptors before and after;
- two annotators: two feedback sessions; every clip either of them is shown is fetched and hashed, and after one
  answers a question the other answers it too: the statuses and messages seen for known-answer questions and for the
  model's queries, and the questions whose clip bytes, one clip's size or both clips' sizes are another question's;
- framing: the ``X-Frame-Options`` and ``Content-Security-Policy`` of the page and of the API.

    python benchmarks/web_probe.py --out benchmarks/results/web_probe.md
"""

import argparse
import hashlib
import json
import os
import queue
import select
import socket
import statistics
import subprocess
import sys
import tempfile
import threading
import time
import urllib.error
import urllib.request
from pathlib import Path
from typing import Any

import numpy as np

HOST = "127.0.0.1"
ANNOTATORS = ("ana", "ben")
SLOW_HEAD = b"GET /api/state HTTP/1.1\r\nHost: 127.0.0.1\r\nX-Slow: "


# the server: a child process ----------------------------------------------------------------------------------------
class PaintedRenderer:
    """Frames painted from the states (a colour and a moving bar over a ramp), at the page's default size."""

    fps = 10.0

    def __init__(self, width: int = 320, height: int = 240):
        self.width, self.height = width, height
        self.ramp = np.add.outer(np.arange(height), np.arange(width)) % 256

    def render(self, states: np.ndarray) -> np.ndarray:
        frames = np.empty((len(states), self.height, self.width, 3), np.uint8)
        for i, state in enumerate(np.asarray(states)):
            frames[i] = ((state[:3] * 200)[None, None, :] + self.ramp[:, :, None] // 2) % 256
            left = int(state[3] * (self.width - 40))
            frames[i, 80:160, left : left + 40] = 255
        return frames

    def close(self) -> None:
        pass


def stand_in_pairs(n: int, seed: int, k: int) -> Any:
    """``n`` segment pairs of ``k`` steps with a constant true reward per segment and random render states."""
    from sb3_pride.common.queries import SegmentPairs

    rng = np.random.default_rng(seed)
    rewards = np.repeat(rng.random((n, 2, 1)), k, axis=-1)
    return SegmentPairs(
        rng.normal(size=(n, 2, k, 3)), rng.normal(size=(n, 2, k, 1)), rewards, 0.5 * k, rng.random((n, 2, k, 4))
    )


def serve(args: argparse.Namespace) -> None:
    """The child: a WebTeacher serving two feedback sessions, saying on stdout its port, tokens and known questions."""
    from sb3_pride.common.journal import PreferenceJournal
    from sb3_pride.common.teachers import FeedbackContext
    from sb3_pride.human import WebTeacher

    folder = Path(tempfile.mkdtemp(prefix="web_probe_"))
    teacher = WebTeacher(
        port=0, annotators=list(ANNOTATORS), known_answer_rate=0.5, seed=0, read_timeout=args.read_timeout, clip_dir=folder
    )
    teacher.clips.renderer = PaintedRenderer()
    if args.max_connections is not None:
        teacher.server.max_connections = args.max_connections
    teacher.port = teacher.server.start(HOST, 0)
    over = teacher.quality.session_over

    def session_over(session: Any) -> None:  # which questions were known-answer ones: the probe's ground truth
        print(json.dumps({"session": session.number, "known": sorted(session.known)}), flush=True)
        over(session)

    teacher.quality.session_over = session_over  # type: ignore[method-assign]
    ready = teacher.store.ready

    def announce_ready(query: Any, known: float | None = None) -> None:  # the team starts once all clips are there
        ready(query, known)
        session = teacher.store.session
        if session is not None and all(question.ready for question in session.queries):
            print(json.dumps({"ready": session.number}), flush=True)

    teacher.store.ready = announce_ready  # type: ignore[method-assign]
    print(json.dumps({"port": teacher.port, "tokens": teacher.server.tokens}), flush=True)
    journal = PreferenceJournal(folder / "preferences.jsonl")
    for number in (1, 2):
        context = FeedbackContext(number, (number - 1) * args.pairs, 100, journal.append, journal.append_undo)
        teacher.ask(stand_in_pairs(args.pairs, number, args.segment_length), context)
    threading.Event().wait()  # until the probe ends it


# what the probe reads of the child -------------------------------------------------------------------------------
def proc(pid: int) -> dict[str, int]:
    """The child's threads, file descriptors (and how many are epoll ones) and resident memory (MB)."""
    status = dict(line.split(":", 1) for line in Path(f"/proc/{pid}/status").read_text().splitlines() if ":" in line)
    fds = list(Path(f"/proc/{pid}/fd").iterdir())
    epoll = 0
    for fd in fds:
        try:
            epoll += "eventpoll" in os.readlink(fd)
        except OSError:
            pass
    return {
        "threads": int(status["Threads"]),
        "fds": len(fds),
        "epoll": epoll,
        "rss_mb": int(status["VmRSS"].split()[0]) // 1024,
    }


def settled(pid: int, seconds: float = 2.0) -> dict[str, int]:
    """``proc(pid)`` once its memory has not moved for ``seconds`` (at most 30 s of waiting)."""
    last, end = proc(pid), time.monotonic() + 30
    while time.monotonic() < end:
        time.sleep(seconds)
        now = proc(pid)
        if now["rss_mb"] == last["rss_mb"]:
            return now
        last = now
    return last


def request(port: int, path: str, token: str | None, body: dict | None = None) -> tuple[int, dict, bytes, float]:
    """(status, headers, body, seconds) of a GET (no ``body``) or a JSON POST, with ``token`` in its header."""
    headers = {"Content-Type": "application/json", **({"X-Annotator-Token": token} if token else {})}
    data = None if body is None else json.dumps(body).encode()
    start = time.monotonic()
    try:
        with urllib.request.urlopen(
            urllib.request.Request(f"http://{HOST}:{port}{path}", data=data, headers=headers), timeout=10
        ) as response:
            return response.status, dict(response.headers), response.read(), time.monotonic() - start
    except urllib.error.HTTPError as error:
        return error.code, dict(error.headers), error.read(), time.monotonic() - start
    except OSError:
        return 0, {}, b"", time.monotonic() - start


# the probes ------------------------------------------------------------------------------------------------------
def framing(port: int, token: str) -> list[str]:
    rows = []
    for path, who in (("/", None), ("/api/state", token), ("/api/state", None)):
        status, headers, _, _ = request(port, path, who)
        rows.append(
            f"| `GET {path}`{' (no token)' if who is None and path != '/' else ''} | {status} | "
            f"{headers.get('X-Frame-Options', '(none)')} | {headers.get('Content-Security-Policy', '(none)')} |"
        )
    return rows


def deadline(port: int, args: argparse.Namespace) -> list[str]:
    """``--dripping`` sockets (fewer than the server's limit) each sending a header byte every ``--drip`` seconds: when
    the server closes each, timed from its connect."""
    opened = {}
    for _ in range(args.dripping):
        connection = socket.create_connection((HOST, port), timeout=5)
        connection.sendall(SLOW_HEAD)
        opened[connection] = time.monotonic()
    held: list[float] = []
    last_drip = time.monotonic()
    end = last_drip + 3 * args.read_timeout
    while opened and time.monotonic() < end:
        readable, _, _ = select.select(list(opened), [], [], 0.05)
        for connection in readable:  # readable: closed (a slow request gets no answer)
            held.append(time.monotonic() - opened.pop(connection))
            connection.close()
        if time.monotonic() - last_drip >= args.drip:
            last_drip = time.monotonic()
            for connection in opened:
                connection.send(b"a")
    for connection in opened:
        connection.close()
    return [
        f"| sockets sending a request a byte every {args.drip:g} s | {args.dripping} |",
        f"| closed by the server | {len(held)} of {args.dripping}"
        + (f", after {min(held):.2f} to {max(held):.2f} s (read_timeout {args.read_timeout:g} s) |" if held else " |"),
    ]


def flood(pid: int, port: int, token: str, args: argparse.Namespace) -> list[str]:
    """``--slow`` sockets dripping a request, re-opened as the server closes them, kept up for ``--attack`` seconds once
    all are open; a page polling its state and the child's threads and descriptors read all along."""
    opened: list[socket.socket] = []
    answers: list[tuple[int, float]] = []
    stop = threading.Event()
    before = settled(pid, 1.0)
    peak = dict(before)

    def page() -> None:
        while not stop.is_set():
            status, _, _, took = request(port, "/api/state", token)
            answers.append((status, took))
            time.sleep(0.5)

    def sample() -> None:
        while not stop.is_set():
            now = proc(pid)
            for key in peak:
                peak[key] = max(peak[key], now[key])
            time.sleep(0.1)

    def connect() -> None:
        try:
            connection = socket.create_connection((HOST, port), timeout=5)
            connection.sendall(SLOW_HEAD)
            connection.setblocking(False)
            opened.append(connection)
        except OSError:
            pass

    watchers = [threading.Thread(target=page, daemon=True), threading.Thread(target=sample, daemon=True)]
    for watcher in watchers:
        watcher.start()
    start = time.monotonic()
    for _ in range(args.slow):
        connect()
    connected = time.monotonic() - start
    reopened, last_drip, start = 0, 0.0, time.monotonic()
    while time.monotonic() - start < args.attack:
        drip = time.monotonic() - last_drip >= args.drip
        last_drip = time.monotonic() if drip else last_drip
        for connection in list(opened):
            try:
                closed = connection.recv(1, socket.MSG_PEEK) == b""
            except BlockingIOError:
                closed = False
            except OSError:
                closed = True
            if not closed and drip:
                try:
                    connection.send(b"a")
                except OSError:
                    closed = True
            if closed:
                opened.remove(connection)
                connection.close()
                connect()
                reopened += 1
        time.sleep(0.1)
    stop.set()
    for watcher in watchers:
        watcher.join()
    for connection in opened:
        connection.close()
    time.sleep(args.read_timeout + 1)
    after, end = proc(pid), time.monotonic() + 30  # on a loaded machine the closed connections' threads end late
    while after["threads"] > before["threads"] and time.monotonic() < end:
        time.sleep(0.2)
        after = proc(pid)
    ok = [took for status, took in answers if status == 200]
    return [
        f"| sockets opened by the probe (in {connected:.1f} s), then kept open for {args.attack:g} s | {args.slow} (a "
        f"byte every {args.drip:g} s, re-opened when closed: {reopened} times) |",
        f"| child threads: before / peak / after | {before['threads']} / {peak['threads']} / {after['threads']} |",
        f"| child file descriptors: before / peak / after | {before['fds']} / {peak['fds']} / {after['fds']} |",
        f"| a page's requests (every 0.5 s) answered meanwhile | {len(ok)} of {len(answers)}"
        + (f", median {1000 * statistics.median(ok):.0f} ms, max {1000 * max(ok):.0f} ms |" if ok else " |"),
    ]


def refused_bodies(pid: int, port: int, args: argparse.Namespace) -> list[str]:
    """``--bodies`` POSTs without a token announcing 200 MB and sending up to 8 MB each, their connections then left
    open (the client neither sends more nor closes) past the server's read_timeout."""
    head = (
        b"POST /api/answer HTTP/1.1\r\nHost: 127.0.0.1\r\nContent-Type: application/json\r\nContent-Length: 200000000\r\n\r\n"
    )
    chunk, let_through, answered, held = b"x" * 65536, [], 0, []
    before = settled(pid)
    for _ in range(args.bodies):
        connection = socket.create_connection((HOST, port), timeout=5)
        held.append(connection)
        connection.sendall(head)
        sent = 0
        try:
            while sent < 8 * 2**20:
                connection.sendall(chunk)
                sent += len(chunk)
        except OSError:
            pass
        let_through.append(sent / 2**20)
        try:
            answered += connection.recv(65536).startswith(b"HTTP/1.1 401")
        except OSError:
            pass
    time.sleep(args.read_timeout + 1)
    after = settled(pid)
    for connection in held:
        connection.close()
    return [
        f"| POSTs without a token, each announcing 200 MB | {args.bodies} |",
        f"| MB of body each could send before the server closed it | {', '.join(f'{mb:.1f}' for mb in let_through)} |",
        f"| answered 401 before the close | {answered} of {args.bodies} |",
        f"| child memory (RSS, MB): before / {args.read_timeout + 1:g} s later | {before['rss_mb']} / {after['rss_mb']} |",
        f"| child epoll descriptors: before / {args.read_timeout + 1:g} s later | {before['epoll']} / {after['epoll']} |",
        f"| child file descriptors: before / {args.read_timeout + 1:g} s later | {before['fds']} / {after['fds']} |",
    ]


def two_annotators(port: int, tokens: dict[str, str], lines: "queue.Queue[dict]", pairs: int) -> list[str]:
    """Both sessions answered by ana and ben; each answer repeated by the other; every clip shown fetched and hashed."""
    refusals: dict[str, list[tuple[int, str]]] = {}  # question id -> (status, message) the other got
    clips: dict[str, list[str]] = {}  # sha256 -> question ids whose clip it is
    sizes: dict[int, set[str]] = {}  # one clip's size -> question ids (distinct clips may match by chance)
    pair_sizes: dict[tuple[int, int], set[str]] = {}  # both clips' sizes -> question ids (a copy that keeps them)
    known: set[str] = set()
    for number in (1, 2):
        deadline = time.monotonic() + 300
        message = lines.get(timeout=300)
        assert message == {"ready": number}, message  # every clip rendered: both annotators have questions
        finished = None
        while finished is None and time.monotonic() < deadline:
            for name in ANNOTATORS:
                other = ANNOTATORS[1] if name == ANNOTATORS[0] else ANNOTATORS[0]
                status, _, body, _ = request(port, "/api/state", tokens[name])
                state = json.loads(body) if status == 200 else {}
                query = state.get("query")
                if query is None:
                    continue
                shown = [request(port, url, tokens[name])[2] for url in (query["left"], query["right"])]
                for clip in shown:
                    clips.setdefault(hashlib.sha256(clip).hexdigest(), []).append(query["id"])
                    sizes.setdefault(len(clip), set()).add(query["id"])
                small, large = sorted(map(len, shown))
                pair_sizes.setdefault((small, large), set()).add(query["id"])
                if request(port, "/api/answer", tokens[name], {"id": query["id"], "label": 1})[0] != 200:
                    continue
                status, _, body, _ = request(port, "/api/answer", tokens[other], {"id": query["id"], "label": 0})
                error = json.loads(body).get("error", "") if body else ""
                # the last answer closed the session (and the next one may have begun), whatever the question was
                if "no feedback session is open" not in error and "feedback session" + f" {state['session'] + 1}" not in error:
                    refusals[query["id"]] = [(status, error.replace(query["id"], "<id>"))]
            try:
                finished = lines.get(timeout=0.05)
            except queue.Empty:
                pass
        if finished is None:
            raise RuntimeError("a feedback session did not end within 300 s")
        known.update(finished["known"])
    kinds = {"known-answer questions": known, "the model's queries": set(refusals) - known}
    rows = []
    for kind, ids in kinds.items():
        seen = sorted({answer for question in ids for answer in refusals.get(question, [])})
        shared = {q for holders in clips.values() if len(set(holders)) > 1 for q in holders if q in ids}
        same_size = {q for holders in sizes.values() if len(holders) > 1 for q in holders if q in ids}
        same_pair = {q for holders in pair_sizes.values() if len(holders) > 1 for q in holders if q in ids}
        answers = "; ".join(f"{s} {m!r}" for s, m in seen)
        rows.append(f"| {kind} | {len(ids)} | {answers} | {len(shared)} | {len(same_size)} | {len(same_pair)} |")
    return rows


def code_version() -> str:
    """The package's version, and whether ``sb3_pride/`` differs from its git checkout's last commit."""
    import sb3_pride

    root = Path(sb3_pride.__file__).resolve().parent.parent
    try:
        changed = subprocess.run(["git", "status", "--porcelain", "sb3_pride"], cwd=root, capture_output=True, text=True)
    except OSError:
        return f"sb3_pride {sb3_pride.__version__}"
    state = " with uncommitted changes" if changed.stdout.strip() else " as committed"
    return f"sb3_pride {sb3_pride.__version__}{state if changed.returncode == 0 else ''}"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--dripping", type=int, default=50, help="slow sockets timed to their close")
    parser.add_argument("--slow", type=int, default=2000, help="slow sockets kept open at once")
    parser.add_argument("--drip", type=float, default=2.0, help="seconds between two bytes of a slow socket")
    parser.add_argument("--attack", type=float, default=15.0, help="seconds the slow sockets are kept up")
    parser.add_argument("--bodies", type=int, default=10, help="refused POSTs announcing 200 MB")
    parser.add_argument("--pairs", type=int, default=12, help="pairs per feedback session")
    parser.add_argument("--segment-length", type=int, default=25, help="steps per segment (frames per clip)")
    parser.add_argument("--read-timeout", type=float, default=5.0, help="the server's read_timeout")
    parser.add_argument("--max-connections", type=int, help="the server's limit on open connections (its default)")
    parser.add_argument("--out", type=Path, help="write the report there too")
    parser.add_argument("--serve", action="store_true", help=argparse.SUPPRESS)  # the child
    args = parser.parse_args()
    if args.serve:
        serve(args)
        return
    command = "python benchmarks/web_probe.py " + " ".join(sys.argv[1:])
    child = subprocess.Popen(
        [sys.executable, __file__, "--serve", *sys.argv[1:]], stdout=subprocess.PIPE, text=True, env=os.environ
    )
    lines: queue.Queue[dict] = queue.Queue()
    assert child.stdout is not None
    first = json.loads(child.stdout.readline())
    port, tokens = first["port"], first["tokens"]

    def read_lines() -> None:
        assert child.stdout is not None
        for line in child.stdout:
            if line.startswith("{"):
                lines.put(json.loads(line))

    threading.Thread(target=read_lines, daemon=True).start()
    try:
        report = [
            f"    {command}",
            "",
            f"`WebTeacher` in a child process on {HOST} (two annotators, known-answer rate 0.5, read_timeout "
            f"{args.read_timeout:g} s); the probe is its clients. Code: {code_version()}.",
            "",
            "## Two annotators comparing notes",
            "",
            "After one answers a question, the other answers it too; every clip either of them is shown is fetched and hashed.",
            "",
            "| questions | how many | what the other was answered | sharing a clip's bytes with another question"
            " | sharing a clip's size (chance matches included) | sharing both clips' sizes |",
            "|---|---|---|---|---|---|",
            *two_annotators(port, tokens, lines, args.pairs),
            "",
            "## Framing",
            "",
            "| request | status | X-Frame-Options | Content-Security-Policy |",
            "|---|---|---|---|",
            *framing(port, tokens[ANNOTATORS[0]]),
            "",
            "## Refused bodies",
            "",
            "| | |",
            "|---|---|",
            *refused_bodies(child.pid, port, args),
            "",
            "## Slow clients",
            "",
            "| | |",
            "|---|---|",
            *deadline(port, args),
            *flood(child.pid, port, tokens[ANNOTATORS[0]], args),
        ]
    finally:
        child.kill()
        child.wait()
    text = "\n".join(report) + "\n"
    print(text)
    if args.out is not None:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(text)


if __name__ == "__main__":
    main()
