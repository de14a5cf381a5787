"""Adam with a step count per slot, for :class:`nue.nerf.stacked.StackedMemory`: slot i's parameters take the bias
correction of slot i's own number of steps, so a slot whose episode started later (or was reset) is optimised as a
fresh :class:`~nue.nerf.online.OnlineNeRF` would be.

- :class:`SlotRowAdam`: :class:`~nue.nerf.grid_field.RowAdam` on the stacked voxel table (``rows_per_slot`` rows a
  slot), updating only the touched rows;
- :func:`slot_adam_step`: Adam on parameters with a leading slot axis (the colour MLPs), ``DenseAdam``'s arithmetic.
"""

from __future__ import annotations

import numpy as np
import torch
from torch import nn

from nue.nerf.grid_field import RowAdam


class SlotRowAdam(RowAdam):
    """:class:`RowAdam` on the stacked table with a step count per slot: each touched row takes the bias
    correction of its own slot's count (rows of different slots are distinct, so slots do not interact)."""

    def __init__(self, table: nn.Parameter, lr: float, slots: int, rows_per_slot: int):
        super().__init__(table, lr)
        self.rows_per_slot = rows_per_slot
        self.slot_steps = np.zeros(slots, dtype=np.int64)

    def reset_slot(self, i: int) -> None:
        a = i * self.rows_per_slot
        self._moments[a : a + self.rows_per_slot].zero_()
        self.slot_steps[i] = 0

    @torch.no_grad()
    def step_slots(self, slots: list[int]) -> None:
        g = self.table.grad
        if g is None:
            return
        self.slot_steps[slots] += 1
        idx, vals = g._indices()[0], g._values()
        rows, m, v = self._update_moments(idx, vals)
        b1, b2 = self.betas
        s = np.maximum(self.slot_steps, 1).astype(np.float64)
        per_slot = -self.lr * np.sqrt(1 - b2**s) / (1 - b1**s)  # as RowAdam's float step size, per slot
        neg_step = torch.as_tensor(per_slot, dtype=vals.dtype, device=vals.device)[rows // self.rows_per_slot]
        delta = neg_step[:, None] * m / (v.sqrt() + self.eps)
        self.table.index_copy_(0, rows, self.table.index_select(0, rows).add_(delta))


@torch.no_grad()
def slot_adam_step(params: dict[str, torch.Tensor], m: dict[str, torch.Tensor], v: dict[str, torch.Tensor],
                   steps: np.ndarray, slots: list[int], lr: float, betas: tuple[float, float] = (0.9, 0.999)) -> None:
    """One Adam step of the listed slots' parameters (each ``(len(slots), ...)``, gradients set) and their moments
    ``m``, ``v`` in place; ``steps`` (one count per slot of the memory) is advanced for ``slots``."""
    b1, b2 = betas
    steps[slots] += 1
    step = steps[slots].astype(np.float64)
    for k, p in params.items():
        neg_step = torch.as_tensor(-lr / (1 - b1**step), dtype=torch.float32, device=p.device)
        bc2 = torch.as_tensor((1 - b2**step) ** 0.5, dtype=torch.float32, device=p.device)
        g = p.grad
        assert g is not None, f"slot_adam_step: {k} has no gradient"
        shape = (-1,) + (1,) * (p.dim() - 1)
        m[k].lerp_(g, 1 - b1)
        v[k].mul_(b2).addcmul_(g, g, value=1 - b2)
        denom = (v[k].sqrt() / bc2.view(shape)).add_(1e-8)
        p.add_(neg_step.view(shape) * m[k] / denom)
