"""The free-space kernels against their numpy references, on random scans: equal to the bit
(the closed loop's runs must not change)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from agent.planning.free_space import (
    ClearSpans,
    FreeSpaceSettings,
    scan_spans,
    scan_spans_reference,
)
from agent.sensor.params import nominal_sensor

SETTINGS = FreeSpaceSettings.for_sensor(nominal_sensor())


def _random_scan(rng: np.random.Generator, n: int) -> dict[str, np.ndarray]:
    """A sweep of ``n`` samples over ±20° at a random pan, from a turning vehicle: readings at
    random ranges about the beams' true headings, every flag, non-finite ranges, points and
    sigmas, intensities about the noise and signal floors."""
    theta = np.linspace(-math.radians(20), math.radians(20), n)
    age = (n - 1 - np.arange(n)) / 2560.0
    heading = 0.3 + theta - 0.4 * age + rng.normal(0.0, 0.003, n)
    origin = np.stack([0.3 + rng.normal(0, 0.01, n), rng.normal(0, 0.01, n)], axis=1)
    ranges = rng.uniform(0.2, 3.0, n)
    points = origin + ranges[:, None] * np.stack([np.cos(heading), np.sin(heading)], axis=1)
    flag = rng.integers(0, 6, n).astype(np.uint8)
    gone = rng.random(n) < 0.4
    ranges[gone] = np.nan
    points[gone] = np.nan
    points[rng.random(n) < 0.03, 1] = np.nan
    sigma = np.where(rng.random(n) < 0.05, np.nan, rng.uniform(0.001, 0.02, n))
    intensity = 10.0 ** rng.uniform(-11.5, -8, n)
    return {
        "points_xy": points,
        "origin_xy": origin,
        "scan_angle_rad": theta,
        "range_m": ranges,
        "sigma_m": sigma,
        "intensity_A": intensity,
        "flag": flag,
    }


def _assert_same(got: ClearSpans, want: ClearSpans) -> None:
    for name in ("origin_xy", "heading_rad", "start_m", "end_m", "hits_xy", "vouched"):
        np.testing.assert_array_equal(getattr(got, name), getattr(want, name), err_msg=name)
    np.testing.assert_array_equal(got.heading_known, want.heading_known)
    assert got.heading_rad.dtype == want.heading_rad.dtype


@pytest.mark.parametrize("seed", range(40))
def test_the_compiled_spans_equal_the_numpy_ones(seed: int) -> None:
    rng = np.random.default_rng(seed)
    n = int(rng.choice([0, 1, 2, 17, 256]))
    scan = _random_scan(rng, n)
    pan = None if seed % 5 == 0 else 0.3 + rng.normal(0.0, 0.01)
    if seed % 7 == 3:
        scan["flag"][:] = 1  # no readings at all: nothing to agree with
        scan["intensity_A"][:] = 1e-12
    kw = {"settings": SETTINGS, "pan_rad": pan, "yaw_rate_rad_s": 0.4}
    if seed % 3 == 1:  # the filter tells each beam's direction (a head that slews)
        slew = np.linspace(0.0, rng.normal(0.0, 0.2), n)
        kw["beam_rad"] = 0.3 + slew + scan["scan_angle_rad"] + rng.normal(0.0, 0.01, n)
    want = scan_spans_reference(**scan, **kw)  # type: ignore[arg-type]
    got = scan_spans(**scan, **kw)  # type: ignore[arg-type]
    _assert_same(got, want)


def test_the_compiled_spans_vouch_as_the_numpy_ones() -> None:
    """Enough scans with vouched beams, shaded ones and a refused pan to cover each branch."""
    vouched = shaded = refused = 0
    for seed in range(200):
        rng = np.random.default_rng(1000 + seed)
        scan = _random_scan(rng, 256)
        blocks = np.repeat(rng.random(256 // 32) < 0.6, 32)  # runs of no-returns
        scan["flag"][blocks] = 1
        scan["points_xy"][blocks] = np.nan
        scan["intensity_A"][scan["flag"] == 1] = 1e-12
        pan = 0.3 + (0.1 if seed % 10 == 0 else 0.0)
        kw = {"settings": SETTINGS, "pan_rad": pan, "yaw_rate_rad_s": 0.4}
        want = scan_spans_reference(**scan, **kw)  # type: ignore[arg-type]
        _assert_same(scan_spans(**scan, **kw), want)  # type: ignore[arg-type]
        vouched += int(want.vouched.sum())
        no_return = (scan["flag"] == 1) & ~np.isfinite(scan["points_xy"]).all(axis=1)
        shaded += int((no_return & ~want.vouched).sum())
        refused += int(not want.heading_known.all())
    assert vouched > 100 and shaded > 100 and refused > 5
