"""The lateral-effect photodiode and the received signal (eq. 6.8-6.11, 6.13-6.14).

The LEP divides its photocurrent between two electrodes according to the position of the
light centroid. Positions here are *normalised*: ``u = (p − p_centre) / (P/2)``, so the
detector's active length is ``−1 ≤ u ≤ +1``; off it there is no reading.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from agent.arrays import FloatArray
from agent.sensor.params import SensorParameters
from agent.sensor.triangulation import synchronised_image_position_from_range


def normalised_position(p: ArrayLike, params: SensorParameters) -> FloatArray:
    """Image position in metres to normalised detector position ``u``."""
    half = 0.5 * params.detector_length_m
    return (np.asarray(p, dtype=np.float64) - params.detector_centre_m) / half


def image_position(u: ArrayLike, params: SensorParameters) -> FloatArray:
    """Normalised detector position ``u`` to image position in metres."""
    half = 0.5 * params.detector_length_m
    return params.detector_centre_m + np.asarray(u, dtype=np.float64) * half


def lep_response(u: ArrayLike, params: SensorParameters) -> FloatArray:
    """Position the LEP reports for a spot at true normalised position ``u``: ``u − β·u⁵``.

    The compression towards the ends stands for the LEP's edge non-linearity; ``β`` is
    ``params.lep_edge_compression`` (zero on the drawing).
    """
    u = np.asarray(u, dtype=np.float64)
    u2 = u * u  # u**5 by multiplication: numpy's general power is several times slower
    return np.asarray(u - params.lep_edge_compression * (u2 * u2 * u), dtype=np.float64)


def electrode_currents(u_read: ArrayLike, signal_A: ArrayLike) -> tuple[FloatArray, FloatArray]:
    """Electrode currents ``(I1, I2)`` that eq. 6.8-6.9 map to position ``u_read``, signal ``I_s``.

    ``I1 = I_s·(1 + u)/2`` and ``I2 = I_s·(1 − u)/2``, so ``(I1 − I2)/(I1 + I2) = u``.
    """
    u = np.asarray(u_read, dtype=np.float64)
    s = np.asarray(signal_A, dtype=np.float64)
    return 0.5 * s * (1.0 + u), 0.5 * s * (1.0 - u)


def position_from_currents(I1: ArrayLike, I2: ArrayLike) -> tuple[FloatArray, FloatArray]:
    """Normalised position and signal current from electrode currents (eq. 6.8, 6.9).

    Returns
    -------
    u : (n,) ``(I1 − I2)/(I1 + I2)``; NaN where the signal is not positive or ``|u| > 1``
        (the spot is off the detector, or the sample is noise only): there is no reading.
    signal_A : (n,) ``I_s = I1 + I2``, kept even where there is no reading.
    """
    I1 = np.asarray(I1, dtype=np.float64)
    I2 = np.asarray(I2, dtype=np.float64)
    signal = I1 + I2
    with np.errstate(divide="ignore", invalid="ignore"):
        u = (I1 - I2) / signal
    u[~((signal > 0) & (np.abs(u) <= 1.0))] = np.nan
    return u, signal


def signal_current(
    range_m: ArrayLike,
    reflectivity: ArrayLike,
    cos_view: ArrayLike,
    scan_angle_rad: ArrayLike,
    params: SensorParameters,
) -> FloatArray:
    """Received signal current ``I_s`` (eq. 6.10-6.11).

    ``I_s = ρ·S·cos(viewing angle)·cos θ / r²``: the point-source, Lambertian model of
    eq. 6.10 with the reflectivity ``ρ`` relative to off-white cardboard (1.0), the cosine of
    the angle between the surface normal and the direction to the detector, and the apparent
    aperture ``cos θ`` at scan angle θ.

    Parameters
    ----------
    range_m : beam range to the spot, m. reflectivity : relative to cardboard.
    cos_view : cosine of the viewing angle on the surface (clipped at 0).
    scan_angle_rad : θ.
    """
    r = np.asarray(range_m, dtype=np.float64)
    view = np.clip(np.asarray(cos_view, dtype=np.float64), 0.0, 1.0)
    return (
        params.signal_constant_Am2
        * np.asarray(reflectivity, dtype=np.float64)
        * view
        * np.cos(np.asarray(scan_angle_rad, dtype=np.float64))
        / r**2
    )


def spot_position(
    range_m: ArrayLike, scan_angle_rad: ArrayLike, params: SensorParameters
) -> FloatArray:
    """True normalised position ``u`` of the image of a spot at beam range ``r`` and angle θ.

    Uses the head's scan-angle-dependent baseline: ``fd`` scales with ``d`` (``fd = f·d``).
    """
    theta = np.asarray(scan_angle_rad, dtype=np.float64)
    ratio = theta / params.scan_half_angle_rad
    growth = 1.0 + params.baseline_edge_growth * ratio * ratio
    p = synchronised_image_position_from_range(
        range_m, theta, params.fd_m2 * growth, params.baseline_m * growth
    )
    return normalised_position(p, params)


def position_sigma(signal_A: ArrayLike, noise_current_A: float) -> FloatArray:
    """Standard deviation of the normalised position, ``I_n / I_s`` (eq. 6.14).

    NaN where the signal is not positive; ``inf`` where it is so small (subnormal) that the
    ratio overflows, which every gate downstream rejects as it would any weak sample.
    """
    s = np.asarray(signal_A, dtype=np.float64)
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        sigma = noise_current_A / s
    return np.where(s > 0, sigma, np.nan)
