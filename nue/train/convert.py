"""Re-encode a demonstration collection in the compact storage (``nue convert``).

Collections written before the compact format (episode files of format version 1, all float16, ~430 KiB a
step) stay readable, but they are three times larger than a fresh ``nue collect`` writes, so a large one
outgrows the page cache and training waits on the disk. :func:`convert_collection` writes a copy whose
per-step arrays are stored as :class:`~nue.train.compact.StepStorage` says (the same episodes, in the same
order and folders, with the same metadata and manifest); everything else is copied unchanged.

The copy is resumable: episode files are written atomically, so a file that exists in the output is
complete and is skipped on a rerun (a truncated or corrupt one is re-written).
"""

from __future__ import annotations

import json
import shutil
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
from tqdm import tqdm

from nue.errors import DataError
from nue.output_lock import hold_output
from nue.train.compact import QuantizedArray, StepStorage
from nue.train.episode_file import read_episode_file, write_episode_file
from nue.train.manifest import read_manifest, write_manifest

PARTS = ("train", "heldout")
"""The parts of a collection folder."""
STEP_ARRAYS = ("rgbd", "i_u", "i_cog")
"""The per-step arrays :class:`StepStorage` encodes; every other array is copied as stored."""


@dataclass(frozen=True)
class ConvertSummary:
    """What :func:`convert_collection` did."""

    episodes: int
    """Episode files in the output."""
    converted: int
    """Episode files written by this call (the others were there from an earlier, interrupted call)."""
    steps: int
    """Steps over all episodes."""
    bytes_before: int
    """Total size of the source's episode files."""
    bytes_after: int
    """Total size of the output's episode files."""

    @property
    def kib_per_step_before(self) -> float:
        return self.bytes_before / max(self.steps, 1) / 1024

    @property
    def kib_per_step_after(self) -> float:
        return self.bytes_after / max(self.steps, 1) / 1024


def _as_float(a) -> np.ndarray:
    return np.asarray(a, dtype=np.float32)


def convert_episode(src: Path, dst: Path, storage: StepStorage) -> int:
    """Write ``src``'s episode to ``dst`` with ``storage``'s encodings; returns its number of steps."""
    arrays, meta = read_episode_file(src, mmap=True, verify=True)
    new = {}
    for name, a in arrays.items():
        if name in STEP_ARRAYS:
            new[name] = storage.encode(name, _as_float(a))
        else:
            new[name] = a if isinstance(a, QuantizedArray) else np.asarray(a)
    write_episode_file(dst, new, meta)
    return len(arrays["action"])


def _complete(path: Path) -> bool:
    try:
        read_episode_file(path, mmap=True, verify=True)
        return True
    except DataError:
        return False


def convert_collection(src, out, storage: StepStorage = StepStorage(), progress: bool = False) -> ConvertSummary:
    """Copy the collection folder ``src`` to ``out`` with its step arrays stored as ``storage`` says.

    Refuses (:class:`DataError`) a source without a manifest, ``out`` = ``src``, and an ``out`` that holds
    another collection. Rerunning after an interruption converts only the missing episodes. ``out`` is held by
    this process meanwhile (:func:`~nue.output_lock.hold_output`).
    """
    with hold_output(out):
        return _convert(Path(src), Path(out), storage, progress)


def _convert(src: Path, out: Path, storage: StepStorage, progress: bool) -> ConvertSummary:
    manifest = read_manifest(src)
    if out.resolve() == src.resolve():
        raise DataError(out, "is the source collection; convert into another folder")
    files = [f for part in PARTS for f in sorted((src / part).glob("*/*.nue"))]
    if not files:
        raise DataError(src, "holds no episode files")
    write_manifest(out, manifest)
    it = tqdm(files, desc="convert", unit="episode", disable=not progress)
    steps = converted = before = after = 0
    for f in it:
        dst = out / f.relative_to(src)
        if dst.is_file() and _complete(dst):
            steps += len(read_episode_file(dst)[0]["action"])
        else:
            steps += convert_episode(f, dst, storage)
            converted += 1
        before += f.stat().st_size
        after += dst.stat().st_size
    summary = ConvertSummary(len(files), converted, steps, before, after)
    old = json.loads((src / "summary.json").read_text()) if (src / "summary.json").is_file() else {}
    old.update({"episodes": len(files), "steps": steps, "bytes": after, "bytes_per_step": after / max(steps, 1),
                "converted_from": str(src), "storage": asdict(storage)})
    (out / "summary.json").write_text(json.dumps(old, indent=1) + "\n")
    for extra in sorted(src.glob("*.json")):  # summaries of DAgger rounds and the like travel with the data
        if extra.name not in ("manifest.json", "summary.json") and not (out / extra.name).exists():
            shutil.copy2(extra, out / extra.name)
    return summary
