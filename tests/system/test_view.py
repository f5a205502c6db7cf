"""``sensor-agent view`` against a live simulated graph, through a hand-written WebSocket
client speaking Foxglove's protocol: the channels advertised, data on a subscription, a
clean stop on SIGTERM."""

from __future__ import annotations

import base64
import contextlib
import json
import os
import queue
import re
import signal
import socket
import struct
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from typing import Any

import pytest

from agent.runtime import topics
from cli.viewer_convert import CHANNEL_SCHEMAS
from tests.system.conftest import ROOT, RunningGraph

pytestmark = pytest.mark.timeout(60)

PROTOCOL = "foxglove.sdk.v1"  # what the SDK's server speaks (it refuses foxglove.websocket.v1)


class Client:
    """A WebSocket client (RFC 6455) just big enough for Foxglove's protocol: text frames
    (JSON operations) and binary frames (message data)."""

    def __init__(self, port: int) -> None:
        self.sock = socket.create_connection(("127.0.0.1", port), timeout=10)
        key = base64.b64encode(os.urandom(16)).decode()
        self.sock.sendall(
            (
                f"GET / HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\nUpgrade: websocket\r\n"
                f"Connection: Upgrade\r\nSec-WebSocket-Key: {key}\r\n"
                f"Sec-WebSocket-Version: 13\r\nSec-WebSocket-Protocol: {PROTOCOL}\r\n\r\n"
            ).encode()
        )
        self.buffer = b""
        while b"\r\n\r\n" not in self.buffer:
            self._fill()
        head, self.buffer = self.buffer.split(b"\r\n\r\n", 1)
        self.response = head.decode()

    def _fill(self) -> None:
        data = self.sock.recv(65536)
        if not data:
            raise ConnectionError("the server closed the connection")
        self.buffer += data

    def _take(self, n: int) -> bytes:
        while len(self.buffer) < n:
            self._fill()
        out, self.buffer = self.buffer[:n], self.buffer[n:]
        return out

    def frame(self) -> tuple[int, bytes]:
        """The next frame's opcode and payload (the server's frames are not masked)."""
        first, second = self._take(2)
        size = second & 0x7F
        if size == 126:
            size = struct.unpack(">H", self._take(2))[0]
        elif size == 127:
            size = struct.unpack(">Q", self._take(8))[0]
        return first & 0x0F, self._take(size)

    def send(self, opcode: int, payload: bytes) -> None:
        """One final frame, masked as a client's must be."""
        mask = os.urandom(4)
        header = bytes([0x80 | opcode])
        if len(payload) < 126:
            header += bytes([0x80 | len(payload)])
        else:
            header += bytes([0x80 | 126]) + struct.pack(">H", len(payload))
        masked = bytes(b ^ mask[i % 4] for i, b in enumerate(payload))
        self.sock.sendall(header + mask + masked)

    def close(self) -> None:
        with contextlib.suppress(OSError):
            self.send(0x8, struct.pack(">H", 1000))  # a close frame: a clean goodbye
        self.sock.close()


def read_lines(stream: Any) -> tuple[queue.Queue[str], threading.Thread]:
    """The lines of ``stream`` as they come, and the thread reading them (it ends at EOF)."""
    lines: queue.Queue[str] = queue.Queue()

    def pump() -> None:
        for line in stream:
            lines.put(line)

    thread = threading.Thread(target=pump, daemon=True)
    thread.start()
    return lines, thread


def wait_for_line(lines: queue.Queue[str], pattern: str, timeout_s: float) -> re.Match[str]:
    deadline = time.monotonic() + timeout_s
    seen = []
    while time.monotonic() < deadline:
        try:
            line = lines.get(timeout=0.1)
        except queue.Empty:
            continue
        seen.append(line)
        match = re.search(pattern, line)
        if match:
            return match
    pytest.fail(f"no line matching {pattern!r} in {timeout_s} s; got {seen}")


def until(client: Client, done: Callable[[int, bytes], bool], timeout_s: float, what: str) -> None:
    """Read frames until ``done(opcode, payload)`` says so."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        opcode, payload = client.frame()
        if done(opcode, payload):
            return
    pytest.fail(f"timed out after {timeout_s:g} s waiting for {what}")


def test_view_serves_the_graph_to_a_foxglove_client(
    launch: Callable[..., RunningGraph],
) -> None:
    graph = launch("launch/demo.toml", "--duration", "40")  # the closed loop: tracks flow
    graph.wait_for_first("world", topics.ODOMETRY, "the graph's first odometry")
    view = subprocess.Popen(
        [sys.executable, "-m", "cli.main", "view", "--graph", str(graph.runtime_dir),
         "--port", "0", "--duration", "30"],
        cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    client: Client | None = None
    try:
        lines, reader = read_lines(view.stdout)
        port = int(wait_for_line(lines, r"open ws://127\.0\.0\.1:(\d+) in Foxglove", 20)[1])
        client = Client(port)
        assert client.response.startswith("HTTP/1.1 101"), client.response
        assert f"sec-websocket-protocol: {PROTOCOL}" in client.response.lower()

        advertised: dict[str, dict[str, Any]] = {}

        def advertise(opcode: int, payload: bytes) -> bool:
            if opcode == 0x1:
                op = json.loads(payload)
                if op["op"] == "advertise":
                    advertised.update({c["topic"]: c for c in op["channels"]})
            return advertised.keys() >= CHANNEL_SCHEMAS.keys()

        until(client, advertise, 10, "every channel advertised")
        # launch/demo.toml publishes every topic the viewer shows: every channel, each with
        # its Foxglove schema, protobuf-encoded, advertised before any message.
        assert {t: c["schemaName"] for t, c in advertised.items()} == {
            t: f"foxglove.{s}" for t, s in CHANNEL_SCHEMAS.items()
        }
        assert {c["encoding"] for c in advertised.values()} == {"protobuf"}
        assert {c["schemaEncoding"] for c in advertised.values()} == {"protobuf"}

        wanted = {1: "/tf", 2: "/scan/points", 3: "/tracks"}
        subscriptions = [{"id": i, "channelId": advertised[t]["id"]} for i, t in wanted.items()]
        subscribe = {"op": "subscribe", "subscriptions": subscriptions}
        client.send(0x1, json.dumps(subscribe).encode())
        arrived: set[str] = set()

        def data(opcode: int, payload: bytes) -> bool:
            if opcode == 0x2 and payload[0] == 0x01:  # message data: op, subscription, time
                subscription, log_time_ns = struct.unpack("<IQ", payload[1:13])
                assert log_time_ns > 1.6e18  # the graph's own stamps: its wall clock
                arrived.add(wanted[subscription])
            return arrived == set(wanted.values())

        until(client, data, 15, "messages on /tf, /scan/points and /tracks")
        client.close()
        client = None
        view.send_signal(signal.SIGTERM)
        view.wait(timeout=15)
        reader.join(timeout=5)
        assert view.stderr is not None
        err = view.stderr.read()
    finally:
        if client is not None:
            client.close()
        if view.poll() is None:
            view.kill()
            view.communicate(timeout=10)
    assert view.returncode == 0, err
    out = "".join(lines.queue)  # what it printed after the URL: the summary
    assert "viewed graph demo for " in out
    sent = dict(re.findall(r"^  (/\S+) +foxglove\.\w+ +(\d+)$", out, re.MULTILINE))
    assert {"/tf", "/scan/points", "/tracks"} <= sent.keys()
    assert "/truth" not in sent  # nobody subscribed to it: never converted
