"""``sensor-agent systemd``: the units carry the launch file's graph and supervision."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from agent.errors import ConfigError
from agent.runtime.launch import GraphSpec, load_launch, parse_launch
from cli.main import main
from cli.systemd import write_units

ROOT = Path(__file__).resolve().parents[2]
ROBOT = ROOT / "launch" / "robot.toml"


def read_unit(path: Path) -> dict[str, dict[str, list[str]]]:
    """A unit file as section → key → values (a key may repeat)."""
    sections: dict[str, dict[str, list[str]]] = {}
    current: dict[str, list[str]] = {}
    for line in path.read_text().splitlines():
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        if line.startswith("["):
            current = sections.setdefault(line.strip("[]"), {})
            continue
        key, _, value = line.partition("=")
        current.setdefault(key, []).append(value)
    return sections


@pytest.fixture
def sensor_units(tmp_path: Path) -> Path:
    write_units(load_launch(ROBOT), "sensor", tmp_path, python="/opt/agent/bin/python")
    return tmp_path


def test_one_service_per_process_of_the_host_and_a_target(sensor_units: Path) -> None:
    graph = load_launch(ROBOT)
    names = sorted(p.name for p in sensor_units.iterdir())
    on_sensor = [p.name for p in graph.processes if p.host == "sensor"]
    assert "vehicle" not in on_sensor and len(on_sensor) == 6
    assert names == sorted(
        ["graph.json", "sensor-agent-robot.target", "sensor-agent-robot-stop.service"]
        + [f"sensor-agent-robot-{n}.service" for n in on_sensor]
    )
    target = read_unit(sensor_units / "sensor-agent-robot.target")
    assert sorted(target["Unit"]["Wants"][0].split()) == sorted(
        f"sensor-agent-robot-{n}.service" for n in on_sensor
    )
    assert target["Install"]["WantedBy"] == ["multi-user.target"]


def test_a_service_runs_its_process_as_the_launcher_does(sensor_units: Path) -> None:
    unit = read_unit(sensor_units / "sensor-agent-robot-tracking.service")
    service = unit["Service"]
    assert service["ExecStart"] == [
        "/opt/agent/bin/python -m processes.tracking "
        "--graph /etc/sensor-agent/robot/graph.json --name tracking"
    ]
    assert service["Type"] == ["notify"] and service["NotifyAccess"] == ["main"]
    assert service["User"] == ["sensor-agent"] and service["Group"] == ["sensor-agent"]
    assert service["RuntimeDirectory"] == ["sensor-agent-robot"]
    assert service["RuntimeDirectoryMode"] == ["0700"]
    assert service["RuntimeDirectoryPreserve"] == ["yes"]
    assert "SupplementaryGroups" not in service  # only the serial head needs the port's group
    head = read_unit(sensor_units / "sensor-agent-robot-head.service")["Service"]
    assert head["SupplementaryGroups"] == ["dialout"]


def test_supervision_maps_onto_systemd(tmp_path: Path) -> None:
    text = """
[graph]
name = "g"
heartbeat_s = 0.25
hang_timeout_s = 1.5
start_timeout_s = 20.0

[[process]]
name = "head"
module = "processes.head"
outputs = ["raw_scan"]
restart = "never"
max_restarts = 3
restart_window_s = 30.0
backoff_s = 0.25
stop_graph_on_failure = false

