"""Sensor parameters, the LEP (eq. 6.8-6.9, 6.14) and the signal model (eq. 6.10-6.11)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from agent.sensor import lep
from agent.sensor.params import (
    SensorParameters,
    nominal_sensor,
    simulated_head,
    theoretical_noise_density,
)


def test_chapter_values_are_the_defaults() -> None:
    p = SensorParameters()
    assert (p.baseline_m, p.focal_length_m, p.detector_length_m) == (0.095, 0.05, 0.01)
    assert p.sample_rate_hz == pytest.approx(2560.0)
    assert math.degrees(p.scan_rate_rad_s) == pytest.approx(400.0)
    assert p.noise_density_A_per_rtHz == pytest.approx(1.15e-12, rel=0.01)  # eq. 6.16
    assert nominal_sensor().fd_m2 == pytest.approx(0.00475)
    assert simulated_head().fd_m2 == pytest.approx(0.0044)


def test_theoretical_noise_density_is_0_632_pA() -> None:
    assert theoretical_noise_density(SensorParameters()) == pytest.approx(0.632e-12, rel=0.005)


def test_triangulation_constant_eq_6_20() -> None:
    p = simulated_head()
    assert p.triangulation_constant_T_per_m3 == pytest.approx(
        0.01 * 36.5e-12 / (2 * 0.0044 * 2.59e-8)
    )


@pytest.mark.parametrize(
    "change",
    [
        {"baseline_m": -1.0},
        {"noise_current_A": float("nan")},
        {"depth_of_field_m": (2.5, 0.4)},
        {"oversampling": 1},
        {"lep_edge_compression": -0.1},
    ],
)
def test_bad_parameters_are_rejected(change: dict[str, object]) -> None:
    with pytest.raises(ValueError):
        SensorParameters().with_changes(**change)


def test_unknown_parameter_is_named() -> None:
    with pytest.raises(ValueError, match="baseline_mm"):
        SensorParameters().with_changes(baseline_mm=95)


def test_depth_of_field_falls_on_the_detector_at_every_scan_angle() -> None:
    head = simulated_head()
    theta = np.radians(np.linspace(-20, 20, 41))[:, None]
    r = np.array([0.4, 2.5])[None, :]
    u = lep.spot_position(r, theta, head)
    assert np.all(np.abs(u) < 0.99)
    assert u[:, 0].max() > 0.95 and u[:, 1].min() < -0.95  # and it uses the whole length


def test_currents_round_trip_eq_6_8_6_9() -> None:
    u = np.linspace(-1, 1, 21)
    I1, I2 = lep.electrode_currents(u, 3e-9)
    u_back, signal = lep.position_from_currents(I1, I2)
    np.testing.assert_allclose(u_back, u, atol=1e-15)
    np.testing.assert_allclose(signal, 3e-9)


def test_no_reading_off_the_detector_or_without_signal() -> None:
    u, s = lep.position_from_currents(
        np.array([2e-9, 1e-12, -1e-12, 0.0]), np.array([-0.5e-9, 0.5e-12, 0.2e-12, 0.0])
    )
    assert np.isnan(u[0])  # |u| > 1: off the detector
    assert np.isfinite(u[1])
    assert np.isnan(u[2]) and np.isnan(u[3])  # no positive signal
    assert s[2] == pytest.approx(-0.8e-12)


def test_lep_edge_compression() -> None:
    head = simulated_head()
    assert lep.lep_response(0.0, head) == 0.0
    assert lep.lep_response(1.0, head) == pytest.approx(1 - head.lep_edge_compression)
    np.testing.assert_allclose(
        lep.lep_response(np.linspace(-1, 1, 5), nominal_sensor()), np.linspace(-1, 1, 5)
    )


def test_signal_model_eq_6_10_6_11() -> None:
    p = SensorParameters()
    assert lep.signal_current(1.0, 1.0, 1.0, 0.0, p) == pytest.approx(2.59e-8)
    assert lep.signal_current(2.0, 1.0, 1.0, 0.0, p) == pytest.approx(2.59e-8 / 4)
    assert lep.signal_current(1.0, 0.5, 1.0, 0.0, p) == pytest.approx(2.59e-8 / 2)
    assert lep.signal_current(1.0, 1.0, 0.5, 0.0, p) == pytest.approx(2.59e-8 / 2)  # Lambertian
    theta = math.radians(20)
    assert lep.signal_current(1.0, 1.0, 1.0, theta, p) == pytest.approx(2.59e-8 * math.cos(theta))
    assert lep.signal_current(1.0, 1.0, -0.3, 0.0, p) == 0.0  # facing away


def test_position_sigma_eq_6_14() -> None:
    np.testing.assert_allclose(
        lep.position_sigma([2.59e-8, 0.0], 36.5e-12), [36.5e-12 / 2.59e-8, np.nan]
    )


def test_position_sigma_of_a_subnormal_signal_is_inf_without_a_warning() -> None:
    # Found by the fuzzing budget (calibration <- raw_scan): a positive but subnormal sum
    # current made the ratio overflow with a RuntimeWarning.
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("error")
        sigma = lep.position_sigma([1e-320], 36.5e-12)
    assert np.isposinf(sigma[0])
