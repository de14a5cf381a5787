"""Navigation grid of one floor: traversable cells eroded by the robot radius, geodesic fields, shortest paths.

Two resolutions: the 1 cm traversability map eroded by the robot radius decides collisions
(``is_free``), and a coarser planning grid (default 5 cm; a cell is free only if every 1 cm pixel in
it is free) carries geodesic distance fields computed with scikit-image's minimum-cost-path
(8-connected; octile path lengths, up to 8.2% longer than the straight line) or, with
``geodesic="fmm"``, with scikit-fmm's second-order fast marching (an optional dependency; within 1%
in open space, +3.3% around a wall tip where octile is +8.3%; tests/test_geodesic_accuracy.py). Unreachable cells have distance ``inf``.

Points off the navigable cells (episodes made with another robot footprint) are *snapped*: within
``snap_tolerance`` of a free planning cell, geodesics and the expert use the nearest free cell's
centre instead (:meth:`NavGrid.snap`).
"""

from __future__ import annotations

from collections import OrderedDict
from dataclasses import dataclass

import numpy as np
from scipy import ndimage
from skimage.graph import MCP_Geometric

from nue.errors import ConfigError
from nue.scene.scene import Scene, trav_pixel_from_world

GEODESIC_METHODS = ("octile", "fmm")
_FMM_SEED_RADIUS = 1.5  # cells: fast marching starts from a circle of this radius around the goal cell's centre
_NEIGHBOURS = np.array([(-1, -1), (-1, 0), (-1, 1), (0, -1), (0, 1), (1, -1), (1, 0), (1, 1)])


ROBOT_RADIUS = 0.18
"""Radius of the robot's disc, metres: the one value the navigation grid and the house generator use."""


@dataclass(frozen=True)
class NavGridConfig:
    """How a traversability map becomes a navigation grid."""

    robot_radius: float = ROBOT_RADIUS
    """Radius of the robot's disc, metres: free space is eroded by it."""
    cell_size: float = 0.05
    """Planning-grid cell size, metres (a multiple of the map's 0.01 m)."""
    cache_size: int = 64
    """Number of geodesic distance fields (one per goal cell) kept in memory."""
    comfort_clearance: float = 0.3
    """Paths for driving (``comfort=True``) pay extra within this clearance from free-space edges, metres."""
    comfort_weight: float = 3.0
    """Extra cost per metre at zero clearance (linear down to 0 at ``comfort_clearance``)."""
    snap_tolerance: float = 0.3
    """A start or goal off the navigable cells but within this distance (metres) of a free planning
    cell's centre is snapped to the nearest one for geodesics and the expert; farther is an error."""
    geodesic: str = "octile"
    """Distance fields: ``octile`` (8-connected shortest paths, the default behind RESULTS.md) or
    ``fmm`` (second-order fast marching with scikit-fmm, closer to the continuous geodesic)."""


