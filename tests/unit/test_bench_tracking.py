"""``sensor-agent bench tracking`` on two short scenes: the JSON's keys and sanity, the
scripted driver, and the Stone Soup baseline's adapter (speed is not checked here)."""

from __future__ import annotations

import importlib.util
import json
import math
from pathlib import Path

import numpy as np
import pytest

from agent.runtime import topics
from agent.runtime.messages import Header, Odometry, VehicleState, WheelCommand, WorldTruth
from cli.bench_tracking import ScriptedDriver
from cli.main import main

HAS_STONESOUP = importlib.util.find_spec("stonesoup") is not None


@pytest.fixture(scope="module")
def figures(tmp_path_factory: pytest.TempPathFactory) -> dict[str, object]:
    out = tmp_path_factory.mktemp("bench") / "tracking.json"
    status = main(
        ["bench", "tracking", "--scenes", "2", "--seed", "3", "--max-scene-s", "6",
         "--json", str(out)]
    )  # fmt: skip
    assert status == 0
    loaded: dict[str, object] = json.loads(out.read_text())
    return loaded


def test_json_has_the_keys(figures: dict[str, object]) -> None:
    f = figures
    for key in (
        "scenes", "scans", "gospa", "position_rmse_m", "nees", "id_switches",
        "fragmentations", "static_deleted_out_of_view", "false_tracks_per_scan",
        "confirm_latency_s", "false_free_rate", "free_coverage", "per_scan_ms", "baseline",
    ):  # fmt: skip
        assert key in f, key
    assert f["scenes"] == 2
    gospa = f["gospa"]
    assert isinstance(gospa, dict)
    assert (gospa["c"], gospa["p"], gospa["alpha"]) == (0.5, 1.0, 2)
    assert set(gospa) >= {"mean", "localisation", "missed", "false"}
    rmse = f["position_rmse_m"]
    assert isinstance(rmse, dict) and set(rmse) >= {"segment", "corner", "cylinder", "mover"}
    nees = f["nees"]
    assert isinstance(nees, dict)
    assert nees["static"]["dof"] == 2 and nees["moving"]["dof"] == 4
    assert set(nees["static"]) >= {"mean", "dof", "runs"}
    assert set(f["confirm_latency_s"]) >= {"p50", "p95"}  # type: ignore[arg-type]
    assert set(f["per_scan_ms"]) >= {"p50", "p99", "tracks"}  # type: ignore[arg-type]


def test_figures_are_sane(figures: dict[str, object]) -> None:
    f = figures
    scans = f["scans"]
    assert isinstance(scans, int) and 2 * 40 <= scans <= 2 * 70  # 10 Hz over 6 s, each
    gospa = f["gospa"]
    assert isinstance(gospa, dict)
    parts = gospa["localisation"] + gospa["missed"] + gospa["false"]
    assert gospa["mean"] == pytest.approx(parts)  # p = 1: the parts add up
    assert 0.0 <= gospa["mean"] <= 0.25 * 40  # at most c/2 per object and track in reach
    assert f["id_switches"] >= 0 and f["fragmentations"] >= 0  # type: ignore[operator]
    if f["false_free_rate"] is not None:
        assert 0.0 <= f["false_free_rate"] <= 1.0  # type: ignore[operator]
    assert f["per_scan_ms"]["p50"] > 0.0  # type: ignore[index]
    counters = f["counters"]
    assert isinstance(counters, dict)
    assert counters["tracking.tracks_published"] >= scans  # every scored scan was tracked


@pytest.mark.skipif(not HAS_STONESOUP, reason="Stone Soup (the baseline extra) not installed")
def test_baseline_is_scored_alike(figures: dict[str, object]) -> None:
    b = figures["baseline"]
    assert isinstance(b, dict)
    assert "Stone Soup" in b["name"]
    for key in ("gospa", "position_rmse_m", "id_switches", "false_tracks_per_scan",
                "per_scan_ms"):  # fmt: skip
        assert key in b, key
    assert b["gospa"]["c"] == 0.5


