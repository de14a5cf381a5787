"""The policy's typed input batch and the one function that builds it from raw frames and NeRF maps.

``prepare_input`` is used identically by demonstration collection, training and evaluation, so the
networks always see the same resizing and normalisation:

* live RGB ``(H, W, 3) uint8`` -> ``rgb / 255``; z-depth metres -> ``clip(d, 0, max_depth) / max_depth``
  (NaN -> 0); stacked as 4 channels and area-resized to the config's frame size;
* goal RGB ``(H, W, 3) uint8`` -> ``/ 255``, area-resized to ``config.goal_size`` (the map size for
  NUE, whose f_cog concatenates it with I_cog; the frame size for the baselines);
* I_u and I_cog pass through raw (area-resized only if not at the config's map size). The model
  itself maps I_u to ``log1p(I_u / uncertainty_scale)``: a rendered variance spans orders of
  magnitude, and keeping the transform inside the model lets a checkpoint carry it.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from typing import Any
from dataclasses import dataclass

import numpy as np
import torch
import torch.nn.functional as F
from torch import Tensor

from nue.policy.config import ModelConfig


@dataclass
class PolicyInput:
    """One batch of policy inputs; every tensor has a leading batch dim B (or (T, B) for sequences).

    ``rgbd``: (B, 4, h_p, w_p) float, channels (r, g, b, depth), rgb / 255 and clip(depth, 0, 5) / 5.
    ``goal``: (B, 3, h_g, w_g) float in [0, 1] (h_g, w_g = ``config.goal_size``).
    ``i_u``: (B, 1, h, w) float >= 0, raw rendered variance; None for models without f_u.
    ``i_cog``: (B, 64, h, w) float, rendered NeRF features; None for the baselines.
    ``panorama``: (B, K, hp, wp) float >= 0, the memory's raw I_u of K views around the robot; None unless the model
    reads it (``ModelConfig.uses_panorama``).
    """

    rgbd: Tensor
    goal: Tensor
    i_u: Tensor | None = None
    i_cog: Tensor | None = None
    panorama: Tensor | None = None

    def _map(self, fn) -> "PolicyInput":
        return PolicyInput(**{f.name: (None if (v := getattr(self, f.name)) is None else fn(v))
                              for f in dataclasses.fields(self)})

    def to(self, device: torch.device | str) -> "PolicyInput":
        """The same batch on another device."""
        return self._map(lambda t: t.to(device))

    def with_image_dtype(self, dtype: torch.dtype) -> "PolicyInput":
        """``rgbd`` and ``i_cog`` cast to ``dtype``; ``goal`` and ``i_u`` keep theirs.

        For training under autocast: both go straight into a concatenation and a convolution (the models cast
        a resampled goal to their dtype, :meth:`nue.policy.nue_model.NUEPolicy.features`), which autocast
        would cast to its dtype anyway, so the network computes the same numbers while the concatenations and
        strided copies in front of the first convolutions move half the bytes. ``goal`` is area-resampled and
        ``i_u`` goes through ``log1p`` first, in their own precision.
        """
        return dataclasses.replace(self, rgbd=self.rgbd.to(dtype), i_cog=None if self.i_cog is None else self.i_cog.to(dtype))

    @property
    def batch_size(self) -> int:
        return int(self.rgbd.shape[0])

    def flatten_time(self) -> "PolicyInput":
        """(T, B, ...) -> (T * B, ...)."""
        return self._map(lambda t: t.reshape(-1, *t.shape[2:]))

    def step(self, t: int) -> "PolicyInput":
        """Time step ``t`` of a (T, B, ...) sequence batch: (B, ...)."""
        return self._map(lambda x: x[t])

    def index(self, idx) -> "PolicyInput":
        """Rows ``idx`` (any tensor index) of every tensor."""
        return self._map(lambda t: t[idx])

    @staticmethod
    def cat(items: Sequence["PolicyInput"], dim: int = 0) -> "PolicyInput":
        """Concatenate batches along ``dim`` (0: batch; use ``stack`` to add a time dim)."""
        return _combine(items, lambda ts: torch.cat(ts, dim))

    @staticmethod
    def stack(items: Sequence["PolicyInput"], dim: int = 0) -> "PolicyInput":
        """Stack batches along a new ``dim`` (e.g. T steps of (B, ...) -> (T, B, ...))."""
        return _combine(items, lambda ts: torch.stack(ts, dim))


def _combine(items: Sequence[PolicyInput], fn) -> PolicyInput:
    if not items:
        raise ValueError("need at least one PolicyInput")
    out: dict[str, Any] = {}
    for f in dataclasses.fields(PolicyInput):
        vals = [getattr(x, f.name) for x in items]
        if all(v is None for v in vals):
            out[f.name] = None
        elif any(v is None for v in vals):
            raise ValueError(f"PolicyInput.{f.name} is None in some items but not in others")
        else:
            out[f.name] = fn(vals)
    return PolicyInput(**out)


def _as_float_tensor(x, device) -> Tensor:
    t = torch.as_tensor(np.asarray(x)) if not isinstance(x, Tensor) else x
    return t.to(device=device, dtype=torch.float32)


def resize_area(x: Tensor, size: tuple[int, int]) -> Tensor:
    """Area-resize (B, C, H, W) to ``size`` (no-op when already there)."""
    if tuple(x.shape[-2:]) == tuple(size):
        return x
    return F.interpolate(x, size=size, mode="area")


def _image(x, batched: bool, device, name: str) -> Tensor:
    """(H, W, 3) or (B, H, W, 3), uint8 in 0..255 or float in [0, 1] -> (B, 3, H, W) float in [0, 1]."""
    raw = x if isinstance(x, Tensor) else torch.as_tensor(np.asarray(x))
    t = raw.to(device=device, dtype=torch.float32)
    if raw.dtype == torch.uint8:
        t = t / 255.0
    elif raw.numel() and (t.min() < 0.0 or t.max() > 1.0):
        raise ValueError(f"{name}: float images must lie in [0, 1] (or pass uint8 0..255)")
    if not batched:
        t = t[None]
    if t.ndim != 4 or t.shape[-1] != 3:
        raise ValueError(f"{name}: expected (H, W, 3) or (B, H, W, 3), got {tuple(t.shape)}")
    return t.permute(0, 3, 1, 2)


def _map_tensor(x, batched: bool, channels: int, device, name: str) -> Tensor:
    """(h, w) [1 channel only], (C, h, w) or batched (B, h, w) [1 channel only], (B, C, h, w) -> (B, C, h, w)."""
    t = _as_float_tensor(x, device)
    if not batched:
        t = t[None]
    if t.ndim == 3 and channels == 1:
        t = t[:, None]
    if t.ndim != 4 or t.shape[1] != channels:
        raise ValueError(f"{name}: expected {channels} channel(s) with shape (C, h, w) or (B, C, h, w), "
                         f"got {tuple(t.shape)}")
    return t


def prepare_goal(goal, config: ModelConfig, device: torch.device | str | None = None, batched: bool = False) -> Tensor:
    """The goal part of :func:`prepare_input`: goal RGB ``(H', W', 3)`` (or ``(B, H', W', 3)`` if ``batched``),
    uint8 or float in [0, 1] -> ``(B, 3, h_g, w_g)`` in [0, 1] at ``config.goal_size``."""
    return resize_area(_image(goal, batched, device, "goal"), config.goal_size)


def prepare_input(
    rgb,
    depth,
    goal,
    i_u,
    i_cog,
    config: ModelConfig,
    device: torch.device | str | None = None,
    *,
    goal_input: Tensor | None = None,
    panorama=None,
) -> PolicyInput:
    """Raw observation + goal + NeRF maps -> a normalised, resized :class:`PolicyInput`.

    Unbatched: ``rgb`` (H, W, 3) uint8, ``depth`` (H, W) or (H, W, 1) metres (z-depth; NaN and the
    renderer's 0 for "no surface" both map to 0), ``goal`` (H', W', 3) uint8, ``i_u`` (h, w) or
    (1, h, w), ``i_cog`` (64, h, w); gives batch size 1. Images may also be float in [0, 1].
    Batched: the same with a leading B (``rgb`` (B, H, W, 3) marks the call as batched).
    numpy arrays or torch tensors. Maps the config does not use may be None (and are dropped
    if given); maps it uses are required. ``goal_input``: ``prepare_goal(goal, ...)`` computed earlier (the
    goal photo stays the same for a whole episode); ``goal`` is then not read. ``panorama``: the memory's I_u panorama
    (K, hp, wp) (or (B, K, hp, wp)), required by models that read it, passed through raw.
    """
    batched = np.ndim(rgb) == 4 if not isinstance(rgb, Tensor) else rgb.ndim == 4
    rgb_t = _image(rgb, batched, device, "rgb")
    b, _, h, w = rgb_t.shape

    d = _as_float_tensor(depth, device)
    if d.ndim == (4 if batched else 3) and d.shape[-1] == 1:
        d = d[..., 0]
    if not batched:
        d = d[None]
    if tuple(d.shape) != (b, h, w):
        raise ValueError(f"depth: expected shape {(h, w)} (per frame) matching rgb, got {tuple(d.shape)}")
    d = torch.nan_to_num(d, nan=0.0, posinf=config.max_depth, neginf=0.0)
    d = d.clamp(0.0, config.max_depth) / config.max_depth
    rgbd = resize_area(torch.cat([rgb_t, d[:, None]], dim=1), config.frame_size)

    goal_t = prepare_goal(goal, config, device, batched) if goal_input is None else goal_input
    if goal_t.shape[0] != b:
        raise ValueError(f"goal: batch {goal_t.shape[0]} does not match rgb batch {b}")

    u = cog = None
    if config.uses_i_u:
        if i_u is None:
            raise ValueError(f"model {config.name!r} reads the uncertainty map I_u, but i_u is None")
        u = resize_area(_map_tensor(i_u, batched, 1, device, "i_u"), config.map_size)
    if config.uses_i_cog:
        if i_cog is None:
            raise ValueError(f"model {config.name!r} reads the feature map I_cog, but i_cog is None")
        cog = resize_area(_map_tensor(i_cog, batched, config.cog_channels, device, "i_cog"), config.map_size)
    pano = None
    if config.uses_panorama:
        if panorama is None:
            raise ValueError(f"model {config.name!r} reads the uncertainty panorama, but panorama is None (a memory "
                             "preset with panorama_headings, e.g. fast_pano)")
        pano = _map_tensor(panorama, batched, config.panorama_shape[0], device, "panorama")
        if tuple(pano.shape[-2:]) != tuple(config.panorama_shape[1:]):
            raise ValueError(f"panorama: expected views of {tuple(config.panorama_shape[1:])}, got {tuple(pano.shape[-2:])}")
    for name, m in (("i_u", u), ("i_cog", cog), ("panorama", pano)):
        if m is not None and m.shape[0] != b:
            raise ValueError(f"{name}: batch {m.shape[0]} does not match rgb batch {b}")
    return PolicyInput(rgbd=rgbd, goal=goal_t, i_u=u, i_cog=cog, panorama=pano)
