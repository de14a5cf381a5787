"""Demonstration data: episode files of a collection, checked, indexed and served as policy batches.

Episodes are memory-mapped (float16, or the compact codes of ``nue.train.compact``, decoded to float32 only
for the steps a batch gathers); a sampler walks a shuffled buffer of episodes at a time (so the page
cache holds what is being read when the data outgrow memory) and shuffles their steps. A file that
is truncated or fails its checksum is reported by name and skipped, never silently used.
"""

from __future__ import annotations

import dataclasses
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from nue.errors import DataError
from nue.policy.inputs import PolicyInput
from nue.train.compact import QuantizedArray
from nue.train.episode_file import read_episode_file
from nue.train.manifest import CollectionManifest, DataLayout, manifest_path, read_manifest

MAP_KEYS = ("i_u", "i_cog")


@dataclass
class Batch:
    """A training batch: the policy input and its labels (leading dims (B,) or (T, B))."""

    inp: PolicyInput
    action: torch.Tensor
    """Expert action labels, long."""
    goal_angle: torch.Tensor
    """True goal angle, radians, float."""
    reset: torch.Tensor | None = None
    """(T, B) bool for sequences: True where an episode starts."""
    goal_in_view: torch.Tensor | None = None
    """Labels of the exploitation head (models with ``goal_head``): goal in view (the exploring expert's switch
    test), float 0/1."""
    goal_distance: torch.Tensor | None = None
    """... and the robot's straight-line distance to the goal, metres."""


_SAME = ("task", "memory", "model_layout")
"""Manifest entries that must agree between aggregated collections (e.g. expert + DAgger rounds)."""


def data_roots(spec) -> list[Path]:
    """Collection folders from a path, a comma-separated string or a sequence."""
    if isinstance(spec, (str, Path)):
        return [Path(p) for p in str(spec).split(",") if p]
    return [Path(p) for p in spec]


