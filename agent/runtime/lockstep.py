"""The lock-step runner: the graph's stages in one process, on a simulated clock.

Deterministic: stages tick at the times they ask for, in the order they were given when two
ask for the same time; every published message is delivered at once, breadth-first, to the
stages that read its topic. Messages are encoded to their wire bytes and decoded again on
the way (as between processes), so a stage sees exactly what it would see on the bus.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field

from agent.runtime.messages import Message, decode, stamp_ns
from agent.runtime.stage import Output, Stage

Observer = Callable[[float, str, Message], None]


@dataclass
class Node:
    """A stage with its name and the topics it reads."""

    name: str
    stage: Stage
    inputs: tuple[str, ...] = ()
    _seq: dict[str, int] = field(default_factory=dict)


class LockstepRunner:
    """Runs stages on a simulated clock.

    Parameters
    ----------
    nodes
        The graph's stages; ties in tick time go in this order.
    start_s
        The simulated clock's start.
    serialise
        Pass every message through its wire encoding (default). Turn off only to measure
        the stages' own cost.
    """

    def __init__(self, nodes: Iterable[Node], start_s: float = 0.0, serialise: bool = True) -> None:
        self.nodes = list(nodes)
        names = [n.name for n in self.nodes]
        if len(set(names)) != len(names):
            raise ValueError(f"node names must be unique: {names}")
        self.now_s = start_s
        self.serialise = serialise
        self._observers: list[tuple[str | None, Observer]] = []
        self._queue: deque[tuple[str, Message]] = deque()
        self._started = False
        self._readers: dict[str, tuple[Node, ...]] = {}  # topic -> its readers, in node order

    def observe(self, callback: Observer, topic: str | None = None) -> None:
        """Call ``callback(time, topic, message)`` for every message (of ``topic``)."""
        self._observers.append((topic, callback))

    def inject(self, topic: str, msg: Message, source: str = "external") -> None:
        """Publish a message from outside the graph at the current simulated time."""
        self._start()
        self._publish(Node(source, Stage()), [(topic, msg)])
        self._drain()

    def _start(self) -> None:
        if not self._started:
            self._started = True
            for node in self.nodes:
                self._publish(node, node.stage.start(self.now_s))
                self._drain()

    def _publish(self, node: Node, outputs: list[Output]) -> None:
        for topic, msg in outputs:
            seq = node._seq.get(topic, 0)
            node._seq[topic] = seq + 1
            stamp = msg.header.stamp_ns or stamp_ns(self.now_s)
            if self.serialise:  # stamped on the wire, as a process's publisher does
                stamped = decode(msg.to_wire(seq=seq, source=node.name, stamp_ns=stamp))
            else:
                stamped = msg.with_header(seq=seq, source=node.name, stamp_ns=stamp)
            for wanted, callback in self._observers:
                if wanted is None or wanted == topic:
                    callback(self.now_s, topic, stamped)
            self._queue.append((topic, stamped))

    def _drain(self) -> None:
        while self._queue:
            topic, msg = self._queue.popleft()
            readers = self._readers.get(topic)
            if readers is None:
                readers = self._readers[topic] = tuple(n for n in self.nodes if topic in n.inputs)
            for node in readers:
                self._publish(node, node.stage.handle(topic, msg, self.now_s))

    def step(self, until_s: float) -> bool:
        """Run the earliest tick due by ``until_s``; ``False`` if there is none."""
        self._start()
        due = [
            (t, i)
            for i, n in enumerate(self.nodes)
            if (t := n.stage.next_tick_s()) is not None and t <= until_s
        ]
        if not due:
            self.now_s = max(self.now_s, until_s)
            return False
        t, i = min(due)
        self.now_s = max(self.now_s, t)
        node = self.nodes[i]
        self._publish(node, node.stage.tick(self.now_s))
        self._drain()
        return True

    def run_until(self, until_s: float) -> None:
        """Advance the simulated clock to ``until_s``, running every tick due before it."""
        while self.step(until_s):
            pass
