"""One training forward of the behaviour-cloning loop (:mod:`nue.train.bc`): the policy over a batch of sequences,
under bf16 autocast when the run's precision resolves to it, and the loss on its float32 outputs."""

from __future__ import annotations

from typing import TYPE_CHECKING

import torch

from nue.policy.base import PolicyOutput
from nue.train.hardware import resolve_precision
from nue.train.losses import bc_loss

if TYPE_CHECKING:
    from nue.train.bc import TrainConfig


def forward_loss(net, model, batch, reset_t, weights: torch.Tensor, cfg: TrainConfig, device: torch.device,
                 goal_pos_weight: float = 1.0):
    """One training forward: (total, cross-entropy, angle L1 or None). Under ``bf16`` the network runs in
    bfloat16 autocast and the loss is taken on its outputs cast back to float32."""
    bf16 = resolve_precision(cfg.precision, device) == "bf16"
    inp = batch.inp.with_image_dtype(torch.bfloat16) if bf16 else batch.inp  # the same numbers, half the bytes
    with torch.autocast(device.type, dtype=torch.bfloat16, enabled=bf16):
        out = net(inp, model.initial_state(reset_t.shape[1], device), reset_t)
    def f32(x):
        return None if x is None else x.float()

    out = PolicyOutput(out.logits.float(), f32(out.aux_angle), out.state, f32(out.goal_view), f32(out.goal_log_distance))
    return bc_loss(out, batch, weights, cfg.aux_weight, cfg.goal_weight, goal_pos_weight, cfg.exploit_weight)


class SequenceForward(torch.nn.Module):
    """``forward`` = the policy's ``forward_sequence``, so DistributedDataParallel can wrap it."""

    def __init__(self, model):
        super().__init__()
        self.model = model

    def forward(self, inp, state, reset_mask):
        return self.model.forward_sequence(inp, state, reset_mask)
