"""Model configs as data: one ``ModelConfig`` per policy, with the paper's ablations and baselines as presets.

A config fully decides the architecture (``build_model(config)`` is deterministic given the torch
seed), so a checkpoint stores ``config.to_dict()`` and rebuilds the same network from it.

Presets (paper Table I; ``f_u`` = uncertainty branch, ``AT`` = auxiliary goal-angle task):

==============  =====  =====  =====  ==========================================
preset          f_u    AT     CBAM   note
==============  =====  =====  =====  ==========================================
``abl_none``    no     no     no     first ablation row
``abl_fu``      yes    no     no
``abl_at_cbam`` no     yes    yes
``abl_fu_cbam`` yes    no     yes
``abl_fu_at``   yes    yes    no
``nue``         yes    yes    yes    full model (last row); the goal also enters f_p (``goal_in_perception``)
``nue_paper``   yes    yes    yes    full model in the paper's layout (goal only through f_cog)
``fr``          --     no     --     fully reactive: RGB-D + goal -> CNN -> policy
``nav_a3c``     --     no     --     same encoder as ``fr`` + LSTM memory
``nrns``        --     no     --     NRNS's distance network (``fr``'s encoder + offset); acts through a graph
``vgm``         --     no     --     Visual Graph Memory (Kwon et al. 2021): graph of view embeddings + LSTM
==============  =====  =====  =====  ==========================================

The five ``abl_*`` rows are ``nue`` with components switched off, so they also feed the goal to f_p:
an ablation differs from the full model only in what Table I switches. A checkpoint keeps its own model config,
so one whose ablation was built on the paper's layout (the v1 rows of ``results/v1/checkpoints``) loads unchanged.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any

from nue.errors import ConfigError
from nue.sim.task import TaskConfig

MODEL_KINDS = ("nue", "fr", "nav_a3c", "nrns", "vgm")

VGM_FIELDS = ("embed_dim", "embed_channels", "embed_grid", "graph_nodes", "graph_threshold", "memory_dim", "gcn_layers",
              "attention_heads", "embed_steps", "embed_batch", "embed_temperature", "embed_window", "embed_lr")
"""Fields of kind ``vgm`` only; :meth:`ModelConfig.to_dict` writes them for that kind alone, so the configs of the
other models keep their exact dict."""


@dataclass(frozen=True)
class ModelConfig:
    """Architecture of one policy network (NUE, an ablation of it, or a baseline)."""

    name: str = "nue"
    """Preset name, recorded in checkpoints and result tables."""
    kind: str = "nue"
    """Model family: ``nue`` (NeRF-memory policy), ``fr`` (fully reactive), ``nav_a3c`` (CNN + LSTM), ``nrns`` (the
    distance network of NRNS's graph agent, :mod:`nue.policy.nrns_agent`; trained by :mod:`nue.train.nrns_train`) or
    ``vgm`` (visual graph memory, :mod:`nue.policy.vgm_model`)."""
    use_uncertainty: bool = True
    """NUE only: include the exploration branch f_u on the uncertainty map I_u."""
    use_aux: bool = True
    """Include the auxiliary head predicting the goal angle (NUE: from f_cog; baselines: from the policy feature)."""
    use_cbam: bool = True
    """NUE only: CBAM attention after the residual blocks of f_u and f_cog."""
    goal_in_perception: bool = False
    """NUE only: the goal image also enters f_p, stacked with the live RGB-D frame in its first layer at frame
    size (as FR does), so NUE has FR's map-free pathway; f_cog still gets the goal at map size. False is the
    paper's layout (the goal enters only through f_cog)."""
    num_actions: int = 3
    """Number of discrete actions; take it from the task preset with :meth:`for_task`."""

    map_height: int = 45
    """Height h of the NeRF maps I_u and I_cog (and of the goal image fed to f_cog)."""
    map_width: int = 60
    """Width w of the NeRF maps."""
    cog_channels: int = 64
    """Channels of the feature map I_cog rendered by the NeRF memory."""
    frame_height: int = 90
    """Height of the live RGB-D frame fed to f_p (and, for baselines, of the goal image)."""
    frame_width: int = 120
    """Width of the live RGB-D frame fed to f_p."""
    max_depth: float = 5.0
    """Depth enters as ``clip(depth, 0, max_depth) / max_depth``, metres."""
    uncertainty_scale: float = 1.0
    """I_u (a rendered variance, >= 0, wide dynamic range) enters f_u as ``log1p(I_u / uncertainty_scale)``."""

    uncertainty_channels: tuple[int, ...] = (8, 16)
    """Output channels of the residual blocks of f_u (each halves the resolution); the paper's F_u has 16."""
    cognition_channels: tuple[int, ...] = (32, 32)
    """Output channels of the residual blocks of f_cog (each halves the resolution)."""
    map_grid: tuple[int, int] = (6, 8)
    """Fixed (rows, cols) grid the map branches pool to before CBAM, so any map size works (~h/16 at 90 x 120)."""
    branch_dim: int = 64
    """Length of the branch vectors f_u and f_cog (paper: 64)."""
    cbam_reduction: int = 4
    """Channel-attention MLP hidden size is ``channels // cbam_reduction`` (at least 1)."""
    cbam_kernel: int = 3
    """Spatial-attention conv kernel. CBAM uses 7 on large maps; on the 6 x 8 grid 3 keeps it local."""

    perception_channels: tuple[int, ...] = (16, 32, 32)
    """Output channels of the residual blocks of the frame encoder (f_p, and the baselines' encoder)."""
    perception_grid: tuple[int, int] = (6, 8)
    """Fixed (rows, cols) grid the frame encoder pools to before its MLP."""
    perception_dim: int = 256
    """Length of the perception vector f_p (authors: 256); also the baselines' feature length."""

    gate_hidden: int = 128
    """Hidden width of the fusion attention MLP giving w = sigmoid(MLP(f_cat1)) (eq. 13)."""
    fusion_dim: int = 256
    """Length of f_cat2 = MLP(w * f_cat1)."""
    head_hidden: int = 128
    """Hidden width of the action head MLP(f_cat2) -> logits (eq. 14)."""
    aux_hidden: int = 64
    """Hidden width of the 2-layer auxiliary angle head."""
    lstm_dim: int = 256
    """Nav-A3C and VGM: LSTM hidden size."""
    panorama_dim: int = 0
    """NUE only: length of the vector f_pano = MLP(log1p(panorama / uncertainty_scale)) of the memory's I_u panorama
    (``MemoryMaps.panorama``, memory presets with ``panorama_headings``), joined to f_cat1 (0 = no panorama)."""
    panorama_shape: tuple[int, int, int] = (8, 6, 8)
    """(headings, height, width) of the panorama the model reads (the memory preset's; used with ``panorama_dim``)."""
    gru_dim: int = 0
    """NUE only: hidden size of a GRU between the fusion (f_cat2) and the action head, carrying a state across
    steps (0 = none, the paper's reactive fusion)."""
    goal_head: bool = False
    """NUE only: an exploitation head on f_cog, ``MLP(f_cog) -> (goal-in-view logit, log goal distance)``, trained on
    the exploring expert's own switch test (the goal's floor seen within 3 m) and the robot's distance to the goal;
    the ``commit+`` wrapper (:mod:`nue.policy.commit`) reads it at decision time."""
    goal_match: int = 0
    """NUE only: length of the goal-view matching vector f_match (:mod:`nue.policy.goal_match`: a shared CNN on the RGB
    frame and the goal photo, cosine correlation of the goal's embedding with the frame's cells), joined to f_cat1 and
    to the exploitation head's input (0 = none). Needs the goal at frame size (``goal_in_perception``)."""
    negative_slope: float = 0.01
    """Slope of every LeakyReLU."""

    # --- VGM only (kind ``vgm``; see :mod:`nue.policy.vgm_model` and docs/vgm.md) ---------------------------------
    embed_dim: int = 128
    """VGM: length of the L2-normalised view embedding (node features, localisation, goal); VGM's is 512."""
    embed_channels: tuple[int, ...] = (16, 32, 32)
    """VGM: residual-block channels of the embedding network (RGB in; trained contrastively, then frozen)."""
    embed_grid: tuple[int, int] = (3, 4)
    """VGM: (rows, cols) grid the embedding network pools to before its MLP."""
    graph_nodes: int = 100
    """VGM: node capacity of the graph (VGM's memory size); when full, a view below the threshold is localised to its
    most similar node instead of adding one."""
    graph_threshold: float = 0.75
    """VGM: a view whose embedding has cosine similarity below this to every node becomes a new node (VGM: 0.75);
    above 1, every view becomes a node (until the graph is full)."""
    memory_dim: int = 128
    """VGM: width of the graph convolution and of the attention read-outs."""
    gcn_layers: int = 2
    """VGM: graph-convolution layers over the goal-fused node features (VGM: 3)."""
    attention_heads: int = 4
    """VGM: heads of each attention read-out (VGM: 4); must divide ``memory_dim``."""
    embed_steps: int = 300
    """VGM: optimiser steps of the contrastive pre-training of the embedding network at the start of ``nue train``
    (no labels; 0 = none, the embedding stays at its random initialisation)."""
    embed_batch: int = 64
    """VGM: anchor frames per contrastive step (each with one positive; 2 x this many views)."""
    embed_temperature: float = 0.1
    """VGM: temperature of the InfoNCE loss."""
    embed_window: int = 3
    """VGM: a frame's positive is an augmented frame at most this many steps away in the same demonstration."""
    embed_lr: float = 1e-3
    """VGM: AdamW learning rate of the contrastive pre-training."""

    def __post_init__(self) -> None:
        where = f"model config {self.name!r}"
        if self.kind not in MODEL_KINDS:
            raise ConfigError(where, f"unknown kind {self.kind!r}; known: {', '.join(MODEL_KINDS)}")
        if self.kind != "nue" and (self.use_uncertainty or self.use_cbam or self.goal_in_perception):
            raise ConfigError(where, f"use_uncertainty / use_cbam / goal_in_perception apply to kind 'nue' only, "
                                     f"not {self.kind!r}")
        if self.kind == "nrns" and self.use_aux:
            raise ConfigError(where, "kind 'nrns' has no auxiliary angle head (use_aux must be False)")
        if self.num_actions < 2:
            raise ConfigError(where, f"num_actions must be >= 2, got {self.num_actions}")
        sizes = (self.map_height, self.map_width, self.frame_height, self.frame_width, *self.map_grid,
                 *self.perception_grid, self.cog_channels, self.branch_dim, self.perception_dim)
        if min(sizes) < 1:
            raise ConfigError(where, "sizes, grids and widths must be positive")
        if not (self.uncertainty_channels and self.cognition_channels and self.perception_channels):
            raise ConfigError(where, "each encoder needs at least one residual block")
        if self.cbam_kernel % 2 != 1:
            raise ConfigError(where, f"cbam_kernel must be odd, got {self.cbam_kernel}")
        if self.panorama_dim < 0 or (self.panorama_dim and self.kind != "nue") or min(self.panorama_shape) < 1:
            raise ConfigError(where, f"panorama_dim must be >= 0 and applies to kind 'nue' only, got {self.panorama_dim}")
        if self.gru_dim < 0 or (self.gru_dim and self.kind != "nue"):
            raise ConfigError(where, f"gru_dim must be >= 0 and applies to kind 'nue' only, got {self.gru_dim}")
        if self.goal_match < 0 or (self.goal_match and (self.kind != "nue" or not self.goal_in_perception)):
            raise ConfigError(where, f"goal_match must be >= 0 and applies to kind 'nue' with goal_in_perception only, "
                                     f"got {self.goal_match}")
        if self.goal_head and self.kind != "nue":
            raise ConfigError(where, f"goal_head applies to kind 'nue' only, not {self.kind!r}")
        if self.max_depth <= 0 or self.uncertainty_scale <= 0:
            raise ConfigError(where, "max_depth and uncertainty_scale must be positive")
        if self.kind == "vgm":
            if min(self.embed_dim, self.graph_nodes, self.memory_dim, self.gcn_layers, self.attention_heads,
                   self.embed_batch, self.embed_window, *self.embed_grid) < 1 or not self.embed_channels:
                raise ConfigError(where, "VGM sizes (embed_dim, graph_nodes, memory_dim, gcn_layers, attention_heads, "
                                         "embed_batch, embed_window, embed_grid) must be positive")
            if self.embed_dim % 2:
                raise ConfigError(where, f"embed_dim must be even (its time encoding), got {self.embed_dim}")
            if self.memory_dim % self.attention_heads:
                raise ConfigError(where, f"attention_heads {self.attention_heads} must divide memory_dim {self.memory_dim}")
            if not -1.0 <= self.graph_threshold or self.embed_temperature <= 0 or self.embed_steps < 0:
                raise ConfigError(where, "graph_threshold must be >= -1, embed_temperature positive and "
                                         "embed_steps >= 0")

    # --- what the model reads -------------------------------------------------------------------
    @property
    def uses_i_u(self) -> bool:
        """The model reads the uncertainty map I_u (so the memory must render it)."""
        return self.kind == "nue" and self.use_uncertainty

    @property
    def uses_panorama(self) -> bool:
        """The model reads the memory's I_u panorama (so the memory preset must render one)."""
        return self.kind == "nue" and self.panorama_dim > 0

    @property
    def uses_i_cog(self) -> bool:
        """The model reads the feature map I_cog."""
        return self.kind == "nue"

    @property
    def uses_memory_maps(self) -> bool:
        """The model needs the NeRF memory at all (False for the baselines)."""
        return self.uses_i_u or self.uses_i_cog

    @property
    def map_size(self) -> tuple[int, int]:
        """(h, w) of I_u and I_cog."""
        return (self.map_height, self.map_width)

    @property
    def frame_size(self) -> tuple[int, int]:
        """(h, w) of the RGB-D frame the model reads."""
        return (self.frame_height, self.frame_width)

    @property
    def goal_size(self) -> tuple[int, int]:
        """(h, w) of the goal image the model reads: the map size for the paper's NUE (it joins I_cog only), else
        the frame size (baselines, and NUE with ``goal_in_perception``, whose f_cog area-resizes it to map size)."""
        return self.map_size if self.kind == "nue" and not self.goal_in_perception else self.frame_size

    @property
    def recurrent(self) -> bool:
        """The model carries a state across steps (Nav-A3C, VGM, NUE with a GRU)."""
        return self.kind in ("nav_a3c", "vgm") or self.gru_dim > 0

    @property
    def pretrains_embedding(self) -> bool:
        """``nue train`` first trains the model's embedding network contrastively (VGM with ``embed_steps > 0``)."""
        return self.kind == "vgm" and self.embed_steps > 0

    # --- derived configs and serialisation ------------------------------------------------------
    def for_task(self, task: TaskConfig) -> "ModelConfig":
        """This config with ``num_actions`` taken from a task preset."""
        return dataclasses.replace(self, num_actions=len(task.actions))

    def replace(self, **changes: Any) -> "ModelConfig":
        """A copy with some fields changed (validated again)."""
        return dataclasses.replace(self, **changes)

    def to_dict(self) -> dict[str, Any]:
        """Plain-data form for checkpoints and JSON (tuples become lists). ``gru_dim``, the panorama's fields,
        ``goal_head`` and ``goal_match`` are written only when set, and :data:`VGM_FIELDS` only for kind ``vgm``, so
        configs from before they existed keep their exact dict."""
        d = {k: list(v) if isinstance(v, tuple) else v for k, v in dataclasses.asdict(self).items()}
        if not d["gru_dim"]:
            del d["gru_dim"]
        if not d["panorama_dim"]:  # likewise the panorama's fields
            del d["panorama_dim"], d["panorama_shape"]
        if not d["goal_head"]:
            del d["goal_head"]
        if not d["goal_match"]:
            del d["goal_match"]
        if self.kind != "vgm":
            for k in VGM_FIELDS:
                del d[k]
        return d

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> "ModelConfig":
        """Inverse of :meth:`to_dict`; unknown keys are an error."""
        names = {f.name: f for f in dataclasses.fields(cls)}
        unknown = set(data) - set(names)
        if unknown:
            raise ConfigError("model config", f"unknown field(s): {', '.join(sorted(unknown))}")
        fields: dict[str, Any] = {k: tuple(v) if isinstance(v, list) else v for k, v in data.items()}
        return cls(**fields)


GRU_DIM = 256
"""Units of the recurrent state of ``nue_gru`` and the ``abl_*_gru`` ablations."""

_NUE = ModelConfig(goal_in_perception=True)
"""The full model as trained here (the goal also enters f_p); the ablations switch its components off."""

MODEL_PRESETS: dict[str, ModelConfig] = {
    "nue": _NUE,
    "nue_paper": _NUE.replace(name="nue_paper", goal_in_perception=False),
    "nue_gru": _NUE.replace(name="nue_gru", gru_dim=GRU_DIM),
    "nue_pano": _NUE.replace(name="nue_pano", panorama_dim=32),
    "nue_pano_gru": _NUE.replace(name="nue_pano_gru", panorama_dim=32, gru_dim=256),
    "nue_goal": _NUE.replace(name="nue_goal", goal_head=True),
    "nue_match": _NUE.replace(name="nue_match", goal_head=True, goal_match=32),
    "abl_none": _NUE.replace(name="abl_none", use_uncertainty=False, use_aux=False, use_cbam=False),
    "abl_fu": _NUE.replace(name="abl_fu", use_uncertainty=True, use_aux=False, use_cbam=False),
    "abl_at_cbam": _NUE.replace(name="abl_at_cbam", use_uncertainty=False, use_aux=True, use_cbam=True),
    "abl_fu_cbam": _NUE.replace(name="abl_fu_cbam", use_uncertainty=True, use_aux=False, use_cbam=True),
    "abl_fu_at": _NUE.replace(name="abl_fu_at", use_uncertainty=True, use_aux=True, use_cbam=False),
    "fr": _NUE.replace(name="fr", kind="fr", use_uncertainty=False, use_aux=False, use_cbam=False,
                        goal_in_perception=False),
    "nav_a3c": _NUE.replace(name="nav_a3c", kind="nav_a3c", use_uncertainty=False, use_aux=False, use_cbam=False,
                        goal_in_perception=False),
    "nrns": _NUE.replace(name="nrns", kind="nrns", use_uncertainty=False, use_aux=False, use_cbam=False,
                         goal_in_perception=False),
    "vgm": _NUE.replace(name="vgm", kind="vgm", use_uncertainty=False, use_aux=False, use_cbam=False,
                        goal_in_perception=False),
}
ABLATION_PRESETS: tuple[str, ...] = ("abl_none", "abl_fu", "abl_at_cbam", "abl_fu_cbam", "abl_fu_at")
"""The paper's five ablation rows, in Table I order."""

LEAN_MAP_SIZE: tuple[int, int] = (30, 40)
"""(h, w) of the ``lean`` memory preset's maps (:mod:`nue.nerf.config`)."""

MODEL_PRESETS.update({f"{m}_gru": MODEL_PRESETS[m].replace(name=f"{m}_gru", gru_dim=GRU_DIM) for m in ABLATION_PRESETS})
MODEL_PRESETS.update({f"{m}_lean": MODEL_PRESETS[m].replace(name=f"{m}_lean", map_height=LEAN_MAP_SIZE[0],
                                                             map_width=LEAN_MAP_SIZE[1])
                      for m in ("nue", "nue_gru", "nue_pano", "nue_pano_gru", *ABLATION_PRESETS,
                                *(f"{a}_gru" for a in ABLATION_PRESETS))})
"""Named model configs. The five ``abl_*`` rows and ``nue`` are paper Table I's ablation block. ``nue_gru`` is NUE
with a recurrent state after the fusion; each ``abl_*_gru`` is an ablation with the same state, the ablation block of
a recurrent NUE (the ablated components are switched off, the state kept). Each of these, ``nue_pano`` and
``nue_pano_gru``, also has a ``<name>_lean`` twin that reads the ``lean`` memory preset's 30 x 40 maps (collect with
``--memory lean``, or ``lean_pano`` for ``nue_pano_lean`` and ``nue_pano_gru_lean``; issue 38); the baselines read no maps and train on any collection."""


def get_model_config(name: str | ModelConfig) -> ModelConfig:
    """Look up a model preset by name (a ModelConfig passes through)."""
    if isinstance(name, ModelConfig):
        return name
    try:
        return MODEL_PRESETS[name]
    except KeyError:
        raise ConfigError(None, f"unknown model preset {name!r}; known: {', '.join(MODEL_PRESETS)}") from None
