"""The simulator's compiled loops over a sweep's fine time grid (:mod:`agent.sim.simulator`;
why compiled: :mod:`agent.compiled`): filling the beams between coarse ones, the spot's image
and the electrode currents, the laser footprint's blur, the electrode noise and the
detection filter's run.

Each works on a few thousand steps with a few operations per step, which numpy spread over a
dozen calls, temporaries and masks.
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt

from agent.arrays import BoolArray, FloatArray
from agent.compiled import compiled

IntArray = npt.NDArray[np.int64]


@compiled
def fill_between(
    coarse: IntArray,
    range_m: FloatArray,
    visible: BoolArray,
    reflectivity: FloatArray,
    cos_view: FloatArray,
    obstacle: IntArray,
    n: int,
    smooth_range_ratio: float,
) -> tuple[FloatArray, BoolArray, FloatArray, FloatArray, IntArray, IntArray]:
    """Fill n beams from the beams cast at the increasing steps ``coarse`` (the first step,
    0, and the last, n - 1, among them).

    Between two coarse beams that meet the same obstacle, both visible or both hidden, at
    ranges within ``smooth_range_ratio`` of the nearer, or that both meet nothing, the beams
    are interpolated: range and viewing cosine linearly in the step, the rest taken from the
    first of the two. The beams between any other two are to be cast.

    Parameters
    ----------
    coarse
        (c,) the steps cast.
    range_m, visible, reflectivity, cos_view, obstacle
        (c,) the coarse beams (see :func:`agent.sim.raycast_kernels.cast_beams`).
    n
        Number of steps.
    smooth_range_ratio
        As above.

    Returns
    -------
    range_m, visible, reflectivity, cos_view, obstacle, rough
        (n,) every step, coarse and interpolated ones filled; (r,) the steps to cast, in
        increasing order (their entries in the others are left unset).
    """
    out_range = np.empty(n)
    out_visible = np.zeros(n, dtype=np.bool_)
    out_reflectivity = np.empty(n)
    out_cos_view = np.empty(n)
    out_obstacle = np.empty(n, dtype=np.int64)
    rough = np.empty(n, dtype=np.int64)
    n_rough = 0
    for c in range(coarse.size):
        i = coarse[c]
        out_range[i], out_visible[i], out_reflectivity[i] = range_m[c], visible[c], reflectivity[c]
        out_cos_view[i], out_obstacle[i] = cos_view[c], obstacle[c]
    for c in range(coarse.size - 1):
        i0, i1 = coarse[c], coarse[c + 1]
        r0, r1 = range_m[c], range_m[c + 1]
        both_hit = math.isfinite(r0) and math.isfinite(r1)
        smooth = (
            obstacle[c] == obstacle[c + 1]
            and visible[c] == visible[c + 1]
            and (
                (both_hit and abs(r1 - r0) <= smooth_range_ratio * min(r0, r1))
                or (not math.isfinite(r0) and not math.isfinite(r1))
            )
        )
        for i in range(i0 + 1, i1):
            if not smooth:
                rough[n_rough] = i
                n_rough += 1
                continue
            frac = (float(i) - float(i0)) / float(i1 - i0)
            out_range[i] = r0 + frac * (r1 - r0) if both_hit else r0
            out_cos_view[i] = cos_view[c] + frac * (cos_view[c + 1] - cos_view[c])
            out_visible[i], out_reflectivity[i] = visible[c], reflectivity[c]
            out_obstacle[i] = obstacle[c]
    return (
        out_range, out_visible, out_reflectivity, out_cos_view, out_obstacle, rough[:n_rough]
    )  # fmt: skip


@compiled
def spot_currents(
    range_m: FloatArray,
    visible: BoolArray,
    reflectivity: FloatArray,
    cos_view: FloatArray,
    theta: FloatArray,
    scan_half_angle_rad: float,
    baseline_edge_growth: float,
    fd_m2: float,
    baseline_m: float,
    detector_centre_m: float,
    detector_length_m: float,
    signal_constant_Am2: float,
    lep_edge_compression: float,
) -> FloatArray:
    """The electrode currents ``(I1, I2)`` of each fine step's spot, before blur and noise.

    Step for step what :func:`agent.sensor.lep.spot_position` (the spot's true normalised
    position ``u``, with the scan-angle-dependent baseline), :func:`~agent.sensor.lep.
    signal_current` (eq. 6.10-6.11), :func:`~agent.sensor.lep.lep_response` and
    :func:`~agent.sensor.lep.electrode_currents` (eq. 6.8-6.9) compute, in their order of
    operations: where the beam hits something (finite range) seen from the detector with
    ``|u| <= 1``; zero currents elsewhere.

    Parameters
    ----------
    range_m, visible, reflectivity, cos_view
        (n,) the beams (:func:`agent.sim.raycast_kernels.cast_beams`): range (m, inf for
        nothing hit), whether the detector sees the spot, relative reflectivity, cosine of
        the viewing angle.
    theta
        (n,) mirror angles, radians.
    scan_half_angle_rad, ..., lep_edge_compression
        The head's parameters (:class:`agent.sensor.params.SensorParameters`).

    Returns
    -------
    numpy.ndarray
        (n, 2) ``I1``, ``I2``, A.
    """
    n = range_m.size
    out = np.zeros((n, 2))
    half_length = 0.5 * detector_length_m
    for i in range(n):
        r = range_m[i]
        if not (math.isfinite(r) and visible[i]):
            continue
        ratio = theta[i] / scan_half_angle_rad
        growth = 1.0 + baseline_edge_growth * ratio * ratio
        image = fd_m2 * growth * math.cos(theta[i]) / (r - baseline_m * growth * math.sin(theta[i]))
        u = (image - detector_centre_m) / half_length
        if not abs(u) <= 1.0:
            continue
        view = min(max(cos_view[i], 0.0), 1.0)
        signal = signal_constant_Am2 * reflectivity[i] * view * math.cos(theta[i]) / (r * r)
        u2 = u * u
        u_read = u - lep_edge_compression * (u2 * u2 * u)
        out[i, 0] = 0.5 * signal * (1.0 + u_read)
        out[i, 1] = 0.5 * signal * (1.0 - u_read)
    return out


@compiled
def add_electrode_noise(
    currents: FloatArray, normal: FloatArray, diff_std_A: float, sum_std_A: float
) -> None:
    """Add the electrode noise to ``currents`` (n, 2) in place: from ``normal`` (n, 2)
    standard normal draws, ``n_diff = normal[:, 0]·diff_std_A`` and ``n_sum = normal[:, 1]·
    sum_std_A``, ``I1 += (n_sum + n_diff)/2`` and ``I2 += (n_sum − n_diff)/2`` (as
    ``0.5·(n_sum + n_diff·(±1))``, numpy's order in :mod:`agent.sim.simulator`'s history)."""
    for i in range(currents.shape[0]):
        n_diff = normal[i, 0] * diff_std_A
        n_sum = normal[i, 1] * sum_std_A
        currents[i, 0] += 0.5 * (n_sum + n_diff * 1.0)
        currents[i, 1] += 0.5 * (n_sum + n_diff * -1.0)


@compiled
def footprint_blur(
    currents: FloatArray,
    range_m: FloatArray,
    kernels: FloatArray,
    kernels_per_step: float,
    spot_diameter_m: float,
    spot_divergence_rad: float,
    step_rad: float,
    min_range_m: float,
    max_range_m: float,
) -> FloatArray:
    """Sum each step's electrode currents over the laser footprint.

    At range ``r`` (clipped to ``[min_range_m, max_range_m]``, ``max_range_m`` where nothing
    is hit) the footprint's 1/e² diameter ``spot_diameter_m + spot_divergence_rad·r`` spans
    ``σ = (spot_diameter_m + spot_divergence_rad·r) / (4·r·step_rad)`` steps (one standard
    deviation). Step ``i`` takes the tabulated kernel of width ``σ`` (row
    ``rint(σ·kernels_per_step)``, clipped to the table, row 0 unused) centred on itself;
    beyond either end of the sweep the end value continues.

    Parameters
    ----------
    currents
        (n, 2) electrode currents per fine step, A.
    range_m
        (n,) beam range per fine step, metres; inf where nothing is hit.
    kernels
        (rows, 2·h + 1) normalised Gaussian kernels, row ``k`` of width ``k / kernels_per_step``
        steps.
    kernels_per_step
        Rows of ``kernels`` per step of width.
    spot_diameter_m, spot_divergence_rad, step_rad, min_range_m, max_range_m
        As above; ``step_rad`` is the mirror's motion per fine step.

    Returns
    -------
    numpy.ndarray
        (n, 2) blurred currents, A.
    """
    n = currents.shape[0]
    width = kernels.shape[1]
    half = (width - 1) // 2
    last_row = kernels.shape[0] - 1
    rows = np.empty(n, dtype=np.int64)
    for i in range(n):
        r = range_m[i] if math.isfinite(range_m[i]) else max_range_m
        r = min(max(r, min_range_m), max_range_m)
        sigma_steps = (spot_diameter_m + spot_divergence_rad * r) / (4.0 * r * step_rad)
        rows[i] = min(max(int(np.rint(sigma_steps * kernels_per_step)), 1), last_row)
    padded = np.empty((n + 2 * half, 2))
    for j in range(n + 2 * half):
        source = min(max(j - half, 0), n - 1)
        padded[j, 0], padded[j, 1] = currents[source, 0], currents[source, 1]
    out = np.empty((n, 2))
    # Four steps at a time: each step's sum is a chain of dependent additions, and four
    # chains in flight keep the adder busy. Each still adds its taps in order.
    i = 0
    while i + 4 <= n:
        row_a, row_b, row_c, row_d = rows[i], rows[i + 1], rows[i + 2], rows[i + 3]
        a1 = a2 = b1 = b2 = c1 = c2 = d1 = d2 = 0.0
        for k in range(width):
            w_a, w_b = kernels[row_a, k], kernels[row_b, k]
            w_c, w_d = kernels[row_c, k], kernels[row_d, k]
            j = i + k
            a1 += w_a * padded[j, 0]
            a2 += w_a * padded[j, 1]
            b1 += w_b * padded[j + 1, 0]
            b2 += w_b * padded[j + 1, 1]
            c1 += w_c * padded[j + 2, 0]
            c2 += w_c * padded[j + 2, 1]
            d1 += w_d * padded[j + 3, 0]
            d2 += w_d * padded[j + 3, 1]
        out[i, 0], out[i, 1], out[i + 1, 0], out[i + 1, 1] = a1, a2, b1, b2
        out[i + 2, 0], out[i + 2, 1], out[i + 3, 0], out[i + 3, 1] = c1, c2, d1, d2
        i += 4
    for last in range(i, n):
        sum_1 = sum_2 = 0.0
        for k in range(width):
            w = kernels[rows[last], k]
            sum_1 += w * padded[last + k, 0]
            sum_2 += w * padded[last + k, 1]
        out[last, 0], out[last, 1] = sum_1, sum_2
    return out


@compiled
def sos_filter(sos: FloatArray, x: FloatArray, zi: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Run a cascade of second-order sections along the first axis (direct form II
    transposed, as :func:`scipy.signal.sosfilt` with ``axis=0``).

    Parameters
    ----------
    sos
        (s, 6) sections ``[b0, b1, b2, 1, a1, a2]``.
    x
        (n, c) input, c channels.
    zi
        (s, 2, c) initial state (see :func:`agent.sensor.detection.filter_state`).

    Returns
    -------
    y, zf
        (n, c) output; (s, 2, c) final state.
    """
    n, channels = x.shape
    y = np.empty((n, channels))
    z = zi.copy()
    for i in range(n):
        for c in range(channels):  # the channels' recursions interleave
            x_cur = x[i, c]
            for s in range(sos.shape[0]):
                x_new = sos[s, 0] * x_cur + z[s, 0, c]
                z[s, 0, c] = sos[s, 1] * x_cur - sos[s, 4] * x_new + z[s, 1, c]
                z[s, 1, c] = sos[s, 2] * x_cur - sos[s, 5] * x_new
                x_cur = x_new
            y[i, c] = x_cur
    return y, z
