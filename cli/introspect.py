"""Introspection and replay commands: ``topics``, ``echo``, ``hz``, ``replay``.

They look at a graph started by ``sensor-agent launch``: the launcher lists each running graph
in the user's graph registry (:func:`processes.launcher.running_graphs`), with its resolved
graph file. The newest graph is used unless ``--graph`` names one (by name, or by its runtime
directory when several graphs of one name run).

* ``topics``  every topic of the graph: publisher, endpoint, subscribers, type, measured rate.
* ``echo``    print the messages of one topic as they arrive (text or JSON lines).
* ``hz``      the rate and period of one topic, once per second, over a sliding window.
* ``replay``  publish a recording (``launch --record``) again, byte for byte, with its timing;
  a damaged recording is refused before anything is sent, and messages that do not decode
  as their topic's type are left out and counted.

Listening commands connect one SUB socket to every publisher of the graph; ``replay`` binds the
endpoints of the graph's ``[[external]]`` publishers (or one given endpoint). Every socket is
closed with linger 0. Ctrl-C stops ``echo`` and ``hz`` with status 0 after what they have
printed; it stops ``replay`` with status 130 after a summary of what was sent.
"""

from __future__ import annotations

import argparse
import dataclasses
import functools
import json
import math
import os
import signal
import sys
import time
from collections import Counter, deque
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager, suppress
from pathlib import Path
from types import FrameType
from typing import TYPE_CHECKING, Any

from agent.errors import ConfigError
from cli.output import jsonable

if TYPE_CHECKING:
    import zmq

    from agent.runtime.bus import Bus, Subscriber
    from agent.runtime.launch import GraphSpec

POLL_S = 0.1  # longest wait between checks for Ctrl-C
MAX_PER_POLL = 1000  # messages taken per poll before checking for a stop
SETTLE_S = 0.2  # rate measurements ignore what arrives this soon after connecting
DRAIN_S = 0.5  # replay keeps its sockets open this long after the last message
SEND_RETRY_MS = 100  # replay: a send blocked by a full subscriber queue is retried this often
SKIPPED_BY_DEFAULT = ("heartbeat", "stop", "")

__all__ = [
    "RateWindow", "add_commands", "echo_line", "find_graph", "format_message", "message_json",
]  # fmt: skip


# ------------------------------------------------------------------------------ helpers
def check_positive(**values: float | None) -> None:
    """One-line errors for options that must be positive numbers (``None``: not given)."""
    for name, value in values.items():
        if value is not None and (not math.isfinite(value) or value <= 0):
            raise ConfigError(f"--{name.replace('_', '-')} must be positive, got {value:g}")


class _Stop:
    """Set by SIGINT or SIGTERM while a command runs (see :func:`interruptible`)."""

    def __init__(self) -> None:
        self.requested = False

    def __bool__(self) -> bool:
        return self.requested


@contextmanager
def interruptible() -> Iterator[_Stop]:
    """Turn Ctrl-C and SIGTERM into a flag the command's loop checks, for a clean stop."""
    stop = _Stop()

    def on_signal(_signum: int, _frame: FrameType | None) -> None:
        stop.requested = True

    old: dict[signal.Signals, Any] = {}
    try:
        for s in (signal.SIGINT, signal.SIGTERM):
            old[s] = signal.signal(s, on_signal)
    except ValueError:  # not the main thread: Ctrl-C stays a KeyboardInterrupt
        pass
    try:
        yield stop
    finally:
        for s, handler in old.items():
            signal.signal(s, handler)


def _print(line: str) -> None:
    print(line, flush=True)


def _quiet_broken_pipe(func: Callable[[argparse.Namespace], int]) -> Callable[..., int]:
    """``sensor-agent echo T | head``: the reader going away ends the command quietly."""

    @functools.wraps(func)
    def run(args: argparse.Namespace) -> int:
        try:
            return func(args)
        except BrokenPipeError:
            with suppress(OSError):
                sys.stdout = open(os.devnull, "w")  # noqa: SIM115 (no flush error at exit)
            return 0

    return run


# -------------------------------------------------------------------------- the graph
@dataclasses.dataclass(frozen=True)
class _Running:
    graph: GraphSpec
    pid: int
    runtime_dir: str


