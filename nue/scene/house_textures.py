"""Procedural textures for generated houses: floors, walls, furniture and framed pictures.

Every function returns an ``(H, W, 3)`` uint8 RGB array. Floor and furniture textures tile
seamlessly (periodic noise and layouts) because the mesh repeats them in world units; wall
textures tile horizontally and cover the wall height exactly once (so a dado rail or wainscot sits
at a fixed height). Pictures are single framed images, distinct per draw.
"""

from __future__ import annotations

import colorsys

import numpy as np
from scipy import ndimage

FLOOR_PATTERNS = ("planks", "tiles", "checker", "carpet", "parquet")
WALL_PATTERNS = ("plaster", "stripes", "wallpaper", "bricks", "wainscot")
PICTURE_STYLES = ("landscape", "shapes", "mondrian", "rings", "bands", "blobs")


def hsv(h: float, s: float, v: float) -> np.ndarray:
    """RGB in [0, 1] (3,) from hue (wraps), saturation and value."""
    return np.array(colorsys.hsv_to_rgb(h % 1.0, float(np.clip(s, 0, 1)), float(np.clip(v, 0, 1))))


def noise(rng, shape: tuple[int, int], sigma) -> np.ndarray:
    """Periodic smooth noise (H, W), zero mean, unit standard deviation."""
    n = ndimage.gaussian_filter(rng.standard_normal(shape), sigma, mode="wrap")
    return (n - n.mean()) / (n.std() + 1e-9)


