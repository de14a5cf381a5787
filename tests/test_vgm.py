"""VGM (visual graph memory): graph building on hand-made embeddings, graph convolution and attention read-out on a
hand-made graph, the contrastive pre-training's loss falling, the policy's state handling, and `nue train --model vgm`
and `nue eval` end to end on a tiny collection."""

from __future__ import annotations

import math
import shutil

import numpy as np
import pytest
import torch

from nue.policy import build_model
from nue.policy.config import MODEL_PRESETS, ModelConfig, get_model_config
from nue.policy.graph_memory import GraphConv, ReadOut, ViewGraph, localise, masked_attention, normalized_adjacency
from nue.policy.inputs import PolicyInput
from nue.train.contrastive import info_nce, pretrain_embedding

from .conftest import BOX_ROOM, FIXTURES, nue_here


def _unit(*v: float) -> torch.Tensor:
    t = torch.tensor(v, dtype=torch.float32)
    return t / t.norm()


def _walk(embs, nodes=8, threshold=0.75):
    g = ViewGraph.empty(1, nodes, len(embs[0]))
    out = []
    for e in embs:
        g = localise(g, e[None], threshold)
        out.append(g)
    return out


def test_a_node_is_added_only_below_the_threshold_and_consecutive_nodes_are_linked():
    a, a2, b, c = _unit(1, 0, 0), _unit(0.9, 0.436, 0), _unit(0, 1, 0), _unit(0, 0, 1)
    a3 = _unit(0.8, 0.6, 0)  # 0.8 to a, 0.6 to b, 0 to c
    gs = _walk([a, a2, b, c, a3, c])
    assert [int(g.num_nodes) for g in gs] == [1, 1, 2, 3, 3, 3]  # a2 is 0.9 to a: no node; b, c: new nodes
    assert [int(g.current) for g in gs] == [0, 0, 1, 2, 0, 2]  # a3 re-localises at node 0, c at node 2
    last = gs[-1]
    edges = {(i, j) for i, j in torch.nonzero(last.adj[0]).tolist() if i < j}
    assert edges == {(0, 1), (1, 2), (0, 2)}  # consecutive nodes; the jump c -> a3 (node 2 -> 0) too
    assert torch.allclose(last.nodes[0, 0], a3)  # a re-visited node takes the new view's embedding
    assert torch.allclose(last.nodes[0, 1], b) and torch.allclose(last.nodes[0, 2], c)
    assert last.visit[0, :3].tolist() == [4.0, 2.0, 5.0] and float(last.step[0]) == 5.0
    assert torch.equal(gs[1].adj, gs[0].adj) and not gs[0].adj.any()  # staying at a node adds no edge


def test_an_episode_start_empties_the_graph_and_a_full_graph_localises_at_the_nearest_node():
    a, b, c = _unit(1, 0, 0), _unit(0, 1, 0), _unit(0.6, 0.0, 0.8)
    g = _walk([a, b], nodes=8)[-1]
    g = localise(g, c[None], 0.75, start=torch.tensor([True]))
    assert int(g.num_nodes) == 1 and torch.allclose(g.nodes[0, 0], c) and not g.adj.any() and float(g.step[0]) == 0
    full = _walk([a, b, c], nodes=2)[-1]  # c is 0.6 to a, 0 to b, the graph holds 2 nodes
    assert int(full.num_nodes) == 2 and int(full.current) == 0
    assert torch.allclose(full.nodes[0, 0], a)  # localised by force: the node keeps its embedding
    # rows of a batch are independent
    two = localise(ViewGraph.empty(2, 4, 3), torch.stack([a, b]), 0.75)
    two = localise(two, torch.stack([a, c]), 0.75)
    assert two.num_nodes.tolist() == [1, 2]


