"""habitat-lab's navigation episode format (PointNav-v1 datasets, also used by its ImageNav task), both ways.

A habitat file (``.json.gz`` or plain JSON) is ``{"episodes": [...]}`` with per episode
``episode_id``, ``scene_id`` (a path to the ``.glb``), ``start_position`` (x, y, z),
``start_rotation`` (quaternion x, y, z, w), ``goals`` (a list of ``{"position", "radius"}``),
``info`` (``geodesic_distance``, ...), ``start_room`` and ``shortest_paths``.

Frames. habitat is y-up with the agent looking along -z; habitat's Gibson and MP3D scenes are the
z-up meshes turned by -90 degrees about x, so a point is

    habitat (x_h, y_h, z_h) = (x, z, -y)        ours (x, y, z) = (x_h, -z_h, y_h)

(y_h is the floor height under the agent, our z). A heading theta about +y_h (habitat quaternion
``[0, sin(theta/2), 0, cos(theta/2)]``) looks along (-sin theta, 0, -cos theta) in habitat's frame,
which is (-sin theta, cos theta) in our x-y plane: our yaw is ``theta + pi/2``. Example: habitat
``start_position [1.0, 0.0, -2.0]`` with rotation ``[0, 0, 0, 1]`` is our (1.0, 2.0, 0.0) facing +y
(yaw pi/2). Any habitat quaternion is read through the direction it turns -z into.

Goal orientation. habitat's ImageNav goals have no orientation (its goal sensor picks one from
Python's salted ``hash`` of the episode id, which differs between processes). We read
``info["goal_rotation"]`` (written by us) or a goal's ``rotation`` when present, else draw the yaw
from the CRC-32 of ``<scene>/<episode_id>`` (reproducible). Positions, ids and distances round-trip
exactly; rotations to float precision.
"""

from __future__ import annotations

import math
import zlib
from pathlib import PurePosixPath

import numpy as np

from nue.sim.camera import quat_from_yaw, wrap_angle, yaw_from_quat

SCENE_ID = "data/scene_datasets/gibson/{scene}.glb"
"""``scene_id`` written for an episode of scene ``scene`` (habitat's Gibson layout)."""


def is_habitat(doc) -> bool:
    """Whether a parsed JSON document looks like a habitat dataset (a dict with an ``episodes`` list)."""
    return isinstance(doc, dict) and "format" not in doc and isinstance(doc.get("episodes"), list)


def position_from_habitat(p) -> tuple[float, float, float]:
    """habitat (x_h, y_h, z_h), y up -> ours (x, y, z) = (x_h, -z_h, y_h), z up."""
    x, y, z = (float(v) for v in p)  # ValueError unless 3 values
    return (x, -z, y)


def position_to_habitat(p) -> list[float]:
    """Ours (x, y, z) -> habitat (x, z, -y)."""
    x, y, z = (float(v) for v in p)
    return [x, z, -y]


def yaw_from_habitat_rotation(q) -> float:
    """Our yaw (radians, counter-clockwise from +x about +z) of a habitat quaternion (x, y, z, w)."""
    if len(q) != 4:
        raise ValueError("a quaternion needs 4 values")
    u = np.array([float(v) for v in q[:3]])
    w = float(q[3])
    v = np.array([0.0, 0.0, -1.0])
    t = 2.0 * np.cross(u, v)
    forward = v + w * t + np.cross(u, t)  # q v q^-1 for a unit quaternion
    return wrap_angle(math.atan2(-forward[2], forward[0]))


def habitat_rotation_from_yaw(yaw: float) -> list[float]:
    """habitat quaternion (x, y, z, w) about +y_h for our yaw: theta = yaw - pi/2."""
    theta = float(yaw) - math.pi / 2
    return [0.0, math.sin(theta / 2), 0.0, math.cos(theta / 2)]


def scene_of(item) -> str:
    """Scene name of a habitat episode: the stem of its ``scene_id`` (``.../Adrian.glb`` -> ``Adrian``)."""
    return PurePosixPath(str(item.get("scene_id", ""))).name.split(".")[0]


def fields_from_habitat(item, scene: str) -> dict:
    """Our :class:`~nue.sim.episodes.Episode` fields (all but the labels) of one habitat episode dict.

    Raises KeyError / TypeError / ValueError for a malformed entry."""
    episode_id = str(item["episode_id"])
    start = position_from_habitat(item["start_position"])
    goals = item["goals"]
    if not goals:
        raise ValueError("no goals")
    goal = position_from_habitat(goals[0]["position"])
    info = item.get("info") or {}
    if info.get("goal_rotation") is not None:
        goal_yaw = yaw_from_habitat_rotation(info["goal_rotation"])
    elif goals[0].get("rotation") is not None:
        goal_yaw = yaw_from_habitat_rotation(goals[0]["rotation"])
    else:
        goal_yaw = (zlib.crc32(f"{scene}/{episode_id}".encode()) / 2**32) * 2 * math.pi
    euclidean = float(info.get("euclidean_distance", math.hypot(goal[0] - start[0], goal[1] - start[1])))
    return dict(
        episode_id=episode_id,
        scene=scene,
        start_position=start,
        start_rotation=tuple(float(v) for v in quat_from_yaw(yaw_from_habitat_rotation(item["start_rotation"]))),
        goal_position=goal,
        goal_rotation=tuple(float(v) for v in quat_from_yaw(goal_yaw)),
        euclidean_distance=euclidean,
        geodesic_distance=float(info.get("geodesic_distance", euclidean)),
        scene_hash=str(info.get("scene_hash", "")),
    )


def habitat_from_fields(ep, success_radius: float | None = None) -> dict:
    """One habitat episode dict of our episode ``ep`` (goal orientation and labels kept in ``info``)."""
    info = {
        "geodesic_distance": ep.geodesic_distance,
        "euclidean_distance": ep.euclidean_distance,
        "goal_rotation": habitat_rotation_from_yaw(yaw_from_quat(ep.goal_rotation)),
        "difficulty": ep.difficulty,
        "path_type": ep.path_type,
    }
    if ep.scene_hash:
        info["scene_hash"] = ep.scene_hash
    return {
        "episode_id": ep.episode_id,
        "scene_id": SCENE_ID.format(scene=ep.scene),
        "start_position": position_to_habitat(ep.start_position),
        "start_rotation": habitat_rotation_from_yaw(yaw_from_quat(ep.start_rotation)),
        "goals": [{"position": position_to_habitat(ep.goal_position), "radius": success_radius}],
        "info": info,
        "start_room": None,
        "shortest_paths": None,
    }
