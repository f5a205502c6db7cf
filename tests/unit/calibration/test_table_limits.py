"""Calibration files and values at their limits: refused before anything large is allocated.

Files are built member by member here (zip records and ``.npy`` headers written by hand), so
they can claim what no honest writer would: huge shapes, foreign dtypes, sizes that disagree.
"""

from __future__ import annotations

import dataclasses
import io
import json
import math
import tracemalloc
import warnings
import zipfile
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from agent.calibration.table import (
    MAX_CALIBRATION_FILE_BYTES,
    MAX_GRID_NODES,
    MAX_HEADER_BYTES,
    Calibration,
)
from agent.errors import CalibrationFileError

pytestmark = pytest.mark.filterwarnings("error")

MEMORY_BOUND_BYTES = 4 << 20
"""Peak allocation allowed while refusing a file that claims a large table. The files are a
few kB and their headers a few hundred bytes; the claims would allocate 32 MiB to 80 GB."""


def _npy(
    shape: tuple[int, ...],
    descr: str = "<f8",
    data: bytes = b"",
    fortran_order: bool = False,
    version: tuple[int, int] = (1, 0),
) -> bytes:
    """A .npy member: a header claiming ``shape`` and ``descr``, then ``data`` as it is."""
    buffer = io.BytesIO()
    header = {"descr": descr, "fortran_order": fortran_order, "shape": shape}
    if version == (1, 0):
        np.lib.format.write_array_header_1_0(buffer, header)
    else:
        np.lib.format.write_array_header_2_0(buffer, header)
    return buffer.getvalue() + data


def _array(values: np.ndarray[Any, Any], version: tuple[int, int] = (1, 0)) -> bytes:
    buffer = io.BytesIO()
    np.lib.format.write_array(buffer, values, version=version)
    return buffer.getvalue()


def _archive(
    members: dict[str, bytes] | list[tuple[str, bytes]], method: int = zipfile.ZIP_DEFLATED
) -> bytes:
    """A zip archive of ``members`` (name without ``.npy`` -> bytes), in the order given."""
    items = members.items() if isinstance(members, dict) else members
    buffer = io.BytesIO()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # zipfile warns of a duplicate name, which we want
        with zipfile.ZipFile(buffer, "w", method) as archive:
            for name, payload in items:
                archive.writestr(name + ".npy", payload)
    return buffer.getvalue()


def _saved(calibration: Calibration, tmp_path: Path) -> dict[str, bytes]:
    """The members of ``calibration``'s file as it saves it, each as .npy bytes."""
    path = tmp_path / "saved.npz"
    calibration.save(path)
    with zipfile.ZipFile(path) as archive:
        return {name.removesuffix(".npy"): archive.read(name) for name in archive.namelist()}


def _refused(data: bytes, match: str) -> CalibrationFileError:
    with pytest.raises(CalibrationFileError, match=match) as info:
        Calibration.from_bytes(data, "c.npz")
    assert "\n" not in str(info.value)
    assert str(info.value).startswith("calibration file c.npz: ")
    return info.value


def _peak_bytes(action: Callable[[], object]) -> int:
    tracemalloc.start()
    try:
        action()
    except CalibrationFileError:
        pass
    finally:
        peak = tracemalloc.get_traced_memory()[1]
        tracemalloc.stop()
    return peak


# --------------------------------------------------------------------------------------------
# Small files that claim large tables
# --------------------------------------------------------------------------------------------


def _bomb(n_angles: int, n_positions: int, honest_grids: bool, header: bytes) -> bytes:
    def grid(n: int) -> bytes:
        return _array(np.linspace(-0.3, 0.3, n)) if honest_grids else _npy((n,))

    # The table first: a reader that allocates what a member claims does so at once.
    return _archive(
        [
            ("inverse_range_per_m", _npy((n_angles, n_positions), data=b"\0" * 64)),
            ("header", header),
            ("scan_angle_grid_rad", grid(n_angles)),
            ("position_grid", grid(n_positions)),
        ]
    )


