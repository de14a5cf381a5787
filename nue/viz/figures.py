"""Paper figures from arrays: Fig. 6 (trajectory + I_u over time), Fig. 7 (predicted vs true goal direction),
Fig. 8 (Grad-CAM of the uncertainty branch, via captum), and an animated GIF of one episode.

Figure functions return a matplotlib ``Figure`` (Agg); :func:`save_figure` writes it as PNG.
Map panels reuse :mod:`nue.viz.topdown`. Episode data usually comes from an
:class:`nue.viz.trace.EpisodeTrace`.
"""

from __future__ import annotations

from pathlib import Path
from typing import Sequence

import matplotlib

matplotlib.use("Agg")
import imageio.v3 as iio  # noqa: E402
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import torch  # noqa: E402
from captum.attr import LayerAttribution, LayerGradCam  # noqa: E402
from matplotlib.colors import LinearSegmentedColormap  # noqa: E402
from matplotlib.patches import Patch  # noqa: E402
from PIL import Image  # noqa: E402

from nue.policy.inputs import PolicyInput  # noqa: E402

from nue.viz.plot import save_figure  # noqa: E402,F401  (re-exported: figures are saved through it)
from nue.viz.topdown import draw_map, draw_trajectory  # noqa: E402
from nue.viz.trace import EpisodeTrace, cog_to_rgb  # noqa: E402

PROGRESS_CMAP = LinearSegmentedColormap.from_list("progress", ["#ffd700", "#ff0000"])
"""Yellow (start) to red (end), as the paper's Fig. 7."""
MOMENT_COLOURS = ("#00a0ff", "#00c853", "#ff9100", "#d500f9", "#ff1744")
"""Marker colours of the five moments t1..t5 in Fig. 6."""


def pick_moments(n_steps: int, k: int = 5) -> np.ndarray:
    """``k`` step indices spread evenly over ``[0, n_steps - 1]`` (fewer if the episode is shorter)."""
    return np.unique(np.floor(np.linspace(0, max(n_steps - 1, 0), k) + 0.5).astype(int))


def frame_indices(n_steps: int, max_frames: int = 150) -> np.ndarray:
    """Which steps become GIF frames: all when ``n_steps <= max_frames``, else ``max_frames`` evenly
    spaced ones including the first and the last (strictly increasing)."""
    if n_steps <= max_frames:
        return np.arange(n_steps)
    return np.floor(np.linspace(0, n_steps - 1, max_frames) + 0.5).astype(int)


def _norm_limits(maps: Sequence[np.ndarray | None]) -> tuple[float, float]:
    vals = np.concatenate([np.ravel(m) for m in maps if m is not None] or [np.zeros(1)])
    vals = vals[np.isfinite(vals)]
    hi = float(np.percentile(vals, 99)) if vals.size else 1.0
    return 0.0, hi if hi > 0 else 1.0


# --- Fig. 6 -------------------------------------------------------------------------------------
def fig6_uncertainty_timeline(scene, poses: np.ndarray, i_u: Sequence[np.ndarray | None], goal_xy,
                              success_radius: float, steps: Sequence[int] | None = None, floor: int = 0,
                              colour: str = "tab:blue"):
    """Top-down map with the trajectory and five moments t1..t5 marked; beneath, I_u at each moment.

    ``poses``: (T, 3) (x, y, yaw) or (T, 2); ``i_u``: T maps (h, w) (None where the memory gave
    none); ``goal_xy``: (2,); ``steps``: the moments (default: 5 evenly spaced over the steps that
    have a map, :func:`pick_moments`).
    The I_u panels share one colour scale (0 to the 99th percentile of the five maps). The map
    axes is ``fig.axes[0]``; the trajectory line has gid ``trajectory``, the markers ``moment``.
    """
    poses = np.asarray(poses, dtype=np.float64)
    if steps is None:  # five moments among the steps that have a map
        have = np.array([t for t, m in enumerate(i_u) if m is not None] or list(range(len(i_u))))
        steps = have[pick_moments(len(have))]
    steps = np.asarray(steps, dtype=int)
    k = len(steps)
    fig = plt.figure(figsize=(2.4 * max(k, 3), 2.4 * max(k, 3) * 0.62 + 2.2))
    gs = fig.add_gridspec(2, k, height_ratios=[3.2, 1.0])
    ax = fig.add_subplot(gs[0, :])
    draw_map(ax, scene, floor)
    n0 = len(ax.lines)
    draw_trajectory(ax, poses, goal_xy, success_radius, colour=colour)
    ax.lines[n0].set_gid("trajectory")
    for j, t in enumerate(steps):
        c = MOMENT_COLOURS[j % len(MOMENT_COLOURS)]
        (m,) = ax.plot(poses[t, 0], poses[t, 1], "o", ms=9, color=c, mec="k", zorder=5)
        m.set_gid("moment")
        ax.annotate(f"$t_{j + 1}$", (poses[t, 0], poses[t, 1]), xytext=(6, 6), textcoords="offset points",
                    fontsize=11, color=c, fontweight="bold")
    ax.set_title(f"{getattr(scene, 'name', '')}: trajectory and uncertainty over time")
    lo, hi = _norm_limits([i_u[t] for t in steps])
    for j, t in enumerate(steps):
        a = fig.add_subplot(gs[1, j])
        if i_u[t] is not None:
            im = a.imshow(i_u[t], cmap="inferno", vmin=lo, vmax=hi, interpolation="nearest")
        else:
            a.text(0.5, 0.5, "no map", ha="center", va="center", transform=a.transAxes)
        a.set_title(f"$t_{j + 1}$ = step {int(t)}", fontsize=10, color=MOMENT_COLOURS[j % len(MOMENT_COLOURS)])
        a.set_xticks([])
        a.set_yticks([])
    if any(i_u[t] is not None for t in steps):
        fig.colorbar(im, ax=fig.axes[1:], fraction=0.02, pad=0.01, label="$I_u$")
    return fig


