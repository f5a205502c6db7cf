"""The message bus: ZeroMQ publish/subscribe. The only module of the project that opens sockets.

Each process binds one XPUB socket at its own endpoint and publishes every topic it produces
there; it connects one SUB socket to the endpoints of the processes whose topics it reads.
A message is two frames: the topic as UTF-8 plus a NUL byte (so ZeroMQ's prefix matching
is exact), then the msgpack payload.

Choices, deliberately:

* **Queues**: ``SNDHWM`` and ``RCVHWM`` of 1000 messages (100 s of scans at 10 Hz, 0.5 s at
  the bench's 2000 scans/s). Past them ZeroMQ drops silently, so drops are counted where they
  can be seen: every publisher numbers its messages per topic (``header.seq``), and the
  receiving side counts gaps (:class:`SeqTracker`).
* **Slow joiners**: a SUB socket that connects after a message was sent misses it. The
  publisher's XPUB socket reports each subscription, so a process can hold its first message
  on a topic until the subscribers the launch file expects have joined
  (:meth:`Publisher.subscriber_count`), and *latched* topics (state, not streams) re-send
  their latest message to every new subscriber.
* **Security**: ``ipc://`` endpoints live in a per-graph directory only the user can open;
  ``tcp://`` endpoints use CURVE: publishers are servers with the graph's server key,
  subscribers are clients whose public keys the publishers' authenticator allows.
* **Shutdown**: every socket closes with linger 0: a stopping process never blocks on
  undelivered messages.
* **Idle cost**: a subscriber retries an endpoint nobody binds (an ``[[external]]``
  publisher that is not running) at a backed-off interval, not every 20 ms: each attempt
  wakes the context's I/O thread, and at 20 ms they cost 0.5 % of a core per socket.
  :meth:`Bus.poll` can also end early on a plain file descriptor (a signal's wake-up pipe),
  so a process need not wake on a short timeout just to notice a signal.
"""

from __future__ import annotations

import logging
import math
import os
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import cast

import zmq
import zmq.auth
from zmq.auth.thread import ThreadAuthenticator

from agent.errors import ConfigError

log = logging.getLogger(__name__)

HWM = 1000
RECONNECT_MS = 20
# Retries of an absent publisher back off (doubling) up to this: 10 attempts a second instead
# of 35 (which cost a subscriber 0.5 % of a core); a restarted publisher is found at most
# this long after it binds again, which every restart pays.
RECONNECT_MAX_MS = 100
TOPIC_END = b"\x00"


def topic_frame(topic: str) -> bytes:
    return topic.encode() + TOPIC_END


@dataclass(frozen=True)
class CurveKeys:
    """CURVE key material for ``tcp://`` endpoints, read from a keys directory.

    Layout (made by :func:`create_keys`): ``server.key_secret`` (the publishers' key pair),
    ``client.key_secret`` (the subscribers' key pair) and ``authorized/`` (public keys of
    clients allowed to connect).
    """

    directory: Path
    server_public: bytes
    server_secret: bytes
    client_public: bytes
    client_secret: bytes

    @classmethod
    def load(cls, directory: str | Path) -> CurveKeys:
        d = Path(directory)
        try:
            server_public, server_secret = zmq.auth.load_certificate(d / "server.key_secret")
            client_public, client_secret = zmq.auth.load_certificate(d / "client.key_secret")
        except (OSError, ValueError) as exc:
            raise ConfigError(
                f"keys directory {d}: {exc} (make keys with 'sensor-agent keys {d}')"
            ) from None
        if server_secret is None or client_secret is None:
            raise ConfigError(f"keys directory {d}: secret keys missing")
        return cls(d, server_public, server_secret, client_public, client_secret)


def create_keys(directory: str | Path) -> Path:
    """Make a keys directory (mode 0700) with server and client CURVE key pairs."""
    d = Path(directory)
    d.mkdir(parents=True, exist_ok=True)
    d.chmod(0o700)
    for name in ("server", "client"):
        _, secret = zmq.auth.create_certificates(str(d), name)
        Path(secret).chmod(0o600)
    authorized = d / "authorized"
    authorized.mkdir(exist_ok=True)
    (authorized / "client.key").write_bytes((d / "client.key").read_bytes())
    return d


