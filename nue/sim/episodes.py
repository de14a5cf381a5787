"""Navigation episodes: the record of a start pose and a goal pose, validation, and both file formats.

Our JSON (``nue-episodes/1``) stores habitat-style fields per episode plus the scene's content hash
and the task preset; the authors' format is a bare list of
``{startXYZ, startQuat, endXYZ, endQuat, dist, pathDist}`` (quaternions x, y, z, w; z up);
habitat-lab's datasets (y up) are converted by :mod:`nue.sim.habitat_format`. Reading checks every
episode and reports all invalid ones of a file together (or skips them, listed, on request).
"""

from __future__ import annotations

import gzip
import json
import math
import os
import tempfile
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from nue.errors import EpisodeError, InvalidEpisodesError
from nue.sim import episode_fields as fields_
from nue.sim import habitat_format as habitat
from nue.sim.camera import quat_from_yaw, yaw_from_quat
from nue.sim.task import TaskConfig, get_task

FORMAT = "nue-episodes/1"


@dataclass(frozen=True)
class Episode:
    """One image-goal episode: start pose, goal pose (the goal photo is rendered there), distances."""

    episode_id: str
    """Identifier, unique within the file."""
    scene: str
    """Scene name."""
    start_position: tuple[float, float, float]
    """Start (x, y, z), metres; z is the floor height (or the robot base height in the authors' files)."""
    start_rotation: tuple[float, float, float, float]
    """Start orientation quaternion (x, y, z, w), a rotation about +z."""
    goal_position: tuple[float, float, float]
    """Goal (x, y, z), metres."""
    goal_rotation: tuple[float, float, float, float]
    """Orientation of the camera that takes the goal photo, quaternion (x, y, z, w)."""
    euclidean_distance: float
    """Straight-line xy start-goal distance, metres."""
    geodesic_distance: float
    """Shortest-path start-goal distance for the robot's disc, metres."""
    difficulty: str = ""
    """Difficulty bin name."""
    path_type: str = ""
    """``straight`` (geodesic / euclidean < 1.2) or ``curved``."""
    scene_hash: str = ""
    """Content hash of the scene the episode was generated in ('' if unknown)."""

    @property
    def start_pose(self) -> np.ndarray:
        """(x, y, yaw) of the start."""
        return np.array([self.start_position[0], self.start_position[1], yaw_from_quat(self.start_rotation)])

    @property
    def goal_pose(self) -> np.ndarray:
        """(x, y, yaw) of the goal camera."""
        return np.array([self.goal_position[0], self.goal_position[1], yaw_from_quat(self.goal_rotation)])

    @classmethod
    def from_dict(cls, d: dict) -> "Episode":
        """Inverse of ``dataclasses.asdict`` (JSON lists become tuples)."""
        fields: dict[str, Any] = {k: tuple(v) if isinstance(v, list) else v for k, v in d.items()}
        return cls(**fields)

    @classmethod
    def from_poses(cls, episode_id, scene, start_pose, goal_pose, z: float = 0.0, **kw) -> "Episode":
        return cls(
            episode_id=str(episode_id),
            scene=scene,
            start_position=(float(start_pose[0]), float(start_pose[1]), float(z)),
            start_rotation=tuple(float(v) for v in quat_from_yaw(float(start_pose[2]))),
            goal_position=(float(goal_pose[0]), float(goal_pose[1]), float(z)),
            goal_rotation=tuple(float(v) for v in quat_from_yaw(float(goal_pose[2]))),
            **kw,
        )


def finite_problem(ep: Episode, floors=None) -> str | None:
    """What is wrong with ``ep``'s poses without a map (NaN, a rotation that is not a unit quaternion
    about +z, start = goal; with ``floors``, a z off every floor), or None; see
    :func:`nue.sim.episode_fields.geometry_problem`."""
    return fields_.geometry_problem(ep, floors)


@dataclass(frozen=True)
class Snap:
    """How far an episode's start and goal are moved to navigable cells for geodesics and the expert."""

    start: float = 0.0
    """Metres from the start to where the robot is placed (0 = the start is navigable)."""
    goal: float = 0.0
    """Metres from the goal to the cell geodesics and the expert aim at (0 = its cell is navigable);
    the goal photo and Euclidean distances still use the goal itself."""


