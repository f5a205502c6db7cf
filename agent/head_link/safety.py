"""The laser's safety state machine, the head firmware's own duty (``docs/head-protocol.md``
§5), and the scan mirror it watches.

**States.** ``OFF`` (laser off, nothing wrong), ``ON`` (laser on), ``TRIPPED`` (switched off
by a fault, held off). Transitions:

======================  ==========================  =========================================
from                    event                       to
======================  ==========================  =========================================
``OFF``                 ``laser on``, mirror at     ``ON`` (refused, ``NOT_READY``, while the
                        speed, heartbeat fresh      mirror is slow or the heartbeat stale)
``ON``                  ``laser off``               ``OFF``
``ON``                  mirror below the safe rate  ``TRIPPED`` (``MIRROR_STALL`` under 5 % of
                        beyond a turnaround         the nominal rate, else ``MIRROR_SLOW``,
                                                    made a stall if it falls under 5 % later)
``ON``                  no heartbeat for            ``TRIPPED`` (``HEARTBEAT_LOST``)
                        ``heartbeat_timeout_s``
``ON``                  a command it cannot honour  ``TRIPPED`` (``BAD_COMMAND``)
``TRIPPED``             ``laser on``                ``TRIPPED`` (refused, ``LASER_LOCKED``)
``TRIPPED``             ``rearm``, cause gone       ``OFF`` (refused, ``NOT_READY``, while it
                                                    is not)
======================  ==========================  =========================================

Plain code rather than a state-machine library: three states and a table of guarded
transitions, checked at every tick of the firmware's control loop, read more directly as
one method each than as a library's declarations, and a firmware port (C) follows them line
by line.

**The mirror.** A galvanometer sweeps the window at the nominal rate (40° in 0.1 s) and
reverses at each end with its acceleration limit, below the safe rate for
``2·ω·(1 − f)/α`` around each reversal (1.0 ms at the defaults). The firmware reads the
mirror's rate every tick; below ``safe_rate_fraction`` of the nominal rate for longer than
``slow_grace_s`` (longer than any reversal) is a fault. Faults the emulator injects
(:class:`Mirror`): ``stall`` (the drive lost: the rate decays with the mirror's damping time
constant) and ``slow`` (a failing drive: the rate ramps down to 30 % of nominal).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from enum import IntEnum

from agent.head_link.messages import Reason, SafetyState

__all__ = ["MIN_WINDOW_RAD", "LaserSafety", "Mirror", "SafetySettings", "TripCause", "check_window"]

MIN_WINDOW_RAD = math.radians(2.0)
"""The narrowest window the firmware sweeps: the beam's energy spreads over the window, and
a narrower one concentrates it on a few degrees however fast the mirror turns (the
active planner's narrowest is 20°)."""
SCAN_HALF_RAD = math.radians(20.0)
WIRE_STEP_RAD = 1e-6  # angles travel in whole µrad


def check_window(low_rad: float, high_rad: float) -> Reason | None:
    """Why the firmware refuses a ``window`` command (``OUT_OF_RANGE``), or None: beyond
    ±20°, not low < high, or narrower than :data:`MIN_WINDOW_RAD`."""
    if not (math.isfinite(low_rad) and math.isfinite(high_rad)):
        return Reason.MALFORMED
    # To the wire's step (1 µrad): ±20° itself arrives rounded to it, either way.
    inside = low_rad >= -SCAN_HALF_RAD - WIRE_STEP_RAD and high_rad <= SCAN_HALF_RAD + WIRE_STEP_RAD
    if not inside or high_rad - low_rad < MIN_WINDOW_RAD - WIRE_STEP_RAD:
        return Reason.OUT_OF_RANGE
    return None


class TripCause(IntEnum):
    """Why the laser tripped."""

    NONE = 0
    MIRROR_STALL = 1
    MIRROR_SLOW = 2
    HEARTBEAT_LOST = 3
    BAD_COMMAND = 4


@dataclass(frozen=True)
class SafetySettings:
    """The firmware's safety constants.

    tick_s
        The control loop's period (1 kHz): every check runs once a tick.
    nominal_rate_rad_s
        The mirror's sweep rate, 40° in 0.1 s.
    safe_rate_fraction
        Below this share of the nominal rate the spot dwells too long: a fault once it lasts
        beyond a reversal. 0.5.
    stall_fraction
        Below this share the mirror has stalled (the cause reported), 5 %.
    slow_grace_s
        How long the rate may stay below the safe rate: a reversal's 1.0 ms (at
        ``accel_rad_s2``) with margin, 4 ms.
    heartbeat_timeout_s
        The host's heartbeat (every 0.1 s) missing this long is a lost host, 0.5 s.
    accel_rad_s2
        The galvanometer's angular acceleration at a reversal (7,000 rad/s²: a reversal at
        6.98 rad/s takes 2 ms).
    """

    tick_s: float = 0.001
    nominal_rate_rad_s: float = math.radians(40.0) / 0.1
    safe_rate_fraction: float = 0.5
    stall_fraction: float = 0.05
    slow_grace_s: float = 0.004
    heartbeat_timeout_s: float = 0.5
    accel_rad_s2: float = 7000.0

    def __post_init__(self) -> None:
        for name in ("tick_s", "nominal_rate_rad_s", "slow_grace_s", "heartbeat_timeout_s",
                     "accel_rad_s2"):  # fmt: skip
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0.0):
                raise ValueError(f"safety setting {name} must be positive, got {value!r}")
        if not 0.0 < self.stall_fraction < self.safe_rate_fraction < 1.0:
            raise ValueError("safety settings: need 0 < stall_fraction < safe_rate_fraction < 1")