def _describe(entries: list[dict[str, Any]]) -> str:
    return ", ".join(
        f"{e.get('graph')} (pid {e.get('pid')}, {e.get('runtime_dir')})" for e in entries
    )


def find_graph(selector: str | None) -> _Running:
    """The running graph to talk to: the newest, or the newest named ``selector``.

    ``selector`` may also be a graph's runtime directory or resolved graph file, to pick one
    of several graphs of the same name. Raise :class:`ConfigError` when there is none.
    """
    from processes.launcher import running_graphs

    if selector is not None and selector.endswith(".json") and Path(selector).is_file():
        # A graph run as services (sensor-agent systemd) has no launcher: its graph file.
        graph = _read_graph(selector, Path(selector).stem)
        return _Running(graph, 0, graph.runtime_dir)
    entries = running_graphs()
    if not entries:
        raise ConfigError("no running graph (start one with 'sensor-agent launch FILE')")
    chosen = entries[0]
    if selector is not None:
        as_path = str(Path(selector).expanduser().resolve()) if "/" in selector else None
        matches = [
            e
            for e in entries
            if e.get("graph") == selector
            or (
                as_path is not None
                and as_path
                in (
                    str(Path(str(e.get("runtime_dir", ""))).resolve()),
                    str(Path(str(e.get("graph_file", ""))).resolve()),
                )
            )
        ]
        if not matches:
            raise ConfigError(f"no running graph {selector!r} (running: {_describe(entries)})")
        chosen = matches[0]
    graph = _read_graph(str(chosen.get("graph_file", "")), chosen.get("graph"))
    return _Running(graph, int(chosen.get("pid", 0)), str(chosen.get("runtime_dir", "")))


def _read_graph(graph_file: str, name: object) -> GraphSpec:
    from agent.runtime.launch import GraphSpec

    try:
        return GraphSpec.from_json(Path(graph_file).read_text())
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise ConfigError(
            f"graph {name!r}: cannot read its graph file {graph_file}: {exc}"
        ) from None


def _keys(graph: GraphSpec) -> Any:
    from agent.runtime.bus import CurveKeys

    return CurveKeys.load(graph.keys_dir) if graph.keys_dir else None


class Listener:
    """One SUB socket on a graph's publishers: by default every one (and its launcher's),
    subscribed to ``topics`` (``None``: everything); ``endpoints`` to connect to only some;
    ``max_bytes``: the largest message it takes (default: the bus's limit)."""

    def __init__(
        self,
        graph: GraphSpec,
        topics: Sequence[str] | None,
        endpoints: Sequence[str] | None = None,
        max_bytes: int | None = None,
    ) -> None:
        import zmq

        from agent.runtime.bus import Subscriber

        self.ctx: zmq.Context[zmq.Socket[bytes]] = zmq.Context()
        self.sub: Subscriber | None = None
        if endpoints is None:
            endpoints = [*graph.endpoints().values(), graph.control_endpoint]
        try:
            if max_bytes is None:
                self.sub = Subscriber(self.ctx, _keys(graph))
            else:
                self.sub = Subscriber(self.ctx, _keys(graph), max_bytes=max_bytes)
            for endpoint in dict.fromkeys(endpoints):
                self.sub.connect(endpoint)
            if topics is None:
                self.sub.subscribe_all()
            for topic in topics or ():
                self.sub.subscribe(topic)
        except BaseException:
            self.close()
            raise

    def poll(self, timeout_s: float) -> list[tuple[str, bytes]]:
        """What arrives within ``timeout_s`` (maybe nothing; at most 1,000 messages)."""
        import zmq

        assert self.sub is not None
        out: list[tuple[str, bytes]] = []
        if self.sub.socket.poll(max(0, int(timeout_s * 1000)), zmq.POLLIN):
            while len(out) < MAX_PER_POLL and (item := self.sub.receive()) is not None:
                out.append(item)
        return out

    def close(self) -> None:
        if self.sub is not None:
            self.sub.close()
        self.ctx.term()


def _check_topic(topic: str, graph: GraphSpec | None = None) -> None:
    from agent.runtime.topics import TOPIC_TYPES

    if topic not in TOPIC_TYPES:
        raise ConfigError(f"unknown topic {topic!r} (known: {', '.join(sorted(TOPIC_TYPES))})")
    if graph is not None and topic not in (*graph.publishers(), "heartbeat", "stop"):
        raise ConfigError(
            f"graph {graph.name!r} does not publish {topic!r} "
            f"(its topics: {', '.join(sorted(graph.publishers()))})"
        )


