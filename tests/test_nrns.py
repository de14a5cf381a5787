"""The NRNS baseline: distance labels on a corridor, ghosts from a hand-built depth frame, the graph's choice on a
hand-built graph, the distance network learning a synthetic set, and `nue train --model nrns` + `nue eval` end to end
on a tiny collection in the box room."""

from __future__ import annotations

import json
import math
import shutil

import numpy as np
import pytest
import torch

from nue.nerf.config import MEMORY_PRESETS, get_memory
from nue.policy import build_model
from nue.policy.config import get_model_config
from nue.policy.inputs import PolicyInput
from nue.policy.nrns_graph import GhostConfig, TopoGraph, ghost_offsets
from nue.sim.episode_gen import EpisodeGenConfig, generate_episodes
from nue.sim.episodes import save_episodes
from nue.sim.task import CameraConfig
from nue.train.nrns_train import episode_labels, path_labels

from .conftest import BOX_ROOM, FIXTURES, nue_here

CAM = CameraConfig(width=48, height=36, fx=24.0, fy=24.0)
"""A small 90 degree camera (the task's intrinsics at a fifth of the size)."""


def test_distance_labels_on_a_straight_corridor():
    """Five poses 0.25 m apart along x, a last move of 0.25 m, 0.3 m left to the goal at the end."""
    poses = np.array([[0.25 * i, 2.0, 0.0] for i in range(5)])
    labels = path_labels(poses, path_length=1.25, final_geodesic=0.3)
    assert np.allclose(labels, [1.55, 1.30, 1.05, 0.80, 0.55])
    turned = np.vstack([poses[:1], poses])  # a turn in place: no distance travelled, the same label
    assert np.allclose(path_labels(turned, 1.25, 0.3)[:2], [1.55, 1.55])
    # An episode file's stored geodesic distances win; a non-finite one (and an old file without them) falls back.
    meta = {"record": {"path_length": 1.25, "final_geodesic": 0.3}}
    geo = np.array([1.5, 1.2, np.inf, 0.8, 0.5], dtype=np.float32)
    assert np.allclose(episode_labels({"pose": poses, "geodesic": geo}, meta, "f"), [1.5, 1.2, 1.05, 0.8, 0.5])
    assert np.allclose(episode_labels({"pose": poses}, meta, "f"), [1.55, 1.30, 1.05, 0.80, 0.55])


