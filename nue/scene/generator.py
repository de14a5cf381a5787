"""Procedural furnished houses written in the Gibson scene layout (the embedded default scenes).

A house is a rectangle footprint (long side 9.6-14 m) centred on the world origin, split into
3-8 rooms by a hallway or by recursive splits, with doorways, box furniture, a distinct wall and
floor texture per room and framed pictures on the walls. ``generate_house`` writes one folder:

- ``mesh_z_up.obj`` / ``mesh_z_up.mtl`` / ``textures/*.png``: z up, metres, one material per
  texture;
- ``floors.txt`` (``0.0``) and ``floor_trav_0.png`` (iGibson traversability map, 1 cm / pixel);
- ``house.json``: seed, config, rooms, doors, furniture and pictures (metres) for figures/tests.

Same seed and config -> byte-identical files. ``SPLITS`` fixes the 21 train / 14 val seeds.
"""

from __future__ import annotations

import dataclasses
import json
import os
import shutil
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from PIL import Image

from nue.errors import ConfigError, SceneError
from nue.scene import house_textures as tx
from nue.scene.house_furnish import furnish, hang_pictures
from nue.scene.house_layout import Plan, PlanFailure, PlanParams, make_plan
from nue.scene.house_mesh import Material, build_mesh, write_obj
from nue.scene.house_trav import check_house, map_size, trav_map
from nue.scene.navgrid import ROBOT_RADIUS
from nue.scene.scene import MESH_NAME, Scene, content_hash

GENERATOR_VERSION = 3
"""Bumped whenever the same seed and config would give a different house."""

SPLITS: dict[str, tuple[int, ...]] = {
    "train": tuple(range(1000, 1021)),
    "val": tuple(range(2000, 2014)),
}
"""Fixed house seeds: 21 training houses, 14 validation houses (disjoint)."""

HOUSE_FILES = ("mesh_z_up.obj", "mesh_z_up.mtl", "floors.txt", "floor_trav_0.png", "house.json")
"""Files every complete house folder holds (plus ``textures/``)."""


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
    """Probability of an extra door between two neighbouring rooms (loops; at most two per house)."""
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

    def validate(self) -> None:
        """Raise ConfigError on inconsistent values."""
        pairs = ("long_side", "short_side", "footprint_area", "floor_area", "rooms", "corridor_width",
                 "door_width", "pictures_per_room", "picture_heights")
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


def _cm(v: float) -> int:
    return int(round(v * 100))


