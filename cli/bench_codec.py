"""What encoding and decoding cost, per message type, in one process.

``encode`` is ``msg.to_wire()``; ``decode`` is ``decode(payload, expect=<its type>)``, which
validates every field as a receiving process does. Each figure is the median of the
per-call wall time (``perf_counter_ns`` around one call) over a tight loop that cycles
through the realistic messages of the type (:mod:`cli.bench_messages`), after a warm-up.
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np

from agent.runtime import topics
from agent.runtime.messages import Message, decode

WARM_UP_CALLS = 50


def _median_us(call: Any, items: list[Any], calls: int) -> float:
    for i in range(min(WARM_UP_CALLS, calls)):
        call(items[i % len(items)])
    took = np.empty(calls, dtype=np.int64)
    clock = time.perf_counter_ns
    for i in range(calls):
        item = items[i % len(items)]
        started = clock()
        call(item)
        took[i] = clock() - started
    return float(np.median(took)) / 1e3


def codec_figures(samples: dict[str, list[Message]], calls: int) -> dict[str, dict[str, float]]:
    """Per topic: median µs of ``encode`` and ``decode`` over ``calls`` calls each."""
    if calls < 1:
        raise ValueError(f"calls must be at least 1, got {calls}")
    figures = {}
    for topic, msgs in samples.items():
        cls = topics.message_type(topic)
        payloads = [m.to_wire() for m in msgs]
        figures[topic] = {
            "encode": _median_us(lambda m: m.to_wire(), msgs, calls),
            "decode": _median_us(lambda p, cls=cls: decode(p, expect=cls), payloads, calls),
        }
    return figures


def message_bytes(samples: dict[str, list[Message]]) -> dict[str, int]:
    """Per topic, the median size of its encoded messages in bytes."""
    return {
        topic: int(np.median([len(m.to_wire()) for m in msgs])) for topic, msgs in samples.items()
    }
