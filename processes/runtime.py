"""What every process shell shares: the poll loop around a stage.

A process is started by the launcher as ``python -m processes.NAME --graph FILE --name NAME``
where ``FILE`` is the resolved graph (JSON) in the graph's runtime directory. It then:

1. builds its stage from the launch file's ``params`` (a bad parameter: one line, exit 2);
2. binds its publisher, connects to the publishers of its inputs and to the launcher's
   control endpoint (for ``stop``);
3. waits, up to ``join_timeout_s``, until the subscribers the graph expects on each of its
   outputs have joined, leaving its inputs queued meanwhile (so nobody silently misses the
   start);
4. loops: poll with a timeout until the stage's next tick or the next heartbeat (no busy
   waiting), drop the stale backlog (below), decode and validate each input (a bad one is
   counted per kind, logged once per kind, and dropped), hand it to the stage, publish what
   the stage returns;
5. stops on SIGINT, SIGTERM or a ``stop`` message: one last heartbeat, sockets closed with
   linger 0, exit status 0.

Failing closed:

* **Stage errors**: an exception in the stage's ``handle`` or ``tick`` is caught, counted
  (``stage_errors_<ExceptionName>``), logged once per kind and then at most once every
  ``ERROR_LOG_S`` with the count meanwhile, and its input is dropped. After
  ``FAULT_AFTER`` failures in a row the process beats ``fault`` (at once, and on every
  heartbeat) instead of ``running`` and keeps going: a stage that fails on every input is
  reported, not restarted in a storm that would stop the graph; its first success clears it.
* **Stale backlog**: when several messages of a stream topic are queued at once (the process
  stalled, or started while its inputs were flowing), only the newest is handled and the
  others are dropped unread (``stale_dropped``), unless the topic is one whose every message
  counts (:data:`agent.runtime.topics.KEEP_BACKLOG`) or the process's ``backlog`` is
  ``"all"``. After the process itself stalled (a poll returned ``STALL_S`` later than it
  could have) the backlog is read until none comes before choosing: it trickles in. What
  trickles in later still is known by its header stamp: for up to ``CATCH_UP_S`` after a
  stall, a stream message that lags the process's clock by more than ``STALL_S`` beyond that
  topic's usual lag is dropped too (``stale_dropped``).
* **Sizes**: a payload over its topic's limit (:data:`agent.runtime.topics.MAX_BYTES`) is
  dropped unread (``dropped_oversized``); the subscriber socket's ZeroMQ limit refuses
  anything bigger than the largest of them before it is read (``links_dropped``).

Idle, a process wakes only for its inputs, its stage's ticks and its heartbeats: a signal
ends the poll through a wake-up pipe (:func:`signal.set_wakeup_fd`) instead of a short
timeout (each wake-up costs 50-150 µs of CPU on this project's 2-core machine). The heartbeat
carries, per topic published, ``published_<topic>`` (messages) and
``last_published_ns_<topic>`` (when the latest went out, on the process's clock), from which
the launcher takes each topic's count and rate without listening to it.
"""

from __future__ import annotations

import argparse
import contextlib
import gc
import importlib
import logging
import os
import signal
import sys
import time
from collections import deque
from collections.abc import Callable, Sequence
from pathlib import Path
from statistics import median_low
from types import FrameType

from agent.errors import ConfigError, MessageError, SensorAgentError
from agent.runtime import topics
from agent.runtime.bus import Bus, CurveKeys, SeqTracker
from agent.runtime.launch import GraphSpec, ProcessSpec
from agent.runtime.lockstep import LockstepRunner, Node
from agent.runtime.messages import Header, Heartbeat, Message, Stop, decode, stamp_ns
from agent.runtime.stage import Output, Params, Stage
from processes.service_notify import ServiceNotifier

