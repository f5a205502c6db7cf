"""A process's word to systemd when it runs as a service (``sensor-agent systemd``).

The units that command writes are ``Type=notify`` with ``WatchdogSec``: systemd counts a
process started once it says ``READY=1`` and kills it as hung when its ``WATCHDOG=1`` pings
stop for longer than the watchdog period. This module speaks that protocol (sd_notify(3)):
one datagram of ``KEY=VALUE`` lines to the ``AF_UNIX`` socket named in ``$NOTIFY_SOCKET``
(a path, or ``@name`` in the abstract namespace). It is written here rather than taken from
a binding of libsystemd: the protocol is one ``sendto`` and the bindings need the C library
and its headers at install time.

What the process says follows its heartbeats (:meth:`ServiceNotifier.beat`), so systemd's
view of it is the launcher's view of it:

* the first ``running`` (or ``fault``) heartbeat: ``READY=1`` (the launcher's start timeout
  is the unit's ``TimeoutStartSec``);
* every heartbeat after that: ``WATCHDOG=1`` (the launcher's hang timeout is the unit's
  ``WatchdogSec``); a process beating ``fault`` is alive and keeps pinging, as the launcher
  keeps it: its stage is failing, and restarting it in a storm would not help;
* a change of state: ``STATUS=<state>`` (shown by ``systemctl status``);
* ``stopping``: ``STOPPING=1``.

Outside systemd (no ``$NOTIFY_SOCKET``) every call does nothing. A failed send is counted in
``failures`` and never raised, and a send never waits (a Unix datagram socket makes the
sender wait once ten datagrams are queued unread): the service manager being slow or gone
must not stall the process. A ``READY=1`` that did not go is said again with the next
heartbeat; a lost ``WATCHDOG=1`` is made good by the next.
"""

from __future__ import annotations

import os
import socket


class ServiceNotifier:
    """sd_notify(3) to ``$NOTIFY_SOCKET``, driven by the process's heartbeats."""

    def __init__(self, address: str | None = None) -> None:
        """``address``: the notify socket (default: ``$NOTIFY_SOCKET``; none: do nothing)."""
        if address is None:
            address = os.environ.get("NOTIFY_SOCKET")
        self.address = "\0" + address[1:] if address and address.startswith("@") else address
        self.ready = False
        self.state = ""
        self.sent = 0
        self.failures = 0

    @property
    def enabled(self) -> bool:
        return bool(self.address)

    def send(self, *fields: str) -> bool:
        """One datagram of ``fields`` (``KEY=VALUE`` each); whether it went."""
        if not self.address:
            return False
        try:
            with socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM) as sock:
                # Never wait: a full queue at the manager would otherwise stall the process.
                sock.setblocking(False)
                sock.sendto("\n".join(fields).encode(), self.address)
        except OSError:
            self.failures += 1
            return False
        self.sent += 1
        return True

    def beat(self, state: str) -> None:
        """Tell systemd what the heartbeat in ``state`` tells the launcher."""
        if not self.address:
            return
        fields = []
        if state != self.state:
            fields.append(f"STATUS={state}")
        if state == "stopping":
            fields.append("STOPPING=1")
        elif state in ("running", "fault"):
            if not self.ready:
                fields.append("READY=1")
            fields.append("WATCHDOG=1")
        if fields and self.send(*fields):
            self.state = state
            self.ready = self.ready or "READY=1" in fields
