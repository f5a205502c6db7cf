"""The simulated head: timing, limits, noise statistics, missing parts and mixed points."""

from __future__ import annotations

import math

import numpy as np
import pytest

from agent.calibration.table import Calibration
from agent.errors import HeadCommandError
from agent.kinematics.trajectory import ConstantTwist, StaticPose, head_origin
from agent.sensor.detection import detection_filter, filter_state
from agent.sensor.lep import (
    electrode_currents,
    lep_response,
    position_from_currents,
    signal_current,
    spot_position,
)
from agent.sensor.params import SensorParameters
from agent.sensor.scanning import ScanWindow
from agent.sim import simulator_kernels
from agent.sim.simulator import SMOOTH_RANGE_RATIO, SensorSimulator
from agent.sim.targets import head_centred_pose, plane_world
from agent.sim.world import World


def _sim(world: World, head: SensorParameters, seed: int = 3) -> SensorSimulator:
    return SensorSimulator(world, head, np.random.default_rng(seed))


def test_full_sweep_timing_and_tags(head: SensorParameters) -> None:
    raw, truth = _sim(plane_world(1.0), head).sweep(
        trajectory=head_centred_pose(head), start_time_s=5.0
    )
    assert len(raw) == 256
    np.testing.assert_allclose(np.diff(raw.time_s), 1 / 2560, rtol=1e-9)
    assert raw.time_s[0] == pytest.approx(5.0 + 0.5 / 2560)
    assert raw.time_s[-1] - raw.time_s[0] == pytest.approx(0.1 - 1 / 2560)
    # Constant angular rate, 40° per 100 ms, within the mirror's 0.1 mrad repeatability.
    rate = np.polyfit(raw.time_s, raw.mirror_angle_rad, 1)[0]
    assert math.degrees(rate) == pytest.approx(400.0, rel=1e-3)
    assert np.all(np.abs(raw.mirror_angle_rad) <= math.radians(20) + 5e-4)
    np.testing.assert_array_equal(raw.pan_rad, 0.0)
    assert raw.direction == 1
    np.testing.assert_allclose(truth.beam_time_s, raw.time_s - sim_delay(head), rtol=0, atol=1e-12)


def sim_delay(head: SensorParameters) -> float:
    return _sim(World.build(), head).detection_delay_s


def test_narrow_window_takes_proportionally_less_time(head: SensorParameters) -> None:
    sim = _sim(plane_world(1.0), head)
    raw, _ = sim.sweep(
        ScanWindow.from_degrees(-5, 5), direction=-1, trajectory=head_centred_pose(head)
    )
    assert len(raw) == 64
    assert raw.time_s[-1] - raw.time_s[0] == pytest.approx(0.025 - 1 / 2560)
    assert raw.mirror_angle_rad[0] > raw.mirror_angle_rad[-1]  # sweeping towards -θ
    assert raw.direction == -1


@pytest.mark.parametrize(
    ("window", "pan", "match"),
    [
        ((-25.0, 5.0), 0.0, "outside the mirror"),
        ((-5.0, 21.0), 0.0, "outside the mirror"),
        ((5.0, -5.0), 0.0, "narrower than one sample"),
        ((-20.0, 20.0), 95.0, "pan 95.00 deg lies outside"),
        ((-20.0, 20.0), float("nan"), "pan"),
    ],
)
def test_impossible_commands_are_refused(
    head: SensorParameters, window: tuple[float, float], pan: float, match: str
) -> None:
    with pytest.raises(HeadCommandError, match=match):
        _sim(plane_world(1.0), head).sweep(
            ScanWindow.from_degrees(*window), pan_rad=math.radians(pan)
        )


def test_stare_outside_the_mirror_is_refused(head: SensorParameters) -> None:
    with pytest.raises(HeadCommandError, match="scan angle"):
        _sim(plane_world(1.0), head).stare(math.radians(21), 10)


