"""Scoring perception against simulation truth: filtering and features, scan by scan.

For one scan, :func:`score_scan` compares the filter's flags with the truth (phantoms: kept
samples more than 5 σ from the truth; losses: visible samples away from discontinuities that
were dropped) and matches features to the world's true surfaces:

* a true **segment** is a straight face (a wall piece or a box side) whose visible, in-range
  samples span at least 0.15 m, all within 2 m; it is detected when a reported segment takes
  at least half of its samples and its line lies within 5° and 5 cm of the face's, or
  within its own covariance (NEES below the χ² 99.9 % point: far at 1.5-2 m, a wall piece of
  0.2-0.4 m has σ_α of 2-3°, so a fixed 5° is under 3σ for it);
* a true **cylinder** of radius at least 5 cm within 2 m with 5 or more visible samples is
  detected by a reported cylinder that takes at least half of its samples, most of whose
  samples are its own, within 5 cm (centre) and 2 cm (radius) or within its own covariance
  (the χ² 99.9 % point);
* a reported feature matching nothing true is **false**: a segment or cylinder that does
  not describe the surface most of its samples hit (neither within the tolerances above
  nor within its own covariance: NEES below the χ² 99.9 % point, so a short, far segment
  whose stated uncertainty covers the truth is not false), a corner or an edge farther than
  5 cm from any true vertex (a face's end, or where two faces cross: two walls, or a wall
  through a box, meet in a real corner that neither face's end marks) or cylinder surface,
  and not within its own covariance of one (the same χ² 99.9 % point: an edge's position
  along the surface is uncertain by the gap to the next beam seen, 3-15 cm where samples
  are dropped or far away, so a fixed 5 cm would call honest edges false).

Features are **associated** with the true surfaces by the samples they share, never by
closeness: a reported segment belongs to the face (a cylinder to the circle) that most of its
samples hit (the simulator's truth names the obstacle of every sample, the face is the one of
that obstacle the sample lies on). Normalised estimation errors squared (NEES) are kept for
every associated segment (α, ρ: 2 dof) and cylinder (cx, cy, r: 3 dof), detected or not:
a feature that misses its surface is not left out of the consistency figures because it
missed. They are summarised by their mean and by their tails, the fractions above the χ²
95 % point (5 % when the covariances are honest, more when they are too small) and below
the 5 % point (5 % when honest, more when they are inflated: a feature "within its own
covariance" is no excuse when the covariance is too large). The mean over the detected
features alone (the figure this module reported first) is kept as ``*_nees_mean_detected``.

Three kinds of error the general scenes draw too rarely are counted apart (see
:mod:`agent.sim.perception_scenes` for scenes that provoke them):

* **bridging segments**: a reported segment whose samples fall on two faces of one obstacle
  meeting at a vertex, the lesser at least ``BRIDGE_MIN_SAMPLES`` and
  ``BRIDGE_MIN_FRACTION`` of them (one line fitted across a bend), over the vertices seen
  (two faces meeting, each with at least ``VERTEX_MIN_SAMPLES`` samples seen), and those
  of them not covered by their covariance against the face most of their samples hit
  (NEES above the χ² 99.9 % point);
* **grazing segments**: associated segments whose samples meet their face at a median
  cosine of incidence below ``GRAZING_MAX_COS`` (beam within 30° of the wall): their NEES
  tails apart, and the fraction whose error is beyond 5° and outside their own covariance
  (χ² 99.9 %);
* **wrong cylinders**: associated cylinders whose samples fall on two true circles (as for
  bridging segments), or whose radius is off by more than ``WRONG_RADIUS_FRACTION``; and the
  fraction of those not covered by their covariance (NEES above the χ² 99.9 % point).

Relative reflectivity errors are kept for detected features.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy import stats

from agent.arrays import FloatArray
from agent.perception.features import Feature
from agent.perception.filtering import SampleFlag
from agent.sim.simulator import ScanTruth
from agent.sim.world import World

SEGMENT_MIN_LENGTH_M = 0.15
CYLINDER_MIN_RADIUS_M = 0.05
MAX_RANGE_M = 2.0
MATCH_ANGLE_RAD = math.radians(5.0)
MATCH_DISTANCE_M = 0.05
MATCH_RADIUS_M = 0.02
# χ² 99.9 % points for 2 and 3 degrees of freedom: a feature this consistent with a true
# surface describes it, however loosely.
CONSISTENT_NEES = {2: 13.82, 3: 16.27}
# The χ² 95 % and 5 % points by degrees of freedom: the NEES tails' bounds.
NEES_UPPER = {k: float(stats.chi2.ppf(0.95, k)) for k in (2, 3)}
NEES_LOWER = {k: float(stats.chi2.ppf(0.05, k)) for k in (2, 3)}
# A feature's samples "fall on" a second surface when it holds at least this many and this
# fraction of them: the boundary between two fitted pieces may stray a sample or two from
# the vertex (three at most, in refine_window's reach, at a shallow bend), which is not a
# line across the bend.
BRIDGE_MIN_SAMPLES = 5
BRIDGE_MIN_FRACTION = 0.2
VERTEX_MIN_SAMPLES = 10
GRAZING_MAX_COS = math.cos(math.radians(60.0))
WRONG_RADIUS_FRACTION = 0.15


@dataclass
class Tally:
    """Running totals over scans."""

    valid: int = 0
    phantoms: int = 0
    visible: int = 0
    lost: int = 0
    true_segments: int = 0
    found_segments: int = 0
    true_cylinders: int = 0
    found_cylinders: int = 0
    false_features: int = 0
    false_by_kind: dict[str, int] = field(default_factory=dict)
    scans: int = 0
    segment_nees: list[float] = field(default_factory=list)
    cylinder_nees: list[float] = field(default_factory=list)
    # (scan, true face) -> (α, ρ) error, and (scan, true circle) -> (cx, cy, r) error, of
    # the matched features: for comparing two extractors on the surfaces both found.
    segment_errors: dict[tuple[int, int], FloatArray] = field(default_factory=dict)
    cylinder_errors: dict[tuple[int, int], FloatArray] = field(default_factory=dict)
    reflectivity_rel_err: list[float] = field(default_factory=list)
    # NEES of every associated feature (by shared samples), detected or not.
    segment_nees_all: list[float] = field(default_factory=list)
    cylinder_nees_all: list[float] = field(default_factory=list)
    vertices_seen: int = 0
    bridging_segments: int = 0
    bridging_uncovered: int = 0
    grazing_nees: list[float] = field(default_factory=list)
    grazing_wrong: int = 0  # beyond 5° and outside their covariance
    cylinders_associated: int = 0
    cylinders_wrong: int = 0
    cylinders_wrong_uncovered: int = 0

    def summary(self) -> dict[str, Any]:
        def rate(a: int, b: int) -> float | None:
            return a / b if b else None

        def mean(v: list[float]) -> float | None:
            return float(np.mean(v)) if v else None

        return {
            "scans": self.scans,
            "phantom_rate": rate(self.phantoms, self.valid),
            "valid_loss_rate": rate(self.lost, self.visible),
            "segment_detection_rate": rate(self.found_segments, self.true_segments),
            "cylinder_detection_rate": rate(self.found_cylinders, self.true_cylinders),
            "false_features_per_scan": rate(self.false_features, self.scans),
            "segment_nees_mean": mean(self.segment_nees_all),
            "segment_nees_dof": 2,
            "cylinder_nees_mean": mean(self.cylinder_nees_all),
            "cylinder_nees_dof": 3,
            "segment_nees_mean_detected": mean(self.segment_nees),
            "cylinder_nees_mean_detected": mean(self.cylinder_nees),
            "nees_tails": {
                "segment": nees_tails(self.segment_nees_all, 2),
                "cylinder": nees_tails(self.cylinder_nees_all, 3),
            },
            "nees_count": {
                "segment": len(self.segment_nees_all),
                "cylinder": len(self.cylinder_nees_all),
            },
            "segment_rho_rms_m": (
                float(np.sqrt(np.mean([e[1] ** 2 for e in self.segment_errors.values()])))
                if self.segment_errors
                else None
            ),
            "reflectivity_rel_err_median": (
                float(np.median(self.reflectivity_rel_err)) if self.reflectivity_rel_err else None
            ),
            "false_features_by_kind": dict(self.false_by_kind),
            "true_segments": self.true_segments,
            "true_cylinders": self.true_cylinders,
            "bend": {
                "vertices_seen": self.vertices_seen,
                "bridging_segments": self.bridging_segments,
                "bridging_rate": rate(self.bridging_segments, self.vertices_seen),
                "bridging_uncovered_rate": rate(self.bridging_uncovered, self.vertices_seen),
            },
            "grazing": {
                "segments": len(self.grazing_nees),
                "nees_mean": mean(self.grazing_nees),
                "nees_tails": nees_tails(self.grazing_nees, 2),
                "wrong_uncovered_rate": rate(self.grazing_wrong, len(self.grazing_nees)),
            },
            "cylinder_errors": {
                "associated": self.cylinders_associated,
                "wrong_rate": rate(self.cylinders_wrong, self.cylinders_associated),
                "wrong_uncovered_rate": rate(
                    self.cylinders_wrong_uncovered, self.cylinders_associated
                ),
            },
        }


def nees_tails(nees: list[float], dof: int) -> dict[str, float | None]:
    """Fractions of ``nees`` above the χ² 95 % point and below its 5 % point for ``dof``
    (about 0.05 each when the covariances describe the errors); None when empty."""
    if not nees:
        return {"above_95": None, "below_5": None}
    v = np.asarray(nees)
    return {
        "above_95": float(np.mean(v > NEES_UPPER[dof])),
        "below_5": float(np.mean(v < NEES_LOWER[dof])),
    }


def paired_accuracy(a: Tally, b: Tally) -> dict[str, Any]:
    """RMS errors of two extractors over the true surfaces *both* detected (same scans).

    Each tally's own RMS is over the surfaces it found, so an extractor that finds more,
    harder surfaces (far, oblique, partly hidden) looks worse there; over the common ones
    the comparison is like for like. For each of ``segment_alpha`` (rad), ``segment_rho``
    (m), ``cylinder_center`` (m) and ``cylinder_radius`` (m): ``*_rms`` and
    ``*_median_abs`` as pairs (a, b), and ``*_a_better``, the fraction of surfaces on which
    a's error is the smaller. ``segments`` and ``cylinders`` count the common surfaces;
    None where there are none.
    """
    seg = sorted(a.segment_errors.keys() & b.segment_errors.keys())
    cyl = sorted(a.cylinder_errors.keys() & b.cylinder_errors.keys())
    out: dict[str, Any] = {"segments": len(seg), "cylinders": len(cyl)}
    for name, table, keys, cols in (
        ("segment_alpha", "segment_errors", seg, slice(0, 1)),
        ("segment_rho", "segment_errors", seg, slice(1, 2)),
        ("cylinder_center", "cylinder_errors", cyl, slice(0, 2)),
        ("cylinder_radius", "cylinder_errors", cyl, slice(2, 3)),
    ):
        if not keys:
            out[f"{name}_rms"] = out[f"{name}_median_abs"] = [None, None]
            out[f"{name}_a_better"] = None
            continue
        size = [
            np.sqrt(np.sum(np.square(np.array([getattr(t, table)[k] for k in keys])[:, cols]), 1))
            for t in (a, b)
        ]
        out[f"{name}_rms"] = [float(np.sqrt(np.mean(v * v))) for v in size]
        out[f"{name}_median_abs"] = [float(np.median(v)) for v in size]
        out[f"{name}_a_better"] = float(np.mean(size[0] < size[1]))
    return out


def away_from_edges(
    truth: ScanTruth, range_interval_m: tuple[float, float], margin: int = 3
) -> np.ndarray:
    """Samples whose beam, and its ``margin`` neighbours each side, meet one surface smoothly.

    Visible from the detector, the same obstacle throughout, no step over 2 cm between
    neighbours, within ``range_interval_m``, and not within ``margin`` of the scan's ends.
    """
    steady = truth.visible & (truth.obstacle >= 0)
    smooth = np.abs(np.diff(truth.range_m, prepend=np.nan)) < 0.02
    for k in range(-margin, margin + 1):
        steady &= np.roll(truth.obstacle, k) == truth.obstacle
        steady &= np.roll(truth.visible & smooth, k)
    steady[:margin] = steady[-margin:] = False
    lo, hi = range_interval_m
    with np.errstate(invalid="ignore"):
        return steady & (truth.range_m >= lo) & (truth.range_m <= hi)


def _to_vehicle(world_xy: FloatArray, pose: tuple[float, float, float]) -> FloatArray:
    x, y, yaw = pose
    c, s = math.cos(yaw), math.sin(yaw)
    d = np.asarray(world_xy, dtype=np.float64) - (x, y)
    return np.stack([c * d[..., 0] + s * d[..., 1], -s * d[..., 0] + c * d[..., 1]], axis=-1)


def _faces_hit(world: World, truth: ScanTruth) -> np.ndarray:
    """Index of the world segment each truth beam hit (-1: a circle or nothing)."""
    hit = np.isfinite(truth.range_m)
    point = truth.beam_origin_xy + np.nan_to_num(truth.range_m)[:, None] * np.stack(
        [np.cos(truth.beam_heading_rad), np.sin(truth.beam_heading_rad)], axis=-1
    )
    face = np.full(truth.range_m.size, -1)
    a, b = world.segments_start, world.segments_end
    if a.shape[0] == 0 or not np.any(hit):
        return face
    e = b - a
    rel = point[hit][:, None, :] - a[None, :, :]
    u = np.clip(np.einsum("nmk,mk->nm", rel, e) / np.sum(e * e, axis=1), 0.0, 1.0)
    dist = np.linalg.norm(rel - u[..., None] * e[None], axis=2)
    owner = truth.obstacle[hit][:, None] == world.segments_obstacle[None, :]
    dist = np.where(owner, dist, np.inf)
    best = np.argmin(dist, axis=1)
    face[np.flatnonzero(hit)] = np.where(np.isfinite(dist[np.arange(best.size), best]), best, -1)
    return face


def _vertices(world: World) -> FloatArray:
    """(k, 2) world-frame vertices: every face's ends and every point where two faces cross.

    Faces of different obstacles may cross (scenes place walls and boxes independently):
    where they do, the visible surface turns a corner that no face's end marks.
    """
    a, b = world.segments_start, world.segments_end
    ends = np.concatenate([a, b])
    if a.shape[0] < 2:
        return ends
    e = b - a
    d = a[None, :, :] - a[:, None, :]  # d[i, j] = a_j − a_i
    cross = e[:, None, 0] * e[None, :, 1] - e[:, None, 1] * e[None, :, 0]  # e_i × e_j
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (d[..., 0] * e[None, :, 1] - d[..., 1] * e[None, :, 0]) / cross  # along face i
        u = (d[..., 0] * e[:, None, 1] - d[..., 1] * e[:, None, 0]) / cross  # along face j
    inside = (t >= 0.0) & (t <= 1.0) & (u >= 0.0) & (u <= 1.0) & np.triu(cross != 0.0, 1)
    i, _ = np.nonzero(inside)
    return np.concatenate([ends, a[i] + t[inside][:, None] * e[i]])


def _line_params(p: FloatArray, q: FloatArray) -> tuple[float, float]:
    """(α, ρ) of the line through p and q: x·cos α + y·sin α = ρ, ρ ≥ 0."""
    d = q - p
    alpha = math.atan2(d[0], -d[1])
    rho = p[0] * math.cos(alpha) + p[1] * math.sin(alpha)
    if rho < 0:
        alpha, rho = alpha + math.pi, -rho
    return math.remainder(alpha, math.tau), rho


def _line_error(feature: Feature, alpha: float, rho: float) -> FloatArray:
    fa, fr = float(feature.params[0]), float(feature.params[1])
    if fr < 0:
        fa, fr = fa + math.pi, -fr
    return np.array([math.remainder(fa - alpha, math.tau), fr - rho])


def score_scan(
    tally: Tally,
    world: World,
    truth: ScanTruth,
    range_m: FloatArray,
    sigma_m: FloatArray,
    flags: np.ndarray,
    features: list[Feature],
    reference_pose: tuple[float, float, float],
) -> None:
    """Add one scan's figures to ``tally`` (see the module docstring)."""
    tally.scans += 1
    valid = flags == SampleFlag.VALID
    with np.errstate(invalid="ignore"):
        far = ~(np.abs(range_m - truth.range_m) <= 5.0 * sigma_m)
    tally.valid += int(valid.sum())
    tally.phantoms += int((valid & far).sum())
    steady = away_from_edges(truth, (0.4, 2.5))
    tally.visible += int(steady.sum())
    tally.lost += int((steady & ~valid).sum())

    seen = truth.visible & (truth.range_m >= 0.4) & (truth.range_m <= 2.5)
    point_world = truth.beam_origin_xy + np.nan_to_num(truth.range_m)[:, None] * np.stack(
        [np.cos(truth.beam_heading_rad), np.sin(truth.beam_heading_rad)], axis=-1
    )
    face = _faces_hit(world, truth)
    used: set[int] = set()
    segments = [i for i, f in enumerate(features) if f.kind == "segment"]
    cylinders = [i for i, f in enumerate(features) if f.kind == "cylinder"]

    # True segments.
    for fi in np.unique(face[seen & (face >= 0)]):
        members = np.flatnonzero(seen & (face == fi))
        pts = point_world[members]
        if (
            np.linalg.norm(pts[-1] - pts[0]) < SEGMENT_MIN_LENGTH_M
            or np.nanmax(truth.range_m[members]) > MAX_RANGE_M
        ):
            continue
        tally.true_segments += 1
        a = _to_vehicle(world.segments_start[fi], reference_pose)
        b = _to_vehicle(world.segments_end[fi], reference_pose)
        alpha, rho = _line_params(a, b)
        for i in segments:
            f = features[i]
            share = np.intersect1d(f.samples, members).size
            err = _line_error(f, alpha, rho)
            if share >= 0.5 * members.size and (
                (abs(err[0]) < MATCH_ANGLE_RAD and abs(err[1]) < MATCH_DISTANCE_M)
                or _consistent(err, f.covariance)
            ):
                tally.found_segments += 1
                used.add(i)
                tally.segment_nees.append(float(err @ np.linalg.solve(f.covariance, err)))
                tally.segment_errors[(tally.scans, int(fi))] = err
                _reflectivity(tally, f, world, truth, f.samples)
                break
    # True cylinders.
    owner = truth.obstacle
    for ci, (centre, radius) in enumerate(
        zip(world.circles_center, world.circles_radius, strict=True)
    ):
        oid = world.circles_obstacle[ci]
        members = np.flatnonzero(seen & (owner == oid))
        if (
            radius < CYLINDER_MIN_RADIUS_M
            or members.size < 5
            or np.nanmax(truth.range_m[members]) > MAX_RANGE_M
        ):
            continue
        tally.true_cylinders += 1
        c = _to_vehicle(centre, reference_pose)
        truth_params = np.array([c[0], c[1], radius])
        for i in cylinders:
            f = features[i]
            share = np.intersect1d(f.samples, members).size
            if share < 0.5 * members.size or _majority(owner[f.samples])[0] != oid:
                continue
            err = f.params - truth_params
            if (
                np.hypot(err[0], err[1]) < MATCH_DISTANCE_M and abs(err[2]) < MATCH_RADIUS_M
            ) or _consistent(err, f.covariance):
                tally.found_cylinders += 1
                used.add(i)
                tally.cylinder_nees.append(float(err @ np.linalg.solve(f.covariance, err)))
                tally.cylinder_errors[(tally.scans, ci)] = err
                _reflectivity(tally, f, world, truth, f.samples)
                break
    _associate(tally, world, truth, face, seen, features, reference_pose)
    # False features: whatever matched nothing true.
    vertices = _to_vehicle(_vertices(world), reference_pose)
    for i, f in enumerate(features):
        if i in used:
            continue
        if f.kind in ("corner", "edge"):
            p = f.params[:2]
            centres = _to_vehicle(world.circles_center, reference_pose)
            away = p - centres
            dist = np.maximum(np.linalg.norm(away, axis=1), 1e-12)
            on_circles = centres + away * (world.circles_radius / dist)[:, None]
            candidates = np.vstack([vertices, on_circles])  # the nearest true points
            errors = p - candidates
            near = np.min(np.linalg.norm(errors, axis=1), initial=np.inf)
            if near > MATCH_DISTANCE_M and not any(_consistent(e, f.covariance) for e in errors):
                tally.false_features += 1
                tally.false_by_kind[f.kind] = tally.false_by_kind.get(f.kind, 0) + 1
        elif not _plausible(f, world, truth, face, reference_pose):
            tally.false_features += 1
            tally.false_by_kind[f.kind] = tally.false_by_kind.get(f.kind, 0) + 1


