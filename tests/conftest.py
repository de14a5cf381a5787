"""Shared fixtures: the hand-written box room, its loaded scene/navgrid/renderer, one torch thread."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

os.environ.setdefault("LP_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

FIXTURES = Path(__file__).parent / "fixtures"
BOX_ROOM = FIXTURES / "box_room"


@pytest.fixture(scope="session", autouse=True)
def _one_torch_thread():
    try:
        import torch

        torch.set_num_threads(1)
    except ImportError:  # pragma: no cover
        pass


@pytest.fixture(scope="session")
def box_scene():
    from nue.scene.scene import Scene

    return Scene.load(BOX_ROOM)


@pytest.fixture(scope="session")
def box_nav(box_scene):
    from nue.scene.navgrid import NavGrid

    return NavGrid.from_scene(box_scene)


@pytest.fixture(scope="session")
def box_renderer(box_scene):
    from nue.sim.renderer import Renderer

    return Renderer(box_scene)
