"""Top-down figures: the traversability map with trajectories, and strips of first-person frames."""

from __future__ import annotations

from pathlib import Path
from typing import Sequence

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from nue.scene.scene import Scene  # noqa: E402
from nue.viz.plot import save_figure  # noqa: E402


def map_extent(scene: Scene, floor: int = 0, margin: float = 0.5) -> tuple[float, float, float, float]:
    """World (xmin, xmax, ymin, ymax) of the free space of a floor plus a margin, metres."""
    free = scene.trav_maps[floor]
    rows, cols = np.nonzero(free)
    n, res = free.shape[0], scene.resolution
    xmin, xmax = (cols.min() - n / 2) * res - margin, (cols.max() + 1 - n / 2) * res + margin
    ymin, ymax = (rows.min() - n / 2) * res - margin, (rows.max() + 1 - n / 2) * res + margin
    return float(xmin), float(xmax), float(ymin), float(ymax)


def draw_map(ax, scene: Scene, floor: int = 0, extent=None) -> tuple[float, float, float, float]:
    """Draw the traversability map in world coordinates (x right, y up); returns the extent drawn."""
    free = scene.trav_maps[floor]
    n, res = free.shape[0], scene.resolution
    extent = extent or map_extent(scene, floor)
    c0, c1 = (int(np.floor(v / res + n / 2)) for v in extent[:2])
    r0, r1 = (int(np.floor(v / res + n / 2)) for v in extent[2:])
    c0, r0 = max(c0, 0), max(r0, 0)
    crop = free[r0:r1, c0:c1]
    shown = (c0 - n / 2) * res, (c0 + crop.shape[1] - n / 2) * res, (r0 - n / 2) * res, (r0 + crop.shape[0] - n / 2) * res
    ax.imshow(np.where(crop, 0.95, 0.35), cmap="gray", vmin=0, vmax=1, origin="lower", extent=shown, interpolation="nearest")
    ax.set_xlim(extent[0], extent[1])
    ax.set_ylim(extent[2], extent[3])
    ax.set_aspect("equal")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    return extent


def draw_trajectory(ax, trajectory: np.ndarray, goal_xy, success_radius: float, colour="tab:blue", label=None) -> None:
    """Trajectory (T, 2 or 3) as a line, its start (circle with heading), the goal (star) and success disc."""
    traj = np.asarray(trajectory)
    ax.plot(traj[:, 0], traj[:, 1], "-", color=colour, lw=1.8, label=label)
    ax.plot(traj[0, 0], traj[0, 1], "o", color=colour, ms=7, mec="k")
    if traj.shape[1] >= 3:
        ax.arrow(traj[0, 0], traj[0, 1], 0.4 * np.cos(traj[0, 2]), 0.4 * np.sin(traj[0, 2]), color=colour, width=0.03)
    ax.add_patch(plt.Circle(goal_xy, success_radius, color=colour, alpha=0.15))
    ax.plot(goal_xy[0], goal_xy[1], "*", color=colour, ms=14, mec="k")


def save_topdown(path, scene: Scene, runs: Sequence[dict], floor: int = 0, title: str | None = None) -> Path:
    """Save a top-down figure; each run is ``{trajectory, goal, radius, label}``."""
    fig, ax = plt.subplots(figsize=(7, 7))
    draw_map(ax, scene, floor)
    colours = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    for i, run in enumerate(runs):
        draw_trajectory(ax, run["trajectory"], run["goal"], run["radius"], colours[i % len(colours)], run.get("label"))
    if any(r.get("label") for r in runs):
        ax.legend(loc="best", fontsize=8)
    ax.set_title(title or scene.name)
    fig.tight_layout()
    return save_figure(fig, path, dpi=110)


def save_frames(path, frames: Sequence[dict], goal: np.ndarray, max_depth: float = 5.0) -> Path:
    """A grid of first-person frames: RGB on top, depth below, the goal photo in the first column.

    Each frame is ``{rgb (H, W, 3) uint8, depth (H, W[, 1]) metres, title}``.
    """
    n = len(frames) + 1
    fig, axes = plt.subplots(2, n, figsize=(2.6 * n, 4.2))
    axes[0, 0].imshow(goal)
    axes[0, 0].set_title("goal photo", fontsize=9)
    axes[1, 0].axis("off")
    for j, f in enumerate(frames, start=1):
        axes[0, j].imshow(f["rgb"])
        axes[0, j].set_title(f.get("title", ""), fontsize=9)
        axes[1, j].imshow(np.squeeze(f["depth"]), cmap="viridis", vmin=0, vmax=max_depth)
    for ax in axes.ravel():
        ax.set_xticks([])
        ax.set_yticks([])
    axes[1, 1].set_ylabel("depth (0-5 m)", fontsize=9)
    fig.tight_layout()
    return save_figure(fig, path, dpi=100)
