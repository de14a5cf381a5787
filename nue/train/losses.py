"""The imitation losses: class-balanced cross-entropy on the expert's actions, the auxiliary goal-angle L1 and the
exploitation head's loss (goal in view, distance), with the weights they read from the data."""

from __future__ import annotations

import numpy as np
import torch
import torch.nn.functional as F

from nue.policy.base import angle_l1_loss


def class_weights(counts: np.ndarray, power: float) -> torch.Tensor:
    """(n / n_c)^power, normalised to mean 1 over the classes present."""
    counts = np.maximum(counts.astype(np.float64), 1.0)
    w = (counts.sum() / counts) ** power
    return torch.as_tensor(w / w.mean(), dtype=torch.float32)


def bc_loss(out, batch, weights: torch.Tensor, aux_weight: float, goal_weight: float = 0.0, goal_pos_weight: float = 1.0,
            exploit_weight: float = 1.0):
    """(total, cross-entropy, angle L1 or None) of a forward_sequence output against a batch; the total includes
    ``goal_weight`` x :func:`goal_head_loss` when the model has the exploitation head. The cross-entropy is
    :func:`action_loss` (the in-view steps weighted ``exploit_weight``)."""
    logits = out.logits.reshape(-1, out.logits.shape[-1])
    ce = action_loss(logits, batch.action.reshape(-1), weights.to(logits.device),
                     None if exploit_weight == 1.0 or batch.goal_in_view is None else batch.goal_in_view.reshape(-1),
                     exploit_weight)
    total = ce
    if out.goal_view is not None and batch.goal_in_view is not None:
        total = total + goal_weight * goal_head_loss(out, batch, goal_pos_weight)
    if out.aux_angle is None:
        return total, ce, None
    aux = angle_l1_loss(out.aux_angle.reshape(-1), batch.goal_angle.reshape(-1))
    return total + aux_weight * aux, ce, aux


def action_loss(logits: torch.Tensor, action: torch.Tensor, weights: torch.Tensor, in_view: torch.Tensor | None = None,
                exploit_weight: float = 1.0) -> torch.Tensor:
    """Class-weighted cross-entropy of ``logits`` (N, A) against the expert's ``action`` (N,): ``sum_i s_i w_{a_i}
    ce_i / sum_i s_i w_{a_i}`` with class weights ``w`` and step weights s_i = ``exploit_weight`` on the steps with the
    goal in view (``in_view`` (N,), the exploring expert's switch), 1 elsewhere. Without ``in_view`` (or at weight 1)
    it is ``F.cross_entropy(..., weight=w)``.

    Example: two steps with class weights 1, cross-entropies 1 (goal not in view) and 3 (in view), exploit_weight 3:
    (1 + 3 x 3) / (1 + 3) = 2.5, against 2 unweighted."""
    if in_view is None or exploit_weight == 1.0:
        return F.cross_entropy(logits, action, weight=weights)
    w = weights[action] * torch.where(in_view.reshape(-1) > 0.5, exploit_weight, 1.0).to(logits.dtype)
    return (F.cross_entropy(logits, action, reduction="none") * w).sum() / w.sum()


def goal_head_loss(out, batch, pos_weight: float = 1.0) -> torch.Tensor:
    """The exploitation head's loss: ``BCE(goal_view, in_view) + mean over in-view steps |log_d - log(d)|`` (the
    in-view terms of the BCE weighted ``pos_weight``; the distance term is 0 for a batch without an in-view step;
    distances are floored at 0.1 m before the log)."""
    view = batch.goal_in_view.reshape(-1).to(out.goal_view.dtype)
    bce = F.binary_cross_entropy_with_logits(out.goal_view.reshape(-1), view,
                                             pos_weight=torch.tensor(float(pos_weight), device=view.device))
    mask = view > 0.5
    if not bool(mask.any()):
        return bce
    target = torch.log(batch.goal_distance.reshape(-1)[mask].clamp_min(0.1))
    return bce + (out.goal_log_distance.reshape(-1)[mask] - target).abs().mean()


def in_view_weight(data) -> float:
    """Steps without the goal in view per step with it, over a collection's episodes (1 without any either way)."""
    n = sum(len(e["goal_in_view"]) for e in data.episodes)
    pos = sum(int(np.asarray(e["goal_in_view"]).sum()) for e in data.episodes)
    return (n - pos) / pos if 0 < pos < n else 1.0
