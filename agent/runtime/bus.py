"""The message bus: ZeroMQ publish/subscribe. The only module of the project that opens sockets.

Each process binds one XPUB socket at its own endpoint and publishes every topic it produces
there; it connects one SUB socket to the endpoints of the processes whose topics it reads.
A message is two frames: the topic as UTF-8 plus a NUL byte (so ZeroMQ's prefix matching
is exact), then the msgpack payload.

Choices, deliberately:

* **Queues**, bounded everywhere: ``SNDHWM`` of 100 messages per subscriber's pipe at every
  publisher and ``RCVHWM`` of 100 at every subscriber (10 s of scans at 10 Hz; with the
  kernel's socket buffers, a subscriber that stops reading holds a few MB per publisher at
  most). Past them ZeroMQ drops, so drops are counted where they can be seen: every
  publisher numbers its messages per topic (``header.seq``), and the receiving side counts
  gaps (:class:`SeqTracker`). A process that resumes after a stall does not work through
  its old queue: see :data:`agent.runtime.topics.KEEP_BACKLOG`.
* **Sizes**: a subscriber's ``MAXMSGSIZE`` is the largest payload its topics allow
  (:data:`agent.runtime.topics.MAX_BYTES`); a publisher's, for subscription events and
  handshakes, is 4 KiB. ZeroMQ refuses a bigger frame as it reads its size, before
  allocating it, and drops the link that sent it; the bus counts the dropped link
  (``links_dropped``, from a socket monitor) and dials it again, since ZeroMQ does not
  redial after a protocol error.
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

import contextlib
import logging
import math
import os
import time
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import cast

import zmq
import zmq.auth
from zmq.auth.thread import ThreadAuthenticator

from agent.errors import ConfigError
from agent.runtime.topics import MAX_SUBSCRIBER_FRAME_BYTES

log = logging.getLogger(__name__)

HWM = 100
RECONNECT_MS = 20
# Retries of an absent publisher back off (doubling) up to this: 10 attempts a second instead
# of 35 (which cost a subscriber 0.5 % of a core); a restarted publisher is found at most
# this long after it binds again, which every restart pays.
RECONNECT_MAX_MS = 100
# A dropped link that ZeroMQ does not retry within this long is dialled again by the bus.
REDIAL_S = 0.05
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


KEY_FILES = ("server.key", "server.key_secret", "client.key", "client.key_secret")


def create_keys(directory: str | Path, force: bool = False) -> Path:
    """Make a keys directory (mode 0700) with server and client CURVE key pairs.

    Keys already there are shared with the graph's other hosts: replacing them would lock
    those hosts out, so :class:`ConfigError` unless ``force``.
    """
    d = Path(directory)
    existing = [name for name in KEY_FILES if (d / name).exists()]
    if existing and not force:
        raise ConfigError(
            f"keys directory {d} already has keys ({', '.join(existing)}); other hosts may "
            "share them: give --force to replace them"
        )
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
        self.socket.setsockopt(zmq.MAXMSGSIZE, MAX_SUBSCRIBER_FRAME_BYTES)  # events, handshakes
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
        """Close the socket and remove its ``ipc://`` file (ZeroMQ leaves it behind)."""
        self.socket.close(0)
        remove_ipc_file(self.endpoint)


def remove_ipc_file(endpoint: str) -> None:
    """Remove the socket file of an ``ipc://`` endpoint, if it is there."""
    if endpoint.startswith("ipc://"):
        with contextlib.suppress(OSError):
            os.unlink(endpoint[len("ipc://") :])


