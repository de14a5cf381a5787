"""OnlineNeRF: the per-episode memory — a replay of RGB-D frames, a NeRF trained on it online, and
the maps (I_u, I_cog) it renders for the current pose.

Use in the agent loop (maps for step t are rendered *before* any update that uses frame t)::

    nerf = OnlineNeRF(get_memory("fast"), task.camera)       # or init_state=checkpoint["memory_init"]
    nerf.reset(seed)
    for each step:
        maps = nerf.render_maps(pose, depth)                  # MemoryMaps on nerf.device
        ...act...
        nerf.step(rgb, depth, pose)                           # observe + update per the schedule

Inputs: ``rgb (H, W, 3)`` uint8 (or float in [0, 1]), ``depth (H, W)`` z-depth metres (0, NaN or inf =
no valid depth: such pixels are never trained on and are rendered with samples over
``[near, no_depth_range]``), ``pose (x, y, yaw)`` (NaN raises :class:`MemoryInputError`), all at the
camera's full resolution. Everything is synchronous and deterministic: the same initial weights,
seed and frames give the same maps.
"""

from __future__ import annotations

import collections
from dataclasses import dataclass

import numpy as np
import torch

from nue.errors import CheckpointError
from nue.nerf.config import MemoryConfig, get_memory
from nue.nerf.field import FieldOutputs, NeRFField
from nue.nerf.grid_field import GridField
from nue.nerf.loss import memory_loss
from nue.nerf.rays import (
    EpisodeFrame,
    MemoryInputError,
    PixelRays,
    RayBundle,
    RaySamples,
    check_pose,
    depth_guided_samples,
    map_pixels,
)
from nue.nerf.rendering import compositing_weights, render_depth, render_features, render_rgb, render_uncertainty
from nue.sim.task import CameraConfig


def rgb_pixels(rgb, camera, device) -> torch.Tensor:
    """An (H, W, 3) frame (uint8, or float in [0, 1]) of ``camera``'s size as (H * W, 3) uint8 on ``device``;
    :class:`MemoryInputError` for another shape."""
    x = rgb if isinstance(rgb, torch.Tensor) else torch.as_tensor(np.asarray(rgb))
    if tuple(x.shape) != (camera.height, camera.width, 3):
        raise MemoryInputError("rgb", f"expected ({camera.height}, {camera.width}, 3), got {tuple(x.shape)}")
    if x.dtype != torch.uint8:
        x = (x.float().clamp(0, 1) * 255.0).round().to(torch.uint8)
    return x.to(device).reshape(-1, 3)


@dataclass
class MemoryMaps:
    """What the memory shows the policy for one pose; torch tensors on the memory's device."""

    i_u: torch.Tensor
    """(1, h, w) uncertainty ``sum w^2 beta^2`` (+ ``T_{N+1} beta_max^2`` if the preset enables it)."""
    i_cog: torch.Tensor
    """(64, h, w) cognition features ``sum w f_c``."""
    rgb: torch.Tensor
    """(3, h, w) rendered colour in [0, 1] (for figures and PSNR)."""
    depth: torch.Tensor
    """(1, h, w) rendered z-depth, metres (for figures)."""
    transmittance: torch.Tensor
    """(1, h, w) transmittance left after the last sample, T_{N+1} (1 = the field saw nothing there)."""
    panorama: torch.Tensor | None = None
    """(K, hp, wp) I_u of K views at the robot's position, heading ``yaw + 2 pi k / K`` (k = 0: the robot's own),
    if the preset renders a panorama (``panorama_headings``); else None."""


@dataclass
class UpdateStats:
    """Mean loss terms over the iterations of one update (floats)."""

    loss: float
    nll: float
    density: float
    iters: int


