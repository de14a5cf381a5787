"""What the 3-D viewer shows: one episode logged to a Rerun recording, step by step.

Entities (world z up, metres; timeline ``step``):
``world/house`` the mesh (triangles wholly above the floor + ``cut_height`` left out, so the rooms show
from above), ``world/goal`` the goal position and its success disc, ``world/robot`` the robot (a
0.18 m disc, heading arrow), ``world/camera`` its pinhole with the RGB frame, ``world/trajectory`` the
poses so far in :data:`TRAJECTORY_COLOUR`, ``world/seen`` the floor cells seen so far (those on the house's floor
map, :func:`floor_cells`),
``world/uncertainty`` the memory's rendered ray termination points coloured by log(1 + I_u).
Images: ``frames/depth``, ``goal/photo``, ``memory/i_u``, ``memory/i_cog`` (a fixed random projection of
the 64 channels to RGB), ``memory/rgb``. Scalars: ``metrics/seen_m2`` (seen area by the evaluation's coverage
measure, :func:`nue.sim.seen.seen_floor_cells`, as in a record's ``extra['coverage']``), ``metrics/geodesic_m``.

Why the dots are masked: the coverage measure counts a cell as seen when a depth point within
``CoverageConfig.floor_tolerance`` (5 cm) of the floor lands in it, which the bottom 5 cm of a wall do, and when its
centre projects onto such a pixel at a depth within a tolerance that grows with the distance
(``CoverageConfig.occlusion_rows``), which cells up to ~0.25 m behind a wall's foot seen from a few metres pass.
Drawn as they are, these cells would show as dots on and just outside the walls; the viewer draws only the cells on
the floor map and leaves the measure as it is.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from nue.scene.navgrid import ROBOT_RADIUS, NavGrid
from nue.sim.camera import pixel_directions, world_from_camera
from nue.sim.renderer import mesh_draw_batches
from nue.sim.seen import seen_floor_cells
from nue.sim.task import CameraConfig

TRAJECTORY_COLOUR = (255, 0, 200)
"""RGB of the trajectory line (tests look for it in a screenshot)."""
GOAL_COLOUR = (255, 170, 0)
SEEN_COLOUR = (60, 200, 90)
ROBOT_COLOUR = (40, 120, 255)


@dataclass(frozen=True)
class SceneViewConfig:
    """What the viewer draws and how finely."""

    cut_height: float = 1.8
    """House triangles whose corners are all higher than the floor + this are left out (ceilings), metres."""
    seen_stride: int = 2
    """Seen floor cells are drawn every this many planning cells per axis (5 cm cells -> 10 cm dots)."""
    jpeg_quality: int = 85
    """JPEG quality of the logged RGB frames (keeps a long episode's recording small)."""
    trajectory_radius: float = 0.04
    """Radius of the trajectory line, metres."""
    cog_seed: int = 0
    """Seed of the fixed random projection of I_cog's channels to RGB (the same for every step)."""


def floor_cells(grid: NavGrid) -> np.ndarray:
    """(M, M) bool planning cells that hold at least one traversable pixel of the floor map (``grid.trav``, before
    the erosion by the robot radius): where the viewer draws seen-floor dots (walls, furniture and the outside
    of the house hold none)."""
    m, f = grid.free.shape[0], grid.factor
    padded = np.zeros((m * f, m * f), dtype=bool)
    padded[: grid.n, : grid.n] = grid.trav
    return padded.reshape(m, f, m, f).any(axis=(1, 3))


def house_mesh(scene, floor_z: float, cut_height: float):
    """The scene's triangles as ``(vertices (3K, 3), colours (3K, 3) uint8)`` (one row per triangle corner).

    A textured part is drawn in its texture's mean colour; triangles whose three corners all lie above
    ``floor_z + cut_height`` are dropped. Example: a ceiling at 2.5 m with ``cut_height = 1.8`` is dropped.
    """
    verts, cols = [], []
    for data, image in mesh_draw_batches(scene.load_mesh(), scene.up_axis):
        xyz = data[:, :3].reshape(-1, 3, 3)
        keep = (xyz[:, :, 2] <= floor_z + cut_height).any(axis=1)
        rgb = data[:, 5:8].reshape(-1, 3, 3)
        if image is not None:
            mean = np.asarray(image.convert("RGB"), dtype=np.float32).reshape(-1, 3).mean(axis=0) / 255.0
            rgb = np.broadcast_to(mean, rgb.shape)
        verts.append(xyz[keep].reshape(-1, 3))
        cols.append(rgb[keep].reshape(-1, 3))
    v = np.concatenate(verts) if verts else np.zeros((0, 3), np.float32)
    c = np.concatenate(cols) if cols else np.zeros((0, 3), np.float32)
    return v.astype(np.float32), (np.clip(c, 0, 1) * 255).astype(np.uint8)


def colourise(values: np.ndarray, vmax: float, cmap: str = "viridis") -> np.ndarray:
    """Values in [0, vmax] -> (..., 3) uint8 through a matplotlib colour map (beyond vmax: the top colour)."""
    import matplotlib

    x = np.clip(np.asarray(values, dtype=np.float64) / max(vmax, 1e-12), 0.0, 1.0)
    return (matplotlib.colormaps[cmap](x)[..., :3] * 255).astype(np.uint8)


def cog_projection(channels: int, seed: int = 0) -> np.ndarray:
    """A fixed (channels, 3) orthonormal projection of I_cog's feature channels to three colour channels."""
    q, _ = np.linalg.qr(np.random.default_rng(seed).standard_normal((channels, 3)))
    return q


def cog_image(i_cog: np.ndarray, projection: np.ndarray) -> np.ndarray:
    """I_cog (C, h, w) -> (h, w, 3) uint8: projected to 3 channels, each stretched between its 2nd and
    98th percentile of this frame."""
    p = np.einsum("chw,ck->hwk", i_cog, projection)
    lo, hi = np.percentile(p, 2, axis=(0, 1)), np.percentile(p, 98, axis=(0, 1))
    return (np.clip((p - lo) / np.maximum(hi - lo, 1e-9), 0, 1) * 255).astype(np.uint8)


def blueprint(eye: tuple | None = None, target: tuple | None = None) -> rrb.Blueprint:
    """The page's layout: the house in 3-D on the left (seen from ``eye`` towards ``target``, world metres),
    frames, goal, memory maps and metrics on the right."""
    images = rrb.Grid(
        rrb.Spatial2DView(origin="world/camera", name="RGB"),
        rrb.Spatial2DView(origin="frames/depth", name="depth"),
        rrb.Spatial2DView(origin="goal/photo", name="goal photo"),
        rrb.Spatial2DView(origin="memory/i_u", name="I_u (memory uncertainty)"),
        rrb.Spatial2DView(origin="memory/i_cog", name="I_cog (projected)"),
        rrb.Spatial2DView(origin="memory/rgb", name="memory RGB"),
    )
    right = rrb.Vertical(images, rrb.TimeSeriesView(origin="metrics", name="metrics"), row_shares=[3, 1])
    controls = None
    if eye is not None:
        controls = rrb.EyeControls3D(kind=rrb.Eye3DKind.Orbital, position=eye, look_target=target, eye_up=(0, 0, 1))
    house = rrb.Spatial3DView(origin="world", name="house", eye_controls=controls)
    return rrb.Blueprint(rrb.Horizontal(house, right, column_shares=[3, 2]), collapse_panels=True)


class EpisodeLogger:
    """Logs an episode to a :class:`rerun.RecordingStream`: :meth:`begin` once, then :meth:`step` per step."""

    def __init__(self, rec: rr.RecordingStream, camera: CameraConfig, grid: NavGrid, floor_z: float,
                 config: SceneViewConfig = SceneViewConfig()):
        self.rec, self.camera, self.grid, self.floor_z, self.config = rec, camera, grid, floor_z, config
        self.poses: list[np.ndarray] = []
        self.seen: np.ndarray | None = None
        """(M, M) bool union of the cells seen so far (:func:`nue.sim.seen.seen_floor_cells`)."""
        self.floor = floor_cells(grid)
        self.u_max = 0.0
        self._cog_proj: np.ndarray | None = None
        self._dirs = pixel_directions(camera)

    def begin(self, scene, goal_xy, goal_image: np.ndarray, success_radius: float) -> None:
        """Static content: the house, the goal (position, success disc, photo), the robot's shape."""
        rec, z = self.rec, self.floor_z
        rec.log("world", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
        v, c = house_mesh(scene, z, self.config.cut_height)
        if len(v):  # look at the house from above one side
            lo, hi = v.min(axis=0), v.max(axis=0)
            mid, extent = (lo + hi) / 2, float(max(hi[0] - lo[0], hi[1] - lo[1]))
            rec.send_blueprint(blueprint(eye=(mid[0], mid[1] - 0.6 * extent, z + 1.2 * extent), target=(mid[0], mid[1], z)))
        rec.log("world/house", rr.Mesh3D(vertex_positions=v, vertex_colors=c,
                                         triangle_indices=np.arange(len(v), dtype=np.uint32).reshape(-1, 3)), static=True)
        g = np.array([goal_xy[0], goal_xy[1], z], dtype=np.float32)
        a = np.linspace(0, 2 * np.pi, 65)
        ring = np.stack([g[0] + success_radius * np.cos(a), g[1] + success_radius * np.sin(a), np.full_like(a, z + 0.02)], 1)
        rec.log("world/goal/position", rr.Points3D([g + [0, 0, 0.3]], colors=[GOAL_COLOUR], radii=0.12,
                                                   labels=["goal"]), static=True)
        rec.log("world/goal/success_disc", rr.LineStrips3D([ring], colors=[GOAL_COLOUR], radii=0.02), static=True)
        rec.log("goal/photo", rr.Image(np.asarray(goal_image)), static=True)
        rec.log("world/robot/body", rr.Cylinders3D(lengths=[0.6], radii=[ROBOT_RADIUS], centers=[[0, 0, 0.3]],
                                                   colors=[ROBOT_COLOUR]), static=True)
        rec.log("world/robot/heading", rr.Arrows3D(vectors=[[0.4, 0, 0]], origins=[[0, 0, 0.65]], colors=[ROBOT_COLOUR],
                                                   radii=0.03), static=True)
        cam = self.camera
        rec.log("world/camera", rr.Pinhole(focal_length=[cam.fx, cam.fy], principal_point=[cam.cx, cam.cy],
                                           resolution=[cam.width, cam.height], camera_xyz=rr.ViewCoordinates.RDF,
                                           image_plane_distance=0.4), static=True)

    def step(self, t: int, pose, rgb: np.ndarray, depth: np.ndarray, maps=None, geodesic: float | None = None) -> None:
        """Step ``t``: pose (x, y, yaw), rgb (H, W, 3) uint8, depth (H, W[, 1]) metres, the memory's maps
        (:class:`nue.nerf.online.MemoryMaps` or None) and the geodesic distance to the goal."""
        rec, z = self.rec, self.floor_z
        pose = np.asarray(pose, dtype=np.float64)[:3]
        depth = np.asarray(depth, dtype=np.float32).reshape(self.camera.height, self.camera.width)
        rec.set_time("step", sequence=t)
        self.poses.append(pose)
        rec.log("world/robot", rr.Transform3D(translation=[pose[0], pose[1], z],
                                              rotation=rr.RotationAxisAngle(axis=[0, 0, 1], radians=pose[2])))
        m = world_from_camera(pose, self.camera, z)
        rec.log("world/camera", rr.Transform3D(translation=m[:3, 3], mat3x3=m[:3, :3]))
        rec.log("world/camera/rgb", rr.Image(np.asarray(rgb, dtype=np.uint8)).compress(self.config.jpeg_quality))
        rec.log("frames/depth", rr.DepthImage((np.clip(depth, 0, 65.0) * 1000).astype(np.uint16), meter=1000.0,
                                              colormap="turbo"))
        track = np.array([[p[0], p[1], z + 0.05] for p in self.poses], dtype=np.float32)
        if len(track) > 1:
            rec.log("world/trajectory", rr.LineStrips3D([track], colors=[TRAJECTORY_COLOUR],
                                                        radii=self.config.trajectory_radius))
        self._log_seen(depth, pose)
        if geodesic is not None:
            rec.log("metrics/geodesic_m", rr.Scalars(float(geodesic)))
        if maps is not None:
            self._log_maps(maps, pose, depth)

    def _log_seen(self, depth: np.ndarray, pose: np.ndarray) -> None:
        cells = seen_floor_cells(depth, pose, self.camera, self.grid, self.floor_z)
        self.seen = cells if self.seen is None else (self.seen | cells)
        s = self.config.seen_stride
        rc = np.argwhere((self.seen & self.floor)[::s, ::s]) * s
        xy = self.grid.cell_centre(rc).reshape(-1, 2)
        pts = np.concatenate([xy, np.full((len(xy), 1), self.floor_z + 0.01)], axis=1).astype(np.float32)
        self.rec.log("world/seen", rr.Points3D(pts, colors=[SEEN_COLOUR], radii=0.4 * s * float(self.grid.cell)))
        self.rec.log("metrics/seen_m2", rr.Scalars(float(self.seen.sum()) * float(self.grid.cell) ** 2))

    def _log_maps(self, maps, pose: np.ndarray, depth: np.ndarray) -> None:
        from nue.nerf.rays import map_pixels

        i_u = maps.i_u.detach().cpu().numpy()[0]
        h, w = i_u.shape
        u = np.log1p(np.maximum(i_u, 0.0))
        self.u_max = max(self.u_max, float(u.max()))
        rec = self.rec
        rec.log("memory/i_u", rr.Image(colourise(u, self.u_max)))
        cog = maps.i_cog.detach().cpu().numpy()
        if self._cog_proj is None:
            self._cog_proj = cog_projection(cog.shape[0], self.config.cog_seed)
        rec.log("memory/i_cog", rr.Image(cog_image(cog, self._cog_proj)))
        rec.log("memory/rgb", rr.Image((np.clip(maps.rgb.detach().cpu().numpy().transpose(1, 2, 0), 0, 1) * 255)
                                       .astype(np.uint8)))
        # lift I_u into the house: each map ray ends at the memory's rendered depth where the memory has
        # seen something (transmittance < 0.5), else at the depth the camera measures
        rows, cols = map_pixels(self.camera, h, w)
        rendered = maps.depth.detach().cpu().numpy()[0]
        seen = maps.transmittance.detach().cpu().numpy()[0] < 0.5
        zs = np.where(seen & (rendered > 0), rendered, depth[np.ix_(rows, cols)])
        ok = zs > 0
        m = world_from_camera(pose, self.camera, self.floor_z)
        p_cam = self._dirs[np.ix_(rows, cols)] * zs[..., None]
        pts = (p_cam @ m[:3, :3].T + m[:3, 3])[ok].astype(np.float32)
        rec.log("world/uncertainty", rr.Points3D(pts, colors=colourise(u, self.u_max)[ok], radii=0.02))
