"""A short soak (cli.soak): the closed loop over the serial emulator while a random process
of the agent is killed every 4 s. The vehicle never moves on stale vectors, nothing leaks,
every killed process comes back. (`sensor-agent soak` runs the 10-minute version.)"""

from __future__ import annotations

import pytest

pytest.importorskip("serial")


def test_a_short_soak_passes() -> None:
    from cli.soak import soak

    doc = soak(minutes=0.3, kill_every_s=4.0, seed=1)
    assert doc["graph_alive"], doc
    assert doc["kills"] >= 3 and doc["restarts"] >= doc["kills"] - 1, doc
    assert doc["moved_on_stale"] == 0, doc
    assert doc["fd_growth"] <= 0, doc
    assert doc["rss_growth"] is not None and doc["rss_growth"] < 0.05, doc
    assert doc["outcome"] == "pass"
