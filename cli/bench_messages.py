"""Realistic messages of every type the bench times: what the graph actually carries.

* ``raw_scan``: full 256-sample sweeps of the simulated head in the office world.
* ``calibrated_scan``, ``filtered_scan``, ``features``, ``tracks``, ``environment``: those raw
  scans through the stages of ``launch/agent.toml`` in the lock-step runner (the vehicle
  standing at the world's start pose), as its processes would publish them.
* The small ones (``vehicle_state``, ``odometry``, ``head_command``, ``head_state``,
  ``heartbeat``, ``world_truth``): built here with values and sizes as the graph sends them
  (a heartbeat carries the counters of a filtering process).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from agent.kinematics.trajectory import StaticPose
from agent.runtime import topics
from agent.runtime.launch import load_launch
from agent.runtime.messages import (
    HeadCommand,
    Header,
    HeadState,
    Heartbeat,
    Message,
    Odometry,
    RawScan,
    VehicleState,
    WorldTruth,
)
from agent.sensor.params import simulated_head
from agent.sim.simulator import SensorSimulator
from agent.sim.world_file import load_world
from agent.stages.head_stage import raw_scan_message
from processes.runtime import lockstep_graph

ROOT = Path(__file__).resolve().parents[1]
AGENT_LAUNCH = ROOT / "launch" / "agent.toml"
STAGE_TOPICS = (
    topics.CALIBRATED_SCAN,
    topics.FILTERED_SCAN,
    topics.FEATURES,
    topics.TRACKS,
    topics.ENVIRONMENT,
)
OFFICE_POSE = load_world(ROOT / "worlds" / "office.toml").vehicle_pose  # where the scans are made


def standing_vehicle_state(stamp_ns: int, seq: int) -> VehicleState:
    """The vehicle state of the bench's scans: standing at the office world's start pose
    (``odom`` = ``world``), stamped ``stamp_ns``; sent before each scan, as a controller's
    states arrive ahead of the scans they place."""
    x, y, yaw = OFFICE_POSE
    return VehicleState(
        header=Header(stamp_ns=stamp_ns, seq=seq, frame_id="odom", source="vehicle"),
        x_m=x, y_m=y, yaw_rad=yaw, speed_m_s=0.0, yaw_rate_rad_s=0.0,
        pose_covariance=np.diag([1e-6, 1e-6, 1e-7]), intent_xy=np.zeros((0, 2)),
    )  # fmt: skip


def raw_scans(n: int, seed: int = 0) -> list[RawScan]:
    """Distinct simulated raw scans of the office world (cycled by the bench)."""
    world = load_world(ROOT / "worlds" / "office.toml")
    sim = SensorSimulator(world, simulated_head(), np.random.default_rng(seed))
    pose = StaticPose(*world.vehicle_pose)
    out = []
    for i in range(n):
        raw, _ = sim.sweep(direction=1 if i % 2 == 0 else -1, trajectory=pose, start_time_s=0.1 * i)
        out.append(raw_scan_message(raw, i))
    return out


def graph_messages(raws: list[RawScan]) -> dict[str, list[Message]]:
    """Per topic, realistic messages of its type: one per raw scan for the scan topics."""
    runner = lockstep_graph(load_launch(AGENT_LAUNCH))
    found: dict[str, list[Message]] = {t: [] for t in STAGE_TOPICS}

    def keep(_t: float, topic: str, msg: Message) -> None:
        if topic in found:
            found[topic].append(msg)

    runner.observe(keep)
    for i, raw in enumerate(raws):
        runner.inject(
            topics.VEHICLE_STATE, standing_vehicle_state(raw.header.stamp_ns, i), source="vehicle"
        )
        runner.inject(topics.RAW_SCAN, raw.with_header(seq=i), source="head")
    for topic, got in found.items():
        if len(got) != len(raws):
            raise RuntimeError(f"the agent graph published {len(got)} {topic} for {len(raws)}")
    filtering = next(n for n in runner.nodes if n.name == "filtering")
    now_ns = raws[-1].header.stamp_ns
    x, y, yaw = 2.0, 1.5, 0.3
    small: dict[str, list[Message]] = {
        topics.VEHICLE_STATE: [
            VehicleState(
                header=Header(stamp_ns=now_ns, seq=41, frame_id="odom", source="vehicle"),
                x_m=x, y_m=y, yaw_rad=yaw, speed_m_s=0.4, yaw_rate_rad_s=0.05,
                pose_covariance=np.diag([1e-4, 1e-4, 3e-5]),
                intent_xy=np.array([[2.5, 1.6], [3.0, 1.8], [3.5, 2.2], [4.0, 2.8]]),
            )
        ],
        topics.ODOMETRY: [
            Odometry(
                header=Header(stamp_ns=now_ns, seq=41, frame_id="odom", source="world"),
                x_m=x, y_m=y, yaw_rad=yaw, speed_m_s=0.4, yaw_rate_rad_s=0.05,
                pose_covariance=np.diag([1e-4, 1e-4, 3e-5]), distance_m=12.5,
            )
        ],
        topics.HEAD_COMMAND: [
            HeadCommand(
                header=Header(stamp_ns=now_ns, seq=7, frame_id="base_link", source="planner"),
                pan_rad=0.4, window_low_rad=-math.radians(20), window_high_rad=math.radians(20),
            )
        ],
        topics.HEAD_STATE: [
            HeadState(
                header=Header(stamp_ns=now_ns, seq=len(raws), frame_id="base_link", source="head"),
                pan_rad=0.39, pan_rate_rad_s=0.1, target_pan_rad=0.4,
                window_low_rad=-math.radians(20), window_high_rad=math.radians(20),
                laser_on=True, mode="scanning", command_seq=7, sweeps=len(raws),
            )
        ],
        topics.HEARTBEAT: [
            Heartbeat(
                header=Header(stamp_ns=now_ns, seq=12, source="filtering"),
                process="filtering", pid=4242, state="running",
                counters={
                    "received": len(raws), "published": len(raws) + 12, "lost": 0,
                    **filtering.stage.counters(),
                },
            )
        ],
        topics.WORLD_TRUTH: [
            WorldTruth(
                header=Header(stamp_ns=now_ns, seq=2 * len(raws), frame_id="world", source="world"),
                x_m=x, y_m=y, yaw_rad=yaw, speed_m_s=0.4, yaw_rate_rad_s=0.05,
                world_name="office",
                mover_xy=np.array([[x + 1.5, y - 0.5], [x + 2.0, y + 1.0]]),
                mover_velocity_xy=np.array([[0.4, 0.0], [0.0, -0.6]]),
                mover_radius_m=np.array([0.2, 0.15]),
            )
        ],
    }  # fmt: skip
    return {topics.RAW_SCAN: list(raws), **found, **small}
