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

from nue.sim import episode_fields as F
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


def scene_of(item) -> str | None:
    """Scene name of a habitat episode: the stem of its ``scene_id`` (``.../Adrian.glb`` -> ``Adrian``),
    or None if the entry has no usable ``scene_id`` (:func:`fields_from_habitat` names the problem)."""
    scene_id = item.get("scene_id") if isinstance(item, dict) else None
    name = PurePosixPath(scene_id).name.split(".")[0] if isinstance(scene_id, str) else ""
    return name or None


REQUIRED = ("episode_id", "scene_id", "start_position", "start_rotation", "goals")
"""Fields every habitat episode entry must have (``info`` and a goal's ``rotation`` are optional)."""


def _rotation(value, name: str) -> tuple[float, ...]:
    """A habitat rotation: 4 finite numbers (x, y, z, w) forming a unit quaternion about +y_h."""
    q = F.vector(value, name, 4)
    problem = F.quaternion_problem(q, name, axis="y")
    if problem:
        raise F.FieldProblem(problem)
    return q


def fields_from_habitat(item, scene: str) -> dict:
    """Our :class:`~nue.sim.episodes.Episode` fields (all but the labels) of one habitat episode dict.

    Every field is type-checked with :mod:`nue.sim.episode_fields`: :class:`~nue.sim.episode_fields.FieldProblem`
    naming the field for an entry that is not an object, lacks one of :data:`REQUIRED`, has a position
    that is not 3 numbers, a rotation that is not a unit quaternion about +y_h, no goals or a first goal
    without a position, or an ``info`` whose distances are not numbers. Only the first goal is used."""
    if not isinstance(item, dict):
        raise F.FieldProblem(f"expected an object with the episode's fields, got a {type(item).__name__}")
    missing = [k for k in REQUIRED if k not in item]
    if missing:
        raise F.FieldProblem(f"missing field(s): {', '.join(missing)}")
    episode_id = F.text(item["episode_id"], "episode_id")
    if scene_of(item) is None:
        raise F.FieldProblem(f"scene_id: expected the path of the scene's mesh, got {F._describe(item['scene_id'])}")
    start = position_from_habitat(F.vector(item["start_position"], "start_position", 3))
    start_yaw = yaw_from_habitat_rotation(_rotation(item["start_rotation"], "start_rotation"))
    goals = item["goals"]
    if not isinstance(goals, list) or not goals:
        raise F.FieldProblem(f"goals: expected a non-empty list of goals, got {F._describe(goals)}")
    if not isinstance(goals[0], dict) or "position" not in goals[0]:
        raise F.FieldProblem(f"goals[0]: expected an object with a position, got {F._describe(goals[0])}")
    goal = position_from_habitat(F.vector(goals[0]["position"], "goals[0].position", 3))
    info = item.get("info") or {}
    if not isinstance(info, dict):
        raise F.FieldProblem(f"info: expected an object, got {F._describe(info)}")
    if info.get("goal_rotation") is not None:
        goal_yaw = yaw_from_habitat_rotation(_rotation(info["goal_rotation"], "info.goal_rotation"))
    elif goals[0].get("rotation") is not None:
        goal_yaw = yaw_from_habitat_rotation(_rotation(goals[0]["rotation"], "goals[0].rotation"))
    else:
        goal_yaw = (zlib.crc32(f"{scene}/{episode_id}".encode()) / 2**32) * 2 * math.pi
    euclidean = (F.number(info["euclidean_distance"], "info.euclidean_distance")
                 if info.get("euclidean_distance") is not None else math.hypot(goal[0] - start[0], goal[1] - start[1]))
    geodesic = (F.number(info["geodesic_distance"], "info.geodesic_distance")
                if info.get("geodesic_distance") is not None else euclidean)
    return dict(
        episode_id=episode_id,
        scene=scene,
        start_position=start,
        start_rotation=tuple(float(v) for v in quat_from_yaw(start_yaw)),
        goal_position=goal,
        goal_rotation=tuple(float(v) for v in quat_from_yaw(goal_yaw)),
        euclidean_distance=euclidean,
        geodesic_distance=geodesic,
        scene_hash=F.text(info.get("scene_hash") or "", "info.scene_hash"),
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
