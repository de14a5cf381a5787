"""Compact storage of demonstration arrays: per-step, per-channel affine n-bit codes (:class:`QuantizedArray`)
and which array ``nue collect`` stores how (:class:`StepStorage`).

A (T, C, H, W) float array is stored as integer codes ``q`` in [0, 2^b - 1] with one offset ``lo`` and one
``scale`` per (step, channel)::

    lo = min_{h,w} x,   scale = (max_{h,w} x - lo) / (2^b - 1),   q = round((x - lo) / scale),   x^ = lo + scale * q

so ``|x^ - x| <= scale / 2`` (up to float32 rounding), a channel's minimum is exact (a feature map's zeros stay
zeros) and a constant channel (``scale = 0``) is exact. Example, b = 4 (15 code steps), one channel holding
``[0, 0.5, 3.75]``: lo = 0, scale = 0.25, q = [0, 2, 15], x^ = [0, 0.5, 3.75] (exact); ``[0, 0.3, 3.75]``
gives q = [0, 1, 15], x^ = [0, 0.25, 3.75], error 0.05 <= scale / 2 = 0.125.

At 4 bits two codes share a byte: column 2k in the low nibble, 2k + 1 in the high one (an odd width pads
the last byte's high nibble with 0). Decoding is a handful of vectorised numpy operations over whatever
steps are selected; the codes stay memory-mapped until then.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

BITS = (4, 8)
"""Supported code widths."""


def _packed_width(width: int, bits: int) -> int:
    return -(-width * bits // 8)


def quantize(x, bits: int) -> QuantizedArray:
    """(T, C, H, W) finite floats -> :class:`QuantizedArray` with ``bits``-bit codes (see the module docstring).

    Raises ValueError for NaN or inf (no offset and scale represent them) or an unsupported ``bits``.
    """
    if bits not in BITS:
        raise ValueError(f"bits must be one of {BITS}, got {bits}")
    x = np.asarray(x, dtype=np.float32)
    if x.ndim != 4:
        raise ValueError(f"expected a (T, C, H, W) array, got shape {x.shape}")
    if not np.isfinite(x).all():
        raise ValueError(f"cannot quantise non-finite values ({int(np.isnan(x).sum())} NaN, "
                         f"{int(np.isinf(x).sum())} inf)")
    levels = (1 << bits) - 1
    t, c, h, w = x.shape
    lo = x.min(axis=(2, 3)) if x.size else np.zeros((t, c), np.float32)
    hi = x.max(axis=(2, 3)) if x.size else lo
    scale = ((hi - lo) / levels).astype(np.float32)
    safe = np.where(scale > 0, scale, 1.0).astype(np.float32)
    q = np.rint((x - lo[..., None, None]) / safe[..., None, None])
    q = np.clip(q, 0, levels).astype(np.uint8)
    if bits == 4:
        if w % 2:
            q = np.concatenate([q, np.zeros((t, c, h, 1), np.uint8)], axis=3)
        q = q[..., 0::2] | (q[..., 1::2] << 4)
    return QuantizedArray(np.ascontiguousarray(q), lo.astype(np.float32), scale, bits, w)


def dequantize(codes: np.ndarray, lo: np.ndarray, scale: np.ndarray, bits: int, width: int) -> np.ndarray:
    """Codes (..., C, H, ceil(width * bits / 8)) uint8, ``lo`` / ``scale`` (..., C) -> (..., C, H, width)
    float32 ``lo + scale * q``."""
    codes = np.asarray(codes)
    out = np.empty((*codes.shape[:-1], width), np.float32)
    if bits == 4:
        out[..., 0::2] = codes[..., : (width + 1) // 2] & 15
        out[..., 1::2] = codes[..., : width // 2] >> 4
    elif bits == 8:
        out[...] = codes
    else:
        raise ValueError(f"bits must be one of {BITS}, got {bits}")
    out *= np.asarray(scale, np.float32)[..., None, None]
    out += np.asarray(lo, np.float32)[..., None, None]
    return out


@dataclass(frozen=True, eq=False)
class QuantizedArray:
    """A (T, C, H, W) float32 array held as n-bit codes; indexing the step axis decodes only those steps.

    Behaves like a read-only array for ``x[t]``, ``x[ts]``, ``x[a:b]`` (step axis only), ``len``, ``shape``,
    ``dtype`` and ``np.asarray(x)``; the parts may be memory-mapped.
    """

    codes: np.ndarray
    """(T, C, H, ceil(W * bits / 8)) uint8."""
    lo: np.ndarray
    """(T, C) float32: each channel's minimum (its code 0)."""
    scale: np.ndarray
    """(T, C) float32: the value of one code step (0 for a constant channel)."""
    bits: int
    """Bits per code (:data:`BITS`)."""
    width: int
    """W (the packed codes hold ``ceil(W * bits / 8)`` bytes per row)."""

    def __post_init__(self):
        t, c = self.lo.shape
        if self.bits not in BITS or self.scale.shape != (t, c) or self.codes.shape[:2] != (t, c) \
                or self.codes.shape[-1] != _packed_width(self.width, self.bits) or self.codes.dtype != np.uint8:
            raise ValueError(f"inconsistent quantised array: codes {self.codes.shape} {self.codes.dtype}, "
                             f"lo {self.lo.shape}, scale {self.scale.shape}, {self.bits} bits, width {self.width}")

    @property
    def shape(self) -> tuple[int, int, int, int]:
        return (*self.codes.shape[:-1], self.width)

    dtype = np.dtype(np.float32)
    ndim = 4

    @property
    def nbytes(self) -> int:
        """Bytes stored (codes + offsets + scales)."""
        return int(self.codes.nbytes + self.lo.nbytes + self.scale.nbytes)

    @property
    def max_error(self) -> np.ndarray:
        """(T, C): the bound on ``|x^ - x|`` per step and channel (half a code step)."""
        return np.asarray(self.scale) / 2

    def __len__(self) -> int:
        return len(self.lo)

    def __getitem__(self, t) -> np.ndarray:
        """Steps ``t`` (an int, a slice or an index array) decoded to float32."""
        if isinstance(t, tuple):
            raise IndexError("a QuantizedArray is indexed along its step axis only")
        return dequantize(self.codes[t], self.lo[t], self.scale[t], self.bits, self.width)

    def __array__(self, dtype=None, copy=None):
        x = self[:]
        return x if dtype is None else x.astype(dtype, copy=False)

    @staticmethod
    def concatenate(parts: list[QuantizedArray]) -> QuantizedArray:
        """Join arrays of the same bits, width, C and H along the step axis."""
        if len({(p.bits, p.width, p.codes.shape[1:]) for p in parts}) != 1:
            raise ValueError("cannot concatenate quantised arrays of different bits or shapes")
        return QuantizedArray(np.concatenate([p.codes for p in parts]), np.concatenate([p.lo for p in parts]),
                              np.concatenate([p.scale for p in parts]), parts[0].bits, parts[0].width)


