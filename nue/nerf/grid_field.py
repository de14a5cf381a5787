"""A dense voxel-grid radiance field (DVGO-style) with the same outputs as the MLP field.

Each voxel corner stores raw density, raw variance and a small appearance code; a point reads them by
trilinear interpolation (one ``embedding_bag`` per query batch, so training touches — and its sparse
gradient names — only the voxels near the samples); a small colour MLP turns the code and the view
direction into the 64-d colour feature f_c and RGB. Parameters are local: space no frame has sampled
keeps its initial values (near-zero density, initial variance), which is what makes the rendered
uncertainty of unseen space stand out. On CPU it is far cheaper than the MLP trunk per point.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from torch import nn
from torch.nn import functional as F

from nue.nerf.encoding import PositionalEncoding
from nue.nerf.field import FieldOutputs, colour_head


@dataclass(frozen=True)
class GridFieldConfig:
    """Geometry and heads of :class:`GridField` (lengths in metres of the episode frame)."""

    voxel_size: float = 0.15
    """Edge of a voxel, metres."""
    half_extent: float = 12.0
    """The grid spans [-half_extent, half_extent] in x and y around the start camera position."""
    z_min: float = -1.0
    """Lowest z of the grid relative to the start camera position (the floor is at -mount_height)."""
    z_max: float = 3.0
    """Highest z of the grid relative to the start camera position."""
    code_dim: int = 16
    """Channels of the per-voxel appearance code fed to the colour MLP."""
    dir_freqs: int = 4
    """Frequencies of the view-direction encoding."""
    feature_dim: int = 64
    """Width of the colour feature f_c (= I_cog channels)."""
    init_density: float = 0.01
    """Density (per metre) of a voxel that was never trained."""
    init_variance: float = 0.5
    """beta^2 of a voxel that was never trained."""
    beta_min: float = 0.01
    """Floor of the per-point variance (as the MLP field)."""
    variance_max: float = 1.0
    """Ceiling beta_max^2 of the per-point variance: ``beta^2 = beta_min + (beta_max^2 - beta_min)
    sigmoid(raw)``; with the memory's ``unseen_variance`` equal to it, no rendered I_u exceeds that of
    never-seen space (``sum w^2 + T <= 1``). 0: unbounded ``softplus(raw) + beta_min`` as the MLP field."""
    density_scale: float = 20.0
    """The stored density channel is multiplied by this before the activation: with Adam that is a
    ``density_scale`` times larger step for density than for variance and code (surfaces must turn
    opaque within a few visits)."""


def _softplus_inverse(y: float) -> float:
    return math.log(math.expm1(y))


class GridField(nn.Module):
    """Voxel grid + colour MLP. ``forward(x, d)`` takes positions normalised by ``radius`` (as the MLP
    field) and unit directions per point ``(..., 3)`` or per ray ``(R, 3)`` for ``x (R, N, 3)``.

    ``table``: ``(V + 1, 2 + code_dim)`` rows of voxel corners ``(density raw, variance raw, code)``, the
    last row standing for every point outside the grid (never trained). All-zero at initialisation, so it
    is not part of the stored initial weights (``zero_init_keys``).
    """

    zero_init_keys = ("table",)
    # buffers (register_buffer), typed for the checker
    lo: torch.Tensor
    strides: torch.Tensor
    dims: torch.Tensor
    corner_rows: torch.Tensor
    scale_in: torch.Tensor
    grid_offset: torch.Tensor
    last_base: torch.Tensor
    channel_scale: torch.Tensor

    def __init__(self, config: GridFieldConfig = GridFieldConfig(), radius: float = 12.0):
        super().__init__()
        self.config = config
        self.radius = float(radius)
        c = config
        self.shape_xyz = (
            int(math.ceil(2 * c.half_extent / c.voxel_size)) + 1,
            int(math.ceil(2 * c.half_extent / c.voxel_size)) + 1,
            int(math.ceil((c.z_max - c.z_min) / c.voxel_size)) + 1,
        )
        nx, ny, nz = self.shape_xyz
        self.n_corners = nx * ny * nz
        self.table = nn.Parameter(torch.zeros(self.n_corners + 1, 2 + c.code_dim))
        self.register_buffer("lo", torch.tensor([-c.half_extent, -c.half_extent, c.z_min]), persistent=False)
        self.register_buffer("strides", torch.tensor([1, nx, nx * ny]), persistent=False)
        self.register_buffer("dims", torch.tensor([nx, ny, nz]), persistent=False)
        corner_rows = torch.tensor([i + j * nx + k * nx * ny for k in (0, 1) for j in (0, 1) for i in (0, 1)])
        self.register_buffer("corner_rows", corner_rows, persistent=False)
        self.register_buffer("scale_in", torch.full((3,), self.radius / c.voxel_size), persistent=False)
        self.register_buffer("grid_offset", -self.lo / c.voxel_size, persistent=False)
        self.register_buffer("last_base", (self.dims - 1).float(), persistent=False)
        scale = torch.ones(2 + c.code_dim)
        scale[0] = c.density_scale
        self.register_buffer("channel_scale", scale, persistent=False)
        self.density_shift = _softplus_inverse(c.init_density)
        if c.variance_max > 0:
            if not c.beta_min < c.init_variance < c.variance_max:
                raise ValueError("grid field needs beta_min < init_variance < variance_max")
            p = (c.init_variance - c.beta_min) / (c.variance_max - c.beta_min)
            self.variance_shift = math.log(p / (1 - p))
        else:
            self.variance_shift = _softplus_inverse(c.init_variance)
        self.dir_enc = PositionalEncoding(3, c.dir_freqs)
        self.colour_code = nn.Linear(c.code_dim, c.feature_dim)
        self.colour_dir = nn.Linear(self.dir_enc.out_dim, c.feature_dim, bias=False)
        self.colour_out = nn.Linear(c.feature_dim, 3)

    def dense_parameters(self) -> list[nn.Parameter]:
        """Parameters with dense gradients (the colour MLP)."""
        return [p for n, p in self.named_parameters() if n != "table"]

    def optimizers(self, lr: float, grid_lr: float) -> list:
        """Fresh optimisers of an episode: Adam (``lr``, :class:`DenseAdam`) on the colour MLP, :class:`RowAdam`
        (``grid_lr``) on the table's touched rows (its gradients are sparse)."""
        return [DenseAdam(self.dense_parameters(), lr=lr), RowAdam(self.table, lr=grid_lr)]

    def corners(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Table rows and trilinear weights of the 8 voxel corners around normalised positions
        ``x (P, 3)``: ``(rows (P, 8) int64, weights (P, 8))``; points outside the grid read the last row
        with weight 0. Corner k = 4 dz + 2 dy + dx."""
        g = torch.addcmul(self.grid_offset, x, self.scale_in)  # position in voxels from the grid's low corner
        base = torch.floor(g)
        frac = g - base
        inside = ((base >= 0) & (base < self.last_base)).all(dim=-1)
        low = (base.long() * self.strides).sum(dim=-1)  # flat row of the low corner
        # (P, 8) rows, formed with the points along the last axis (broadcasts over 8 columns are slow)
        rows = torch.where(inside, low + self.corner_rows[:, None], self.n_corners).T.contiguous()
        # trilinear weights wz * wy * wx of the 8 corners, computed with the points along the last axis
        frac = frac.T.contiguous()
        f = torch.stack([1.0 - frac, frac])  # (2, 3, P): weight of the low / high corner per axis
        wz = f[:, 2] * inside
        w = wz[:, None, None, :] * f[None, :, 1, None, :] * f[None, None, :, 0, :]  # (dz, dy, dx, P)
        return rows, w.reshape(8, -1).T.contiguous()

    def interpolate(self, x: torch.Tensor) -> torch.Tensor:
        """Trilinear read of the table at normalised positions ``x (P, 3)`` -> ``(P, 2 + code_dim)``;
        the table's gradient is sparse (only the rows read)."""
        rows, w = self.corners(x)
        return F.embedding_bag(rows, self.table, per_sample_weights=w, mode="sum", sparse=True)

    def forward(self, x: torch.Tensor, d: torch.Tensor) -> FieldOutputs:
        return self.from_corners(*self.corners(x.reshape(-1, 3)), x, d)

    def from_corners(self, rows: torch.Tensor, w: torch.Tensor, x: torch.Tensor, d: torch.Tensor) -> FieldOutputs:
        """``forward(x, d)`` given ``corners(x.reshape(-1, 3))`` computed earlier (they do not depend on the
        table, so the corners of several training iterations can be found at once)."""
        if torch.is_grad_enabled() and self.table.requires_grad:
            raw = _TrilinearRead.apply(self.table, rows, w)
        else:
            raw = F.embedding_bag(rows, self.table, per_sample_weights=w, mode="sum")
        raw = raw * self.channel_scale
        density = F.softplus(raw[:, 0] + self.density_shift)
        c = self.config
        if c.variance_max > 0:
            variance = c.beta_min + (c.variance_max - c.beta_min) * torch.sigmoid(raw[:, 1] + self.variance_shift)
        else:
            variance = F.softplus(raw[:, 1] + self.variance_shift) + c.beta_min
        dir_part = self.colour_dir(self.dir_enc(d))
        # a contiguous copy of the code columns first: a GEMM on the strided slice takes a path ~2.5x slower
        # on CPU (same result, bit for bit)
        return colour_head(self.colour_code(raw[:, 2:].contiguous()), dir_part, x, d, self.colour_out, density, variance)

    def flops_per_point(self, samples_per_ray: int = 1) -> float:
        """FLOPs of one point query: trilinear read (8 corners x channels, multiply-add) + colour GEMMs;
        the direction branch is shared by the ``samples_per_ray`` points of a ray."""
        c = self.config
        read = 2.0 * 8 * (2 + c.code_dim)
        gemm = 2.0 * (c.code_dim * c.feature_dim + c.feature_dim * 3)
        per_ray = 2.0 * self.dir_enc.out_dim * c.feature_dim
        return read + gemm + per_ray / max(samples_per_ray, 1)


class _TrilinearRead(torch.autograd.Function):
    """``embedding_bag(rows, table, per_sample_weights=w, mode="sum", sparse=True)`` with the same forward and
    the same sparse table gradient as autograd's (entry j of ``rows.reshape(-1)`` gets ``grad[j // 8] * w[j]``,
    uncoalesced, in that order), formed by one broadcast multiply instead of a row gather and a multiply."""

    @staticmethod
    def forward(ctx, table: torch.Tensor, rows: torch.Tensor, w: torch.Tensor) -> torch.Tensor:
        ctx.save_for_backward(rows, w)
        ctx.table_shape = table.shape
        return F.embedding_bag(rows, table, per_sample_weights=w, mode="sum")

    @staticmethod
    def backward(ctx, grad: torch.Tensor):
        rows, w = ctx.saved_tensors
        values = (grad.unsqueeze(1) * w.unsqueeze(2)).reshape(-1, grad.shape[1])
        table_grad = torch.sparse_coo_tensor(rows.reshape(1, -1), values, ctx.table_shape, check_invariants=False)
        return table_grad, None, None


class DenseAdam:
    """``torch.optim.Adam`` (default settings: no weight decay, no AMSGrad) with the same arithmetic, op for op,
    as its single-tensor path on CPU, without the optimiser framework around it (hooks, parameter groups,
    state dicts): the colour MLP's five small tensors take two steps per environment step, where that
    framework costs more than the update. A parameter without a gradient is skipped and keeps its own step
    count, as in Adam.
    """

    def __init__(self, params, lr: float, betas: tuple[float, float] = (0.9, 0.999), eps: float = 1e-8):
        self.params = list(params)
        self.lr, self.betas, self.eps = lr, betas, eps
        self.exp_avg = [torch.zeros_like(p, memory_format=torch.preserve_format) for p in self.params]
        self.exp_avg_sq = [torch.zeros_like(p, memory_format=torch.preserve_format) for p in self.params]
        self.steps = [0] * len(self.params)

    def zero_grad(self, set_to_none: bool = True) -> None:
        for p in self.params:
            p.grad = None

    @torch.no_grad()
    def step(self) -> None:
        b1, b2 = self.betas
        for i, (p, m, v) in enumerate(zip(self.params, self.exp_avg, self.exp_avg_sq)):
            g = p.grad
            if g is None:
                continue
            self.steps[i] += 1
            step = float(self.steps[i])
            m.lerp_(g, 1 - b1)
            v.mul_(b2).addcmul_(g, g, value=1 - b2)
            step_size = self.lr / (1 - b1**step)
            denom = (v.sqrt() / (1 - b2**step) ** 0.5).add_(self.eps)
            p.addcdiv_(m, denom, value=-step_size)


class RowAdam:
    """Adam for a table trained through sparse row gradients, updating only the rows a step touched.

    Same update as ``torch.optim.SparseAdam`` (lazy Adam: the moments of untouched rows do not decay),
    without its sort and without scanning the table: the touched rows are found from the gradient's own
    indices (each row once, through a per-row stamp), duplicate rows of the uncoalesced gradient are summed
    with ``index_add_`` in the gradient's order into a buffer of the touched rows only, and the moments and
    the table are read and written at those rows. Each row's arithmetic is that of a dense Adam step, so the
    result does not depend on the order in which the rows are found. ``table (V, C)``.
    """

    def __init__(self, table: nn.Parameter, lr: float, betas: tuple[float, float] = (0.9, 0.999), eps: float = 1e-8):
        self.table, self.lr, self.betas, self.eps = table, lr, betas, eps
        # both moments of a row side by side (one gather and one scatter per step); fill_ writes every page
        # now (zeros may map them lazily), so steps do not page-fault
        self._moments = torch.empty((table.shape[0], 2, table.shape[1]), dtype=table.dtype, device=table.device).fill_(0.0)
        self._stamp = torch.empty(table.shape[0], dtype=torch.long, device=table.device).fill_(0)
        self._arange = torch.arange(0, device=table.device)
        self.steps = 0

    @property
    def exp_avg(self) -> torch.Tensor:
        """(V, C) first moments (a view)."""
        return self._moments[:, 0]

    @property
    def exp_avg_sq(self) -> torch.Tensor:
        """(V, C) second moments (a view)."""
        return self._moments[:, 1]

    def zero_grad(self, set_to_none: bool = True) -> None:
        self.table.grad = None

    def _unique_rows(self, idx: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """The distinct rows of ``idx (K,)`` (each once, in no particular order) and each entry's position
        among them: ``(rows (U,), inverse (K,))`` with ``rows[inverse] == idx``. Touches only those rows of
        the (V,) stamp buffer, never the whole table (no sort, no scan of V)."""
        k = idx.numel()
        if self._arange.numel() < k:
            self._arange = torch.arange(max(k, 2 * self._arange.numel()), device=idx.device)
        ar = self._arange[:k]
        self._stamp.index_copy_(0, idx, ar)  # among duplicates one position wins
        rows = idx[self._stamp.index_select(0, idx) == ar]  # the winning entry of each row
        self._stamp.index_copy_(0, rows, self._arange[: rows.numel()])
        return rows, self._stamp.index_select(0, idx)

    def _update_moments(self, idx: torch.Tensor, vals: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Adam's moment update at the rows an uncoalesced row gradient ``(idx (K,), vals (K, C))`` touches; returns
        ``(rows (U,), m (U, C), v (U, C))``, the distinct rows and their new moments (also written back)."""
        rows, inverse = self._unique_rows(idx)
        # duplicates summed in the gradient's order (index_put_'s accumulate is index_add_'s sum, op for op, and
        # on CPU about twice as fast for rows this narrow)
        grad = torch.zeros(rows.numel(), vals.shape[1], dtype=vals.dtype, device=vals.device)
        grad.index_put_((inverse,), vals, accumulate=True)
        b1, b2 = self.betas
        moments = self._moments.index_select(0, rows)
        m, v = moments[:, 0], moments[:, 1]
        m.mul_(b1).add_(grad, alpha=1 - b1)
        v.mul_(b2).addcmul_(grad, grad, value=1 - b2)
        self._moments.index_copy_(0, rows, moments)
        return rows, m, v

    @torch.no_grad()
    def step(self) -> None:
        g = self.table.grad
        if g is None:
            return
        self.steps += 1
        if g.is_sparse:
            idx, vals = g._indices()[0], g._values()
        else:
            idx = torch.nonzero(g.abs().sum(dim=1)).squeeze(1)
            vals = g[idx]
        rows, m, v = self._update_moments(idx, vals)
        b1, b2 = self.betas
        step_size = self.lr * math.sqrt(1 - b2**self.steps) / (1 - b1**self.steps)
        # table - step m / (sqrt(v) + eps), as an add of the negated step; the rows are distinct, so a gather,
        # an add and a scatter give index_add_'s result
        delta = (-step_size) * m / (v.sqrt() + self.eps)
        self.table.index_copy_(0, rows, self.table.index_select(0, rows).add_(delta))
