"""Style distributions: a ``HouseConfig`` drawn per house from documented ranges (issue 43).

A :class:`StyleDistribution` is a preset (data) of ranges and probabilities; :func:`sample_style` draws
one house's ``HouseConfig`` from it with a random stream of its own (``[seed, STYLE_STREAM]``), so the
same house seed always gives the same style and the house generator's own stream is untouched.

``diverse`` is the training distribution (split ``train_diverse``). It varies the appearance
(patterned vs flat-colour surfaces, the palette's saturation and value, how many rooms share a wall
colour, near-white patterned walls, floors close to the walls' colour, picture density) and the
geometry (wall and door height, furniture width / depth / height, layout: corridor, recursive splits,
L- and T-shaped hallways, open plan; room size, hallway width, loop doors, furniture density).

Held-out families are distributions too, built to lie outside ``diverse``'s support (the ranges
:func:`outside_support` checks) on several parameters at once:

- ``pale`` (split ``val_pale``): flat colours only, one near-white wall colour for every room
  (saturation <= 0.06, value >= 0.86), floors of low saturation, walls 2.85-3.05 m, doors 2.2-2.3 m,
  wide low furniture (width x1.2-1.3, height x0.7-0.8), open-plan or L-hallway layouts, 0-1 pictures.
- ``plain`` (split ``val_plain``, a fixed ``HouseConfig`` of :mod:`nue.scene.house_config`): flat colours
  with wall saturation <= 0.2, walls 2.8 m, doors 2.2 m, furniture x(1.25, 0.85, 0.8).

What ``diverse`` never draws (so no training house resembles either family): flat-colour walls with
saturation below ``flat_wall_saturation[0]`` = 0.3 (near-white walls occur only patterned), walls
higher than 2.75 m, doors higher than 2.15 m, furniture wider than x1.15 or lower than x0.85.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from nue.errors import ConfigError
from nue.scene.house_config import Appearance, HouseConfig
from nue.scene.house_plans import LAYOUTS

STYLE_STREAM = 43
"""Second entry of the style's random stream ``default_rng([seed, STYLE_STREAM])`` (the generator uses
``[seed, attempt]`` with attempt < ``max_attempts``, far below it)."""

Range = tuple[float, float]


@dataclass(frozen=True)
class StyleDistribution:
    """Ranges a house's style is drawn from. A range ``(lo, hi)`` holds every value a house may get; for
    colour bands, the house's own band (``*_spread`` wide) lies inside it."""

    name: str
    """Style name written to each house's ``HouseConfig.style``."""
    textured_prob: float = 0.65
    """Probability of patterned surfaces (``Appearance.surfaces = 'textured'``); else flat colours."""
    textured_wall_saturation: Range = (0.1, 0.55)
    """Patterned walls that are not near-white: range holding the house's wall-saturation band."""
    flat_wall_saturation: Range = (0.3, 0.65)
    """Flat-colour walls: range holding the house's wall-saturation band."""
    wall_value: Range = (0.5, 0.92)
    """Walls that are not near-white: range holding the house's wall-value (brightness) band."""
    near_white_prob: float = 0.2
    """Patterned houses only: probability of near-white walls (saturation and value from the two ranges below)."""
    near_white_saturation: Range = (0.0, 0.08)
    """Near-white walls: range holding the saturation band."""
    near_white_value: Range = (0.86, 0.97)
    """Near-white walls: range holding the value band."""
    saturation_spread: float = 0.06
    """Width of a house's wall-saturation band (``Appearance.wall_saturation``), clipped to its range."""
    value_spread: float = 0.06
    """Width of a house's wall-value band (``Appearance.wall_value``), clipped to its range."""
    wall_colours: tuple[tuple[int, float], ...] = ((0, 0.45), (1, 0.15), (2, 0.2), (3, 0.2))
    """(``Appearance.wall_colours``, weight) pairs: 0 = a colour per room, k = k colours the rooms share."""
    low_contrast_prob: float = 0.2
    """Probability that floors take the walls' saturation band and a value band just below the walls'."""
    floor_saturation: Range = (0.1, 0.6)
    """Other houses: range holding the floors' saturation band (0.15 wide)."""
    floor_value: Range = (0.3, 0.85)
    """Other houses: range holding the floors' value band (0.2 wide)."""
    plain_noise: Range = (0.01, 0.04)
    """Flat-colour houses: range of ``Appearance.plain_noise``."""
    pictures_per_room: tuple[tuple[int, int], ...] = ((0, 1), (1, 2), (1, 3), (2, 3))
    """``HouseConfig.pictures_per_room`` choices (equally likely)."""
    wall_height: Range = (2.4, 2.75)
    """Range of the wall height, m (drawn to the cm)."""
    door_height: Range = (2.0, 2.15)
    """Range of the door height, m (drawn to the cm; at most the wall height - 0.25 m)."""
    furniture_scale: tuple[Range, Range, Range] = ((0.85, 1.15), (0.85, 1.15), (0.85, 1.15))
    """Ranges of the multipliers on furniture width, depth and height (``HouseConfig.furniture_scale``)."""
    furniture_density: Range = (0.7, 1.2)
    """Range of ``HouseConfig.furniture_density``."""
    layouts: tuple[tuple[str, float], ...] = (("corridor", 0.25), ("bsp", 0.25), ("l_hall", 0.2), ("t_hall", 0.15),
                                              ("open_plan", 0.15))
    """(layout of ``house_plans.LAYOUTS``, weight) pairs."""
    rooms: tuple[int, int] = (3, 10)
    """``HouseConfig.rooms`` of every house (a draw outside it is retried by the generator)."""
    room_area: Range = (9.0, 22.0)
    """Range holding the house's mean-room-area band (4 m^2 wide; recursive-split layouts)."""
    corridor_width: Range = (1.3, 1.8)
    """Range holding the house's hallway-width band (0.2 m wide)."""
    extra_door_prob: Range = (0.1, 0.8)
    """Range of ``HouseConfig.extra_door_prob`` (loop doors)."""
    max_extra_doors: tuple[int, int] = (0, 4)
    """Range of ``HouseConfig.max_extra_doors``."""

    def validate(self) -> None:
        """Raise ConfigError on inconsistent values."""
        ranges = [self.textured_wall_saturation, self.flat_wall_saturation, self.wall_value,
                  self.near_white_saturation, self.near_white_value, self.floor_saturation, self.floor_value]
        if any(not 0 <= lo <= hi <= 1 for lo, hi in ranges):
            raise ConfigError(self.name, "colour ranges must be increasing pairs within [0, 1]")
        if not (0 <= self.textured_prob <= 1 and 0 <= self.near_white_prob <= 1 and 0 <= self.low_contrast_prob <= 1):
            raise ConfigError(self.name, "probabilities must lie within [0, 1]")
        if any(name not in LAYOUTS for name, _ in self.layouts) or sum(w for _, w in self.layouts) <= 0:
            raise ConfigError(self.name, f"layouts must name layouts of {', '.join(LAYOUTS)} with a positive weight")
        if self.door_height[0] + 0.25 > self.wall_height[0] or self.wall_height[0] < 2.0:
            raise ConfigError(self.name, "wall_height must start >= 2 m and >= door_height + 0.25 m")