@dataclass(frozen=True)
class StepStorage:
    """How ``nue collect`` stores the per-step arrays of a demonstration (bits of :func:`quantize`; 0 = float16).

    The default takes a step from 428 KiB (all float16) to about 140 KiB; ``docs/history/benchmarks.md`` has the
    measured quantisation error and held-out accuracy.
    """

    rgbd_bits: int = 8
    """Bits of the RGB-D frame (T, 4, fh, fw), values in [0, 1]; 0 = float16; 8 bits = at most 1/510 of a
    channel's range per step."""
    i_cog_bits: int = 4
    """Bits of the feature map I_cog (T, 64, h, w); 0 = float16; 4 bits = a quarter of float16's bytes."""
    i_u_bits: int = 0
    """Bits of the uncertainty map I_u (T, 1, h, w); 0 = float16 (its values span decades; 5 KB a step)."""

    def encode(self, name: str, x) -> np.ndarray | QuantizedArray:
        """``x`` (T, C, H, W) float as ``name`` is stored: a :class:`QuantizedArray`, or float16."""
        bits = {"rgbd": self.rgbd_bits, "i_cog": self.i_cog_bits, "i_u": self.i_u_bits}[name]
        return quantize(x, bits) if bits else np.asarray(x, dtype=np.float16)
