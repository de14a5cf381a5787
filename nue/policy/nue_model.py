"""The NUE policy (paper Fig. 3): exploration branch f_u, exploitation branch f_cog (+ auxiliary angle head),
perception f_p, and attention-weighted fusion into action logits (eqs. 8-10, 13-14).

::

    f_u   = MLP(flatten(CBAM(pool(res(res(log1p(I_u / s)))))))          (B, 64)   eq. 10
    f_cog = MLP(flatten(CBAM(pool(res(res([I_cog, goal]))))))            (B, 64)
    f_p   = MLP(flatten(pool(res(res(res(rgbd))))))                      (B, 256)
            [or of [rgbd, goal] at frame size with ``goal_in_perception``, as FR's first layer]
    f_cat1 = [f_cog, f_u, f_p];  w = sigmoid(MLP(f_cat1))
    f_cat2 = MLP(w * f_cat1);    logits = MLP(f_cat2)                    eqs. 13-14
    [with ``panorama_dim``: f_pano = MLP(flatten(log1p(panorama / s))) joins f_cat1]
    [with ``gru_dim``: h_t = GRU(f_cat2, h_{t-1}); logits = MLP(h_t)]
    aux_angle = wrap(MLP_2layer(f_cog))
    [with ``goal_match``: f_match = goal-view matching of rgb and goal (nue.policy.goal_match) joins f_cat1]
    [with ``goal_head``: (goal-in-view logit, log goal distance) = MLP_2layer([f_cog, f_match])]

Switches: ``use_uncertainty=False`` drops f_u (f_cat1 = [f_cog, f_p]), ``use_aux=False`` drops the
angle head, ``use_cbam=False`` drops both CBAMs; a dropped part is ``None`` and has no parameters.
"""

from __future__ import annotations

from typing import Any

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from nue.policy.base import PolicyModel, PolicyOutput, State, wrap_angle_t
from nue.policy.blocks import ConvBranch, mlp
from nue.policy.config import ModelConfig
from nue.policy.goal_match import GoalMatch
from nue.policy.inputs import PolicyInput


class FusionHead(nn.Module):
    """Adaptive fusion (eqs. 13-14): ``w = sigmoid(MLP(x))``, ``f_cat2 = MLP(w * x)``, ``logits = MLP(f_cat2)``.

    ``(B, in_dim) -> (B, num_actions)``; ``weights(f_cat1)`` gives w for inspection.
    """

    def __init__(self, in_dim: int, config: ModelConfig):
        super().__init__()
        s = config.negative_slope
        self.gate = mlp([in_dim, config.gate_hidden, in_dim], s, final_activation=False)
        self.fuse = mlp([in_dim, config.fusion_dim], s)
        head_in = config.gru_dim or config.fusion_dim
        self.policy = mlp([head_in, config.head_hidden, config.num_actions], s, final_activation=False)

    def weights(self, f_cat1: Tensor) -> Tensor:
        """The attention weights w (B, in_dim) in (0, 1)."""
        return torch.sigmoid(self.gate(f_cat1))

    def fused(self, f_cat1: Tensor) -> Tensor:
        """f_cat2 = MLP(w * f_cat1), (B, fusion_dim)."""
        return self.fuse(self.weights(f_cat1) * f_cat1)

    def forward(self, f_cat1: Tensor) -> Tensor:
        return self.policy(self.fused(f_cat1))


