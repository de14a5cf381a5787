"""The radiance field with uncertainty: position (+ view direction) -> density, RGB, variance, feature.

Paper eqs. 1, 2 and 11: ``[sigma, f, beta^2] = MLP_theta1,3(gamma_x(x))`` and
``f_c = MLP_theta2(f, gamma_d(d))`` with ``rgb = sigmoid(Linear(f_c))``; ``f_c`` (64-d) is the
per-point feature that volume rendering turns into ``I_cog``.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import nn
from torch.nn import functional as F

from nue.nerf.encoding import PositionalEncoding


@dataclass(frozen=True)
class FieldConfig:
    """Architecture of :class:`NeRFField` (paper sec. III-B; the authors' release in brackets)."""

    xyz_freqs: int = 10
    """Frequencies L of the position encoding [10]; positions are normalised to about [-1, 1]."""
    dir_freqs: int = 4
    """Frequencies of the view-direction encoding [4]."""
    width: int = 64
    """Width of every hidden layer of the trunk [64]."""
    depth: int = 4
    """Number of hidden layers of the trunk [4]."""
    skip: int = 2
    """Index of the trunk layer whose input is concatenated with the encoded position (-1: none)."""
    feature_dim: int = 64
    """Width of the intermediate feature f and of the colour feature f_c (= I_cog channels) [64]."""
    beta_min: float = 0.01
    """Floor of the per-point variance: ``beta^2 = softplus(raw) + beta_min`` (ActiveNeRF)."""


@dataclass
class FieldOutputs:
    """What the field says about each query point; ``...`` is the batch shape of the queries."""

    density: torch.Tensor
    """sigma: (...,) volume density per metre, >= 0 (ReLU)."""
    rgb: torch.Tensor
    """(..., 3) colour in [0, 1] (sigmoid)."""
    variance: torch.Tensor
    """beta^2: (...,) colour variance, >= beta_min (softplus + beta_min)."""
    feature: torch.Tensor
    """f_c: (..., feature_dim) colour feature, >= 0 (ReLU), rendered into I_cog."""


class NeRFField(nn.Module):
    """Trunk MLP with a skip connection plus a colour MLP, on positionally encoded inputs.

    ``forward(x, d)``: ``x (..., 3)`` positions already normalised (the memory divides metres by its
    radius), ``d`` unit view directions in the same frame, either per point ``(..., 3)`` or per ray
    ``(R, 3)`` for ``x (R, N, 3)`` (cheaper: the direction branch then runs once per ray)
    -> :class:`FieldOutputs` with batch shape ``x.shape[:-1]``.

    The skip layer and the colour layer are written as sums of two products instead of one product
    of a concatenation (the same function, without copying the inputs on CPU).
    """

    def __init__(self, config: FieldConfig = FieldConfig()):
        super().__init__()
        self.config = config
        self.pos_enc = PositionalEncoding(3, config.xyz_freqs)
        self.dir_enc = PositionalEncoding(3, config.dir_freqs)
        w, px = config.width, self.pos_enc.out_dim
        self.trunk = nn.ModuleList(nn.Linear(px if i == 0 else w, w) for i in range(config.depth))
        # the skip layer's extra input: the encoded position again (no bias: the trunk layer has one)
        self.skip_in = nn.Linear(px, w, bias=False) if 0 < config.skip < config.depth else None
        # density, variance and the intermediate feature f in one GEMM
        self.heads = nn.Linear(w, 2 + config.feature_dim)
        self.colour_feature = nn.Linear(config.feature_dim, config.feature_dim)
        self.colour_dir = nn.Linear(self.dir_enc.out_dim, config.feature_dim, bias=False)
        self.colour_out = nn.Linear(config.feature_dim, 3)

    def forward(self, x: torch.Tensor, d: torch.Tensor) -> FieldOutputs:
        gx = self.pos_enc(x.reshape(-1, 3))
        h = gx
        for i, layer in enumerate(self.trunk):
            h = layer(h)
            if i == self.config.skip and self.skip_in is not None:
                h = h + self.skip_in(gx)
            h = F.relu(h, inplace=True)
        out = self.heads(h)
        density = F.relu(out[:, 0])
        variance = F.softplus(out[:, 1]) + self.config.beta_min
        dir_part = self.colour_dir(self.dir_enc(d))
        return colour_head(self.colour_feature(out[:, 2:]), dir_part, x, d, self.colour_out, density, variance)

    def optimizers(self, lr: float, grid_lr: float) -> list[torch.optim.Optimizer]:
        """Fresh optimisers of an episode: one Adam (``lr``) over every parameter (``grid_lr`` is the voxel
        grid's, unused here)."""
        return [torch.optim.Adam(self.parameters(), lr=lr)]

    def flops_per_point(self, samples_per_ray: int = 1) -> float:
        """GEMM FLOPs (2 per multiply-add) of one point query; the direction branch is shared by the
        ``samples_per_ray`` points of a ray. Encodings and activations (~2%) are not counted."""
        per_point = per_ray = 0
        for m in self.modules():
            if isinstance(m, nn.Linear):
                if m is self.colour_dir:
                    per_ray += m.in_features * m.out_features
                else:
                    per_point += m.in_features * m.out_features
        return 2.0 * (per_point + per_ray / max(samples_per_ray, 1))


def colour_head(fc: torch.Tensor, dir_part: torch.Tensor, x: torch.Tensor, d: torch.Tensor, colour_out,
                density: torch.Tensor, variance: torch.Tensor) -> FieldOutputs:
    """Shared tail of both fields: f_c = ReLU(feature + direction term) (64-d), RGB = sigmoid(linear(f_c)).

    ``fc``: (N, F) per point (overwritten when no gradient is recorded); ``dir_part``: (R, F) per ray (broadcast over the ray's samples when
    ``d`` has one dim less than ``x``) or per point; ``density``, ``variance``: (N,). Outputs are
    reshaped to ``x.shape[:-1]``.
    """
    batch = x.shape[:-1]
    if d.dim() == x.dim() - 1:  # one direction per ray: broadcast over the ray's samples
        fc, dir_part = fc.view(*d.shape[:-1], -1, fc.shape[-1]), dir_part.unsqueeze(-2)
    else:
        dir_part = dir_part.reshape(fc.shape)
    # without autograd in place (``fc`` is a fresh linear output); with it out of place, as an in-place op on
    # a view costs autograd a copy of the whole tensor in backward
    if torch.is_grad_enabled() and fc.requires_grad:
        fc = F.relu((fc + dir_part).reshape(-1, fc.shape[-1]))
    else:
        fc = F.relu(fc.add_(dir_part).reshape(-1, fc.shape[-1]), inplace=True)
    rgb = torch.sigmoid(colour_out(fc))
    return FieldOutputs(
        density=density.reshape(batch),
        rgb=rgb.reshape(*batch, 3),
        variance=variance.reshape(batch),
        feature=fc.reshape(*batch, -1),
    )
