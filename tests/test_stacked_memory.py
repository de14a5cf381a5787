"""StackedMemory: B episodes' memories side by side agree with one OnlineNeRF each; slots are independent."""

from __future__ import annotations

import pytest
import torch

from nue.errors import ConfigError
from nue.nerf import MemoryInputError, OnlineNeRF, get_memory
from nue.nerf.slots import StackedSlot
from nue.nerf.stacked import StackedMemory
from nue.sim.task import CameraConfig

from .nerf_box_room import box_room_frame, box_room_trajectory

torch.set_num_threads(1)

CAMERA = CameraConfig()
SMALL = get_memory("fast").replace(map_height=24, map_width=32)
TOL = 1e-5
"""Largest absolute difference allowed between a slot's maps and an OnlineNeRF's with the same seed and frames
(the batched matmuls may round differently from the single ones; on the CPU this was written on they are equal
bit for bit, difference 0)."""
KEYS = ("i_u", "i_cog", "rgb", "depth", "transmittance")


@pytest.fixture(scope="module")
def frames():
    return [box_room_frame(p, CAMERA) + (p,) for p in box_room_trajectory(24)]


def max_diff(a, b) -> dict[str, float]:
    out = {k: float((getattr(a, k) - getattr(b, k)).abs().max()) for k in KEYS}
    if a.panorama is not None or b.panorama is not None:
        out["panorama"] = float((a.panorama - b.panorama).abs().max())
    return out


def test_slots_match_one_online_nerf_each(frames):
    """Three slots with their own seeds and frames: slot 0 from step 0, slot 1 joins at step 2, slot 2 is reset
    with a new seed at step 4 (its episode ended); each slot's maps equal its own OnlineNeRF's within TOL."""
    stacked = StackedMemory(SMALL, 3, CAMERA)
    refs = [OnlineNeRF(SMALL, CAMERA) for _ in range(3)]
    start = {0: 0, 1: 2, 2: 0}  # step at which each slot's (first) episode starts
    seeds = {0: 11, 1: 12, 2: 13}
    worst = dict.fromkeys(KEYS, 0.0)
    changed = False
    for t in range(9):
        if t == 4:  # slot 2's episode ends, a new one starts in its slot
            start[2], seeds[2] = 4, 99
        active = [i for i in range(3) if t >= start[i]]
        for i in active:
            if t == start[i]:
                pose = frames[5 * i][2]
                stacked.reset_slot(i, seeds[i], pose, 0.0)
                refs[i].reset(seeds[i], pose, 0.0)
        fr = {i: frames[(5 * i + t - start[i]) % len(frames)] for i in active}
        got = stacked.render_maps(active, [fr[i][2] for i in active], [fr[i][1] for i in active], [0.0] * len(active))
        for i, maps in zip(active, got):
            want = refs[i].render_maps(fr[i][2], fr[i][1])
            for k, v in max_diff(maps, want).items():
                worst[k] = max(worst[k], v)
            changed |= bool(float(maps.i_u.mean()) < 0.9)  # the memory learns (I_u of unseen space is ~1)
        stacked.step(active, [fr[i][0] for i in active], [fr[i][1] for i in active], [fr[i][2] for i in active],
                     [0.0] * len(active))
        for i in active:
            refs[i].step(fr[i][0], fr[i][1], fr[i][2])
    assert changed
    assert all(v <= TOL for v in worst.values()), worst
    assert stacked.replay_len(2) == refs[2].replay_len == 5


def test_unlisted_slots_do_not_change(frames):
    stacked = StackedMemory(SMALL, 3, CAMERA)
    for i in range(3):
        stacked.reset_slot(i, i, frames[0][2])
    rgb, depth, pose = frames[0]
    stacked.step([1], [rgb], [depth], [pose])
    before = stacked.render_maps([1], [pose], [depth])[0]
    table = stacked.table[stacked.rows_per_slot : 2 * stacked.rows_per_slot].detach().clone()
    for rgb, depth, pose in frames[1:4]:  # slots 0 and 2 train; slot 1 is left alone
        stacked.render_maps([2, 0], [pose, pose], [depth, depth])
        stacked.step([2, 0], [rgb, rgb], [depth, depth], [pose, pose])
    after = stacked.render_maps([1], [frames[0][2]], [frames[0][1]])[0]
    assert all(v == 0.0 for v in max_diff(before, after).values())
    assert torch.equal(table, stacked.table[stacked.rows_per_slot : 2 * stacked.rows_per_slot])
    assert stacked.replay_len(1) == 1 and stacked.replay_len(0) == 3
    # slots 0 and 2 had the same frames but their own seeds: they drew different rays
    m0, m2 = stacked.render_maps([0, 2], [pose, pose], [depth, depth])
    assert float((m0.rgb - m2.rgb).abs().max()) > 1e-4


