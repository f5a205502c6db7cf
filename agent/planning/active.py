"""The active sensor planner: where the head looks, by each action's utility against its time.

The sensor sees a 40° window to 2.5 m, ten sweeps a second; the vehicle needs to know the
space it is about to drive through and the obstacles near its way. Each time the head has
finished a sweep at its target, :class:`ActivePolicy` scores every *action* ``a`` (a pan
``p`` and a window ``[l, h]``; :func:`candidate_actions`) and commands the best.

**Cost** (:class:`HeadTiming`): the time the action takes, from the head's own limits: the
slew from the current pan at the rate and acceleration limits (a triangular or trapezoidal
profile), then ``dwell_s`` of sweeping the window at the mirror's rate (40° in 0.1 s, so a
20° window is swept ``n = dwell_s·ω_mirror/(h − l)`` times, twice as often as the full one)::

    t(a) = t_slew(|p − p_now|) + dwell_s

The dwell is the horizon an action is valued over, not a commitment (the planner decides
again after each sweep at its target): valued over one sweep alone, a slew of 0.5 s would
have to promise ten times what a 0.05 s sweep where the head already looks does, and the
head, once anywhere, would never leave.

**Utility** (bits), from what the agent knows now (:class:`Situation`):

* *Space along the way.* A cell ``c`` of the look memory (:class:`LookMemory`, 10 cm, ``odom``)
  last scanned ``age_c`` ago has lost ``1 − exp(−age_c/τ)`` of the bit that said what was
  there (a mover may have walked in since: τ = ``stale_tau_s``; never scanned: the whole
  bit). Its weight ``w_c`` says how much the vehicle needs it: ``exp(−t_c/T)`` for a cell
  within ``corridor_half_m`` of the intended path, reached in ``t_c`` at the vehicle's speed
  (``T`` = ``reach_time_s``), plus ``near_weight·exp(−d_c/near_scale_m)`` for any cell at
  ``d_c`` from the vehicle (an obstacle not yet tracked may stand anywhere near it)::

      U_space(a) = Σ_{c seen by a} w_c · (1 − exp(−age_c/τ))

* *Tracks that matter.* Track ``i``'s position covariance ``P_i`` would become
  ``P_i⁺ = (P_i⁻¹ + n·R_i⁻¹)⁻¹`` if seen on the ``n`` sweeps of the dwell, with
  ``R_i = σ(r_i)²·I`` the predicted error of a feature at its range ``r_i`` (eq. 6.19-6.20:
  ``σ = T_s·r⁴`` at best, held to at least the tracker's 3 mm floor). Its relevance
  ``ρ_i = exp(−d_i/ℓ)`` falls with ``d_i``, how close its predicted position (with its
  velocity, at the time the vehicle gets there) comes to the corridor of the intended path
  (ℓ = ``track_relevance_m``)::

      U_tracks(a) = Σ_{i seen by a} ρ_i · ½·log₂(det(P_i + N) / det(P_i⁺ + N))

  with ``N = σ_N²·I`` the precision the vehicle can use (``track_need_m``, 1 cm: it inflates
  an obstacle by 3σ on a 5 cm grid): information below it changes nothing the vehicle
  does; without it a track known to 1 cm still promised 5.5 bits a look (the gain depends
  only on the ratio of its variance to a look's, (3 mm)² at best), with it 1 bit. A
  segment (a wall) is observable only across its line: no look at a plain wall tells
  where along it its midpoint lies (its ends are its extent, not features), so its
  ``P_i`` is the across-line variance alone (the environment vector's
  ``across_sigma_m``). Taken as its 2-D position covariance, a wall whose ends were unseen
  (30 cm along its line) promised 5-8 bits a look forever: down an empty corridor the
  side walls won 18 % of the head's decisions (now 1 %), some while the vehicle stood
  waiting for the way ahead.

A cell or track is *seen by* ``a`` when it lies between the near and far limits of the depth of
field from the centre of scanning and its bearing is inside ``[p + l, p + h]`` (occlusion is
not modelled: a stated limit); for the space, inside ``[p + l, p + h − 15°]``: in open space
only that part of a window can clear anything (``unvouched_left_deg``).

**Objective**: information per second of head time, ``J(a) = (U_space + U_tracks) / t(a)``,
the best ``a`` commanded and held for one sweep at its target before the next decision.

**Path.** The intent ``vehicle_state`` carries (waypoints in ``odom``), from the vehicle's
position, out to ``horizon_m``; with no intent, the direction of motion (the heading, or
behind when reversing) is the path, so the way the vehicle goes is protected all the same.

:class:`GreedyPolicy` is the third baseline: each decision, the action that most reduces the
tracks' uncertainty in view, summed over tracks, with no regard to its time or to the path
(as a brute-force sensor manager with an uncertainty reward: the reduction of each track's
covariance norm).

Angles in radians (REP-103), ``base_link`` for pan and windows, ``odom`` for the memory.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from agent.arrays import BoolArray, FloatArray, shifted
from agent.errors import ConfigError
from agent.kinematics.limits import rest_to_rest_s
from agent.planning.policies import HeadLimits, HeadTarget, HeadView
from agent.sensor.params import SensorParameters, nominal_sensor

__all__ = [
    "ActivePolicy",
    "ActiveSettings",
    "Decision",
    "GreedyPolicy",
    "HeadTiming",
    "LookMemory",
    "Situation",
    "candidate_actions",
    "feature_sigma_m",
]

_LN2 = math.log(2.0)
_BIN_RAD = math.radians(1.0)  # the bearing histogram's bins (the actions' edges are whole degrees)


# ------------------------------------------------------------------------------- the cost
@dataclass(frozen=True)
class HeadTiming:
    """The head's time for an action: slew (rate and acceleration limited) plus one sweep."""

    rate_rad_s: float
    accel_rad_s2: float
    mirror_rate_rad_s: float

    @classmethod
    def of(cls, sensor: SensorParameters) -> HeadTiming:
        return cls(
            sensor.pan_rate_limit_rad_s,
            sensor.pan_acceleration_limit_rad_s2,
            sensor.scan_rate_rad_s,
        )

    def slew_s(self, delta_rad: FloatArray | float) -> FloatArray:
        """Time to pan through ``|delta_rad|`` from rest to rest: ``2√(Δ/a)`` while the rate
        limit is not reached (``Δ ≤ v²/a``), else ``Δ/v + v/a``."""
        return rest_to_rest_s(delta_rad, self.rate_rad_s, self.accel_rad_s2)

    def sweep_s(self, width_rad: FloatArray | float) -> FloatArray:
        """One sweep of a window ``width_rad`` wide."""
        return np.asarray(width_rad, dtype=np.float64) / self.mirror_rate_rad_s


