"""Network building blocks: residual block, CBAM (channel + spatial attention), MLPs and a conv branch.

CBAM follows Woo et al. 2018 and paper eqs. 8-10, applied sequentially::

    M_C(F) = sigmoid(MLP(avgpool_hw(F)) + MLP(maxpool_hw(F)))          (B, C, 1, 1)   eq. 8
    F'     = M_C(F) * F
    M_S(F') = sigmoid(conv([avgpool_c(F'), maxpool_c(F')]))             (B, 1, H, W)   eq. 9
    F''    = M_S(F') * F'

Eq. 9 in the paper concatenates ``F_avg`` twice; that is a typo, the second map is the max-pool.
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
from torch import Tensor, nn


class ResidualBlock(nn.Module):
    """conv3x3(stride)-BN-LeakyReLU-conv3x3-BN plus a bypass, then LeakyReLU.

    The bypass is a 1x1 conv(stride)-BN projection when the channels or the resolution change,
    else the identity. ``(B, in_ch, H, W) -> (B, out_ch, ceil(H / stride), ceil(W / stride))``.
    """

    def __init__(self, in_ch: int, out_ch: int, stride: int = 1, negative_slope: float = 0.01):
        super().__init__()
        self.conv1 = nn.Conv2d(in_ch, out_ch, 3, stride=stride, padding=1, bias=False)
        self.bn1 = nn.BatchNorm2d(out_ch)
        self.conv2 = nn.Conv2d(out_ch, out_ch, 3, padding=1, bias=False)
        self.bn2 = nn.BatchNorm2d(out_ch)
        self.act = nn.LeakyReLU(negative_slope)
        if stride != 1 or in_ch != out_ch:
            self.bypass: nn.Module = nn.Sequential(SubsampledPointwiseConv(in_ch, out_ch, stride), nn.BatchNorm2d(out_ch))
        else:
            self.bypass = nn.Identity()

    def forward(self, x: Tensor) -> Tensor:
        y = self.act(self.bn1(self.conv1(x)))
        y = self.bn2(self.conv2(y))
        return self.act(y + self.bypass(x))


class SubsampledPointwiseConv(nn.Conv2d):
    """A 1x1 convolution with stride s, computed as a stride-1 1x1 convolution of ``x[..., ::s, ::s]``.

    The same function and the same parameters (``weight (out_ch, in_ch, 1, 1)``, no bias) as
    ``nn.Conv2d(in_ch, out_ch, 1, stride=s, bias=False)``: a 1x1 kernel with stride s reads exactly the pixels
    (s i, s j), so ``(B, in_ch, H, W) -> (B, out_ch, ceil(H / s), ceil(W / s))``. oneDNN's CPU kernels for a strided
    1x1 convolution are slow (forward and backward ~2.5x the time of slicing first at batch 64 on 45 x 60 x 67;
    ``docs/history/benchmarks.md``, "Training throughput"); the sum over input channels may round differently (~1e-6).
    """

    def __init__(self, in_ch: int, out_ch: int, stride: int):
        super().__init__(in_ch, out_ch, 1, stride=1, bias=False)
        self.subsample = stride

    def forward(self, x: Tensor) -> Tensor:
        s = self.subsample
        return super().forward(x[..., ::s, ::s] if s > 1 else x)

    def extra_repr(self) -> str:
        return f"{super().extra_repr()}, subsample={self.subsample}"


class ChannelAttention(nn.Module):
    """Channel attention map M_C (eq. 8): ``(B, C, H, W) -> (B, C, 1, 1)`` in (0, 1).

    Average- and max-pool over space, one shared MLP ``C -> max(C // reduction, 1) -> C``
    (LeakyReLU between), sum, sigmoid.
    """

    def __init__(self, channels: int, reduction: int = 4, negative_slope: float = 0.01):
        super().__init__()
        hidden = max(channels // reduction, 1)
        self.mlp = nn.Sequential(
            nn.Linear(channels, hidden), nn.LeakyReLU(negative_slope), nn.Linear(hidden, channels)
        )

    def forward(self, x: Tensor) -> Tensor:
        avg = self.mlp(x.mean(dim=(2, 3)))
        mx = self.mlp(x.flatten(2).max(dim=2).values)  # not amax: see SpatialAttention.forward
        return torch.sigmoid(avg + mx)[:, :, None, None]


class SpatialAttention(nn.Module):
    """Spatial attention map M_S (eq. 9): ``(B, C, H, W) -> (B, 1, H, W)`` in (0, 1).

    Average- and max-pool over channels, stack as 2 channels ``[avg, max]``, conv (odd ``kernel``,
    same padding, no bias), sigmoid.
    """

    def __init__(self, kernel: int = 7):
        super().__init__()
        if kernel % 2 != 1:
            raise ValueError(f"kernel must be odd, got {kernel}")
        self.conv = nn.Conv2d(2, 1, kernel, padding=kernel // 2, bias=False)

    def forward(self, x: Tensor) -> Tensor:
        # max(...).values, not amax: the same forward, but amax's backward finds the maxima again by comparing x
        # with them, and torch.compile under bf16 autocast compares a recomputed fp32 x with the bf16-rounded
        # maximum; a row then has no maximum, the gradient is 0 / 0 and NUE's training loss NaN from step 2
        # (torch 2.13.0, CBAM of f_u). max's backward routes through the indices of the forward. Ties get the whole
        # gradient at one index instead of an even split.
        pooled = torch.cat([x.mean(dim=1, keepdim=True), x.max(dim=1, keepdim=True).values], dim=1)
        return torch.sigmoid(self.conv(pooled))


class CBAM(nn.Module):
    """Convolutional block attention: ``F'' = M_S(F') * F'`` with ``F' = M_C(F) * F``; shape preserved."""

    def __init__(self, channels: int, reduction: int = 4, kernel: int = 7, negative_slope: float = 0.01):
        super().__init__()
        self.channel = ChannelAttention(channels, reduction, negative_slope)
        self.spatial = SpatialAttention(kernel)

    def forward(self, x: Tensor) -> Tensor:
        x = self.channel(x) * x
        return self.spatial(x) * x


def mlp(dims: Sequence[int], negative_slope: float = 0.01, final_activation: bool = True) -> nn.Sequential:
    """Linear layers ``dims[0] -> dims[1] -> ... -> dims[-1]`` with LeakyReLU between (and after, if asked)."""
    layers: list[nn.Module] = []
    for i, (a, b) in enumerate(zip(dims[:-1], dims[1:])):
        layers.append(nn.Linear(a, b))
        if i < len(dims) - 2 or final_activation:
            layers.append(nn.LeakyReLU(negative_slope))
    return nn.Sequential(*layers)


class ConvBranch(nn.Module):
    """Image -> vector: stride-2 residual blocks -> adaptive average pool to a fixed grid -> [CBAM] -> flatten -> MLP.

    ``(B, in_ch, H, W) -> (B, out_dim)`` for any H, W (the pool fixes the MLP's input length).
    Attributes a reader may hook (e.g. Grad-CAM): ``encoder`` (the residual blocks), ``pool``,
    ``cbam`` (None when disabled: no parameters then), ``head``.
    """

    def __init__(
        self,
        in_ch: int,
        channels: Sequence[int],
        grid: tuple[int, int],
        out_dim: int,
        cbam: bool = False,
        cbam_reduction: int = 4,
        cbam_kernel: int = 7,
        negative_slope: float = 0.01,
    ):
        super().__init__()
        chans = [in_ch, *channels]
        self.encoder = nn.Sequential(
            *(ResidualBlock(a, b, stride=2, negative_slope=negative_slope) for a, b in zip(chans[:-1], chans[1:]))
        )
        self.pool = nn.AdaptiveAvgPool2d(grid)
        self.cbam = CBAM(chans[-1], cbam_reduction, cbam_kernel, negative_slope) if cbam else None
        self.head = nn.Sequential(
            nn.Flatten(), mlp([chans[-1] * grid[0] * grid[1], out_dim, out_dim], negative_slope)
        )

    def feature_map(self, x: Tensor) -> Tensor:
        """The pooled (and attended) grid ``(B, C, *grid)`` before the MLP (F_u for the uncertainty branch)."""
        f = self.pool(self.encoder(x))
        return self.cbam(f) if self.cbam is not None else f

    def forward(self, x: Tensor) -> Tensor:
        return self.head(self.feature_map(x))
