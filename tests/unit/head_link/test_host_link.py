"""The host's end of the link (agent.head_link.host) against the emulated head, on one
simulated clock: the handshake, commands, heartbeats keeping the laser on, the clock, and
sweeps that agree with the simulated head's own up to the protocol's quantisation."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from agent.head_link import messages as m
from agent.head_link.host import HeadLink
from agent.runtime.messages import HeadCommand, Header, RawScan, stamp_ns
from agent.sensor.samples import RawScan as Sweep
from agent.sim.world_file import load_world
from agent.stages.head_stage import HeadStage
from cli.head_emulator import EmulatedHead, Faults

ROOT = Path(__file__).resolve().parents[3]
STEP_S = 0.002


def _world():  # type: ignore[no-untyped-def]
    return load_world(ROOT / "worlds" / "demo.toml")


def _run(
    link: HeadLink, head: EmulatedHead, t0: float, t1: float, quiet_from: float = math.inf
) -> tuple[list[Sweep], float]:
    sweeps: list[Sweep] = []
    t = t0
    while t < t1 - 1e-9:
        t = round(t + STEP_S, 6)
        if t < quiet_from:
            link.poll(t)
            head.receive(link.take_output(), t)
        head.step(t)
        sweeps += link.feed(head.take_output(), t)
    return sweeps, t


def test_the_link_connects_commands_the_head_and_keeps_it_streaming() -> None:
    head = EmulatedHead(HeadStage(_world(), seed=3))
    link = HeadLink()
    link.command(0.4, -0.349, 0.349, True)
    sweeps, t = _run(link, head, 0.0, 1.5)
    assert link.connected and link.identity is not None
    assert link.identity.firmware == "emulator-1.0"
    assert link.streaming(t) and link.status is not None and link.status.laser_on
    assert abs(link.clock.offset_us) <= link.clock.error_us <= 2 * STEP_S * 1e6
    # 10 sweeps a second once the laser is on, alternating direction, 256 samples each.
    full = [s for s in sweeps if s.time_s.size == 256]
    assert len(full) >= 12
    assert {s.direction for s in full} == {-1, 1}
    assert np.abs(full[-1].pan_rad - 0.4).max() < 1e-3
    assert link.pan_rate_rad_s == 0.0  # settled: its pan rate from the statuses
    assert link.counters["refused"] == 0 and link.decoder.counters.dropped == 0
    # The host goes quiet: the head's laser goes off, and the link says it is not streaming.
    _, t = _run(link, head, t, t + 1.0, quiet_from=t)
    assert not link.streaming(t)
    assert link.status is not None and link.status.state is m.SafetyState.TRIPPED


def test_sweeps_over_the_link_agree_with_the_simulated_head_up_to_quantisation() -> None:
    # The same head (world, seed) run directly with the same commands at the same times:
    # each sweep's samples agree within the wire's steps (scan angle 10 µrad, pan 25 µrad,
    # time 0.5 µs plus the clock's stated error, currents 2⁻²⁴ relative).
    head = EmulatedHead(HeadStage(_world(), seed=5))
    link = HeadLink()
    link.command(-0.3, -0.2, 0.3, True)
    sweeps, _ = _run(link, head, 0.0, 1.2)
    direct = HeadStage(_world(), seed=5)
    direct.start(0.0)
    # The emulated head took the commands when it received them (the link's first poll
    # after the hello reply); replay them at those times on the direct head.
    took = head.stage._last_command_s  # the last command's time: pan, window, laser together
    assert took is not None

    def command(at: float, pan: float, low: float, high: float, laser: bool) -> None:
        direct.handle(
            "head_command",
            HeadCommand(header=Header(stamp_ns=stamp_ns(at)), pan_rad=pan, window_low_rad=low,
                        window_high_rad=high, laser=laser),
            at,
        )  # fmt: skip

    command(0.0, 0.0, -0.349, 0.349, False)  # the emulator starts with the laser off
    command(took, -0.3, -0.2, 0.3, True)
    scans: list[RawScan] = []
    t = took
    while t < 1.2:
        nxt = direct.next_tick_s()
        assert nxt is not None
        t = nxt
        scans += [msg for topic, msg in direct.tick(t) if topic == "raw_scan"]  # type: ignore[misc]
    by_start = {round(float(s.time_s[0]), 4): s for s in scans}
    matched = 0
    for sweep in sweeps:
        scan = by_start.get(round(float(sweep.time_s[0]), 4))
        if scan is None or scan.time_s.size != sweep.time_s.size:
            continue
        matched += 1
        assert sweep.direction == scan.direction
        assert np.abs(sweep.mirror_angle_rad - scan.mirror_angle_rad).max() <= 1e-5 + 1e-12
        assert np.abs(sweep.pan_rad - scan.pan_rad).max() <= 2.5e-5 + 1e-12
        err = link.clock.error_us * 1e-6 + 0.5e-6 + abs(link.clock.offset_us) * 1e-6
        assert np.abs(sweep.time_s - scan.time_s).max() <= err + 1e-9
        np.testing.assert_allclose(sweep.current_1_A, scan.current_1_A, rtol=2**-23, atol=0)
        np.testing.assert_allclose(sweep.current_2_A, scan.current_2_A, rtol=2**-23, atol=0)
    assert matched >= 8, matched


def test_a_wrong_protocol_version_is_not_connected() -> None:
    link = HeadLink()
    from agent.head_link.frames import encode_frame

    link.feed(encode_frame(m.HelloReply.TYPE, 0, m.HelloReply(2, "x", "y", "z").pack()), 0.0)
    assert not link.connected and link.counters["wrong_version"] == 1


def test_a_garbled_line_is_counted_not_raised() -> None:
    head = EmulatedHead(HeadStage(_world(), seed=1), faults=Faults(flip=0.001))
    link = HeadLink()
    link.command(0.0, -0.349, 0.349, True)
    sweeps, _ = _run(link, head, 0.0, 1.0)
    assert link.decoder.counters.crc_errors + link.decoder.counters.cobs_errors > 0
    assert sweeps  # the sweeps that lost a frame end at the gap; the rest come whole


def test_the_pan_rate_is_read_from_the_statuses_while_the_head_slews() -> None:
    head = EmulatedHead(HeadStage(_world(), seed=2))
    link = HeadLink()
    link.command(1.5, -0.349, 0.349, True)
    _run(link, head, 0.0, 0.5)  # a 1.5 rad slew at up to 3.1 rad/s takes about 0.7 s
    assert link.pan_rate_rad_s > 1.0
