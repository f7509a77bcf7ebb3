"""
Checkpoints written as one unit, and resumed from the newest complete one.

A checkpoint is SB3's (``CheckpointCallback``'s names): ``{prefix}_{N}_steps.zip`` (the model) with, beside it,
``{prefix}_replay_buffer_{N}_steps.pkl`` and ``{prefix}_vecnormalize_{N}_steps.pkl`` when they are saved. SB3 writes
the model first, so a run killed while its buffer is written leaves a model without its buffer. This module's
``CheckpointCallback`` writes the buffer (and the statistics) first and the model last, each file under a temporary
name renamed once complete (``atomic_write_path``): the model's rename completes the checkpoint, and a model on disk
always has its buffer beside it. ``clean_leftovers`` removes what a killed save left (temporary files, a buffer
whose model was never written), ``latest_checkpoint`` finds the newest complete checkpoint of a folder and
``resume`` loads it, replay buffer included. ``AtomicSaves`` (mixed into ``PEBBLE``) makes every ``save`` and
``save_replay_buffer`` such a rename.
"""

import contextlib
import os
import re
import warnings
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TypeVar

from stable_baselines3.common import callbacks
from stable_baselines3.common.base_class import BaseAlgorithm


SelfAlgorithm = TypeVar("SelfAlgorithm", bound=BaseAlgorithm)

#: ``atomic_write_path``'s temporary files: ``.{name}.{pid}.tmp``
TEMPORARY_FILE = re.compile(r"\.(?P<name>.+)\.(?P<pid>\d+)\.tmp")


@contextlib.contextmanager
def atomic_write_path(path: str | os.PathLike, suffix: str | None = None) -> Iterator[Path]:
    """
    A temporary path beside ``path`` to write to; when the block ends without error it is flushed to disk and
    renamed onto ``path`` (one atomic step), so a reader, or a run killed mid-write, sees the old file or the new
    one, never half of one. On error the temporary file is removed and ``path`` is untouched.

    :param suffix: appended to ``path`` when it has none (SB3's rule: ".zip" for models, ".pkl" for buffers)
    """
    final = Path(path)
    if final.suffix == "" and suffix:
        final = final.with_name(f"{final.name}.{suffix}")
    final.parent.mkdir(parents=True, exist_ok=True)
    temporary = final.with_name(f".{final.name}.{os.getpid()}.tmp")
    try:
        yield temporary
        with open(temporary, "rb") as file:
            os.fsync(file.fileno())
        os.replace(temporary, final)
    finally:
        temporary.unlink(missing_ok=True)


class AtomicSaves:
    """
    SB3's ``save`` and ``save_replay_buffer`` written to a temporary file renamed over ``path`` once complete, so that
    a run killed mid-save leaves the previous checkpoint readable (mixed in before the algorithm's class).
    """

    def save(self, path, exclude=None, include=None) -> None:
        if not isinstance(path, (str, os.PathLike)):
            return super().save(path, exclude, include)  # type: ignore[misc]
        with atomic_write_path(path, suffix="zip") as temporary:
            super().save(temporary, exclude, include)  # type: ignore[misc]

    def save_replay_buffer(self, path) -> None:
        if not isinstance(path, (str, os.PathLike)):
            return super().save_replay_buffer(path)  # type: ignore[misc]
        with atomic_write_path(path, suffix="pkl") as temporary:
            super().save_replay_buffer(temporary)  # type: ignore[misc]


@dataclass(frozen=True)
class Checkpoint:
    """A checkpoint's files: the model, and its replay buffer and ``VecNormalize`` statistics (None: not saved)."""

    step: int
    model: Path
    replay_buffer: Path | None = None
    vecnormalize: Path | None = None


def checkpoint_path(folder: str | os.PathLike, name_prefix: str, step: int, kind: str = "") -> Path:
    """The path of a checkpoint's file, as SB3's ``CheckpointCallback`` names it (``kind``: "", ``"replay_buffer_"``
    or ``"vecnormalize_"``)."""
    return Path(folder) / f"{name_prefix}_{kind}{step}_steps.{'pkl' if kind else 'zip'}"


def _steps(folder: Path, name_prefix: str, kind: str = "") -> list[int]:
    """The steps of the files of one kind of a folder's checkpoints, oldest first."""
    pattern = re.compile(rf"{re.escape(name_prefix)}_{kind}(\d+)_steps\.{'pkl' if kind else 'zip'}")
    found = (pattern.fullmatch(path.name) for path in folder.iterdir()) if folder.is_dir() else iter(())
    return sorted(int(match[1]) for match in found if match)


def _abandoned(path: Path, name_prefix: str) -> bool:
    """Whether ``path`` is a temporary file (``atomic_write_path``'s) that no running process is writing."""
    match = TEMPORARY_FILE.fullmatch(path.name)
    if match is None or not path.is_file():
        return False
    pid = int(match["pid"])
    if pid == os.getpid():  # its id taken again (by a restarted container's first process): none of its checkpoints
        # is being written while it cleans up (other files may be)
        return re.fullmatch(rf"{re.escape(name_prefix)}_\w*?\d+_steps\.(zip|pkl)", match["name"]) is not None
    if os.name != "posix":  # no signal 0 there: an open file cannot be removed anyway
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return True
    except PermissionError:  # another user's
        return False
    return False


