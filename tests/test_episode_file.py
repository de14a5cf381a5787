"""Episode files: round trip, memory mapping, truncation and corruption are reported by name."""

from __future__ import annotations

import numpy as np
import pytest

from nue.errors import DataError
from nue.train.episode_file import read_episode_file, read_header, write_episode_file


@pytest.fixture()
def arrays():
    rng = np.random.default_rng(0)
    return {
        "i_cog": rng.normal(size=(5, 64, 9, 12)).astype(np.float16),
        "actions": np.array([0, 1, 2, 0, 0], dtype=np.int8),
        "pose": rng.normal(size=(5, 3)).astype(np.float32),
        "empty": np.zeros((0, 3), np.float32),
    }


def test_round_trip_memory_mapped(tmp_path, arrays):
    p = write_episode_file(tmp_path / "ep.nue", arrays, {"scene": "x", "steps": 5})
    got, meta = read_episode_file(p, verify=True)
    assert meta == {"scene": "x", "steps": 5}
    for k, v in arrays.items():
        assert got[k].dtype == v.dtype and got[k].shape == v.shape and np.array_equal(got[k], v)
    assert isinstance(got["i_cog"], np.memmap)
    assert not list(tmp_path.glob(".*.tmp"))  # no temporary file left behind


def test_truncated_file_is_reported_by_name(tmp_path, arrays):
    p = write_episode_file(tmp_path / "ep.nue", arrays)
    data = p.read_bytes()
    p.write_bytes(data[: len(data) - 100])
    with pytest.raises(DataError, match=r"ep.nue: truncated"):
        read_episode_file(p)
    p.write_bytes(data[:10])
    with pytest.raises(DataError, match=r"ep.nue: "):
        read_header(p)


def test_corruption_is_caught_by_the_checksum(tmp_path, arrays):
    p = write_episode_file(tmp_path / "ep.nue", arrays)
    data = bytearray(p.read_bytes())
    data[-50] ^= 0xFF  # flip bits inside the last array
    p.write_bytes(bytes(data))
    read_episode_file(p)  # without verification the damage is invisible...
    with pytest.raises(DataError, match=r"ep.nue: corrupt: checksum of array"):
        read_episode_file(p, verify=True)


def test_not_an_episode_file(tmp_path):
    (tmp_path / "x.nue").write_text("hello world, not a nue file")
    with pytest.raises(DataError, match=r"x.nue: not a nue episode file"):
        read_episode_file(tmp_path / "x.nue")
