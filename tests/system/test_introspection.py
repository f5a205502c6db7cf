"""``topics``, ``echo``, ``hz`` against a live simulated graph; their errors; bad replays."""

from __future__ import annotations

import json
import os
import queue
import re
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
from collections.abc import Iterator
from pathlib import Path

import pytest

from agent.runtime import topics
from agent.runtime.recording import Recorder
from cli.introspect import RateWindow, echo_line
from cli.main import main
from tests.system.conftest import ROOT, RunningGraph, graph_pids

pytestmark = pytest.mark.timeout(60)


def sensor_agent(
    *args: str, env: dict[str, str] | None = None, timeout_s: float = 30
) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "cli.main", *args],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=timeout_s,
        env=env,
    )


def one_line_error(done: subprocess.CompletedProcess[str]) -> str:
    assert done.returncode == 2, (done.stdout, done.stderr)
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("sensor-agent: "), done.stderr
    return lines[0]


def in_process(capsys: pytest.CaptureFixture[str], *args: str) -> str:
    """Run the command in this process (no interpreter start-up); return its one-line error."""
    capsys.readouterr()
    status = main(list(args))
    captured = capsys.readouterr()
    return one_line_error(subprocess.CompletedProcess(args, status, captured.out, captured.err))


@pytest.fixture(scope="module")
def sim() -> Iterator[RunningGraph]:
    """The simulated graph, running (raw scans flowing) for the whole module."""
    d = Path(tempfile.mkdtemp(prefix="lep"))
    graph = RunningGraph(ROOT / "launch/sensor.toml", d / "rt", d / "s.json", [])
    try:
        graph.wait_for_first("head", topics.RAW_SCAN, "the first raw scan")
        yield graph
        assert graph.stop() == 0, graph.stderr
        assert graph_pids(graph.runtime_dir) == []
    finally:
        graph.kill_all()
        shutil.rmtree(d, ignore_errors=True)


# ------------------------------------------------------------------------------ live graph
def test_topics_lists_the_graph_with_rates(sim: RunningGraph) -> None:
    done = sensor_agent("topics", "--graph", str(sim.runtime_dir))
    assert done.returncode == 0, done.stderr
    listing, processes = done.stdout.split("\n\n")
    rows = {line.split()[0]: line for line in listing.splitlines()[2:]}
    states = {line.split()[0]: line.split()[1] for line in processes.splitlines()[1:]}
    assert states == dict.fromkeys(("world", "head", "calibration", "filtering", "features"),
                                   "running")  # fmt: skip
    assert set(rows) >= {
        "world_truth", "raw_scan", "head_state", "calibrated_scan", "wheel_command",
        "head_command", "heartbeat", "stop",
    }  # fmt: skip

    def rate(topic: str) -> float:
        match = re.match(rf"{topic} +{topic}/\d+ +([\d.]+) Hz ", rows[topic])
        assert match, rows[topic]
        return float(match.group(1))

    assert 7 < rate("raw_scan") < 13
    assert 16 < rate("world_truth") < 24  # launch/sensor.toml: 20 Hz
    assert 16 < rate("odometry") < 24  # published with world_truth
    assert 7 < rate("calibrated_scan") < 13
    head = rows["raw_scan"].split()
    assert head[4:] == ["head", sim.endpoint("head"), "calibration"]
    assert "- (0 msgs)" in rows["wheel_command"] and "controller" in rows["wheel_command"]


def test_topics_json(sim: RunningGraph) -> None:
    done = sensor_agent("topics", "--graph", str(sim.runtime_dir), "--listen", "0.5", "--json")
    assert done.returncode == 0, done.stderr
    listing = json.loads(done.stdout)
    assert listing["graph"] == "sensor" and listing["runtime_dir"] == str(sim.runtime_dir)
    by_topic = {row["topic"]: row for row in listing["topics"]}
    assert by_topic["world_truth"]["subscribers"] == ["head"]
    assert 16 < by_topic["world_truth"]["rate_hz"] < 24
    assert set(listing["processes"]) == {"world", "head", "calibration", "filtering", "features"}
    for process in listing["processes"].values():
        assert process["state"] in ("running", "starting") and process["pid"] > 0


def test_echo_prints_count_lines(sim: RunningGraph) -> None:
    done = sensor_agent("echo", "raw_scan", "--count", "2", "--graph", str(sim.runtime_dir))
    assert done.returncode == 0, done.stderr
    lines = done.stdout.splitlines()
    assert len(lines) == 2
    for line in lines:
        assert re.match(r"raw_scan seq=\d+ source=head stamp=\d+\.\d{9} frame=head ", line), line
        assert re.search(r" mirror_angle_rad\[256\] -?[\d.e-]+\.\.[\d.e-]+ ", line), line
        assert " direction=" in line and " sweep_index=" in line


def test_echo_json_has_the_fields(sim: RunningGraph) -> None:
    done = sensor_agent(
        "echo", "raw_scan", "--count", "1", "--json", "--graph", str(sim.runtime_dir)
    )
    assert done.returncode == 0, done.stderr
    lines = done.stdout.splitlines()
    assert len(lines) == 1
    msg = json.loads(lines[0])
    assert msg["topic"] == "raw_scan" and msg["type"] == "raw_scan/1"
    assert msg["header"]["source"] == "head" and msg["header"]["frame_id"] == "head"
    arrays = ("time_s", "mirror_angle_rad", "pan_rad", "current_1_A", "current_2_A")
    for name in arrays:
        assert len(msg[name]) == len(msg["time_s"]) > 0
    assert msg["direction"] in (-1, 1) and isinstance(msg["sweep_index"], int)


