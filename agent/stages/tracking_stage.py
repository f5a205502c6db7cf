"""The tracking stage: features to tracks in ``odom``.

Inputs: ``features`` (``base_link`` at each scan's reference time), ``filtered_scan`` (the
same scan's samples, for expected visibility; the last ``keep_scans`` are held by stamp),
``vehicle_state`` (the odometry pose and its covariance). The filtered scan and its features
come from two processes over two sockets, so a features message may arrive first (a busy
stage reads its queues in turn): it then waits, up to ``WAITING_FEATURES`` of them, for its
scan, and is used when the scan comes.
Output: ``tracks`` (tracks/2, frame ``odom``, stamped with the scan's stamp), once for every
features message that is used. See :mod:`agent.tracking`.

A features message is dropped and counted (counters, in the heartbeat) when:

* ``features_no_vehicle_state``: no vehicle state has arrived;
* ``features_stale_pose``: the state nearest the scan's stamp is older than
  ``max_state_age_s`` (as in filtering: a stopped stream is not extrapolated on and on);
* ``features_without_scan``: its filtered scan (same ``header.stamp_ns``) did not come
  while ``WAITING_FEATURES`` later features messages arrived (``features_waited`` counts
  those that waited and were used);
* ``features_wrong_frame``: its frame is not ``base_link``;
* ``features_inconsistent``: its arrays disagree in length (a decoded message cannot, a
  hand-built one can);
* ``features_out_of_order``: not later than the last scan used.

Features inside a used message that are malformed (NaN or non-positive-definite covariance
within their degrees of freedom, ...) are counted in ``features_malformed`` and the rest used;
occluding edges are counted in ``edges_ignored`` (why: :mod:`agent.tracking.tracker`).
Vehicle states with a non-finite pose or covariance are counted in
``vehicle_state_malformed``, and older or repeated ones in ``vehicle_state_out_of_order`` and
``vehicle_state_duplicate``.
"""

from __future__ import annotations

import math
from collections import OrderedDict

import numpy as np

from agent import tracking
from agent.errors import ConfigError
from agent.runtime import topics
from agent.runtime.messages import Features, FilteredScan, Header, Message, Tracks, VehicleState
from agent.runtime.stage import Output, Params, Stage
from agent.tracking.poses import PoseCovarianceHistory
from agent.tracking.tracker import FeatureBatch, ScanView, Tracker, TrackerSettings, TrackSet

MAX_STATE_AGE_S = 0.3  # s; as the filtering stage's (why: agent.stages.filtering_stage)
# Filtered scans held for their features. A scan's features follow it within a sweep when
# the graph keeps up, but a features process that is behind (a busy core, a restart, a
# saturated bench with 50 scans in flight) delivers them later; 64 scans (6.4 s at 10 Hz,
# about 2 MB) cover that, and an older one is dropped and counted.
KEEP_SCANS = 64
# Features messages held while their filtered scans have not come: 0.8 s of scans at 10 Hz
# (filtering that far behind features is not a race between two sockets any more).
WAITING_FEATURES = 8


def _malformed(msg: Features) -> str | None:
    """Why a features message cannot be used whatever else arrives (None: it can)."""
    k = msg.kind.shape[0]
    if msg.header.frame_id not in ("base_link", ""):
        return "wrong_frame"
    if (msg.params.shape, msg.covariance.shape, msg.endpoints.shape,
            msg.reflectivity.shape) != ((k, 3), (k, 3, 3), (k, 2, 2), (k,)):  # fmt: skip
        return "inconsistent"
    return None


def tracks_message(tracks: TrackSet, stamp_ns: int) -> Tracks:
    """Pack a :class:`TrackSet` into the ``tracks/2`` message (frame ``odom``)."""
    return Tracks(
        header=Header(stamp_ns=stamp_ns, frame_id="odom"),
        track_id=tracks.track_id, kind=tracks.kind, status=tracks.status, state=tracks.state,
        covariance=tracks.covariance, params=tracks.params,
        params_covariance=tracks.params_covariance, extent=tracks.extent,
        end_seen=tracks.end_seen, reflectivity=tracks.reflectivity,
        moving_probability=tracks.moving_probability, last_seen_ns=tracks.last_seen_ns,
        hits=tracks.hits, information_bits=tracks.information_bits,
    )  # fmt: skip


