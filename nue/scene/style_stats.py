"""How a split's houses look and are laid out, measured on the generated files: the statistics that show
the held-out style families apart from the training houses (``nue scenes stats``).

Per house (from ``house.json`` and the wall / floor textures): the walls' mean CIE L* lightness and C*
chroma, the pattern contrast (standard deviation of L* inside a wall texture, averaged over rooms), the
wall-floor lightness contrast (mean |L*_wall - L*_floor| per room), how many distinct wall colours the
rooms have (mean colours closer than ``SAME_COLOUR`` Delta-E are one colour), the surface kind, the layout,
the wall height, the furniture scale, and the parameters its config has outside the training style
distribution's support (:func:`nue.scene.house_styles.outside_support`). Per split: medians and ranges,
counts of layouts and surface kinds, and how many houses fall in the "flat pale" box (:data:`PALE_BOX`).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
from PIL import Image

from nue.scene.house_config import Appearance, HouseConfig
from nue.scene.house_styles import TRAINING_DISTRIBUTION, get_distribution, outside_support

SAME_COLOUR = 5.0
"""Delta-E (CIE76) below which two rooms' mean wall colours count as one colour."""

PALE_BOX = {"wall_L": (85.0, 100.0), "wall_chroma": (0.0, 6.0), "pattern_std": (0.0, 3.0)}
"""A house is "flat pale" when its wall lightness, chroma and pattern contrast all lie in these ranges."""


def srgb_to_lab(rgb: np.ndarray) -> np.ndarray:
    """uint8 or [0, 1] sRGB (..., 3) -> CIE L*a*b* (..., 3), D65 white."""
    c = np.asarray(rgb, dtype=float)
    c = c / 255.0 if c.max() > 1.0 else c
    lin = np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)
    m = np.array([[0.4124, 0.3576, 0.1805], [0.2126, 0.7152, 0.0722], [0.0193, 0.1192, 0.9505]])
    xyz = lin @ m.T / np.array([0.95047, 1.0, 1.08883])
    f = np.where(xyz > (6 / 29) ** 3, np.cbrt(xyz), xyz / (3 * (6 / 29) ** 2) + 4 / 29)
    return np.stack([116 * f[..., 1] - 16, 500 * (f[..., 0] - f[..., 1]), 200 * (f[..., 1] - f[..., 2])], -1)


def _distinct(colours: list[np.ndarray]) -> int:
    """Greedy count of colours at least ``SAME_COLOUR`` apart."""
    kept: list[np.ndarray] = []
    for c in colours:
        if all(np.linalg.norm(c - k) >= SAME_COLOUR for k in kept):
            kept.append(c)
    return len(kept)


def config_of(meta: dict) -> HouseConfig:
    """The ``HouseConfig`` recorded in a ``house.json`` (fields it omits keep their defaults)."""
    def plain(d: dict) -> dict[str, Any]:
        return {k: tuple(v) if isinstance(v, list) else v for k, v in d.items()}

    data = plain(meta["config"])
    look = Appearance(**plain(meta["config"].get("appearance", {})))
    return HouseConfig(**{**data, "appearance": look})


def house_stats(folder: Path) -> dict:
    """The statistics of one generated house folder."""
    meta = json.loads((Path(folder) / "house.json").read_text())
    cfg = config_of(meta)
    walls, floors, stds, contrast = [], [], [], []
    for room in meta["rooms"]:
        wall = srgb_to_lab(np.asarray(Image.open(Path(folder) / "textures" / f"{room['wall_texture']}.png").convert("RGB")))
        floor = srgb_to_lab(np.asarray(Image.open(Path(folder) / "textures" / f"{room['floor_texture']}.png").convert("RGB")))
        walls.append(wall.reshape(-1, 3).mean(0))
        floors.append(floor.reshape(-1, 3).mean(0))
        stds.append(float(wall[..., 0].std()))
        contrast.append(abs(walls[-1][0] - floors[-1][0]))
    wall_mean = np.mean(walls, 0)
    out = {
        "house": Path(folder).name, "layout": meta["layout"], "surfaces": cfg.appearance.surfaces,
        "rooms": len(meta["rooms"]), "wall_colours": _distinct(walls),
        "wall_L": round(float(wall_mean[0]), 1), "wall_chroma": round(float(np.mean([np.hypot(w[1], w[2]) for w in walls])), 1),
        "pattern_std": round(float(np.mean(stds)), 1), "wall_floor_dL": round(float(np.mean(contrast)), 1),
        "wall_height": cfg.wall_height, "furniture_scale": list(cfg.furniture_scale),
        "pictures_per_room": round(len(meta["pictures"]) / len(meta["rooms"]), 2),
        "outside_training": outside_support(get_distribution(TRAINING_DISTRIBUTION), cfg),
    }
    out["flat_pale"] = all(lo <= out[k] <= hi for k, (lo, hi) in PALE_BOX.items())
    return out


