"""The whole simulated graph with tracking and the planner, and tracking's agreement between
lock-step and processes.

* ``launch/sim.toml`` with a thread playing the vehicle controller (odometry back as the
  vehicle state): confirmed tracks and trusted environment vectors come out, and the planner
  points the head forward.
* The same tracking inputs, made in lock-step, fed to a tracking process over a real socket in
  the same order: the process publishes exactly the tracks the lock-step stage does.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from agent.runtime import topics
from agent.runtime.launch import load_launch
from agent.runtime.lockstep import LockstepRunner, Node
from agent.runtime.messages import (
    EnvironmentVector,
    Header,
    Message,
    Odometry,
    Tracks,
    WheelCommand,
    decode,
)
from agent.runtime.stage import Output, Stage
from cli.bench_graph import GraphUnderTest, OdometryRelay, vehicle_state_of
from processes.runtime import lockstep_graph

ROOT = Path(__file__).resolve().parents[2]
TRACK_FIELDS = (
    "track_id", "kind", "status", "state", "covariance", "params", "params_covariance",
    "extent", "end_seen", "reflectivity", "moving_probability", "last_seen_ns", "hits",
)  # fmt: skip


def test_the_simulated_graph_tracks_and_publishes_a_trusted_environment() -> None:
    with (
        GraphUnderTest(ROOT / "launch" / "sim.toml", play=None, listen=(topics.TRACKS,)) as graph,
        OdometryRelay(graph) as relay,
    ):
        bus = graph.listen()
        vectors: list[EnvironmentVector] = []
        tracks: list[Tracks] = []
        deadline = time.monotonic() + 60.0
        while not (
            any(v.sensor_ok and v.obstacle_id.size for v in vectors)
            and any((t.status == 1).any() for t in tracks)
        ):
            assert time.monotonic() < deadline, f"no trusted vector: {graph.log_tail(8)}"
            for _topic, payload in bus.poll(0.1):
                msg = decode(payload)
                if isinstance(msg, EnvironmentVector):
                    vectors.append(msg)
                elif isinstance(msg, Tracks):
                    tracks.append(msg)
        assert relay.relayed > 0
    trusted = [v for v in vectors if v.sensor_ok]
    assert all(v.header.frame_id == "odom" and v.valid_for_s > 0 for v in trusted)
    assert all(v.free_bearing_rad.size == v.free_range_m.size for v in vectors)
    # Obstacles are confirmed or coasting tracks (every tracks message lists every track).
    kept = {int(i) for t in tracks for i in t.track_id[t.status >= 1]}
    assert {int(i) for v in trusted for i in v.obstacle_id} <= kept


class _Controller(Stage):
    """Drives the vehicle in a slow arc and passes its odometry on as the vehicle state."""

    def __init__(self) -> None:
        self._next = 0.0

    def handle(self, topic: str, msg: Message, now_s: float) -> list[Output]:
        if isinstance(msg, Odometry):
            return [(topics.VEHICLE_STATE, vehicle_state_of(msg))]
        return []

    def tick(self, now_s: float) -> list[Output]:
        self._next = now_s + 0.1
        return [(topics.WHEEL_COMMAND, WheelCommand(header=Header(), speed_m_s=0.15,
                                                    yaw_rate_rad_s=0.1))]  # fmt: skip

    def next_tick_s(self) -> float | None:
        return self._next


TRACKING_ONLY = """
[graph]
name = "tracking-only"
heartbeat_s = 0.5
join_timeout_s = 3.0

[defaults]
backlog = "all"

[[process]]
name = "tracking"
module = "processes.tracking"
inputs = ["features", "vehicle_state", "filtered_scan"]
outputs = ["tracks"]
params = { max_state_age_s = 0.3 }

[[external]]
name = "feed"
endpoint = "ipc://{runtime}/feed.pub"
outputs = ["features", "vehicle_state", "filtered_scan"]
"""


def test_lockstep_and_a_tracking_process_give_the_same_tracks(tmp_path: Path) -> None:
    """Tracking's inputs from 6 s of the simulated graph in lock-step, in the order its stage
    took them, sent to a tracking process on one socket (which keeps their order): the
    process's tracks equal the lock-step stage's, message for message, array for array."""
    spec = load_launch(ROOT / "launch" / "sim.toml")
    nodes = [*lockstep_graph(spec).nodes, Node("controller", _Controller(), (topics.ODOMETRY,))]
    runner = LockstepRunner(nodes)
    tracking_inputs = set(spec.process("tracking").inputs)
    fed: list[tuple[str, Message]] = []
    stepped: list[Tracks] = []

    def seen(_t: float, topic: str, msg: Message) -> None:
        if topic in tracking_inputs:
            fed.append((topic, msg))
        elif isinstance(msg, Tracks):
            stepped.append(msg)

    runner.observe(seen)
    runner.run_until(6.0)
    assert any((t.status == 1).any() for t in stepped), "no confirmed track in lock-step"

    launch_file = tmp_path / "tracking.toml"
    launch_file.write_text(TRACKING_ONLY)
    live: list[Tracks] = []
    with GraphUnderTest(launch_file, play="feed") as graph:
        for topic in tracking_inputs:
            graph.wait_subscribed(topic)
        bus = graph.listen()
        deadline = time.monotonic() + 40.0
        sent = 0  # features messages: each makes one tracks message
        for topic, msg in fed:
            bus.publish(topic, msg.to_wire())
            sent += topic == topics.FEATURES
            # Paced by the process: at most 10 scans ahead of its output, so that no queue
            # nears its limit (ZeroMQ drops past 100 messages a pipe) even while a loaded
            # machine holds the process back.
            while True:
                for _, payload in bus.poll(0.002):
                    live.append(decode(payload, expect=Tracks))  # type: ignore[arg-type]
                if sent - len(live) <= 10 or time.monotonic() > deadline:
                    break
        while len(live) < len(stepped) and time.monotonic() < deadline:
            for _, payload in bus.poll(0.1):
                live.append(decode(payload, expect=Tracks))  # type: ignore[arg-type]
    assert len(live) == len(stepped)
    for got, want in zip(live, stepped, strict=True):
        assert got.header.stamp_ns == want.header.stamp_ns
        for name in TRACK_FIELDS:
            np.testing.assert_array_equal(getattr(got, name), getattr(want, name), name)
