"""Synthetic scans with the sensor's noise model, for the feature extractor's tests.

The helper :func:`simulate_scan` casts the 256 beams of a ±20° scan from a centre of scanning
at (0.3, 0) (the head ahead of the vehicle origin) onto true surfaces and draws each sample
with the sensor's noise: σ_r = 1.6e-3·r⁴/(cos(incidence)·cos θ) m along the beam (eq. 6.20
with the signal's Lambertian and aperture factors), r·1e-4 across it. Intensity follows
eq. 6.10-6.11 with the beam's own incidence. Beams meeting a surface more obliquely than 84°
(cos < 0.1) are dropped, as the filter's signal gate would; segment ids are contiguous runs of
one object (a wall, a polyline, a box, a cylinder) between dropped samples.

Statistical checks use fixed seeds and state their tolerance: NEES means over N scans have a
standard deviation of sqrt(2·dof/N) (a χ² variable of dof degrees of freedom has variance
2·dof), and the bands are three of those.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from agent.perception.features import Feature, FeatureSettings, extract_features
from agent.perception.features.samples import Samples, prepare_samples

NOISE_CURRENT_A = 36.5e-12  # the chapter's measured I_n
INTENSITY_ERROR = FeatureSettings().intensity_model_sigma
UNBIASED = FeatureSettings(range_bias_fraction=0.0)
S_CARDBOARD = 2.59e-8  # A·m², eq. 6.10-6.12
ORIGIN = (0.3, 0.0)
N_BEAMS = 256
HALF_FOV = math.radians(20.0)


@dataclass(frozen=True)
class Wall:
    """A straight surface from p0 to p1 (m, vehicle frame)."""

    p0: tuple[float, float]
    p1: tuple[float, float]
    reflectivity: float = 1.0
    obj: int = 0


@dataclass(frozen=True)
class Arc:
    """A circle (convex: a cylinder seen from outside) or a concave arc seen from inside.

    ``span_rad`` limits a concave arc to polar angles about the centre in [lo, hi].
    """

    center: tuple[float, float]
    radius: float
    reflectivity: float = 1.0
    obj: int = 0
    concave: bool = False
    span_rad: tuple[float, float] = (-math.pi, math.pi)


def box(
    center: tuple[float, float], half: float, obj: int, reflectivity: float = 1.0
) -> list[Wall]:
    cx, cy = center
    c = [
        (cx - half, cy - half),
        (cx - half, cy + half),
        (cx + half, cy + half),
        (cx + half, cy - half),
    ]
    return [Wall(c[k], c[(k + 1) % 4], reflectivity, obj) for k in range(4)]


def simulate_scan(
    surfaces: Sequence[Wall | Arc],
    rng: np.random.Generator,
    *,
    origin: tuple[float, float] = ORIGIN,
    flat_intensity: bool = False,
    drop: slice | None = None,
) -> dict[str, Any]:
    """Keyword arguments for :func:`extract_features` (plus ``truth_obj``) of one scan."""
    theta = np.linspace(-HALF_FOV, HALF_FOV, N_BEAMS)
    b = np.stack([np.cos(theta), np.sin(theta)], axis=1)
    o = np.array(origin)
    best_t = np.full(N_BEAMS, np.inf)
    normal = np.full((N_BEAMS, 2), np.nan)
    refl = np.full(N_BEAMS, np.nan)
    obj = np.full(N_BEAMS, -1)
    for srf in surfaces:
        if isinstance(srf, Wall):
            p0, d = np.array(srf.p0), np.array(srf.p1) - np.array(srf.p0)
            # o + t b = p0 + u d  →  [b, -d] (t, u) = p0 - o
            det = b[:, 0] * -d[1] - b[:, 1] * -d[0]
            rhs = p0 - o
            with np.errstate(divide="ignore", invalid="ignore"):
                t = (rhs[0] * -d[1] - rhs[1] * -d[0]) / det
                u = (b[:, 0] * rhs[1] - b[:, 1] * rhs[0]) / det
            hit = (np.abs(det) > 1e-12) & (t > 0) & (u >= 0) & (u <= 1)
            nrm = np.broadcast_to(np.array([-d[1], d[0]]) / np.hypot(*d), (N_BEAMS, 2))
        else:
            c = np.array(srf.center)
            bb = b @ (o - c)
            cc = float((o - c) @ (o - c)) - srf.radius**2
            disc = bb * bb - cc
            with np.errstate(invalid="ignore"):
                root = np.sqrt(disc)
                t = -bb + root if srf.concave else -bb - root
            pts = o + t[:, None] * b
            phi = np.arctan2(pts[:, 1] - c[1], pts[:, 0] - c[0])
            hit = (disc > 0) & (t > 0) & (phi >= srf.span_rad[0]) & (phi <= srf.span_rad[1])
            nrm = (pts - c) / srf.radius
        closer = hit & (t < best_t)
        best_t[closer] = t[closer]
        normal[closer] = nrm[closer]
        refl[closer] = srf.reflectivity
        obj[closer] = srf.obj
    with np.errstate(invalid="ignore"):
        cos_inc = np.abs(np.sum(b * normal, axis=1))
    valid = np.isfinite(best_t) & (cos_inc >= 0.1) & (best_t >= 0.4) & (best_t <= 2.5)
    if drop is not None:
        valid[drop] = False
    r_true = np.where(valid, best_t, np.nan)
    sigma_r = 1.6e-3 * r_true**4 / (cos_inc * np.cos(theta))
    sigma_a = r_true * 1e-4
    across = np.stack([-b[:, 1], b[:, 0]], axis=1)
    e_r = rng.standard_normal(N_BEAMS) * sigma_r
    e_a = rng.standard_normal(N_BEAMS) * sigma_a
    range_m = r_true + e_r
    points = o + range_m[:, None] * b + e_a[:, None] * across
    cov = (sigma_r**2)[:, None, None] * b[:, :, None] * b[:, None, :] + (sigma_a**2)[
        :, None, None
    ] * across[:, :, None] * across[:, None, :]
    intensity = np.where(valid, refl * S_CARDBOARD * cos_inc * np.cos(theta) / r_true**2, 1e-12)
    # The intensity model's own error (``FeatureSettings.intensity_model_sigma``), drawn
    # last so the range noise of a seed is the same with or without it.
    intensity *= np.exp(INTENSITY_ERROR * rng.standard_normal(N_BEAMS))
    if flat_intensity:
        intensity = np.where(valid, float(np.nanmedian(intensity[valid])), 1e-12)
    # Segment ids: runs of one object between dropped samples.
    seg = np.full(N_BEAMS, -1, dtype=np.int32)
    new_run = valid & ~(np.r_[False, valid[:-1]] & (np.r_[-2, obj[:-1]] == obj))
    seg[valid] = (np.cumsum(new_run) - 1)[valid]
    return {
        "points_xy": points,
        "covariance": cov,
        "segment": seg,
        "flag": np.where(valid, 0, 1).astype(np.uint8),
        "intensity_A": intensity,
        "range_m": range_m,
        "origin_xy": np.broadcast_to(o, (N_BEAMS, 2)).copy(),
        "beam_angle_rad": theta,
        "signal_constant_Am2": S_CARDBOARD,
        "truth_obj": obj,
    }


def features_of(scan: dict[str, Any], **kw: Any) -> list[Feature]:
    # The synthetic intensities follow the beam's own incidence (a viewpoint at the centre
    # of scanning: baseline 0) and carry no noise beyond the model's; the noise current
    # lets intensities join the cylinder fits as in the features stage. The synthetic
    # ranges have independent errors and no calibration bias.
    args = {k: v for k, v in scan.items() if k != "truth_obj"}
    kw = {
        "baseline_m": 0.0,
        "noise_current_A": NOISE_CURRENT_A,
        "settings": UNBIASED,
        **kw,
    }
    return extract_features(**args, **kw)


def of_kind(features: list[Feature], kind: str) -> list[Feature]:
    return [f for f in features if f.kind == kind]


def line_truth(p0: tuple[float, float], p1: tuple[float, float]) -> np.ndarray:
    """(α, ρ) of the line through p0 and p1, ρ ≥ 0."""
    d = np.subtract(p1, p0)
    n = np.array([-d[1], d[0]]) / np.hypot(*d)
    rho = float(n @ p0)
    if rho < 0:
        n, rho = -n, -rho
    return np.array([math.atan2(n[1], n[0]), rho])


def line_error(f: Feature, truth: np.ndarray) -> np.ndarray:
    e = np.array(f.params - truth)
    e[0] = math.remainder(float(e[0]), 2 * math.pi)
    return e


def nees(err: np.ndarray, cov: np.ndarray) -> float:
    return float(err @ np.linalg.solve(cov, err))


def within_3_sigma(err: np.ndarray, cov: np.ndarray) -> bool:
    """Every component of ``err`` within three of its marginal σ."""
    return bool(np.all(np.abs(err) <= 3.0 * np.sqrt(np.diag(cov))))


def reversed_scan(scan: dict[str, Any]) -> dict[str, Any]:
    """The same scan swept the other way (the mirror sweeps in both directions)."""
    out = {k: (v[::-1].copy() if isinstance(v, np.ndarray) else v) for k, v in scan.items()}
    seg = out["segment"]
    valid = seg >= 0
    seg[valid] = seg[valid].max() - seg[valid]  # ids number the runs in scan order
    return out


WALL_1P5 = Wall((1.8, -2.0), (1.8, 2.0))  # 1.5 m ahead of the centre of scanning
L_CORNER = (1.8, 0.0)
L_WALLS = [Wall((1.3, -0.8), L_CORNER), Wall(L_CORNER, (1.3, 0.8))]  # an inside corner, 64°


def oblique_wall() -> Wall:
    """A wall the beams meet from 0.6 m (at −20°) to 2.4 m (at +20°)."""
    o = np.array(ORIGIN)
    p0 = o + 0.6 * np.array([math.cos(-HALF_FOV), math.sin(-HALF_FOV)])
    p1 = o + 2.4 * np.array([math.cos(HALF_FOV), math.sin(HALF_FOV)])
    a, b = p0 - 0.05 * (p1 - p0), p1 + 0.05 * (p1 - p0)
    return Wall((float(a[0]), float(a[1])), (float(b[0]), float(b[1])))


BOX_AND_WALL = [*box((1.3, 0.0), 0.15, obj=1), Wall((2.3, -2.0), (2.3, 2.0), obj=0)]
CYLINDER = Arc((1.5, 0.0), 0.1)  # r = 0.1 m, centre 1.2 m from the centre of scanning
SMALL_FAR_CYLINDER = Arc((2.1, 0.0), 0.05)  # r = 0.05 m at 1.8 m


def stacked(scan: dict[str, Any], neighbour_correlation: float = 0.13) -> Samples:
    """A synthetic scan's samples as the extractor stacks them (every row filled)."""
    args = {k: v for k, v in scan.items() if k not in ("truth_obj", "signal_constant_Am2")}
    samples = prepare_samples(
        **args, signal_constant=S_CARDBOARD, baseline_m=0.05, noise_current_A=NOISE_CURRENT_A,
        intensity_model_sigma=INTENSITY_ERROR, neighbour_correlation=neighbour_correlation,
    )  # fmt: skip
    assert samples is not None
    return samples
