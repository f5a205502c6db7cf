"""The planner stage: the environment vector for the vehicle, and where the head looks.

Inputs: ``tracks`` (obstacles), ``filtered_scan`` (free space), ``vehicle_state`` (the
vehicle's odometry pose, to carry free space with its motion; its intent, for the active
planner), ``head_state`` (the head's health, and its pan for placing beams that returned
nothing). Outputs: ``environment`` once
per ``tracks`` message (stamped with the tracks' stamp, frame ``odom``), and at
``idle_period_s`` with ``sensor_ok`` false while no tracks come (never silence); and
``head_command`` when the head policy's target changes, or again when the head's reports
show it did not take it.

See :mod:`agent.planning.environment` (obstacles, health), :mod:`agent.planning.free_space`
(the profile), :mod:`agent.planning.policies` (the head policies) and
:mod:`agent.planning.active` (the active planners). Everything is by stamps and the graph
clock ``now_s``: the same inputs give the same outputs in lock-step and as processes.

Counters: ``tracks``, ``filtered_scans``, ``vehicle_states``, ``head_states``;
``environments`` published, ``environments_not_ok`` of them, and per reason
``not_ok_<reason>`` (``stale_tracks``, ``stale_scans``, ``stale_vehicle``, ``stale_head``,
``head_fault``, ``laser_off``, ``command_refused``); ``obstacles``, ``docking_targets``,
``tracks_tentative`` (not obstacles), ``tracks_non_finite`` (dropped); free space:
``scans_added``, ``scans_uncompensated`` and ``scans_no_pose`` (not used: their beams cannot
be placed in ``odom``), ``scans_out_of_order``, ``scans_pan_unknown`` (the beams'
directions not told, nor the head's pan steady: no-returns not used),
``beams_vouched`` (no-returns taken as nothing in range), ``profiles_no_pose`` (published
as all unknown), ``scan_window_given`` (vectors naming the window their scan covered);
``vehicle_state_out_of_order``, ``vehicle_state_duplicate``;
``head_commands``, ``head_commands_resent``.
"""

from __future__ import annotations

import dataclasses
import math
from collections import deque

import numpy as np

from agent import perception
from agent.arrays import FloatArray
from agent.errors import ConfigError
from agent.perception.filtering import PoseHistory
from agent.planning import free_space
from agent.planning.active import Situation
from agent.planning.environment import (
    DOCKING_REFLECTIVITY,
    HeadReport,
    Obstacles,
    obstacles_from_tracks,
    sensor_health,
)
from agent.planning.free_space import (
    FreeSpaceMap,
    FreeSpaceSettings,
    scan_dark,
    scan_spans,
    told_headings,
)
from agent.planning.policies import (
    POLICIES,
    HeadLimits,
    HeadPolicy,
    HeadTarget,
    HeadView,
    make_policy,
)
from agent.runtime import topics
from agent.runtime.messages import (
    EnvironmentVector,
    FilteredScan,
    HeadCommand,
    Header,
    HeadState,
    Message,
    Tracks,
    VehicleState,
    stamp_ns,
)
from agent.runtime.stage import Output, Params, Stage
from agent.sensor.params import SensorParameters, nominal_sensor
from agent.stages.scan_checks import filtered_scan_problem