# ----------------------------------------------------------------------------- topics
def _rate(times: list[float]) -> float | None:
    if len(times) < 2 or times[-1] <= times[0]:
        return None
    return (len(times) - 1) / (times[-1] - times[0])


def cmd_topics(args: argparse.Namespace) -> int:
    check_positive(listen=args.listen)
    running = find_graph(args.graph)
    graph = running.graph
    arrivals: dict[str, list[float]] = {}
    beats: dict[str, Any] = {}  # process: its latest heartbeat
    with interruptible() as stop:
        listener = Listener(graph, None)
        try:
            started = time.monotonic()
            end = started + SETTLE_S + args.listen
            while not stop and (now := time.monotonic()) < end:
                for topic, payload in listener.poll(min(POLL_S, end - now)):
                    t = time.monotonic()
                    if topic == "heartbeat":
                        _see_beat(beats, payload)
                    if t - started >= SETTLE_S:  # skip latched re-sends on joining
                        arrivals.setdefault(topic, []).append(t)
        finally:
            listener.close()
    processes = _process_states(graph, beats)
    from agent.runtime.topics import TOPIC_TYPES

    def tag(topic: str) -> str:
        cls = TOPIC_TYPES.get(topic)
        return f"{cls.TYPE}/{cls.VERSION}" if cls is not None else "?"

    rows: list[dict[str, Any]] = []
    for topic, (publisher, endpoint) in graph.publishers().items():
        rows.append(
            {"topic": topic, "type": tag(topic), "publisher": publisher, "endpoint": endpoint,
             "subscribers": graph.subscribers(topic)}
        )  # fmt: skip
    rows.append(
        {"topic": "heartbeat", "type": tag("heartbeat"), "publisher": "(every process)",
         "endpoint": "(each process's)", "subscribers": ["launcher"]}
    )  # fmt: skip
    rows.append(
        {"topic": "stop", "type": tag("stop"), "publisher": "launcher",
         "endpoint": graph.control_endpoint, "subscribers": ["(every process)"]}
    )  # fmt: skip
    declared = {r["topic"] for r in rows}
    for topic in sorted(set(arrivals) - declared):
        rows.append(
            {"topic": topic or "<malformed>", "type": tag(topic), "publisher": "(undeclared)",
             "endpoint": "?", "subscribers": []}
        )  # fmt: skip
    for row in rows:
        times = arrivals.get("" if row["topic"] == "<malformed>" else row["topic"], [])
        row["messages"] = len(times)
        row["rate_hz"] = _rate(times)
    if args.json:
        _print(json.dumps({"graph": graph.name, "pid": running.pid,
                           "runtime_dir": running.runtime_dir, "listened_s": args.listen,
                           "topics": rows, "processes": processes}))  # fmt: skip
        return 0
    _print(
        f"graph {graph.name} ("
        + (f"launcher pid {running.pid}" if running.pid else "no launcher: services")
        + f", runtime {running.runtime_dir}); "
        f"rates over {args.listen:g} s"
    )
    table = [("TOPIC", "TYPE", "RATE", "PUBLISHER", "ENDPOINT", "SUBSCRIBERS")]
    for row in rows:
        rate = row["rate_hz"]
        rate_text = f"{rate:.2f} Hz" if rate is not None else f"- ({row['messages']} msgs)"
        table.append(
            (row["topic"], row["type"], rate_text, row["publisher"], row["endpoint"],
             ", ".join(row["subscribers"]) or "-")
        )  # fmt: skip
    widths = [max(len(r[i]) for r in table) for i in range(len(table[0]) - 1)]
    for r in table:
        _print("  ".join(c.ljust(w) for c, w in zip(r, widths, strict=False)) + "  " + r[-1])
    _print("")
    states: list[tuple[str, ...]] = [("PROCESS", "STATE", "PID", "NOTES")]
    for name, p in processes.items():
        notes = ", ".join(f"{k} {v}" for k, v in p["notes"].items()) or "-"
        states.append((name, str(p["state"]), str(p["pid"] or "-"), notes))
    widths = [max(len(state[i]) for state in states) for i in range(len(states[0]) - 1)]
    for state in states:
        cells = zip(state, widths, strict=False)
        _print("  ".join(c.ljust(w) for c, w in cells) + "  " + state[-1])
    return 0


