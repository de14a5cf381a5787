"""Tests for nue.policy: blocks (residual, CBAM), NUE branches and switches, baselines, interface, overfitting."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
import torch.nn.functional as F
from torch import nn

from nue.errors import ConfigError
from nue.policy import (
    ABLATION_PRESETS,
    CBAM,
    ConvBranch,
    MODEL_PRESETS,
    ChannelAttention,
    ModelConfig,
    NavA3CPolicy,
    NUEPolicy,
    PolicyInput,
    ResidualBlock,
    SpatialAttention,
    SubsampledPointwiseConv,
    angle_l1_loss,
    build_model,
    choose_actions,
    detach_state,
    get_model_config,
    prepare_input,
    wrap_angle_t,
)
from nue.sim.task import TASK_PRESETS

torch.set_num_threads(1)

# Table I ablation rows: (f_u, AT, CBAM).
TABLE_ONE = {
    "abl_none": (False, False, False),
    "abl_fu": (True, False, False),
    "abl_at_cbam": (False, True, True),
    "abl_fu_cbam": (True, False, True),
    "abl_fu_at": (True, True, False),
    "nue": (True, True, True),
}

ACTING_PRESETS = [name for name, cfg in MODEL_PRESETS.items() if cfg.kind != "nrns"]
"""Presets whose network picks actions (NRNS's distance network is tested in tests/test_nrns.py)."""


def random_input(config: ModelConfig, batch: int, gen: torch.Generator, time: int | None = None) -> PolicyInput:
    """A random PolicyInput at the config's sizes, with a leading time dim if ``time`` is given."""
    lead = (batch,) if time is None else (time, batch)
    h, w = config.map_size

    def r(*shape):
        return torch.rand(*lead, *shape, generator=gen)

    return PolicyInput(
        rgbd=r(4, *config.frame_size),
        goal=r(3, *config.goal_size),
        i_u=r(1, h, w) * 10.0 if config.uses_i_u else None,
        i_cog=torch.randn(*lead, config.cog_channels, h, w, generator=gen) if config.uses_i_cog else None,
        panorama=r(*config.panorama_shape) if config.uses_panorama else None,
    )


def count(model: nn.Module, kind: type) -> int:
    return sum(isinstance(m, kind) for m in model.modules())


# --- blocks -------------------------------------------------------------------------------------


def test_residual_block_shapes_and_bypass():
    torch.manual_seed(0)
    down = ResidualBlock(1, 8, stride=2)
    assert down(torch.rand(2, 1, 45, 60)).shape == (2, 8, 23, 30)
    assert isinstance(down.bypass, nn.Sequential)  # projection: 1x1 conv + BN
    same = ResidualBlock(8, 8, stride=1)
    assert isinstance(same.bypass, nn.Identity)
    assert same(torch.rand(2, 8, 5, 7)).shape == (2, 8, 5, 7)


def test_subsampled_pointwise_conv_is_a_strided_1x1_conv():
    """The bypass reads x[..., ::2, ::2] with a stride-1 1x1 conv: the function and the parameters of
    nn.Conv2d(k=1, stride=2) (old checkpoints load), odd sizes included."""
    torch.manual_seed(0)
    fast = SubsampledPointwiseConv(5, 3, stride=2)
    assert [n for n, _ in fast.named_parameters()] == ["weight"] and fast.weight.shape == (3, 5, 1, 1)
    x = torch.randn(2, 5, 7, 9, requires_grad=True)
    y = fast(x)
    ref = F.conv2d(x, fast.weight, stride=2)
    assert y.shape == ref.shape == (2, 3, 4, 5)
    torch.testing.assert_close(y, ref)
    y.square().sum().backward()
    g_fast, gx_fast = fast.weight.grad.clone(), x.grad.clone()
    fast.weight.grad, x.grad = None, None
    ref.square().sum().backward()
    torch.testing.assert_close(g_fast, fast.weight.grad)
    torch.testing.assert_close(gx_fast, x.grad)
    assert gx_fast[..., 1::2, :].abs().sum() == 0  # odd rows are never read
    block = ResidualBlock(5, 3, stride=2)
    assert "bypass.0.weight" in block.state_dict() and isinstance(block.bypass[0], SubsampledPointwiseConv)


def test_cbam_on_hand_built_input():
    """2 channels x 2 x 2, identity channel MLP, 1x1 spatial conv with weights (avg: 0.5, max: -1)."""
    cbam = CBAM(2, reduction=1, kernel=1)
    with torch.no_grad():
        for lin in (cbam.channel.mlp[0], cbam.channel.mlp[2]):
            lin.weight.copy_(torch.eye(2))
            lin.bias.zero_()
        cbam.spatial.conv.weight.copy_(torch.tensor([0.5, -1.0]).reshape(1, 2, 1, 1))
    f0 = [[1.0, 2.0], [3.0, 6.0]]  # avg 3, max 6
    f1 = [[0.0, 0.0], [0.0, 2.0]]  # avg 0.5, max 2
    x = torch.tensor([[f0, f1]])

    def sig(z):
        return 1.0 / (1.0 + math.exp(-z))

    mc = [sig(3.0 + 6.0), sig(0.5 + 2.0)]  # eq. 8: sigmoid(MLP(avg) + MLP(max)), MLP = identity here
    assert torch.allclose(cbam.channel(x).flatten(), torch.tensor(mc), atol=1e-6)
    expected = torch.zeros(1, 2, 2, 2)
    for i in range(2):
        for j in range(2):
            a, b = mc[0] * f0[i][j], mc[1] * f1[i][j]
            ms = sig(0.5 * (a + b) / 2 - 1.0 * max(a, b))  # eq. 9 on F' = M_C * F: conv([avg_c, max_c])
            expected[0, 0, i, j], expected[0, 1, i, j] = ms * a, ms * b
    assert torch.allclose(cbam(x), expected, atol=1e-6)


def test_spatial_attention_uses_max_not_avg_twice():
    sa = SpatialAttention(kernel=3)
    with torch.no_grad():
        sa.conv.weight.zero_()
        sa.conv.weight[0, 1, 1, 1] = 1.0  # centre tap on the second pooled channel only
    x = torch.tensor([[[[1.0, -2.0]], [[3.0, 4.0]]]])  # (1, 2, 1, 2): channel max (3, 4), mean (2, 1)
    assert torch.allclose(sa(x).flatten(), torch.sigmoid(torch.tensor([3.0, 4.0])))


@pytest.mark.slow
@pytest.mark.timeout(600)  # one inductor compile: ~10-20 s on an idle core
def test_compiled_cbam_branch_has_finite_gradients_under_bf16_autocast():
    """f_u's branch (1 channel in, CBAM on a 16-channel grid) compiled under bf16 autocast: with ``amax`` in the
    attention pools its gradients were NaN from the first step (inductor's amax backward compares a recomputed
    fp32 input with the bf16-rounded maximum and divides by a tie count of 0), so `nue train --compile` of NUE
    failed on every bf16 CPU. The compiled gradient must also be eager's up to bf16 rounding."""
    branch = ConvBranch(1, (8, 16), (6, 8), 64, cbam=True, cbam_reduction=4, cbam_kernel=3)
    x = torch.rand(4, 1, 45, 60, generator=torch.Generator().manual_seed(0))
    grads = []
    for net in (branch, torch.compile(branch, dynamic=False)):
        branch.zero_grad()
        with torch.autocast("cpu", dtype=torch.bfloat16):
            y = net(x)
        y.float().square().mean().backward()
        grads.append({n: p.grad.clone() for n, p in branch.named_parameters()})
    eager, compiled = grads
    assert all(bool(torch.isfinite(g).all()) for g in compiled.values()), [n for n, g in compiled.items()
                                                                            if not torch.isfinite(g).all()]
    e, c = (torch.cat([g[n].flatten() for n in eager]) for g in (eager, compiled))
    assert float((c - e).norm() / e.norm()) < 0.1  # measured 0.015 (single tensors of small norm differ more)


def test_attention_max_pools_route_the_gradient_to_one_maximum():
    """The max pools use max(...).values: a tie's gradient goes to one of the tied entries (amax split it)."""
    sa = SpatialAttention(kernel=1)
    with torch.no_grad():
        sa.conv.weight.copy_(torch.tensor([0.0, 1.0]).reshape(1, 2, 1, 1))  # sigmoid(channel max)
    x = torch.tensor([[[[2.0]], [[2.0]], [[1.0]]]], requires_grad=True)  # (1, 3, 1, 1): channels 0 and 1 tie
    sa(x).sum().backward()
    g = x.grad.flatten()
    s = torch.sigmoid(torch.tensor(2.0))
    assert torch.allclose(g.sum(), s * (1 - s)) and int((g != 0).sum()) == 1 and g[2] == 0


def test_channel_attention_shape_and_range():
    ca = ChannelAttention(16, reduction=4)
    assert ca.mlp[0].out_features == 4
    m = ca(torch.randn(3, 16, 6, 8))
    assert m.shape == (3, 16, 1, 1) and bool(((m > 0) & (m < 1)).all())


# --- configs and switches -----------------------------------------------------------------------


@pytest.mark.parametrize("name", list(TABLE_ONE))
def test_ablation_presets_have_exactly_their_modules(name):
    fu, at, cb = TABLE_ONE[name]
    cfg = get_model_config(name)
    assert (cfg.kind, cfg.use_uncertainty, cfg.use_aux, cfg.use_cbam) == ("nue", fu, at, cb)
    model = build_model(cfg)
    assert isinstance(model, NUEPolicy)
    assert (model.f_u is not None) == fu
    assert (model.aux_head is not None) == at
    assert count(model, CBAM) == (2 if fu else 1) * cb
    names = [n for n, _ in model.named_parameters()]
    assert any(n.startswith("f_u.") for n in names) == fu
    assert any(n.startswith("aux_head.") for n in names) == at
    assert any(".cbam." in n for n in names) == cb
    assert model.fusion.gate[0].in_features == 64 * (2 if fu else 1) + cfg.perception_dim
    assert cfg.uses_i_u == fu and cfg.uses_i_cog


def test_ablations_differ_from_nue_only_in_what_table_one_switches():
    """Each ablation is the full model with f_u / AT / CBAM switched: same layout (goal also in f_p), same sizes."""
    nue = get_model_config("nue")
    for name, (fu, at, cbam) in TABLE_ONE.items():
        cfg = get_model_config(name)
        assert cfg.goal_in_perception and cfg.goal_size == nue.goal_size == nue.frame_size, name
        assert cfg == nue.replace(name=name, use_uncertainty=fu, use_aux=at, use_cbam=cbam), name
    assert not get_model_config("nue_paper").goal_in_perception


def test_goal_in_perception_feeds_the_goal_to_f_p():
    paper, cfg = get_model_config("nue_paper"), get_model_config("nue")
    assert cfg.goal_in_perception and not paper.goal_in_perception
    assert paper.goal_size == (45, 60) and cfg.goal_size == cfg.frame_size == (90, 120)
    model = build_model(cfg)
    assert next(model.f_p.encoder.parameters()).shape[1] == 7 and next(build_model(paper).f_p.encoder.parameters()).shape[1] == 4
    torch.manual_seed(0)
    inp = PolicyInput(rgbd=torch.rand(2, 4, 90, 120), goal=torch.rand(2, 3, 90, 120), i_u=torch.rand(2, 1, 45, 60),
                      i_cog=torch.rand(2, 64, 45, 60))
    other = PolicyInput(inp.rgbd, torch.rand(2, 3, 90, 120), inp.i_u, inp.i_cog)
    model.eval()
    f_cog, _, f_p = model.features(inp)
    f_cog2, _, f_p2 = model.features(other)
    assert not torch.allclose(f_p, f_p2)  # the goal reaches f_p ...
    paper_model = build_model(paper).eval()
    small = PolicyInput(inp.rgbd, F.interpolate(inp.goal, size=(45, 60), mode="area"), inp.i_u, inp.i_cog)
    small2 = PolicyInput(inp.rgbd, F.interpolate(other.goal, size=(45, 60), mode="area"), inp.i_u, inp.i_cog)
    assert torch.equal(paper_model.features(small)[2], paper_model.features(small2)[2])  # ... not in the paper's layout
    with pytest.raises(ConfigError):
        get_model_config("fr").replace(goal_in_perception=True)


def test_preset_sets_and_baselines():
    assert set(ABLATION_PRESETS) | {"nue"} == set(TABLE_ONE)
    assert {"fr", "nav_a3c"} <= set(MODEL_PRESETS)
    for name in ("fr", "nav_a3c"):
        cfg = get_model_config(name)
        assert not cfg.uses_memory_maps and cfg.goal_size == cfg.frame_size
        model = build_model(cfg)
        assert count(model, CBAM) == 0 and count(model, nn.LSTMCell) == (name == "nav_a3c")
        assert model.aux_head is None


def test_config_validation_roundtrip_and_task():
    cfg = get_model_config("abl_fu_at").replace(map_grid=(3, 4))
    assert ModelConfig.from_dict(cfg.to_dict()) == cfg
    assert get_model_config("nue").for_task(TASK_PRESETS["habitat"]).num_actions == 4
    with pytest.raises(ConfigError):
        get_model_config("nope")
    with pytest.raises(ConfigError):
        ModelConfig(kind="fr")  # use_uncertainty / use_cbam default True: not for a baseline
    with pytest.raises(ConfigError):
        ModelConfig.from_dict({**cfg.to_dict(), "bogus": 1})


# --- forward: shapes, gradients, interface ------------------------------------------------------


@pytest.mark.parametrize("map_size", [(45, 60), (90, 120)])
@pytest.mark.parametrize("name", ACTING_PRESETS)
def test_output_shapes(name, map_size):
    cfg = get_model_config(name).replace(map_height=map_size[0], map_width=map_size[1])
    cfg = cfg.for_task(TASK_PRESETS["habitat"])
    torch.manual_seed(0)
    model = build_model(cfg).eval()
    gen = torch.Generator().manual_seed(1)
    inp = random_input(cfg, 2, gen)
    with torch.no_grad():
        out = model(inp, model.initial_state(2))
        seq = model.forward_sequence(random_input(cfg, 2, gen, time=3), model.initial_state(2))
    assert out.logits.shape == (2, 4) and seq.logits.shape == (3, 2, 4)
    if cfg.use_aux:
        assert out.aux_angle.shape == (2,) and seq.aux_angle.shape == (3, 2)
        assert bool((out.aux_angle.abs() <= math.pi).all())
    else:
        assert out.aux_angle is None and seq.aux_angle is None
    assert torch.isfinite(out.logits).all()
    if cfg.recurrent:
        expected = [(2, cfg.gru_dim)] if cfg.gru_dim else [(2, cfg.lstm_dim)] * 2
        if cfg.kind == "vgm":  # the LSTM's (h, c), then the graph: nodes, mask, adjacency, visits, current node, step
            n, e = cfg.graph_nodes, cfg.embed_dim
            expected += [(2, n, e), (2, n), (2, n, n), (2, n), (2,), (2,)]
        assert [s.shape for s in out.state] == expected and [s.shape for s in seq.state] == expected
    else:
        assert out.state is None and seq.state is None


def test_aux_head_works_on_baselines_too():
    cfg = get_model_config("fr").replace(use_aux=True)
    out = build_model(cfg)(random_input(cfg, 2, torch.Generator().manual_seed(0)))
    assert out.aux_angle.shape == (2,)


@pytest.mark.parametrize("name", ACTING_PRESETS)
def test_gradients_reach_every_enabled_parameter(name):
    cfg = get_model_config(name)
    if cfg.kind == "vgm":  # every frame a new node, so the attention has two nodes to weigh at the second step
        cfg = cfg.replace(graph_threshold=2.0)
    torch.manual_seed(0)
    model = build_model(cfg).train()
    gen = torch.Generator().manual_seed(2)
    inp = random_input(cfg, 2, gen, time=2)  # T = 2 so the LSTM's recurrent weights see a nonzero h
    inp.rgbd.requires_grad_(True)
    if inp.i_u is not None:
        inp.i_u.requires_grad_(True)
    out = model.forward_sequence(inp, model.initial_state(2))
    target = torch.randint(0, cfg.num_actions, (2, 2), generator=gen)
    loss = F.cross_entropy(out.logits.reshape(4, -1), target.reshape(4))
    if out.aux_angle is not None:
        loss = loss + angle_l1_loss(out.aux_angle, torch.rand(2, 2, generator=gen) * 6 - 3)
    if out.goal_view is not None:
        loss = loss + out.goal_view.sum() + out.goal_log_distance.square().sum()
    loss.backward()
    for n, p in model.named_parameters():
        if not p.requires_grad:  # VGM's embedding network: frozen after its contrastive pre-training
            assert cfg.kind == "vgm" and n.startswith("embed.") and p.grad is None, n
            continue
        assert p.grad is not None, n
        assert torch.isfinite(p.grad).all() and p.grad.abs().sum() > 0, n
    assert inp.rgbd.grad is not None
    if cfg.uses_i_u:
        assert inp.i_u.grad is not None and inp.i_u.grad.abs().sum() > 0


def test_disabled_uncertainty_branch_ignores_i_u():
    cfg = get_model_config("abl_at_cbam")
    torch.manual_seed(0)
    model = build_model(cfg).eval()
    inp = random_input(cfg, 2, torch.Generator().manual_seed(0))
    i_u = torch.rand(2, 1, *cfg.map_size, requires_grad=True)
    out = model(PolicyInput(inp.rgbd, inp.goal, i_u, inp.i_cog))
    out.logits.sum().backward()
    assert i_u.grad is None  # no path from I_u to the output


def test_uncertainty_normalisation_handles_wide_range():
    cfg = get_model_config("nue")
    torch.manual_seed(0)
    model = build_model(cfg).eval()
    inp = random_input(cfg, 2, torch.Generator().manual_seed(0))
    with torch.no_grad():
        lo = model(PolicyInput(inp.rgbd, inp.goal, torch.full_like(inp.i_u, 1e-4), inp.i_cog)).logits
        hi = model(PolicyInput(inp.rgbd, inp.goal, torch.full_like(inp.i_u, 1e6), inp.i_cog)).logits
    assert torch.isfinite(hi).all() and not torch.allclose(lo, hi)


@pytest.mark.parametrize("name", ["abl_none", "nue", "fr"])
def test_reactive_forward_sequence_equals_folded_forward(name):
    cfg = get_model_config(name)
    torch.manual_seed(0)
    model = build_model(cfg).eval()
    seq = random_input(cfg, 2, torch.Generator().manual_seed(3), time=3)
    with torch.no_grad():
        a = model.forward_sequence(seq, None)
        b = torch.stack([model(seq.step(t)).logits for t in range(3)])
    assert torch.allclose(a.logits, b, atol=1e-5)


def test_nav_a3c_state_carries_information():
    cfg = get_model_config("nav_a3c")
    torch.manual_seed(0)
    model = build_model(cfg).eval()
    assert isinstance(model, NavA3CPolicy)
    gen = torch.Generator().manual_seed(4)
    seq_a = random_input(cfg, 1, gen, time=3)
    first_b = random_input(cfg, 1, gen)  # a different past at t = 0, identical frames afterwards
    seq_b = PolicyInput.cat([PolicyInput.stack([first_b]), seq_a.index(slice(1, None))])
    with torch.no_grad():
        out_a = model.forward_sequence(seq_a, model.initial_state(1))
        out_b = model.forward_sequence(seq_b, model.initial_state(1))
        assert not torch.equal(out_a.logits[1:], out_b.logits[1:])
        assert not torch.equal(out_a.state[0], out_b.state[0])
        # A reset at t = 1 erases the past: the two runs then agree from t = 1 on.
        reset = torch.tensor([[False], [True], [False]])
        ra = model.forward_sequence(seq_a, model.initial_state(1), reset)
        rb = model.forward_sequence(seq_b, model.initial_state(1), reset)
        assert torch.allclose(ra.logits[1:], rb.logits[1:], atol=1e-6)
        # Step-by-step forward == forward_sequence, and the state changes.
        state = model.initial_state(1)
        for t in range(3):
            out = model(seq_a.step(t), state)
            assert torch.allclose(out.logits, out_a.logits[t], atol=1e-5)
            assert not torch.equal(out.state[0], state[0])
            state = out.state
    assert detach_state(state)[0].requires_grad is False and detach_state(None) is None


def test_nav_a3c_learns_to_recall_a_past_frame():
    """Label at t = 1 = brightness of the frame at t = 0; frames at t = 1 are identical noise.

    A reactive model cannot beat chance here; the LSTM must carry the bit across the step.
    """
    cfg = get_model_config("nav_a3c").replace(frame_height=24, frame_width=32, perception_grid=(3, 4))
    torch.manual_seed(0)
    model = build_model(cfg).train()
    gen = torch.Generator().manual_seed(7)
    b = 32
    bright = torch.arange(b) % 2 == 1
    first = torch.where(bright[:, None, None, None], 0.9, 0.1).expand(b, 4, 24, 32)
    second = torch.rand(1, 4, 24, 32, generator=gen).expand(b, 4, 24, 32)
    goal = torch.rand(1, 3, 24, 32, generator=gen).expand(2, b, 3, 24, 32)
    seq = PolicyInput(rgbd=torch.stack([first, second]), goal=goal)
    labels = bright.long() + 1  # TURN_LEFT after a bright frame, TURN_RIGHT after a dark one
    opt = torch.optim.AdamW(model.parameters(), lr=3e-3)
    for _ in range(60):
        logits = model.forward_sequence(seq, model.initial_state(b)).logits[1]
        loss = F.cross_entropy(logits, labels)
        opt.zero_grad()
        loss.backward()
        opt.step()
    _settle_batchnorm(model, seq.flatten_time(), sequence=seq)
    model.eval()
    with torch.no_grad():
        pred = model.forward_sequence(seq, model.initial_state(b)).logits[1].argmax(-1)
    assert torch.equal(pred, labels)


@pytest.mark.parametrize("name", ["nue", "nav_a3c"])
def test_act_greedy_and_sampling(name):
    cfg = get_model_config(name)
    torch.manual_seed(0)
    model = build_model(cfg).eval()
    inp = random_input(cfg, 4, torch.Generator().manual_seed(5))

    def act(greedy=False, generator=None):  # what PolicyAgent.act does, batched
        with torch.no_grad():
            out = model(inp, model.initial_state(4))
        return choose_actions(out.logits, greedy, generator), out.state

    with torch.no_grad():
        logits = model(inp, model.initial_state(4)).logits
    greedy, state = act(greedy=True)
    assert torch.equal(greedy, logits.argmax(-1)) and greedy.dtype == torch.long
    assert (state is None) == (not cfg.recurrent)
    s1, _ = act(generator=torch.Generator().manual_seed(9))
    s2, _ = act(generator=torch.Generator().manual_seed(9))
    assert torch.equal(s1, s2) and s1.shape == (4,)
    last = (model.fusion.policy if name == "nue" else model.policy)[-1]
    with torch.no_grad():  # a head that puts all mass on action 1
        last.weight.zero_()
        last.bias.copy_(torch.tensor([-50.0, 50.0, -50.0]))
    sampled, _ = act(generator=torch.Generator().manual_seed(1))
    assert sampled.tolist() == [1, 1, 1, 1]


def test_angle_l1_loss_wraps():
    pred = torch.tensor([math.pi - 0.1, 0.3, -3.0], requires_grad=True)
    target = torch.tensor([-math.pi + 0.1, 0.1, 3.0])
    loss = angle_l1_loss(pred, target)
    expected = (0.2 + 0.2 + (2 * math.pi - 6.0)) / 3
    assert abs(loss.item() - expected) < 1e-5
    loss.backward()
    # d|wrap(p - t)|/dp = sign(wrap(p - t)) / n; wrap(p - t) = -0.2, 0.2, 2 pi - 6 across the seam
    assert torch.allclose(pred.grad, torch.tensor([-1.0, 1.0, 1.0]) / 3, atol=1e-5)
    w = wrap_angle_t(torch.tensor([3 * math.pi / 2, -3 * math.pi / 2, 0.5]))
    assert torch.allclose(w, torch.tensor([-math.pi / 2, math.pi / 2, 0.5]), atol=1e-6)


# --- prepare_input ------------------------------------------------------------------------------


def test_prepare_input_normalises_and_resizes():
    cfg = get_model_config("nue_paper")
    rgb = np.full((180, 240, 3), 255, np.uint8)
    rgb[..., 1] = 51
    depth = np.full((180, 240), 2.5, np.float32)
    depth[:90] = 10.0  # beyond max_depth: clipped to 1
    depth[0, 0] = np.nan
    goal = np.zeros((180, 240, 3), np.uint8)
    i_u = np.full((45, 60), 3.0, np.float32)
    i_cog = np.ones((64, 90, 120), np.float32)  # rendered at another size: area-resized to the map size
    inp = prepare_input(rgb, depth, goal, i_u, i_cog, cfg)
    assert inp.rgbd.shape == (1, 4, 90, 120) and inp.rgbd.dtype == torch.float32
    assert torch.allclose(inp.rgbd[0, 0], torch.ones(90, 120))
    assert torch.allclose(inp.rgbd[0, 1], torch.full((90, 120), 0.2))
    assert torch.allclose(inp.rgbd[0, 3, 50:], torch.full((40, 120), 0.5))
    assert torch.allclose(inp.rgbd[0, 3, 1:45], torch.ones(44, 120)) and 0.7 < inp.rgbd[0, 3, 0, 0] < 1.0
    assert inp.goal.shape == (1, 3, 45, 60) and inp.i_u.shape == (1, 1, 45, 60) and inp.i_cog.shape == (1, 64, 45, 60)
    assert torch.allclose(inp.i_u, torch.full_like(inp.i_u, 3.0))  # raw: the model applies log1p
    same = prepare_input(torch.from_numpy(rgb), torch.from_numpy(depth[..., None]), torch.from_numpy(goal),
                         torch.from_numpy(i_u[None]), torch.from_numpy(i_cog), cfg)
    assert all(torch.equal(getattr(inp, k), getattr(same, k)) for k in ("rgbd", "goal", "i_u", "i_cog"))
    as_float = prepare_input(rgb / np.float32(255), depth, goal.astype(np.float32), i_u, i_cog, cfg)
    assert torch.allclose(as_float.rgbd, inp.rgbd) and torch.allclose(as_float.goal, inp.goal)
    with pytest.raises(ValueError, match="rgb"):
        prepare_input(rgb.astype(np.float32), depth, goal, i_u, i_cog, cfg)  # float 0..255: ambiguous

    batched = prepare_input(np.stack([rgb] * 3), np.stack([depth] * 3), np.stack([goal] * 3),
                            np.stack([i_u] * 3), np.stack([i_cog] * 3), cfg)
    assert batched.batch_size == 3 and torch.equal(batched.rgbd[2], inp.rgbd[0])

    fr = prepare_input(rgb, depth, goal, i_u, i_cog, get_model_config("fr"))  # unused maps are dropped
    assert fr.goal.shape == (1, 3, 90, 120) and fr.i_u is None and fr.i_cog is None
    no_u = prepare_input(rgb, depth, goal, None, i_cog, get_model_config("abl_at_cbam"))
    assert no_u.i_u is None
    with pytest.raises(ValueError, match="i_u"):
        prepare_input(rgb, depth, goal, None, i_cog, cfg)
    with pytest.raises(ValueError, match="depth"):
        prepare_input(rgb, depth[:10], goal, i_u, i_cog, cfg)
    out = build_model(cfg).eval()(inp)
    assert out.logits.shape == (1, 3)


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs CUDA")
def test_runs_on_cuda():
    for name in ("nue", "nav_a3c"):
        cfg = get_model_config(name)
        model = build_model(cfg).cuda().eval()
        inp = random_input(cfg, 2, torch.Generator().manual_seed(0)).to("cuda")
        with torch.no_grad():
            logits = model(inp, model.initial_state(2, "cuda")).logits
        actions = choose_actions(logits, generator=torch.Generator("cuda").manual_seed(0))
        assert actions.device.type == "cuda"


# --- overfitting ----------------------------------------------------------------------------------


def _settle_batchnorm(model: nn.Module, inp: PolicyInput, sequence: PolicyInput | None = None) -> None:
    """Set every BN's running statistics to the statistics of a batch (one cumulative pass).

    Uses ``model.forward_sequence(sequence)`` if given (T folded into B by the encoder), else ``model(inp)``.
    """
    bns = [m for m in model.modules() if isinstance(m, nn.BatchNorm2d)]
    for bn in bns:
        bn.reset_running_stats()
        bn.momentum = None
    model.train()
    with torch.no_grad():
        model.forward_sequence(sequence) if sequence is not None else model(inp)
    for bn in bns:
        bn.momentum = 0.1


def test_nue_overfits_32_samples():
    """The full-size model memorises 32 random samples (labels and goal angles) in about 20 iterations."""
    cfg = get_model_config("nue")
    torch.manual_seed(0)
    model = build_model(cfg)
    gen = torch.Generator().manual_seed(6)
    n = 32  # 64 took 34 iterations of twice the cost: 4 x the time for the same check
    inp = random_input(cfg, n, gen)
    labels = torch.randint(0, cfg.num_actions, (n,), generator=gen)
    angles = torch.rand(n, generator=gen) * 2 * math.pi - math.pi
    opt = torch.optim.AdamW(model.parameters(), lr=2e-3)
    model.train()
    fitted = []
    for _ in range(150):
        out = model(inp)
        loss = F.cross_entropy(out.logits, labels) + 0.5 * angle_l1_loss(out.aux_angle, angles)
        opt.zero_grad()
        loss.backward()
        opt.step()
        fitted.append((out.logits.argmax(-1) == labels).float().mean().item())
        if fitted[-1] == 1.0 and loss.item() < 0.1:
            break
    assert fitted[0] < 0.6  # untrained: near chance (1/3)
    _settle_batchnorm(model, inp)
    model.eval()
    with torch.no_grad():
        out = model(inp)
    accuracy = (out.logits.argmax(-1) == labels).float().mean().item()
    assert accuracy >= 0.95
    assert angle_l1_loss(out.aux_angle, angles).item() < 0.5  # random guessing: pi / 2


def _two_pasts(model, cfg, seed: int, time: int):
    """Two input sequences that differ only in their first step, and the model's outputs on each from a fresh state."""
    gen = torch.Generator().manual_seed(seed)
    seq_a = random_input(cfg, 1, gen, time=time)
    seq_b = PolicyInput.cat([PolicyInput.stack([random_input(cfg, 1, gen)]), seq_a.index(slice(1, None))])
    with torch.no_grad():
        return seq_a, seq_b, model.forward_sequence(seq_a, model.initial_state(1)), \
            model.forward_sequence(seq_b, model.initial_state(1))


def test_nue_gru_state_carries_information_and_resets():
    """NUE with a GRU after the fusion: a different past changes later logits, a reset erases it, step by step equals
    forward_sequence; without the GRU (``nue``) the config dict and modules are as before."""
    cfg = get_model_config("nue_gru").replace(map_height=12, map_width=16, frame_height=24, frame_width=32)
    assert cfg.recurrent and not get_model_config("nue").recurrent
    assert "gru_dim" not in get_model_config("nue").to_dict() and ModelConfig.from_dict(cfg.to_dict()) == cfg
    torch.manual_seed(0)
    model = build_model(cfg).eval()
    assert model.gru is not None and build_model(get_model_config("nue")).gru is None
    seq_a, seq_b, out_a, out_b = _two_pasts(model, cfg, seed=4, time=3)
    assert not torch.allclose(out_a.logits[1:], out_b.logits[1:], atol=1e-6)
    with torch.no_grad():
        reset = torch.tensor([[False], [True], [False]])
        ra = model.forward_sequence(seq_a, model.initial_state(1), reset)
        rb = model.forward_sequence(seq_b, model.initial_state(1), reset)
        assert torch.allclose(ra.logits[1:], rb.logits[1:], atol=1e-6)
        state = model.initial_state(1)
        for t in range(3):
            out = model(seq_a.step(t), state)
            assert torch.allclose(out.logits, out_a.logits[t], atol=1e-5)
            assert torch.allclose(out.aux_angle, out_a.aux_angle[t], atol=1e-6)
            state = out.state
    with pytest.raises(ConfigError):
        get_model_config("fr").replace(gru_dim=8)


def test_recurrent_ablations_differ_from_the_recurrent_nue_only_by_the_ablated_components():
    """``abl_*_gru`` (and their ``_lean`` twins) are the ablations with NUE's GRU: each config equals ``nue_gru``'s with
    the ablation's three switches, and the built model has the state (a past changes later logits)."""
    for abl in ABLATION_PRESETS:
        for suffix, ref in (("_gru", "nue_gru"), ("_gru_lean", "nue_gru_lean")):
            cfg, plain = get_model_config(abl + suffix), get_model_config(abl)
            switches = {k: getattr(plain, k) for k in ("use_uncertainty", "use_aux", "use_cbam")}
            assert cfg == get_model_config(ref).replace(name=abl + suffix, **switches) and cfg.recurrent
    cfg = get_model_config("abl_none_gru").replace(map_height=12, map_width=16, frame_height=24, frame_width=32)
    torch.manual_seed(0)
    model = build_model(cfg).eval()
    _, _, out_a, out_b = _two_pasts(model, cfg, seed=5, time=2)
    assert not torch.allclose(out_a.logits[1:], out_b.logits[1:], atol=1e-6)


def test_nue_pano_reads_the_panorama():
    """The panorama branch: the logits depend on the panorama (and only models with ``panorama_dim`` read it);
    prepare_input passes it through and refuses a missing or misshapen one."""
    cfg = get_model_config("nue_pano").replace(map_height=12, map_width=16, frame_height=24, frame_width=32)
    assert cfg.uses_panorama and not get_model_config("nue").uses_panorama
    assert "panorama_dim" not in get_model_config("nue").to_dict() and ModelConfig.from_dict(cfg.to_dict()) == cfg
    torch.manual_seed(0)
    model = build_model(cfg).eval()
    gen = torch.Generator().manual_seed(2)
    inp = random_input(cfg, 2, gen)
    other = PolicyInput(inp.rgbd, inp.goal, inp.i_u, inp.i_cog, inp.panorama.flip(1))
    with torch.no_grad():
        assert not torch.allclose(model(inp).logits, model(other).logits)
        with pytest.raises(ValueError, match="panorama"):
            model(PolicyInput(inp.rgbd, inp.goal, inp.i_u, inp.i_cog, None))
    rgb, depth = np.zeros((180, 240, 3), np.uint8), np.ones((180, 240), np.float32)
    pano = np.random.default_rng(0).random((8, 6, 8)).astype(np.float32)
    got = prepare_input(rgb, depth, rgb, np.ones((45, 60)), np.zeros((64, 45, 60)), cfg.replace(map_height=45, map_width=60),
                        panorama=pano)
    assert got.panorama.shape == (1, 8, 6, 8) and torch.allclose(got.panorama[0], torch.from_numpy(pano))
    with pytest.raises(ValueError, match="panorama"):
        prepare_input(rgb, depth, rgb, np.ones((45, 60)), np.zeros((64, 45, 60)), cfg.replace(map_height=45, map_width=60))
    with pytest.raises(ValueError, match="panorama"):
        prepare_input(rgb, depth, rgb, np.ones((45, 60)), np.zeros((64, 45, 60)), cfg.replace(map_height=45, map_width=60),
                      panorama=pano[:, :3])
