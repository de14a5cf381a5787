"""Memory (NeRF) presets as data: field, sampling, map size and online schedule; ``get_memory(name)``.

A run is task preset x memory preset x model config; checkpoints store the memory config by value.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from dataclasses import field as dc_field

from nue.errors import ConfigError
from nue.nerf.field import FieldConfig
from nue.nerf.grid_field import GridFieldConfig
from nue.nerf.rays import SamplerConfig


@dataclass(frozen=True)
class MemoryConfig:
    """Everything that defines the online NeRF memory of one episode (the authors' values in brackets)."""

    name: str = "custom"
    """Preset name, recorded in checkpoints."""
    field_type: str = "mlp"
    """``mlp``: the paper's positional-encoding MLP (``field``); ``grid``: a dense voxel grid (``grid``)."""
    field: FieldConfig = dc_field(default_factory=FieldConfig)
    """Architecture of the MLP radiance field."""
    grid: GridFieldConfig = dc_field(default_factory=GridFieldConfig)
    """Geometry of the voxel-grid field (used when ``field_type == "grid"``)."""
    sampler: SamplerConfig = dc_field(default_factory=SamplerConfig)
    """Depth-guided sample placement, shared by training and rendering."""
    radius: float = 12.0
    """Positions are divided by this radius (metres) around the episode's start pose before encoding."""
    train_rays: int = 10_800
    """Rays per training iteration, drawn from the replay [10,800 = every other pixel of one frame]."""
    train_samples: int = 64
    """Samples per ray while training [64]."""
    render_samples: int = 192
    """Samples per ray while rendering the maps [192]."""
    map_height: int = 90
    """Height h of the rendered maps I_u, I_cog [90]."""
    map_width: int = 120
    """Width w of the rendered maps [120]."""
    iters_per_update: int = 1
    """Training iterations per update (K); see the ``authors`` preset for the choice of K."""
    update_every: int = 1
    """Run an update every k-th step (``step``); 1 = every step."""
    observe_every: int = 1
    """Add the frame to the replay every k-th step (``step``); 1 = every frame."""
    replay_size: int = 100
    """Frames kept in the replay; the oldest is dropped first [100]."""
    lag: int = 0
    """Memory lag: frame t joins the replay (and is trained on) only at step t + lag, so the maps of step t come
    from a NeRF that has learned frames up to t - 1 - lag (0 = up to t - 1, the paper's synchronous order; the
    authors' asynchronous trainer lags by several steps)."""
    newest_fraction: float = 0.0
    """Fraction of each iteration's rays drawn from the newest frame; the rest uniformly from the replay."""
    lr: float = 5e-4
    """Adam learning rate of the MLP weights [5e-4, nerf-pytorch's default]."""
    grid_lr: float = 0.1
    """SparseAdam learning rate of the voxel grid (grid field only; DVGO uses 0.1)."""
    density_weight: float = 0.01
    """Weight of mean(sigma) in the loss [0.01, ActiveNeRF]."""
    depth_weight: float = 0.0
    """Weight of an L1 loss between the expected ray termination ``sum w t + T_{N+1} t_far`` and the
    observed surface distance, metres (0 = the paper's loss)."""
    unseen_variance: float = 0.0
    """beta_max^2 in ``I_u += T_{N+1} beta_max^2`` (0 = the paper's I_u = sum w^2 beta^2)."""
    panorama_headings: int = 0
    """Also render a panorama of I_u at the robot's position (``MemoryMaps.panorama``): this many headings evenly
    around it, the first the robot's own (0 = none). Only a memory that can render any view can show the policy
    how uncertain the directions behind and beside it are."""
    panorama_height: int = 6
    """Height of each panoramic view, pixels (subsampled from the camera's as the maps are)."""
    panorama_width: int = 8
    """Width of each panoramic view, pixels."""
    panorama_samples: int = 32
    """Samples per panoramic ray, uniform over ``[near, no_depth_range]`` of the sampler (no depth is observed in
    those directions to guide them)."""
    render_chunk: int = 1 << 16
    """Sample points per forward pass while rendering maps (bounds memory, not results)."""
    init_seed: int = 0
    """Seed of the fixed initial weights (used only when no stored initialisation is given)."""
    device: str = "cpu"
    """Torch device of the field, replay and maps: ``cpu``, ``cuda``, ``cuda:1``..."""

    def __post_init__(self):
        if self.field_type not in ("mlp", "grid"):
            raise ConfigError(None, f"memory field_type must be 'mlp' or 'grid', got {self.field_type!r}")
        for name in ("train_rays", "train_samples", "render_samples", "map_height", "map_width",
                     "update_every", "observe_every", "replay_size", "panorama_height", "panorama_width",
                     "panorama_samples"):
            if getattr(self, name) < 1:
                raise ConfigError(None, f"memory {name} must be >= 1, got {getattr(self, name)}")
        if not 0.0 <= self.newest_fraction <= 1.0:
            raise ConfigError(None, f"memory newest_fraction must lie in [0, 1], got {self.newest_fraction}")
        if self.lag < 0:
            raise ConfigError(None, f"memory lag must be >= 0, got {self.lag}")
        if self.panorama_headings < 0:
            raise ConfigError(None, f"memory panorama_headings must be >= 0, got {self.panorama_headings}")

    def replace(self, **changes) -> "MemoryConfig":
        """A copy with some fields changed (``dataclasses.replace``)."""
        return dataclasses.replace(self, **changes)

    def to_dict(self) -> dict:
        """Plain-data form for checkpoints (``MemoryConfig.from_dict`` inverts it). ``lag`` is written only when
        set, so configs from before it existed keep their exact dict (manifests, checkpoints compare dicts)."""
        d = dataclasses.asdict(self)
        if not d["lag"]:
            del d["lag"]
        if not d["panorama_headings"]:  # likewise the panorama's fields, written only when it is on
            for k in ("panorama_headings", "panorama_height", "panorama_width", "panorama_samples"):
                del d[k]
        return d

    @classmethod
    def from_dict(cls, data: dict) -> "MemoryConfig":
        d = dict(data)
        d["field"] = FieldConfig(**d.get("field", {}))
        d["sampler"] = SamplerConfig(**d.get("sampler", {}))
        d["grid"] = GridFieldConfig(**d.get("grid", {}))
        return cls(**d)


MEMORY_PRESETS: dict[str, MemoryConfig] = {
    # The authors' schedule. Their trainer ran in a background thread as fast as it could; one of
    # its iterations (10,800 rays x 64 samples, forward + backward ~ 2.1M point-forwards) costs about
    # what rendering the maps (10,800 x 192 = 2.1M point-forwards) costs the main loop each step, on
    # the same GPU, so about one iteration completes per environment step: K = 1.
    "authors": MemoryConfig(name="authors"),
    # The same field and sampling trained far longer each step: the quality yardstick. 20 iterations
    # of 1024 rays per step (2x the authors' rays and 20x their gradient steps per step); the issue's
    # "200 iterations of 10,800 rays" would cost ~200 s per step on this CPU.
    "reference": MemoryConfig(name="reference", train_rays=1024, iters_per_update=20),
    # Our default (docs/history/benchmarks.md, "NeRF memory", has the measurements behind each choice): a
    # voxel-grid field (local parameters: never-sampled space keeps near-zero density, so with
    # T_{N+1} beta_max^2 it renders as uncertain), 8 samples in +-0.3 m around the observed surface,
    # 2 iterations of 512 rays per step (a quarter from the newest frame), maps at 45 x 60.
    "fast": MemoryConfig(
        name="fast",
        field_type="grid",
        sampler=SamplerConfig(band=0.3),
        train_rays=512,
        train_samples=8,
        render_samples=8,
        map_height=45,
        map_width=60,
        iters_per_update=2,
        lr=2e-3,
        grid_lr=0.5,
        newest_fraction=0.25,
        unseen_variance=1.0,
    ),
}
MEMORY_PRESETS["fast_pano"] = MEMORY_PRESETS["fast"].replace(name="fast_pano", panorama_headings=8)
"""``fast`` with an 8-heading panorama of I_u (6 x 8 pixels each, 32 samples per ray): issue 37's panoramic uncertainty."""
MEMORY_PRESETS["lean"] = MEMORY_PRESETS["fast"].replace(
    name="lean", iters_per_update=1, train_samples=4, render_samples=4, map_height=30, map_width=40, lr=4e-3,
    grid_lr=0.75,
)
"""``fast`` at less than half its cost per step (issue 38; ``benchmarks/lean_memory.py``, table in
``benchmarks/README.md``): 1 iteration of 512 rays instead of 2, 4 samples per ray instead of 8 (training and
maps), maps at 30 x 40 instead of 45 x 60, and a larger grid step (0.75, colour MLP 4e-3) so one Adam step per
frame learns about as fast as two did early on. Measured against ``fast`` in one run: update ~2.4x, maps ~2.2x
cheaper; PSNR 2-3 dB lower in the first 30 steps and ~1.5 dB lower at step 100, AUROC of I_u within ~0.035.
A policy trained on ``fast``'s 45 x 60 maps needs retraining on its maps."""
MEMORY_PRESETS["lean_pano"] = MEMORY_PRESETS["lean"].replace(name="lean_pano", panorama_headings=8)
"""``lean`` with ``fast_pano``'s 8-heading panorama of I_u (the ``nue_pano_lean`` model's collection)."""


def get_memory(name: str | MemoryConfig | dict) -> MemoryConfig:
    """Look up a memory preset by name; a MemoryConfig passes through, a dict (``to_dict()``, e.g. from a
    manifest or checkpoint) is rebuilt exactly."""
    if isinstance(name, MemoryConfig):
        return name
    if isinstance(name, dict):
        return MemoryConfig.from_dict(name)
    try:
        return MEMORY_PRESETS[name]
    except KeyError:
        raise ConfigError(None, f"unknown memory preset {name!r}; known: {', '.join(MEMORY_PRESETS)}") from None
