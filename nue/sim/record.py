"""What one finished episode produced: :class:`EpisodeRecord` (the metrics' input, one JSON line of
``nue eval``) and its compact per-step :class:`Trajectory` (actions, poses, blocked moves).

The trajectory is stored in ``record.extra["trajectory"]`` so that diagnostics (collisions per step,
P(forward | previous move blocked), turn reversals), figures and replays can be recomputed from the
records alone. Encoding (``trajectory/1``): ``actions`` a string of action-id digits, one per step;
``collided`` the sorted step indices whose forward move was blocked; ``poses`` base64 of little-endian
int16 ``(T + 1, 3)`` = round(x / 0.01 m), round(y / 0.01 m), round(yaw / 0.001 rad) — 8 bytes of
text per step, exact to 5 mm and 0.0005 rad. Example: actions ``[0, 1]`` -> ``"01"``.
"""

from __future__ import annotations

import base64
from dataclasses import asdict, dataclass, field

import numpy as np

TRAJECTORY_KEY = "trajectory"
"""Key of ``EpisodeRecord.extra`` holding the encoded :class:`Trajectory`."""
TRAJECTORY_FORMAT = "trajectory/1"
RECORD_FORMAT = "nue-record/1"
"""``format`` entry of a record's dict; records written before it existed carry none and read as this one."""
POSE_SCALE = (0.01, 0.01, 0.001)
"""Metres, metres, radians per int16 unit of the encoded poses."""


@dataclass(frozen=True)
class Trajectory:
    """Per-step history of an episode: ``actions`` (T,) int, ``collided`` (T,) bool (forward move blocked
    at step t), ``poses`` (T + 1, 3) float (x, y, yaw) before step 0 and after every step."""

    actions: np.ndarray
    collided: np.ndarray
    poses: np.ndarray

    def __post_init__(self) -> None:
        t = len(self.actions)
        if len(self.collided) != t or len(self.poses) != t + 1:
            raise ValueError(f"trajectory: {t} actions, {len(self.collided)} collision flags and "
                             f"{len(self.poses)} poses (need T, T and T + 1)")

    def encode(self) -> dict:
        """The JSON form stored in a record (see the module docstring)."""
        acts = np.asarray(self.actions, dtype=np.int64)
        if acts.size and (acts.min() < 0 or acts.max() > 9):
            raise ValueError("trajectory: action ids must be 0..9 to encode")
        q = np.round(np.asarray(self.poses, dtype=np.float64) / np.asarray(POSE_SCALE))
        if np.abs(q).max(initial=0) > 32767:
            raise ValueError("trajectory: a pose is beyond +-327 m")
        return {"format": TRAJECTORY_FORMAT, "actions": "".join(str(int(a)) for a in acts),
                "collided": [int(i) for i in np.flatnonzero(self.collided)],
                "poses": base64.b64encode(q.astype("<i2").tobytes()).decode("ascii")}

    @classmethod
    def decode(cls, d: dict) -> "Trajectory":
        """Inverse of :meth:`encode` (poses to the stored precision)."""
        if d.get("format") != TRAJECTORY_FORMAT:
            raise ValueError(f"trajectory: unknown format {d.get('format')!r}")
        actions = np.frombuffer(d["actions"].encode("ascii"), dtype=np.uint8).astype(np.int64) - ord("0")
        if actions.size and (actions.min() < 0 or actions.max() > 9):
            raise ValueError("trajectory: actions must be digits 0..9")
        collided = np.zeros(len(actions), dtype=bool)
        collided[np.asarray(d["collided"], dtype=np.int64)] = True
        q = np.frombuffer(base64.b64decode(d["poses"]), dtype="<i2").reshape(-1, 3)
        return cls(actions, collided, q.astype(np.float64) * np.asarray(POSE_SCALE))


class RecordFormatError(ValueError):
    """A record's dict carries a ``format`` other than :data:`RECORD_FORMAT`."""


@dataclass(frozen=True)
class EpisodeRecord:
    """What one finished episode produced; everything the metrics need."""

    episode_id: str
    """Episode identifier (unique within its scene)."""
    scene: str
    """Scene name."""
    difficulty: str
    """Difficulty bin (``easy`` / ``medium`` / ``hard``)."""
    success: bool
    """Whether the episode ended in success under its task preset."""
    geodesic_start: float
    """Geodesic start->goal distance l, metres."""
    path_length: float
    """Distance travelled p, metres."""
    final_geodesic: float
    """Geodesic distance from the final position to the goal, metres."""
    final_euclidean: float
    """Euclidean xy distance from the final position to the goal, metres."""
    success_radius: float
    """The task preset's success radius r, metres."""
    collisions: int = 0
    """Number of steps in which a forward move was blocked."""
    steps: int = 0
    """Number of actions taken."""
    path_type: str = ""
    """``straight`` or ``curved`` (geodesic / euclidean < 1.2)."""
    method: str = ""
    """Name of the agent (e.g. ``expert``, ``nue``)."""
    wall_time: float = 0.0
    """Seconds the episode took."""
    extra: dict = field(default_factory=dict)
    """Free-form additions (seed, checkpoint, ...)."""

    def to_dict(self) -> dict:
        """The record as one JSON object: ``{"format": RECORD_FORMAT, <field>: <value>, ...}``."""
        return {"format": RECORD_FORMAT, **asdict(self)}

    @classmethod
    def from_dict(cls, d: dict) -> "EpisodeRecord":
        """The record of :meth:`to_dict`'s dict (or of one without ``format``, written before it existed);
        :class:`RecordFormatError` for another format."""
        fmt = d.get("format", RECORD_FORMAT)
        if fmt != RECORD_FORMAT:
            raise RecordFormatError(f"record format {fmt!r} is not {RECORD_FORMAT!r}")
        return cls(**{k: v for k, v in d.items() if k != "format"})

    def trajectory(self) -> Trajectory | None:
        """The per-step trajectory, if the record carries one (records made before it existed do not)."""
        d = self.extra.get(TRAJECTORY_KEY)
        return None if d is None else Trajectory.decode(d)
