"""Geodesic distances against analytic values: an open room and around one wall tip, octile vs fast marching.

A synthetic 6 m x 6 m map (1 cm pixels, 5 cm cells, robot radius 0.18 m). Points are cell centres, so
the only error is the distance field's. Around a wall tip the continuous shortest path for a disc of
radius r is: tangent to the circle of radius r about the first tip corner, an arc, the wall's width
w, an arc about the second corner, tangent to the goal (see ``around_wall_tip``).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from nue.scene.navgrid import NavGrid, NavGridConfig

N, RES, R = 600, 0.01, 0.18
TIP_Y, HALF_W = 0.5, 0.05  # the wall: x in [-0.05, 0.05], from the south edge up to y = 0.5


def room(wall: bool) -> np.ndarray:
    trav = np.ones((N, N), dtype=bool)
    trav[[0, -1], :] = trav[:, [0, -1]] = False
    if wall:
        rows = slice(0, int(TIP_Y / RES + N / 2))
        cols = slice(int(-HALF_W / RES + N / 2), int(HALF_W / RES + N / 2))
        trav[rows, cols] = False
    return trav


def around_wall_tip(a, b) -> float:
    """Shortest path length for a disc of radius R from a (west of the wall) over the tip to b (east)."""
    c1, c2 = np.array([-HALF_W, TIP_Y]), np.array([HALF_W, TIP_Y])
    d1, d2 = np.linalg.norm(np.subtract(a, c1)), np.linalg.norm(np.subtract(b, c2))
    beta1 = math.atan2(a[1] - c1[1], a[0] - c1[0]) % (2 * math.pi)  # in (pi/2, 3pi/2)
    beta2 = math.atan2(b[1] - c2[1], b[0] - c2[0])  # in (-pi/2, pi/2)
    arc1 = beta1 - math.acos(R / d1) - math.pi / 2
    arc2 = math.pi / 2 - (beta2 + math.acos(R / d2))
    assert arc1 > 0 and arc2 > 0
    return math.sqrt(d1**2 - R**2) + R * arc1 + 2 * HALF_W + R * arc2 + math.sqrt(d2**2 - R**2)


A = (-1.475, -1.475)
B = (1.475, -1.475)


def test_around_wall_tip_by_hand():
    # |a - c1| = |(-1.425, -1.975)| = 2.43542; tangent sqrt(2.43542^2 - 0.18^2) = 2.42876; arc angle
    # (pi + atan(1.975 / 1.425)) - acos(0.18 / 2.43542) - pi/2 = 4.08720 - 1.49683 - 1.57080 = 1.01957
    assert around_wall_tip(A, B) == pytest.approx(2 * (2.42876 + 0.18 * 1.01957) + 0.1, abs=1e-4)


def test_octile_errors_against_analytic_values():
    open_nav, wall_nav = NavGrid(room(False)), NavGrid(room(True))
    # along an axis and a diagonal octile paths are exact; at (40, 17) cells (23 deg) they are 8.2% long
    assert open_nav.geodesic_distance((-1.475, -0.025), (0.525, -0.025)) == pytest.approx(2.0, abs=1e-9)
    assert open_nav.geodesic_distance((-1.475, -1.475), (0.025, 0.025)) == pytest.approx(1.5 * math.sqrt(2), abs=1e-9)
    octile = (40 - 17 + 17 * math.sqrt(2)) * 0.05
    got = open_nav.geodesic_distance((-1.475, -0.025), (0.525, 0.825))
    assert got == pytest.approx(octile, abs=1e-9) and got / math.hypot(2.0, 0.85) == pytest.approx(1.0823, abs=1e-4)
    exact = around_wall_tip(A, B)
    assert 1.0 < wall_nav.geodesic_distance(A, B) / exact < 1.09


def test_fast_marching_is_within_one_percent_in_the_open_and_closer_around_the_tip():
    pytest.importorskip("skfmm")
    cfg = NavGridConfig(geodesic="fmm")
    open_nav, wall_nav = NavGrid(room(False), config=cfg), NavGrid(room(True), config=cfg)
    start = (-1.475, -0.025)
    for cells in [(40, 0), (40, 17), (30, 30), (17, 40), (50, 5)]:
        goal = (start[0] + 0.05 * cells[0], start[1] + 0.05 * cells[1])
        assert open_nav.geodesic_distance(start, goal) / math.dist(start, goal) == pytest.approx(1.0, abs=0.01), cells
    # around the tip it is +3.3% (the front follows the blocked cells' staircase), octile +8.3%
    assert 1.0 < wall_nav.geodesic_distance(A, B) / around_wall_tip(A, B) < 1.04
    assert wall_nav.distance_field(B)[wall_nav.cell_of((0.0, -1.0))[0], wall_nav.cell_of((0.0, -1.0))[1]] == math.inf
