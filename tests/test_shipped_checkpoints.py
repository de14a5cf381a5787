"""The checkpoints shipped in checkpoints/: they load, rebuild their model, act on a real-shaped input,
carry the provenance the README promises, and fit the 40 MB budget; every checkpoint in the repository
(also results/v*/checkpoints/) reads into a PolicyHeader that writes back the same entries."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest
import torch

from nue.policy.checkpoint import PolicyHeader, load_checkpoint, load_policy
from nue.policy.inputs import prepare_input

REPO = Path(__file__).resolve().parents[1]
ROOT = REPO / "checkpoints"
FILES = sorted(ROOT.glob("*.pt"))
ALL_FILES = FILES + sorted(REPO.glob("results/v*/checkpoints/*.pt"))


def test_the_nue_checkpoint_is_shipped_and_all_fit_40_mb():
    assert ROOT / "nue.pt" in FILES and ROOT / "fr.pt" in FILES
    assert sum(p.stat().st_size for p in FILES) <= 40 * 1024**2
    readme = (ROOT / "README.md").read_text()
    for p in FILES:
        assert f"`{p.name}`" in readme, f"{p.name} is not described in checkpoints/README.md"


@pytest.mark.parametrize("path", FILES, ids=[p.stem for p in FILES])
def test_shipped_checkpoint_loads_and_acts(path):
    model, header = load_policy(path)
    assert header.name == path.stem
    assert header.task == "paper" and re.fullmatch(r"[0-9a-f]{16}", header.manifest_hash)
    assert len(header.scenes) == 21 and all(name.startswith("train_") for name in header.scenes)
    assert re.fullmatch(r"[0-9a-f]{40}", header.git_commit)
    memory = header.memory
    cfg = model.config
    rng = np.random.default_rng(0)
    rgb = rng.integers(0, 256, (180, 240, 3), dtype=np.uint8)
    depth = rng.uniform(0.2, 4.0, (180, 240)).astype(np.float32)
    maps = (torch.rand(1, memory.map_height, memory.map_width), torch.randn(cfg.cog_channels, memory.map_height,
                                                                         memory.map_width))
    inp = prepare_input(rgb, depth, rgb, *(maps if cfg.uses_memory_maps else (None, None)), cfg)
    with torch.no_grad():
        out = model(inp, model.initial_state(1, "cpu"))
    assert out.logits.shape == (1, cfg.num_actions) and torch.isfinite(out.logits).all()


@pytest.mark.parametrize("path", ALL_FILES, ids=[str(p.relative_to(REPO)) for p in ALL_FILES])
def test_checkpoint_header_round_trips(path):
    """Checkpoints written before the header was typed read into a PolicyHeader that writes back every entry
    of the file unchanged (config fields added since then are written with their defaults)."""
    ckpt = load_checkpoint(path)
    header = PolicyHeader.from_dict(ckpt, path)
    stored = header.to_dict()
    assert _within({k: ckpt[k] for k in stored}, stored) and PolicyHeader.from_dict(stored) == header
    assert header.memory is not None and header.task == "paper" and header.model.name in path.stem


def _within(part, full) -> bool:
    """Every entry of ``part`` (nested dicts) is in ``full`` with the same value."""
    if isinstance(part, dict):
        return isinstance(full, dict) and all(k in full and _within(v, full[k]) for k, v in part.items())
    return part == full
