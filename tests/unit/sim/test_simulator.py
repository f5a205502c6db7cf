"""The simulated head: timing, limits, noise statistics, missing parts and mixed points."""

from __future__ import annotations

import math

import numpy as np
import pytest

from agent.calibration.characterisation import head_centred_pose, plane_world
from agent.calibration.table import Calibration
from agent.errors import HeadCommandError
from agent.kinematics.trajectory import ConstantTwist, StaticPose, head_origin
from agent.sensor.lep import position_from_currents
from agent.sensor.params import SensorParameters
from agent.sensor.scanning import ScanWindow
from agent.sim.simulator import SensorSimulator
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