@pytest.mark.parametrize(
    ("n_angles", "n_positions", "honest_grids", "match"),
    [
        (
            100_000,
            100_000,
            False,
            r"scan_angle_grid_rad: float64 of shape \(100000,\); the format has float64 of 2 to "
            rf"{MAX_GRID_NODES} nodes$",
        ),
        (20_000, 20_000, False, r"scan_angle_grid_rad: float64 of shape \(20000,\)"),
        # Within the grid limits, but the table's data is not there: its declared size says so.
        (
            MAX_GRID_NODES,
            MAX_GRID_NODES,
            True,
            r"inverse_range_per_m: the archive declares 192 bytes where its .npy header describes "
            rf"{128 + 8 * MAX_GRID_NODES**2}$",
        ),
    ],
    ids=["100000x100000", "20000x20000", "2048x2048-empty"],
)
def test_a_small_file_claiming_a_large_table_is_refused_before_allocating(
    calibration: Calibration,
    tmp_path: Path,
    n_angles: int,
    n_positions: int,
    honest_grids: bool,
    match: str,
) -> None:
    data = _bomb(n_angles, n_positions, honest_grids, _saved(calibration, tmp_path)["header"])
    assert len(data) < 40_000
    _refused(data, match)
    peak = _peak_bytes(lambda: Calibration.from_bytes(data, "c.npz"))
    assert peak < MEMORY_BOUND_BYTES, f"peak {peak} bytes"


def test_an_oversized_file_is_refused_before_reading(tmp_path: Path) -> None:
    sparse = tmp_path / "huge.npz"
    with open(sparse, "wb") as f:
        f.truncate(1 << 30)
    with pytest.raises(CalibrationFileError, match=r"huge.npz: larger than the \d+-byte limit"):
        Calibration.load(sparse)
    assert _peak_bytes(lambda: Calibration.load(sparse)) < MEMORY_BOUND_BYTES
    _refused(b"\0" * (MAX_CALIBRATION_FILE_BYTES + 1), "larger than the")


# --------------------------------------------------------------------------------------------
# Members that are not what the format allows
# --------------------------------------------------------------------------------------------


def _with(members: dict[str, bytes], **changes: bytes | None) -> dict[str, bytes]:
    """``members`` with some replaced or added, and those changed to ``None`` left out."""
    out = dict(members)
    for name, payload in changes.items():
        if payload is None:
            del out[name]
        else:
            out[name] = payload
    return out


@pytest.mark.parametrize(
    ("change", "match"),
    [
        (
            lambda m: _with(m, position_grid=_npy((201,), "|O")),
            r"position_grid: object of shape \(201,\); the format has float64 of 2 to 2048",
        ),
        (
            lambda m: _with(m, position_grid=_array(np.arange(201))),
            r"position_grid: int64 of shape \(201,\)",
        ),
        (
            lambda m: _with(m, position_grid=_array(np.linspace(-1, 1, 201, dtype=np.float32))),
            r"position_grid: float32 of shape \(201,\)",
        ),
        (
            lambda m: _with(m, position_grid=_array(np.zeros((201, 1)))),
            r"position_grid: float64 of shape \(201, 1\)",
        ),
        (
            lambda m: _with(m, position_grid=_array(np.array(1.0))),
            r"position_grid: float64 of shape \(\)",
        ),
        (
            lambda m: _with(m, position_grid=_array(np.linspace(-1, 1, 1))),
            r"position_grid: float64 of shape \(1,\)",
        ),
        (
            lambda m: _with(m, inverse_range_per_m=_array(np.ones((201, 161)))),
            r"inverse_range_per_m: float64 of shape \(201, 161\); the format has float64 of "
            r"shape \(161, 201\), as its grids",
        ),
        (
            lambda m: _with(m, inverse_range_per_m=_array(np.asfortranarray(np.ones((161, 201))))),
            "inverse_range_per_m: stored in Fortran order",
        ),
        (
            lambda m: _with(m, header=_array(np.zeros(10, dtype=np.int8))),
            r"header: int8 of shape \(10,\); the format has uint8 of 1 to 65536 bytes",
        ),
        (
            lambda m: _with(m, header=_array(np.zeros(MAX_HEADER_BYTES + 1, dtype=np.uint8))),
            rf"header: uint8 of shape \({MAX_HEADER_BYTES + 1},\)",
        ),
        (lambda m: _with(m, position_grid=None), "missing entry 'position_grid'$"),
        (lambda m: _with(m, header=None), "missing entry 'header'$"),
        (lambda m: _with(m, position_grid=None, extra=b""), r"unexpected entry 'extra.npy'$"),
        (
            lambda m: [*_with(m, position_grid=None).items(), ("header", m["header"])],
            "an entry appears twice",
        ),
        (lambda m: {**m, "extra": b""}, r"its zip directory lists 5 entries"),
        (
            lambda m: [*m.items(), *((f"x{i}", b"") for i in range(5000))],
            r"its zip directory lists 5004 entries in \d+ bytes; the format has 4\)$",
        ),
    ],
)
def test_members_are_checked_by_their_headers(
    calibration: Calibration,
    tmp_path: Path,
    change: Callable[[dict[str, bytes]], dict[str, bytes] | list[tuple[str, bytes]]],
    match: str,
) -> None:
    members = _saved(calibration, tmp_path)
    Calibration.from_bytes(_archive(members))  # as saved, it loads
    _refused(_archive(change(members)), match)


