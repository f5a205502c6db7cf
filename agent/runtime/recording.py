"""Recordings of the bus: every message, byte for byte, in an MCAP file.

Layout of a recording
---------------------
* Header: profile ``lep-sensor-agent``, library ``lep-sensor-agent <version> (mcap <version>)``.
* One channel per topic, ``message_encoding="msgpack"`` (the wire format of
  :mod:`agent.runtime.messages`), with a schema named after the topic's message type tag
  (``raw_scan/1``, from :data:`agent.runtime.topics.TOPIC_TYPES`; schema encoding ``""``, no data).
  A topic the registry does not know (malformed traffic arrives with topic ``""``) gets its own
  channel with no schema; its payloads are kept as they came.
* Messages: the payload exactly as received (never decoded or re-encoded), with the time it was
  logged in integer nanoseconds. Log times never go backwards in a recording: a log time older
  than the previous one (a wall clock stepped back) is stored as the previous one.
* Chunked and zstd-compressed, with the usual MCAP summary (indexes, statistics), so other MCAP
  tools read it too.

Reading returns the messages in file order (which is log-time order), checking the file as it
goes: the CRCs of chunks and of the data section, no record longer than the file. A file that
cannot be read, is empty, is not MCAP, is cut short or damaged (a chunk that does not
decompress or fails its CRC, a record that does not parse) raises
:class:`agent.errors.ConfigError`, one line naming the file and the problem. Payloads are not
decoded here: whether they are messages is the reader's to check.

This module does only file I/O: the caller supplies every time stamp.
"""

from __future__ import annotations

import importlib.metadata
import os
import struct
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import IO, NamedTuple

from mcap.exceptions import EndOfFile, McapError, RecordLengthLimitExceeded
from mcap.reader import NonSeekingReader
from mcap.stream_reader import CRCValidationError
from mcap.writer import CompressionType, Writer

from agent.errors import ConfigError
from agent.runtime.topics import TOPIC_TYPES

PROFILE = "lep-sensor-agent"
MESSAGE_ENCODING = "msgpack"
CHUNK_SIZE = 512 * 1024
_MAGIC = b"\x89MCAP0\r\n"
_DETAIL_CHARS = 160  # of what the MCAP library says is wrong with a damaged file

__all__ = ["MESSAGE_ENCODING", "PROFILE", "RecordedMessage", "Recorder", "read_recording"]


def _version(package: str) -> str:
    try:
        return importlib.metadata.version(package)
    except importlib.metadata.PackageNotFoundError:
        return "unknown"


def library_identifier() -> str:
    """What a recording's header names as the library that wrote it."""
    return f"{PROFILE} {_version('lep-sensor-agent')} (mcap {_version('mcap')})"


class RecordedMessage(NamedTuple):
    """One message of a recording: its topic, its payload as sent, when it was logged."""

    topic: str
    payload: bytes
    log_time_ns: int


class Recorder:
    """Writes bus messages to an MCAP file (see the module docstring).

    Call :meth:`write` for every message and :meth:`close` once at the end; a recorder that is
    not closed leaves a file without its summary and may lose its last chunk of messages.
    """

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            self._stream: IO[bytes] = open(self.path, "wb")  # noqa: SIM115 (closed in close())
        except OSError as exc:
            raise ConfigError(f"cannot write recording {self.path}: {exc.strerror}") from None
        self._writer = Writer(self._stream, chunk_size=CHUNK_SIZE, compression=CompressionType.ZSTD)
        self._writer.start(profile=PROFILE, library=library_identifier())
        self._channels: dict[str, int] = {}
        self._schemas: dict[str, int] = {}
        self._last_ns = 0
        self.count = 0
        self.closed = False

    def _channel(self, topic: str) -> int:
        channel = self._channels.get(topic)
        if channel is not None:
            return channel
        schema_id = 0  # no schema: a topic the registry does not know
        metadata: dict[str, str] = {}
        cls = TOPIC_TYPES.get(topic)
        if cls is not None:
            tag = f"{cls.TYPE}/{cls.VERSION}"
            schema_id = self._schemas.get(tag, 0)
            if schema_id == 0:
                schema_id = self._writer.register_schema(name=tag, encoding="", data=b"")
                self._schemas[tag] = schema_id
            metadata = {"type": tag}
        channel = self._writer.register_channel(
            topic=topic, message_encoding=MESSAGE_ENCODING, schema_id=schema_id, metadata=metadata
        )
        self._channels[topic] = channel
        return channel

    def write(self, topic: str, payload: bytes, log_time_ns: int) -> None:
        """Record one message exactly as it came off the bus."""
        if self.closed:
            raise ValueError(f"recording {self.path} is closed")
        log_time = max(int(log_time_ns), self._last_ns)
        self._last_ns = log_time
        self._writer.add_message(
            channel_id=self._channel(topic),
            log_time=log_time,
            data=bytes(payload),
            publish_time=log_time,
            sequence=self.count & 0xFFFFFFFF,
        )
        self.count += 1

    def close(self) -> None:
        """Write the summary and close the file (once; later calls do nothing)."""
        if self.closed:
            return
        self.closed = True
        finish: Callable[[], None] = self._writer.finish  # mcap leaves it unannotated
        try:
            finish()
        finally:
            self._stream.close()

    def __enter__(self) -> Recorder:
        return self

    def __exit__(self, *_exc: object) -> None:
        self.close()


