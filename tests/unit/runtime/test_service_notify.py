"""The sd_notify protocol a process speaks under systemd, on a socket of the test's own."""

from __future__ import annotations

import socket
from collections.abc import Iterator
from pathlib import Path

import pytest

from processes.service_notify import ServiceNotifier


@pytest.fixture
def notify_socket(tmp_path: Path) -> Iterator[tuple[str, socket.socket]]:
    path = str(tmp_path / "notify")
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    sock.bind(path)
    sock.setblocking(False)
    yield path, sock
    sock.close()


def received(sock: socket.socket) -> list[list[str]]:
    out = []
    while True:
        try:
            out.append(sock.recv(4096).decode().split("\n"))
        except BlockingIOError:
            return out


def test_ready_once_then_a_watchdog_ping_per_heartbeat(
    notify_socket: tuple[str, socket.socket],
) -> None:
    path, sock = notify_socket
    notifier = ServiceNotifier(path)
    for state in ("starting", "running", "running", "fault", "running", "stopping"):
        notifier.beat(state)
    assert received(sock) == [
        ["STATUS=starting"],
        ["STATUS=running", "READY=1", "WATCHDOG=1"],
        ["WATCHDOG=1"],
        ["STATUS=fault", "WATCHDOG=1"],  # alive, its stage failing: kept, as the launcher does
        ["STATUS=running", "WATCHDOG=1"],
        ["STATUS=stopping", "STOPPING=1"],
    ]
    assert notifier.sent == 6 and notifier.failures == 0


def test_the_abstract_namespace_is_spelt_with_an_at_sign() -> None:
    name = f"lep-notify-test-{id(object())}"
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    sock.bind("\0" + name)
    try:
        assert ServiceNotifier("@" + name).send("READY=1")
        assert sock.recv(64) == b"READY=1"
    finally:
        sock.close()


def test_outside_systemd_nothing_is_sent(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv("NOTIFY_SOCKET", raising=False)
    notifier = ServiceNotifier()
    assert not notifier.enabled
    notifier.beat("running")
    assert notifier.sent == 0 and not notifier.send("READY=1")


def test_a_manager_gone_is_counted_not_raised(tmp_path: Path) -> None:
    notifier = ServiceNotifier(str(tmp_path / "nobody-listens"))
    notifier.beat("running")
    notifier.beat("running")
    assert notifier.failures == 2 and notifier.sent == 0
    assert not notifier.ready  # READY=1 is said again once it can be heard


def test_a_manager_that_does_not_read_never_stalls_the_process(
    notify_socket: tuple[str, socket.socket],
) -> None:
    """A Unix datagram socket queues ten datagrams; a blocking send would then wait."""
    path, sock = notify_socket
    notifier = ServiceNotifier(path)
    for _ in range(200):
        notifier.beat("running")
    assert notifier.failures > 0 and notifier.sent + notifier.failures == 200
    assert len(received(sock)) == notifier.sent  # what went, arrived