def test_normalized_adjacency_and_graph_convolution_ignore_empty_nodes():
    adj = torch.zeros(1, 3, 3)
    adj[0, 0, 1] = adj[0, 1, 0] = 1.0
    adj[0, 1, 2] = adj[0, 2, 1] = 1.0  # an edge to the empty slot 2 must not count
    mask = torch.tensor([[1.0, 1.0, 0.0]])
    a_hat = normalized_adjacency(adj, mask)
    assert torch.allclose(a_hat[0], torch.tensor([[0.5, 0.5, 0.0], [0.5, 0.5, 0.0], [0.0, 0.0, 0.0]]))
    chain = torch.zeros(1, 3, 3)
    chain[0, 0, 1] = chain[0, 1, 0] = chain[0, 1, 2] = chain[0, 2, 1] = 1.0  # path 0-1-2: degrees (with I) 2, 3, 2
    a3 = normalized_adjacency(chain, torch.ones(1, 3))
    assert math.isclose(float(a3[0, 0, 1]), 1 / math.sqrt(6), rel_tol=1e-6) and math.isclose(float(a3[0, 1, 1]), 1 / 3, rel_tol=1e-6)
    torch.manual_seed(0)
    gcn = GraphConv(4, 5, layers=2)
    x = torch.randn(1, 3, 4)
    y = gcn(x, a_hat)
    x2 = x.clone()
    x2[0, 2] = 100.0
    assert y.shape == (1, 3, 5) and torch.equal(y[0, 2], torch.zeros(5)) and torch.allclose(gcn(x2, a_hat), y)


def test_masked_attention_by_hand_and_the_read_out_ignores_empty_nodes():
    q = torch.tensor([[[1.0, 0.0]]])  # (B=1, H=1, d=2)
    k = torch.tensor([[[[1.0, 0.0], [0.0, 1.0], [5.0, 5.0]]]])
    v = torch.tensor([[[[1.0, 0.0], [0.0, 1.0], [100.0, 100.0]]]])
    read, w = masked_attention(q, k, v, torch.tensor([[1.0, 1.0, 0.0]]))
    w0 = math.exp(1 / math.sqrt(2)) / (math.exp(1 / math.sqrt(2)) + 1)  # softmax of (1, 0) / sqrt(2)
    assert torch.allclose(w[0, 0], torch.tensor([w0, 1 - w0, 0.0]), atol=1e-6)
    assert torch.allclose(read[0, 0], torch.tensor([w0, 1 - w0]), atol=1e-6)
    torch.manual_seed(0)
    ro = ReadOut(8, heads=2, hidden=16)
    nodes, mask = torch.randn(2, 4, 8), torch.tensor([[1.0, 1.0, 0.0, 0.0], [1.0, 1.0, 1.0, 1.0]])
    query = torch.randn(2, 8)
    out = ro(query, nodes, mask)
    other = nodes.clone()
    other[0, 2:] = torch.randn(2, 8) * 10
    assert out.shape == (2, 8) and torch.allclose(ro(query, other, mask), out, atol=1e-6)
    assert ro.last_weights is not None and torch.equal(ro.last_weights[0, :, 2:], torch.zeros(2, 2))


def test_info_nce_by_hand_and_the_contrastive_loss_falls_on_a_tiny_synthetic_set():
    z = torch.nn.functional.normalize(torch.ones(4, 3), dim=-1)
    assert math.isclose(float(info_nce(z, z, 0.5)), math.log(7), rel_tol=1e-5)  # all alike: chance among 2B - 1
    cfg = get_model_config("vgm").replace(embed_channels=(8, 8), embed_dim=16)
    torch.manual_seed(0)
    embed = build_model(cfg).embed
    places = torch.rand(6, 3, 3, 4, generator=torch.Generator().manual_seed(1))  # six coarse colour layouts

    def pairs(rng, n):
        idx = torch.as_tensor(rng.integers(6, size=n))
        img = torch.nn.functional.interpolate(places[idx], size=(24, 32), mode="nearest")
        noise = torch.as_tensor(rng.normal(0, 0.05, size=(2, *img.shape)), dtype=torch.float32)
        return (img + noise[0]).clamp(0, 1), (img + noise[1]).clamp(0, 1)

    losses = pretrain_embedding(embed, pairs, steps=40, batch=12, temperature=0.2, lr=3e-3, seed=0)
    assert np.mean(losses[-5:]) < 0.75 * np.mean(losses[:5]), losses
    assert not embed.training and not any(p.requires_grad for p in embed.parameters())


