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
from math import factorial

import numpy as np
from numpy.polynomial import Polynomial
from numpy.typing import NDArray

from agent.arrays import FloatArray
from agent.sensor.params import SensorParameters

ComplexArray = NDArray[np.complex128]

# The filter is designed here with numpy, as scipy.signal.bessel(norm="mag") and
# sosfilt_zi design it (the tests compare the two to 1e-12), rather than by scipy.signal
# itself: importing scipy.signal costs a process 0.9 s of its start, and the head and the
# features stage build this filter when they start, so every restart paid for it. Odd orders
# (a real pole, paired as scipy pairs it) are left to scipy, imported then.


def _analog_poles(order: int) -> tuple[ComplexArray, float]:
    """Poles and gain of the Bessel low-pass prototype with its 3 dB point at 1 rad/s.

    The poles are the roots of the reverse Bessel polynomial θ_N (group delay 1 s at DC),
    scaled by the frequency where |θ_N(0)/θ_N(jω)|² = ½; the gain makes the DC gain one.
    """
    theta = [
        factorial(2 * order - k) / (2 ** (order - k) * factorial(k) * factorial(order - k))
        for k in range(order + 1)
    ]  # the coefficients, lowest power first
    # |θ(jω)|² as a polynomial in x = ω²: even part E(x), odd part ω·O(x).
    even = Polynomial([theta[k] * (-1) ** (k // 2) for k in range(0, order + 1, 2)])
    odd = Polynomial([theta[k] * (-1) ** (k // 2) for k in range(1, order + 1, 2)])
    magnitude = even**2 + Polynomial([0.0, 1.0]) * odd**2 - 2.0 * theta[0] ** 2
    roots = magnitude.roots()
    x = float(min(r.real for r in roots if abs(r.imag) < 1e-9 and r.real > 0))
    cutoff = math.sqrt(x)
    poles = np.asarray(Polynomial(theta).roots(), dtype=np.complex128) / cutoff
    return poles, theta[0] / cutoff**order


@lru_cache(maxsize=16)
def _bessel_sos(order: int, bandwidth_hz: float, fs_hz: float) -> FloatArray:
    if order % 2:
        from scipy import signal

        sos = signal.bessel(order, bandwidth_hz, btype="low", norm="mag", fs=fs_hz, output="sos")
        return np.asarray(sos, dtype=np.float64)
    poles, gain = _analog_poles(order)
    # Bilinear transform with the cut-off pre-warped (as scipy does, on the grid fs = 2).
    warped = 4.0 * math.tan(math.pi * bandwidth_hz / fs_hz)
    poles, gain = poles * warped, gain * warped**order
    digital = (4.0 + poles) / (4.0 - poles)
    gain = float(np.real(gain / np.prod(4.0 - poles)))
    # One section per conjugate pair, every zero at z = -1; the pair nearest the unit circle
    # last and the gain in the first section (scipy's "nearest" pairing).
    upper = digital[digital.imag > 0]
    upper = upper[np.argsort(np.abs(upper))]
    sos = np.zeros((upper.size, 6))
    sos[:, :3] = [1.0, 2.0, 1.0]
    sos[:, 3] = 1.0
    sos[:, 4] = -2.0 * upper.real
    sos[:, 5] = np.abs(upper) ** 2
    sos[0, :3] *= gain
    return sos


def _sosfilt(sos: FloatArray, x: FloatArray) -> FloatArray:
    """``scipy.signal.sosfilt(sos, x)`` from rest, for the one-off responses below (a loop
    over a few thousand samples, once per process; the simulator filters compiled)."""
    y = np.asarray(x, dtype=np.float64).copy()
    for b0, b1, b2, _, a1, a2 in sos:
        out = np.empty_like(y)
        s1 = s2 = 0.0
        for i, v in enumerate(y.tolist()):  # transposed direct form II, as scipy
            o = b0 * v + s1
            s1 = b1 * v - a1 * o + s2
            s2 = b2 * v - a2 * o
            out[i] = o
        y = out
    return y


def detection_filter(params: SensorParameters) -> FloatArray:
    """Second-order sections of the digital Bessel low-pass at the simulation rate.

    The bilinear transform of the analogue prototype, 3 dB at ``bandwidth_hz``, unity gain
    at DC: scipy.signal.bessel(norm="mag")'s design (see the note at the top).
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
    # scipy.signal.sosfilt_zi: each section's steady state for a unit input (lfilter_zi,
    # a 2×2 solve), scaled by the DC gain of the sections before it.
    sos = _bessel_sos(order, bandwidth_hz, fs_hz)
    zi = np.empty((sos.shape[0], 2))
    scale = 1.0
    for i, (b0, b1, b2, _, a1, a2) in enumerate(sos):
        i_minus_a = np.array([[1.0 + a1, -1.0], [a2, 1.0]])
        zi[i] = scale * np.linalg.solve(i_minus_a, [b1 - a1 * b0, b2 - a2 * b0])
        scale *= (b0 + b1 + b2) / (1.0 + a1 + a2)
    zi.flags.writeable = False
    return zi


@lru_cache(maxsize=16)
def _impulse_response(order: int, bandwidth_hz: float, fs_hz: float) -> FloatArray:
    sos = _bessel_sos(order, bandwidth_hz, fs_hz).copy()
    n = int(64 * fs_hz / bandwidth_hz)  # the response has long decayed by 64 cut-off periods
    impulse = np.zeros(n)
    impulse[0] = 1.0
    h = _sosfilt(sos, impulse)
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
    poles, _ = _analog_poles(params.filter_order)
    a = np.real(np.poly(poles * wc))  # highest power first: a[-1] is a0, a[-2] is a1
    return float(a[-2] / a[-1])  # B is a constant: b1 = 0


def step_response(params: SensorParameters, duration_s: float = 0.01) -> FloatArray:
    """The filter's unit step response on the fine grid (used to check it does not ring)."""
    fs = params.sample_rate_hz * params.oversampling
    n = max(2, int(duration_s * fs))
    return _sosfilt(detection_filter(params), np.ones(n))


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
