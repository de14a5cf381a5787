"""Reader for scenes in the Gibson layout: mesh + floors.txt + per-floor traversability maps, with a content hash.

A scene folder holds ``mesh_z_up.obj`` (with its ``.mtl`` and textures, or vertex colours),
``floors.txt`` (floor heights in metres, one per line) and ``floor_trav_{i}.png`` per floor: a
square 8-bit grey image at 0.01 m per pixel centred on the world origin, where pixel
(row, col) = (y / 0.01 + N/2, x / 0.01 + N/2) and 255 = traversable (iGibson's convention; any
value below 255 is an obstacle). Our generated houses and real Gibson scans load the same way.
"""

from __future__ import annotations

import hashlib
import math
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from PIL import Image

from nue.errors import SceneError

MESH_NAME = "mesh_z_up.obj"
FLOORS_NAME = "floors.txt"
TRAV_RESOLUTION = 0.01
"""Metres per pixel of ``floor_trav_{i}.png``."""


def trav_pixel_from_world(xy, n: int, resolution: float = TRAV_RESOLUTION) -> np.ndarray:
    """World (x, y) (..., 2) -> integer pixel (row, col) (..., 2) of an N x N traversability map."""
    xy = np.asarray(xy, dtype=np.float64)
    col = np.floor(xy[..., 0] / resolution + n / 2).astype(np.int64)
    row = np.floor(xy[..., 1] / resolution + n / 2).astype(np.int64)
    return np.stack([row, col], axis=-1)


def world_from_trav_pixel(rc, n: int, resolution: float = TRAV_RESOLUTION) -> np.ndarray:
    """Pixel (row, col) (..., 2) -> world (x, y) (..., 2) of the pixel centre."""
    rc = np.asarray(rc, dtype=np.float64)
    x = (rc[..., 1] + 0.5 - n / 2) * resolution
    y = (rc[..., 0] + 0.5 - n / 2) * resolution
    return np.stack([x, y], axis=-1)


@dataclass
class Scene:
    """A loaded scene: where its mesh is, its floors and their traversability maps (True = free)."""

    name: str
    """Folder name, e.g. ``val_03`` or a Gibson scan's name."""
    path: Path
    """The scene folder."""
    mesh_path: Path
    """The mesh file (OBJ, GLB or PLY)."""
    floor_heights: tuple[float, ...]
    """Floor heights in metres (z), one per floor, from floors.txt."""
    trav_maps: list[np.ndarray] = field(repr=False)
    """Per floor: (N, N) bool, True where the floor is traversable."""
    content_hash: str = ""
    """sha256 (first 16 hex digits) of mesh, material, texture, floors and map bytes."""
    up_axis: str = "z"
    """Up axis of the mesh file: ``z`` (Gibson) or ``y`` (most GLB files)."""
    resolution: float = TRAV_RESOLUTION
    """Metres per traversability-map pixel."""

    @classmethod
    def load(cls, folder: str | Path, mesh: str = MESH_NAME, up_axis: str = "z") -> "Scene":
        """Load a Gibson-layout folder; raises :class:`SceneError` naming the file and the problem."""
        folder = Path(folder)
        if not folder.is_dir():
            raise SceneError(folder, "scene folder not found")
        mesh_path = folder / mesh
        if not mesh_path.is_file():
            raise SceneError(mesh_path, "mesh file not found")
        if up_axis not in ("z", "y"):
            raise SceneError(folder, f"up_axis must be 'z' or 'y', got {up_axis!r}")
        heights = read_floors(folder / FLOORS_NAME)
        maps = [read_trav_map(folder / f"floor_trav_{i}.png") for i in range(len(heights))]
        scene = cls(folder.name, folder, mesh_path, heights, maps, up_axis=up_axis)
        scene.content_hash = content_hash(folder, mesh_path, len(heights))
        return scene

    def floor_of(self, z: float) -> int:
        """Index of the floor a point at height ``z`` stands on (the highest floor at or below z + 0.5 m)."""
        below = [i for i, h in enumerate(self.floor_heights) if h <= z + 0.5]
        return max(below, key=lambda i: self.floor_heights[i]) if below else 0

    def load_mesh(self):
        """The mesh as a ``trimesh.Scene`` (textures included); :class:`SceneError` if unreadable, empty
        or holding a NaN / inf vertex (see :func:`read_mesh`)."""
        return read_mesh(self.mesh_path)


UNPROCESSED_SUFFIXES = (".glb", ".gltf")
"""Mesh formats trimesh loads as stored (no vertex merging); the others it cleans up after reading."""


def read_mesh(path: str | Path):
    """A mesh file (OBJ, GLB, PLY, ... anything trimesh reads) as a ``trimesh.Scene``, checked once here
    for every format: :class:`SceneError` naming the file if it cannot be read, has no triangles, or
    has a vertex with a NaN or inf coordinate.

    An OBJ's text is checked line by line first (the message names the line). The vertices of every
    format are checked as read, before trimesh's clean-up, which would otherwise drop the non-finite
    vertices and their faces without a word (it does so for PLY); the clean-up then runs as
    ``trimesh.load`` runs it by default, so the loaded mesh is the same as before the check."""
    import trimesh

    path = Path(path)
    if path.suffix.lower() == ".obj":
        check_obj_text(path)
    try:
        loaded = trimesh.load(str(path), force="scene", process=False)
    except Exception as exc:  # trimesh raises many types for a corrupt file
        raise SceneError(path, f"cannot read mesh ({type(exc).__name__}: {exc})") from None
    meshes = {name: g for name, g in loaded.geometry.items() if isinstance(g, trimesh.Trimesh)}
    if sum(len(g.faces) for g in meshes.values()) == 0:
        raise SceneError(path, "mesh has no triangles (corrupt or empty file)")
    for name, g in meshes.items():
        bad = ~np.isfinite(np.asarray(g.vertices)).all(axis=1)
        if bad.any():
            raise SceneError(path, f"{int(bad.sum())} of {len(bad)} vertices of geometry {name!r} are NaN or inf "
                                   f"(the first is vertex {int(np.argmax(bad))})")
    if path.suffix.lower() not in UNPROCESSED_SUFFIXES:
        for g in meshes.values():
            g.process()
    return loaded


