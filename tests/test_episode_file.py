"""Episode files: round trip, memory mapping, truncation and corruption are reported by name; the compact
arrays of format version 2 (hand-checked values, the error bound, constant channels, NaN / inf refused)
and old float16 files of version 1 read side by side."""

from __future__ import annotations

import json
import struct
import zlib

import numpy as np
import pytest
import torch

from nue.errors import DataError
from nue.policy import get_model_config
from nue.train.compact import QuantizedArray, StepStorage, quantize
from nue.train.dataset import DemoSet
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


# --- compact arrays (format version 2) and old float16 files (version 1) ---------------------------------
def _write_version_1(path, arrays: dict, meta: dict):
    """An episode file exactly as nue wrote it before the compact format (magic NUEEPI1, no encodings)."""
    entries, offset = {}, 0
    for name, a in arrays.items():
        entries[name] = {"dtype": a.dtype.str, "shape": list(a.shape), "offset": offset, "nbytes": int(a.nbytes),
                         "crc32": zlib.crc32(a.data) & 0xFFFFFFFF}
        offset = -(-(offset + a.nbytes) // 64) * 64
    header = json.dumps({"arrays": entries, "meta": meta}, sort_keys=True).encode()
    start = -(-(16 + len(header)) // 64) * 64
    with open(path, "wb") as f:
        f.write(b"NUEEPI1\n" + struct.pack("<Q", len(header)) + header)
        for name, a in arrays.items():
            f.seek(start + entries[name]["offset"])
            f.write(a.data)
        f.truncate(start + offset)
    return path


def test_quantize_hand_checked_values():
    x = np.array([0.0, 0.3, 3.75, 1.0], np.float32).reshape(1, 1, 1, 4)  # lo 0, scale 3.75 / 15 = 0.25
    q = quantize(x, 4)
    assert q.lo.tolist() == [[0.0]] and q.scale.tolist() == [[0.25]]
    assert q.codes.tolist() == [[[[0 | 1 << 4, 15 | 4 << 4]]]]  # codes 0, 1, 15, 4: two a byte, low nibble first
    assert q[0].tolist() == [[[0.0, 0.25, 3.75, 1.0]]] and q.shape == (1, 1, 1, 4) and q.dtype == np.float32
    q8 = quantize(np.array([1.0, 1.4, 3.6, 256.0], np.float32).reshape(1, 1, 1, 4), 8)  # lo 1, scale 255 / 255 = 1
    assert q8.codes.tolist() == [[[[0, 0, 3, 255]]]] and q8[:].tolist() == [[[[1.0, 1.0, 4.0, 256.0]]]]


@pytest.mark.parametrize("bits", [4, 8])
def test_quantize_error_within_half_a_step_per_channel(bits):
    rng = np.random.default_rng(1)
    x = np.abs(rng.normal(size=(3, 5, 4, 7))) * rng.uniform(0.1, 10, size=(3, 5, 1, 1))  # odd width: a padded nibble
    x = x.astype(np.float32)
    x[0, 0] = 2.5  # constant channel: exact
    x[1, 2] = 0.0
    q = quantize(x, bits)
    err = np.abs(q[:] - x)
    bound = (x.max(axis=(2, 3)) - x.min(axis=(2, 3))) / (2**bits - 1) / 2
    np.testing.assert_allclose(q.max_error, bound, rtol=1e-6)
    assert (err <= bound[..., None, None] * (1 + 1e-5) + 1e-6).all()
    assert err.max() > 0.5 * bound.max()  # the bound is reached, not loose
    assert (q[0][0] == 2.5).all() and (q[1][2] == 0.0).all() and q.scale[0, 0] == 0 and q.scale[1, 2] == 0
    lowest = x == x.min(axis=(2, 3), keepdims=True)
    assert (q[:][lowest] == x[lowest]).all()  # each channel's minimum is exact
    assert q.codes.shape[-1] == (4 if bits == 4 else 7)


@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
def test_quantize_refuses_non_finite(bad):
    x = np.zeros((2, 3, 4, 4), np.float32)
    x[1, 2, 3, 0] = bad
    with pytest.raises(ValueError, match="non-finite"):
        quantize(x, 4)


def test_compact_arrays_round_trip_memory_mapped(tmp_path):
    rng = np.random.default_rng(2)
    cog = np.maximum(rng.normal(size=(6, 64, 9, 12)), 0).astype(np.float32)
    rgbd = rng.uniform(0, 1, (6, 4, 18, 24)).astype(np.float32)
    s = StepStorage()
    stored = {"i_cog": s.encode("i_cog", cog), "rgbd": s.encode("rgbd", rgbd), "i_u": s.encode("i_u", rgbd[:, :1]),
              "action": np.arange(6, dtype=np.int8)}
    p = write_episode_file(tmp_path / "ep.nue", stored, {"steps": 6})
    header, _ = read_header(p)
    assert header["version"] == 2 and p.read_bytes()[:8] == b"NUEEPI2\n"
    assert header["arrays"]["i_cog"]["encoding"] == {"kind": "affine", "bits": 4, "width": 12}
    got, meta = read_episode_file(p, verify=True)
    assert meta == {"steps": 6} and set(got) == {"i_cog", "rgbd", "i_u", "action"}  # parts folded back
    assert isinstance(got["i_cog"], QuantizedArray) and isinstance(got["i_cog"].codes, np.memmap)
    assert got["i_u"].dtype == np.float16 and got["i_cog"].shape == (6, 64, 9, 12) and len(got["rgbd"]) == 6
    for k in ("i_cog", "rgbd"):
        assert np.array_equal(got[k][[4, 1, 4]], stored[k][[4, 1, 4]])
        assert np.array_equal(np.asarray(got[k]), stored[k][:])
    assert np.abs(got["i_cog"][:] - cog).max() <= (cog.max() / 15 / 2) * (1 + 1e-5)
    assert np.abs(got["rgbd"][:] - rgbd).max() <= 1 / 255 / 2 * (1 + 1e-5)
    data = bytearray(p.read_bytes())
    lo = header["arrays"]["i_cog.lo"]
    data[-(-(16 + int.from_bytes(data[8:16], "little")) // 64) * 64 + lo["offset"]] ^= 0xFF  # damage an offset
    p.write_bytes(bytes(data))
    with pytest.raises(DataError, match=r"checksum of array 'i_cog.lo'"):
        read_episode_file(p, verify=True)


def test_newer_format_version_is_refused(tmp_path, arrays):
    p = write_episode_file(tmp_path / "ep.nue", arrays)
    p.write_bytes(b"NUEEPI3\n" + p.read_bytes()[8:])
    with pytest.raises(DataError, match=r"ep.nue: episode file format version 3; this nue reads versions 1 to 2"):
        read_episode_file(p)


def _write_manifest(root):
    from nue.nerf.config import get_memory
    from nue.train.manifest import CollectionManifest, DataLayout, write_manifest

    write_manifest(root, CollectionManifest(task="paper", memory=get_memory("fast"),
                                            model_layout=DataLayout.of(get_model_config("nue")), split="train",
                                            scenes={"h": "0123456789abcdef"}, episodes_per_bin=2, heldout_per_bin=1,
                                            seed=0))


def _demo_folder(root):
    """A collection folder with an empty held-out house ``h``."""
    (root / "heldout" / "h").mkdir(parents=True)
    _write_manifest(root)
    return root


def _step_arrays(rng, t, fh=90, fw=120):
    return {"rgbd": rng.uniform(0, 1, (t, 4, fh, fw)).astype(np.float16),
            "i_u": rng.uniform(0, 1, (t, 1, 45, 60)).astype(np.float16),
            "i_cog": np.maximum(rng.normal(size=(t, 64, 45, 60)), 0).astype(np.float16),
            "action": rng.integers(0, 3, t).astype(np.int8), "goal_angle": rng.uniform(-3, 3, t).astype(np.float32),
            "goal_map": rng.uniform(0, 1, (3, 45, 60)).astype(np.float16),
            "goal_frame": rng.uniform(0, 1, (3, fh, fw)).astype(np.float16)}


def test_old_float16_and_compact_episodes_load_side_by_side(tmp_path):
    """A version-1 float16 file reads as before; DemoSet mixes it with compact ones and batches both (one
    fancy index per episode) to exactly what a per-sample gather of the stored values gives."""
    rng = np.random.default_rng(3)
    root = _demo_folder(tmp_path / "demos")
    old = _step_arrays(rng, 5)
    _write_version_1(root / "heldout" / "h" / "a.nue", old, {"steps": 5})
    got, meta = read_episode_file(root / "heldout" / "h" / "a.nue", verify=True)
    assert meta == {"steps": 5} and read_header(root / "heldout" / "h" / "a.nue")[0]["version"] == 1
    for k, v in old.items():
        assert got[k].dtype == v.dtype and np.array_equal(got[k], v), k
    new = _step_arrays(rng, 4)
    compact = {**new, **{k: StepStorage().encode(k, new[k].astype(np.float32)) for k in ("rgbd", "i_u", "i_cog")}}
    write_episode_file(root / "heldout" / "h" / "b.nue", compact, {"steps": 4})

    data = DemoSet(root, "heldout")
    assert data.n_episodes == 2 and len(data) == 9 and [f.name for f in data.files] == ["a.nue", "b.nue"]
    ep, st = np.array([[1, 0, 1], [0, 0, 1]]), np.array([[3, 4, 0], [1, 4, 3]])
    for cfg in (get_model_config("nue"), get_model_config("nue_paper"), get_model_config("fr")):
        b = data.batch(ep, st, cfg)
        sources = [old, {**new, **{k: compact[k][:] for k in ("rgbd", "i_u", "i_cog")}}]
        goal_key = "goal_map" if tuple(cfg.goal_size) == tuple(cfg.map_size) else "goal_frame"
        for key, x in (("rgbd", b.inp.rgbd), ("i_u", b.inp.i_u), ("i_cog", b.inp.i_cog), (goal_key, b.inp.goal)):
            if x is None:
                continue
            want = np.stack([np.asarray(sources[e][key] if key == goal_key else sources[e][key][t], np.float32)
                             for e, t in zip(ep.ravel(), st.ravel())])
            assert x.dtype == torch.float32 and tuple(x.shape[:2]) == (2, 3), key
            assert np.array_equal(x.reshape(6, *x.shape[2:]).numpy(), want), key
        want_action = [sources[e]["action"][t] for e, t in zip(ep.ravel(), st.ravel())]
        assert b.action.dtype == torch.int64 and b.action.reshape(-1).tolist() == want_action
    # the compact episode stays within the bound of the stored float16 values
    assert np.abs(data.episodes[1]["i_cog"][:] - new["i_cog"].astype(np.float32)).max() <= \
        float(new["i_cog"].max()) / 15 / 2 * (1 + 1e-5)


# --- nue convert: an old float16 collection re-encoded compactly ------------------------------------------
def _float16_collection(root, rng):
    """A collection folder as nue wrote it before the compact format: a real manifest, version-1 files."""
    _write_manifest(root)
    episodes = {}
    for rel, t in (("train/h/easy_000.nue", 3), ("train/h/easy_001.nue", 2), ("heldout/h/easy_000.nue", 4)):
        (root / rel).parent.mkdir(parents=True, exist_ok=True)
        episodes[rel] = _step_arrays(rng, t)
        _write_version_1(root / rel, episodes[rel], {"steps": t, "episode": rel})
    return episodes


def test_convert_collection_re_encodes_and_resumes(tmp_path, capsys):
    from nue.cli import main
    from nue.train.convert import convert_collection
    from nue.train.manifest import read_manifest

    rng = np.random.default_rng(5)
    src, out = tmp_path / "old", tmp_path / "new"
    episodes = _float16_collection(src, rng)
    s = convert_collection(src, out)
    assert (s.episodes, s.converted, s.steps) == (3, 3, 9)
    assert s.bytes_after < 0.45 * s.bytes_before  # random maps: i_cog 4 bits, RGB-D 8 bits, I_u float16
    assert read_manifest(out) == read_manifest(src)
    for rel, old in episodes.items():
        assert read_header(out / rel)[0]["version"] == 2
        got, meta = read_episode_file(out / rel, verify=True)
        assert meta == {"steps": len(old["action"]), "episode": rel}
        assert isinstance(got["i_cog"], QuantizedArray) and got["i_cog"].bits == 4
        assert isinstance(got["rgbd"], QuantizedArray) and got["rgbd"].bits == 8
        for k in ("action", "goal_angle", "goal_map", "goal_frame", "i_u"):  # copied as stored
            assert got[k].dtype == old[k].dtype and np.array_equal(got[k], old[k]), k
        x = old["rgbd"].astype(np.float32)
        assert np.abs(got["rgbd"][:] - x).max() <= 1 / 255 / 2 + 1e-6  # values in [0, 1]: half an 8-bit step
        assert np.abs(got["i_cog"][:] - old["i_cog"].astype(np.float32)).max() <= \
            float(old["i_cog"].max()) / 15 / 2 * (1 + 1e-5)
    assert DemoSet(out, "train").n_episodes == 2 and len(DemoSet(out, "heldout")) == 4

    # resume: a missing and a truncated output file are written again, the intact one is kept
    (out / "train/h/easy_000.nue").unlink()
    bad = out / "heldout/h/easy_000.nue"
    bad.write_bytes(bad.read_bytes()[:-100])
    kept = (out / "train/h/easy_001.nue").stat().st_mtime_ns
    s2 = convert_collection(src, out)
    assert (s2.episodes, s2.converted, s2.steps, s2.bytes_after) == (3, 2, 9, s.bytes_after)
    assert (out / "train/h/easy_001.nue").stat().st_mtime_ns == kept
    read_episode_file(bad, verify=True)

    # refusals: the source itself, a folder of another collection, no manifest; the CLI says so in one line
    with pytest.raises(DataError, match="is the source collection"):
        convert_collection(src, src)
    other = tmp_path / "other"
    _float16_collection(other, rng)
    (other / "manifest.json").write_text((other / "manifest.json").read_text().replace('"seed": 0', '"seed": 1'))
    with pytest.raises(DataError, match=r"other/manifest.json: holds a different collection \(differs in seed\)"):
        convert_collection(src, other)
    with pytest.raises(DataError, match="no manifest"):
        convert_collection(tmp_path / "nothing", tmp_path / "n2")
    assert not (tmp_path / "n2").exists()
    with pytest.raises(SystemExit) as exc:
        main(["convert", str(src), "--out", str(tmp_path / "n3"), "--i-cog-bits", "3"])
    err = capsys.readouterr().err.strip()
    assert exc.value.code == 2 and err.startswith("error: --i-cog-bits: must be 0 or one of (4, 8)") and "\n" not in err
    assert not (tmp_path / "n3").exists()
    with pytest.raises(SystemExit) as exc:
        main(["convert", str(src), "--out", str(tmp_path / "n4"), "--rgbd-bits", "0"])
    assert exc.value.code == 0
    assert "3 episodes (3 converted now), 9 steps" in capsys.readouterr().out
    assert not isinstance(read_episode_file(tmp_path / "n4/train/h/easy_000.nue")[0]["rgbd"], QuantizedArray)


def test_demo_set_reads_typed_manifests_and_refuses_mixed_collections(tmp_path):
    from nue.train.manifest import CollectionManifest, read_manifest

    rng = np.random.default_rng(6)
    a, b = tmp_path / "a", tmp_path / "b"
    _float16_collection(a, rng)
    _float16_collection(b, rng)
    data = DemoSet([a, b], "train")
    assert isinstance(data.manifest, CollectionManifest) and data.manifest == read_manifest(a)
    assert data.n_episodes == 4 and len(data) == 10
    data.check_layout(get_model_config("nue"))
    with pytest.raises(DataError, match=r"a/manifest.json: data layout .* does not fit model 'nue'"):
        data.check_layout(get_model_config("nue").replace(cog_channels=32))
    # a model that reads no maps trains on a collection made for other maps (the lean memory's), not other frames
    with pytest.raises(DataError, match=r"does not fit model 'nue_lean'"):
        data.check_layout(get_model_config("nue_lean"))
    data.check_layout(get_model_config("fr").replace(map_height=30, map_width=40, cog_channels=32))
    with pytest.raises(DataError, match=r"does not fit model 'fr'"):
        data.check_layout(get_model_config("fr").replace(frame_height=60))
    raw = json.loads((b / "manifest.json").read_text())
    raw["memory"]["train_rays"] = 256
    (b / "manifest.json").write_text(json.dumps(raw))
    with pytest.raises(DataError, match=r"b/manifest.json: memory differs from .*a/manifest.json; cannot aggregate"):
        DemoSet([a, b], "train")
    (b / "manifest.json").write_text('{"task": "paper"}')
    with pytest.raises(DataError, match=r"b/manifest.json: not a nue-demos/1 collection manifest"):
        DemoSet([a, b], "train")