# Heartbeat counters worth a look when they are not zero: trouble, or its aftermath.
_NOTABLE = ("stage_errors", "stale_dropped", "links_dropped", "lost", "hangs", "restarts")


def _see_beat(beats: dict[str, Any], payload: bytes) -> None:
    from agent.errors import MessageError
    from agent.runtime.messages import Heartbeat, decode

    try:
        beat = decode(payload, expect=Heartbeat)
    except MessageError:
        return
    if isinstance(beat, Heartbeat):
        beats[beat.process] = beat


def _process_states(graph: Any, beats: dict[str, Any]) -> dict[str, Any]:
    """Each process's state from its latest heartbeat heard: ``fault`` when it says so, or
    when the launcher beat it on the process's behalf (it hung); ``silent`` if none came."""
    out: dict[str, Any] = {}
    for spec in graph.processes:
        beat = beats.get(spec.name)
        if beat is None:
            out[spec.name] = {"state": "silent", "pid": None, "notes": {}}
            continue
        counters = beat.counters
        notes = {k: counters[k] for k in _NOTABLE if counters.get(k)}
        notes.update({k: v for k, v in counters.items() if k.startswith("dropped_") and v})
        if beat.header.source == "launcher":
            notes["hung"] = counters.get("hangs", 1)
        out[spec.name] = {"state": beat.state, "pid": beat.pid, "notes": notes}
    return out


# ------------------------------------------------------------------------------- echo
def _number(value: Any) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int):
        return str(value)
    f = float(value)
    if 1e5 <= abs(f) < 1e15:  # times in seconds since the epoch: keep the microseconds
        return f"{f:.6f}"
    return f"{f:.6g}"


def _array_text(name: str, value: Any) -> str:
    import numpy as np

    shape = ",".join(str(s) for s in value.shape)
    if value.size == 0:
        return f"{name}[{shape}]"
    data = value.astype(np.int64) if value.dtype == np.bool_ else value
    finite = data[np.isfinite(data)] if data.dtype.kind == "f" else data
    if finite.size == 0:
        return f"{name}[{shape}] nan"
    nans = f" ({value.size - finite.size} nan)" if finite.size < value.size else ""
    low, high = _number(finite.min().item()), _number(finite.max().item())
    return f"{name}[{shape}] {low}..{high}{nans}"


def _stamp(ns: int) -> str:
    return f"{ns // 1_000_000_000}.{ns % 1_000_000_000:09d}"


def format_message(topic: str, msg: Any) -> str:
    """One line: header seq/source/stamp, scalar fields, arrays as ``name[shape] min..max``."""
    import numpy as np

    h = msg.header
    parts = [f"{topic} seq={h.seq} source={h.source or '-'} stamp={_stamp(h.stamp_ns)}"]
    if h.frame_id:
        parts.append(f"frame={h.frame_id}")
    for f in dataclasses.fields(msg):
        if f.name == "header":
            continue
        value = getattr(msg, f.name)
        if isinstance(value, np.ndarray):
            parts.append(_array_text(f.name, value))
        elif isinstance(value, dict):
            inner = ",".join(f"{k}:{v}" for k, v in value.items())
            parts.append(f"{f.name}={{{inner}}}")
        elif isinstance(value, str):
            parts.append(f"{f.name}={value if value and ' ' not in value else repr(value)}")
        else:
            parts.append(f"{f.name}={_number(value)}")
    return " ".join(parts)


def message_json(topic: str, msg: Any) -> str:
    """One JSON object: topic, type tag, header and every field (arrays as lists, NaN null)."""
    h = msg.header
    obj: dict[str, Any] = {
        "topic": topic,
        "type": msg.tag,
        "header": {"stamp_ns": h.stamp_ns, "seq": h.seq, "frame_id": h.frame_id,
                   "source": h.source},
    }  # fmt: skip
    for f in dataclasses.fields(msg):
        if f.name != "header":
            obj[f.name] = getattr(msg, f.name)
    return json.dumps(jsonable(obj), allow_nan=False)


