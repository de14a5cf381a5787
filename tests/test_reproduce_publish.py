"""``scripts/reproduce_publish.py`` on a hand-made repository and a finished quick-recipe run: the seed-0 checkpoint of
every row ships (the earlier ones kept or deleted), the previous recipe's rows are renamed, an earlier recipe's stay,
an appended experiment's rows with a copy elsewhere leave, the experts' are replaced, the 84-episode file gets the
``val`` subset, a new set's file is made, the exploration file is merged; every refusal is one line, exit 2, before
anything is written."""

from __future__ import annotations

import importlib.util
import json
import shutil
from pathlib import Path

import pytest

from nue.recipes import get_recipe
from nue.reproduce import check_recipe

REPO = Path(__file__).resolve().parents[1]
spec = importlib.util.spec_from_file_location("reproduce_publish", REPO / "scripts" / "reproduce_publish.py")
publish = importlib.util.module_from_spec(spec)
spec.loader.exec_module(publish)
pytestmark = pytest.mark.timeout(120)

TEMPLATE = [json.loads(line) for line in (REPO / "results" / "mix" / "records_val252_fr_mix.jsonl").read_text().splitlines()
            if '"scene": "val_00"' in line]  # 18 real records of one house: 6 of them are episodes/val's
QUICK_ROWS = ["nue", "abl_none", "abl_fu", "abl_at_cbam", "abl_fu_cbam", "abl_fu_at", "fr", "nav_a3c"]


def _rows(method: str, scene: str = "val_00", n: int = 18, success: bool | None = None) -> list[dict]:
    rows = []
    for r in TEMPLATE[:n]:
        r = {**r, "method": method, "scene": scene, "extra": {**r["extra"], "key": f"old/{method}/{r['episode_id']}"}}
        if success is not None:
            r["success"] = success
        rows.append(r)
    return rows


def _write(path: Path, rows: list[dict]) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("".join(json.dumps(r) + "\n" for r in rows))


def _methods(path: Path) -> dict[str, int]:
    counts: dict[str, int] = {}
    for line in path.read_text().splitlines():
        m = json.loads(line)["method"]
        counts[m] = counts.get(m, 0) + 1
    return counts


@pytest.fixture
def setup(tmp_path):
    """(repository, run): the repository holds v6-named rows, an earlier recipe's, an appended memory baseline's (with
    its copy in results/memory_baselines/), the experts' and two v6 checkpoints; the run is a finished quick run."""
    root, run = tmp_path / "repo", tmp_path / "run"
    (root / "episodes" / "val").mkdir(parents=True)
    shutil.copy(REPO / "episodes" / "val" / "val_00.json", root / "episodes" / "val")
    (root / "checkpoints").mkdir()
    for m in ("nue", "fr"):
        (root / "checkpoints" / f"{m}.pt").write_bytes(f"v6 {m}".encode())
    vgm = _rows("vgm")
    _write(root / "results" / "memory_baselines" / "records_val252_vgm.jsonl", vgm)
    # another run's vgm rows of the same episodes, e.g. the run's store read after the experiment's file
    _write(root / "results" / "v12" / "run" / "records" / "val252.jsonl", _rows("vgm", success=False))
    old = _rows("nue") + _rows("nue+swap") + _rows("sling+nue") + _rows("fr_v5") + vgm + _rows("expert", success=False)
    _write(root / "results" / "records_val252.jsonl", old)
    _write(root / "results" / "records.jsonl", [r for r in old if r["episode_id"].endswith(("_000", "_001"))])
    _write(root / "results" / "explore_val252.jsonl", _rows("nue", n=3) + _rows("random", n=3, success=False))

    check_recipe(run, get_recipe("quick"))
    for name in QUICK_ROWS + ["nue@s1"]:
        (run / "runs" / name).mkdir(parents=True)
        shutil.copy(REPO / "checkpoints" / "fr.pt", run / "runs" / name / "best.pt")
    (run / "runs" / "nue" / "best.pt").write_bytes((run / "runs" / "nue" / "best.pt").read_bytes() + b"seed 0")
    for s in ("val252", "val_plain"):
        scene = "val_00" if s == "val252" else "val_plain_00"
        _write(run / "records" / f"{s}.jsonl", [r for m in QUICK_ROWS + ["nue@s1", "expert"] for r in _rows(m, scene)])
        _write(run / "records" / f"{s}+swap.jsonl", _rows("nue+swap", scene) + _rows("nue@s1+swap", scene))
        _write(run / "records" / f"{s}+sling.jsonl", _rows("sling+nue", scene) + _rows("sling+nue@s1", scene))
    _write(run / "records" / "explore" / "val252.jsonl",
           [r for m in ("nue", "nue@s1", "expert-explore", "random") for r in _rows(m, n=3)])
    (run / "stages").mkdir()
    (run / "stages" / "report.json").write_text("{}")
    for stage in ("train__nue", "eval__val252"):  # two stages' real markers (50 min and 21 min)
        shutil.copy(REPO / "results" / ("v12" if stage.startswith("train") else "reproduce") / "run" / "stages"
                    / f"{stage}.json", run / "stages")
    (root / "RESULTS.meta.json").write_text(json.dumps({"command": "v6's", "stage wall-clock": "v6's stages"}))
    return root, run