def check_episode(ep: Episode, navgrid, floors=None) -> tuple[Snap | None, str | None]:
    """``(snap, None)`` if ``ep`` is usable on ``navgrid``, else ``(None, problem)``.

    A start or goal off the navigable cells but on the floor and within the grid's snap tolerance is
    snapped (:meth:`~nue.scene.navgrid.NavGrid.snap`); the episode keeps its positions, ``snap``
    says how far they are moved. Problems: those of :func:`finite_problem` (z checked against
    ``floors`` if given), a start or goal inside an obstacle or wall or
    too far from navigable cells, a goal unreachable from the start."""
    problem = finite_problem(ep, floors)
    if problem:
        return None, problem
    tol = navgrid.config.snap_tolerance
    start, start_d = navgrid.snap(ep.start_position[:2])
    goal, goal_d = navgrid.snap(ep.goal_position[:2], on_cell=True)
    for name, xy, point, d in (("start", ep.start_position, start, start_d), ("goal", ep.goal_position, goal, goal_d)):
        if point is None:
            where = (f"inside an obstacle or wall ({d:.2f} m from the nearest navigable cell)" if not navgrid.on_floor(xy[:2])
                     else f"{d:.2f} m from the nearest navigable cell (snap tolerance {tol:g} m)")
            verb = "is unreachable: " if name == "goal" else "is "
            return None, f"{name} {list(xy[:2])} {verb}{where}"
    if not np.isfinite(navgrid.geodesic_distance(start, goal)):
        return None, f"goal {list(ep.goal_position[:2])} is unreachable from the start"
    return Snap(start_d, goal_d), None


def validate_episode(ep: Episode, navgrid, where=None) -> Snap:
    """How far ``ep``'s start and goal are snapped (see :func:`check_episode`); :class:`EpisodeError` if unusable."""
    snap, problem = check_episode(ep, navgrid)
    if problem:
        raise EpisodeError(where, f"episode {ep.episode_id}: {problem}")
    return snap


def _atomic_write_bytes(path: Path, data: bytes) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    with os.fdopen(fd, "wb") as f:
        f.write(data)
    os.replace(tmp, path)


def _atomic_write_text(path: Path, text: str) -> None:
    _atomic_write_bytes(path, text.encode())


def save_episodes(path, episodes: Sequence[Episode], task: TaskConfig | str = "paper", fmt: str = "nue") -> Path:
    """Write episodes atomically, in our format (``nue``), the authors' (``authors``) or habitat-lab's
    (``habitat``; gzip-compressed when ``path`` ends in ``.gz``, see :mod:`nue.sim.habitat_format`)."""
    path = Path(path)
    if fmt == "authors":
        items = [
            {
                "startXYZ": list(e.start_position),
                "startQuat": list(e.start_rotation),
                "endXYZ": list(e.goal_position),
                "endQuat": list(e.goal_rotation),
                "dist": e.euclidean_distance,
                "pathDist": e.geodesic_distance,
            }
            for e in episodes
        ]
        _atomic_write_text(path, json.dumps(items, indent=1))
        return path
    if fmt == "habitat":
        radius = get_task(task).success_radius
        text = json.dumps({"episodes": [habitat.habitat_from_fields(e, radius) for e in episodes]})
        if path.name.endswith(".gz"):
            _atomic_write_bytes(path, gzip.compress(text.encode(), mtime=0))
        else:
            _atomic_write_bytes(path, text.encode())
        return path
    if fmt != "nue":
        raise EpisodeError(path, f"unknown episode format {fmt!r} (use 'nue', 'authors' or 'habitat')")
    doc = {"format": FORMAT, "task": get_task(task).name, "episodes": [asdict(e) for e in episodes]}
    _atomic_write_text(path, json.dumps(doc, indent=1))
    return path


@dataclass(frozen=True)
class InvalidEpisode:
    """An episode of a file that cannot be run: which file, which episode, what is wrong."""

    file: str
    """The episode file."""
    episode_id: str
    """The episode's id (for an unparsable entry: its index in the file)."""
    problem: str
    """What is wrong, one line."""

    def __str__(self) -> str:
        return f"{self.file}: episode {self.episode_id}: {self.problem}"


