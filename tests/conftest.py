"""Shared fixtures: the hand-written box room, its loaded scene/navgrid/renderer, one torch thread; ``nue_here``
runs a command line in the test process."""

from __future__ import annotations

import contextlib
import io
import os
import subprocess
from pathlib import Path
from unittest import mock

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


def nue_here(*args, env: dict[str, str] | None = None) -> subprocess.CompletedProcess:
    """``nue ARGS`` in this process: ``nue.cli.main``, what the console script runs, without the few seconds of
    a new interpreter importing torch. Returns what ``subprocess.run(..., capture_output=True, text=True)`` would
    (exit status, stdout, stderr); ``env``: environment variables set for the call."""
    from nue.cli import main

    argv = [str(a) for a in args]
    out, err = io.StringIO(), io.StringIO()
    with mock.patch.dict(os.environ, env or {}), contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        try:
            main(argv)
            code = 0
        except SystemExit as exc:
            code = exc.code if isinstance(exc.code, int) else (0 if exc.code is None else 1)
    return subprocess.CompletedProcess(["nue", *argv], code, out.getvalue(), err.getvalue())


@pytest.fixture
def local_ray():
    """A local 2-CPU Ray cluster for one test (skipped without Ray), shut down after it. Ray gives its node a fixed
    30 s to register, which a loaded machine can miss: ``ray.init`` is retried, and the test skipped (naming the
    cause) if the node never starts."""
    ray = pytest.importorskip("ray", reason="Ray is not installed (pip install 'nue[ray]')")
    attempts = 3
    for _ in range(attempts):
        try:
            ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False)
            break
        except Exception as exc:  # Ray raises a bare Exception for "node timed out during startup"
            ray.shutdown()
            if "timed out during startup" not in str(exc):
                raise
    else:
        pytest.skip(f"a local Ray node did not start within {attempts} x 30 s (machine overloaded)")
    try:
        yield ray
    finally:
        ray.shutdown()