OBJ_MIN_VALUES = {b"v": 3, b"vt": 2, b"vn": 3, b"f": 3}
"""Values an OBJ statement needs at least (vertex, texture coordinate, normal, face)."""


def check_obj_text(path: Path) -> None:
    """:class:`SceneError` naming the line if a text OBJ has a vertex, texture coordinate or normal
    with too few values or a NaN/inf, or a face with fewer than 3 corners. Binary garbage is left
    to the mesh reader."""
    with open(path, "rb") as f:
        for lineno, raw in enumerate(f, 1):
            parts = raw.split()
            need = OBJ_MIN_VALUES.get(parts[0]) if parts else None
            if need is None:
                continue
            kind = parts[0].decode()
            if len(parts) - 1 < need:
                raise SceneError(path, f"line {lineno}: '{kind}' needs at least {need} values, got {len(parts) - 1}")
            if kind != "f":
                try:
                    values = [float(v) for v in parts[1 : need + 1]]
                except ValueError:
                    raise SceneError(path, f"line {lineno}: '{kind}' values are not numbers") from None
                if not all(math.isfinite(v) for v in values):
                    raise SceneError(path, f"line {lineno}: '{kind}' has a NaN or inf value")


def read_floors(path: Path) -> tuple[float, ...]:
    """Floor heights from floors.txt: one float per non-empty line."""
    if not path.is_file():
        raise SceneError(path, "floors.txt not found (one floor height in metres per line)")
    heights = []
    for lineno, line in enumerate(path.read_text().splitlines(), 1):
        if not line.strip():
            continue
        try:
            h = float(line.split()[0])
        except ValueError:
            raise SceneError(path, f"line {lineno}: not a number: {line.strip()!r}") from None
        if not math.isfinite(h):
            raise SceneError(path, f"line {lineno}: floor height is not finite")
        heights.append(h)
    if not heights:
        raise SceneError(path, "no floor heights")
    return tuple(heights)


def read_trav_map(path: Path) -> np.ndarray:
    """A traversability PNG -> (N, N) bool, True = free (pixel value 255)."""
    if not path.is_file():
        raise SceneError(path, "traversability map not found")
    try:
        with Image.open(path) as img:
            img.load()
            mode, size = img.mode, img.size
            arr = np.asarray(img)
    except Exception as exc:
        raise SceneError(path, f"cannot read image ({type(exc).__name__})") from None
    if mode != "L":
        raise SceneError(path, f"traversability map must be 8-bit greyscale (mode 'L'), got mode {mode!r}")
    if size[0] != size[1]:
        raise SceneError(path, f"traversability map must be square, got {size[0]} x {size[1]}")
    free = arr == 255
    if not free.any():
        raise SceneError(path, "traversability map has no free pixel (255)")
    return free


def _referenced_files(mesh_path: Path) -> list[Path]:
    """Material libraries of an OBJ and the texture images they reference; :class:`SceneError` if one
    is missing or a texture is not a readable image (rather than rendering it untextured)."""
    if mesh_path.suffix.lower() != ".obj":
        return []
    files: list[Path] = []
    with open(mesh_path, "rb") as f:
        for raw in f:
            if raw.startswith(b"mtllib"):
                parts = raw.split(None, 1)
                if len(parts) < 2:
                    raise SceneError(mesh_path, "'mtllib' without a file name")
                files.append(mesh_path.parent / parts[1].decode(errors="replace").strip())
    textures: dict[Path, Path] = {}
    for mtl in files:
        if not mtl.is_file():
            raise SceneError(mtl, f"material library referenced by {mesh_path.name} not found")
        for line in mtl.read_text(errors="replace").splitlines():
            m = re.match(r"\s*map_\w+\s+(?:-\S+\s+\S+\s+)*(.+)$", line)
            if m:
                textures.setdefault(mtl.parent / m.group(1).strip(), mtl)
    for tex, mtl in textures.items():
        if not tex.is_file():
            raise SceneError(tex, f"texture referenced by {mtl.name} not found")
        try:
            with Image.open(tex) as img:
                img.verify()
        except Exception as exc:
            raise SceneError(tex, f"texture is not a readable image ({type(exc).__name__})") from None
    return list(dict.fromkeys([*files, *textures]))


def content_hash(folder: Path, mesh_path: Path, n_floors: int) -> str:
    """sha256 over the mesh, its materials and textures, floors.txt and the traversability maps."""
    h = hashlib.sha256()
    files = [mesh_path, *_referenced_files(mesh_path), folder / FLOORS_NAME]
    files += [folder / f"floor_trav_{i}.png" for i in range(n_floors)]
    for p in files:
        h.update(p.relative_to(folder).as_posix().encode() + b"\0")
        with open(p, "rb") as f:
            for chunk in iter(lambda: f.read(1 << 20), b""):
                h.update(chunk)
    return h.hexdigest()[:16]
