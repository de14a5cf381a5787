"""Volume rendering, sampling, loss and metrics of the NeRF memory against hand-computed values."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from nue.nerf.encoding import PositionalEncoding
from nue.nerf.quality import auroc, psnr
from nue.nerf.loss import memory_loss, uncertainty_nll
from nue.nerf.rays import SamplerConfig, depth_guided_samples
from nue.nerf.rendering import (
    compositing_weights,
    render_depth,
    render_features,
    render_rgb,
    render_uncertainty,
)

torch.set_num_threads(1)


def three_samples():
    density = torch.tensor([[1.0, 2.0, 0.0]], dtype=torch.float64)
    deltas = torch.full((1, 3), 0.5, dtype=torch.float64)
    return density, deltas


def test_compositing_three_samples_by_hand():
    density, deltas = three_samples()
    w, residual = compositing_weights(density, deltas)
    # alpha = 1 - exp(-sigma delta); T_1 = 1, T_2 = exp(-0.5), T_3 = exp(-1.5); w = T alpha
    a1, a2 = 1 - math.exp(-0.5), 1 - math.exp(-1.0)
    expected = [a1, math.exp(-0.5) * a2, 0.0]
    assert w[0].tolist() == pytest.approx(expected, abs=1e-12)
    assert w[0].tolist() == pytest.approx([0.3935, 0.3834, 0.0], abs=1e-4)
    assert residual.item() == pytest.approx(math.exp(-1.5), abs=1e-12)
    assert (w.sum() + residual).item() == pytest.approx(1.0, abs=1e-12)

    variance = torch.tensor([[0.1, 0.2, 0.3]], dtype=torch.float64)
    i_u = render_uncertainty(w, variance)  # sum w^2 beta^2 (squared weights, ActiveNeRF)
    assert i_u.item() == pytest.approx(expected[0] ** 2 * 0.1 + expected[1] ** 2 * 0.2, abs=1e-12)
    assert i_u.item() == pytest.approx(0.04488, abs=1e-5)
    with_unseen = render_uncertainty(w, variance, residual, unseen_variance=1.0)
    assert with_unseen.item() == pytest.approx(0.04488 + math.exp(-1.5), abs=1e-5)
    assert render_uncertainty(w, variance, residual, unseen_variance=0.0).item() == pytest.approx(i_u.item())

    feature = torch.tensor([[[1.0, 0.0, 2.0], [0.0, 1.0, 2.0], [5.0, 5.0, 5.0]]], dtype=torch.float64)
    i_cog = render_features(w, feature)
    assert i_cog[0].tolist() == pytest.approx([expected[0], expected[1], 2 * (expected[0] + expected[1])], abs=1e-12)
    rgb = render_rgb(w, feature)  # same contraction for colours
    assert rgb.shape == (1, 3)
    t = torch.tensor([[1.0, 2.0, 3.0]], dtype=torch.float64)
    d = render_depth(w, t)
    assert d.item() == pytest.approx((expected[0] * 1 + expected[1] * 2) / (expected[0] + expected[1]), abs=1e-12)


def test_docstring_examples():
    w = torch.tensor([[0.5, 0.25]])
    assert render_rgb(w, torch.tensor([[[1.0, 0, 0], [0, 1.0, 0]]]))[0].tolist() == [0.5, 0.25, 0.0]
    assert render_features(w, torch.tensor([[[2.0, 0], [4.0, 4.0]]]))[0].tolist() == [2.0, 1.0]
    assert render_depth(w, torch.tensor([[1.0, 4.0]])).item() == pytest.approx(2.0)
    nll = uncertainty_nll(torch.tensor([[0.5, 0.5, 0.5]]), torch.tensor([[0.7, 0.5, 0.5]]), torch.tensor([0.02]))
    assert nll.item() == pytest.approx(0.04 / 0.04 + 0.5 * math.log(0.02), abs=1e-6)
    enc = PositionalEncoding(1, 1)(torch.tensor([[0.5]]))
    assert enc[0].tolist() == pytest.approx([0.5, 1.0, 0.0], abs=1e-6)
    assert PositionalEncoding(3, 10).out_dim == 63 and PositionalEncoding(3, 4).out_dim == 27
    assert auroc(np.array([0.1, 0.4, 0.35, 0.8]), np.array([0, 0, 1, 1])) == pytest.approx(0.75)
    assert math.isnan(auroc(np.array([0.1, 0.2]), np.array([1, 1])))
    assert psnr(np.full((2, 3), 0.5), np.full((2, 3), 0.6)) == pytest.approx(20.0)


def test_compositing_gradients_match_finite_differences():
    torch.manual_seed(0)
    density = (torch.rand(4, 5, dtype=torch.float64) * 3).requires_grad_()
    deltas = torch.rand(4, 5, dtype=torch.float64) * 0.3 + 0.05
    variance = (torch.rand(4, 5, dtype=torch.float64) + 0.1).requires_grad_()

    def f(sig, var):
        w, res = compositing_weights(sig, deltas)
        return render_uncertainty(w, var, res, 1.0)

    assert torch.autograd.gradcheck(f, (density, variance))


def test_loss_terms():
    rgb_pred = torch.tensor([[0.5, 0.5, 0.5], [0.2, 0.2, 0.2]], requires_grad=True)
    rgb_true = torch.tensor([[0.7, 0.5, 0.5], [0.2, 0.2, 0.2]])
    var = torch.tensor([0.02, 0.5])
    density = torch.tensor([[1.0, 3.0], [0.0, 0.0]])
    terms = memory_loss(rgb_pred, rgb_true, var, density, density_weight=0.01)
    nll = ((0.04 / 0.04 + 0.5 * math.log(0.02)) + 0.5 * math.log(0.5)) / 2
    assert terms.nll.item() == pytest.approx(nll, abs=1e-6)
    assert terms.density.item() == pytest.approx(0.01 * 1.0, abs=1e-7)
    assert terms.total.item() == pytest.approx(nll + 0.01, abs=1e-6)
    terms.total.backward()
    assert rgb_pred.grad[0, 0].item() < 0  # pulls the prediction toward the target


def test_depth_guided_samples():
    cfg = SamplerConfig(band=1.0, near=0.05)
    s = depth_guided_samples(torch.tensor([2.0]), 2, cfg)
    assert s.t[0].tolist() == pytest.approx([1.5, 2.5]) and s.deltas[0].tolist() == pytest.approx([1.0, 1.0])
    # a surface closer than the band: samples never go below `near`
    s = depth_guided_samples(torch.tensor([0.3]), 4, cfg)
    assert s.t.min().item() >= 0.05 and (s.deltas >= 0).all()
    # invalid depth (NaN) -> uniform over [near, no_depth_range]
    s = depth_guided_samples(torch.tensor([float("nan")]), 4, cfg)
    assert s.t[0, 0].item() > 0.05 and s.t[0, -1].item() < cfg.no_depth_range
    assert s.deltas.sum().item() == pytest.approx(cfg.no_depth_range - 0.05, abs=1e-5)
    # concentration packs samples toward the surface
    tight = depth_guided_samples(torch.tensor([3.0]), 8, SamplerConfig(band=1.0, concentration=2.0))
    assert (tight.t - 3.0).abs().mean() < 0.5 * 1.0 * 0.9
    # stratified: inside the bins, reproducible from the generator
    g1, g2 = torch.Generator().manual_seed(3), torch.Generator().manual_seed(3)
    a = depth_guided_samples(torch.tensor([2.0, 4.0]), 8, cfg, g1)
    b = depth_guided_samples(torch.tensor([2.0, 4.0]), 8, cfg, g2)
    assert torch.equal(a.t, b.t)
    assert (a.t >= torch.tensor([[1.0], [3.0]])).all() and (a.t <= torch.tensor([[3.0], [5.0]])).all()
    # free-space samples lie in front of the band
    free = depth_guided_samples(torch.tensor([4.0]), 4, SamplerConfig(band=0.5, free_samples=3))
    assert free.t.shape == (1, 7) and (free.t[0, :3] < 3.5).all() and (free.t[0].diff() > 0).all()