def _band(rng, rng_range: Range, width: float, digits: int = 3) -> Range:
    """A band ``width`` wide (narrower if the range is) at a random place inside ``rng_range``."""
    lo, hi = rng_range
    width = min(width, hi - lo)
    a = round(float(rng.uniform(lo, hi - width)), digits)
    return (a, round(min(a + width, hi), digits))


def _pick(rng, weighted):
    weights = np.array([w for _, w in weighted], dtype=float)
    return weighted[int(rng.choice(len(weighted), p=weights / weights.sum()))][0]


def sample_style(dist: StyleDistribution, seed: int) -> HouseConfig:
    """The ``HouseConfig`` of house ``seed`` drawn from ``dist`` (same seed -> same config)."""
    rng = np.random.default_rng([int(seed), STYLE_STREAM])
    textured = bool(rng.random() < dist.textured_prob)
    near_white = textured and bool(rng.random() < dist.near_white_prob)
    if near_white:
        sat_range, val_range = dist.near_white_saturation, dist.near_white_value
    else:
        sat_range = dist.textured_wall_saturation if textured else dist.flat_wall_saturation
        val_range = dist.wall_value
    wall_sat, wall_val = _band(rng, sat_range, dist.saturation_spread), _band(rng, val_range, dist.value_spread)
    if rng.random() < dist.low_contrast_prob:
        floor_sat, floor_val = wall_sat, (round(max(0.0, wall_val[0] - 0.15), 3), wall_val[0])
    else:
        floor_sat, floor_val = _band(rng, dist.floor_saturation, 0.15), _band(rng, dist.floor_value, 0.2)
    look = Appearance(surfaces="textured" if textured else "plain",
                      plain_noise=0.02 if textured else round(float(rng.uniform(*dist.plain_noise)), 3),
                      wall_colours=int(_pick(rng, dist.wall_colours)), wall_saturation=wall_sat, wall_value=wall_val,
                      floor_saturation=floor_sat, floor_value=floor_val)
    wall_height = round(float(rng.uniform(*dist.wall_height)), 2)
    door_height = round(min(float(rng.uniform(*dist.door_height)), wall_height - 0.25), 2)
    pictures = dist.pictures_per_room[int(rng.integers(len(dist.pictures_per_room)))]
    scale = tuple(round(float(rng.uniform(lo, hi)), 3) for lo, hi in dist.furniture_scale)
    return HouseConfig(
        style=dist.name, layout=str(_pick(rng, dist.layouts)), rooms=dist.rooms, appearance=look,
        wall_height=wall_height, door_height=door_height, pictures_per_room=(int(pictures[0]), int(pictures[1])),
        furniture_scale=(scale[0], scale[1], scale[2]),
        furniture_density=round(float(rng.uniform(*dist.furniture_density)), 3),
        room_area=_band(rng, dist.room_area, 4.0, 2), corridor_width=_band(rng, dist.corridor_width, 0.2, 2),
        extra_door_prob=round(float(rng.uniform(*dist.extra_door_prob)), 3),
        max_extra_doors=int(rng.integers(dist.max_extra_doors[0], dist.max_extra_doors[1] + 1)),
    )


