"""A damaged recording is one line naming the file and the problem, and ``replay`` exits 2.

Damage of every kind: an empty file, random bytes, a file cut short, a chunk whose compressed
data is garbage, a chunk claiming a size beyond memory, a chunk whose data no longer matches
its CRC, a record longer than the file, and recordings whose payloads are not messages.
``replay`` reads the whole recording before it binds a socket, so none of these tests opens one.
"""

from __future__ import annotations

import struct
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from agent.errors import ConfigError
from agent.runtime import topics
from agent.runtime.recording import Recorder, read_recording
from cli import introspect
from cli.main import main
from tests.unit.runtime.test_messages import _head_state, _raw_scan

REPO = Path(__file__).resolve().parents[3]
DAMAGE_SEED = 20260318
CHUNK_OPCODE = 0x06
# A chunk record's body: start and end times, uncompressed size (u64 each), uncompressed CRC
# (u32), compression (u32 length + "zstd"), records' length (u64), then the compressed records.
CHUNK_DATA_AT = 8 + 8 + 8 + 4 + 4 + 4 + 8


def _write(path: Path, payloads: list[tuple[str, bytes]]) -> Path:
    with Recorder(path) as rec:
        for i, (topic, payload) in enumerate(payloads):
            rec.write(topic, payload, 1_000 + i * 50_000_000)
    return path


@pytest.fixture(scope="module")
def good(tmp_path_factory: pytest.TempPathFactory) -> bytes:
    """A sound recording of 40 messages: raw scans and head states."""
    scan, state = _raw_scan(), _head_state()
    payloads = [
        (topic, msg.to_wire(seq=i))
        for i in range(20)
        for topic, msg in ((topics.RAW_SCAN, scan), (topics.HEAD_STATE, state))
    ]
    return _write(tmp_path_factory.mktemp("rec") / "good.mcap", payloads).read_bytes()


def _first_chunk(data: bytes) -> tuple[int, int]:
    """Where the first chunk record's body starts, and its length."""
    at = 8  # after the magic
    while True:
        opcode, length = data[at], struct.unpack_from("<Q", data, at + 1)[0]
        if opcode == CHUNK_OPCODE:
            return at + 9, length
        at += 9 + length


def _chunk_data_replaced(data: bytes, new: Callable[[int], bytes]) -> bytes:
    """``data`` with the first chunk's compressed records replaced by ``new(their length)``."""
    body, length = _first_chunk(data)
    start, end = body + CHUNK_DATA_AT, body + length
    return data[:start] + new(end - start) + data[end:]


def _huge_zstd_frame(length: int) -> bytes:
    """A zstd frame header claiming 2**62 bytes of content, padded to ``length`` bytes."""
    frame = b"\x28\xb5\x2f\xfd" + bytes([0xE0]) + struct.pack("<Q", 1 << 62)
    return frame + bytes(length - len(frame))


def _flipped_in_chunk(data: bytes) -> bytes:
    """One byte of the first chunk's compressed records flipped, in the middle."""
    body, length = _first_chunk(data)
    at = body + CHUNK_DATA_AT + (length - CHUNK_DATA_AT) // 2
    return data[:at] + bytes([data[at] ^ 0x01]) + data[at + 1 :]


def _record_longer_than_the_file(data: bytes) -> bytes:
    body, _ = _first_chunk(data)
    return data[: body - 8] + struct.pack("<Q", len(data) + 1) + data[body:]


