"""``sensor-agent export RUN.mcap OUT.mcap --foxglove`` and ``sensor-agent view``: a run, or a
running graph, in the Foxglove app (channels, schemas and frames: :mod:`cli.viewer_convert`).

* ``export`` reads a recording (``launch --record``, ``demo``'s ``run.mcap``), decodes each
  message as its topic's type, converts it and writes the Foxglove messages with the Foxglove
  SDK's MCAP writer, logged at their stamps. ``--foxglove`` is the only output format so far;
  it is required all the same, so that another format can come without changing what a
  command line means. OUT is written as ``.OUT.partial`` beside it and renamed when complete:
  a recording that turns out damaged part-way leaves no OUT behind. OUT may not be the input.
* ``view`` attaches to a running graph as ``echo`` does (the newest, or ``--graph``: a name,
  a runtime directory, or the graph.json of a graph run as services), subscribes to the
  topics it shows, converts each message as ``export`` does and serves the result on a
  Foxglove WebSocket server (``ws://HOST:PORT``: in the Foxglove app, Open connection,
  Foxglove WebSocket). Every channel of the graph's topics is advertised at once; a message
  is converted only for the channels a client has subscribed to. It runs until Ctrl-C or
  SIGTERM (status 0) or ``--duration`` seconds.

A message that does not decode is skipped and counted, never fatal. Both commands end with
what went to each channel and what was skipped, by reason. Only these commands import the
Foxglove SDK (``pip install '.[viewer]'``), when they run; each logs through a private SDK
context, so nothing lingers in the SDK's global state.
"""

from __future__ import annotations

import argparse
import logging
import os
import time
from collections import Counter
from pathlib import Path
from typing import Any

from agent.errors import ConfigError, MessageError
from agent.runtime.messages import Message, decode
from agent.runtime.topics import MAX_BYTES, TOPIC_TYPES
from cli.introspect import POLL_S, Listener, check_positive, find_graph, interruptible
from cli.viewer_convert import CHANNEL_SCHEMAS, TOPIC_CHANNELS, Converter

SDK_HINT = "pip install '.[viewer]'"

__all__ = ["export_command", "view_command"]


def _sdk(what: str) -> Any:
    """The ``foxglove`` package, or a one-line :class:`ConfigError` naming how to install it."""
    try:
        import foxglove
        import foxglove.channels
        import foxglove.messages
    except ImportError:
        raise ConfigError(f"{what} needs the Foxglove SDK: {SDK_HINT}") from None
    return foxglove


def _print(line: str) -> None:
    print(line, flush=True)


class _Channels:
    """The SDK's typed channels of one context, made on first use, and what each carried."""

    def __init__(self, fox: Any, context: Any) -> None:
        self._fox = fox
        self._context = context
        self._made: dict[str, Any] = {}
        self.counts: Counter[str] = Counter()

    def get(self, name: str) -> Any:
        channel = self._made.get(name)
        if channel is None:
            kind = getattr(self._fox.channels, f"{CHANNEL_SCHEMAS[name]}Channel")
            channel = self._made[name] = kind(name, context=self._context)
        return channel

    def has_sinks(self, name: str) -> bool:
        return bool(self.get(name).has_sinks())

    def log(self, name: str, message: Any, stamp_ns: int) -> None:
        self.get(name).log(message, log_time=stamp_ns)
        self.counts[name] += 1

    def close(self) -> None:
        for channel in self._made.values():
            channel.close()


class _Intake:
    """Decoding of bus payloads for conversion, with the counts of what was left out."""

    def __init__(self) -> None:
        self.received: Counter[str] = Counter()
        self.not_shown: Counter[str] = Counter()
        self.skipped: Counter[str] = Counter()
        self.first_problem: dict[str, str] = {}

    def decode(self, topic: str, payload: bytes) -> Message | None:
        """The message, or ``None`` (counted) for a topic not shown or a payload that does not
        decode as its topic's type."""
        self.received[topic] += 1
        if topic not in TOPIC_CHANNELS:
            self.not_shown[topic or "<malformed>"] += 1
            return None
        try:
            return decode(payload, expect=TOPIC_TYPES[topic])
        except MessageError as exc:
            reason = f"{topic}: does not decode ({exc.kind})"
            self.skipped[reason] += 1
            self.first_problem.setdefault(reason, exc.problem)
            return None

    def report(self, converter: Converter) -> list[str]:
        lines = []
        if self.not_shown:
            listed = ", ".join(f"{t} {n}" for t, n in sorted(self.not_shown.items()))
            lines.append(f"not shown (no view of these topics): {listed}")
        skipped = self.skipped + converter.skipped
        if skipped:
            lines.append(f"skipped {sum(skipped.values())} messages:")
            for reason, n in sorted(skipped.items()):
                first = self.first_problem.get(reason)
                lines.append(f"  {reason}: {n}" + (f" (first: {first})" if first else ""))
        else:
            lines.append("skipped: none")
        return lines


def _channel_table(counts: Counter[str]) -> list[str]:
    lines = [f"  {'channel':14s} {'schema':26s} {'messages':>9s}"]
    for name in CHANNEL_SCHEMAS:
        if counts[name]:
            schema = f"foxglove.{CHANNEL_SCHEMAS[name]}"
            lines.append(f"  {name:14s} {schema:26s} {counts[name]:9d}")
    return lines


def _summary(headline: str, channels: _Channels, intake: _Intake, converter: Converter) -> int:
    """A command's closing lines: ``headline``, then what each channel carried and what
    was left out; status 0."""
    for line in [headline, *_channel_table(channels.counts), *intake.report(converter)]:
        _print(line)
    return 0