def _plan_params(rng, cfg: HouseConfig) -> PlanParams:
    long_side = 2 * int(rng.integers(_cm(cfg.long_side[0]) // 2, _cm(cfg.long_side[1]) // 2 + 1))
    area = rng.uniform(*cfg.footprint_area) * 1e4
    lo, hi = _cm(cfg.short_side[0]), min(_cm(cfg.short_side[1]), long_side)
    short_side = 2 * (int(np.clip(area / long_side, lo, hi)) // 2)
    return PlanParams(long_side, short_side, max(1, _cm(cfg.wall_thickness) // 2), _cm(cfg.min_room_side),
                      (_cm(cfg.corridor_width[0]), _cm(cfg.corridor_width[1])),
                      (_cm(cfg.door_width[0]), _cm(cfg.door_width[1])), 15, cfg.rooms[1], cfg.rooms[0],
                      cfg.corridor_prob, cfg.extra_door_prob)


def _materials(rng, plan: Plan, cfg: HouseConfig) -> tuple[dict[str, Material], list[dict[str, str]]]:
    """Per-room wall / floor textures with spread-out hues, plus shared furniture textures.

    Returns the materials and, per room, its wall and floor pattern names.
    """
    n, wh = cfg.texture_size, cfg.wall_height
    mats: dict[str, Material] = {}
    styles = []
    hue0 = rng.random()
    hue_order = rng.permutation(len(plan.rooms))  # evenly spread hues, neighbours not adjacent in hue
    walls = [tx.WALL_PATTERNS[i] for i in rng.permutation(len(tx.WALL_PATTERNS))]
    floors = [tx.FLOOR_PATTERNS[i] for i in rng.permutation(len(tx.FLOOR_PATTERNS))]
    for i, room in enumerate(plan.rooms):
        hue = hue0 + hue_order[i] / len(plan.rooms)
        wall = walls[i % len(walls)]
        floor = floors[(i + i // len(walls)) % len(floors)]  # no two rooms share both patterns
        if room.kind in ("bathroom", "kitchen") and floor in ("planks", "carpet", "parquet"):
            floor = "tiles" if rng.random() < 0.5 else "checker"
        if floor in ("planks", "parquet"):
            fcol = tx.hsv(rng.uniform(0.04, 0.11), rng.uniform(0.35, 0.65), rng.uniform(0.35, 0.8))
        else:
            fcol = tx.hsv(hue + rng.uniform(0.4, 0.6), rng.uniform(0.2, 0.55), rng.uniform(0.4, 0.85))
        wcol = tx.hsv(hue, rng.uniform(0.12, 0.45), rng.uniform(0.68, 0.92))
        mats[f"room{i}_wall"] = Material(tx.wall_texture(rng, wall, wcol, wh, n), (1.0, wh))
        mats[f"room{i}_floor"] = Material(tx.floor_texture(rng, floor, fcol, n), (1.0, 1.0))
        styles.append({"wall": wall, "floor": floor})
    small = n // 2
    wood_l = tx.hsv(rng.uniform(0.07, 0.11), rng.uniform(0.3, 0.5), rng.uniform(0.65, 0.85))
    wood_d = tx.hsv(rng.uniform(0.03, 0.08), rng.uniform(0.4, 0.7), rng.uniform(0.25, 0.45))
    mats["ceiling"] = Material(tx.plain(rng, tx.hsv(0.1, 0.03, 0.93), small, 0.02), (2.0, 2.0))
    mats["trim"] = Material(tx.plain(rng, tx.hsv(0.1, 0.05, 0.88), small, 0.01), (1.0, 1.0))
    mats["wood_light"] = Material(tx.to_uint8(tx.wood(rng, wood_l, n, n // 8, n)), (1.0, 1.0))
    mats["wood_dark"] = Material(tx.to_uint8(tx.wood(rng, wood_d, n, n // 8, n)), (1.0, 1.0))
    for name in ("fabric_a", "fabric_b", "bedding"):
        col = tx.hsv(rng.random(), rng.uniform(0.3, 0.7), rng.uniform(0.35, 0.8))
        mats[name] = Material(tx.fabric(rng, col, small), (0.5, 0.5))
    mats["white"] = Material(tx.plain(rng, tx.hsv(0.0, 0.0, 0.92), small), (1.0, 1.0))
    mats["screen"] = Material(tx.plain(rng, tx.hsv(0.6, 0.3, 0.1), small, 0.2, 8.0), (1.0, 1.0))
    mats["pot"] = Material(tx.plain(rng, tx.hsv(0.05, 0.65, 0.6), small, 0.08), (0.5, 0.5))
    mats["plant"] = Material(tx.foliage(rng, small), (0.4, 0.4))
    mats["books"] = Material(tx.books(rng, n), None)
    mats["drawers"] = Material(tx.panel_front(rng, wood_l * 0.95, 3, 1, n), None)
    mats["doors"] = Material(tx.panel_front(rng, wood_l, 1, 2, n), None)
    return mats, styles


def _attempt(seed: int, attempt: int, cfg: HouseConfig):
    """One deterministic draw, or None if it fails a check.

    Returns (plan, items, pictures, materials, trav (N, N) uint8, per-room pattern names).
    """
    rng = np.random.default_rng([seed, attempt])
    try:
        plan = make_plan(rng, _plan_params(rng, cfg))
    except PlanFailure:
        return None
    items = furnish(rng, plan, cfg.furniture_density, _cm(cfg.door_clearance), _cm(cfg.min_passage) // 2,
                   _cm(cfg.robot_radius))
    trav = trav_map(plan, items, map_size(plan))
    if check_house(plan, trav, cfg.robot_radius, cfg.min_free_extent, cfg.floor_area, cfg.door_width[0]):
        return None
    z = (_cm(cfg.picture_heights[0]), _cm(cfg.picture_heights[1]))
    pictures = hang_pictures(rng, plan, items, cfg.pictures_per_room, z)
    mats, styles_per_room = _materials(rng, plan, cfg)
    styles = [tx.PICTURE_STYLES[i] for i in rng.permutation(len(tx.PICTURE_STYLES))]
    for k, pic in enumerate(pictures):
        mats[pic.material] = Material(tx.picture(rng, styles[k % len(styles)], cfg.texture_size), None)
    return plan, items, pictures, mats, trav, styles_per_room


def _m(v) -> float | list:
    return [_m(x) for x in v] if isinstance(v, (tuple, list)) else round(v / 100, 2)


def generate_house(seed: int, out_dir: str | Path, config: HouseConfig = HouseConfig()) -> Path:
    """Generate the house of ``seed`` into ``out_dir`` (created; existing files overwritten); returns it."""
    config.validate()
    for attempt in range(config.max_attempts):
        result = _attempt(int(seed), attempt, config)
        if result is not None:
            break
    else:
        raise SceneError(out_dir, f"no valid house for seed {seed} in {config.max_attempts} attempts")
    plan, items, pictures, mats, trav, room_styles = result
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    mb = build_mesh(plan, items, pictures, mats, _cm(config.wall_height), _cm(config.door_height))
    write_obj(mb, out, f"nue procedural house: seed {seed}, generator version {GENERATOR_VERSION}")
    (out / "floors.txt").write_text("0.0\n")
    Image.fromarray(trav, "L").save(out / "floor_trav_0.png", format="PNG")
    meta = {
        "generator": "nue.scene.generator", "version": GENERATOR_VERSION, "seed": int(seed), "attempt": attempt,
        "config": dataclasses.asdict(config), "layout": plan.layout, "footprint": _m(plan.footprint),
        "floor_area": round(sum(r.area_m2 for r in plan.rooms), 2), "triangles": mb.triangle_count,
        "trav_map_size": int(trav.shape[0]),
        "rooms": [{"name": r.name, "kind": r.kind, "rect": _m(r.interior), "area": round(r.area_m2, 2),
                   "wall_texture": f"room{i}_wall", "wall_pattern": room_styles[i]["wall"],
                   "floor_texture": f"room{i}_floor", "floor_pattern": room_styles[i]["floor"]}
                  for i, r in enumerate(plan.rooms)],
        "doors": [{"rooms": list(d.rooms), "rect": _m(d.rect), "width": _m(d.width),
                   "axis": "x" if d.normal == 0 else "y"} for d in plan.doors],
        "furniture": [{"kind": it.kind, "room": it.room, "rect": _m(it.rect), "height": _m(it.height),
                       "against_wall": it.against_wall} for it in items],
        "pictures": [{"room": p.room, "texture": p.material, "wall_axis": "x" if p.axis == 0 else "y",
                      "facing": p.sign, "plane": _m(p.plane), "span": _m(p.span), "z": _m(p.z)} for p in pictures],
    }
    meta["content_hash"] = content_hash(out, out / MESH_NAME, 1)  # lets a later run tell a corrupted copy
    (out / "house.json").write_text(json.dumps(meta, indent=1, sort_keys=True) + "\n")
    return out


def house_problem(folder: Path, seed: int, config: HouseConfig) -> str | None:
    """What keeps ``folder`` from being a complete, intact copy of house ``seed`` (None if it is one):
    a missing file, an unreadable or foreign ``house.json``, another seed / config / generator
    version, a scene that does not load, or content that changed since it was generated."""
    missing = [f for f in HOUSE_FILES if not (folder / f).is_file()] + ([] if (folder / "textures").is_dir() else ["textures/"])
    if missing:
        return f"not a complete generated house (missing {', '.join(missing)})"
    try:
        meta = json.loads((folder / "house.json").read_text())
    except (OSError, ValueError) as exc:
        return f"house.json is unreadable ({type(exc).__name__})"
    if not isinstance(meta, dict) or meta.get("generator") != "nue.scene.generator":
        return "house.json was not written by nue's house generator"
    want = {"seed": seed, "version": GENERATOR_VERSION, "config": json.loads(json.dumps(dataclasses.asdict(config)))}
    for key, value in want.items():
        if meta.get(key) != value:
            return f"holds a different house ({key} differs)"
    try:
        scene = Scene.load(folder)
    except SceneError as exc:
        return f"corrupt ({exc})"
    if meta.get("content_hash") not in (None, scene.content_hash):
        return f"content changed since it was generated (hash {scene.content_hash}, generated {meta['content_hash']})"
    return None


def _is_ours(folder: Path) -> bool:
    """Whether ``folder/house.json`` says nue's generator wrote the folder (so it may be regenerated)."""
    try:
        return json.loads((folder / "house.json").read_text()).get("generator") == "nue.scene.generator"
    except (OSError, ValueError, AttributeError):
        return False


def _generate_into(folder: Path, seed: int, config: HouseConfig) -> Path:
    """Generate into a temporary sibling folder and rename it to ``folder`` (replacing it if present)."""
    root = folder.parent
    root.mkdir(parents=True, exist_ok=True)
    _remove_stale_temps(root, folder.name)
    tmp = root / f".{folder.name}.tmp-{os.getpid()}"
    shutil.rmtree(tmp, ignore_errors=True)
    generate_house(seed, tmp, config)
    if folder.exists():
        shutil.rmtree(folder)
    os.replace(tmp, folder)
    return folder


def _remove_stale_temps(root: Path, name: str) -> None:
    """Delete temporary folders ``.<name>.tmp-<pid>`` left by runs whose process has ended."""
    for tmp in sorted(root.glob(f".{name}.tmp-*")):
        try:
            os.kill(int(tmp.name.rsplit("-", 1)[1]), 0)
        except ProcessLookupError:
            shutil.rmtree(tmp, ignore_errors=True)
        except (ValueError, PermissionError):
            pass


def generate_split(split: str, out_root: str | Path, config: HouseConfig = HouseConfig(),
                   progress: bool = True, force: bool = False) -> list[Path]:
    """Write ``out_root/<split>_<NN>/`` for every seed of ``split``; intact houses are kept.

    Each house is written to a temporary folder and renamed into place, so an interrupted run
    leaves no half-written house. A folder that is not an intact copy of its house
    (:func:`house_problem`) is refused with :class:`SceneError`; with ``force`` it is regenerated if
    its ``house.json`` shows our generator made it (a folder of the user's is never overwritten).
    Unknown split -> ConfigError.
    """
    if split not in SPLITS:
        raise ConfigError(split, f"unknown split; choose one of {sorted(SPLITS)}")
    config.validate()
    root = Path(out_root)
    root.mkdir(parents=True, exist_ok=True)
    paths = []
    for k, seed in enumerate(SPLITS[split]):
        folder = root / f"{split}_{k:02d}"
        problem = house_problem(folder, seed, config) if folder.exists() else None
        if folder.exists() and problem is None:
            status = "kept"
        elif problem is not None and not (force and _is_ours(folder)):
            hint = ("rerun with --force to regenerate it" if _is_ours(folder)
                    else "it is not a house nue generated: move it away or use another --out")
            raise SceneError(folder, f"{problem}; {hint}")
        else:
            _generate_into(folder, seed, config)
            status = "regenerated" if problem else "generated"
        paths.append(folder)
        if progress:
            print(f"[{k + 1}/{len(SPLITS[split])}] {folder} ({status}, seed {seed})", file=sys.stderr)
    return paths


def ensure_house(split: str, index: int, root: str | Path, config: HouseConfig = HouseConfig()) -> Path:
    """``root/<split>_<NN>/``: house ``index`` of ``split``, generated if the folder does not exist; a
    folder that is not an intact copy of exactly this house (:func:`house_problem`) is refused with
    :class:`SceneError`, never overwritten."""
    if split not in SPLITS:
        raise ConfigError(split, f"unknown split; choose one of {sorted(SPLITS)}")
    seed = SPLITS[split][index]
    folder = Path(root) / f"{split}_{index:02d}"
    if not folder.exists():
        return _generate_into(folder, seed, config)
    problem = house_problem(folder, seed, config)
    if problem:
        raise SceneError(folder, f"{problem}; regenerate it with `nue scenes generate --split {split} --out {root} "
                                 f"--force`, or point --scenes-root elsewhere")
    return folder