# --- Fig. 7 -------------------------------------------------------------------------------------
def fig7_goal_direction(poses: np.ndarray, pred_angle: np.ndarray, true_angle: np.ndarray, every: int = 5,
                        scene=None, goal_xy=None, success_radius: float | None = None, floor: int = 0,
                        arrow_length: float = 0.45, ax=None):
    """Predicted vs true goal direction along a trajectory, every ``every``-th pose.

    ``poses``: (T, 3) (x, y, yaw); ``pred_angle``, ``true_angle``: (T,) radians from the heading,
    positive = left (NaN = no prediction). At pose i the true arrow points along
    ``yaw_i + true_angle_i`` (filled, gid ``true``) and the predicted one along
    ``yaw_i + pred_angle_i`` (hollow, gid ``predicted``); colour runs yellow -> red with progress
    ``i / (T - 1)``. With ``scene`` the map is drawn beneath. Draws into ``ax`` if given.
    """
    poses = np.asarray(poses, dtype=np.float64)
    pred, true = np.asarray(pred_angle, dtype=np.float64), np.asarray(true_angle, dtype=np.float64)
    fig = ax.figure if ax is not None else plt.figure(figsize=(6.5, 6.5))
    ax = ax if ax is not None else fig.add_subplot(1, 1, 1)
    if scene is not None:
        draw_map(ax, scene, floor)
    else:
        ax.set_aspect("equal")
    ax.plot(poses[:, 0], poses[:, 1], "-", color="0.45", lw=1.0, zorder=2)
    if goal_xy is not None:
        if success_radius:
            ax.add_patch(plt.Circle(goal_xy, success_radius, color="tab:red", alpha=0.12))
        ax.plot(goal_xy[0], goal_xy[1], "*", color="tab:red", ms=15, mec="k", zorder=6)
    idx = np.arange(0, len(poses), max(1, int(every)))
    colours = PROGRESS_CMAP(idx / max(len(poses) - 1, 1))
    x, y, yaw = poses[idx, 0], poses[idx, 1], poses[idx, 2]
    kw = dict(angles="xy", scale_units="xy", scale=1.0, width=0.006, zorder=4)
    qt = ax.quiver(x, y, arrow_length * np.cos(yaw + true[idx]), arrow_length * np.sin(yaw + true[idx]),
                   color=colours, edgecolor="k", linewidth=0.4, **kw)
    qt.set_gid("true")
    ok = np.isfinite(pred[idx])
    qp = ax.quiver(x[ok], y[ok], arrow_length * np.cos(yaw[ok] + pred[idx][ok]),
                   arrow_length * np.sin(yaw[ok] + pred[idx][ok]), facecolor="none", edgecolor=colours[ok],
                   linewidth=1.2, **kw)
    qp.set_gid("predicted")
    ax.legend(handles=[Patch(facecolor="#ff8c00", edgecolor="k", label="true goal direction"),
                       Patch(facecolor="none", edgecolor="#ff8c00", label="predicted (auxiliary task)")],
              loc="best", fontsize=8)
    ax.set_title("goal direction: predicted vs true (yellow -> red = progress)", fontsize=10)
    return fig


