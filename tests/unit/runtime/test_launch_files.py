"""Tests of launch files (agent.runtime.launch), restart policy (agent.runtime.supervision)
and stage Params.

The shipped launch files parse to the graph they describe; every validation error is a
one-line :class:`LaunchFileError` naming the problem; restart decisions are checked with
made-up times and exit codes; typed parameter reads refuse wrong types and ranges.
"""

from __future__ import annotations

import math
from pathlib import Path

import pytest

from agent.errors import ConfigError, LaunchFileError
from agent.runtime import topics
from agent.runtime.launch import GraphSpec, ProcessSpec, load_launch, parse_launch
from agent.runtime.stage import Params
from agent.runtime.supervision import MAX_BACKOFF_S, Decision, RestartTracker
from agent.stages.world_stage import WorldStage
from processes.launcher import TopicStats
from processes.runtime import lockstep_graph

pytestmark = pytest.mark.filterwarnings("error")

REPO = Path(__file__).resolve().parents[3]
SIM = REPO / "launch" / "sim.toml"
SENSOR = REPO / "launch" / "sensor.toml"
AGENT = REPO / "launch" / "agent.toml"
FAKE_PATH = Path("/srv/robot/launch/test.toml")  # need not exist: parse_launch takes text


def _parse(path: Path) -> GraphSpec:
    return parse_launch(path.read_text(encoding="utf-8"), path)


# ============================================================================================
# The shipped launch files
# ============================================================================================
def _check_defaults_and_paths(graph: GraphSpec, backoff_s: float) -> None:
    """What holds for every process of the shipped files: their [defaults] and default endpoint,
    path parameters made absolute (an empty one left empty)."""
    for p in graph.processes:
        assert p.endpoint == f"ipc://{{runtime}}/{p.name}.pub"
        assert (p.restart, p.max_restarts, p.restart_window_s) == ("on-failure", 5, 60.0)
        assert (p.backoff_s, p.stop_graph_on_failure, p.host) == (backoff_s, True, "localhost")
        for key in ("world", "calibration"):
            value = p.params.get(key)
            if value:
                assert Path(value).is_absolute() and Path(value).is_file(), (p.name, key)


def test_sim_launch_file_describes_the_simulated_graph() -> None:
    graph = _parse(SIM)
    assert graph.name == "sim" and graph.path == str(SIM)
    assert graph.heartbeat_s == 0.5 and graph.join_timeout_s == 3.0
    assert graph.keys_dir == "" and graph.control_endpoint == "ipc://{runtime}/launcher.pub"
    names = [p.name for p in graph.processes]
    assert names[:3] == ["world", "head", "calibration"]  # later stages follow
    world, head, calibration = (graph.process(n) for n in names[:3])
    assert world.module == "processes.world"
    assert world.inputs == (topics.WHEEL_COMMAND,)
    assert world.outputs == (topics.WORLD_TRUTH, topics.ODOMETRY)
    assert head.module == "processes.head"
    assert head.inputs == (topics.HEAD_COMMAND, topics.WORLD_TRUTH)
    assert head.outputs == (topics.RAW_SCAN, topics.HEAD_STATE)
    assert calibration.module == "processes.calibration"
    assert calibration.inputs == (topics.RAW_SCAN,)
    assert calibration.outputs == (topics.CALIBRATED_SCAN,)
    _check_defaults_and_paths(graph, backoff_s=0.1)
    office = str((REPO / "worlds" / "office.toml").resolve())
    assert world.params == {"world": office, "rate_hz": 20.0, "command_timeout_s": 0.5, "seed": 1}
    assert head.params == {"world": office, "seed": 1}
    assert calibration.params == {"calibration": ""}  # empty: not made a path
    (controller,) = graph.externals
    assert controller.name == "controller"
    assert controller.endpoint == "ipc://{runtime}/controller.pub"
    assert controller.outputs == (topics.WHEEL_COMMAND, topics.VEHICLE_STATE)
    assert names[3:] == ["filtering", "features", "tracking", "planner"]
    tracking, planner = graph.process("tracking"), graph.process("planner")
    assert tracking.inputs == (topics.FEATURES, topics.VEHICLE_STATE, topics.FILTERED_SCAN)
    assert tracking.outputs == (topics.TRACKS,)
    assert planner.inputs == (
        topics.TRACKS,
        topics.FILTERED_SCAN,
        topics.VEHICLE_STATE,
        topics.HEAD_STATE,
    )
    assert planner.outputs == (topics.ENVIRONMENT, topics.HEAD_COMMAND)
    assert planner.params["policy"] == "forward"
    assert graph.publishers()[topics.RAW_SCAN] == ("head", "ipc://{runtime}/head.pub")
    assert graph.publishers()[topics.HEAD_COMMAND] == ("planner", "ipc://{runtime}/planner.pub")
    assert graph.subscribers(topics.WORLD_TRUTH) == ["head"]
    assert graph.subscribers(topics.RAW_SCAN) == ["calibration"]
    assert graph.process("head") is head
    with pytest.raises(KeyError, match="no process 'nobody'"):
        graph.process("nobody")


