"""The passive head policies: within the head's limits, and the sweep's sequence."""

from __future__ import annotations

import math

import pytest

from agent.errors import ConfigError
from agent.planning.policies import (
    ForwardPolicy,
    HeadLimits,
    HeadView,
    SweepPolicy,
    make_policy,
    sweep_pans,
)

LIMITS = HeadLimits()


def _view(pan_deg: float, sweeps: int, settled: bool = True) -> HeadView:
    pan = math.radians(pan_deg)
    return HeadView(
        stamp_s=0.0, pan_rad=pan, target_pan_rad=pan, window_low_rad=-0.35,
        window_high_rad=0.35, settled=settled, sweeps=sweeps, laser_on=True,
        command_accepted=True,
    )  # fmt: skip


def test_forward_is_pan_zero_with_the_full_window() -> None:
    target = ForwardPolicy(LIMITS).choose(None, 0.0)
    assert target.pan_rad == 0.0
    assert target.window_low_rad == pytest.approx(-math.radians(20))
    assert target.window_high_rad == pytest.approx(math.radians(20))
    assert target.within(LIMITS)


def test_sweep_pans_tile_the_head_range() -> None:
    pans = [round(math.degrees(p)) for p in sweep_pans(math.radians(40), LIMITS)]
    assert pans == [-80, -40, 0, 40, 80]
    assert [round(math.degrees(p)) for p in sweep_pans(math.radians(30), LIMITS)] == [
        -90, -60, -30, 0, 30, 60, 90,
    ]  # fmt: skip
    with pytest.raises(ConfigError, match="exceeds the pan limit"):
        sweep_pans(math.radians(100), LIMITS)


def test_sweep_steps_there_and_back_one_settled_sweep_per_step() -> None:
    policy = SweepPolicy(math.radians(40), dwell_sweeps=1, limits=LIMITS)
    seen: list[int] = []
    for sweeps in range(40):
        target = policy.choose(_view(math.degrees(policy.pan_rad), sweeps), 0.0)
        assert target.within(LIMITS)
        assert target.window_high_rad - target.window_low_rad == pytest.approx(math.radians(40))
        pan = round(math.degrees(target.pan_rad))
        if not seen or seen[-1] != pan:
            seen.append(pan)
    assert seen[:10] == [0, 40, 80, 40, 0, -40, -80, -40, 0, 40]


def test_sweep_waits_for_the_head_to_settle() -> None:
    policy = SweepPolicy(math.radians(40), dwell_sweeps=2, limits=LIMITS)
    assert policy.choose(_view(0, 5), 0.0).pan_rad == 0.0  # settled at 5
    assert policy.choose(_view(0, 6), 0.0).pan_rad == 0.0  # one sweep: dwell is 2
    assert policy.choose(_view(0, 7), 0.0).pan_rad == pytest.approx(math.radians(40))
    # Slewing (not settled) or elsewhere: it holds its target.
    for sweeps in range(8, 20):
        assert policy.choose(_view(20, sweeps, settled=False), 0.0).pan_rad == pytest.approx(
            math.radians(40)
        )


def test_unknown_policy_is_refused_by_name() -> None:
    with pytest.raises(
        ConfigError, match="unknown head policy 'stare'; choose one of forward, sweep"
    ):
        make_policy("stare", LIMITS)
    with pytest.raises(ConfigError, match="dwell"):
        SweepPolicy(dwell_sweeps=0)