# --- Fig. 8 -------------------------------------------------------------------------------------
def gradcam_uncertainty(model, policy_input, action: int | None = None, layer=None) -> np.ndarray:
    """Grad-CAM of the uncertainty branch f_u for one input, upsampled to the map size: ``(h, w)`` >= 0.

    ``model``: a :class:`nue.policy.nue_model.NUEPolicy` with f_u; ``policy_input``: a
    :class:`nue.policy.inputs.PolicyInput` (row 0 is used) with ``i_u`` (B, 1, h, w); ``action``:
    the target logit (default: the argmax). Uses ``captum.attr.LayerGradCam`` on ``layer``
    (default: the last residual block ``model.f_u.encoder[-1]``): ReLU(sum_k mean_ij(dy/dA_k) A_k),
    upsampled bilinearly with ``LayerAttribution.interpolate``. Runs the model in eval mode.
    """
    if getattr(model, "f_u", None) is None:
        raise ValueError("the model has no uncertainty branch f_u (an ablation without it?)")
    inp = policy_input.index(slice(0, 1))
    if inp.i_u is None:
        raise ValueError("policy_input.i_u is None")
    layer = layer if layer is not None else model.f_u.encoder[-1]

    def forward(i_u, rgbd, goal, i_cog):
        return model(PolicyInput(rgbd=rgbd, goal=goal, i_u=i_u, i_cog=i_cog)).logits

    was_training = model.training
    model.eval()
    try:
        if action is None:
            with torch.no_grad():
                action = int(forward(inp.i_u, inp.rgbd, inp.goal, inp.i_cog).argmax(dim=1)[0])
        cam = LayerGradCam(forward, layer).attribute(
            inp.i_u.detach().clone(), target=int(action), additional_forward_args=(inp.rgbd, inp.goal, inp.i_cog),
            relu_attributions=True)
        up = LayerAttribution.interpolate(cam, tuple(inp.i_u.shape[-2:]), interpolate_mode="bilinear")
    finally:
        model.train(was_training)
    return up[0, 0].detach().cpu().numpy().clip(min=0.0)


def fig8_gradcam(i_u: Sequence[np.ndarray], cams: Sequence[np.ndarray], titles: Sequence[str] | None = None,
                 alpha: float = 0.55):
    """Pairs of (I_u, Grad-CAM): I_u on top, the Grad-CAM heatmap (blue -> red, over a grey I_u) beneath.

    ``i_u``, ``cams``: N maps (h, w) each (a cam from :func:`gradcam_uncertainty`). Each cam is
    scaled to [0, 1] by its own maximum.
    """
    n = len(i_u)
    fig, axes = plt.subplots(2, n, figsize=(2.8 * n, 4.4), squeeze=False)
    for j, (u, c) in enumerate(zip(i_u, cams)):
        lo, hi = _norm_limits([u])
        axes[0, j].imshow(u, cmap="inferno", vmin=lo, vmax=hi, interpolation="nearest")
        axes[0, j].set_title(titles[j] if titles else f"$I_u$ #{j + 1}", fontsize=9)
        axes[1, j].imshow(u, cmap="gray", vmin=lo, vmax=hi, interpolation="nearest")
        cmax = float(np.max(c)) if np.max(c) > 0 else 1.0
        axes[1, j].imshow(np.asarray(c) / cmax, cmap="jet", vmin=0, vmax=1, alpha=alpha, interpolation="bilinear")
    axes[0, 0].set_ylabel("uncertainty $I_u$", fontsize=9)
    axes[1, 0].set_ylabel("Grad-CAM of $f_u$", fontsize=9)
    for a in axes.ravel():
        a.set_xticks([])
        a.set_yticks([])
    fig.tight_layout()
    return fig


