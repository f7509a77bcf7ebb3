"""
Run folders claimed by the grid process that runs them, so that several grid processes on the same folders share the
runs out (``benchmarks/run.py``'s ``run_specs``): a folder's :data:`CLAIM` file names the processes that hold it
(:func:`claim_holders`); :func:`claim_run` takes a free folder, or one whose processes are all gone.
"""

import os
from pathlib import Path

#: the file in a run folder that names the grid process running it (:func:`claim_run`)
CLAIM = "claim"


def process_alive(pid: int) -> bool:
    """Whether a process of this id runs on this machine."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # it runs, as another user
        return True
    return True


def claim_holders(path: Path) -> list[int] | None:
    """
    The process ids a run folder's claim names: the grid process that claimed it, then the worker it started (which
    goes on if that grid process is stopped); ``[]`` without a claim, ``None`` while one is being written (empty).
    """
    text = path.read_text().strip() if path.exists() else ""
    if not text:
        return None if path.exists() else []
    words = text.split()
    return [int(word) for word in words] if all(word.isdigit() for word in words) else None


def claim_run(folder: Path) -> bool:
    """
    Claim a run folder for this process, so that another grid process on the same folders leaves it (its ``claim``
    file holds the process ids, :func:`claim_holders`; a claim none of whose processes lives is taken over): False if
    a live process holds it.
    """
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / CLAIM
    for _ in range(2):
        try:
            fd = os.open(path, os.O_CREAT | os.O_EXCL | os.O_WRONLY)
        except FileExistsError:
            holders = claim_holders(path)
            if holders is None:  # being written
                return False
            if any(process_alive(pid) for pid in holders):
                return os.getpid() in holders
            path.unlink(missing_ok=True)
            continue
        with os.fdopen(fd, "w") as file:
            file.write(str(os.getpid()))
        return True
    return False


def claimed_elsewhere(folder: Path) -> bool:
    """Whether a live process other than this one holds the run folder's claim."""
    holders = claim_holders(folder / CLAIM) or []
    return os.getpid() not in holders and any(process_alive(pid) for pid in holders)