@dataclass(frozen=True)
class EpisodeSet:
    """The episodes read from one file, and the invalid ones left out (only with ``skip_invalid``)."""

    episodes: list[Episode]
    """Usable episodes, in file order, positions as in the file."""
    skipped: list[InvalidEpisode]
    """Episodes left out, in file order."""
    snapped: dict[str, Snap]
    """Episode id -> its snap, for the (validated) episodes whose start or goal is snapped."""


def load_episodes(
    path, scene=None, task: TaskConfig | str = "paper", scene_name: str | None = None, navgrid=None
) -> list[Episode]:
    """The episodes of a file (see :func:`read_episodes`); any invalid episode raises :class:`InvalidEpisodesError`."""
    return read_episodes(path, scene, task, scene_name, navgrid).episodes


def read_episodes(
    path, scene=None, task: TaskConfig | str = "paper", scene_name: str | None = None, navgrid=None,
    skip_invalid: bool = False,
) -> EpisodeSet:
    """Read an episode file in any of the three formats (detected from its content; ``.gz`` is gunzipped).

    With ``scene`` (a :class:`~nue.scene.scene.Scene`), episodes recording a different content hash
    are refused, and episodes without labels (the authors', habitat's) get their scene name,
    difficulty and path type from ``task``'s bins; a habitat file holding several scenes gives the
    episodes of this one. Every episode is checked (a malformed entry, a NaN pose and, with
    ``navgrid``, the checks of :func:`check_episode`; snapped ones are listed in ``snapped``).
    Invalid episodes are all named in one :class:`InvalidEpisodesError` (file, ids, problems), or
    with ``skip_invalid`` left out and listed in ``skipped``.
    """
    path = Path(path)
    if not path.is_file():
        raise EpisodeError(path, "episode file not found")
    try:
        raw = path.read_bytes()
        doc = json.loads(gzip.decompress(raw) if raw[:2] == b"\x1f\x8b" else raw)
    except (json.JSONDecodeError, UnicodeDecodeError, OSError, EOFError) as exc:
        raise EpisodeError(path, f"not valid JSON ({exc})") from None
    task = get_task(task)
    name = scene_name or (scene.name if scene is not None else "")
    if isinstance(doc, list):
        parsed = [_from_authors(item, i, name, task) for i, item in enumerate(doc)]
    elif isinstance(doc, dict) and doc.get("format") == FORMAT:
        if doc.get("task", task.name) != task.name:
            raise EpisodeError(path, f"episodes made for task preset {doc['task']!r}, but this run uses {task.name!r} "
                                     f"(pass --task {doc['task']})")
        items = doc.get("episodes")
        if not isinstance(items, list):
            raise EpisodeError(path, f"'episodes' must be a list, got {fields_._describe(items)}")
        parsed = [_from_ours(item, i) for i, item in enumerate(items)]
    elif habitat.is_habitat(doc):
        parsed = _from_habitat(doc["episodes"], name, task, path)
    else:
        raise EpisodeError(path, f"unknown episode file format (expected a list, format {FORMAT!r} or habitat's)")
    if not parsed:
        raise EpisodeError(path, "the file holds no episodes")
    parsed = _mark_duplicates(parsed)
    if scene is not None:
        for e in parsed:
            if isinstance(e, Episode) and e.scene_hash and e.scene_hash != scene.content_hash:
                raise EpisodeError(
                    path,
                    f"episode {e.episode_id} was made for scene content {e.scene_hash}, "
                    f"but {scene.path} has content {scene.content_hash} (the scene changed)",
                )
    floors = scene.floor_heights if scene is not None else None
    episodes, invalid, snapped = [], [], {}
    for e in parsed:
        if isinstance(e, InvalidEpisode):
            invalid.append(replace(e, file=str(path)))
            continue
        snap, problem = (check_episode(e, navgrid, floors) if navgrid is not None
                         else (Snap(), finite_problem(e, floors)))
        if problem:
            invalid.append(InvalidEpisode(str(path), e.episode_id, problem))
            continue
        episodes.append(e)
        if snap != Snap():
            snapped[e.episode_id] = snap
    if invalid and not skip_invalid:
        raise InvalidEpisodesError(path, [(e.episode_id, e.problem) for e in invalid])
    return EpisodeSet(episodes, invalid, snapped)


