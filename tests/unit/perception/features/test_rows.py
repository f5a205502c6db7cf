"""The stacked rows' layout as the compiled kernels see it.

The kernels read the row indices of :mod:`agent.perception.features.rows` as constants
compiled into them, and numba's on-disk cache notices changes to a kernel's own file only:
a kernel loaded from a cache older than the layout reads the wrong rows. Each kernel that
reads the rows must then agree with its own Python source run on the same samples.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from agent.arrays import FloatArray
from agent.perception.features import (
    circle_kernels,
    cylinder_kernels,
    line_kernels,
    reflectivity_kernels,
    sample_kernels,
    split_merge_kernels,
)
from agent.perception.features.samples import prepare_samples
from tests.unit.perception.features.scans import (
    CYLINDER,
    INTENSITY_ERROR,
    NOISE_CURRENT_A,
    S_CARDBOARD,
    simulate_scan,
)


def _rows(rng: np.random.Generator) -> FloatArray:
    """One run of a cylinder's samples, every row filled."""
    scan = simulate_scan([CYLINDER], rng)
    args = {k: v for k, v in scan.items() if k not in ("truth_obj", "signal_constant_Am2")}
    samples = prepare_samples(
        **args, signal_constant=S_CARDBOARD, baseline_m=0.05, noise_current_A=NOISE_CURRENT_A,
        intensity_model_sigma=INTENSITY_ERROR, neighbour_correlation=0.13,
    )  # fmt: skip
    assert samples is not None and len(samples.runs) == 1
    return samples.rows


def _calls(rows: FloatArray) -> dict[str, tuple[Any, tuple[Any, ...]]]:
    m = rows.shape[1]
    ok, alpha, _, xm, ym, num, den, _, _, w = line_kernels.wtls.py_func(rows, 0, m, 6)
    assert ok
    pair_cov = np.full(m - 1, 1e-8)
    return {
        "wtls": (line_kernels.wtls, (rows, 0, m, 6)),
        "line_covariance": (
            line_kernels.line_covariance,
            (rows, 0, m, w, alpha, xm, ym, num, den, pair_cov, 0.07, True),
        ),
        "along_noise_ratio": (line_kernels.along_noise_ratio, (rows, 0, m, w, alpha)),
        "circle_problem": (circle_kernels.circle_problem, (rows, 0, m, 1e-3)),
        "kasa": (circle_kernels.kasa, (rows, 0, m)),
        "plane_intensity_misfit": (
            cylinder_kernels.plane_intensity_misfit,
            (rows, 0, m, alpha, 1.3),
        ),
        "convex": (cylinder_kernels.convex, (rows, 0, m, 1.5, 0.0)),
        "line_reflectivities": (reflectivity_kernels.line_reflectivities, (rows, 0, m, alpha, 0.2)),
        "circle_reflectivities": (
            reflectivity_kernels.circle_reflectivities,
            (rows, 0, m, 1.5, 0.0, 0.1, 0.2),
        ),
        "best_split": (split_merge_kernels.best_split, (rows, 0, m, w)),
        "boundary": (split_merge_kernels.boundary, (rows, 3, m - 3, 1.2, 1.0, 0.0, 1.3, 0.9, 0.1)),
    }


def _flat(value: Any) -> list[float]:
    parts = value if isinstance(value, tuple) else (value,)
    return [float(v) for p in parts for v in np.ravel(np.asarray(p, dtype=np.float64))]


@pytest.mark.parametrize(
    "kernel",
    [
        "wtls",
        "line_covariance",
        "along_noise_ratio",
        "circle_problem",
        "kasa",
        "plane_intensity_misfit",
        "convex",
        "line_reflectivities",
        "circle_reflectivities",
        "best_split",
        "boundary",
    ],
)
def test_compiled_kernels_read_the_rows_of_the_current_layout(
    rng: np.random.Generator, kernel: str
) -> None:
    # Compiled and interpreted arithmetic may round differently: agreement to 1e-9 of each
    # value (rows read from a stale layout differ by far more, or in shape).
    compiled_kernel, args = _calls(_rows(rng))[kernel]
    compiled_value = _flat(compiled_kernel(*args))
    source_value = _flat(compiled_kernel.py_func(*args))
    assert compiled_value == pytest.approx(source_value, rel=1e-9, abs=1e-15), (
        f"{kernel} disagrees with its source: a compiled cache older than the rows' layout? "
        "Delete agent/perception/features/__pycache__/*_kernels.*.nb[ic]"
    )


def test_the_compiled_stacking_writes_the_rows_of_the_current_layout(
    rng: np.random.Generator,
) -> None:
    # As above, for the kernel that fills the rows (compared with its own source run on the
    # same scan: the same arithmetic, to 1e-9).
    scan = simulate_scan([CYLINDER], rng)
    n = scan["segment"].size
    arrays = (
        scan["points_xy"], scan["covariance"].reshape(n, 4), scan["segment"], scan["flag"],
        scan["origin_xy"], scan["beam_angle_rad"], scan["range_m"], scan["intensity_A"],
    )  # fmt: skip
    for a in arrays:
        a.flags.writeable = False  # as prepare_samples passes them (one compiled signature)
    args = (*arrays, S_CARDBOARD, 0.05, NOISE_CURRENT_A, INTENSITY_ERROR, 0.13)
    compiled_value = _flat(sample_kernels.stacked_samples(*args))
    source_value = _flat(sample_kernels.stacked_samples.py_func(*args))
    assert compiled_value == pytest.approx(source_value, rel=1e-9, abs=1e-15), (
        "stacked_samples disagrees with its source: a compiled cache older than the rows' "
        "layout? Delete agent/perception/features/__pycache__/*_kernels.*.nb[ic]"
    )
