"""The bench's realistic messages and its codec figures, on tiny counts (no sockets)."""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
import threading
import time

import pytest

from agent.runtime import topics
from agent.runtime.messages import decode
from cli import bench_pipeline
from cli.bench_codec import codec_figures, message_bytes
from cli.bench_messages import graph_messages, raw_scans
from cli.output import jsonable

GRAPH_TYPES = {
    "raw_scan", "calibrated_scan", "filtered_scan", "features",
    "vehicle_state", "head_command", "head_state", "heartbeat", "world_truth",
}  # fmt: skip


@pytest.fixture(scope="module")
def samples() -> dict[str, list]:
    return graph_messages(raw_scans(3))


def test_realistic_messages_cover_the_graph_and_survive_their_own_decoding(samples) -> None:
    assert set(samples) >= GRAPH_TYPES
    for topic in ("raw_scan", "calibrated_scan", "filtered_scan", "features"):
        assert [m.sweep_index for m in samples[topic]] == [0, 1, 2]
    for topic, msgs in samples.items():
        cls = topics.message_type(topic)
        for msg in msgs:
            assert isinstance(decode(msg.to_wire(), expect=cls), cls)
    # Real scans: a filtered scan of 256 samples dwarfs the small messages.
    sizes = message_bytes(samples)
    assert sizes["filtered_scan"] > 10_000 > 1_000 > sizes["head_command"]


def test_codec_figures_are_positive_finite_per_type(samples) -> None:
    figures = codec_figures(samples, calls=5)
    assert set(figures) == set(samples)
    for topic, us in figures.items():
        assert set(us) == {"encode", "decode"}, topic
        assert all(math.isfinite(v) and v > 0 for v in us.values()), (topic, us)
    json.dumps(jsonable(figures), allow_nan=False)


def test_codec_figures_refuse_no_calls(samples) -> None:
    with pytest.raises(ValueError, match="calls"):
        codec_figures(samples, calls=0)


@pytest.mark.parametrize(
    ("flag", "value"), [("--hop-round-trips", "0"), ("--codec-calls", "0"), ("--hop-warm-up", "-1")]
)
def test_bench_refuses_counts_it_cannot_measure_with(flag: str, value: str, capsys) -> None:
    from cli.main import main

    assert main(["bench", flag, value]) == 2
    assert flag in capsys.readouterr().err


class _SilentGraph:
    """A graph that takes scans and never answers: one process of it busy, one idle, one
    gone (its pid no longer running)."""

    class _Bus:
        def publish(self, topic: str, payload: bytes) -> None:
            pass

        def poll(self, timeout_s: float) -> list:
            time.sleep(timeout_s)
            return []

    def __init__(self, busy_pid: int, gone_pid: int) -> None:
        self.proc = type("Proc", (), {"pid": os.getpid()})()
        self._pids = {"tracking": busy_pid, "planner": os.getpid(), "features": gone_pid}

    def listen(self) -> _Bus:
        return self._Bus()

    def pids(self) -> dict[str, int]:
        return {**self._pids, "launcher": self.proc.pid}

    def log_tail(self) -> str:
        return "(no log output)"


def test_a_graph_that_stops_answering_names_who_worked_since_its_last_output(
    monkeypatch,
) -> None:
    """The saturated bench gives up after its reply timeout, saying how many scans came
    back and each process's CPU since the last output: a busy one (stuck in its work), idle
    ones (waiting for lost messages), a gone one (replaced)."""
    scans = raw_scans(1)
    busy = subprocess.Popen([sys.executable, "-c", "while True: pass"])
    # Gone before the bench gives up (reaped, so that its pid is no process's).
    gone = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(0.3)"])
    threading.Thread(target=gone.wait, daemon=True).start()
    try:
        monkeypatch.setattr(bench_pipeline, "REPLY_TIMEOUT_S", 2.0)
        driver = bench_pipeline._Driver(_SilentGraph(busy.pid, gone.pid), scans)
        with pytest.raises(RuntimeError) as err:
            driver.closed_loop(4, 2)
    finally:
        busy.kill()
        busy.wait()
    message = str(err.value)
    assert message.startswith("the agent graph returned 0 of 2 scans; CPU s since its last")
    cpu = dict(
        part.rsplit(" ", 1) for part in message.split("output: ")[1].split(" (")[0].split(", ")
    )
    assert cpu["features"] == "gone"
    assert float(cpu["tracking"]) > 0.2 and float(cpu["planner"]) < float(cpu["tracking"])
