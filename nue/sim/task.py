"""Task presets: camera, action set, success rule, step limit and difficulty bins, as data.

A run is task preset x memory (NeRF) preset x model config; this module holds the first.
``paper`` follows the paper's text, ``official`` the authors' release and ``habitat`` the
Habitat image-goal convention (STOP action, geodesic success).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field

from nue.errors import ConfigError


@dataclass(frozen=True)
class CameraConfig:
    """Pinhole RGB-D camera mounted on the robot, looking along the robot's +x axis."""

    width: int = 240
    """Image width W in pixels."""
    height: int = 180
    """Image height H in pixels."""
    fx: float = 120.0
    """Focal length in pixels along x (120 px at W = 240 is a 90 deg horizontal field of view)."""
    fy: float = 120.0
    """Focal length in pixels along y (square pixels: fy = fx)."""
    mount_height: float = 0.6
    """Height of the optical centre above the floor, metres."""
    near: float = 0.05
    """Near clipping distance, metres."""
    far: float = 30.0
    """Far clipping distance, metres; depth is 0 where no surface lies closer."""

    @property
    def cx(self) -> float:
        """Principal point x: the image centre, in pixels."""
        return self.width / 2.0

    @property
    def cy(self) -> float:
        """Principal point y: the image centre, in pixels."""
        return self.height / 2.0

    def scaled(self, width: int, height: int) -> "CameraConfig":
        """The same camera at another resolution (intrinsics scaled with it)."""
        return dataclasses.replace(
            self, width=width, height=height, fx=self.fx * width / self.width, fy=self.fy * height / self.height
        )


@dataclass(frozen=True)
class DifficultyBins:
    """Difficulty bins of start-goal distance: ``[lo, hi)`` per name, the last bin closed."""

    key: str = "euclidean"
    """Which distance decides the bin: ``euclidean`` or ``geodesic``."""
    edges: tuple[tuple[str, float, float], ...] = (("easy", 1.5, 3.0), ("medium", 3.0, 5.0), ("hard", 5.0, 10.0))
    """(name, lo, hi) per bin, in metres."""
    straight_ratio: float = 1.2
    """An episode is ``straight`` when geodesic / euclidean < this ratio, else ``curved``."""

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(name for name, _, _ in self.edges)

    def classify(self, distance: float) -> str | None:
        """The bin a distance falls in, or None outside every bin."""
        for i, (name, lo, hi) in enumerate(self.edges):
            last = i == len(self.edges) - 1
            if lo <= distance < hi or (last and distance == hi):
                return name
        return None

    def label(self, euclidean: float, geodesic: float) -> tuple[str, str]:
        """``(difficulty, path_type)`` of a start-goal pair: the bin of the ``key`` distance ('' outside every
        bin) and ``straight`` when geodesic / euclidean < ``straight_ratio`` (1 at zero distance), else ``curved``.

        Example (the paper's bins): euclidean 4, geodesic 5.2 -> ("medium", "curved")."""
        ratio = geodesic / euclidean if euclidean > 0 else 1.0
        difficulty = self.classify(euclidean if self.key == "euclidean" else geodesic) or ""
        return difficulty, "straight" if ratio < self.straight_ratio else "curved"

    def range_of(self, name: str) -> tuple[float, float]:
        for n, lo, hi in self.edges:
            if n == name:
                return lo, hi
        raise ConfigError(None, f"unknown difficulty {name!r}; known: {', '.join(self.names)}")


@dataclass(frozen=True)
class TaskConfig:
    """Everything that defines the navigation task a policy is trained and evaluated on."""

    name: str = "paper"
    """Preset name, recorded in episode files, records and checkpoints."""
    camera: CameraConfig = field(default_factory=CameraConfig)
    """The RGB-D camera."""
    actions: tuple[str, ...] = ("MOVE_FORWARD", "TURN_LEFT", "TURN_RIGHT")
    """Discrete action names; the index in this tuple is the action id."""
    forward_step: float = 0.25
    """Distance of MOVE_FORWARD, metres."""
    turn_angle_deg: float = 15.0
    """Angle of TURN_LEFT / TURN_RIGHT, degrees."""
    success_radius: float = 0.8
    """Success distance to the goal, metres."""
    success_metric: str = "euclidean"
    """Distance used for success: ``euclidean`` (xy) or ``geodesic``."""
    success_requires_stop: bool = False
    """True: success only when the agent calls STOP inside the radius; False: reaching it ends the episode."""
    max_steps: int = 800
    """Step limit; reaching it truncates the episode."""
    bins: DifficultyBins = field(default_factory=DifficultyBins)
    """Difficulty bins of start-goal distance."""
    collision: str = "slide"
    """What a blocked forward move does: ``slide`` along the obstacle or ``stop`` at it."""
    greedy: bool = False
    """Policies act greedily (argmax) instead of sampling from their action distribution."""

    @property
    def turn_angle(self) -> float:
        """Turn angle in radians."""
        return math.radians(self.turn_angle_deg)

    def action_id(self, name: str) -> int | None:
        """Index of an action name, or None if this preset has no such action."""
        return self.actions.index(name) if name in self.actions else None


TASK_PRESETS: dict[str, TaskConfig] = {
    "paper": TaskConfig(),
    "official": TaskConfig(
        name="official",
        camera=CameraConfig(fx=117.56, fy=117.56),
        success_radius=1.0,
        max_steps=500,
        greedy=True,
    ),
    "habitat": TaskConfig(
        name="habitat",
        actions=("STOP", "MOVE_FORWARD", "TURN_LEFT", "TURN_RIGHT"),
        turn_angle_deg=10.0,
        success_radius=1.0,
        success_metric="geodesic",
        success_requires_stop=True,
        max_steps=500,
        bins=DifficultyBins(key="geodesic"),
    ),
}


def get_task(name: str | TaskConfig) -> TaskConfig:
    """Look up a task preset by name (a TaskConfig passes through)."""
    if isinstance(name, TaskConfig):
        return name
    try:
        return TASK_PRESETS[name]
    except KeyError:
        raise ConfigError(None, f"unknown task preset {name!r}; known: {', '.join(TASK_PRESETS)}") from None