@pytest.mark.parametrize("range_m", [0.75, 1.5, 2.5])
def test_position_noise_is_I_n_over_I_s(head: SensorParameters, range_m: float) -> None:
    sim = _sim(plane_world(range_m), head, seed=11)
    raw, _ = sim.stare(0.0, 20_000, trajectory=head_centred_pose(head))
    u, signal = position_from_currents(raw.current_1_A, raw.current_2_A)
    predicted = head.noise_current_A / signal.mean()
    # 20k samples at 2.56 kHz through a 1 kHz filter: about 10k independent ones, so the std
    # is known to ~1 %. The model adds the common-mode noise's u·σ_s term (up to 3 % at the
    # detector's ends): tolerance 5 %.
    assert np.nanstd(u) == pytest.approx(predicted, rel=0.05)
    # Mean signal follows eq. 6.10 times the Lambertian cosine of the detector's viewpoint, a
    # baseline to the side: cos(atan(d/r)) = 0.992 at 0.75 m. Sample mean to better than 0.1 %.
    view = math.cos(math.atan(head.baseline_m / range_m))
    assert signal.mean() == pytest.approx(head.signal_constant_Am2 * view / range_m**2, rel=0.002)


def test_position_noise_is_gaussian(head: SensorParameters) -> None:
    from scipy import stats

    sim = _sim(plane_world(1.0), head, seed=5)
    raw, _ = sim.stare(0.0, 5000, trajectory=head_centred_pose(head))
    u, _ = position_from_currents(raw.current_1_A, raw.current_2_A)
    # Every 4th sample is close to independent; a normality test at the 1 % level.
    assert stats.normaltest(u[::4]).pvalue > 0.01


def test_nothing_in_range_gives_noise_only(head: SensorParameters) -> None:
    raw, truth = _sim(World.build(), head).sweep(trajectory=StaticPose())
    _, signal = position_from_currents(raw.current_1_A, raw.current_2_A)
    assert np.all(np.isnan(truth.range_m))
    # Only common-mode noise (a quarter of I_n) on the sum: within 6 of its σ.
    assert np.all(np.abs(signal) < 6 * 0.25 * head.noise_current_A)


def _box_before_wall() -> tuple[World, float, float]:
    """A wall 2 m ahead of the centre of scanning and a 0.4 m box 1 m ahead, centred."""
    world = World.build(
        walls=[(((2.0, -1.5), (2.0, 1.5)), 1.0)], boxes=[((1.2, 0.0), (0.4, 0.4), 0.0, 1.0)]
    )
    return world, 1.0, 2.0


def test_missing_parts_appear_beside_the_box(
    head: SensorParameters, calibration: Calibration
) -> None:
    world, _, _ = _box_before_wall()
    raw, truth = _sim(world, head).sweep(trajectory=head_centred_pose(head))
    scan = calibration.calibrate_scan(raw)
    hidden = ~truth.visible
    theta = np.degrees(truth.beam_angle_rad)
    # The detector looks from a baseline to the left (+θ), so the box hides the wall on its
    # right: about d·(2 − 1)/1 = 9.5 cm of wall, 2.7° of scan, just right of the box's edge
    # at atan(0.2/1.0) = -11.3°.
    assert 10 <= hidden.sum() <= 25
    assert np.all((theta[hidden] < -11.0) & (theta[hidden] > -14.5))
    # There the signal is noise only, and readings (if any) have no useful precision.
    core = hidden & np.roll(hidden, 3) & np.roll(hidden, -3)
    assert np.all(np.abs(scan.intensity_A[core]) < 6 * 0.25 * head.noise_current_A)
    assert np.all(~(scan.sigma_m[core] < 0.05))


def test_mixed_points_appear_at_the_far_edge_of_the_box(
    head: SensorParameters, calibration: Calibration
) -> None:
    world, near, far = _box_before_wall()
    edge_deg = math.degrees(math.atan(0.2 / near))
    for seed in range(3):
        raw, truth = _sim(world, head, seed).sweep(trajectory=head_centred_pose(head))
        scan = calibration.calibrate_scan(raw)
        wrong = np.abs(scan.range_m - truth.range_m) > 5.0 * scan.sigma_m
        phantom = wrong & truth.visible & (scan.range_m > near + 0.1) & (scan.range_m < far - 0.1)
        theta = np.degrees(scan.scan_angle_rad)
        # On the box's left edge (+11.3°) both surfaces are seen, and the footprint and the
        # filter blend their currents: phantom ranges between box and wall, far from the
        # truth of their own beam, from no special case. Elsewhere there are none.
        assert np.count_nonzero(phantom) >= 1
        assert np.all(np.abs(theta[phantom] - edge_deg) < 1.0)


