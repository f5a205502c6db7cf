"""Launch files: a whole process graph in one TOML file, validated before anything starts.

::

    [graph]
    name = "sim"
    heartbeat_s = 0.5            # every process's heartbeat period
    hang_timeout_s = 2.0         # no heartbeat this long from a running process: it hung
                                 # (default: four heartbeat periods)
    start_timeout_s = 30.0       # ... or this long from its start to its first "running" beat
    join_timeout_s = 3.0         # how long a publisher waits for the subscribers it expects
    keys_dir = "keys"            # CURVE keys, needed for tcp:// endpoints (relative: to this file)

    [defaults]                   # any per-process supervision key, for every process
    restart = "on-failure"       # "never" | "on-failure" | "always"
    max_restarts = 5             # restarts allowed within restart_window_s ...
    restart_window_s = 60.0
    backoff_s = 0.1              # ... after a delay doubling with each recent restart (cap 4 s)
    stop_graph_on_failure = true # when the limit is reached, stop the whole graph
    host = "localhost"
    backlog = "newest"           # after a stall, only the newest queued message of a stream
                                 # topic is handled ("all": every one, for throughput benches)
    standby = true               # keep a prepared spare process to restart in well under 1 s

    [[process]]
    name = "head"
    module = "processes.head"    # a stage entry point of the project, run as `python -m`
    inputs = ["head_command", "world_truth"]
    outputs = ["raw_scan", "head_state"]
    endpoint = "ipc://{runtime}/head.pub"   # optional; this is the default
    params = { world = "../worlds/office.toml", seed = 1 }

    [[external]]                 # a publisher outside the graph, e.g. a vehicle controller
    name = "controller"
    endpoint = "ipc://{runtime}/controller.pub"
    outputs = ["wheel_command", "head_command"]

Modules: a process's ``module`` must be one of the project's stage entry points (the
``sensor_agent.stages`` entry-point group in ``pyproject.toml``; :func:`stage_modules`), not
any importable module: a launch file cannot make the launcher run arbitrary code.

Endpoints: ``{runtime}`` is the graph's private runtime directory (made per run, mode 0700).
Every ``ipc://`` endpoint must lie inside it: a socket elsewhere could be reached, or
replaced, by other users, and would outlive the run.
A graph split over hosts names each process's ``host`` and gives ``tcp://`` endpoints to every
publisher whose topics cross hosts; the same file is launched on each host with ``--host``.
Topic names must be in :mod:`agent.runtime.topics`. Parameters named like paths (``world``,
``calibration``) are resolved relative to the launch file.
"""

from __future__ import annotations

import functools
import importlib.metadata
import json
import math
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any

from agent.errors import LaunchFileError
from agent.runtime.topics import HEARTBEAT, STOP, TOPIC_TYPES
from agent.toml_files import load_toml, parse_toml

RESTART_POLICIES = ("never", "on-failure", "always")
BACKLOG_POLICIES = ("newest", "all")
STAGE_ENTRY_POINTS = "sensor_agent.stages"
PATH_PARAMS = ("world", "calibration")
_GRAPH_KEYS = {
    "name",
    "heartbeat_s",
    "hang_timeout_s",
    "start_timeout_s",
    "join_timeout_s",
    "keys_dir",
    "control_endpoint",
}
_SUPERVISION_KEYS = {
    "restart",
    "max_restarts",
    "restart_window_s",
    "backoff_s",
    "stop_graph_on_failure",
    "host",
    "backlog",
    "standby",
}
_PROCESS_KEYS = {"name", "module", "inputs", "outputs", "endpoint", "params"} | _SUPERVISION_KEYS
_EXTERNAL_KEYS = {"name", "endpoint", "outputs"}


@dataclass(frozen=True)
class ProcessSpec:
    """One process of the graph, as the launch file describes it."""

    name: str
    module: str
    inputs: tuple[str, ...]
    outputs: tuple[str, ...]
    endpoint: str
    params: dict[str, Any] = field(default_factory=dict)
    host: str = "localhost"
    restart: str = "on-failure"
    max_restarts: int = 5
    restart_window_s: float = 60.0
    backoff_s: float = 0.1
    stop_graph_on_failure: bool = True
    backlog: str = "newest"
    standby: bool = True


@dataclass(frozen=True)
class ExternalSpec:
    """A publisher outside the graph (a vehicle controller, a replay, a test)."""

    name: str
    endpoint: str
    outputs: tuple[str, ...]