# A backstop only: inputs, ticks, heartbeats and signals (through the wake-up pipe) end a
# poll before it.
MAX_POLL_S = 1.0
FAULT_AFTER = 5  # stage errors in a row that make a process beat "fault"
ERROR_LOG_S = 10.0  # a kind of stage error already logged is logged again at most this often
MAX_DRAIN = 1000  # messages read in one go while dropping a stale backlog
# A poll that returns this much later than it was allowed to wait means the process did not
# run meanwhile (stopped, or starved of CPU): its inputs' backlog then arrives from the
# sockets' I/O thread a few messages at a time, and is drained with short waits of
# STALL_DRAIN_S until none comes, before the newest is chosen. (Measured in CI: after a
# 1.2 s SIGSTOP, filtering handled three scans 0.5-0.9 s old one by one as they trickled in.)
STALL_S = 0.25
STALL_DRAIN_S = 0.02
# Some of the backlog still trickles in after that drain on a loaded machine (CI: one or two
# scans 0.4-0.9 s old, in 2 of 5 fresh-clone runs). Each stream message's lag (this process's
# clock minus its header stamp) is compared with the median of the topic's last LAG_WINDOW
# accepted lags, a relative test that holds across hosts' clock offsets and for replayed
# recordings: after a stall, one lagging more than STALL_S beyond it is backlog and dropped,
# until the topic's first fresh message, for at most CATCH_UP_S (a pipeline that got slower
# for good is then believed, not starved).
LAG_WINDOW = 8
CATCH_UP_S = 2.0
StageFactory = Callable[[Params], Stage]


class Startup:
    """When each step of a process's start was done, in ms since the launcher spawned it.

    Steps: ``imported`` (the interpreter and the process's modules), ``built`` (the stage),
    ``bound`` (its sockets), ``joined`` (its subscribers), ``started`` (the stage's start,
    e.g. compiled kernels loaded), ``first_output`` (its first message other than a
    heartbeat). They go into the heartbeat as ``startup_ms_<step>``: where a restart's time
    goes. Without ``--spawned-ns`` (a process started by hand) nothing is recorded.
    """

    STEPS = ("imported", "built", "bound", "joined", "started", "first_output")

    def __init__(self, spawned_ns: int | None) -> None:
        self.spawned_ns = spawned_ns
        self.done: dict[str, int] = {}

    @property
    def pending(self) -> bool:
        """Whether a step is still to be recorded."""
        return self.spawned_ns is not None and len(self.done) < len(self.STEPS)

    def mark(self, step: str) -> None:
        if self.spawned_ns is not None and step not in self.done:
            self.done[step] = (time.time_ns() - self.spawned_ns) // 1_000_000

    def counters(self) -> dict[str, int]:
        return {f"startup_ms_{step}": ms for step, ms in self.done.items()}