@dataclass
class LaserSafety:
    """The state machine of the module docstring; times in seconds on the firmware's clock."""

    settings: SafetySettings = field(default_factory=SafetySettings)
    state: SafetyState = SafetyState.OFF
    cause: TripCause = TripCause.NONE
    trips: int = 0
    tripped_at_s: float = math.nan
    _last_heartbeat_s: float = -math.inf
    # Since when the mirror has been below the safe rate (None: it is not); before the first
    # tick it is taken as slow for ever.
    _slow_since_s: float | None = -math.inf

    @property
    def laser_on(self) -> bool:
        return self.state is SafetyState.ON

    @property
    def last_heartbeat_s(self) -> float:
        """When the host's last heartbeat came (−inf before the first)."""
        return self._last_heartbeat_s

    def _fresh(self, now_s: float) -> bool:
        return now_s - self._last_heartbeat_s <= self.settings.heartbeat_timeout_s

    def _trip(self, now_s: float, cause: TripCause) -> None:
        if self.state is SafetyState.ON:
            self.trips += 1
            self.tripped_at_s = now_s
        if self.state is not SafetyState.TRIPPED:
            self.state, self.cause = SafetyState.TRIPPED, cause

    def heartbeat(self, now_s: float) -> None:
        self._last_heartbeat_s = now_s

    def laser(self, now_s: float, on: bool) -> Reason | None:
        """A ``laser`` command: None when taken, else why it is refused."""
        if not on:
            if self.state is SafetyState.ON:
                self.state = SafetyState.OFF
            return None
        if self.state is SafetyState.TRIPPED:
            return Reason.LASER_LOCKED
        if not (self._fresh(now_s) and self._at_speed(now_s)):
            return Reason.NOT_READY
        self.state = SafetyState.ON
        return None

    def rearm(self, now_s: float) -> Reason | None:
        """A ``rearm``: from ``TRIPPED`` to ``OFF`` once the cause is gone."""
        if self.state is not SafetyState.TRIPPED:
            return None
        if not (self._fresh(now_s) and self._at_speed(now_s)):
            return Reason.NOT_READY
        self.state, self.cause = SafetyState.OFF, TripCause.NONE
        return None

    def bad_command(self, now_s: float) -> None:
        """A command the head cannot honour: the laser may not stay on after it."""
        self._trip(now_s, TripCause.BAD_COMMAND)

    def _at_speed(self, now_s: float) -> bool:
        """The mirror is at speed, or within a reversal's grace of it."""
        since = self._slow_since_s
        return since is None or now_s - since <= self.settings.slow_grace_s

    def tick(self, now_s: float, mirror_rate_rad_s: float) -> None:
        """One pass of the control loop: the mirror's rate now and the heartbeat's age."""
        st = self.settings
        slow = not (abs(mirror_rate_rad_s) >= st.safe_rate_fraction * st.nominal_rate_rad_s)
        if not slow:
            self._slow_since_s = None
        elif self._slow_since_s is None:
            self._slow_since_s = now_s
        if self.state is not SafetyState.ON:
            stalled = abs(mirror_rate_rad_s) < st.stall_fraction * st.nominal_rate_rad_s
            if self.cause is TripCause.MIRROR_SLOW and stalled:  # it went on slowing
                self.cause = TripCause.MIRROR_STALL
            return
        if not self._at_speed(now_s):
            stalled = abs(mirror_rate_rad_s) < st.stall_fraction * st.nominal_rate_rad_s
            self._trip(now_s, TripCause.MIRROR_STALL if stalled else TripCause.MIRROR_SLOW)
        elif not self._fresh(now_s):
            self._trip(now_s, TripCause.HEARTBEAT_LOST)