def echo_line(topic: str, payload: bytes, as_json: bool = False) -> str:
    """A message as ``echo`` prints it; one that fails decoding as a line saying it was dropped."""
    from agent.errors import MessageError
    from agent.runtime.messages import decode
    from agent.runtime.topics import message_type

    try:
        msg = decode(payload, expect=message_type(topic))
    except MessageError as exc:
        if as_json:
            dropped = {"topic": topic, "dropped": exc.problem, "kind": exc.kind}
            return json.dumps({**dropped, "bytes": len(payload)})
        return f"{topic}: dropped a message of {len(payload)} bytes: {exc}"
    return message_json(topic, msg) if as_json else format_message(topic, msg)


def cmd_echo(args: argparse.Namespace) -> int:
    _check_topic(args.topic)
    check_positive(count=args.count)
    graph = find_graph(args.graph).graph
    _check_topic(args.topic, graph)
    shown = 0
    with interruptible() as stop:
        listener = Listener(graph, [args.topic])
        try:
            while not stop and (args.count is None or shown < args.count):
                for topic, payload in listener.poll(POLL_S):
                    _print(echo_line(topic, payload, args.json))
                    shown += 1
                    if args.count is not None and shown >= args.count:
                        break
        finally:
            listener.close()
    return 0


# --------------------------------------------------------------------------------- hz
class RateWindow:
    """Arrival times of one topic over a sliding window; rate and period statistics."""

    def __init__(self, window_s: float) -> None:
        self.window_s = window_s
        self.times: deque[float] = deque()
        self.total = 0

    def add(self, t: float) -> None:
        self.times.append(t)
        self.total += 1

    def trim(self, now: float) -> None:
        while self.times and self.times[0] < now - self.window_s:
            self.times.popleft()

    def line(self, topic: str) -> str:
        n = len(self.times)
        if n < 2:
            return f"{topic}: {n} message{'' if n == 1 else 's'} in the last {self.window_s:g} s"
        periods = [b - a for a, b in zip(self.times, list(self.times)[1:], strict=False)]
        mean = (self.times[-1] - self.times[0]) / (n - 1)
        return (
            f"{topic}: rate {1.0 / mean:.2f} Hz  period mean {mean:.4f} s  "
            f"min {min(periods):.4f} s  max {max(periods):.4f} s  "
            f"n {n} (window {self.window_s:g} s, {self.total} in all)"
        )


def cmd_hz(args: argparse.Namespace) -> int:
    _check_topic(args.topic)
    check_positive(window=args.window, duration=args.duration)
    graph = find_graph(args.graph).graph
    _check_topic(args.topic, graph)
    window = RateWindow(args.window)
    with interruptible() as stop:
        listener = Listener(graph, [args.topic])
        try:
            started = time.monotonic()
            counting_from = started + SETTLE_S  # skip a latched re-send on joining
            end = started + args.duration if args.duration is not None else math.inf
            next_print = counting_from + 1.0
            while not stop and (now := time.monotonic()) < end:
                for _topic, _payload in listener.poll(min(POLL_S, next_print - now, end - now)):
                    t = time.monotonic()
                    if t >= counting_from:
                        window.add(t)
                now = time.monotonic()
                if now >= next_print:
                    window.trim(now)
                    _print(window.line(args.topic))
                    next_print += 1.0
            window.trim(time.monotonic())
            _print(window.line(args.topic))
        finally:
            listener.close()
    return 0


# ----------------------------------------------------------------------------- replay
@dataclasses.dataclass
class _Target:
    endpoint: str
    topics: list[str]
    expected: dict[str, int]
    bus: Bus | None = None


@dataclasses.dataclass
class _Survey:
    """What a recording holds, read once before replaying: messages per topic, and those that
    do not decode as their topic's message type (by their place in the file)."""

    counts: Counter[str]
    undecodable: Counter[str]
    skip: set[int]
    first_problem: dict[str, str]


def _survey(path: str) -> _Survey:
    """Read a whole recording, decoding each payload on a topic of a known message type.

    Raises
    ------
    ConfigError
        The file cannot be read, is not MCAP, is damaged or cut short, or holds no messages.
    """
    from agent.errors import MessageError
    from agent.runtime.messages import decode
    from agent.runtime.recording import read_recording
    from agent.runtime.topics import TOPIC_TYPES

    survey = _Survey(Counter(), Counter(), set(), {})
    for i, message in enumerate(read_recording(path)):
        survey.counts[message.topic] += 1
        cls = TOPIC_TYPES.get(message.topic)
        if cls is None:  # no type to check against (malformed traffic: topic "")
            continue
        try:
            decode(message.payload, expect=cls)
        except MessageError as exc:
            survey.undecodable[message.topic] += 1
            survey.skip.add(i)
            survey.first_problem.setdefault(message.topic, str(exc))
    if not survey.counts:
        raise ConfigError(f"recording {path} holds no messages")
    return survey