@dataclass(frozen=True)
class GraphSpec:
    """A validated process graph."""

    name: str
    path: str
    processes: tuple[ProcessSpec, ...]
    externals: tuple[ExternalSpec, ...] = ()
    heartbeat_s: float = 0.5
    hang_timeout_s: float = 2.0
    start_timeout_s: float = 30.0
    join_timeout_s: float = 3.0
    keys_dir: str = ""
    control_endpoint: str = "ipc://{runtime}/launcher.pub"
    runtime_dir: str = ""

    # --------------------------------------------------------------------------- queries
    def process(self, name: str) -> ProcessSpec:
        for p in self.processes:
            if p.name == name:
                return p
        raise KeyError(f"no process {name!r} in graph {self.name!r}")

    def publishers(self) -> dict[str, tuple[str, str]]:
        """Topic → (publisher name, endpoint), over processes and externals."""
        out: dict[str, tuple[str, str]] = {}
        for p in self.processes:
            for t in p.outputs:
                out[t] = (p.name, p.endpoint)
        for e in self.externals:
            for t in e.outputs:
                out[t] = (e.name, e.endpoint)
        return out

    def subscribers(self, topic: str) -> list[str]:
        return [p.name for p in self.processes if topic in p.inputs]

    def endpoints(self) -> dict[str, str]:
        """Name → publisher endpoint, for every process and external."""
        out = {p.name: p.endpoint for p in self.processes}
        out.update({e.name: e.endpoint for e in self.externals})
        return out

    def on_host(self, host: str | None) -> tuple[ProcessSpec, ...]:
        return tuple(p for p in self.processes if host is None or p.host == host)

    # ----------------------------------------------------------------------- resolution
    def resolve(self, runtime_dir: str | Path) -> GraphSpec:
        """Fill ``{runtime}`` in every endpoint with the graph's runtime directory.

        :class:`LaunchFileError` if an ``ipc://`` endpoint then lies outside it.
        """
        rt = str(runtime_dir)
        inside = Path(rt).resolve()

        def fill(endpoint: str) -> str:
            filled = endpoint.replace("{runtime}", rt)
            if filled.startswith("ipc://"):
                where = Path(filled[len("ipc://") :]).resolve()
                if not where.is_relative_to(inside) or where == inside:
                    raise LaunchFileError(
                        self.path or None,
                        f"endpoint {endpoint!r} lies outside the graph's runtime directory "
                        "(write it as ipc://{runtime}/NAME)",
                    )
            return filled

        return replace(
            self, runtime_dir=rt, control_endpoint=fill(self.control_endpoint),
            processes=tuple(replace(p, endpoint=fill(p.endpoint)) for p in self.processes),
            externals=tuple(replace(e, endpoint=fill(e.endpoint)) for e in self.externals),
        )  # fmt: skip

    def to_json(self) -> str:
        return json.dumps(asdict(self), indent=1)

    @classmethod
    def from_json(cls, text: str) -> GraphSpec:
        d = json.loads(text)
        return cls(
            **{k: v for k, v in d.items() if k not in ("processes", "externals")},
            processes=tuple(ProcessSpec(**{**p, "inputs": tuple(p["inputs"]),
                                           "outputs": tuple(p["outputs"])})
                            for p in d["processes"]),
            externals=tuple(ExternalSpec(**{**e, "outputs": tuple(e["outputs"])})
                            for e in d["externals"]),
        )  # fmt: skip


# --------------------------------------------------------------------------------- parsing
class _Reader:
    def __init__(self, path: str | Path | None) -> None:
        self.path = path

    def fail(self, problem: str) -> LaunchFileError:
        return LaunchFileError(self.path, problem)

    def table(self, value: Any, where: str, allowed: set[str]) -> dict[str, Any]:
        if not isinstance(value, dict):
            raise self.fail(f"{where} must be a table")
        unknown = sorted(set(value) - allowed)
        if unknown:
            raise self.fail(
                f"{where}: unknown key {unknown[0]!r} (allowed: {', '.join(sorted(allowed))})"
            )
        return value

    def string(self, d: dict[str, Any], key: str, where: str, default: str | None = None) -> str:
        value = d.get(key, default)
        if not isinstance(value, str) or not value:
            raise self.fail(f"{where}: {key} must be a non-empty string, got {value!r}")
        return value

    def number(
        self, d: dict[str, Any], key: str, where: str, default: float, positive: bool = True
    ) -> float:
        value = d.get(key, default)
        if (
            isinstance(value, bool)
            or not isinstance(value, int | float)
            or not math.isfinite(value)
            or (positive and value <= 0)
        ):
            raise self.fail(f"{where}: {key} must be a positive number, got {value!r}")
        return float(value)

    def integer(self, d: dict[str, Any], key: str, where: str, default: int) -> int:
        value = d.get(key, default)
        if isinstance(value, bool) or not isinstance(value, int) or value < 0:
            raise self.fail(f"{where}: {key} must be a whole number >= 0, got {value!r}")
        return value

    def boolean(self, d: dict[str, Any], key: str, where: str, default: bool) -> bool:
        value = d.get(key, default)
        if not isinstance(value, bool):
            raise self.fail(f"{where}: {key} must be true or false, got {value!r}")
        return value

    def topics(self, d: dict[str, Any], key: str, where: str) -> tuple[str, ...]:
        value = d.get(key, [])
        if not isinstance(value, list) or not all(isinstance(t, str) for t in value):
            raise self.fail(f"{where}: {key} must be a list of topic names")
        for t in value:
            if t not in TOPIC_TYPES or t in (HEARTBEAT, STOP):
                raise self.fail(
                    f"{where}: unknown topic {t!r} in {key} (known: "
                    f"{', '.join(sorted(set(TOPIC_TYPES) - {HEARTBEAT, STOP}))})"
                )
        if len(set(value)) != len(value):
            raise self.fail(f"{where}: {key} lists a topic twice")
        return tuple(value)


