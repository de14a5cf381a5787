"""The graph memories of VGM and NRNS in the 3-D viewer: their nodes, edges and (NRNS) ghosts, step by step.

:func:`graph_snapshot` reads an agent's graph after it chose this step's action (``nue view``'s ``on_step``):

* **NRNS** (:class:`nue.policy.nrns_agent.NRNSAgent`): the explored nodes at their world positions, the edges between
  them, the ghosts (unexplored places the depth showed) and the ghost it is driving to. Positions are the graph's own.
* **VGM** (a :class:`nue.policy.agent.PolicyAgent` around :class:`nue.policy.vgm_model.VGMPolicy`): the graph holds
  view embeddings and no positions, so a :class:`VGMPlacer` draws each node at the mean robot position of the steps
  the graph localised at it. That is a picture for a reader, not something the policy knows.

Entities (:meth:`GraphLogger.log`): ``world/graph/nodes`` (the current node larger), ``world/graph/edges``,
``world/graph/ghosts``, ``world/graph/target``; the scalar ``metrics/graph_nodes``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import rerun as rr

NODE_COLOUR = (250, 250, 250)
CURRENT_COLOUR = (255, 60, 60)
EDGE_COLOUR = (200, 200, 200)
GHOST_COLOUR = (150, 110, 255)
HEIGHT = 0.9
"""Metres above the floor the graph is drawn at (above the furniture, below the cut walls' top)."""


@dataclass(frozen=True)
class GraphSnapshot:
    """One step's graph in world coordinates."""

    kind: str
    """``vgm`` or ``nrns``."""
    nodes: np.ndarray
    """(N, 2) float world (x, y) of the nodes (VGM: placed by :class:`VGMPlacer`)."""
    edges: np.ndarray
    """(E, 2) int, rows of ``nodes`` joined by an edge (each pair once)."""
    current: int | None
    """Row of ``nodes`` the agent is localised at, None if none yet."""
    ghosts: np.ndarray
    """(G, 2) float world (x, y) of NRNS's ghosts; (0, 2) for VGM."""
    target: np.ndarray | None
    """(2,) world (x, y) of the ghost NRNS drives to, else None."""


class VGMPlacer:
    """Positions for a VGM graph's nodes: the running mean of the robot's position over the steps the graph was
    localised at each node (a node index is its slot; an emptied graph starts again)."""

    def __init__(self) -> None:
        self.sums: dict[int, np.ndarray] = {}
        self.counts: dict[int, int] = {}

    def update(self, node: int, xy, fresh: bool) -> None:
        """The graph is localised at ``node`` with the robot at ``xy``; ``fresh`` = the graph was emptied this step."""
        if fresh:
            self.sums.clear()
            self.counts.clear()
        self.sums[node] = self.sums.get(node, np.zeros(2)) + np.asarray(xy, dtype=np.float64)[:2]
        self.counts[node] = self.counts.get(node, 0) + 1

    def position(self, node: int) -> np.ndarray:
        return self.sums[node] / self.counts[node]


def _vgm_snapshot(graph, pose, placer: VGMPlacer) -> GraphSnapshot:
    """Row 0 of a :class:`nue.policy.graph_memory.ViewGraph` (the agent's batch of one)."""
    mask = graph.mask[0].detach().cpu().numpy() > 0
    current = int(graph.current[0])
    placer.update(current, pose, fresh=float(graph.step[0]) == 0.0)
    used = [i for i in np.flatnonzero(mask) if i in placer.counts]
    row = {int(n): k for k, n in enumerate(used)}
    adj = graph.adj[0].detach().cpu().numpy()
    edges = [(row[int(a)], row[int(b)]) for a, b in zip(*np.nonzero(np.triu(adj))) if int(a) in row and int(b) in row]
    nodes = np.array([placer.position(int(n)) for n in used], dtype=np.float64).reshape(-1, 2)
    return GraphSnapshot("vgm", nodes, np.array(edges, dtype=np.int64).reshape(-1, 2), row.get(current),
                         np.zeros((0, 2)), None)


def _nrns_snapshot(agent) -> GraphSnapshot:
    g = agent.graph.graph
    ids = list(g.nodes)
    row = {n: k for k, n in enumerate(ids)}
    nodes = np.array([g.nodes[n]["xy"] for n in ids], dtype=np.float64).reshape(-1, 2)
    edges = np.array([(row[a], row[b]) for a, b in g.edges], dtype=np.int64).reshape(-1, 2)
    ghosts = np.array([gh.xy for gh in agent.graph.ghosts.values()], dtype=np.float64).reshape(-1, 2)
    target = None if agent.target is None else np.asarray(agent.target.xy, dtype=np.float64)[:2]
    return GraphSnapshot("nrns", nodes, edges, row.get(agent.node), ghosts, target)


def graph_snapshot(agent, pose, placer: VGMPlacer) -> GraphSnapshot | None:
    """The agent's graph after it chose this step's action at ``pose`` (x, y, yaw), or None for an agent without one."""
    from nue.policy.nrns_agent import NRNSAgent
    from nue.policy.vgm_model import VGMPolicy

    if isinstance(agent, NRNSAgent):
        return _nrns_snapshot(agent) if hasattr(agent, "graph") else None
    model = getattr(agent, "model", None)
    if isinstance(model, VGMPolicy) and model.last_graph is not None:
        return _vgm_snapshot(model.last_graph, pose, placer)
    return None


def _lift(xy: np.ndarray, z: float) -> np.ndarray:
    return np.concatenate([xy, np.full((len(xy), 1), z)], axis=1).astype(np.float32)


class GraphLogger:
    """Logs an agent's graph each step to a :class:`rerun.RecordingStream` (the step's time already set)."""

    def __init__(self, rec: rr.RecordingStream, floor_z: float):
        self.rec, self.z = rec, floor_z + HEIGHT
        self.placer = VGMPlacer()

    def log(self, agent, pose) -> GraphSnapshot | None:
        snap = graph_snapshot(agent, pose, self.placer)
        if snap is None:
            return None
        rec, nodes = self.rec, _lift(snap.nodes, self.z)
        radii = np.full(len(nodes), 0.08, dtype=np.float32)
        colours = np.tile(np.array(NODE_COLOUR, dtype=np.uint8), (len(nodes), 1))
        if snap.current is not None:
            radii[snap.current] = 0.14
            colours[snap.current] = CURRENT_COLOUR
        rec.log("world/graph/nodes", rr.Points3D(nodes, colors=colours, radii=radii))
        rec.log("world/graph/edges", rr.LineStrips3D([nodes[[a, b]] for a, b in snap.edges], colors=[EDGE_COLOUR],
                                                     radii=0.015))
        rec.log("world/graph/ghosts", rr.Points3D(_lift(snap.ghosts, self.z), colors=[GHOST_COLOUR], radii=0.07))
        target = np.zeros((0, 3), np.float32) if snap.target is None else _lift(snap.target[None], self.z)
        rec.log("world/graph/target", rr.Points3D(target, colors=[GHOST_COLOUR], radii=0.16))
        rec.log("metrics/graph_nodes", rr.Scalars(float(len(nodes))))
        return snap