def _check_decodable(path: str, survey: _Survey, topics: list[str]) -> str | None:
    """Refuse ``topics`` if none of their messages decodes; else a warning naming the messages
    that do not, or ``None``."""
    bad = {t: survey.undecodable[t] for t in topics if survey.undecodable[t]}
    if not bad:
        return None
    first = survey.first_problem[next(iter(bad))]
    per_topic = ", ".join(f"{t} {n}" for t, n in bad.items())
    if sum(bad.values()) == sum(survey.counts[t] for t in topics):
        raise ConfigError(
            f"recording {path}: none of its {sum(bad.values())} messages on "
            f"{', '.join(topics)} decode (first: {first})"
        )
    return (
        f"recording {path}: skipping {sum(bad.values())} messages that do not decode "
        f"({per_topic}; first: {first})"
    )


def _plan_replay(
    args: argparse.Namespace, survey: _Survey
) -> tuple[list[_Target], list[str], list[str]]:
    """Where each selected topic goes; the topics skipped and a note saying why.

    Raises
    ------
    ConfigError
        A topic of ``--topics`` was not recorded, or nothing selected goes anywhere in the
        graph.
    """
    counts = survey.counts
    if args.topics:
        missing = [t for t in args.topics if t not in counts]
        if missing:
            raise ConfigError(
                f"recording {args.file} has no messages on {', '.join(map(repr, missing))} "
                f"(its topics: {', '.join(sorted(counts))})"
            )
        selected = list(dict.fromkeys(args.topics))
    else:
        selected = [t for t in counts if t not in SKIPPED_BY_DEFAULT]
    notes = []
    default_skip = [t or "<malformed>" for t in counts if t not in selected]
    if default_skip and not args.topics:
        notes.append(
            f"not replaying {', '.join(default_skip)} (name a topic in --topics to replay it)"
        )
    if args.endpoint is not None:
        target = _Target(args.endpoint, selected, {t: 1 for t in selected})
        return [target], [], notes
    graph = find_graph(args.graph).graph
    targets: dict[str, _Target] = {}
    skipped: list[str] = []
    for topic in selected:
        external = next((e for e in graph.externals if topic in e.outputs), None)
        if external is None:
            skipped.append(topic)
            continue
        target = targets.setdefault(external.name, _Target(external.endpoint, [], {}))
        target.topics.append(topic)
        target.expected[topic] = len(graph.subscribers(topic))
    if skipped:
        notes.append(
            f"skipping {', '.join(t or '<malformed>' for t in skipped)}: graph {graph.name} "
            "does not take them from an [[external]] publisher"
        )
    if not targets:
        raise ConfigError(
            f"nothing to replay into graph {graph.name}: its [[external]] publishers "
            f"({', '.join(t for e in graph.externals for t in e.outputs) or 'none'}) "
            f"publish none of the recorded topics ({', '.join(selected) or 'none'})"
        )
    args.keys_dir = args.keys_dir or graph.keys_dir or None
    return list(targets.values()), skipped, notes


def _wait_for_subscribers(targets: list[_Target], wait_s: float, stop: _Stop) -> list[str]:
    """Wait until every topic has the subscribers expected; return those still missing."""
    import zmq

    poller = zmq.Poller()
    for target in targets:
        assert target.bus is not None and target.bus.publisher is not None
        poller.register(target.bus.publisher.socket, zmq.POLLIN)
    deadline = time.monotonic() + wait_s
    while True:
        missing = []
        for target in targets:
            assert target.bus is not None and target.bus.publisher is not None
            target.bus.publisher.handle_subscriptions()
            missing += [
                t
                for t, n in target.expected.items()
                if target.bus.publisher.subscriber_count(t) < n
            ]
        now = time.monotonic()
        if not missing or stop or now >= deadline:
            return missing
        poller.poll(max(1, int(1000 * min(POLL_S, deadline - now))))


