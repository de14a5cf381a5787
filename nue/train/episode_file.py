"""One file per demonstration episode: named arrays, memory-mappable, checksummed, written atomically.

Layout: 8-byte magic ``NUEEPI1\\n``, a little-endian uint64 header length, a JSON header
``{"arrays": {name: {dtype, shape, offset, nbytes, crc32}}, "meta": {...}}``, then the raw C-order
array bytes, each starting at a 64-byte-aligned offset. Reading maps the arrays with
``numpy.memmap``, so a training step touches only the steps it samples. A truncated file, a bad
header or (with ``verify=True``) a checksum mismatch raises :class:`nue.errors.DataError` naming the file.
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

MAGIC = b"NUEEPI1\n"
ALIGN = 64


def _align(n: int) -> int:
    return -(-n // ALIGN) * ALIGN


def write_episode_file(path, arrays: dict[str, np.ndarray], meta: dict | None = None) -> Path:
    """Write ``arrays`` and ``meta`` to ``path`` atomically (temporary file in the same folder + rename)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    arrays = {k: np.ascontiguousarray(v) for k, v in arrays.items()}
    entries, offset = {}, 0
    for name, a in arrays.items():
        entries[name] = {"dtype": a.dtype.str, "shape": list(a.shape), "offset": offset, "nbytes": int(a.nbytes),
                         "crc32": zlib.crc32(a.data) & 0xFFFFFFFF}
        offset = _align(offset + a.nbytes)
    header = json.dumps({"arrays": entries, "meta": meta or {}}, sort_keys=True).encode()
    data_start = _align(len(MAGIC) + 8 + len(header))
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(MAGIC + struct.pack("<Q", len(header)) + header)
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
    """The header dict and the byte offset where array data starts; DataError if malformed or truncated."""
    path = Path(path)
    try:
        size = path.stat().st_size
        with open(path, "rb") as f:
            head = f.read(len(MAGIC) + 8)
            if len(head) < len(MAGIC) + 8 or head[: len(MAGIC)] != MAGIC:
                raise DataError(path, "not a nue episode file (bad magic) or truncated header")
            (n,) = struct.unpack("<Q", head[len(MAGIC):])
            if n > size:
                raise DataError(path, f"truncated: header of {n} bytes in a {size}-byte file")
            header = json.loads(f.read(n))
    except (OSError, ValueError, UnicodeDecodeError) as exc:
        raise DataError(path, f"unreadable episode file ({type(exc).__name__}: {exc})") from None
    data_start = _align(len(MAGIC) + 8 + n)
    try:
        end = max((data_start + e["offset"] + e["nbytes"] for e in header["arrays"].values()), default=data_start)
    except (KeyError, TypeError):
        raise DataError(path, "malformed header") from None
    if end > size:
        raise DataError(path, f"truncated: {size} bytes on disk, {end} expected")
    return header, data_start


def read_episode_file(path, mmap: bool = True, verify: bool = False) -> tuple[dict[str, np.ndarray], dict]:
    """Arrays (memory-mapped read-only if ``mmap``) and meta of an episode file.

    ``verify=True`` checks every array's CRC32 (reads the whole file once).
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
    return arrays, header.get("meta", {})