class ProcessShell:
    """Runs one stage as one OS process on the bus."""

    def __init__(
        self,
        graph: GraphSpec,
        spec: ProcessSpec,
        stage: Stage,
        clock: Callable[[], float] = time.time,
        bus: Bus | None = None,
        startup: Startup | None = None,
    ) -> None:
        """``bus`` is a test seam: anything with Bus's interface (default: real sockets)."""
        self.startup = startup if startup is not None else Startup(None)
        self.graph = graph
        self.spec = spec
        self.stage = stage
        self.clock = clock
        self.log = logging.getLogger(f"process.{spec.name}")
        self.stopping = False
        self.counters: dict[str, int] = {"received": 0, "published": 0, "stale_dropped": 0}
        self.state = "starting"
        self._seq: dict[str, int] = {}  # per topic: messages published so far
        self._last_ns: dict[str, int] = {}  # per topic: when the latest was published
        self._seen_kinds: set[str] = set()
        self._gaps = SeqTracker()
        self._unread: dict[str, int] = {}  # per topic: backlog dropped unread since the last read
        self._errors_in_row = 0
        self._error_logged: dict[str, tuple[float, int]] = {}  # kind: (when, count then)
        self._newest_only = spec.backlog == "newest"
        self._lags_ns: dict[str, deque[int]] = {}  # per stream topic: its last accepted lags
        self._catching_up: dict[str, float] = {}  # stream topic: since when (after a stall)
        self.notifier = ServiceNotifier()  # systemd's Type=notify and watchdog, when under it
        if bus is None:
            keys = CurveKeys.load(graph.keys_dir) if graph.keys_dir else None
            max_bytes = max(topics.MAX_BYTES[t] for t in (*spec.inputs, topics.STOP))
            bus = Bus(spec.endpoint, keys, latched=topics.LATCHED, max_bytes=max_bytes)
        self.bus = bus
        publishers = graph.publishers()
        for topic in spec.inputs:
            self.bus.subscriber.connect(publishers[topic][1])
            self.bus.subscriber.subscribe(topic)
        self.bus.subscriber.connect(graph.control_endpoint)
        self.bus.subscriber.subscribe(topics.STOP)

    # ------------------------------------------------------------------------- publishing
    def publish(self, outputs: list[Output]) -> None:
        if not outputs:
            return
        if self.startup.pending and any(t != topics.HEARTBEAT for t, _ in outputs):
            self.startup.mark("first_output")
        now_ns = stamp_ns(self.clock())
        name = self.spec.name
        for topic, msg in outputs:
            seq = self._seq.get(topic, 0)
            self._seq[topic] = seq + 1
            self._last_ns[topic] = now_ns
            # Stamped on the wire: no copy of the message (and its header) per publication.
            wire = msg.to_wire(seq=seq, source=name, stamp_ns=msg.header.stamp_ns or now_ns)
            self.bus.publish(topic, wire)
        self.counters["published"] += len(outputs)

    def heartbeat(self, state: str) -> None:
        counts = {
            **self.counters,
            **self.stage.counters(),
            "lost": self._gaps.lost,
            "links_dropped": self.bus.subscriber.links_dropped,
            **self.startup.counters(),
        }
        if self.notifier.enabled:
            counts["service_notify_failures"] = self.notifier.failures
        for topic, n in self._seq.items():
            counts[f"published_{topic}"] = n
            counts[f"last_published_ns_{topic}"] = self._last_ns[topic]
        self.publish(
            [
                (
                    topics.HEARTBEAT,
                    Heartbeat(
                        header=Header(stamp_ns=stamp_ns(self.clock())),
                        process=self.spec.name,
                        pid=os.getpid(),
                        state=state,
                        counters=counts,
                    ),
                )
            ]
        )
        self.notifier.beat(state)

    # ---------------------------------------------------------------------------- inputs
    def _drop(self, error: MessageError, topic: str) -> None:
        key = f"dropped_{error.kind}"
        self.counters[key] = self.counters.get(key, 0) + 1
        if error.kind not in self._seen_kinds:  # log each kind once, count them all
            self._seen_kinds.add(error.kind)
            self.log.warning(
                "dropped a message on %r: %s (further %s messages are counted, not logged)",
                topic,
                error,
                error.kind,
            )

    def receive(self, topic: str, payload: bytes) -> None:
        if topic == topics.STOP:
            try:
                stop = decode(payload, expect=Stop)
            except MessageError as exc:
                self._drop(exc, topic)
                return
            if isinstance(stop, Stop) and stop.process in ("", self.spec.name):
                self.log.info("stop requested: %s", stop.reason or "no reason given")
                self.stopping = True
            return
        self.counters["received"] += 1
        try:
            if topic not in self.spec.inputs:
                raise MessageError("unknown_type", f"topic {topic!r} is not an input here")
            if len(payload) > topics.MAX_BYTES[topic]:
                raise MessageError(
                    "oversized",
                    f"{len(payload)} bytes, over the {topics.MAX_BYTES[topic]} a {topic} may have",
                )
            msg: Message = decode(payload, expect=topics.message_type(topic))
        except MessageError as exc:
            self._drop(exc, topic)
            return
        lost = self._gaps.see(topic, msg.header.source, msg.header.seq, self._unread.pop(topic, 0))
        if lost:
            self.counters["lost"] = self.counters.get("lost", 0) + lost
        if self._stale_after_stall(topic, msg.header.stamp_ns):
            self.counters["stale_dropped"] += 1
            return
        self._run_stage(self.stage.handle, topic, msg)

    def _stale_after_stall(self, topic: str, stamp: int) -> bool:
        """Whether a stream message is backlog that trickled in after a stall (see
        ``CATCH_UP_S``); otherwise its lag joins the topic's usual lags."""
        if not self._newest_only or topic in topics.KEEP_BACKLOG:
            return False
        now = self.clock()
        lag = stamp_ns(now) - stamp
        lags = self._lags_ns.setdefault(topic, deque(maxlen=LAG_WINDOW))
        since = self._catching_up.get(topic)
        if since is not None:
            if lags and lag > median_low(lags) + stamp_ns(STALL_S):
                if now - since <= CATCH_UP_S:
                    return True
                lags.clear()  # slower for good: a new usual lag
            del self._catching_up[topic]
        lags.append(lag)
        return False

    def _stalled(self, now: float) -> None:
        """The process itself stalled: its stream inputs catch up (see ``CATCH_UP_S``)."""
        for topic in self.spec.inputs:
            if topic not in topics.KEEP_BACKLOG and topic in self._lags_ns:
                self._catching_up.setdefault(topic, now)

    def _run_stage(self, call: Callable[..., list[Output]], *args: object) -> None:
        """Call the stage and publish what it returns; an exception drops the input only."""
        try:
            outputs = call(*args, self.clock())
        except Exception as exc:  # any stage bug: count it, drop the input, keep the graph up
            self._stage_failed(exc, call.__name__)
            return
        if self._errors_in_row:
            if self.state == "fault":
                self.log.info("stage recovered after %d errors in a row", self._errors_in_row)
                self.state = "running"
            self._errors_in_row = 0
        self.publish(outputs)

    def _stage_failed(self, exc: Exception, where: str) -> None:
        kind = type(exc).__name__
        key = f"stage_errors_{kind}"
        self.counters[key] = count = self.counters.get(key, 0) + 1
        self.counters["stage_errors"] = self.counters.get("stage_errors", 0) + 1
        now = time.monotonic()
        logged = self._error_logged.get(kind)
        if logged is None or now - logged[0] >= ERROR_LOG_S:
            since = "" if logged is None else f" ({count - logged[1]} since the last report)"
            self.log.error(
                "stage %s failed, input dropped: %s: %s%s",
                where,
                kind,
                str(exc).splitlines()[0] if str(exc) else "",
                since,
                exc_info=logged is None,  # the traceback once per kind
            )
            self._error_logged[kind] = (now, count)
        self._errors_in_row += 1
        if self._errors_in_row >= FAULT_AFTER and self.state != "fault":
            self.state = "fault"
            self.log.error("stage failed on %d inputs in a row: beating fault", FAULT_AFTER)
            self.heartbeat(self.state)

    def newest(
        self, messages: list[tuple[str, bytes]], stalled: bool = False
    ) -> list[tuple[str, bytes]]:
        """``messages`` without the stale backlog: of each stream topic, the newest only.

        When several messages of a stream topic are queued, more of the backlog is usually
        still on its way from the publisher: it is read too (up to ``MAX_DRAIN``) before
        choosing, so that one stall costs at most one stale message downstream. After the
        process itself ``stalled`` (see ``STALL_S``) the backlog trickles in: it is read
        with short waits until none comes.
        """
        if not self._newest_only or not messages:
            return messages
        if stalled:
            while len(messages) < MAX_DRAIN and (more := self.bus.poll(STALL_DRAIN_S)):
                messages = [*messages, *more]
        if len(messages) < 2:
            return messages
        keep = topics.KEEP_BACKLOG
        streams = [t for t, _ in messages if t not in keep]
        if len(streams) == len(set(streams)):
            return messages
        while len(messages) < MAX_DRAIN and (more := self.bus.poll(0.0)):
            messages = [*messages, *more]
        last = {t: i for i, (t, _) in enumerate(messages) if t not in keep}
        kept = []
        for i, message in enumerate(messages):
            topic = message[0]
            if topic in keep or last[topic] == i:
                kept.append(message)
            else:
                self._unread[topic] = self._unread.get(topic, 0) + 1
        self.counters["stale_dropped"] += len(messages) - len(kept)
        return kept

    # ------------------------------------------------------------------------------- loop
    def _wait_for_subscribers(self) -> None:
        assert self.bus.publisher is not None  # ProcessSpec always has an endpoint
        expected = {t: len(self.graph.subscribers(t)) for t in self.spec.outputs}
        deadline = self.clock() + self.graph.join_timeout_s
        while not self.stopping and self.clock() < deadline:
            missing = {
                t: n for t, n in expected.items() if self.bus.publisher.subscriber_count(t) < n
            }
            if not missing:
                return
            # Only subscription events: inputs wait in their queue, so nothing is processed
            # (and nothing published) before the expected subscribers are there to hear it.
            self.bus.poll_subscriptions(0.02)
        if not self.stopping:
            late = [t for t, n in expected.items() if self.bus.publisher.subscriber_count(t) < n]
            if late:
                self.log.warning(
                    "starting without every subscriber of %s after %.1f s",
                    ", ".join(late),
                    self.graph.join_timeout_s,
                )

    def run(self) -> int:
        self.heartbeat("starting")
        self._wait_for_subscribers()
        self.startup.mark("joined")
        self.publish(self.stage.start(self.clock()))
        self.startup.mark("started")
        self.state = "running"
        next_beat = self.clock()
        last_return = self.clock()

        def beat_if_due() -> float:
            """Beat when due; the clock now."""
            nonlocal next_beat
            now = self.clock()
            if now >= next_beat:
                self.heartbeat(self.state)
                next_beat = now + self.graph.heartbeat_s
            return now

        while not self.stopping:
            now = beat_if_due()
            tick = self.stage.next_tick_s()
            wake = min(next_beat, tick if tick is not None else next_beat)
            wait = min(MAX_POLL_S, max(0.0, wake - now))
            polled = self.clock()
            received = self.bus.poll(wait)
            # Stopped while waiting, or since the last poll (while handling, or starved).
            returned = self.clock()
            stalled = polled - last_return > STALL_S or returned - polled - wait > STALL_S
            last_return = returned
            if stalled and self._newest_only:
                self._stalled(returned)
            for topic, payload in self.newest(received, stalled):
                self.receive(topic, payload)
                if self.stopping:
                    break
                # A long backlog (up to a queue's 100 messages) is work, not a hang: beat
                # between its messages when due, or the launcher takes a busy process for a
                # hung one and replaces it, losing what it held (seen as scans lost in the
                # saturated pipeline bench on a loaded machine).
                beat_if_due()
            tick = self.stage.next_tick_s()
            if tick is not None and self.clock() >= tick and not self.stopping:
                self._run_stage(self.stage.tick)
        self.heartbeat("stopping")
        return 0

    def close(self) -> None:
        self.bus.close()


