"""Recording the bus to MCAP (``launch --record``), reading it back, and ``replay``."""

from __future__ import annotations

import re
import shutil
import subprocess
import sys
import tempfile
from collections import Counter
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest
from mcap.reader import make_reader

from agent.errors import ConfigError
from agent.runtime import topics
from agent.runtime.bus import Bus
from agent.runtime.launch import load_launch
from agent.runtime.messages import Heartbeat, decode
from agent.runtime.recording import RecordedMessage, Recorder, read_recording
from processes.launcher import live_pids
from tests.system.conftest import ROOT, RunningGraph, graph_pids, wait_for

pytestmark = pytest.mark.timeout(60)
Launch = Callable[..., RunningGraph]


def sensor_agent(*args: str, timeout_s: float = 30) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "cli.main", *args],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=timeout_s,
    )


@dataclass
class SimRecording:
    path: Path
    summary: dict[str, Any]
    messages: list[RecordedMessage]


@pytest.fixture(scope="module")
def sim_recording() -> Iterator[SimRecording]:
    """Eight seconds of the sensor graph (2.5-5 s of them starting up, by the load), recorded."""
    d = Path(tempfile.mkdtemp(prefix="lep"))
    graph = RunningGraph(
        ROOT / "launch/sensor.toml",
        d / "rt",
        d / "s.json",
        ["--duration", "8", "--record", str(d / "sim.mcap")],
    )
    try:
        assert graph.wait(40) == 0, graph.stderr
        assert graph_pids(graph.runtime_dir) == []
        yield SimRecording(d / "sim.mcap", graph.summary(), list(read_recording(d / "sim.mcap")))
    finally:
        graph.kill_all()
        shutil.rmtree(d, ignore_errors=True)


# ------------------------------------------------------------------------------ recording
def test_recording_holds_every_message_the_launcher_counted(sim_recording: SimRecording) -> None:
    messages = sim_recording.messages
    counts = Counter(m.topic for m in messages)
    expected = {t: s["count"] for t, s in sim_recording.summary["topics"].items()}
    assert set(counts) == {
        "raw_scan",
        "calibrated_scan",
        "filtered_scan",
        "features",
        "world_truth",
        "odometry",
        "head_state",
        "heartbeat",
    }
    assert counts == expected
    # Recording, the launcher hears every topic: counts and gaps are its own.
    for stats in sim_recording.summary["topics"].values():
        assert stats["counted_from"] == "bus" and stats["max_gap_s"] >= 0, stats
    assert counts["raw_scan"] >= 15 and counts["world_truth"] >= 30  # 10 Hz and 20 Hz
    for m in messages:
        msg = decode(m.payload, expect=topics.message_type(m.topic))
        assert msg.header.source  # stamped by a process
    times = [m.log_time_ns for m in messages]
    assert times == sorted(times)
    assert 0.5 < (times[-1] - times[0]) * 1e-9 < 9.0  # within the 8 s run


def test_recording_layout(sim_recording: SimRecording) -> None:
    with sim_recording.path.open("rb") as f:
        reader = make_reader(f)
        header = reader.get_header()
        summary = reader.get_summary()
        assert summary is not None
    assert header.profile == "lep-sensor-agent"
    assert header.library.startswith("lep-sensor-agent ")
    for channel in summary.channels.values():
        assert channel.message_encoding == "msgpack"
        cls = topics.TOPIC_TYPES[channel.topic]
        assert summary.schemas[channel.schema_id].name == f"{cls.TYPE}/{cls.VERSION}"
    assert len({c.topic for c in summary.channels.values()}) == len(summary.channels)
    assert summary.statistics is not None
    assert summary.statistics.message_count == len(sim_recording.messages)


def test_recorder_keeps_bytes_and_odd_topics(tmp_path: Path) -> None:
    path = tmp_path / "sub" / "r.mcap"
    with Recorder(path) as rec:
        rec.write("raw_scan", b"\x81\xa4type\xa0", 200)
        rec.write("", b"\x00garbage\xff", 300)  # malformed traffic: topic ""
        rec.write("raw_scan", b"", 250)  # a clock that stepped back
        rec.write("head_state", bytes(range(256)), 400)
    got = list(read_recording(path))
    assert got == [
        RecordedMessage("raw_scan", b"\x81\xa4type\xa0", 200),
        RecordedMessage("", b"\x00garbage\xff", 300),
        RecordedMessage("raw_scan", b"", 300),
        RecordedMessage("head_state", bytes(range(256)), 400),
    ]
    with path.open("rb") as f:
        summary = make_reader(f).get_summary()
    assert summary is not None
    by_topic = {c.topic: c for c in summary.channels.values()}
    assert set(by_topic) == {"raw_scan", "", "head_state"}
    assert by_topic[""].schema_id == 0  # no schema for a topic outside the registry
    assert summary.schemas[by_topic["raw_scan"].schema_id].name == "raw_scan/1"


