"""StackedMemory: the online NeRF memories of B episodes run side by side, one batched op per step (issue 38).

Slot i holds what one :class:`nue.nerf.online.OnlineNeRF` holds for one episode — a replay, a voxel-grid field and
its optimiser state, a ray generator, an episode frame — and behaves like it (``reset_slot`` / ``render_maps`` /
``step`` follow ``reset`` / ``render_maps`` / ``step``), but the listed slots of a call share field queries,
backward passes and optimiser steps (in groups of ``train_points`` / ``render_points`` sample points), so the
fixed cost of a call is paid once for several episodes. The per-ray work is not shared: on the CPU measured
(docs/history/benchmarks.md, "Stacked memory") B = 8 costs about what 8 OnlineNeRFs cost.

Stacking (``grid`` field only):
- the B voxel tables are one table of ``B * (V + 1)`` rows, slot i's at rows ``[i (V + 1), (i + 1) (V + 1))``,
  its last row standing for every point outside slot i's grid; one :class:`~nue.nerf.grid_field.RowAdam`-style
  optimiser updates the touched rows, each with its own slot's step count (:class:`~nue.nerf.slot_adam.SlotRowAdam`);
- the colour MLPs are weights with a leading slot axis ``(B, ...)`` applied by batched matmuls to each slot's
  points (the listed slots have equal ray counts, so the shapes stack), trained by Adam with per-slot step counts;
- each slot has its own ``torch.Generator`` seeded as ``OnlineNeRF.reset`` seeds it, drawn in the same order, so a
  slot's rays depend only on its own seed and frames.

A slot's maps equal an ``OnlineNeRF``'s with the same initial weights, seed and frames up to float rounding (the
batched matmuls and reductions round differently; tests/test_stacked_memory.py states the tolerance). Slots not
listed in a call are not read or written. An episode that ends frees its slot; ``reset_slot`` starts the next.
"""

from __future__ import annotations

import collections
from dataclasses import dataclass, field

import numpy as np
import torch
from torch import nn
from torch.nn import functional as F

from nue.errors import CheckpointError, ConfigError
from nue.nerf.config import MemoryConfig, get_memory
from nue.nerf.field import FieldOutputs
from nue.nerf.grid_field import GridField, _TrilinearRead
from nue.nerf.loss import uncertainty_nll
from nue.nerf.online import MemoryMaps, rgb_pixels
from nue.nerf.rays import (
    EpisodeFrame,
    MemoryInputError,
    PixelRays,
    RayBundle,
    check_pose,
    depth_guided_samples,
    map_pixels,
)
from nue.nerf.slot_adam import SlotRowAdam, slot_adam_step
from nue.nerf.rendering import compositing_weights, render_depth, render_features, render_rgb, render_uncertainty
from nue.sim.task import CameraConfig

TRAIN_POINTS = 8192
"""Default sample points per training query: two slots of the ``fast`` preset (512 rays x 8 samples). Measured on
this project's 2-core machine (benchmarks/stacked_memory.py, thread CPU time, B = 8): queries of 1, 2 and 8 slots
cost 14.6, 12.9 and 14.8 ms per episode-step, and rendering 8 slots' maps in one query cost more per point than one
query per slot (larger tensors fall out of the cache and past the allocator's mmap threshold)."""
DENSE_KEYS = ("colour_code.weight", "colour_code.bias", "colour_dir.weight", "colour_out.weight", "colour_out.bias")
"""The colour MLP's parameters, stacked along a leading slot axis."""


@dataclass
class _Slot:
    """Per-episode state of one slot besides its parameters (those live in the stacked tensors)."""

    generator: torch.Generator
    frame: EpisodeFrame | None = None
    steps: int = 0
    pending: collections.deque = field(default_factory=collections.deque)
    n: int = 0  # frames in the replay
    next: int = 0  # ring-buffer position of the next frame
    newest: int = -1


