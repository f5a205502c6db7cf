"""Synchronous detection's low-pass filter and the noise it shapes (section 6.5.2, 6.6.2).

After synchronous detection the electrode signals are base-band currents; a fourth-order
Bessel low-pass with its 3 dB point at 1 kHz sets the measurement bandwidth. A Bessel response
was chosen in the chapter to avoid ringing at range edges.

The simulator works on a time grid ``oversampling`` times finer than the output sample rate:
white noise added there and filtered by the digital Bessel filter has, after filtering, the
standard deviation asked for (the measured ``I_n`` of eq. 6.15).
"""

from __future__ import annotations

import math
from functools import lru_cache

import numpy as np
from scipy import signal

from agent.arrays import FloatArray
from agent.sensor.params import SensorParameters


@lru_cache(maxsize=16)
def _bessel_sos(order: int, bandwidth_hz: float, fs_hz: float) -> FloatArray:
    sos = signal.bessel(order, bandwidth_hz, btype="low", norm="mag", fs=fs_hz, output="sos")
    return np.asarray(sos, dtype=np.float64)


def detection_filter(params: SensorParameters) -> FloatArray:
    """Second-order sections of the digital Bessel low-pass at the simulation rate.

    Designed by scipy.signal (bilinear transform of the analogue prototype, 3 dB at
    ``bandwidth_hz``, unity gain at DC).
    """
    fs = params.sample_rate_hz * params.oversampling
    # A copy: the design is cached, and sosfilt wants a writable array.
    return _bessel_sos(params.filter_order, params.bandwidth_hz, fs).copy()


def filter_state(params: SensorParameters, level: FloatArray) -> FloatArray:
    """Filter state for a steady input ``level`` (one value per channel).

    Returns an array of shape ``(n_sections, 2, n_channels)`` for ``sosfilt(..., axis=0)``.
    """
    fs = params.sample_rate_hz * params.oversampling
    zi = _unit_state(params.filter_order, params.bandwidth_hz, fs)
    return np.asarray(zi[:, :, None] * np.asarray(level, dtype=np.float64)[None, None, :])


@lru_cache(maxsize=16)
def _unit_state(order: int, bandwidth_hz: float, fs_hz: float) -> FloatArray:
    zi = np.asarray(signal.sosfilt_zi(_bessel_sos(order, bandwidth_hz, fs_hz).copy()))
    zi.flags.writeable = False
    return zi


@lru_cache(maxsize=16)
def _impulse_response(order: int, bandwidth_hz: float, fs_hz: float) -> FloatArray:
    sos = _bessel_sos(order, bandwidth_hz, fs_hz).copy()
    n = int(64 * fs_hz / bandwidth_hz)  # the response has long decayed by 64 cut-off periods
    impulse = np.zeros(n)
    impulse[0] = 1.0
    h = np.asarray(signal.sosfilt(sos, impulse), dtype=np.float64)
    h.flags.writeable = False
    return h


def _impulse_energy(order: int, bandwidth_hz: float, fs_hz: float) -> float:
    h = _impulse_response(order, bandwidth_hz, fs_hz)
    return float(h @ h)


def white_noise_std(params: SensorParameters, filtered_std: float) -> float:
    """Per-step std of white noise on the fine grid that filters to ``filtered_std``.

    The variance of filtered white noise is the input variance times ``Σ h[k]²`` of the
    filter's impulse response.
    """
    fs = params.sample_rate_hz * params.oversampling
    return filtered_std / math.sqrt(_impulse_energy(params.filter_order, params.bandwidth_hz, fs))


def detection_delay_s(params: SensorParameters) -> float:
    """Group delay of the Bessel low-pass at DC, seconds (0.34 ms for 4th order at 1 kHz).

    A Bessel filter's group delay is nearly flat across its pass band, so the filtered signal
    is, to a good approximation, the scene delayed by this much: a sample taken at time ``t``
    measures the beam as it pointed at ``t − delay``. Computed from the analogue prototype
    (the bilinear transform keeps the DC group delay), as ``a₁/a₀ − b₁/b₀`` of ``H = B/A``.
    """
    wc = 2.0 * math.pi * params.bandwidth_hz
    b, a = signal.bessel(params.filter_order, wc, btype="low", analog=True, norm="mag")
    b = np.atleast_1d(b)
    a = np.atleast_1d(a)
    # Coefficients are highest power first: a[-1] is a0, a[-2] is a1.
    b1 = b[-2] if b.size > 1 else 0.0
    return float(a[-2] / a[-1] - b1 / b[-1])


def step_response(params: SensorParameters, duration_s: float = 0.01) -> FloatArray:
    """The filter's unit step response on the fine grid (used to check it does not ring)."""
    fs = params.sample_rate_hz * params.oversampling
    n = max(2, int(duration_s * fs))
    return np.asarray(signal.sosfilt(detection_filter(params), np.ones(n)))


def sample_noise_correlation(params: SensorParameters, lags: int = 2) -> FloatArray:
    """Correlation of the filtered noise between samples 1 .. ``lags`` apart.

    White noise through the low-pass has autocorrelation ``Σ_k h[k] h[k+m] / Σ_k h[k]²`` at
    lag m; the samples are ``oversampling`` steps of the simulation grid apart. At 2.56 kHz
    a 1 kHz Bessel leaves neighbouring samples correlated by 0.14: fits over many samples
    that take their errors as independent understate their variance by about 1 + 2·0.14.
    """
    if lags < 1:
        raise ValueError(f"lags must be at least 1, got {lags}")
    fs = params.sample_rate_hz * params.oversampling
    h = _impulse_response(params.filter_order, params.bandwidth_hz, fs)
    step, n = params.oversampling, h.size
    return np.array([h[: max(n - m * step, 0)] @ h[m * step :] for m in range(1, lags + 1)]) / (
        h @ h
    )