def load_launch(path: str | Path) -> GraphSpec:
    """Read and validate a launch file; raise :class:`LaunchFileError` naming the problem.

    The file goes through :func:`agent.toml_files.load_toml`: at most 1 MiB, UTF-8, TOML
    nested no deeper than the parser's stack allows, each failure one line.
    """
    return _parse(load_toml(path, functools.partial(LaunchFileError, path)), path)


def parse_launch(text: str, path: str | Path | None = None) -> GraphSpec:
    """Parse launch TOML text (see the module docstring)."""
    return _parse(parse_toml(text, functools.partial(LaunchFileError, path)), path)


def _parse(doc: dict[str, Any], path: str | Path | None) -> GraphSpec:
    r = _Reader(path)
    r.table(doc, "top level", {"graph", "defaults", "process", "external"})
    base = Path(path).resolve().parent if path is not None else Path.cwd()
    graph = r.table(doc.get("graph", {}), "[graph]", _GRAPH_KEYS)
    defaults = r.table(doc.get("defaults", {}), "[defaults]", _SUPERVISION_KEYS)
    raw_processes = doc.get("process", [])
    if not isinstance(raw_processes, list) or not raw_processes:
        raise r.fail("needs at least one [[process]]")
    processes = [_process(r, item, i + 1, defaults, base) for i, item in enumerate(raw_processes)]
    raw_externals = doc.get("external", [])
    if not isinstance(raw_externals, list):
        raise r.fail("[[external]] must be an array of tables")
    externals = []
    for i, item in enumerate(raw_externals):
        where = f"[[external]] {i + 1}"
        e = r.table(item, where, _EXTERNAL_KEYS)
        externals.append(
            ExternalSpec(
                r.string(e, "name", where),
                r.string(e, "endpoint", where),
                r.topics(e, "outputs", where),
            )
        )
    keys_dir = graph.get("keys_dir", "")
    if not isinstance(keys_dir, str):
        raise r.fail("[graph]: keys_dir must be a string")
    heartbeat_s = r.number(graph, "heartbeat_s", "[graph]", 0.5)
    spec = GraphSpec(
        name=r.string(graph, "name", "[graph]", Path(path).stem if path else "graph"),
        path=str(path or ""),
        processes=tuple(processes),
        externals=tuple(externals),
        heartbeat_s=heartbeat_s,
        hang_timeout_s=r.number(graph, "hang_timeout_s", "[graph]", 4 * heartbeat_s),
        start_timeout_s=r.number(graph, "start_timeout_s", "[graph]", 30.0),
        join_timeout_s=r.number(graph, "join_timeout_s", "[graph]", 3.0),
        keys_dir=str((base / keys_dir).resolve()) if keys_dir else "",
        control_endpoint=r.string(
            graph, "control_endpoint", "[graph]", "ipc://{runtime}/launcher.pub"
        ),
    )
    _check_graph(r, spec)
    return spec


