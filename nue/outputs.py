"""Output paths checked before any work starts: a file that is a folder, a folder that is a file, a path
under a file, or a place the user cannot write is refused with :class:`~nue.errors.ConfigError`.

Nothing is created here: the checks look at the path and its nearest existing ancestor only, so a
refused command leaves no trace. The commands create their outputs later, when they write them.
"""

from __future__ import annotations

import os
from pathlib import Path

from nue.errors import ConfigError


def _writable(path: Path) -> bool:
    """Whether we may create or replace entries in (or write to) ``path``."""
    return os.access(path, os.W_OK | (os.X_OK if path.is_dir() else 0))


def _nearest_existing(path: Path) -> Path:
    """``path`` itself or its closest ancestor that exists (``.`` for a relative path with none)."""
    for p in (path, *path.parents):
        if os.path.lexists(p):
            return p
    return Path(".")


def _check_ancestor(path: Path, what: str) -> None:
    """The nearest existing ancestor of ``path`` must be a folder we can create entries in."""
    base = _nearest_existing(path.parent) if path.parent != path else path
    if not base.is_dir():
        raise ConfigError(path, f"cannot create {what}: {base} is a file, not a folder")
    if not _writable(base):
        raise ConfigError(path, f"cannot create {what}: folder {base} is not writable")


def check_output_file(path: str | os.PathLike, what: str = "the output file") -> Path:
    """``path`` as a :class:`Path` if a file can be written there (created or replaced); else ConfigError."""
    path = Path(path)
    if path.is_dir():
        raise ConfigError(path, f"is a directory, but {what} must be a file")
    if path.exists():
        if not _writable(path):
            raise ConfigError(path, f"{what} is not writable")
        return path
    _check_ancestor(path, what)
    return path


def check_output_dir(path: str | os.PathLike, what: str = "the output folder") -> Path:
    """``path`` as a :class:`Path` if it is (or can be created as) a writable folder; else ConfigError."""
    path = Path(path)
    if path.exists() or path.is_symlink():
        if not path.is_dir():
            raise ConfigError(path, f"is a file, but {what} must be a folder")
        if not _writable(path):
            raise ConfigError(path, f"{what} is not writable")
        return path
    _check_ancestor(path, what)
    return path