class DemoSet:
    """The episodes of one part (``train`` or ``heldout``) of one or more collection folders.

    Several folders (expert data + DAgger rounds) are aggregated; their task, memory and input
    layout must agree. ``manifest`` is the first folder's.
    """

    def __init__(self, roots, part: str = "train", verify: bool = True, max_episodes: int | None = None):
        roots = data_roots(roots)
        self.root = roots[0]
        manifests = [read_manifest(root) for root in roots]
        for root, m in zip(roots[1:], manifests[1:]):
            for key in _SAME:
                if getattr(m, key) != getattr(manifests[0], key):
                    raise DataError(manifest_path(root), f"{key} differs from {manifest_path(roots[0])}; cannot aggregate")
        self.manifest: CollectionManifest = manifests[0]
        """The first folder's manifest."""
        self.manifests: list[CollectionManifest] = manifests
        files = [f for root in roots for f in sorted((root / part).glob("*/*.nue"))]
        if max_episodes is not None:
            files = files[:max_episodes]
        self.episodes: list[dict[str, np.ndarray | QuantizedArray]] = []
        """Per episode: name -> (T, ...) step array (memory-mapped; compact ones as ``QuantizedArray``) or a
        per-episode array (the goal photos)."""
        self.files: list[Path] = []
        """The file of each episode."""
        self.metas: list[dict] = []
        self.skipped: list[tuple[Path, str]] = []
        for f in files:
            try:
                arrays, meta = read_episode_file(f, mmap=True, verify=verify)
            except DataError as exc:
                self.skipped.append((f, exc.problem))
                warnings.warn(f"skipping {f}: {exc.problem}", stacklevel=2)
                continue
            self.episodes.append(arrays)
            self.files.append(f)
            self.metas.append(meta)
        lengths = np.array([len(a["action"]) for a in self.episodes], dtype=np.int64)
        self.lengths = lengths
        self.offsets = np.concatenate([[0], np.cumsum(lengths)])
        self.part = part

    def __len__(self) -> int:
        """Number of steps."""
        return int(self.offsets[-1])

    @property
    def n_episodes(self) -> int:
        return len(self.episodes)

    def summary(self) -> dict:
        """What a checkpoint records about its training data (``data``): episodes, steps, skipped files and the
        manifest hash of every folder, in order (a resumed run compares these, so another second folder is refused)."""
        return {"episodes": self.n_episodes, "steps": len(self), "skipped": [str(p) for p, _ in self.skipped],
                "manifests": [m.hash() for m in self.manifests]}

    def locate(self, idx: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(episode, step within it) of flat step indices ``idx`` (0 .. len - 1)."""
        ep = np.searchsorted(self.offsets, idx, side="right") - 1
        return ep, np.asarray(idx) - self.offsets[ep]

    def sample_steps(self, n: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
        """(episodes, steps) of ``n`` distinct steps drawn with ``numpy.random.default_rng(seed)``, in order (every
        step when there are no more than ``n``): a fixed evaluation sample of the set."""
        idx = np.arange(len(self))
        if len(idx) > n:
            idx = np.sort(np.random.default_rng(seed).choice(idx, n, replace=False))
        return self.locate(idx)

    def check_layout(self, model_cfg) -> None:
        """Refuse a model whose input sizes differ from the stored ones. A model that reads no memory maps (FR,
        Nav-A3C, NRNS, VGM) is checked on the frame only, so it trains on a collection made for any map size (e.g.
        the ``lean`` memory's 30 x 40)."""
        want, have = DataLayout.of(model_cfg), self.manifest.model_layout
        if not model_cfg.uses_memory_maps:
            want = dataclasses.replace(want, map_size=have.map_size, cog_channels=have.cog_channels)
        if want != have:
            raise DataError(manifest_path(self.root), f"data layout {have.to_dict()} does not fit model "
                                                      f"{model_cfg.name!r} ({want.to_dict()})")
        if model_cfg.goal_head and self.episodes and "goal_in_view" not in self.episodes[0]:
            raise DataError(self.files[0], f"model {model_cfg.name!r} trains a goal head on 'goal_in_view' / "
                                           "'goal_distance' labels, which this collection predates (collect again)")
        if model_cfg.uses_panorama and self.episodes:
            pano = self.episodes[0].get("panorama")
            if pano is None or tuple(pano.shape[1:]) != tuple(model_cfg.panorama_shape):
                raise DataError(self.files[0], f"model {model_cfg.name!r} reads an uncertainty panorama of "
                                               f"{tuple(model_cfg.panorama_shape)}, the collection holds "
                                               f"{'none' if pano is None else tuple(pano.shape[1:])} (collect with a "
                                               "memory preset that renders it, e.g. --memory fast_pano)")

    def action_counts(self, num_actions: int) -> np.ndarray:
        counts = np.zeros(num_actions, dtype=np.int64)
        for a in self.episodes:
            counts += np.bincount(np.asarray(a["action"], dtype=np.int64), minlength=num_actions)[:num_actions]
        return counts

    def batch(self, episodes: np.ndarray, steps: np.ndarray, model_cfg, device="cpu", in_view: bool = False) -> Batch:
        """Gather the given (episode, step) pairs, any leading shape, into a :class:`Batch`; the goal-in-view and
        distance labels for a model with the exploitation head or when ``in_view`` (the in-view-weighted loss).

        Reads one index array per episode in the batch (not one per sample); float16 arrays are widened
        and compact ones (:class:`~nue.train.compact.QuantizedArray`) decoded to float32 there.
        """
        shape = episodes.shape
        ep, st = episodes.ravel(), steps.ravel()
        goal_key = "goal_map" if tuple(model_cfg.goal_size) == tuple(model_cfg.map_size) else "goal_frame"
        groups = episode_groups(ep)

        def gather(key, dtype=np.float32, per_episode=False):
            pieces = [(self.episodes[e][key], pos) for e, pos in groups]
            return torch.from_numpy(take_steps(pieces, None if per_episode else st, len(ep), dtype))

        def shaped(x):
            return x.reshape(*shape, *x.shape[1:]).to(device)

        inp = PolicyInput(
            rgbd=shaped(gather("rgbd")),
            goal=shaped(gather(goal_key, per_episode=True)),
            i_u=shaped(gather("i_u")) if model_cfg.uses_i_u else None,
            i_cog=shaped(gather("i_cog")) if model_cfg.uses_i_cog else None,
            panorama=shaped(gather("panorama")) if model_cfg.uses_panorama else None,
        )
        action, angle = gather("action", np.int64), gather("goal_angle")
        view = dist = None
        if model_cfg.goal_head or in_view:
            view, dist = shaped(gather("goal_in_view")).reshape(shape), shaped(gather("goal_distance")).reshape(shape)
        return Batch(inp, action.reshape(shape).to(device), angle.reshape(shape).to(device),
                     goal_in_view=view, goal_distance=dist)


def episode_groups(ep: np.ndarray) -> list[tuple[int, np.ndarray]]:
    """(episode, positions in ``ep`` holding it) for each distinct episode of ``ep`` (N,), in ascending order."""
    order = np.argsort(ep, kind="stable")
    uniq, starts = np.unique(ep[order], return_index=True)
    return [(int(e), pos) for e, pos in zip(uniq, np.split(order, starts[1:]))]


def take_steps(pieces, steps: np.ndarray | None, n: int, dtype=np.float32) -> np.ndarray:
    """The (n, ...) ``dtype`` array whose rows ``pos`` are ``a[steps[pos]]``, for each ``(a, pos)`` of ``pieces``.

    ``a`` (T, ...) is one episode's step-indexable array (memory-mapped, a ``QuantizedArray``, a view): one
    fancy index per episode, written into a preallocated output (no per-sample copies). ``steps=None``: ``a``
    is a per-episode array (...) repeated at its positions.
    """
    if not pieces:
        raise ValueError("an empty batch")
    first = pieces[0][0]
    out = np.empty((n, *(first.shape if steps is None else first.shape[1:])), dtype)
    for a, pos in pieces:
        out[pos] = a if steps is None else a[steps[pos]]
    return out


def swap_maps(batch, rng: np.random.Generator, p: float):
    """Map dropout: each sample's (I_u, I_cog) replaced with probability ``p`` by another sample's.

    ``batch.inp.i_u`` (N, 1, h, w) / ``i_cog`` (N, 64, h, w) for a flat batch (the leading dims are
    flattened and restored). Draws from ``rng`` (the run's generator, so a resumed run repeats it).
    """
    inp = batch.inp
    if p <= 0 or (inp.i_u is None and inp.i_cog is None):
        return batch
    ref = inp.i_cog if inp.i_cog is not None else inp.i_u
    lead = ref.shape[:-3]
    n = int(np.prod(lead))
    drop = torch.as_tensor(rng.random(n) < p)
    src = torch.as_tensor(rng.permutation(n))
    idx = torch.where(drop, src, torch.arange(n))

    def take(x):
        return None if x is None else x.reshape(n, *x.shape[-3:])[idx].reshape(x.shape)

    inp = dataclasses.replace(inp, i_u=take(inp.i_u), i_cog=take(inp.i_cog), panorama=take(inp.panorama))
    return dataclasses.replace(batch, inp=inp)


class BufferSampler:
    """Random step indices, a shuffled buffer of ``buffer_episodes`` episodes at a time.

    ``rank``/``world`` split every buffer between data-parallel processes. An iterator whose position
    (epoch order, buffer, permutation, batch offset) is :meth:`state_dict`, so a resumed run draws
    the same batches as an uninterrupted one (together with the generator's state). Draws from
    ``rng`` happen in this order: an epoch's episode order, then each buffer's step permutation.
    """

    def __init__(self, data: DemoSet, batch_size: int, rng: np.random.Generator, buffer_episodes: int = 64,
                 rank: int = 0, world: int = 1):
        self.data, self.batch_size, self.rng = data, batch_size, rng
        self.buffer_episodes, self.rank, self.world = buffer_episodes, rank, world
        self._order: np.ndarray | None = None
        """This epoch's episode order (None before the first draw)."""
        self._start = 0
        """Index in ``_order`` of the current buffer's first episode."""
        self._perm: np.ndarray | None = None
        """Permutation of the current buffer's steps."""
        self._next = 0
        """Offset in ``_perm`` of the next batch."""
        self._steps: tuple[np.ndarray, np.ndarray] | None = None

    def __iter__(self):
        return self

    def __next__(self) -> tuple[np.ndarray, np.ndarray]:
        per = self.batch_size * self.world
        while self._perm is None or self._next + per > len(self._perm):
            self._next_buffer()
        take = self._perm[self._next : self._next + per][self.rank :: self.world]
        self._next += per
        ep_idx, st_idx = self._buffer_steps()
        return ep_idx[take], st_idx[take]

    def _next_buffer(self) -> None:
        if self._order is not None and self._start + self.buffer_episodes < len(self._order):
            self._start += self.buffer_episodes
        else:
            self._order, self._start = self.rng.permutation(self.data.n_episodes), 0
        self._steps = None
        self._perm, self._next = self.rng.permutation(len(self._buffer_steps()[0])), 0

    def _buffer_steps(self) -> tuple[np.ndarray, np.ndarray]:
        """(episode, step) index of every step of the current buffer, in buffer order."""
        if self._steps is None:
            d, eps = self.data, self._order[self._start : self._start + self.buffer_episodes]
            self._steps = (np.concatenate([np.full(d.lengths[e], e) for e in eps]),
                           np.concatenate([np.arange(d.lengths[e]) for e in eps]))
        return self._steps

    def state_dict(self) -> dict:
        """Where the sampler is (not the generator's state: the training loop saves that)."""
        return {"order": None if self._order is None else self._order.tolist(), "start": self._start,
                "perm": None if self._perm is None else self._perm.tolist(), "next": self._next}

    def load_state_dict(self, state: dict) -> None:
        self._order = None if state["order"] is None else np.asarray(state["order"], dtype=np.int64)
        self._perm = None if state["perm"] is None else np.asarray(state["perm"], dtype=np.int64)
        self._start, self._next, self._steps = int(state["start"]), int(state["next"]), None


class SequenceSampler:
    """(T, B) windows of consecutive steps for recurrent models; windows start at random steps and
    are padded by continuing into the next sampled episode (the reset mask marks the boundary)."""

    def __init__(self, data: DemoSet, batch_size: int, seq_len: int, rng: np.random.Generator, rank: int = 0, world: int = 1):
        self.data, self.batch_size, self.seq_len, self.rng = data, batch_size, seq_len, rng
        self.rank, self.world = rank, world

    def state_dict(self) -> dict:
        """Nothing: each window is drawn afresh from the generator, whose state the loop saves."""
        return {}

    def load_state_dict(self, state: dict) -> None:
        pass

    def __iter__(self):
        d, T = self.data, self.seq_len
        while True:
            eps = np.zeros((T, self.batch_size * self.world), dtype=np.int64)
            steps = np.zeros_like(eps)
            reset = np.zeros(eps.shape, dtype=bool)
            for b in range(eps.shape[1]):
                e = int(self.rng.integers(d.n_episodes))
                t = int(self.rng.integers(d.lengths[e]))
                reset[0, b] = True
                for i in range(T):
                    if t >= d.lengths[e]:
                        e, t = int(self.rng.integers(d.n_episodes)), 0
                        reset[i, b] = True
                    eps[i, b], steps[i, b] = e, t
                    t += 1
            cols = slice(self.rank, None, self.world)
            yield eps[:, cols], steps[:, cols], reset[:, cols]
