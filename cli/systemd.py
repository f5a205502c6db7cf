"""``sensor-agent systemd LAUNCH --host H --out DIR``: a host's part of a graph as systemd units.

On the robot each computer runs its own part of the graph (the ``host`` of each process in
the launch file) as services that start at boot, restart on failure and log to the journal,
without a launcher in a terminal. This command writes, for the processes of one host:

* ``sensor-agent-GRAPH-NAME.service`` per process: ``python -m MODULE --graph FILE --name
  NAME``, exactly as the launcher starts it, with the launch file's supervision in systemd's
  terms (below);
* ``sensor-agent-GRAPH.target``: the host's part as one unit to enable, start and stop;
* ``sensor-agent-GRAPH-stop.service`` when a process has ``stop_graph_on_failure``: stops the
  target when that process has failed for good;
* ``graph.json``: the resolved graph the units read (install it as ``--etc``/GRAPH/graph.json):
  endpoints under the runtime directory ``/run/sensor-agent-GRAPH``, CURVE keys at
  ``--keys-dir``.

The launch file's supervision, as the units carry it:

=========================== ==============================================================
launcher                    unit
=========================== ==============================================================
restart on-failure, always  ``Restart=always`` (a stage never ends by itself: any exit while
                            the graph runs is a failure, as for the launcher); ``never``:
                            ``Restart=no``. ``RestartPreventExitStatus=2``: a bad parameter
                            does not mend by restarting.
max_restarts in window      ``StartLimitBurst`` = max_restarts + 1 starts within
                            ``StartLimitIntervalSec`` = restart_window_s
backoff_s                   ``RestartSec`` (fixed: systemd 252, Debian 12's, has no growing
                            delay; ``RestartSteps`` came in 254)
start_timeout_s             ``TimeoutStartSec``, to ``READY=1`` (the first running heartbeat)
hang_timeout_s              ``WatchdogSec``: each heartbeat pings the watchdog
                            (:mod:`processes.service_notify`); a hung process is killed
stop_graph_on_failure       ``OnFailure=sensor-agent-GRAPH-stop.service``
standby spares              none: systemd starts a new interpreter (a restart takes the
                            imports' second or two, not the launcher's tens of ms)
=========================== ==============================================================

Every unit runs as ``--user`` (made by the install steps in ``docs/deploy.md``), shares the
graph's runtime directory (``RuntimeDirectory``, mode 0700, kept across a unit's restart so
the others' sockets stay), and is sandboxed read-only (``ProtectSystem=strict``): a stage
writes nothing but its sockets. A head on a serial line also gets the ``dialout`` group.
Path parameters (``world``, ``calibration``) were made absolute when the launch file was
read: run this command on the robot, where those files are.
"""

from __future__ import annotations

import argparse
import re
import sys
from dataclasses import replace
from pathlib import Path

from agent.errors import ConfigError
from agent.runtime.launch import GraphSpec, ProcessSpec, load_launch

PREFIX = "sensor-agent"
DEFAULT_USER = "sensor-agent"
DEFAULT_ETC = Path("/etc/sensor-agent")
_UNIT_NAME = re.compile(r"[A-Za-z0-9_.-]+")  # what a unit name may hold without escaping
# The serial head's device: the group that owns /dev/ttyUSB* and /dev/ttyACM* on Debian.
SERIAL_GROUP = "dialout"


def unit_prefix(graph: GraphSpec) -> str:
    return f"{PREFIX}-{graph.name}"


def runtime_directory(graph: GraphSpec) -> str:
    """The runtime directory's name under ``/run`` (``RuntimeDirectory=``)."""
    return unit_prefix(graph)


def _span(seconds: float) -> str:
    """A systemd time span: whole seconds as such, else whole milliseconds (at least 1)."""
    ms = max(1, round(seconds * 1000))
    return f"{ms // 1000}s" if ms % 1000 == 0 else f"{ms}ms"


def _header(graph: GraphSpec, host: str) -> str:
    return (
        f"# Written by `sensor-agent systemd {graph.path} --host {host}`; "
        "regenerate rather than edit.\n"
    )


def service_unit(
    graph: GraphSpec,
    spec: ProcessSpec,
    *,
    host: str,
    python: str,
    graph_file: str,
    user: str,
    group: str,
) -> str:
    """The ``.service`` unit of one process."""
    prefix = unit_prefix(graph)
    tcp = any(ep.startswith("tcp://") for ep in graph.endpoints().values())
    unit = [
        "[Unit]",
        f"Description=sensor agent {graph.name}: {spec.name} ({spec.module})",
        f"PartOf={prefix}.target",
        f"StartLimitIntervalSec={_span(spec.restart_window_s)}",
        f"StartLimitBurst={spec.max_restarts + 1}",
    ]
    if tcp:
        unit += ["Wants=network-online.target", "After=network-online.target"]
    if spec.stop_graph_on_failure:
        unit.append(f"OnFailure={prefix}-stop.service")
    service = [
        "[Service]",
        "Type=notify",
        "NotifyAccess=main",
        f"ExecStart={python} -m {spec.module} --graph {graph_file} --name {spec.name}",
        f"Restart={'no' if spec.restart == 'never' else 'always'}",
        "RestartPreventExitStatus=2",
        f"RestartSec={_span(spec.backoff_s)}",
        f"TimeoutStartSec={_span(graph.start_timeout_s)}",
        f"WatchdogSec={_span(graph.hang_timeout_s)}",
        "WatchdogSignal=SIGKILL",
        f"User={user}",
        f"Group={group}",
    ]
    if spec.params.get("backend") == "serial":
        service.append(f"SupplementaryGroups={SERIAL_GROUP}")
    service += [
        f"RuntimeDirectory={runtime_directory(graph)}",
        "RuntimeDirectoryMode=0700",
        "RuntimeDirectoryPreserve=yes",
        f"SyslogIdentifier={prefix}-{spec.name}",
        "Environment=PYTHONUNBUFFERED=1",
        "NoNewPrivileges=yes",
        "ProtectSystem=strict",
        "ProtectHome=read-only",
        "PrivateTmp=yes",
        "ProtectKernelTunables=yes",
        "ProtectControlGroups=yes",
        "RestrictSUIDSGID=yes",
    ]
    install = ["[Install]", f"WantedBy={prefix}.target"]
    return (
        _header(graph, host)
        + "\n".join(unit)
        + "\n\n"
        + "\n".join(service)
        + "\n\n"
        + "\n".join(install)
        + "\n"
    )


