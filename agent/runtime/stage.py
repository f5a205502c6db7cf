"""What every stage provides."""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

from agent.errors import ConfigError
from agent.runtime.messages import Message

Output = tuple[str, Message]  # (topic, message)


class Stage:
    """A stage of the process graph.

    The runtime calls :meth:`start` once, then :meth:`handle` for every input message and
    :meth:`tick` whenever the time :meth:`next_tick_s` asked for has come. All three return
    the messages to publish, each with its topic. ``now_s`` is the graph's clock in seconds.
    A stage keeps its own counters (what it dropped, refused, clamped) for the heartbeat.
    """

    def prepare(self) -> None:
        """Work that needs nothing of the graph (loading compiled kernels, say): a standby
        process (see :mod:`processes.launcher`) does it before it is called in."""

    def start(self, now_s: float) -> list[Output]:
        return []

    def handle(self, topic: str, msg: Message, now_s: float) -> list[Output]:
        return []

    def tick(self, now_s: float) -> list[Output]:
        return []

    def next_tick_s(self) -> float | None:
        """When the stage next wants :meth:`tick` (``None``: only when messages arrive)."""
        return None

    def counters(self) -> dict[str, int]:
        return {}


class Params:
    """Typed access to a process's ``params`` table from the launch file.

    Every read names the key and the expected type; a wrong type raises :class:`ConfigError`
    naming the process and key; unread keys can be reported as unknown.
    """

    def __init__(self, process: str, values: Mapping[str, Any]) -> None:
        self.process = process
        self._values = dict(values)
        self._read: set[str] = set()

    def _get(self, key: str, types: tuple[type, ...], default: Any) -> Any:
        self._read.add(key)
        value = self._values.get(key, default)
        if isinstance(value, bool) and bool not in types:
            value = None  # booleans are not numbers here
        if not isinstance(value, types):
            names = " or ".join(t.__name__ for t in types)
            raise ConfigError(
                f"process {self.process}: parameter {key!r} must be {names}, "
                f"got {self._values.get(key, default)!r}"
            )
        return value

    def number(
        self, key: str, default: float, lo: float | None = None, hi: float | None = None
    ) -> float:
        value = float(self._get(key, (int, float), default))
        if not math.isfinite(value):
            raise ConfigError(
                f"process {self.process}: parameter {key!r} must be finite, got {value}"
            )
        if (lo is not None and value < lo) or (hi is not None and value > hi):
            raise ConfigError(
                f"process {self.process}: parameter {key!r} = {value} outside [{lo}, {hi}]"
            )
        return value

    def integer(self, key: str, default: int) -> int:
        return int(self._get(key, (int,), default))

    def string(self, key: str, default: str) -> str:
        return str(self._get(key, (str,), default))

    def flag(self, key: str, default: bool) -> bool:
        return bool(self._get(key, (bool,), default))

    def unknown(self) -> list[str]:
        """Keys given in the launch file that the stage never read."""
        return sorted(set(self._values) - self._read)

    def check_all_read(self) -> None:
        extra = self.unknown()
        if extra:
            raise ConfigError(f"process {self.process}: unknown parameter(s) {', '.join(extra)}")
