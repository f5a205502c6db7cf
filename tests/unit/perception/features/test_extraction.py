"""Features of a scan (:mod:`agent.perception.features.extraction`): corners, occluding
edges, and what short runs and the thresholds give.

The synthetic scans and the tolerances of statistical checks: :mod:`.scans`.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from agent.perception.features import Feature, FeatureSettings, extraction_kernels
from tests.unit.perception.features.scans import (
    BOX_AND_WALL,
    CYLINDER,
    L_CORNER,
    L_WALLS,
    N_BEAMS,
    WALL_1P5,
    Arc,
    Wall,
    box,
    features_of,
    line_error,
    line_truth,
    nees,
    oblique_wall,
    of_kind,
    reversed_scan,
    simulate_scan,
    within_3_sigma,
)

# ---------------------------------------------------------------------------------- corners


def test_two_walls_make_two_segments_and_a_corner(rng: np.random.Generator) -> None:
    features = features_of(simulate_scan(L_WALLS, rng))
    assert [f.kind for f in features] == ["segment", "corner", "segment"]
    corner = features[1]
    assert corner.point is not None and corner.covariance.shape == (2, 2)
    assert within_3_sigma(corner.point - np.array(L_CORNER), corner.covariance)
    for seg, wall in zip((features[0], features[2]), L_WALLS, strict=True):
        assert within_3_sigma(line_error(seg, line_truth(wall.p0, wall.p1)), seg.covariance)


def test_corner_nees_is_consistent_over_400_scans() -> None:
    # χ² with 2 dof: mean of 400 within 2 ± 0.3 (3σ).
    values = []
    for seed in range(400):
        corners = of_kind(
            features_of(simulate_scan(L_WALLS, np.random.default_rng(seed))), "corner"
        )
        assert len(corners) == 1
        values.append(nees(corners[0].params - np.array(L_CORNER), corners[0].covariance))
    assert np.mean(values) == pytest.approx(2.0, abs=0.3)


def test_corner_found_where_the_filter_broke_the_segment(rng: np.random.Generator) -> None:
    # The filter also breaks segments at intensity steps, which a corner makes when its walls
    # face the beam differently: a corner across two segment ids, and no occluding edge.
    walls = [Wall(w.p0, w.p1, obj=k) for k, w in enumerate(L_WALLS)]
    scan = simulate_scan(walls, rng)
    assert scan["segment"].max() == 1
    features = features_of(scan)
    assert [f.kind for f in features] == ["segment", "corner", "segment"]
    corner = features[1]
    assert within_3_sigma(corner.params - np.array(L_CORNER), corner.covariance)


def test_thresholds_are_settings(rng: np.random.Generator) -> None:
    scan = simulate_scan(L_WALLS, rng)
    strict = FeatureSettings(corner_min_angle_deg=70.0)  # the L's walls meet at 64°
    assert [f.kind for f in features_of(scan, settings=strict)] == ["segment", "segment"]


# ---------------------------------------------------------------------------- occluding edges


def test_box_in_front_of_a_wall_has_occluding_edges_on_its_sides(
    rng: np.random.Generator,
) -> None:
    features = features_of(simulate_scan(BOX_AND_WALL, rng))
    assert [f.kind for f in features] == ["segment", "edge", "segment", "edge", "segment"]
    right, left = features[1], features[3]  # scan order: increasing angle, right to left
    # The box's right side (y < 0): the nearer surface (the box) lies at higher angles.
    assert right.nearer_side == "left"
    assert left.nearer_side == "right"
    for edge, y in ((right, -0.15), (left, 0.15)):
        assert edge.point is not None
        assert within_3_sigma(edge.point - np.array([1.15, y]), edge.covariance)
    box_front = features[2]
    assert box_front.params == pytest.approx([0.0, 1.15], abs=0.01)


def test_edge_sides_do_not_depend_on_the_sweep_direction(rng: np.random.Generator) -> None:
    scan = simulate_scan(BOX_AND_WALL, rng)

    def sides_by_y(features: list[Feature]) -> dict[float, str | None]:
        return {round(float(e.params[1]), 1): e.nearer_side for e in of_kind(features, "edge")}

    forward = sides_by_y(features_of(scan))
    backward = sides_by_y(features_of(reversed_scan(scan)))
    assert forward == backward == {-0.2: "left", 0.2: "right"}


def test_edge_nees_is_consistent() -> None:
    # The edge lies somewhere between the last beam on the box and the first past it: the
    # covariance carries that gap (uniform, width²/12), so over random box positions the NEES
    # (χ², 2 dof; 800 edges, mean σ ≈ 0.07, band ±0.3) stays consistent.
    values = []
    for seed in range(400):
        g = np.random.default_rng(seed)
        offset = g.uniform(-0.02, 0.02)
        scene = [*box((1.3, offset), 0.15, obj=1), Wall((2.3, -2.0), (2.3, 2.0), obj=0)]
        edges = of_kind(features_of(simulate_scan(scene, g)), "edge")
        assert len(edges) == 2
        for e in edges:
            corner = np.array([1.15, offset + math.copysign(0.15, e.params[1] - offset)])
            values.append(nees(e.params - corner, e.covariance))
    assert np.mean(values) == pytest.approx(2.0, abs=0.3)


def test_missing_data_on_one_wall_is_no_edge(rng: np.random.Generator) -> None:
    # A hole in the data splits a wall into two segment ids; across it the range changes by
    # more than 5 cm on an oblique wall, but both sides lie on one line: no occluding edge.
    wall = oblique_wall()
    scan = simulate_scan([wall], rng, drop=slice(120, 150))
    assert scan["segment"].max() == 1
    r = scan["range_m"]
    assert abs(r[150] - r[119]) > 0.05
    assert [f.kind for f in features_of(scan)] == ["segment", "segment"]


def test_no_edges_at_the_ends_of_the_scan(rng: np.random.Generator) -> None:
    # A box alone: its ends are where the field of view or the data stop, not occlusions.
    kinds = [f.kind for f in features_of(simulate_scan(box((1.3, 0.0), 0.15, obj=1), rng))]
    assert "edge" not in kinds


def test_cylinder_before_a_wall_has_edges_at_its_sides(rng: np.random.Generator) -> None:
    scene: list[Wall | Arc] = [
        Arc(CYLINDER.center, CYLINDER.radius, obj=1),
        Wall((2.3, -2.0), (2.3, 2.0), obj=0),
    ]
    features = features_of(simulate_scan(scene, rng))
    assert [f.kind for f in features] == ["segment", "edge", "cylinder", "edge", "segment"]
    assert [features[1].nearer_side, features[3].nearer_side] == ["left", "right"]


# ------------------------------------------------------------------- short runs and thresholds


def test_short_segments_give_no_features(rng: np.random.Generator) -> None:
    for count in (1, 2, 4):
        scan = simulate_scan([WALL_1P5], rng)
        keep = np.zeros(N_BEAMS, dtype=bool)
        keep[100 : 100 + count] = True
        scan["flag"][~keep] = 1
        scan["segment"][~keep] = -1
        scan["points_xy"][~keep] = np.nan
        assert features_of(scan) == []


def test_two_point_segment_beside_a_wall_makes_nothing_up(rng: np.random.Generator) -> None:
    scan = simulate_scan([WALL_1P5], rng)
    # Two samples pulled 0.5 m nearer, a segment of their own between two parts of the wall.
    scan["points_xy"][100:102] -= 0.5 * np.array([1.0, 0.0])
    scan["range_m"][100:102] -= 0.5
    seg = np.zeros(N_BEAMS, dtype=np.int32)
    seg[100:102] = 1
    seg[102:] = 2
    scan["segment"] = seg
    kinds = [f.kind for f in features_of(scan)]
    assert kinds == ["segment", "segment"]


# ------------------------------------------------------------------------- the arithmetic
def test_corner_arithmetic_is_the_numpy_formulation(rng: np.random.Generator) -> None:
    # The kernel's matrix products are BLAS's, as numpy's @ takes them: equal to the last
    # bit where numpy and numba call one BLAS (as here); 1e-12 allows two builds of it.
    for _ in range(100):
        a1, a2 = rng.uniform(-math.pi, math.pi, 2)
        rho1, rho2 = rng.uniform(0.5, 2.0, 2)
        covs = [(m @ m.T) * 1e-4 for m in rng.normal(size=(2, 2, 2))]
        c1, s1, c2, s2 = math.cos(a1), math.sin(a1), math.cos(a2), math.sin(a2)
        ok, x, y, cov = extraction_kernels.intersection(
            c1, s1, rho1, covs[0], c2, s2, rho2, covs[1]
        )
        det = c1 * s2 - s1 * c2
        assert ok == (abs(det) >= 1e-9)
        if not ok:
            continue
        k1x, k1y, k2x, k2y = s2 / det, -c2 / det, -s1 / det, c1 / det
        px, py = k1x * rho1 + k2x * rho2, k1y * rho1 + k2y * rho2
        d1, d2 = -s1 * px + c1 * py, -s2 * px + c2 * py
        j1 = np.array([[-k1x * d1, k1x], [-k1y * d1, k1y]])
        j2 = np.array([[-k2x * d2, k2x], [-k2y * d2, k2y]])
        assert (x, y) == (px, py)
        expected = j1 @ covs[0] @ j1.T + j2 @ covs[1] @ j2.T
        np.testing.assert_allclose(cov, expected, rtol=1e-12, atol=0.0)