def test_sensor_launch_file_is_the_simulated_graph_without_tracking_and_planner() -> None:
    sensor, sim = _parse(SENSOR), _parse(SIM)
    assert sensor.name == "sensor"
    assert [p.name for p in sensor.processes] == [
        p.name for p in sim.processes if p.name not in ("tracking", "planner")
    ]
    for process in sensor.processes:
        assert process == sim.process(process.name)
    (controller,) = sensor.externals
    assert controller.outputs == (topics.WHEEL_COMMAND, topics.HEAD_COMMAND, topics.VEHICLE_STATE)


def test_agent_launch_file_describes_the_agent_alone() -> None:
    graph = _parse(AGENT)
    assert graph.name == "agent"
    assert graph.processes[0].name == "calibration"  # later stages follow
    assert not {"world", "head"} & {p.name for p in graph.processes}
    calibration = graph.process("calibration")
    assert calibration.module == "processes.calibration"
    assert calibration.inputs == (topics.RAW_SCAN,)
    assert calibration.outputs == (topics.CALIBRATED_SCAN,)
    assert calibration.params == {"calibration": ""}
    _check_defaults_and_paths(graph, backoff_s=0.1)  # backoff_s: not in [defaults]
    assert [(e.name, e.endpoint, e.outputs) for e in graph.externals] == [
        ("head", "ipc://{runtime}/head.pub", (topics.RAW_SCAN, topics.HEAD_STATE)),
        ("vehicle", "ipc://{runtime}/vehicle.pub", (topics.VEHICLE_STATE,)),
    ]
    assert graph.publishers()[topics.RAW_SCAN] == ("head", "ipc://{runtime}/head.pub")


def test_shipped_launch_files_load_from_disk_and_build_their_stages() -> None:
    assert load_launch(SIM) == _parse(SIM)
    graph = _parse(SIM)
    runner = lockstep_graph(graph)  # every stage accepts its params
    assert [n.name for n in runner.nodes] == [p.name for p in graph.processes]
    assert [n.inputs for n in runner.nodes] == [p.inputs for p in graph.processes]


@pytest.mark.parametrize("path", [SIM, SENSOR, AGENT], ids=["sim", "sensor", "agent"])
def test_resolve_fills_the_runtime_directory(path: Path) -> None:
    graph = _parse(path)
    resolved = graph.resolve("/run/user/1000/graph-1")
    assert resolved.runtime_dir == "/run/user/1000/graph-1"
    assert resolved.control_endpoint == "ipc:///run/user/1000/graph-1/launcher.pub"
    for name, endpoint in resolved.endpoints().items():
        assert endpoint == f"ipc:///run/user/1000/graph-1/{name}.pub"
    assert all("{runtime}" in e for e in graph.endpoints().values())  # the original is kept
    assert graph.runtime_dir == ""
    assert [p.params for p in resolved.processes] == [p.params for p in graph.processes]


@pytest.mark.parametrize(
    "endpoint",
    [
        "ipc:///tmp/elsewhere.pub",
        "ipc://{runtime}/../escape.pub",
        "ipc://{runtime}",
        "ipc://relative.pub",
    ],
)
def test_ipc_endpoints_outside_the_runtime_directory_are_refused(endpoint: str) -> None:
    graph = parse_launch(VALID.replace("ipc://{runtime}/head.pub", endpoint), FAKE_PATH)
    with pytest.raises(LaunchFileError) as caught:
        graph.resolve("/run/user/1000/graph-1")
    assert "lies outside the graph's runtime directory" in str(caught.value)
    assert "\n" not in str(caught.value)


@pytest.mark.parametrize("path", [SIM, SENSOR, AGENT], ids=["sim", "sensor", "agent"])
def test_json_round_trip(path: Path) -> None:
    graph = _parse(path)
    for spec in (graph, graph.resolve(Path("/tmp/rt"))):
        again = GraphSpec.from_json(spec.to_json())
        assert again == spec
        assert isinstance(again.processes[0].inputs, tuple)


