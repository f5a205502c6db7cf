"""The head process's serial backend over a real pseudo-terminal: the firmware emulator
(`sensor-agent head-emulator --link`) on one side, the `head` process with
`backend = "serial"` (pyserial) on the other. Raw scans flow; the emulator killed, the head
says it is not streaming (mode fault, so the vector's sensor_ok is false) and counts the
port lost; the emulator back, it reconnects and the scans flow again."""

from __future__ import annotations

import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from agent.runtime import topics
from agent.runtime.messages import HeadState, Heartbeat, RawScan, decode
from tests.system.test_launch import Launch, listening

pytest.importorskip("serial")
ROOT = Path(__file__).resolve().parents[2]


def _emulator(link: Path) -> subprocess.Popen[str]:
    proc = subprocess.Popen(
        [sys.executable, "-m", "cli.main", "head-emulator", "--link", str(link),
         "--duration", "60"],
        cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    assert proc.stdout is not None
    assert proc.stdout.readline().startswith("/dev/")
    return proc


def _poll(bus, seconds: float) -> list[object]:  # type: ignore[no-untyped-def]
    got: list[object] = []
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        got += [decode(payload) for _, payload in bus.poll(0.05)]
    return got


def test_the_head_over_a_serial_line_reconnects(launch: Launch, short_dir: Path) -> None:
    link = short_dir / "head"
    graph_file = short_dir / "serial.toml"
    graph_file.write_text(
        '[graph]\nname = "serialhead"\nheartbeat_s = 0.5\n\n'
        '[[process]]\nname = "head"\nmodule = "processes.head"\n'
        'inputs = ["head_command"]\noutputs = ["raw_scan", "head_state"]\n'
        f'params = {{ backend = "serial", port = "{link}" }}\n\n'
        '[[external]]\nname = "planner"\nendpoint = "ipc://{runtime}/planner.pub"\n'
        'outputs = ["head_command"]\n'
    )
    emulator = _emulator(link)
    try:
        graph = launch(graph_file)
        with listening(
            (graph.endpoint("head"), topics.RAW_SCAN),
            (graph.endpoint("head"), topics.HEAD_STATE),
            (graph.endpoint("head"), topics.HEARTBEAT),
        ) as bus:
            got = _poll(bus, 6.0)
            scans = [x for x in got if isinstance(x, RawScan)]
            assert len(scans) >= 10, f"{len(scans)} raw scans in 6 s"
            assert scans[-1].time_s.size == 256
            states = [x for x in got if isinstance(x, HeadState)]
            assert states[-1].mode == "scanning" and states[-1].laser_on

            emulator.kill()
            emulator.wait(10)
            got = _poll(bus, 2.0)
            states = [x for x in got if isinstance(x, HeadState)]
            assert states and states[-1].mode == "fault", [s.command_message for s in states]
            beats = [x for x in got if isinstance(x, Heartbeat) and x.process == "head"]
            assert beats and beats[-1].counters["port_lost"] >= 1

            emulator = _emulator(link)
            got = _poll(bus, 6.0)
            assert sum(isinstance(x, RawScan) for x in got) >= 10
            beats = [x for x in got if isinstance(x, Heartbeat) and x.process == "head"]
            assert beats[-1].counters["reconnects"] >= 1
            assert beats[-1].counters["crc_errors"] == 0
    finally:
        emulator.kill()
        emulator.wait(10)


def test_the_closed_loop_runs_over_the_serial_link(launch: Launch, short_dir: Path) -> None:
    """launch/demo_serial.toml with the emulator taking the graph's true vehicle motion: the
    agent's vectors are trusted (sensor_ok) and the vehicle drives."""
    from agent.runtime.messages import EnvironmentVector, WorldTruth

    link = short_dir / "head"
    text = (ROOT / "launch" / "demo_serial.toml").read_text()
    text = text.replace('"../', f'"{ROOT}/').replace('"/tmp/lep-head"', f'"{link}"')
    graph_file = short_dir / "demo_serial.toml"
    graph_file.write_text(text)
    graph = launch(graph_file)
    emulator = subprocess.Popen(
        [sys.executable, "-m", "cli.main", "head-emulator", "--link", str(link),
         "--truth", graph.endpoint("world"), "--duration", "90"],
        cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    try:
        with listening(
            (graph.endpoint("planner"), topics.ENVIRONMENT),
            (graph.endpoint("world"), topics.WORLD_TRUTH),
        ) as bus:
            trusted = 0
            start_xy = None
            moved = 0.0
            deadline = time.monotonic() + 60.0
            while time.monotonic() < deadline and not (trusted >= 20 and moved > 0.2):
                for _, payload in bus.poll(0.1):
                    msg = decode(payload)
                    if isinstance(msg, EnvironmentVector) and msg.sensor_ok:
                        trusted += 1
                    elif isinstance(msg, WorldTruth):
                        xy = (msg.x_m, msg.y_m)
                        start_xy = start_xy or xy
                        moved = max(
                            moved, float(np.hypot(xy[0] - start_xy[0], xy[1] - start_xy[1]))
                        )
            assert trusted >= 20, f"{trusted} trusted vectors"
            assert moved > 0.2, f"the vehicle moved {moved:.2f} m"
    finally:
        emulator.kill()
        emulator.wait(10)
