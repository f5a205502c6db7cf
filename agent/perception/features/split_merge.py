"""Split and merge: the straight pieces of a run of samples.

A piece is split when a point lies more than ``split_sigma`` of *its own* σ along the
fitted normal from the piece's weighted line (so noisy far points do not over-split and
precise near points do split); the split goes where two lines fit best (found for all split
positions at once from prefix sums of weighted moments). Adjacent pieces are merged back
when one line passes the same test, and the boundary between pieces is moved to where each
point fits its own line best. A range that is not one line is first offered to the
cylinder test, so a cylinder beside another surface on one run comes out whole.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from agent.arrays import FloatArray
from agent.perception.features.cylinders import Circle
from agent.perception.features.lines import Line, LineFits, misfit
from agent.perception.features.rows import MIN_VARIANCE_M2
from agent.perception.features.samples import Samples
from agent.perception.features.settings import FeatureSettings


def _normal_variance(c: float, s: float, cov3: FloatArray) -> FloatArray:
    """Each point's variance along the unit vector (c, s): nᵀ C_i n, floored."""
    return np.maximum(np.array([c * c, c * s, s * s]) @ cov3, MIN_VARIANCE_M2)


class SplitMerge:
    """Split-and-merge over the compressed samples."""

    def __init__(self, s: Samples, settings: FeatureSettings, lines: LineFits) -> None:
        self.s = s
        self.settings = settings
        self.lines = lines  # the spans' line fits, shared with the cylinder test

    def _bad(self, line: Line) -> bool:
        fit = line.fit
        return misfit(line.count, fit.max_z, fit.chi2, self.settings)

    def _best_split(self, line: Line) -> int:
        """Split position k (left [start, k), right [k, stop), ≥ 2 points each) of least cost.

        The cost of each side is its weighted TLS residual for weights fixed from the piece's
        normal: the smaller eigenvalue of its weighted scatter matrix, from prefix sums of
        weighted moments, so every split position is evaluated at once.
        """
        xy1 = line.xy1
        w = line.fit.w
        x = xy1[1] - xy1[1, 0]  # local origin: keeps the prefix sums well conditioned
        y = xy1[2] - xy1[2, 0]
        wx, wy = w * x, w * y
        cum = np.cumsum(np.stack([w, wx, wy, wx * x, wy * y, wx * y]), axis=1)
        left = cum[:, 1:-2]  # first k points, k = 2 .. count-2
        right = cum[:, -1:] - left

        def lam_min(mm: FloatArray) -> FloatArray:
            sw, sx, sy, sxx, syy, sxy = mm
            cxx = sxx - sx * sx / sw
            cyy = syy - sy * sy / sw
            cxy = sxy - sx * sy / sw
            return np.asarray(
                0.5 * (cxx + cyy) - np.sqrt(0.25 * (cxx - cyy) ** 2 + cxy * cxy),
                dtype=np.float64,
            )

        cost = lam_min(left) + lam_min(right)
        return line.start + 2 + int(np.argmin(cost))

    def split_and_merge(
        self, start: int, stop: int, curve: Callable[[int, int], Circle | None]
    ) -> list[Line | Circle]:
        """Straight pieces of the run [start, stop), in sample order.

        A range that is not one line is first offered to ``curve`` (the cylinder test): a
        cylinder beside a wall on one range-continuous run comes out whole.
        """
        done: list[Line | Circle] = []
        split: set[tuple[int, int]] = set()  # ranges already found not to be one line
        stack = [(start, stop)]
        while stack:
            a, b = stack.pop()
            line = self.lines.fit(a, b)
            if line is None:
                continue  # fewer than 2 usable points: belongs to no line
            if self._bad(line):
                circle = curve(a, b)
                if circle is not None:
                    done.append(circle)
                    continue
                split.add((a, b))
                k = self._best_split(line)
                stack.append((k, b))
                stack.append((a, k))
            else:
                done.append(line)
        done.sort(key=lambda item: item.start)
        # Merge: adjacent pieces that one line explains (undoes splits at noise).
        i = 0
        while i + 1 < len(done):
            p, q = done[i], done[i + 1]
            if (
                isinstance(p, Line)
                and isinstance(q, Line)
                and p.stop == q.start
                and (p.start, q.stop) not in split
            ):
                merged = self.lines.fit(p.start, q.stop)
                if merged is not None and not self._bad(merged):
                    done[i : i + 2] = [merged]
                    continue
            i += 1
        for i in range(len(done) - 1):
            p, q = done[i], done[i + 1]
            if isinstance(p, Line) and isinstance(q, Line):
                pair = self._refine_boundary(p, q)
                if pair is not None:
                    done[i], done[i + 1] = pair
        return done

    def _refine_boundary(self, p: Line, q: Line) -> tuple[Line, Line] | None:
        """Move the boundary between adjacent pieces to where each point fits its own line."""
        if p.stop != q.start or p.count < 3 or q.count < 3:
            return None
        s = self.s
        win = self.settings.refine_window
        lo = max(p.start + 2, p.stop - win)
        hi = min(q.stop - 2, q.start + win)
        if hi <= lo:
            return None
        xy1 = s.xy1[:, lo:hi]
        cov3 = s.cov3[:, lo:hi]

        def z2(line: Line) -> FloatArray:
            c, sn = line.normal
            d = np.array([-line.rho, c, sn]) @ xy1
            return np.asarray(d * d / _normal_variance(c, sn, cov3))

        zp, zq = z2(p), z2(q)
        # cost(k) = Σ_{lo ≤ i < k} zp_i + Σ_{k ≤ i < hi} zq_i for k = lo .. hi
        cost = np.concatenate([[0.0], np.cumsum(zp)]) + np.concatenate(
            [np.cumsum(zq[::-1])[::-1], [0.0]]
        )
        k = lo + int(np.argmin(cost))
        if k == p.stop:
            return None
        p2, q2 = self.lines.fit(p.start, k), self.lines.fit(k, q.stop)
        if p2 is None or q2 is None:
            return None
        return p2, q2
