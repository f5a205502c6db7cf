"""The Foxglove view (cli.viewer_convert, cli.viewer): conversions checked through the
messages' own protobuf schemas, and ``export --foxglove`` of a short closed-loop recording
read back with the ``mcap`` package; bad input is one line and status 2."""

from __future__ import annotations

import dataclasses
import math
import struct
import sys
from collections import Counter
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import foxglove.messages as fm
import numpy as np
import pytest
from mcap.reader import make_reader

from agent.runtime import topics
from agent.runtime.messages import (
    CalibratedScan,
    EnvironmentVector,
    FilteredScan,
    Header,
    HeadState,
    Message,
    Odometry,
    Tracks,
    VehicleState,
    WorldTruth,
    decode,
    stamp_ns,
)
from agent.runtime.recording import Recorder, read_recording
from agent.sim.world_file import load_world
from cli.closed_loop import run_closed_loop
from cli.main import main
from cli.viewer_convert import (
    CHANNEL_SCHEMAS,
    ELLIPSE_POINTS,
    GRID_TOLERANCE_RAD,
    Converter,
    bearing_grid,
    ellipse_axes,
    ellipse_points,
    laser_scan,
    scan_points,
    tracks_update,
    world_to_odom,
)

ROOT = Path(__file__).resolve().parents[2]
HEAD_OFFSET_M = 0.3


# ------------------------------------------------------ a protobuf reader, for the checks
def _varint(buf: bytes, i: int) -> tuple[int, int]:
    result = shift = 0
    while True:
        byte = buf[i]
        i += 1
        result |= (byte & 0x7F) << shift
        if byte < 0x80:
            return result, i
        shift += 7


def _wire(buf: bytes) -> Iterator[tuple[int, int, Any]]:
    """(field number, wire type, value) of each field of a protobuf message."""
    i = 0
    while i < len(buf):
        key, i = _varint(buf, i)
        number, wire = key >> 3, key & 7
        if wire == 0:
            value, i = _varint(buf, i)
        elif wire == 1:
            value, i = buf[i : i + 8], i + 8
        elif wire == 2:
            size, i = _varint(buf, i)
            value, i = buf[i : i + size], i + size
        elif wire == 5:
            value, i = buf[i : i + 4], i + 4
        else:
            raise ValueError(f"wire type {wire}")
        yield number, wire, value


class Protobuf:
    """Messages of a schema's FileDescriptorSet (what an MCAP channel's schema holds) decoded
    into dicts by field name: enough of protobuf to read Foxglove's schemas back."""

    def __init__(self, descriptor_set: bytes) -> None:
        self.types: dict[str, dict[int, tuple[str, int, int, str]]] = {}
        for number, _, file in _wire(descriptor_set):
            if number == 1:  # FileDescriptorSet.file
                items = list(_wire(file))
                package = next((v.decode() for n, _, v in items if n == 2), "")
                for n, _, message in items:
                    if n == 4:  # FileDescriptorProto.message_type
                        self._add(package, message)

    def _add(self, scope: str, message: bytes) -> None:
        items = list(_wire(message))
        name = next(v.decode() for n, _, v in items if n == 1)
        full = f"{scope}.{name}" if scope else name
        fields = {}
        for n, _, v in items:
            if n == 2:  # DescriptorProto.field: name 1, number 3, label 4, type 5, type_name 6
                f = {k: value for k, _, value in _wire(v)}
                sub = f.get(6, b"").decode().lstrip(".")
                fields[f[3]] = (f[1].decode(), f[5], f.get(4, 1), sub)
            elif n == 3:  # nested types
                self._add(full, v)
        self.types[full] = fields

    def decode(self, data: bytes, type_name: str) -> dict[str, Any]:
        fields = self.types[type_name]
        out: dict[str, Any] = {}
        for number, wire, value in _wire(data):
            name, kind, label, sub = fields[number]
            values = self._values(kind, wire, value, sub)
            if label == 3:  # repeated
                out.setdefault(name, []).extend(values)
            else:
                out[name] = values[-1]
        return out

    def _values(self, kind: int, wire: int, value: Any, sub: str) -> list[Any]:
        if kind == 11:
            return [self.decode(value, sub)]
        if kind == 9:
            return [value.decode()]
        if kind == 12:
            return [bytes(value)]
        if kind in (1, 2):  # double, float (packed when repeated)
            fmt = "d" if kind == 1 else "f"
            return list(struct.unpack(f"<{len(value) // struct.calcsize(fmt)}{fmt}", value))
        if kind == 7:  # fixed32
            return [struct.unpack("<I", value)[0]]
        if wire == 2:  # packed varints
            out, i = [], 0
            while i < len(value):
                v, i = _varint(value, i)
                out.append(v)
            return out
        return [value]