def test_bad_recordings_are_config_errors(tmp_path: Path, sim_recording: SimRecording) -> None:
    not_mcap = tmp_path / "notes.mcap"
    not_mcap.write_text("hello\n")
    for path in (not_mcap, tmp_path / "missing.mcap", tmp_path):
        with pytest.raises(ConfigError, match=str(path)) as info:
            read_recording(path)
        assert "\n" not in str(info.value)
    cut = tmp_path / "cut.mcap"
    data = sim_recording.path.read_bytes()
    cut.write_bytes(data[: len(data) // 2])
    with pytest.raises(ConfigError, match="cut short"):
        list(read_recording(cut))


# --------------------------------------------------------------------------------- replay
def _listen(endpoint: str, *names: str) -> Bus:
    bus = Bus(None)
    bus.subscriber.connect(endpoint)
    for name in names:
        bus.subscriber.subscribe(name)
    return bus


def test_replay_into_the_agent_graph_makes_calibrated_scans(
    launch: Launch, sim_recording: SimRecording
) -> None:
    replayed = [m for m in sim_recording.messages if m.topic in ("raw_scan", "head_state")]
    n_raw = sum(m.topic == "raw_scan" for m in replayed)
    graph = launch("launch/agent.toml")
    n = len(load_launch(ROOT / "launch/agent.toml").processes)
    wait_for(lambda: len(live_pids(graph.runtime_dir)) == n, 20, "the agent's processes")
    bus = _listen(graph.endpoint("calibration"), topics.HEARTBEAT)
    try:
        done = sensor_agent(
            "replay", str(sim_recording.path), "--graph", str(graph.runtime_dir), "--speed", "4"
        )
        assert done.returncode == 0, done.stderr
        out = done.stdout
        assert re.search(rf"^ +raw_scan +{n_raw} msgs -> {graph.endpoint('head')}$", out, re.M)
        skipped = next(line for line in out.splitlines() if line.startswith("skipping"))
        assert "world_truth" in skipped and "calibrated_scan" in skipped
        assert "not replaying heartbeat" in out
        # The recorded spacing, divided by the speed.
        took, span = map(float, re.findall(r"in ([\d.]+) s \(recording span ([\d.]+) s", out)[0])
        span_replayed = (replayed[-1].log_time_ns - replayed[0].log_time_ns) * 1e-9
        assert span == pytest.approx(span_replayed, abs=0.01)
        assert span / 4 - 0.02 < took < span / 4 + 0.5

        def calibrated_all() -> bool:
            for _, payload in bus.poll(0.1):
                beat = decode(payload, expect=Heartbeat)
                assert isinstance(beat, Heartbeat)
                counters = beat.counters
                if counters.get("scans", 0) + counters.get("stale_dropped", 0) >= n_raw:
                    return True
            return False

        # Each scan is calibrated, or dropped unread as stale backlog when it queued behind a
        # newer one (at 4x speed, while the process starts): none is lost or counted twice.
        wait_for(calibrated_all, 10, f"calibration to account for {n_raw} scans")
    finally:
        bus.close()
    assert graph.stop() == 0, graph.stderr
    summary = graph.summary()
    counters = summary["processes"]["calibration"]["counters"]
    assert counters["scans"] + counters["stale_dropped"] == n_raw
    assert counters["scans"] >= 1
    assert counters["scans"] - 2 <= summary["topics"]["calibrated_scan"]["count"] <= n_raw
    assert graph_pids(graph.runtime_dir) == []


def test_replay_to_an_endpoint_is_byte_for_byte(sim_recording: SimRecording) -> None:
    chosen = ("raw_scan", "head_state", "heartbeat")
    expected = [(m.topic, m.payload) for m in sim_recording.messages if m.topic in chosen]
    d = Path(tempfile.mkdtemp(prefix="lep"))
    endpoint = f"ipc://{d}/replay.pub"
    bus = _listen(endpoint, *chosen)
    proc = subprocess.Popen(
        [sys.executable, "-m", "cli.main", "replay", str(sim_recording.path),
         "--endpoint", endpoint, "--topics", *chosen, "--speed", "0", "--wait", "20"],
        cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    try:
        got: list[tuple[str, bytes]] = []

        def all_arrived() -> bool:
            got.extend(bus.poll(0.1))
            return len(got) >= len(expected)

        wait_for(all_arrived, 20, f"{len(expected)} replayed messages")
        out, err = proc.communicate(timeout=20)
    finally:
        bus.close()
        if proc.poll() is None:
            proc.kill()
            proc.communicate(timeout=10)
        shutil.rmtree(d, ignore_errors=True)
    assert proc.returncode == 0, err
    assert got == expected
    assert "as fast as possible" in out and "not replaying" not in out
