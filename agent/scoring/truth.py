"""The true objects a tracker is scored against, and which of them a scan's samples hit.

Frames follow REP-103; metres; world frame unless stated.

From a :class:`~agent.sim.world.World`:

* **faces**: every wall piece and box side (a straight segment);
* **corners**: points where two faces meet at more than ``CORNER_MIN_ANGLE_RAD`` (box
  corners, a wall polyline's inner vertices, a closed wall's every vertex). Faces that cross
  without sharing an end (a wall through a box) are not corners here: the tracking scenes
  keep obstacles 0.1 m apart, so they do not occur;
* **cylinders**: the static circles;
* **movers**: the moving cylinders, placed at a given time by the caller.

A scan **hits** an object when enough of its valid samples, placed in the world with the
vehicle's true pose at the scan's stamp, lie on it: within ``max(HIT_TOLERANCE_M, 3σ)`` of
the surface (σ the sample's own range σ); for a mover, also within the distance it walks in
one sweep (``SWEEP_S``: the samples are of different moments, the mover's place is taken at
the stamp). A corner is hit when both of its faces have ``MIN_SAMPLES`` such samples within
``CORNER_REACH_M`` of it, spanning ``MIN_FACE_SPAN_M`` (the feature extractor reports a
corner where two reported segments of at least 5 points and 10 cm meet), counting on
each face only samples whose beam meets it within ``MAX_INCIDENCE_RAD`` (60°) of its
normal: on a face grazed more obliquely the samples' range noise lies mostly along the
face, and the extractor reports no line where that along-line noise is large
(``FeatureSettings.segment_max_along_noise_ratio``), so no corner either; a cylinder or a
mover when ``MIN_SAMPLES`` samples lie on its circle.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from agent.arrays import FloatArray
from agent.sim.world import World

__all__ = ["SceneTruth", "circles_hit", "corners_hit", "faces_hit", "scene_truth"]

IntArray = npt.NDArray[np.int64]
BoolArray = npt.NDArray[np.bool_]

CORNER_MIN_ANGLE_RAD = math.radians(10.0)  # a shallower bend is one face to the extractor
HIT_TOLERANCE_M = 0.03  # noise and mixed samples near the surface, at least
MIN_SAMPLES = 5
MAX_INCIDENCE_RAD = math.radians(60.0)  # beyond it a face is grazed (see the module doc)
MIN_FACE_SPAN_M = 0.1  # the extractor's shortest segment (FeatureSettings.min_segment_length_m)
CORNER_REACH_M = 0.3
SWEEP_S = 0.1  # the longest sweep (the full ±20° window)
_SAME_POINT_M = 1e-6


@dataclass(frozen=True)
class SceneTruth:
    """The static truth of a world (module docstring), world frame.

    Attributes
    ----------
    face_start, face_end : (f, 2) the faces' ends, m.
    corner_xy : (c, 2) corners, m.
    corner_faces : (c, 2) int64, the two faces meeting at each corner.
    cylinder_xy : (k, 2) static cylinders' centres, m.
    cylinder_radius_m : (k,) their radii.
    """

    face_start: FloatArray
    face_end: FloatArray
    corner_xy: FloatArray
    corner_faces: IntArray
    cylinder_xy: FloatArray
    cylinder_radius_m: FloatArray


def scene_truth(world: World) -> SceneTruth:
    """The faces, corners and static cylinders of ``world``."""
    start = np.asarray(world.segments_start, dtype=np.float64).reshape(-1, 2)
    end = np.asarray(world.segments_end, dtype=np.float64).reshape(-1, 2)
    f = start.shape[0]
    ends = np.concatenate([start, end])  # end point e belongs to face e % f
    face = np.arange(2 * f) % f
    gap = np.hypot(*(ends[:, None, :] - ends[None, :, :]).transpose(2, 0, 1))
    a, b = np.nonzero(np.triu(gap < _SAME_POINT_M, k=1) & (face[:, None] != face[None, :]))
    d = end - start
    heading = np.arctan2(d[:, 1], d[:, 0])
    turn = np.abs((heading[face[a]] - heading[face[b]] + math.pi) % math.tau - math.pi)
    bend = np.minimum(turn, math.pi - turn)  # the faces' lines' angle, whatever their sense
    keep = bend > CORNER_MIN_ANGLE_RAD
    return SceneTruth(
        face_start=start,
        face_end=end,
        corner_xy=ends[a[keep]],
        corner_faces=np.stack([face[a[keep]], face[b[keep]]], axis=1).astype(np.int64),
        cylinder_xy=np.asarray(world.circles_center, dtype=np.float64).reshape(-1, 2),
        cylinder_radius_m=np.asarray(world.circles_radius, dtype=np.float64).reshape(-1),
    )


def point_segment_distance(
    points: FloatArray, start: FloatArray, end: FloatArray
) -> tuple[FloatArray, FloatArray]:
    """Distances (n, f) from points (n, 2) to segments (f, 2)-(f, 2), and the position along
    each segment of the nearest point, as a fraction of its length (unclipped), (n, f)."""
    d = end - start
    length2 = np.maximum(np.einsum("ij,ij->i", d, d), 1e-18)
    rel = points[:, None, :] - start[None, :, :]
    u = np.einsum("nfj,fj->nf", rel, d) / length2
    nearest = start[None] + np.clip(u, 0.0, 1.0)[..., None] * d[None]
    gap = points[:, None, :] - nearest
    return np.hypot(gap[..., 0], gap[..., 1]), u


def _tolerance(sigma_m: FloatArray) -> FloatArray:
    s = np.where(np.isfinite(sigma_m), sigma_m, 0.0)
    return np.maximum(HIT_TOLERANCE_M, 3.0 * s)


def faces_hit(
    truth: SceneTruth,
    points_world: FloatArray,
    sigma_m: FloatArray,
    origin_world: FloatArray | None = None,
) -> BoolArray:
    """(n, f): which samples (valid ones, (n, 2), world frame) lie on which faces; with the
    centre of scanning ``origin_world`` (2,), only samples whose beam meets the face within
    ``MAX_INCIDENCE_RAD`` of its normal."""
    if points_world.shape[0] == 0 or truth.face_start.shape[0] == 0:
        return np.zeros((points_world.shape[0], truth.face_start.shape[0]), dtype=bool)
    dist, _ = point_segment_distance(points_world, truth.face_start, truth.face_end)
    on = dist <= _tolerance(sigma_m)[:, None]
    if origin_world is not None:
        beam = points_world - origin_world
        beam = beam / np.maximum(np.hypot(beam[:, 0], beam[:, 1]), 1e-12)[:, None]
        d = truth.face_end - truth.face_start
        normal = np.stack([-d[:, 1], d[:, 0]], axis=1) / np.hypot(d[:, 0], d[:, 1])[:, None]
        on &= np.abs(beam @ normal.T) >= math.cos(MAX_INCIDENCE_RAD)
    return np.asarray(on)


def corners_hit(
    truth: SceneTruth,
    points_world: FloatArray,
    sigma_m: FloatArray,
    origin_world: FloatArray | None = None,
) -> BoolArray:
    """(c,): the corners whose two faces both have ``MIN_SAMPLES`` samples on them within
    ``CORNER_REACH_M`` of the corner, spanning ``MIN_FACE_SPAN_M`` along it (and with
    ``origin_world`` given, not at grazing incidence: :func:`faces_hit`)."""
    if truth.corner_xy.shape[0] == 0 or points_world.shape[0] == 0:
        return np.zeros(truth.corner_xy.shape[0], dtype=bool)
    on_face = faces_hit(truth, points_world, sigma_m, origin_world)  # (n, f)
    near = (
        np.hypot(*(points_world[:, None, :] - truth.corner_xy[None]).transpose(2, 0, 1))
        <= CORNER_REACH_M
    )  # (n, c)
    reach = np.hypot(*(points_world[:, None, :] - truth.corner_xy[None]).transpose(2, 0, 1))
    hit = np.ones(truth.corner_xy.shape[0], dtype=bool)
    for side in (0, 1):
        on = on_face[:, truth.corner_faces[:, side]] & near  # (n, c)
        span = np.where(on, reach, -np.inf).max(axis=0) - np.where(on, reach, np.inf).min(axis=0)
        hit &= (on.sum(axis=0) >= MIN_SAMPLES) & (span >= MIN_FACE_SPAN_M)
    return hit


def circles_hit(
    centre_xy: FloatArray,
    radius_m: FloatArray,
    points_world: FloatArray,
    sigma_m: FloatArray,
    smear_m: npt.ArrayLike = 0.0,
) -> BoolArray:
    """(k,): the circles with ``MIN_SAMPLES`` samples within tolerance (plus ``smear_m``,
    scalar or (k,), for a mover's walk during the sweep) of their outline."""
    k = centre_xy.shape[0]
    if k == 0 or points_world.shape[0] == 0:
        return np.zeros(k, dtype=bool)
    r = np.hypot(*(points_world[:, None, :] - centre_xy[None]).transpose(2, 0, 1))
    slack = _tolerance(sigma_m)[:, None] + np.broadcast_to(np.asarray(smear_m), (k,))[None]
    on = np.abs(r - radius_m[None]) <= slack
    return np.asarray(on.sum(axis=0) >= MIN_SAMPLES)