def feature_sigma_m(range_m: FloatArray, sensor: SensorParameters, floor_m: float) -> FloatArray:
    """A feature's predicted position σ at ``range_m``: the range σ of a sample on a white
    surface seen square on, eq. 6.19-6.20 (``T·z⁴``, ``T = P·I_n/(2·f·d·S)``), held to at
    least ``floor_m``."""
    t = (
        sensor.detector_length_m
        * sensor.noise_current_A
        / (2.0 * sensor.fd_m2 * sensor.signal_constant_Am2)
    )
    return np.maximum(t * np.asarray(range_m, dtype=np.float64) ** 4, floor_m)


# ------------------------------------------------------------------------------ actions
def candidate_actions(
    limits: HeadLimits, pan_step_rad: float, window_widths_rad: tuple[float, ...]
) -> FloatArray:
    """(n, 3) the actions (pan, low, high): pans every ``pan_step_rad`` within the limit;
    for each width, the windows of that width at the low end, the centre and the high end
    of the mirror's range (one window for the full width)."""
    if not (math.isfinite(pan_step_rad) and pan_step_rad > 0):
        raise ConfigError(f"active planner: pan step must be positive, got {pan_step_rad}")
    k = math.floor(limits.pan_limit_rad / pan_step_rad + 1e-9)
    pans = np.arange(-k, k + 1) * pan_step_rad
    half = limits.scan_half_angle_rad
    windows: list[tuple[float, float]] = []
    for w in window_widths_rad:
        if not (0 < w <= 2 * half + 1e-12):
            raise ConfigError(
                f"active planner: window width {math.degrees(w):g} deg is outside "
                f"(0, {math.degrees(2 * half):g}] deg"
            )
        for low in sorted({-half, -0.5 * w, half - w}):
            windows.append((low, min(low + w, half)))
    out = [(float(p), lo, hi) for p in pans for lo, hi in dict.fromkeys(windows)]
    return np.asarray(out, dtype=np.float64)