def _publish(root: Path, run: Path, *args: str) -> int:
    try:
        publish.main(["--root", str(root), "--run", str(run), "--previous", "v6", *args])
    except SystemExit as e:
        return int(e.code)
    return 0


def _snapshot(root: Path) -> dict[str, bytes]:
    return {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()}


def test_a_finished_run_becomes_the_shipped_rows(setup, capsys):
    root, run = setup
    assert _publish(root, run) == 0, capsys.readouterr().err
    shipped = sorted(p.stem for p in (root / "checkpoints").glob("*.pt"))
    assert shipped == sorted(QUICK_ROWS)  # seed 0 of every row, not nue@s1
    assert (root / "checkpoints" / "nue.pt").read_bytes() == (run / "runs" / "nue" / "best.pt").read_bytes()
    assert (root / "results" / "v6" / "checkpoints" / "nue_v6.pt").read_bytes() == b"v6 nue"

    val252 = _methods(root / "results" / "records_val252.jsonl")
    assert {"nue_v6", "nue_v6+swap", "sling+nue_v6", "fr_v5"} <= set(val252)  # renamed; the earlier recipe's kept
    assert "vgm" not in val252  # appended from results/memory_baselines/, where its copy stays
    assert val252["expert"] == 18 and val252["nue"] == val252["nue@s1"] == val252["sling+nue@s1"] == 18
    rows = [json.loads(line) for line in (root / "results" / "records_val252.jsonl").read_text().splitlines()]
    # the run's expert records (15 of 18 successes, as the template's) replaced the old ones (all failures)
    assert sum(r["success"] for r in rows if r["method"] == "expert") == 15
    assert all(r["extra"]["key"] == f"{r['method']}/{r['scene']}/{r['episode_id']}" for r in rows
               if r["method"].endswith("_v6") or r["method"].endswith("_v6+swap"))

    val = _methods(root / "results" / "records.jsonl")
    assert val["nue"] == val["nue@s1+swap"] == val["nue_v6"] == 6  # the 6 episodes of episodes/val
    plain = _methods(root / "results" / "records_val_plain.jsonl")  # a set the repository had no file of
    assert plain["nue"] == 18 and plain["sling+nue"] == 18 and not any(m.endswith("_v6") for m in plain)
    explore = _methods(root / "results" / "explore_val252.jsonl")
    assert explore == {"nue_v6": 3, "nue": 3, "nue@s1": 3, "expert-explore": 3, "random": 3}

    meta = json.loads((root / "RESULTS.meta.json").read_text())
    assert meta["command"] == "v6's"  # written by hand: kept for revising
    walls = meta["stage wall-clock"]  # from the run's markers, in the plan's order, with each evaluation's records
    assert walls.index("train/nue 50 min") < walls.index(f"eval/val252 21 min ({len(QUICK_ROWS) * 18 + 36} runs, ")
    assert meta["demonstrations"].startswith("? episodes")  # the fixture's run has no collection marker
    assert meta["stage machines"].endswith("not recorded (markers written before the field) 2")  # older markers

    out = capsys.readouterr().out
    assert "revise by hand: command" in out
    assert "8 rows shipped" in out and "1 removed" not in out and "18 removed, copies elsewhere" in out
    assert "whose outcome differs from the earlier one: expert 15)" in out  # the old expert rows were made to differ
    # published twice: refused before anything changes
    before = _snapshot(root)
    assert _publish(root, run) == 2
    assert "published before" in capsys.readouterr().err and _snapshot(root) == before


def test_partial_publishes_the_sets_the_run_has_reached(setup, capsys):
    root, run = setup
    (run / "stages" / "report.json").unlink()
    for f in ("val_plain.jsonl", "val_plain+swap.jsonl", "val_plain+sling.jsonl", "explore/val252.jsonl"):
        (run / "records" / f).unlink()
    before = _snapshot(root)
    assert _publish(root, run) == 2  # unfinished: refused without --partial, nothing changed
    assert "has not finished" in capsys.readouterr().err and _snapshot(root) == before

    assert _publish(root, run, "--partial") == 0, capsys.readouterr().err
    out = capsys.readouterr().out
    assert _methods(root / "results" / "records_val252.jsonl")["nue"] == 18
    assert not (root / "results" / "records_val_plain.jsonl").exists()  # not reached: left as it was
    explore = _methods(root / "results" / "explore_val252.jsonl")
    assert explore == {"nue": 3, "random": 3}  # the repository's file, untouched
    assert "val_plain: no records in the run yet" in out and "explore/val252: no records in the run yet" in out
    assert "--set val_plain=" not in out and "--explore val252=results/explore_val252.jsonl" in out


