"""One hop between two OS processes, per message type: p50 and p99 in µs.

A hop is what a message costs from one stage's process to the next: the sender encodes it
with its header stamped (``to_wire(seq=..., source=...)``) and publishes it on its ``Bus``;
ZeroMQ carries it over an ``ipc://`` socket; the receiver's poll wakes, it receives the
message and decodes it with full validation (``decode(payload, expect=<type>)``).

The bench and an echo process (:mod:`cli.bench_echo`, a separate interpreter, each side
with its own ``Bus``) play ping-pong with one message in flight: the bench encodes and
publishes, the echo receives, decodes, encodes and publishes it back, the bench receives
and decodes it. That round trip is two hops, so one hop is half of it. The types take turns
in blocks of ``BLOCK`` round trips, so a shared machine's changing load falls on all alike.

``transport`` is the same ping-pong for the largest message's bytes, echoed unchanged and
decoded by neither side: what the sockets and polls alone cost.
"""

from __future__ import annotations

import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from types import TracebackType

import numpy as np

from agent.runtime import topics
from agent.runtime.bus import Bus
from agent.runtime.messages import Header, Message, Stop, decode
from cli.bench_echo import TRANSPORT

ROOT = Path(__file__).resolve().parents[1]
BLOCK = 100
SOURCE = "bench"
START_TIMEOUT_S = 30.0  # the echo imports numpy and msgpack on a shared machine
STOP_TIMEOUT_S = 5.0


class EchoProcess:
    """The echo process and the bench's end of the ping-pong; closes both, on error too."""

    def __init__(self, echo_topics: list[str], reply_timeout_s: float = 5.0) -> None:
        self.reply_timeout_s = reply_timeout_s
        self.dir = Path(tempfile.mkdtemp(prefix="lepb-hop"))  # mode 0700
        self.proc: subprocess.Popen[bytes] | None = None
        ping, pong = f"ipc://{self.dir}/bench.pub", f"ipc://{self.dir}/echo.pub"
        try:
            self.bus = Bus(ping)
        except BaseException:
            shutil.rmtree(self.dir, ignore_errors=True)
            raise
        self._closed = False
        try:
            self.bus.subscriber.connect(pong)
            for topic in [*echo_topics, TRANSPORT]:
                self.bus.subscriber.subscribe(topic)
            command = [sys.executable, "-m", "cli.bench_echo", "--listen", ping, "--publish", pong]
            with (self.dir / "echo.log").open("wb") as log:
                self.proc = subprocess.Popen(
                    [*command, *echo_topics],
                    cwd=ROOT,
                    stdout=subprocess.DEVNULL,
                    stderr=log,
                )
            self._wait_ready([*echo_topics, TRANSPORT])
        except BaseException:
            self.close()
            raise

    def _check_alive(self, deadline: float, what: str) -> None:
        if self.proc is not None and self.proc.poll() is not None:
            log = (self.dir / "echo.log").read_text(errors="replace").strip().splitlines()
            raise RuntimeError(
                f"the echo process exited with status {self.proc.returncode} while {what}"
                + (f": {log[-1]}" if log else "")
            )
        if time.monotonic() > deadline:
            raise RuntimeError(f"timed out after {START_TIMEOUT_S:g} s {what}")

    def _wait_ready(self, wanted: list[str]) -> None:
        publisher = self.bus.publisher
        assert publisher is not None  # Bus(endpoint) always has one
        deadline = time.monotonic() + START_TIMEOUT_S
        while any(publisher.subscriber_count(t) < 1 for t in wanted):
            self._check_alive(deadline, "waiting for the echo to subscribe")
            self.bus.poll_subscriptions(0.02)
        # Its subscriptions reached us; ours reach it asynchronously: ping until one returns.
        while not self.bus.poll(0.0):
            self._check_alive(deadline, "waiting for the first echo")
            self.bus.publish(TRANSPORT, b"ready?")
            time.sleep(0.02)
        while self.bus.poll(0.05):  # the other pings' echoes
            pass

    def send(self, topic: str, payload: bytes) -> None:
        self.bus.publish(topic, payload)

    def receive(self, topic: str) -> bytes:
        """The echo of the one message in flight, which must be on ``topic``."""
        deadline = time.monotonic() + self.reply_timeout_s
        while not (got := self.bus.poll(self.reply_timeout_s)):
            if time.monotonic() > deadline:
                raise RuntimeError(f"no echo of a {topic} within {self.reply_timeout_s:g} s")
        if len(got) != 1 or got[0][0] != topic:
            raise RuntimeError(f"expected one {topic} back, got {[t for t, _ in got]}")
        return got[0][1]

    def close(self) -> None:
        """Stop the echo (a stop message, then SIGTERM, then SIGKILL) and close the sockets."""
        if self._closed:
            return
        if self.proc is not None and self.proc.poll() is None:
            self.bus.publish(topics.STOP, Stop(header=Header(), reason="bench").to_wire())
            try:
                self.proc.wait(STOP_TIMEOUT_S)
            except subprocess.TimeoutExpired:
                self.proc.terminate()
                try:
                    self.proc.wait(STOP_TIMEOUT_S)
                except subprocess.TimeoutExpired:
                    self.proc.kill()
                    self.proc.wait()
        self.bus.close()
        self._closed = True
        shutil.rmtree(self.dir, ignore_errors=True)

    def __enter__(self) -> EchoProcess:
        return self

    def __exit__(
        self, _t: type[BaseException] | None, _e: BaseException | None, _tb: TracebackType | None
    ) -> None:
        self.close()


