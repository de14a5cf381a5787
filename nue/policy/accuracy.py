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
    model.train()
    seen = per_class[1] > 0
    res = {"action_accuracy": correct / max(total, 1),
           "balanced_accuracy": float((per_class[0][seen] / per_class[1][seen]).mean()) if seen.any() else 0.0}
    if angle_err:
        res["angle_error_deg"] = float(np.degrees(np.concatenate(angle_err).mean()))
    return res
