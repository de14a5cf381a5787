"""Regenerates ``box_room_geodesic.json`` (only when the geodesic definition changes on purpose).

Geodesic distances in the hand-written box-room fixture from one goal to hand-picked points: open
floor, around the interior wall, next to the obstacle, inside the obstacle (inf).
"""

import json
from pathlib import Path

from nue.scene.navgrid import NavGrid
from nue.scene.scene import Scene

HERE = Path(__file__).parent
GOAL = (2.0, -2.5)
POINTS = [(2.0, 0.5), (0.0, 0.0), (2.5, 2.5), (-2.0, -2.0), (-2.5, 2.5), (-2.0, 0.0), (0.0, -2.0), (1.0, -2.0), (5.0, 5.0)]


def compute():
    nav = NavGrid.from_scene(Scene.load(HERE.parent / "fixtures" / "box_room"))
    return [nav.geodesic_distance(p, GOAL) for p in POINTS]


if __name__ == "__main__":
    out = {"goal": GOAL, "points": POINTS, "distances": [d if d != float("inf") else "inf" for d in compute()]}
    (HERE / "box_room_geodesic.json").write_text(json.dumps(out, indent=1) + "\n")
