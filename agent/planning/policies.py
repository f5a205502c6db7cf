"""Head policies: where to point the head and which window to scan.

A policy is one small choice, ``choose(head, now_s, situation) -> HeadTarget``: from what the
head last reported (:class:`HeadView`, or ``None`` before it has reported), the time, and (for
the planners that use it) what the agent knows (:class:`agent.planning.active.Situation`),
the pan and window it should have. The planner stage sends a command when that target changes (and
again when the head shows it did not take it); an active planner replaces only this choice.

* :class:`ForwardPolicy`: pan 0, the full window (±20°). The passive baseline of a fixed head.
* :class:`agent.planning.active.ActivePolicy` (``active``): where it pays, by each action's
  utility against its time; :class:`agent.planning.active.GreedyPolicy` (``greedy``): the
  most track uncertainty reduced, whatever the time or the path (a baseline).
* :class:`SweepPolicy`: pan stepping through the head's range with the full window, so that
  the windows tile (40° steps: pans −80°, −40°, 0°, 40°, 80° cover ±100°), there and back,
  dwelling ``dwell_sweeps`` whole sweeps at each step once the head has settled on it. No
  regard to anything else: the blind-sweep baseline.

Angles in radians, ``base_link`` (REP-103: counter-clockwise positive, 0 straight ahead).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Protocol

from agent.errors import ConfigError
from agent.sensor.params import SensorParameters

POLICIES = ("forward", "sweep", "active", "greedy")


@dataclass(frozen=True)
class HeadLimits:
    """What the head accepts: pan within ±``pan_limit_rad``, windows within
    ±``scan_half_angle_rad``."""

    pan_limit_rad: float = math.radians(90.0)
    scan_half_angle_rad: float = math.radians(20.0)

    @classmethod
    def of(cls, sensor: SensorParameters) -> HeadLimits:
        return cls(sensor.pan_limit_rad, sensor.scan_half_angle_rad)


@dataclass(frozen=True)
class HeadTarget:
    """A pan and scan window for the head (rad)."""

    pan_rad: float
    window_low_rad: float
    window_high_rad: float

    def within(self, limits: HeadLimits) -> bool:
        """True if the head accepts it."""
        return (
            abs(self.pan_rad) <= limits.pan_limit_rad
            and -limits.scan_half_angle_rad <= self.window_low_rad < self.window_high_rad
            and self.window_high_rad <= limits.scan_half_angle_rad
        )

    def matches(self, pan_rad: float, low_rad: float, high_rad: float, tol_rad: float) -> bool:
        return (
            abs(self.pan_rad - pan_rad) <= tol_rad
            and abs(self.window_low_rad - low_rad) <= tol_rad
            and abs(self.window_high_rad - high_rad) <= tol_rad
        )


@dataclass(frozen=True)
class HeadView:
    """What the head last reported (``head_state``), as a policy sees it."""

    stamp_s: float
    pan_rad: float
    target_pan_rad: float
    window_low_rad: float
    window_high_rad: float
    settled: bool  # scanning, at its target, not moving
    sweeps: int  # sweeps completed since the head started
    laser_on: bool
    command_accepted: bool


class HeadPolicy(Protocol):
    """Chooses the head's target from the head's last report, the time and (optionally)
    what the agent knows."""

    name: str

    def choose(self, head: HeadView | None, now_s: float, situation: Any = None) -> HeadTarget: ...


class ForwardPolicy:
    """Pan 0 with the full window, always."""

    name = "forward"

    def __init__(self, limits: HeadLimits | None = None) -> None:
        self.limits = limits if limits is not None else HeadLimits()

    def choose(self, head: HeadView | None, now_s: float, situation: Any = None) -> HeadTarget:
        half = self.limits.scan_half_angle_rad
        return HeadTarget(0.0, -half, half)


def sweep_pans(step_rad: float, limits: HeadLimits) -> list[float]:
    """The sweep's pans: multiples of ``step_rad`` within the pan limit, lowest first."""
    if not (math.isfinite(step_rad) and step_rad > 0):
        raise ConfigError(f"sweep step must be a positive angle, got {step_rad} rad")
    k = math.floor(limits.pan_limit_rad / step_rad + 1e-9)
    if k < 1:
        raise ConfigError(
            f"sweep step {math.degrees(step_rad):g} deg exceeds the pan limit "
            f"{math.degrees(limits.pan_limit_rad):g} deg: nothing to step through"
        )
    return [i * step_rad for i in range(-k, k + 1)]


class SweepPolicy:
    """Pan stepping through the head's range and back, the full window, ``dwell_sweeps``
    sweeps per step.

    It starts at pan 0 moving to positive pans. It moves on when the head, settled at the
    current pan, has completed ``dwell_sweeps`` more sweeps: a report that shows it settled
    with ``sweeps = N`` means sweep ``N + 1`` runs wholly at that pan (the head stamps its
    state at each sweep's end).
    """

    name = "sweep"

    def __init__(
        self,
        step_rad: float = math.radians(40.0),
        dwell_sweeps: int = 1,
        limits: HeadLimits | None = None,
    ) -> None:
        if dwell_sweeps < 1:
            raise ConfigError(f"sweep dwell must be at least 1 sweep, got {dwell_sweeps}")
        self.limits = limits if limits is not None else HeadLimits()
        self.pans = sweep_pans(step_rad, self.limits)
        k = len(self.pans) // 2
        # There and back: indices 0 .. 2k then 2k-1 .. 1; start at pan 0 heading up.
        self.sequence = list(range(len(self.pans))) + list(range(len(self.pans) - 2, 0, -1))
        self.position = self.sequence.index(k)
        self.dwell_sweeps = dwell_sweeps
        self._settled_at: int | None = None  # head's sweeps when first seen settled here

    @property
    def pan_rad(self) -> float:
        return self.pans[self.sequence[self.position]]

    def choose(self, head: HeadView | None, now_s: float, situation: Any = None) -> HeadTarget:
        half = self.limits.scan_half_angle_rad
        if head is not None and head.settled and abs(head.pan_rad - self.pan_rad) < 1e-3:
            if self._settled_at is None:
                self._settled_at = head.sweeps
            elif head.sweeps >= self._settled_at + self.dwell_sweeps:
                self.position = (self.position + 1) % len(self.sequence)
                self._settled_at = None
        return HeadTarget(self.pan_rad, -half, half)


def make_policy(
    name: str,
    limits: HeadLimits,
    sweep_step_rad: float = math.radians(40.0),
    sweep_dwell_sweeps: int = 1,
) -> HeadPolicy:
    """The policy called ``name`` (:data:`POLICIES`); ConfigError naming it otherwise."""
    if name == "forward":
        return ForwardPolicy(limits)
    if name == "sweep":
        return SweepPolicy(sweep_step_rad, sweep_dwell_sweeps, limits)
    if name in ("active", "greedy"):
        from agent.planning.active import ActivePolicy, GreedyPolicy

        return (ActivePolicy if name == "active" else GreedyPolicy)(limits=limits)
    raise ConfigError(f"unknown head policy {name!r}; choose one of {', '.join(POLICIES)}")