def test_stepwise_forward_equals_the_sequence_forward_and_the_embedding_stays_frozen():
    cfg = get_model_config("vgm").replace(graph_nodes=6, graph_threshold=0.999)  # nearly every frame a new node
    torch.manual_seed(0)
    model = build_model(cfg)
    model.train()
    assert not model.embed.training and model.training
    model.eval()
    g = torch.Generator().manual_seed(0)
    t, b = 5, 2
    inp = PolicyInput(rgbd=torch.rand(t, b, 4, *cfg.frame_size, generator=g),
                      goal=torch.rand(t, b, 3, *cfg.goal_size, generator=g))
    reset = torch.zeros(t, b, dtype=torch.bool)
    reset[0] = True
    reset[3, 1] = True  # a new episode in row 1 at step 3
    with torch.no_grad():
        seq = model.forward_sequence(inp, model.initial_state(b), reset)
        state, logits = model.initial_state(b), []
        for i in range(t):
            out = model(inp.step(i), state, reset[i])
            state = out.state
            logits.append(out.logits)
    assert torch.allclose(seq.logits, torch.stack(logits), atol=1e-5)
    graph = ViewGraph(*seq.state[2:])
    assert graph.num_nodes.tolist()[1] <= 2 and float(graph.step[1]) == 1.0  # row 1 restarted at step 3
    model.train()
    model.forward_sequence(inp, None, reset).logits.sum().backward()
    assert all(p.grad is None for p in model.embed.parameters())
    assert all(p.grad is not None for n, p in model.named_parameters() if p.requires_grad and "aux" not in n)


def test_vgm_config_round_trips_and_other_configs_keep_their_dict():
    vgm = get_model_config("vgm")
    assert vgm.recurrent and vgm.pretrains_embedding and not vgm.uses_memory_maps
    assert ModelConfig.from_dict(vgm.to_dict()) == vgm and "graph_threshold" in vgm.to_dict()
    assert "graph_threshold" not in get_model_config("nav_a3c").to_dict()


@pytest.fixture(scope="module")
def tiny_vgm_run(tmp_path_factory):
    """A one-house collection (tiny memory), `nue train --model vgm_tiny` on it (a few contrastive and BC steps)."""
    from nue.nerf.config import get_memory
    from nue.train.collect import CollectConfig, collect

    root = tmp_path_factory.mktemp("vgm")
    shutil.copytree(BOX_ROOM, root / "room_a")
    memory = get_memory("fast").replace(name="tiny", train_rays=32, iters_per_update=1)
    collect(root / "demos", CollectConfig(scene_dirs=(str(root / "room_a"),), episodes_per_bin=1, heldout_per_bin=1,
                                          memory=memory), root / "scenes", workers=1, progress=False)
    tiny = get_model_config("vgm").replace(name="vgm_tiny", embed_steps=4, embed_batch=8, graph_nodes=16)
    with pytest.MonkeyPatch.context() as patch:
        patch.setitem(MODEL_PRESETS, "vgm_tiny", tiny)
        res = nue_here("train", "--data", root / "demos", "--out", root / "run", "--model", "vgm_tiny", "--steps", 4,
                       "--batch-size", 2, "--warmup", 1, "--eval-every", 2)
    assert res.returncode == 0, res.stderr
    return root


@pytest.mark.timeout(900)  # with the tiny collection (~15 s idle): ~250 s on a machine loaded 4x over
def test_nue_train_vgm_pretrains_the_embedding_then_imitates_and_checkpoints_round_trip(tiny_vgm_run):
    from nue.policy.checkpoint import load_checkpoint, load_policy

    ck = load_checkpoint(tiny_vgm_run / "run" / "last.pt")
    assert ck["step"] == 4 and "action_accuracy" in ck["metrics"]
    model, header = load_policy(tiny_vgm_run / "run" / "last.pt")
    assert header.model.name == "vgm_tiny" and header.model.embed_steps == 4
    for k, v in model.state_dict().items():
        assert torch.equal(v, ck["model_state"][k]), k
    torch.manual_seed(0)
    fresh = build_model(header.model).embed.state_dict()  # what the embedding was before its pre-training
    assert any(not torch.equal(fresh[k], ck["model_state"][f"embed.{k}"]) for k in fresh if "running" not in k)


