"""The head process's serial backend over a real pseudo-terminal: the firmware emulator
(`sensor-agent head-emulator --link`) on one side, the `head` process with
`backend = "serial"` (pyserial) on the other. Raw scans flow; the emulator killed, the head
says it is not streaming (mode fault, so the vector's sensor_ok is false) and counts the
port lost; the emulator back, it reconnects and the scans flow again. The closed loop runs
over the link, and stops the vehicle when the head stops answering."""

from __future__ import annotations

import math
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from agent.runtime import topics
from agent.runtime.messages import (
    EnvironmentVector,
    HeadState,
    Heartbeat,
    RawScan,
    WheelCommand,
    decode,
)
from tests.system.conftest import RunningGraph
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


def _closed_loop_over_the_emulator(
    launch: Launch, short_dir: Path, *emulator_args: str
) -> tuple[RunningGraph, subprocess.Popen[str]]:
    """launch/demo_serial.toml over the emulator, which takes the graph's true motion."""
    link = short_dir / "head"
    text = (ROOT / "launch" / "demo_serial.toml").read_text()
    text = text.replace('"../', f'"{ROOT}/').replace('"/tmp/lep-head"', f'"{link}"')
    graph_file = short_dir / "demo_serial.toml"
    graph_file.write_text(text)
    graph = launch(graph_file)
    emulator = subprocess.Popen(
        [sys.executable, "-m", "cli.main", "head-emulator", "--link", str(link),
         "--truth", graph.endpoint("world"), "--duration", "90", *emulator_args],
        cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    return graph, emulator


def test_the_closed_loop_runs_over_the_serial_link(launch: Launch, short_dir: Path) -> None:
    """launch/demo_serial.toml with the emulator taking the graph's true vehicle motion: the
    agent's vectors are trusted (sensor_ok) and the vehicle drives."""
    from agent.runtime.messages import WorldTruth

    graph, emulator = _closed_loop_over_the_emulator(launch, short_dir)
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


SILENT_AT_S = 12.0  # on the emulator's clock: trusted vectors and a driving vehicle by then
STOP_WITHIN_S = 0.5


def test_a_head_that_stops_answering_stops_the_vehicle(launch: Launch, short_dir: Path) -> None:
    """The closed loop over the link with the head going silent (``silent@T``): the head
    process's head_state turns fault, the vector's sensor_ok false, the wheel command zero
    within 0.5 s of the last trusted vector's validity running out, and the head process
    counts the silent head; all by the messages' stamps."""
    graph, emulator = _closed_loop_over_the_emulator(
        launch, short_dir, "--faults", f"silent@{SILENT_AT_S}"
    )
    vectors: list[EnvironmentVector] = []
    commands: list[WheelCommand] = []
    states: list[HeadState] = []
    beats: list[Heartbeat] = []

    def settled() -> bool:  # 3 s of commands after the first untrusted vector after trust
        trusted = [v.header.stamp_s for v in vectors if v.sensor_ok]
        untrusted = [v.header.stamp_s for v in vectors if trusted and not v.sensor_ok
                     and v.header.stamp_s > trusted[-1]]  # fmt: skip
        return bool(untrusted and commands and commands[-1].header.stamp_s > untrusted[0] + 3)

    try:
        with listening(
            (graph.endpoint("planner"), topics.ENVIRONMENT),
            (graph.endpoint("vehicle"), topics.WHEEL_COMMAND),
            (graph.endpoint("head"), topics.HEAD_STATE),
            (graph.endpoint("head"), topics.HEARTBEAT),
        ) as bus:
            deadline = time.monotonic() + 45.0
            while time.monotonic() < deadline and not settled():
                for _, payload in bus.poll(0.1):
                    msg = decode(payload)
                    if isinstance(msg, EnvironmentVector):
                        vectors.append(msg)
                    elif isinstance(msg, WheelCommand):
                        commands.append(msg)
                    elif isinstance(msg, HeadState):
                        states.append(msg)
                    elif isinstance(msg, Heartbeat) and msg.process == "head":
                        beats.append(msg)
    finally:
        emulator.kill()
        emulator.wait(10)
    trusted = [v for v in vectors if v.sensor_ok]
    assert trusted, f"no trusted vector in {len(vectors)} before the head went silent"
    last = trusted[-1]
    valid_until = last.header.stamp_s + last.valid_for_s
    moving = [c for c in commands if c.speed_m_s != 0.0 or c.yaw_rate_rad_s != 0.0]
    assert moving and moving[0].header.stamp_s < last.header.stamp_s, "never drove"
    assert settled(), "the vectors never turned untrusted"
    # After the last trusted vector: every vector untrusted, every head_state fault.
    after = [v for v in vectors if v.header.stamp_s > last.header.stamp_s]
    assert after and not any(v.sensor_ok for v in after)
    late_states = [s for s in states if s.header.stamp_s > valid_until]
    assert late_states and all(s.mode == "fault" and not s.laser_on for s in late_states)
    # The wheel command: zero from at most 0.5 s after the validity ran out, and ever after.
    stopped_at = next(
        (c.header.stamp_s for k, c in enumerate(commands)
         if all(d.speed_m_s == 0.0 and d.yaw_rate_rad_s == 0.0 for d in commands[k:])),
        math.inf,
    )  # fmt: skip
    assert stopped_at <= valid_until + STOP_WITHIN_S, (stopped_at - valid_until, len(commands))
    assert commands[-1].header.stamp_s - valid_until >= 2.0  # and seen zero for 2 s on
    # Two seconds without a frame: the head process says so and counts it.
    assert "the head is not answering" in states[-1].command_message, states[-1].command_message
    assert beats and beats[-1].counters["head_silent"] == 1
