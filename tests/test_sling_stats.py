"""scripts/sling_stats.py on hand-made records: the paired difference, gains and losses, the estimates' accuracy and
the wrapper's cost per step come out as computed by hand."""

import json
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _rec(method, ep, success, steps=100, extra=None):
    return {"method": method, "scene": "val_00", "episode_id": ep, "success": success, "geodesic_start": 4.0,
            "path_length": 8.0, "steps": steps, "wall_time": steps * 0.05, "extra": extra or {}}


def test_sling_stats_pairs_each_wrapped_episode_with_its_policy(tmp_path):
    base = [_rec("fr", "easy_000", False), _rec("fr", "easy_001", True), _rec("nue", "easy_000", True)]
    lm = lambda errs, ms: {"last_mile": {"accepted_errors": errs, "ms_per_step": ms}}  # noqa: E731
    sling = [_rec("sling+fr", "easy_000", True, extra=lm([0.1, 2.0], {"match": 6.0, "map": 2.0})),
             _rec("sling+fr", "easy_001", True, steps=300, extra=lm([], {"match": 10.0, "map": 2.0}))]
    (tmp_path / "base.jsonl").write_text("".join(json.dumps(r) + "\n" for r in base))
    (tmp_path / "sling.jsonl").write_text("".join(json.dumps(r) + "\n" for r in sling))
    out = subprocess.run([sys.executable, str(ROOT / "scripts" / "sling_stats.py"), str(tmp_path / "base.jsonl"),
                          str(tmp_path / "sling.jsonl")], capture_output=True, text=True, check=True).stdout
    row = json.loads(out)
    assert (row["method"], row["episodes"], row["sr"], row["wrapped_sr"]) == ("sling+fr", 2, 100.0, 50.0)
    assert row["sr_diff"][0] == 50.0 and (row["gained"], row["lost"]) == (1, 0)
    assert row["spl_diff"][0] == 0.25  # one more success at SPL 4 / 8, over two episodes
    assert row["accepted_estimates"] == 2 and row["accepted_within_0.5m"] == 0.5
    assert row["episodes_with_an_accepted_estimate"] == 1
    # per-step cost weighted by steps: match (6 x 100 + 10 x 300) / 400 = 9.0, map 2.0
    assert row["wrapper_cpu_ms_per_step"] == {"match": 9.0, "map": 2.0} and row["wrapper_cpu_ms_per_step_total"] == 11.0
