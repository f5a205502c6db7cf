"""The free-space profile on synthetic scans: spans, vouching, aging, motion, hits.

The profile against the real simulator chain (false free space against ray casts of the true
world) is in ``tests/unit/stages/test_planner_stage.py``.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pytest

from agent.calibration.table import Calibration
from agent.perception.filtering import SampleFlag
from agent.planning.free_space import (
    ClearSpans,
    FreeSpaceMap,
    FreeSpaceSettings,
    end_hits_reference,
    scan_dark,
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


def test_the_far_profile_shows_open_space_the_profile_cannot() -> None:
    """Nothing in range anywhere: the profile stays 0 (a no-return clears from the near
    limit only), the far profile shows the vouched sectors clear from ``far_from_m`` out,
    and the unvouched left end of the window stays 0 in both."""
    ranges = np.full(N, np.nan)
    fmap, _, near = _profile_after(_spans(ranges), 0.05)
    far = fmap.profile_far((0.0, 0.0, 0.0), 0.05)
    assert fmap.far_from_m == pytest.approx(SETTINGS.depth_of_field_m[0] + SETTINGS.far_gap_m)
    assert not near.any()
    centre = _index(-12.0)  # vouched, and clear of the unknown's erosion beside the left end
    assert far[centre] > 1.5  # to about the dark surfaces' 1.8 m, less its margins
    assert far[_index(15.0)] == 0.0  # the left end of the window: not vouched
    assert far[_index(90.0)] == 0.0  # never scanned
    # With a return at 1 m, the far profile is at least the profile.
    ranges[:] = 1.0
    fmap, _, near = _profile_after(_spans(ranges), 0.05)
    far = fmap.profile_far((0.0, 0.0, 0.0), 0.05)
    assert near[centre] > 0.7 and far[centre] >= near[centre] - 1e-9


def test_a_sector_ends_at_a_hit_only_where_a_surface_returned() -> None:
    """A wall at 2 m across the left of the window; on the right the beams went beyond
    the far limit (out of range, with signal): the left sectors end at the wall (short of
    it by what a mover hidden at a hit could cover), the right ones at the far limit,
    where knowledge ends, not at a surface; unseen sectors are 0 and end at nothing."""
    ranges = np.full(N, 2.0)
    flags = np.full(N, SampleFlag.VALID)
    ranges[: N // 2], flags[: N // 2] = 3.0, SampleFlag.OUT_OF_RANGE
    fmap, _, free = _profile_after(_spans(ranges, flag=flags), 0.05)
    hit = fmap.end_hits((0.0, 0.0, 0.0), 0.05, free)
    assert hit.dtype == np.uint8 and hit.shape == free.shape
    wall, beyond = slice(_index(6), _index(15) + 1), slice(_index(-15), _index(-6) + 1)
    assert free[wall].min() > 1.5 and hit[wall].all()
    assert free[beyond].min() > 2.0 and not hit[beyond].any()
    assert free[_index(90)] == 0.0 and not hit[_index(90)]
    # A hit is a surface only while it is recent.
    assert not fmap.end_hits((0.0, 0.0, 0.0), SETTINGS.max_age_s + 1e-6, free).any()
    # The hits move with the grid when it is re-centred, as the deadlines do.
    fmap.recentre(SETTINGS.recentre_m + 0.05, 0.0)
    assert fmap.end_hits((0.0, 0.0, 0.0), 0.05, free)[wall].all()


@pytest.mark.parametrize("seed", range(4))
def test_the_compiled_end_hits_equal_their_numpy_reference(seed: int) -> None:
    """Scans at random pans and ranges (walls, no-returns, out of range), queried at
    random poses and times: the kernel and the reference agree on every bearing."""
    rng = np.random.default_rng(seed)
    fmap = FreeSpaceMap(SETTINGS, MOUNT)
    for k in range(8):
        ranges = rng.choice([np.nan, 3.0, 1.2, 2.0], N) * rng.uniform(0.8, 1.1, N)
        flags = np.where(
            np.isnan(ranges), SampleFlag.NO_READING,
            np.where(ranges > 2.5, SampleFlag.OUT_OF_RANGE, SampleFlag.VALID),
        )  # fmt: skip
        pan = rng.uniform(-1.5, 1.5)
        fmap.add(_spans(ranges, pan, flag=flags), (0.02 * k, 0.0, 0.0), 0.1 * k, 0.1 * k + 0.1)
    checked = 0
    for _ in range(10):
        pose = (rng.uniform(-0.3, 0.5), rng.uniform(-0.3, 0.3), rng.uniform(-0.5, 0.5))
        now = rng.uniform(0.7, 1.2)
        _, free = fmap.profile(pose, now)
        got = fmap.end_hits(pose, now, free)
        np.testing.assert_array_equal(got, end_hits_reference(fmap, pose, now, free))
        checked += int(got.sum())
    assert checked > 0


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


def test_beams_told_by_the_filter_place_no_returns_as_a_steady_pan_does() -> None:
    """The filter's per-beam directions stand for a steady pan (the same beams place the
    same no-returns), and place a slewing head's as well; told directions that disagree
    with the returns' own headings are not believed."""
    ranges = np.full(N, np.nan)
    ranges[100:110] = 1.0
    theta = np.linspace(-math.radians(20), math.radians(20), N)
    steady = _spans(ranges, pan=0.2)
    scan = _scan(ranges, 0.2)
    told = scan_spans(**scan, settings=SETTINGS, beam_rad=0.2 + theta)  # type: ignore[arg-type]
    np.testing.assert_array_equal(told.vouched, steady.vouched)
    np.testing.assert_allclose(told.heading_rad, steady.heading_rad, atol=1e-12)
    assert told.heading_known.all() and told.vouched.sum() > 100
    # Slewing 0.2 → 0.5 rad through the sweep: each no-return goes where its beam went.
    beams = np.linspace(0.2, 0.5, N) + theta
    slewing = scan_spans(**_scan(np.full(N, np.nan)), settings=SETTINGS, beam_rad=beams)  # type: ignore[arg-type]
    np.testing.assert_allclose(slewing.heading_rad, beams, atol=1e-12)
    assert slewing.vouched.sum() > 100
    wrong = scan_spans(**scan, settings=SETTINGS, beam_rad=0.3 + theta)  # type: ignore[arg-type]
    assert not np.any(wrong.vouched)