def read_back(message: Any) -> dict[str, Any]:
    """A Foxglove message object as a dict, through its encoding and its own schema."""
    schema = type(message).get_schema()
    return Protobuf(schema.data).decode(message.encode(), schema.name)


def xy(points: list[dict[str, float]]) -> np.ndarray:
    return np.array([[p.get("x", 0.0), p.get("y", 0.0)] for p in points])


# --------------------------------------------------------------------------------- maths
def rotation(angle: float) -> np.ndarray:
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[c, -s], [s, c]])


def test_ellipse_axes_of_a_known_covariance() -> None:
    """σ 2 m and 1 m along axes turned 30°: 3σ semi-axes 6 and 3 m at 30°; turned 120°, the
    major axis is reported at -60° (the same line)."""
    for turn, expected in ((math.radians(30), math.radians(30)), (math.radians(120), -math.pi / 3)):
        cov = rotation(turn) @ np.diag([4.0, 1.0]) @ rotation(turn).T
        major, minor, angle = ellipse_axes(cov, sigmas=3.0)
        assert major == pytest.approx(6.0) and minor == pytest.approx(3.0)
        assert angle == pytest.approx(expected)
    major, minor, angle = ellipse_axes(np.zeros((2, 2)))
    assert (major, minor) == (0.0, 0.0) and math.isfinite(angle)


def test_ellipse_points_lie_at_the_stated_mahalanobis_distance() -> None:
    cov = np.array([[[0.04, 0.01], [0.01, 0.02]], [[1.0, 0.0], [0.0, 0.25]]])
    centre = np.array([[1.0, 2.0], [-3.0, 0.5]])
    points = ellipse_points(centre, cov, sigmas=2.0)
    assert points.shape == (2, ELLIPSE_POINTS, 2)
    for k in range(2):
        d = points[k] - centre[k]
        mahalanobis_sq = np.einsum("ni,ij,nj->n", d, np.linalg.inv(cov[k]), d)
        np.testing.assert_allclose(mahalanobis_sq, 4.0, rtol=1e-9)


def test_bearing_grid_fits_a_uniform_sweep_and_measures_the_stray() -> None:
    bearings = np.linspace(-0.25, 0.45, 256)
    start, end, deviation = bearing_grid(bearings)
    assert (start, end) == (pytest.approx(-0.25), pytest.approx(0.45))
    assert deviation < 1e-12
    bent = bearings + np.where(np.arange(256) < 128, 0.0, 0.1)  # the pan jumps mid-sweep
    assert bearing_grid(bent)[2] > 0.02
    assert bearing_grid(np.array([0.1, np.nan]))[2] == math.inf
    assert bearing_grid(np.zeros(0))[2] == math.inf


def test_world_to_odom_maps_the_odometry_pose_onto_the_truth() -> None:
    truth, odom = (4.0, -1.0, 0.7), (3.5, -0.2, 0.5)
    x, y, yaw = world_to_odom(truth, odom)
    mapped = rotation(yaw) @ np.array(odom[:2]) + np.array([x, y])
    np.testing.assert_allclose(mapped, truth[:2], atol=1e-12)
    assert yaw + odom[2] == pytest.approx(truth[2])


# ---------------------------------------------------------------------------- messages
def calibrated_scan(pan_rad: np.ndarray) -> CalibratedScan:
    n = pan_rad.size
    angle = np.linspace(-0.2, 0.2, n)
    ranges = np.linspace(1.0, 2.0, n)
    ranges[1] = np.nan
    return CalibratedScan(
        header=Header(stamp_ns=2_500_000_000, frame_id="head"),
        time_s=np.linspace(2.4, 2.5, n), scan_angle_rad=angle, pan_rad=pan_rad,
        image_position_norm=np.zeros(n), intensity_A=np.linspace(1e-9, 5e-9, n),
        range_m=ranges, sigma_m=np.full(n, 0.01), direction=1, sweep_index=3,
    )  # fmt: skip