# ============================================================================================
# Defaults, overrides, paths
# ============================================================================================
MERGE_TOML = """
[graph]
name = "merge"
heartbeat_s = 0.25
join_timeout_s = 1
keys_dir = "../keys"
control_endpoint = "tcp://127.0.0.1:6000"

[defaults]
restart = "always"
max_restarts = 2
restart_window_s = 10
backoff_s = 0.5
stop_graph_on_failure = false
host = "base"

[[process]]
name = "world"
module = "processes.world"
outputs = ["world_truth"]
endpoint = "tcp://127.0.0.1:6001"
params = { world = "../worlds/office.toml", rate_hz = 20, note = "../not/a/path" }

[[process]]
name = "calibration"
module = "processes.calibration"
inputs = ["raw_scan"]
outputs = ["calibrated_scan"]
restart = "never"
max_restarts = 0
backoff_s = 2.0
stop_graph_on_failure = true
host = "arm"
params = { calibration = "cal/head.npz" }

[[external]]
name = "head"
endpoint = "tcp://10.0.0.2:6002"
outputs = ["raw_scan"]
"""


def test_defaults_apply_and_per_process_settings_win() -> None:
    graph = parse_launch(MERGE_TOML, FAKE_PATH)
    world, calibration = graph.processes
    assert (world.restart, world.max_restarts, world.restart_window_s) == ("always", 2, 10.0)
    assert (world.backoff_s, world.stop_graph_on_failure, world.host) == (0.5, False, "base")
    assert (calibration.restart, calibration.max_restarts) == ("never", 0)
    assert calibration.restart_window_s == 10.0  # not overridden
    assert (calibration.backoff_s, calibration.stop_graph_on_failure) == (2.0, True)
    assert calibration.host == "arm"
    assert graph.on_host("arm") == (calibration,) and graph.on_host(None) == graph.processes
    assert graph.heartbeat_s == 0.25 and graph.join_timeout_s == 1.0
    assert isinstance(graph.join_timeout_s, float)
    assert graph.control_endpoint == "tcp://127.0.0.1:6000"


def test_path_params_and_keys_dir_are_resolved_relative_to_the_file() -> None:
    graph = parse_launch(MERGE_TOML, FAKE_PATH)
    world, calibration = graph.processes
    assert world.params["world"] == str(Path("/srv/robot/worlds/office.toml").resolve())
    assert world.params["note"] == "../not/a/path"  # not a path parameter
    assert world.params["rate_hz"] == 20
    assert calibration.params["calibration"] == str(
        Path("/srv/robot/launch/cal/head.npz").resolve()
    )
    assert graph.keys_dir == str(Path("/srv/robot/keys").resolve())


