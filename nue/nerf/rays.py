"""Rays from the simulator's camera model (``nue.sim.camera``) and depth-guided sample placement.

Every ray here comes from :func:`nue.sim.camera.world_from_camera` and
:func:`nue.sim.camera.pixel_directions`, the same functions the renderer builds its GL matrices from,
so a ray's point at the rendered depth lands on the mesh. Rays are expressed in the *episode frame*:
metres, origin at the camera's start position, x along the start heading, z up. The field sees
positions divided by a fixed radius (:class:`EpisodeFrame`), never by scene bounds.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np
import torch

from nue.errors import NueError
from nue.sim.camera import pixel_directions, world_from_camera
from nue.sim.task import CameraConfig


class MemoryInputError(NueError):
    """Bad input to the NeRF memory: NaN pose, wrong image shape, no valid depth, empty replay."""


@dataclass(frozen=True)
class SamplerConfig:
    """Depth-guided placement of samples along a ray around the observed surface."""

    band: float = 1.0
    """Half-width of the band around the observed surface, metres along the ray [authors: 1.0]."""
    concentration: float = 1.0
    """Bin edges at ``r + band * sign(s) |s|^p`` for s uniform in [-1, 1]; p = 1 is uniform, p > 1
    packs samples near the surface."""
    free_samples: int = 0
    """Extra samples spread uniformly over the free space in front of the band (near .. r - band)."""
    near: float = 0.05
    """No sample closer to the camera than this, metres."""
    no_depth_range: float = 5.0
    """A ray with invalid depth (0, NaN, inf) is sampled uniformly over [near, no_depth_range] when
    rendered; such rays are never used for training."""


@dataclass
class RaySamples:
    """Sample positions along rays: ``t (R, N)`` metres along unit directions, ``deltas (R, N)`` bin widths."""

    t: torch.Tensor
    deltas: torch.Tensor


@dataclass
class RayBundle:
    """Rays in the episode frame: ``origins (R, 3)`` and unit ``directions (R, 3)`` in metres, and the
    observed surface distance along each ray ``ranges (R,)`` (z-depth / cos theta; NaN = no valid depth)."""

    origins: torch.Tensor
    directions: torch.Tensor
    ranges: torch.Tensor


@dataclass(frozen=True)
class EpisodeFrame:
    """The episode's coordinate frame: the camera's start position and heading, and the radius that
    maps metres to the field's input range (``x_field = x_episode / radius``)."""

    origin: tuple[float, float, float]
    yaw: float
    radius: float

    @classmethod
    def from_pose(cls, pose, camera: CameraConfig, floor_z: float = 0.0, radius: float = 12.0) -> "EpisodeFrame":
        pose = check_pose(pose)
        m = world_from_camera(pose, camera, floor_z)
        return cls(origin=tuple(float(v) for v in m[:3, 3]), yaw=float(pose[2]), radius=float(radius))

    def episode_from_world(self) -> np.ndarray:
        """4x4 rigid transform world -> episode frame (float64)."""
        c, s = math.cos(self.yaw), math.sin(self.yaw)
        r = np.array([[c, s, 0.0], [-s, c, 0.0], [0.0, 0.0, 1.0]])
        m = np.eye(4)
        m[:3, :3] = r
        m[:3, 3] = -r @ np.asarray(self.origin)
        return m


def check_pose(pose) -> np.ndarray:
    """A robot pose ``(x, y, yaw)`` as float64 (3,); raises :class:`MemoryInputError` if not finite."""
    p = np.asarray(pose.detach().cpu() if isinstance(pose, torch.Tensor) else pose, dtype=np.float64).reshape(-1)
    if p.shape[0] < 3:
        raise MemoryInputError("pose", f"expected (x, y, yaw), got shape {tuple(p.shape)}")
    if not np.all(np.isfinite(p[:3])):
        raise MemoryInputError("pose", f"pose must be finite, got {p[:3].tolist()}")
    return p[:3]


def map_pixels(camera: CameraConfig, height: int, width: int) -> tuple[np.ndarray, np.ndarray]:
    """Full-resolution pixels read for an (height, width) map: the pixel nearest each map-pixel centre.

    Returns ``(rows (height,), cols (width,))`` int64, ``row_i = floor((i + 0.5) * H / height)``; for a
    map at half resolution that is every other pixel (rows 1, 3, 5, ...), as the authors' 90 x 120 maps.
    """
    if not (0 < height <= camera.height and 0 < width <= camera.width):
        raise MemoryInputError("map size", f"{height} x {width} must lie within the camera's {camera.height} x {camera.width}")
    rows = np.floor((np.arange(height) + 0.5) * camera.height / height).astype(np.int64)
    cols = np.floor((np.arange(width) + 0.5) * camera.width / width).astype(np.int64)
    return rows, cols


