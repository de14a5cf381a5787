"""Quality measures of the memory: which pixels earlier frames saw (ground truth), AUROC, PSNR.

Ground truth for uncertainty comes from the simulator's depth and poses only: a pixel of the current
view is *seen* if its back-projected 3-D point projects inside an earlier frame's image, in front of
that camera, and that frame's depth there agrees with the point's depth within a tolerance.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from scipy.stats import rankdata

from nue.sim.camera import pixel_directions, world_from_camera
from nue.sim.task import CameraConfig


def seen_mask(
    depth: np.ndarray,
    pose,
    earlier: Sequence[tuple[np.ndarray, object]],
    camera: CameraConfig,
    pixels: tuple[np.ndarray, np.ndarray] | None = None,
    floor_z: float = 0.0,
    abs_tol: float = 0.05,
    rel_tol: float = 0.03,
) -> tuple[np.ndarray, np.ndarray]:
    """Which pixels of the current frame some earlier frame saw.

    ``depth (H, W)`` z-depth metres of the current frame at ``pose (x, y, yaw)``; ``earlier``: (depth
    (H, W), pose) of the frames the memory was trained on; ``pixels = (rows, cols)`` selects a map grid
    (default: every pixel). Returns ``(seen, valid)``, both boolean ``(len(rows), len(cols))``; ``valid``
    is False where the current depth is invalid (such pixels have no label). Agreement:
    ``|z_earlier - z_projected| <= abs_tol + rel_tol * z_projected``.
    """
    rows, cols = pixels if pixels is not None else (np.arange(camera.height), np.arange(camera.width))
    z = np.asarray(depth, dtype=np.float64)[np.ix_(rows, cols)]
    valid = np.isfinite(z) & (z > 0)
    d_cam = pixel_directions(camera)[np.ix_(rows, cols)]
    m = world_from_camera(np.asarray(pose, dtype=np.float64), camera, floor_z)
    pts = (d_cam * np.where(valid, z, 0.0)[..., None]) @ m[:3, :3].T + m[:3, 3]
    pts = pts.reshape(-1, 3)
    seen = np.zeros(pts.shape[0], dtype=bool)
    for d_j, pose_j in earlier:
        mj = world_from_camera(np.asarray(pose_j, dtype=np.float64), camera, floor_z)
        p = (pts - mj[:3, 3]) @ mj[:3, :3]  # world -> camera j (rotation transpose)
        zj = p[:, 2]
        front = zj > camera.near
        with np.errstate(divide="ignore", invalid="ignore"):
            u = camera.fx * p[:, 0] / zj + camera.cx
            v = camera.fy * p[:, 1] / zj + camera.cy
        inside = front & (u >= 0) & (u < camera.width) & (v >= 0) & (v < camera.height)
        idx = np.nonzero(inside & ~seen)[0]
        if idx.size == 0:
            continue
        obs = np.asarray(d_j, dtype=np.float64)[v[idx].astype(np.int64), u[idx].astype(np.int64)]
        ok = np.isfinite(obs) & (obs > 0) & (np.abs(obs - zj[idx]) <= abs_tol + rel_tol * zj[idx])
        seen[idx[ok]] = True
    return seen.reshape(z.shape) & valid, valid


def auroc(scores: np.ndarray, positives: np.ndarray) -> float:
    """Area under the ROC curve of ``scores`` for labels ``positives`` (Mann-Whitney U, ties averaged).

    Returns NaN when one class is empty. Example: scores [0.1, 0.4, 0.35, 0.8], labels [0, 0, 1, 1] -> 0.75.
    """
    s = np.asarray(scores, dtype=np.float64).reshape(-1)
    y = np.asarray(positives, dtype=bool).reshape(-1)
    n_pos, n_neg = int(y.sum()), int((~y).sum())
    if n_pos == 0 or n_neg == 0:
        return float("nan")
    ranks = rankdata(s)
    return float((ranks[y].sum() - n_pos * (n_pos + 1) / 2.0) / (n_pos * n_neg))


def psnr(pred: np.ndarray, target: np.ndarray, mask: np.ndarray | None = None) -> float:
    """Peak signal-to-noise ratio in dB of images in [0, 1]: ``-10 log10(mean squared error)``, over the
    pixels where ``mask`` is True (``pred, target (..., 3)``, ``mask`` the leading shape)."""
    err = (np.asarray(pred, dtype=np.float64) - np.asarray(target, dtype=np.float64)) ** 2
    if mask is not None:
        err = err[np.asarray(mask, dtype=bool)]
    if err.size == 0:
        return float("nan")
    return float(-10.0 * np.log10(max(err.mean(), 1e-12)))