def _inside(band, rng_range, eps: float = 1e-9) -> bool:
    lo, hi = (band, band) if isinstance(band, (int, float)) else band
    return rng_range[0] - eps <= lo <= hi <= rng_range[1] + eps


def outside_support(dist: StyleDistribution, cfg: HouseConfig) -> list[str]:
    """The parameters of ``cfg`` that ``dist`` never draws (empty = ``cfg`` could be one of its houses);
    the wall colour bands are named ``<surfaces>_wall_colour``.

    Checked: surfaces with the wall-colour bands they allow, wall colours, wall and door height, furniture
    scale and density, layout ('' = the corridor / BSP mix, inside when both have weight), pictures, room
    area, hallway width, loop doors. Floors and ``plain_noise`` are not checked (not an exclusion)."""
    look, out = cfg.appearance, []
    if look.surfaces == "textured":
        ok = dist.textured_prob > 0 and (
            (_inside(look.wall_saturation, dist.textured_wall_saturation) and _inside(look.wall_value, dist.wall_value))
            or (dist.near_white_prob > 0 and _inside(look.wall_saturation, dist.near_white_saturation)
                and _inside(look.wall_value, dist.near_white_value)))
    else:
        ok = (dist.textured_prob < 1 and _inside(look.wall_saturation, dist.flat_wall_saturation)
              and _inside(look.wall_value, dist.wall_value))
    if not ok:
        out.append(f"{look.surfaces}_wall_colour")
    if look.wall_colours not in {k for k, w in dist.wall_colours if w > 0}:
        out.append("wall_colours")
    weights = dict(dist.layouts)
    if not (weights.get(cfg.layout, 0) > 0 or (not cfg.layout and weights.get("corridor", 0) > 0
                                                 and weights.get("bsp", 0) > 0)):
        out.append("layout")
    checks = [("wall_height", cfg.wall_height, dist.wall_height), ("door_height", cfg.door_height, dist.door_height),
              ("furniture_density", cfg.furniture_density, dist.furniture_density),
              ("room_area", cfg.room_area, dist.room_area), ("corridor_width", cfg.corridor_width, dist.corridor_width),
              ("extra_door_prob", cfg.extra_door_prob, dist.extra_door_prob),
              ("max_extra_doors", cfg.max_extra_doors, dist.max_extra_doors)]
    checks += [(f"furniture_scale[{i}]", cfg.furniture_scale[i], dist.furniture_scale[i]) for i in range(3)]
    out += [name for name, value, rng_range in checks if not _inside(value, rng_range)]
    if tuple(cfg.pictures_per_room) not in {tuple(p) for p in dist.pictures_per_room}:
        out.append("pictures_per_room")
    return out


STYLE_DISTRIBUTIONS: dict[str, StyleDistribution] = {
    "diverse": StyleDistribution("diverse"),
    "pale": StyleDistribution(
        "pale", textured_prob=0.0, flat_wall_saturation=(0.0, 0.06), wall_value=(0.86, 0.96), near_white_prob=0.0,
        saturation_spread=0.03, value_spread=0.04, wall_colours=((1, 1.0),), low_contrast_prob=0.5,
        floor_saturation=(0.03, 0.25), floor_value=(0.45, 0.85), plain_noise=(0.005, 0.02),
        pictures_per_room=((0, 1),), wall_height=(2.85, 3.05), door_height=(2.2, 2.3),
        furniture_scale=((1.2, 1.3), (0.85, 1.0), (0.7, 0.8)), furniture_density=(0.8, 1.1),
        layouts=(("open_plan", 0.5), ("l_hall", 0.5)), rooms=(3, 10), room_area=(9.0, 22.0),
        corridor_width=(1.4, 1.9), extra_door_prob=(0.2, 0.6), max_extra_doors=(0, 3)),
}
"""Named style distributions: ``diverse`` (training), ``pale`` (held-out family)."""

TRAINING_DISTRIBUTION = "diverse"
"""The distribution the held-out families are built to lie outside of."""


def get_distribution(name: str) -> StyleDistribution:
    """A style distribution by name; unknown name -> ConfigError."""
    try:
        return STYLE_DISTRIBUTIONS[name]
    except KeyError:
        raise ConfigError(name, f"unknown style distribution; known: {', '.join(STYLE_DISTRIBUTIONS)}") from None
