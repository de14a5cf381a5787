"""Radiance fields (MLP and voxel grid): outputs, gradients to every parameter, sparse grid updates."""

from __future__ import annotations

import pytest
import torch

from nue.nerf.field import FieldConfig, NeRFField
from nue.nerf.grid_field import GridField, GridFieldConfig, RowAdam
from nue.nerf.loss import memory_loss
from nue.nerf.rendering import compositing_weights, render_rgb, render_uncertainty

torch.set_num_threads(1)

SMALL_GRID = GridFieldConfig(voxel_size=0.25, half_extent=3.0, z_min=-1.0, z_max=2.0)


def make_fields():
    torch.manual_seed(0)
    return [NeRFField(FieldConfig()), GridField(SMALL_GRID, radius=12.0)]


def rays(n_rays=32, n_samples=6):
    g = torch.Generator().manual_seed(1)
    x = (torch.rand(n_rays, n_samples, 3, generator=g) - 0.5) * 0.3  # normalised positions (~ +-1.8 m)
    d = torch.nn.functional.normalize(torch.randn(n_rays, 3, generator=g), dim=-1)
    return x, d


@pytest.mark.parametrize("field", make_fields(), ids=["mlp", "grid"])
def test_field_outputs(field):
    x, d = rays()
    out = field(x, d)
    assert out.density.shape == (32, 6) and (out.density >= 0).all()
    assert out.rgb.shape == (32, 6, 3) and ((out.rgb >= 0) & (out.rgb <= 1)).all()
    assert out.variance.shape == (32, 6) and (out.variance >= field.config.beta_min).all()
    assert out.feature.shape == (32, 6, 64) and (out.feature >= 0).all()
    # a direction per ray equals the same direction repeated per point
    per_point = field(x, d[:, None, :].expand_as(x))
    assert torch.allclose(per_point.rgb, out.rgb, atol=1e-6) and torch.allclose(per_point.feature, out.feature, atol=1e-5)
    assert field.flops_per_point(8) > 0


@pytest.mark.parametrize("field", make_fields(), ids=["mlp", "grid"])
def test_gradients_reach_every_parameter(field):
    x, d = rays()
    if isinstance(field, GridField):  # give the grid some density so every head is in play
        with torch.no_grad():
            field.table[:, 0] = 0.2
            field.table[:, 2:].normal_(0, 0.1)
    out = field(x, d)
    w, residual = compositing_weights(out.density, torch.full_like(out.density, 0.05))
    target = torch.rand(32, 3, generator=torch.Generator().manual_seed(2))
    ray_var = render_uncertainty(w, out.variance) + 0.01
    terms = memory_loss(render_rgb(w, out.rgb), target, ray_var, out.density)
    (terms.total + 1e-3 * out.feature.mean()).backward()
    for name, p in field.named_parameters():
        assert p.grad is not None, name
        g = p.grad.coalesce().values() if p.grad.is_sparse else p.grad
        assert torch.isfinite(g).all(), name
        assert g.abs().sum() > 0, f"no gradient reaches {name}"


def test_grid_outside_points_read_the_untrained_row():
    field = GridField(SMALL_GRID, radius=12.0)
    far = torch.tensor([[[0.9, 0.9, 0.0]]])  # 10.8 m: outside the 3 m grid
    out = field(far, torch.tensor([[1.0, 0.0, 0.0]]))
    assert out.density.item() == pytest.approx(SMALL_GRID.init_density, rel=1e-4)
    assert out.variance.item() == pytest.approx(SMALL_GRID.init_variance, rel=1e-4)


def test_row_adam_updates_only_touched_rows():
    field = GridField(SMALL_GRID, radius=12.0)
    opt = RowAdam(field.table, lr=0.1)
    x, d = rays(4, 3)
    before = field.table.detach().clone()
    field(x, d).density.sum().backward()
    touched = torch.zeros(field.table.shape[0], dtype=torch.bool)
    touched[field.table.grad.coalesce().indices()[0]] = True
    opt.step()
    changed = (field.table.detach() != before).any(dim=1)
    assert changed.any() and not (changed & ~touched).any()
    # Adam's first step moves each touched entry with a non-zero gradient by lr against its sign
    moved = (field.table.detach() - before)[changed, 0]
    assert torch.allclose(moved.abs(), torch.full_like(moved, 0.1), atol=2e-3)