def test_without_a_path_params_are_relative_to_the_working_directory(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.chdir(tmp_path)
    graph = parse_launch(MERGE_TOML)
    assert graph.path == "" and graph.name == "merge"
    assert graph.process("world").params["world"] == str(
        (tmp_path / "../worlds/office.toml").resolve()
    )


def test_graph_name_defaults_to_the_file_name() -> None:
    text = MERGE_TOML.replace('name = "merge"\n', "", 1)
    assert parse_launch(text, FAKE_PATH).name == "test"
    assert parse_launch(text).name == "graph"


def test_json_round_trip_with_overrides_and_tcp() -> None:
    graph = parse_launch(MERGE_TOML, FAKE_PATH).resolve("/tmp/rt")
    assert GraphSpec.from_json(graph.to_json()) == graph
    assert graph.process("world").endpoint == "tcp://127.0.0.1:6001"  # nothing to fill


def test_a_launch_file_that_validates_can_be_written_for_the_children() -> None:
    text = MERGE_TOML.replace("rate_hz = 20,", "rate_hz = 20, since = 2026-01-01T00:00:00Z,")
    try:
        graph = parse_launch(text, FAKE_PATH)
    except LaunchFileError:
        return  # refusing it would be fine too
    assert GraphSpec.from_json(graph.to_json()) == graph


# ============================================================================================
# Validation errors
# ============================================================================================
GRAPH = '[graph]\nname = "t"\n'
CALIBRATION = """
[[process]]
name = "calibration"
module = "processes.calibration"
inputs = ["raw_scan"]
outputs = ["calibrated_scan"]
"""
HEAD = """
[[external]]
name = "head"
endpoint = "ipc://{runtime}/head.pub"
outputs = ["raw_scan"]
"""
VALID = GRAPH + CALIBRATION + HEAD


def _process(name: str, module: str, extra: str = "") -> str:
    return f'\n[[process]]\nname = "{name}"\nmodule = "{module}"\n{extra}\n'


def _calibration(extra: str) -> str:
    """The calibration process with extra lines (they replace none of its keys)."""
    return GRAPH + CALIBRATION + extra + "\n" + HEAD


def _external(name: str, endpoint: str, outputs: str) -> str:
    return f'\n[[external]]\nname = "{name}"\nendpoint = "{endpoint}"\noutputs = {outputs}\n'


INVALID: list[tuple[str, str, str]] = [
    # (id, text, a fragment of the message)
    ("not-toml", "[graph\nname = 1", "not valid TOML"),
    ("not-toml-value", VALID + "x = ", "not valid TOML"),
    ("empty", "", "needs at least one [[process]]"),
    ("no-process", GRAPH + HEAD, "needs at least one [[process]]"),
    ("process-not-array", "process = 3\n" + GRAPH, "needs at least one [[process]]"),
    ("external-not-array", "external = 3\n" + GRAPH + CALIBRATION, "[[external]] must be an"),
    ("external-not-table", "external = [3]\n" + GRAPH + CALIBRATION, "[[external]] 1 must be a"),
    # unknown keys, in every table
    ("unknown-top", "colour = 1\n" + VALID, "top level: unknown key 'colour'"),
    ("unknown-graph", VALID.replace(GRAPH, GRAPH + "colour = 1\n"), "[graph]: unknown key"),
    ("unknown-defaults", "[defaults]\nmodule = 'x'\n" + VALID, "[defaults]: unknown key 'module'"),
    ("unknown-process", _calibration("colour = 1"), "[[process]] 1: unknown key 'colour'"),
    ("unknown-external", VALID + 'host = "a"\n', "[[external]] 1: unknown key 'host'"),
    # wrong types
    ("graph-not-table", "graph = 3\n" + CALIBRATION + HEAD, "[graph] must be a table"),
    ("graph-name", VALID.replace('name = "t"', "name = 3"), "[graph]: name must be a non-empty"),
    ("heartbeat-str", GRAPH + 'heartbeat_s = "fast"\n' + CALIBRATION + HEAD, "heartbeat_s must"),
    ("heartbeat-zero", GRAPH + "heartbeat_s = 0\n" + CALIBRATION + HEAD, "heartbeat_s must"),
    ("heartbeat-bool", GRAPH + "heartbeat_s = true\n" + CALIBRATION + HEAD, "heartbeat_s must"),
    ("heartbeat-nan", GRAPH + "heartbeat_s = nan\n" + CALIBRATION + HEAD, "heartbeat_s must"),
    ("heartbeat-inf", GRAPH + "heartbeat_s = inf\n" + CALIBRATION + HEAD, "heartbeat_s must"),
    ("join-negative", GRAPH + "join_timeout_s = -1\n" + CALIBRATION + HEAD, "join_timeout_s"),
    ("keys-dir", GRAPH + "keys_dir = 3\n" + CALIBRATION + HEAD, "keys_dir must be a string"),
    ("control", GRAPH + 'control_endpoint = ""\n' + CALIBRATION + HEAD, "control_endpoint"),
    ("process-name", VALID.replace('name = "calibration"', 'name = ""'), "name must be a non"),
    ("module-type", VALID.replace('"processes.calibration"', "3"), "module must be a non-empty"),
    ("max-restarts-float", _calibration("max_restarts = 1.5"), "max_restarts must be a whole"),
    ("max-restarts-negative", _calibration("max_restarts = -1"), "max_restarts must be a whole"),
    ("max-restarts-bool", _calibration("max_restarts = true"), "max_restarts must be a whole"),
    ("window-zero", _calibration("restart_window_s = 0"), "restart_window_s must be a positive"),
    ("backoff-str", _calibration('backoff_s = "1"'), "backoff_s must be a positive number"),
    ("defaults-backoff", "[defaults]\nbackoff_s = -1\n" + VALID, "'calibration': backoff_s"),
    ("stop-graph-int", _calibration("stop_graph_on_failure = 1"), "must be true or false"),
    ("host-type", _calibration("host = 5"), "host must be a non-empty string"),
    ("endpoint-type", _calibration("endpoint = 5"), "endpoint must be a non-empty string"),
    ("params-type", _calibration("params = 3"), "params must be a table"),
    ("inputs-str", VALID.replace('inputs = ["raw_scan"]', 'inputs = "raw_scan"'), "list of topic"),
    ("outputs-ints", VALID.replace('outputs = ["calibrated_scan"]', "outputs = [1]"), "list of"),
    ("external-name", VALID.replace('name = "head"', "name = 1"), "[[external]] 1: name must"),
    # restart policy
    ("restart", _calibration('restart = "sometimes"'), "restart must be one of never, on-failure"),
    ("restart-defaults", '[defaults]\nrestart = "often"\n' + VALID, "got 'often'"),
    ("restart-type", _calibration("restart = 1"), "restart must be one of"),
    # topics
    ("unknown-input", VALID.replace('["raw_scan"]', '["raw_scans"]', 1), "unknown topic 'raw_sc"),
    ("unknown-output", VALID.replace("calibrated_scan", "ranges"), "unknown topic 'ranges'"),
    ("unknown-external", VALID.replace('outputs = ["raw_scan"]', 'outputs = ["x"]'), "topic 'x'"),
    ("heartbeat-topic", VALID.replace('["calibrated_scan"]', '["heartbeat"]'), "'heartbeat'"),
    ("stop-topic", VALID.replace('["raw_scan"]', '["raw_scan", "stop"]', 1), "topic 'stop'"),
    ("topic-twice", VALID.replace('["raw_scan"]', '["raw_scan", "raw_scan"]', 1), "twice"),
    # the graph as a whole
    (
        "duplicate-process",
        VALID + _process("calibration", "processes.world"),
        "duplicate process name 'calibration'",
    ),
    (
        "duplicate-external",
        VALID + _external("calibration", "ipc://{runtime}/c2.pub", '["vehicle_state"]'),
        "duplicate process name 'calibration'",
    ),
    ("reserved-process", VALID.replace('"calibration"', '"launcher"', 1), "'launcher' is reserved"),
    ("reserved-external", VALID.replace('"head"', '"launcher"'), "'launcher' is reserved"),
    (
        "duplicate-endpoint",
        _calibration('endpoint = "ipc://{runtime}/head.pub"'),
        "duplicate endpoint 'ipc://{runtime}/head.pub'",
    ),
    (
        "control-endpoint-reused",
        _calibration('endpoint = "ipc://{runtime}/launcher.pub"'),
        "duplicate endpoint",
    ),
    ("inproc", _calibration('endpoint = "inproc://c"'), "must be ipc:// or tcp://"),
    (
        "two-publishers-externals",
        VALID + _external("replay", "ipc://{runtime}/replay.pub", '["raw_scan"]'),
        "topic 'raw_scan' published by both 'head' and 'replay'",
    ),
    (
        "two-publishers-processes",
        VALID + _process("other", "processes.world", 'outputs = ["calibrated_scan"]'),
        "topic 'calibrated_scan' published by both 'calibration' and 'other'",
    ),
    (
        "two-publishers-mixed",
        VALID + _external("rogue", "ipc://{runtime}/rogue.pub", '["calibrated_scan"]'),
        "published by both 'calibration' and 'rogue'",
    ),
    ("no-publisher", GRAPH + CALIBRATION, "reads 'raw_scan', which nothing publishes"),
    (
        "tcp-without-keys",
        VALID.replace("ipc://{runtime}/head.pub", "tcp://10.0.0.2:5555"),
        "is tcp:// but [graph] has no keys_dir",
    ),
    (
        "ipc-across-hosts",
        GRAPH
        + _process("world", "processes.world", 'outputs = ["world_truth"]\nhost = "a"')
        + _process("head", "processes.head", 'inputs = ["world_truth"]\nhost = "b"'),
        "process 'head' on b reads 'world_truth' from 'world' on a: that endpoint must be tcp://",
    ),
    ("module-missing", VALID.replace("processes.calibration", "processes.nope"), "'processes.no"),
    ("package-missing", VALID.replace("processes.calibration", "nopkg.sub"), "not a stage"),
    ("module-bad-name", VALID.replace("processes.calibration", ".relative"), "not a stage"),
    # Importable, but not a stage: a launch file must not run arbitrary modules.
    ("module-foreign", VALID.replace("processes.calibration", "http.server"), "not a stage"),
    ("module-shell", VALID.replace("processes.calibration", "processes.launcher"), "not a stage"),
    ("module-runtime", VALID.replace("processes.calibration", "processes.runtime"), "not a stage"),
    ("backlog", VALID.replace("[[external]]", 'backlog = "oldest"\n[[external]]'), "backlog must"),
    (
        "hang-timeout-short",
        VALID.replace('name = "t"', 'name = "t"\nheartbeat_s = 1.0\nhang_timeout_s = 1.5'),
        "hang_timeout_s (1.5) must be at least two heartbeat periods",
    ),
]


@pytest.mark.parametrize(
    ("text", "fragment"), [c[1:] for c in INVALID], ids=[c[0] for c in INVALID]
)
def test_invalid_launch_files_raise_one_line_errors(text: str, fragment: str) -> None:
    with pytest.raises(LaunchFileError) as caught:
        parse_launch(text, FAKE_PATH)
    message = str(caught.value)
    assert "\n" not in message
    assert message.startswith(f"launch file {FAKE_PATH}: ")
    assert fragment in message
    assert caught.value.path == FAKE_PATH
    assert isinstance(caught.value, ConfigError)


def test_the_valid_base_of_the_error_cases_parses() -> None:
    graph = parse_launch(VALID, FAKE_PATH)
    assert [p.name for p in graph.processes] == ["calibration"]
    assert [e.name for e in graph.externals] == ["head"]


def test_a_graph_across_hosts_with_tcp_and_keys_parses() -> None:
    text = (
        '[graph]\nname = "t"\nkeys_dir = "keys"\n'
        + _process(
            "world",
            "processes.world",
            'outputs = ["world_truth"]\nhost = "a"\nendpoint = "tcp://10.0.0.1:6000"',
        )
        + _process("head", "processes.head", 'inputs = ["world_truth"]\nhost = "b"')
    )
    graph = parse_launch(text, FAKE_PATH)
    assert [p.host for p in graph.processes] == ["a", "b"]
    assert graph.keys_dir == str(Path("/srv/robot/launch/keys").resolve())


def test_load_launch_names_a_missing_file(tmp_path: Path) -> None:
    missing = tmp_path / "nowhere.toml"
    with pytest.raises(LaunchFileError, match="no such file") as caught:
        load_launch(missing)
    assert "\n" not in str(caught.value)
    bad = tmp_path / "bad.toml"
    bad.write_bytes(b"\xff\xfe[graph]")
    with pytest.raises(LaunchFileError, match="not UTF-8"):
        load_launch(bad)


@pytest.mark.parametrize(
    "text",
    [
        "a = " + "[" * 100_000 + "]" * 100_000,
        "a = " + "{b = " * 100_000 + "1" + "}" * 100_000,
    ],
    ids=["arrays", "inline tables"],
)
def test_deeply_nested_launch_toml_is_one_line_and_status_2(
    tmp_path: Path, text: str, capsys: pytest.CaptureFixture[str]
) -> None:
    deep = tmp_path / "deep.toml"
    deep.write_text(text)
    with pytest.raises(LaunchFileError, match="nested too deeply"):
        load_launch(deep)
    from cli.main import main

    assert main(["launch", str(deep)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "nested too deeply" in err and "Traceback" not in err


def test_a_launch_file_over_the_size_limit_is_refused_unread(tmp_path: Path) -> None:
    big = tmp_path / "big.toml"
    big.write_text("# " + "x" * (2 << 20) + "\n")
    with pytest.raises(LaunchFileError, match="larger than"):
        load_launch(big)


# ============================================================================================
# RestartTracker
# ============================================================================================
def _spec(
    restart: str = "on-failure",
    max_restarts: int = 5,
    window_s: float = 60.0,
    backoff_s: float = 0.1,
) -> ProcessSpec:
    return ProcessSpec(
        name="p", module="processes.calibration", inputs=(), outputs=(),
        endpoint="ipc://{runtime}/p.pub", restart=restart, max_restarts=max_restarts,
        restart_window_s=window_s, backoff_s=backoff_s,
    )  # fmt: skip


def test_on_failure_restarts_with_doubling_backoff_up_to_the_cap() -> None:
    tracker = RestartTracker(_spec(max_restarts=10))
    decisions = [tracker.on_exit(float(t), 1) for t in range(10)]
    assert [d.action for d in decisions] == ["restart"] * 10
    expected = [0.1, 0.2, 0.4, 0.8, 1.6, 3.2] + [MAX_BACKOFF_S] * 4
    assert [d.delay_s for d in decisions] == pytest.approx(expected)
    assert MAX_BACKOFF_S == 4.0
    assert tracker.restarts == 10
    assert "exit code 1" in decisions[0].reason and "restart 1" in decisions[0].reason


def test_on_failure_gives_up_past_max_restarts_within_the_window() -> None:
    tracker = RestartTracker(_spec(max_restarts=3, window_s=60.0))
    assert [tracker.on_exit(t, 2).action for t in (0.0, 1.0, 2.0)] == ["restart"] * 3
    decision = tracker.on_exit(3.0, 2)
    assert decision.action == "give-up" and decision.delay_s == 0.0
    assert "3 restarts within 60 s (limit 3)" in decision.reason
    assert "last: exit code 2" in decision.reason
    assert tracker.restarts == 3


def test_restarts_older_than_the_window_are_forgotten() -> None:
    tracker = RestartTracker(_spec(max_restarts=3, window_s=10.0))
    for t in (0.0, 1.0, 2.0):
        tracker.on_exit(t, 1)
    assert tracker.on_exit(10.0, 1).action == "give-up"  # 0.0 is exactly 10 s old: kept
    decision = tracker.on_exit(10.5, 1)  # 0.0 has left the window; 1.0 and 2.0 remain
    assert decision == Decision("restart", pytest.approx(0.4), decision.reason)
    decision = tracker.on_exit(12.5, 1)  # only 10.5 remains
    assert decision.action == "restart" and decision.delay_s == pytest.approx(0.2)
    decision = tracker.on_exit(100.0, 1)  # all forgotten: the backoff starts again
    assert decision.action == "restart" and decision.delay_s == pytest.approx(0.1)
    assert tracker.restarts == 6


def test_never_gives_up_on_any_exit_status_0_included() -> None:
    tracker = RestartTracker(_spec(restart="never"))
    failed = tracker.on_exit(0.0, 3)
    assert failed.action == "give-up" and failed.reason == "exit code 3; restart = never"
    assert tracker.on_exit(1.0, -15).action == "give-up"  # killed by a signal
    early = tracker.on_exit(2.0, 0)
    assert early.action == "give-up"
    assert early.reason == "exited with status 0 while the graph runs; restart = never"
    assert tracker.restarts == 0


def test_on_failure_restarts_a_stage_that_exits_0_while_the_graph_runs() -> None:
    tracker = RestartTracker(_spec(restart="on-failure"))
    early = tracker.on_exit(0.0, 0)
    assert early.action == "restart"
    assert early.reason == "exited with status 0 while the graph runs; restart 1"
    assert tracker.on_exit(1.0, -9).action == "restart"
    assert tracker.restarts == 2


def test_a_kill_by_the_launcher_is_reported_with_its_cause() -> None:
    tracker = RestartTracker(_spec(restart="on-failure"))
    decision = tracker.on_exit(0.0, -9, cause="hung: no heartbeat for 2.0 s")
    assert decision.action == "restart"
    assert decision.reason == "hung: no heartbeat for 2.0 s; restart 1"


def test_always_restarts_even_after_a_clean_exit() -> None:
    tracker = RestartTracker(_spec(restart="always", max_restarts=2))
    first = tracker.on_exit(0.0, 0)
    assert first.action == "restart" and first.delay_s == pytest.approx(0.1)
    assert "status 0 while the graph runs" in first.reason
    assert tracker.on_exit(1.0, 1).delay_s == pytest.approx(0.2)
    assert tracker.on_exit(2.0, 0).action == "give-up"  # the limit holds for "always" too


def test_restart_trackers_take_their_settings_from_the_launch_file() -> None:
    graph = parse_launch(MERGE_TOML, FAKE_PATH)
    world = RestartTracker(graph.process("world"))  # always, 2 in 10 s, backoff 0.5
    assert [world.on_exit(t, 0).delay_s for t in (0.0, 1.0)] == [0.5, 1.0]
    assert world.on_exit(2.0, 0).action == "give-up"
    calibration = RestartTracker(graph.process("calibration"))  # never
    assert calibration.on_exit(0.0, 1).action == "give-up"


# ============================================================================================
# TopicStats: the rates a launch summary reports
# ============================================================================================
def _rate(arrivals_s: list[float]) -> TopicStats:
    stats = TopicStats()
    for t in arrivals_s:
        stats.see(t)
    return stats


def test_topic_rate_ignores_a_start_up_burst() -> None:
    steady = [0.1 * k for k in range(60)]
    assert _rate(steady).rate_hz() == pytest.approx(10.0)
    # 20 scans queued for 1 s then flushed within 20 ms, then 40 at 10 Hz: the whole-run
    # mean would be 59 / 4.02 s = 15 Hz.
    burst = [1.0 + 0.001 * k for k in range(20)] + [1.019 + 0.1 * k for k in range(1, 41)]
    stats = _rate(burst)
    assert stats.count == 60 and stats.rate_hz() == pytest.approx(10.0)
    assert stats.max_gap_s == pytest.approx(0.1)


def test_topic_rate_sums_publishers_and_follows_the_recent_window() -> None:
    interleaved = sorted([0.5 * k for k in range(40)] + [0.5 * k + 0.2 for k in range(40)])
    assert _rate(interleaved).rate_hz() == pytest.approx(4.0, rel=0.02)  # two at 2 Hz
    slowed = [0.05 * k for k in range(300)] + [15.0 + 0.1 * k for k in range(1, 301)]
    assert _rate(slowed).rate_hz() == pytest.approx(10.0)  # 20 Hz, then 10 Hz for longer
    assert _rate([]).rate_hz() == 0.0 and _rate([1.0]).rate_hz() == 0.0
    assert _rate([1.0, 1.0]).rate_hz() == 0.0  # no span: no rate, not a division by zero


# ============================================================================================
# Params
# ============================================================================================
def _params(**values: object) -> Params:
    return Params("world", values)


def test_params_typed_reads() -> None:
    p = _params(rate=20, gain=0.5, seed=3, name="office", on=True, off=False)
    assert p.number("rate", 1.0) == 20.0 and isinstance(p.number("rate", 1.0), float)
    assert p.number("gain", 1.0, lo=0.5, hi=0.5) == 0.5  # bounds are inclusive
    assert p.integer("seed", 0) == 3
    assert p.string("name", "") == "office"
    assert p.flag("on", False) is True and p.flag("off", True) is False
    # Defaults when absent.
    assert p.number("missing", 2.5) == 2.5
    assert p.integer("missing_int", 7) == 7
    assert p.string("missing_str", "x") == "x"
    assert p.flag("missing_flag", True) is True
    p.check_all_read()
    assert p.unknown() == []


@pytest.mark.parametrize(
    ("read", "value", "expected"),
    [
        ("number", "fast", "must be int or float, got 'fast'"),
        ("number", True, "must be int or float, got True"),  # booleans are not numbers
        ("number", [1.0], "must be int or float"),
        ("integer", 1.5, "must be int, got 1.5"),
        ("integer", False, "must be int, got False"),
        ("string", 3, "must be str, got 3"),
        ("flag", 1, "must be bool, got 1"),
        ("flag", "true", "must be bool"),
    ],
)
def test_params_wrong_types_raise_config_error(read: str, value: object, expected: str) -> None:
    p = _params(key=value)
    defaults = {"number": 1.0, "integer": 1, "string": "", "flag": False}
    with pytest.raises(ConfigError) as caught:
        getattr(p, read)("key", defaults[read])
    message = str(caught.value)
    assert message.startswith("process world: parameter 'key'")
    assert expected in message and "\n" not in message


@pytest.mark.parametrize(
    ("value", "lo", "hi"), [(0.5, 1.0, None), (1001, 1.0, 1000.0), (-1e-9, 0.0, None)]
)
def test_params_out_of_range_raise_config_error(
    value: float, lo: float | None, hi: float | None
) -> None:
    with pytest.raises(ConfigError, match=r"process world: parameter 'rate_hz' = .* outside"):
        _params(rate_hz=value).number("rate_hz", 50.0, lo=lo, hi=hi)


def test_params_refuse_nan() -> None:
    with pytest.raises(ConfigError):
        _params(rate_hz=math.nan).number("rate_hz", 50.0, lo=1.0, hi=1000.0)


def test_params_check_all_read_names_unknown_keys() -> None:
    p = _params(rate_hz=20.0, speed=1.0, colour="red")
    p.number("rate_hz", 50.0)
    assert p.unknown() == ["colour", "speed"]
    with pytest.raises(ConfigError, match=r"^process world: unknown parameter\(s\) colour, speed$"):
        p.check_all_read()


def test_stages_refuse_unknown_params() -> None:
    world = str(REPO / "worlds" / "box_before_wall.toml")
    stage = WorldStage.from_params(Params("world", {"world": world, "rate_hz": 25}))
    assert stage.period_s == pytest.approx(0.04)
    with pytest.raises(ConfigError, match="unknown parameter"):
        WorldStage.from_params(Params("world", {"world": world, "max_sped_m_s": 1.0}))
    with pytest.raises(ConfigError, match=r"'rate_hz' = 0\.5 outside"):
        WorldStage.from_params(Params("world", {"world": world, "rate_hz": 0.5}))