class StackedMemory:
    """The memories of ``slots`` episodes (see the module docstring). ``config``: a preset name or
    :class:`MemoryConfig` with ``field_type == "grid"``; ``init_state``: the fixed initial weights
    (``OnlineNeRF.initial_state()``, e.g. a checkpoint's ``memory_init``), by default those of ``init_seed``;
    ``render_points``: sample points per rendering query (default one slot's map, or the preset's ``render_chunk`` if
    smaller): slots are rendered in groups that fit, or one slot in chunks of rays if one does not; ``train_points``:
    sample points per training query (default ``TRAIN_POINTS``), at least one slot's. Neither changes the maps."""

    def __init__(
        self,
        config: MemoryConfig | str,
        slots: int,
        camera: CameraConfig | None = None,
        device: str | torch.device | None = None,
        init_state: dict[str, torch.Tensor] | None = None,
        render_points: int | None = None,
        train_points: int | None = None,
    ):
        self.config = cfg = get_memory(config)
        if cfg.field_type != "grid":
            raise ConfigError(None, f"stacked memory needs field_type grid, memory preset {cfg.name!r} has {cfg.field_type!r}")
        if int(slots) < 1:
            raise ConfigError(None, f"stacked memory needs at least one slot, got {slots}")
        self.slots = int(slots)
        per_map = cfg.map_height * cfg.map_width * (cfg.render_samples + cfg.sampler.free_samples)
        self.render_points = int(render_points if render_points is not None else min(cfg.render_chunk, per_map))
        self.train_points = int(train_points if train_points is not None else TRAIN_POINTS)
        self.camera = camera if camera is not None else CameraConfig()
        self.device = torch.device(device if device is not None else cfg.device)
        self.pixel_rays = PixelRays(self.camera, self.device)
        with torch.random.fork_rng(devices=[]):  # the global generator is left as it was
            torch.manual_seed(cfg.init_seed)
            geom = GridField(cfg.grid, cfg.radius)
        if init_state is not None:
            _load_init(geom, init_state)
        self.geom = geom.to(self.device)  # corner lookup, direction encoding and constants; its own table unused
        self._init = {k: v.detach().clone() for k, v in geom.state_dict().items() if k in DENSE_KEYS}
        self.geom.table = nn.Parameter(torch.zeros(0, geom.table.shape[1], device=self.device), requires_grad=False)
        self.rows_per_slot = geom.n_corners + 1
        width = 2 + cfg.grid.code_dim
        self.table = nn.Parameter(torch.zeros(self.slots * self.rows_per_slot, width, device=self.device))
        self.row_adam = SlotRowAdam(self.table, cfg.grid_lr, self.slots, self.rows_per_slot)
        b = self.slots
        self.dense = {k: v[None].repeat(b, *([1] * v.dim())).contiguous() for k, v in self._init.items()}
        self.exp_avg = {k: torch.zeros_like(v) for k, v in self.dense.items()}
        self.exp_avg_sq = {k: torch.zeros_like(v) for k, v in self.dense.items()}
        self.dense_steps = np.zeros(b, dtype=np.int64)
        rows, cols = map_pixels(self.camera, cfg.map_height, cfg.map_width)
        self._map_pixels = self._flat_pixels(rows, cols)
        self._map_dirs = self.pixel_rays.dirs[self._map_pixels]
        self._map_range_per_z = self.pixel_rays.range_per_z[self._map_pixels]
        self._pano_pixels = self._flat_pixels(*map_pixels(self.camera, cfg.panorama_height, cfg.panorama_width))
        # replay (B, replay_size, H * W, ...), allocated at the first frame
        self._rgb: torch.Tensor | None = None
        self._ranges: torch.Tensor | None = None
        self._valid: torch.Tensor | None = None
        self._n_valid: torch.Tensor | None = None
        self._poses: torch.Tensor | None = None
        self._state = [self._fresh_state(0) for _ in range(b)]

    # ----------------------------------------------------------------- episode state
    def _fresh_state(self, seed: int) -> _Slot:
        g = torch.Generator(device="cpu")
        g.manual_seed(int(seed))
        return _Slot(generator=g)

    def _check_slot(self, i) -> int:
        if not 0 <= int(i) < self.slots:
            raise MemoryInputError("slot", f"slot {i} out of range [0, {self.slots})")
        return int(i)

    def reset_slot(self, i: int, seed: int = 0, start_pose=None, floor_z: float = 0.0) -> None:
        """Slot ``i`` starts an episode, as ``OnlineNeRF.reset(seed, start_pose, floor_z)``: the initial weights,
        fresh optimiser state, an empty replay, its generator seeded with ``seed``. Other slots are untouched."""
        i = self._check_slot(i)
        a = i * self.rows_per_slot
        with torch.no_grad():
            self.table[a : a + self.rows_per_slot].zero_()
            for k, v in self._init.items():
                self.dense[k][i] = v
                self.exp_avg[k][i].zero_()
                self.exp_avg_sq[k][i].zero_()
        self.row_adam.reset_slot(i)
        self.dense_steps[i] = 0
        self._state[i] = self._fresh_state(seed)
        if start_pose is not None:
            self._ensure_frame(i, start_pose, floor_z)

    def replay_len(self, i: int) -> int:
        """Frames currently in slot ``i``'s replay."""
        return self._state[self._check_slot(i)].n

    def _ensure_frame(self, i: int, pose, floor_z: float) -> EpisodeFrame:
        s = self._state[i]
        if s.frame is None:
            s.frame = EpisodeFrame.from_pose(pose, self.camera, floor_z, self.config.radius)
        return s.frame

    def _flat_pixels(self, rows: np.ndarray, cols: np.ndarray) -> torch.Tensor:
        flat = (rows[:, None] * self.camera.width + cols[None, :]).reshape(-1)
        return torch.as_tensor(flat, dtype=torch.long, device=self.device)

    def _listed(self, slots, *columns) -> list[int]:
        slots = [self._check_slot(i) for i in slots]
        if len(set(slots)) != len(slots):
            raise MemoryInputError("slots", f"a slot is listed twice in {slots}")
        for col in columns:
            if len(col) != len(slots):
                raise MemoryInputError("slots", f"{len(slots)} slots but {len(col)} inputs")
        return slots

    # ----------------------------------------------------------------- stacked field
    def _field(self, rows: torch.Tensor, w: torch.Tensor, d: torch.Tensor, params: dict[str, torch.Tensor],
               n_samples: int) -> FieldOutputs:
        """The field at points given by their corners ``rows, w (S * R * N, 8)`` (rows already offset to their
        slot), rays' unit directions ``d (S * R, 3)``, slot-major; ``params`` the S slots' colour MLPs.
        Outputs have batch shape ``(S * R, N)``."""
        g = self.geom
        c = self.config.grid
        s = params["colour_code.weight"].shape[0]
        grad = torch.is_grad_enabled()
        if grad:
            raw = _TrilinearRead.apply(self.table, rows, w)
        else:
            raw = F.embedding_bag(rows, self.table, per_sample_weights=w, mode="sum")
        raw = raw * g.channel_scale
        density = F.softplus(raw[:, 0] + g.density_shift)
        if c.variance_max > 0:
            variance = c.beta_min + (c.variance_max - c.beta_min) * torch.sigmoid(raw[:, 1] + g.variance_shift)
        else:
            variance = F.softplus(raw[:, 1] + g.variance_shift) + c.beta_min
        enc = g.dir_enc(d)
        n_rays = d.shape[0] // s
        dir_part = torch.bmm(enc.view(s, n_rays, -1), params["colour_dir.weight"].transpose(1, 2))  # (S, R, F)
        code = raw[:, 2:].contiguous().view(s, n_rays * n_samples, -1)
        fc = torch.baddbmm(params["colour_code.bias"].unsqueeze(1), code, params["colour_code.weight"].transpose(1, 2))
        fc = fc.view(s, n_rays, n_samples, -1)
        fc = F.relu(fc + dir_part.unsqueeze(2)) if grad else F.relu(fc.add_(dir_part.unsqueeze(2)), inplace=True)
        fc = fc.view(s, n_rays * n_samples, -1)
        rgb = torch.sigmoid(torch.baddbmm(params["colour_out.bias"].unsqueeze(1), fc, params["colour_out.weight"].transpose(1, 2)))
        return FieldOutputs(
            density=density.view(-1, n_samples),
            rgb=rgb.view(-1, n_samples, 3),
            variance=variance.view(-1, n_samples),
            feature=fc.view(s * n_rays, n_samples, -1),
        )

    def _query(self, slots: list[int], bundle: RayBundle, n_samples: int, params: dict[str, torch.Tensor]):
        """Samples, field outputs, weights and T_{N+1} of ``bundle`` (the listed slots' rays, slot-major, equal counts),
        samples at bin centres (rendering)."""
        samples = depth_guided_samples(bundle.ranges, n_samples, self.config.sampler, None)
        pts = bundle.origins[:, None, :] + samples.t[..., None] * bundle.directions[:, None, :]
        rows, w = self.geom.corners((pts * (1.0 / self.config.radius)).reshape(-1, 3))
        rows = rows + self._row_offsets(slots, rows.shape[0])
        out = self._field(rows, w, bundle.directions, params, samples.t.shape[1])
        weights, transmittance = compositing_weights(out.density, samples.deltas)
        return samples, out, weights, transmittance

    def _row_offsets(self, slots: list[int], n_points: int) -> torch.Tensor:
        """(P, 1) first table row of each point's slot, for ``n_points`` points split evenly, slot-major."""
        offs = torch.as_tensor(slots, dtype=torch.long, device=self.device) * self.rows_per_slot
        return offs.repeat_interleave(n_points // len(slots))[:, None]

    def _params(self, slots: list[int]) -> dict[str, torch.Tensor]:
        if slots == list(range(self.slots)):
            return dict(self.dense)
        idx = torch.as_tensor(slots, dtype=torch.long, device=self.device)
        return {k: v.index_select(0, idx) for k, v in self.dense.items()}

    # ----------------------------------------------------------------- rendering
    @torch.no_grad()
    def render_maps(self, slots: list[int], poses, depths, floor_zs=None) -> list[MemoryMaps]:
        """The maps of each listed slot for its pose, as ``OnlineNeRF.render_maps`` gives them (with the
        panorama if the preset has one), from one batched query. Does not change the memory."""
        floor_zs = [0.0] * len(slots) if floor_zs is None else list(floor_zs)
        slots = self._listed(slots, poses, depths, floor_zs)
        cfg = self.config
        h, w = cfg.map_height, cfg.map_width
        transforms, bundles = [], []
        for i, pose, depth, fz in zip(slots, poses, depths, floor_zs):
            pose = check_pose(pose)
            frame = self._ensure_frame(i, pose, fz)
            ranges = self.pixel_rays.ranges_from_depth(depth, self._map_pixels)
            m = self.pixel_rays.episode_from_camera(pose, frame, fz)
            transforms.append((pose, fz))
            bundles.append(self.pixel_rays.bundle(m, self._map_pixels, ranges, self._map_dirs))
        n = h * w
        # one query per group of slots, or per chunk of one slot's rays, of at most ``render_points`` sample points:
        # larger tensors fall out of the cache (and past the allocator's mmap threshold), which costs more per point
        # than a query's fixed cost
        group = self.render_points // (n * cfg.render_samples)
        queries: list[tuple[list[int], RayBundle]] = []
        if group >= 1:
            for g0 in range(0, len(slots), group):
                bs = bundles[g0 : g0 + group]
                queries.append((slots[g0 : g0 + group], RayBundle(*(torch.cat([getattr(b, k) for b in bs])
                                                                   for k in ("origins", "directions", "ranges")))))
        else:
            rays = max(1, self.render_points // cfg.render_samples)
            for i, b in zip(slots, bundles):
                queries += [([i], RayBundle(b.origins[r : r + rays], b.directions[r : r + rays], b.ranges[r : r + rays]))
                            for r in range(0, n, rays)]
        chunks: dict[str, list[torch.Tensor]] = {"i_u": [], "rgb": [], "depth": [], "transmittance": [], "i_cog": []}
        with torch.inference_mode():
            for sl, bundle in queries:
                samples, out, wts, transmittance = self._query(sl, bundle, cfg.render_samples, self._params(sl))
                chunks["i_u"].append(render_uncertainty(wts, out.variance, transmittance, cfg.unseen_variance)[:, None])
                chunks["rgb"].append(render_rgb(wts, out.rgb))
                chunks["depth"].append(render_depth(wts, samples.t)[:, None])
                chunks["transmittance"].append(transmittance[:, None])
                chunks["i_cog"].append(render_features(wts, out.feature))
            pano = None
            if cfg.panorama_headings:
                per_slot = cfg.panorama_headings * self._pano_pixels.numel() * cfg.panorama_samples
                pg = max(1, self.render_points // per_slot)
                pano = torch.cat([self._panorama(slots[g0 : g0 + pg], transforms[g0 : g0 + pg], self._params(slots[g0 : g0 + pg]))
                                  for g0 in range(0, len(slots), pg)])
        parts = {k: torch.cat(v) for k, v in chunks.items()}
        maps = []
        for j in range(len(slots)):
            one = {k: v[j * n : (j + 1) * n].T.reshape(-1, h, w) for k, v in parts.items()}
            one["depth"] = one["depth"] / self._map_range_per_z.reshape(1, h, w)
            maps.append(MemoryMaps(**one, panorama=None if pano is None else pano[j].clone()))
        return maps

    def _panorama(self, slots: list[int], poses: list[tuple[np.ndarray, float]], params) -> torch.Tensor:
        """(S, K, hp, wp) I_u of K views at each slot's position, as ``OnlineNeRF.render_panorama``."""
        cfg = self.config
        k, pix = cfg.panorama_headings, self._pano_pixels
        per_ray = []
        for i, (pose, fz) in zip(slots, poses):
            frame = self._state[i].frame
            assert frame is not None
            t = torch.stack([self.pixel_rays.episode_from_camera((pose[0], pose[1], pose[2] + 2.0 * np.pi * j / k), frame, fz)
                             for j in range(k)])
            per_ray.append(t.repeat_interleave(pix.numel(), dim=0))
        n = len(slots) * k * pix.numel()
        bundle = self.pixel_rays.bundle(torch.cat(per_ray), pix.repeat(len(slots) * k),
                                        torch.full((n,), float("nan"), device=self.device))
        _, out, w, transmittance = self._query(slots, bundle, cfg.panorama_samples, params)
        i_u = render_uncertainty(w, out.variance, transmittance, cfg.unseen_variance)
        return i_u.reshape(len(slots), k, cfg.panorama_height, cfg.panorama_width)

    # ----------------------------------------------------------------- replay
    def _check_rgb(self, rgb) -> torch.Tensor:
        return rgb_pixels(rgb, self.camera, self.device)

    def observe(self, i: int, rgb, depth, pose, floor_z: float = 0.0) -> None:
        """Add a frame to slot ``i``'s replay, as ``OnlineNeRF.observe``."""
        i = self._check_slot(i)
        pose = check_pose(pose)
        rgb_t = self._check_rgb(rgb)
        ranges = self.pixel_rays.ranges_from_depth(depth)
        valid = torch.nonzero(torch.isfinite(ranges)).squeeze(1)
        if valid.numel() == 0:
            raise MemoryInputError("depth", "frame has no valid depth pixel (all 0, NaN or inf)")
        frame = self._ensure_frame(i, pose, floor_z)
        cap, hw = self.config.replay_size, ranges.numel()
        if self._rgb is None:
            b, dev = self.slots, self.device
            self._rgb = torch.zeros(b, cap, hw, 3, dtype=torch.uint8, device=dev)
            self._ranges = torch.zeros(b, cap, hw, dtype=torch.float32, device=dev)
            self._valid = torch.zeros(b, cap, hw, dtype=torch.long, device=dev)
            self._n_valid = torch.zeros(b, cap, dtype=torch.long, device=dev)
            self._poses = torch.zeros(b, cap, 4, 4, dtype=torch.float32, device=dev)
        assert self._ranges is not None and self._valid is not None and self._n_valid is not None and self._poses is not None
        s = self._state[i]
        j = s.next
        self._rgb[i, j] = rgb_t
        self._ranges[i, j] = ranges
        self._valid[i, j, : valid.numel()] = valid
        self._n_valid[i, j] = valid.numel()
        self._poses[i, j] = self.pixel_rays.episode_from_camera(pose, frame, floor_z)
        s.newest = j
        s.next = (j + 1) % cap
        s.n = min(s.n + 1, cap)

    def _draw_rays(self, i: int, n_rays: int) -> tuple[torch.Tensor, torch.Tensor]:
        """Slot ``i``'s generator's draws of one iteration, as ``OnlineNeRF._draw_rays``: replay positions and flat
        pixels ``(R,)`` each."""
        assert self._n_valid is not None and self._valid is not None
        s = self._state[i]
        g = s.generator
        n_new = int(round(self.config.newest_fraction * n_rays)) if s.n > 1 else 0
        frames = torch.randint(0, s.n, (n_rays - n_new,), generator=g)
        frames = torch.cat([torch.full((n_new,), s.newest, dtype=torch.long), frames]).to(self.device)
        u = torch.rand(n_rays, generator=g).to(self.device)
        pos = (u * self._n_valid[i, frames]).long()
        return frames, self._valid[i, frames, pos]

    # ----------------------------------------------------------------- training
    def step(self, slots: list[int], rgbs, depths, poses, floor_zs=None) -> None:
        """One environment step of each listed slot's schedule, as ``OnlineNeRF.step``: observe, then one
        batched update of the slots whose schedule updates now."""
        floor_zs = [0.0] * len(slots) if floor_zs is None else list(floor_zs)
        slots = self._listed(slots, rgbs, depths, poses, floor_zs)
        cfg = self.config
        update = []
        for i, rgb, depth, pose, fz in zip(slots, rgbs, depths, poses, floor_zs):
            s = self._state[i]
            if cfg.lag:
                s.pending.append((np.array(rgb, copy=True), np.array(depth, copy=True), np.array(pose, copy=True), fz))
                if len(s.pending) <= cfg.lag:
                    continue
                rgb, depth, pose, fz = s.pending.popleft()
            t = s.steps
            s.steps += 1
            if t % cfg.observe_every == 0:
                self.observe(i, rgb, depth, pose, fz)
            if t % cfg.update_every == 0 and s.n > 0:
                update.append(i)
        if update:
            self.update(update)

    def update(self, slots: list[int], n_iters: int | None = None) -> None:
        """``n_iters`` (default: the preset's K) training iterations of each listed slot on rays from its own replay:
        per iteration one query of all their rays, one backward, one optimiser step (per group of slots if
        ``train_points`` splits them)."""
        slots = self._listed(slots)
        for i in slots:
            if self._state[i].n == 0:
                raise MemoryInputError("replay", f"update() of slot {i} needs at least one observed frame")
        assert self._rgb is not None and self._ranges is not None and self._poses is not None
        cfg = self.config
        n_iters = cfg.iters_per_update if n_iters is None else int(n_iters)
        n_rays, n_bins, n_slots = cfg.train_rays, cfg.train_samples + cfg.sampler.free_samples, len(slots)
        draws: list[list[tuple[torch.Tensor, torch.Tensor, torch.Tensor]]] = []
        for i in slots:  # each slot's draws in OnlineNeRF's order: per iteration its rays, then their jitter
            g = self._state[i].generator
            per_slot = []
            for _ in range(n_iters):
                frames, pix = self._draw_rays(i, n_rays)
                per_slot.append((frames, pix, torch.rand((n_rays, n_bins), generator=g).to(self.device)))
            draws.append(per_slot)
        # iteration-major, then slot-major within an iteration: iteration k is one contiguous block
        order = [draws[j][k] for k in range(n_iters) for j in range(n_slots)]
        frames, pix, jitter = (torch.cat(v) for v in zip(*order))
        slot_of = torch.as_tensor(slots, dtype=torch.long, device=self.device).repeat_interleave(n_rays).repeat(n_iters)
        bundle = self.pixel_rays.bundle(self._poses[slot_of, frames], pix, self._ranges[slot_of, frames, pix])
        target = self._rgb[slot_of, frames, pix].float() / 255.0
        samples = depth_guided_samples(bundle.ranges, cfg.train_samples, cfg.sampler, jitter=jitter)
        pts = bundle.origins[:, None, :] + samples.t[..., None] * bundle.directions[:, None, :]
        rows, w = self.geom.corners((pts * (1.0 / cfg.radius)).reshape(-1, 3))
        rows = rows + (slot_of * self.rows_per_slot).repeat_interleave(n_bins)[:, None]
        # slots in groups of at most train_points sample points per query, each group with its own leaf parameters
        size = max(1, self.train_points // (n_rays * n_bins))
        groups = []
        for g0 in range(0, n_slots, size):
            sl = slots[g0 : g0 + size]
            idx = torch.as_tensor(sl, dtype=torch.long, device=self.device)
            groups.append((g0, sl, idx, {k: v.index_select(0, idx).requires_grad_(True) for k, v in self.dense.items()},
                           {k: v.index_select(0, idx) for k, v in self.exp_avg.items()},
                           {k: v.index_select(0, idx) for k, v in self.exp_avg_sq.items()}))
        beta_min = self.geom.config.beta_min
        per = n_slots * n_rays
        for it in range(n_iters):
            for g0, sl, _, params, m, v2 in groups:
                ns = len(sl)
                r0 = it * per + g0 * n_rays
                r = slice(r0, r0 + ns * n_rays)
                p = slice(r0 * n_bins, (r0 + ns * n_rays) * n_bins)
                out = self._field(rows[p], w[p], bundle.directions[r], params, n_bins)
                weights, transmittance = compositing_weights(out.density, samples.deltas[r])
                ray_var = render_uncertainty(weights, out.variance) + beta_min
                nll = uncertainty_nll(render_rgb(weights, out.rgb), target[r], ray_var).view(ns, n_rays).mean(dim=1)
                loss = nll + cfg.density_weight * out.density.view(ns, -1).mean(dim=1)
                if cfg.depth_weight > 0:
                    t, d = samples.t[r], samples.deltas[r]
                    depth_pred = (weights * t).sum(dim=-1) + transmittance * (t[:, -1] + 0.5 * d[:, -1])
                    err = (depth_pred - bundle.ranges[r]).abs().view(ns, n_rays).mean(dim=1)
                    loss = loss + cfg.depth_weight * err
                self.table.grad = None
                for q in params.values():
                    q.grad = None
                loss.sum().backward()  # slots share no parameter: each slot's gradient is that of its own loss
                slot_adam_step(params, m, v2, self.dense_steps, sl, self.config.lr)
                self.row_adam.step_slots(sl)
        with torch.no_grad():
            for _, _, idx, params, m, v2 in groups:
                for k in self.dense:
                    self.dense[k].index_copy_(0, idx, params[k].detach())
                    self.exp_avg[k].index_copy_(0, idx, m[k])
                    self.exp_avg_sq[k].index_copy_(0, idx, v2[k])
        self.table.grad = None

def _load_init(geom: GridField, init_state: dict[str, torch.Tensor]) -> None:
    """Load stored initial weights into ``geom`` with ``OnlineNeRF``'s checks (the table is zero by definition)."""
    try:
        missing, unexpected = geom.load_state_dict(init_state, strict=False)
    except RuntimeError as e:
        raise CheckpointError("memory init", f"stored NeRF initialisation does not fit the field config: {e}") from None
    if unexpected or set(missing) - {"table"}:
        raise CheckpointError("memory init", f"stored NeRF initialisation does not fit the field config (missing "
                                             f"{sorted(set(missing) - {'table'})}, unexpected {sorted(unexpected)})")
