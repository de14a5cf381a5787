"""Navigation episodes: the record of a start pose and a goal pose, validation, and both file formats.

Our JSON (``nue-episodes/1``) stores habitat-style fields per episode plus the scene's content hash
and the task preset; the authors' format is a bare list of
``{startXYZ, startQuat, endXYZ, endQuat, dist, pathDist}`` (quaternions x, y, z, w; z up).
"""

from __future__ import annotations

import json
import math
import os
import tempfile
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import Sequence

import numpy as np

from nue.errors import EpisodeError
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
        return cls(**{k: tuple(v) if isinstance(v, list) else v for k, v in d.items()})

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


def check_finite(ep: Episode, where) -> None:
    """Raise :class:`EpisodeError` if a pose of ``ep`` holds NaN or inf."""
    for name in ("start_position", "start_rotation", "goal_position", "goal_rotation"):
        if not all(math.isfinite(v) for v in getattr(ep, name)):
            raise EpisodeError(where, f"episode {ep.episode_id}: {name} is not finite: {list(getattr(ep, name))}")


def validate_episode(ep: Episode, navgrid, where=None) -> None:
    """Raise :class:`EpisodeError` for a NaN pose, a start or goal outside free space, or an unreachable goal."""
    where = where or f"episode {ep.episode_id}"
    check_finite(ep, where)
    if not navgrid.is_free(ep.start_position[:2]):
        raise EpisodeError(where, f"episode {ep.episode_id}: start {ep.start_position[:2]} is inside an obstacle or wall")
    if not np.isfinite(navgrid.geodesic_distance(ep.start_position[:2], ep.goal_position[:2])):
        raise EpisodeError(where, f"episode {ep.episode_id}: goal {ep.goal_position[:2]} is unreachable from the start")


def _atomic_write_text(path: Path, text: str) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    with os.fdopen(fd, "w") as f:
        f.write(text)
    os.replace(tmp, path)


def save_episodes(path, episodes: Sequence[Episode], task: TaskConfig | str = "paper", fmt: str = "nue") -> Path:
    """Write episodes atomically, in our format (``nue``) or the authors' (``authors``)."""
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
    if fmt != "nue":
        raise EpisodeError(path, f"unknown episode format {fmt!r} (use 'nue' or 'authors')")
    doc = {"format": FORMAT, "task": get_task(task).name, "episodes": [asdict(e) for e in episodes]}
    _atomic_write_text(path, json.dumps(doc, indent=1))
    return path


def load_episodes(
    path, scene=None, task: TaskConfig | str = "paper", scene_name: str | None = None, navgrid=None
) -> list[Episode]:
    """Read an episode file in either format (detected from its content).

    With ``scene`` (a :class:`~nue.scene.scene.Scene`), episodes recording a different content hash
    are refused, and the authors' episodes (which carry no labels) get their scene name, difficulty
    and path type from ``task``'s bins. With ``navgrid``, every episode is validated (start in free
    space, goal reachable) and a bad one is reported with this file's name.
    """
    path = Path(path)
    if not path.is_file():
        raise EpisodeError(path, "episode file not found")
    try:
        doc = json.loads(path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise EpisodeError(path, f"not valid JSON ({exc})") from None
    task = get_task(task)
    name = scene_name or (scene.name if scene is not None else "")
    if isinstance(doc, list):
        episodes = [_from_authors(item, i, name, task, path) for i, item in enumerate(doc)]
    elif isinstance(doc, dict) and doc.get("format") == FORMAT:
        try:
            episodes = [Episode.from_dict(e) for e in doc["episodes"]]
        except (KeyError, TypeError) as exc:
            raise EpisodeError(path, f"malformed episode entry ({exc})") from None
    else:
        raise EpisodeError(path, f"unknown episode file format (expected a list or format {FORMAT!r})")
    for e in episodes:
        check_finite(e, path)
    if scene is not None:
        for e in episodes:
            if e.scene_hash and e.scene_hash != scene.content_hash:
                raise EpisodeError(
                    path,
                    f"episode {e.episode_id} was made for scene content {e.scene_hash}, "
                    f"but {scene.path} has content {scene.content_hash} (the scene changed)",
                )
    if navgrid is not None:
        for e in episodes:
            validate_episode(e, navgrid, where=path)
    return episodes




def _from_authors(item, i: int, scene: str, task: TaskConfig, path) -> Episode:
    try:
        start, sq, goal, gq = (tuple(float(v) for v in item[k]) for k in ("startXYZ", "startQuat", "endXYZ", "endQuat"))
        dist = float(item.get("dist", math.hypot(goal[0] - start[0], goal[1] - start[1])))
        path_dist = float(item.get("pathDist", dist))
    except (KeyError, TypeError, ValueError) as exc:
        raise EpisodeError(path, f"entry {i}: malformed authors' episode ({exc})") from None
    if len(start) != 3 or len(goal) != 3 or len(sq) != 4 or len(gq) != 4:
        raise EpisodeError(path, f"entry {i}: positions need 3 values and quaternions 4")
    key = dist if task.bins.key == "euclidean" else path_dist
    ratio = path_dist / dist if dist > 0 else 1.0
    return Episode(
        episode_id=str(i),
        scene=scene,
        start_position=start,
        start_rotation=sq,
        goal_position=goal,
        goal_rotation=gq,
        euclidean_distance=dist,
        geodesic_distance=path_dist,
        difficulty=task.bins.classify(key) or "",
        path_type="straight" if ratio < task.bins.straight_ratio else "curved",
    )


def relabel(ep: Episode, task: TaskConfig) -> Episode:
    """The episode with difficulty and path type recomputed from ``task``'s bins."""
    key = ep.euclidean_distance if task.bins.key == "euclidean" else ep.geodesic_distance
    ratio = ep.geodesic_distance / ep.euclidean_distance if ep.euclidean_distance > 0 else 1.0
    return replace(
        ep, difficulty=task.bins.classify(key) or "", path_type="straight" if ratio < task.bins.straight_ratio else "curved"
    )
