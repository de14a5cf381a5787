"""The collection manifest (``manifest.json``): what a demonstration folder holds, typed; a dict only in the file.

``nue collect`` writes it, and resuming compares it; ``nue train`` reads the task, memory and scenes
of its data from it, and DAgger the collection to revisit. The file is the plain JSON of
:meth:`CollectionManifest.to_dict` (format ``nue-demos/1``, keys sorted); optional entries
(``subsample_per_bin``, ``agent``, ``expert``, ``noise``) are written only when they differ from their
defaults, so manifests written before those options existed read back, and write, unchanged.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping

from nue.errors import DataError
from nue.nerf.config import MemoryConfig
from nue.policy.config import ModelConfig
from nue.train.collect_job import AgentSpec

FORMAT = "nue-demos/1"
"""Format version of ``manifest.json`` (and of the collection folder it describes)."""


@dataclass(frozen=True)
class DataLayout:
    """The input layout episode files are stored in; a model must use the same to train on them."""

    frame_size: tuple[int, int]
    """(height, width) of the RGB-D frame input, pixels."""
    map_size: tuple[int, int]
    """(height, width) of the memory maps I_u, I_cog, pixels."""
    max_depth: float
    """Depth is divided by this (metres) and clipped to [0, 1]."""
    cog_channels: int
    """Channels of I_cog."""

    @classmethod
    def of(cls, model_cfg: ModelConfig) -> "DataLayout":
        """The layout a model config reads."""
        return cls(tuple(model_cfg.frame_size), tuple(model_cfg.map_size), model_cfg.max_depth, model_cfg.cog_channels)

    def to_dict(self) -> dict:
        return {"frame_size": list(self.frame_size), "map_size": list(self.map_size), "max_depth": self.max_depth,
                "cog_channels": self.cog_channels}

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> "DataLayout":
        return cls(tuple(d["frame_size"]), tuple(d["map_size"]), d["max_depth"], d["cog_channels"])


def data_layout(model_cfg: ModelConfig) -> dict:
    """The stored input layout of a model config as the manifest writes it (``DataLayout.of(cfg).to_dict()``)."""
    return DataLayout.of(model_cfg).to_dict()


@dataclass(frozen=True)
class CollectionManifest:
    """What one collection folder holds: how its episodes were made and in which input layout."""

    task: str
    """Task preset name."""
    memory: MemoryConfig
    """The online NeRF memory the maps were rendered with (also what a policy trained on them runs)."""
    model_layout: DataLayout
    """Input layout of the stored arrays."""
    split: str
    """House split (``train``), or the split the explicit scene folders stand in for."""
    scenes: Mapping[str, str]
    """Scene name -> content hash, for every house collected in."""
    episodes_per_bin: int
    """Training episodes per difficulty bin per house."""
    heldout_per_bin: int
    """Held-out episodes per bin per house."""
    seed: int
    """Seed of episode sampling and of the episodes' own seeds."""
    subsample_per_bin: int = 0
    """Only the first k training episodes per bin were collected (0 = all)."""
    agent: AgentSpec = field(default_factory=AgentSpec)
    """Who drove: the expert, or DAgger's mix with a policy."""
    expert: str = "geodesic"
    """Which expert drove or labelled."""
    noise: float = 0.0
    """DART noise injection probability."""
    format: str = FORMAT
    """File format version."""

    def to_dict(self) -> dict:
        """The JSON form of ``manifest.json``; default-valued optional entries are left out."""
        d = {"format": self.format, "task": self.task, "memory": self.memory.to_dict(),
             "model_layout": self.model_layout.to_dict(), "split": self.split, "scenes": dict(self.scenes),
             "episodes_per_bin": self.episodes_per_bin, "heldout_per_bin": self.heldout_per_bin, "seed": self.seed}
        if self.subsample_per_bin:
            d["subsample_per_bin"] = self.subsample_per_bin
        if self.agent.kind != "expert":
            d["agent"] = self.agent.to_dict()
        if self.expert != "geodesic":
            d["expert"] = self.expert
        if self.noise:
            d["noise"] = self.noise
        return d

    @classmethod
    def from_dict(cls, d: Mapping[str, Any], path=None) -> "CollectionManifest":
        """Inverse of :meth:`to_dict`; :class:`DataError` naming ``path`` if it is not a manifest of this format."""
        if not isinstance(d, Mapping) or d.get("format") != FORMAT:
            raise DataError(path, f"not a {FORMAT} collection manifest")
        try:
            return cls(task=d["task"], memory=MemoryConfig.from_dict(d["memory"]),
                       model_layout=DataLayout.from_dict(d["model_layout"]), split=d["split"], scenes=dict(d["scenes"]),
                       episodes_per_bin=d["episodes_per_bin"], heldout_per_bin=d["heldout_per_bin"], seed=d["seed"],
                       subsample_per_bin=d.get("subsample_per_bin", 0),
                       agent=AgentSpec.from_dict(d["agent"]) if "agent" in d else AgentSpec(),
                       expert=d.get("expert", "geodesic"), noise=d.get("noise", 0.0))
        except (KeyError, TypeError, ValueError) as exc:
            raise DataError(path, f"malformed collection manifest ({type(exc).__name__}: {exc})") from None

    def hash(self) -> str:
        """sha256 (16 hex digits) of the canonical JSON of :meth:`to_dict` (stored in checkpoints)."""
        return hashlib.sha256(json.dumps(self.to_dict(), sort_keys=True).encode()).hexdigest()[:16]

    def differences(self, other: "CollectionManifest") -> list[str]:
        """Sorted names of the file entries in which the two manifests differ."""
        a, b = self.to_dict(), other.to_dict()
        return sorted(k for k in set(a) | set(b) if a.get(k) != b.get(k))


def manifest_path(folder) -> Path:
    """``folder/manifest.json``."""
    return Path(folder) / "manifest.json"


def read_manifest(folder) -> CollectionManifest:
    """The manifest of a collection folder; :class:`DataError` if it is missing or not one."""
    path = manifest_path(folder)
    if not path.is_file():
        raise DataError(path, "no manifest: not a demonstration folder (run `nue collect` first)")
    try:
        data = json.loads(path.read_text())
    except (OSError, ValueError) as exc:
        raise DataError(path, f"cannot read manifest ({type(exc).__name__})") from None
    return CollectionManifest.from_dict(data, path)


def write_manifest(folder, manifest: CollectionManifest) -> None:
    """Create ``folder/manifest.json``, or check that an existing one describes the same collection
    (:class:`DataError` naming the entries that differ)."""
    path = manifest_path(folder)
    if path.is_file():
        old = read_manifest(folder)
        if old != manifest:
            raise DataError(path, f"holds a different collection (differs in {', '.join(old.differences(manifest))}); "
                                  "use another --out")
        return
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(".tmp")
    tmp.write_text(json.dumps(manifest.to_dict(), indent=1, sort_keys=True) + "\n")
    tmp.replace(path)