def clean_leftovers(folder: str | os.PathLike, name_prefix: str = "rl_model") -> list[Path]:
    """
    Remove what a save killed midway left in ``folder``: the temporary files of processes no longer running
    (``atomic_write_path``'s; a checkpoint's even under this process's id, which a restarted container reuses), and
    the replay buffers and statistics of a checkpoint whose model was never written, newer than the newest model (a
    complete checkpoint is never touched).

    :param folder: the checkpoints' folder (``CheckpointCallback``'s ``save_path``)
    :param name_prefix: the checkpoints' prefix
    :return: the paths removed
    """
    folder = Path(folder)
    if not folder.is_dir():
        return []
    removed = [path for path in folder.iterdir() if _abandoned(path, name_prefix)]
    models = _steps(folder, name_prefix)
    newest = models[-1] if models else -1
    for kind in ("replay_buffer_", "vecnormalize_"):
        removed += [
            checkpoint_path(folder, name_prefix, step, kind) for step in _steps(folder, name_prefix, kind) if step > newest
        ]
    for path in removed:
        try:
            path.unlink()
        except OSError as error:  # held open (a running writer where its pid cannot be checked): left alone
            warnings.warn(f"{path} was left in place: {error}")
    return [path for path in removed if not path.exists()]


def latest_checkpoint(folder: str | os.PathLike, name_prefix: str = "rl_model") -> Checkpoint | None:
    """
    The newest complete checkpoint of ``folder``, None when there is none: the model of the highest step with its
    replay buffer beside it or, in a folder where no checkpoint has one (a run that saves none), the newest model.
    A model without its buffer where others have theirs is a save cut short by a kill (SB3's ``CheckpointCallback``
    writes the model first) and is passed over.

    :param folder: the checkpoints' folder (``CheckpointCallback``'s ``save_path``)
    :param name_prefix: the checkpoints' prefix
    """
    folder = Path(folder)
    models = _steps(folder, name_prefix)
    with_buffer = set(models) & set(_steps(folder, name_prefix, "replay_buffer_"))
    complete = sorted(with_buffer) if with_buffer else models
    if not complete:
        return None
    step = complete[-1]
    files = [checkpoint_path(folder, name_prefix, step, kind) for kind in ("replay_buffer_", "vecnormalize_")]
    replay_buffer, vecnormalize = (path if path.is_file() else None for path in files)
    return Checkpoint(step, checkpoint_path(folder, name_prefix, step), replay_buffer, vecnormalize)


def resume(
    algo: type[SelfAlgorithm], folder: str | os.PathLike, env: Any = None, name_prefix: str = "rl_model", **load_kwargs: Any
) -> SelfAlgorithm:
    """
    Load the newest complete checkpoint of ``folder`` (``latest_checkpoint``), its replay buffer included, after
    removing what a killed save left there (``clean_leftovers``). Then ``learn(n, reset_num_timesteps=False)`` goes on
    from its step; a PEBBLE or PRIDE model takes back from its preference journal the answers given after it.

    :param algo: the algorithm's class (``PEBBLE``, ``PRIDE``, or any SB3 algorithm)
    :param folder: the checkpoints' folder (``CheckpointCallback``'s ``save_path``)
    :param env: the environment to go on in (``algo.load``'s)
    :param name_prefix: the checkpoints' prefix
    :param load_kwargs: more of ``algo.load``'s arguments
    :return: the model, at the checkpoint's step
    """
    clean_leftovers(folder, name_prefix)
    checkpoint = latest_checkpoint(folder, name_prefix)
    if checkpoint is None:
        raise FileNotFoundError(f"resume: no checkpoint {name_prefix}_N_steps.zip in {os.fspath(folder)}")
    model = algo.load(checkpoint.model, env=env, **load_kwargs)
    if checkpoint.replay_buffer is not None:
        model.load_replay_buffer(checkpoint.replay_buffer)  # type: ignore[attr-defined]
    elif getattr(model, "replay_buffer", None) is not None:
        warnings.warn(f"resume: {checkpoint.model} has no replay buffer beside it: the run goes on with an empty one")
    return model


class CheckpointCallback(callbacks.CheckpointCallback):
    """
    SB3's ``CheckpointCallback`` (same arguments and file names), each checkpoint written as one unit: the replay
    buffer and ``VecNormalize`` statistics first, the model last, each under a temporary name renamed once complete.
    A run killed during a save leaves its previous checkpoints complete and the newest model with its buffer; at its
    start the callback removes what a killed save left in ``save_path`` (``clean_leftovers``).
    """

    def _init_callback(self) -> None:
        super()._init_callback()
        clean_leftovers(self.save_path, self.name_prefix)

    def _on_step(self) -> bool:
        if self.n_calls % self.save_freq == 0:
            self.save_checkpoint()
        return True

    def save_checkpoint(self) -> Checkpoint:
        """Write a checkpoint of the model at its current step, the model last; return its files."""
        step, folder = self.num_timesteps, self.save_path
        replay_buffer = vecnormalize = None
        if self.save_replay_buffer and getattr(self.model, "replay_buffer", None) is not None:
            replay_buffer = checkpoint_path(folder, self.name_prefix, step, "replay_buffer_")
            self._write_whole(replay_buffer, self.model.save_replay_buffer)  # type: ignore[attr-defined]
        normalize = self.model.get_vec_normalize_env()
        if self.save_vecnormalize and normalize is not None:
            vecnormalize = checkpoint_path(folder, self.name_prefix, step, "vecnormalize_")
            self._write_whole(vecnormalize, normalize.save, by_itself=False)
        model = checkpoint_path(folder, self.name_prefix, step)
        self._write_whole(model, self.model.save)
        if self.verbose >= 2:
            print(
                f"Saving model checkpoint to {model}" + (f" with its replay buffer {replay_buffer}" if replay_buffer else "")
            )
        return Checkpoint(step, model, replay_buffer, vecnormalize)

    def _write_whole(self, path: Path, save: Callable[[Any], None], by_itself: bool = True) -> None:
        if by_itself and isinstance(self.model, AtomicSaves):  # PEBBLE's and PRIDE's saves are written whole already
            save(path)
            return
        with atomic_write_path(path) as temporary:
            save(temporary)
