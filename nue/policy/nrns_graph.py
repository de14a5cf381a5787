"""NRNS's topological graph: visited nodes, ghost nodes read from the robot's own depth, and the global choice.

* :func:`ghost_offsets`: the directions a depth frame shows as open. For each bearing of
  :attr:`GhostConfig.bearings_deg` (inside the camera's 90 degree field of view) and each range of
  :attr:`GhostConfig.ranges`, a corridor of the robot's width, ``range + clearance`` long, is checked against the
  frame's back-projected points between ``obstacle_min_height`` and ``obstacle_max_height`` above the floor; an empty
  corridor gives a ghost at that range along that bearing (NRNS: fixed-length edges at fixed angles, kept where the
  depth shows free space).
* :class:`TopoGraph`: explored nodes (places the robot stood, joined in the order it reached them) and ghost nodes
  (leaves hanging off the node whose view showed them, each with the distance to the goal the distance network
  predicted for it). :meth:`TopoGraph.choose` picks the ghost with the least
  ``predicted distance + travel_weight * path length through the graph + turn_cost * heading change``.

Positions are world (x, y) metres, headings radians (counter-clockwise from +x); bearings are relative to the robot's
heading, positive to the left. A turn ghost (NRNS's backward ghost) stands at its node with another heading: reaching
it means turning there, so the camera sees that way. The graph never reads the scene.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import networkx as nx
import numpy as np

from nue.sim.camera import pixel_directions, wrap_angle
from nue.sim.task import CameraConfig


@dataclass(frozen=True)
class GhostConfig:
    """Where ghost nodes are placed and how the graph merges places (metres, degrees)."""

    bearings_deg: tuple[float, ...] = (-30.0, -20.0, -10.0, 0.0, 10.0, 20.0, 30.0)
    """Directions tested for free space, relative to the heading (NRNS tests 0, +-15 ... +-60 on its wider view;
    +-30 keeps the ghost and most of its corridor inside the 90 degree camera)."""
    ranges: tuple[float, ...] = (0.75, 1.5)
    """Distances of the ghosts from the view they were read from (NRNS: one edge length, 1.5 m; the nearer ring
    finds the openings a 90 degree view shows only close by, e.g. a door beside the robot)."""
    clearance: float = 0.3
    """Free space the corridor must show beyond the ghost."""
    half_width: float = 0.2
    """Half-width of the tested corridor (the robot's radius plus a margin)."""
    obstacle_min_height: float = 0.1
    """Depth points at least this high above the floor are obstacles."""
    obstacle_max_height: float = 1.5
    """Points higher than this (ceilings, lintels) are ignored."""
    turn_headings_deg: tuple[float, ...] = (90.0, 180.0, -90.0)
    """Turn ghosts added at each new node, relative to the heading it was reached with (NRNS adds 180 only; with a
    90 degree camera the sides are unseen too)."""
    node_radius: float = 0.5
    """A place within this of an explored node is that node (localisation by the robot's own pose)."""
    ghost_merge: float = 0.5
    """A new ghost within this of a node or of another ghost is not added."""


def ghost_offsets(depth: np.ndarray, camera: CameraConfig, config: GhostConfig = GhostConfig()) -> np.ndarray:
    """(K, 2) robot-frame offsets (forward, left) of the ghosts a z-depth frame (H, W[, 1]) metres shows, range by
    range (``config.ranges``), each in the order of ``config.bearings_deg`` (depth 0 = no surface: open space)."""
    z = np.nan_to_num(np.asarray(depth, dtype=np.float64).reshape(camera.height, camera.width))
    rays = pixel_directions(camera)
    forward, left = z, -rays[..., 0] * z
    height = camera.mount_height - rays[..., 1] * z
    hit = (z > 0) & (height >= config.obstacle_min_height) & (height <= config.obstacle_max_height)
    points = np.stack([forward[hit], left[hit]], axis=-1)
    out = []
    for r in config.ranges:
        for b in np.radians(config.bearings_deg):
            d = np.array([math.cos(b), math.sin(b)])
            along = points @ d
            across = np.abs(points[:, 0] * d[1] - points[:, 1] * d[0])
            if not ((along > 0) & (along <= r + config.clearance) & (across <= config.half_width)).any():
                out.append(r * d)
    return np.array(out, dtype=np.float64).reshape(-1, 2)


@dataclass
class Ghost:
    """An unexplored place: where, seen from which node, which way the robot faces there, how far the goal is."""

    xy: np.ndarray
    """World (x, y) metres."""
    parent: int
    """The explored node whose view showed it."""
    heading: float
    """Heading (radians) the robot has on reaching it: the direction from its node (turn ghosts: the turned one)."""
    distance: float
    """Distance to the goal the distance network predicted for it, metres."""
    turn: bool = False
    """A turn ghost: at its node's position, reached by turning to ``heading``."""


@dataclass
class TopoGraph:
    """Explored nodes and ghosts; ids are shared (a graph node id is an explored node or a ghost)."""

    config: GhostConfig = field(default_factory=GhostConfig)
    graph: nx.Graph = field(default_factory=nx.Graph)
    """Explored nodes (attribute ``xy``) joined by edges of attribute ``length`` (metres); ghosts are not in it."""
    ghosts: dict[int, Ghost] = field(default_factory=dict)
    next_id: int = 0

    def nearest_node(self, xy) -> int | None:
        """The explored node within ``node_radius`` of world ``xy``, nearest first; None if there is none."""
        xy = np.asarray(xy, dtype=np.float64)[:2]
        best, best_d = None, self.config.node_radius
        for n, data in self.graph.nodes(data=True):
            d = float(np.linalg.norm(data["xy"] - xy))
            if d <= best_d:
                best, best_d = n, d
        return best

    def localize(self, xy, previous: int | None) -> tuple[int, bool]:
        """(the explored node at world ``xy``, whether it is new): an existing node within ``node_radius``, else a new
        one; joined to ``previous`` (the node the robot came from) if given and different. Ghosts within
        ``ghost_merge`` of the node are explored now and dropped."""
        xy = np.asarray(xy, dtype=np.float64)[:2].copy()
        node = self.nearest_node(xy)
        new = node is None
        if node is None:
            node, self.next_id = self.next_id, self.next_id + 1
            self.graph.add_node(node, xy=xy)
        if previous is not None and previous != node:
            a, b = self.graph.nodes[previous]["xy"], self.graph.nodes[node]["xy"]
            self.graph.add_edge(previous, node, length=float(np.linalg.norm(a - b)))
        for g in [g for g, ghost in self.ghosts.items() if not ghost.turn
                  and np.linalg.norm(ghost.xy - self.graph.nodes[node]["xy"]) <= self.config.ghost_merge]:
            del self.ghosts[g]
        return node, new

    def add_ghost(self, xy, parent: int, heading: float, distance: float, turn: bool = False) -> int | None:
        """Add a ghost (its id), or None when a node or another (non-turn) ghost lies within ``ghost_merge``."""
        xy = np.asarray(xy, dtype=np.float64)[:2].copy()
        if not turn:
            near = [self.graph.nodes[n]["xy"] for n in self.graph.nodes]
            near += [g.xy for g in self.ghosts.values() if not g.turn]
            if any(np.linalg.norm(p - xy) <= self.config.ghost_merge for p in near):
                return None
        gid, self.next_id = self.next_id, self.next_id + 1
        self.ghosts[gid] = Ghost(xy, parent, float(heading), float(distance), turn)
        return gid

    def travel(self, source: int) -> dict[int, float]:
        """Path length (metres) through the explored nodes from node ``source`` to every node it reaches."""
        return nx.single_source_dijkstra_path_length(self.graph, source, weight="length")

    def costs(self, source: int, yaw: float, travel_weight: float = 1.0, turn_cost: float = 0.0) -> dict[int, float]:
        """Each reachable ghost's cost from node ``source`` with heading ``yaw``: predicted distance +
        ``travel_weight`` * (graph path to its node + the edge to it) + ``turn_cost`` (per radian) * the heading
        change from ``yaw`` to the ghost's heading."""
        travel = self.travel(source)
        out = {}
        for gid, g in self.ghosts.items():
            if g.parent not in travel:
                continue
            edge = float(np.linalg.norm(g.xy - self.graph.nodes[g.parent]["xy"]))
            out[gid] = (g.distance + travel_weight * (travel[g.parent] + edge)
                        + turn_cost * abs(wrap_angle(g.heading - yaw)))
        return out

    def choose(self, source: int, yaw: float, travel_weight: float = 1.0, turn_cost: float = 0.0) -> int | None:
        """The ghost of least :meth:`costs` (ties: the lower id), None if no ghost is reachable."""
        costs = self.costs(source, yaw, travel_weight, turn_cost)
        return min(costs, key=lambda g: (costs[g], g)) if costs else None
