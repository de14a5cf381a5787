"""Typed errors for bad input: each names the offending file (or object) and the problem in one line.

The CLI catches :class:`NueError`, prints ``error: <message>`` and exits with status 2, so a user
never sees a traceback for a bad scene folder, episode file or checkpoint.
"""

from __future__ import annotations

from pathlib import Path


class NueError(Exception):
    """Base class: a problem with user input, reported as ``<where>: <problem>``."""

    def __init__(self, where: str | Path | None, problem: str):
        self.where = str(where) if where is not None else None
        self.problem = problem
        super().__init__(f"{self.where}: {problem}" if self.where else problem)

    def __reduce__(self):
        """Pickle as (class, (where, problem)), so an error raised in a worker process reaches the driver intact."""
        return type(self), (self.where, self.problem)


class SceneError(NueError):
    """A scene folder is missing a file or holds a malformed mesh, floors.txt or traversability map."""


class EpisodeError(NueError):
    """An episode (file) is malformed or unusable in its scene: NaN pose, start in a wall, unreachable goal."""


class EpisodeGenerationError(NueError):
    """The episode generator could not fill a difficulty bin of a house within its try budget."""


class ConfigError(NueError):
    """An unknown preset name or an inconsistent configuration."""


class CheckpointError(NueError):
    """A checkpoint that cannot be loaded or does not match the requested presets / scenes."""


class DataError(NueError):
    """A demonstration or record file that is corrupt or truncated."""


class InvalidEpisodesError(EpisodeError):
    """Episodes of one file that cannot be run, all named in one line: ``<file>: episode <id>: <problem>; ...``."""

    def __init__(self, where: str | Path | None, invalid: list[tuple[str, str]]):
        self.invalid = list(invalid)
        """(episode id, problem) of each invalid episode, in file order."""
        listed = "; ".join(f"episode {eid}: {problem}" for eid, problem in self.invalid)
        super().__init__(where, listed if len(self.invalid) == 1 else f"{len(self.invalid)} invalid episodes: {listed}")

    def __reduce__(self):
        return type(self), (self.where, self.invalid)


class OutputInUseError(NueError):
    """An output (records file, collection or run folder) that another nue process is writing."""
