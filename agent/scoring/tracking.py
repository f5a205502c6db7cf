"""Scoring tracks against the simulation's truth, scan by scan, run by run.

Everything is compared in the drifting ``odom`` frame: each true object is mapped there
with the odometry and true poses at the scan's stamp (:func:`agent.scoring.frames.
world_to_odom`): where a perfect tracker using this odometry would put it. Metres, seconds,
radians; REP-103.

**Objects.** Point objects are corners (track kind 1) and cylinders, static or moving (track
kind 3); segments (kind 0) are scored against the faces (:mod:`agent.scoring.truth`). A
track is *confirmed* when its status is confirmed or coasting.

**Should be known.** A point object the tracker is expected to hold at a scan: within
``reach_m`` (2.5 m, the sensor's far limit) of the vehicle's centre of scanning (a cylinder
by its surface), and hit by the samples of at least ``min_hits`` scans (3: the tracker's
confirmation needs 3 updates; :mod:`agent.scoring.truth` says when a scan hits an object):
ever for static objects (a tracker is to keep them while out of view), within the last
``mover_memory_s`` (1 s) for movers.

**Association.** Per scan, confirmed point tracks are paired with *every* true point object
of their kind (corner to corner, cylinder to static cylinder or mover), nearer than ``c``:
as in the CLEAR MOT metrics (Bernardin and Stiefelhagen 2008), a track still within ``c``
of the object it was last paired with keeps it (or still within its own 99 % gate of it:
a pillar's track coasting out of view drifts with the odometry, its covariance with it, and
a mover passing near where it now is must not take it over on paper; or not updated by the
scan, unless an updated track took the object: a track that took no feature cannot have
changed which object it follows, only how far it has drifted from it, which its errors and
NEES then show), and the rest are
assigned by the GOSPA assignment (:func:`agent.scoring.gospa.assign`), so that two movers
walking past each other within ``c`` do not swap their tracks on paper at every scan. These
pairs give the position errors (RMSE), NEES, id switches and fragmentations
(:mod:`agent.scoring.identity`).

**GOSPA** (c = 0.5 m, p = 1, α = 2) per scan between the objects that should be known and
the confirmed point tracks within ``reach_m + c`` of the centre of scanning, leaving out
the tracks the association paired with an object not (or no longer) expected: a pillar
tracked while 3 m behind, a mover kept while it walks out of view. The mean over scans,
and of its localisation, missed and false parts.

**False tracks.** Confirmed tracks (any kind, any distance) with no true object of their
kind within ``c`` nor inside the track's own 99 % gate (its position covariance, χ² 9.21):
a track that coasted out of view while the odometry drifted, with a covariance that
covers where its object now is in ``odom``, is a track of that object, not a false one
(GOSPA still counts its distance). For a segment track, no face within ``c`` of its
reference point (the midpoint of its extent), nor a face whose line lies inside the
track's 99 % gate in (α, ρ) and that reaches, along its line, within ``c`` of the track's
extent. ``false_tracks_beyond_c_per_scan`` counts by ``c`` alone.

**Position errors.** Per associated pair, the distance from the track's point to the
truth, root mean square over pairs per kind (corner, cylinder: static, mover); for
segments, the distance of the track's midpoint from its face's line, each confirmed segment
track paired with the face at the least such distance among those within 15° of its
direction whose extent (0.25 m either side) its midpoint falls in, nearer than ``c``.

**NEES.** ``static``: the (x, y) of corner and static-cylinder pairs against the tracks'
covariance (2 dof); segments are kept apart (``segment``: their (α, ρ) against the face's
line in ``odom``, 2 dof), because their state is a line, not a point. ``moving``: movers'
(x, y, vx, vy) against the tracks' 4×4 covariance (4 dof), the true velocity rotated into
``odom`` (the odom frame's own drift rate, the odometry's error rate of about 2 % of the
vehicle's 0.4 m/s, is neglected). Each run's mean over its samples, then the mean over the
runs that have any, with the χ² interval for that many runs (:mod:`agent.scoring.nees`):
a run's mean is over correlated scans, so it varies less than one NEES and the interval is
conservative. Beside it, over every sample: the median (1.39 for 2 dof, 3.36 for 4 when
consistent) and the fraction above the χ² 95 % point (5 % when consistent), which one wild
sample cannot move. And what makes the mean: the samples' mean apart for tracks the scan
updated and for tracks coasting (``updated``, ``coasting``), and the mean of runs over the
samples within the χ² 99.9 % point with the share beyond it (``within_999``: about dof and
0.1 % when consistent), which tells a loose bulk under a few wild samples from honest
covariances whose mean happens to fall inside the interval.

**Deletions.** A confirmed static track (segment, corner, or cylinder with moving
probability below 0.5 when last reported) missing from a scan's tracks was deleted at that
scan; *out of view* when its point (a segment: its midpoint and both ends) lay outside the
scan's wedge: the bearings, from the scan's centre of scanning, between its outermost valid
samples (widened by 2°), from 0.3 to 2.6 m (the depth of field widened by 0.1 m).
``static_deleted_out_of_view_returned`` counts those of them whose place (in ``odom``,
where the track last put it) was in a later scan's wedge: a track deleted while away from
a feature the head then looked at again.

**Confirmation latency.** A mover *enters* the window at the first scan that hits it, its
near surface within ``reach_m`` of the centre of scanning (in the depth of field: beyond it,
samples at the far limit with σ up to 19 cm put a mover 2.9 m away within the hit
tolerance), while no confirmed track is assigned to it; the entry lapses if no scan hits it
for ``entry_reset_s`` (1 s) before it is confirmed. The latency is from the entry's scan to
the first scan in which a confirmed track is assigned to it.

**Along the path** (``path``; only with the vehicle's path ahead, ``ScanInput.
path_ahead_xy``: the bench driver's next 3 m). A mover *enters* the path's concern at the
first scan its surface comes within ``PATH_MOVER_M`` (2.5 m) of the path ahead while no
confirmed track is assigned to it, seen or not; the latency runs from there to the first
scan with a confirmed track assigned to it (lapsing, as above, after ``entry_reset_s``
out of that reach: ``unconfirmed``). The tracks' uncertainty along the path: over the
objects that should be known within ``PATH_OBJECT_M`` (1 m) of the path ahead and their
paired tracks, the mean of ``det(P)^¼`` (the geometric mean of the position σ's axes: the
log-determinant the active planner reduces); ``objects_tracked`` is the share of those
objects with a track.

**Information** (``information``; only where the tracks carry ``information_bits``, the
bits each track's updates have brought so far): the bits gained between consecutive scans,
summed over all tracks and over the path-relevant ones (reference point, or for a segment
any point of its extent, within ``PATH_OBJECT_M`` of the path ahead), over the seconds the
runs lasted: the information per second of head time, slews included, that a head policy
buys.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt
from scipy.stats import chi2

from agent.arrays import FloatArray
from agent.scoring.frames import line_params, rotation, to_frame, world_to_odom, wrap_angle
from agent.scoring.gospa import assign, gospa
from agent.scoring.identity import IdentityLedger
from agent.scoring.nees import average_interval, nees
from agent.scoring.truth import (
    SWEEP_S,
    SceneTruth,
    circles_hit,
    corners_hit,
    point_segment_distance,
)

__all__ = ["ScanInput", "TrackView", "TrackingScore"]

IntArray = npt.NDArray[np.int64]
BoolArray = npt.NDArray[np.bool_]

KIND_SEGMENT, KIND_CORNER, KIND_CYLINDER = 0, 1, 3
SEGMENT_ANGLE_RAD = math.radians(15.0)
SEGMENT_OVERHANG_M = 0.25
VIEW_MARGIN_RAD = math.radians(2.0)
VIEW_RANGE_M = (0.3, 2.6)
MOVING = 0.5
PATH_MOVER_M = 2.5  # a mover whose surface is this near the path ahead is the path's concern
PATH_OBJECT_M = 1.0  # an object this near the path ahead is path-relevant
GATE_PROBABILITY = 0.99  # a track's own gate: its 99 % ellipse (χ², 2 dof: 9.21)
_GATE_D2 = float(chi2.ppf(GATE_PROBABILITY, 2))
# Truth ids for the identity ledger: one space for every object of a run.
_CYLINDER_BASE, _MOVER_BASE = 1_000_000, 2_000_000


@dataclass(frozen=True)
class TrackView:
    """One scan's tracks, frame ``odom`` (the arrays of ``tracks/2``, or a baseline's).

    ``kind`` 0 segment, 1 corner, 3 cylinder; ``confirmed`` per track; ``state`` (k, 4)
    x, y, vx, vy and ``covariance`` (k, 4, 4); ``params`` (k, 3) and
    ``params_covariance`` (k, 3, 3) as in ``tracks/2`` (NaN where unknown); ``extent``
    (k, 4); ``moving_probability`` (k,); ``updated`` (k,): whether the scan updated the
    track (None: not known, every track taken as updated).
    """

    track_id: IntArray
    kind: npt.NDArray[np.integer[Any]]
    confirmed: BoolArray
    state: FloatArray
    covariance: FloatArray
    params: FloatArray
    params_covariance: FloatArray
    extent: FloatArray
    moving_probability: FloatArray
    updated: BoolArray | None = None
    information_bits: FloatArray | None = None

    @classmethod
    def points(
        cls, track_id: npt.ArrayLike, kind: npt.ArrayLike, state: FloatArray, cov: FloatArray
    ) -> TrackView:
        """Confirmed point tracks with no segment parameters (a baseline's)."""
        k = state.shape[0]
        return cls(
            track_id=np.asarray(track_id, dtype=np.int64).reshape(k),
            kind=np.asarray(kind, dtype=np.uint8).reshape(k),
            confirmed=np.ones(k, dtype=bool),
            state=state.reshape(k, 4),
            covariance=cov.reshape(k, 4, 4),
            params=np.full((k, 3), np.nan),
            params_covariance=np.full((k, 3, 3), np.nan),
            extent=np.zeros((k, 4)),
            moving_probability=np.zeros(k),
        )

    def __len__(self) -> int:
        return int(self.track_id.shape[0])


@dataclass(frozen=True)
class ScanInput:
    """The truth and the scan around one set of tracks.

    ``stamp_s`` the scan's stamp; ``true_pose`` and ``odom_pose`` (x, y, yaw) of
    ``base_link`` in ``world`` and in ``odom`` then; ``points_base`` (n, 2) the scan's
    valid samples in ``base_link`` at the stamp with their range σ ``sigma_m`` (n,);
    ``origin_base`` (2,) the centre of scanning in ``base_link``; ``mover_xy`` and
    ``mover_velocity_xy`` (m, 2), ``mover_radius_m`` (m,) the movers at the stamp (world);
    ``path_ahead_xy`` (k, 2) the vehicle's intended path ahead then (world; may be empty).
    """

    stamp_s: float
    true_pose: FloatArray
    odom_pose: FloatArray
    points_base: FloatArray
    sigma_m: FloatArray
    origin_base: FloatArray
    mover_xy: FloatArray
    mover_velocity_xy: FloatArray
    mover_radius_m: FloatArray
    path_ahead_xy: FloatArray = field(default_factory=lambda: np.zeros((0, 2)))


@dataclass
class _Entry:
    start_s: float
    last_hit_s: float


@dataclass
class _Run:
    """What one run keeps between scans."""

    ledger: IdentityLedger = field(default_factory=IdentityLedger)
    static_hits: dict[str, IntArray] = field(default_factory=dict)
    mover_hits_s: list[list[float]] = field(default_factory=list)
    mover_tracked: BoolArray = field(default_factory=lambda: np.zeros(0, dtype=bool))
    entries: dict[int, _Entry] = field(default_factory=dict)
    path_entries: dict[int, _Entry] = field(default_factory=dict)
    confirmed_static: dict[int, FloatArray] = field(default_factory=dict)  # id -> points odom
    deleted_away: list[FloatArray] = field(default_factory=list)  # points odom, not yet back
    nees: dict[str, list[float]] = field(default_factory=dict)
    nees_updated: dict[str, list[bool]] = field(default_factory=dict)  # beside nees
    bits: dict[int, float] = field(default_factory=dict)  # id -> information_bits last seen
    first_s: float | None = None
    last_s: float | None = None


class TrackingScore:
    """Accumulates the figures of the module docstring over runs and scans.

    Call :meth:`start_run` for each scene, :meth:`add_scan` for each set of tracks, and
    :meth:`summary` at the end.
    """

    def __init__(
        self,
        c: float = 0.5,
        p: float = 1.0,
        reach_m: float = 2.5,
        mover_memory_s: float = 1.0,
        entry_reset_s: float = 1.0,
        min_hits: int = 3,
    ) -> None:
        self.c, self.p, self.reach_m = c, p, reach_m
        self.min_hits = min_hits
        self.mover_memory_s = mover_memory_s
        self.entry_reset_s = entry_reset_s
        self.scans = 0
        self.runs = 0
        self.gospa_parts: list[tuple[float, float, float, float]] = []
        self.errors: dict[str, list[float]] = {
            "segment": [], "corner": [], "cylinder": [], "mover": []
        }  # fmt: skip
        self.run_nees: dict[str, list[float]] = {"static": [], "moving": [], "segment": []}
        self.all_nees: dict[str, list[float]] = {"static": [], "moving": [], "segment": []}
        self.nees_samples: dict[str, int] = {"static": 0, "moving": 0, "segment": 0}
        self.all_updated: dict[str, list[bool]] = {"static": [], "moving": [], "segment": []}
        self.run_of_nees: dict[str, list[int]] = {"static": [], "moving": [], "segment": []}
        self.id_switches = 0
        self.fragmentations = 0
        self.false_tracks = 0
        self.false_by_kind = {"segment": 0, "corner": 0, "cylinder": 0}
        self.false_beyond_c = 0
        self.static_deleted_out_of_view_returned = 0
        self.static_deleted_out_of_view = 0
        self.static_deleted_in_view = 0
        self.latencies_s: list[float] = []
        self.missed_objects = {"corner": 0, "cylinder": 0, "mover": 0}
        self.known_objects = 0
        self.unconfirmed_entries = 0
        self.path_latencies_s: list[float] = []
        self.path_unconfirmed = 0
        self.path_sigmas_m: list[float] = []
        self.path_known = 0
        self.path_paired = 0
        self.information_bits = 0.0
        self.information_path_bits = 0.0
        self.information_seconds = 0.0
        self.information_given = False  # any tracks with information_bits
        self._truth: SceneTruth | None = None
        self._run: _Run | None = None

    # ----------------------------------------------------------------------------- runs
    def start_run(self, truth: SceneTruth, n_movers: int) -> None:
        """Begin a run over the scene ``truth`` with ``n_movers`` movers."""
        self.end_run()
        self._truth = truth
        self._run = _Run(
            static_hits={
                "corner": np.zeros(truth.corner_xy.shape[0], dtype=np.int64),
                "cylinder": np.zeros(truth.cylinder_xy.shape[0], dtype=np.int64),
            },
            mover_hits_s=[[] for _ in range(n_movers)],
            mover_tracked=np.zeros(n_movers, dtype=bool),
            nees={"static": [], "moving": [], "segment": []},
            nees_updated={"static": [], "moving": [], "segment": []},
        )
        self.runs += 1

    def end_run(self) -> None:
        """Close the current run (also done by :meth:`start_run` and :meth:`summary`)."""
        run = self._run
        if run is None:
            return
        self.id_switches += run.ledger.id_switches
        self.fragmentations += run.ledger.fragmentations
        for name, values in run.nees.items():
            if values:
                self.run_nees[name].append(float(np.mean(values)))
                self.nees_samples[name] += len(values)
                self.all_nees[name].extend(values)
                self.all_updated[name].extend(run.nees_updated[name])
                self.run_of_nees[name].extend([len(self.run_nees[name])] * len(values))
        self.unconfirmed_entries += len(run.entries)
        if run.first_s is not None and run.last_s is not None:
            self.information_seconds += run.last_s - run.first_s
        self._run = None

    # ---------------------------------------------------------------------------- scans
    def add_scan(self, scan: ScanInput, tracks: TrackView) -> None:
        """Score one set of tracks (module docstring)."""
        truth, run = self._truth, self._run
        if truth is None or run is None:
            raise RuntimeError("start_run before add_scan")
        self.scans += 1
        c = self.c
        true_pose, odom_pose = scan.true_pose, scan.odom_pose
        points_world = to_frame(true_pose, scan.points_base)
        centre = to_frame(odom_pose, scan.origin_base[None])[0]  # centre of scanning, odom

        # The truth in odom, and what this scan hit.
        corners = world_to_odom(true_pose, odom_pose, truth.corner_xy)
        cylinders = world_to_odom(true_pose, odom_pose, truth.cylinder_xy)
        movers = world_to_odom(true_pose, odom_pose, scan.mover_xy)
        turn = rotation(float(odom_pose[2] - true_pose[2]))
        mover_v = scan.mover_velocity_xy @ turn.T
        origin_world = to_frame(true_pose, scan.origin_base[None])[0]
        hit_corner = corners_hit(truth, points_world, scan.sigma_m, origin_world)
        hit_cylinder = circles_hit(
            truth.cylinder_xy, truth.cylinder_radius_m, points_world, scan.sigma_m
        )
        speed = np.hypot(*scan.mover_velocity_xy.T) if movers.size else np.zeros(0)
        hit_mover = circles_hit(
            scan.mover_xy, scan.mover_radius_m, points_world, scan.sigma_m, speed * SWEEP_S
        )
        run.static_hits["corner"] += hit_corner
        run.static_hits["cylinder"] += hit_cylinder
        recent = np.zeros(hit_mover.shape[0], dtype=bool)
        for m, hits in enumerate(run.mover_hits_s):
            if hit_mover[m]:
                hits.append(scan.stamp_s)
            while hits and hits[0] < scan.stamp_s - self.mover_memory_s:
                hits.pop(0)
            recent[m] = len(hits) >= self.min_hits

        def near(xy: FloatArray, radius: FloatArray | float = 0.0) -> BoolArray:
            return np.asarray(np.hypot(*(xy - centre).T) - radius <= self.reach_m)

        known = np.concatenate([
            (run.static_hits["corner"] >= self.min_hits) & near(corners),
            (run.static_hits["cylinder"] >= self.min_hits)
            & near(cylinders, truth.cylinder_radius_m),
            recent & near(movers, scan.mover_radius_m),
        ])  # fmt: skip
        n_c, n_k = corners.shape[0], cylinders.shape[0]
        truth_xy = np.concatenate([corners, cylinders, movers])
        truth_kind = np.concatenate([
            np.full(n_c, KIND_CORNER), np.full(n_k + movers.shape[0], KIND_CYLINDER)
        ])  # fmt: skip
        truth_uid = np.concatenate([
            np.arange(n_c), _CYLINDER_BASE + np.arange(n_k),
            _MOVER_BASE + np.arange(movers.shape[0]),
        ])  # fmt: skip

        # Association of confirmed point tracks with every true point object.
        conf = tracks.confirmed
        point = conf & np.isin(tracks.kind, (KIND_CORNER, KIND_CYLINDER))
        pidx = np.flatnonzero(point)
        pxy = tracks.state[pidx, :2]
        ti, ei, dist = self._associate(run, truth_xy, truth_kind, truth_uid, tracks, pidx)
        run.ledger.update(
            zip(tracks.track_id[pidx[ei]].tolist(), truth_uid[ti].tolist(), strict=True),
            tracks.track_id.tolist(),
        )

        # GOSPA: known objects against the tracks in reach not paired with the unexpected.
        dont_care = np.zeros(pidx.size, dtype=bool)
        dont_care[ei[~known[ti]]] = True
        scored = ~dont_care & (
            np.hypot(pxy[:, 0] - centre[0], pxy[:, 1] - centre[1]) <= self.reach_m + c
        )
        g = gospa(
            truth_xy[known], pxy[scored], c, self.p, 2.0,
            truth_kind[known], tracks.kind[pidx][scored],
        )  # fmt: skip
        self.gospa_parts.append((g.distance, g.localisation, g.missed, g.false))
        missed = np.flatnonzero(known)
        missed = np.delete(missed, g.pairs[:, 0])
        self.missed_objects["corner"] += int(np.sum(missed < n_c))
        self.missed_objects["cylinder"] += int(np.sum((missed >= n_c) & (missed < n_c + n_k)))
        self.missed_objects["mover"] += int(np.sum(missed >= n_c + n_k))
        self.known_objects += int(known.sum())

        # Position errors and NEES of the pairs.
        is_mover = ti >= n_c + n_k
        is_cyl = (ti >= n_c) & ~is_mover
        is_corner = ti < n_c
        self.errors["corner"].extend(dist[is_corner].tolist())
        self.errors["cylinder"].extend(dist[is_cyl].tolist())
        self.errors["mover"].extend(dist[is_mover].tolist())
        static = is_corner | is_cyl
        if static.any():
            k = pidx[ei[static]]
            e = tracks.state[k, :2] - truth_xy[ti[static]]
            _add_nees(run, "static", nees(e, tracks.covariance[k, :2, :2]), tracks, k)
        if is_mover.any():
            k = pidx[ei[is_mover]]
            m = ti[is_mover] - n_c - n_k
            e = tracks.state[k] - np.concatenate([movers[m], mover_v[m]], axis=1)
            _add_nees(run, "moving", nees(e, tracks.covariance[k]), tracks, k)

        faces = (
            world_to_odom(true_pose, odom_pose, truth.face_start),
            world_to_odom(true_pose, odom_pose, truth.face_end),
        )
        self._segments(tracks, faces)
        self._false_tracks(tracks, truth_xy, truth_kind, faces)
        self._deletions(scan, tracks)
        self._latency(scan.stamp_s, hit_mover & near(movers, scan.mover_radius_m), ti, n_c + n_k)
        # The path ahead in odom, once for both (None: the scan has none).
        path = (
            world_to_odom(true_pose, odom_pose, scan.path_ahead_xy)
            if scan.path_ahead_xy.shape[0] else None
        )  # fmt: skip
        self._path_relevant(scan, path, truth_xy, known, movers, ti, ei, pidx, tracks, n_c + n_k)
        self._information(scan, path, tracks)

    def _information(self, scan: ScanInput, path: FloatArray | None, tracks: TrackView) -> None:
        """The bits the tracks gained since the last scan, in all and near the path."""
        run = self._run
        assert run is not None
        run.first_s = scan.stamp_s if run.first_s is None else run.first_s
        run.last_s = scan.stamp_s
        bits = tracks.information_bits
        if bits is None or bits.shape[0] != len(tracks):
            return
        self.information_given = True
        ids = tracks.track_id.tolist()
        before = np.array([run.bits.get(i, 0.0) for i in ids])
        gained = np.maximum(bits - before, 0.0)
        run.bits = dict(zip(ids, bits.tolist(), strict=True))
        self.information_bits += float(gained.sum())
        if path is None or not gained.any():
            return
        near = _path_gap(tracks, path) <= PATH_OBJECT_M
        self.information_path_bits += float(gained[near].sum())

    def _associate(
        self,
        run: _Run,
        truth_xy: FloatArray,
        truth_kind: IntArray,
        truth_uid: IntArray,
        tracks: TrackView,
        pidx: IntArray,
    ) -> tuple[IntArray, IntArray, FloatArray]:
        """Pairs (truth index, index into ``pidx``, distance): a track still within ``c`` of
        the object it was last paired with, or within its own gate of it, keeps it (the
        updated tracks first); the other updated tracks are assigned (:func:`assign`); a
        track not updated by this scan then keeps its last object if no updated track took
        it (a track that took no feature cannot have changed which object it follows, only
        drifted from it; but one that did take the object's features follows it now); the
        rest are assigned."""
        pxy = tracks.state[pidx, :2]
        where = {int(u): i for i, u in enumerate(truth_uid.tolist())}
        updated = np.ones(pidx.size, dtype=bool) if tracks.updated is None else tracks.updated[pidx]
        kept_t: list[int] = []
        kept_e: list[int] = []
        claims: list[tuple[int, int]] = []  # coasting tracks' last objects, beyond c and gate
        ids = tracks.track_id[pidx]
        for e in np.argsort(~updated, kind="stable").tolist():
            last = run.ledger.last_truth(int(ids[e]))
            t = where.get(last) if last is not None else None
            if t is None or truth_kind[t] != tracks.kind[pidx[e]] or t in kept_t:
                continue
            d = pxy[e] - truth_xy[t]
            if float(np.hypot(*d)) < self.c or _in_gate(d, tracks.covariance[pidx[e], :2, :2]):
                kept_t.append(t)
                kept_e.append(e)
            elif not updated[e]:
                claims.append((e, t))

        def assign_rest(candidates: BoolArray) -> None:
            free_t = np.setdiff1d(np.arange(truth_xy.shape[0]), kept_t)
            free_e = np.setdiff1d(np.flatnonzero(candidates), kept_e)
            pairs, _ = assign(
                truth_xy[free_t], pxy[free_e], self.c, truth_kind[free_t],
                tracks.kind[pidx[free_e]],
            )  # fmt: skip
            kept_t.extend(free_t[pairs[:, 0]].tolist())
            kept_e.extend(free_e[pairs[:, 1]].tolist())

        assign_rest(updated)
        for e, t in claims:
            if t not in kept_t:
                kept_t.append(t)
                kept_e.append(e)
        assign_rest(np.ones(pidx.size, dtype=bool))
        ti = np.asarray(kept_t, dtype=np.int64)
        ei = np.asarray(kept_e, dtype=np.int64)
        dist = np.hypot(*(pxy[ei] - truth_xy[ti]).T) if ti.size else np.zeros(0)
        return ti, ei, np.asarray(dist, dtype=np.float64)

    def _segments(self, tracks: TrackView, faces: tuple[FloatArray, FloatArray]) -> None:
        run = self._run
        start, end = faces
        seg = np.flatnonzero(tracks.confirmed & (tracks.kind == KIND_SEGMENT))
        if seg.size == 0 or start.shape[0] == 0 or run is None:
            return
        mid = tracks.state[seg, :2]
        alpha = tracks.params[seg, 0]
        direction = np.stack([-np.sin(alpha), np.cos(alpha)], axis=1)  # along the line
        d = end - start
        length = np.hypot(d[:, 0], d[:, 1])
        u = d / length[:, None]
        across = np.abs(direction @ u.T)  # (s, f) |cos| between the lines
        normal = np.stack([-u[:, 1], u[:, 0]], axis=1)
        offset = np.abs(np.einsum("sfj,fj->sf", mid[:, None, :] - start[None], normal))
        along = np.einsum("sfj,fj->sf", mid[:, None, :] - start[None], u)
        ok = (
            (across >= math.cos(SEGMENT_ANGLE_RAD))
            & (along >= -SEGMENT_OVERHANG_M)
            & (along <= length[None] + SEGMENT_OVERHANG_M)
            & (offset < self.c)
        )
        cost = np.where(ok, offset, np.inf)
        face = np.argmin(cost, axis=1)
        has = np.isfinite(cost[np.arange(seg.size), face])
        if not has.any():
            return
        self.errors["segment"].extend(cost[np.arange(seg.size), face][has].tolist())
        lines = line_params(start[face[has]], end[face[has]])
        params = tracks.params[seg[has], :2]
        flip = np.abs(wrap_angle(params[:, 0] - lines[:, 0])) > math.pi / 2
        lines[flip, 0] += math.pi
        lines[flip, 1] *= -1.0
        e = np.stack([wrap_angle(params[:, 0] - lines[:, 0]), params[:, 1] - lines[:, 1]], 1)
        _add_nees(
            run, "segment", nees(e, tracks.params_covariance[seg[has], :2, :2]), tracks, seg[has]
        )

    def _false_tracks(
        self,
        tracks: TrackView,
        truth_xy: FloatArray,
        truth_kind: npt.NDArray[np.integer[Any]],
        faces: tuple[FloatArray, FloatArray],
    ) -> None:
        for kind, name in ((KIND_CORNER, "corner"), (KIND_CYLINDER, "cylinder")):
            mine = np.flatnonzero(tracks.confirmed & (tracks.kind == kind))
            them = truth_xy[truth_kind == kind]
            if mine.size == 0:
                continue
            if them.shape[0] == 0:
                self._count_false(name, mine.size, mine.size)
                continue
            d = tracks.state[mine, None, :2] - them[None]  # (tracks, objects, 2)
            near = np.hypot(d[..., 0], d[..., 1]) < self.c
            cov = np.broadcast_to(tracks.covariance[mine, None, :2, :2], (*d.shape[:2], 2, 2))
            covered = near | _in_gate(d, cov)
            self._count_false(
                name, int(np.sum(~covered.any(axis=1))), int(np.sum(~near.any(axis=1)))
            )
        seg = tracks.confirmed & (tracks.kind == KIND_SEGMENT)
        if seg.any():
            start, end = faces
            if start.shape[0] == 0:
                self._count_false("segment", int(seg.sum()), int(seg.sum()))
                return
            gap, _ = point_segment_distance(tracks.state[seg, :2], start, end)
            near = gap.min(axis=1) < self.c
            covered = near.copy()
            far = np.flatnonzero(~near)
            if far.size:
                covered[far] = self._segments_in_gate(tracks, np.flatnonzero(seg)[far], faces)
            self._count_false("segment", int(np.sum(~covered)), int(np.sum(~near)))

    def _segments_in_gate(
        self, tracks: TrackView, idx: IntArray, faces: tuple[FloatArray, FloatArray]
    ) -> BoolArray:
        """Per segment track ``idx``: whether some face's line lies inside the track's own
        99 % gate in (α, ρ) and the face reaches, along its line, within ``c`` of the
        track's extent."""
        start, end = faces
        lines = line_params(start, end)  # (f, 2)
        params = tracks.params[idx, :2]  # (s, 2)
        da = wrap_angle(params[:, None, 0] - lines[None, :, 0])
        flip = np.abs(da) > math.pi / 2  # the same line written the other way round
        da = np.where(flip, wrap_angle(da - math.pi), da)
        dr = params[:, None, 1] - np.where(flip, -lines[None, :, 1], lines[None, :, 1])
        cov = np.broadcast_to(tracks.params_covariance[idx, None, :2, :2], (*da.shape, 2, 2))
        in_gate = _in_gate(np.stack([da, dr], axis=-1), cov)
        d = end - start
        length = np.hypot(d[:, 0], d[:, 1])
        u = d / length[:, None]
        ext = tracks.extent[idx].reshape(-1, 2, 2)
        half = 0.5 * np.hypot(*(ext[:, 1] - ext[:, 0]).T)
        along = np.einsum("sfj,fj->sf", tracks.state[idx, None, :2] - start[None], u)
        reach = (half + self.c)[:, None]
        overlaps = (along >= -reach) & (along <= length[None] + reach)
        return np.asarray((in_gate & overlaps).any(axis=1))

    def _count_false(self, kind: str, n: int, beyond_c: int) -> None:
        self.false_tracks += n
        self.false_by_kind[kind] += n
        self.false_beyond_c += beyond_c

    def _deletions(self, scan: ScanInput, tracks: TrackView) -> None:
        run = self._run
        if run is None:
            return
        alive = set(tracks.track_id.tolist())
        to_base = _inverse(scan.odom_pose)
        lo, hi = _wedge(scan.points_base, scan.origin_base)

        def in_view(pts: FloatArray) -> bool:
            rel = to_frame(to_base, pts) - scan.origin_base
            bearing = np.arctan2(rel[:, 1], rel[:, 0])
            rng = np.hypot(rel[:, 0], rel[:, 1])
            return bool(np.any(
                (bearing >= lo - VIEW_MARGIN_RAD) & (bearing <= hi + VIEW_MARGIN_RAD)
                & (rng >= VIEW_RANGE_M[0]) & (rng <= VIEW_RANGE_M[1])
            ))  # fmt: skip

        # Deleted out of view earlier, and in view again now: the deletion cost a track.
        back = [in_view(pts) for pts in run.deleted_away]
        self.static_deleted_out_of_view_returned += sum(back)
        run.deleted_away = [p for p, b in zip(run.deleted_away, back, strict=True) if not b]
        for tid, pts in run.confirmed_static.items():
            if tid in alive:
                continue
            if in_view(pts):
                self.static_deleted_in_view += 1
            else:
                self.static_deleted_out_of_view += 1
                run.deleted_away.append(pts)
        static = tracks.confirmed & (
            np.isin(tracks.kind, (KIND_SEGMENT, KIND_CORNER))
            | ((tracks.kind == KIND_CYLINDER) & (tracks.moving_probability < MOVING))
        )
        kept: dict[int, FloatArray] = {}
        for i in np.flatnonzero(static).tolist():
            if tracks.kind[i] == KIND_SEGMENT:
                ends = tracks.extent[i].reshape(2, 2)
                kept[int(tracks.track_id[i])] = np.concatenate([tracks.state[i, None, :2], ends])
            else:
                kept[int(tracks.track_id[i])] = tracks.state[i, None, :2].copy()
        # A confirmed track reported non-static now (a cylinder found moving) stops counting.
        run.confirmed_static = kept

    def _latency(self, stamp_s: float, hit_mover: BoolArray, ti: IntArray, base: int) -> None:
        run = self._run
        if run is None:
            return
        tracked = np.zeros(hit_mover.shape[0], dtype=bool)
        tracked[ti[ti >= base] - base] = True
        for m in range(hit_mover.shape[0]):
            entry = run.entries.get(m)
            if tracked[m]:
                if entry is not None:
                    self.latencies_s.append(stamp_s - entry.start_s)
                    del run.entries[m]
                continue
            if entry is not None and stamp_s - entry.last_hit_s > self.entry_reset_s:
                self.unconfirmed_entries += 1
                del run.entries[m]
                entry = None
            if hit_mover[m]:
                if entry is None:
                    run.entries[m] = _Entry(stamp_s, stamp_s)
                else:
                    entry.last_hit_s = stamp_s
        run.mover_tracked = tracked

    def _path_relevant(
        self,
        scan: ScanInput,
        path: FloatArray | None,
        truth_xy: FloatArray,
        known: BoolArray,
        movers: FloatArray,
        ti: IntArray,
        ei: IntArray,
        pidx: IntArray,
        tracks: TrackView,
        base: int,
    ) -> None:
        """The path-relevant figures (module docstring): movers' confirmation from entering
        ``path_mover_m`` of the path ahead, and the uncertainty of the tracks of the objects
        that should be known within ``path_object_m`` of it."""
        run = self._run
        if run is None or path is None:
            return

        def gap(xy: FloatArray) -> FloatArray:
            if xy.shape[0] == 0:
                return np.zeros(0)
            d = np.hypot(xy[:, None, 0] - path[None, :, 0], xy[:, None, 1] - path[None, :, 1])
            return np.asarray(d.min(axis=1))

        tracked = np.zeros(movers.shape[0], dtype=bool)
        tracked[ti[ti >= base] - base] = True
        near_path = gap(movers) - scan.mover_radius_m <= PATH_MOVER_M
        for m in range(movers.shape[0]):
            entry = run.path_entries.get(m)
            if tracked[m]:
                if entry is not None:
                    self.path_latencies_s.append(scan.stamp_s - entry.start_s)
                    del run.path_entries[m]
                continue
            if entry is not None and scan.stamp_s - entry.last_hit_s > self.entry_reset_s:
                self.path_unconfirmed += 1
                del run.path_entries[m]
                entry = None
            if near_path[m]:
                if entry is None:
                    run.path_entries[m] = _Entry(scan.stamp_s, scan.stamp_s)
                else:
                    entry.last_hit_s = scan.stamp_s
        relevant = known & (gap(truth_xy) <= PATH_OBJECT_M)
        self.path_known += int(relevant.sum())
        pairs = relevant[ti]
        self.path_paired += int(pairs.sum())
        if pairs.any():
            P = tracks.covariance[pidx[ei[pairs]], :2, :2]
            det = np.linalg.det(P)
            self.path_sigmas_m.extend(np.sqrt(np.sqrt(np.maximum(det, 0.0))).tolist())

    # -------------------------------------------------------------------------- summary
    def summary(self) -> dict[str, Any]:
        """Every figure (module docstring), JSON-ready (None where there is no sample)."""
        self.end_run()
        parts = np.asarray(self.gospa_parts).reshape(-1, 4)
        mean = parts.mean(axis=0) if parts.size else np.full(4, np.nan)

        def rmse(v: list[float]) -> float | None:
            return float(np.sqrt(np.mean(np.square(v)))) if v else None

        def nees_block(name: str, dof: int) -> dict[str, Any]:
            runs = self.run_nees[name]
            block: dict[str, Any] = {
                "mean": float(np.mean(runs)) if runs else None,
                "dof": dof,
                "runs": len(runs),
                "samples": self.nees_samples[name],
            }
            block["interval_95"] = list(average_interval(dof, len(runs))) if runs else None
            every = np.asarray(self.all_nees[name])
            block["median"] = float(np.median(every)) if every.size else None
            block["above_95"] = float(np.mean(every > chi2.ppf(0.95, dof))) if every.size else None
            updated = np.asarray(self.all_updated[name], dtype=bool)
            for part, sel in (("updated", updated), ("coasting", ~updated)):
                some = every[sel]
                block[part] = {
                    "samples": int(some.size),
                    "mean": float(some.mean()) if some.size else None,
                    "median": float(np.median(some)) if some.size else None,
                }
            # The bulk: the mean of runs over the samples within the χ² 99.9 % point (about
            # dof − 0.02 when consistent), and the share of samples beyond it (0.1 %).
            edge = float(chi2.ppf(0.999, dof))
            within = every <= edge
            run_of = np.asarray(self.run_of_nees[name], dtype=np.int64)
            bulk = [every[within & (run_of == r)] for r in np.unique(run_of[within])]
            block["within_999"] = {
                "mean": float(np.mean([b.mean() for b in bulk])) if bulk else None,
                "beyond_share": float(np.mean(~within)) if every.size else None,
            }
            return block

        lat = np.asarray(self.latencies_s)
        return {
            "gospa": {
                "c": self.c, "p": self.p, "alpha": 2,
                "mean": _num(mean[0]), "localisation": _num(mean[1]),
                "missed": _num(mean[2]), "false": _num(mean[3]),
                "known_per_scan": self.known_objects / self.scans if self.scans else None,
                "missed_per_scan": {
                    k: v / self.scans if self.scans else None
                    for k, v in self.missed_objects.items()
                },
            },
            "position_rmse_m": {k: rmse(v) for k, v in self.errors.items()},
            "position_pairs": {k: len(v) for k, v in self.errors.items()},
            "nees": {
                "static": nees_block("static", 2),
                "moving": nees_block("moving", 4),
                "segment": nees_block("segment", 2),
            },
            "id_switches": self.id_switches,
            "fragmentations": self.fragmentations,
            "static_deleted_out_of_view": self.static_deleted_out_of_view,
            "static_deleted_in_view": self.static_deleted_in_view,
            "static_deleted_out_of_view_returned": self.static_deleted_out_of_view_returned,
            "false_tracks_per_scan": self.false_tracks / self.scans if self.scans else None,
            "false_tracks_by_kind": dict(self.false_by_kind),
            "false_tracks_beyond_c_per_scan": (
                self.false_beyond_c / self.scans if self.scans else None
            ),
            "path": {
                "mover_m": PATH_MOVER_M,
                "object_m": PATH_OBJECT_M,
                "confirm_latency_s": {
                    "p50": _pct(self.path_latencies_s, 50),
                    "p95": _pct(self.path_latencies_s, 95),
                    "entries": len(self.path_latencies_s),
                    "unconfirmed": self.path_unconfirmed,
                },
                "track_sigma_m_mean": (
                    float(np.mean(self.path_sigmas_m)) if self.path_sigmas_m else None
                ),
                "objects_tracked": (
                    self.path_paired / self.path_known if self.path_known else None
                ),
            },
            "information": {
                "seconds": self.information_seconds,
                "bits_per_s": (
                    self.information_bits / self.information_seconds
                    if self.information_given and self.information_seconds > 0.0 else None
                ),
                "path_bits_per_s": (
                    self.information_path_bits / self.information_seconds
                    if self.information_given and self.information_seconds > 0.0 else None
                ),
            },
            "confirm_latency_s": {
                "p50": float(np.percentile(lat, 50)) if lat.size else None,
                "p95": float(np.percentile(lat, 95)) if lat.size else None,
                "entries": int(lat.size),
                "unconfirmed": self.unconfirmed_entries,
            },
        }  # fmt: skip


def _pct(values: list[float], q: float) -> float | None:
    return float(np.percentile(values, q)) if values else None


def _add_nees(run: _Run, name: str, values: FloatArray, tracks: TrackView, rows: IntArray) -> None:
    """The finite NEES ``values`` of tracks ``rows`` into ``run``, each beside whether the
    scan updated its track (all taken as updated when the tracks do not say)."""
    ok = np.isfinite(values)
    run.nees[name].extend(values[ok].tolist())
    updated = np.ones(len(values), dtype=bool) if tracks.updated is None else tracks.updated[rows]
    run.nees_updated[name].extend(updated[ok].tolist())


def _num(value: float) -> float | None:
    return float(value) if math.isfinite(value) else None


def _in_gate(d: FloatArray, cov: FloatArray) -> BoolArray:
    """Whether each offset ``d`` (..., 2) lies inside the 99 % ellipse of ``cov`` (..., 2, 2)
    (False where ``cov`` is not positive definite)."""
    a, b, c = cov[..., 0, 0], cov[..., 0, 1], cov[..., 1, 1]
    det = a * c - b * b
    with np.errstate(divide="ignore", invalid="ignore"):
        d2 = (c * d[..., 0] ** 2 - 2.0 * b * d[..., 0] * d[..., 1] + a * d[..., 1] ** 2) / det
    return np.asarray((det > 0.0) & (a > 0.0) & (d2 <= _GATE_D2))


def _inverse(pose: FloatArray) -> FloatArray:
    """The pose of the parent frame in the child's: maps parent points into the child."""
    x, y, yaw = (float(v) for v in pose)
    c, s = math.cos(yaw), math.sin(yaw)
    return np.array([-(c * x + s * y), s * x - c * y, -yaw])


def _wedge(points_base: FloatArray, origin_base: FloatArray) -> tuple[float, float]:
    """The bearings (base_link, from the centre of scanning) spanned by a scan's valid
    samples; an empty interval when it has none."""
    if points_base.shape[0] == 0:
        return math.inf, -math.inf
    rel = points_base - origin_base
    bearing = np.arctan2(rel[:, 1], rel[:, 0])
    return float(bearing.min()), float(bearing.max())


def _path_gap(tracks: TrackView, path: FloatArray) -> FloatArray:
    """(k,) each track's distance from the path's points ``path`` (p, 2): a segment's
    extent (the stretch between its end points), any other track's reference point."""
    xy = tracks.state[:, :2]
    a = np.where((tracks.kind == 0)[:, None], tracks.extent[:, :2], xy)
    b = np.where((tracks.kind == 0)[:, None], tracks.extent[:, 2:], xy)
    ab = b - a
    length2 = np.maximum(np.einsum("ki,ki->k", ab, ab), 1e-12)
    rel = path[None, :, :] - a[:, None, :]
    f = np.clip(np.einsum("kpi,ki->kp", rel, ab) / length2[:, None], 0.0, 1.0)
    nearest = a[:, None, :] + f[..., None] * ab[:, None, :]
    return np.asarray(np.hypot(*(path[None] - nearest).transpose(2, 0, 1)).min(axis=1))
