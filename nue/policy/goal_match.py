"""Goal-view matching branch f_match: does the current frame show what the goal photo shows, and where?

A shared CNN embeds the RGB frame and the goal photo (both at frame size) into cells; each cell's feature is
centred on its image's mean feature and normalised, and every goal cell is compared with every frame cell::

    F = unit_c(E(rgb) - mean_hw E(rgb))     (B, C, n)      E: 4 convolutions, stride 8; n = h * w cells
    G = unit_c(E(goal) - mean_hw E(goal))   (B, C, n)
    S = G^T F                               (B, n, n)      cosines in [-1, 1]
    m_goal[b, i]  = max_j S[b, i, j]        how well goal cell i is found somewhere in the frame
    m_frame[b, j] = max_i S[b, i, j]        how well frame cell j matches some goal cell: *where* the goal is
    f_match = MLP([mean m_goal, top-25% mean m_goal, mean m_frame, max m_frame, std m_frame, pool_6x8(m_frame)])

Centring removes what every image of a house shares, so the cosines speak about this goal's content; the best match
per cell tolerates the viewpoint change between the goal photo and the robot's view (a shift, a partial overlap).
NUE with ``goal_match`` joins f_match to f_cat1 and feeds it, with f_cog, to the exploitation head.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from nue.policy.blocks import mlp

MATCH_GRID = (6, 8)
"""Cells of the pooled correlation map in f_match's input."""


class GoalMatch(nn.Module):
    """``(rgb (B, 3, H, W), goal (B, 3, H, W)) -> f_match (B, out_dim)``; ``correlation`` gives the best-match maps."""

    def __init__(self, out_dim: int, channels: int = 32, negative_slope: float = 0.01):
        super().__init__()
        s = negative_slope
        self.encoder = nn.Sequential(
            nn.Conv2d(3, 16, 5, stride=2, padding=2), nn.LeakyReLU(s),
            nn.Conv2d(16, 32, 3, stride=2, padding=1), nn.LeakyReLU(s),
            nn.Conv2d(32, channels, 3, stride=2, padding=1), nn.LeakyReLU(s),
            nn.Conv2d(channels, channels, 3, padding=1))
        self.head = mlp([5 + MATCH_GRID[0] * MATCH_GRID[1], 64, out_dim], s)

    def cells(self, image: Tensor) -> Tensor:
        """Centred unit cell features (B, C, n) of an image batch (B, 3, H, W)."""
        f = self.encoder(image).flatten(2)
        return F.normalize(f - f.mean(dim=2, keepdim=True), dim=1)

    def correlation(self, rgb: Tensor, goal: Tensor) -> tuple[Tensor, Tensor]:
        """(m_goal (B, n), m_frame (B, h, w)): each goal cell's best cosine in the frame, each frame cell's best
        cosine among the goal's cells."""
        f = self.encoder(rgb)
        h, w = f.shape[-2:]
        fc = F.normalize((f := f.flatten(2)) - f.mean(dim=2, keepdim=True), dim=1)
        s = torch.einsum("bci,bcj->bij", self.cells(goal.to(rgb.dtype)), fc)
        return s.max(dim=2).values, s.max(dim=1).values.reshape(-1, h, w)

    def forward(self, rgb: Tensor, goal: Tensor) -> Tensor:
        m_goal, m_frame = self.correlation(rgb, goal)
        frame = m_frame.flatten(1)
        top = m_goal.topk(max(1, m_goal.shape[1] // 4), dim=1).values.mean(dim=1)
        stats = torch.stack([m_goal.mean(dim=1), top, frame.mean(dim=1), frame.max(dim=1).values, frame.std(dim=1)],
                            dim=1)
        grid = F.adaptive_avg_pool2d(m_frame[:, None], MATCH_GRID).flatten(1)
        return self.head(torch.cat([stats, grid], dim=1))
