"""One file per demonstration episode: named arrays, memory-mappable, checksummed, written atomically.

Layout: 8-byte magic ``NUEEPI<v>\\n`` (``v`` the format version), a little-endian uint64 header length, a
JSON header ``{"arrays": {name: {dtype, shape, offset, nbytes, crc32[, encoding]}}, "meta": {...}}``,
then the raw C-order array bytes, each starting at a 64-byte-aligned offset. Reading maps the arrays
with ``numpy.memmap``, so a training step touches only the steps it samples. A truncated file, a bad
header, a version newer than this reader or (with ``verify=True``) a checksum mismatch raises
:class:`nue.errors.DataError` naming the file.

Versions: 1 holds plain arrays only (collections before the compact format: float16 maps and frames).
2 (written now) may also hold a :class:`~nue.train.compact.QuantizedArray` ``x``, stored as three plain
arrays ``x`` (the codes, whose entry carries ``"encoding": {"kind": "affine", "bits", "width"}``),
``x.lo`` and ``x.scale``, and read back as one ``QuantizedArray`` over the memory-mapped parts.
"""

from __future__ import annotations

import json
import os
import struct
import tempfile
import zlib
from pathlib import Path

import numpy as np

from nue.errors import DataError
from nue.train.compact import QuantizedArray

MAGIC_PREFIX = b"NUEEPI"
VERSION = 2
"""Format version written; every version from 1 up to it is read."""
ALIGN = 64
MAGIC_LEN = 8


def magic(version: int) -> bytes:
    """The 8 leading bytes of a version-``version`` file (``NUEEPI1\\n``, ``NUEEPI2\\n``)."""
    return MAGIC_PREFIX + str(version).encode() + b"\n"


def _align(n: int) -> int:
    return -(-n // ALIGN) * ALIGN


def _stored_arrays(arrays: dict) -> tuple[dict[str, np.ndarray], dict[str, dict]]:
    """Plain arrays to write and the encodings of their entries: a QuantizedArray ``x`` becomes ``x``, ``x.lo``,
    ``x.scale``."""
    plain, encodings = {}, {}
    for name, a in arrays.items():
        if isinstance(a, QuantizedArray):
            parts = {name: a.codes, f"{name}.lo": a.lo, f"{name}.scale": a.scale}
            encodings[name] = {"kind": "affine", "bits": a.bits, "width": a.width}
        else:
            parts = {name: a}
        for key, part in parts.items():
            if key in plain or (key != name and key in arrays):
                raise ValueError(f"array name {key!r} is used twice")
            plain[key] = np.ascontiguousarray(part)
    return plain, encodings


def write_episode_file(path, arrays: dict[str, np.ndarray | QuantizedArray], meta: dict | None = None) -> Path:
    """Write ``arrays`` and ``meta`` to ``path`` (format :data:`VERSION`) atomically (temporary file in the same
    folder + rename)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    arrays, encodings = _stored_arrays(arrays)
    entries, offset = {}, 0
    for name, a in arrays.items():
        entries[name] = {"dtype": a.dtype.str, "shape": list(a.shape), "offset": offset, "nbytes": int(a.nbytes),
                         "crc32": zlib.crc32(a.data) & 0xFFFFFFFF}
        if name in encodings:
            entries[name]["encoding"] = encodings[name]
        offset = _align(offset + a.nbytes)
    header = json.dumps({"arrays": entries, "meta": meta or {}}, sort_keys=True).encode()
    data_start = _align(MAGIC_LEN + 8 + len(header))
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(magic(VERSION) + struct.pack("<Q", len(header)) + header)
            for name, a in arrays.items():
                f.seek(data_start + entries[name]["offset"])
                f.write(a.data)
            f.truncate(data_start + offset)  # pad to the aligned end (empty trailing arrays stay in range)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise
    return path


def read_header(path) -> tuple[dict, int]:
    """The header dict (with the file's ``"version"``) and the byte offset where array data starts; DataError if
    malformed, truncated or of a newer version."""
    path = Path(path)
    try:
        size = path.stat().st_size
        with open(path, "rb") as f:
            head = f.read(MAGIC_LEN + 8)
            digit = head[len(MAGIC_PREFIX):MAGIC_LEN - 1]
            if len(head) < MAGIC_LEN + 8 or not head.startswith(MAGIC_PREFIX) or not digit.isdigit() \
                    or head[MAGIC_LEN - 1:MAGIC_LEN] != b"\n":
                raise DataError(path, "not a nue episode file (bad magic) or truncated header")
            version = int(digit)
            if not 1 <= version <= VERSION:
                raise DataError(path, f"episode file format version {version}; this nue reads versions 1 to {VERSION}")
            (n,) = struct.unpack("<Q", head[MAGIC_LEN:])
            if n > size:
                raise DataError(path, f"truncated: header of {n} bytes in a {size}-byte file")
            header = json.loads(f.read(n))
    except (OSError, ValueError, UnicodeDecodeError) as exc:
        raise DataError(path, f"unreadable episode file ({type(exc).__name__}: {exc})") from None
    data_start = _align(MAGIC_LEN + 8 + n)
    try:
        end = max((data_start + e["offset"] + e["nbytes"] for e in header["arrays"].values()), default=data_start)
    except (KeyError, TypeError):
        raise DataError(path, "malformed header") from None
    if end > size:
        raise DataError(path, f"truncated: {size} bytes on disk, {end} expected")
    header["version"] = version
    return header, data_start


def read_episode_file(path, mmap: bool = True,
                      verify: bool = False) -> tuple[dict[str, np.ndarray | QuantizedArray], dict]:
    """Arrays (memory-mapped read-only if ``mmap``; compact ones as :class:`QuantizedArray`) and meta of an
    episode file of any version.

    ``verify=True`` checks every stored array's CRC32 (reads the whole file once).
    """
    path = Path(path)
    header, start = read_header(path)
    arrays = {}
    for name, e in header["arrays"].items():
        dtype, shape = np.dtype(e["dtype"]), tuple(e["shape"])
        if mmap and e["nbytes"] > 0:
            a = np.memmap(path, dtype=dtype, mode="r", offset=start + e["offset"], shape=shape)
        else:
            with open(path, "rb") as f:
                f.seek(start + e["offset"])
                a = np.frombuffer(f.read(e["nbytes"]), dtype=dtype).reshape(shape)
        if verify and (zlib.crc32(np.ascontiguousarray(a).data) & 0xFFFFFFFF) != e["crc32"]:
            raise DataError(path, f"corrupt: checksum of array {name!r} does not match")
        arrays[name] = a
    for name, e in header["arrays"].items():
        if "encoding" in e:
            arrays[name] = _decoder(path, name, e["encoding"], arrays)
    return arrays, header.get("meta", {})


def _decoder(path: Path, name: str, encoding: dict, arrays: dict) -> QuantizedArray:
    """The QuantizedArray over the stored parts of ``name`` (removed from ``arrays``); DataError if inconsistent."""
    try:
        if encoding.get("kind") != "affine":
            raise ValueError(f"unknown encoding {encoding.get('kind')!r}")
        return QuantizedArray(arrays[name], arrays.pop(f"{name}.lo"), arrays.pop(f"{name}.scale"),
                              int(encoding["bits"]), int(encoding["width"]))
    except (KeyError, ValueError, TypeError) as exc:
        raise DataError(path, f"malformed compact array {name!r} ({type(exc).__name__}: {exc})") from None