def test_laser_scan_has_the_sweeps_bearings_and_ranges() -> None:
    scan = calibrated_scan(np.full(5, 0.1))
    got = read_back(laser_scan(scan, HEAD_OFFSET_M))
    assert got["frame_id"] == "base_link"
    assert got["timestamp"] == {"seconds": 2, "nanos": 500_000_000}
    assert got["pose"]["position"] == {"x": HEAD_OFFSET_M}  # the centre of scanning
    assert got["start_angle"] == pytest.approx(-0.1) and got["end_angle"] == pytest.approx(0.3)
    np.testing.assert_array_equal(got["ranges"], scan.range_m)  # NaN where no reading
    np.testing.assert_allclose(got["intensities"], [1, 2, 3, 4, 5])  # nA


def test_a_sweep_off_a_uniform_grid_is_not_a_laser_scan() -> None:
    pan = np.where(np.arange(9) < 5, 0.0, 10 * GRID_TOLERANCE_RAD)  # a swing mid-sweep
    scan = calibrated_scan(pan)
    assert laser_scan(scan, HEAD_OFFSET_M) is None
    converter = Converter()
    assert converter.convert(topics.CALIBRATED_SCAN, scan) == []
    assert sum(converter.skipped.values()) == 1


def test_scan_points_pack_every_placed_sample_with_its_fields() -> None:
    points = np.array([[1.0, 0.5], [np.nan, np.nan], [2.0, -0.5], [1.5, 0.0]])
    scan = FilteredScan(
        header=Header(stamp_ns=7, frame_id="base_link"), points_xy=points,
        covariance=np.zeros((4, 2, 2)), origin_xy=np.zeros((4, 2)),
        scan_angle_rad=np.zeros(4), intensity_A=np.array([1e-9, 0, 3e-9, 4e-9]),
        range_m=np.ones(4), sigma_m=np.array([0.001, 0.0, 0.003, 0.004]),
        flag=np.array([0, 1, 0, 4], np.uint8), segment=np.array([0, -1, 0, -1], np.int32),
        sweep_index=0, motion_compensated=True,
    )  # fmt: skip
    got = read_back(scan_points(scan))
    numeric = {7: "<f4", 6: "<i4", 1: "u1"}  # PackedElementFieldNumericType
    fields = {f["name"]: (f.get("offset", 0), numeric[f["type"]]) for f in got["fields"]}
    dtype = np.dtype(
        {"names": list(fields), "formats": [t for _, t in fields.values()],
         "offsets": [o for o, _ in fields.values()], "itemsize": got["point_stride"]}
    )  # fmt: skip
    cloud = np.frombuffer(got["data"], dtype=dtype)
    assert cloud.size == 3  # the sample without a position is left out
    np.testing.assert_allclose(np.stack([cloud["x"], cloud["y"]], 1), points[[0, 2, 3]])
    np.testing.assert_array_equal(cloud["flag"], [0, 0, 4])
    np.testing.assert_array_equal(cloud["segment"], [0, 0, -1])
    np.testing.assert_allclose(cloud["sigma_mm"], [1, 3, 4], rtol=1e-6)


def segment_track() -> Tracks:
    cov = np.zeros((1, 4, 4))
    cov[0, :2, :2] = [[0.01, 0.004], [0.004, 0.02]]
    return Tracks(
        header=Header(stamp_ns=3_000_000_000, frame_id="odom"),
        track_id=np.array([7]), kind=np.array([0], np.uint8), status=np.array([1], np.uint8),
        state=np.array([[1.5, 0.5, 0.0, 0.0]]), covariance=cov,
        params=np.array([[0.3, 1.2, np.nan]]), params_covariance=np.full((1, 3, 3), np.nan),
        extent=np.array([[1.0, 0.0, 2.0, 1.0]]), end_seen=np.array([[1, 0]], np.uint8),
        reflectivity=np.array([1.0]), moving_probability=np.array([0.0]),
        last_seen_ns=np.array([2_900_000_000]), hits=np.array([4]),
        information_bits=np.array([3.5]),
    )  # fmt: skip


