"""House generator configs as data: ``HouseConfig`` (sizes, layout, look of one family of houses), its
``Appearance``, and the named scene styles ``STYLES`` (a style is a full ``HouseConfig`` preset).

``gibson`` is the style every model trains on (21 training houses) and is validated on (14 houses):
per-room wall and floor patterns, one hue per room, the furniture templates at their own sizes, a
hallway plan or recursive splits with at most two loop doors. ``plain`` is a held-out style for
validation only: flat diffuse colours (no patterns), two wall colours shared by all rooms, wider,
shallower and lower furniture, higher walls, mostly recursive-split plans with smaller rooms and more
loop doors, fewer pictures. Same Gibson layout conventions (mesh, ``floors.txt``, 1 cm traversability
map, one floor), same navigation constraints (doorways, passages, free extent).

Styles drawn per house from a distribution (the ``diverse`` training houses, the held-out ``pale`` family) are
:mod:`nue.scene.house_styles`'s; each house's drawn ``HouseConfig`` is recorded like a fixed style's.

``house.json`` records :func:`config_dict`: fields added after generator version 3 appear only when they
differ from their defaults, so houses generated before them stay intact copies of their seed.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

from nue.errors import ConfigError
from nue.scene.house_plans import LAYOUTS
from nue.scene.navgrid import ROBOT_RADIUS

SURFACES = ("textured", "plain")


@dataclass(frozen=True)
class Appearance:
    """How a style's surfaces look (colours as HSV ranges; hue is drawn per house)."""

    surfaces: str = "textured"
    """``textured``: a wall and a floor pattern per room (``house_textures.WALL_PATTERNS`` / ``FLOOR_PATTERNS``),
    wood grain, woven fabric, bookshelf and cabinet fronts; ``plain``: every surface one flat diffuse colour
    with faint brightness noise (``plain_noise``)."""
    plain_noise: float = 0.02
    """``plain`` only: standard deviation of the smooth brightness noise on every surface (relative)."""
    wall_colours: int = 0
    """Distinct wall colours in a house (hue, saturation and value drawn once per house), which the rooms take
    in turn; 0 = one colour per room, their hues spread evenly round the colour wheel."""
    wall_saturation: tuple[float, float] = (0.12, 0.45)
    """Range of the wall colours' saturation."""
    wall_value: tuple[float, float] = (0.68, 0.92)
    """Range of the wall colours' value (brightness)."""
    floor_saturation: tuple[float, float] = (0.2, 0.55)
    """Range of the saturation of floors that are not wood (wood floors keep their brown range)."""
    floor_value: tuple[float, float] = (0.4, 0.85)
    """Range of the value of floors that are not wood."""

    def validate(self) -> None:
        """Raise ConfigError on inconsistent values."""
        if self.surfaces not in SURFACES:
            raise ConfigError("Appearance", f"surfaces must be one of {', '.join(SURFACES)}, got {self.surfaces!r}")
        for name in ("wall_saturation", "wall_value", "floor_saturation", "floor_value"):
            lo, hi = getattr(self, name)
            if not 0 <= lo <= hi <= 1:
                raise ConfigError("Appearance", f"{name} must be an increasing pair within [0, 1]")
        if self.wall_colours < 0 or not 0 <= self.plain_noise <= 0.5:
            raise ConfigError("Appearance", "wall_colours must be >= 0 and plain_noise within [0, 0.5]")