# -------------------------------------------------------------------------- look memory
class LookMemory:
    """When each cell about the vehicle (``odom``, ``cell_m`` squares, a ``size_m`` square
    re-centred on the vehicle) was last inside a scanned window within the depth of field."""

    def __init__(self, cell_m: float = 0.1, size_m: float = 8.0) -> None:
        self.cell_m = cell_m
        self.n = math.ceil(size_m / cell_m)
        self.origin_xy = np.zeros(2)
        self.last_s = np.full((self.n, self.n), -np.inf)
        self._placed = False

    def recentre(self, xy: FloatArray) -> None:
        """Keep the vehicle within a metre of the grid's centre (cells shifted, new ones
        never seen)."""
        half = 0.5 * self.n * self.cell_m
        if not self._placed:
            self.origin_xy = np.floor((np.asarray(xy[:2]) - half) / self.cell_m) * self.cell_m
            self._placed = True
            return
        centre = self.origin_xy + half
        if np.all(np.abs(np.asarray(xy[:2]) - centre) <= 1.0):
            return
        shift = np.round((np.asarray(xy[:2]) - centre) / self.cell_m).astype(np.int64)
        self.last_s = shifted(self.last_s, int(shift[1]), int(shift[0]))
        self.origin_xy = self.origin_xy + shift * self.cell_m

    def centres(self) -> tuple[FloatArray, FloatArray]:
        """(n,) x and (n,) y of the cells' centres along each axis."""
        idx = (np.arange(self.n) + 0.5) * self.cell_m
        return self.origin_xy[0] + idx, self.origin_xy[1] + idx

    def add_wedge(
        self,
        t_s: float,
        head_xy: FloatArray,
        low_rad: float,
        high_rad: float,
        near_m: float,
        far_m: float,
    ) -> None:
        """Stamp ``t_s`` into the cells whose centre lies between ``near_m`` and ``far_m``
        of ``head_xy`` at an ``odom`` bearing within ``[low_rad, high_rad]``."""
        self.recentre(head_xy)
        c = self.cell_m
        lo = np.floor((np.asarray(head_xy) - far_m - self.origin_xy) / c).astype(int)
        hi = np.ceil((np.asarray(head_xy) + far_m - self.origin_xy) / c).astype(int)
        lo = np.clip(lo, 0, self.n)
        hi = np.clip(hi, 0, self.n)
        if np.any(hi <= lo):
            return
        xs = self.origin_xy[0] + (np.arange(lo[0], hi[0]) + 0.5) * c - head_xy[0]
        ys = self.origin_xy[1] + (np.arange(lo[1], hi[1]) + 0.5) * c - head_xy[1]
        dx, dy = np.meshgrid(xs, ys)
        r = np.hypot(dx, dy)
        mid = 0.5 * (low_rad + high_rad)
        off = np.abs(np.remainder(np.arctan2(dy, dx) - mid + math.pi, 2 * math.pi) - math.pi)
        inside = (r >= near_m) & (r <= far_m) & (off <= 0.5 * (high_rad - low_rad))
        block = self.last_s[lo[1] : hi[1], lo[0] : hi[0]]
        block[inside] = t_s


# ---------------------------------------------------------------------------- situation
@dataclass
class Situation:
    """What the planner knows when it chooses (``odom`` unless said).

    ``pose`` (3,) the vehicle's newest pose, ``speed_m_s`` and ``yaw_rate_rad_s``;
    ``intent_xy`` (k, 2) its intended waypoints, nearest first (may be empty); ``watch_xy``
    (w, 2) the places it asks to be looked at (may be empty);
    ``position_xy`` (n, 2), ``velocity_xy`` (n, 2), ``covariance`` (n, 2, 2) the
    obstacles' positions (segments: midpoints), velocities and position covariances,
    ``ends_xy`` (n, 2, 2) the points a track is seen by (a segment's ends; a point's own
    position twice); ``line_sigma_m`` (n,) a segment's σ across its line (the only part of
    its position a look observes), NaN for other kinds (empty: every track a point);
    ``memory``: when each cell was last scanned."""

    pose: FloatArray | None = None
    speed_m_s: float = 0.0
    yaw_rate_rad_s: float = 0.0
    intent_xy: FloatArray = field(default_factory=lambda: np.zeros((0, 2)))
    watch_xy: FloatArray = field(default_factory=lambda: np.zeros((0, 2)))
    position_xy: FloatArray = field(default_factory=lambda: np.zeros((0, 2)))
    velocity_xy: FloatArray = field(default_factory=lambda: np.zeros((0, 2)))
    covariance: FloatArray = field(default_factory=lambda: np.zeros((0, 2, 2)))
    ends_xy: FloatArray = field(default_factory=lambda: np.zeros((0, 2, 2)))
    line_sigma_m: FloatArray = field(default_factory=lambda: np.zeros(0))
    memory: LookMemory = field(default_factory=LookMemory)


@dataclass(frozen=True)
class Decision:
    """The chosen action, its utility (bits: space, tracks), its time (s) and the stamp;
    ``in_bits`` false where the utility is another reward (:class:`GreedyPolicy`'s, the
    covariance norms' reduction, m, in ``track_bits``)."""

    target: HeadTarget
    space_bits: float
    track_bits: float
    time_s: float
    stamp_s: float
    in_bits: bool = True