def test_a_segment_track_is_its_line_its_ellipse_and_its_label() -> None:
    msg = segment_track()
    got = read_back(tracks_update(msg))
    assert [d.get("type") for d in got["deletions"]] == [1]  # all older entities go
    (entity,) = got["entities"]
    assert entity["id"] == "track/7" and entity["frame_id"] == "odom"
    segment, ring = entity["lines"]
    np.testing.assert_allclose(xy(segment["points"]), [[1.0, 0.0], [2.0, 1.0]])
    assert ring["type"] == 1  # a closed loop
    d = xy(ring["points"]) - msg.state[0, :2]
    mahalanobis_sq = np.einsum("ni,ij,nj->n", d, np.linalg.inv(msg.covariance[0, :2, :2]), d)
    np.testing.assert_allclose(mahalanobis_sq, 9.0, rtol=1e-9)  # the 3σ ellipse
    (end,) = entity["spheres"]  # only the end seen as a real end
    assert (end["pose"]["position"].get("x"), end["pose"]["position"].get("y", 0.0)) == (1.0, 0.0)
    assert entity["texts"][0]["text"] == "7 segment confirmed"
    meta = {kv["key"]: kv["value"] for kv in entity["metadata"]}
    assert meta["hits"] == "4" and meta["information_bits"] == "3.50"


# --------------------------------------------------------------------------- converter
def odometry(t_s: float, x: float, y: float, yaw: float) -> Odometry:
    return Odometry(
        header=Header(stamp_ns=stamp_ns(t_s), frame_id="odom"), x_m=x, y_m=y, yaw_rad=yaw,
        speed_m_s=0.0, yaw_rate_rad_s=0.0, pose_covariance=np.eye(3) * 1e-4,
    )  # fmt: skip


def truth(t_s: float, x: float, y: float, yaw: float, collision: str = "") -> WorldTruth:
    return WorldTruth(
        header=Header(stamp_ns=stamp_ns(t_s), frame_id="world"), x_m=x, y_m=y, yaw_rad=yaw,
        speed_m_s=0.0, yaw_rate_rad_s=0.0, mover_xy=np.zeros((1, 2)),
        mover_velocity_xy=np.zeros((1, 2)), mover_radius_m=np.array([0.2]),
        collision=collision, collision_obstacle=3 if collision else -1,
    )  # fmt: skip


def vehicle_state(t_s: float) -> VehicleState:
    return VehicleState(
        header=Header(stamp_ns=stamp_ns(t_s), frame_id="odom"), x_m=0.0, y_m=0.0, yaw_rad=0.0,
        speed_m_s=0.0, yaw_rate_rad_s=0.0, pose_covariance=np.eye(3) * 1e-4,
        intent_xy=np.array([[1.0, 0.0], [2.0, 1.0]]),
    )  # fmt: skip


def head_state(t_s: float, mode: str = "scanning", refused: int | None = None) -> HeadState:
    return HeadState(
        header=Header(stamp_ns=stamp_ns(t_s), frame_id="base_link", source="head"),
        pan_rad=0.2, pan_rate_rad_s=0.0, target_pan_rad=0.2, window_low_rad=-0.3,
        window_high_rad=0.3, laser_on=mode != "fault", mode=mode,
        command_seq=-1 if refused is None else refused, command_accepted=refused is None,
        command_message="" if refused is None else "pan outside ±90°", sweeps=1,
    )  # fmt: skip


def environment(t_s: float, sensor_ok: bool) -> EnvironmentVector:
    return EnvironmentVector(
        header=Header(stamp_ns=stamp_ns(t_s), frame_id="odom"),
        obstacle_id=np.zeros(0, np.int64), kind=np.zeros(0, np.uint8),
        position_xy=np.zeros((0, 2)), velocity_xy=np.zeros((0, 2)),
        covariance=np.zeros((0, 4, 4)), extent=np.zeros((0, 4)), reflectivity=np.zeros(0),
        free_bearing_rad=np.linspace(-0.3, 0.3, 5), free_range_m=np.array([0, 1, 1, 1, 0.0]),
        sensor_ok=sensor_ok,
    )  # fmt: skip


def channels_of(outputs: list[tuple[str, Any]]) -> list[str]:
    return [channel for channel, _ in outputs]