def test_vehicle_motion_moves_the_beam_origin(head: SensorParameters) -> None:
    twist = ConstantTwist(-head.mount_offset_m, 0.0, 0.0, speed_m_s=0.5, yaw_rate_rad_s=1.0)
    _, truth = _sim(plane_world(1.5), head).sweep(trajectory=twist)
    # Each sample's beam starts where the mount was at the time it measures.
    x, y, yaw = twist.poses_at(truth.beam_time_s)
    np.testing.assert_allclose(
        truth.beam_origin_xy, head_origin(x, y, yaw, head.mount_offset_m), atol=1e-12
    )
    travelled = np.linalg.norm(truth.beam_origin_xy[-1] - truth.beam_origin_xy[0])
    assert 0.045 < travelled < 0.065  # 0.05 m driven, plus the 0.3 m mount swung by 0.1 rad
    heading_change = truth.beam_heading_rad[-1] - truth.beam_heading_rad[0]
    assert heading_change == pytest.approx(math.radians(40) * 255 / 256 + 0.1 * 255 / 256, rel=0.01)


def test_same_seed_same_scan(head: SensorParameters) -> None:
    a, _ = _sim(plane_world(1.0), head, seed=9).sweep(trajectory=head_centred_pose(head))
    b, _ = _sim(plane_world(1.0), head, seed=9).sweep(trajectory=head_centred_pose(head))
    np.testing.assert_array_equal(a.current_1_A, b.current_1_A)


# --------------------------------------------------------------------------------------------
# The compiled signal loops against numpy and scipy
# --------------------------------------------------------------------------------------------


def reference_blur(
    currents: np.ndarray, range_m: np.ndarray, table: np.ndarray, head: SensorParameters
) -> np.ndarray:
    """The footprint blur in numpy: per-step kernel rows, windows over the edge-padded
    signal."""
    step_rad = head.scan_rate_rad_s / (head.sample_rate_hz * head.oversampling)
    r = np.clip(np.where(np.isfinite(range_m), range_m, 6.0), 0.3, 6.0)
    sigma_steps = (head.spot_diameter_m + head.spot_divergence_rad * r) / (4.0 * r * step_rad)
    row = np.clip(np.rint(sigma_steps * 20).astype(np.intp), 1, table.shape[0] - 1)
    half = (table.shape[1] - 1) // 2
    out = np.empty_like(currents)
    for c in range(2):
        padded = np.pad(currents[:, c], half, mode="edge")
        windows = np.lib.stride_tricks.sliding_window_view(padded, 2 * half + 1)
        out[:, c] = np.einsum("nk,nk->n", table[row], windows)
    return out


@pytest.mark.parametrize("n", [2130, 7, 1])  # a sweep; shorter than the kernel
def test_footprint_blur_agrees_with_numpy(head: SensorParameters, n: int) -> None:
    rng = np.random.default_rng(n)
    sim = _sim(World.build(), head)
    step_rad = head.scan_rate_rad_s / (head.sample_rate_hz * head.oversampling)
    table = sim._blur_kernels(step_rad)
    currents = rng.uniform(0.0, 5e-8, (n, 2))
    range_m = rng.uniform(0.1, 8.0, n)  # also beyond both clips
    range_m[rng.random(n) < 0.2] = np.inf
    got = sim._footprint_blur(currents, range_m)
    expected = reference_blur(currents, range_m, table, head)
    np.testing.assert_allclose(got, expected, rtol=1e-13, atol=1e-13 * currents.max())
    if n > 1:  # the kernel's width follows each step's range: far steps blur less
        assert not np.allclose(got, currents, rtol=1e-3)


