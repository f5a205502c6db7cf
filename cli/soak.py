"""``sensor-agent soak [--minutes M] [--kill-every S] [--seed N] [--json FILE]``: the closed
loop over the head's serial link while a random process of the agent is killed every ``S``
seconds.

It starts the firmware emulator on a pseudo-terminal (``head-emulator --link --truth``) and
``launch/demo_serial.toml`` against it in a private runtime directory, lets the graph warm up
(until its vectors are trusted, at most 60 s), then for ``M`` minutes sends ``SIGKILL`` to one
of the agent's processes (head, calibration, filtering, features, tracking, planner; drawn
with ``--seed``) every ``S`` s, which the launcher restarts. It measures:

* ``moved_on_stale``: wheel commands that would move the vehicle (speed or yaw rate not 0)
  issued when the newest environment vector seen so far was older than its ``valid_for_s``
  plus 50 ms of transport (the controller must stop within its period of going stale, and
  resume only on fresh, trusted data); ``stale_s`` how long the vectors were stale in all;
* ``rss_growth``, ``fd_growth``: over the processes never killed (the launcher, the world,
  the vehicle and the emulator), the relative growth of their total resident memory and the
  growth of their open file descriptors, from the end of the warm-up to the end;
* ``restarts`` (the launcher's count), ``kills``, and ``outcome``: ``pass`` when nothing
  moved on stale data, memory grew less than 5 % and no descriptor leaked, else ``fail``.

Prints the figures and writes them with ``--json``: ``{"minutes", "kills",
"moved_on_stale", "rss_growth", "fd_growth", "restarts", "outcome", ...}``.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

from agent.errors import ConfigError
from agent.runtime import topics
from agent.runtime.bus import Bus
from agent.runtime.messages import EnvironmentVector, WheelCommand, decode
from cli.output import write_json
from processes.launcher import live_pids

ROOT = Path(__file__).resolve().parents[1]
VICTIMS = ("head", "calibration", "filtering", "features", "tracking", "planner")
KEPT = ("world", "vehicle")  # the vehicle's side: not the agent, never killed
SLACK_S = 0.05
WARM_UP_LIMIT_S = 60.0


def _rss_kib(pid: int) -> int:
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                return int(line.split()[1])
    except OSError:
        pass
    return 0


def _fds(pid: int) -> int:
    try:
        return len(os.listdir(f"/proc/{pid}/fd"))
    except OSError:
        return 0


class _Watch:
    """The graph's vectors and wheel commands, as they come."""

    def __init__(self, runtime: Path | None) -> None:
        self.bus = Bus(None) if runtime is not None else None  # None: judged by take() alone
        for name, topic in (("planner", topics.ENVIRONMENT), ("vehicle", topics.WHEEL_COMMAND)):
            if self.bus is not None:
                self.bus.subscriber.connect(f"ipc://{runtime}/{name}.pub")
                self.bus.subscriber.subscribe(topic)
        self.valid_until = -np.inf  # the newest vector's stamp + valid_for_s
        self.trusted = 0
        self.moved_on_stale = 0
        self.commands = 0
        self.stale_s = 0.0
        self._stale_since: float | None = None

    def poll(self, timeout_s: float) -> None:
        assert self.bus is not None
        for _, payload in self.bus.poll(timeout_s):
            try:
                msg = decode(payload)
            except Exception:
                continue
            self.take(msg)

    def take(self, msg: object) -> None:
        """One message from the graph: a vector renews the validity, a command is judged."""
        if isinstance(msg, EnvironmentVector):
            self.valid_until = max(self.valid_until, msg.header.stamp_s + msg.valid_for_s)
            self.trusted += int(msg.sensor_ok)
        elif isinstance(msg, WheelCommand):
            self.commands += 1
            t = msg.header.stamp_s
            stale = t > self.valid_until + SLACK_S
            if stale and (msg.speed_m_s != 0.0 or msg.yaw_rate_rad_s != 0.0):
                self.moved_on_stale += 1
            if stale and self._stale_since is None:
                self._stale_since = t
            elif not stale and self._stale_since is not None:
                self.stale_s += t - self._stale_since
                self._stale_since = None

    def close(self) -> None:
        if self.bus is not None:
            self.bus.close()