def test_world_to_odom_comes_from_truth_and_odometry_of_one_instant() -> None:
    converter = Converter()
    assert channels_of(converter.convert(topics.ODOMETRY, odometry(1.0, 0.5, 0.0, 0.1))) == [
        "/odometry", "/tf", "/vehicle"
    ]  # fmt: skip
    out = converter.convert(topics.WORLD_TRUTH, truth(1.0, 3.0, 2.0, 0.4))
    assert channels_of(out) == ["/truth", "/truth/pose", "/tf"]
    (transform,) = read_back(out[-1][1])["transforms"]
    assert (transform["parent_frame_id"], transform["child_frame_id"]) == ("world", "odom")
    x, y, yaw = world_to_odom((3.0, 2.0, 0.4), (0.5, 0.0, 0.1))
    assert transform["translation"]["y"] == pytest.approx(y)
    assert transform["translation"]["x"] == pytest.approx(x)
    assert transform["rotation"]["z"] == pytest.approx(math.sin(yaw / 2))
    # A truth a second after the latest odometry is not paired with it.
    assert "/tf" not in channels_of(converter.convert(topics.WORLD_TRUTH, truth(2.0, 3, 2, 0.4)))


def test_vehicle_state_places_the_vehicle_only_until_odometry_arrives() -> None:
    converter = Converter()
    first = converter.convert(topics.VEHICLE_STATE, vehicle_state(0.0))
    assert channels_of(first) == ["/tf", "/vehicle", "/vehicle/path"]
    path = read_back(first[-1][1])
    assert xy([p["position"] for p in path["poses"]]).tolist() == [[0, 0], [1, 0], [2, 1]]
    converter.convert(topics.ODOMETRY, odometry(0.05, 0.0, 0.0, 0.0))
    later = converter.convert(topics.VEHICLE_STATE, vehicle_state(0.1))
    assert channels_of(later) == ["/vehicle/path"]


def test_log_lines_report_changes_once() -> None:
    converter = Converter()

    def logs(topic: str, msg: Message) -> list[str]:
        return [read_back(m)["message"] for c, m in converter.convert(topic, msg) if c == "/log"]

    assert logs(topics.HEAD_STATE, head_state(0.1)) == []
    assert logs(topics.HEAD_STATE, head_state(0.2, refused=4)) == [
        "head refused command 4: pan outside ±90°"
    ]
    assert logs(topics.HEAD_STATE, head_state(0.3, refused=4)) == []  # the same refusal
    assert logs(topics.HEAD_STATE, head_state(0.4, mode="fault")) == ["head fault: laser off"]
    assert logs(topics.ENVIRONMENT, environment(0.5, True)) == []
    assert logs(topics.ENVIRONMENT, environment(0.6, False)) == [
        "environment: sensor not ok (a vehicle must not move on it)"
    ]
    assert logs(topics.ENVIRONMENT, environment(0.7, False)) == []
    assert logs(topics.ENVIRONMENT, environment(0.8, True)) == ["environment: sensor ok again"]
    assert logs(topics.WORLD_TRUTH, truth(0.9, 0, 0, 0, collision="vehicle")) == [
        "collision: vehicle moved, obstacle 3"
    ]
    assert logs(topics.WORLD_TRUTH, truth(1.0, 0, 0, 0, collision="vehicle")) == []


def test_a_stamp_past_foxgloves_time_range_is_skipped_not_fatal() -> None:
    converter = Converter()
    assert converter.convert(topics.ODOMETRY, odometry(2.0**32, 0, 0, 0)) == []
    assert list(converter.skipped.values()) == [1]
    assert converter.convert(topics.ODOMETRY, odometry(2.0**32 - 1, 0, 0, 0)) != []


def test_unwanted_channels_are_not_built_but_state_is_kept() -> None:
    converter = Converter()
    assert converter.convert(topics.ODOMETRY, odometry(1.0, 0, 0, 0), lambda _c: False) == []
    out = converter.convert(topics.WORLD_TRUTH, truth(1.0, 1, 1, 0), lambda c: c == "/tf")
    assert channels_of(out) == ["/tf"]  # paired with the odometry it was not asked to show