class Subscriber:
    """A SUB socket connected to several publishers' endpoints, subscribed to exact topics."""

    def __init__(
        self,
        ctx: zmq.Context[zmq.Socket[bytes]],
        keys: CurveKeys | None = None,
        max_bytes: int | None = None,
    ) -> None:
        """``max_bytes``: the largest frame accepted (ZeroMQ's ``MAXMSGSIZE``; ``None``: any)."""
        self.socket = ctx.socket(zmq.SUB)
        self.socket.setsockopt(zmq.LINGER, 0)
        self.socket.setsockopt(zmq.RCVHWM, HWM)
        if max_bytes is not None:
            self.socket.setsockopt(zmq.MAXMSGSIZE, max_bytes)
        # Reconnect quickly to a restarted publisher (ZeroMQ's default waits 100 ms).
        self.socket.setsockopt(zmq.RECONNECT_IVL, RECONNECT_MS)
        self.socket.setsockopt(zmq.RECONNECT_IVL_MAX, RECONNECT_MAX_MS)
        # Dropped links, to count them and dial again those ZeroMQ gives up on.
        self.monitor = self.socket.get_monitor_socket(
            zmq.EVENT_DISCONNECTED | zmq.EVENT_CONNECT_RETRIED | zmq.EVENT_CONNECTED
        )
        self._dropped: dict[str, float] = {}  # endpoint: when its link dropped (monotonic)
        self.links_redialled = 0
        self._keys = keys
        self.endpoints: list[str] = []
        self.topics: list[str] = []
        self.links_dropped = 0

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

    def handle_link_events(self) -> None:
        """Count dropped links; dial again those ZeroMQ gives up on.

        A link drops when its publisher exits, and ZeroMQ then retries by itself (a
        ``CONNECT_RETRIED`` event follows), or when the publisher breaks the protocol, e.g.
        with a frame over ``MAXMSGSIZE``: ZeroMQ then gives the link up for good, so the bus
        dials it again, at the latest ``REDIAL_S`` later (sooner if it polls sooner).
        """
        now = time.monotonic()
        while True:
            try:
                frames = self.monitor.recv_multipart(zmq.NOBLOCK)
            except zmq.Again:
                break
            if len(frames) != 2 or len(frames[0]) != 6:
                continue
            event = int.from_bytes(frames[0][:2], "little")
            endpoint = frames[1].decode(errors="replace")
            if event == zmq.EVENT_DISCONNECTED:
                self.links_dropped += 1
                self._dropped[endpoint] = now
            else:  # ZeroMQ is dialling it again itself
                self._dropped.pop(endpoint, None)
        for endpoint, since in list(self._dropped.items()):
            if now - since >= REDIAL_S:
                del self._dropped[endpoint]
                if endpoint in self.endpoints:
                    with contextlib.suppress(zmq.ZMQError):  # already gone
                        self.socket.disconnect(endpoint)
                    self.socket.connect(endpoint)
                    self.links_redialled += 1

    def redial_due(self) -> float | None:
        """When (monotonic) a link ZeroMQ gave up on is due to be dialled again, if any."""
        return min(self._dropped.values()) + REDIAL_S if self._dropped else None

    def close(self) -> None:
        self.socket.disable_monitor()
        self.monitor.close(0)
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

    def see(self, topic: str, source: str, seq: int, dropped_here: int = 0) -> int:
        """Record a message; return how many were lost just before it.

        ``dropped_here``: messages of the topic that arrived since the last one seen but were
        dropped unread on purpose (a stale backlog): not lost on the way.
        """
        key = (topic, source)
        previous = self.last.get(key)
        self.last[key] = seq
        if previous is None:
            return 0
        if seq <= previous:
            self.restarts += 1
            return 0
        gap = max(0, seq - previous - 1 - dropped_here)
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
    latched
        Topics whose latest message is re-sent to every new subscriber.
    max_bytes
        The largest frame the subscriber accepts (``None``: any); see the module docstring.
    """

    def __init__(
        self,
        publish_endpoint: str | None,
        keys: CurveKeys | None = None,
        latched: Iterable[str] = (),
        max_bytes: int | None = None,
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
            self.subscriber = Subscriber(self.ctx, keys, max_bytes)
        except Exception:
            self.close()
            raise
        self.poller = zmq.Poller()
        self.poller.register(self.subscriber.socket, zmq.POLLIN)
        self.poller.register(self.subscriber.monitor, zmq.POLLIN)
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
        redial = self.subscriber.redial_due()
        if redial is not None:
            timeout_s = min(timeout_s, max(0.0, redial - time.monotonic()))
        # Round up: truncating 0.4 ms to 0 would spin until a tick is due.
        ready = dict(self.poller.poll(max(0, math.ceil(timeout_s * 1000))))
        if redial is not None and self.subscriber.monitor not in ready:
            self.subscriber.handle_link_events()
        if not ready:
            return []
        for fd in self._wake_fds:
            if fd in ready:
                _drain(fd)
        if self.publisher is not None and self.publisher.socket in ready:
            self.publisher.handle_subscriptions()
        if self.subscriber.monitor in ready:
            self.subscriber.handle_link_events()
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
