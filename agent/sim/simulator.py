"""The simulated sensor head: a synchronised-scanning LEP range sensor over a 2-D world.

One sweep is simulated the way the real signal is formed:

1. On a time grid ``oversampling`` times finer than the 2.56 kHz sample rate, the mirror angle,
   the vehicle pose and the head's pan give a beam; the beam is ray-cast into the world.
2. The spot's image position follows the *true* head's geometry (eq. 6.5, with its own
   ``fd``, detector offset, baseline growth and LEP non-linearity). Its signal current follows
   eq. 6.10-6.11, and is zero where the return path from the spot to the detector is blocked
   (missing parts), where nothing is hit, or where the image falls off the detector.
3. The spot is not a point: each electrode current is the sum over the laser footprint, a
   Gaussian whose angular width follows the range. At a range discontinuity the two surfaces'
   currents blend: mixed points emerge, with no special case.
4. Noise is added to each electrode (differential noise of std ``I_n`` after filtering plus a
   smaller common-mode part), both currents pass the fourth-order Bessel low-pass, and every
   ``oversampling``-th value is the sample.

Each sweep starts with a short lead-in in which the mirror arrives at the window's start from
the opposite direction, as it does when sweeping back and forth, so the filter starts in the
state the real one would be in.

Movers (:mod:`agent.sim.movers`) are placed where they are at each fine step's own time
(the graph clock, ``start_time_s`` plus the step's offset), so a mover crossing the window
during a 0.1 s sweep is seen smeared along its motion, as a real one would be; they hide and
are hidden, on the beam and on its return path to the detector, like static cylinders. A
world without movers is simulated exactly as before they existed (the same compiled loop).

The simulator returns what the head reports (:class:`RawScan`: times, mirror angles, pan,
electrode currents) and, separately, the simulation's truth (:class:`ScanTruth`).
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from agent.arrays import FloatArray
from agent.kinematics.trajectory import StaticPose, Trajectory, head_origin
from agent.sensor.detection import (
    detection_delay_s,
    detection_filter,
    filter_state,
    white_noise_std,
)
from agent.sensor.params import SensorParameters, simulated_head
from agent.sensor.samples import RawScan
from agent.sensor.scanning import (
    ScanWindow,
    SweepTiming,
    sweep_timing,
    validate_pan,
    validate_scan_angle,
)
from agent.sim import raycast, raycast_kernels, simulator_kernels
from agent.sim.movers import Mover, mover_states
from agent.sim.world import World

PanProfile = Callable[[FloatArray], FloatArray]  # head pan (rad) at given times (s)
SMOOTH_RANGE_RATIO = 0.05  # neighbouring beams this close in range lie on one smooth surface
CULL_MARGIN_M = 1.0  # a culled world serves while the head stays this close to where it was cut
LEAD_IN_S = 4e-3  # the 1 kHz Bessel filter's impulse response has decayed to < 1e-3 by 2 ms
MAX_BEAM_RANGE_M = 6.0  # beyond this nothing images on the detector (it ends near 3.3 m)
RETURN_PATH_MARGIN_M = 1e-6  # surfaces this close to the spot do not block its return path
_MIN_SPOT_RANGE_M = 0.3  # footprint widths are evaluated no nearer than this
_BLUR_TABLE_RES = 20  # footprint kernels tabulated every 1/20 of a fine step in width


@dataclass(frozen=True)
class ScanTruth:
    """Simulation truth for each sample of a :class:`RawScan`.

    A sample taken at time ``t`` measures the beam as it pointed at ``t − delay`` (the Bessel
    filter's group delay); the truth is for that beam.

    Attributes
    ----------
    beam_time_s : (n,) time the measurement refers to, s.
    beam_angle_rad : (n,) true mirror angle then.
    beam_origin_xy : (n, 2) centre of scanning, world frame, m.
    beam_heading_rad : (n,) beam direction, world frame.
    range_m : (n,) distance along the beam to the first surface; NaN where nothing is hit.
    visible : (n,) the return path from the spot to the detector is clear.
    reflectivity : (n,) of the surface hit; NaN where nothing is hit.
    cos_view : (n,) cosine of the viewing angle on the surface (0 where nothing is hit).
    obstacle : (n,) id of the obstacle hit (:attr:`~agent.sim.world.Obstacle.id`; a mover's
        is :attr:`~agent.sim.world.World.mover_ids`, after every static obstacle), -1 where
        none.
    """

    beam_time_s: FloatArray
    beam_angle_rad: FloatArray
    beam_origin_xy: FloatArray
    beam_heading_rad: FloatArray
    range_m: FloatArray
    visible: np.ndarray
    reflectivity: FloatArray
    cos_view: FloatArray
    obstacle: np.ndarray

    @classmethod
    def empty(cls) -> ScanTruth:
        """No truth (a sweep simulated without it)."""
        e = np.empty(0)
        return cls(
            e, e, np.empty((0, 2)), e, e, np.empty(0, dtype=bool), e, e, np.empty(0, dtype=np.int64)
        )


@dataclass(frozen=True)
class _Beams:
    range_m: FloatArray  # (n,) inf where nothing hit
    visible: np.ndarray  # (n,) bool
    reflectivity: FloatArray
    cos_view: FloatArray
    obstacle: np.ndarray


class SensorSimulator:
    """Simulates the head's sensor over a world.

    Parameters
    ----------
    world
        Obstacles, world frame.
    params
        The head *as built* (default :func:`agent.sensor.params.simulated_head`).
    rng
        Source of noise; pass ``numpy.random.default_rng(seed)`` for repeatable scans.
    continuous
        The head scans without pause: a sweep that starts when the previous one ended
        continues that sweep's filter state instead of simulating a lead-in.
    """

    def __init__(
        self,
        world: World,
        params: SensorParameters | None = None,
        rng: np.random.Generator | None = None,
        continuous: bool = False,
    ) -> None:
        self.world = world
        self.params = params if params is not None else simulated_head()
        self.rng = rng if rng is not None else np.random.default_rng()
        p = self.params
        self._fine_dt = 1.0 / (p.sample_rate_hz * p.oversampling)
        self._sos = detection_filter(p)
        self._delay_s = detection_delay_s(p)
        self._noise_diff_std = white_noise_std(p, p.noise_current_A)
        self._noise_sum_std = self._noise_diff_std * p.common_mode_noise_ratio
        self._lead_in = math.ceil(LEAD_IN_S / self._fine_dt)
        self._local: tuple[FloatArray, float, tuple[FloatArray, FloatArray]] | None = None
        self._blur_table: FloatArray | None = None
        self.continuous = continuous
        self._carry: tuple[float, FloatArray] | None = None  # (end time, filter state)
        # Movers' radius, reflectivity and id, as the compiled loop reads them.
        self._movers = np.array(
            [
                (m.radius_m, m.reflectivity, float(i))
                for m, i in zip(world.movers, world.mover_ids.tolist(), strict=True)
            ],
            dtype=np.float64,
        ).reshape(-1, 3)
        load_kernels()  # here rather than in the first sweep, which a head times
        if world.movers:
            load_moving_kernel()

    def _local_world(self, centre: FloatArray, reach_m: float) -> tuple[FloatArray, FloatArray]:
        """The obstacles within ``reach_m`` of ``centre`` as the ray caster's tables (see
        :func:`agent.sim.raycast.world_tables`), cut once per metre travelled."""
        if self._local is not None:
            cut_centre, cut_reach, tables = self._local
            if float(np.linalg.norm(centre - cut_centre)) + reach_m <= cut_reach:
                return tables
        cut_reach = reach_m + CULL_MARGIN_M
        tables = raycast.world_tables(self.world.nearby(centre, cut_reach))
        self._local = (centre.copy(), cut_reach, tables)
        return tables

    @property
    def detection_delay_s(self) -> float:
        return self._delay_s

    # ------------------------------------------------------------------------------ public
    def sweep(
        self,
        window: ScanWindow | None = None,
        *,
        direction: int = 1,
        pan_rad: float | PanProfile = 0.0,
        start_time_s: float = 0.0,
        trajectory: Trajectory | None = None,
        with_truth: bool = True,
    ) -> tuple[RawScan, ScanTruth]:
        """Simulate one sweep of ``window`` (default: the full ±20°).

        ``with_truth=False`` skips the truth's ray casting (the head has no use for it); the
        truth returned is then empty.

        ``pan_rad`` is the head's pan, constant or a function of time (the head may slew while
        it scans). Raises :class:`agent.errors.HeadCommandError` for a window or a constant
        pan the head cannot scan.
        """
        p = self.params
        window = window if window is not None else ScanWindow.full(p)
        pan = pan_rad if callable(pan_rad) else validate_pan(pan_rad, p)
        timing = sweep_timing(window, direction, start_time_s, p)
        n_fine = timing.n_samples * p.oversampling
        carry = self._carry if self.continuous else None
        if carry is not None and abs(carry[0] - start_time_s) > 0.5 * self._fine_dt:
            carry = None  # not straight after the previous sweep: simulate a lead-in
        lead = 0 if carry is not None else self._lead_in
        t_rel = np.arange(-lead, n_fine, dtype=np.float64) * self._fine_dt

        def mirror(t: FloatArray) -> FloatArray:
            # Before the start the mirror was coming back the other way (back-and-forth scan).
            return timing.start_angle_rad + timing.rate_rad_s * np.abs(t)

        return self._simulate(
            start_time_s, t_rel, mirror, pan, trajectory, timing, blur=True,
            with_truth=with_truth, lead=lead, filter_in=None if carry is None else carry[1],
        )  # fmt: skip

    def stare(
        self,
        scan_angle_rad: float,
        n_samples: int,
        *,
        pan_rad: float = 0.0,
        start_time_s: float = 0.0,
        trajectory: Trajectory | None = None,
    ) -> tuple[RawScan, ScanTruth]:
        """Hold the mirror at one angle and take ``n_samples`` samples (section 6.6.1)."""
        p = self.params
        scan_angle_rad = validate_scan_angle(scan_angle_rad, p)
        if n_samples < 1:
            raise ValueError(f"n_samples must be at least 1, got {n_samples}")
        pan = validate_pan(pan_rad, p)
        n_fine = n_samples * p.oversampling
        t_rel = np.arange(-self._lead_in, n_fine, dtype=np.float64) * self._fine_dt
        timing = SweepTiming(n_samples, 0, start_time_s, scan_angle_rad, 0.0, p.sample_rate_hz)

        def mirror(t: FloatArray) -> FloatArray:
            return np.full(np.shape(t), float(scan_angle_rad))

        return self._simulate(start_time_s, t_rel, mirror, pan, trajectory, timing, blur=False)

    # ----------------------------------------------------------------------------- physics
    def _poses(
        self, t: FloatArray, pan: float | PanProfile, trajectory: Trajectory
    ) -> tuple[FloatArray, FloatArray, FloatArray]:
        """Centre of scanning (n, 2), world frame, the head's heading (n,), radians, at
        (absolute) times ``t``, and those times."""
        x, y, yaw = trajectory.poses_at(t)
        origin = head_origin(x, y, yaw, self.params.mount_offset_m)
        return origin, yaw + (pan(t) if callable(pan) else pan), t

    def _cast(
        self, origin: FloatArray, head_heading: FloatArray, t: FloatArray, theta: FloatArray
    ) -> _Beams:
        """Ray-cast beams from ``origin`` (n, 2) at mirror angles ``theta`` and check their
        return paths to the detector (see :func:`agent.sim.raycast_kernels.cast_beams`);
        ``head_heading`` is the head's own heading (vehicle yaw plus pan), per beam, and ``t``
        each beam's (absolute) time, where the movers are placed."""
        p = self.params
        if theta.size == 0:
            empty = np.empty(0)
            return _Beams(empty, np.zeros(0, dtype=bool), empty, empty, np.empty(0, np.int64))
        # Column by column: numpy reduces a (n, 2) array along its long axis slowly.
        lo = np.array([origin[:, 0].min(), origin[:, 1].min()])
        hi = np.array([origin[:, 0].max(), origin[:, 1].max()])
        centre = 0.5 * (lo + hi)
        spread = 0.5 * float(np.linalg.norm(hi - lo))
        segments, circles = self._local_world(centre, MAX_BEAM_RANGE_M + spread)
        if self.world.movers:
            mover_xy, _ = mover_states(self.world.movers, t)  # (m, n, 2)
            beams = raycast_kernels.cast_beams_moving(
                np.ascontiguousarray(origin, dtype=np.float64),
                np.ascontiguousarray(head_heading, dtype=np.float64),
                np.ascontiguousarray(head_heading + theta, dtype=np.float64),
                np.ascontiguousarray(theta, dtype=np.float64),
                MAX_BEAM_RANGE_M, p.baseline_m, p.baseline_edge_growth, p.scan_half_angle_rad,
                RETURN_PATH_MARGIN_M, segments, circles,
                np.ascontiguousarray(mover_xy.transpose(1, 0, 2)), self._movers,
            )  # fmt: skip
            return _Beams(*beams)
        range_m, visible, reflectivity, cos_view, obstacle = raycast_kernels.cast_beams(
            np.ascontiguousarray(origin, dtype=np.float64),
            np.ascontiguousarray(head_heading, dtype=np.float64),
            np.ascontiguousarray(head_heading + theta, dtype=np.float64),
            np.ascontiguousarray(theta, dtype=np.float64),
            MAX_BEAM_RANGE_M, p.baseline_m, p.baseline_edge_growth, p.scan_half_angle_rad,
            RETURN_PATH_MARGIN_M, segments, circles,
        )  # fmt: skip
        return _Beams(range_m, visible, reflectivity, cos_view, obstacle)

    def _beams(
        self,
        t: FloatArray,
        theta: FloatArray,
        pan: float | PanProfile,
        trajectory: Trajectory,
        coarse_step: int = 1,
    ) -> _Beams:
        """Ray-cast the beams at (absolute) times ``t`` and mirror angles ``theta``; check
        their return paths to the detector.

        With ``coarse_step`` k > 1 the beams are cast every k-th step first; where two
        neighbouring coarse beams meet the same surface, both seen (or both hidden) from the
        detector, at ranges within ``SMOOTH_RANGE_RATIO`` of each other, the steps between are
        interpolated; everywhere else (edges, shadows, grazing jumps) every step is cast
        (see :func:`agent.sim.simulator_kernels.fill_between`). Across one 0.16° interval a
        plane's range departs from a straight line by under 10 µm even at 60° incidence, far
        below the sensor's noise. The vehicle's and the head's poses are needed only where a
        beam is cast.
        """
        n = t.size
        if coarse_step <= 1 or n <= 2 * coarse_step:
            return self._cast(*self._poses(t, pan, trajectory), theta)
        idx = np.arange(0, n, coarse_step)
        if idx[-1] != n - 1:
            idx = np.append(idx, n - 1)
        coarse = self._cast(*self._poses(t[idx], pan, trajectory), theta[idx])
        range_m, visible, reflectivity, cos_view, obstacle, rough = simulator_kernels.fill_between(
            idx,
            coarse.range_m,
            coarse.visible,
            coarse.reflectivity,
            coarse.cos_view,
            coarse.obstacle,
            n,
            SMOOTH_RANGE_RATIO,
        )
        beams = _Beams(range_m, visible, reflectivity, cos_view, obstacle)
        exact = self._cast(*self._poses(t[rough], pan, trajectory), theta[rough])
        for name in ("range_m", "visible", "reflectivity", "cos_view", "obstacle"):
            getattr(beams, name)[rough] = getattr(exact, name)
        return beams

    def _footprint_blur(self, currents: FloatArray, range_m: FloatArray) -> FloatArray:
        """Sum each step's electrode currents over the laser footprint.

        The footprint is Gaussian with a 1/e² diameter ``w0 + divergence·r``; across the fine
        grid the mirror moves ``Δθ`` per step, so at range ``r`` the footprint spans
        ``w/(4·r·Δθ)`` steps (one standard deviation). Widths use each step's own range; see
        :func:`agent.sim.simulator_kernels.footprint_blur`.
        """
        p = self.params
        step_rad = p.scan_rate_rad_s * self._fine_dt
        # Kernels come from a table over widths quantised to 1/20 of a step (a per-step
        # exp() costs more than the rest of the blur).
        return simulator_kernels.footprint_blur(
            currents, range_m, self._blur_kernels(step_rad), float(_BLUR_TABLE_RES),
            p.spot_diameter_m, p.spot_divergence_rad, step_rad, _MIN_SPOT_RANGE_M,
            MAX_BEAM_RANGE_M,
        )  # fmt: skip

    def _blur_kernels(self, step_rad: float) -> FloatArray:
        """(rows, 2·half + 1) normalised Gaussian kernels, row k of width
        ``k / _BLUR_TABLE_RES`` fine steps (row 0 as row 1), ``half`` three of the widest."""
        if self._blur_table is None:
            p = self.params
            widest = (p.spot_diameter_m + p.spot_divergence_rad * _MIN_SPOT_RANGE_M) / (
                4.0 * _MIN_SPOT_RANGE_M * step_rad
            )
            half = max(1, math.ceil(3.0 * widest))
            sigma = np.maximum(np.arange(math.ceil(widest * _BLUR_TABLE_RES) + 2), 1)
            sigma = sigma / _BLUR_TABLE_RES
            offsets = np.arange(-half, half + 1)
            table = np.exp(-0.5 * (offsets[None, :] / sigma[:, None]) ** 2)
            table /= table.sum(axis=1, keepdims=True)
            self._blur_table = table
        return self._blur_table

    def _simulate(
        self,
        start_s: float,
        t_rel: FloatArray,
        angle_at: Callable[[FloatArray], FloatArray],
        pan: float | PanProfile,
        trajectory: Trajectory | None,
        timing: SweepTiming,
        *,
        blur: bool,
        with_truth: bool = True,
        lead: int | None = None,
        filter_in: FloatArray | None = None,
    ) -> tuple[RawScan, ScanTruth]:
        # The mirror's motion is computed from time relative to the sweep's start, so a sweep
        # comes out the same whatever the clock reads (1.7e9 s of wall clock would otherwise
        # round away 0.2 µs of every fine step).
        p = self.params
        trajectory = trajectory if trajectory is not None else StaticPose()
        theta = angle_at(t_rel)
        beams = self._beams(
            start_s + t_rel, theta, pan, trajectory, coarse_step=p.oversampling if blur else 1
        )

        # Image position and signal of each fine step (eq. 6.5, 6.8-6.11): the electrode
        # currents of spot_position, signal_current, lep_response and electrode_currents,
        # in one compiled pass.
        currents = simulator_kernels.spot_currents(
            beams.range_m, beams.visible, beams.reflectivity, beams.cos_view,
            np.ascontiguousarray(theta, dtype=np.float64), p.scan_half_angle_rad,
            p.baseline_edge_growth, p.fd_m2, p.baseline_m, p.detector_centre_m,
            p.detector_length_m, p.signal_constant_Am2, p.lep_edge_compression,
        )  # fmt: skip
        if blur:
            currents = self._footprint_blur(currents, beams.range_m)

        # Electrode noise: differential part (std I_n after filtering) and common-mode part,
        # I1 += (n_sum + n_diff)/2 and I2 += (n_sum - n_diff)/2.
        noise = self.rng.standard_normal((t_rel.size, 2))
        simulator_kernels.add_electrode_noise(
            currents, noise, self._noise_diff_std, self._noise_sum_std
        )

        zi = filter_state(p, currents[0]) if filter_in is None else filter_in
        filtered, filter_out = simulator_kernels.sos_filter(self._sos, currents, zi)
        if self.continuous and timing.direction != 0:
            self._carry = (start_s + timing.n_samples * p.oversampling * self._fine_dt, filter_out)

        lead = self._lead_in if lead is None else lead
        k = np.arange(timing.n_samples)
        sample_idx = lead + k * p.oversampling + p.oversampling // 2
        t_samples = start_s + t_rel[sample_idx]
        repeatability = p.scan_angle_repeatability_rad * self.rng.standard_normal(k.size)
        raw = RawScan(
            time_s=t_samples,
            mirror_angle_rad=theta[sample_idx] + repeatability,
            pan_rad=pan(t_samples) if callable(pan) else np.full(k.size, pan),
            current_1_A=np.ascontiguousarray(filtered[sample_idx, 0]),
            current_2_A=np.ascontiguousarray(filtered[sample_idx, 1]),
            direction=timing.direction,
        )

        if not with_truth:
            return raw, ScanTruth.empty()
        beam_rel = t_rel[sample_idx] - self._delay_s
        beam_time = start_s + beam_rel
        beam_angle = angle_at(beam_rel)
        beam_origin, head_heading, _ = self._poses(beam_time, pan, trajectory)
        truth_beams = self._cast(beam_origin, head_heading, beam_time, beam_angle)
        truth_range = np.where(np.isfinite(truth_beams.range_m), truth_beams.range_m, np.nan)
        truth = ScanTruth(
            beam_time_s=beam_time,
            beam_angle_rad=beam_angle,
            beam_origin_xy=beam_origin,
            beam_heading_rad=head_heading + beam_angle,
            range_m=truth_range,
            visible=truth_beams.visible,
            reflectivity=truth_beams.reflectivity,
            cos_view=truth_beams.cos_view,
            obstacle=truth_beams.obstacle,
        )
        return raw, truth