def test_echo_stops_cleanly_on_ctrl_c(sim: RunningGraph) -> None:
    proc = subprocess.Popen(
        [sys.executable, "-m", "cli.main", "echo", "world_truth", "--graph", str(sim.runtime_dir)],
        cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    lines: queue.Queue[str] = queue.Queue()
    assert proc.stdout is not None
    reader = threading.Thread(target=lambda: [lines.put(line) for line in proc.stdout or ()])
    reader.start()
    try:
        first = lines.get(timeout=15)
        assert first.startswith("world_truth seq=")
        proc.send_signal(signal.SIGINT)
        assert proc.wait(timeout=10) == 0
    finally:
        if proc.poll() is None:
            proc.kill()
        proc.wait(timeout=10)
        reader.join(timeout=10)
    assert proc.stderr is not None
    assert proc.stderr.read() == ""


def test_hz_measures_the_rate(sim: RunningGraph) -> None:
    done = sensor_agent("hz", "world_truth", "--duration", "2.5", "--graph", str(sim.runtime_dir))
    assert done.returncode == 0, done.stderr
    lines = done.stdout.splitlines()
    assert 2 <= len(lines) <= 4, lines
    match = re.match(
        r"world_truth: rate ([\d.]+) Hz  period mean ([\d.]+) s  min ([\d.]+) s  "
        r"max ([\d.]+) s  n (\d+) ",
        lines[-1],
    )
    assert match, lines[-1]
    rate, mean, low, high, n = map(float, match.groups())
    assert 16 < rate < 24  # launch/sensor.toml publishes world_truth at 20 Hz
    assert low <= mean <= high
    assert 28 < n < 64


# ---------------------------------------------------------------------------------- errors
def test_unknown_topic_is_one_line(sim: RunningGraph, capsys: pytest.CaptureFixture[str]) -> None:
    line = one_line_error(sensor_agent("echo", "nosuchtopic", "--graph", str(sim.runtime_dir)))
    assert "unknown topic 'nosuchtopic'" in line and "raw_scan" in line
    line = in_process(capsys, "hz", "nosuchtopic")
    assert "unknown topic 'nosuchtopic'" in line and "raw_scan" in line
    line = in_process(capsys, "echo", "tracks", "--graph", str(sim.runtime_dir))
    assert "does not publish 'tracks'" in line


def test_no_running_graph_is_one_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    recording = tmp_path / "r.mcap"
    with Recorder(recording) as rec:
        rec.write("raw_scan", b"\x80", 1)
    empty = tmp_path / "xdg"
    empty.mkdir(mode=0o700)
    env = {**os.environ, "XDG_RUNTIME_DIR": str(empty)}  # an empty graph registry
    line = one_line_error(sensor_agent("topics", env=env))
    assert "no running graph" in line
    monkeypatch.setenv("XDG_RUNTIME_DIR", str(empty))
    for args in (
        ["echo", "raw_scan"],
        ["hz", "raw_scan", "--duration", "1"],
        ["replay", str(recording)],
    ):
        line = in_process(capsys, *args)
        assert "no running graph" in line, args
    monkeypatch.undo()
    line = in_process(capsys, "topics", "--graph", "no-such-graph")
    assert "no running graph 'no-such-graph'" in line


def test_replay_of_a_file_that_is_not_mcap_is_one_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    bad = tmp_path / "notes.mcap"
    bad.write_text("not a recording\n")
    line = one_line_error(sensor_agent("replay", str(bad), "--endpoint", "ipc:///tmp/lep-x.pub"))
    assert str(bad) in line and "not an MCAP file" in line
    line = in_process(capsys, "replay", str(tmp_path / "missing.mcap"))
    assert "missing.mcap" in line


def test_replay_of_a_topic_not_recorded_is_one_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    recording = tmp_path / "r.mcap"
    with Recorder(recording) as rec:
        rec.write("raw_scan", b"\x80", 1)
    line = in_process(
        capsys, "replay", str(recording), "--endpoint", "ipc:///tmp/x", "--topics", "tracks"
    )
    assert "no messages on 'tracks'" in line and "raw_scan" in line


# ------------------------------------------------------------------------ output formats
GOLDEN = ROOT / "tests" / "data" / "golden"


def test_echo_lines_of_arrays_with_nan() -> None:
    payload = (GOLDEN / "calibrated_scan.msgpack").read_bytes()
    line = echo_line("calibrated_scan", payload)
    assert line.startswith("calibrated_scan seq=41 source=calibration stamp=1767225600.125000000")
    assert re.search(r" range_m\[256\] [\d.]+\.\.[\d.]+ \(\d+ nan\) ", line)
    assert " direction=-1 " in line and "\n" not in line
    obj = json.loads(echo_line("calibrated_scan", payload, as_json=True))
    assert obj["type"] == "calibrated_scan/1" and obj["header"]["seq"] == 41
    assert len(obj["range_m"]) == 256 and None in obj["range_m"]  # NaN as null


def test_echo_lines_of_malformed_messages() -> None:
    line = echo_line("raw_scan", b"\x93\x01")
    assert line.startswith("raw_scan: dropped a message of 2 bytes: ") and "[truncated]" in line
    wrong = (GOLDEN / "heartbeat.msgpack").read_bytes()
    obj = json.loads(echo_line("raw_scan", wrong, as_json=True))
    assert obj["kind"] == "unknown_type" and "heartbeat/1" in obj["dropped"]


def test_rate_window() -> None:
    window = RateWindow(2.0)
    assert window.line("t") == "t: 0 messages in the last 2 s"
    for i in range(31):
        window.add(10.0 + 0.1 * i)  # 10 Hz for 3 s
    window.trim(13.0)
    assert re.match(
        r"t: rate 10\.00 Hz  period mean 0\.1000 s  min 0\.1000 s  max 0\.1000 s  n 21 ",
        window.line("t"),
    )
