"""The controller's view of one environment vector, and when it may be used.

``environment/1`` (``docs/interface.md`` §4) as arrays: obstacles in ``odom`` over ``k``, the
free-space profile over ``b`` bearings in ``base_link`` axes at the stamp. A vector may be
used from its stamp until ``stamp + valid_for_s``, and only if ``sensor_ok`` (§5).
"""

from __future__ import annotations

import dataclasses
import functools
import math
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from agent.arrays import FloatArray

__all__ = ["EnvironmentView", "unusable_reason"]

_EMPTY = np.zeros(0)
_EMPTY_U8 = np.zeros(0, dtype=np.uint8)


@dataclass(frozen=True, eq=False)
class EnvironmentView:
    """One environment vector, as arrays (obstacles in ``odom``).

    Attributes
    ----------
    stamp_s, valid_for_s, sensor_ok
        The vector's time (s, graph clock), how long after it the vector may be used, and
        whether the agent vouches for it.
    obstacle_id, kind
        (k,) int64 track ids; (k,) uint8 kinds: 0 segment, 1 corner, 2 occluding edge,
        3 cylinder, 4 docking target.
    position_xy, velocity_xy
        (k, 2) reference point (m) and its velocity (m/s), ``odom``.
    covariance
        (k, 4, 4) over (x, y, vx, vy).
    extent
        (k, 4) m: a segment's (or docking target's) end points (x1, y1, x2, y2), a
        cylinder's (radius, 0, 0, 0), zeros otherwise.
    reflectivity
        (k,) relative to cardboard, NaN if unknown.
    free_bearing_rad, free_range_m
        (b,) the free-space profile: bearings in ``base_link`` axes at ``stamp_s`` on a
        uniform grid over the circle (360 of them, from −π), and the distance from the
        centre of scanning known clear over each bearing's sector (0 = unknown).
    free_far_m, free_far_from_m
        (b,) or empty: the distance from the centre of scanning such that each sector is
        known clear from ``free_far_from_m`` (m) out to it, whatever lies nearer (0 =
        unknown; empty: not given).
    free_end_hit
        (b,) or empty: 1 where ``free_range_m``'s sector ends at a surface the agent's scans
        hit, 0 where it ends where the agent's knowledge ends; empty (not given, an older
        agent): every end may be a surface.
    scan_window_rad
        (2,) or empty: the bearings (low, high), ``base_link`` axes at ``stamp_s`` from the
        centre of scanning, of the outermost beams of the scan the vector was made from,
        whenever the agent knows where its beams went (slewing or not); empty when not
        known (no scan at this stamp, an older agent). Inside it, a sector the profile leaves at 0
        was scanned, but it may have returned light (a valid reading whose clear span the
        agent's aging left too thin to count, a mixed or isolated sample, a surface nearer
        than the near limit): ``scan_dark_m`` says how far it returned none.
    scan_dark_m
        (b,) or empty (given with ``scan_window_rad``): per sector, how far from the centre
        of scanning that scan's samples returned no light (the range of the nearest that
        did, the far limit where none did; 0 outside the window). What the silence rule
        reads (:mod:`agent.control.clearance`); without it, a profile's 0 is taken for
        silence.
    seen_range_m, seen_far_m, seen_end_hit
        (b,) or empty (an older agent): ``free_range_m``, ``free_far_m`` and
        ``free_end_hit`` of space the scans saw clear, with no allowance for movers that may
        have entered it since (:attr:`seen`).
    across_sigma_m
        (k,) or empty (an older agent): per obstacle, for a segment or docking target the
        largest standard deviation (m) of its surface's place across its line over its
        extent; 0 for other kinds.
    seen_age_s
        (k,) or empty (an older agent): per obstacle, seconds from the scan that last
        updated its track to ``stamp_s``.

    Raises
    ------
    ValueError
        When shapes disagree, the bearings are not a uniform grid over the circle, a time is
        not finite, or ``scan_window_rad`` is not empty or (low, high) with
        ``-pi <= low < high <= pi``.
    """

    stamp_s: float
    valid_for_s: float
    sensor_ok: bool
    obstacle_id: NDArray[np.int64]
    kind: NDArray[np.uint8]
    position_xy: FloatArray
    velocity_xy: FloatArray
    covariance: FloatArray
    extent: FloatArray
    reflectivity: FloatArray
    free_bearing_rad: FloatArray
    free_range_m: FloatArray
    free_far_m: FloatArray = field(default_factory=lambda: np.zeros(0))
    free_far_from_m: float = 0.0
    scan_window_rad: FloatArray = field(default_factory=lambda: np.zeros(0))
    free_end_hit: NDArray[np.uint8] = field(default_factory=lambda: np.zeros(0, np.uint8))
    scan_dark_m: FloatArray = field(default_factory=lambda: np.zeros(0))
    seen_range_m: FloatArray = field(default_factory=lambda: np.zeros(0))
    seen_far_m: FloatArray = field(default_factory=lambda: np.zeros(0))
    seen_end_hit: NDArray[np.uint8] = field(default_factory=lambda: np.zeros(0, np.uint8))
    across_sigma_m: FloatArray = field(default_factory=lambda: np.zeros(0))
    seen_age_s: FloatArray = field(default_factory=lambda: np.zeros(0))

    def __post_init__(self) -> None:
        if not (math.isfinite(self.stamp_s) and math.isfinite(self.valid_for_s)):
            raise ValueError("EnvironmentView: stamp_s and valid_for_s must be finite")
        k = np.shape(self.obstacle_id)
        if len(k) != 1:
            raise ValueError(f"EnvironmentView.obstacle_id must be (k,), got {k}")
        n = k[0]
        for name, shape in (
            ("kind", (n,)), ("position_xy", (n, 2)), ("velocity_xy", (n, 2)),
            ("covariance", (n, 4, 4)), ("extent", (n, 4)), ("reflectivity", (n,)),
        ):  # fmt: skip
            got = np.shape(getattr(self, name))
            if got != shape:
                raise ValueError(f"EnvironmentView.{name} must be {shape}, got {got}")
        age = np.shape(self.seen_age_s)
        if age not in ((0,), (n,)):
            raise ValueError(f"EnvironmentView.seen_age_s must be empty or ({n},), got {age}")
        across = np.shape(self.across_sigma_m)
        if across != (0,) and across != (n,):
            raise ValueError(
                f"EnvironmentView.across_sigma_m must be empty or ({n},), got {across}"
            )
        b = np.shape(self.free_bearing_rad)
        if len(b) != 1 or np.shape(self.free_range_m) != b:
            raise ValueError(
                f"EnvironmentView: free_bearing_rad {b} and free_range_m "
                f"{np.shape(self.free_range_m)} must be the same (b,)"
            )
        if not (math.isfinite(self.free_far_from_m) and self.free_far_from_m >= 0.0):
            raise ValueError("EnvironmentView.free_far_from_m must be finite and >= 0")
        near = np.shape(self.free_far_m)
        if near != (0,) and near != b:
            raise ValueError(f"EnvironmentView.free_far_m must be empty or {b}, got {near}")
        ends = np.shape(self.free_end_hit)
        if ends != (0,) and ends != b:
            raise ValueError(f"EnvironmentView.free_end_hit must be empty or {b}, got {ends}")
        dark = np.shape(self.scan_dark_m)
        if dark != (0,) and dark != b:
            raise ValueError(f"EnvironmentView.scan_dark_m must be empty or {b}, got {dark}")
        seen = {n: np.shape(getattr(self, n)) for n in ("seen_range_m", "seen_far_m",
                                                        "seen_end_hit")}  # fmt: skip
        if len(set(seen.values())) != 1 or next(iter(seen.values())) not in ((0,), b):
            raise ValueError(
                f"EnvironmentView: seen_range_m, seen_far_m and seen_end_hit must all be "
                f"empty or all {b}, got {', '.join(str(v) for v in seen.values())}"
            )
        window = np.shape(self.scan_window_rad)
        if window != (0,):
            if window != (2,):
                raise ValueError(
                    f"EnvironmentView.scan_window_rad must be empty or (2,), got {window}"
                )
            low, high = float(self.scan_window_rad[0]), float(self.scan_window_rad[1])
            if not -math.pi <= low < high <= math.pi:
                raise ValueError(
                    "EnvironmentView.scan_window_rad must be (low, high) with "
                    f"-pi <= low < high <= pi, got ({low}, {high})"
                )
        if b[0]:
            expected = _bearing_grid(b[0])
            if not np.max(np.abs(self.free_bearing_rad - expected)) <= 1e-6:
                raise ValueError(
                    "EnvironmentView.free_bearing_rad must be a uniform grid over the circle "
                    "from -pi"
                )

    @property
    def seen(self) -> EnvironmentView:
        """This view with its profiles the seen ones (``seen_*``) where the agent gives them:
        what a memory of static space records. Itself otherwise."""
        if not self.seen_range_m.size:
            return self
        return dataclasses.replace(
            self, free_range_m=self.seen_range_m, free_far_m=self.seen_far_m,
            free_end_hit=self.seen_end_hit, seen_range_m=_EMPTY, seen_far_m=_EMPTY,
            seen_end_hit=_EMPTY_U8,
        )  # fmt: skip

    @property
    def far_or_range_m(self) -> FloatArray:
        """(b,) the further of the two profiles' reaches (``free_far_m``, ``free_range_m``):
        how far each sector is known clear somewhere beyond the vehicle."""
        if self.free_far_m.size:
            return np.asarray(np.maximum(self.free_far_m, self.free_range_m), dtype=np.float64)
        return self.free_range_m

    @property
    def surface_ends(self) -> FloatArray:
        """(b,) 1.0 where a sector's end may be a surface (``free_end_hit``, every sector
        when not given), else 0.0."""
        if self.free_end_hit.size:
            return np.asarray(self.free_end_hit, dtype=np.float64)
        return np.ones(self.free_range_m.size)

    @property
    def bearing_step_rad(self) -> float:
        """The profile's sector width (rad); 0 for an empty profile."""
        b = int(self.free_bearing_rad.size)
        return 2.0 * math.pi / b if b else 0.0


@functools.lru_cache(maxsize=8)
def _bearing_grid(b: int) -> FloatArray:
    """The uniform grid of ``b`` bearings over the circle from −π (read-only, shared)."""
    grid = np.asarray(-math.pi + (2.0 * math.pi / b) * np.arange(b), dtype=np.float64)
    grid.flags.writeable = False
    return grid


def unusable_reason(view: EnvironmentView | None, now_s: float) -> str:
    """Why the controller may not move on ``view`` at ``now_s``; ``""`` when it may.

    ``"no_environment"`` (none received yet), ``"sensor_not_ok"`` (the agent cannot vouch
    for it) or ``"stale_environment"`` (outside ``[stamp_s, stamp_s + valid_for_s]``).
    """
    if view is None:
        return "no_environment"
    if not view.sensor_ok:
        return "sensor_not_ok"
    if not view.stamp_s <= now_s <= view.stamp_s + view.valid_for_s:
        return "stale_environment"
    return ""