VALID_FOR_S = 0.3  # three scan periods: one lost vector is ridden over, two stop the vehicle
STALE_AFTER_S = 0.3  # three periods of the slowest input (scans, states at 10 Hz)
IDLE_PERIOD_S = 0.1  # the vector's rate while no tracks come: the scan rate, 10 Hz
RESEND_AFTER_S = 0.5  # longer than a sweep plus a slew of 40° (0.1 s + 0.47 s is the worst)
# The seen map (the vector's seen_* profiles): the same scans with the movers taken as still
# (the settings want a positive speed; at 1 mm/s no deadline is cut by movers), cells within
# SEEN_EDGE_M of the unseen refused (half a cell: the cells whose centre the footprint
# covers, plus 5 mm), kept SEEN_MAX_AGE_S (the aged map's: it bounds the odometry's drift
# between a scan and the vector). Measured on evaluate's random runs 0-47 of seed 0
# (active, perfect odometry, no walkers), tasks done: the aged profiles recorded, 0; the
# seen ones with edge 0.07 m (the aged map's), kept 2 s, 5; with 0.03 m, kept 0.5 s, 8,
# kept 2 s, 13. Kept 2 s, the odometry's drift (a turn's heading error) moved a doorway's
# edge 6 cm under what was seen clear, and the vehicle struck it (run 6, drift and walkers).
SEEN_MOVER_SPEED_M_S = 1e-3
SEEN_EDGE_M = 0.03
SEEN_MAX_AGE_S = 0.5
_MAX_SEEN_AGE_S = 1e6  # environment/1's bound on seen_age_s
_SETTLED_RATE_RAD_S = 1e-6
_SETTLED_PAN_RAD = 1e-3
_PAN_REPORT_SLACK_S = 0.005  # detection delay (< 1 ms) and stamp rounding, with room
_REASONS = (
    "stale_tracks", "stale_scans", "stale_vehicle", "stale_head", "head_fault", "laser_off",
    "command_refused",
)  # fmt: skip


