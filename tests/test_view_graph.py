"""The viewer's graph layer (:mod:`nue.viz.view_graph`): NRNS's nodes, edges and ghosts at the graph's own positions,
VGM's nodes placed at the mean robot position of the steps localised at them, and ``nue view`` logging the graph of
a VGM and of an NRNS checkpoint at every step."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

pytest.importorskip("rerun")

from nue.policy import build_model
from nue.policy.agent import PolicyAgent
from nue.policy.config import get_model_config
from nue.policy.graph_memory import ViewGraph, localise
from nue.policy.nrns_agent import NRNSAgent
from nue.policy.nrns_graph import GhostConfig, TopoGraph
from nue.sim.task import get_task
from nue.viz.view_graph import VGMPlacer, graph_snapshot

from .conftest import BOX_ROOM, nue_here
from .test_view import _column, episode_file  # noqa: F401  (the module's episode fixture)


def _unit(*v: float) -> torch.Tensor:
    t = torch.tensor(v, dtype=torch.float32)
    return t / t.norm()


def test_nrns_snapshot_has_the_graphs_nodes_edges_ghosts_and_target():
    task = get_task("paper")
    agent = NRNSAgent(build_model(get_model_config("nrns").for_task(task)))
    g = TopoGraph(GhostConfig(ghost_merge=0.2))
    n0, _ = g.localize((0.0, 0.0), None)
    n1, _ = g.localize((1.0, 0.0), n0)
    n2, _ = g.localize((1.0, 3.0), n1)
    a = g.add_ghost((2.5, 0.0), n1, 0.0, distance=2.8)
    g.add_ghost((-1.5, 0.0), n0, math.pi, distance=1.0)
    agent.graph, agent.node, agent.target = g, n1, g.ghosts[a]
    snap = graph_snapshot(agent, np.zeros(3), VGMPlacer())
    assert snap is not None and snap.kind == "nrns"
    assert snap.nodes.tolist() == [[0.0, 0.0], [1.0, 0.0], [1.0, 3.0]]
    assert sorted(map(sorted, snap.edges.tolist())) == [[0, 1], [1, 2]]
    assert snap.current == 1 and snap.target.tolist() == [2.5, 0.0]
    assert sorted(snap.ghosts.tolist()) == [[-1.5, 0.0], [2.5, 0.0]]
    assert graph_snapshot(NRNSAgent(agent.model), np.zeros(3), VGMPlacer()) is None  # before its first episode


def test_vgm_nodes_sit_at_the_mean_position_of_the_steps_localised_there():
    task = get_task("paper")
    model = build_model(get_model_config("vgm").for_task(task).replace(graph_nodes=8))
    agent = PolicyAgent(model)
    a, a2, b = _unit(1, 0, 0), _unit(0.9, 0.436, 0), _unit(0, 1, 0)
    # node 0 at steps 0, 1 (positions (0, 0), (1, 0)), node 1 at step 2 ((4, 2)), node 0 again at step 3 ((2, 0))
    walk = [(a, (0.0, 0.0)), (a2, (1.0, 0.0)), (b, (4.0, 2.0)), (a, (2.0, 0.0))]
    graph, placer = ViewGraph.empty(1, 8, 3), VGMPlacer()
    for e, xy in walk:
        graph = localise(graph, e[None], 0.75)
        model.last_graph = graph
        snap = graph_snapshot(agent, (*xy, 0.0), placer)
    assert snap is not None and snap.kind == "vgm"
    assert np.allclose(snap.nodes, [[1.0, 0.0], [4.0, 2.0]])  # (0 + 1 + 2) / 3; a single visit
    assert snap.edges.tolist() == [[0, 1]] and snap.current == 0 and snap.target is None and len(snap.ghosts) == 0
    # a new episode empties the graph and the placement
    graph = localise(graph, b[None], 0.75, start=torch.tensor([True]))
    model.last_graph = graph
    snap = graph_snapshot(agent, (7.0, 7.0, 0.0), placer)
    assert snap.nodes.tolist() == [[7.0, 7.0]] and len(snap.edges) == 0 and snap.current == 0


def _untrained(path, kind: str):
    from nue.nerf.config import get_memory
    from nue.policy.checkpoint import policy_meta, save_checkpoint

    task = get_task("paper")
    cfg = get_model_config(kind).for_task(task)
    torch.manual_seed(0)
    meta = policy_meta(task, get_memory("fast"), cfg, {})
    return save_checkpoint(path, {**meta, "model_state": build_model(cfg).state_dict(), "step": 0})


@pytest.mark.parametrize("kind", ["vgm", "nrns"])
def test_nue_view_logs_the_graph_of_a_vgm_and_an_nrns_run_at_every_step(tmp_path, episode_file, kind):  # noqa: F811
    eps_path, _ = episode_file
    rrd = tmp_path / "live.rrd"
    ckpt = _untrained(tmp_path / f"{kind}.pt", kind)
    run = nue_here("view", "--scene", BOX_ROOM, "--episodes", eps_path, "--max-steps", 5, "--checkpoint", ckpt,
                    "--no-serve", "--save", rrd)
    assert run.returncode == 0, run.stderr
    steps, _ = _column(rrd, "/world/robot", "translation")
    node_steps, positions = _column(rrd, "/world/graph/nodes", "positions")
    assert list(node_steps) == list(steps[:-1])  # a graph at every step the agent acted
    assert all(len(p) >= 1 for p in positions)  # the start is a node
    counts = _column(rrd, "/metrics/graph_nodes", "scalars")[1]
    assert [len(p) for p in positions] == [int(np.ravel(c)[0]) for c in counts]
