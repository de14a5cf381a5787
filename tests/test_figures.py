"""Figures 6-8 and the episode GIF: content checks (pixels where the trajectory is, arrow directions,
Grad-CAM against a reference computation), and the trace recorder on the shared agent loop."""

from __future__ import annotations

import math
from types import SimpleNamespace

import imageio.v3 as iio
import numpy as np
import pytest
import torch

from nue.viz import figures as F
from nue.viz.trace import EpisodeTrace, TraceRecorder, cog_to_rgb, pca_basis, reduce_cog

MAGENTA = np.array([255, 0, 255])


def l_path(nav):
    """A path of planning-cell centres: east along row 80 (y = -0.975), then north along column 140 (x = 2.025)."""
    cells = [(80, c) for c in range(86, 140, 2)] + [(r, 140) for r in range(80, 150, 2)]
    assert all(nav.free[c] for c in cells)
    xy = nav.cell_centre(np.array(cells))
    yaw = np.arctan2(np.gradient(xy[:, 1]), np.gradient(xy[:, 0]))
    return np.array(cells), np.c_[xy, yaw]


def i_u_maps(t_steps, h=45, w=60):
    """Structured maps whose uncertain blob moves right with time."""
    yy, xx = np.mgrid[0:h, 0:w]
    return [np.exp(-((xx - w * t / t_steps) ** 2 + (yy - h / 2) ** 2) / 40.0).astype(np.float32) for t in range(t_steps)]


def test_fig6_trajectory_pixels_fall_on_cells(box_scene, box_nav, tmp_path):
    cells, poses = l_path(box_nav)
    iu = i_u_maps(len(poses))
    steps = [0, 10, 25, 40, 61]
    fig = F.fig6_uncertainty_timeline(box_scene, poses, iu, goal_xy=(2.0, 2.0), success_radius=0.8, steps=steps,
                                      colour="#ff00ff")
    ax = fig.axes[0]
    (line,) = [ln for ln in ax.lines if ln.get_gid() == "trajectory"]
    np.testing.assert_allclose(line.get_xydata(), poses[:, :2])
    fig.canvas.draw()  # fixes the equal-aspect layout before reading transforms
    px = ax.transData.transform(box_nav.cell_centre(cells))
    wall_px = ax.transData.transform([(-1.0, -2.0)])[0]  # inside the interior wall at x = -1
    path = F.save_figure(fig, tmp_path / "fig6.png", dpi=fig.dpi)
    img = iio.imread(path)[..., :3].astype(int)
    height = img.shape[0]

    def colour_near(p, target, r=1):
        col, row = int(round(p[0])), int(round(height - p[1]))
        patch = img[row - r:row + r + 1, col - r:col + r + 1].reshape(-1, 3)
        return np.abs(patch - target).sum(axis=1).min()

    moments = {tuple(cells[s]) for s in steps}
    checked = [i for i, c in enumerate(cells) if tuple(c) not in moments and i > 2]  # the start marker covers i <= 2
    assert all(colour_near(px[i], MAGENTA) < 60 for i in checked)
    assert colour_near(wall_px, np.array([89, 89, 89]), r=0) < 6  # the map beneath is aligned: the wall is dark
    assert colour_near(ax.transData.transform([(-2.0, 2.0)])[0], MAGENTA, r=3) > 200  # off the path: no magenta
    markers = [ln for ln in ax.lines if ln.get_gid() == "moment"]
    np.testing.assert_allclose([m.get_xydata()[0] for m in markers], poses[steps, :2])
    panels = fig.axes[1:6]
    assert [a.get_title() for a in panels] == [f"$t_{j + 1}$ = step {s}" for j, s in enumerate(steps)]
    arrays = [np.asarray(a.images[0].get_array()) for a in panels]
    for j in range(5):
        np.testing.assert_array_equal(arrays[j], iu[steps[j]])
        for k in range(j):
            assert not np.array_equal(arrays[j], arrays[k])