def _process(
    r: _Reader, item: Any, index: int, defaults: dict[str, Any], base: Path
) -> ProcessSpec:
    where = f"[[process]] {index}"
    d = r.table(item, where, _PROCESS_KEYS)
    name = r.string(d, "name", where)
    where = f"process {name!r}"
    merged = {**defaults, **d}
    module = r.string(d, "module", where)
    stages = stage_modules()
    if module not in stages:
        raise r.fail(
            f"{where}: module {module!r} is not a stage of this project "
            f"(stages: {', '.join(sorted(stages)) or 'none installed'})"
        )
    restart = merged.get("restart", "on-failure")
    if restart not in RESTART_POLICIES:
        raise r.fail(
            f"{where}: restart must be one of {', '.join(RESTART_POLICIES)}, got {restart!r}"
        )
    backlog = merged.get("backlog", "newest")
    if backlog not in BACKLOG_POLICIES:
        raise r.fail(
            f"{where}: backlog must be one of {', '.join(BACKLOG_POLICIES)}, got {backlog!r}"
        )
    params = d.get("params", {})
    if not isinstance(params, dict):
        raise r.fail(f"{where}: params must be a table")
    for key, value in params.items():
        if not _plain(value):
            raise r.fail(
                f"{where}: parameter {key!r} must be a string, number, boolean or a "
                f"list or table of them, got {type(value).__name__}"
            )
    params = {
        k: (str((base / v).resolve()) if k in PATH_PARAMS and isinstance(v, str) and v else v)
        for k, v in params.items()
    }
    return ProcessSpec(
        name=name, module=module,
        inputs=r.topics(d, "inputs", where), outputs=r.topics(d, "outputs", where),
        endpoint=r.string(d, "endpoint", where, "ipc://{runtime}/" + name + ".pub"),
        params=params,
        host=r.string(merged, "host", where, "localhost"),
        restart=restart,
        max_restarts=r.integer(merged, "max_restarts", where, 5),
        restart_window_s=r.number(merged, "restart_window_s", where, 60.0),
        backoff_s=r.number(merged, "backoff_s", where, 0.1),
        stop_graph_on_failure=r.boolean(merged, "stop_graph_on_failure", where, True),
        backlog=backlog,
        standby=r.boolean(merged, "standby", where, True),
    )  # fmt: skip


def stage_modules() -> frozenset[str]:
    """The modules a launch file may run: the project's ``sensor_agent.stages`` entry points."""
    return frozenset(
        ep.value.partition(":")[0]
        for ep in importlib.metadata.entry_points(group=STAGE_ENTRY_POINTS)
    )


def _plain(value: Any) -> bool:
    """A value the launcher can hand to a process (through JSON)."""
    if isinstance(value, bool | str):
        return True
    if isinstance(value, int | float):
        return math.isfinite(value)
    if isinstance(value, list):
        return all(_plain(v) for v in value)
    if isinstance(value, dict):
        return all(isinstance(k, str) and _plain(v) for k, v in value.items())
    return False


def _check_graph(r: _Reader, spec: GraphSpec) -> None:
    if spec.hang_timeout_s < 2 * spec.heartbeat_s:
        raise r.fail(
            f"[graph]: hang_timeout_s ({spec.hang_timeout_s:g}) must be at least two "
            f"heartbeat periods ({2 * spec.heartbeat_s:g} s)"
        )
    names = [p.name for p in spec.processes] + [e.name for e in spec.externals]
    for n in names:
        if names.count(n) > 1:
            raise r.fail(f"duplicate process name {n!r}")
        if n == "launcher":
            raise r.fail("'launcher' is reserved for the supervisor")
    endpoints = [spec.control_endpoint, *spec.endpoints().values()]
    for ep in endpoints:
        if endpoints.count(ep) > 1:
            raise r.fail(f"duplicate endpoint {ep!r}")
        if not ep.startswith(("ipc://", "tcp://")):
            raise r.fail(f"endpoint {ep!r} must be ipc:// or tcp://")
        if ep.startswith("tcp://") and not spec.keys_dir:
            raise r.fail(f"endpoint {ep!r} is tcp:// but [graph] has no keys_dir for CURVE")
    published: dict[str, str] = {}
    for p in spec.processes:
        for t in p.outputs:
            if t in published:
                raise r.fail(f"topic {t!r} published by both {published[t]!r} and {p.name!r}")
            published[t] = p.name
    for e in spec.externals:
        for t in e.outputs:
            if t in published:
                raise r.fail(f"topic {t!r} published by both {published[t]!r} and {e.name!r}")
            published[t] = e.name
    hosts = {p.name: p.host for p in spec.processes}
    endpoint_of = spec.endpoints()
    for p in spec.processes:
        for t in p.inputs:
            if t not in published:
                raise r.fail(
                    f"process {p.name!r} reads {t!r}, which nothing publishes "
                    "(add a process or an [[external]])"
                )
            source = published[t]
            if (
                source in hosts
                and hosts[source] != p.host
                and not endpoint_of[source].startswith("tcp://")
            ):
                raise r.fail(
                    f"process {p.name!r} on {p.host} reads {t!r} from {source!r} on "
                    f"{hosts[source]}: that endpoint must be tcp://"
                )
