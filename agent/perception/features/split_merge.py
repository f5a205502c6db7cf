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

from agent.perception.features import split_merge_kernels
from agent.perception.features.cylinders import Circle
from agent.perception.features.lines import Line, LineFits, misfit
from agent.perception.features.samples import Samples
from agent.perception.features.settings import FeatureSettings


def bend_gain(line: Line, min_side: int) -> tuple[int, float]:
    """``(k, Δχ²)``: the best split of ``line``'s samples into two lines (left [start, k),
    right [k, stop), each at least ``min_side``) and how much it lowers χ² (weights held at
    the one line's), divided by the two lines' reduced χ² where that exceeds 1 (noise larger
    than predicted does not read as a bend); ``k`` is −1 (and the gain 0) when the piece is
    too short to split (:func:`split_merge_kernels.two_line_gain`)."""
    fit = line.fit
    k, one, two = split_merge_kernels.two_line_gain(
        fit.rows, line.start, line.stop, fit.w, min_side
    )
    if k < 0:
        return k, 0.0
    return k, (one - two) / max(1.0, two / max(line.count - 4, 1))


class SplitMerge:
    """Split-and-merge over the compressed samples."""

    def __init__(self, s: Samples, settings: FeatureSettings, lines: LineFits) -> None:
        self.s = s
        self.settings = settings
        self.lines = lines  # the spans' line fits, shared with the cylinder test

    def _bad(self, line: Line) -> bool:
        fit = line.fit
        return misfit(line.count, fit.max_z, fit.chi2, self.settings) or self._bent(line)

    def _bent(self, line: Line) -> bool:
        """Two lines explain the piece clearly better than one: a shallow bend.

        Two faces meeting at 10-20° far away stay within 5σ of one line everywhere and add
        too little to χ² for ``misfit`` to see, yet their residuals run in two ramps. The
        likelihood ratio of the best two-line split (each side at least
        ``min_segment_points``) against the one line, ``Δχ² = χ²_one − χ²_two`` (weights held
        at the one line's), is compared with ``bend_min_chi2_gain``; it is divided by the
        two lines' reduced χ² where that exceeds 1, so that noise larger than predicted
        does not read as a bend. Compiled: :func:`split_merge_kernels.two_line_gain`.
        """
        k, gain = bend_gain(line, self.settings.min_segment_points)
        return k >= 0 and gain > self.settings.bend_min_chi2_gain

    def _best_split(self, line: Line) -> int:
        """Split position k (left [start, k), right [k, stop), ≥ 2 points each) of least cost.

        The cost of each side is its weighted TLS residual for weights fixed from the piece's
        normal: the smaller eigenvalue of its weighted scatter matrix, from prefix sums of
        weighted moments, so every split position is evaluated at once (compiled:
        :func:`split_merge_kernels.best_split`).
        """
        return int(split_merge_kernels.best_split(self.s.rows, line.start, line.stop, line.fit.w))

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
        # Each sample on the side whose line it fits better, along the lines' normals
        # (compiled: split_merge_kernels.boundary).
        k = int(split_merge_kernels.boundary(s.rows, lo, hi, p.rho, *p.normal, q.rho, *q.normal))
        if k == p.stop:
            return None
        p2, q2 = self.lines.fit(p.start, k), self.lines.fit(k, q.stop)
        if p2 is None or q2 is None:
            return None
        return p2, q2
