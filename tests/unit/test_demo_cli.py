"""``sensor-agent demo``'s arguments and the launch files it rewrites."""

from __future__ import annotations

import argparse
from pathlib import Path

import pytest

from agent.errors import ConfigError
from cli.demo import LAUNCH_FILE, ROOT, SERIAL_LAUNCH_FILE, demo_command


def test_serial_runs_processes_only() -> None:
    args = argparse.Namespace(
        world=None, policy="forward", controller="default", out="unused", lockstep=True,
        serial=True,
    )  # fmt: skip
    with pytest.raises(ConfigError, match="--serial"):
        demo_command(args)


@pytest.mark.parametrize("launch", [LAUNCH_FILE, SERIAL_LAUNCH_FILE])
def test_the_launch_files_hold_what_the_demo_replaces(launch: Path) -> None:
    # run_processes rewrites these literals; a launch file that changed them would leave the
    # demo driving the default world or the default policy without a word.
    text = launch.read_text()
    assert '"../worlds/demo.toml"' in text
    assert 'policy = "active"' in text
    assert 'planner = "default"' in text
    if launch == SERIAL_LAUNCH_FILE:
        assert 'port = "/tmp/lep-head"' in text
    assert (ROOT / "worlds" / "demo.toml").exists()


def test_the_main_job_docks_in_the_demo_world(tmp_path: Path) -> None:
    """What `python3 run.py` runs (`sensor-agent demo --lockstep`): the shipped demo world's
    dock, seed 0, done, with every output written and the run record saying so. In
    lock-step the run is the same on every machine: a change that breaks the README's main
    command fails here."""
    import json

    args = argparse.Namespace(
        world=None, policy="active", controller="default", out=str(tmp_path), lockstep=True,
        serial=False,
    )  # fmt: skip
    assert demo_command(args) == 0
    record = json.loads((tmp_path / "summary.json").read_text())
    assert record["outcome"] == "success" and record["collision_by"] is None
    for name in ("run.mcap", "run.png", "run.gif"):
        assert (tmp_path / name).stat().st_size > 0