class NavGrid:
    """Free space of one floor for a disc robot, with cached geodesic distance fields."""

    def __init__(self, trav: np.ndarray, resolution: float = 0.01, config: NavGridConfig = NavGridConfig()):
        """``trav``: (N, N) bool traversability map (True = free), iGibson convention, ``resolution`` m/pixel."""
        if config.geodesic not in GEODESIC_METHODS:
            raise ConfigError(None, f"unknown geodesic method {config.geodesic!r} (use one of {', '.join(GEODESIC_METHODS)})")
        self.config = config
        self.resolution = resolution
        self.n = trav.shape[0]
        self.trav = np.asarray(trav, dtype=bool)
        """(N, N) bool: the traversability map itself (floor, before the erosion by the robot radius)."""
        # Erode: a pixel is free for the robot's centre if no obstacle pixel lies within the radius.
        clearance = ndimage.distance_transform_edt(trav) * resolution
        self.fine_free: np.ndarray = clearance > config.robot_radius
        """(N, N) bool: where the robot's centre may be (1 cm pixels)."""
        self.factor = max(1, int(round(config.cell_size / resolution)))
        self.cell = self.factor * resolution
        m = -(-self.n // self.factor)
        padded = np.zeros((m * self.factor, m * self.factor), dtype=bool)
        padded[: self.n, : self.n] = self.fine_free
        self.free: np.ndarray = padded.reshape(m, self.factor, m, self.factor).all(axis=(1, 3))
        """(M, M) bool planning grid: cell (r, c) covers fine pixels [r*f, (r+1)*f) x [c*f, (c+1)*f)."""
        self._costs = np.where(self.free, 1.0, np.inf)
        edge = ndimage.distance_transform_edt(self.free) * self.cell
        penalty = config.comfort_weight * np.clip(1.0 - edge / config.comfort_clearance, 0.0, 1.0)
        self._comfort_costs = np.where(self.free, 1.0 + penalty, np.inf)
        self._fields: OrderedDict[tuple, np.ndarray] = OrderedDict()
        self._nearest_free: np.ndarray | None = None  # (2, M, M) nearest free cell of each cell, made on demand
        labels, count = ndimage.label(self.free, structure=np.ones((3, 3)))
        self.component = labels
        """(M, M) int: connected component of each free cell (0 = blocked)."""

    @classmethod
    def from_scene(cls, scene: Scene, floor: int = 0, config: NavGridConfig = NavGridConfig()) -> "NavGrid":
        return cls(scene.trav_maps[floor], scene.resolution, config)

    # -- coordinates ---------------------------------------------------------------------------
    def cell_of(self, xy) -> np.ndarray:
        """World (x, y) (..., 2) -> planning cell (row, col) (..., 2), int."""
        return trav_pixel_from_world(xy, self.n, self.resolution) // self.factor

    def cell_centre(self, rc) -> np.ndarray:
        """Planning cell (row, col) (..., 2) -> world (x, y) (..., 2) of its centre."""
        rc = np.asarray(rc, dtype=np.float64)
        x = (rc[..., 1] + 0.5) * self.cell - self.n / 2 * self.resolution
        y = (rc[..., 0] + 0.5) * self.cell - self.n / 2 * self.resolution
        return np.stack([x, y], axis=-1)

    def is_free(self, xy) -> bool | np.ndarray:
        """Whether the robot's centre may stand at world (x, y) (..., 2); outside the map is not free."""
        rc = trav_pixel_from_world(xy, self.n, self.resolution)
        inside = np.all((rc >= 0) & (rc < self.n), axis=-1)
        rcc = np.clip(rc, 0, self.n - 1)
        ok = inside & self.fine_free[rcc[..., 0], rcc[..., 1]]
        return bool(ok) if np.ndim(ok) == 0 else ok

    def segment_free(self, a, b, step: float = 0.02) -> bool:
        """Whether the straight segment from a to b stays in free space (sampled every ``step`` metres)."""
        a, b = np.asarray(a, dtype=np.float64), np.asarray(b, dtype=np.float64)
        k = max(2, int(np.ceil(np.linalg.norm(b - a) / step)) + 1)
        pts = a + (b - a) * np.linspace(0.0, 1.0, k)[:, None]
        return bool(np.all(self.is_free(pts)))

    # -- geodesics -----------------------------------------------------------------------------
    def distance_field(self, goal_xy, comfort: bool = False) -> np.ndarray:
        """(M, M) geodesic distance in metres from every planning cell to the goal's cell; inf = unreachable.

        ``comfort=True`` gives the cost-to-go of a driving field instead, where cells near free-space
        edges cost more (so paths keep to the middle of corridors); use it for steering, never as a
        distance. Cached per goal cell (LRU). If the goal's own cell is blocked, the field is all inf.
        """
        r, c = (int(v) for v in self.cell_of(goal_xy))
        cell = (r, c)
        key = (*cell, comfort)
        if key in self._fields:
            self._fields.move_to_end(key)
            return self._fields[key]
        field = np.full(self.free.shape, np.inf)
        if self._in_grid(cell) and self.free[cell]:
            if self.config.geodesic == "fmm" and not comfort:
                field = self._fmm_field(cell)
            else:
                costs_map = self._comfort_costs if comfort else self._costs
                costs, _ = MCP_Geometric(costs_map, fully_connected=True).find_costs([cell])
                field = np.where(np.isfinite(costs), costs * self.cell, np.inf)
        self._fields[key] = field
        if len(self._fields) > self.config.cache_size:
            self._fields.popitem(last=False)
        return field

    def _fmm_field(self, cell: tuple[int, int]) -> np.ndarray:
        """(M, M) metres from the centre of free cell ``cell`` by second-order fast marching on the free cells.

        The front starts as the circle of radius rho = 1.5 cells around the cell's centre (level set
        phi = |x - g| - rho, so the first update uses exact distances), then d(x) = rho + FMM(phi)(x);
        inside the circle d is the straight distance. Cells of other components are inf. In an open
        grid the error is within [-0.1%, +0.9%] beyond 1 m (octile: up to +8.2%)."""
        try:
            import skfmm
        except ImportError:
            raise ConfigError(None, "geodesic='fmm' needs scikit-fmm (pip install 'nue[geodesic]')") from None
        rr, cc = np.indices(self.free.shape)
        centre = np.hypot(rr - cell[0], cc - cell[1])
        phi = np.ma.MaskedArray(centre - _FMM_SEED_RADIUS, mask=~self.free)
        marched = skfmm.distance(phi, dx=1.0, order=2)
        reached = self.free & ~np.ma.getmaskarray(marched) & (self.component == self.component[cell])
        cells = np.where(centre <= _FMM_SEED_RADIUS, centre, np.ma.getdata(marched) + _FMM_SEED_RADIUS)
        return np.where(reached, cells * self.cell, np.inf)

    def lookup(self, field: np.ndarray, xy, max_ring: int = 10) -> float:
        """Geodesic distance at world (x, y) from a distance field: min over the cells around xy of
        field + straight distance to that cell's centre. Starts with the 3x3 cells; for a position
        where the robot may stand it widens the square ring by ring (up to ``max_ring`` cells) while
        none is reachable, since a legal position next to a wall can have all 3x3 planning cells
        blocked (a cell is free only if all its pixels are). Points inside obstacles stay inf."""
        xy = np.asarray(xy, dtype=np.float64)
        if not self.is_free(xy):
            max_ring = 1
        rc = self.cell_of(xy)
        m = self.free.shape[0]
        for ring in range(1, max_ring + 1):
            dr, dc = np.mgrid[-ring : ring + 1, -ring : ring + 1]
            cells = rc + np.stack([dr.ravel(), dc.ravel()], axis=1)
            cells = cells[np.all((cells >= 0) & (cells < m), axis=1)]
            vals = field[cells[:, 0], cells[:, 1]]
            ok = np.isfinite(vals)
            if ok.any():
                return float((vals[ok] + np.linalg.norm(self.cell_centre(cells[ok]) - xy, axis=1)).min())
        return float("inf")

    def geodesic_distance(self, a_xy, b_xy) -> float:
        """Geodesic distance between two world points (metres); inf if unreachable."""
        return self.lookup(self.distance_field(b_xy), a_xy)

    def shortest_path(self, start_xy, goal_xy, max_len: int | None = None, comfort: bool = False) -> np.ndarray:
        """Waypoints (K, 2) in world coordinates from start towards goal along the distance field
        (steepest descent over 8 neighbours), starting at the start point and ending at the goal.
        ``max_len`` limits the number of cells followed; ``comfort`` follows the driving field.
        Empty (0, 2) if unreachable."""
        field = self.distance_field(goal_xy, comfort)
        start_xy = np.asarray(start_xy, dtype=np.float64)
        rc = self._best_cell_near(field, start_xy)
        if rc is None:
            return np.zeros((0, 2))
        m = self.free.shape[0]
        cells = [rc]
        limit = max_len if max_len is not None else m * m
        while field[rc] > 0 and len(cells) < limit:
            nb = rc + _NEIGHBOURS
            nb = nb[np.all((nb >= 0) & (nb < m), axis=1)]
            vals = field[nb[:, 0], nb[:, 1]]
            i = int(np.argmin(vals))
            if not vals[i] < field[rc]:
                break
            rc = tuple(nb[i])
            cells.append(rc)
        pts = self.cell_centre(np.array(cells))
        if field[rc] == 0:
            pts = np.vstack([pts, np.asarray(goal_xy, dtype=np.float64)[:2]])
        return np.vstack([start_xy[:2], pts])

    def snap(self, xy, on_cell: bool = False) -> tuple[np.ndarray | None, float]:
        """Where geodesics and the expert take world point ``xy`` (2,) to be, and how far that is from it.

        ``xy`` itself (distance 0) when it is navigable: the robot's centre may stand there and, with
        ``on_cell`` (a goal: distance fields start from its planning cell), its planning cell is free.
        Otherwise, for a point on the floor of the traversability map (not inside an obstacle or wall),
        the centre of the nearest free planning cell within ``config.snap_tolerance`` that a straight
        line over the floor reaches; failing that ``(None, d)``, d the distance to the nearest free
        cell's centre (to a cell's width).
        Example: 0.19 m from a wall face a 0.18 m disc may stand, but the 5 cm cell holding the point
        also holds pixels within 0.18 m of the wall, so a goal there snaps to the next cell's centre,
        0.01-0.06 m away."""
        xy = np.asarray(xy, dtype=np.float64)[:2]
        m = self.free.shape[0]
        rc = np.clip(self.cell_of(xy), 0, m - 1)
        if self.is_free(xy) and (not on_cell or self.free[tuple(rc)]):
            return xy, 0.0
        if not self.free.any():
            return None, float("inf")
        if self.on_floor(xy):
            reach = int(np.ceil(self.config.snap_tolerance / self.cell)) + 1
            lo, hi = np.clip(rc - reach, 0, m), np.clip(rc + reach + 1, 0, m)
            cells = np.argwhere(self.free[lo[0]:hi[0], lo[1]:hi[1]]) + lo
            centres = self.cell_centre(cells)
            d = np.linalg.norm(centres - xy, axis=1)
            for i in np.argsort(d, kind="stable"):
                if d[i] > self.config.snap_tolerance:
                    break
                if self._floor_segment(xy, centres[i]):
                    return centres[i], float(d[i])
        if self._nearest_free is None:
            self._nearest_free = ndimage.distance_transform_edt(~self.free, return_distances=False, return_indices=True)
        nearest = self._nearest_free[:, rc[0], rc[1]]
        return None, float(np.linalg.norm(self.cell_centre(nearest) - xy))

    def on_floor(self, xy) -> bool:
        """Whether world (x, y) is traversable floor in the map itself (not inside an obstacle or wall)."""
        rc = trav_pixel_from_world(np.asarray(xy, dtype=np.float64)[:2], self.n, self.resolution)
        return bool(np.all((rc >= 0) & (rc < self.n)) and self.trav[rc[0], rc[1]])

    def _floor_segment(self, a, b) -> bool:
        """Whether the segment a-b crosses only traversable floor (sampled every map pixel)."""
        k = max(2, int(np.ceil(np.linalg.norm(b - a) / self.resolution)) + 1)
        rc = trav_pixel_from_world(a + (b - a) * np.linspace(0.0, 1.0, k)[:, None], self.n, self.resolution)
        rc = np.clip(rc, 0, self.n - 1)
        return bool(self.trav[rc[:, 0], rc[:, 1]].all())

    def _best_cell_near(self, field: np.ndarray, xy) -> tuple[int, int] | None:
        rc = self.cell_of(xy)
        cells = rc + np.vstack([[0, 0], _NEIGHBOURS])
        m = self.free.shape[0]
        cells = cells[np.all((cells >= 0) & (cells < m), axis=1)]
        vals = field[cells[:, 0], cells[:, 1]] + np.linalg.norm(self.cell_centre(cells) - xy, axis=1)
        i = int(np.argmin(vals))
        return (int(cells[i][0]), int(cells[i][1])) if np.isfinite(vals[i]) else None

    def _in_grid(self, rc) -> bool:
        m = self.free.shape[0]
        return 0 <= rc[0] < m and 0 <= rc[1] < m

    # -- sampling ------------------------------------------------------------------------------
    def largest_component_cells(self) -> np.ndarray:
        """(K, 2) planning cells of the largest connected free component."""
        counts = np.bincount(self.component.ravel())
        counts[0] = 0
        return np.argwhere(self.component == int(np.argmax(counts)))
