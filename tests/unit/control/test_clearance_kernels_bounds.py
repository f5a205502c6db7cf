"""The controller's grid kernels on spans far off the grid: huge, infinite or not-a-number
ends give the cells they reach on the grid, or none, and return. Before, a span beyond
int64's range of cells went through numba's undefined float-to-integer conversion and a
loop bounded by it ran for ever: an environment vector with a mover at 1e188 m/s (found
by tests/unit/test_fuzz_hypothesis.py) hung the vehicle stage. The kernels run in a child
process with a time limit, since a compiled loop cannot be interrupted."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from agent.control.clearance_kernels import _cell_span

ROOT = Path(__file__).resolve().parents[3]
INF = float("inf")
NAN = float("nan")


@pytest.mark.parametrize(
    ("lo_m", "hi_m", "cells"),
    [
        (0.0, 0.26, (0, 6)),  # within the grid, as before: floor(0.26 / 0.05) + 1
        (-1.0, 0.07, (0, 2)),
        (4.9, 9.0, (98, 100)),
        (-1e188, 1e188, (0, 100)),  # beyond int64's cells: clamped to the grid
        (0.5, 1e300, (10, 100)),
        (-INF, INF, (0, 100)),
        (6.0, 1e188, (0, 0)),  # off the grid
        (-1e188, -0.5, (0, 0)),
        (NAN, 1.0, (0, 0)),
        (0.0, NAN, (0, 0)),
    ],
)
def test_a_span_gives_the_cells_it_reaches_on_the_grid(
    lo_m: float, hi_m: float, cells: tuple[int, int]
) -> None:
    assert _cell_span(lo_m, hi_m, 0.0, 0.05, 100) == cells


_KERNELS = """
import numpy as np
from agent.control import clearance_kernels as k
grid = np.zeros((160, 160))
a = np.array([[0.34, 2.53], [0.0, 0.0], [np.nan, 1.0]])
b = np.array([[0.34, 2.1e188], [np.inf, -np.inf], [1.0, np.nan]])
reach = np.array([0.76, 0.3, 0.3])
k.forget_capsules(grid, -4.0, -4.0, 0.05, a, b, reach)
hit = np.zeros((160, 160), dtype=np.bool_)
k.mark_capsules(hit, np.ones((160, 160), dtype=np.bool_), -4.0, -4.0, 0.05, a[:1], b[:1], reach[:1])
there = np.zeros((160, 160))
k.record_outline(there, 1.0, -4.0, -4.0, 0.05, 1e300, np.nan, 0.0, 0.4, 0.3)
# The mover at 1e188 m/s is marked where it is now (its swept path has no length a float
# can square); the outline at 1e300 m is off the grid.
print(int(np.isneginf(grid).sum()), int(hit.sum()), int(there.sum()))
"""


def test_capsules_and_outlines_far_off_the_grid_return() -> None:
    done = subprocess.run(
        [sys.executable, "-c", _KERNELS], cwd=ROOT, capture_output=True, text=True, timeout=120
    )
    assert done.returncode == 0, done.stderr
    forgotten, marked, outline = (int(v) for v in done.stdout.split())
    assert forgotten > 0 and marked > 0 and outline == 0
