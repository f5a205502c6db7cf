"""The far side of the bench's hop measurement: a process that sends every message back.

Run by :mod:`cli.bench_hop` as ``python -m cli.bench_echo --listen EP --publish EP TOPIC...``.

Subscribes: each ``TOPIC`` and ``TRANSPORT`` at ``--listen``, and ``stop``. Publishes, at
``--publish``, each message back on its topic: decoded with full validation and encoded
again with a publisher's header stamping, as a stage's process does when it publishes; on
``TRANSPORT``, the payload bytes unchanged and not decoded (the bare transport). Stops on
SIGINT, SIGTERM, a ``stop`` message, or when its parent is gone; sockets close with
linger 0.
"""

from __future__ import annotations

import argparse
import gc
import logging
import os
import signal
import sys
from collections.abc import Sequence
from types import FrameType

from agent.errors import MessageError
from agent.runtime import topics
from agent.runtime.bus import Bus
from agent.runtime.messages import decode

log = logging.getLogger("bench-echo")

TRANSPORT = "transport"
SOURCE = "echo"
POLL_S = 0.1  # how soon a vanished parent is noticed


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description="echo bus messages back (the bench's hop)")
    parser.add_argument("--listen", required=True, help="endpoint of the bench's publisher")
    parser.add_argument("--publish", required=True, help="endpoint to bind and echo at")
    parser.add_argument("topics", nargs="*", help="topics to decode and echo")
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, stream=sys.stderr)
    types = {t: topics.message_type(t) for t in args.topics}
    stopping = False

    def on_signal(_signum: int, _frame: FrameType | None) -> None:
        nonlocal stopping
        stopping = True

    parent = os.getppid()
    bus = Bus(args.publish)
    try:
        bus.subscriber.connect(args.listen)
        for topic in [*types, TRANSPORT, topics.STOP]:
            bus.subscriber.subscribe(topic)
        signal.signal(signal.SIGINT, on_signal)
        signal.signal(signal.SIGTERM, on_signal)
        gc.freeze()  # as every process shell does: the start-up heap stays out of collections
        while not stopping and os.getppid() == parent:
            for topic, payload in bus.poll(POLL_S):
                if topic == TRANSPORT:
                    bus.publish(topic, payload)
                elif topic == topics.STOP:
                    stopping = True
                    break
                elif topic in types:
                    try:
                        msg = decode(payload, expect=types[topic])
                    except MessageError as exc:
                        log.warning("dropped a %s: %s", topic, exc)
                        continue
                    h = msg.header
                    bus.publish(topic, msg.to_wire(seq=h.seq, source=SOURCE, stamp_ns=h.stamp_ns))
    finally:
        bus.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