class Publisher:
    """An XPUB socket bound at one endpoint, publishing any number of topics.

    Tracks subscriptions per topic (for slow-joiner handling) and re-sends the latest message
    of latched topics to new subscribers.
    """

    def __init__(
        self,
        ctx: zmq.Context[zmq.Socket[bytes]],
        endpoint: str,
        keys: CurveKeys | None = None,
        latched: Iterable[str] = (),
    ) -> None:
        self.endpoint = endpoint
        self.socket = ctx.socket(zmq.XPUB)
        self.socket.setsockopt(zmq.LINGER, 0)
        self.socket.setsockopt(zmq.SNDHWM, HWM)
        self.socket.setsockopt(zmq.XPUB_VERBOSER, 1)  # every (un)subscription, for counting
        if endpoint.startswith("tcp://"):
            if keys is None:
                self.socket.close(0)  # an open socket would block the context's term()
                raise ConfigError(f"endpoint {endpoint}: tcp needs CURVE keys (keys_dir)")
            self.socket.curve_secretkey = keys.server_secret
            self.socket.curve_publickey = keys.server_public
            self.socket.curve_server = True
        try:
            self.socket.bind(endpoint)
        except zmq.ZMQError as exc:
            self.socket.close(0)
            raise ConfigError(f"cannot bind {endpoint}: {exc}") from None
        self._subscribers: dict[str, int] = {}
        self._latched = set(latched)
        self._last: dict[str, bytes] = {}
        self.sent: dict[str, int] = {}

    def handle_subscriptions(self) -> list[str]:
        """Read pending (un)subscription events; re-send latched topics to new subscribers.

        Returns the topics that gained a subscriber.
        """
        joined: list[str] = []
        while True:
            try:
                event = self.socket.recv(zmq.NOBLOCK)
            except zmq.Again:
                return joined
            if not event or not event.endswith(TOPIC_END):
                continue  # a prefix subscription (e.g. everything, b""): not one topic
            topic = event[1:-1].decode(errors="replace")
            delta = 1 if event[0] == 1 else -1
            self._subscribers[topic] = max(0, self._subscribers.get(topic, 0) + delta)
            if delta > 0:
                joined.append(topic)
                if topic in self._last:
                    self._send(topic, self._last[topic])

    def subscriber_count(self, topic: str) -> int:
        return self._subscribers.get(topic, 0)

    def publish(self, topic: str, payload: bytes) -> None:
        if topic in self._latched:
            self._last[topic] = payload
        self._send(topic, payload)

    def _send(self, topic: str, payload: bytes) -> None:
        self.socket.send_multipart((topic_frame(topic), payload), copy=False)
        self.sent[topic] = self.sent.get(topic, 0) + 1

    def close(self) -> None:
        self.socket.close(0)


class Subscriber:
    """A SUB socket connected to several publishers' endpoints, subscribed to exact topics."""

    def __init__(self, ctx: zmq.Context[zmq.Socket[bytes]], keys: CurveKeys | None = None) -> None:
        self.socket = ctx.socket(zmq.SUB)
        self.socket.setsockopt(zmq.LINGER, 0)
        self.socket.setsockopt(zmq.RCVHWM, HWM)
        # Reconnect quickly to a restarted publisher (ZeroMQ's default waits 100 ms).
        self.socket.setsockopt(zmq.RECONNECT_IVL, RECONNECT_MS)
        self.socket.setsockopt(zmq.RECONNECT_IVL_MAX, RECONNECT_MAX_MS)
        self._keys = keys
        self.endpoints: list[str] = []
        self.topics: list[str] = []

    def connect(self, endpoint: str) -> None:
        if endpoint in self.endpoints:
            return
        if endpoint.startswith("tcp://"):
            if self._keys is None:
                raise ConfigError(f"endpoint {endpoint}: tcp needs CURVE keys (keys_dir)")
            self.socket.curve_serverkey = self._keys.server_public
            self.socket.curve_publickey = self._keys.client_public
            self.socket.curve_secretkey = self._keys.client_secret
        self.socket.connect(endpoint)
        self.endpoints.append(endpoint)

    def subscribe(self, topic: str) -> None:
        if topic not in self.topics:
            self.socket.setsockopt(zmq.SUBSCRIBE, topic_frame(topic))
            self.topics.append(topic)

    def subscribe_all(self) -> None:
        """Every topic (for monitors and recorders)."""
        self.socket.setsockopt(zmq.SUBSCRIBE, b"")

    def receive(self) -> tuple[str, bytes] | None:
        """One pending message as ``(topic, payload)``, or ``None`` if there is none.

        A message that is not two frames with a NUL-terminated topic is returned with topic
        ``""`` so the caller can count it as malformed.
        """
        try:
            frames = self.socket.recv_multipart(zmq.NOBLOCK)
        except zmq.Again:
            return None
        if len(frames) != 2 or not frames[0].endswith(TOPIC_END):
            return "", b"".join(frames)
        return frames[0][:-1].decode(errors="replace"), frames[1]

    def pending(self) -> bool:
        """Whether a message can be received now."""
        return bool(cast(int, self.socket.get(zmq.EVENTS)) & zmq.POLLIN)

    def close(self) -> None:
        self.socket.close(0)