# Each damage and words the one line must hold.
DAMAGES: dict[str, tuple[Callable[[bytes], bytes], str]] = {
    "empty": (lambda good: b"", "is empty"),
    "random bytes": (
        lambda good: np.random.default_rng(DAMAGE_SEED).bytes(4000),
        "not an MCAP file",
    ),
    "magic then random bytes": (
        lambda good: good[:8] + np.random.default_rng(DAMAGE_SEED).bytes(4000),
        "damaged or cut short",
    ),
    "cut in the first chunk": (lambda good: good[: _first_chunk(good)[0] + 100], "cut short"),
    "cut at half": (lambda good: good[: len(good) // 2], "cut short"),
    "cut before the footer": (lambda good: good[:-20], "cut short"),
    "chunk data garbage": (
        lambda good: _chunk_data_replaced(good, lambda n: b"\xff" * n),
        "ZstdError",
    ),
    "chunk claims 2**62 bytes": (
        lambda good: _chunk_data_replaced(good, _huge_zstd_frame),
        "more memory than there is",
    ),
    "chunk fails its CRC": (_flipped_in_chunk, "crc"),
    "record longer than the file": (_record_longer_than_the_file, "longer than the whole file"),
}


def _damaged(tmp_path: Path, good: bytes, name: str) -> Path:
    make, _ = DAMAGES[name]
    path = tmp_path / f"{name.replace(' ', '_').replace('*', '')}.mcap"
    path.write_bytes(make(good))
    return path


def test_the_sound_recording_reads_whole(tmp_path: Path, good: bytes) -> None:
    path = tmp_path / "good.mcap"
    path.write_bytes(good)
    assert len(list(read_recording(path))) == 40


def test_reading_damaged_recordings_is_one_line_naming_the_file(
    tmp_path: Path, good: bytes
) -> None:
    for name, (_, words) in DAMAGES.items():
        path = _damaged(tmp_path, good, name)
        try:
            got = list(read_recording(path))
        except ConfigError as exc:
            text = str(exc)
            assert str(path) in text and words in text and "\n" not in text, (name, text)
            assert len(text) < 300, (name, text)
        else:
            pytest.fail(f"{name}: read {len(got)} messages without an error")


def _replay(path: Path, capsys: pytest.CaptureFixture[str], *extra: str) -> tuple[int, str]:
    """``sensor-agent replay PATH`` in this process: its status and its stderr (it must print
    nothing on stdout: it refuses before saying what it would replay)."""
    status = main(["replay", str(path), "--endpoint", "ipc:///nonexistent/replay.pub", *extra])
    out, err = capsys.readouterr()
    assert out == "", out
    return status, err


def test_replay_of_damaged_recordings_exits_2_with_one_line(
    tmp_path: Path, good: bytes, capsys: pytest.CaptureFixture[str]
) -> None:
    for name, (_, words) in DAMAGES.items():
        path = _damaged(tmp_path, good, name)
        status, err = _replay(path, capsys)
        assert status == 2, (name, err)
        assert err.startswith(f"sensor-agent: recording {path}"), (name, err)
        assert err.count("\n") == 1 and words in err, (name, err)


def test_replay_refuses_a_recording_whose_payloads_are_all_garbage(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    rng = np.random.default_rng(DAMAGE_SEED)
    garbage = [(topics.RAW_SCAN, rng.bytes(int(n))) for n in rng.integers(0, 300, size=10)]
    path = _write(tmp_path / "garbage.mcap", garbage)
    status, err = _replay(path, capsys)
    assert status == 2, err
    assert err.count("\n") == 1, err
    assert f"recording {path}: none of its 10 messages on raw_scan decode (first: " in err
    # Each selected topic counts: one garbage topic among sound ones is skipped, not refused.
    cut_scan = _raw_scan().to_wire()[:-5]
    mixed = [*garbage, (topics.HEAD_STATE, cut_scan)]
    path = _write(tmp_path / "mixed.mcap", mixed)
    status, err = _replay(path, capsys, "--topics", topics.HEAD_STATE)
    assert status == 2 and "none of its 1 messages on head_state decode" in err, err


def test_payloads_that_do_not_decode_are_counted_and_skipped(tmp_path: Path) -> None:
    scan = _raw_scan()
    payloads = [(topics.RAW_SCAN, scan.to_wire(seq=i)) for i in range(6)]
    payloads[2] = (topics.RAW_SCAN, b"\x00garbage")
    payloads[4] = (topics.RAW_SCAN, scan.to_wire()[:-1])  # cut short
    payloads.append(("", b"\xc1"))  # malformed traffic as the recorder keeps it: not checked
    path = _write(tmp_path / "some_bad.mcap", payloads)
    survey = introspect._survey(str(path))
    assert survey.counts == {topics.RAW_SCAN: 6, "": 1}
    assert survey.undecodable == {topics.RAW_SCAN: 2}
    assert survey.skip == {2, 4}  # by place in the file: replay leaves these out
    warning = introspect._check_decodable(str(path), survey, [topics.RAW_SCAN])
    assert warning is not None and "\n" not in warning
    assert warning.startswith(f"recording {path}: skipping 2 messages that do not decode")
    assert "(raw_scan 2; first: 7 bytes after the message [malformed])" in warning


def test_the_replay_command_exits_2_with_one_line_and_no_traceback(tmp_path: Path) -> None:
    """The real command line, in its own process: status 2, one line on stderr."""
    path = _write(tmp_path / "garbage.mcap", [(topics.HEAD_STATE, b"\xc1")] * 3)
    done = subprocess.run(
        [sys.executable, "-m", "cli.main", "replay", str(path),
         "--endpoint", f"ipc://{tmp_path}/replay.pub", "--wait", "0", "--speed", "0"],
        cwd=REPO, capture_output=True, text=True, timeout=60,
    )  # fmt: skip
    assert done.returncode == 2, done
    assert done.stderr.count("\n") == 1 and "Traceback" not in done.stderr, done.stderr
    assert done.stderr.startswith(f"sensor-agent: recording {path}: none of its 3 messages")