@pytest.mark.timeout(900)  # with the tiny collection (~15 s idle): ~250 s on a machine loaded 4x over
def test_nue_eval_runs_a_vgm_checkpoint(tiny_vgm_run, box_scene, box_nav, box_renderer):
    import json

    from nue.sim.episode_gen import EpisodeGenConfig, generate_episodes
    from nue.sim.episodes import save_episodes

    eps_dir = tiny_vgm_run / "episodes"
    eps_dir.mkdir()
    eps = generate_episodes(box_scene, "paper", EpisodeGenConfig(per_bin=1), seed=4, navgrid=box_nav,
                            renderer=box_renderer)
    save_episodes(eps_dir / "box_room.json", eps[:1], "paper")
    out = tiny_vgm_run / "records.jsonl"
    res = nue_here("eval", "-c", f"vgm={tiny_vgm_run / 'run' / 'best.pt'}", "--out", out, "--episodes-dir", eps_dir,
                   "--scenes-root", FIXTURES, "--max-steps", 12)
    assert res.returncode == 0, res.stderr
    (rec,) = [json.loads(line) for line in out.read_text().splitlines()]
    assert rec["method"] == "vgm" and 1 <= rec["steps"] <= 12


@pytest.mark.timeout(900)  # with the tiny collection (~15 s idle): ~250 s on a machine loaded 4x over
def test_vgm_imitation_loss_falls_on_the_tiny_collection(tiny_vgm_run, tmp_path):
    """40 steps of behaviour cloning (after 4 contrastive steps) bring the loss on every training step, the graph built
    along each whole episode, well below the initial one."""
    from nue.policy.checkpoint import load_checkpoint
    from nue.sim.task import get_task
    from nue.train.bc import TrainConfig, bc_loss, class_weights, train
    from nue.train.dataset import DemoSet

    tiny = get_model_config("vgm").replace(name="vgm_tiny", embed_steps=4, embed_batch=8, graph_nodes=16)
    data = DemoSet(tiny_vgm_run / "demos", "train")
    cfg = tiny.for_task(get_task("paper"))

    def loss_of(state_dict) -> float:
        model = build_model(cfg)
        model.load_state_dict(state_dict)
        model.eval()
        total = 0.0
        with torch.no_grad():
            for e, n in enumerate(data.lengths):
                t = np.arange(n)
                batch = data.batch(np.full((n, 1), e), t[:, None], cfg)
                out = model.forward_sequence(batch.inp, None, torch.zeros(n, 1, dtype=torch.bool))
                total += float(bc_loss(out, batch, class_weights(data.action_counts(3), 0.5), 0.5)[0]) * n
        return total / len(data)

    with pytest.MonkeyPatch.context() as patch:
        patch.setitem(MODEL_PRESETS, "vgm_tiny", tiny)
        res = train(TrainConfig(data=str(tiny_vgm_run / "demos"), out=str(tmp_path / "run"), model="vgm_tiny", steps=40,
                                batch_size=4, seq_len=8, warmup=4, eval_every=40, lr=2e-3, precision="fp32"),
                    progress=False)
    state = load_checkpoint(res.last)["model_state"]
    torch.manual_seed(0)
    init = build_model(cfg).state_dict()
    init.update({k: v for k, v in state.items() if k.startswith("embed.")})  # the same (pre-trained) embedding
    before, after = loss_of(init), loss_of(state)
    assert after < 0.8 * before, (before, after)  # measured: 1.10 -> 0.75


def test_the_goal_is_encoded_once_per_episode_in_eval_mode_and_gives_the_same_actions():
    cfg = get_model_config("vgm")
    torch.manual_seed(0)
    model = build_model(cfg).eval()
    g = torch.Generator().manual_seed(0)
    goal = torch.rand(1, 3, *cfg.goal_size, generator=g)
    frames = [torch.rand(1, 4, *cfg.frame_size, generator=g) for _ in range(3)]
    calls = []
    model.goal_encoder.register_forward_hook(lambda *a: calls.append(1))
    with torch.no_grad():
        s = model.initial_state(1)
        kept = []
        for f in frames:
            out = model(PolicyInput(rgbd=f, goal=goal), s)
            s = out.state
            kept.append(out.logits)
        s = model.initial_state(1)
        fresh = []
        for f in frames:
            out = model(PolicyInput(rgbd=f, goal=goal.clone()), s)  # a new tensor each step: encoded each step
            s = out.state
            fresh.append(out.logits)
    assert len(calls) == 1 + 3 and torch.equal(torch.cat(kept), torch.cat(fresh))