def test_spot_currents_and_noise_equal_the_lep_functions_to_the_bit(
    head: SensorParameters,
) -> None:
    """The compiled detection (simulator_kernels.spot_currents, add_electrode_noise) against
    agent.sensor.lep's numpy functions, composed as the simulator composed them: equal to the
    bit (a scan, and so everything downstream, must not depend on which ran). Beams that
    miss, are hidden, image off the detector, or see a surface from behind (cos_view < 0)."""
    rng = np.random.default_rng(11)
    n = 5000
    theta = rng.uniform(-head.scan_half_angle_rad, head.scan_half_angle_rad, n)
    range_m = rng.uniform(0.1, 4.0, n)
    range_m[rng.random(n) < 0.1] = np.inf
    visible = rng.random(n) > 0.1
    reflectivity = rng.uniform(0.05, 2.0, n)
    cos_view = rng.uniform(-0.2, 1.0, n)
    hit = np.isfinite(range_m)
    u_true = np.where(hit, spot_position(np.where(hit, range_m, 1.0), theta, head), np.nan)
    on = hit & visible & (np.abs(u_true) <= 1.0)
    assert 0.3 * n < np.count_nonzero(on) < 0.9 * n
    signal_A = np.zeros(n)
    signal_A[on] = signal_current(range_m[on], reflectivity[on], cos_view[on], theta[on], head)
    u_read = np.zeros(n)
    u_read[on] = lep_response(u_true[on], head)
    expected = np.stack(electrode_currents(u_read, signal_A), axis=-1)
    got = simulator_kernels.spot_currents(
        range_m, visible, reflectivity, cos_view, theta, head.scan_half_angle_rad,
        head.baseline_edge_growth, head.fd_m2, head.baseline_m, head.detector_centre_m,
        head.detector_length_m, head.signal_constant_Am2, head.lep_edge_compression,
    )  # fmt: skip
    np.testing.assert_array_equal(got, expected)
    noise = rng.standard_normal((n, 2))
    scaled = noise * (3e-11, 5e-11)
    expected += 0.5 * (scaled[:, 1:] + scaled[:, :1] * (1.0, -1.0))
    simulator_kernels.add_electrode_noise(got, noise, 3e-11, 5e-11)
    np.testing.assert_array_equal(got, expected)


def test_sos_filter_agrees_with_scipy(head: SensorParameters) -> None:
    from scipy import signal

    rng = np.random.default_rng(4)
    sos = detection_filter(head)
    x = 1e-8 + 1e-9 * rng.standard_normal((2130, 2))
    zi = filter_state(head, x[0])
    y, zf = simulator_kernels.sos_filter(sos, x, zi)
    y_ref, zf_ref = signal.sosfilt(sos, x, axis=0, zi=zi)
    # The same recursion in the same order: equal to rounding.
    np.testing.assert_allclose(y, y_ref, rtol=1e-14, atol=0.0)
    np.testing.assert_allclose(zf, zf_ref, rtol=1e-12, atol=1e-30)
    # A carried state continues the run: two halves equal the whole.
    y1, z1 = simulator_kernels.sos_filter(sos, x[:1000].copy(), zi)
    y2, _ = simulator_kernels.sos_filter(sos, x[1000:].copy(), z1)
    np.testing.assert_allclose(np.concatenate([y1, y2]), y, rtol=1e-14, atol=0.0)


Beams = tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]


def reference_fill(exact: Beams, step: int) -> Beams:
    """Coarse-to-fine filling in numpy from every beam cast exactly (``exact``: range,
    visible, reflectivity, cos_view, obstacle): every ``step``-th beam and the last are kept;
    between two that meet the same obstacle, both seen or both hidden, at ranges within
    SMOOTH_RANGE_RATIO of the nearer (or that both meet nothing), range and viewing cosine are
    interpolated and the rest copied from the first; elsewhere the exact beams stay."""
    range_m, visible, reflectivity, cos_view, obstacle = (a.copy() for a in exact)
    n = range_m.size
    idx = np.arange(0, n, step)
    if idx[-1] != n - 1:
        idx = np.append(idx, n - 1)
    r0, r1 = range_m[idx[:-1]], range_m[idx[1:]]
    both_hit = np.isfinite(r0) & np.isfinite(r1)
    with np.errstate(invalid="ignore"):
        close = np.abs(r1 - r0) <= SMOOTH_RANGE_RATIO * np.fmin(r0, r1)
    smooth = (
        (obstacle[idx[:-1]] == obstacle[idx[1:]])
        & (visible[idx[:-1]] == visible[idx[1:]])
        & ((both_hit & close) | (~np.isfinite(r0) & ~np.isfinite(r1)))
    )
    for c in np.flatnonzero(smooth):
        i0, i1 = idx[c], idx[c + 1]
        inside = np.arange(i0 + 1, i1)
        frac = (inside - i0) / (i1 - i0)
        range_m[inside] = r0[c] + frac * (r1[c] - r0[c]) if both_hit[c] else r0[c]
        cos_view[inside] = cos_view[i0] + frac * (cos_view[i1] - cos_view[i0])
        visible[inside], reflectivity[inside] = visible[i0], reflectivity[i0]
        obstacle[inside] = obstacle[i0]
    return range_m, visible, reflectivity, cos_view, obstacle