def target_unit(graph: GraphSpec, host: str, services: list[str]) -> str:
    """The ``.target`` that starts and stops the host's part of the graph."""
    return _header(graph, host) + "\n".join(
        [
            "[Unit]",
            f"Description=sensor agent {graph.name} on {host}: {len(services)} processes",
            f"Wants={' '.join(services)}",
            "",
            "[Install]",
            "WantedBy=multi-user.target",
            "",
        ]
    )


def stop_unit(graph: GraphSpec, host: str, systemctl: str) -> str:
    """Stops the target when a process with ``stop_graph_on_failure`` has failed for good."""
    prefix = unit_prefix(graph)
    return _header(graph, host) + "\n".join(
        [
            "[Unit]",
            f"Description=stop sensor agent {graph.name}: a process failed for good",
            "",
            "[Service]",
            "Type=oneshot",
            f"ExecStart={systemctl} stop --no-block {prefix}.target",
            "",
        ]
    )


def write_units(
    graph: GraphSpec,
    host: str,
    out: Path,
    *,
    python: str = sys.executable,
    user: str = DEFAULT_USER,
    group: str | None = None,
    etc: Path = DEFAULT_ETC,
    keys_dir: str | None = None,
    systemctl: str = "/usr/bin/systemctl",
) -> list[Path]:
    """Write the units and the resolved graph for ``host``'s processes; the files written.

    :class:`ConfigError` if the host runs no process or a name cannot be a unit's.
    """
    processes = graph.on_host(host)
    if not processes:
        hosts = sorted({p.host for p in graph.processes})
        raise ConfigError(f"no process on host {host!r} (hosts: {', '.join(hosts)})")
    for name in (graph.name, *(p.name for p in processes)):
        if not _UNIT_NAME.fullmatch(name):
            raise ConfigError(f"{name!r} cannot name a unit: use letters, digits, '_', '.' and '-'")
    if not Path(python).is_absolute():
        raise ConfigError(f"--python {python!r} must be an absolute path")
    if graph.keys_dir:
        graph = replace(graph, keys_dir=keys_dir or str(etc / graph.name / "keys"))
    resolved = graph.resolve(Path("/run") / runtime_directory(graph))
    graph_file = str(etc / graph.name / "graph.json")
    out.mkdir(parents=True, exist_ok=True)
    prefix = unit_prefix(graph)
    written: list[Path] = []

    def write(name: str, text: str) -> None:
        path = out / name
        path.write_text(text)
        written.append(path)

    write("graph.json", resolved.to_json() + "\n")
    services = []
    for spec in resolved.on_host(host):
        name = f"{prefix}-{spec.name}.service"
        services.append(name)
        write(
            name,
            service_unit(
                resolved, spec, host=host, python=python, graph_file=graph_file,
                user=user, group=group or user,
            ),
        )  # fmt: skip
    write(f"{prefix}.target", target_unit(resolved, host, services))
    if any(p.stop_graph_on_failure for p in processes):
        write(f"{prefix}-stop.service", stop_unit(resolved, host, systemctl))
    return written


def systemd_command(args: argparse.Namespace) -> int:
    try:
        graph = load_launch(args.launch)
        out = Path(args.out)
        written = write_units(
            graph, args.host, out, python=args.python, user=args.user, group=args.group,
            etc=Path(args.etc), keys_dir=args.keys_dir,
        )  # fmt: skip
    except ConfigError as exc:
        print(f"sensor-agent: systemd {args.launch}: {exc}", file=sys.stderr)
        return 2
    except OSError as exc:
        print(f"sensor-agent: systemd: cannot write {args.out}: {exc}", file=sys.stderr)
        return 2
    prefix = unit_prefix(graph)
    graph_dir = Path(args.etc) / graph.name
    units = [p for p in written if p.suffix in (".service", ".target")]
    print(f"graph {graph.name}, host {args.host}: {len(units)} units in {out}")
    for path in written:
        print(f"  {path.name}")
    print("install, as root (docs/deploy.md):")
    print(f"  install -D -m 0644 {out / 'graph.json'} {graph_dir / 'graph.json'}")
    if graph.keys_dir:
        keys = args.keys_dir or str(graph_dir / "keys")
        owner = f"chown -R {args.user}: {keys} && chmod 700 {keys}"
        print(f"  cp -r {graph.keys_dir} {keys} && {owner}")
    print(f"  install -m 0644 {' '.join(str(p) for p in units)} /etc/systemd/system/")
    print(f"  systemctl daemon-reload && systemctl enable --now {prefix}.target")
    return 0
