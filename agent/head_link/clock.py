"""Head time to host time (``docs/head-protocol.md`` §4): the offset from clock probes.

A probe sent at host time ``t₀`` and answered with head time ``h``, the answer received at
``t₁``: the head read its clock somewhere in ``[t₀, t₁]``, so ``offset = h − (t₀ + t₁)/2``
is right to within ``(t₁ − t₀)/2``. Of the last ``keep`` probes, the one with the smallest
round trip gives the estimate and its stated error (the operating systems' latencies vary
from probe to probe; the quickest round trip bounds the offset most tightly). Drift of the
head's crystal (tens of ppm) moves the offset by tens of µs a second; probes every second
keep the estimate within that.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, field

__all__ = ["ClockAlignment"]


@dataclass
class ClockAlignment:
    """The head clock's offset from the host's, from probes (module docstring); µs."""

    keep: int = 16
    _probes: deque[tuple[float, float]] = field(default_factory=deque)  # (round trip, offset)
    refused: int = 0

    def add(self, host_sent_us: float, host_received_us: float, head_us: float) -> None:
        """One probe's three times (µs); one whose reply came before it left, or with a
        non-finite time, is counted in ``refused`` and ignored."""
        times = (host_sent_us, host_received_us, head_us)
        if not all(math.isfinite(t) for t in times) or host_received_us < host_sent_us:
            self.refused += 1
            return
        trip = host_received_us - host_sent_us
        self._probes.append((trip, head_us - 0.5 * (host_sent_us + host_received_us)))
        while len(self._probes) > self.keep:
            self._probes.popleft()

    @property
    def known(self) -> bool:
        return bool(self._probes)

    @property
    def offset_us(self) -> float:
        """Head time less host time (the best probe's); NaN before any probe."""
        return min(self._probes)[1] if self._probes else math.nan

    @property
    def error_us(self) -> float:
        """The bound on :attr:`offset_us`'s error: half the best probe's round trip."""
        return 0.5 * min(self._probes)[0] if self._probes else math.inf

    def to_host_us(self, head_us: float) -> float:
        """A head time on the host's clock."""
        return head_us - self.offset_us
