"""Reading TOML configuration files with stated limits, failing with one line.

Every TOML file the project reads (world files, launch files) goes through here, so that each
of them refuses the same things in the same words (:func:`read_limited`, the first two items,
serves other configuration files too):

* a file that is missing, not a regular file (a directory, a FIFO, a device), or unreadable;
* a file larger than ``max_bytes`` (:data:`MAX_TOML_BYTES` unless the caller says otherwise),
  checked before the content is read, so ``/dev/zero``-like inputs cost nothing;
* bytes that are not UTF-8;
* text that is not TOML (:class:`tomllib.TOMLDecodeError`);
* arrays or inline tables nested so deeply that :mod:`tomllib`, which is recursive, runs out
  of stack (:class:`RecursionError`), and a parse that runs out of memory (:class:`MemoryError`).

Each failure becomes the exception the caller's ``error`` callable builds from a one-line
problem, e.g. ``functools.partial(WorldFileError, path)``; nothing else escapes.
"""

from __future__ import annotations

import os
import stat
import tomllib
from collections.abc import Callable
from pathlib import Path
from typing import Any

from agent.errors import ConfigError

__all__ = ["MAX_TOML_BYTES", "ErrorFactory", "load_toml", "parse_toml", "read_limited"]

MAX_TOML_BYTES = 1 << 20
"""Largest TOML file read by default (1 MiB): a hand-written launch file is a few kB and a
generated world of a thousand 64-vertex polygons is about 0.5 MiB; a parse of 1 MiB takes
well under a second and a few tens of MB at most."""

ErrorFactory = Callable[[str], ConfigError]
"""Builds the project error to raise from a one-line problem, e.g.
``functools.partial(WorldFileError, path)``."""


def load_toml(
    path: str | Path, error: ErrorFactory, *, max_bytes: int = MAX_TOML_BYTES
) -> dict[str, Any]:
    """Read a UTF-8 TOML file of at most ``max_bytes`` bytes.

    Parameters
    ----------
    path
        The file to read.
    error
        Builds the exception to raise from a one-line problem (``"no such file"``,
        ``"larger than the 1048576-byte limit (...)"``, ``"not valid TOML: ..."``, ...).
    max_bytes
        The size limit; the file's size is checked before its content is read.

    Returns
    -------
    dict
        The parsed document, as :func:`tomllib.loads` returns it.

    Raises
    ------
    ConfigError
        Whatever ``error`` builds, for every way the file can be unusable.
    """
    data = read_limited(path, error, max_bytes=max_bytes)
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise error(f"not UTF-8 text (byte {exc.start})") from None
    return parse_toml(text, error, max_chars=max_bytes)


def read_limited(path: str | Path, error: ErrorFactory, *, max_bytes: int) -> bytes:
    """Read a regular file of at most ``max_bytes`` bytes, checking its size first.

    The file half of :func:`load_toml`, for other configuration files (e.g. calibration
    archives): ``"no such file"``, ``"not a regular file"``, ``"cannot read: ..."`` and
    ``"larger than the N-byte limit (M bytes)"`` become whatever ``error`` builds.
    """
    try:
        # Non-blocking, so that opening a FIFO returns at once instead of waiting for a writer.
        fd = os.open(path, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0))
        with os.fdopen(fd, "rb") as f:
            # Check the kind and size of what was opened (not of the path, which could change).
            info = os.fstat(f.fileno())
            if not stat.S_ISREG(info.st_mode):
                raise error("not a regular file")
            if info.st_size > max_bytes:
                raise error(f"larger than the {max_bytes}-byte limit ({info.st_size} bytes)")
            # Read one byte past the limit in case the file grew since fstat.
            data = f.read(max_bytes + 1)
    except FileNotFoundError:
        raise error("no such file") from None
    except IsADirectoryError:
        raise error("not a regular file") from None
    except OSError as exc:
        raise error(f"cannot read: {exc.strerror or type(exc).__name__}") from None
    if len(data) > max_bytes:
        raise error(f"larger than the {max_bytes}-byte limit")
    return data


def parse_toml(
    text: str, error: ErrorFactory, *, max_chars: int = MAX_TOML_BYTES
) -> dict[str, Any]:
    """Parse TOML text of at most ``max_chars`` characters.

    Parameters
    ----------
    text
        The TOML text.
    error
        Builds the exception to raise from a one-line problem.
    max_chars
        The size limit, in characters (a UTF-8 file within a byte limit is always within the
        same character limit).

    Returns
    -------
    dict
        The parsed document.

    Raises
    ------
    ConfigError
        Whatever ``error`` builds: text too long, not TOML, nested too deeply, or too large to
        parse in memory.
    """
    if len(text) > max_chars:
        raise error(f"longer than the {max_chars}-character limit ({len(text)} characters)")
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise error("not valid TOML: " + " ".join(str(exc).split())) from None
    except RecursionError:
        raise error("not valid TOML: arrays or inline tables nested too deeply") from None
    except MemoryError:
        raise error("not valid TOML: too large to parse in memory") from None