def _plausible(
    feature: Feature,
    world: World,
    truth: ScanTruth,
    face: np.ndarray,
    pose: tuple[float, float, float],
) -> bool:
    """A segment or cylinder that did not count as a detection but describes a true surface.

    (A face shorter than 0.15 m or beyond 2 m is not counted as a true segment, but a segment
    found on it is not false.)
    """
    s = feature.samples
    if s.size == 0:
        return False
    if feature.kind == "segment":
        faces = face[s][face[s] >= 0]
        if faces.size == 0:
            return False
        fi = int(np.bincount(faces).argmax())
        a = _to_vehicle(world.segments_start[fi], pose)
        b = _to_vehicle(world.segments_end[fi], pose)
        err = _line_error(feature, *_line_params(a, b))
        if abs(err[0]) < MATCH_ANGLE_RAD and abs(err[1]) < MATCH_DISTANCE_M:
            return True
        return _consistent(err, feature.covariance)
    oids = truth.obstacle[s][truth.obstacle[s] >= 0]
    if oids.size == 0:
        return False
    oid = int(np.bincount(oids).argmax())
    match = np.flatnonzero(world.circles_obstacle == oid)
    if match.size == 0:
        return False
    c = _to_vehicle(world.circles_center[match[0]], pose)
    if np.hypot(*(feature.params[:2] - c)) < MATCH_DISTANCE_M:
        return True
    err = feature.params - np.array([c[0], c[1], world.circles_radius[match[0]]])
    return _consistent(err, feature.covariance)


