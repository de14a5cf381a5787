"""Procedural furnished houses written in the Gibson scene layout (the embedded default scenes).

A house is a rectangle footprint (long side 9.6-14 m) centred on the world origin, split into
3-8 rooms by a hallway or by recursive splits, with doorways, box furniture, a distinct wall and
floor texture per room and framed pictures on the walls (the ``gibson`` style; the held-out ``plain``
style and every parameter are in :mod:`nue.scene.house_config`). ``generate_house`` writes one folder:

- ``mesh_z_up.obj`` / ``mesh_z_up.mtl`` / ``textures/*.png``: z up, metres, one material per
  texture;
- ``floors.txt`` (``0.0``) and ``floor_trav_0.png`` (iGibson traversability map, 1 cm / pixel);
- ``house.json``: seed, config, rooms, doors, furniture and pictures (metres) for figures/tests.

Same seed and config -> byte-identical files. ``SPLITS`` fixes the 21 train / 14 val seeds and the 14
seeds of ``val_plain``, whose houses are in the held-out style (``SPLIT_STYLES``); ``train_diverse`` and
``val_pale`` houses draw their config per house from a style distribution (:mod:`nue.scene.house_styles`).
"""

from __future__ import annotations

import json
import os
import shutil
import sys
from pathlib import Path

import numpy as np
from PIL import Image

from nue.errors import ConfigError, SceneError
from nue.scene import house_textures as tx
from nue.scene.house_config import STYLES, HouseConfig, config_dict, get_style  # noqa: F401  (HouseConfig re-exported)
from nue.scene.house_furnish import furnish, hang_pictures
from nue.scene.house_layout import Plan, PlanFailure, PlanParams
from nue.scene.house_plans import make_any_plan
from nue.scene.house_styles import STYLE_DISTRIBUTIONS, sample_style
from nue.scene.house_mesh import Material, build_mesh, write_obj
from nue.scene.house_trav import check_house, map_size, trav_map
from nue.scene.scene import MESH_NAME, Scene, content_hash

GENERATOR_VERSION = 3
"""Bumped whenever the same seed and config would give a different house."""

SPLITS: dict[str, tuple[int, ...]] = {
    "train": tuple(range(1000, 1021)),
    "val": tuple(range(2000, 2014)),
    "val_plain": tuple(range(3000, 3014)),
    "train_diverse": tuple(range(4000, 4042)),
    "val_pale": tuple(range(5000, 5014)),
}
"""Fixed house seeds: 21 training houses, 14 validation houses, 14 validation houses of the held-out style,
42 training houses of the ``diverse`` style distribution, 14 houses of the held-out ``pale`` family
(all disjoint)."""

TRAINING_SPLITS: tuple[str, ...] = ("train", "train_diverse")
"""Splits models may learn from (demonstrations, selection); the others are for evaluation only."""

SPLIT_STYLES: dict[str, str] = {"val_plain": "plain", "train_diverse": "diverse", "val_pale": "pale"}
"""Scene style of each split that is not ``gibson``: a fixed style of ``STYLES``, or a style distribution of
``house_styles.STYLE_DISTRIBUTIONS`` (a config drawn per house from its seed). Models train on ``train`` or
``train_diverse``; ``val_plain`` and ``val_pale`` are held-out families outside ``diverse``'s support."""

HOUSE_FILES = ("mesh_z_up.obj", "mesh_z_up.mtl", "floors.txt", "floor_trav_0.png", "house.json")
"""Files every complete house folder holds (plus ``textures/``)."""


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
                      cfg.corridor_prob, cfg.extra_door_prob, cfg.room_area, cfg.max_extra_doors, cfg.layout)


def _shared_wall_colours(rng, look, hue0: float) -> list[np.ndarray]:
    """The ``look.wall_colours`` wall colours the rooms of a house take in turn (evenly spread hues)."""
    k = look.wall_colours
    return [tx.hsv(hue0 + j / k, rng.uniform(*look.wall_saturation), rng.uniform(*look.wall_value)) for j in range(k)]


def _wall_colour(rng, look, hue: float, order: int, shared: list[np.ndarray]) -> np.ndarray:
    """A room's wall colour: the shared colour at its turn ``order``, else its own at ``hue``."""
    if shared:
        return shared[order % len(shared)]
    return tx.hsv(hue, rng.uniform(*look.wall_saturation), rng.uniform(*look.wall_value))


