"""The detection chain's Bessel low-pass and noise scaling."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest
from scipy import signal

from agent.sensor.detection import (
    detection_delay_s,
    detection_filter,
    filter_state,
    sample_noise_correlation,
    step_response,
    white_noise_std,
)
from agent.sensor.params import SensorParameters, nominal_sensor, simulated_head


def test_step_response_does_not_ring() -> None:
    step = step_response(nominal_sensor(), duration_s=0.02)
    overshoot = step.max() - 1.0
    assert 0.0 <= overshoot < 0.02  # a Bessel response: under 2 % (4th order: about 0.8-1.1 %)
    assert step[-1] == pytest.approx(1.0, abs=1e-6)


def test_a_butterworth_would_fail_the_ringing_check() -> None:
    # The check above can fail: the same order and cut-off as a Butterworth overshoots ~11 %.
    p = nominal_sensor()
    fs = p.sample_rate_hz * p.oversampling
    sos = signal.butter(4, p.bandwidth_hz, fs=fs, output="sos")
    assert signal.sosfilt(sos, np.ones(2000)).max() - 1.0 > 0.02


def test_three_db_point_at_the_bandwidth() -> None:
    p = nominal_sensor()
    fs = p.sample_rate_hz * p.oversampling
    _, h = signal.sosfreqz(detection_filter(p), worN=[0.0, p.bandwidth_hz], fs=fs)
    assert abs(h[0]) == pytest.approx(1.0, abs=1e-9)
    assert 20 * np.log10(abs(h[1])) == pytest.approx(-3.01, abs=0.05)


def test_filtered_white_noise_has_the_requested_std(rng: np.random.Generator) -> None:
    p = nominal_sensor()
    n = 400_000
    noise = rng.standard_normal(n) * white_noise_std(p, 36.5e-12)
    filtered = signal.sosfilt(detection_filter(p), noise)[1000:]
    # Filtered noise is correlated over ~20 steps: ~20k effective samples, 0.5 % on the std.
    assert filtered.std() == pytest.approx(36.5e-12, rel=0.02)


def test_group_delay_matches_the_digital_filter() -> None:
    p = nominal_sensor()
    fs = p.sample_rate_hz * p.oversampling
    b, a = signal.sos2tf(detection_filter(p))
    _, gd = signal.group_delay((b, a), w=[1.0], fs=fs)
    # The digital design pre-warps its cut-off (tan(π·fc/fs)/(π·fc/fs) = 1.008 at 20x
    # oversampling), shortening its delay by 0.8 % (2.6 µs, 18 µrad of mirror travel: a fifth
    # of the mirror's repeatability). Agreement within 1 %.
    assert detection_delay_s(p) == pytest.approx(gd[0] / fs, rel=0.01)
    assert 0.3e-3 < detection_delay_s(p) < 0.4e-3


def test_bandwidth_above_simulation_nyquist_is_rejected() -> None:
    with pytest.raises(ValueError, match="Nyquist"):
        SensorParameters(bandwidth_hz=20_000.0, oversampling=2)


def test_sample_noise_correlation_matches_filtered_white_noise() -> None:
    # White noise on the simulation grid, filtered, kept every `oversampling` steps: the
    # lag-1 and lag-2 correlations of 200,000 samples have σ ≈ 1/√200000 = 0.0022; band
    # ±0.01 (4.5σ).
    params = simulated_head()
    predicted = sample_noise_correlation(params, 2)
    assert predicted[0] == pytest.approx(0.129, abs=0.002)  # 1 kHz Bessel at 2.56 kHz
    rng = np.random.default_rng(7)
    fine = signal.sosfilt(detection_filter(params), rng.standard_normal(200_000 * 8))
    samples = fine[1000 :: params.oversampling]
    samples = samples - samples.mean()
    for lag in (1, 2):
        measured = float(samples[:-lag] @ samples[lag:]) / float(samples @ samples)
        assert measured == pytest.approx(predicted[lag - 1], abs=0.01)
    with pytest.raises(ValueError, match="lags"):
        sample_noise_correlation(params, 0)


@pytest.mark.parametrize("order", [1, 2, 3, 4, 6, 8])
@pytest.mark.parametrize(("bandwidth_hz", "oversampling"), [(1000.0, 8), (1000.0, 2), (300.0, 4)])
def test_the_design_is_scipys_bessel(order: int, bandwidth_hz: float, oversampling: int) -> None:
    # The filter is designed without scipy.signal (its import costs a start 0.9 s); it must
    # be scipy's design: sections, their order and gain, and the steady state.
    p = SensorParameters(filter_order=order, bandwidth_hz=bandwidth_hz, oversampling=oversampling)
    fs_hz = p.sample_rate_hz * oversampling
    ref = signal.bessel(order, bandwidth_hz, btype="low", norm="mag", fs=fs_hz, output="sos")
    np.testing.assert_allclose(detection_filter(p), ref, rtol=0, atol=1e-12)
    zi = filter_state(p, np.array([1.0]))[:, :, 0]
    np.testing.assert_allclose(zi, signal.sosfilt_zi(ref), rtol=0, atol=1e-12)
    _, a = signal.bessel(order, 2 * np.pi * bandwidth_hz, analog=True, norm="mag")
    assert detection_delay_s(p) == pytest.approx(a[-2] / a[-1], rel=1e-12)
    step = signal.sosfilt(ref, np.ones(200))
    np.testing.assert_allclose(step_response(p, 200 / fs_hz), step, rtol=0, atol=1e-12)


def test_the_detection_filter_does_not_import_scipy_signal() -> None:
    code = (
        "import sys; from agent.sensor import detection, params; "
        "p = params.simulated_head(); detection.detection_filter(p); "
        "detection.filter_state(p, [1.0]); detection.sample_noise_correlation(p); "
        "detection.detection_delay_s(p); print('scipy.signal' in sys.modules)"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"
