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

The simulator returns what the head reports (:class:`RawScan`: times, mirror angles, pan,
electrode currents) and, separately, the simulation's truth (:class:`ScanTruth`).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from scipy import signal

from agent.arrays import FloatArray
from agent.kinematics.trajectory import StaticPose, Trajectory, head_origin
from agent.sensor.detection import (
    detection_delay_s,
    detection_filter,
    filter_state,
    white_noise_std,
)
from agent.sensor.lep import electrode_currents, lep_response, signal_current, spot_position
from agent.sensor.params import SensorParameters, simulated_head
from agent.sensor.samples import RawScan
from agent.sensor.scanning import (
    ScanWindow,
    SweepTiming,
    sweep_timing,
    validate_pan,
    validate_scan_angle,
)
from agent.sim.world import World, cast_rays, ray_directions, segment_clear

PanProfile = Callable[[FloatArray], FloatArray]  # head pan (rad) at given times (s)
SMOOTH_RANGE_RATIO = 0.05  # neighbouring beams this close in range lie on one smooth surface
CULL_MARGIN_M = 1.0  # a culled world serves while the head stays this close to where it was cut
LEAD_IN_S = 4e-3  # the 1 kHz Bessel filter's impulse response has decayed to < 1e-3 by 2 ms
MAX_BEAM_RANGE_M = 6.0  # beyond this nothing images on the detector (it ends near 3.3 m)
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
    obstacle : (n,) index of the obstacle hit, -1 where none.
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
    origin: FloatArray  # (n, 2)
    heading: FloatArray  # (n,)
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
        self._local: tuple[FloatArray, float, World] | None = None
        self._blur_table: tuple[FloatArray, int] | None = None
        self.continuous = continuous
        self._carry: tuple[float, FloatArray] | None = None  # (end time, filter state)

    def _local_world(self, centre: FloatArray, reach_m: float) -> World:
        """The obstacles within ``reach_m`` of ``centre``, cut once per metre travelled."""
        if self._local is not None:
            cut_centre, cut_reach, world = self._local
            if float(np.linalg.norm(centre - cut_centre)) + reach_m <= cut_reach:
                return world
        cut_reach = reach_m + CULL_MARGIN_M
        world = self.world.nearby(centre, cut_reach)
        self._local = (centre.copy(), cut_reach, world)
        return world

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
    def _beams(
        self,
        t: FloatArray,
        theta: FloatArray,
        pan: float | PanProfile,
        trajectory: Trajectory,
        coarse_step: int = 1,
    ) -> _Beams:
        """Ray-cast the beams at (absolute) times ``t`` and mirror angles ``theta``.

        With ``coarse_step`` k > 1 the beams are cast every k-th step first; where two
        neighbouring coarse beams meet the same surface, both seen (or both hidden) from the
        detector, at ranges within ``SMOOTH_RANGE_RATIO`` of each other, the steps between are
        interpolated; everywhere else (edges, shadows, grazing jumps) every step is cast.
        Across one 0.16° interval a plane's range departs from a straight line by under
        10 µm even at 60° incidence, far below the sensor's noise.
        """
        n = t.size
        x, y, yaw = trajectory.poses_at(t)
        origin = head_origin(x, y, yaw, self.params.mount_offset_m)
        head_heading = yaw + (pan(t) if callable(pan) else pan)
        heading = head_heading + theta
        if coarse_step <= 1 or n <= 2 * coarse_step:
            return self._cast(origin, head_heading, heading, theta)
        idx = np.arange(0, n, coarse_step)
        if idx[-1] != n - 1:
            idx = np.append(idx, n - 1)
        coarse = self._cast(origin[idx], head_heading[idx], heading[idx], theta[idx])
        r0, r1 = coarse.range_m[:-1], coarse.range_m[1:]
        both_hit = np.isfinite(r0) & np.isfinite(r1)
        r0, r1 = np.where(both_hit, r0, 0.0), np.where(both_hit, r1, 0.0)  # misses: inf
        smooth = (
            (coarse.obstacle[:-1] == coarse.obstacle[1:])
            & (coarse.visible[:-1] == coarse.visible[1:])
            & ((both_hit & (np.abs(r1 - r0) <= SMOOTH_RANGE_RATIO * np.fmin(r0, r1)))
               | (~np.isfinite(coarse.range_m[:-1]) & ~np.isfinite(coarse.range_m[1:])))
        )  # fmt: skip
        # Fill every step by interpolating between coarse beams, then re-cast the rough parts.
        pos = np.arange(n, dtype=np.float64)
        seg = np.clip(np.searchsorted(idx, pos, side="right") - 1, 0, idx.size - 2)
        frac = (pos - idx[seg]) / (idx[seg + 1] - idx[seg])
        range_m = np.where(both_hit[seg], r0[seg] + frac * (r1 - r0)[seg], coarse.range_m[seg])
        cos_view = coarse.cos_view[seg] + frac * (coarse.cos_view[seg + 1] - coarse.cos_view[seg])
        out = _Beams(
            origin=origin,
            heading=heading,
            range_m=range_m,
            visible=coarse.visible[seg].copy(),
            reflectivity=coarse.reflectivity[seg].copy(),
            cos_view=cos_view,
            obstacle=coarse.obstacle[seg].copy(),
        )
        rough = ~smooth[seg]
        rough[idx] = False  # coarse beams are exact already
        exact = self._cast(origin[rough], head_heading[rough], heading[rough], theta[rough])
        for name in ("range_m", "visible", "reflectivity", "cos_view", "obstacle"):
            getattr(out, name)[rough] = getattr(exact, name)
            getattr(out, name)[idx] = getattr(coarse, name)
        return out

    def _cast(
        self, origin: FloatArray, head_heading: FloatArray, heading: FloatArray, theta: FloatArray
    ) -> _Beams:
        """Ray-cast beams from ``origin`` (n, 2) along ``heading``; check their return paths.

        ``head_heading`` is the head's own heading (vehicle yaw plus pan), ``theta`` the
        mirror angle, per beam.
        """
        p = self.params
        n = heading.size
        directions = ray_directions(heading)
        visible = np.zeros(n, dtype=bool)
        cos_view = np.zeros(n)
        if n == 0:
            empty = np.empty(0)
            return _Beams(
                origin, heading, empty, visible, empty, cos_view, np.empty(0, dtype=np.int64)
            )
        centre = 0.5 * (origin.min(axis=0) + origin.max(axis=0))
        spread = 0.5 * float(np.linalg.norm(origin.max(axis=0) - origin.min(axis=0)))
        world = self._local_world(centre, MAX_BEAM_RANGE_M + spread)
        hits = cast_rays(world, origin, directions, max_range_m=MAX_BEAM_RANGE_M)
        range_m = np.array(hits.distance_m)
        hit = np.isfinite(range_m)
        if np.any(hit):
            # The detector's virtual viewpoint: a baseline d(θ) to the head's left (eq. 6.5).
            ratio = theta[hit] / p.scan_half_angle_rad
            baseline = p.baseline_m * (1.0 + p.baseline_edge_growth * ratio * ratio)
            hh = head_heading[hit]
            receiver = origin[hit] + baseline[:, None] * np.stack([-np.sin(hh), np.cos(hh)], -1)
            spot = origin[hit] + range_m[hit][:, None] * directions[hit]
            visible[hit] = segment_clear(world, spot, receiver)
            to_receiver = receiver - spot
            to_receiver /= np.linalg.norm(to_receiver, axis=1, keepdims=True)
            cos_view[hit] = np.clip(np.sum(hits.normal[hit] * to_receiver, axis=1), 0.0, 1.0)
        return _Beams(
            origin,
            heading,
            range_m,
            visible,
            np.array(hits.reflectivity),
            cos_view,
            np.array(hits.obstacle),
        )

    def _footprint_blur(self, currents: FloatArray, range_m: FloatArray) -> FloatArray:
        """Sum each step's electrode currents over the laser footprint.

        The footprint is Gaussian with a 1/e² diameter ``w0 + divergence·r``; across the fine
        grid the mirror moves ``Δθ`` per step, so at range ``r`` the footprint spans
        ``w/(4·r·Δθ)`` steps (one standard deviation). Widths use each step's own range.
        """
        p = self.params
        step_rad = p.scan_rate_rad_s * self._fine_dt
        r = np.clip(
            np.where(np.isfinite(range_m), range_m, MAX_BEAM_RANGE_M),
            _MIN_SPOT_RANGE_M,
            MAX_BEAM_RANGE_M,
        )
        sigma_steps = (p.spot_diameter_m + p.spot_divergence_rad * r) / (4.0 * r * step_rad)
        # Kernels come from a table over widths quantised to 1/20 of a step (a per-step
        # exp() costs more than the rest of the blur).
        table, half = self._blur_kernels(step_rad)
        row = np.rint(sigma_steps * _BLUR_TABLE_RES).astype(np.intp)
        weights = table[np.clip(row, 1, table.shape[0] - 1)]
        out = np.empty_like(currents)
        for c in range(currents.shape[1]):  # the two electrodes
            # Windows over the edge-padded signal: views, not copies.
            padded = np.pad(currents[:, c], half, mode="edge")
            windows = np.lib.stride_tricks.sliding_window_view(padded, 2 * half + 1)
            out[:, c] = np.einsum("nk,nk->n", weights, windows)
        return out

    def _blur_kernels(self, step_rad: float) -> tuple[FloatArray, int]:
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
            self._blur_table = (table, half)
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

        # Image position and signal of each fine step (eq. 6.5, 6.8-6.11).
        hit = np.isfinite(beams.range_m)
        u_true = np.where(hit, spot_position(np.where(hit, beams.range_m, 1.0), theta, p), np.nan)
        on_detector = hit & beams.visible & (np.abs(u_true) <= 1.0)
        signal_A = np.zeros(t_rel.shape)
        signal_A[on_detector] = signal_current(
            beams.range_m[on_detector],
            beams.reflectivity[on_detector],
            beams.cos_view[on_detector],
            theta[on_detector],
            p,
        )
        u_read = np.where(on_detector, lep_response(np.nan_to_num(u_true), p), 0.0)
        I1, I2 = electrode_currents(u_read, signal_A)
        currents = np.stack([I1, I2], axis=-1)
        if blur:
            currents = self._footprint_blur(currents, beams.range_m)

        # Electrode noise: differential part (std I_n after filtering) and common-mode part.
        noise = self.rng.standard_normal((t_rel.size, 2))
        n_diff = noise[:, 0] * self._noise_diff_std
        n_sum = noise[:, 1] * self._noise_sum_std
        currents[:, 0] += 0.5 * (n_sum + n_diff)
        currents[:, 1] += 0.5 * (n_sum - n_diff)

        zi = filter_state(p, currents[0]) if filter_in is None else filter_in
        filtered, filter_out = signal.sosfilt(self._sos, currents, axis=0, zi=zi)
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
        truth_beams = self._beams(beam_time, beam_angle, pan, trajectory)
        truth_range = np.where(np.isfinite(truth_beams.range_m), truth_beams.range_m, np.nan)
        truth = ScanTruth(
            beam_time_s=beam_time,
            beam_angle_rad=beam_angle,
            beam_origin_xy=truth_beams.origin,
            beam_heading_rad=truth_beams.heading,
            range_m=truth_range,
            visible=truth_beams.visible,
            reflectivity=truth_beams.reflectivity,
            cos_view=truth_beams.cos_view,
            obstacle=truth_beams.obstacle,
        )
        return raw, truth