def soak(minutes: float, kill_every_s: float, seed: int) -> dict[str, Any]:
    """The soak (module docstring); its figures."""
    rng = np.random.default_rng(seed)
    work = Path(tempfile.mkdtemp(prefix="lepsoak"))
    runtime, link = work / "rt", work / "head"
    text = (ROOT / "launch" / "demo_serial.toml").read_text()
    text = text.replace('"../', f'"{ROOT}/').replace('"/tmp/lep-head"', f'"{link}"')
    graph_file = work / "demo_serial.toml"
    graph_file.write_text(text)
    summary = work / "summary.json"
    total_s = 60.0 * minutes + WARM_UP_LIMIT_S + 60.0
    launcher = subprocess.Popen(
        [sys.executable, "-m", "cli.main", "launch", str(graph_file), "--runtime-dir",
         str(runtime), "--json", str(summary), "--duration", f"{total_s:.0f}"],
        cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    emulator = subprocess.Popen(
        [sys.executable, "-m", "cli.main", "head-emulator", "--link", str(link), "--truth",
         f"ipc://{runtime}/world.pub", "--duration", f"{total_s:.0f}"],
        cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
    )  # fmt: skip
    watch = _Watch(runtime)
    kills = 0
    try:
        started = time.monotonic()
        while watch.trusted < 20:  # warm-up: the loop closed
            if time.monotonic() - started > WARM_UP_LIMIT_S or launcher.poll() is not None:
                raise ConfigError("soak: the closed loop did not start (no trusted vectors)")
            watch.poll(0.1)
        kept = [launcher.pid, emulator.pid] + [
            pid for name, pid in live_pids(runtime).items() if name in KEPT
        ]
        time.sleep(2.0)  # past the first vectors' allocations
        rss_0 = sum(_rss_kib(p) for p in kept)
        fds_0 = sum(_fds(p) for p in kept)
        watch.moved_on_stale = 0  # counted from here
        end = time.monotonic() + 60.0 * minutes
        next_kill = time.monotonic() + kill_every_s
        while time.monotonic() < end:
            watch.poll(0.05)
            if time.monotonic() >= next_kill:
                name = VICTIMS[int(rng.integers(0, len(VICTIMS)))]
                pid = live_pids(runtime).get(name)
                if pid is not None:
                    try:
                        os.kill(pid, signal.SIGKILL)
                        kills += 1
                    except OSError:
                        pass
                next_kill += kill_every_s
            if launcher.poll() is not None:
                break
        settle = time.monotonic() + 2.0  # the last kill's restart
        while time.monotonic() < settle:
            watch.poll(0.05)
        rss_1 = sum(_rss_kib(p) for p in kept)
        fds_1 = sum(_fds(p) for p in kept)
        alive = launcher.poll() is None
    finally:
        watch.close()
        if launcher.poll() is None:
            launcher.send_signal(signal.SIGINT)
        try:
            launcher.wait(30)
        except subprocess.TimeoutExpired:
            launcher.kill()
        emulator.kill()
        emulator.wait(10)
    restarts = 0
    try:
        processes = json.loads(summary.read_text())["processes"]
        restarts = sum(int(p.get("restarts", 0)) for p in processes.values())
    except (OSError, ValueError, KeyError):
        pass
    shutil.rmtree(work, ignore_errors=True)
    rss_growth = (rss_1 - rss_0) / rss_0 if rss_0 else None
    fd_growth = fds_1 - fds_0
    ok = alive and watch.moved_on_stale == 0 and fd_growth <= 0
    ok = ok and rss_growth is not None and rss_growth < 0.05
    return {
        "minutes": minutes, "kill_every_s": kill_every_s, "kills": kills,
        "moved_on_stale": watch.moved_on_stale, "stale_s": round(watch.stale_s, 3),
        "wheel_commands": watch.commands, "rss_growth": rss_growth, "fd_growth": fd_growth,
        "rss_kib": [rss_0, rss_1], "restarts": restarts, "graph_alive": alive,
        "outcome": "pass" if ok else "fail",
    }  # fmt: skip


def soak_command(args: argparse.Namespace) -> int:
    """``sensor-agent soak``: the figures, and ``--json``."""
    if not (args.minutes > 0 and args.kill_every > 0):
        raise ConfigError("soak: --minutes and --kill-every must be positive")
    doc = soak(args.minutes, args.kill_every, args.seed)
    print(f"soak: {doc['minutes']:g} min, a process of the agent killed every "
          f"{doc['kill_every_s']:g} s")  # fmt: skip
    for key in ("kills", "restarts", "moved_on_stale", "stale_s", "wheel_commands",
                "rss_growth", "fd_growth", "outcome"):  # fmt: skip
        value = doc[key]
        shown = f"{value:+.2%}" if key == "rss_growth" and value is not None else str(value)
        print(f"  {key:16s} {shown}")
    if args.json:
        write_json(Path(args.json), doc)
    return 0 if doc["outcome"] == "pass" else 1