def test_fig7_arrow_directions_and_colours(box_scene):
    t = 40
    poses = np.c_[np.linspace(-2, 2, t), np.linspace(-2.5, -0.5, t), np.linspace(0, math.pi, t)]
    true = np.linspace(-1.0, 1.0, t)
    pred = true + np.linspace(1.0, 0.0, t)
    pred[5] = np.nan  # no prediction at that step
    fig = F.fig7_goal_direction(poses, pred, true, every=5, scene=box_scene, arrow_length=0.5)
    ax = fig.axes[0]
    (qt,) = [c for c in ax.collections if c.get_gid() == "true"]
    (qp,) = [c for c in ax.collections if c.get_gid() == "predicted"]
    idx = np.arange(0, t, 5)
    np.testing.assert_allclose(qt.U, 0.5 * np.cos(poses[idx, 2] + true[idx]))
    np.testing.assert_allclose(qt.V, 0.5 * np.sin(poses[idx, 2] + true[idx]))
    np.testing.assert_allclose(np.c_[qt.X, qt.Y], poses[idx, :2])
    ok = idx != 5
    np.testing.assert_allclose(qp.U, 0.5 * np.cos(poses[idx[ok], 2] + pred[idx[ok]]))
    np.testing.assert_allclose(qp.V, 0.5 * np.sin(poses[idx[ok], 2] + pred[idx[ok]]))
    fc = qt.get_facecolor()
    assert fc[0][:3] == pytest.approx((1.0, 215 / 255, 0.0), abs=0.01)  # yellow at the start
    assert fc[-1][:3] == pytest.approx((1.0, (215 / 255) * (1 - 35 / 39), 0.0), abs=0.01)  # near red at the end
    assert np.all(np.diff(fc[:, 1]) < 0)  # green falls: yellow -> red with progress