# ------------------------------------------------------------------------------ settings
@dataclass(frozen=True)
class ActiveSettings:
    """The active planner's constants (module docstring), with their reasons.

    pan_step_deg, window_widths_deg
        Candidate pans every 5° (the head holds any pan; 5° is an eighth of the window, finer
        than anything the utilities resolve) and windows of 40° and 20° (a 20° window at
        either end or the centre: twice the revisit rate over half the width).
    dwell_s
        The horizon an action is valued over after its slew (0.2 s: two full sweeps, four
        half ones; module docstring).
    horizon_m
        How far along the intended path the corridor reaches (3 m: past the far limit from
        the head, 6 s at 0.5 m/s).
    corridor_half_m
        The corridor's half width about the path: the vehicle's half width (0.3 m) and the
        swing of its corners in a turn (to its 0.5 m circumradius), with a cell to spare.
    reach_time_s, min_speed_m_s
        A corridor cell reached in ``t`` weighs ``exp(−t/reach_time_s)`` (2 s: what the
        vehicle reaches in the next 2 s matters most); the time at no less than
        ``min_speed_m_s`` (0.5 m/s, the vehicle's top speed: the soonest it could be there.
        A vehicle stopped for want of known space still means to go, and its way is then
        what matters most: at 0.2 m/s its corridor 1 m on weighed 0.08, less than the
        untracked space beside it, and the head wandered while the vehicle waited).
    stale_tau_s
        A cell's knowledge decays with this time constant (2 s: a walker at 0.8 m/s crosses
        the vehicle's length in one).
    near_weight, near_scale_m
        Any cell within reach: ``near_weight·exp(−d/near_scale_m)`` at ``d`` from the
        vehicle's centre (0.05, 1 m): something not yet tracked may be next to it; small,
        as such cells are many (a window holds 200-300 of them) and the corridor few.
    track_relevance_m
        A track's relevance falls by ``e`` per this distance from the corridor (1 m).
    sigma_floor_m
        No feature is predicted better than this (3 mm, the tracker's position floor).
    path_near_weight, path_near_scale_m
        Beside the corridor, a cell weighs ``path_near_weight·exp(−g/path_near_scale_m)``
        at ``g`` from its edge (out to three scales): a walker there may cross the path.
        Measured on ``bench tracking`` (100 scenes, seed 0), off / 0.1 / 0.2: movers near
        the path confirmed p50 2.1 / 1.4 / 1.4 s (``forward`` 4.0), movers' NEES 5.81 /
        4.23 / 4.27 ([3.40, 4.65]), false tracks 0.025 / 0.012 / 0.014 a scan, path-relevant
        tracks' det(P)^¼ 0.039 / 0.042 / 0.045 m (``sweep`` 0.054): 0.1.
    track_weight
        The tracks' bits against the space's (1). At 5 (with ``path_near_weight`` 0.2) the
        path-relevant tracks' det(P)^¼ fell to 0.037 m, but movers glimpsed and left
        coasting made their NEES 28 and false tracks 0.024 a scan.
    unvouched_left_deg
        The space a window is credited with leaves out its left 15°: where a scan returns
        no light (open space), a beam is vouched for only if the scan reached the
        detector's baseline over the near limit (13.6°) plus 1° to its left
        (:func:`agent.planning.free_space.vouched_no_return`), so the left 14.6° of every
        window clear nothing there, and a 20° window only its right 5.4°: credited with its
        whole width, a window placed on the way may clear none of it. The look memory still
        marks the whole window (the planner stage's ``_situate_scan`` says why).
    watch_weight
        A cell holding a place the vehicle asks to be looked at (``vehicle_state``'s
        ``watch_xy``: where a walker it lost may be, whose walk it waits beside) weighs this
        much more, and so do its eight neighbours (a walker's place is known to a cell or
        two): as much as the corridor's nearest cells, since the vehicle waits on it.
    track_need_m
        The precision of a track the vehicle can use (1 cm, module docstring: it inflates
        by 3σ, on 5 cm cells); what a look adds below it is not counted.
    """

    pan_step_deg: float = 5.0
    dwell_s: float = 0.2
    window_widths_deg: tuple[float, ...] = (40.0, 20.0)
    horizon_m: float = 3.0
    corridor_half_m: float = 0.55
    reach_time_s: float = 2.0
    min_speed_m_s: float = 0.5
    stale_tau_s: float = 2.0
    near_weight: float = 0.05
    near_scale_m: float = 1.0
    track_relevance_m: float = 1.0
    sigma_floor_m: float = 0.003
    path_near_weight: float = 0.1
    path_near_scale_m: float = 1.0
    track_weight: float = 1.0
    unvouched_left_deg: float = 15.0
    watch_weight: float = 1.0
    track_need_m: float = 0.01

    def __post_init__(self) -> None:
        for name in (
            "pan_step_deg", "dwell_s", "horizon_m", "corridor_half_m", "reach_time_s",
            "min_speed_m_s", "stale_tau_s", "near_scale_m", "track_relevance_m",
            "sigma_floor_m", "path_near_scale_m", "track_need_m",
        ):  # fmt: skip
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise ConfigError(f"active planner: {name} must be positive, got {value}")
        for name in (
            "near_weight", "path_near_weight", "track_weight", "unvouched_left_deg",
            "watch_weight",
        ):  # fmt: skip
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0):
                raise ConfigError(f"active planner: {name} must be >= 0, got {value}")
        if not self.window_widths_deg:
            raise ConfigError("active planner: window_widths_deg must not be empty")