def _megabytes(path: Path) -> str:
    return f"{path.stat().st_size / 1e6:.1f} MB"


# ------------------------------------------------------------------------------- export
def _same_file(a: Path, b: Path) -> bool:
    try:
        return a.resolve() == b.resolve() or (b.exists() and os.path.samefile(a, b))
    except OSError:
        return False


def export_command(args: argparse.Namespace) -> int:
    from agent.runtime.recording import library_identifier, read_recording

    if not args.foxglove:
        raise ConfigError(
            "export: --foxglove is required (Foxglove's schemas are the only format so far)"
        )
    source, out = Path(args.input), Path(args.output)
    if _same_file(source, out):
        raise ConfigError(f"export: {out} is the input recording; name another output file")
    fox = _sdk("export --foxglove")
    messages = read_recording(source)  # a missing, empty or non-MCAP file: ConfigError now
    partial = out.with_name(f".{out.name}.partial")
    context = fox.Context()
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
        writer = fox.open_mcap(partial, allow_overwrite=True, context=context)
    except OSError as exc:
        raise ConfigError(f"cannot write {out}: {exc.strerror or exc}") from None
    started = time.perf_counter()
    intake, converter, channels = _Intake(), Converter(), _Channels(fox, context)
    try:
        with writer:
            writer.write_metadata(
                "lep-sensor-agent", {"source": str(source), "library": library_identifier()}
            )
            for message in messages:
                msg = intake.decode(message.topic, message.payload)
                if msg is None:
                    continue
                stamp = msg.header.stamp_ns or message.log_time_ns
                for channel, converted in converter.convert(message.topic, msg):
                    channels.log(channel, converted, stamp)
        if not intake.received:
            raise ConfigError(f"recording {source} holds no messages")
        if not channels.counts:
            topics = ", ".join(sorted(t or "<malformed>" for t in intake.received))
            raise ConfigError(f"recording {source}: nothing to show (its topics: {topics})")
        partial.replace(out)
    except BaseException:
        partial.unlink(missing_ok=True)
        raise
    elapsed = time.perf_counter() - started
    return _summary(
        f"exported {source} ({_megabytes(source)}, {sum(intake.received.values())} messages) "
        f"to {out} ({_megabytes(out)}, {sum(channels.counts.values())} messages, Foxglove "
        f"schemas) in {elapsed:.1f} s",
        channels, intake, converter,
    )  # fmt: skip


# --------------------------------------------------------------------------------- view
def _ws_url(host: str, port: int) -> str:
    return f"ws://[{host}]:{port}" if ":" in host else f"ws://{host}:{port}"


def view_command(args: argparse.Namespace) -> int:
    check_positive(duration=args.duration)
    if not 0 <= args.port <= 65535:
        raise ConfigError(f"--port must be 0-65535 (0: any free port), got {args.port}")
    fox = _sdk("view")
    running = find_graph(args.graph)
    graph = running.graph
    publishers = graph.publishers()
    shown = [t for t in TOPIC_CHANNELS if t in publishers]
    if not shown:
        raise ConfigError(
            f"graph {graph.name} publishes nothing the viewer shows (its topics: "
            f"{', '.join(sorted(publishers)) or 'none'}; shown: {', '.join(TOPIC_CHANNELS)})"
        )
    fox.set_log_level(logging.getLogger().getEffectiveLevel())  # the SDK's logs go to ours
    context = fox.Context()
    try:
        server = fox.start_server(
            name=f"sensor-agent {graph.name}", host=args.host, port=args.port, context=context
        )
    except RuntimeError as exc:
        raise ConfigError(f"view: cannot serve on {args.host}:{args.port}: {exc}") from None
    intake, converter, channels = _Intake(), Converter(), _Channels(fox, context)
    started = time.monotonic()
    try:
        for topic in shown:  # advertised now, before any message: a client sees them all
            for name in TOPIC_CHANNELS[topic]:
                channels.get(name)
        launcher = f"launcher pid {running.pid}" if running.pid else "no launcher: services"
        _print(f"viewing graph {graph.name} ({launcher}): {', '.join(shown)}")
        _print(
            f"open {_ws_url(args.host, server.port)} in Foxglove (Open connection, Foxglove "
            f"WebSocket), or {server.app_url()}; Ctrl-C stops"
        )
        with interruptible() as stop:
            # Only the publishers of the topics shown, and only those topics: raw scans,
            # heartbeats and the rest are not even sent here.
            publishers = graph.publishers()
            listener = Listener(
                graph, shown, endpoints=[publishers[t][1] for t in shown],
                max_bytes=max(MAX_BYTES[t] for t in shown),
            )  # fmt: skip
            try:
                end = started + args.duration if args.duration is not None else float("inf")
                while not stop and (now := time.monotonic()) < end:
                    for topic, payload in listener.poll(min(POLL_S, end - now)):
                        msg = intake.decode(topic, payload)
                        if msg is None:
                            continue
                        stamp = msg.header.stamp_ns or time.time_ns()
                        for name, converted in converter.convert(topic, msg, channels.has_sinks):
                            channels.log(name, converted, stamp)
            finally:
                listener.close()
    finally:
        channels.close()
        server.stop()
    return _summary(
        f"viewed graph {graph.name} for {time.monotonic() - started:.1f} s: "
        f"{sum(intake.received.values())} messages received, "
        f"{sum(channels.counts.values())} sent to clients",
        channels, intake, converter,
    )  # fmt: skip