# ------------------------------------------------------------------------------ export
@pytest.fixture(scope="module")
def run_mcap(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Two simulated seconds of the demo's closed loop in lock-step, recorded."""
    world = load_world(ROOT / "worlds" / "demo.toml")
    assert world.task is not None
    task = dataclasses.replace(world.task, time_limit_s=2.0)
    path = tmp_path_factory.mktemp("run") / "run.mcap"
    with Recorder(path) as recorder:

        def observe(t: float, topic: str, msg: Message) -> None:
            recorder.write(topic, msg.to_wire(), stamp_ns(t))

        run_closed_loop(world, task, "active", observe=observe)
    return path


def expected_counts(path: Path) -> tuple[Counter[str], dict[str, set[int]]]:
    """What the export should hold, worked out from the recording: messages per channel and
    the stamps of each channel's messages."""
    counts: Counter[str] = Counter()
    stamps: dict[str, set[int]] = {}
    odometry_stamps: set[int] = set()
    odometry_seen = False
    per_topic = {
        topics.CALIBRATED_SCAN: ["/scan"], topics.FILTERED_SCAN: ["/scan/points"],
        topics.FEATURES: ["/features"], topics.TRACKS: ["/tracks"],
        topics.ENVIRONMENT: ["/environment"], topics.ODOMETRY: ["/odometry", "/vehicle", "/tf"],
        topics.VEHICLE_STATE: ["/vehicle/path"], topics.HEAD_STATE: ["/head", "/tf"],
        topics.WORLD_TRUTH: ["/truth", "/truth/pose"],
    }  # fmt: skip
    for message in read_recording(path):
        if message.topic not in per_topic:
            continue
        msg = decode(message.payload)
        channels = list(per_topic[message.topic])
        if isinstance(msg, Odometry):
            odometry_seen = True
            odometry_stamps.add(msg.header.stamp_ns)
        if isinstance(msg, VehicleState) and not odometry_seen:
            channels += ["/vehicle", "/tf"]
        if isinstance(msg, WorldTruth) and msg.header.stamp_ns in odometry_stamps:
            channels.append("/tf")  # world -> odom (the world stage stamps both alike)
        for channel in channels:
            counts[channel] += 1
            stamps.setdefault(channel, set()).add(msg.header.stamp_ns)
    return counts, stamps


def test_export_writes_every_channel_with_its_schema_and_count(
    run_mcap: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "view" / "fox.mcap"
    assert main(["export", str(run_mcap), str(out), "--foxglove"]) == 0
    printed = capsys.readouterr().out
    assert "skipped: none" in printed
    assert "not shown (no view of these topics): head_command" in printed
    expected, expected_stamps = expected_counts(run_mcap)
    assert expected["/tracks"] >= 10  # the run is long enough to mean something

    counts: Counter[str] = Counter()
    stamps: dict[str, set[int]] = {}
    last_tracks: dict[str, Any] = {}
    with out.open("rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        assert summary is not None
        schema_names = {
            c.topic: summary.schemas[c.schema_id].name for c in summary.channels.values()
        }
        assert schema_names == {c: f"foxglove.{CHANNEL_SCHEMAS[c]}" for c in expected}
        for channel in summary.channels.values():
            assert channel.message_encoding == "protobuf"
            assert summary.schemas[channel.schema_id].encoding == "protobuf"
        assert summary.statistics is not None
        by_id = {c.id: c.topic for c in summary.channels.values()}
        assert {by_id[i]: n for i, n in summary.statistics.channel_message_counts.items()} == dict(
            expected
        )
        for schema, channel, message in reader.iter_messages():
            counts[channel.topic] += 1
            stamps.setdefault(channel.topic, set()).add(message.log_time)
            if channel.topic == "/tracks":
                last_tracks = Protobuf(schema.data).decode(message.data, schema.name)
    assert counts == expected
    assert stamps == expected_stamps  # logged at the messages' own stamps
    (last,) = [decode(m.payload) for m in read_recording(run_mcap) if m.topic == "tracks"][-1:]
    assert isinstance(last, Tracks)
    assert sorted(e["id"] for e in last_tracks.get("entities", [])) == sorted(
        f"track/{i}" for i in last.track_id.tolist()
    )
    assert printed.count("\n  /") == len(expected)  # one summary line per channel


def hand_recording(path: Path, extra: list[tuple[str, bytes]]) -> Path:
    with Recorder(path) as recorder:
        for i in range(3):
            recorder.write(topics.ODOMETRY, odometry(0.1 * i, 0.1 * i, 0, 0).to_wire(), i)
        for i, (topic, payload) in enumerate(extra):
            recorder.write(topic, payload, 10 + i)
    return path


def test_undecodable_messages_are_skipped_and_counted(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    run = hand_recording(
        tmp_path / "run.mcap",
        [(topics.TRACKS, b"\x81\xa4type\xa8tracks/2"), ("", b"junk"), (topics.STOP, b"")],
    )
    out = tmp_path / "out.mcap"
    assert main(["export", str(run), str(out), "--foxglove"]) == 0
    printed = capsys.readouterr().out
    assert "skipped 1 messages:\n  tracks: does not decode (" in printed
    assert "not shown (no view of these topics): <malformed> 1, stop 1" in printed
    with out.open("rb") as f:
        summary = make_reader(f).get_summary()
    assert summary is not None and summary.statistics is not None
    assert sorted(c.topic for c in summary.channels.values()) == ["/odometry", "/tf", "/vehicle"]
    assert set(summary.statistics.channel_message_counts.values()) == {3}


def one_line_error(capsys: pytest.CaptureFixture[str], *args: str) -> str:
    capsys.readouterr()
    status = main(list(args))
    err = capsys.readouterr().err.strip().splitlines()
    assert status == 2 and len(err) == 1, err
    return err[0]


def test_bad_input_is_one_line_and_status_2(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    run = hand_recording(tmp_path / "run.mcap", [])
    out = tmp_path / "out.mcap"
    missing = tmp_path / "missing.mcap"
    assert one_line_error(capsys, "export", str(missing), str(out), "--foxglove") == (
        f"sensor-agent: cannot read recording {missing}: No such file or directory"
    )
    garbled = tmp_path / "garbled.mcap"
    garbled.write_bytes(b"not a recording")
    assert one_line_error(capsys, "export", str(garbled), str(out), "--foxglove") == (
        f"sensor-agent: recording {garbled} is not an MCAP file"
    )
    same = tmp_path / "." / "run.mcap"
    assert "is the input recording" in one_line_error(
        capsys, "export", str(run), str(same), "--foxglove"
    )
    assert "--foxglove is required" in one_line_error(capsys, "export", str(run), str(out))
    idle = hand_recording(tmp_path / "idle.mcap", [])
    with Recorder(idle) as recorder:
        recorder.write(topics.STOP, b"", 0)
    assert "nothing to show" in one_line_error(capsys, "export", str(idle), str(out), "--foxglove")
    assert not out.exists() and run.read_bytes()  # nothing written, the input untouched


def test_a_recording_damaged_part_way_leaves_no_output(
    run_mcap: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(run_mcap.read_bytes()[: run_mcap.stat().st_size // 2])
    out = tmp_path / "out.mcap"
    error = one_line_error(capsys, "export", str(cut), str(out), "--foxglove")
    assert error.startswith(f"sensor-agent: recording {cut} is damaged or cut short after ")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["cut.mcap"]  # no OUT, no partial


def test_without_the_sdk_both_commands_say_how_to_install_it(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setitem(sys.modules, "foxglove", None)  # import foxglove raises ImportError
    run = hand_recording(tmp_path / "run.mcap", [])
    assert one_line_error(capsys, "export", str(run), str(tmp_path / "o.mcap"), "--foxglove") == (
        "sensor-agent: export --foxglove needs the Foxglove SDK: pip install '.[viewer]'"
    )
    assert one_line_error(capsys, "view", "--duration", "1") == (
        "sensor-agent: view needs the Foxglove SDK: pip install '.[viewer]'"
    )


def test_the_conversions_do_not_import_the_sdk_at_import_time() -> None:
    """Only the two commands may load the SDK, when they run: importing the modules (as
    ``sensor-agent --help`` does) must not."""
    import subprocess

    code = (
        "import sys, cli.main, cli.viewer, cli.viewer_convert; "
        "cli.main.build_parser(); print('foxglove' in sys.modules)"
    )
    done = subprocess.run(
        [sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=60
    )
    assert done.stdout.strip() == "False", done.stderr


def test_view_refuses_a_bad_port(capsys: pytest.CaptureFixture[str]) -> None:
    assert "--port must be 0-65535" in one_line_error(capsys, "view", "--port", "70000")
    assert "--duration must be positive" in one_line_error(capsys, "view", "--duration", "0")


_ = fm  # the SDK is a test dependency: fail here, loudly, if it is missing