def _majority(labels: np.ndarray) -> tuple[int, int, int]:
    """The most frequent non-negative label, its count, and the second one's count
    ((-1, 0, 0) when there is none)."""
    labels = labels[labels >= 0]
    if labels.size == 0:
        return -1, 0, 0
    counts = np.bincount(labels)
    order = np.argsort(counts)[::-1]
    second = int(counts[order[1]]) if order.size > 1 else 0
    return int(order[0]), int(counts[order[0]]), second


def _nees(err: FloatArray, covariance: FloatArray) -> float:
    try:
        return float(err @ np.linalg.solve(covariance, err))
    except np.linalg.LinAlgError:
        return math.inf


def _adjacent_faces(world: World) -> np.ndarray:
    """(m, m) bool: faces i and j of one obstacle share an end (meet at a vertex)."""
    a, b = world.segments_start, world.segments_end
    ends = np.stack([a, b], axis=1)  # (m, 2 ends, 2)
    gap = np.linalg.norm(ends[:, None, :, None, :] - ends[None, :, None, :, :], axis=-1)
    touch = np.any(gap.reshape(gap.shape[0], gap.shape[1], 4) < 1e-9, axis=-1)
    same = world.segments_obstacle[:, None] == world.segments_obstacle[None, :]
    out: np.ndarray = touch & same & ~np.eye(a.shape[0], dtype=bool)
    return out