def run_process(factory: StageFactory, argv: Sequence[str] | None = None) -> int:
    """The ``main`` of every process module: parse arguments, build, run, clean up."""
    parser = argparse.ArgumentParser(description="a process of the sensor agent's graph")
    parser.add_argument("--graph", required=True, help="resolved graph JSON from the launcher")
    parser.add_argument("--name", required=True, help="this process's name in the graph")
    parser.add_argument(
        "--spawned-ns", type=int, help="when the launcher started this process (time_ns)"
    )
    parser.add_argument(
        "--standby",
        action="store_true",
        help="prepare, then wait for 'go SPAWNED_NS' on stdin before joining the graph",
    )
    args = parser.parse_args(argv)
    startup = Startup(args.spawned_ns)
    startup.mark("imported")
    logging.basicConfig(
        level=logging.INFO,
        stream=sys.stderr,
        format=f"%(asctime)s {args.name} %(levelname)s: %(message)s",
    )
    log = logging.getLogger(f"process.{args.name}")
    try:
        graph = GraphSpec.from_json(Path(args.graph).read_text())
        spec = graph.process(args.name)
        stage = factory(Params(spec.name, spec.params))
    except (OSError, KeyError, ValueError, SensorAgentError) as exc:
        log.error("cannot start: %s", exc)
        return 2
    startup.mark("built")
    if args.standby:
        stage.prepare()
        go = _wait_for_go()
        if go is None:
            return 0  # the launcher closed our stdin: not needed
        startup = Startup(go)
        for step in ("imported", "built"):
            startup.mark(step)
        log.info("standing in")
    stop_signals: list[int] = []

    def on_signal(signum: int, _frame: FrameType | None) -> None:
        stop_signals.append(signum)
        shell.stopping = True
        if shell.state == "starting":  # maybe seconds of kernel loading: stop at once
            raise _StoppedWhileStarting

    try:
        shell = ProcessShell(graph, spec, stage, startup=startup)
    except ConfigError as exc:
        log.error("cannot start: %s", exc)
        return 2
    startup.mark("bound")
    signal.signal(signal.SIGINT, on_signal)
    signal.signal(signal.SIGTERM, on_signal)
    wake_read, wake_write = os.pipe()
    os.set_blocking(wake_read, False)
    os.set_blocking(wake_write, False)
    signal.set_wakeup_fd(wake_write, warn_on_full_buffer=False)
    shell.bus.wake_on(wake_read)
    # Everything made so far (modules, the world, tables) lives as long as the process: keep
    # it out of the cyclic garbage collector's full passes, which would walk it every time.
    gc.freeze()
    try:
        status = shell.run()
    except _StoppedWhileStarting:
        status = 0
    finally:
        shell.close()
        signal.set_wakeup_fd(-1)
        os.close(wake_read)
        os.close(wake_write)
    if stop_signals:
        log.info("stopped by signal %s", signal.Signals(stop_signals[0]).name)
    return status


