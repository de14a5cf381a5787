"""The checkpoints shipped in checkpoints/: they load, rebuild their model, act on a real-shaped input,
carry the provenance the README promises, and fit the 20 MB budget."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest
import torch

from nue.nerf.config import MemoryConfig
from nue.policy.inputs import prepare_input
from nue.train.checkpoint import load_policy

ROOT = Path(__file__).resolve().parents[1] / "checkpoints"
FILES = sorted(ROOT.glob("*.pt"))


def test_the_nue_checkpoint_is_shipped_and_all_fit_20_mb():
    assert ROOT / "nue.pt" in FILES and ROOT / "fr.pt" in FILES
    assert sum(p.stat().st_size for p in FILES) <= 20 * 1024**2
    readme = (ROOT / "README.md").read_text()
    for p in FILES:
        assert f"`{p.name}`" in readme, f"{p.name} is not described in checkpoints/README.md"


@pytest.mark.parametrize("path", FILES, ids=[p.stem for p in FILES])
def test_shipped_checkpoint_loads_and_acts(path):
    model, ckpt = load_policy(path)
    assert ckpt["model_config"]["name"] == path.stem
    assert ckpt["task"]["name"] == "paper" and re.fullmatch(r"[0-9a-f]{16}", ckpt["manifest_hash"])
    assert len(ckpt["scenes"]) == 21 and all(name.startswith("train_") for name in ckpt["scenes"])
    assert re.fullmatch(r"[0-9a-f]{40}", ckpt["git_commit"])
    memory = MemoryConfig.from_dict(ckpt["memory"])
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
