"""The memory's training loss: ActiveNeRF's Gaussian negative log-likelihood (paper eq. 5) + density penalty."""

from __future__ import annotations

from dataclasses import dataclass

import torch


@dataclass
class LossTerms:
    """Scalar loss terms of one training iteration (``total`` is what is minimised)."""

    total: torch.Tensor
    nll: torch.Tensor
    """mean over rays of ``||C - C_bar||^2 / (2 beta_bar^2) + log(beta_bar^2) / 2``."""
    density: torch.Tensor
    """``density_weight * mean(sigma)`` over all samples."""
    depth: torch.Tensor
    """``depth_weight * mean |D_bar - D|`` (0 unless enabled; not part of the paper's loss)."""


def uncertainty_nll(rgb_pred: torch.Tensor, rgb_true: torch.Tensor, ray_variance: torch.Tensor) -> torch.Tensor:
    """Per-ray Gaussian NLL (paper eq. 5): ``||C - C_bar||^2 / (2 beta_bar^2) + log(beta_bar^2) / 2``.

    ``rgb_pred, rgb_true (R, 3)`` in [0, 1] (squared error summed over channels), ``ray_variance (R,) > 0``
    -> ``(R,)``. Example: C_bar = [0.5, 0.5, 0.5], C = [0.7, 0.5, 0.5], beta_bar^2 = 0.02 ->
    0.04 / 0.04 + log(0.02) / 2 = 1 - 1.956 = -0.956.
    """
    sq = (rgb_pred - rgb_true).square().sum(dim=-1)
    return sq / (2.0 * ray_variance) + 0.5 * torch.log(ray_variance)


def memory_loss(
    rgb_pred: torch.Tensor,
    rgb_true: torch.Tensor,
    ray_variance: torch.Tensor,
    density: torch.Tensor,
    density_weight: float = 0.01,
    depth_pred: torch.Tensor | None = None,
    depth_true: torch.Tensor | None = None,
    depth_weight: float = 0.0,
) -> LossTerms:
    """Eq. 5 averaged over rays, plus ``density_weight * mean(sigma)`` over every sample (ActiveNeRF),
    plus an optional ``depth_weight * mean |D_bar - D|`` on the rendered ray distance.

    Shapes: ``rgb_* (R, 3)``, ``ray_variance (R,)``, ``density (R, N)``, ``depth_* (R,)``.
    """
    nll = uncertainty_nll(rgb_pred, rgb_true, ray_variance).mean()
    dens = density_weight * density.mean()
    if depth_weight > 0.0 and depth_pred is not None and depth_true is not None:
        dep = depth_weight * (depth_pred - depth_true).abs().mean()
    else:
        dep = torch.zeros((), device=nll.device)
    return LossTerms(total=nll + dens + dep, nll=nll, density=dens, depth=dep)