class _StoppedWhileStarting(BaseException):
    """Raised by the stop signals' handler while the process is still starting."""


def normal_priority(pid: int) -> None:
    """Every thread of a process back from ``SCHED_IDLE`` to the normal policy."""
    if not hasattr(os, "sched_setscheduler"):
        return
    try:
        tasks = [int(t) for t in os.listdir(f"/proc/{pid}/task")]
    except OSError:
        tasks = [pid]
    for task in tasks:
        with contextlib.suppress(OSError):
            os.sched_setscheduler(task, os.SCHED_OTHER, os.sched_param(0))


def _wait_for_go() -> int | None:
    """A standby's wait: until the launcher writes ``go SPAWNED_NS`` (``None`` on EOF).

    The launcher starts a standby under ``SCHED_IDLE`` (it prepares on CPU nobody else
    wants) and puts it back under the normal policy before it writes ``go``. The standby
    does so again once it has read it: a thread its imports started while the launcher
    was at it (numpy's BLAS workers) would otherwise stay idle, and a call waiting on it
    could wait for as long as the machine is busy.
    """
    line = sys.stdin.readline().split()
    if len(line) != 2 or line[0] != "go" or not line[1].isdigit():
        return None
    normal_priority(os.getpid())
    return int(line[1])


def lockstep_graph(
    graph: GraphSpec, host: str | None = None, start_s: float = 0.0, serialise: bool = True
) -> LockstepRunner:
    """The graph's stages, built as their processes build them, in one lock-step runner."""
    nodes = []
    for spec in graph.on_host(host):
        module = importlib.import_module(spec.module)
        factory: StageFactory = module.build
        nodes.append(Node(spec.name, factory(Params(spec.name, spec.params)), spec.inputs))
    return LockstepRunner(nodes, start_s=start_s, serialise=serialise)