def to_uint8(img: np.ndarray) -> np.ndarray:
    """Float RGB in [0, 1] (H, W, 3) -> uint8 (H, W, 3)."""
    return (np.clip(img, 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)


def _shade(color: np.ndarray, amount: np.ndarray) -> np.ndarray:
    """Colour (3,) modulated by a per-pixel brightness factor (H, W) -> (H, W, 3)."""
    return color[None, None, :] * (1.0 + amount[..., None])


def wood(rng, color: np.ndarray, n: int = 128, plank: int = 32, length: int = 128,
         vertical: bool = False) -> np.ndarray:
    """Planks of width ``plank`` px and length ``length`` px with grain and seams, float (n, n, 3)."""
    yy, xx = np.mgrid[0:n, 0:n]
    if vertical:
        yy, xx = xx, yy
    row = yy // plank
    offsets = rng.integers(0, length, size=n // plank + 1)
    idx = row * 1000 + (xx + offsets[row]) // length
    uniq, inv = np.unique(idx, return_inverse=True)
    jitter = rng.normal(0.0, 0.08, size=len(uniq))[inv.reshape(idx.shape)]
    grain = noise(rng, (n, n), (0.6, 6.0) if not vertical else (6.0, 0.6))
    img = _shade(color, jitter + 0.07 * grain)
    seam = (yy % plank == 0) | ((xx + offsets[row]) % length == 0)
    img[seam] *= 0.6
    return img


def floor_texture(rng, pattern: str, color: np.ndarray, n: int = 128) -> np.ndarray:
    """Floor texture covering 1 m x 1 m, uint8 (n, n, 3)."""
    yy, xx = np.mgrid[0:n, 0:n]
    fine = noise(rng, (n, n), 0.8)
    if pattern == "planks":
        img = wood(rng, color, n, plank=n // 4, length=n)
    elif pattern == "parquet":
        block = n // 2
        a = wood(rng, color, n, plank=block // 4, length=block)
        b = wood(rng, color * 0.92, n, plank=block // 4, length=block, vertical=True)
        img = np.where((((yy // block) + (xx // block)) % 2 == 0)[..., None], a, b)
    elif pattern == "tiles":
        tile = n // 2
        jit = rng.normal(0.0, 0.05, size=(2, 2))[yy // tile, xx // tile]
        img = _shade(color, jit + 0.04 * fine)
        img[(yy % tile < 2) | (xx % tile < 2)] = 0.85
    elif pattern == "checker":
        sq = n // 4
        other = np.clip(1.0 - color * 0.8, 0.0, 1.0)
        img = np.where((((yy // sq) + (xx // sq)) % 2 == 0)[..., None], color, other)
        img = img * (1.0 + 0.03 * fine[..., None])
    elif pattern == "carpet":
        img = _shade(color, 0.12 * fine + 0.1 * noise(rng, (n, n), 10.0))
    else:
        raise ValueError(pattern)
    return to_uint8(img)


def wall_texture(rng, pattern: str, color: np.ndarray, wall_height: float, n: int = 128) -> np.ndarray:
    """Wall texture, 1 m wide x the wall height tall (row 0 at the top), uint8 (2n, n, 3)."""
    h = 2 * n
    yy, xx = np.mgrid[0:h, 0:n]
    z = (h - 0.5 - yy) / h * wall_height  # height of each row above the floor, metres
    img = _shade(color, 0.02 * noise(rng, (h, n), 0.7) + 0.03 * noise(rng, (h, n), 12.0))
    accent = hsv(colorsys.rgb_to_hsv(*color)[0] + rng.uniform(0.3, 0.7), 0.35, 0.55)
    if pattern == "stripes":
        period = n // int(rng.choice([2, 4, 8]))
        img[(xx % period) < period // 2] *= 0.85
    elif pattern == "wallpaper":
        cell = n // 4
        cy, cx = (yy % cell) - cell / 2, ((xx + (yy // cell % 2) * cell // 2) % cell) - cell / 2
        img[(np.abs(cx) + np.abs(cy)) < cell * 0.22] = accent
    elif pattern == "bricks":
        bh, bw = 12, n // 4
        row = yy // bh
        jit = rng.normal(0.0, 0.06, size=(h // bh + 1, 8))[row, ((xx + (row % 2) * bw // 2) // bw) % 8]
        img = _shade(color, jit + 0.05 * noise(rng, (h, n), 0.8))
        img[(yy % bh < 2) | (((xx + (row % 2) * bw // 2) % bw) < 2)] = 0.8
    elif pattern == "wainscot":
        top = rng.uniform(0.8, 1.1)
        low = z < top
        img[low] = _shade(accent, 0.03 * noise(rng, (h, n), 0.7))[low]
        img[low & ((xx % (n // 2)) < 2)] *= 0.75
        img[np.abs(z - top) < 0.025] = 0.92
    elif pattern != "plaster":
        raise ValueError(pattern)
    img[z < 0.08] = 0.9  # skirting board
    return to_uint8(img)


def plain(rng, color: np.ndarray, n: int = 64, amount: float = 0.03, sigma: float = 0.8) -> np.ndarray:
    """Nearly uniform texture with a little noise, uint8 (n, n, 3)."""
    return to_uint8(_shade(color, amount * noise(rng, (n, n), sigma)))


def fabric(rng, color: np.ndarray, n: int = 64) -> np.ndarray:
    """Woven fabric, uint8 (n, n, 3)."""
    yy, xx = np.mgrid[0:n, 0:n]
    weave = ((xx // 2 + yy // 2) % 2) * 0.06 - 0.03
    return to_uint8(_shade(color, weave + 0.05 * noise(rng, (n, n), 0.6)))


def foliage(rng, n: int = 64) -> np.ndarray:
    """Leafy green blotches, uint8 (n, n, 3)."""
    leaves = noise(rng, (n, n), 2.0)
    img = np.where((leaves > 0)[..., None], hsv(0.3, 0.7, 0.55), hsv(0.27, 0.8, 0.3))
    return to_uint8(img * (1.0 + 0.1 * noise(rng, (n, n), 0.7))[..., None])


def books(rng, n: int = 128) -> np.ndarray:
    """Front of a bookshelf: shelves with rows of coloured spines, uint8 (2n, n, 3); fitted to the face."""
    h = 2 * n
    img = np.empty((h, n, 3))
    img[:] = hsv(0.08, 0.5, 0.3)
    shelves = 5
    pitch = h // shelves
    for s in range(shelves):
        top, x = s * pitch + 5, 4
        while x < n - 4:
            w = int(rng.integers(3, 8))
            book_h = int(rng.integers(pitch * 5 // 10, pitch - 8))
            spine = hsv(rng.random(), rng.uniform(0.3, 0.8), rng.uniform(0.3, 0.85))
            img[top + pitch - 5 - book_h: top + pitch - 5, x:min(x + w, n - 4)] = spine
            x += w + int(rng.integers(0, 2))
        img[top + pitch - 5: top + pitch, :] = hsv(0.08, 0.45, 0.5)
    img[:, :4] = img[:, -4:] = hsv(0.08, 0.45, 0.5)
    return to_uint8(img)


def panel_front(rng, color: np.ndarray, rows: int, cols: int, n: int = 128) -> np.ndarray:
    """Cabinet front with ``rows`` x ``cols`` panels and handles, uint8 (n, n, 3); fitted to the face."""
    img = _shade(color, 0.03 * noise(rng, (n, n), 0.8))
    ph, pw = n // rows, n // cols
    yy, xx = np.mgrid[0:n, 0:n]
    img[((yy % ph) < 2) | ((xx % pw) < 2) | (yy >= n - 2) | (xx >= n - 2)] *= 0.55
    hy, hx = (yy % ph) - ph * (0.5 if cols > 1 else 0.2), (xx % pw) - pw * (0.85 if cols > 1 else 0.5)
    handle = (np.abs(hy) < (ph * 0.18 if cols > 1 else 2)) & (np.abs(hx) < (2 if cols > 1 else pw * 0.15))
    img[handle] = 0.75
    return to_uint8(img)


def _palette(rng, k: int) -> np.ndarray:
    base = rng.random()
    return np.stack([hsv(base + rng.uniform(-0.15, 0.15) + i * rng.choice([0.1, 0.33, 0.5]),
                         rng.uniform(0.4, 0.95), rng.uniform(0.35, 0.95)) for i in range(k)])


def picture(rng, style: str, n: int = 128) -> np.ndarray:
    """A framed procedural picture in ``style`` (one of PICTURE_STYLES), uint8 (n, n, 3)."""
    pal = _palette(rng, 6)
    yy, xx = (np.mgrid[0:n, 0:n] + 0.5) / n
    img = np.empty((n, n, 3))
    img[:] = pal[0]
    if style == "landscape":
        t = yy[..., None]
        img = pal[0] * (1 - t) + hsv(rng.uniform(0.5, 0.65), 0.3, 0.95) * t
        sx, sy, sr = rng.uniform(0.2, 0.8), rng.uniform(0.15, 0.4), rng.uniform(0.05, 0.12)
        img[(xx - sx) ** 2 + (yy - sy) ** 2 < sr ** 2] = hsv(rng.uniform(0.0, 0.15), 0.8, 1.0)
        for layer in range(3):
            base = 0.45 + 0.15 * layer
            ridge = base + sum(rng.uniform(0.02, 0.08) * np.sin(2 * np.pi * (f * xx + rng.random()))
                               for f in (1, 2, 5))
            img[yy > ridge] = pal[1 + layer] * (0.6 + 0.2 * layer)
    elif style == "shapes":
        for _ in range(int(rng.integers(5, 13))):
            c = pal[int(rng.integers(1, 6))]
            cx, cy, r = rng.random(), rng.random(), rng.uniform(0.06, 0.25)
            kind = int(rng.integers(0, 3))
            if kind == 0:
                mask = (xx - cx) ** 2 + (yy - cy) ** 2 < r ** 2
            elif kind == 1:
                mask = (np.abs(xx - cx) < r) & (np.abs(yy - cy) < r * rng.uniform(0.3, 1.0))
            else:
                mask = (yy - cy < r) & (np.abs(xx - cx) < (yy - cy + r) * 0.6) & (yy > cy - r)
            img[mask] = c
    elif style == "mondrian":
        img[:] = 0.95
        rects = [(0.0, 0.0, 1.0, 1.0)]
        for _ in range(int(rng.integers(4, 9))):
            i = int(rng.integers(0, len(rects)))
            x0, y0, x1, y1 = rects.pop(i)
            if (x1 - x0) > (y1 - y0):
                m = rng.uniform(x0 + 0.3 * (x1 - x0), x1 - 0.3 * (x1 - x0))
                rects += [(x0, y0, m, y1), (m, y0, x1, y1)]
            else:
                m = rng.uniform(y0 + 0.3 * (y1 - y0), y1 - 0.3 * (y1 - y0))
                rects += [(x0, y0, x1, m), (x0, m, x1, y1)]
        for x0, y0, x1, y1 in rects:
            inside = (xx >= x0) & (xx < x1) & (yy >= y0) & (yy < y1)
            if rng.random() < 0.5:
                img[inside] = pal[int(rng.integers(1, 6))]
            edge = inside & ((xx - x0 < 0.02) | (yy - y0 < 0.02))
            img[edge] = 0.08
    elif style == "rings":
        cx, cy = rng.uniform(0.3, 0.7, size=2)
        r = np.sqrt((xx - cx) ** 2 + (yy - cy) ** 2)
        img = pal[(r / rng.uniform(0.05, 0.12)).astype(int) % 6]
    elif style == "bands":
        ang = rng.uniform(0, np.pi)
        s = xx * np.cos(ang) + yy * np.sin(ang)
        img = pal[(s / rng.uniform(0.08, 0.2) + rng.random()).astype(int) % 6]
    elif style == "blobs":
        img = img * 0.6
        for i in range(1, 6):
            cx, cy, w = rng.random(), rng.random(), rng.uniform(0.08, 0.25)
            g = np.exp(-((xx - cx) ** 2 + (yy - cy) ** 2) / (2 * w * w))[..., None]
            img = img * (1 - g) + pal[i] * g
    else:
        raise ValueError(style)
    frame = max(4, n // 20)
    frame_colour = hsv(rng.uniform(0.05, 0.12), 0.6, rng.choice([0.15, 0.45, 0.8]))
    img[:frame], img[-frame:], img[:, :frame], img[:, -frame:] = (frame_colour,) * 4
    return to_uint8(img)