class TrackingStage(Stage):
    """Runs the :class:`agent.tracking.tracker.Tracker` on every scan's features.

    Parameters
    ----------
    settings
        The tracker's (:class:`agent.tracking.tracker.TrackerSettings`).
    max_state_age_s
        Launch parameter: the longest from the vehicle state nearest a scan's stamp (by
        stamps, not the clock) for the scan to be used; default 0.3 s as in filtering.
    keep_scans
        Filtered scans held, newest first, waiting for their features.
    """

    def __init__(
        self,
        settings: TrackerSettings | None = None,
        max_state_age_s: float = MAX_STATE_AGE_S,
        keep_scans: int = KEEP_SCANS,
    ) -> None:
        if not (math.isfinite(max_state_age_s) and max_state_age_s >= 0):
            raise ValueError(f"max_state_age_s must be finite and >= 0, got {max_state_age_s}")
        if keep_scans < 1:
            raise ValueError(f"keep_scans must be at least 1, got {keep_scans}")
        self.tracker = Tracker(settings if settings is not None else TrackerSettings())
        self.max_state_age_s = max_state_age_s
        self.keep_scans = keep_scans
        self.poses = PoseCovarianceHistory()
        self.scans: OrderedDict[int, ScanView] = OrderedDict()
        self._waiting: OrderedDict[int, Features] = OrderedDict()  # features before scans
        self._counts = {
            "features": 0,
            "tracks_published": 0,
            "features_no_vehicle_state": 0,
            "features_stale_pose": 0,
            "features_without_scan": 0,
            "features_waited": 0,
            "features_wrong_frame": 0,
            "features_inconsistent": 0,
            "features_out_of_order": 0,
            "vehicle_state_malformed": 0,
            "filtered_scan_inconsistent": 0,
        }

    @classmethod
    def from_params(cls, params: Params) -> TrackingStage:
        defaults = TrackerSettings()
        values = dict(
            gate_probability=params.number(
                "gate_probability", defaults.gate_probability, lo=0.5, hi=0.99999
            ),
            confirm_hits=params.integer("confirm_hits", defaults.confirm_hits),
            confirm_hits_moving=params.integer("confirm_hits_moving", defaults.confirm_hits_moving),
            confirm_window=params.integer("confirm_window", defaults.confirm_window),
            delete_misses=params.integer("delete_misses", defaults.delete_misses),
            max_coast_moving_s=params.number(
                "max_coast_moving_s", defaults.max_coast_moving_s, lo=0.1, hi=60.0
            ),
            cv_accel_psd_m2_s3=params.number(
                "cv_accel_psd_m2_s3", defaults.cv_accel_psd_m2_s3, lo=1e-4, hi=100.0
            ),
            moving_threshold=params.number(
                "moving_threshold", defaults.moving_threshold, lo=0.0, hi=1.0
            ),
            static_resolution_m=params.number(
                "static_resolution_m", defaults.static_resolution_m, lo=0.0, hi=1.0
            ),
        )
        try:
            settings = TrackerSettings(**values)  # type: ignore[arg-type]
        except ValueError as e:  # a combination out of bounds (confirm_hits > window, ...)
            raise ConfigError(f"process {params.process}: {e}") from None
        max_state_age_s = params.number("max_state_age_s", MAX_STATE_AGE_S, lo=0.0, hi=1.0)
        params.check_all_read()
        return cls(settings, max_state_age_s=max_state_age_s)

    def prepare(self) -> None:
        """Load the compiled visibility kernels (once per process)."""
        tracking.warm_up()

    def start(self, now_s: float) -> list[Output]:
        # Before the first scan, once the process has joined the graph (as features does).
        self.prepare()
        return []

    def handle(self, topic: str, msg: Message, now_s: float) -> list[Output]:
        if topic == topics.VEHICLE_STATE and isinstance(msg, VehicleState):
            self._take_state(msg)
            return []
        if topic == topics.FILTERED_SCAN and isinstance(msg, FilteredScan):
            self._take_scan(msg)
            waiting = self._waiting.pop(msg.header.stamp_ns, None)
            if waiting is None:
                return []
            self._counts["features_waited"] += 1
            out = self.track(waiting)  # counted as without_scan if the scan was refused
            return [] if out is None else [(topics.TRACKS, out)]
        if topic == topics.FEATURES and isinstance(msg, Features):
            stamp = msg.header.stamp_ns
            last = self.tracker.last_stamp_ns
            if (
                stamp not in self.scans
                and (last is None or stamp > last)
                and _malformed(msg) is None
            ):
                self._wait(msg)
                return []
            out = self.track(msg)
            return [] if out is None else [(topics.TRACKS, out)]
        return []

    def _wait(self, msg: Features) -> None:
        """Hold ``msg`` until its filtered scan comes; the oldest held beyond
        ``WAITING_FEATURES`` is dropped (``features_without_scan``)."""
        self._waiting[msg.header.stamp_ns] = msg
        while len(self._waiting) > WAITING_FEATURES:
            self._waiting.popitem(last=False)
            self._counts["features"] += 1
            self._counts["features_without_scan"] += 1

    def _take_state(self, msg: VehicleState) -> None:
        pose = np.array([msg.x_m, msg.y_m, msg.yaw_rad])
        cov = np.asarray(msg.pose_covariance, dtype=np.float64)
        if not (np.isfinite(pose).all() and np.isfinite(cov).all() and cov.shape == (3, 3)):
            self._counts["vehicle_state_malformed"] += 1
            return
        self.poses.add(
            msg.header.stamp_s, pose, 0.5 * (cov + cov.T), msg.speed_m_s, msg.yaw_rate_rad_s
        )

    def _take_scan(self, msg: FilteredScan) -> None:
        n = msg.range_m.shape[0]
        shapes = (msg.points_xy.shape, msg.origin_xy.shape, msg.scan_angle_rad.shape,
                  msg.flag.shape)  # fmt: skip
        if shapes != ((n, 2), (n, 2), (n,), (n,)) or not np.isfinite(msg.origin_xy).all():
            self._counts["filtered_scan_inconsistent"] += 1
            return
        self.scans[msg.header.stamp_ns] = ScanView(
            points_xy=msg.points_xy, origin_xy=msg.origin_xy,
            scan_angle_rad=msg.scan_angle_rad, range_m=msg.range_m, flag=msg.flag,
        )  # fmt: skip
        self.scans.move_to_end(msg.header.stamp_ns)
        while len(self.scans) > self.keep_scans:
            self.scans.popitem(last=False)

    def track(self, msg: Features) -> Tracks | None:
        """The tracks after one features message, or None if it is dropped (module doc)."""
        self._counts["features"] += 1
        stamp = msg.header.stamp_ns
        why = _malformed(msg)
        if why is None and stamp not in self.scans:
            why = "without_scan"
        elif self.tracker.last_stamp_ns is not None and stamp <= self.tracker.last_stamp_ns:
            why = "out_of_order"
        pose = None
        if why is None:
            pose = self.poses.at(stamp * 1e-9)
            if pose is None:
                why = "no_vehicle_state"
            elif pose.age_s > self.max_state_age_s:
                why = "stale_pose"
        if why is not None or pose is None:
            self._counts[f"features_{why}"] += 1
            return None
        batch = FeatureBatch(
            kind=msg.kind, params=msg.params, covariance=msg.covariance,
            endpoints=msg.endpoints, reflectivity=msg.reflectivity,
        )  # fmt: skip
        tracks = self.tracker.update(stamp, pose, batch, self.scans[stamp])
        self._counts["tracks_published"] += 1
        return tracks_message(tracks, stamp)

    def counters(self) -> dict[str, int]:
        states = {
            "vehicle_state_out_of_order": self.poses.out_of_order,
            "vehicle_state_duplicate": self.poses.duplicates,
        }
        return {**self._counts, **states, **self.tracker.counters.as_dict()}
