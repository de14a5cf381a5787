"""The memories of B lock-step slots behind one interface (:class:`nue.rollout.SlotMemory`): each call covers a
list of slots at once.

:class:`MemoryList` holds B separate :class:`~nue.nerf.online.OnlineNeRF` memories and calls them one by one:
each slot's maps and updates are exactly those of a memory used alone. A stacked memory (one field with a
leading slot dimension, one update for all slots: :class:`nue.nerf.stacked.StackedMemory`) has the same interface;
:func:`slot_memory` chooses.
"""

from __future__ import annotations

from typing import Any, Sequence

import numpy as np

from nue.nerf.online import MemoryMaps, OnlineNeRF
from nue.nerf.stacked import StackedMemory

SLOT_MEMORY_KINDS = ("list", "stacked")
"""What :func:`slot_memory` can build: ``list`` = :class:`MemoryList` (the default), ``stacked`` =
:class:`nue.nerf.stacked.StackedMemory` (grid fields only; its maps equal the list's up to float rounding)."""


class MemoryList:
    """B independent memories (anything with the single memory's ``reset`` / ``render_maps`` / ``step``)."""

    def __init__(self, memories: Sequence[Any]):
        if not memories:
            raise ValueError("a MemoryList needs at least one memory")
        if len({id(m) for m in memories}) != len(memories):
            raise ValueError("each slot needs its own memory object")
        self.memories = list(memories)
        self.slots = len(self.memories)

    def reset_slot(self, i: int, seed: int, start_pose: np.ndarray, floor_z: float) -> None:
        """Start an episode in slot ``i`` (the memory's initial weights, ray sampling seeded by ``seed``)."""
        self.memories[i].reset(seed, start_pose=start_pose, floor_z=floor_z)

    def render_maps(self, slots: list[int], poses: list[np.ndarray], depths: list[np.ndarray],
                    floor_zs: list[float]) -> list[MemoryMaps]:
        """The maps of each listed slot for its current pose and depth (before it learns the frame)."""
        return [self.memories[i].render_maps(p, d, floor_z=z) for i, p, d, z in zip(slots, poses, depths, floor_zs)]

    def step(self, slots: list[int], rgbs, depths, poses, floor_zs) -> None:
        """Each listed slot learns its current frame (its memory's schedule: observe, update)."""
        for i, rgb, d, p, z in zip(slots, rgbs, depths, poses, floor_zs):
            self.memories[i].step(rgb, d, p, floor_z=z)


def slot_memory(first: OnlineNeRF, slots: int, kind: str = "list") -> MemoryList | StackedMemory:
    """The memory of ``slots`` lock-step slots built like ``first`` (same config, camera, initial weights,
    device); for ``list`` slot 0 is ``first`` itself.

    ``kind``: ``list`` (:class:`MemoryList`) or ``stacked`` (:class:`~nue.nerf.stacked.StackedMemory`). The kind
    changes the arithmetic, so a caller that offers ``stacked`` must store it with its records (``nue eval`` does
    not offer it yet: its runs use ``list``).
    """
    if kind not in SLOT_MEMORY_KINDS:
        raise ValueError(f"unknown slot memory kind {kind!r}; expected one of {SLOT_MEMORY_KINDS}")
    if kind == "stacked":
        return StackedMemory(first.config, slots, camera=first.camera, device=first.device,
                             init_state=first.initial_state())
    twins = [OnlineNeRF(first.config, first.camera, init_state=first.initial_state(), device=first.device)
             for _ in range(slots - 1)]
    return MemoryList([first, *twins])


class StackedSlot:
    """One slot of a :class:`~nue.nerf.stacked.StackedMemory` with the single-episode memory protocol
    (``nue.rollout.Memory``): ``reset`` / ``render_maps`` / ``step`` as an ``OnlineNeRF``'s (each call batched over
    this slot alone)."""

    def __init__(self, stacked: StackedMemory, i: int):
        self.stacked, self.slot = stacked, stacked._check_slot(i)
        self.config, self.camera, self.device = stacked.config, stacked.camera, stacked.device

    def reset(self, seed: int = 0, start_pose=None, floor_z: float = 0.0) -> None:
        self.stacked.reset_slot(self.slot, seed, start_pose, floor_z)

    def render_maps(self, pose, depth, floor_z: float = 0.0) -> MemoryMaps:
        return self.stacked.render_maps([self.slot], [pose], [depth], [floor_z])[0]

    def step(self, rgb, depth, pose, floor_z: float = 0.0) -> None:
        self.stacked.step([self.slot], [rgb], [depth], [pose], [floor_z])

    @property
    def replay_len(self) -> int:
        return self.stacked.replay_len(self.slot)