class OnlineNeRF:
    """Per-episode online NeRF memory (see the module docstring for the loop)."""

    def __init__(
        self,
        config: MemoryConfig | str = "fast",
        camera: CameraConfig | None = None,
        init_state: dict[str, torch.Tensor] | None = None,
        device: str | torch.device | None = None,
    ):
        self.config = get_memory(config)
        self.camera = camera if camera is not None else CameraConfig()
        self.device = torch.device(device if device is not None else self.config.device)
        self.pixel_rays = PixelRays(self.camera, self.device)
        self.field = self._make_field().to(self.device)
        self._zero_keys = set(getattr(self.field, "zero_init_keys", ()))
        if init_state is None:
            with torch.random.fork_rng(devices=[]):
                torch.manual_seed(self.config.init_seed)
                init_state = self._make_field().state_dict()
        self._init_state = {k: v.detach().clone().cpu() for k, v in init_state.items() if k not in self._zero_keys}
        self._load_initial_weights()
        rows, cols = map_pixels(self.camera, self.config.map_height, self.config.map_width)
        self._map_pixels = self._flat_pixels(rows, cols)
        self._map_dirs = self.pixel_rays.dirs[self._map_pixels]
        self._map_range_per_z = self.pixel_rays.range_per_z[self._map_pixels]
        self._pano_pixels: torch.Tensor | None = None
        self.reset(0)

    def _load_initial_weights(self) -> None:
        try:
            missing, unexpected = self.field.load_state_dict(self._init_state, strict=False)
        except RuntimeError as e:
            raise CheckpointError("memory init", f"stored NeRF initialisation does not fit the field config: {e}") from None
        if unexpected or set(missing) - self._zero_keys:
            raise CheckpointError(
                "memory init",
                f"stored NeRF initialisation does not fit the field config (missing {sorted(set(missing) - self._zero_keys)}, "
                f"unexpected {sorted(unexpected)})",
            )
        with torch.no_grad():
            for key in self._zero_keys:  # parameters that start at zero by definition
                getattr(self.field, key).zero_()

    def _make_field(self) -> torch.nn.Module:
        if self.config.field_type == "grid":
            return GridField(self.config.grid, self.config.radius)
        return NeRFField(self.config.field)

    # ----------------------------------------------------------------- episode state
    def initial_state(self) -> dict[str, torch.Tensor]:
        """The fixed initial weights every ``reset`` restores (CPU copies; store them with the policy).
        Parameters that start at zero by definition (the voxel grid's table) are left out."""
        return {k: v.clone() for k, v in self._init_state.items()}

    def state_dict(self) -> dict[str, torch.Tensor]:
        """The field's current weights."""
        return self.field.state_dict()

    def reset(self, seed: int = 0, start_pose=None, floor_z: float = 0.0) -> None:
        """Start an episode: the initial weights, a fresh optimiser, an empty replay; ``seed`` drives ray
        sampling only. The episode frame is fixed at ``start_pose`` or else at the first pose seen."""
        self._load_initial_weights()
        self.optimizers = self.field.optimizers(self.config.lr, self.config.grid_lr)
        self.generator = torch.Generator(device="cpu")
        self.generator.manual_seed(int(seed))
        self.frame: EpisodeFrame | None = None
        self.steps = 0
        self._pending: collections.deque = collections.deque()  # frames waiting out the memory lag
        self._n = 0  # frames in the replay
        self._next = 0  # ring-buffer slot of the next frame
        self._newest = -1
        self._rgb = self._ranges = self._valid = self._n_valid = self._poses = None
        if start_pose is not None:
            self._ensure_frame(start_pose, floor_z)

    @property
    def replay_len(self) -> int:
        """Frames currently in the replay."""
        return self._n

    def _ensure_frame(self, pose, floor_z: float) -> None:
        if self.frame is None:
            self.frame = EpisodeFrame.from_pose(pose, self.camera, floor_z, self.config.radius)

    def _flat_pixels(self, rows: np.ndarray, cols: np.ndarray) -> torch.Tensor:
        flat = (rows[:, None] * self.camera.width + cols[None, :]).reshape(-1)
        return torch.as_tensor(flat, dtype=torch.long, device=self.device)

    # ----------------------------------------------------------------- replay
    def _check_rgb(self, rgb) -> torch.Tensor:
        return rgb_pixels(rgb, self.camera, self.device)

    def observe(self, rgb, depth, pose, floor_z: float = 0.0) -> None:
        """Add a frame to the replay (the oldest is dropped beyond ``replay_size``). Pixels with invalid
        depth are masked; a frame without any valid depth pixel raises :class:`MemoryInputError`."""
        pose = check_pose(pose)
        rgb_t = self._check_rgb(rgb)
        ranges = self.pixel_rays.ranges_from_depth(depth)
        valid = torch.nonzero(torch.isfinite(ranges)).squeeze(1)
        if valid.numel() == 0:
            raise MemoryInputError("depth", "frame has no valid depth pixel (all 0, NaN or inf)")
        self._ensure_frame(pose, floor_z)
        cap, hw = self.config.replay_size, ranges.numel()
        if self._rgb is None:
            dev = self.device
            self._rgb = torch.zeros(cap, hw, 3, dtype=torch.uint8, device=dev)
            self._ranges = torch.zeros(cap, hw, dtype=torch.float32, device=dev)
            self._valid = torch.zeros(cap, hw, dtype=torch.long, device=dev)
            self._n_valid = torch.zeros(cap, dtype=torch.long, device=dev)
            self._poses = torch.zeros(cap, 4, 4, dtype=torch.float32, device=dev)
        i = self._next
        self._rgb[i] = rgb_t
        self._ranges[i] = ranges
        self._valid[i, : valid.numel()] = valid
        self._n_valid[i] = valid.numel()
        self._poses[i] = self.pixel_rays.episode_from_camera(pose, self.frame, floor_z)
        self._newest = i
        self._next = (i + 1) % cap
        self._n = min(self._n + 1, cap)

    def _draw_rays(self, n_rays: int) -> tuple[torch.Tensor, torch.Tensor]:
        """The generator's draws of one iteration's rays: replay slots ``frames (R,)`` and flat pixels ``(R,)``
        (a ``newest_fraction`` of them from the newest frame, the rest uniform over the replay)."""
        g = self.generator
        n_new = int(round(self.config.newest_fraction * n_rays)) if self._n > 1 else 0
        frames = torch.randint(0, self._n, (n_rays - n_new,), generator=g)
        frames = torch.cat([torch.full((n_new,), self._newest, dtype=torch.long), frames]).to(self.device)
        u = torch.rand(n_rays, generator=g).to(self.device)
        slot = (u * self._n_valid[frames]).long()
        return frames, self._valid[frames, slot]

    def _rays(self, frames: torch.Tensor, pix: torch.Tensor) -> tuple[RayBundle, torch.Tensor]:
        """Rays through replay pixels, each with its own frame's colour: (bundle, rgb (R, 3) in [0, 1])."""
        bundle = self.pixel_rays.bundle(self._poses[frames], pix, self._ranges[frames, pix])
        return bundle, self._rgb[frames, pix].float() / 255.0

    # ----------------------------------------------------------------- field evaluation
    def _query(self, bundle: RayBundle, n_samples: int, generator: torch.Generator | None):
        samples = depth_guided_samples(bundle.ranges, n_samples, self.config.sampler, generator)
        pts = bundle.origins[:, None, :] + samples.t[..., None] * bundle.directions[:, None, :]
        out: FieldOutputs = self.field(pts * (1.0 / self.config.radius), bundle.directions)
        weights, transmittance = compositing_weights(out.density, samples.deltas)
        return samples, out, weights, transmittance

    def _training_batches(self, n_iters: int):
        """The rays, samples and (grid field) voxel corners of ``n_iters`` iterations, drawn in the order one
        iteration after the other would draw them (rays, then their jitter) and computed for all at once: none
        of it depends on the field. Yields per iteration ``(bundle, target, samples, x, corners | None)``."""
        cfg = self.config
        n_rays, n_bins = cfg.train_rays, cfg.train_samples + cfg.sampler.free_samples
        draws = []
        for _ in range(n_iters):
            frames, pix = self._draw_rays(n_rays)
            draws.append((frames, pix, torch.rand((n_rays, n_bins), generator=self.generator).to(self.device)))
        frames, pix, jitter = (torch.cat(v) for v in zip(*draws))
        bundle, target = self._rays(frames, pix)
        samples = depth_guided_samples(bundle.ranges, cfg.train_samples, cfg.sampler, jitter=jitter)
        pts = bundle.origins[:, None, :] + samples.t[..., None] * bundle.directions[:, None, :]
        x = pts * (1.0 / cfg.radius)
        corners = self.field.corners(x.reshape(-1, 3)) if isinstance(self.field, GridField) else None
        for i in range(n_iters):
            r = slice(i * n_rays, (i + 1) * n_rays)
            p = slice(i * n_rays * n_bins, (i + 1) * n_rays * n_bins)
            yield (RayBundle(bundle.origins[r], bundle.directions[r], bundle.ranges[r]), target[r],
                   RaySamples(samples.t[r], samples.deltas[r]), x[r],
                   None if corners is None else (corners[0][p], corners[1][p]))

    def update(self, n_iters: int | None = None) -> UpdateStats:
        """Run ``n_iters`` (default: the preset's K) training iterations on rays drawn from the replay."""
        if self._n == 0:
            raise MemoryInputError("replay", "update() needs at least one observed frame; call observe() first")
        n_iters = self.config.iters_per_update if n_iters is None else int(n_iters)
        cfg = self.config
        beta_min = self.field.config.beta_min
        tot = nll = dens = 0.0
        self.field.train()
        for bundle, target, samples, x, corners in self._training_batches(n_iters):
            if corners is None:
                out: FieldOutputs = self.field(x, bundle.directions)
            else:
                out = self.field.from_corners(*corners, x, bundle.directions)
            weights, transmittance = compositing_weights(out.density, samples.deltas)
            ray_var = render_uncertainty(weights, out.variance) + beta_min
            depth_pred = None
            if cfg.depth_weight > 0:  # expected termination, leftover transmittance ending at the band's far end
                t_far = samples.t[:, -1] + 0.5 * samples.deltas[:, -1]
                depth_pred = (weights * samples.t).sum(dim=-1) + transmittance * t_far
            terms = memory_loss(
                render_rgb(weights, out.rgb), target, ray_var, out.density, cfg.density_weight,
                depth_pred, bundle.ranges, cfg.depth_weight,
            )
            for opt in self.optimizers:
                opt.zero_grad(set_to_none=True)
            terms.total.backward()
            for opt in self.optimizers:
                opt.step()
            tot += float(terms.total.detach())
            nll += float(terms.nll.detach())
            dens += float(terms.density.detach())
        k = max(n_iters, 1)
        return UpdateStats(loss=tot / k, nll=nll / k, density=dens / k, iters=n_iters)

    def step(self, rgb, depth, pose, floor_z: float = 0.0) -> UpdateStats | None:
        """One environment step of the schedule: observe every ``observe_every``-th frame, update every
        ``update_every``-th step. Call after ``render_maps`` for the same step. Returns the update's stats.
        With ``lag`` = k the frame handled is the one of k steps ago (nothing for the first k steps)."""
        if self.config.lag:
            self._pending.append((np.array(rgb, copy=True), np.array(depth, copy=True), np.array(pose, copy=True), floor_z))
            if len(self._pending) <= self.config.lag:
                return None
            rgb, depth, pose, floor_z = self._pending.popleft()
        t = self.steps
        self.steps += 1
        if t % self.config.observe_every == 0:
            self.observe(rgb, depth, pose, floor_z)
        if t % self.config.update_every == 0 and self._n > 0:
            return self.update()
        return None

    # ----------------------------------------------------------------- rendering
    @torch.no_grad()
    def render_maps(self, pose, depth, floor_z: float = 0.0) -> MemoryMaps:
        """Maps for the current pose at the preset's (map_height, map_width), depth-guided by the
        current full-resolution depth frame (and the panorama if the preset has one). Does not change the memory."""
        maps = self.render_view(pose, depth, self.config.map_height, self.config.map_width, floor_z)
        if self.config.panorama_headings:
            maps.panorama = self.render_panorama(pose, floor_z)
        return maps

    @torch.no_grad()
    def render_panorama(self, pose, floor_z: float = 0.0, headings: int | None = None) -> torch.Tensor:
        """I_u ``(K, hp, wp)`` of ``K`` (default ``panorama_headings``) views at the robot's position, view k heading
        ``yaw + 2 pi k / K``, at the preset's panorama size; no depth guides them: ``panorama_samples`` samples per
        ray spread over ``[near, no_depth_range]``. Does not change the memory."""
        cfg = self.config
        k = int(headings if headings is not None else cfg.panorama_headings)
        if k < 1:
            raise ValueError("render_panorama: needs at least one heading")
        pose = check_pose(pose)
        self._ensure_frame(pose, floor_z)
        if self._pano_pixels is None:  # the panorama's pixels, once
            self._pano_pixels = self._flat_pixels(*map_pixels(self.camera, cfg.panorama_height, cfg.panorama_width))
        pix = self._pano_pixels
        transforms = torch.stack([self.pixel_rays.episode_from_camera(
            (pose[0], pose[1], pose[2] + 2.0 * np.pi * i / k), self.frame, floor_z) for i in range(k)])
        per_ray = transforms.repeat_interleave(pix.numel(), dim=0)  # (K * P, 4, 4): view by view
        bundle = self.pixel_rays.bundle(per_ray, pix.repeat(k), torch.full((k * pix.numel(),), float("nan"),
                                                                           device=self.device))
        self.field.eval()
        chunk = max(1, cfg.render_chunk // cfg.panorama_samples)
        parts = []
        with torch.inference_mode():
            for s in range(0, k * pix.numel(), chunk):
                sub = RayBundle(bundle.origins[s : s + chunk], bundle.directions[s : s + chunk], bundle.ranges[s : s + chunk])
                _, out, w, transmittance = self._query(sub, cfg.panorama_samples, None)
                parts.append(render_uncertainty(w, out.variance, transmittance, cfg.unseen_variance))
        return torch.cat(parts).reshape(k, cfg.panorama_height, cfg.panorama_width).clone()

    @torch.no_grad()
    def render_view(self, pose, depth, height: int, width: int, floor_z: float = 0.0) -> MemoryMaps:
        """Like :meth:`render_maps` at any (height, width) within the camera's resolution."""
        pose = check_pose(pose)
        self._ensure_frame(pose, floor_z)
        if (height, width) == (self.config.map_height, self.config.map_width):
            pix, dirs, range_per_z = self._map_pixels, self._map_dirs, self._map_range_per_z
        else:
            pix = self._flat_pixels(*map_pixels(self.camera, height, width))
            dirs, range_per_z = self.pixel_rays.dirs[pix], self.pixel_rays.range_per_z[pix]
        cfg = self.config
        self.field.eval()
        chunk = max(1, cfg.render_chunk // max(cfg.render_samples, 1))
        parts: dict[str, list[torch.Tensor]] = {"i_u": [], "rgb": [], "depth": [], "transmittance": [], "i_cog": []}
        with torch.inference_mode():
            ranges = self.pixel_rays.ranges_from_depth(depth, pix)
            bundle = self.pixel_rays.bundle(self.pixel_rays.episode_from_camera(pose, self.frame, floor_z), pix, ranges, dirs)
            for s in range(0, pix.numel(), chunk):
                sub = RayBundle(bundle.origins[s : s + chunk], bundle.directions[s : s + chunk], bundle.ranges[s : s + chunk])
                samples, out, w, transmittance = self._query(sub, cfg.render_samples, None)
                parts["i_u"].append(render_uncertainty(w, out.variance, transmittance, cfg.unseen_variance)[:, None])
                parts["rgb"].append(render_rgb(w, out.rgb))
                parts["depth"].append(render_depth(w, samples.t)[:, None])
                parts["transmittance"].append(transmittance[:, None])
                parts["i_cog"].append(render_features(w, out.feature))
        # (P, C) chunks -> (C, h, w); built outside inference mode, so the maps are ordinary tensors
        maps = {k: torch.cat(v).T.reshape(-1, height, width) for k, v in parts.items()}
        maps["depth"] = maps["depth"] / range_per_z.reshape(1, height, width)  # range -> z-depth
        return MemoryMaps(**maps)

    def flops_per_step(self) -> dict[str, float]:
        """Analytic GEMM FLOPs per environment step of this preset: training (forward + backward = 3x
        forward) and map rendering, averaged over the update / observe schedule."""
        cfg = self.config
        n_train = cfg.train_samples + cfg.sampler.free_samples
        n_render = cfg.render_samples + cfg.sampler.free_samples
        f_train, f_render = self.field.flops_per_point(n_train), self.field.flops_per_point(n_render)
        train = 3.0 * f_train * cfg.train_rays * n_train * cfg.iters_per_update / cfg.update_every
        render = f_render * cfg.map_height * cfg.map_width * n_render
        return {"train": train, "render": render, "total": train + render}