@dataclass(frozen=True)
class HouseConfig:
    """Parameters of the house generator (lengths in metres)."""

    long_side: tuple[float, float] = (9.6, 14.0)
    """Range of the footprint's long side; >= 9.5 m gives >= 9 m of free extent."""
    short_side: tuple[float, float] = (4.6, 10.5)
    """Range of the footprint's short side (also capped by the long side and the area range)."""
    footprint_area: tuple[float, float] = (50.0, 150.0)
    """Range of the footprint area, m^2 (the floor area is ~7 % smaller: walls)."""
    floor_area: tuple[float, float] = (40.0, 150.0)
    """Accepted range of the total free floor area (room interiors), m^2."""
    rooms: tuple[int, int] = (3, 8)
    """Minimum and maximum number of rooms, the hallway included."""
    corridor_prob: float = 0.5
    """Probability of a hallway layout; otherwise recursive splits (BSP)."""
    min_room_side: float = 2.6
    """Minimum room width along either axis, on wall centre lines."""
    corridor_width: tuple[float, float] = (1.3, 1.7)
    """Range of the hallway width on wall centre lines (free width = this - wall thickness)."""
    wall_height: float = 2.6
    """Height of walls and ceiling above the floor."""
    wall_thickness: float = 0.1
    """Wall thickness (rounded to an even number of cm)."""
    door_width: tuple[float, float] = (0.9, 1.2)
    """Range of the free doorway width."""
    door_height: float = 2.1
    """Height of doorway openings."""
    door_clearance: float = 1.0
    """Depth of the furniture-free zone in front of each door, on both sides."""
    extra_door_prob: float = 0.35
    """Probability of an extra door between two neighbouring rooms (loops; at most ``max_extra_doors``)."""
    furniture_density: float = 1.0
    """Multiplier on each piece's placement probability (0 = empty rooms; probabilities cap at 1)."""
    pictures_per_room: tuple[int, int] = (1, 2)
    """Range of pictures per room (one more in rooms over 20 m^2; hallways: one per 3.5 m)."""
    picture_heights: tuple[float, float] = (1.1, 1.9)
    """Lowest bottom and highest top edge of a picture above the floor."""
    robot_radius: float = ROBOT_RADIUS
    """Robot radius: free space eroded by it must stay one piece that reaches every room."""
    min_passage: float = 0.5
    """Furniture leaves passages at least this wide: each room's floor eroded by half of it stays one piece."""
    min_free_extent: float = 9.0
    """Minimum extent of the robot-free space along x or y."""
    texture_size: int = 128
    """Texture resolution in pixels per metre (floor) / per face (pictures)."""
    max_attempts: int = 40
    """Random draws tried per seed before giving up (each attempt is deterministic)."""
    style: str = "gibson"
    """Name of the scene style (a key of ``STYLES``, or of ``house_styles.STYLE_DISTRIBUTIONS`` for a house
    whose parameters were drawn from a style distribution) these parameters belong to."""
    room_area: tuple[float, float] = (12.0, 20.0)
    """BSP layouts: range of the mean room area, m^2, drawn per house (footprint area / it = the room count)."""
    max_extra_doors: int = 2
    """At most this many loop doors per house beyond those that connect the rooms (the room graph's cycles)."""
    furniture_scale: tuple[float, float, float] = (1.0, 1.0, 1.0)
    """Multipliers on every furniture template's width (along its wall), depth and height ranges."""
    appearance: Appearance = field(default_factory=Appearance)
    """How the surfaces look."""
    layout: str = ""
    """Floor-plan layout of every house (one of ``house_plans.LAYOUTS``); '' = the original mix: a hallway
    layout with probability ``corridor_prob``, else recursive splits."""

    def validate(self) -> None:
        """Raise ConfigError on inconsistent values."""
        pairs = ("long_side", "short_side", "footprint_area", "floor_area", "rooms", "corridor_width",
                 "door_width", "pictures_per_room", "picture_heights", "room_area")
        for name in pairs:
            lo, hi = getattr(self, name)
            if not 0 <= lo <= hi:
                raise ConfigError("HouseConfig", f"{name} must be an increasing pair of non-negative values")
        if self.rooms[0] < 2 or self.rooms[1] > 12:
            raise ConfigError("HouseConfig", "rooms must lie within 2..12")
        if self.door_width[0] < 0.6 or self.door_height >= self.wall_height:
            raise ConfigError("HouseConfig", "doors must be >= 0.6 m wide and lower than the walls")
        if self.corridor_width[0] - self.wall_thickness < self.door_width[0] + 0.3:
            raise ConfigError("HouseConfig", "corridor_width minus the wall must leave door_width + 0.3 m "
                              "(for a door at the hallway's end)")
        if self.picture_heights[1] - self.picture_heights[0] < 0.4 or self.picture_heights[1] > self.wall_height:
            raise ConfigError("HouseConfig", "picture_heights must span >= 0.4 m below the ceiling")
        if self.texture_size < 16 or self.texture_size & (self.texture_size - 1):
            raise ConfigError("HouseConfig", "texture_size must be a power of two >= 16")
        if self.min_passage < 2 * self.robot_radius:
            raise ConfigError("HouseConfig", "min_passage must be at least the robot's diameter")
        if self.max_attempts < 1 or self.furniture_density < 0:
            raise ConfigError("HouseConfig", "max_attempts must be >= 1 and furniture_density >= 0")
        if self.room_area[0] <= 0 or self.max_extra_doors < 0 or min(self.furniture_scale) <= 0:
            raise ConfigError("HouseConfig", "room_area and furniture_scale must be positive, max_extra_doors >= 0")
        if self.layout and self.layout not in LAYOUTS:
            raise ConfigError("HouseConfig", f"layout must be '' or one of {', '.join(LAYOUTS)}, got {self.layout!r}")
        self.appearance.validate()

    def replace(self, **changes) -> "HouseConfig":
        """A copy with some fields changed."""
        return dataclasses.replace(self, **changes)


ADDED_FIELDS = ("style", "room_area", "max_extra_doors", "furniture_scale", "appearance", "layout")
"""HouseConfig fields added after generator version 3 (recorded in ``house.json`` only when not default)."""


def config_dict(config: HouseConfig) -> dict:
    """``config`` as plain JSON data for ``house.json``: every field, except the :data:`ADDED_FIELDS` that
    keep their default (so the record of a ``gibson`` house is what it was before styles existed)."""
    default = dataclasses.asdict(HouseConfig())
    data = dataclasses.asdict(config)
    return {k: v for k, v in data.items() if k not in ADDED_FIELDS or v != default[k]}


STYLES: dict[str, HouseConfig] = {
    "gibson": HouseConfig(),
    "plain": HouseConfig(
        style="plain",
        rooms=(4, 10),
        corridor_prob=0.15,
        room_area=(9.0, 14.0),
        extra_door_prob=0.7,
        max_extra_doors=4,
        wall_height=2.8,
        door_height=2.2,
        pictures_per_room=(0, 1),
        furniture_scale=(1.25, 0.85, 0.8),
        appearance=Appearance(surfaces="plain", plain_noise=0.02, wall_colours=2, wall_saturation=(0.04, 0.2),
                              wall_value=(0.78, 0.95), floor_saturation=(0.05, 0.3), floor_value=(0.3, 0.7)),
    ),
}
"""Named scene styles. ``gibson``: the training style (the default); ``plain``: the held-out style."""


def get_style(name: str) -> HouseConfig:
    """The ``HouseConfig`` of a scene style; unknown name -> ConfigError."""
    try:
        return STYLES[name]
    except KeyError:
        raise ConfigError(name, f"unknown scene style; known: {', '.join(STYLES)}") from None