# ----------------------------------------------------------------------------- policies
class _Deciding:
    """What both planners share: one decision per sweep completed at the target."""

    name = "deciding"

    def __init__(
        self,
        settings: ActiveSettings | None = None,
        limits: HeadLimits | None = None,
        sensor: SensorParameters | None = None,
    ) -> None:
        self.settings = settings if settings is not None else ActiveSettings()
        self.sensor = sensor if sensor is not None else nominal_sensor()
        self.limits = limits if limits is not None else HeadLimits.of(self.sensor)
        self.timing = HeadTiming.of(self.sensor)
        self.near_m, self.far_m = self.sensor.depth_of_field_m
        self.actions = candidate_actions(
            self.limits,
            math.radians(self.settings.pan_step_deg),
            tuple(math.radians(w) for w in self.settings.window_widths_deg),
        )
        edges = np.rint((self.actions[:, :1] + self.actions[:, 1:] + math.pi) / _BIN_RAD).astype(
            np.int64
        )
        self._lo_bin, self._width_bins = edges[:, 0], edges[:, 1] - edges[:, 0]
        # What a window can vouch clear where nothing returns light (module docstring).
        trim = round(self.settings.unvouched_left_deg)
        self._width_bins = np.maximum(self._width_bins - trim, 1)
        widths = self.actions[:, 2] - self.actions[:, 1]
        self._sweeps = np.maximum(1.0, self.settings.dwell_s / self.timing.sweep_s(widths))
        half = self.limits.scan_half_angle_rad
        self.target = HeadTarget(0.0, -half, half)
        self.decision: Decision | None = None
        self.decisions = 0
        self._settled_at: int | None = None

    def _due(self, head: HeadView | None) -> bool:
        """A decision is due when the head, settled at the target, has swept it once."""
        if head is None:
            return self.decision is None
        t = self.target
        if not (head.settled and abs(head.pan_rad - t.pan_rad) < 1e-3):
            return False
        if self._settled_at is None:
            self._settled_at = head.sweeps
            return False
        return head.sweeps >= self._settled_at + 1

    def choose(
        self, head: HeadView | None, now_s: float, situation: Situation | None = None
    ) -> HeadTarget:
        if situation is None or situation.pose is None or not self._due(head):
            return self.target
        pan_now = head.pan_rad if head is not None else 0.0
        decision = self.decide(situation, pan_now, now_s)
        self.decision = decision
        self.decisions += 1
        if decision.target != self.target:
            self.target = decision.target
            self._settled_at = None
        else:
            self._settled_at = head.sweeps if head is not None else None
        return self.target

    def decide(self, situation: Situation, pan_now: float, now_s: float) -> Decision:
        raise NotImplementedError

    # ---------------------------------------------------------------- what an action sees
    def _head(self, pose: FloatArray) -> FloatArray:
        h = self.sensor.mount_offset_m
        return np.array([pose[0] + h * math.cos(pose[2]), pose[1] + h * math.sin(pose[2])])

    def _seen(self, bearing: FloatArray, rng: FloatArray, turn: FloatArray) -> BoolArray:
        """(n_actions, m) whether each action sees each of ``m`` points at ``bearing`` (from
        the vehicle's heading now) and ``rng`` from the centre of scanning, the vehicle
        having turned by ``turn`` (n_actions,) when the action's slew ends."""
        a = self.actions
        mid = (a[:, 0] + 0.5 * (a[:, 1] + a[:, 2]) + turn)[:, None]
        half = (0.5 * (a[:, 2] - a[:, 1]))[:, None]
        off = np.abs(np.remainder(bearing[None] - mid + math.pi, 2 * math.pi) - math.pi)
        inside = (rng >= self.near_m) & (rng <= self.far_m)
        return np.asarray((off <= half) & inside[None])

    def _turn(self, situation: Situation, pan_now: float) -> FloatArray:
        """(n_actions,) how far the vehicle turns, at its yaw rate now, while the head slews
        to each action (held to a quarter turn): its window lies that much round in
        ``odom``."""
        slew = self.timing.slew_s(self.actions[:, 0] - pan_now)
        return np.clip(situation.yaw_rate_rad_s * slew, -0.5 * math.pi, 0.5 * math.pi)

    def _time_s(self, pan_now: float) -> FloatArray:
        """(n_actions,) each action's time: the slew from ``pan_now`` and the dwell."""
        return self.timing.slew_s(self.actions[:, 0] - pan_now) + self.settings.dwell_s

    def _window_sums(self, bearing: FloatArray, value: FloatArray, turn: FloatArray) -> FloatArray:
        """(n_actions,) the sum of ``value`` over the points (already within the depth of
        field) at ``bearing`` from the heading now inside each action's window, turned by
        ``turn``: a histogram over 1° bins, twice round, and its cumulative sum (the
        actions' edges fall on whole degrees, the turn is rounded to one)."""
        step = _BIN_RAD
        n_bins = round(2 * math.pi / step)
        idx = np.floor((np.remainder(bearing + math.pi, 2 * math.pi)) / step).astype(np.int64)
        hist = np.bincount(np.minimum(idx, n_bins - 1), weights=value, minlength=n_bins)
        cum = np.concatenate([[0.0], np.cumsum(np.concatenate([hist, hist]))])
        lo = np.remainder(self._lo_bin + np.rint(turn / step).astype(np.int64), n_bins)
        return np.asarray(cum[lo + self._width_bins] - cum[lo], dtype=np.float64)

    @staticmethod
    def _looked(lam: FloatArray, k: FloatArray) -> FloatArray:
        """(n_actions, n, 2) the eigenvalues of each track's position covariance after each
        action's looks, ``(P⁻¹ + k·I)⁻¹``: ``λ/(1 + k·λ)`` (``λ`` (n, 2), ``k``
        (n_actions, n): :meth:`_track_looks`)."""
        return np.asarray(lam[None] / (1.0 + k[..., None] * lam[None]), dtype=np.float64)

    def _track_looks(
        self, situation: Situation, turn: FloatArray
    ) -> tuple[FloatArray, FloatArray, BoolArray]:
        """Per track, the eigenvalues ``λ`` (n, 2) of its position covariance (a segment's:
        its across-line variance and 0, :class:`Situation`'s ``line_sigma_m``); per action
        and track, ``k`` (n_actions, n), the information its looks add (``n/σ²``: the
        action's sweeps in its dwell over the predicted feature variance at the track's
        range); and the seen-by matrix (n_actions, n): a track is seen by an action that
        sees its position or either end. After the looks the covariance is
        ``(P⁻¹ + k·I)⁻¹``, with eigenvalues ``λ/(1 + k·λ)`` (closed form: 2×2 inverses for
        every action and track took 3 ms with 40 tracks)."""
        pose = situation.pose
        assert pose is not None
        head = self._head(pose)
        n = situation.position_xy.shape[0]
        pts = np.concatenate([situation.position_xy[:, None], situation.ends_xy], axis=1)
        d = pts - head
        rng = np.hypot(d[..., 0], d[..., 1])
        brg = np.remainder(np.arctan2(d[..., 1], d[..., 0]) - pose[2] + math.pi, 2 * math.pi)
        brg -= math.pi
        seen = np.asarray(
            self._seen(brg.reshape(-1), rng.reshape(-1), turn).reshape(-1, n, 3).any(axis=2)
        )
        sigma = feature_sigma_m(rng[:, 0], self.sensor, self.settings.sigma_floor_m)
        k = self._sweeps[:, None] / (sigma**2)[None]
        P = situation.covariance
        a, b, c = P[:, 0, 0], P[:, 0, 1], P[:, 1, 1]
        mid = 0.5 * (a + c)
        rad = np.sqrt(np.maximum(0.25 * (a - c) ** 2 + b * b, 0.0))
        lam = np.maximum(np.stack([mid + rad, mid - rad], axis=1), 0.0)
        line = situation.line_sigma_m
        if line.shape[0] == n:
            on_line = np.isfinite(line)
            lam[on_line, 0] = line[on_line] ** 2
            lam[on_line, 1] = 0.0
        return lam, k, seen


