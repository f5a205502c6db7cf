"""The units of ``sensor-agent systemd`` run a graph: each ``ExecStart`` started as systemd
would start it (no launcher), speaking sd_notify to a socket of the test's own.

systemd itself is not run (the test needs no root and no manager): the test plays its part
of the protocol, reading each process's notifications with the sender's pid attached by the
kernel (``SO_PASSCRED``), as systemd does.
"""

from __future__ import annotations

import json
import os
import shlex
import signal
import socket
import struct
import subprocess
import sys
import threading
import time
from collections import defaultdict
from pathlib import Path

import pytest

from agent.runtime import topics
from agent.runtime.bus import Bus
from agent.runtime.launch import GraphSpec, load_launch
from cli.systemd import write_units
from tests.system.conftest import ROOT

pytestmark = pytest.mark.timeout(120)


class _Manager:
    """systemd's side of sd_notify: reads every notification as it comes, with its sender."""

    def __init__(self, path: Path) -> None:
        self.sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
        self.sock.bind(str(path))
        self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_PASSCRED, 1)
        self.sock.settimeout(0.1)
        self.said: list[tuple[int, list[str]]] = []  # (sender pid, fields)
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._read, daemon=True)
        self._thread.start()

    def _read(self) -> None:
        creds = struct.calcsize("3i")
        while not self._stop.is_set():
            try:
                data, ancillary, _, _ = self.sock.recvmsg(4096, socket.CMSG_SPACE(creds))
            except TimeoutError:
                continue
            pid = next(
                struct.unpack("3i", d[:creds])[0]
                for level, kind, d in ancillary
                if level == socket.SOL_SOCKET and kind == socket.SCM_CREDENTIALS
            )
            with self._lock:
                self.said.append((pid, data.decode().split("\n")))

    def by_sender(self, names: dict[int, str]) -> dict[str, list[list[str]]]:
        out: dict[str, list[list[str]]] = defaultdict(list)
        with self._lock:
            for pid, fields in self.said:
                out[names[pid]].append(fields)
        return out

    def close(self) -> None:
        self._stop.set()
        self._thread.join()
        self.sock.close()


def _pings_after_ready(notes: list[list[str]]) -> int:
    ready = [i for i, f in enumerate(notes) if "READY=1" in f]
    return sum("WATCHDOG=1" in f for f in notes[ready[0] :]) if ready else 0


def _exit_code(proc: subprocess.Popen[bytes], timeout_s: float) -> int | None:
    try:
        return proc.wait(timeout_s)
    except subprocess.TimeoutExpired:
        return None


def test_the_units_run_the_graph_and_speak_to_systemd(short_dir: Path) -> None:
    units = short_dir / "units"
    write_units(load_launch(ROOT / "launch" / "sim.toml"), "localhost", units)
    # Where systemd would make /run/sensor-agent-sim, a directory of the test's.
    runtime = short_dir / "run"
    runtime.mkdir(mode=0o700)
    graph_file = short_dir / "graph.json"
    graph_file.write_text(
        (units / "graph.json").read_text().replace("/run/sensor-agent-sim", str(runtime))
    )
    graph = GraphSpec.from_json(graph_file.read_text())
    manager = _Manager(short_dir / "notify")
    env = {**os.environ, "NOTIFY_SOCKET": str(short_dir / "notify")}
    children: dict[int, str] = {}
    procs = []
    try:
        for unit in sorted(units.glob("sensor-agent-sim-*.service")):
            if unit.name == "sensor-agent-sim-stop.service":
                continue
            exec_start = next(
                line.partition("=")[2]
                for line in unit.read_text().splitlines()
                if line.startswith("ExecStart=")
            )
            argv = shlex.split(exec_start)
            argv[argv.index("--graph") + 1] = str(graph_file)
            log = (short_dir / f"{unit.stem}.log").open("w")  # journald's part
            proc = subprocess.Popen(argv, env=env, stderr=log)
            log.close()
            procs.append(proc)
            children[proc.pid] = unit.name
        assert len(procs) == len(graph.processes) == 7
        listener = Bus(None, None)
        listener.subscriber.connect(graph.process("planner").endpoint)
        listener.subscriber.subscribe(topics.ENVIRONMENT)
        deadline = time.monotonic() + 30.0
        while time.monotonic() < deadline:
            said = manager.by_sender(children)
            if len(said) == len(procs) and all(_pings_after_ready(n) >= 4 for n in said.values()):
                break
            time.sleep(0.2)
        environment = 0
        deadline = time.monotonic() + 5.0
        while environment < 5 and time.monotonic() < deadline:
            environment += len(listener.poll(0.1))
        listener.close()
        for name, notes in said.items():
            ready = [i for i, f in enumerate(notes) if "READY=1" in f]
            assert len(ready) == 1, (name, notes)  # once, on the first running heartbeat
            assert "STATUS=running" in notes[ready[0]]
            assert _pings_after_ready(notes) >= 4, (name, notes)
        assert set(said) == set(children.values())
        assert environment >= 5  # the graph works end to end: the planner's vector arrives
        # With no launcher, the introspection commands find the graph by its graph file.
        listed = subprocess.run(
            [sys.executable, "-m", "cli.main", "topics", "--graph", str(graph_file), "--json",
             "--listen", "3"],
            capture_output=True, text=True, timeout=30,
        )  # fmt: skip
        assert listed.returncode == 0, listed.stderr
        rates = {row["topic"]: row["rate_hz"] for row in json.loads(listed.stdout)["topics"]}
        assert rates[topics.RAW_SCAN] > 5 and rates[topics.ENVIRONMENT] > 5
        for proc in procs:
            proc.send_signal(signal.SIGTERM)  # systemctl stop's signal
        codes = [_exit_code(proc, 20.0) for proc in procs]
        logs = [p.read_text()[-2000:] for p in short_dir.glob("*.log")]
        assert codes == [0] * len(procs), logs
        said = manager.by_sender(children)
        assert all("STOPPING=1" in notes[-1] for notes in said.values()), said
    finally:
        for proc in procs:
            if proc.poll() is None:
                proc.kill()
            proc.wait()
        manager.close()
