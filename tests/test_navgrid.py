"""Navigation grid: erosion, golden geodesic distances, unreachable = inf, shortest paths."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

GOLDEN = Path(__file__).parent / "golden" / "box_room_geodesic.json"


def test_geodesic_distances_match_the_golden_file(box_nav):
    golden = json.loads(GOLDEN.read_text())
    for p, want in zip(golden["points"], golden["distances"]):
        got = box_nav.geodesic_distance(p, golden["goal"])
        if want == "inf":
            assert got == math.inf, p
        else:
            assert abs(got - want) < 1e-9, (p, got, want)


def test_geodesics_are_close_to_hand_computed_lengths(box_nav):
    goal = (2.0, -2.5)
    # straight line through open floor: 3.0 m, within a cell
    assert abs(box_nav.geodesic_distance((2.0, 0.5), goal) - 3.0) < 0.05
    # around the interior wall tip at (-1, 1.5): via the eroded corner (-1, 1.5 + 0.18 + cell)
    corner = np.array([-1.0, 1.73])
    around = np.linalg.norm(corner - (-2.0, -2.0)) + np.linalg.norm(corner - goal)
    d = box_nav.geodesic_distance((-2.0, -2.0), goal)
    assert around - 0.05 < d < around * 1.09  # 8-connected paths overestimate by at most ~8%


def test_erosion_by_robot_radius(box_nav):
    assert not box_nav.is_free((2.9, 0.0))  # 0.10 m from the east wall
    assert box_nav.is_free((2.75, 0.0))  # 0.25 m from it
    assert not box_nav.is_free((1.0, -1.6))  # 0.10 m from the obstacle face
    assert not box_nav.is_free((20.0, 0.0))  # outside the map


def test_unreachable_is_inf(box_nav):
    assert box_nav.geodesic_distance((0.0, 0.0), (1.0, -2.0)) == math.inf  # goal inside the obstacle


def test_shortest_path_goes_through_the_gap(box_nav):
    path = box_nav.shortest_path((-2.0, -2.0), (2.0, -2.5))
    assert np.allclose(path[0], (-2.0, -2.0)) and np.allclose(path[-1], (2.0, -2.5))
    assert np.all(box_nav.is_free(path[1:-1]))
    near_wall = np.abs(path[:, 0] + 1.0) < 0.2
    assert near_wall.any() and np.all(path[near_wall, 1] > 1.5)  # crosses x = -1 only above the wall tip
    length = np.linalg.norm(np.diff(path, axis=0), axis=1).sum()
    assert abs(length - box_nav.geodesic_distance((-2.0, -2.0), (2.0, -2.5))) < 0.15


def test_distance_fields_are_cached(box_nav):
    a = box_nav.distance_field((0.0, 0.0))
    assert box_nav.distance_field((0.01, 0.01)) is a  # same goal cell
