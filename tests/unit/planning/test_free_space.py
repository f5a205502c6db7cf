"""The free-space profile on synthetic scans: spans, vouching, aging, motion, hits.

The profile against the real simulator chain (false free space against ray casts of the true
world) is in ``tests/unit/stages/test_planner_stage.py``.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from agent.perception.filtering import SampleFlag
from agent.planning.free_space import (
    ClearSpans,
    FreeSpaceMap,
    FreeSpaceSettings,
    scan_spans,
    vouch_range_m,
)
from agent.sensor.params import nominal_sensor

MOUNT = 0.30
SETTINGS = FreeSpaceSettings.for_sensor(nominal_sensor())
N = 256


def _scan(
    ranges: np.ndarray, pan_rad: float = 0.0, flag: np.ndarray | None = None
) -> dict[str, np.ndarray]:
    """A still vehicle's scan over ±20° at ``pan_rad``: beams from (MOUNT, 0) in base_link."""
    theta = np.linspace(-math.radians(20), math.radians(20), N)
    heading = pan_rad + theta
    origin = np.tile([MOUNT, 0.0], (N, 1))
    points = origin + ranges[:, None] * np.stack([np.cos(heading), np.sin(heading)], axis=1)
    if flag is None:
        flag = np.where(np.isfinite(ranges), SampleFlag.VALID, SampleFlag.NO_READING)
    flag = flag.astype(np.uint8)
    intensity = np.where(np.isfinite(ranges), 1e-8, 1e-12)
    return {
        "points_xy": np.where(np.isfinite(points), points, np.nan),
        "origin_xy": origin,
        "scan_angle_rad": theta,
        "range_m": ranges,
        "sigma_m": np.where(np.isfinite(ranges), 0.005, np.nan),
        "intensity_A": intensity,
        "flag": flag,
    }


def _spans(ranges: np.ndarray, pan: float | None = 0.0, **kw: object) -> ClearSpans:
    scan = _scan(ranges, pan if pan is not None else 0.0)
    scan.update(kw)  # type: ignore[arg-type]
    return scan_spans(**scan, settings=SETTINGS, pan_rad=pan)  # type: ignore[arg-type]


def _profile_after(spans: ClearSpans, query_s: float, pose=(0.0, 0.0, 0.0)):  # type: ignore[no-untyped-def]
    fmap = FreeSpaceMap(SETTINGS, MOUNT)
    assert fmap.add(spans, (0.0, 0.0, 0.0), 0.0, 0.1)
    return fmap, *fmap.profile(pose, query_s)


def _index(deg: float) -> int:
    return round(deg + 180) % 360


def test_valid_returns_clear_short_of_the_surface() -> None:
    spans = _spans(np.full(N, 2.0))
    margin = SETTINGS.range_sigmas * 0.005 + SETTINGS.range_margin_m
    np.testing.assert_allclose(spans.end_m, 2.0 - margin)
    assert spans.hits_xy.shape == (N, 2)
    _, bearings, free = _profile_after(spans, 0.1)
    ahead = free[_index(-15) : _index(15) + 1]
    # Clear from the centre of scanning, never to the wall, and at least 1.2 m of it.
    assert np.all(ahead < 2.0 - margin)
    assert np.all(ahead > 1.2), ahead
    assert bearings[_index(0)] == pytest.approx(0.0, abs=1e-12)


def test_unknown_is_zero() -> None:
    fmap = FreeSpaceMap(SETTINGS, MOUNT)
    bearings, free = fmap.profile((0.0, 0.0, 0.0), 0.0)
    assert bearings.shape == free.shape == (360,)
    assert np.all(free == 0.0)
    _, _, free = _profile_after(_spans(np.full(N, 2.0)), 0.1)
    # Behind and beside the vehicle nothing was seen: unknown, although the body is clear.
    assert np.all(free[_index(45) : _index(180) - 1] == 0.0)
    assert np.all(free[: _index(-45)] == 0.0)


def test_free_space_ages_out() -> None:
    spans = _spans(np.full(N, 2.0))
    fmap, _, fresh = _profile_after(spans, 0.1)
    assert fresh.max() > 1.0
    # Shrinks at the mover speed from what could hide a mover (the wall's side), ...
    _, later = fmap.profile((0.0, 0.0, 0.0), 0.35)
    assert later.max() < fresh.max() - 0.15
    # ... and none is left after max_age_s.
    _, old = fmap.profile((0.0, 0.0, 0.0), SETTINGS.max_age_s + 1e-6)
    assert np.all(old == 0.0)


def test_free_space_is_carried_with_the_vehicle() -> None:
    """A turn by 90° about the centre of scanning turns the profile by 90°."""
    spans = _spans(np.full(N, 2.0))
    fmap, _, before = _profile_after(spans, 0.1)
    # base_link turned by +90° with the centre of scanning where it was.
    pose = (MOUNT, -MOUNT, math.pi / 2)
    _, after = fmap.profile(pose, 0.1)
    expected = np.roll(before, -90)
    # Inside the window the same clear ranges, to a few grid steps of rasterisation. (At
    # its edges the turned body covers other cells beside the apex, and those count free.)
    inner = slice(_index(-90 - 15), _index(-90 + 15) + 1)
    assert np.max(np.abs(after[inner] - expected[inner])) <= 0.08
    assert np.all(after[inner] > 1.0)
    assert np.all(after[_index(-90 + 30) :] == 0.0)  # nothing claimed where none was seen


