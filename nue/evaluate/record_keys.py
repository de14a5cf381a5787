"""One record per key in a records file: the readers (``nue report``, ``nue diagnose``, ``nue view``) refuse a
file in which an episode is recorded twice, or, when asked (``--drop-duplicates``), keep the first record of
each key and count the others.

A record's key is ``extra["key"]`` (``method/scene/episode_id``, as ``nue eval`` writes it), or
``method/scene/episode_id`` for a record without one (``nue expert --records``). Two records are duplicates
when they share the key and the method: rows renamed after their run (method ``nue_v2``, key ``nue/...``) are
not duplicates of that run's own rows. Duplicates are looked for within one file, not across files.
"""

from __future__ import annotations

from pathlib import Path
from typing import Callable

from nue.errors import DataError

DROP_HINT = "--drop-duplicates keeps the first record of each key"
"""What the refusal suggests."""

OnDropped = Callable[[Path, int], None]
"""Told (file, number of records left out) after a file with duplicates was read with ``drop=True``."""


def record_key(d: dict) -> str:
    """The key of a record dict: ``extra["key"]``, else ``method/scene/episode_id``."""
    extra = d.get("extra")
    key = extra.get("key") if isinstance(extra, dict) else None
    return str(key) if key else f"{d.get('method')}/{d.get('scene')}/{d.get('episode_id')}"


class UniqueKeys:
    """The records of one file, fed in file order: :meth:`first` tells whether a record is the first of its key."""

    def __init__(self, path: str | Path, drop: bool = False):
        self.path = Path(path)
        self.drop = drop
        self.dropped = 0
        """Records left out so far (``drop=True``)."""
        self._lines: dict[tuple[str, object], int] = {}

    def first(self, d: dict, line: int) -> bool:
        """True for the first record of its key and method. A later one is :class:`~nue.errors.DataError` naming
        the file, the key and both lines, or, with ``drop``, False (and counted)."""
        ident = (record_key(d), d.get("method"))
        seen = self._lines.setdefault(ident, line)
        if seen == line:
            return True
        if not self.drop:
            raise DataError(self.path, f"record key {ident[0]!r} appears twice (lines {seen} and {line}); {DROP_HINT}")
        self.dropped += 1
        return False

    def report(self, on_dropped: OnDropped | None) -> None:
        """Tell ``on_dropped`` how many records of this file were left out, if any were."""
        if self.dropped and on_dropped is not None:
            on_dropped(self.path, self.dropped)


def dropped_message(path: Path, n: int) -> str:
    """The line the commands print for a file read with ``--drop-duplicates``."""
    return f"{path}: dropped {n} duplicate record{'' if n == 1 else 's'} (kept the first of each key)"
