"""Tests of agent.toml_files: every way a TOML file can be unusable is one project error."""

from __future__ import annotations

import functools
import os
import tracemalloc
from pathlib import Path

import pytest

from agent.errors import ConfigError, LaunchFileError, WorldFileError
from agent.toml_files import MAX_TOML_BYTES, load_toml, parse_toml

pytestmark = pytest.mark.filterwarnings("error")


def _problem(path: Path, max_bytes: int = MAX_TOML_BYTES) -> str:
    with pytest.raises(WorldFileError) as info:
        load_toml(path, functools.partial(WorldFileError, path), max_bytes=max_bytes)
    message = str(info.value)
    assert "\n" not in message
    assert message.startswith(f"world file {path}: ")
    return info.value.problem


def test_reads_a_file_and_uses_the_callers_error(tmp_path: Path) -> None:
    path = tmp_path / "g.toml"
    path.write_text('name = "g"\n[[process]]\nmodule = "m"\n', encoding="utf-8")
    assert load_toml(path, functools.partial(LaunchFileError, path)) == {
        "name": "g",
        "process": [{"module": "m"}],
    }
    with pytest.raises(LaunchFileError, match=r"^launch: not valid TOML: "):
        parse_toml("a = ", functools.partial(LaunchFileError, None))


def test_missing_unreadable_and_not_a_file(tmp_path: Path) -> None:
    assert _problem(tmp_path / "absent.toml") == "no such file"
    assert _problem(tmp_path) == "not a regular file"
    fifo = tmp_path / "fifo.toml"
    os.mkfifo(fifo)
    assert _problem(fifo) == "not a regular file"  # and opening it did not wait for a writer
    if os.geteuid() != 0:  # root reads files regardless of their mode
        locked = tmp_path / "locked.toml"
        locked.write_text("a = 1\n")
        locked.chmod(0)
        assert _problem(locked).startswith("cannot read: ")


def test_size_limit_is_checked_before_reading(tmp_path: Path) -> None:
    path = tmp_path / "big.toml"
    path.write_text("a = 1\n" + "#" * 100 + "\n")
    assert load_toml(path, functools.partial(WorldFileError, path), max_bytes=107) == {"a": 1}
    assert _problem(path, max_bytes=106) == "larger than the 106-byte limit (107 bytes)"
    # A sparse file far above the default limit is refused without being read.
    sparse = tmp_path / "sparse.toml"
    with open(sparse, "wb") as f:
        f.truncate(1 << 30)
    tracemalloc.start()
    try:
        problem = _problem(sparse)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert problem == f"larger than the {MAX_TOML_BYTES}-byte limit ({1 << 30} bytes)"
    assert peak < 1 << 20  # bound: far below the gigabyte the file claims


def test_text_limit() -> None:
    error = functools.partial(ConfigError)
    assert parse_toml("a = 1", error, max_chars=5) == {"a": 1}
    with pytest.raises(ConfigError, match=r"^longer than the 4-character limit \(5 characters\)$"):
        parse_toml("a = 1", error, max_chars=4)


def test_not_utf8(tmp_path: Path) -> None:
    path = tmp_path / "latin1.toml"
    path.write_bytes('name = "caf\xe9"\n'.encode("latin-1"))
    assert _problem(path) == "not UTF-8 text (byte 11)"


def test_not_toml_is_one_line(tmp_path: Path) -> None:
    path = tmp_path / "bad.toml"
    path.write_text("a = [1,\n\n2\nb = ")
    problem = _problem(path)
    assert problem.startswith("not valid TOML: ")


@pytest.mark.parametrize(
    ("opening", "closing"),
    [("[", "]"), ("{b = ", "}"), ("[{b = ", "}]")],
    ids=["arrays", "inline-tables", "both"],
)
def test_deep_nesting_is_refused(tmp_path: Path, opening: str, closing: str) -> None:
    # tomllib parses nested values recursively: without the guard a RecursionError escapes.
    depth = 100_000 // len(opening)
    path = tmp_path / "deep.toml"
    path.write_text("a = " + opening * depth + closing * depth + "\n")
    assert path.stat().st_size <= MAX_TOML_BYTES
    assert _problem(path) == "not valid TOML: arrays or inline tables nested too deeply"


def test_moderate_nesting_is_accepted() -> None:
    doc = parse_toml("a = " + "[" * 50 + "]" * 50, ConfigError)
    value = doc["a"]
    for _ in range(49):
        (value,) = value
    assert value == []


def test_memory_error_is_one_line(monkeypatch: pytest.MonkeyPatch) -> None:
    def exhausted(text: str) -> dict[str, object]:
        raise MemoryError

    monkeypatch.setattr("agent.toml_files.tomllib.loads", exhausted)
    with pytest.raises(ConfigError, match=r"^not valid TOML: too large to parse in memory$"):
        parse_toml("a = 1", ConfigError)
