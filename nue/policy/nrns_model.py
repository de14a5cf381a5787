"""NRNS's distance network (Hahn et al., NeurIPS 2021, "No RL, No Simulation"): how far is the goal from a point?

``D(view, goal, offset) -> metres``: the geodesic distance to the goal photo's place from the point ``offset`` =
(forward, left) metres in the robot frame of the view (offset (0, 0): from where the view was taken). The view
(live RGB-D) and the goal photo are stacked early as 7 channels and encoded by the residual CNN the baselines use
(:class:`nue.policy.blocks.ConvBranch`); the offset enters through a small MLP of its features
``(forward, left) / offset_scale``, its length and the cosine and sine of its bearing; a head maps the joined vector to
a distance >= 0 (softplus)::

    f = enc([rgbd, goal]);  g = MLP(offset features);  D = softplus(MLP([f, g]))

NRNS predicts the distance of its *ghost* nodes (points the robot has not visited) with a graph network over the
explored nodes' features; here a ghost's distance is read from the one view that showed it, at the ghost's offset
(see ``docs/nrns.md``). The network picks no actions: :class:`nue.policy.nrns_agent.NRNSAgent` acts with it,
so :meth:`forward` refuses to run (the training loop is :mod:`nue.train.nrns_train`).
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import Tensor

from nue.policy.base import PolicyModel, PolicyOutput, State
from nue.policy.blocks import ConvBranch, mlp
from nue.policy.config import ModelConfig
from nue.policy.inputs import PolicyInput

OFFSET_SCALE = 2.0
"""Offsets enter the network divided by this (metres): the ghosts and training offsets lie within ~2 m."""
OFFSET_FEATURES = 5
"""(forward, left) / scale, length / scale, cos and sin of the bearing."""


def offset_features(offset: Tensor) -> Tensor:
    """(..., 2) offsets (forward, left) metres -> (..., 5) network features (the bearing of (0, 0) is 0)."""
    length = offset.norm(dim=-1, keepdim=True)
    bearing = torch.atan2(offset[..., 1:2], offset[..., 0:1])
    return torch.cat([offset / OFFSET_SCALE, length / OFFSET_SCALE, torch.cos(bearing), torch.sin(bearing)], dim=-1)


class DistanceNetwork(PolicyModel):
    """``kind="nrns"``: predicted geodesic distance (metres) to the goal from points around a view."""

    def __init__(self, config: ModelConfig):
        super().__init__(config)
        c, s = config, config.negative_slope
        self.encoder = ConvBranch(7, c.perception_channels, c.perception_grid, c.perception_dim, negative_slope=s)
        self.offset_mlp = mlp([OFFSET_FEATURES, 32, 32], s)
        self.head = mlp([c.perception_dim + 32, c.head_hidden, 1], s, final_activation=False)

    def encode(self, rgbd: Tensor, goal: Tensor) -> Tensor:
        """(B, 4, h, w) views and (B, 3, h', w') goal photos (prepared as :func:`nue.policy.inputs.prepare_input`
        does) -> (B, perception_dim) features; the goal is area-resized to the view's size if it differs."""
        if goal.shape[-2:] != rgbd.shape[-2:]:
            goal = F.interpolate(goal, size=tuple(rgbd.shape[-2:]), mode="area")
        return self.encoder(torch.cat([rgbd, goal.to(rgbd.dtype)], dim=1))

    def distance_from(self, features: Tensor, offsets: Tensor) -> Tensor:
        """Distances (B, K) metres from encoded views ``features`` (B, F) at ``offsets`` (B, K, 2) (forward, left)."""
        g = self.offset_mlp(offset_features(offsets))
        f = features[:, None, :].expand(-1, offsets.shape[1], -1)
        return F.softplus(self.head(torch.cat([f, g], dim=-1))[..., 0])

    def distance(self, inp: PolicyInput, offsets: Tensor | None = None) -> Tensor:
        """Distances (B, K) from the views and goals of ``inp`` at ``offsets`` (B, K, 2); None = (B, 1) at (0, 0)."""
        self._check_input(inp)
        if offsets is None:
            offsets = inp.rgbd.new_zeros(inp.rgbd.shape[0], 1, 2)
        return self.distance_from(self.encode(inp.rgbd, inp.goal), offsets)

    def forward(self, inp: PolicyInput, state: State = None, reset_mask: Tensor | None = None) -> PolicyOutput:
        raise TypeError(f"model {self.config.name!r} (kind 'nrns') predicts distances, not actions: it acts through "
                        "nue.policy.nrns_agent.NRNSAgent and trains with nue.train.nrns_train")