def test_no_baseline_flag(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "t.json"
    assert main(["bench", "tracking", "--scenes", "1", "--max-scene-s", "1", "--no-baseline",
                 "--json", str(out)]) == 0  # fmt: skip
    assert "baseline skipped" in capsys.readouterr().out
    assert json.loads(out.read_text())["baseline"] is None


def test_bad_arguments_exit_2(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["bench", "tracking", "--scenes", "0"]) == 2
    assert "--scenes" in capsys.readouterr().err
    assert main(["bench", "tracking", "--max-scene-s", "-1"]) == 2


# ------------------------------------------------------------------------------ the driver
def _truth(x: float, y: float, yaw: float, t_ns: int) -> WorldTruth:
    return WorldTruth(
        header=Header(stamp_ns=t_ns, frame_id="world"), x_m=x, y_m=y, yaw_rad=yaw,
        speed_m_s=0.0, yaw_rate_rad_s=0.0, mover_xy=np.zeros((0, 2)),
        mover_velocity_xy=np.zeros((0, 2)), mover_radius_m=np.zeros(0),
    )  # fmt: skip


def test_driver_pursues_the_path_and_stops() -> None:
    path = np.array([[0.0, 0.0], [2.0, 0.0], [2.0, 2.0]])
    driver = ScriptedDriver(path)
    driver.start(0.0)
    # No truth yet: stand still.
    ((topic, cmd),) = driver.tick(0.0)
    assert topic == topics.WHEEL_COMMAND and isinstance(cmd, WheelCommand)
    assert (cmd.speed_m_s, cmd.yaw_rate_rad_s) == (0.0, 0.0)
    # On the first leg, heading along it: full speed, straight.
    driver.handle(topics.WORLD_TRUTH, _truth(0.5, 0.0, 0.0, 1), 0.05)
    ((_, cmd),) = driver.tick(0.05)
    assert isinstance(cmd, WheelCommand)
    assert cmd.speed_m_s == pytest.approx(0.4) and cmd.yaw_rate_rad_s == pytest.approx(0.0)
    # Left of the line: steer right (negative yaw rate), within the limit.
    driver.handle(topics.WORLD_TRUTH, _truth(1.0, 0.2, 0.0, 2), 0.1)
    ((_, cmd),) = driver.tick(0.1)
    assert isinstance(cmd, WheelCommand)
    assert -1.0 <= cmd.yaw_rate_rad_s < 0.0
    # Near the corner: turn left toward the second leg.
    driver.handle(topics.WORLD_TRUTH, _truth(1.8, 0.0, 0.0, 3), 0.15)
    ((_, cmd),) = driver.tick(0.15)
    assert isinstance(cmd, WheelCommand) and cmd.yaw_rate_rad_s > 0.0
    # At the end: done, stopped.
    driver.handle(topics.WORLD_TRUTH, _truth(2.0, 1.95, math.pi / 2, 4), 0.2)
    ((_, cmd),) = driver.tick(0.2)
    assert isinstance(cmd, WheelCommand)
    assert driver.done and (cmd.speed_m_s, cmd.yaw_rate_rad_s) == (0.0, 0.0)
    assert driver.next_tick_s() == pytest.approx(0.25)


def test_driver_relays_odometry_as_vehicle_state() -> None:
    driver = ScriptedDriver(np.array([[0.0, 0.0], [1.0, 0.0]]))
    cov = np.diag([1e-4, 2e-4, 3e-5])
    odom = Odometry(
        header=Header(stamp_ns=123_000_000, frame_id="odom"), x_m=0.1, y_m=-0.2, yaw_rad=0.3,
        speed_m_s=0.4, yaw_rate_rad_s=-0.1, pose_covariance=cov, distance_m=1.0,
    )  # fmt: skip
    ((topic, state),) = driver.handle(topics.ODOMETRY, odom, 0.2)
    assert topic == topics.VEHICLE_STATE and isinstance(state, VehicleState)
    assert state.header.stamp_ns == 123_000_000 and state.header.frame_id == "odom"
    assert (state.x_m, state.y_m, state.yaw_rad) == (0.1, -0.2, 0.3)
    assert (state.speed_m_s, state.yaw_rate_rad_s) == (0.4, -0.1)
    np.testing.assert_array_equal(state.pose_covariance, cov)
    assert state.intent_xy.shape == (0, 2)
    assert driver.handle(topics.HEAD_STATE, odom, 0.2) == []  # wrong topic: ignored


@pytest.mark.skipif(not HAS_STONESOUP, reason="Stone Soup (the baseline extra) not installed")
def test_baseline_confirms_a_steady_point_after_three_scans() -> None:
    from cli.baseline_stonesoup import StoneSoupBaseline, detections_in_odom

    # A corner 1 m ahead of a vehicle at (1, 2) facing +y: at (1, 3) in odom.
    kind, xy, cov = detections_in_odom(
        np.array([1, 0], dtype=np.uint8),
        np.array([[1.0, 0.0, np.nan], [0.3, 1.0, np.nan]]),  # the segment is left out
        np.array([np.diag([1e-4, 4e-4, np.nan]), np.eye(3)]),
        np.array([1.0, 2.0, math.pi / 2]),
    )
    np.testing.assert_allclose(xy, [[1.0, 3.0]], atol=1e-12)
    np.testing.assert_allclose(cov[0], np.diag([4e-4, 1e-4]), atol=1e-15)  # axes swapped
    baseline = StoneSoupBaseline()
    counts = []
    for scan in range(5):
        ids, kinds, state, covariance = baseline.step(0.1 * scan, kind, xy, cov)
        counts.append(ids.size)
    assert counts == [0, 0, 1, 1, 1]  # sure after its third update
    np.testing.assert_allclose(state[0, :2], [1.0, 3.0], atol=1e-6)
    assert kinds.tolist() == [1] and covariance.shape == (1, 4, 4)
