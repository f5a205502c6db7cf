"""The bench's hop measurement between two real processes, and the whole command, run short.

They check what the figures are made of (every type, finite, ordered), never how fast:
benchmarks print figures, tests do not time them.
"""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
from pathlib import Path

import pytest

from cli.bench_hop import EchoProcess, hop_figures
from cli.bench_messages import graph_messages, raw_scans
from cli.output import jsonable
from tests.system.conftest import ROOT

pytestmark = pytest.mark.timeout(180)


def children() -> set[int]:
    """Pids whose parent is this process, zombies included (an exited, unreaped echo)."""
    found = set()
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                stat = (entry / "stat").read_text()
            except OSError:
                continue
            if int(stat.rsplit(")", 1)[1].split()[1]) == os.getpid():
                found.add(int(entry.name))
    return found


def processes_mentioning(text: str) -> list[int]:
    found = []
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                if text.encode() in (entry / "cmdline").read_bytes():
                    found.append(int(entry.name))
            except OSError:
                continue
    return found


@pytest.fixture(scope="module")
def samples() -> dict[str, list]:
    return graph_messages(raw_scans(3))


def test_hop_figures_cover_every_type_and_leave_no_echo(samples) -> None:
    before = children()
    figures = hop_figures(samples, round_trips=20, warm_up=2)
    assert children() - before == set()
    assert set(figures) == {*samples, "transport"}
    for topic, us in figures.items():
        p50, p99 = us["p50"], us["p99"]
        assert isinstance(p50, float) and isinstance(p99, float)
        assert math.isfinite(p50) and math.isfinite(p99), topic
        assert 0 < p50 <= p99, (topic, us)
    sizes = {t: max(len(m.to_wire()) for m in msgs) for t, msgs in samples.items()}
    assert figures["transport"]["message"] == max(sizes, key=lambda t: sizes[t])
    assert figures["transport"]["bytes"] == max(sizes.values())
    json.dumps(jsonable(figures), allow_nan=False)


def test_hop_stops_the_echo_when_a_message_is_not_echoed(samples) -> None:
    # A head_state sent on raw_scan: the echo refuses it, so no reply comes back.
    before = children()
    with pytest.raises(RuntimeError, match="no echo of a raw_scan"):
        hop_figures({"raw_scan": samples["head_state"]}, 1, 0, reply_timeout_s=0.5)
    assert children() - before == set()


def test_an_echo_that_cannot_start_is_reported_and_reaped() -> None:
    before = children()
    with pytest.raises(RuntimeError, match=r"echo process exited .*no_such_topic"):
        EchoProcess(["no_such_topic"])
    assert children() - before == set()


@pytest.mark.slow
def test_bench_command_writes_every_figure_and_leaves_nothing_running(tmp_path: Path) -> None:
    out = tmp_path / "bench.json"
    tmp = tmp_path / "t"  # every temporary directory (and so every socket) of the run
    tmp.mkdir()
    tiny = ["--scans", "2", "--pipeline-scans", "20", "--latency-scans", "3"]
    tiny += ["--cpu-seconds", "0.5", "--codec-calls", "3", "--hop-round-trips", "3"]
    tiny += ["--hop-warm-up", "1"]
    run = subprocess.run(
        [sys.executable, "-m", "cli.main", "bench", *tiny, "--json", str(out)],
        cwd=ROOT,
        env={**os.environ, "TMPDIR": str(tmp)},
        capture_output=True,
        text=True,
        timeout=170,
    )
    assert run.returncode == 0, run.stderr
    assert processes_mentioning(str(tmp)) == []
    assert not list(tmp.glob("lepb*"))
    figures = json.loads(out.read_text())
    assert {"pipeline", "latency_ms", "cpu_percent", "hop_us", "codec_us"} <= set(figures)
    pipe = figures["pipeline"]
    for key in ("in_process_scans_per_s", "multi_process_scans_per_s", "multi_to_in_process"):
        assert pipe[key] > 0, key
    assert pipe["stages"] == ["calibration", "filtering", "features", "tracking", "planner"]
    assert pipe["final_topics"] == ["environment", "head_command"]
    for key in (
        "latency_ms",
        "latency_ms_in_process",
        "latency_ms_to_environment",
        "latency_ms_to_environment_in_process",
    ):
        lat = figures[key]
        assert lat["of"] == 3 and 0 < lat["scans"] <= 3
        assert 0 < lat["p50"] <= lat["p99"] <= lat["max"]
    cpu = figures["cpu_percent"]
    graph = ["world", "head", "calibration", "filtering", "features", "tracking", "planner"]
    assert set(cpu) == {*graph, "launcher", "total", "total_with_launcher"}
    assert all(cpu[name] >= 0 for name in cpu)
    assert cpu["total"] == pytest.approx(sum(cpu[n] for n in graph))
    assert cpu["total_with_launcher"] == pytest.approx(cpu["total"] + cpu["launcher"])
    assert set(figures["hop_us"]) == {*figures["codec_us"], "transport"}
    assert "hop between two processes" in run.stdout