def test_panorama_per_slot(frames):
    cfg = get_memory("fast_pano").replace(map_height=12, map_width=16)
    stacked = StackedMemory(cfg, 2, CAMERA)
    refs = [OnlineNeRF(cfg, CAMERA) for _ in range(2)]
    for i in range(2):
        stacked.reset_slot(i, i, frames[8 * i][2])
        refs[i].reset(i, frames[8 * i][2])
    for t in range(3):
        fr = [frames[8 * i + t] for i in range(2)]
        got = stacked.render_maps([0, 1], [f[2] for f in fr], [f[1] for f in fr])
        for i in range(2):
            want = refs[i].render_maps(fr[i][2], fr[i][1])
            assert got[i].panorama is not None and got[i].panorama.shape == (8, 6, 8)
            assert max(max_diff(got[i], want).values()) <= TOL
        stacked.step([0, 1], [f[0] for f in fr], [f[1] for f in fr], [f[2] for f in fr])
        for i in range(2):
            refs[i].step(*fr[i])
    assert float((got[0].panorama - got[1].panorama).abs().max()) > 1e-3  # each slot its own view


def test_slot_memory_adapter_is_one_episode_memory(frames):
    """StackedSlot has OnlineNeRF's reset / render_maps / step and gives its maps."""
    mem, ref = StackedSlot(StackedMemory(SMALL, 2, CAMERA), 1), OnlineNeRF(SMALL, CAMERA)
    mem.reset(5, frames[0][2], 0.0)
    ref.reset(5, frames[0][2], 0.0)
    for rgb, depth, pose in frames[:4]:
        a, b = mem.render_maps(pose, depth, 0.0), ref.render_maps(pose, depth, 0.0)
        assert max(max_diff(a, b).values()) <= TOL
        mem.step(rgb, depth, pose, 0.0)
        ref.step(rgb, depth, pose, 0.0)
    assert mem.replay_len == 4 and mem.stacked.replay_len(0) == 0


def test_stored_initialisation_is_used(frames):
    other = OnlineNeRF(SMALL.replace(init_seed=3), CAMERA)
    stacked = StackedMemory(SMALL, 1, CAMERA, init_state=other.initial_state())
    other.reset(0)
    rgb, depth, pose = frames[0]
    other.step(rgb, depth, pose)
    stacked.step([0], [rgb], [depth], [pose])
    assert max(max_diff(stacked.render_maps([0], [pose], [depth])[0], other.render_maps(pose, depth)).values()) <= TOL


def test_bad_use_is_rejected(frames):
    with pytest.raises(ConfigError, match="field_type grid"):
        StackedMemory("authors", 2, CAMERA)
    with pytest.raises(ConfigError, match="at least one slot"):
        StackedMemory(SMALL, 0, CAMERA)
    stacked = StackedMemory(SMALL, 2, CAMERA)
    rgb, depth, pose = frames[0]
    with pytest.raises(MemoryInputError, match="out of range"):
        stacked.reset_slot(2, 0)
    with pytest.raises(MemoryInputError, match="twice"):
        stacked.render_maps([0, 0], [pose, pose], [depth, depth])
    with pytest.raises(MemoryInputError, match="inputs"):
        stacked.step([0, 1], [rgb], [depth], [pose])


def test_chunking_does_not_change_the_maps(frames):
    """Slots rendered in one query, one by one, or in chunks of a slot's rays, and trained together or one by one,
    give the same maps."""
    mems = [StackedMemory(SMALL, 2, CAMERA, render_points=p, train_points=q)
            for p, q in ((1 << 16, None), (24 * 32 * 8, 1), (1000, 512 * 8))]
    for rgb, depth, pose in frames[:2]:
        for m in mems:
            m.step([0, 1], [rgb, rgb], [depth, depth], [pose, pose])
    rgb, depth, pose = frames[2]
    got = [m.render_maps([1, 0], [pose, pose], [depth, depth]) for m in mems]
    for other in got[1:]:
        for a, b in zip(got[0], other):
            assert max(max_diff(a, b).values()) <= TOL


def test_lag_and_schedule_per_slot(frames):
    """With a memory lag and a sparser schedule each slot still follows OnlineNeRF's step for step."""
    cfg = SMALL.replace(lag=2, observe_every=2, update_every=3)
    stacked, refs = StackedMemory(cfg, 2, CAMERA), [OnlineNeRF(cfg, CAMERA) for _ in range(2)]
    for i in range(2):
        refs[i].reset(i)
        stacked.reset_slot(i, i)
    for t in range(7):
        fr = [frames[t], frames[10 + t]]
        if t == 3:  # slot 1 sits this step out (e.g. its env is between episodes)
            stacked.step([0], [fr[0][0]], [fr[0][1]], [fr[0][2]])
            refs[0].step(*fr[0])
            continue
        stacked.step([1, 0], [fr[1][0], fr[0][0]], [fr[1][1], fr[0][1]], [fr[1][2], fr[0][2]])
        for i in range(2):
            refs[i].step(*fr[i])
    rgb, depth, pose = frames[20]
    for i, maps in enumerate(stacked.render_maps([0, 1], [pose, pose], [depth, depth])):
        assert max(max_diff(maps, refs[i].render_maps(pose, depth)).values()) <= TOL
        assert stacked.replay_len(i) == refs[i].replay_len