class PixelRays:
    """Per-pixel ray directions of one camera, cached on a device; turns (pose, pixels) into rays.

    ``dirs``: (H * W, 3) unit directions in the camera (OpenCV) frame; ``range_per_z``: (H * W,)
    ``1 / cos theta``, so the surface at z-depth ``z`` lies at ``t = z * range_per_z`` along the ray.
    """

    def __init__(self, camera: CameraConfig, device: torch.device | str = "cpu"):
        self.camera = camera
        d = pixel_directions(camera).reshape(-1, 3)
        norm = np.linalg.norm(d, axis=-1)
        self.dirs = torch.as_tensor(d / norm[:, None], dtype=torch.float32, device=device)
        self.range_per_z = torch.as_tensor(norm, dtype=torch.float32, device=device)
        self.device = torch.device(device)

    def episode_from_camera(self, pose, frame: EpisodeFrame, floor_z: float = 0.0) -> torch.Tensor:
        """4x4 camera -> episode transform for a robot pose, float32 on the device (computed in float64)."""
        m = frame.episode_from_world() @ world_from_camera(check_pose(pose), self.camera, floor_z)
        return torch.as_tensor(m, dtype=torch.float32, device=self.device)

    def ranges_from_depth(self, depth, pixels: torch.Tensor | None = None) -> torch.Tensor:
        """Surface distance along each pixel's ray, (H * W,) float32 (or ``(R,)`` at flat ``pixels (R,)``
        only); NaN where depth <= 0 or not finite."""
        z = torch.as_tensor(np.asarray(depth, dtype=np.float32) if not isinstance(depth, torch.Tensor) else depth)
        z = z.to(self.device, torch.float32).reshape(-1)
        if z.numel() != self.dirs.shape[0]:
            raise MemoryInputError("depth", f"expected {self.camera.height} x {self.camera.width} pixels, got {z.numel()}")
        range_per_z = self.range_per_z
        if pixels is not None:
            z, range_per_z = z[pixels], range_per_z[pixels]
        r = z * range_per_z
        return torch.where(torch.isfinite(r) & (z > 0), r, torch.full_like(r, float("nan")))

    def bundle(self, episode_from_camera: torch.Tensor, pixels: torch.Tensor, ranges: torch.Tensor,
               directions: torch.Tensor | None = None) -> RayBundle:
        """Rays through flat pixel indices ``pixels (R,)`` of one frame (transform (4, 4)) or of one frame
        per ray (transforms (R, 4, 4)); ``ranges (R,)`` is passed through. ``directions``: ``dirs[pixels]``
        if the caller keeps them."""
        d = self.dirs[pixels] if directions is None else directions
        if episode_from_camera.dim() == 2:
            rot, org = episode_from_camera[:3, :3], episode_from_camera[:3, 3]
            return RayBundle(org.expand(d.shape[0], 3), d @ rot.T, ranges)
        rot, org = episode_from_camera[:, :3, :3], episode_from_camera[:, :3, 3]
        return RayBundle(org, torch.einsum("rij,rj->ri", rot, d), ranges)


def depth_guided_samples(
    ranges: torch.Tensor,
    n_samples: int,
    config: SamplerConfig,
    generator: torch.Generator | None = None,
    jitter: torch.Tensor | None = None,
) -> RaySamples:
    """Place ``n_samples`` per ray in ``[r - band, r + band]`` around the observed surface distance r.

    Bin edges are ``r + band * sign(s) |s|^p`` for ``s`` evenly spaced in [-1, 1] (``p`` =
    ``concentration``), clipped to ``>= near``; with ``free_samples = F`` another F bins cover
    ``[near, r - band]``. Rays with NaN range get ``n_samples + F`` bins over ``[near, no_depth_range]``.
    Each sample sits at its bin's centre, or uniformly inside its bin when a ``generator`` is given
    (stratified sampling, for training); ``jitter (R, n_samples + F)`` in [0, 1) gives those positions
    directly (draws made earlier, e.g. with the same generator). ``deltas`` are the bin widths.

    Shapes: ``ranges (R,)`` -> ``t, deltas (R, n_samples + F)``.
    Example: r = 2, band = 1, n = 2, p = 1, no jitter -> edges [1, 2, 3], t = [1.5, 2.5], deltas = [1, 1].
    """
    dev = ranges.device
    valid = torch.isfinite(ranges)
    r = torch.where(valid, ranges, torch.zeros_like(ranges))
    band_s, fallback = _bin_offsets(n_samples, config, dev)
    edges = r[:, None] + band_s  # (R, n + 1)
    if config.free_samples > 0:
        lo = torch.clamp(r - config.band, min=config.near)
        u = torch.linspace(0.0, 1.0, config.free_samples + 1, device=dev)[:-1]
        free = config.near + (lo - config.near)[:, None] * u[None, :]
        edges = torch.cat([free, edges], dim=1)
    edges = torch.where(valid[:, None], edges, fallback)
    edges = torch.clamp(edges, min=config.near)
    lower, upper = edges[:, :-1], edges[:, 1:]
    if jitter is not None:
        u = jitter
    elif generator is None:
        u = torch.full_like(lower, 0.5)
    else:
        u = torch.rand(lower.shape, generator=generator, device="cpu").to(dev)
    t = lower + (upper - lower) * u
    return RaySamples(t=t, deltas=upper - lower)


@functools.lru_cache(maxsize=32)
def _bin_offsets(n_samples: int, config: SamplerConfig, device: torch.device) -> tuple[torch.Tensor, torch.Tensor]:
    """Constants of :func:`depth_guided_samples` (kept; never written): the band's bin edges relative to the
    surface ``band * sign(s) |s|^p`` (1, n + 1) and the edges of a ray without depth (1, n + F + 1)."""
    with torch.inference_mode(False):  # ordinary tensors, also when first asked for inside inference mode
        s = torch.linspace(-1.0, 1.0, n_samples + 1, device=device)
        s = torch.sign(s) * s.abs() ** config.concentration
        fallback = torch.linspace(config.near, config.no_depth_range, n_samples + config.free_samples + 1, device=device)
        return config.band * s[None, :], fallback[None, :]
