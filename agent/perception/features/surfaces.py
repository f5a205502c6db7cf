"""The surfaces of one run of samples: its cylinders and straight pieces, in sample order.

A run (one segment id, range-continuous) is first offered whole to the cylinder test
(:mod:`agent.perception.features.cylinders`); otherwise it is split and merged into
straight pieces (:mod:`agent.perception.features.split_merge`). Runs of consecutive short
pieces (a curve the splitter chops up) get the cylinder test again, and so do circles with
the next circle along the run (one cylinder beside another surface can come out in two).
Last, each straight piece gives up the samples at its ends that the depth of field censors
(:meth:`Surfaces.uncensored`).
"""

from __future__ import annotations

from dataclasses import replace
from typing import TypeAlias

import numpy as np

from agent.perception.features.cylinders import Circle, Cylinders
from agent.perception.features.lines import Line, LineFits
from agent.perception.features.rows import BX, BY, OX, OY, VARB
from agent.perception.features.samples import Samples
from agent.perception.features.settings import FeatureSettings
from agent.perception.features.split_merge import SplitMerge

# A fitted surface: a straight piece, or a circle (a cylinder).
Surface: TypeAlias = Line | Circle


class Surfaces:
    """The surfaces of the runs of one scan's samples (see the module docstring)."""

    def __init__(self, s: Samples, settings: FeatureSettings) -> None:
        self.settings = settings
        lines = LineFits(s, settings)  # each span fitted once, for both of these
        self.lines = lines
        self.cylinders = Cylinders(s, settings, lines)
        self.split_merge = SplitMerge(s, settings, lines)

    def of_run(self, start: int, stop: int) -> list[Surface]:
        """Cylinders and straight pieces of one run, in sample order."""
        cyl = self.cylinders.test(start, stop)
        if cyl is not None:
            return [cyl]
        pieces = self.split_merge.split_and_merge(start, stop, self.cylinders.test)
        # A curve the splitter chopped up: consecutive pieces none of which is a segment.
        items: list[Surface] = []
        i = 0
        while i < len(pieces):
            first = pieces[i]
            if isinstance(first, Circle) or first.reportable(self.settings):
                items.append(first)
                i += 1
                continue
            j = i + 1
            while j < len(pieces):
                nxt = pieces[j]
                if isinstance(nxt, Circle) or nxt.reportable(self.settings):
                    break
                if nxt.start != pieces[j - 1].stop:
                    break
                j += 1
            found = self._cylinder_over(first, pieces[j - 1]) if j - i >= 2 else None
            if found is not None:
                items.append(found)
            else:
                items.extend(pieces[i:j])
            i = j
        out: list[Surface] = []
        for item in self._joined_circles(items):
            if isinstance(item, Circle):
                out.append(item)
                continue
            kept = self.uncensored(item)
            if kept is not None:
                out.append(kept)
        return out

    def uncensored(self, line: Line) -> Line | None:
        """``line`` without the samples at its ends that the depth of field censors, fitted
        again; None when none is left (``FeatureSettings.censor_margin_sigma``).

        The filter drops a sample whose measured range is outside the depth of field, so
        near a limit the samples kept are those whose noise pointed inward. Which samples
        are near a limit is judged by the range the line predicts along each one's beam,
        which the selection did not bias, with the sample's own along-beam σ. Along a
        straight surface the range is convex in scan order, so such samples lie at a
        piece's ends (any inside the first and last kept sample are kept too). Twice: the
        line refitted on the rest moves.
        """
        st = self.settings
        near, far = st.depth_of_field_m
        k = st.censor_margin_sigma
        for _ in range(2):
            rows = line.fit.rows
            i, j = line.start, line.stop
            c, s = line.normal
            along = c * rows[BX, i:j] + s * rows[BY, i:j]
            with np.errstate(divide="ignore", invalid="ignore"):
                predicted = (line.rho - c * rows[OX, i:j] - s * rows[OY, i:j]) / along
            margin = k * np.sqrt(rows[VARB, i:j])
            ok = np.isfinite(predicted) & (predicted - margin >= near) & (predicted + margin <= far)
            if ok.all():
                return line
            inside = np.flatnonzero(ok)
            if inside.size < 2:
                return None
            trimmed = self.lines.fit(i + int(inside[0]), i + int(inside[-1]) + 1)
            if trimmed is None:
                return None
            line = trimmed
        return line

    def _joined_circles(self, items: list[Surface]) -> list[Surface]:
        """Circles that are one cylinder, joined with the short pieces between them.

        One cylinder beside a wall on one run fails the cylinder test whole when the wall's
        samples sit off the circle; split, it came out as two or three circles, maybe with
        pieces too short to be segments between them (2 % of the bench's cylinders).
        Reported twice, it would count its samples twice downstream. Each circle and the
        next one reached through such pieces are offered to the cylinder test together, as
        far as the circles were fitted: the samples at their ends that missed or grazed
        them may be the wall's. (A circle is not joined with the pieces beside it alone:
        at a wall, a few of its samples and the cylinder's silhouette then fitted a circle
        that passed the test yet was biased by 2 cm.)
        """
        out = list(items)
        k = 0
        while k < len(out):
            if not isinstance(out[k], Circle):
                k += 1
                continue
            j = k + 1  # past the pieces too short to be segments that follow without a gap
            while (
                j < len(out) and out[j].start == out[j - 1].stop and self._unreported_piece(out[j])
            ):
                j += 1
            if j < len(out) and isinstance(out[j], Circle) and out[j].start == out[j - 1].stop:
                joined = self._cylinder_over(out[k], out[j])
                if joined is not None:
                    out[k : j + 1] = [joined]
                    continue  # and try it with the next circle
            k += 1
        return out

    def _cylinder_over(self, first: Surface, last: Surface) -> Circle | None:
        """The cylinder test from ``first`` to ``last`` (circles as far as they were fitted);
        the cylinder found spans both whole."""
        lo = first.fit_start if isinstance(first, Circle) else first.start
        hi = last.fit_stop if isinstance(last, Circle) else last.stop
        found = self.cylinders.test(lo, hi)
        return None if found is None else replace(found, start=first.start, stop=last.stop)

    def _unreported_piece(self, item: Surface) -> bool:
        """A straight piece that is no segment (see :meth:`Line.reportable`)."""
        return isinstance(item, Line) and not item.reportable(self.settings)
