"""Textured triangle mesh of a generated house and its hand-written OBJ / MTL / PNG files.

Geometry is in integer cm (written in metres, z up). Every surface is an axis-aligned quad
(two triangles) facing the side it is seen from: floors up, ceiling down, wall faces into their
room, furniture outwards, pictures into the room (1 cm proud of the wall). Texture coordinates
are in world units divided by the material's repeat size (GL_REPEAT tiles them), except for
"fitted" materials (pictures, shelf and cabinet fronts) whose image spans each face once.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from PIL import Image

from nue.scene.house_furnish import Item, Picture, free_intervals
from nue.scene.house_layout import Plan


@dataclass
class Material:
    """A texture image and how it is mapped."""

    image: np.ndarray
    """RGB texture, uint8 (H, W, 3)."""
    scale: tuple[float, float] | None
    """Metres per texture repeat along (u, v); None = the image is fitted to each face once."""


class MeshBuilder:
    """Collects quads per material; vertices in cm."""

    def __init__(self, materials: dict[str, Material]):
        self.materials = materials
        self.quads: dict[str, list[tuple[list[tuple[int, int, int]], list[tuple[float, float]]]]] = {}

    def face(self, mat: str, axis: int, sign: int, lo: tuple[int, int, int], hi: tuple[int, int, int]) -> None:
        """Quad of the box ``lo..hi`` (flat along ``axis``) whose normal points to ``sign`` * axis."""
        i, j = (axis + 1) % 3, (axis + 2) % 3

        def pt(a: int, b: int) -> tuple[int, int, int]:
            p = [0, 0, 0]
            p[axis], p[i], p[j] = lo[axis], a, b
            return (p[0], p[1], p[2])

        corners = [(lo[i], lo[j]), (hi[i], lo[j]), (hi[i], hi[j]), (lo[i], hi[j])]
        if sign < 0:
            corners = [corners[0], corners[3], corners[2], corners[1]]
        pts = [pt(a, b) for a, b in corners]
        if lo[i] == hi[i] or lo[j] == hi[j]:
            return
        self.quads.setdefault(mat, []).append((pts, self._uvs(mat, axis, sign, pts)))

    def _uvs(self, mat: str, axis: int, sign: int, pts) -> list[tuple[float, float]]:
        p = np.asarray(pts, dtype=np.float64) / 100.0
        if axis == 2:
            u, v = p[:, 0], p[:, 1]
        else:  # u runs to the right of a viewer facing the quad, v up
            u, v = (sign * p[:, 1], p[:, 2]) if axis == 0 else (-sign * p[:, 0], p[:, 2])
        scale = self.materials[mat].scale
        if scale is None:
            u = (u - u.min()) / max(np.ptp(u), 1e-9)
            v = (v - v.min()) / max(np.ptp(v), 1e-9)
        else:
            u, v = u / scale[0], v / scale[1]
        return [(float(a), float(b)) for a, b in zip(u, v)]

    def box(self, rect, z0: int, z1: int, mat: str, front: str | None = None, front_dir=None) -> None:
        """Five faces of a box (no bottom); the face towards ``front_dir`` = (axis, sign) gets ``front``."""
        x0, y0, x1, y1 = rect
        lo, hi = (x0, y0, z0), (x1, y1, z1)
        self.face(mat, 2, 1, (x0, y0, z1), hi)
        for axis in (0, 1):
            for sign in (-1, 1):
                c = lo[axis] if sign < 0 else hi[axis]
                a, b = list(lo), list(hi)
                a[axis] = b[axis] = c
                m = front if (front is not None and front_dir == (axis, sign)) else mat
                self.face(m, axis, sign, tuple(a), tuple(b))

    @property
    def triangle_count(self) -> int:
        return 2 * sum(len(q) for q in self.quads.values())


def build_mesh(plan: Plan, items: list[Item], pictures: list[Picture], materials: dict[str, Material],
               wall_height: int, door_height: int) -> MeshBuilder:
    """All house surfaces; room i uses materials ``room<i>_wall`` / ``room<i>_floor``."""
    mb = MeshBuilder(materials)
    H, Dh = wall_height, door_height
    for ri, room in enumerate(plan.rooms):
        interior = room.interior
        x0, y0, x1, y1 = interior
        mb.face(f"room{ri}_floor", 2, 1, (x0, y0, 0), (x1, y1, 0))
        for axis in (0, 1):
            o = 1 - axis
            for sign in (1, -1):
                plane = interior[axis] if sign > 0 else interior[axis + 2]
                spans = [d.span for d in plan.doors if ri in d.rooms and d.normal == axis and
                         (d.rect[axis + 2] == plane or d.rect[axis] == plane)]
                pieces = [(a, b, 0) for a, b in free_intervals(interior[o], interior[o + 2], spans)]
                pieces += [(a, b, Dh) for a, b in spans]
                for a, b, z0 in pieces:
                    lo, hi = [0, 0, z0], [0, 0, H]
                    lo[axis] = hi[axis] = plane
                    lo[o], hi[o] = a, b
                    mb.face(f"room{ri}_wall", axis, sign, tuple(lo), tuple(hi))
    for door in plan.doors:
        n, o = door.normal, 1 - door.normal
        x0, y0, x1, y1 = door.rect
        mb.face(f"room{door.rooms[0]}_floor", 2, 1, (x0, y0, 0), (x1, y1, 0))
        mb.face("trim", 2, -1, (x0, y0, Dh), (x1, y1, Dh))
        for sign, c in ((1, door.rect[o]), (-1, door.rect[o + 2])):
            lo, hi = [0, 0, 0], [0, 0, Dh]
            lo[o] = hi[o] = c
            lo[n], hi[n] = door.rect[n], door.rect[n + 2]
            mb.face("trim", o, sign, tuple(lo), tuple(hi))
    fx0, fy0, fx1, fy1 = plan.footprint
    mb.face("ceiling", 2, -1, (fx0, fy0, H), (fx1, fy1, H))
    for item in items:
        for rect, z0, z1, mat, front in item.boxes:
            mb.box(rect, z0, z1, mat, front, item.back)
    for pic in pictures:
        o = 1 - pic.axis
        lo, hi = [0, 0, pic.z[0]], [0, 0, pic.z[1]]
        lo[pic.axis] = hi[pic.axis] = pic.plane + pic.sign
        lo[o], hi[o] = pic.span
        mb.face(pic.material, pic.axis, pic.sign, tuple(lo), tuple(hi))
    return mb


def write_obj(mb: MeshBuilder, folder: Path, header: str, mesh_name: str = "mesh_z_up",
              tex_dir: str = "textures") -> list[str]:
    """Write ``<mesh_name>.obj`` / ``.mtl`` and one PNG per used material; returns the material names."""
    verts: dict[tuple[int, int, int], int] = {}
    uvs: dict[tuple[str, str], int] = {}
    body: list[str] = []
    names = [m for m in mb.quads]
    for mat in names:
        body.append(f"usemtl {mat}")
        for pts, tex in mb.quads[mat]:
            vi = [verts.setdefault(p, len(verts) + 1) for p in pts]
            ti = [uvs.setdefault((f"{u:.4f}", f"{v:.4f}"), len(uvs) + 1) for u, v in tex]
            for a, b, c in ((0, 1, 2), (0, 2, 3)):
                body.append(f"f {vi[a]}/{ti[a]} {vi[b]}/{ti[b]} {vi[c]}/{ti[c]}")
    lines = [f"# {header}", f"mtllib {mesh_name}.mtl"]
    lines += [f"v {x / 100:.2f} {y / 100:.2f} {z / 100:.2f}" for x, y, z in verts]
    lines += [f"vt {u} {v}" for u, v in uvs]
    (folder / f"{mesh_name}.obj").write_text("\n".join(lines + body) + "\n")
    (folder / tex_dir).mkdir(exist_ok=True)
    for stale in sorted((folder / tex_dir).glob("*.png")):  # left over from an earlier house here
        if stale.stem not in mb.quads:
            stale.unlink()
    mtl = [f"# {header}"]
    for mat in names:
        Image.fromarray(mb.materials[mat].image, "RGB").save(folder / tex_dir / f"{mat}.png", format="PNG")
        mtl += [f"newmtl {mat}", "Ka 1.000 1.000 1.000", "Kd 1.000 1.000 1.000", "Ks 0.000 0.000 0.000",
                "d 1.000", "illum 1", f"map_Kd {tex_dir}/{mat}.png", ""]
    (folder / f"{mesh_name}.mtl").write_text("\n".join(mtl))
    return names
