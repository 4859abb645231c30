"""The straightened road frame (``RoadCurve.to_road``) against independent truth: a hand-made
curved road whose arclengths come from adaptive quadrature and whose points are placed at known
perpendicular offsets."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.integrate import quad

from nudge_train.data.commonroad import RoadCurve


@pytest.mark.parametrize("c2,c1", [(2.5e-4, 0.03), (-2.5e-4, -0.03), (3e-4, 0.0)])
def test_to_road_gives_arclength_and_offset_of_the_foot_point(c2: float, c1: float) -> None:
    """Road y = c2 x^2 + c1 x (radius about 1.7-2 km, slope up to 0.09, as US-101 after
    rotation): a point placed at offset d along the normal at parameter u maps to (s(u), d), with
    s(u) the quadrature of sqrt(1 + f'^2) from 0 to u. The first-order straightening is exact to
    a few millimetres at |d| <= 12 m; the old sign of the along-road correction was off by
    2 d sin(a) cos(a), up to 2 m here."""
    road = RoadCurve(coef=(c2, c1, 0.0), x0=-150.0, x1=150.0)

    def slope(x: np.ndarray | float) -> np.ndarray | float:
        return 2.0 * c2 * x + c1

    rng = np.random.default_rng(0)
    u = rng.uniform(-100.0, 100.0, 60)
    d = rng.uniform(-12.0, 12.0, 60)
    normal = np.stack([-slope(u), np.ones_like(u)], axis=1) / np.sqrt(1.0 + slope(u) ** 2)[:, None]
    pts = np.stack([u, c2 * u * u + c1 * u], axis=1) + d[:, None] * normal
    s_true = np.asarray([quad(lambda x: math.sqrt(1.0 + slope(x) ** 2), 0.0, float(ui))[0] for ui in u])
    got = road.to_road(pts)
    assert np.max(np.abs(got[:, 1] - d)) < 1e-3
    assert np.max(np.abs(got[:, 0] - s_true)) < 1e-2
    # Points on the centre line: exactly the arclength (no offset, no correction).
    on = road.to_road(np.stack([u, c2 * u * u + c1 * u], axis=1))
    assert np.max(np.abs(on[:, 0] - s_true)) < 1e-3 and np.max(np.abs(on[:, 1])) < 1e-9