@dataclass
class Mirror:
    """The scan mirror's rate over time (module docstring): sweeping ``low``-``high`` at the
    nominal rate with reversals at ``accel_rad_s2``; ``fault`` ``"stall"`` from
    ``fault_at_s`` (rate decays with ``damping_s``) or ``"slow"`` (rate ramps to
    ``slow_to`` of nominal over ``slow_ramp_s``)."""

    settings: SafetySettings = field(default_factory=SafetySettings)
    low_rad: float = -math.radians(20.0)
    high_rad: float = math.radians(20.0)
    fault: str = ""
    fault_at_s: float = math.inf
    damping_s: float = 0.010
    slow_to: float = 0.3
    slow_ramp_s: float = 0.05
    angle_rad: float = 0.0
    rate_rad_s: float = field(init=False)
    _t_s: float = 0.0

    def __post_init__(self) -> None:
        if self.fault not in ("", "stall", "slow"):
            raise ValueError(f"mirror fault must be '', 'stall' or 'slow', got {self.fault!r}")
        if not self.low_rad < self.high_rad:
            raise ValueError("mirror window: need low < high")
        self.rate_rad_s = self.settings.nominal_rate_rad_s

    def _drive(self, t_s: float) -> float:
        """The speed the drive sustains at ``t_s`` (rad/s)."""
        nominal = self.settings.nominal_rate_rad_s
        if t_s < self.fault_at_s or not self.fault:
            return nominal
        if self.fault == "slow":
            f = min(1.0, (t_s - self.fault_at_s) / self.slow_ramp_s)
            return nominal * (1.0 - f * (1.0 - self.slow_to))
        return 0.0

    def advance(self, t_s: float) -> float:
        """Move to ``t_s`` in steps of at most 0.1 ms; the rate then (rad/s, signed)."""
        accel = self.settings.accel_rad_s2
        while self._t_s < t_s - 1e-12:
            dt = min(1e-4, t_s - self._t_s)
            self._t_s += dt
            speed = self._drive(self._t_s)
            if self.fault == "stall" and self._t_s >= self.fault_at_s:
                self.rate_rad_s *= math.exp(-dt / self.damping_s)  # no drive: damped
            else:
                # Toward the drive's speed in the sweep's direction, reversing at the ends
                # within the acceleration limit (braking to stop at the end).
                sign = 1.0 if self.rate_rad_s >= 0.0 else -1.0
                end = self.high_rad if sign > 0 else self.low_rad
                ahead = sign * (end - self.angle_rad)  # negative once past the end
                stopping = self.rate_rad_s**2 / (2.0 * accel) + abs(self.rate_rad_s) * dt
                target = -sign * speed if ahead <= stopping else sign * speed
                step = accel * dt
                self.rate_rad_s += max(-step, min(step, target - self.rate_rad_s))
            self.angle_rad += self.rate_rad_s * dt
        return self.rate_rad_s