@functools.cache
def load_kernels() -> None:
    """Load the compiled kernels of a sweep (compiling them on the first use on this machine).

    The first kernel a process loads sets numba up, about half a second of CPU; a simulator
    does this when it is made, so that a head's first sweep is not late.
    """
    world = World.build(
        walls=[(((1.0, -1.0), (1.0, 1.0)), 1.0)], cylinders=[((0.6, 0.2), 0.05, 1.0)]
    )
    n = 5
    theta, zeros = np.linspace(-0.1, 0.1, n), np.zeros(n)
    beams = raycast_kernels.cast_beams(
        np.zeros((n, 2)), zeros, theta, theta, MAX_BEAM_RANGE_M, 0.1, 0.0, 0.35,
        RETURN_PATH_MARGIN_M, *raycast.world_tables(world),
    )  # fmt: skip
    coarse = np.array([0, n - 1])
    range_m, visible, reflectivity, cos_view, obstacle = beams
    simulator_kernels.fill_between(
        coarse, range_m[coarse], visible[coarse], reflectivity[coarse], cos_view[coarse],
        obstacle[coarse], n, SMOOTH_RANGE_RATIO,
    )  # fmt: skip
    currents = simulator_kernels.spot_currents(
        range_m, visible, reflectivity, cos_view, theta, 0.35, 0.0, 0.005, 0.1, 0.0, 0.01,
        1e-8, 0.0,
    )  # fmt: skip
    simulator_kernels.footprint_blur(
        currents, range_m, np.full((2, 3), 1.0 / 3.0), float(_BLUR_TABLE_RES),
        0.002, 0.001, 3e-4, _MIN_SPOT_RANGE_M, MAX_BEAM_RANGE_M,
    )  # fmt: skip
    simulator_kernels.add_electrode_noise(currents, np.zeros((n, 2)), 1e-11, 1e-11)
    simulator_kernels.sos_filter(np.zeros((1, 6)), np.zeros((n, 2)), np.zeros((1, 2, 2)))


@functools.cache
def load_moving_kernel() -> None:
    """Load the compiled loops of beams among movers and of the movers' places (compiling
    them on the first use on this machine); a simulator of a world with movers does this
    when it is made."""
    world = World.build(walls=[(((1.0, -1.0), (1.0, 1.0)), 1.0)])
    n = 5
    theta, zeros = np.linspace(-0.1, 0.1, n), np.zeros(n)
    mover_xy = np.tile(np.array([[0.6, 0.0]]), (n, 1, 1))
    mover_states([Mover(0.1, 1.0, np.array([[0.6, 0.0], [0.6, 1.0]]), 0.5)], np.zeros(n))
    raycast_kernels.cast_beams_moving(
        np.zeros((n, 2)), zeros, theta, theta, MAX_BEAM_RANGE_M, 0.1, 0.0, 0.35,
        RETURN_PATH_MARGIN_M, *raycast.world_tables(world), mover_xy,
        np.array([[0.1, 1.0, 1.0]]),
    )  # fmt: skip


def warm_up() -> None:
    """Load the simulator's and the ray caster's compiled kernels (compiling them on the first
    use on this machine)."""
    raycast.warm_up()
    load_kernels()
    load_moving_kernel()
