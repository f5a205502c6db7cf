"""The topic registry: every topic of the process graph and the message type it carries.

Process code names topics only through these constants; launch files name them by value.
"""

from __future__ import annotations

from typing import Final

from agent.runtime import messages as m

VEHICLE_STATE: Final = "vehicle_state"
WHEEL_COMMAND: Final = "wheel_command"
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


def message_type(topic: str) -> type[m.Message]:
    """The message type a topic carries; ``KeyError`` naming the topic if it is unknown."""
    try:
        return TOPIC_TYPES[topic]
    except KeyError:
        known = ", ".join(sorted(TOPIC_TYPES))
        raise KeyError(f"unknown topic {topic!r}; known: {known}") from None