def cmd_replay(args: argparse.Namespace) -> int:
    import zmq

    from agent.runtime.bus import Bus, CurveKeys
    from agent.runtime.recording import read_recording
    from agent.runtime.topics import LATCHED

    for name, value in (("speed", args.speed), ("wait", args.wait)):
        if value < 0 or not math.isfinite(value):
            raise ConfigError(f"--{name} must be a number >= 0, got {value:g}")
    survey = _survey(args.file)  # a damaged file is refused before anything is sent
    counts = survey.counts
    targets, _skipped, notes = _plan_replay(args, survey)
    # Refused if none of the messages to send decodes; else a warning if some do not.
    warning = _check_decodable(args.file, survey, [t for g in targets for t in g.topics])
    route = {t: target for target in targets for t in target.topics}
    keys = CurveKeys.load(args.keys_dir) if args.keys_dir else None
    for target in targets:
        if not target.endpoint.startswith(("ipc://", "tcp://")):
            raise ConfigError(f"endpoint {target.endpoint!r} must be ipc:// or tcp://")
        if target.endpoint.startswith("tcp://") and keys is None:
            raise ConfigError(f"endpoint {target.endpoint}: tcp needs CURVE keys (--keys-dir)")
    for note in notes:
        _print(note)
    if warning is not None:
        print(f"sensor-agent: {warning}", file=sys.stderr, flush=True)
    sent: Counter[str] = Counter()
    interrupted = False
    with interruptible() as stop:
        try:
            for target in targets:
                target.bus = Bus(target.endpoint, keys, latched=LATCHED)
                assert target.bus.publisher is not None
                socket = target.bus.publisher.socket
                socket.setsockopt(zmq.XPUB_NODROP, 1)  # wait for a full queue: drop nothing
                socket.setsockopt(zmq.SNDTIMEO, SEND_RETRY_MS)
            for target in targets:
                sending = (f"{t} ({counts[t] - survey.undecodable[t]})" for t in target.topics)
                _print(f"replaying {', '.join(sending)} at {target.endpoint}")
            missing = _wait_for_subscribers(targets, args.wait, stop)
            if missing and not stop:
                print(
                    f"sensor-agent: starting without every subscriber of "
                    f"{', '.join(sorted(set(missing)))} after {args.wait:g} s",
                    file=sys.stderr,
                    flush=True,
                )
            started = time.monotonic()
            first_ns: int | None = None
            last_ns = 0
            for i, message in enumerate(read_recording(args.file)):
                if stop:
                    break
                to = route.get(message.topic)
                if to is None or i in survey.skip:
                    continue
                assert to.bus is not None and to.bus.publisher is not None
                if first_ns is None:
                    first_ns = message.log_time_ns
                last_ns = message.log_time_ns
                if args.speed > 0:
                    due = started + (message.log_time_ns - first_ns) * 1e-9 / args.speed
                    _idle_until(targets, due, stop)
                while not stop:
                    try:
                        to.bus.publisher.publish(message.topic, message.payload)
                    except zmq.Again:  # a subscriber's queue is full: wait for it
                        to.bus.publisher.handle_subscriptions()
                        continue
                    sent[message.topic] += 1
                    break
            finished = time.monotonic()
            if not stop:
                _idle_until(targets, finished + DRAIN_S, stop)  # let the queues drain
            interrupted = bool(stop)
        finally:
            for target in targets:
                if target.bus is not None:
                    target.bus.close()
    span_s = (last_ns - first_ns) * 1e-9 if first_ns is not None else 0.0
    speed = f"speed {args.speed:g}" if args.speed > 0 else "as fast as possible"
    _print(
        f"{'interrupted after replaying' if interrupted else 'replayed'} {sum(sent.values())} "
        f"messages in {finished - started:.2f} s (recording span {span_s:.2f} s, {speed})"
    )
    for target in targets:
        for t in target.topics:
            skipped = survey.undecodable[t]
            _print(
                f"  {t:16s} {sent[t]:7d} msgs -> {target.endpoint}"
                + (f" ({skipped} skipped: they do not decode)" if skipped else "")
            )
    if interrupted:
        print("sensor-agent: interrupted", file=sys.stderr)
        return 130
    return 0