def test_noise_level_low_signal_samples_are_no_returns_not_occluders() -> None:
    """In open space about one beam in fifteen comes out low-SNR at the noise level, its
    "range" the ratio of two noise currents: it saw nothing, so it neither shades the
    no-returns beside it nor goes unvouched itself. One with signal above the noise floor
    (a dim surface) still shades them."""
    rng = np.random.default_rng(5)
    noisy = rng.choice(N, 18, replace=False)
    ranges = np.full(N, np.nan)
    ranges[noisy] = rng.uniform(0.4, 1.1, noisy.size)  # noise "positions"
    flags = np.where(np.isfinite(ranges), SampleFlag.LOW_SNR, SampleFlag.NO_READING)
    intensity = np.where(np.isfinite(ranges), 9e-12, 1e-12)  # both at the noise level
    spans = _spans(ranges, flag=flags, intensity_A=intensity)
    clean = _spans(np.full(N, np.nan))
    np.testing.assert_array_equal(spans.vouched, clean.vouched)
    assert spans.vouched.sum() > N // 2
    dim = intensity.copy()
    dim[noisy] = 5 * SETTINGS.noise_floor_A  # light came back: something dim is there
    shaded = _spans(ranges, flag=flags, intensity_A=dim)
    assert shaded.vouched.sum() < clean.vouched.sum() // 2
    assert not np.any(shaded.vouched[noisy])


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


# ------------------------------------------------------------------------------------------
# The compiled map against its numpy formulation: the same grid and the same profiles, to the
# bit, on synthetic scans and on the simulator chain's.