def _wall_depth(z_left: float, z_right: float) -> np.ndarray:
    """Z-depth of a frame facing two walls: at ``z_left`` metres on the image's left half, ``z_right`` on the right."""
    depth = np.empty((CAM.height, CAM.width))
    depth[:, : CAM.width // 2] = z_left
    depth[:, CAM.width // 2 :] = z_right
    return depth


def _bearings(offsets: np.ndarray) -> list[float]:
    return [round(math.degrees(math.atan2(o[1], o[0]))) for o in offsets]


def test_ghosts_read_from_a_hand_built_depth_frame():
    cfg = GhostConfig(bearings_deg=(-30.0, -15.0, 0.0, 15.0, 30.0), ranges=(1.5,))
    # A wall 1 m ahead on the left half, 4 m ahead on the right: only the directions to the right are open (the
    # straight-ahead corridor, 0.2 m wide each side, holds the left wall's points).
    got = ghost_offsets(_wall_depth(1.0, 4.0), CAM, cfg)
    assert _bearings(got) == [-30, -15]
    assert np.allclose(np.linalg.norm(got, axis=1), 1.5)
    assert _bearings(ghost_offsets(_wall_depth(4.0, 1.0), CAM, cfg)) == [15, 30]
    # Nothing in range (the renderer's 0 = no surface, or walls beyond range + clearance): every bearing.
    assert _bearings(ghost_offsets(np.zeros((CAM.height, CAM.width)), CAM, cfg)) == [-30, -15, 0, 15, 30]
    assert len(ghost_offsets(_wall_depth(1.9, 1.9), CAM, cfg)) == 5
    # A wall across the view at 1.7 m: met at 1.7 / cos(b) along bearing b, beyond 1.5 + 0.3 only at +-30 degrees.
    assert _bearings(ghost_offsets(_wall_depth(1.7, 1.7), CAM, cfg)) == [-30, 30]
    assert len(ghost_offsets(_wall_depth(1.5, 1.5), CAM, cfg)) == 0
    # The floor alone is no obstacle: the lower half sees the floor at z = mount_height / v.
    v = (np.arange(CAM.height) + 0.5 - CAM.cy) / CAM.fy
    floor = np.where(v[:, None] > 0, CAM.mount_height / np.maximum(v[:, None], 1e-9), 0.0) * np.ones((1, CAM.width))
    assert len(ghost_offsets(floor, CAM, cfg)) == 5
    # Two rings (the default ranges 0.75 and 1.5 m): a wall across at 1.5 m leaves the near ring only.
    near = ghost_offsets(_wall_depth(1.5, 1.5), CAM, GhostConfig())
    assert np.allclose(np.linalg.norm(near, axis=1), 0.75) and _bearings(near) == [-30, -20, -10, 0, 10, 20, 30]


def _hand_graph() -> tuple[TopoGraph, dict[str, int]]:
    """Nodes 0 (0, 0) - 1 (1, 0) - 2 (1, 3); ghosts: A off node 1 ahead, B off node 2 (a long way round), C off node 0
    behind the robot."""
    g = TopoGraph(GhostConfig(ghost_merge=0.2))
    n0, _ = g.localize((0.0, 0.0), None)
    n1, _ = g.localize((1.0, 0.0), n0)
    n2, _ = g.localize((1.0, 3.0), n1)
    n1_again, new = g.localize((1.1, 0.1), n2)  # back at node 1: localised, joined to node 2
    assert (n0, n1, n2, n1_again, new) == (0, 1, 2, 1, False)
    ids = {"A": g.add_ghost((2.5, 0.0), n1, 0.0, distance=2.8),
           "B": g.add_ghost((1.0, 4.5), n2, math.pi / 2, distance=2.5),
           "C": g.add_ghost((-1.5, 0.0), n0, math.pi, distance=1.0)}
    return g, ids


def test_graph_chooses_least_predicted_distance_plus_travel_cost():
    g, ids = _hand_graph()
    costs = g.costs(1, yaw=0.0, travel_weight=1.0, turn_cost=0.0)
    # A: 2.8 + 1.5 = 4.3; B: 2.5 + (3 + 1.5) = 7.0; C: 1.0 + (1 + 1.5) = 3.5
    assert costs[ids["A"]] == pytest.approx(4.3) and costs[ids["B"]] == pytest.approx(7.0)
    assert costs[ids["C"]] == pytest.approx(3.5)
    assert g.choose(1, 0.0, 1.0, 0.0) == ids["C"]
    # Turning round costs 0.955 per radian: C 3.5 + pi * 0.955 = 6.5 > A 4.3; B is never the least (travel).
    assert g.choose(1, 0.0, 1.0, 0.955) == ids["A"]
    # Without travel cost the least predicted distance alone would win: C, then B once C is gone.
    assert g.choose(1, 0.0, 0.0, 0.0) == ids["C"]
    del g.ghosts[ids["C"]]
    assert g.choose(1, 0.0, 0.0, 0.0) == ids["B"] and g.choose(1, 0.0, 1.0, 0.0) == ids["A"]


def test_graph_merges_ghosts_and_drops_explored_ones():
    g, ids = _hand_graph()
    assert g.add_ghost((2.6, 0.1), 1, 0.0, distance=1.0) is None  # within ghost_merge of A
    assert g.add_ghost((1.05, 0.0), 1, 0.0, distance=1.0) is None  # on node 1
    assert g.add_ghost((1.0, 0.0), 1, math.pi, distance=1.0, turn=True) is not None  # a turn ghost stands on its node
    node, new = g.localize((2.45, 0.05), 1)  # the robot reaches A: a new node, A is explored
    assert new and ids["A"] not in g.ghosts and g.graph.has_edge(1, node)


def test_distance_network_learns_a_synthetic_set():
    """Views whose depth channel is uniform at level a, goals of brightness b; the distance from an offset (f, l) is
    4a + 2b + f: after 150 steps the error is under half its start."""
    torch.manual_seed(0)
    cfg = get_model_config("nrns").replace(frame_height=12, frame_width=16, perception_channels=(8, 8),
                                           perception_grid=(2, 2), perception_dim=32, head_hidden=32)
    model = build_model(cfg)
    gen = torch.Generator().manual_seed(1)

    def batch(n):
        a, b = torch.rand(n, generator=gen), torch.rand(n, generator=gen)
        off = torch.rand(n, 1, 2, generator=gen) * 2 - 1
        rgbd = torch.rand(n, 4, 12, 16, generator=gen) * 0.1
        rgbd[:, 3] = a[:, None, None]
        goal = b[:, None, None, None].expand(n, 3, 12, 16).clone()
        return PolicyInput(rgbd=rgbd, goal=goal), off, 4 * a + 2 * b + off[:, 0, 0]

    test_inp, test_off, test_y = batch(256)

    def error():
        with torch.no_grad():
            return float((model.distance(test_inp, test_off)[:, 0] - test_y).abs().mean())

    before = error()
    opt = torch.optim.Adam(model.parameters(), lr=3e-3)
    for _ in range(150):
        inp, off, y = batch(32)
        loss = torch.nn.functional.smooth_l1_loss(model.distance(inp, off)[:, 0], y)
        opt.zero_grad()
        loss.backward()
        opt.step()
    after = error()
    assert after < 0.5 * before, (before, after)
    with pytest.raises(TypeError, match="distances, not actions"):
        model(test_inp)


TINY = get_memory("fast").replace(name="tiny", train_rays=32, iters_per_update=1)


@pytest.fixture(scope="module")
def tiny_demos(tmp_path_factory):
    """One box-room copy: 3 training + 3 held-out expert episodes with the tiny memory."""
    from nue.train.collect import CollectConfig, collect

    root = tmp_path_factory.mktemp("nrns")
    shutil.copytree(BOX_ROOM, root / "room_a")
    out = root / "demos"
    cfg = CollectConfig(scene_dirs=(str(root / "room_a"),), episodes_per_bin=1, heldout_per_bin=1, memory=TINY)
    collect(out, cfg, root / "scenes", workers=1, progress=False)
    return out


def test_collection_stores_the_geodesic_labels(tiny_demos):
    """Each step's geodesic distance to the goal: the episode's start distance first; the geodesic expert's path still
    to travel agrees with it to within its comfort detours."""
    from nue.train.dataset import DemoSet

    demos = DemoSet(tiny_demos, "train")
    for arrays, meta in zip(demos.episodes, demos.metas):
        geo, record = np.asarray(arrays["geodesic"]), meta["record"]
        assert geo.shape == (meta["steps"],) and geo.dtype == np.float32
        assert geo[0] == pytest.approx(record["geodesic_start"], abs=1e-4)
        path = path_labels(np.asarray(arrays["pose"]), record["path_length"], record["final_geodesic"])
        assert np.abs(path - geo).max() < 0.5, np.abs(path - geo).max()


def test_train_and_eval_nrns_end_to_end(tiny_demos, tmp_path, box_scene, box_nav, box_renderer):
    from nue.policy.checkpoint import load_agent, load_policy
    from nue.policy.nrns_agent import NRNSAgent
    from nue.sim.task import get_task

    run = tmp_path / "run"
    res = nue_here("train", "--data", tiny_demos, "--out", run, "--model", "nrns", "--steps", 6, "--batch-size", 8,
                   "--warmup", 1, "--eval-every", 3)
    assert res.returncode == 0, res.stderr
    ckpt = torch.load(run / "last.pt", weights_only=True)
    assert ckpt["step"] == 6 and ckpt["model_config"]["kind"] == "nrns"
    assert {"distance_mae", "distance_mae_offset", "baseline_mae"} <= set(ckpt["metrics"])
    res = nue_here("train", "--data", tiny_demos, "--out", run, "--model", "nrns", "--steps", 6, "--batch-size", 8,
                   "--warmup", 1, "--eval-every", 3, "--lr", "2e-3", "--resume")  # a resume with another lr is refused
    assert res.returncode == 2 and "other settings (lr 0.001 -> 0.002)" in res.stderr, res.stderr
    assert len(res.stderr.strip().splitlines()) == 1
    model, header = load_policy(run / "best.pt")  # the checkpoint round-trips
    assert header.model == get_model_config("nrns").for_task(get_task("paper"))
    agent, memory = load_agent(run / "best.pt", get_task("paper"))
    assert isinstance(agent, NRNSAgent) and memory is None

    eps_dir = tmp_path / "episodes"
    eps = generate_episodes(box_scene, "paper", EpisodeGenConfig(per_bin=1), seed=4, navgrid=box_nav,
                            renderer=box_renderer)
    save_episodes(eps_dir / "box_room.json", eps[:2], "paper")
    out = tmp_path / "records.jsonl"
    res = nue_here("eval", "-c", f"nrns={run / 'best.pt'}", "--out", out, "--episodes-dir", eps_dir,
                   "--scenes-root", FIXTURES, "--max-steps", 40)
    assert res.returncode == 0, res.stderr
    records = [json.loads(line) for line in out.read_text().splitlines()]
    assert len(records) == 2 and {r["method"] for r in records} == {"nrns"}
    assert all(0 < r["steps"] <= 40 for r in records)
    graph = records[0]["extra"]["nrns"]  # the record carries the agent's graph
    assert len(graph["nodes"]) >= 1 and graph["events"] and graph["events"][0][1] in ("subgoal", "goal_switch")


@pytest.fixture(scope="module", autouse=True)
def _tiny_memory_preset():
    with pytest.MonkeyPatch.context() as patch:
        patch.setitem(MEMORY_PRESETS, "tiny", TINY)
        yield
