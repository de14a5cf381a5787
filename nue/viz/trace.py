"""Per-step episode traces for figures: an ``EpisodeTrace`` and a ``TraceRecorder`` to use as the ``on_step``
callback of :func:`nue.rollout.run_episode`.

Memory stays bounded: the live RGB is stored subsampled (every ``rgb_stride``-th pixel), I_u as
(h, w) float32 and I_cog reduced from 64 to 3 channels (a fixed PCA basis or 3 fixed channels), so
an 800-step episode at the default sizes takes about 60 MB.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Callable, Sequence

import numpy as np


def to_numpy(x) -> np.ndarray | None:
    """A torch tensor or array-like as a float32 numpy array (None stays None)."""
    if x is None:
        return None
    if hasattr(x, "detach"):
        x = x.detach().cpu().float().numpy()
    return np.asarray(x, dtype=np.float32)


def pca_basis(i_cog: np.ndarray, k: int = 3) -> tuple[np.ndarray, np.ndarray]:
    """First ``k`` principal directions of the pixels of a feature map ``(C, h, w)``.

    Returns ``(mean (C,), basis (k, C))``; each direction's sign is fixed so that its largest
    entry is positive (so the colours do not flip between runs).
    """
    x = np.asarray(i_cog, dtype=np.float64).reshape(i_cog.shape[0], -1).T  # (h*w, C)
    mean = x.mean(axis=0)
    _, _, vt = np.linalg.svd(x - mean, full_matrices=False)
    basis = vt[:k]
    if basis.shape[0] < k:
        basis = np.vstack([basis, np.zeros((k - basis.shape[0], x.shape[1]))])
    signs = np.sign(basis[np.arange(k), np.abs(basis).argmax(axis=1)])
    basis *= np.where(signs == 0, 1.0, signs)[:, None]
    return mean.astype(np.float32), basis.astype(np.float32)


def reduce_cog(i_cog: np.ndarray, mean: np.ndarray | None = None, basis: np.ndarray | None = None,
               channels: Sequence[int] = (0, 1, 2)) -> np.ndarray:
    """I_cog ``(C, h, w)`` -> ``(3, h, w)``: projected on ``basis`` (3, C) after removing ``mean`` (C,),
    or, without a basis, the given 3 channels."""
    i_cog = np.asarray(i_cog, dtype=np.float32)
    if basis is None:
        return i_cog[list(channels)].copy()
    c, h, w = i_cog.shape
    x = i_cog.reshape(c, -1) - (0 if mean is None else mean[:, None])
    return (basis @ x).reshape(-1, h, w).astype(np.float32)


def cog_to_rgb(x: np.ndarray, lo: np.ndarray | None = None, hi: np.ndarray | None = None) -> np.ndarray:
    """Reduced I_cog ``(3, h, w)`` -> image ``(h, w, 3)`` in [0, 1], per channel ``(x - lo) / (hi - lo)``.

    ``lo``, ``hi`` (3,) default to this map's 1st / 99th percentiles; pass an episode's to keep
    colours comparable across frames.
    """
    x = np.asarray(x, dtype=np.float32)
    lo = np.percentile(x, 1, axis=(1, 2)) if lo is None else np.asarray(lo)
    hi = np.percentile(x, 99, axis=(1, 2)) if hi is None else np.asarray(hi)
    span = np.where(hi - lo > 1e-12, hi - lo, 1.0)
    return np.clip((x - lo[:, None, None]) / span[:, None, None], 0.0, 1.0).transpose(1, 2, 0)


@dataclass
class EpisodeTrace:
    """What one episode looked like, step by step (index t = the t-th decision)."""

    poses: list[np.ndarray] = field(default_factory=list)
    """Robot pose ``(x, y, yaw)`` (3,) when the action was chosen."""
    rgb: list[np.ndarray] = field(default_factory=list)
    """Live RGB ``(H / s, W / s, 3)`` uint8 (s = the recorder's ``rgb_stride``)."""
    i_u: list[np.ndarray | None] = field(default_factory=list)
    """Uncertainty map ``(h, w)`` float32, or None when the memory gave none."""
    i_cog: list[np.ndarray | None] = field(default_factory=list)
    """Reduced feature map ``(3, h, w)`` float32 (see :func:`reduce_cog`), or None."""
    aux_angle: list[float | None] = field(default_factory=list)
    """Predicted goal angle (radians, positive = left) from the auxiliary head, or None."""
    goal_angle: list[float] = field(default_factory=list)
    """True goal angle (radians, positive = left), from ``info["goal_angle"]``."""
    actions: list[int] = field(default_factory=list)
    """Action chosen."""
    goal_xy: np.ndarray | None = None
    """Goal position (2,), metres."""
    success_radius: float = 0.0
    """The task's success radius, metres."""
    scene: str = ""
    """Scene name."""
    episode_id: str = ""
    """Episode id."""
    final_pose: np.ndarray | None = None
    """Pose after the last action (set by :meth:`TraceRecorder.finish`), or None."""

    def __len__(self) -> int:
        return len(self.poses)

    def pose_array(self) -> np.ndarray:
        """``(T, 3)`` poses at the decisions."""
        return np.asarray(self.poses, dtype=np.float64).reshape(-1, 3)

    def trajectory(self) -> np.ndarray:
        """``(T [+ 1], 3)`` poses, with the final pose appended when known."""
        p = self.pose_array()
        return p if self.final_pose is None else np.vstack([p, np.asarray(self.final_pose, dtype=np.float64)[None]])

    def aux_array(self) -> np.ndarray:
        """``(T,)`` predicted goal angles, NaN where there was none."""
        return np.array([np.nan if a is None else a for a in self.aux_angle], dtype=np.float64)

    def goal_angle_array(self) -> np.ndarray:
        """``(T,)`` true goal angles."""
        return np.asarray(self.goal_angle, dtype=np.float64)


class TraceRecorder:
    """``on_step`` callback filling an :class:`EpisodeTrace`; a step with ``t == 0`` starts a new trace.

    ``StepData.maps`` may be None or any object with ``i_u`` (1, h, w) and ``i_cog`` (C, h, w)
    (torch or numpy; missing attributes count as None). I_cog is reduced with ``cog_basis``
    (``(mean (C,), basis (3, C))``) when given; else with the PCA basis of the episode's first
    I_cog (``cog_mode="pca"``) or the fixed ``cog_channels`` (``cog_mode="channels"``).
    ``aux_source(step)`` returns the predicted goal angle; with :class:`nue.policy.agent.PolicyAgent`
    (``on_step`` runs right after ``act``) pass ``aux_source=lambda s: agent.last_aux``. Without
    it the trace's predictions are None.
    """

    def __init__(self, rgb_stride: int = 2, cog_mode: str = "pca", cog_channels: Sequence[int] = (0, 1, 2),
                 cog_basis: tuple[np.ndarray, np.ndarray] | None = None,
                 aux_source: Callable[[Any], float | None] | None = None):
        if cog_mode not in ("pca", "channels"):
            raise ValueError(f"cog_mode must be 'pca' or 'channels', got {cog_mode!r}")
        self.rgb_stride = max(1, int(rgb_stride))
        self.cog_mode = cog_mode
        self.cog_channels = tuple(cog_channels)
        self.fixed_basis = cog_basis
        self.aux_source = aux_source
        self.trace = EpisodeTrace()
        self._basis: tuple[np.ndarray, np.ndarray] | None = cog_basis

    def __call__(self, step) -> None:
        if step.t == 0:
            env = step.env
            self.trace = EpisodeTrace(goal_xy=np.asarray(env.goal_xy, dtype=np.float64).copy(),
                                      success_radius=float(env.task.success_radius), scene=env.scene.name,
                                      episode_id=str(getattr(env.episode, "episode_id", "")))
            self._basis = self.fixed_basis
        tr, s = self.trace, self.rgb_stride
        tr.poses.append(np.asarray(step.obs["pose"], dtype=np.float64)[:3].copy())
        tr.rgb.append(np.ascontiguousarray(np.asarray(step.obs["rgb"])[::s, ::s, :3]).astype(np.uint8))
        i_u = to_numpy(getattr(step.maps, "i_u", None))
        tr.i_u.append(None if i_u is None else i_u.reshape(i_u.shape[-2:]).copy())
        cog = to_numpy(getattr(step.maps, "i_cog", None))
        if cog is not None:
            if self._basis is None and self.cog_mode == "pca":
                self._basis = pca_basis(cog)
            mean, basis = self._basis if self._basis is not None else (None, None)
            cog = reduce_cog(cog, mean, basis, self.cog_channels)
        tr.i_cog.append(cog)
        aux = self.aux_source(step) if self.aux_source is not None else None
        tr.aux_angle.append(None if aux is None else float(aux))
        tr.goal_angle.append(float(step.info["goal_angle"]))
        tr.actions.append(int(step.action))

    def finish(self, env) -> EpisodeTrace:
        """Record the pose after the last action (``env.pose``) and return the trace."""
        self.trace.final_pose = np.asarray(env.pose, dtype=np.float64)[:3].copy()
        return self.trace