class NUEPolicy(PolicyModel):
    """NUE and its ablations. Submodules: ``f_u`` (or None), ``f_cog``, ``f_p``, ``aux_head`` (or None), ``fusion``.

    Grad-CAM on the uncertainty branch (Fig. 8): hook ``f_u.encoder`` (last residual block) or
    ``f_u.cbam``; its input is ``inp.i_u``.
    """

    def __init__(self, config: ModelConfig):
        if config.kind != "nue":
            raise ValueError(f"NUEPolicy needs kind 'nue', got {config.kind!r}")
        super().__init__(config)
        c, s = config, config.negative_slope
        cbam: dict[str, Any] = dict(cbam=c.use_cbam, cbam_reduction=c.cbam_reduction, cbam_kernel=c.cbam_kernel, negative_slope=s)
        self.f_u = (
            ConvBranch(1, c.uncertainty_channels, c.map_grid, c.branch_dim, **cbam) if c.use_uncertainty else None
        )
        self.f_cog = ConvBranch(c.cog_channels + 3, c.cognition_channels, c.map_grid, c.branch_dim, **cbam)
        self.f_p = ConvBranch(7 if c.goal_in_perception else 4, c.perception_channels, c.perception_grid, c.perception_dim, negative_slope=s)
        self.aux_head = mlp([c.branch_dim, c.aux_hidden, 1], s, final_activation=False) if c.use_aux else None
        self.f_match = GoalMatch(c.goal_match, negative_slope=s) if c.goal_match else None
        self.goal_head = (mlp([c.branch_dim + c.goal_match, c.aux_hidden, 2], s, final_activation=False)
                          if c.goal_head else None)
        k, hp, wp = c.panorama_shape
        self.f_pano = mlp([k * hp * wp, 2 * c.panorama_dim, c.panorama_dim], s) if c.panorama_dim else None
        fused = c.branch_dim * (2 if c.use_uncertainty else 1) + c.perception_dim + c.panorama_dim + c.goal_match
        self.fusion = FusionHead(fused, config)
        self.gru = nn.GRUCell(c.fusion_dim, c.gru_dim) if c.gru_dim else None

    def features(self, inp: PolicyInput) -> tuple[Tensor, Tensor | None, Tensor]:
        """The branch vectors ``(f_cog (B, 64), f_u (B, 64) | None, f_p (B, 256))``."""
        self._check_input(inp)
        i_cog = inp.i_cog
        assert i_cog is not None
        goal = inp.goal
        if goal.shape[-2:] != i_cog.shape[-2:]:
            goal = F.interpolate(goal, size=tuple(i_cog.shape[-2:]), mode="area")
        f_cog = self.f_cog(torch.cat([i_cog, goal.to(i_cog.dtype)], dim=1))
        f_u = None
        if self.f_u is not None:
            assert inp.i_u is not None
            f_u = self.f_u(torch.log1p(inp.i_u.clamp_min(0.0) / self.config.uncertainty_scale))
        frame = torch.cat([inp.rgbd, inp.goal.to(inp.rgbd.dtype)], dim=1) if self.config.goal_in_perception else inp.rgbd
        return f_cog, f_u, self.f_p(frame)

    def _fused(self, inp: PolicyInput) -> tuple[Tensor, Tensor | None, Tensor | None]:
        """(f_cat2 (B, fusion_dim), aux angle (B,) | None, goal head (B, 2) | None)."""
        f_cog, f_u, f_p = self.features(inp)
        parts = [f_cog, f_p] if f_u is None else [f_cog, f_u, f_p]
        if self.f_pano is not None:
            if inp.panorama is None:
                raise ValueError(f"model {self.config.name!r} reads the uncertainty panorama, but inp.panorama is None")
            pano = torch.log1p(inp.panorama.clamp_min(0.0) / self.config.uncertainty_scale)
            parts.append(self.f_pano(pano.reshape(pano.shape[0], -1).to(f_p.dtype)))
        head_in = f_cog
        if self.f_match is not None:
            f_match = self.f_match(inp.rgbd[:, :3], inp.goal).to(f_p.dtype)
            parts.append(f_match)
            head_in = torch.cat([f_cog, f_match.to(f_cog.dtype)], dim=1)
        f_cat1 = torch.cat(parts, dim=1)
        aux = None if self.aux_head is None else wrap_angle_t(self.aux_head(f_cog)[:, 0])
        goal = None if self.goal_head is None else self.goal_head(head_in)
        return self.fusion.fused(f_cat1), aux, goal

    def initial_state(self, batch_size: int, device: torch.device | str | None = None) -> State:
        if self.gru is None:
            return None
        if device is None:
            device = next(self.parameters()).device
        return (torch.zeros(batch_size, self.config.gru_dim, device=device),)

    def _step(self, x: Tensor, state: State, reset_mask: Tensor | None) -> Tensor:
        """h_t = GRU(x, h_{t-1}) (B, gru_dim), with h_{t-1} zeroed where ``reset_mask``."""
        assert self.gru is not None
        prev = self.initial_state(x.shape[0], x.device) if state is None else state
        assert prev is not None
        h = prev[0]
        if reset_mask is not None:
            h = h * (~reset_mask.to(device=x.device, dtype=torch.bool)).to(h.dtype)[:, None]
        return self.gru(x, h.to(x.dtype))

    def forward(self, inp: PolicyInput, state: State = None, reset_mask: Tensor | None = None) -> PolicyOutput:
        f_cat2, aux, goal = self._fused(inp)
        view, dist = (None, None) if goal is None else (goal[:, 0], goal[:, 1])
        if self.gru is None:
            return PolicyOutput(self.fusion.policy(f_cat2), aux, None, view, dist)
        h = self._step(f_cat2, state, reset_mask)
        return PolicyOutput(self.fusion.policy(h), aux, (h,), view, dist)

    def forward_sequence(self, inp: PolicyInput, state: State = None, reset_mask: Tensor | None = None) -> PolicyOutput:
        """Reactive: T folded into B. With a GRU: the branches and fusion for all T * B steps in one batch, then the
        GRU step by step (its state zeroed where ``reset_mask`` (T, B))."""
        if self.gru is None:
            return super().forward_sequence(inp, state, reset_mask)
        t, b = inp.rgbd.shape[:2]
        f_cat2, aux, goal = self._fused(inp.flatten_time())
        x = f_cat2.reshape(t, b, -1)
        hs = []
        for i in range(t):
            h = self._step(x[i], state, None if reset_mask is None else reset_mask[i])
            state = (h,)
            hs.append(h)
        logits = self.fusion.policy(torch.cat(hs, dim=0))
        view, dist = (None, None) if goal is None else (goal[:, 0].reshape(t, b), goal[:, 1].reshape(t, b))
        return PolicyOutput(logits.reshape(t, b, -1), None if aux is None else aux.reshape(t, b), state, view, dist)