def structured_input(cfg, seed=0):
    from nue.policy.inputs import prepare_input

    h, w = cfg.map_size
    yy, xx = np.mgrid[0:h, 0:w]
    i_u = np.where(xx > w // 2, 4.0, 0.01) + 3.0 * np.exp(-((yy - 10) ** 2 + (xx - 10) ** 2) / 20.0)
    rng = np.random.default_rng(seed)
    return prepare_input(rng.integers(0, 255, (90, 120, 3), dtype=np.uint8), rng.random((90, 120)) * 3,
                         rng.integers(0, 255, (h, w, 3), dtype=np.uint8), i_u.astype(np.float32),
                         rng.standard_normal((64, h, w)).astype(np.float32), cfg)


def reference_gradcam(model, inp, action):
    """Grad-CAM by hand (hook + autograd), to check the captum-based function against."""
    acts = {}
    layer = model.f_u.encoder[-1]
    handle = layer.register_forward_hook(lambda m, i, o: acts.setdefault("a", o))
    model.eval()
    logits = model(inp).logits
    handle.remove()
    a = acts["a"]
    (g,) = torch.autograd.grad(logits[0, action], a)
    cam = torch.relu((g.mean(dim=(2, 3), keepdim=True) * a).sum(dim=1, keepdim=True))
    return torch.nn.functional.interpolate(cam, size=inp.i_u.shape[-2:], mode="bilinear")[0, 0].detach().numpy()


def test_gradcam_uncertainty_branch():
    from nue.policy.config import get_model_config
    from nue.policy.nue_model import NUEPolicy

    cfg = get_model_config("nue")
    torch.manual_seed(1)
    model = NUEPolicy(cfg)
    model.train()
    inp = structured_input(cfg)
    cam = F.gradcam_uncertainty(model, inp)  # target: the argmax action
    assert cam.shape == cfg.map_size and cam.min() >= 0 and cam.std() > 0
    assert model.training  # mode restored
    with torch.no_grad():
        model.eval()
        action = int(model(inp).logits.argmax())
    ref = reference_gradcam(model, inp, action)
    np.testing.assert_allclose(cam, ref, rtol=1e-4, atol=1e-6 * ref.max())
    cams = [F.gradcam_uncertainty(model, inp, a) for a in range(cfg.num_actions)]
    assert not np.allclose(cams[0], cams[1]) or not np.allclose(cams[1], cams[2])
    fig = F.fig8_gradcam([inp.i_u[0, 0].numpy()] * 2, cams[:2])
    assert len(fig.axes) == 4 and all(len(a.images) >= 1 for a in fig.axes)
    with pytest.raises(ValueError, match="f_u"):
        F.gradcam_uncertainty(NUEPolicy(get_model_config("abl_none")), inp)


def make_trace(t_steps, h=45, w=60):
    poses = np.c_[np.linspace(-2, 2, t_steps), np.linspace(-2, 2, t_steps), np.full(t_steps, 0.7)]
    iu = i_u_maps(t_steps, h, w)
    rng = np.random.default_rng(0)
    return EpisodeTrace(poses=list(poses), rgb=[rng.integers(0, 255, (90, 120, 3), dtype=np.uint8) for _ in range(t_steps)],
                        i_u=iu, i_cog=[rng.random((3, h, w)).astype(np.float32) for _ in range(t_steps)],
                        aux_angle=[None] * t_steps, goal_angle=[0.0] * t_steps, actions=[0] * t_steps,
                        goal_xy=np.array([2.5, 2.5]), success_radius=0.8)


def test_gif_frame_count_and_size(box_scene, tmp_path):
    path = F.save_episode_gif(tmp_path / "ep.gif", make_trace(12), box_scene, dpi=50)
    frames = iio.imread(path, index=None)
    assert frames.shape[:3] == (12, 150, 600)  # 3 x 12 inches at 50 dpi
    assert not np.array_equal(frames[0], frames[-1])
    path = F.save_episode_gif(tmp_path / "short.gif", make_trace(30), None, max_frames=7, dpi=40)
    assert iio.imread(path, index=None).shape[:3] == (7, 120, 480)
    idx = F.frame_indices(801, 150)
    assert len(idx) == 150 and idx[0] == 0 and idx[-1] == 800 and np.all(np.diff(idx) >= 1)
    np.testing.assert_array_equal(F.frame_indices(20, 150), np.arange(20))


def test_cog_reduction():
    rng = np.random.default_rng(0)
    base = rng.standard_normal((3, 10, 12))
    mix = rng.standard_normal((64, 3))
    cog = np.einsum("ck,khw->chw", mix, base).astype(np.float32)  # rank 3
    mean, basis = pca_basis(cog)
    red = reduce_cog(cog, mean, basis)
    assert red.shape == (3, 10, 12)
    back = np.einsum("kc,khw->chw", basis, red) + mean[:, None, None]
    np.testing.assert_allclose(back, cog, atol=1e-3)  # 3 components reconstruct a rank-3 map
    np.testing.assert_array_equal(reduce_cog(cog, channels=(5, 6, 7)), cog[5:8])
    img = cog_to_rgb(red)
    assert img.shape == (10, 12, 3) and img.min() >= 0 and img.max() <= 1


class FakeMemory:
    """Maps like the NeRF memory's: i_u (1, h, w) and i_cog (64, h, w) torch tensors; None maps on odd calls if asked."""

    def __init__(self, none_every_other=False):
        self.calls, self.none_every_other = 0, none_every_other

    def reset(self, seed, start_pose, floor_z):
        self.calls = 0

    def render_maps(self, pose, depth, floor_z):
        self.calls += 1
        if self.none_every_other and self.calls % 2 == 0:
            return None
        g = torch.Generator().manual_seed(self.calls)
        return SimpleNamespace(i_u=torch.rand(1, 9, 12, generator=g), i_cog=torch.randn(64, 9, 12, generator=g))

    def step(self, rgb, depth, pose, floor_z):
        pass


def test_trace_recorder_on_the_agent_loop(box_scene, box_nav, box_renderer, tmp_path):
    from nue.policy.agent import ExpertAgent
    from nue.rollout import run_episode
    from nue.sim.env import ImageNavEnv
    from nue.sim.camera import wrap_angle
    from nue.sim.episodes import Episode

    ep = Episode.from_poses("t0", "box_room", (1.5, 1.5, math.pi), (-0.2, 1.0, 0.0), euclidean_distance=1.77,
                            geodesic_distance=0.0, difficulty="easy")
    env = ImageNavEnv(box_scene, "paper", navgrid=box_nav, renderer=box_renderer)
    rec = TraceRecorder(rgb_stride=3, aux_source=lambda s: 0.1 * s.t)
    record = run_episode(env, ExpertAgent(), episode=ep, memory=FakeMemory(none_every_other=True), on_step=rec)
    trace = rec.finish(env)
    n = record.steps
    assert len(trace) == n and len(trace.i_u) == len(trace.i_cog) == len(trace.actions) == n > 3
    np.testing.assert_allclose(trace.pose_array()[0], (1.5, 1.5, math.pi), atol=1e-6)
    np.testing.assert_allclose(trace.trajectory(), np.array(env.trajectory), atol=1e-5)
    assert trace.rgb[0].shape == (60, 80, 3) and trace.rgb[0].dtype == np.uint8
    assert trace.i_u[0].shape == (9, 12) and trace.i_u[1] is None
    assert trace.i_cog[0].shape == (3, 9, 12) and trace.i_cog[1] is None
    assert trace.aux_array()[3] == pytest.approx(0.3)
    assert trace.goal_angle[0] == pytest.approx(wrap_angle(math.atan2(1.0 - 1.5, -0.2 - 1.5) - math.pi), abs=1e-6)
    assert trace.goal_xy.tolist() == [-0.2, 1.0] and trace.success_radius == 0.8
    # the same trace drives the figures, None maps included
    fig = F.fig6_uncertainty_timeline(box_scene, trace.trajectory(), trace.i_u + [None], trace.goal_xy,
                                      trace.success_radius)
    F.save_figure(fig, tmp_path / "f6.png")
    path = F.save_episode_gif(tmp_path / "t.gif", trace, box_scene, dpi=30)
    assert iio.imread(path, index=None).shape[0] == n
    # without memory: no maps at all
    rec2 = TraceRecorder()
    run_episode(env, ExpertAgent(), episode=ep, on_step=rec2)
    assert all(u is None for u in rec2.trace.i_u) and all(a is None for a in rec2.trace.aux_angle)
