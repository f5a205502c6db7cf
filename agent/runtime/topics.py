"""The topic registry: every topic of the process graph and the message type it carries.

Process code names topics only through these constants; launch files name them by value.
"""

from __future__ import annotations

from typing import Final

from agent.runtime import messages as m

VEHICLE_STATE: Final = "vehicle_state"
WHEEL_COMMAND: Final = "wheel_command"
ODOMETRY: Final = "odometry"
WORLD_TRUTH: Final = "world_truth"
HEAD_COMMAND: Final = "head_command"
HEAD_STATE: Final = "head_state"
RAW_SCAN: Final = "raw_scan"
CALIBRATED_SCAN: Final = "calibrated_scan"
FILTERED_SCAN: Final = "filtered_scan"
FEATURES: Final = "features"
TRACKS: Final = "tracks"
ENVIRONMENT: Final = "environment"
HEARTBEAT: Final = "heartbeat"
STOP: Final = "stop"

TOPIC_TYPES: Final[dict[str, type[m.Message]]] = {
    VEHICLE_STATE: m.VehicleState,
    WHEEL_COMMAND: m.WheelCommand,
    ODOMETRY: m.Odometry,
    WORLD_TRUTH: m.WorldTruth,
    HEAD_COMMAND: m.HeadCommand,
    HEAD_STATE: m.HeadState,
    RAW_SCAN: m.RawScan,
    CALIBRATED_SCAN: m.CalibratedScan,
    FILTERED_SCAN: m.FilteredScan,
    FEATURES: m.Features,
    TRACKS: m.Tracks,
    ENVIRONMENT: m.EnvironmentVector,
    HEARTBEAT: m.Heartbeat,
    STOP: m.Stop,
}

# Topics whose latest message is re-sent to a subscriber that joins late: they describe state,
# not a stream, and a late joiner needs the current value.
LATCHED: Final = frozenset({HEAD_STATE, WORLD_TRUTH})

# Topics of which a subscriber that fell behind (a stall, a restart, a busy core) keeps every
# queued message: the vehicle's states and odometry (pose histories interpolate between them), the
# heartbeats (every process's) and stop requests. Of every other topic, a stream of scans,
# states or commands, only the newest queued message is still useful: the older ones are
# dropped unread (``stale_dropped``) so that a stage that resumes works on data of now, not
# on seconds of old scans in a burst. A process's ``backlog = "all"`` (launch file) keeps
# everything, for benches that measure saturated throughput.
KEEP_BACKLOG: Final = frozenset({VEHICLE_STATE, ODOMETRY, HEARTBEAT, STOP})

# The largest payload a subscriber accepts per topic, in bytes. The bus sets each SUB socket's
# ZeroMQ ``MAXMSGSIZE`` to the largest of its topics' limits, so a bigger frame is refused by
# ZeroMQ itself before it is allocated (and the link that sent it dropped and re-dialled);
# a payload over its own topic's limit but under the socket's is dropped unread and counted
# (``dropped_oversized``). Scan messages of the longest sweep the head can make (a ±20°
# window at the slowest rate, about 1,000 samples) are under 150 kB: 4 MiB leaves room for
# higher sample rates; the small messages are under 10 kB.
_SMALL = 64 * 1024
_SCAN = 4 * 1024 * 1024
MAX_BYTES: Final[dict[str, int]] = {
    VEHICLE_STATE: _SMALL,
    WHEEL_COMMAND: _SMALL,
    ODOMETRY: _SMALL,
    WORLD_TRUTH: _SCAN,
    HEAD_COMMAND: _SMALL,
    HEAD_STATE: _SMALL,
    RAW_SCAN: _SCAN,
    CALIBRATED_SCAN: _SCAN,
    FILTERED_SCAN: _SCAN,
    FEATURES: _SCAN,
    TRACKS: _SCAN,
    ENVIRONMENT: _SCAN,
    HEARTBEAT: _SMALL,
    STOP: _SMALL,
}
# What a publisher accepts from its subscribers: subscription events (a topic name and a
# byte) and, on tcp://, the CURVE handshake, whose INITIATE command carries the client's
# vouch and metadata (a few hundred bytes): 4 KiB covers both with room.
MAX_SUBSCRIBER_FRAME_BYTES: Final = 4096


def message_type(topic: str) -> type[m.Message]:
    """The message type a topic carries; ``KeyError`` naming the topic if it is unknown."""
    try:
        return TOPIC_TYPES[topic]
    except KeyError:
        known = ", ".join(sorted(TOPIC_TYPES))
        raise KeyError(f"unknown topic {topic!r}; known: {known}") from None
