"""The command line: outputs, and one-line errors with exit status 2 on bad input."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from cli.main import main

ROOT = Path(__file__).resolve().parents[2]
WORLDS = ROOT / "worlds"
BAD_WORLDS = ROOT / "tests" / "data" / "worlds"
PNG = b"\x89PNG\r\n\x1a\n"


def _run(*args: str) -> subprocess.CompletedProcess[str]:
    """Run the real command in a new process, as a user would."""
    return subprocess.run(
        [sys.executable, "-m", "cli.main", *args],
        capture_output=True,
        text=True,
        timeout=120,
        cwd=ROOT,
    )


def test_scan_writes_the_issue_fields(tmp_path: Path) -> None:
    out, plot = tmp_path / "scan.json", tmp_path / "scan.png"
    assert (
        main(
            [
                "scan",
                "--world",
                str(WORLDS / "box_before_wall.toml"),
                "--json",
                str(out),
                "--plot",
                str(plot),
                "--window",
                "-10",
                "10",
                "--pan",
                "15",
            ]
        )
        == 0
    )
    samples = json.loads(out.read_text())["samples"]
    names = {
        "time_s",
        "scan_angle_rad",
        "pan_rad",
        "image_position_norm",
        "intensity_A",
        "range_m",
        "sigma_m",
        "beam_origin_xy",
        "beam_heading_rad",
        "truth_range_m",
        "truth_visible",
    }
    assert names <= set(samples)
    assert {len(samples[k]) for k in names | {"flag", "segment"}} == {128}
    assert samples["pan_rad"][0] == pytest.approx(0.2618, abs=1e-4)
    assert all(len(xy) == 2 for xy in samples["beam_origin_xy"])
    assert plot.read_bytes().startswith(PNG)


@pytest.mark.parametrize(
    ("args", "needle"),
    [
        (["--world", str(BAD_WORLDS / "unknown_key.toml")], "unknown_key.toml"),
        (["--world", str(BAD_WORLDS / "bad_syntax.toml")], "bad_syntax.toml"),
        (["--world", str(BAD_WORLDS / "boolean_radius.toml")], "boolean_radius.toml"),
        (["--world", "no/such/world.toml"], "no such file"),
        (["--world", str(WORLDS / "cylinder.toml"), "--window", "-30", "10"], "outside the mirror"),
        (["--world", str(WORLDS / "cylinder.toml"), "--pan", "120"], "pan 120.00 deg"),
        (
            ["--world", str(WORLDS / "cylinder.toml"), "--calibration", "missing.npz"],
            "calibration file missing.npz",
        ),
    ],
)
def test_bad_input_is_one_line_and_status_2(args: list[str], needle: str) -> None:
    done = _run("scan", *args)
    assert done.returncode == 2, done.stderr
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1, done.stderr  # no traceback
    assert lines[0].startswith("sensor-agent: ") and needle in lines[0]


def test_characterise_writes_json_and_figures(tmp_path: Path) -> None:
    out = tmp_path / "figs"
    assert (
        main(
            [
                "characterise",
                "--samples",
                "200",
                "--json",
                str(tmp_path / "c.json"),
                "--plots",
                str(out),
            ]
        )
        == 0
    )
    data = json.loads((tmp_path / "c.json").read_text())
    assert {"true", "fit", "noise", "table", "edge_to_centre_accuracy"} <= set(data)
    pngs = sorted(p.name for p in out.glob("*.png"))
    assert len(pngs) == 5 and all((out / p).read_bytes().startswith(PNG) for p in pngs)


def test_calibrate_writes_a_loadable_file_and_report(tmp_path: Path) -> None:
    from agent.calibration import Calibration

    cal = tmp_path / "cal.npz"
    assert (
        main(
            [
                "calibrate",
                "--out",
                str(cal),
                "--planes",
                "24",
                "--sweeps",
                "2",
                "--eval-sweeps",
                "2",
                "--json",
                str(tmp_path / "r.json"),
            ]
        )
        == 0
    )
    Calibration.load(cal)
    report = json.loads((tmp_path / "r.json").read_text())
    assert report["before"]["max_abs_bias_sigma"] > report["after"]["max_abs_bias_sigma"]


def test_too_few_samples_is_refused() -> None:
    done = _run("characterise", "--samples", "3")
    assert done.returncode == 2 and "at least 10" in done.stderr
