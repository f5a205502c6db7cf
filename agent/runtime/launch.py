"""Launch files: a whole process graph in one TOML file, validated before anything starts.

::

    [graph]
    name = "sim"
    heartbeat_s = 0.5            # every process's heartbeat period
    join_timeout_s = 3.0         # how long a publisher waits for the subscribers it expects
    keys_dir = "keys"            # CURVE keys, needed for tcp:// endpoints (relative: to this file)

    [defaults]                   # any per-process supervision key, for every process
    restart = "on-failure"       # "never" | "on-failure" | "always"
    max_restarts = 5             # restarts allowed within restart_window_s ...
    restart_window_s = 60.0
    backoff_s = 0.1              # ... after a delay doubling with each recent restart (cap 4 s)
    stop_graph_on_failure = true # when the limit is reached, stop the whole graph
    host = "localhost"

    [[process]]
    name = "head"
    module = "processes.head"    # run as `python -m processes.head`
    inputs = ["head_command", "world_truth"]
    outputs = ["raw_scan", "head_state"]
    endpoint = "ipc://{runtime}/head.pub"   # optional; this is the default
    params = { world = "../worlds/office.toml", seed = 1 }

    [[external]]                 # a publisher outside the graph, e.g. a vehicle controller
    name = "controller"
    endpoint = "ipc://{runtime}/controller.pub"
    outputs = ["wheel_command", "head_command"]

Endpoints: ``{runtime}`` is the graph's private runtime directory (made per run, mode 0700).
A graph split over hosts names each process's ``host`` and gives ``tcp://`` endpoints to every
publisher whose topics cross hosts; the same file is launched on each host with ``--host``.
Topic names must be in :mod:`agent.runtime.topics`. Parameters named like paths (``world``,
``calibration``) are resolved relative to the launch file.
"""

from __future__ import annotations

import importlib.util
import json
import math
import tomllib
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any

from agent.errors import LaunchFileError
from agent.runtime.topics import HEARTBEAT, STOP, TOPIC_TYPES

RESTART_POLICIES = ("never", "on-failure", "always")
PATH_PARAMS = ("world", "calibration")
_GRAPH_KEYS = {"name", "heartbeat_s", "join_timeout_s", "keys_dir", "control_endpoint"}
_SUPERVISION_KEYS = {
    "restart",
    "max_restarts",
    "restart_window_s",
    "backoff_s",
    "stop_graph_on_failure",
    "host",
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
        """Fill ``{runtime}`` in every endpoint with the graph's runtime directory."""
        rt = str(runtime_dir)

        def fill(endpoint: str) -> str:
            return endpoint.replace("{runtime}", rt)

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
    """Read and validate a launch file; raise :class:`LaunchFileError` naming the problem."""
    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise LaunchFileError(path, "no such file") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise LaunchFileError(path, f"cannot read: {exc}") from None
    return parse_launch(text, path)


def parse_launch(text: str, path: str | Path | None = None) -> GraphSpec:
    """Parse launch TOML text (see the module docstring)."""
    r = _Reader(path)
    try:
        doc = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise r.fail(f"not valid TOML: {str(exc).splitlines()[0]}") from None
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
    spec = GraphSpec(
        name=r.string(graph, "name", "[graph]", Path(path).stem if path else "graph"),
        path=str(path or ""),
        processes=tuple(processes),
        externals=tuple(externals),
        heartbeat_s=r.number(graph, "heartbeat_s", "[graph]", 0.5),
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
    try:
        found = importlib.util.find_spec(module) is not None
    except (ImportError, ValueError):
        found = False
    if not found:
        raise r.fail(f"{where}: module {module!r} not found")
    restart = merged.get("restart", "on-failure")
    if restart not in RESTART_POLICIES:
        raise r.fail(
            f"{where}: restart must be one of {', '.join(RESTART_POLICIES)}, got {restart!r}"
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
    )  # fmt: skip


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