class ActivePolicy(_Deciding):
    """Information per second along the vehicle's way (module docstring)."""

    name = "active"

    def _path(self, situation: Situation) -> tuple[FloatArray, FloatArray]:
        """(k, 2) points along the intended path every half corridor from the vehicle, and
        (k,) the time the vehicle reaches each."""
        s = self.settings
        pose = situation.pose
        assert pose is not None
        start = np.asarray(pose[:2], dtype=np.float64)
        if situation.intent_xy.shape[0] > 0:
            poly = np.concatenate([start[None], situation.intent_xy])
        else:
            sign = -1.0 if situation.speed_m_s < -1e-3 else 1.0
            ahead = start + sign * s.horizon_m * np.array([math.cos(pose[2]), math.sin(pose[2])])
            poly = np.stack([start, ahead])
        seg = np.diff(poly, axis=0)
        length = np.hypot(seg[:, 0], seg[:, 1])
        cum = np.concatenate([[0.0], np.cumsum(length)])
        total = min(float(cum[-1]), s.horizon_m)
        step = 0.5 * s.corridor_half_m
        arc = np.arange(0.0, total + 1e-9, step) if total > 0 else np.zeros(1)
        x = np.interp(arc, cum, poly[:, 0])
        y = np.interp(arc, cum, poly[:, 1])
        speed = max(abs(situation.speed_m_s), s.min_speed_m_s)
        return np.stack([x, y], axis=1), arc / speed

    def _relevance(self, situation: Situation, path: FloatArray, reach_s: FloatArray) -> FloatArray:
        """(n,) each track's relevance ``ρ``: how near its predicted position (with its
        velocity, when the vehicle reaches each path point) comes to the corridor."""
        s = self.settings
        pred = (
            situation.position_xy[:, None] + situation.velocity_xy[:, None] * reach_s[None, :, None]
        )
        gap = np.hypot(*(pred - path[None]).transpose(2, 0, 1)).min(axis=1)
        return np.asarray(
            np.exp(-np.maximum(gap - s.corridor_half_m, 0.0) / s.track_relevance_m),
            dtype=np.float64,
        )

    @staticmethod
    def _watched(watch_xy: FloatArray, xs: FloatArray, ys: FloatArray, cell_m: float) -> FloatArray:
        """(len(ys), len(xs)) 1 on the cells (centres ``xs``, ``ys``, ``cell_m`` apart) that
        hold a place of ``watch_xy`` (w, 2), or neighbour one; else 0."""
        out = np.zeros((ys.size, xs.size))
        if not (watch_xy.shape[0] and xs.size and ys.size):
            return out
        col = np.floor((watch_xy[:, 0] - xs[0]) / cell_m + 0.5).astype(np.int64)
        row = np.floor((watch_xy[:, 1] - ys[0]) / cell_m + 0.5).astype(np.int64)
        for dr in (-1, 0, 1):
            for dc in (-1, 0, 1):
                r, c = row + dr, col + dc
                ok = (r >= 0) & (r < ys.size) & (c >= 0) & (c < xs.size)
                out[r[ok], c[ok]] = 1.0
        return out

    def maintained(self, situation: Situation) -> NDArray[np.uint8]:
        """(n,) 1 for the obstacles of ``situation`` the planner keeps up to date (relevance
        at least 1/e: predicted within ``track_relevance_m`` of the corridor), 0 for those it
        lets coast; empty without a pose."""
        n = situation.position_xy.shape[0]
        if situation.pose is None or n == 0:
            return np.zeros(0, dtype=np.uint8)
        path, reach_s = self._path(situation)
        rho = self._relevance(situation, path, reach_s)
        return np.asarray(rho >= math.exp(-1.0) - 1e-12, dtype=np.uint8)

    def decide(self, situation: Situation, pan_now: float, now_s: float) -> Decision:
        s = self.settings
        pose = situation.pose
        assert pose is not None
        head = self._head(pose)
        path, reach_s = self._path(situation)
        mem = situation.memory
        mem.recentre(head)
        # The cells within reach of the head: weights and staleness.
        xs, ys = mem.centres()
        ix = (xs >= head[0] - self.far_m) & (xs <= head[0] + self.far_m)
        iy = (ys >= head[1] - self.far_m) & (ys <= head[1] + self.far_m)
        cx, cy = np.meshgrid(xs[ix], ys[iy])
        cells = np.stack([cx.ravel(), cy.ravel()], axis=1)
        last = mem.last_s[np.ix_(iy, ix)].ravel()
        asked = self._watched(situation.watch_xy, xs[ix], ys[iy], mem.cell_m).ravel()
        d_head = cells - head
        rng = np.hypot(d_head[:, 0], d_head[:, 1])
        keep = (rng >= self.near_m) & (rng <= self.far_m)
        cells, last, rng, d_head = cells[keep], last[keep], rng[keep], d_head[keep]
        dist_vehicle = np.hypot(cells[:, 0] - pose[0], cells[:, 1] - pose[1])
        weight = s.near_weight * np.exp(-dist_vehicle / s.near_scale_m)
        weight += s.watch_weight * asked[keep]
        # The corridor: cells within its half width of a path point (only those in the
        # path's box are compared); each weighs by the first (soonest) such point.
        # Beside the corridor, out to the mover's reach, what may walk into it weighs
        # ``path_near_weight`` falling by e per ``path_near_scale_m`` from its edge.
        reach_m = s.corridor_half_m + (3.0 * s.path_near_scale_m if s.path_near_weight else 0)
        lo = path.min(axis=0) - reach_m
        hi = path.max(axis=0) + reach_m
        box = np.flatnonzero(np.all((cells >= lo) & (cells <= hi), axis=1))
        d2 = (cells[box, None, 0] - path[None, :, 0]) ** 2 + (
            cells[box, None, 1] - path[None, :, 1]
        ) ** 2
        near_path = d2 <= s.corridor_half_m**2
        hit = near_path.any(axis=1)
        first = np.argmax(near_path, axis=1)
        weight[box[hit]] += np.exp(-reach_s[first[hit]] / s.reach_time_s)
        if s.path_near_weight:
            beside = np.sqrt(d2.min(axis=1)) - s.corridor_half_m
            weight[box] += np.where(
                hit,
                0.0,
                s.path_near_weight * np.exp(-np.maximum(beside, 0.0) / s.path_near_scale_m),
            )
        age = now_s - last
        stale = 1.0 - np.exp(-np.maximum(age, 0.0) / s.stale_tau_s)
        value = weight * stale
        brg = np.arctan2(d_head[:, 1], d_head[:, 0]) - pose[2]
        turn = self._turn(situation, pan_now)
        space = self._window_sums(brg, value, turn)

        tracks = np.zeros(self.actions.shape[0])
        if situation.position_xy.shape[0] > 0:
            lam, k, seen = self._track_looks(situation, turn)
            # ½·log₂(det(P + N) / det(P⁺ + N)) over the eigenvalues λ of P (of P⁺:
            # λ/(1 + k·λ)), N = track_need_m²·I.
            need = s.track_need_m**2
            after = self._looked(lam, k)
            gain = 0.5 * np.log((lam[None] + need) / (after + need)).sum(axis=2) / _LN2
            gain = np.where(np.isfinite(gain), gain, 0.0)
            rho = self._relevance(situation, path, reach_s)
            tracks = s.track_weight * np.sum(seen * gain * rho[None], axis=1)

        time_s = self._time_s(pan_now)
        rate = (space + tracks) / time_s
        best = int(np.argmax(rate))
        a = self.actions[best]
        return Decision(
            HeadTarget(float(a[0]), float(a[1]), float(a[2])),
            float(space[best]), float(tracks[best]), float(time_s[best]), now_s,
        )  # fmt: skip


