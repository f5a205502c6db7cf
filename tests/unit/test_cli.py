"""The command line: outputs, and one-line errors with exit status 2 on bad input."""

from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np
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


def _wall_and_cylinder_world(path: Path, pose: tuple[float, float, float]) -> dict[str, Any]:
    """A wall 1.8 m ahead of the vehicle, square to it, and a cylinder (r 0.15 m) 1.0 m
    ahead of the centre of scanning (0.3 m ahead of the vehicle), all placed relative to a
    turned and shifted vehicle pose so that the world mapping matters. Returns the truth."""
    x0, y0, yaw_deg = pose
    c, s = math.cos(math.radians(yaw_deg)), math.sin(math.radians(yaw_deg))

    def world(x: float, y: float) -> list[float]:
        return [x0 + c * x - s * y, y0 + s * x + c * y]

    wall = [world(1.8, -1.5), world(1.8, 1.5)]
    centre = world(1.3, 0.05)
    path.write_text(
        f"""name = "wall and cylinder"
[vehicle]
pose = [{x0}, {y0}, {yaw_deg}]
[[wall]]
points = {wall}
reflectivity = 1.0
[[cylinder]]
center = {centre}
radius = 0.15
reflectivity = 1.0
"""
    )
    return {"wall": np.array(wall), "normal": np.array([c, s]), "centre": centre, "radius": 0.15}


def test_scan_reports_features_in_the_world_frame(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    truth = _wall_and_cylinder_world(tmp_path / "w.toml", (0.5, -0.4, 30.0))
    out, plot = tmp_path / "scan.json", tmp_path / "scan.png"
    args = ["scan", "--world", str(tmp_path / "w.toml"), "--json", str(out), "--plot", str(plot)]
    assert main(args) == 0
    assert "  features: 2 segments, 0 corners, 2 edges, 1 cylinder" in capsys.readouterr().out
    data = json.loads(out.read_text())
    assert data["vehicle_pose_at_reference"] == pytest.approx([0.5, -0.4, math.radians(30.0)])
    assert {"frame", "segment", "corner", "edge", "cylinder"} <= set(data["feature_conventions"])
    features = data["features"]
    # The wall's line in the world: normal · p = rho. Endpoints within 2 cm of it (the
    # sensor's σ at 1.5 m is about 8 mm per sample; seeds 1-40 give at most 9 mm).
    rho = float(truth["normal"] @ truth["wall"][0])
    segments = [f for f in features if f["kind"] == "segment"]
    on_wall = [
        f
        for f in segments
        if all(abs(float(truth["normal"] @ p) - rho) < 0.02 for p in f["endpoints_world"])
    ]
    assert on_wall, segments
    cylinders = [f for f in features if f["kind"] == "cylinder"]
    assert len(cylinders) == 1
    assert math.dist(cylinders[0]["center_world"], truth["centre"]) < 0.03
    assert cylinders[0]["radius_m"] == pytest.approx(truth["radius"], abs=0.01)
    for f in features:
        cov = np.array(f["covariance"])
        dof = 3 if f["kind"] == "cylinder" else 2
        assert cov.shape == (dof, dof), f
        assert np.allclose(cov, cov.T) and np.all(np.diag(cov) > 0), f
        assert f["covariance_params"]
    samples = data["samples"]
    assert len(samples["flag"]) == len(samples["segment"]) == len(samples["time_s"])
    assert plot.stat().st_size > 0 and plot.read_bytes().startswith(PNG)


def test_pose_to_world_rotates_then_translates() -> None:
    from cli.sensor_commands import pose_to_world

    to_world = pose_to_world(1.0, 2.0, math.pi / 2)
    got = to_world(np.array([[1.0, 0.0], [0.0, 1.0], [0.0, 0.0]]))
    assert got == pytest.approx(np.array([[1.0, 3.0], [0.0, 2.0], [1.0, 2.0]]))


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
    from agent.calibration.table import Calibration

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


def test_keys_are_not_overwritten_unless_forced(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    keys = tmp_path / "keys"
    assert main(["keys", str(keys)]) == 0
    before = {p.name: p.read_bytes() for p in keys.glob("*.key*")}
    assert set(before) == {"server.key", "server.key_secret", "client.key", "client.key_secret"}
    capsys.readouterr()
    assert main(["keys", str(keys)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "already has keys" in err and "--force" in err
    assert {p.name: p.read_bytes() for p in keys.glob("*.key*")} == before  # untouched
    assert main(["keys", str(keys), "--force"]) == 0
    after = {p.name: p.read_bytes() for p in keys.glob("*.key*")}
    assert after.keys() == before.keys() and after["server.key"] != before["server.key"]