@dataclass
class SeqTracker:
    """Counts messages lost between a publisher and here, from gaps in ``header.seq``.

    A sequence number lower than the last one means the publisher restarted; that is counted
    as a restart, not as a loss.
    """

    last: dict[tuple[str, str], int] = field(default_factory=dict)
    lost: int = 0
    restarts: int = 0

    def see(self, topic: str, source: str, seq: int) -> int:
        """Record a message; return how many were lost just before it."""
        key = (topic, source)
        previous = self.last.get(key)
        self.last[key] = seq
        if previous is None:
            return 0
        if seq <= previous:
            self.restarts += 1
            return 0
        gap = seq - previous - 1
        self.lost += gap
        return gap


class Bus:
    """One process's sockets: a publisher, a subscriber, and a poller over both.

    Parameters
    ----------
    publish_endpoint
        Where this process's publisher binds; ``None`` for a process that only listens.
    keys
        CURVE keys, needed when any endpoint is ``tcp://``.
    """

    def __init__(
        self,
        publish_endpoint: str | None,
        keys: CurveKeys | None = None,
        latched: Iterable[str] = (),
    ) -> None:
        self.ctx: zmq.Context[zmq.Socket[bytes]] = zmq.Context()
        self._auth: ThreadAuthenticator | None = None
        try:
            if keys is not None and publish_endpoint and publish_endpoint.startswith("tcp://"):
                self._auth = ThreadAuthenticator(self.ctx)
                self._auth.start()
                self._auth.configure_curve(domain="*", location=str(keys.directory / "authorized"))
            self.publisher = (
                Publisher(self.ctx, publish_endpoint, keys, latched) if publish_endpoint else None
            )
            self.subscriber = Subscriber(self.ctx, keys)
        except Exception:
            self.close()
            raise
        self.poller = zmq.Poller()
        self.poller.register(self.subscriber.socket, zmq.POLLIN)
        if self.publisher is not None:
            self.poller.register(self.publisher.socket, zmq.POLLIN)
        self._wake_fds: list[int] = []

    def wake_on(self, fd: int) -> None:
        """End :meth:`poll` early whenever ``fd`` (a non-blocking pipe, e.g. the one
        :func:`signal.set_wakeup_fd` writes to) becomes readable; what it holds is discarded."""
        self.poller.register(fd, zmq.POLLIN)
        self._wake_fds.append(fd)

    def poll(self, timeout_s: float) -> list[tuple[str, bytes]]:
        """Wait up to ``timeout_s`` for traffic; return the messages received (maybe none).

        Subscription events on the publisher are handled on the way.
        """
        # Round up: truncating 0.4 ms to 0 would spin until a tick is due.
        ready = dict(self.poller.poll(max(0, math.ceil(timeout_s * 1000))))
        if not ready:
            return []
        for fd in self._wake_fds:
            if fd in ready:
                _drain(fd)
        if self.publisher is not None and self.publisher.socket in ready:
            self.publisher.handle_subscriptions()
        messages: list[tuple[str, bytes]] = []
        if self.subscriber.socket in ready:
            sub = self.subscriber
            # Ask the socket whether more is queued rather than read until zmq.Again: the
            # exception costs about 10 µs a wake-up, the question 3.
            while len(messages) < HWM:
                item = sub.receive()
                if item is None:
                    break
                messages.append(item)
                if not sub.pending():
                    break
        return messages

    def poll_subscriptions(self, timeout_s: float) -> None:
        """Wait up to ``timeout_s`` for (un)subscription events only; inputs stay queued."""
        if self.publisher is None:
            return
        if self.publisher.socket.poll(max(0, math.ceil(timeout_s * 1000)), zmq.POLLIN):
            self.publisher.handle_subscriptions()

    def publish(self, topic: str, payload: bytes) -> None:
        if self.publisher is None:
            raise ConfigError(f"this process has no publisher endpoint, cannot publish {topic}")
        self.publisher.publish(topic, payload)

    def close(self) -> None:
        """Close every socket with linger 0, then the context."""
        for part in (getattr(self, "publisher", None), getattr(self, "subscriber", None)):
            if part is not None:
                part.close()
        if self._auth is not None:
            self._auth.stop()
        self.ctx.term()


def _drain(fd: int) -> None:
    try:
        while os.read(fd, 512):
            pass
    except (BlockingIOError, InterruptedError):
        pass
