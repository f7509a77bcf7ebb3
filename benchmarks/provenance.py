"""
Where a benchmark's numbers came from: :func:`provenance` (the ``sb3_pride`` version and the git commit and code tree
of the checkout it was imported from), :func:`system_info` (the CPU model and the library versions) and
:func:`utc_now` (a time stamp). ``benchmarks/run.py`` records them in every run's ``settings.json``; the other
benchmarks in their result files.
"""

import subprocess
from pathlib import Path
from typing import Any


def git(folder: Path, *argv: str) -> str | None:
    """``git argv`` run in ``folder``, its output stripped (``None`` where git fails or is missing)."""
    try:
        done = subprocess.run(["git", *argv], cwd=folder, capture_output=True, text=True, timeout=30)
    except (OSError, subprocess.TimeoutExpired):
        return None
    return done.stdout.strip() if done.returncode == 0 else None


def provenance() -> dict[str, Any]:
    """
    What code made a run: the version of the ``sb3_pride`` imported (its ``__version__``; an editable install's
    metadata keeps the version it was installed at), the folder it was imported from, and, from the git checkout that
    folder lies in, the commit, whether the checkout had uncommitted changes to tracked files (``dirty``), the tree
    hash of ``sb3_pride/`` at that commit (``code_tree``) and whether ``sb3_pride/`` itself differed from it, untracked
    files included (``code_dirty``). The git fields are ``None`` outside a git checkout (an installed wheel).
    """
    import sb3_pride

    package = Path(sb3_pride.__file__).resolve().parent
    checkout = git(package, "rev-parse", "--show-toplevel")
    commit = git(package, "rev-parse", "HEAD") if checkout else None
    found: dict[str, Any] = {
        "sb3_pride": sb3_pride.__version__,
        "sb3_pride_path": str(package),
        "commit": commit,
        "dirty": None,
        "code_tree": None,
        "code_dirty": None,
    }
    if commit is None or checkout is None:
        return found
    status = git(package, "status", "--porcelain", "--untracked-files=no")
    found["dirty"] = None if status is None else bool(status)
    inside = package.relative_to(Path(checkout).resolve()).as_posix()  # "sb3_pride"
    found["code_tree"] = git(package, "rev-parse", f"HEAD:{inside}")
    code_status = git(package, "status", "--porcelain", "--untracked-files=normal", "--", ".")
    found["code_dirty"] = None if code_status is None else bool(code_status)
    return found


def utc_now() -> str:
    """The time now, UTC, ISO 8601 to the second (``2025-01-31T12:00:00+00:00``)."""
    from datetime import datetime, timezone

    return datetime.now(timezone.utc).isoformat(timespec="seconds")


def system_info() -> dict[str, str]:
    """
    SB3's system info (OS, Python, SB3, PyTorch, NumPy, Gymnasium versions) plus the simulators' versions (MuJoCo,
    dm_control, Meta-World, shimmy), ``sb3_pride``'s ``__version__`` and the CPU model:
    the same seed gives the same run only on the same CPU kind and library versions (float rounding differs), so a
    run records them.
    """
    import platform
    from importlib import metadata

    import torch as th
    from stable_baselines3.common.utils import get_system_info

    import sb3_pride

    info, _ = get_system_info(print_info=False)
    for package in ("mujoco", "dm-control", "metaworld", "shimmy"):
        try:
            info[package] = metadata.version(package)
        except metadata.PackageNotFoundError:
            pass
    # the package's own __version__, as in provenance(): an editable install's metadata keeps the version it was
    # installed at
    info["sb3_pride"] = sb3_pride.__version__
    cpuinfo = Path("/proc/cpuinfo")
    models = (
        [line.split(":", 1)[1].strip() for line in cpuinfo.read_text().splitlines() if line.startswith("model name")]
        if cpuinfo.exists()
        else []
    )
    info["CPU"] = models[0] if models else platform.processor() or platform.machine()
    info["PyTorch CPU capability"] = th.backends.cpu.get_cpu_capability()  # which vector kernels torch dispatches to
    return info