class PlannerStage(Stage):
    """Publishes the environment vector and drives the head with a head policy (passive,
    or an active planner fed the :class:`agent.planning.active.Situation` it keeps).

    Parameters
    ----------
    policy
        The head policy (:mod:`agent.planning.policies`).
    valid_for_s
        How long after its stamp a vector may be used (``valid_for_s`` of ``environment/1``).
    stale_after_s
        An input whose newest stamp is older than this before the vector's stamp makes
        ``sensor_ok`` false; and no tracks for this long starts the idle vectors.
    idle_period_s
        The rate of the vectors (all unknown, ``sensor_ok`` false) while no tracks come, and
        of the policy's ticks.
    docking_reflectivity
        Segments at least this reflective are docking targets (kind 4); see
        :data:`agent.planning.environment.DOCKING_REFLECTIVITY`.
    free_space
        The free-space profile's settings (:class:`FreeSpaceSettings`).
    resend_after_s
        A command the head's reports do not show taken this long after it was sent is sent
        again (at most this often).
    sensor
        The sensor's nominal parameters (mount offset, head limits, sample rate).
    """

    def __init__(
        self,
        policy: HeadPolicy,
        valid_for_s: float = VALID_FOR_S,
        stale_after_s: float = STALE_AFTER_S,
        idle_period_s: float = IDLE_PERIOD_S,
        docking_reflectivity: float = DOCKING_REFLECTIVITY,
        free_space: FreeSpaceSettings | None = None,
        resend_after_s: float = RESEND_AFTER_S,
        sensor: SensorParameters | None = None,
    ) -> None:
        for name, value in (
            ("valid_for_s", valid_for_s),
            ("stale_after_s", stale_after_s),
            ("idle_period_s", idle_period_s),
            ("resend_after_s", resend_after_s),
        ):
            if not (math.isfinite(value) and value > 0):
                raise ConfigError(f"planner: {name} must be a positive number, got {value}")
        self.policy = policy
        self.situation = Situation()  # what the active planners choose from
        self.sensor = sensor if sensor is not None else nominal_sensor()
        self.limits = HeadLimits.of(self.sensor)
        self.valid_for_s = valid_for_s
        self.stale_after_s = stale_after_s
        self.idle_period_s = idle_period_s
        self.docking_reflectivity = docking_reflectivity
        self.resend_after_s = resend_after_s
        settings = (
            free_space if free_space is not None else FreeSpaceSettings.for_sensor(self.sensor)
        )
        self.free_space = FreeSpaceMap(settings, self.sensor.mount_offset_m)
        # The same scans with the movers taken as still: what was seen clear, for a
        # controller that remembers static space and guards against movers by their tracks
        # (the vector's seen_* profiles).
        self.seen_space = FreeSpaceMap(
            dataclasses.replace(
                settings,
                mover_speed_m_s=SEEN_MOVER_SPEED_M_S,
                edge_m=SEEN_EDGE_M,
                max_age_s=SEEN_MAX_AGE_S,
            ),
            self.sensor.mount_offset_m,
        )
        self.poses = PoseHistory()
        self._sample_period_s = 1.0 / self.sensor.sample_rate_hz
        self._tracks_s: float | None = None
        self._scan_s: float | None = None
        self._vehicle_s: float | None = None
        self._yaw_rate = 0.0
        self._head: HeadView | None = None
        self._head_report: HeadReport | None = None
        # Recent head reports (stamp s, settled, pan rad), oldest first: the pan over a sweep.
        self._head_history: deque[tuple[float, bool, float]] = deque(maxlen=32)
        # The newest scan added with its beams' directions: (stamp ns, low, high), its
        # outermost beams' bearings (base_link at its stamp, from the centre of scanning).
        self._scan_window: tuple[int, float, float] | None = None
        # That scan's darkness per sector (scan_dark): the vector's scan_dark_m.
        self._scan_dark = np.zeros(0)
        self._target: HeadTarget | None = None
        self._sent_s = -math.inf
        self._last_tracks_now = -math.inf
        self._last_env_now = -math.inf
        self._next_tick: float | None = None
        self._counts: dict[str, int] = dict.fromkeys(
            (
                "tracks", "filtered_scans", "vehicle_states", "head_states", "environments",
                "environments_not_ok", *(f"not_ok_{r}" for r in _REASONS), "obstacles",
                "docking_targets", "tracks_tentative", "tracks_non_finite", "scans_added",
                "filtered_scan_malformed", "scans_uncompensated", "scans_no_pose",
                "scans_out_of_order", "scans_pan_unknown", "beams_vouched", "profiles_no_pose",
                "head_commands", "head_commands_resent",
                "scan_window_given",
            ),
            0,
        )  # fmt: skip

    @classmethod
    def from_params(cls, params: Params) -> PlannerStage:
        sensor = nominal_sensor()
        limits = HeadLimits.of(sensor)
        name = params.string("policy", "forward")
        if name not in POLICIES:
            raise ConfigError(
                f"process {params.process}: parameter 'policy' = {name!r} is not one of "
                f"{', '.join(POLICIES)}"
            )
        step_deg = params.number("sweep_step_deg", 40.0, lo=1.0, hi=90.0)
        dwell = params.integer("sweep_dwell_sweeps", 1)
        if dwell < 1:
            raise ConfigError(
                f"process {params.process}: parameter 'sweep_dwell_sweeps' must be >= 1, "
                f"got {dwell}"
            )
        policy = make_policy(name, limits, math.radians(step_deg), dwell)
        free = FreeSpaceSettings.for_sensor(
            sensor,
            max_age_s=params.number("free_space_max_age_s", 0.5, lo=0.05, hi=10.0),
            mover_speed_m_s=params.number("mover_speed_m_s", 0.8, lo=0.01, hi=10.0),
        )
        stage = cls(
            policy,
            valid_for_s=params.number("valid_for_s", VALID_FOR_S, lo=0.01, hi=60.0),
            stale_after_s=params.number("stale_after_s", STALE_AFTER_S, lo=0.01, hi=60.0),
            idle_period_s=params.number("idle_period_s", IDLE_PERIOD_S, lo=0.01, hi=10.0),
            docking_reflectivity=params.number(
                "docking_reflectivity", DOCKING_REFLECTIVITY, lo=0.0, hi=1000.0
            ),
            free_space=free,
            resend_after_s=params.number("resend_after_s", RESEND_AFTER_S, lo=0.01, hi=60.0),
            sensor=sensor,
        )
        params.check_all_read()
        return stage

    # ------------------------------------------------------------------------- life cycle
    def prepare(self) -> None:
        """Load the compiled kernels: the pose history's and the free-space map's (a fraction
        of a second once cached, once per process)."""
        perception.warm_up()
        free_space.warm_up()

    def start(self, now_s: float) -> list[Output]:
        self.prepare()
        self._next_tick = now_s + self.idle_period_s
        return []

    def next_tick_s(self) -> float | None:
        return self._next_tick

    def tick(self, now_s: float) -> list[Output]:
        step = self._next_tick if self._next_tick is not None else now_s
        self._next_tick = step + self.idle_period_s
        if self._next_tick <= now_s:  # fell behind: no burst of ticks
            self._next_tick = now_s + self.idle_period_s
        out = self._steer(now_s)
        if (
            now_s - self._last_tracks_now >= self.stale_after_s
            and now_s - self._last_env_now >= self.idle_period_s * (1 - 1e-9)
        ):
            out.append(self._environment(now_s, Obstacles.empty(), None, now_s))
        return out

    # ----------------------------------------------------------------------------- inputs
    def handle(self, topic: str, msg: Message, now_s: float) -> list[Output]:
        if topic == topics.TRACKS and isinstance(msg, Tracks):
            return self._on_tracks(msg, now_s)
        if topic == topics.FILTERED_SCAN and isinstance(msg, FilteredScan):
            self._on_scan(msg)
            return []
        if topic == topics.VEHICLE_STATE and isinstance(msg, VehicleState):
            self._counts["vehicle_states"] += 1
            t = msg.header.stamp_s
            self.poses.add(t, msg.x_m, msg.y_m, msg.yaw_rad, msg.speed_m_s, msg.yaw_rate_rad_s)
            if self._vehicle_s is None or t > self._vehicle_s:
                self._vehicle_s, self._yaw_rate = t, msg.yaw_rate_rad_s
                self._situate_vehicle(msg)
            return []
        if topic == topics.HEAD_STATE and isinstance(msg, HeadState):
            self._on_head_state(msg)
            return self._steer(now_s)
        return []

    def _on_head_state(self, msg: HeadState) -> None:
        self._counts["head_states"] += 1
        t = msg.header.stamp_s
        if self._head is not None and t < self._head.stamp_s:
            return  # an older report than the one held: it says nothing new
        settled = (
            msg.mode == "scanning"
            and msg.laser_on
            and abs(msg.pan_rate_rad_s) < _SETTLED_RATE_RAD_S
            and abs(msg.pan_rad - msg.target_pan_rad) < _SETTLED_PAN_RAD
        )
        self._head_history.append((t, settled, msg.pan_rad))
        self._head = HeadView(
            stamp_s=t, pan_rad=msg.pan_rad, target_pan_rad=msg.target_pan_rad,
            window_low_rad=msg.window_low_rad, window_high_rad=msg.window_high_rad,
            settled=settled, sweeps=msg.sweeps, laser_on=msg.laser_on,
            command_accepted=msg.command_accepted,
        )  # fmt: skip
        self._head_report = HeadReport(t, msg.mode, msg.laser_on, msg.command_accepted)

    def _steady_pan(self, start_s: float, end_s: float) -> float | None:
        """The head's pan over a sweep from ``start_s`` to ``end_s``, if the head's reports
        show it held still throughout: the last report at or before the start, and every one
        during the sweep, settled at the same pan. Else ``None``. The head stamps a report at
        each sweep's end and after each command (a command makes it slew), so a move within
        the sweep always shows; ``_PAN_REPORT_SLACK_S`` covers the detection delay between a
        sweep's end and its last sample's time."""
        before = [r for r in self._head_history if r[0] <= start_s + _PAN_REPORT_SLACK_S]
        if not before or not before[-1][1]:
            return None
        pan = before[-1][2]
        for stamp, settled, other in self._head_history:
            if start_s + _PAN_REPORT_SLACK_S < stamp <= end_s + _PAN_REPORT_SLACK_S and (
                not settled or abs(other - pan) > 1e-9
            ):
                return None
        return pan

    def _beams(self, scan: FilteredScan, start_s: float, end_s: float) -> FloatArray | None:
        """Each beam's direction (n,), ``base_link`` at the scan's stamp, or ``None`` when
        not known: the filter's (from the head's pan at each sample), else, from an older
        filter, ``pan + θ − ω·(t_ref − t_k)`` while the head's reports show its pan held
        still through the sweep (:meth:`_steady_pan`), the last sample at the stamp."""
        n = int(scan.flag.size)
        told = scan.beam_rad if n and scan.beam_rad.size == n else None
        pan = None if told is not None else self._steady_pan(start_s, end_s)
        return told_headings(scan.scan_angle_rad, pan, self._yaw_rate, self._sample_period_s, told)

    def _on_scan(self, scan: FilteredScan) -> None:
        self._counts["filtered_scans"] += 1
        if filtered_scan_problem(scan, covariance=False) is not None:
            self._counts["filtered_scan_malformed"] += 1
            return
        t_end = scan.header.stamp_s
        if self._scan_s is None or t_end > self._scan_s:
            self._scan_s = t_end
        if not scan.motion_compensated:
            self._counts["scans_uncompensated"] += 1
            return
        x, y, yaw, age = self.poses.poses_and_age_at(np.array([t_end]))
        if not age <= self.stale_after_s:
            self._counts["scans_no_pose"] += 1
            return
        n = int(scan.flag.size)
        t_start = t_end - n * self._sample_period_s
        beams = self._beams(scan, t_start, t_end)
        if beams is None:
            self._counts["scans_pan_unknown"] += 1
        spans = scan_spans(
            scan.points_xy, scan.origin_xy, scan.scan_angle_rad, scan.range_m, scan.sigma_m,
            scan.intensity_A, scan.flag, self.free_space.settings, beam_rad=beams,
        )  # fmt: skip
        pose = (float(x[0]), float(y[0]), float(yaw[0]))
        self.seen_space.add(spans, pose, t_start, t_end)
        if self.free_space.add(spans, pose, t_start, t_end):
            self._counts["scans_added"] += 1
            self._counts["beams_vouched"] += int(np.count_nonzero(spans.vouched))
            if beams is not None and n:
                # The beam moves continuously (the head's pan and the mirror's angle, a
                # fraction of a degree a sample), so it crossed every bearing between
                # its outermost ones: the window it scanned, slewing or not.
                low, high = float(np.min(beams)), float(np.max(beams))
                self._scan_window = (scan.header.stamp_ns, low, high)
                self._scan_dark = scan_dark(
                    beams, scan.range_m, scan.flag, scan.intensity_A, (low, high),
                    self.free_space.settings, self.free_space.bearings_rad,
                )  # fmt: skip
                self._situate_scan(t_end, pose, low, high)
        else:
            self._counts["scans_out_of_order"] += 1

    def _on_tracks(self, msg: Tracks, now_s: float) -> list[Output]:
        self._counts["tracks"] += 1
        t = msg.header.stamp_s
        self._tracks_s = t if self._tracks_s is None else max(self._tracks_s, t)
        self._last_tracks_now = now_s
        obstacles, counts = obstacles_from_tracks(
            msg.track_id, msg.kind, msg.status, msg.state, msg.covariance, msg.extent,
            msg.reflectivity, self.docking_reflectivity, msg.params, msg.params_covariance,
            msg.last_seen_ns,
        )  # fmt: skip
        self._counts["obstacles"] += len(obstacles)
        self._counts["docking_targets"] += counts.docking
        self._counts["tracks_tentative"] += counts.tentative
        self._counts["tracks_non_finite"] += counts.non_finite
        self._situate_obstacles(obstacles)
        x, y, yaw, age = self.poses.poses_and_age_at(np.array([t]))
        pose = (float(x[0]), float(y[0]), float(yaw[0])) if age <= self.stale_after_s else None
        return [self._environment(t, obstacles, pose, now_s, stamp=msg.header.stamp_ns)]

    # ------------------------------------------------------------- the planners' situation
    def _situate_vehicle(self, msg: VehicleState) -> None:
        """The vehicle's newest pose, speed, intent and the places it asks to be looked at,
        for the active planners."""
        sit = self.situation
        sit.pose = np.array([msg.x_m, msg.y_m, msg.yaw_rad])
        sit.speed_m_s = float(msg.speed_m_s)
        sit.yaw_rate_rad_s = float(msg.yaw_rate_rad_s)
        intent = np.asarray(msg.intent_xy, dtype=np.float64).reshape(-1, 2)
        sit.intent_xy = intent[np.isfinite(intent).all(axis=1)]
        watch = np.asarray(msg.watch_xy, dtype=np.float64).reshape(-1, 2)
        sit.watch_xy = watch[np.isfinite(watch).all(axis=1)]

    def _situate_obstacles(self, obstacles: Obstacles) -> None:
        """The obstacles' positions, velocities, covariances, the points they are seen by
        (a segment's ends, else the position) and a segment's σ across its line (what a
        look at it observes), for the active planners."""
        sit = self.situation
        sit.position_xy = obstacles.position_xy
        sit.velocity_xy = obstacles.velocity_xy
        sit.covariance = obstacles.covariance[:, :2, :2]
        ends = np.repeat(obstacles.position_xy[:, None], 2, axis=1)
        segment = (obstacles.kind == 0) | (obstacles.kind == 4)
        ends[segment] = obstacles.extent[segment].reshape(-1, 2, 2)
        sit.ends_xy = ends
        across = obstacles.across_sigma_m
        sit.line_sigma_m = (
            np.where(segment, across, np.nan)
            if across.shape[0] == segment.shape[0]
            else np.zeros(0)
        )

    def _situate_scan(
        self, t_end: float, pose: tuple[float, float, float], lo: float, hi: float
    ) -> None:
        """The window a scan covered (``lo``, ``hi``: base_link bearings from
        the centre of scanning) marked in the look memory, from the scan's pose. The whole
        window: marking only what each beam's evidence reached (its clear span, its hit) held
        the head on open space that never turns fresh (``bench tracking``, 30 scenes,
        ``active``: movers near the path confirmed p50 5.2 s against 1.3 s)."""
        x, y, yaw = pose
        h = self.sensor.mount_offset_m
        head = np.array([x + h * math.cos(yaw), y + h * math.sin(yaw)])
        near, far = self.sensor.depth_of_field_m
        self.situation.memory.add_wedge(t_end, head, yaw + lo, yaw + hi, near, far)

    # ---------------------------------------------------------------------------- outputs
    def _environment(
        self,
        at_s: float,
        obstacles: Obstacles,
        pose: tuple[float, float, float] | None,
        now_s: float,
        stamp: int | None = None,
    ) -> Output:
        reasons = sensor_health(
            at_s, self.stale_after_s, self._tracks_s, self._scan_s, self._vehicle_s,
            self._head_report,
        )  # fmt: skip
        if pose is None:
            self._counts["profiles_no_pose"] += 1
            bearings = self.free_space.bearings_rad.copy()
            ranges = beyond = seen = seen_beyond = np.zeros(bearings.size)
            end_hit = seen_end_hit = np.zeros(bearings.size, dtype=np.uint8)
        else:
            bearings, ranges = self.free_space.profile(pose, at_s)
            beyond = self.free_space.profile_far(pose, at_s)
            end_hit = self.free_space.end_hits(pose, at_s, ranges)
            seen = self.seen_space.profile(pose, at_s)[1]
            seen_beyond = self.seen_space.profile_far(pose, at_s)
            seen_end_hit = self.seen_space.end_hits(pose, at_s, seen)
        # The window the vector's own scan covered, when its beams' directions are known
        # (and the profile was made: one left all unknown would read as silence).
        window = self._scan_window
        scanned = dark = np.zeros(0)
        if (
            pose is not None
            and window is not None
            and window[0] == stamp
            and -math.pi <= window[1] < window[2] <= math.pi
        ):
            scanned = np.array(window[1:])
            dark = self._scan_dark
            self._counts["scan_window_given"] += 1
        self._counts["environments"] += 1
        if reasons:
            self._counts["environments_not_ok"] += 1
            for r in reasons:
                self._counts[f"not_ok_{r}"] += 1
        self._last_env_now = now_s
        stamp_at = stamp_ns(at_s) if stamp is None else stamp
        # Held to the message's range (1e6 s: "long ago").
        seen_age = (
            np.clip((stamp_at - obstacles.last_seen_ns) * 1e-9, 0.0, _MAX_SEEN_AGE_S)
            if obstacles.last_seen_ns.size == len(obstacles)
            else np.zeros(0)
        )
        vector = EnvironmentVector(
            header=Header(stamp_ns=stamp_at, frame_id="odom"),
            obstacle_id=obstacles.obstacle_id, kind=obstacles.kind,
            position_xy=obstacles.position_xy, velocity_xy=obstacles.velocity_xy,
            covariance=obstacles.covariance, extent=obstacles.extent,
            reflectivity=obstacles.reflectivity, free_bearing_rad=bearings,
            free_range_m=ranges, free_far_m=np.maximum(beyond, ranges), free_end_hit=end_hit,
            free_far_from_m=self.free_space.far_from_m, scan_window_rad=scanned,
            scan_dark_m=dark, seen_range_m=seen, seen_far_m=np.maximum(seen_beyond, seen),
            seen_end_hit=seen_end_hit, across_sigma_m=obstacles.across_sigma_m,
            maintained=self._maintained(obstacles), seen_age_s=seen_age, sensor_ok=not reasons,
            valid_for_s=self.valid_for_s,
        )  # fmt: skip
        return (topics.ENVIRONMENT, vector)

    def _maintained(self, obstacles: Obstacles) -> np.ndarray:
        """Per obstacle, whether the head planner keeps it up to date (``maintained`` of
        ``environment/1``), from a planner that chooses (:meth:`ActivePolicy.maintained`);
        empty otherwise, or when ``obstacles`` are not the situation's."""
        choose = getattr(self.policy, "maintained", None)
        if choose is None or len(obstacles) == 0:
            return np.zeros(0, dtype=np.uint8)
        if self.situation.position_xy is not obstacles.position_xy:
            return np.zeros(0, dtype=np.uint8)
        return np.asarray(choose(self.situation), dtype=np.uint8)

    def _steer(self, now_s: float) -> list[Output]:
        """Ask the policy; command the head when the target changes, or again when the
        head's reports, newer than ``resend_after_s`` after the last command, show it not
        taken (another target, refused, or laser off)."""
        target = self.policy.choose(self._head, now_s, self.situation)
        if not target.within(self.limits):  # a policy's bug must not reach the head
            raise ConfigError(f"planner: policy {self.policy.name} chose {target}, beyond the head")
        if target != self._target:
            self._target = target
            self._counts["head_commands"] += 1
            return [self._command(target, now_s)]
        head = self._head
        if (
            head is not None
            and now_s - self._sent_s >= self.resend_after_s
            and head.stamp_s >= self._sent_s + self.resend_after_s
            and not (
                head.command_accepted
                and head.laser_on
                and target.matches(
                    head.target_pan_rad, head.window_low_rad, head.window_high_rad, 1e-6
                )
            )
        ):
            self._counts["head_commands_resent"] += 1
            return [self._command(target, now_s)]
        return []

    def _command(self, target: HeadTarget, now_s: float) -> Output:
        self._sent_s = now_s
        # Why, where the policy chose this target by utility and cost (the active planners).
        utility = cost = 0.0
        decision = getattr(self.policy, "decision", None)
        if decision is not None and decision.target == target:
            cost = min(float(decision.time_s), 60.0)
            if decision.in_bits:
                utility = min(float(decision.space_bits + decision.track_bits), 1e9)
        return (
            topics.HEAD_COMMAND,
            HeadCommand(
                header=Header(stamp_ns=stamp_ns(now_s), frame_id="base_link"),
                pan_rad=target.pan_rad,
                window_low_rad=target.window_low_rad,
                window_high_rad=target.window_high_rad,
                laser=True,
                utility_bits=utility,
                cost_s=cost,
            ),
        )

    def counters(self) -> dict[str, int]:
        return {
            **self._counts,
            "vehicle_state_out_of_order": self.poses.out_of_order,
            "vehicle_state_duplicate": self.poses.duplicates,
        }
