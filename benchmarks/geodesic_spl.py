"""Geodesic method vs SPL: how much the start-goal geodesic (SPL's shortest-path length l) of the 84
validation episodes changes with fast marching (NavGridConfig(geodesic="fmm")) instead of octile
paths, and the SPL of recorded runs recomputed with it (SPL = S * l / max(l, p), from the records'
success and path length; nothing is re-run).

    python benchmarks/geodesic_spl.py [results/records.jsonl]   # prints JSON; needs data/scenes/val_*
"""

from __future__ import annotations

import json
import sys
from collections import defaultdict
from pathlib import Path

import numpy as np

from nue.scene.navgrid import NavGrid, NavGridConfig
from nue.scene.scene import Scene
from nue.sim.episodes import load_episodes


def main(records_path: str = "results/records.jsonl") -> dict:
    geo = {}
    for f in sorted(Path("episodes/val").glob("*.json")):
        scene = Scene.load(Path("data/scenes") / f.stem)
        octile, fmm = NavGrid.from_scene(scene), NavGrid.from_scene(scene, config=NavGridConfig(geodesic="fmm"))
        for e in load_episodes(f, scene):
            a, b = e.start_position[:2], e.goal_position[:2]
            geo[(scene.name, e.episode_id)] = (octile.geodesic_distance(a, b), fmm.geodesic_distance(a, b))
    ratio = np.array([f / o for o, f in geo.values()])
    spl: dict = defaultdict(lambda: [[], []])
    for line in Path(records_path).read_text().splitlines():
        r = json.loads(line)
        key = (r["scene"], r["episode_id"])
        if key not in geo:
            continue
        for k, geo_len in enumerate(geo[key]):
            spl[r["method"]][k].append(float(r["success"]) * geo_len / max(geo_len, r["path_length"]))
    return {
        "episodes": len(geo),
        "fmm_over_octile_geodesic": {"mean": float(ratio.mean()), "min": float(ratio.min()), "max": float(ratio.max())},
        "spl": {m: {"octile": float(np.mean(o)), "fmm": float(np.mean(f)), "n": len(o)} for m, (o, f) in sorted(spl.items())},
    }


if __name__ == "__main__":
    print(json.dumps(main(*sys.argv[1:]), indent=1))