# --- GIF ----------------------------------------------------------------------------------------
def episode_frames(trace: EpisodeTrace, scene=None, floor: int = 0, max_frames: int = 150, dpi: int = 60):
    """Yield GIF frames ``(H_f, W_f, 3)`` uint8 of an episode: live RGB | I_u | I_cog | top-down map so far.

    One frame per step of :func:`frame_indices` (at most ``max_frames``). I_u and I_cog use one
    colour scale for the whole episode; the frame size is ``(3.0 * dpi, 12.0 * dpi)`` pixels.
    """
    poses = trace.pose_array()
    fig, axes = plt.subplots(1, 4, figsize=(12.0, 3.0), dpi=dpi)
    lo, hi = _norm_limits(trace.i_u)
    cogs = [c for c in trace.i_cog if c is not None]
    c_lo = np.percentile(np.stack(cogs), 1, axis=(0, 2, 3)) if cogs else None
    c_hi = np.percentile(np.stack(cogs), 99, axis=(0, 2, 3)) if cogs else None
    first_u = next((u for u in trace.i_u if u is not None), np.zeros((2, 2)))
    blank = np.zeros_like(first_u)
    first_c = cogs[0].shape[1:] if cogs else blank.shape
    ims = [axes[0].imshow(trace.rgb[0]),
           axes[1].imshow(blank, cmap="inferno", vmin=lo, vmax=hi),
           axes[2].imshow(np.zeros((*first_c, 3)))]
    for a, t in zip(axes[:3], ("live RGB", "uncertainty $I_u$", "features $I_{cog}$ (3 comp.)")):
        a.set_title(t, fontsize=9)
        a.set_xticks([])
        a.set_yticks([])
    if scene is not None:
        draw_map(axes[3], scene, floor)
    else:
        pad = 1.0
        axes[3].set_xlim(poses[:, 0].min() - pad, poses[:, 0].max() + pad)
        axes[3].set_ylim(poses[:, 1].min() - pad, poses[:, 1].max() + pad)
        axes[3].set_aspect("equal")
    axes[3].set_xlabel("")
    axes[3].set_ylabel("")
    if trace.goal_xy is not None:
        axes[3].plot(*trace.goal_xy, "*", color="tab:red", ms=12, mec="k")
    (line,) = axes[3].plot([], [], "-", color="tab:blue", lw=1.5)
    (robot,) = axes[3].plot([], [], "o", color="tab:blue", ms=6, mec="k")
    title = axes[3].set_title("", fontsize=9)
    axes[3].tick_params(labelsize=6)
    fig.subplots_adjust(left=0.02, right=0.99, bottom=0.08, top=0.88, wspace=0.15)
    moving = [*ims, line, robot, title]
    for art in moving:
        art.set_animated(True)
    try:
        # Static parts (map, axes, labels) are drawn once; each frame restores them and draws the moving artists.
        fig.canvas.draw()
        background = fig.canvas.copy_from_bbox(fig.bbox)
        for t in frame_indices(len(trace), max_frames):
            ims[0].set_data(trace.rgb[t])
            u = trace.i_u[t]
            u = blank if u is None else u
            ims[1].set_data(u)
            ims[1].set_extent((-0.5, u.shape[1] - 0.5, u.shape[0] - 0.5, -0.5))
            c = trace.i_cog[t]
            rgb = np.zeros((*first_c, 3)) if c is None else cog_to_rgb(c, c_lo, c_hi)
            ims[2].set_data(rgb)
            ims[2].set_extent((-0.5, rgb.shape[1] - 0.5, rgb.shape[0] - 0.5, -0.5))
            line.set_data(poses[: t + 1, 0], poses[: t + 1, 1])
            robot.set_data([poses[t, 0]], [poses[t, 1]])
            title.set_text(f"step {int(t)} / {len(trace) - 1}")
            fig.canvas.restore_region(background)
            for art in moving:
                art.axes.draw_artist(art)
            yield np.asarray(fig.canvas.buffer_rgba())[..., :3].copy()
    finally:
        plt.close(fig)


def save_episode_gif(path, trace: EpisodeTrace, scene=None, floor: int = 0, max_frames: int = 150, fps: float = 8.0,
                     dpi: int = 60) -> Path:
    """Write the frames of :func:`episode_frames` as a looping GIF (imageio) at ``fps`` frames per second.

    Frames are first reduced to 256 colours with Pillow's fast octree quantiser: the GIF writer's
    default median cut costs ~100 ms per frame on one core, the octree ~3 ms.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    frames = np.stack([np.asarray(Image.fromarray(f).quantize(256, method=Image.Quantize.FASTOCTREE).convert("RGB"))
                       for f in episode_frames(trace, scene, floor, max_frames, dpi)])
    iio.imwrite(path, frames, extension=".gif", duration=1000.0 / fps, loop=0)
    return path
