"""The project's exceptions, in one tree.

::

    SensorAgentError                  base of everything the project raises on purpose
    ├── ConfigError                   a configuration value or file is unusable
    │   ├── WorldFileError            a world TOML file: unreadable, unknown key, wrong type, ...
    │   └── CalibrationFileError      a calibration file: unreadable, wrong format or version
    ├── HeadCommandError              a head command outside the head's limits (pan, window)
    ├── MessageError                  a bus message that cannot be decoded or fails validation;
    │                                 ``kind`` says which: malformed, truncated, oversized,
    │                                 unknown_type, wrong_version, out_of_range
    └── LaunchFileError               a launch file: unreadable, unknown key or process, ...

Every message is one line that names what was wrong, so a command-line shell can print
``str(error)`` as it is and exit with status 2.
"""

from __future__ import annotations

from pathlib import Path


class SensorAgentError(Exception):
    """Base class of the project's own errors."""


class ConfigError(SensorAgentError, ValueError):
    """A configuration value or file is unusable."""


class WorldFileError(ConfigError):
    """A world file could not be read or does not describe a valid world.

    Parameters
    ----------
    path
        The file, or ``None`` when the world came from a string or a mapping.
    problem
        What is wrong, naming the key or entry (e.g. ``"[[box]] 2: size must be positive"``).
    """

    def __init__(self, path: str | Path | None, problem: str) -> None:
        self.path = None if path is None else Path(path)
        self.problem = problem
        where = "world" if path is None else f"world file {path}"
        super().__init__(f"{where}: {problem}")


class CalibrationFileError(ConfigError):
    """A calibration file could not be read or is of an unsupported format or version."""

    def __init__(self, path: str | Path | None, problem: str) -> None:
        self.path = None if path is None else Path(path)
        self.problem = problem
        where = "calibration" if path is None else f"calibration file {path}"
        super().__init__(f"{where}: {problem}")


class HeadCommandError(SensorAgentError, ValueError):
    """A head command (pan angle, scan window) the head cannot honour."""


class MessageError(SensorAgentError):
    """A bus message that cannot be decoded, or whose content fails validation.

    ``kind`` names the class of problem, so receivers can count drops per kind and log each
    kind once: ``malformed``, ``truncated``, ``oversized``, ``unknown_type``,
    ``wrong_version`` or ``out_of_range``.
    """

    KINDS = ("malformed", "truncated", "oversized", "unknown_type", "wrong_version", "out_of_range")

    def __init__(self, kind: str, problem: str) -> None:
        if kind not in self.KINDS:
            raise ValueError(f"unknown message error kind {kind!r}")
        self.kind = kind
        self.problem = problem
        super().__init__(f"{problem} [{kind}]")


class LaunchFileError(ConfigError):
    """A launch file could not be read or does not describe a valid process graph."""

    def __init__(self, path: str | Path | None, problem: str) -> None:
        self.path = None if path is None else Path(path)
        self.problem = problem
        where = "launch" if path is None else f"launch file {path}"
        super().__init__(f"{where}: {problem}")
