"""A graph split over two hosts: tcp:// endpoints with CURVE, one launch file run per host.

Both "hosts" are launchers on this machine, on the loopback address; what crosses between
them goes over tcp with CURVE, exactly as between machines.
"""

from __future__ import annotations

import socket
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path

import pytest

from agent.runtime import topics
from agent.runtime.bus import Bus, CurveKeys
from tests.system.conftest import ROOT, RunningGraph

pytestmark = pytest.mark.timeout(90)


def _free_ports(n: int) -> list[int]:
    socks = [socket.socket() for _ in range(n)]
    for s in socks:
        s.bind(("127.0.0.1", 0))
    ports = [s.getsockname()[1] for s in socks]
    for s in socks:
        s.close()
    return ports


def _split_launch_file(tmp: Path, keys: Path) -> tuple[Path, list[int]]:
    ports = _free_ports(3)
    text = f"""
[graph]
name = "split"
keys_dir = "{keys}"

[[process]]
name = "world"
module = "processes.world"
host = "a"
inputs = ["wheel_command"]
outputs = ["world_truth"]
endpoint = "tcp://127.0.0.1:{ports[0]}"
params = {{ world = "{ROOT}/worlds/office.toml" }}

[[process]]
name = "head"
module = "processes.head"
host = "a"
inputs = ["head_command", "world_truth"]
outputs = ["raw_scan", "head_state"]
endpoint = "tcp://127.0.0.1:{ports[1]}"
params = {{ world = "{ROOT}/worlds/office.toml", seed = 2 }}

[[process]]
name = "calibration"
module = "processes.calibration"
host = "b"
inputs = ["raw_scan"]
outputs = ["calibrated_scan"]
endpoint = "tcp://127.0.0.1:{ports[2]}"

[[external]]
name = "controller"
endpoint = "ipc://{{runtime}}/controller.pub"
outputs = ["wheel_command", "head_command"]
"""
    path = tmp / "split.toml"
    path.write_text(text)
    return path, ports


def _keys(directory: Path) -> Path:
    done = subprocess.run(
        [sys.executable, "-m", "cli.main", "keys", str(directory)],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=30,
    )
    assert done.returncode == 0, done.stderr
    assert (directory / "server.key_secret").stat().st_mode & 0o077 == 0  # private
    return directory


def _received(endpoint: str, keys: Path, topic: str, seconds: float) -> int:
    bus = Bus(None, CurveKeys.load(keys))
    try:
        bus.subscriber.connect(endpoint)
        bus.subscriber.subscribe(topic)
        count = 0
        deadline = time.monotonic() + seconds
        while time.monotonic() < deadline:
            count += len(bus.poll(0.05))
        return count
    finally:
        bus.close()


def test_graph_split_over_two_hosts_with_curve(
    launch: Callable[..., RunningGraph], short_dir: Path
) -> None:
    keys = _keys(short_dir / "keys")
    path, ports = _split_launch_file(short_dir, keys)
    host_a = launch(path, "--host", "a", "--duration", "9")
    host_b = launch(path, "--host", "b", "--duration", "7")
    # An eavesdropper with the graph's keys hears the head; one with other keys hears nothing.
    head = f"tcp://127.0.0.1:{ports[1]}"
    assert _received(head, keys, topics.RAW_SCAN, 4.0) >= 5
    strangers = _keys(short_dir / "other-keys")
    assert _received(head, strangers, topics.RAW_SCAN, 1.5) == 0
    assert host_b.wait(40) == 0, host_b.stderr
    assert host_a.wait(40) == 0, host_a.stderr
    b, a = host_b.summary(), host_a.summary()
    assert set(b["processes"]) == {"calibration"} and set(a["processes"]) == {"world", "head"}
    # Raw scans crossed from host a to host b over tcp, and were calibrated there.
    assert b["processes"]["calibration"]["counters"]["scans"] >= 20
    assert 8 < b["topics"]["calibrated_scan"]["rate_hz"] < 12
    assert all(p["exit_code"] == 0 for p in (*a["processes"].values(), *b["processes"].values()))


def test_host_with_no_process_is_refused(short_dir: Path) -> None:
    path, _ = _split_launch_file(short_dir, short_dir)
    done = subprocess.run(
        [sys.executable, "-m", "cli.main", "launch", str(path), "--host", "c"],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=30,
    )
    assert done.returncode == 2 and "no process on host 'c'" in done.stderr
