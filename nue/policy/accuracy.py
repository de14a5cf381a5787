"""Held-out action accuracy: how often a policy network's argmax action matches the expert's label on
demonstration episodes (teacher-forced, episode by episode). ``nue train`` scores its checkpoints with it
(``best.pt`` by accuracy) and ``nue diagnose --data`` runs its map controls through it."""

from __future__ import annotations

from typing import Protocol

import numpy as np
import torch

from nue.policy.base import PolicyModel, wrap_angle_t
from nue.policy.config import ModelConfig


class Demonstrations(Protocol):
    """What :func:`held_out_accuracy` reads of a demonstration set (``nue.train.dataset.DemoSet`` is one)."""

    @property
    def n_episodes(self) -> int: ...

    @property
    def lengths(self) -> np.ndarray: ...

    def batch(self, eps: np.ndarray, steps: np.ndarray, model_cfg: ModelConfig, device): ...


@torch.no_grad()
def held_out_accuracy(model: PolicyModel, data: Demonstrations, model_cfg: ModelConfig, device,
                      max_episodes: int = 200) -> dict[str, float]:
    """Held-out action accuracy, balanced accuracy and goal-angle error (degrees), episode by episode, over the
    first ``max_episodes`` episodes of ``data``; the model is left in training mode."""
    model.eval()
    correct = total = 0
    per_class = np.zeros((2, model_cfg.num_actions))
    angle_err = []
    goal: list[tuple[np.ndarray, ...]] = []  # (p_view, log d_pred, in view, d, angle error) per episode, goal head
    for e in range(min(data.n_episodes, max_episodes)):
        t = np.arange(data.lengths[e])
        batch = data.batch(np.full((len(t), 1), e), t[:, None], model_cfg, device)
        out = model.forward_sequence(batch.inp, model.initial_state(1, device),
                                     torch.zeros(len(t), 1, dtype=torch.bool, device=device))
        pred = out.logits.argmax(-1).reshape(-1).cpu().numpy()
        truth = batch.action.reshape(-1).cpu().numpy()
        correct += int((pred == truth).sum())
        total += len(truth)
        np.add.at(per_class[0], truth, pred == truth)
        np.add.at(per_class[1], truth, 1)
        if out.aux_angle is not None:
            angle_err.append(wrap_angle_t(out.aux_angle.reshape(-1) - batch.goal_angle.reshape(-1)).abs().cpu().numpy())
        if out.goal_view is not None and out.goal_log_distance is not None and batch.goal_in_view is not None:
            err = angle_err[-1] if out.aux_angle is not None else np.full(len(t), np.nan)
            goal.append((torch.sigmoid(out.goal_view.float()).reshape(-1).cpu().numpy(),
                         out.goal_log_distance.float().reshape(-1).cpu().numpy(),
                         batch.goal_in_view.reshape(-1).cpu().numpy() > 0.5,
                         batch.goal_distance.reshape(-1).cpu().numpy(), err))
    model.train()
    seen = per_class[1] > 0
    res = {"action_accuracy": correct / max(total, 1),
           "balanced_accuracy": float((per_class[0][seen] / per_class[1][seen]).mean()) if seen.any() else 0.0}
    if angle_err:
        res["angle_error_deg"] = float(np.degrees(np.concatenate(angle_err).mean()))
    if goal:
        res.update(goal_head_scores(*(np.concatenate(x) for x in zip(*goal))))
    return res


def auroc(score: np.ndarray, label: np.ndarray) -> float:
    """Area under the ROC curve, P(score of a positive > score of a negative) with ties counted half, from ranks
    (NaN without both classes). ``auroc([0.1, 0.4, 0.35, 0.8], [0, 0, 1, 1]) == 0.75``."""
    from scipy.stats import rankdata

    pos = np.asarray(label, dtype=bool)
    n1, n0 = int(pos.sum()), int((~pos).sum())
    if n1 == 0 or n0 == 0:
        return float("nan")
    r = rankdata(np.asarray(score, dtype=np.float64))
    return float((r[pos].sum() - n1 * (n1 + 1) / 2) / (n1 * n0))


def goal_head_scores(p_view: np.ndarray, log_d: np.ndarray, in_view: np.ndarray, distance: np.ndarray,
                     angle_error: np.ndarray) -> dict[str, float]:
    """Held-out scores of the exploitation head: AUROC of the in-view probability, precision and recall at 0.5,
    and on the in-view steps the median |log d_pred - log d| and the median angle error (degrees, auxiliary head)."""
    pred = p_view >= 0.5
    res = {"goal_view_auroc": auroc(p_view, in_view),
           "goal_view_precision": float((pred & in_view).sum() / max(int(pred.sum()), 1)),
           "goal_view_recall": float((pred & in_view).sum() / max(int(in_view.sum()), 1))}
    if in_view.any():
        res["goal_log_distance_error"] = float(np.median(np.abs(log_d[in_view] - np.log(np.maximum(distance[in_view], 0.1)))))
        res["angle_error_in_view_deg"] = float(np.degrees(np.nanmedian(angle_error[in_view])))
    return res
