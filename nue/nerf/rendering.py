"""Volume rendering as pure functions of per-sample values and weights (paper eqs. 6, 7, 12).

All functions take samples along the last-but-one axis: ``(R, N)`` scalars or ``(R, N, C)`` vectors
for R rays of N samples, ordered near to far. ``transmittance`` always means T_{N+1}, the
transmittance left after the last sample (what :class:`nue.nerf.online.MemoryMaps` also calls it).
"""

from __future__ import annotations

import torch


def compositing_weights(density: torch.Tensor, deltas: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Weights ``w_i = T_i alpha_i`` and the transmittance left after the last sample, T_{N+1}.

    ``alpha_i = 1 - exp(-sigma_i delta_i)``, ``T_i = prod_{j<i} (1 - alpha_j) = exp(-sum_{j<i} sigma_j delta_j)``,
    ``T_{N+1} = exp(-sum_j sigma_j delta_j)``, so ``sum_i w_i + T_{N+1} = 1``.

    Shapes: ``density, deltas (R, N)`` -> ``weights (R, N)``, ``transmittance (R,)``.
    Example: sigma = [1, 2, 0], delta = [0.5, 0.5, 0.5] -> alpha = [0.3935, 0.6321, 0],
    T = [1, 0.6065, 0.2231], w = [0.3935, 0.3834, 0], T_4 = 0.2231.
    """
    tau = density * deltas
    cum = torch.cumsum(tau, dim=-1)
    t_i = torch.exp(-(cum - tau))  # exclusive cumulative sum
    alpha = 1.0 - torch.exp(-tau)
    return t_i * alpha, torch.exp(-cum[..., -1])


def composite(weights: torch.Tensor, values: torch.Tensor) -> torch.Tensor:
    """Expected value along each ray ``sum_i w_i v_i``: ``weights (R, N)``, ``values (R, N, C)`` -> ``(R, C)``.

    With colours it is the expected colour ``C = sum_i w_i c_i`` (:func:`render_rgb`), with the field's
    features the cognition feature ``I_cog = sum_i w_i f_c,i`` (paper eq. 12, :func:`render_features`).
    Example: w = [0.5, 0.25], c = [[1, 0, 0], [0, 1, 0]] -> [0.5, 0.25, 0]; f = [[2, 0], [4, 4]] -> [2, 1].
    """
    return torch.einsum("rn,rnc->rc", weights, values)


render_rgb = composite
"""Expected colour ``C = sum_i w_i c_i``: ``rgb (R, N, 3)`` -> ``(R, 3)`` (:func:`composite`)."""
render_features = composite
"""Cognition feature ``I_cog = sum_i w_i f_c,i`` (paper eq. 12): ``(R, N, C)`` -> ``(R, C)`` (:func:`composite`)."""


def render_depth(weights: torch.Tensor, t: torch.Tensor) -> torch.Tensor:
    """Expected distance along the ray ``D = sum_i w_i t_i / sum_i w_i`` (normalised by the weight sum
    so leftover transmittance does not pull it to 0): ``(R, N)``, ``(R, N)`` -> ``(R,)``.

    Example: w = [0.5, 0.25], t = [1, 4] -> (0.5 + 1) / 0.75 = 2.
    """
    acc = weights.sum(dim=-1)
    return (weights * t).sum(dim=-1) / acc.clamp_min(1e-6)


def render_uncertainty(
    weights: torch.Tensor,
    variance: torch.Tensor,
    transmittance: torch.Tensor | None = None,
    unseen_variance: float = 0.0,
) -> torch.Tensor:
    """Rendered colour variance ``I_u = sum_i w_i^2 beta_i^2 (+ T_{N+1} beta_max^2)`` (ActiveNeRF; paper eq. 6).

    The squared weights are ActiveNeRF's convention (the variance of a weighted sum of independent
    Gaussians). The optional term ``T_{N+1} * unseen_variance`` (``transmittance`` = T_{N+1}) makes rays that
    pass through empty, never-trained space (density ~ 0, so every w_i ~ 0) uncertain instead of certain.

    Shapes: ``weights, variance (R, N)``, ``transmittance (R,)`` -> ``(R,)``.
    Example: w = [0.3935, 0.3834, 0], beta^2 = [0.1, 0.2, 0.3] -> 0.3935^2 * 0.1 + 0.3834^2 * 0.2 = 0.04488;
    with T_4 = 0.2231 and unseen_variance = 1 -> 0.26798.
    """
    out = (weights.square() * variance).sum(dim=-1)
    if transmittance is not None and unseen_variance > 0.0:
        out = out + transmittance * unseen_variance
    return out