class _NumpyMap(FreeSpaceMap):
    """The map's update and profile written in numpy (and scipy's distance transform), as
    the module documents them: the reference the compiled kernels must reproduce."""

    def _cells_xy(self, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        h = self.settings.cell_m
        i = np.floor((x - self.origin[0]) / h).astype(np.int64)
        j = np.floor((y - self.origin[1]) / h).astype(np.int64)
        return i, j, (i >= 0) & (i < self.size) & (j >= 0) & (j < self.size)

    def add(
        self,
        spans: ClearSpans,
        pose: tuple[float, float, float],
        scan_start_s: float,
        scan_end_s: float,
    ) -> bool:
        if scan_end_s < self.newest_scan_s:
            return False
        self.newest_scan_s = scan_end_s
        x, y, yaw = pose
        self.recentre(x, y)
        c, si = math.cos(yaw), math.sin(yaw)
        rot = np.array([[c, -si], [si, c]])
        origin = spans.origin_xy @ rot.T + (x, y)
        heading = spans.heading_rad + yaw
        fi, fj = self._footprint(spans, origin, heading)
        hits = spans.hits_xy @ rot.T + (x, y)
        hi, hj, inside = self._cells_xy(hits[:, 0], hits[:, 1])
        hi = (hi[inside, None] + self._hit_offsets[None, :, 0]).ravel()
        hj = (hj[inside, None] + self._hit_offsets[None, :, 1]).ravel()
        keep = (hi >= 0) & (hi < self.size) & (hj >= 0) & (hj < self.size)
        hi, hj = hi[keep], hj[keep]
        known = np.flatnonzero(spans.heading_known)
        if fi.size and known.size:
            body = self._body_points @ rot.T + (x, y)
            bi, bj, bin_ = self._cells_xy(body[:, 0], body[:, 1])
            self._deepen(
                fi, fj, hi, hj, (bi[bin_], bj[bin_]), origin[known[-1]], heading[known],
                scan_start_s,
            )  # fmt: skip
        self.free_until[hi, hj] = -np.inf
        return True

    def _footprint(
        self, spans: ClearSpans, origin: np.ndarray, heading: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        step = 0.7 * self.settings.cell_m
        beams = np.flatnonzero(spans.end_m > spans.start_m)
        if not beams.size:
            return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)
        length = spans.end_m[beams] - spans.start_m[beams]
        m = np.arange(math.ceil(float(length.max()) / step) + 1)
        along = np.minimum(spans.start_m[beams, None] + m * step, spans.end_m[beams, None])
        px = origin[beams, 0, None] + along * np.cos(heading[beams])[:, None]
        py = origin[beams, 1, None] + along * np.sin(heading[beams])[:, None]
        fi, fj, inside = self._cells_xy(px.ravel(), py.ravel())
        return fi[inside], fj[inside]

    def _deepen(
        self,
        fi: np.ndarray,
        fj: np.ndarray,
        hi: np.ndarray,
        hj: np.ndarray,
        body: tuple[np.ndarray, np.ndarray],
        centre: np.ndarray,
        headings: np.ndarray,
        scan_start_s: float,
    ) -> None:
        from scipy import ndimage

        s, h = self.settings, self.settings.cell_m
        far = s.depth_of_field_m[1] + s.edge_m
        mid = float(np.arctan2(np.sin(headings).mean(), np.cos(headings).mean()))
        rel = (headings - mid + np.pi) % (2 * np.pi) - np.pi
        lo, hi_rel = float(rel.min()), float(rel.max())
        arc = mid + np.linspace(lo, hi_rel, 9)
        corners = np.vstack([centre, centre + far * np.stack([np.cos(arc), np.sin(arc)], 1)])
        ci, cj, _ = self._cells_xy(corners[:, 0], corners[:, 1])
        pad = math.ceil((s.mover_speed_m_s * s.max_age_s + s.edge_m) / h) + 1
        i0 = max(0, min(int(ci.min()), int(fi.min())) - pad)
        j0 = max(0, min(int(cj.min()), int(fj.min())) - pad)
        i1 = min(self.size, max(int(ci.max()), int(fi.max())) + pad + 1)
        j1 = min(self.size, max(int(cj.max()), int(fj.max())) + pad + 1)
        foot = np.zeros((i1 - i0, j1 - j0), dtype=bool)
        foot[fi - i0, fj - j0] = True
        cx = self.origin[0] + (np.arange(i0, i1) + 0.5) * h - centre[0]
        cy = self.origin[1] + (np.arange(j0, j1) + 0.5) * h - centre[1]
        half_diag = h / math.sqrt(2.0)
        a_lo, a_hi = mid + lo, mid + hi_rel
        from_lo = math.cos(a_lo) * cy[None, :] - math.sin(a_lo) * cx[:, None]
        from_hi = math.sin(a_hi) * cx[:, None] - math.cos(a_hi) * cy[None, :]
        ahead = math.cos(mid) * cx[:, None] + math.sin(mid) * cy[None, :]
        in_wedge = (
            (from_lo >= half_diag)
            & (from_hi >= half_diag)
            & (ahead > 0)
            & (cx[:, None] ** 2 + cy[None, :] ** 2 <= far * far)
        )
        hiding = in_wedge & ~foot
        bi, bj = body
        inbody = (bi >= i0) & (bi < i1) & (bj >= j0) & (bj < j1)
        hiding[bi[inbody] - i0, bj[inbody] - j0] = False
        inbox = (hi >= i0) & (hi < i1) & (hj >= j0) & (hj < j1)
        hiding[hi[inbox] - i0, hj[inbox] - j0] = True
        ii, jj = np.nonzero(foot & ~hiding)
        if hiding.any():
            depth = ndimage.distance_transform_edt(~hiding)[ii, jj] * h
        else:
            depth = np.full(ii.size, np.inf)
        keep_for = np.minimum((depth - s.edge_m) / s.mover_speed_m_s, s.max_age_s)
        ok = keep_for > 0
        gi, gj = ii[ok] + i0, jj[ok] + j0
        self.free_until[gi, gj] = np.maximum(self.free_until[gi, gj], scan_start_s + keep_for[ok])

    def profile(
        self, pose: tuple[float, float, float], now_s: float
    ) -> tuple[np.ndarray, np.ndarray]:
        x, y, yaw = pose
        c, si = math.cos(yaw), math.sin(yaw)
        centre = np.array([x + self.mount_offset_m * c, y + self.mount_offset_m * si])
        if not self._centred:
            return self.bearings_rad.copy(), np.zeros(self.bearings_rad.size)
        dirs = self._sub_dirs @ np.array([[c, -si], [si, c]]).T
        free_cells = (self.free_until >= now_s).ravel()
        steps, n_steps, h, size = self._steps, self._steps.size, self.settings.cell_m, self.size
        first_blocked = np.full(dirs.shape[0], n_steps)
        for r in range(dirs.shape[0]):  # the reference: plain and slow
            k = int(self._exit[r])
            while k < n_steps:
                px = np.floor((centre[0] - self.origin[0] + steps[k] * dirs[r, 0]) / h)
                py = np.floor((centre[1] - self.origin[1] + steps[k] * dirs[r, 1]) / h)
                if not (0 <= px < size and 0 <= py < size and free_cells[int(px * size + py)]):
                    break
                k += 1
            first_blocked[r] = k
        sub_range = np.where(first_blocked > self._exit, steps[first_blocked - 1], 0.0)
        even, odd = sub_range[0::2], sub_range[1::2]
        return self.bearings_rad.copy(), np.minimum(even, np.minimum(odd, np.roll(odd, 1)))


Call = tuple[Any, ...]  # ("add", spans, pose, start, end) or ("profile", pose, now)


def _replay_both(calls: list[Call]) -> tuple[int, int]:
    """Replay ``calls`` into the compiled map and the numpy one: the grids must be equal after
    every scan, the profiles equal; (profiles, bearings claimed)."""
    fast, slow = FreeSpaceMap(SETTINGS, MOUNT), _NumpyMap(SETTINGS, MOUNT)
    profiles = claimed = 0
    for call in calls:
        if call[0] == "add":
            assert fast.add(*call[1:]) == slow.add(*call[1:])
            np.testing.assert_array_equal(fast.origin, slow.origin)
            np.testing.assert_array_equal(fast.free_until, slow.free_until)
        else:
            b_fast, r_fast = fast.profile(*call[1:])
            b_slow, r_slow = slow.profile(*call[1:])
            np.testing.assert_array_equal(b_fast, b_slow)
            np.testing.assert_array_equal(r_fast, r_slow)
            profiles += 1
            claimed += int(np.count_nonzero(r_fast > 0))
    return profiles, claimed


def test_compiled_map_equals_numpy_on_synthetic_scans() -> None:
    """Walls, posts, gaps, no-returns, a turning and driving vehicle (the grid re-centres),
    one scan left out of order; profiles at the scans' ends and between them."""
    rng = np.random.default_rng(7)
    theta = np.linspace(-math.radians(20), math.radians(20), N)
    calls: list[Call] = []
    x = y = yaw = 0.0
    for k in range(60):
        ranges = np.full(N, rng.uniform(0.6, 2.8))  # a wall, at times beyond the far limit
        ranges += 0.3 * np.sin(theta * rng.uniform(2, 20))
        post = rng.integers(0, N - 20)
        ranges[post : post + rng.integers(3, 20)] = rng.uniform(0.45, 1.2)
        ranges[rng.random(N) < 0.1] = np.nan  # no-returns
        flags = np.where(np.isfinite(ranges), SampleFlag.VALID, SampleFlag.NO_READING)
        flags[np.isfinite(ranges) & (ranges > 2.5)] = SampleFlag.OUT_OF_RANGE
        flags[rng.random(N) < 0.05] = SampleFlag.MIXED
        pan = float(rng.uniform(-1.5, 1.5))
        scan = _scan(ranges, pan, flags)
        scan["intensity_A"] = np.where(np.isfinite(ranges), 1e-8, 1e-12)
        spans = scan_spans(**scan, settings=SETTINGS, pan_rad=pan if k % 3 else None)  # type: ignore[arg-type]
        t = 0.1 * k
        calls.append(("add", spans, (x, y, yaw), t, t + 0.1))
        calls.append(("profile", (x, y, yaw), t + 0.1))
        calls.append(("profile", (x + 0.05, y, yaw + 0.1), t + 0.25))
        if k == 30:
            calls.append(("add", spans, (x, y, yaw), t - 0.2, t - 0.1))  # refused
        x, y = x + 0.12 * math.cos(yaw), y + 0.12 * math.sin(yaw)
        yaw += float(rng.uniform(-0.3, 0.3))
    profiles, claimed = _replay_both(calls)
    assert profiles == 120
    assert claimed > 1000, claimed  # the comparison covers claims, not just zeros


def test_compiled_map_equals_numpy_on_the_simulator_chain(
    calibration: Calibration, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The planner stage's own calls in the office with a mover, the real head, calibration
    and filtering in lock-step (as in the stage's free-space test), replayed into both."""
    from tests.unit.stages.test_planner_stage import _office_with_a_mover, _run

    calls: list[Call] = []
    add, profile = FreeSpaceMap.add, FreeSpaceMap.profile

    def recording_add(self, spans, pose, start, end):  # type: ignore[no-untyped-def]
        calls.append(("add", spans, pose, start, end))
        return add(self, spans, pose, start, end)

    def recording_profile(self, pose, now_s):  # type: ignore[no-untyped-def]
        calls.append(("profile", pose, now_s))
        return profile(self, pose, now_s)

    monkeypatch.setattr(FreeSpaceMap, "add", recording_add)
    monkeypatch.setattr(FreeSpaceMap, "profile", recording_profile)
    world = _office_with_a_mover()
    for policy, seed in (("forward", 1), ("sweep", 2)):
        _run(world, calibration, policy, seed, 3.0)
    monkeypatch.undo()
    profiles, claimed = _replay_both(calls)
    assert profiles >= 50
    assert claimed > 1000, claimed


def test_distance_transform_is_exact_within_its_reach() -> None:
    """The kernels' squared distances against scipy's exact Euclidean distance transform, on
    random sparse and dense masks, lines, empty masks, every shape from 1 × 1: equal to the
    bit within ``reach`` cells, more than ``reach`` beyond."""
    from scipy import ndimage

    from agent.planning.free_space_kernels import squared_distances

    rng = np.random.default_rng(3)
    for trial in range(400):
        shape = (int(rng.integers(1, 50)), int(rng.integers(1, 50)))
        mask = rng.random(shape) < [0.0, 0.002, 0.02, 0.2, 0.7][trial % 5]
        if trial % 7 == 0:
            mask[rng.integers(0, shape[0]), :] = True
        reach = int(rng.integers(1, 30))
        got = np.sqrt(squared_distances(mask, reach).astype(np.float64))
        want = ndimage.distance_transform_edt(~mask) if mask.any() else np.full(shape, np.inf)
        near = want <= reach
        np.testing.assert_array_equal(got[near], want[near])
        assert np.all(got[~near] > reach)


def test_bad_poses_and_read_only_spans_are_handled() -> None:
    """Spans of read-only arrays (as decoded from a message) are taken; a pose or time that
    is not finite is refused by ``add`` and gives an all-unknown profile."""
    spans = _spans(np.full(N, 2.0))
    for name in ("origin_xy", "heading_rad", "start_m", "end_m", "hits_xy"):
        getattr(spans, name).flags.writeable = False
    fmap = FreeSpaceMap(SETTINGS, MOUNT)
    assert fmap.add(spans, (0.0, 0.0, 0.0), 0.0, 0.1)
    before = fmap.free_until.copy()
    assert not fmap.add(spans, (math.nan, 0.0, 0.0), 0.1, 0.2)
    assert not fmap.add(spans, (0.0, 0.0, math.inf), 0.1, 0.2)
    assert not fmap.add(spans, (0.0, 0.0, 0.0), math.nan, 0.2)
    np.testing.assert_array_equal(fmap.free_until, before)
    assert fmap.profile((0.0, 0.0, 0.0), 0.1)[1].max() > 1.0
    assert np.all(fmap.profile((math.nan, 0.0, 0.0), 0.1)[1] == 0.0)
    assert np.all(fmap.profile((0.0, 0.0, 0.0), -math.inf)[1] == 0.0)


def test_hits_far_off_the_grid_or_not_finite_are_dropped_without_a_warning() -> None:
    # Found by the fuzzing budget (planner <- filtered_scan): a hit at 1e306 m overflowed
    # the division and cast a non-finite float to an integer (undefined) before the grid
    # bounds were checked.
    import warnings

    from agent.planning.free_space import FreeSpaceMap

    grid = FreeSpaceMap()
    centre = grid.origin + 0.5 * grid.size * grid.settings.cell_m
    hits = np.array([[1e306, 0.0], [np.nan, 0.0], [-np.inf, 1.0], centre])
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        grid._mark_hits(hits, 3.0)
    stamped = np.argwhere(grid.hit_at == 3.0)
    assert stamped.size
    # Only the cells about the one real hit (within the dilation: a cell and a bit).
    assert np.abs(stamped - grid.size // 2).max() <= 2


def test_scan_dark_is_how_far_each_sector_returned_no_light() -> None:
    """A window (9.5°, 30.5°) of samples every 0.1°: no readings, but a valid return at 0.9 m
    about 15°, a mixed sample at no finite range at 25°, a low-signal sample above the noise
    floor at 1.2 m at 20°, and one at the noise level at 12° (no light). Each sector reads
    the nearest light in it, the far limit where none came, 0 outside the window."""
    beams = np.radians(np.arange(9.5, 30.5 + 1e-9, 0.1))
    ranges = np.full(beams.size, np.nan)
    flags = np.full(beams.size, SampleFlag.NO_READING, dtype=np.uint8)
    signal = np.full(beams.size, 1e-12)
    deg = np.degrees(beams)

    def at(d: float) -> int:
        return int(np.argmin(np.abs(deg - d)))

    ranges[at(15.0)], flags[at(15.0)], signal[at(15.0)] = 0.9, SampleFlag.VALID, 2e-8
    flags[at(25.0)], signal[at(25.0)] = SampleFlag.MIXED, 1e-8
    ranges[at(20.0)], flags[at(20.0)], signal[at(20.0)] = 1.2, SampleFlag.LOW_SNR, 5e-10
    ranges[at(12.0)], flags[at(12.0)] = 1.5, SampleFlag.LOW_SNR  # signal at the noise level
    grid = -math.pi + 2.0 * math.pi * np.arange(360) / 360
    dark = scan_dark(beams, ranges, flags, signal, (beams[0], beams[-1]), SETTINGS, grid)
    sector = {round(math.degrees(b)): k for k, b in enumerate(grid)}
    far = SETTINGS.depth_of_field_m[1]
    assert dark[sector[15]] == pytest.approx(0.9)
    assert dark[sector[20]] == pytest.approx(1.2)
    assert dark[sector[25]] == 0.0
    assert dark[sector[12]] == far and dark[sector[28]] == far
    assert dark[sector[9]] == 0.0 and dark[sector[31]] == 0.0 and dark[sector[-20]] == 0.0
    assert np.count_nonzero(dark == far) == 21 - 3