def _associate(
    tally: Tally,
    world: World,
    truth: ScanTruth,
    face: np.ndarray,
    seen: np.ndarray,
    features: list[Feature],
    pose: tuple[float, float, float],
) -> None:
    """NEES of every segment and cylinder against the surface most of its samples hit, and
    the three error classes of the module docstring."""
    adjacent = _adjacent_faces(world)
    counts = np.bincount(face[seen & (face >= 0)], minlength=adjacent.shape[0])
    big = counts >= VERTEX_MIN_SAMPLES
    tally.vertices_seen += int(np.count_nonzero(np.triu(adjacent & big[:, None] & big[None, :])))
    for f in features:
        s = f.samples
        if s.size == 0 or f.kind not in ("segment", "cylinder"):
            continue
        bridge = max(BRIDGE_MIN_SAMPLES, BRIDGE_MIN_FRACTION * s.size)
        if f.kind == "segment":
            fi, most, _ = _majority(face[s])
            if fi < 0 or most < 0.5 * s.size:
                continue
            a = _to_vehicle(world.segments_start[fi], pose)
            b = _to_vehicle(world.segments_end[fi], pose)
            err = _line_error(f, *_line_params(a, b))
            nees = _nees(err, f.covariance)
            tally.segment_nees_all.append(nees)
            other = face[s][(face[s] >= 0) & (face[s] != fi)]
            beside = np.bincount(other, minlength=adjacent.shape[0])[adjacent[fi]]
            if np.max(beside, initial=0) >= bridge:
                tally.bridging_segments += 1
                tally.bridging_uncovered += int(nees > CONSISTENT_NEES[2])
            cos_view = truth.cos_view[s][face[s] == fi]
            if np.median(cos_view) < GRAZING_MAX_COS:
                tally.grazing_nees.append(nees)
                if abs(err[0]) > MATCH_ANGLE_RAD and nees > CONSISTENT_NEES[2]:
                    tally.grazing_wrong += 1
            continue
        oid, most, _ = _majority(truth.obstacle[s])
        match = np.flatnonzero(world.circles_obstacle == oid)
        if oid < 0 or most < 0.5 * s.size or match.size == 0:
            continue
        c = _to_vehicle(world.circles_center[match[0]], pose)
        radius = float(world.circles_radius[match[0]])
        err = f.params - np.array([c[0], c[1], radius])
        nees = _nees(err, f.covariance)
        tally.cylinder_nees_all.append(nees)
        tally.cylinders_associated += 1
        others = truth.obstacle[s][(truth.obstacle[s] >= 0) & (truth.obstacle[s] != oid)]
        on_circles = np.isin(others, world.circles_obstacle)
        two = np.max(np.bincount(others[on_circles]), initial=0) >= bridge
        if two or abs(err[2]) > WRONG_RADIUS_FRACTION * radius:
            tally.cylinders_wrong += 1
            if nees > CONSISTENT_NEES[3]:
                tally.cylinders_wrong_uncovered += 1


def _consistent(err: FloatArray, covariance: FloatArray) -> bool:
    """The error lies inside the feature's own covariance (see ``CONSISTENT_NEES``)."""
    try:
        nees = float(err @ np.linalg.solve(covariance, err))
    except np.linalg.LinAlgError:
        return False
    return nees < CONSISTENT_NEES[err.size]


def _reflectivity(
    tally: Tally, feature: Feature, world: World, truth: ScanTruth, samples: np.ndarray
) -> None:
    if not math.isfinite(feature.reflectivity) or samples.size == 0:
        return
    refl = truth.reflectivity[samples]
    refl = refl[np.isfinite(refl)]
    if refl.size:
        true_refl = float(np.median(refl))
        tally.reflectivity_rel_err.append(abs(feature.reflectivity / true_refl - 1.0))
