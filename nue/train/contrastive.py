"""Contrastive pre-training of VGM's embedding network on demonstration frames, without labels.

VGM trains its image encoder unsupervised on images of the training environments and freezes it; here the images
are the RGB frames of the demonstrations ``nue train`` reads (the same training houses; actions, poses and goals
are not read). A batch draws ``embed_batch`` anchor frames; each anchor's positive is a frame at most
``embed_window`` steps away in the same demonstration (a nearby view: the robot moved or turned a little), both
augmented (a random crop of 80-100 % of the frame resized back, a brightness and contrast jitter). The loss is
InfoNCE (SimCLR's NT-Xent) over the 2 x batch views with temperature tau: each view must pick its partner among
the other 2 x batch - 1 views. Views of one place a few steps apart thus embed close, and the graph's threshold
on cosine similarity separates places.

Deviation from VGM: its encoder (a ResNet-18 on RGB-D panoramas) was trained with prototypical contrastive learning
(instance discrimination plus clustering into prototypes); here plain InfoNCE with temporal neighbours as positives,
on a small CNN, a few hundred steps (``ModelConfig.embed_steps``) at the start of ``nue train --model vgm``.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import torch
import torch.nn.functional as F
from torch import Tensor


def info_nce(z1: Tensor, z2: Tensor, temperature: float) -> Tensor:
    """NT-Xent loss of paired L2-normalised embeddings ``z1``, ``z2`` (B, E): the mean over the 2B views of
    ``-log softmax_j(sim(i, j) / t)[partner(i)]`` over the other 2B - 1 views; ``log(2B - 1)`` when all are alike."""
    z = torch.cat([z1, z2], dim=0)
    n = z1.shape[0]
    sim = (z @ z.t()) / temperature
    sim = sim.masked_fill(torch.eye(2 * n, dtype=torch.bool, device=z.device), -1e9)
    partner = torch.cat([torch.arange(n, 2 * n), torch.arange(0, n)]).to(z.device)
    return F.cross_entropy(sim, partner)


def augment(x: Tensor, gen: torch.Generator) -> Tensor:
    """Random crop (80-100 % of each side, anywhere) resized back, then brightness +-0.2 and contrast x[0.8, 1.2],
    clipped to [0, 1]: ``(B, 3, h, w) -> (B, 3, h, w)``, drawn from ``gen``."""
    b, _, h, w = x.shape
    out = torch.empty_like(x)
    r = torch.rand(b, 6, generator=gen)
    for i in range(b):
        ch, cw = max(1, int(h * (0.8 + 0.2 * r[i, 0]))), max(1, int(w * (0.8 + 0.2 * r[i, 1])))
        y0, x0 = int((h - ch) * r[i, 2]), int((w - cw) * r[i, 3])
        crop = x[i:i + 1, :, y0:y0 + ch, x0:x0 + cw]
        out[i] = F.interpolate(crop, size=(h, w), mode="bilinear", align_corners=False)[0]
    mean = out.mean(dim=(1, 2, 3), keepdim=True)
    contrast = (0.8 + 0.4 * r[:, 4]).to(x.dtype)[:, None, None, None]
    bright = (0.4 * r[:, 5] - 0.2).to(x.dtype)[:, None, None, None]
    return ((out - mean) * contrast + mean + bright).clamp(0.0, 1.0)


PairSource = Callable[[np.random.Generator, int], tuple[Tensor, Tensor]]
"""Draws ``n`` (anchor, positive) RGB pairs, each (n, 3, h, w) in [0, 1]."""


def demo_pairs(data, model_cfg, window: int, device="cpu") -> PairSource:
    """A :data:`PairSource` over a demonstration set (``nue.train.dataset.DemoSet``): anchor = a uniformly drawn
    step, positive = another step at most ``window`` away in the same episode (the anchor itself in a 1-step one)."""

    def draw(rng: np.random.Generator, n: int) -> tuple[Tensor, Tensor]:
        eps = rng.integers(data.n_episodes, size=n)
        lengths = data.lengths[eps]
        t = (rng.random(n) * lengths).astype(np.int64)
        off = rng.integers(1, window + 1, size=n) * rng.choice([-1, 1], size=n)
        t2 = t + off
        t2 = np.where((t2 < 0) | (t2 >= lengths), t - off, t2)
        t2 = np.clip(t2, 0, lengths - 1)
        batch = data.batch(np.stack([eps, eps]), np.stack([t, t2]), model_cfg, device)
        rgb = batch.inp.rgbd[:, :, :3]
        return rgb[0], rgb[1]

    return draw


def pretrain_embedding(embed: torch.nn.Module, pairs: PairSource, steps: int, batch: int, temperature: float,
                       lr: float, seed: int = 0, progress: Callable[[int, float], None] | None = None) -> list[float]:
    """Train ``embed`` (RGB (B, 3, h, w) -> L2-normalised (B, E)) for ``steps`` AdamW steps of :func:`info_nce` on
    augmented pairs from ``pairs``; returns the loss per step. ``embed`` is left in eval mode with ``requires_grad``
    False (frozen, as the policy uses it). Deterministic given ``seed`` (its own generators: the caller's draws are
    not shifted)."""
    rng = np.random.default_rng([seed, 39])
    gen = torch.Generator().manual_seed(int(rng.integers(2**31)))
    params = list(embed.parameters())
    for p in params:
        p.requires_grad_(True)
    opt = torch.optim.AdamW(params, lr=lr, weight_decay=1e-4)
    embed.train()
    losses = []
    for i in range(steps):
        anchor, positive = pairs(rng, batch)
        dev = anchor.device
        loss = info_nce(embed(augment(anchor.cpu(), gen).to(dev)), embed(augment(positive.cpu(), gen).to(dev)),
                        temperature)
        opt.zero_grad(set_to_none=True)
        loss.backward()
        opt.step()
        losses.append(float(loss.detach()))
        if progress is not None:
            progress(i + 1, losses[-1])
    embed.eval()
    for p in params:
        p.requires_grad_(False)
        p.grad = None
    return losses
