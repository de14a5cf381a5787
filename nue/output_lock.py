"""One writer per output: an advisory lock held while a command writes a resumable output (an evaluation's
records file, a collection folder, a training, DAgger, selection or reproduce run folder).

The lock is ``fcntl.flock`` on a hidden file beside the output (``records.jsonl`` -> ``.records.jsonl.lock``,
``runs/nue`` -> ``runs/.nue.lock``) that holds the writer's pid; it is removed when the writer releases it.
A second writer finds it taken and stops at once with :class:`~nue.errors.OutputInUseError`
``<output>: in use by another nue process (pid N)``, before it reads or writes anything of the output.

The kernel drops a flock when the process holding it ends, however it ends (``kill -9`` included), so the
lock of a killed writer is simply taken over by the next one; the pid it left in the file is read only for
messages (:attr:`OutputLock.took_over_from`). The lock is advisory: it keeps nue processes apart, not
other programs, and needs a file system with working locks (local disks; NFS on Linux).

Within one process the lock is re-entrant: a command holding its run folder may call a library function
that locks the same output again (``nue train`` running closed-loop selection, ``nue dagger`` writing its
summary). Worker processes never lock: their driver holds the output and writes every result.
"""

from __future__ import annotations

import contextlib
import fcntl
import os
import threading
from dataclasses import dataclass
from pathlib import Path
from typing import Iterator

from nue.errors import ConfigError, OutputInUseError


@dataclass(frozen=True)
class OutputLock:
    """A held lock on ``output``."""

    output: Path
    """The output as the caller named it."""
    path: Path
    """The lock file beside it."""
    took_over_from: int | None = None
    """Pid of a writer that had died holding the lock (its file was left behind), else None."""


_HELD: dict[str, list] = {}
"""Lock file (absolute) -> [file descriptor, depth, OutputLock] of the locks this process holds."""
_GUARD = threading.Lock()


def lock_file(output: str | os.PathLike) -> Path:
    """The lock file of ``output``: ``.<name>.lock`` in the folder that holds it."""
    path = Path(os.path.abspath(output))
    return path.parent / f".{path.name}.lock"


@contextlib.contextmanager
def hold_output(output: str | os.PathLike) -> Iterator[OutputLock]:
    """Hold the lock of ``output`` for the ``with`` block; :class:`~nue.errors.OutputInUseError` at once if
    another process holds it. Creates the output's parent folder if needed (for the lock file)."""
    key = str(lock_file(output))
    with _GUARD:
        held = _HELD.get(key)
        if held is not None:
            held[1] += 1
        else:
            fd, previous = _acquire(Path(output), Path(key))
            held = _HELD[key] = [fd, 1, OutputLock(Path(output), Path(key), previous)]
    try:
        yield held[2]
    finally:
        with _GUARD:
            held[1] -= 1
            if held[1] == 0:
                del _HELD[key]
                _release(Path(key), held[0])


def _acquire(output: Path, lock: Path) -> tuple[int, int | None]:
    """(open descriptor of the locked file, pid a dead writer left in it or None)."""
    try:
        lock.parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise ConfigError(output, f"cannot create its lock file {lock} ({exc.strerror or exc})") from None
    while True:
        try:
            fd = os.open(lock, os.O_RDWR | os.O_CREAT, 0o644)
        except OSError as exc:
            raise ConfigError(output, f"cannot create its lock file {lock} ({exc.strerror or exc})") from None
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            pid = _read_pid(fd)
            os.close(fd)
            raise OutputInUseError(output, f"in use by another nue process (pid {pid or 'unknown'})") from None
        except OSError as exc:
            os.close(fd)
            raise ConfigError(output, f"cannot lock {lock} ({exc.strerror or exc})") from None
        # The holder removes the file when it lets go: if that happened between our open and our flock, we
        # hold a file nobody else will open; start again on the current one.
        try:
            current = os.path.samestat(os.fstat(fd), os.stat(lock))
        except FileNotFoundError:
            current = False
        if current:
            break
        os.close(fd)
    previous = _read_pid(fd)
    os.ftruncate(fd, 0)
    os.pwrite(fd, f"{os.getpid()}\n".encode(), 0)
    return fd, previous if previous and previous != os.getpid() else None


def _release(lock: Path, fd: int) -> None:
    """Remove the lock file while still holding it, then let go (a writer that opened it meanwhile retries)."""
    with contextlib.suppress(FileNotFoundError):
        os.unlink(lock)
    os.close(fd)


def _read_pid(fd: int) -> int | None:
    """The pid written in a lock file, None if it holds none (yet)."""
    text = os.pread(fd, 32, 0).decode(errors="replace").strip()
    return int(text) if text.isdigit() else None