def test_drop_deletes_the_replaced_checkpoints(setup, capsys):
    root, run = setup
    assert _publish(root, run, "--previous-checkpoints", "drop") == 0
    assert not (root / "results" / "v6").exists() and len(list((root / "checkpoints").glob("*.pt"))) == 8


def test_refusals_name_the_file_and_change_nothing(setup, capsys):
    root, run = setup
    before = _snapshot(root)
    assert _publish(root, run, "--max-mb", "5") == 2
    err = capsys.readouterr().err
    assert err.startswith(f"error: {root / 'checkpoints'}: ") and "over --max-mb 5" in err and "nue 2.2" in err
    assert len(err.strip().splitlines()) == 1
    assert _publish(root, run, "--not-shipped", "msm") == 2 and "not a row of this recipe" in capsys.readouterr().err
    (run / "stages" / "report.json").unlink()
    assert _publish(root, run) == 2 and "has not finished" in capsys.readouterr().err
    (run / "stages" / "report.json").write_text("{}")
    (root / "RESULTS.meta.json").write_text("[]")
    before = _snapshot(root)
    assert _publish(root, run) == 2 and "RESULTS.meta.json: not a JSON object" in capsys.readouterr().err
    assert _snapshot(root) == before
    (root / "RESULTS.meta.json").write_text("{}")
    # a row nobody can account for: not the previous recipe's, not an earlier one's, no copy elsewhere
    with (root / "results" / "records_val252.jsonl").open("a") as f:
        f.write(json.dumps(_rows("mystery", n=1)[0]) + "\n")
    before = _snapshot(root)
    assert _publish(root, run) == 2
    err = capsys.readouterr().err
    assert "row 'mystery' (val_00/easy_000)" in err and "records_val252.jsonl" in err
    assert _snapshot(root) == before


def test_not_shipped_leaves_a_row_out_and_the_table_lists_the_rest(setup, capsys):
    root, run = setup
    assert _publish(root, run, "--not-shipped", "nav_a3c", "--table") == 0
    table = capsys.readouterr().out.splitlines()
    assert len(table) == 2 + 7 and not any("nav_a3c.pt" in line for line in table)
    nue = next(line for line in table if line.startswith("| `nue.pt`"))
    # the template records are FR's on val_00: 15 of 18 succeeded; both NUE seeds have the same records
    sr = 100 * sum(r["success"] for r in TEMPLATE) / len(TEMPLATE)
    assert f"| {sr:.1f}% | {sr:.1f}% (2 seeds) |" in nue and "`nue` (NUE (full))" in nue
    assert _snapshot(root)["checkpoints/nue.pt"] == b"v6 nue"  # --table changes nothing


def test_hand_off_lines_follow_the_renamed_rows(setup, capsys):
    """The previous recipe's records carry no hand-off of their own (made before the evaluation measured it): their
    lines in ``records_<set>.handoff.jsonl`` move to the renamed keys and still attach; replaced or removed rows' go."""
    from nue.evaluate.handoff import HANDOFF_KEY, record_handoff
    from nue.evaluate.handoff_job import handoff_path, load_records_with_handoff, record_key, trajectory_digest
    from nue.sim.record import EpisodeRecord

    root, run = setup
    records = root / "results" / "records_val252.jsonl"
    old = [json.loads(line) for line in records.read_text().splitlines()]
    for r in old:
        del r["extra"][HANDOFF_KEY]
    _write(records, old)
    lines, before = [], {}
    for i, r in enumerate(old):
        rec = EpisodeRecord.from_dict(r)
        h = {**TEMPLATE[0]["extra"][HANDOFF_KEY], "closest_step": i}
        lines.append({"key": record_key(rec), "method": r["method"], "trajectory": trajectory_digest(rec), HANDOFF_KEY: h})
        before[(r["method"], r["episode_id"])] = i
    _write(handoff_path(records), lines)

    assert _publish(root, run) == 0, capsys.readouterr().err
    moved = [json.loads(line) for line in handoff_path(records).read_text().splitlines()]
    assert {m["method"] for m in moved} == {"nue_v6", "nue_v6+swap", "sling+nue_v6", "fr_v5"}  # expert, vgm: gone
    assert len(moved) == 4 * 18 and all(m["key"].startswith(m["method"] + "/val_00/") for m in moved)
    renamed = {"nue_v6": "nue", "nue_v6+swap": "nue+swap", "sling+nue_v6": "sling+nue", "fr_v5": "fr_v5"}
    attached = [r for r in load_records_with_handoff(records) if r.method in renamed]
    assert len(attached) == 4 * 18
    for r in attached:  # each renamed row reads its own old line
        assert record_handoff(r).closest_step == before[(renamed[r.method], r.episode_id)]
    assert all(record_handoff(r) is not None for r in load_records_with_handoff(records) if r.method == "nue")  # the run's
    assert f"{handoff_path(records)}: {len(old)} -> {4 * 18} lines" in capsys.readouterr().out
