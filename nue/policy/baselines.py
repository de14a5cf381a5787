"""Baselines without NeRF memory: FR (fully reactive) and a Nav-A3C-style recurrent policy.

Both read only the live RGB-D frame and the goal image, stacked early as 7 channels
``[r, g, b, depth, goal_r, goal_g, goal_b]`` at the frame size, encoded by the same residual CNN as
NUE's f_p (so pixels of frame and goal are compared from the first layer on)::

    FR:       logits = MLP(enc([rgbd, goal]))
    Nav-A3C:  h_t, c_t = LSTMCell(enc([rgbd, goal]), (h_{t-1}, c_{t-1}));  logits = MLP(h_t)

Unlike Mirowski et al.'s Nav-A3C, the LSTM does not receive the previous action and reward
(imitation learning has no reward; the interface carries no action history).
With ``use_aux`` a 2-layer head predicts the goal angle from the policy feature (encoder output
for FR, h_t for Nav-A3C).
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import Tensor

from nue.policy.base import PolicyModel, PolicyOutput, State, wrap_angle_t
from nue.policy.blocks import ConvBranch, mlp
from nue.policy.config import ModelConfig
from nue.policy.inputs import PolicyInput


class _FrameGoalPolicy(PolicyModel):
    """Shared parts of the baselines: the 7-channel frame+goal encoder and the action / aux heads."""

    def _build_encoder(self, config: ModelConfig) -> None:
        c = config
        self.encoder = ConvBranch(7, c.perception_channels, c.perception_grid, c.perception_dim,
                                  negative_slope=c.negative_slope)

    def _encode(self, inp: PolicyInput) -> Tensor:
        self._check_input(inp)
        goal = inp.goal
        if goal.shape[-2:] != inp.rgbd.shape[-2:]:
            goal = F.interpolate(goal, size=tuple(inp.rgbd.shape[-2:]), mode="area")
        return self.encoder(torch.cat([inp.rgbd, goal.to(inp.rgbd.dtype)], dim=1))

    def _heads(self, feature_dim: int, config: ModelConfig) -> None:
        s = config.negative_slope
        self.policy = mlp([feature_dim, config.head_hidden, config.num_actions], s, final_activation=False)
        self.aux_head = mlp([feature_dim, config.aux_hidden, 1], s, final_activation=False) if config.use_aux else None

    def _outputs(self, feature: Tensor, state: State) -> PolicyOutput:
        aux = None if self.aux_head is None else wrap_angle_t(self.aux_head(feature)[:, 0])
        return PolicyOutput(self.policy(feature), aux, state)


class FRPolicy(_FrameGoalPolicy):
    """Fully reactive baseline: no memory, no NeRF maps. Submodules ``encoder``, ``policy``, ``aux_head`` (or None)."""

    def __init__(self, config: ModelConfig):
        if config.kind != "fr":
            raise ValueError(f"FRPolicy needs kind 'fr', got {config.kind!r}")
        super().__init__(config)
        self._build_encoder(config)
        self._heads(config.perception_dim, config)

    def forward(self, inp: PolicyInput, state: State = None, reset_mask: Tensor | None = None) -> PolicyOutput:
        return self._outputs(self._encode(inp), None)


class NavA3CPolicy(_FrameGoalPolicy):
    """Nav-A3C-style baseline: FR's encoder + an LSTM over time. State = (h, c), each (B, lstm_dim).

    Submodules ``encoder``, ``lstm`` (an ``nn.LSTMCell``), ``policy``, ``aux_head`` (or None).
    """

    def __init__(self, config: ModelConfig):
        if config.kind != "nav_a3c":
            raise ValueError(f"NavA3CPolicy needs kind 'nav_a3c', got {config.kind!r}")
        super().__init__(config)
        self._build_encoder(config)
        self.lstm = torch.nn.LSTMCell(config.perception_dim, config.lstm_dim)
        self._heads(config.lstm_dim, config)

    def initial_state(self, batch_size: int, device: torch.device | str | None = None) -> State:
        if device is None:
            device = next(self.parameters()).device
        z = torch.zeros(batch_size, self.config.lstm_dim, device=device)
        return (z, z.clone())

    def _step(self, x: Tensor, state: State, reset_mask: Tensor | None) -> State:
        if state is None:
            state = self.initial_state(x.shape[0], x.device)
        h, c = state
        if reset_mask is not None:
            keep = (~reset_mask.to(device=x.device, dtype=torch.bool)).to(x.dtype)[:, None]
            h, c = h * keep, c * keep
        return self.lstm(x, (h, c))

    def forward(self, inp: PolicyInput, state: State = None, reset_mask: Tensor | None = None) -> PolicyOutput:
        h, c = self._step(self._encode(inp), state, reset_mask)
        return self._outputs(h, (h, c))

    def forward_sequence(
        self, inp: PolicyInput, state: State = None, reset_mask: Tensor | None = None
    ) -> PolicyOutput:
        """Encode all T * B frames in one batch, then run the LSTM step by step, resetting where ``reset_mask``."""
        t, b = inp.rgbd.shape[:2]
        x = self._encode(inp.flatten_time()).reshape(t, b, -1)
        hs = []
        for i in range(t):
            state = self._step(x[i], state, None if reset_mask is None else reset_mask[i])
            hs.append(state[0])
        out = self._outputs(torch.cat(hs, dim=0), state)
        aux = None if out.aux_angle is None else out.aux_angle.reshape(t, b)
        return PolicyOutput(out.logits.reshape(t, b, -1), aux, state)