def _open(path: Path) -> tuple[IO[bytes], int]:
    """The file, open at its start, and its size in bytes."""
    try:
        stream: IO[bytes] = open(path, "rb")  # noqa: SIM115 (closed by the reading generator)
    except OSError as exc:
        raise ConfigError(f"cannot read recording {path}: {exc.strerror}") from None
    try:
        size = os.fstat(stream.fileno()).st_size
        magic = stream.read(len(_MAGIC))
    except OSError as exc:
        stream.close()
        raise ConfigError(f"cannot read recording {path}: {exc.strerror}") from None
    if magic != _MAGIC:
        stream.close()
        raise ConfigError(f"recording {path} is {'not an MCAP file' if magic else 'empty'}")
    stream.seek(0)
    return stream, size


def read_recording(path: str | Path) -> Iterator[RecordedMessage]:
    """The messages of a recording, in file order (log times ascending).

    The file is opened and checked now: one that cannot be opened, is empty or is not MCAP
    raises :class:`ConfigError` at once. A file damaged or cut short further on raises it
    while iterating, after the messages before the damage; a damaged data section (its CRC)
    is found only at its end, after every message.
    """
    p = Path(path)
    stream, size = _open(p)
    return _messages(p, stream, size)


def _messages(path: Path, stream: IO[bytes], size: int) -> Iterator[RecordedMessage]:
    count = 0
    try:
        # No record is longer than the file: a damaged length is refused before it is read.
        reader = NonSeekingReader(stream, validate_crcs=True, record_size_limit=size)
        for _schema, channel, message in reader.iter_messages(log_time_order=False):
            yield RecordedMessage(channel.topic, bytes(message.data), int(message.log_time))
            count += 1
    except OSError as exc:
        raise ConfigError(f"cannot read recording {path}: {exc.strerror}") from None
    except Exception as exc:  # mcap, zstandard and lz4 raise many types for damaged input
        where = f"after {count} messages" if count else "before any message"
        raise ConfigError(
            f"recording {path} is damaged or cut short {where}: {_detail(exc)}"
        ) from None
    finally:
        stream.close()


def _detail(exc: Exception) -> str:
    """What is wrong, in one short line: the MCAP library's words, or the error's type and
    words where they come from elsewhere (a decompressor, a missing channel)."""
    if isinstance(exc, EndOfFile):
        return "the file ends early"
    if isinstance(exc, struct.error):  # a field read past the end of its record
        return "a record is cut short"
    if isinstance(exc, MemoryError):  # a damaged size, of a chunk's content say
        return "a record claims more memory than there is"
    if isinstance(exc, RecordLengthLimitExceeded):  # the limit is the file's size
        return f"a record is longer than the whole file ({exc})"
    text = " ".join(str(exc).split())
    if not isinstance(exc, McapError | CRCValidationError) or not text:
        text = f"{type(exc).__name__}: {text}" if text else type(exc).__name__
    return text if len(text) <= _DETAIL_CHARS else text[: _DETAIL_CHARS - 1] + "…"