LOOK = ("wall_L", "wall_chroma", "pattern_std")
"""The wall-look features of :func:`nearest_look`."""


def nearest_look(houses: list[dict], reference: list[dict]) -> list[float]:
    """Per house of ``houses``, the distance to the nearest house of ``reference`` in the :data:`LOOK` features,
    each divided by its standard deviation over ``reference`` (a house is never its own neighbour)."""
    ref = np.array([[h[k] for k in LOOK] for h in reference], dtype=float)
    scale = ref.std(0) + 1e-9
    out = []
    for h in houses:
        d = np.linalg.norm((ref - np.array([h[k] for k in LOOK], dtype=float)) / scale, axis=1)
        d = d[[r["house"] != h["house"] for r in reference]]
        out.append(round(float(d.min()), 2))
    return out


def _summary(values: list[float]) -> list[float]:
    """[median, min, max] rounded."""
    return [round(float(np.median(values)), 2), round(float(np.min(values)), 2), round(float(np.max(values)), 2)]


def split_stats(houses: list[dict], reference: list[dict] | None = None) -> dict:
    """Per-split aggregate of :func:`house_stats` rows (with :func:`nearest_look` to ``reference`` if given)."""
    def counts(key: str) -> dict[str, int]:
        keys = sorted({str(h[key]) for h in houses})
        return {k: sum(str(h[key]) == k for h in houses) for k in keys}

    numeric = ("wall_L", "wall_chroma", "pattern_std", "wall_floor_dL", "wall_height", "pictures_per_room")
    return {
        "houses": len(houses), "layouts": counts("layout"), "surfaces": counts("surfaces"),
        **{k: _summary([h[k] for h in houses]) for k in numeric},
        "distinct_wall_colours_per_room": _summary([h["wall_colours"] / h["rooms"] for h in houses]),
        "furniture_width_scale": _summary([h["furniture_scale"][0] for h in houses]),
        "furniture_height_scale": _summary([h["furniture_scale"][2] for h in houses]),
        "flat_pale_houses": sum(h["flat_pale"] for h in houses),
        "houses_outside_training_support": sum(bool(h["outside_training"]) for h in houses),
        "outside_training_parameters": counts_of([p for h in houses for p in h["outside_training"]]),
        **({"nearest_training_look": _summary(nearest_look(houses, reference))} if reference else {}),
    }


def counts_of(items: list[str]) -> dict[str, int]:
    """Occurrences of each item, sorted by name."""
    return {k: items.count(k) for k in sorted(set(items))}


def stats_markdown(stats: dict[str, dict]) -> str:
    """A markdown table of :func:`split_stats` per split (median [min, max])."""
    def rng(v) -> str:
        return f"{v[0]:g} [{v[1]:g}, {v[2]:g}]"

    rows = [("houses", lambda s: str(s["houses"])),
            ("surfaces", lambda s: ", ".join(f"{k} {v}" for k, v in s["surfaces"].items())),
            ("layouts", lambda s: ", ".join(f"{k} {v}" for k, v in s["layouts"].items())),
            ("wall L*", lambda s: rng(s["wall_L"])), ("wall chroma C*", lambda s: rng(s["wall_chroma"])),
            ("wall pattern contrast (std L*)", lambda s: rng(s["pattern_std"])),
            ("wall-floor contrast (mean abs dL*)", lambda s: rng(s["wall_floor_dL"])),
            ("distinct wall colours / room", lambda s: rng(s["distinct_wall_colours_per_room"])),
            ("pictures / room", lambda s: rng(s["pictures_per_room"])),
            ("wall height, m", lambda s: rng(s["wall_height"])),
            ("furniture width scale", lambda s: rng(s["furniture_width_scale"])),
            ("furniture height scale", lambda s: rng(s["furniture_height_scale"])),
            ("flat pale houses (PALE_BOX)", lambda s: str(s["flat_pale_houses"])),
            ("look distance to the nearest training house", lambda s: rng(s["nearest_training_look"])
             if "nearest_training_look" in s else "-"),
            ("houses outside the training support", lambda s: str(s["houses_outside_training_support"])),
            ("parameters outside it (houses)",
             lambda s: ", ".join(f"{k} {v}" for k, v in s["outside_training_parameters"].items()) or "-")]
    names = list(stats)
    lines = ["| | " + " | ".join(names) + " |", "|---|" + "---|" * len(names)]
    lines += [f"| {label} | " + " | ".join(f(stats[n]) for n in names) + " |" for label, f in rows]
    return "\n".join(lines) + "\n"