def fill(exact: Beams, step: int) -> Beams:
    """simulator_kernels.fill_between from ``exact``'s coarse beams, then the rough steps
    taken from ``exact``."""
    n = exact[0].size
    idx = np.arange(0, n, step)
    if idx[-1] != n - 1:
        idx = np.append(idx, n - 1)
    range_m, visible, reflectivity, cos_view, obstacle = exact
    *filled, rough = simulator_kernels.fill_between(
        idx, range_m[idx], visible[idx], reflectivity[idx], cos_view[idx], obstacle[idx], n,
        SMOOTH_RANGE_RATIO,
    )  # fmt: skip
    assert np.all(np.diff(rough) > 0) and not np.isin(rough, idx).any()
    for out, a in zip(filled, exact, strict=True):
        out[rough] = a[rough]
    return filled[0], filled[1], filled[2], filled[3], filled[4]


def assert_same(got: Beams, expected: Beams) -> None:
    for g, e in zip(got, expected, strict=True):
        np.testing.assert_array_equal(g, e)


def test_fill_between_agrees_with_numpy() -> None:
    # A curved surface (ranges not linear in the step) with a step 5.25 % deep (over
    # SMOOTH_RANGE_RATIO of the nearer range, under it of the farther) and a 4 % one, a change
    # of obstacle, a shadow and a stretch of misses, each inside a coarse interval; 203 steps
    # so that the last is off the coarse grid.
    n = 203
    steps = np.arange(n)
    range_m = 1.0 + 0.01 * np.sin(steps / 7.0)
    range_m[44:] *= 1.0525
    range_m[84:] *= 1.04
    range_m[[40, 48, 80, 88]] = 1.0, 1.0525, 1.2, 1.2 * 1.04  # the coarse beams either side
    obstacle = np.where(steps < 124, 3, 5)
    visible = ~((steps >= 150) & (steps < 155))
    range_m[172:187] = np.inf
    obstacle[172:187] = -1
    visible[172:187] = False
    hit = np.isfinite(range_m)
    exact: Beams = (
        range_m,
        visible,
        np.where(hit, np.where(obstacle == 3, 0.5, 1.5), np.nan),
        np.where(hit, np.linspace(0.2, 0.9, n), 0.0),
        obstacle,
    )
    got = fill(exact, 8)
    assert_same(got, reference_fill(exact, 8))
    # Cast (exact) in the intervals holding the deep step, the change of obstacle, the
    # shadow's ends and the misses' ends; interpolated across the shallow step and the rest.
    cast = got[0] == range_m
    for lo, hi in [(40, 48), (120, 128), (144, 160), (168, 176), (184, 192)]:
        assert cast[lo:hi].all(), (lo, hi)
    assert not cast[81:88].any() and not cast[1:8].any()


def test_coarse_beams_are_cast_where_rough(head: SensorParameters) -> None:
    # The box before the wall, swept with the coarse step and with every step cast.
    world, _, _ = _box_before_wall()
    sim = _sim(world, head)
    t = np.arange(2130) / 20480.0
    theta = np.linspace(-0.35, 0.35, t.size)
    pose = ConstantTwist(-head.mount_offset_m, 0.0, 0.0, speed_m_s=0.3, yaw_rate_rad_s=0.5)
    pan = lambda t: 0.2 * t  # noqa: E731 - a pan profile
    exact = sim._beams(t, theta, pan, pose, coarse_step=1)
    got = sim._beams(t, theta, pan, pose, coarse_step=8)
    beams: Beams = (got.range_m, got.visible, got.reflectivity, got.cos_view, got.obstacle)
    expected = reference_fill(
        (exact.range_m, exact.visible, exact.reflectivity, exact.cos_view, exact.obstacle), 8
    )
    assert_same(beams, expected)
    assert (~exact.visible & np.isfinite(exact.range_m)).any()  # the shadow is there
