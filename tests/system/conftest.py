"""Fixtures for system tests: real launcher processes, real sockets, explicit timeouts."""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest

from processes.launcher import live_pids, process_ids

ROOT = Path(__file__).resolve().parents[2]


def wait_for(
    condition: Callable[[], Any], timeout_s: float, what: str, interval_s: float = 0.05
) -> Any:
    """Poll ``condition`` until it returns something truthy; fail naming ``what``."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        value = condition()
        if value:
            return value
        time.sleep(interval_s)
    pytest.fail(f"timed out after {timeout_s:g} s waiting for {what}")


def graph_pids(runtime_dir: Path) -> list[int]:
    """Pids of every process started for the graph whose runtime directory this is."""
    return process_ids(runtime_dir)


def child_pid(runtime_dir: Path, name: str) -> int | None:
    """The live process's pid (not its standby's), from the launcher's ``pids.json``."""
    return live_pids(runtime_dir).get(name)


class RunningGraph:
    """``sensor-agent launch`` in a subprocess, with a private runtime directory."""

    def __init__(
        self, launch_file: Path, runtime_dir: Path, summary: Path, extra: list[str]
    ) -> None:
        self.runtime_dir = runtime_dir
        self.summary_path = summary
        cmd = [
            sys.executable,
            "-m",
            "cli.main",
            "launch",
            str(launch_file),
            "--runtime-dir",
            str(runtime_dir),
            "--json",
            str(summary),
            *extra,
        ]
        self.proc = subprocess.Popen(
            cmd, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
        )
        self.stdout = ""
        self.stderr = ""

    def endpoint(self, name: str) -> str:
        return f"ipc://{self.runtime_dir}/{name}.pub"

    def wait_for_first(self, publisher: str, topic: str, what: str, timeout_s: float = 30) -> None:
        """Until ``publisher``'s first message on ``topic`` arrives (``what`` in the failure)."""
        from agent.runtime.bus import Bus

        bus = Bus(None)
        try:
            bus.subscriber.connect(self.endpoint(publisher))
            bus.subscriber.subscribe(topic)
            wait_for(lambda: bus.poll(0.1), timeout_s, what)
        finally:
            bus.close()

    def wait(self, timeout_s: float = 30.0) -> int:
        self.stdout, self.stderr = self.proc.communicate(timeout=timeout_s)
        return self.proc.returncode

    def stop(self, sig: int = signal.SIGINT, timeout_s: float = 20.0) -> int:
        if self.proc.poll() is None:
            self.proc.send_signal(sig)
        return self.wait(timeout_s)

    def summary(self) -> dict[str, Any]:
        result: dict[str, Any] = json.loads(self.summary_path.read_text())
        return result

    def kill_all(self) -> None:
        if self.proc.poll() is None:
            self.proc.kill()
            self.proc.communicate(timeout=10)
        for pid in graph_pids(self.runtime_dir):
            with contextlib.suppress(OSError):
                os.kill(pid, signal.SIGKILL)


@pytest.fixture
def short_dir() -> Iterator[Path]:
    """A short private directory under /tmp: ipc:// paths must stay under ~100 bytes."""
    d = Path(tempfile.mkdtemp(prefix="lep"))
    try:
        yield d
    finally:
        shutil.rmtree(d, ignore_errors=True)


@pytest.fixture
def launch(short_dir: Path) -> Iterator[Callable[..., RunningGraph]]:
    """Start graphs; whatever happens, stop them and check nothing is left running."""
    started: list[RunningGraph] = []

    def start(launch_file: str | Path, *extra: str) -> RunningGraph:
        n = len(started)
        graph = RunningGraph(
            ROOT / launch_file, short_dir / f"rt{n}", short_dir / f"s{n}.json", list(extra)
        )
        started.append(graph)
        return graph

    yield start
    leftovers = []
    for graph in started:
        if graph.proc.poll() is None:
            graph.stop()
        leftovers += graph_pids(graph.runtime_dir)
        graph.kill_all()
    assert not leftovers, f"processes left behind: {leftovers}"
