"""``sensor-agent safety-test [--trials N] [--seed S] [--json FILE]``: the laser's safety
state machine under injected faults (``docs/head-protocol.md`` §5).

Each trial runs the head firmware's control loop (:class:`agent.head_link.safety.LaserSafety`
at its 1 kHz tick) over the scan mirror (:class:`agent.head_link.safety.Mirror`) on the
firmware's own clock: a random window (5-40° within ±20°), the mirror at a random place and
direction, the host's heartbeat every 0.1 s with ±10 ms jitter, the laser switched on once the
mirror is at speed, then one fault at a random time 50-300 ms later. The figure is the time
from the fault to the laser off:

* ``mirror_stall``: the drive lost (the mirror's rate decays with its 10 ms damping);
* ``mirror_slow``: a failing drive (the rate ramps to 30 % of nominal over 50 ms);
* ``heartbeat_lost``: the host stops; the fault is the documented timeout (0.5 s after the
  last heartbeat) expiring;
* ``bad_command``: a command the head cannot honour arrives (taken at the next tick, as the
  firmware reads its port once a tick).

A trial fails when the laser is still on 100 ms after the fault. Beside them, ``false_trips``:
the same loop without faults over ``--trials`` × 2 s of sweeping, which must never trip (the
mirror's reversals, below the safe rate for 1 ms each, must not count). Prints the table;
``--json`` writes ``{"causes": {<cause>: {"trials", "max_ms", "p50_ms", "failures"}},
"false_trips": {"seconds", "trips"}}``.
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path
from typing import Any

import numpy as np

from agent.head_link.safety import LaserSafety, Mirror, SafetySettings
from cli.output import write_json

CAUSES = ("mirror_stall", "mirror_slow", "heartbeat_lost", "bad_command")
LIMIT_S = 0.1  # the laser must be off within this of the fault
HEARTBEAT_S = 0.1


def _window(rng: np.random.Generator) -> tuple[float, float]:
    width = math.radians(float(rng.uniform(5.0, 40.0)))
    low = float(rng.uniform(-math.radians(20.0), math.radians(20.0) - width))
    return low, low + width


def _heartbeats(rng: np.random.Generator, until_s: float) -> list[float]:
    n = int(until_s / HEARTBEAT_S) + 1
    return sorted(float(t) for t in np.arange(n) * HEARTBEAT_S + rng.uniform(-0.01, 0.01, n))


def _start(rng: np.random.Generator, settings: SafetySettings) -> tuple[Mirror, LaserSafety]:
    low, high = _window(rng)
    mirror = Mirror(settings, low, high, angle_rad=float(rng.uniform(low, high)))
    if rng.random() < 0.5:
        mirror.rate_rad_s = -mirror.rate_rad_s
    return mirror, LaserSafety(settings)


def trial(cause: str, rng: np.random.Generator, settings: SafetySettings) -> float:
    """One trial: seconds from the fault to the laser off; inf when it stayed on, −inf when
    it went off before the fault (a false trip)."""
    mirror, safety = _start(rng, settings)
    tick = settings.tick_s
    t = float(rng.uniform(0.0, tick))  # the tick's phase against the host's clock
    beats = _heartbeats(rng, 3.0)
    fault_after = float(rng.uniform(0.05, 0.3))
    on_at: float | None = None
    fault_at = stop_beats = command_at = math.inf
    while t < 3.0:
        while beats and beats[0] <= min(t, stop_beats):
            safety.heartbeat(beats.pop(0))
        if on_at is None and t > 0.02 and safety.laser(t, True) is None:
            on_at, fault_at = t, t + fault_after
            if cause in ("mirror_stall", "mirror_slow"):
                mirror.fault, mirror.fault_at_s = cause.removeprefix("mirror_"), fault_at
            elif cause == "heartbeat_lost":
                stop_beats = fault_at  # the host sends nothing after this
            else:
                command_at = fault_at
        if t >= command_at:  # read from the port at the first tick after it came
            safety.bad_command(t)
            command_at = math.inf
        safety.tick(t, mirror.advance(t))
        if on_at is not None and not safety.laser_on:
            start = (
                safety.last_heartbeat_s + settings.heartbeat_timeout_s
                if cause == "heartbeat_lost"
                else fault_at
            )
            return t - start if t >= start else -math.inf
        if t > fault_at + 1.0:
            return math.inf
        t += tick
    return math.inf


def control(rng: np.random.Generator, settings: SafetySettings, seconds: float) -> int:
    """Trips in ``seconds`` of sweeping with the laser on and nothing wrong."""
    mirror, safety = _start(rng, settings)
    beats = _heartbeats(rng, seconds + 0.1)
    t = float(rng.uniform(0.0, settings.tick_s))
    while t < seconds:
        while beats and beats[0] <= t:
            safety.heartbeat(beats.pop(0))
        if safety.state.name == "OFF" and t > 0.02:
            safety.laser(t, True)
        safety.tick(t, mirror.advance(t))
        t += settings.tick_s
    return safety.trips


def run(trials: int, seed: int) -> dict[str, Any]:
    """Every cause's trials and the fault-free control (module docstring)."""
    settings = SafetySettings()
    rng = np.random.default_rng(seed)
    causes: dict[str, Any] = {}
    false_trips = 0
    for cause in CAUSES:
        lat = np.array([trial(cause, rng, settings) for _ in range(trials)])
        false_trips += int(np.sum(lat == -math.inf))
        ok = np.isfinite(lat)
        causes[cause] = {
            "trials": trials,
            "max_ms": float(lat[ok].max() * 1e3) if ok.any() else None,
            "p50_ms": float(np.median(lat[ok]) * 1e3) if ok.any() else None,
            "failures": int(np.sum(~ok | (lat > LIMIT_S))),
        }
    seconds = 2.0
    trips = sum(control(rng, settings, seconds) for _ in range(trials))
    return {
        "seed": seed,
        "limit_ms": LIMIT_S * 1e3,
        "causes": causes,
        "false_trips": {"seconds": trials * seconds, "trips": trips + false_trips},
    }


def safety_test_command(args: argparse.Namespace) -> int:
    """``sensor-agent safety-test``: the table, and ``--json``."""
    doc = run(args.trials, args.seed)
    print(f"laser safety under injected faults ({args.trials} trials each, seed {args.seed})")
    print(f"  {'cause':16s} {'trials':>7s} {'p50 (ms)':>9s} {'max (ms)':>9s} {'failures':>9s}")
    for cause, c in doc["causes"].items():
        p50 = "-" if c["p50_ms"] is None else f"{c['p50_ms']:.2f}"
        worst = "-" if c["max_ms"] is None else f"{c['max_ms']:.2f}"
        print(f"  {cause:16s} {c['trials']:7d} {p50:>9s} {worst:>9s} {c['failures']:9d}")
    f = doc["false_trips"]
    print(f"  no fault: {f['trips']} trips in {f['seconds']:.0f} s of sweeping")
    print(f"  limit: off within {doc['limit_ms']:.0f} ms of the fault")
    if args.json:
        write_json(Path(args.json), doc)
    failed = sum(c["failures"] for c in doc["causes"].values()) + f["trips"]
    return 1 if failed else 0
