"""What a feature is: its kinds, parameters and covariances, and its JSON form.

Feature conventions (all vehicle frame, metres and radians)
------------------------------------------------------------
=========  ==========================  ===================================  ===
kind       ``params``                  ``covariance``                       dof
=========  ==========================  ===================================  ===
segment    (α, ρ): ``x cos α + y sin   2×2 over (α [rad], ρ [m]); ρ ≥ 0,    2
           α = ρ``, the line's normal  α in (-π, π], the normal pointing
           angle and its distance      from the vehicle origin to the line
           from the vehicle origin
corner     (x, y) of the intersection  2×2 over (x, y), m², from both       2
                                       lines' (α, ρ) covariances
edge       (x, y) of the nearer        2×2 over (x, y), m²: the end         2
           surface's end, half-way     sample's covariance plus the gap's
           across the gap to the next  (uniform, width²/12, along the
           beam seen                   surface)
cylinder   (cx, cy, r)                 3×3 over (cx, cy, r), m²             3
=========  ==========================  ===================================  ===

Comparing a segment's α with a reference must wrap the difference to (-π, π]. When a line
passes close to the vehicle origin (ρ → 0) α becomes ill-defined; the covariance says so.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np
from numpy.typing import NDArray

from agent.arrays import FloatArray

FeatureKind = Literal["segment", "corner", "edge", "cylinder"]
Side = Literal["left", "right"]
IndexArray = NDArray[np.intp]


@dataclass(frozen=True, eq=False)
class Feature:
    """One feature of a scan, in the vehicle frame.

    Attributes
    ----------
    kind : "segment", "corner", "edge" or "cylinder".
    params : (dof,) float64; see the module docstring (segment (α, ρ); corner and edge
        (x, y); cylinder (cx, cy, r)).
    covariance : (dof, dof) float64 over ``params``; dof 2, or 3 for a cylinder.
    reflectivity : relative to the calibration target (off-white cardboard = 1); NaN when
        fewer than ``reflectivity_min_samples`` samples were usable.
    samples : indices into the scan's arrays of the samples the feature was fitted to (for a
        corner, both lines' samples; for an edge, the nearer surface's end sample; for a
        cylinder, all its run's samples, though the most oblique are left out of the fit).
    endpoints : (2, 2) for segments: the first and last sample projected on the line, in
        sample order.
    point : (2,) for corners and edges (the same as ``params``).
    center, radius : (2,) and m, for cylinders.
    nearer_side : for edges: "left" when the nearer (occluding) surface lies at the higher
        scan angle (counter-clockwise of the edge, to the left seen from the sensor),
        "right" when at the lower.
    """

    kind: FeatureKind
    params: FloatArray
    covariance: FloatArray
    reflectivity: float
    samples: IndexArray
    endpoints: FloatArray | None = None
    point: FloatArray | None = None
    center: FloatArray | None = None
    radius: float | None = None
    nearer_side: Side | None = None

    @property
    def dof(self) -> int:
        """Degrees of freedom of ``params`` (the χ² dof of a NEES test)."""
        return int(self.params.size)


_COVARIANCE_PARAMS: dict[str, str] = {
    "segment": "alpha_rad, rho_m (vehicle frame)",
    "corner": "x_m, y_m (vehicle frame)",
    "edge": "x_m, y_m (vehicle frame)",
    "cylinder": "cx_m, cy_m, r_m (vehicle frame)",
}


def feature_to_dict(
    feature: Feature, to_world: Callable[[FloatArray], FloatArray] | None = None
) -> dict[str, Any]:
    """A JSON-ready description of ``feature``.

    ``to_world`` maps (k, 2) vehicle-frame points to the world frame (None: identity). Only
    positions are mapped: ``covariance`` stays over the vehicle-frame parameters that
    ``covariance_params`` names. A NaN reflectivity becomes None (JSON has no NaN).
    """

    def world(points: FloatArray) -> list[list[float]]:
        pts = np.asarray(points, dtype=np.float64).reshape(-1, 2)
        mapped = pts if to_world is None else np.asarray(to_world(pts), dtype=np.float64)
        return [[float(v) for v in row] for row in mapped.reshape(-1, 2)]

    out: dict[str, Any] = {"kind": feature.kind}
    if feature.kind == "segment" and feature.endpoints is not None:
        out["endpoints_world"] = world(feature.endpoints)
    elif feature.kind in ("corner", "edge") and feature.point is not None:
        out["point_world"] = world(feature.point)[0]
        if feature.nearer_side is not None:
            out["nearer_side"] = feature.nearer_side
    elif feature.kind == "cylinder" and feature.center is not None:
        out["center_world"] = world(feature.center)[0]
        out["radius_m"] = float(feature.radius) if feature.radius is not None else None
    out["covariance"] = [[float(v) for v in row] for row in feature.covariance]
    out["covariance_params"] = _COVARIANCE_PARAMS[feature.kind]
    out["reflectivity"] = None if math.isnan(feature.reflectivity) else float(feature.reflectivity)
    return out