class GreedyPolicy(_Deciding):
    """The action that most reduces the tracks' uncertainty in view (module docstring)."""

    name = "greedy"

    def decide(self, situation: Situation, pan_now: float, now_s: float) -> Decision:
        time_s = self._time_s(pan_now)
        reward = np.zeros(self.actions.shape[0])
        if situation.position_xy.shape[0] > 0:
            lam, k, seen = self._track_looks(situation, self._turn(situation, pan_now))
            # Frobenius norms from the eigenvalues, before and after: λ and λ/(1 + k·λ).
            after = self._looked(lam, k)
            drop = np.hypot(lam[:, 0], lam[:, 1])[None] - np.hypot(after[..., 0], after[..., 1])
            reward = np.sum(seen * np.where(np.isfinite(drop), drop, 0.0), axis=1)
        # Ties (no track in view anywhere): stay where the head is, at the full window.
        current = np.abs(self.actions[:, 0] - self.target.pan_rad) < 1e-9
        current &= np.abs(self.actions[:, 1] - self.target.window_low_rad) < 1e-9
        current &= np.abs(self.actions[:, 2] - self.target.window_high_rad) < 1e-9
        best = int(np.argmax(reward + 1e-12 * current))
        a = self.actions[best]
        return Decision(
            HeadTarget(float(a[0]), float(a[1]), float(a[2])),
            0.0, float(reward[best]), float(time_s[best]), now_s, in_bits=False,
        )  # fmt: skip