[[process]]
name = "calibration"
module = "processes.calibration"
inputs = ["raw_scan"]
outputs = ["calibrated_scan"]
"""
    write_units(parse_launch(text, tmp_path / "g.toml"), "localhost", tmp_path / "u")
    head = read_unit(tmp_path / "u" / "sensor-agent-g-head.service")
    assert head["Unit"]["StartLimitBurst"] == ["4"]  # the first start and 3 restarts
    assert head["Unit"]["StartLimitIntervalSec"] == ["30s"]
    assert "OnFailure" not in head["Unit"]
    assert head["Service"]["Restart"] == ["no"]
    assert head["Service"]["RestartSec"] == ["250ms"]
    assert head["Service"]["WatchdogSec"] == ["1500ms"]
    assert head["Service"]["TimeoutStartSec"] == ["20s"]
    calibration = read_unit(tmp_path / "u" / "sensor-agent-g-calibration.service")
    assert calibration["Service"]["Restart"] == ["always"]
    assert calibration["Unit"]["OnFailure"] == ["sensor-agent-g-stop.service"]
    assert "Wants" not in calibration["Unit"]  # ipc only: no network to wait for
    stop = read_unit(tmp_path / "u" / "sensor-agent-g-stop.service")
    assert stop["Service"]["ExecStart"] == [
        "/usr/bin/systemctl stop --no-block sensor-agent-g.target"
    ]


def test_the_graph_file_runs_in_the_runtime_directory_with_the_keys_where_installed(
    sensor_units: Path,
) -> None:
    graph = GraphSpec.from_json((sensor_units / "graph.json").read_text())
    assert graph.runtime_dir == "/run/sensor-agent-robot"
    assert graph.keys_dir == "/etc/sensor-agent/robot/keys"
    assert graph.process("head").endpoint == "ipc:///run/sensor-agent-robot/head.pub"
    assert graph.control_endpoint == "ipc:///run/sensor-agent-robot/launcher.pub"
    # Both hosts' processes: the sensor's read vehicle_state from the vehicle computer.
    assert graph.process("vehicle").endpoint == "tcp://192.168.50.11:5620"
    planner = read_unit(sensor_units / "sensor-agent-robot-planner.service")["Unit"]
    assert planner["After"] == ["network-online.target"]


def test_the_vehicle_host_gets_its_own_part(tmp_path: Path) -> None:
    status = main(
        ["systemd", str(ROBOT), "--host", "vehicle", "--out", str(tmp_path), "--user", "robot",
         "--keys-dir", "/srv/keys", "--etc", "/srv/etc"]
    )  # fmt: skip
    assert status == 0
    services = sorted(p.name for p in tmp_path.glob("*.service"))
    assert services == ["sensor-agent-robot-stop.service", "sensor-agent-robot-vehicle.service"]
    vehicle = read_unit(tmp_path / "sensor-agent-robot-vehicle.service")["Service"]
    assert vehicle["User"] == ["robot"]
    assert vehicle["ExecStart"][0].endswith("--graph /srv/etc/robot/graph.json --name vehicle")
    assert json.loads((tmp_path / "graph.json").read_text())["keys_dir"] == "/srv/keys"


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["--host", "nowhere"], "no process on host 'nowhere' (hosts: sensor, vehicle)"),
        (["--host", "sensor", "--python", "python3"], "--python 'python3' must be an absolute"),
    ],
)
def test_bad_requests_get_one_line(
    argv: list[str], message: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["systemd", str(ROBOT), "--out", str(tmp_path / "u"), *argv]) == 2
    err = capsys.readouterr().err
    assert message in err and err.count("\n") == 1
    assert not (tmp_path / "u").exists()


def test_a_name_that_cannot_name_a_unit_is_refused(tmp_path: Path) -> None:
    text = '[graph]\nname = "my graph"\n[[process]]\nname = "a"\nmodule = "processes.head"\n'
    with pytest.raises(ConfigError, match="'my graph' cannot name a unit"):
        write_units(parse_launch(text), "localhost", tmp_path)


@pytest.mark.skipif(shutil.which("systemd-analyze") is None, reason="no systemd-analyze here")
def test_systemd_accepts_the_units(sensor_units: Path, tmp_path: Path) -> None:
    """``systemd-analyze verify`` parses every key (it warns of unknown or malformed ones)."""
    units = tmp_path / "verify"
    write_units(load_launch(ROBOT), "sensor", units, python=sys.executable)
    names = sorted(str(p) for p in units.iterdir() if p.suffix in (".service", ".target"))
    done = subprocess.run(
        ["systemd-analyze", "verify", "--man=no", *names], capture_output=True, text=True
    )
    # The user and the install path need not exist here; any other complaint is ours.
    complaints = [
        line for line in done.stderr.splitlines()
        if "sensor-agent" in line and "user" not in line.lower()
    ]  # fmt: skip
    assert done.returncode == 0 and not complaints, done.stderr
