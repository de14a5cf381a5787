"""Positional encoding gamma(x) = [x, sin(2^k pi x), cos(2^k pi x)]_{k < L} (NeRF, paper eq. 1-2)."""

from __future__ import annotations

import math

import torch
from torch import nn


class PositionalEncoding(nn.Module):
    """Frequency encoding of each input coordinate.

    ``x: (..., D)`` -> ``(..., D * (include_input + 2 * n_freqs))``, ordered
    ``[x, sin(2^0 pi x), cos(2^0 pi x), ..., sin(2^(L-1) pi x), cos(2^(L-1) pi x)]`` with the sines
    and cosines of all D coordinates grouped per frequency. Inputs are expected in about [-1, 1]
    (positions normalised by the memory radius, unit directions).

    Example: D = 1, L = 1, x = 0.5 -> ``[0.5, sin(pi / 2), cos(pi / 2)] = [0.5, 1.0, 0.0]``.
    """

    freqs: torch.Tensor  # a buffer (register_buffer), typed for the checker

    def __init__(self, in_dim: int, n_freqs: int, include_input: bool = True):
        super().__init__()
        self.in_dim = in_dim
        self.n_freqs = n_freqs
        self.include_input = include_input
        freqs = (2.0 ** torch.arange(n_freqs, dtype=torch.float32)) * math.pi
        self.register_buffer("freqs", freqs, persistent=False)

    @property
    def out_dim(self) -> int:
        """Width of the encoding: ``D * (include_input + 2 * n_freqs)``."""
        return self.in_dim * (int(self.include_input) + 2 * self.n_freqs)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        scaled = x[..., None, :] * self.freqs[:, None]  # (..., L, D)
        enc = torch.cat([torch.sin(scaled), torch.cos(scaled)], dim=-1).flatten(-2)  # (..., L * 2D)
        return torch.cat([x, enc], dim=-1) if self.include_input else enc