def _decoded_trip(echo: EchoProcess, topic: str, cls: type[Message], msg: Message, seq: int) -> int:
    """One round trip of ``msg`` in ns: encoded and decoded on both sides, as stages do."""
    started = time.perf_counter_ns()
    echo.send(topic, msg.to_wire(seq=seq, source=SOURCE))
    back = decode(echo.receive(topic), expect=cls)
    took = time.perf_counter_ns() - started
    if back.header.seq != seq:
        raise RuntimeError(f"{topic}: sent seq {seq}, the echo returned {back.header.seq}")
    return took


def _transport_trip(echo: EchoProcess, payload: bytes) -> int:
    """One round trip of ``payload`` in ns, as bytes: neither side decodes it."""
    started = time.perf_counter_ns()
    echo.send(TRANSPORT, payload)
    back = echo.receive(TRANSPORT)
    took = time.perf_counter_ns() - started
    if back != payload:
        raise RuntimeError("the echo changed the transport payload")
    return took


def hop_figures(
    samples: dict[str, list[Message]],
    round_trips: int,
    warm_up: int,
    reply_timeout_s: float = 5.0,
) -> dict[str, dict[str, float | int | str]]:
    """Per topic of ``samples``, and ``transport``: the hop's p50 and p99 in µs.

    ``round_trips`` timed round trips per type after ``warm_up`` untimed ones, cycling
    through each type's messages. ``transport`` also names the message whose bytes it
    carried and their size.
    """
    if round_trips < 1 or warm_up < 0:
        raise ValueError(f"need round_trips >= 1 and warm_up >= 0, got {round_trips}, {warm_up}")
    if not samples or not all(samples.values()):
        raise ValueError("need at least one message of every type to send")
    sizes = {t: max(len(m.to_wire()) for m in msgs) for t, msgs in samples.items()}
    largest = max(sizes, key=lambda t: sizes[t])
    raw_bytes = max((m.to_wire() for m in samples[largest]), key=len)
    took: dict[str, list[int]] = {t: [] for t in [*samples, TRANSPORT]}
    seq = dict.fromkeys(samples, 0)
    types = {t: topics.message_type(t) for t in samples}
    with EchoProcess(list(samples), reply_timeout_s) as echo:
        for timed, count in ((False, warm_up), (True, round_trips)):
            for block in range(0, count, BLOCK):
                n = min(BLOCK, count - block)
                for topic, msgs in samples.items():
                    for _ in range(n):
                        msg = msgs[seq[topic] % len(msgs)]
                        ns = _decoded_trip(echo, topic, types[topic], msg, seq[topic])
                        seq[topic] += 1
                        if timed:
                            took[topic].append(ns)
                for _ in range(n):
                    ns = _transport_trip(echo, raw_bytes)
                    if timed:
                        took[TRANSPORT].append(ns)
    figures: dict[str, dict[str, float | int | str]] = {}
    for topic, values in took.items():
        hop_us = np.asarray(values, dtype=np.float64) / 2e3  # half the round trip, in µs
        figures[topic] = {
            "p50": float(np.percentile(hop_us, 50)),
            "p99": float(np.percentile(hop_us, 99)),
        }
    figures[TRANSPORT].update(message=largest, bytes=len(raw_bytes))
    return figures
