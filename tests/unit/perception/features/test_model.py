"""Features as JSON (:mod:`agent.perception.features.model`)."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from agent.perception.features import feature_to_dict
from tests.unit.perception.features.scans import (
    BOX_AND_WALL,
    CYLINDER,
    L_WALLS,
    WALL_1P5,
    features_of,
    simulate_scan,
)


def test_feature_to_dict_is_json_with_world_positions(rng: np.random.Generator) -> None:
    features = [
        f
        for scene in ([CYLINDER], L_WALLS, BOX_AND_WALL)
        for f in features_of(simulate_scan(scene, rng))
    ]
    assert {f.kind for f in features} == {"segment", "corner", "edge", "cylinder"}

    def shift(points: np.ndarray) -> np.ndarray:
        return np.asarray(points + np.array([10.0, -5.0]))

    for f in features:
        plain = feature_to_dict(f, None)
        moved = feature_to_dict(f, shift)
        json.dumps(moved, allow_nan=False)
        assert moved["kind"] == f.kind
        assert np.shape(moved["covariance"]) == (f.dof, f.dof)
        assert moved["covariance_params"].endswith("(vehicle frame)")
        key = {
            "segment": "endpoints_world",
            "corner": "point_world",
            "edge": "point_world",
            "cylinder": "center_world",
        }[f.kind]
        assert np.array(moved[key]) - np.array(plain[key]) == pytest.approx(
            np.broadcast_to([10.0, -5.0], np.shape(plain[key]))
        )
        if f.kind == "cylinder":
            assert moved["radius_m"] == pytest.approx(f.params[2])
        if f.kind == "edge":
            assert moved["nearer_side"] in ("left", "right")


def test_feature_to_dict_writes_unknown_reflectivity_as_null(rng: np.random.Generator) -> None:
    scan = simulate_scan([WALL_1P5], rng)
    scan["intensity_A"][:] = 0.0  # no usable intensity
    (seg,) = features_of(scan)
    assert math.isnan(seg.reflectivity)
    assert feature_to_dict(seg, None)["reflectivity"] is None
