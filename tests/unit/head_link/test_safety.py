"""The laser's safety state machine and the mirror it watches (docs/head-protocol.md §5),
and the safety test's measurement."""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path

import numpy as np
import pytest

from agent.head_link.messages import Reason, SafetyState
from agent.head_link.safety import LaserSafety, Mirror, SafetySettings, TripCause

NOMINAL = SafetySettings().nominal_rate_rad_s


def _running(now: float = 0.1) -> LaserSafety:
    safety = LaserSafety()
    safety.heartbeat(now)
    safety.tick(now, NOMINAL)
    assert safety.laser(now, True) is None and safety.laser_on
    return safety


def test_the_laser_goes_on_only_with_the_mirror_at_speed_and_the_host_alive() -> None:
    safety = LaserSafety()
    assert safety.laser(0.0, True) is Reason.NOT_READY  # no tick, no heartbeat yet
    safety.tick(0.0, NOMINAL)
    assert safety.laser(0.0, True) is Reason.NOT_READY  # no heartbeat
    safety.heartbeat(0.0)
    safety.tick(0.001, 0.2 * NOMINAL)
    assert safety.laser(0.01, True) is Reason.NOT_READY  # slow for 9 ms
    safety.tick(0.011, NOMINAL)
    assert safety.laser(0.011, True) is None and safety.state is SafetyState.ON
    assert safety.laser(0.012, False) is None and safety.state is SafetyState.OFF


@pytest.mark.parametrize(
    ("rate", "cause"),
    [(0.0, TripCause.MIRROR_STALL), (0.3 * NOMINAL, TripCause.MIRROR_SLOW)],
)
def test_a_slow_mirror_trips_after_the_grace_and_not_before(rate: float, cause: TripCause) -> None:
    safety = _running(0.1)
    for k in range(1, 5):  # 4 ms below the safe rate: a reversal's worth, allowed
        safety.tick(0.1 + 0.001 * k, rate)
    assert safety.laser_on
    safety.tick(0.1055, rate)
    assert safety.state is SafetyState.TRIPPED and safety.cause is cause and safety.trips == 1


def test_a_tripped_laser_stays_off_until_rearmed_once_the_cause_is_gone() -> None:
    safety = _running(0.1)
    safety.tick(0.7, NOMINAL)  # no heartbeat since 0.1 s: lost
    assert safety.cause is TripCause.HEARTBEAT_LOST and not safety.laser_on
    assert safety.laser(0.71, True) is Reason.LASER_LOCKED
    assert safety.rearm(0.71) is Reason.NOT_READY  # the host still silent
    safety.heartbeat(0.72)
    assert safety.laser(0.72, True) is Reason.LASER_LOCKED
    assert safety.rearm(0.72) is None and safety.state is SafetyState.OFF
    assert safety.laser(0.72, True) is None and safety.laser_on


def test_a_command_it_cannot_honour_switches_the_laser_off() -> None:
    safety = _running()
    safety.bad_command(0.2)
    assert safety.cause is TripCause.BAD_COMMAND and safety.tripped_at_s == 0.2
    idle = LaserSafety()
    idle.bad_command(0.0)  # with the laser off, it is held off as well
    assert idle.state is SafetyState.TRIPPED and idle.trips == 0


def test_the_mirror_sweeps_its_window_and_is_slow_only_at_reversals() -> None:
    st = SafetySettings()
    mirror = Mirror(st, -0.2, 0.3)
    t = np.arange(1, 20001) * 1e-4  # 2 s at 0.1 ms
    rates, angles = np.array([(mirror.advance(float(x)), mirror.angle_rad) for x in t]).T
    # Within its window, to the braking's last step (0.7 mrad at 0.1 ms).
    assert angles.min() >= -0.2 - 7e-4 and angles.max() <= 0.3 + 7e-4
    slow = np.abs(rates) < st.safe_rate_fraction * NOMINAL
    starts = np.flatnonzero(slow[1:] & ~slow[:-1])
    reversals = 2.0 / (0.5 / NOMINAL)  # one each way per traverse
    assert abs(len(starts) - reversals) <= 2
    runs = np.diff(np.flatnonzero(np.diff(slow.astype(np.int8)) != 0))[::2] * 1e-4
    # Each reversal below the safe rate for 2·ω·(1 − f)/α = 1.0 ms, to the steps' 0.1 ms.
    assert runs.max() <= 2 * NOMINAL * (1 - st.safe_rate_fraction) / st.accel_rad_s2 + 3e-4


def test_injected_mirror_faults_slow_the_mirror() -> None:
    stall = Mirror(fault="stall", fault_at_s=0.05)
    slow = Mirror(fault="slow", fault_at_s=0.05)
    stall.advance(0.1)
    slow.advance(0.2)
    assert abs(stall.rate_rad_s) < 0.01 * NOMINAL
    assert abs(slow.rate_rad_s) == pytest.approx(0.3 * NOMINAL, rel=1e-6)
    with pytest.raises(ValueError, match="mirror fault"):
        Mirror(fault="melt")


def test_safety_test_turns_the_laser_off_in_time_for_every_cause(tmp_path: Path) -> None:
    # 30 trials of each cause (fixed seed): every fault switches the laser off within
    # 100 ms (the firmware's duty), and 60 s of fault-free sweeping never trips it.
    from cli.safety_test import CAUSES, safety_test_command

    out = tmp_path / "safety.json"
    args = argparse.Namespace(trials=30, seed=1, json=str(out))
    assert safety_test_command(args) == 0
    doc = json.loads(out.read_text())
    assert set(doc["causes"]) == set(CAUSES)
    for cause, c in doc["causes"].items():
        assert set(c) == {"trials", "max_ms", "p50_ms", "failures"}
        assert c["trials"] == 30 and c["failures"] == 0, cause
        assert 0.0 <= c["p50_ms"] <= c["max_ms"] < 100.0, cause
    assert doc["false_trips"] == {"seconds": 60.0, "trips": 0}
    # The mirror faults take what the physics says: the rate falls below half its nominal
    # 6.9 ms after a stall (10 ms damping) and 36 ms into a slowing ramp, then 4 ms of grace.
    assert 10.0 < doc["causes"]["mirror_stall"]["p50_ms"] < 13.0
    assert 39.0 < doc["causes"]["mirror_slow"]["p50_ms"] < 42.0
    assert math.isclose(doc["limit_ms"], 100.0)


def test_windows_the_firmware_refuses() -> None:
    from agent.head_link.safety import check_window

    deg = math.radians
    assert check_window(deg(-20), deg(20)) is None
    assert check_window(-0.349066, 0.349066) is None  # ±20° as the wire rounds it (µrad)
    assert check_window(deg(5), deg(7)) is None
    assert check_window(deg(5), deg(6.5)) is Reason.OUT_OF_RANGE  # narrower than 2°
    assert check_window(deg(-21), deg(0)) is Reason.OUT_OF_RANGE
    assert check_window(deg(3), deg(1)) is Reason.OUT_OF_RANGE
    assert check_window(math.nan, 0.1) is Reason.MALFORMED