def test_compression_methods(calibration: Calibration, tmp_path: Path) -> None:
    members = _saved(calibration, tmp_path)
    for method in (zipfile.ZIP_STORED, zipfile.ZIP_DEFLATED):
        Calibration.from_bytes(_archive(members, method))
    _refused(_archive(members, zipfile.ZIP_BZIP2), r"header: zip compression method 12")


def test_npy_format_2_is_read(calibration: Calibration, tmp_path: Path) -> None:
    members = _saved(calibration, tmp_path)
    members["inverse_range_per_m"] = _array(calibration.inverse_range_per_m, version=(2, 0))
    again = Calibration.from_bytes(_archive(members))
    np.testing.assert_array_equal(again.inverse_range_per_m, calibration.inverse_range_per_m)


def test_save_writes_what_load_accepts(calibration: Calibration, tmp_path: Path) -> None:
    # A table held in Fortran order is saved in C order, the only order a file may have.
    fortran = dataclasses.replace(
        calibration, inverse_range_per_m=np.asfortranarray(calibration.inverse_range_per_m)
    )
    path = tmp_path / "f.npz"
    fortran.save(path)
    again = Calibration.load(path)
    np.testing.assert_array_equal(again.inverse_range_per_m, calibration.inverse_range_per_m)
    big = dataclasses.replace(calibration, metadata={"notes": "x" * MAX_HEADER_BYTES})
    with pytest.raises(CalibrationFileError, match=r"big.npz: header of \d+ bytes is larger"):
        big.save(tmp_path / "big.npz")
    assert not (tmp_path / "big.npz").exists()


# --------------------------------------------------------------------------------------------
# Values no sensor of this kind could have
# --------------------------------------------------------------------------------------------


def _table_change(calibration: Calibration, name: str, change: Callable[[Any], Any]) -> Any:
    return change(np.array(getattr(calibration, name)))


def _set(values: Any, index: Any, value: float) -> Any:
    values[index] = value
    return values


@pytest.mark.parametrize(
    ("name", "change", "match"),
    [
        (
            "scan_angle_grid_rad",
            lambda g: _set(g, 3, np.nan),
            "scan angle grid holds NaN or infinite values",
        ),
        ("position_grid", lambda g: _set(g, -1, np.inf), "position grid holds NaN or infinite"),
        (
            "scan_angle_grid_rad",
            lambda g: 3 * g,
            r"scan angle grid must lie within ±0.785398 rad \(±45°\), got -1.0472 to 1.0472",
        ),
        ("position_grid", lambda g: 2 * g, r"position grid must lie within ±1 \(the ends"),
        ("inverse_range_per_m", lambda q: _set(q, (80, 100), np.inf), "holds infinite values"),
        ("inverse_range_per_m", lambda q: _set(q, (0, 0), -np.inf), "holds infinite values"),
        (
            "inverse_range_per_m",
            lambda q: np.full_like(q, np.nan),
            "inverse_range_per_m has no calibrated \\(finite\\) value",
        ),
        (
            "inverse_range_per_m",
            lambda q: q / 1000,  # per millimetre
            r"inverse_range_per_m must be from 0.2 to 5 per metre where calibrated \(ranges of "
            r"0.2 to 5 m, .*\), got 0.000332237 to 0.00304218$",
        ),
        ("inverse_range_per_m", lambda q: _set(q, (80, 100), -0.5), "got -0.5 to 3.04218$"),
        ("inverse_range_per_m", lambda q: _set(q, (80, 100), 0.0), "got 0 to 3.04218$"),
        ("inverse_range_per_m", lambda q: _set(q, (80, 100), 5.01), "got 0.332237 to 5.01$"),
    ],
)
def test_implausible_tables_are_refused(
    calibration: Calibration,
    tmp_path: Path,
    name: str,
    change: Callable[[Any], Any],
    match: str,
) -> None:
    bad = _table_change(calibration, name, change)
    with pytest.raises(CalibrationFileError, match=match):
        dataclasses.replace(calibration, **{name: bad})
    # The same values in a file are refused naming the file.
    members = _saved(calibration, tmp_path)
    members[name] = _array(bad)
    error = _refused(_archive(members), match)
    assert error.path == Path("c.npz")