def _idle_until(targets: list[_Target], due: float, stop: _Stop) -> None:
    """Wait until ``due`` (monotonic), handling subscriptions (and latched re-sends)."""
    import zmq

    poller = zmq.Poller()
    for target in targets:
        assert target.bus is not None and target.bus.publisher is not None
        poller.register(target.bus.publisher.socket, zmq.POLLIN)
    while not stop and (now := time.monotonic()) < due:
        if poller.poll(max(0, int(1000 * min(POLL_S, due - now)))):
            for target in targets:
                assert target.bus is not None and target.bus.publisher is not None
                target.bus.publisher.handle_subscriptions()


# ----------------------------------------------------------------------------- parser
def add_commands(sub: Any) -> None:
    """Register the subcommands on the main parser's subparsers object."""
    graph_help = (
        "running graph: its name, its runtime directory, or (run as services) its graph.json "
        "(default: the newest running graph)"
    )

    p = sub.add_parser(
        "topics",
        help="list the topics of a running graph with their measured rates",
        description="Every topic of the running graph: message type, rate measured by listening, "
        "publisher, endpoint and subscribers.",
    )
    p.add_argument("--graph", metavar="NAME", help=graph_help)
    p.add_argument(
        "--listen", type=float, default=1.0, metavar="S", help="seconds to measure rates (1)"
    )
    p.add_argument("--json", action="store_true", help="print one JSON object instead of a table")
    p.set_defaults(func=_quiet_broken_pipe(cmd_topics))

    p = sub.add_parser(
        "echo",
        help="print the messages of a topic as they arrive",
        description="One line per message (header, scalar fields, arrays as name[shape] "
        "min..max), or one JSON object per line with --json. Ctrl-C stops.",
    )
    p.add_argument("topic", help="topic name, e.g. raw_scan")
    p.add_argument("--graph", metavar="NAME", help=graph_help)
    p.add_argument("--count", type=int, metavar="N", help="stop after N messages")
    p.add_argument("--json", action="store_true", help="one JSON object per message (NaN as null)")
    p.set_defaults(func=_quiet_broken_pipe(cmd_echo))

    p = sub.add_parser(
        "hz",
        help="measure the rate of a topic",
        description="Rate, mean/min/max period and message count over a sliding window, "
        "printed once per second. Ctrl-C stops.",
    )
    p.add_argument("topic", help="topic name, e.g. world_truth")
    p.add_argument("--graph", metavar="NAME", help=graph_help)
    p.add_argument("--window", type=float, default=5.0, metavar="S", help="sliding window in s (5)")
    p.add_argument("--duration", type=float, metavar="S", help="stop after S seconds")
    p.set_defaults(func=_quiet_broken_pipe(cmd_hz))

    p = sub.add_parser(
        "replay",
        help="publish a recording again into a running graph or at an endpoint",
        description="Publish the messages of a recording (launch --record) byte for byte, "
        "keeping their recorded spacing divided by --speed. With --graph (default: the newest "
        "running graph) each recorded topic the graph takes from an [[external]] publisher is "
        "published at that external's endpoint; with --endpoint every topic is published there. "
        "The heartbeat and stop topics are skipped unless named in --topics. The whole "
        "recording is read first: one that cannot be read (empty, not MCAP, cut short, a "
        "damaged chunk or record) is refused with one line and status 2, before anything is "
        "sent. A message that does not decode as its topic's type is skipped and counted (a "
        "warning on stderr names the first problem); if no selected message decodes, replay "
        "refuses with status 2.",
    )
    p.add_argument("file", metavar="FILE.mcap", help="recording to replay")
    target = p.add_mutually_exclusive_group()
    target.add_argument("--graph", metavar="NAME", help=graph_help)
    target.add_argument(
        "--endpoint", metavar="EP", help="bind this endpoint and publish every topic there"
    )
    p.add_argument(
        "--speed",
        type=float,
        default=1.0,
        metavar="X",
        help="speed-up of the recorded timing (1; 0: as fast as possible)",
    )
    p.add_argument("--topics", nargs="+", metavar="T", help="replay only these topics")
    p.add_argument(
        "--wait",
        type=float,
        default=3.0,
        metavar="S",
        help="wait up to S seconds for the expected subscribers before starting (3)",
    )
    p.add_argument(
        "--keys-dir", metavar="DIR", help="CURVE keys for a tcp:// --endpoint (default: graph's)"
    )
    p.set_defaults(func=_quiet_broken_pipe(cmd_replay))