def _materials(rng, plan: Plan, cfg: HouseConfig) -> tuple[dict[str, Material], list[dict[str, str]]]:
    """Per-room wall / floor textures with spread-out hues, plus shared furniture textures (``textured``
    surfaces; ``plain`` ones: :func:`_plain_materials`).

    Returns the materials and, per room, its wall and floor pattern names.
    """
    look = cfg.appearance
    if look.surfaces == "plain":
        return _plain_materials(rng, plan, cfg)
    n, wh = cfg.texture_size, cfg.wall_height
    mats: dict[str, Material] = {}
    styles = []
    hue0 = rng.random()
    hue_order = rng.permutation(len(plan.rooms))  # evenly spread hues, neighbours not adjacent in hue
    walls = [tx.WALL_PATTERNS[i] for i in rng.permutation(len(tx.WALL_PATTERNS))]
    floors = [tx.FLOOR_PATTERNS[i] for i in rng.permutation(len(tx.FLOOR_PATTERNS))]
    shared = _shared_wall_colours(rng, look, hue0)
    for i, room in enumerate(plan.rooms):
        hue = hue0 + hue_order[i] / len(plan.rooms)
        wall = walls[i % len(walls)]
        floor = floors[(i + i // len(walls)) % len(floors)]  # no two rooms share both patterns
        if room.kind in ("bathroom", "kitchen") and floor in ("planks", "carpet", "parquet"):
            floor = "tiles" if rng.random() < 0.5 else "checker"
        if floor in ("planks", "parquet"):
            fcol = tx.hsv(rng.uniform(0.04, 0.11), rng.uniform(0.35, 0.65), rng.uniform(0.35, 0.8))
        else:
            fcol = tx.hsv(hue + rng.uniform(0.4, 0.6), rng.uniform(*look.floor_saturation), rng.uniform(*look.floor_value))
        wcol = _wall_colour(rng, look, hue, int(hue_order[i]), shared)
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


def _plain_materials(rng, plan: Plan, cfg: HouseConfig) -> tuple[dict[str, Material], list[dict[str, str]]]:
    """``plain`` surfaces: one flat diffuse colour per material (faint smooth noise), walls in the style's
    shared colours, floors one colour each, furniture in flat wood / fabric / white tones. Same material
    names as :func:`_materials`, so the mesh is built the same way."""
    look = cfg.appearance
    small, wh, amount = cfg.texture_size // 2, cfg.wall_height, look.plain_noise

    def flat(color) -> np.ndarray:
        return tx.plain(rng, color, small, amount)

    rooms = len(plan.rooms)
    hue0 = rng.random()
    hue_order = rng.permutation(rooms)
    shared = _shared_wall_colours(rng, look, hue0)
    mats: dict[str, Material] = {}
    for i in range(rooms):
        wcol = _wall_colour(rng, look, hue0 + hue_order[i] / rooms, int(hue_order[i]), shared)
        fcol = tx.hsv(rng.random(), rng.uniform(*look.floor_saturation), rng.uniform(*look.floor_value))
        mats[f"room{i}_wall"] = Material(flat(wcol), (1.0, wh))
        mats[f"room{i}_floor"] = Material(flat(fcol), (1.0, 1.0))
    mats["ceiling"] = Material(flat(tx.hsv(0.1, 0.03, 0.93)), (2.0, 2.0))
    mats["trim"] = Material(flat(tx.hsv(0.1, 0.05, 0.88)), (1.0, 1.0))
    wood_l = tx.hsv(rng.uniform(0.07, 0.11), rng.uniform(0.3, 0.5), rng.uniform(0.65, 0.85))
    wood_d = tx.hsv(rng.uniform(0.03, 0.08), rng.uniform(0.4, 0.7), rng.uniform(0.25, 0.45))
    for name, col in (("wood_light", wood_l), ("wood_dark", wood_d), ("drawers", wood_l * 0.95), ("doors", wood_l),
                      ("books", wood_d)):
        mats[name] = Material(flat(col), (1.0, 1.0))
    for name in ("fabric_a", "fabric_b", "bedding"):
        mats[name] = Material(flat(tx.hsv(rng.random(), rng.uniform(0.3, 0.7), rng.uniform(0.35, 0.8))), (0.5, 0.5))
    mats["white"] = Material(flat(tx.hsv(0.0, 0.0, 0.92)), (1.0, 1.0))
    mats["screen"] = Material(flat(tx.hsv(0.6, 0.3, 0.1)), (1.0, 1.0))
    mats["pot"] = Material(flat(tx.hsv(0.05, 0.65, 0.6)), (0.5, 0.5))
    mats["plant"] = Material(flat(tx.hsv(0.3, 0.7, 0.45)), (0.4, 0.4))
    return mats, [{"wall": "plain", "floor": "plain"} for _ in range(rooms)]


def _attempt(seed: int, attempt: int, cfg: HouseConfig):
    """One deterministic draw, or None if it fails a check.

    Returns (plan, items, pictures, materials, trav (N, N) uint8, per-room pattern names).
    """
    rng = np.random.default_rng([seed, attempt])
    try:
        plan = make_any_plan(rng, _plan_params(rng, cfg))
    except PlanFailure:
        return None
    items = furnish(rng, plan, cfg.furniture_density, _cm(cfg.door_clearance), _cm(cfg.min_passage) // 2,
                   _cm(cfg.robot_radius), scale=cfg.furniture_scale)
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
        "config": config_dict(config), "layout": plan.layout, "footprint": _m(plan.footprint),
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
    want = {"seed": seed, "version": GENERATOR_VERSION, "config": json.loads(json.dumps(config_dict(config)))}
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


def _generate_into(folder: Path, seed: int, config: HouseConfig, replace: bool = False) -> Path:
    """Generate into a temporary sibling folder and rename it to ``folder``. With ``replace`` a folder already
    there is replaced (``--force``); without, a folder another process renamed into place while this one was
    generating wins and this copy is dropped (several evaluations may start on a machine without scenes, and a
    reader must never see a house half-removed)."""
    root = folder.parent
    root.mkdir(parents=True, exist_ok=True)
    _remove_stale_temps(root, folder.name)
    tmp = root / f".{folder.name}.tmp-{os.getpid()}"
    shutil.rmtree(tmp, ignore_errors=True)
    generate_house(seed, tmp, config)
    if replace and folder.exists():
        shutil.rmtree(folder)
    try:
        os.rename(tmp, folder)  # atomic; fails if another process's copy is already in place
    except OSError:
        if not folder.exists():
            raise
        shutil.rmtree(tmp, ignore_errors=True)
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


def split_config(split: str) -> HouseConfig:
    """The generator config (scene style) of a split's houses: ``SPLIT_STYLES``, else ``gibson``; a split
    whose houses draw their style from a distribution -> ConfigError (use :func:`house_config`)."""
    if split not in SPLITS:
        raise ConfigError(split, f"unknown split; choose one of {sorted(SPLITS)}")
    name = SPLIT_STYLES.get(split, "gibson")
    if name in STYLE_DISTRIBUTIONS:
        raise ConfigError(split, f"houses of this split draw their style from the {name!r} distribution, one per house")
    return get_style(name)


def house_config(split: str, index: int) -> HouseConfig:
    """The generator config of house ``index`` of ``split``: the split's fixed style, or the style drawn
    from its distribution for that house's seed (:func:`nue.scene.house_styles.sample_style`)."""
    if split not in SPLITS:
        raise ConfigError(split, f"unknown split; choose one of {sorted(SPLITS)}")
    name = SPLIT_STYLES.get(split, "gibson")
    if name in STYLE_DISTRIBUTIONS:
        return sample_style(STYLE_DISTRIBUTIONS[name], SPLITS[split][index])
    return get_style(name)


def generate_split(split: str, out_root: str | Path, config: HouseConfig | None = None,
                   progress: bool = True, force: bool = False) -> list[Path]:
    """Write ``out_root/<split>_<NN>/`` for every seed of ``split``; intact houses are kept.

    Each house is written to a temporary folder and renamed into place, so an interrupted run
    leaves no half-written house. A folder that is not an intact copy of its house
    (:func:`house_problem`) is refused with :class:`SceneError`; with ``force`` it is regenerated if
    its ``house.json`` shows our generator made it (a folder of the user's is never overwritten).
    ``config`` defaults to each house's style (:func:`house_config`). Unknown split -> ConfigError.
    """
    if split not in SPLITS:
        raise ConfigError(split, f"unknown split; choose one of {sorted(SPLITS)}")
    root = Path(out_root)
    root.mkdir(parents=True, exist_ok=True)
    paths = []
    for k, seed in enumerate(SPLITS[split]):
        house_cfg = config or house_config(split, k)
        house_cfg.validate()
        folder = root / f"{split}_{k:02d}"
        problem = house_problem(folder, seed, house_cfg) if folder.exists() else None
        if folder.exists() and problem is None:
            status = "kept"
        elif problem is not None and not (force and _is_ours(folder)):
            hint = ("rerun with --force to regenerate it" if _is_ours(folder)
                    else "it is not a house nue generated: move it away or use another --out")
            raise SceneError(folder, f"{problem}; {hint}")
        else:
            _generate_into(folder, seed, house_cfg, replace=problem is not None)
            status = "regenerated" if problem else "generated"
        paths.append(folder)
        if progress:
            print(f"[{k + 1}/{len(SPLITS[split])}] {folder} ({status}, seed {seed})", file=sys.stderr)
    return paths


def ensure_house(split: str, index: int, root: str | Path, config: HouseConfig | None = None) -> Path:
    """``root/<split>_<NN>/``: house ``index`` of ``split`` (in the split's style unless ``config`` is given),
    generated if the folder does not exist; a folder that is not an intact copy of exactly this house
    (:func:`house_problem`) is refused with :class:`SceneError`, never overwritten."""
    if split not in SPLITS:
        raise ConfigError(split, f"unknown split; choose one of {sorted(SPLITS)}")
    config = config or house_config(split, index)
    seed = SPLITS[split][index]
    folder = Path(root) / f"{split}_{index:02d}"
    if not folder.exists():
        _generate_into(folder, seed, config)
    problem = house_problem(folder, seed, config)
    if problem:
        raise SceneError(folder, f"{problem}; regenerate it with `nue scenes generate --split {split} --out {root} "
                                 f"--force`, or point --scenes-root elsewhere")
    return folder