def test_uncalibrated_nodes_and_grid_sizes_at_their_limits(calibration: Calibration) -> None:
    q = np.array(calibration.inverse_range_per_m)
    assert np.isnan(q).any()  # the shipped table leaves unreached nodes NaN
    q[:, :100] = np.nan
    assert np.isnan(
        dataclasses.replace(calibration, inverse_range_per_m=q).lookup(
            np.zeros(1), np.array([-0.5])
        )[0]
    ).all()
    for n in (2, MAX_GRID_NODES):
        dataclasses.replace(
            calibration,
            scan_angle_grid_rad=np.linspace(-0.35, 0.35, n),
            position_grid=np.linspace(-1.0, 1.0, 2),
            inverse_range_per_m=np.ones((n, 2)),
        )
    with pytest.raises(CalibrationFileError, match=rf"scan angle grid has {MAX_GRID_NODES + 1} "):
        dataclasses.replace(
            calibration,
            scan_angle_grid_rad=np.linspace(-0.35, 0.35, MAX_GRID_NODES + 1),
            position_grid=np.linspace(-1.0, 1.0, 2),
            inverse_range_per_m=np.ones((MAX_GRID_NODES + 1, 2)),
        )


NOMINAL = {
    "signal_constant_Am2": 2.59e-8,
    "noise_current_A": 36.5e-12,
    "fd_m2": 0.00475,
    "scan_rate_rad_s": math.radians(40.0) / 0.1,
}


@pytest.mark.parametrize(
    ("name", "allowed", "refused"),
    [
        *(
            (name, [value / 10, value * 10], [value / 10.01, value * 10.01, 0.0, -value])
            for name, value in NOMINAL.items()
            if name != "fd_m2"
        ),
        ("fd_m2", [0.00475 / 2, 0.0044, 0.00475 * 2], [0.00475 / 2.01, 0.00475 * 2.01, 4.4]),
        ("noise_current_A", [], [36.5]),  # amperes written as picoamperes
        ("detection_delay_s", [0.0, 0.336e-3, 3.36e-3], [-1e-6, 3.4e-3, 0.336]),
        ("scan_angle_sigma_rad", [0.0, 1e-4, 1e-3], [-1e-9, 1.01e-3, 0.1]),
        *((name, [], [math.nan, math.inf]) for name in [*NOMINAL, "detection_delay_s"]),
    ],
)
def test_implausible_constants_are_refused(
    calibration: Calibration,
    tmp_path: Path,
    name: str,
    allowed: list[float],
    refused: list[float],
) -> None:
    for value in allowed:
        changes: dict[str, Any] = {name: value}
        assert getattr(dataclasses.replace(calibration, **changes), name) == value
    for value in refused:
        changes = {name: value}
        with pytest.raises(CalibrationFileError, match=rf"^calibration: {name} must be from "):
            dataclasses.replace(calibration, **changes)
    # In a file, the message names the file, the bounds and why.
    members = _saved(calibration, tmp_path)
    header = json.loads(bytes(np.lib.format.read_array(io.BytesIO(members["header"]))))
    header[name] = refused[0]
    members["header"] = _array(np.frombuffer(json.dumps(header).encode(), dtype=np.uint8))
    error = _refused(_archive(members), rf"{name} must be from [-+.e\d]+ to [-+.e\d]+ \(.+\), got")
    assert error.path == Path("c.npz")