def _entry_id(item, i: int) -> str:
    """An entry's id for messages: its ``episode_id`` if it is a usable string, else ``#<index>``."""
    eid = item.get("episode_id") if isinstance(item, dict) else None
    return eid if isinstance(eid, str) else str(eid) if isinstance(eid, int) and not isinstance(eid, bool) else f"#{i}"


def _from_ours(item, i: int) -> Episode | InvalidEpisode:
    try:
        return Episode(**fields_.parse_ours(item, Episode))
    except fields_.FieldProblem as exc:
        return InvalidEpisode("", _entry_id(item, i), str(exc))


def _mark_duplicates(parsed: list) -> list:
    """Entries whose id repeats an earlier entry's become invalid (ids key records and resumes)."""
    first: dict[str, int] = {}
    out = []
    for i, e in enumerate(parsed):
        if isinstance(e, Episode):
            if e.episode_id in first:
                e = InvalidEpisode("", e.episode_id, f"duplicate episode id (entry {i}; first used by entry {first[e.episode_id]})")
            else:
                first[e.episode_id] = i
        out.append(e)
    return out


def _labelled(fields: dict, task: TaskConfig) -> Episode:
    """An episode from its fields, with difficulty and path type from ``task``'s bins."""
    difficulty, path_type = task.bins.label(fields["euclidean_distance"], fields["geodesic_distance"])
    return Episode(**fields, difficulty=difficulty, path_type=path_type)


def _from_habitat(items: list, name: str, task: TaskConfig, path) -> list[Episode | InvalidEpisode]:
    """The entries of a habitat file (those of scene ``name`` if it holds several scenes), each an
    :class:`Episode` or, if malformed, an :class:`InvalidEpisode` naming the field. An entry without a
    usable ``scene_id`` is kept, and reported, whichever scene is asked for."""
    scenes = [habitat.scene_of(item) for item in items]
    keep = range(len(items))
    if name and len({s for s in scenes if s}) > 1:
        keep = [i for i, s in enumerate(scenes) if s in (name, None)]
        if all(scenes[i] is None for i in keep):
            raise EpisodeError(path, f"no episodes of scene {name!r} (the file has "
                                     f"{', '.join(sorted({s for s in scenes if s}))})")
    out: list[Episode | InvalidEpisode] = []
    for i in keep:
        try:
            out.append(_labelled(habitat.fields_from_habitat(items[i], name or scenes[i] or ""), task))
        except fields_.FieldProblem as exc:
            out.append(InvalidEpisode("", _entry_id(items[i], i), str(exc)))
    return out


def _from_authors(item, i: int, scene: str, task: TaskConfig) -> Episode | InvalidEpisode:
    try:
        if not isinstance(item, dict):
            raise fields_.FieldProblem(f"expected an object with startXYZ, startQuat, endXYZ, endQuat, got a "
                                       f"{type(item).__name__}")
        missing = [k for k in AUTHORS_KEYS[:4] if k not in item]
        if missing:
            raise fields_.FieldProblem(f"missing field(s): {', '.join(missing)}")
        start, goal = fields_.vector(item["startXYZ"], "startXYZ", 3), fields_.vector(item["endXYZ"], "endXYZ", 3)
        sq, gq = fields_.vector(item["startQuat"], "startQuat", 4), fields_.vector(item["endQuat"], "endQuat", 4)
        dist = fields_.number(item.get("dist", math.hypot(goal[0] - start[0], goal[1] - start[1])), "dist")
        path_dist = fields_.number(item.get("pathDist", dist), "pathDist")
        problem = fields_.quaternion_problem(sq, "startQuat") or fields_.quaternion_problem(gq, "endQuat")
        if problem:
            raise fields_.FieldProblem(problem)
    except fields_.FieldProblem as exc:
        return InvalidEpisode("", str(i), str(exc))
    return _labelled(dict(episode_id=str(i), scene=scene, start_position=start, start_rotation=sq, goal_position=goal,
                          goal_rotation=gq, euclidean_distance=dist, geodesic_distance=path_dist), task)


AUTHORS_KEYS = ("startXYZ", "startQuat", "endXYZ", "endQuat", "dist", "pathDist")
"""Fields of one entry of the authors' format (the last two optional)."""