def test_moving_forward_keeps_what_is_ahead() -> None:
    spans = _spans(np.full(N, 2.0))
    fmap, _, before = _profile_after(spans, 0.1)
    _, after = fmap.profile((0.5, 0.0, 0.0), 0.1)  # 0.5 m closer to the wall
    assert after[_index(0)] == pytest.approx(before[_index(0)] - 0.5, abs=0.06)


def test_hits_override_clears() -> None:
    fmap = FreeSpaceMap(SETTINGS, MOUNT)
    fmap.add(_spans(np.full(N, 2.0)), (0.0, 0.0, 0.0), 0.0, 0.1)
    # The next scan sees something at 1 m straight ahead, and nothing else (no spans).
    box = np.full(N, np.nan)
    box[120:136] = 1.0
    flags = np.where(np.isfinite(box), SampleFlag.ISOLATED, SampleFlag.LOW_SNR)
    fmap.add(_spans(box, flag=flags), (0.0, 0.0, 0.0), 0.1, 0.2)
    _, free = fmap.profile((0.0, 0.0, 0.0), 0.2)
    assert free[_index(0)] < 1.0 - SETTINGS.hit_dilation_m
    assert free[_index(-12)] > 1.2  # beside it the first scan still counts


def test_older_scans_are_refused() -> None:
    fmap = FreeSpaceMap(SETTINGS, MOUNT)
    assert fmap.add(_spans(np.full(N, 2.0)), (0.0, 0.0, 0.0), 1.0, 1.1)
    assert not fmap.add(_spans(np.full(N, 2.0)), (0.0, 0.0, 0.0), 0.9, 1.0)


def test_no_return_is_vouched_only_where_nothing_can_hide_the_spot() -> None:
    ranges = np.full(N, np.nan)  # nothing in range anywhere
    spans = _spans(ranges)
    # The left end of the window (within d/near + margin of it) cannot be vouched for.
    edge = math.radians(20) - SETTINGS.baseline_m / SETTINGS.depth_of_field_m[0]
    theta = np.linspace(-math.radians(20), math.radians(20), N)
    limit = edge - math.radians(SETTINGS.shadow_margin_deg)
    assert np.all(spans.vouched[theta < limit - 1e-3])
    assert not np.any(spans.vouched[theta > limit + 1e-3])
    np.testing.assert_allclose(spans.start_m[spans.vouched], SETTINGS.depth_of_field_m[0])
    reach = vouch_range_m(theta[spans.vouched], SETTINGS) - SETTINGS.range_margin_m
    np.testing.assert_allclose(spans.end_m[spans.vouched], reach)
    assert 1.5 < reach.max() < SETTINGS.depth_of_field_m[1]


def test_an_object_on_the_detector_side_shades_the_no_returns_beside_it() -> None:
    ranges = np.full(N, np.nan)
    ranges[100:110] = 1.0  # a post at 1 m: left of it (higher θ) is its own return
    spans = _spans(ranges)
    theta = np.linspace(-math.radians(20), math.radians(20), N)
    shade = SETTINGS.baseline_m / 1.0 + math.radians(SETTINGS.shadow_margin_deg)
    right_of_post = (theta < theta[100]) & (theta > theta[100] - shade)
    assert not np.any(spans.vouched[right_of_post])
    assert np.all(spans.vouched[theta < theta[100] - shade - 1e-3])


def test_no_returns_are_not_vouched_without_a_steady_pan_or_with_signal() -> None:
    ranges = np.full(N, np.nan)
    assert not np.any(_spans(ranges, pan=None).vouched)
    bright = _scan(ranges)
    bright["intensity_A"] = np.full(N, 1e-9)  # light came back, off the detector
    spans = scan_spans(**bright, settings=SETTINGS, pan_rad=0.0)  # type: ignore[arg-type]
    assert not np.any(spans.vouched)
    # A told pan that disagrees with the returns' own headings is not believed.
    some = np.full(N, np.nan)
    some[:20] = 1.5
    wrong = _scan(some)
    spans = scan_spans(**wrong, settings=SETTINGS, pan_rad=math.radians(5))  # type: ignore[arg-type]
    assert not np.any(spans.vouched)


def test_mixed_and_low_signal_samples_clear_nothing() -> None:
    ranges = np.full(N, 1.5)
    flags = np.full(N, SampleFlag.MIXED)
    flags[::2] = SampleFlag.LOW_SNR
    spans = _spans(ranges, flag=flags)
    assert spans.spans == 0
    assert spans.hits_xy.shape[0] == N // 2  # mixed samples are hits, low-signal ones not


def test_settings_are_checked() -> None:
    with pytest.raises(ValueError, match="mover_speed_m_s"):
        FreeSpaceSettings(mover_speed_m_s=0.0)
    with pytest.raises(ValueError, match="bearing_step_deg"):
        FreeSpaceSettings(bearing_step_deg=7.0)
