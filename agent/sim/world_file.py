"""World files: TOML text to a :class:`~agent.sim.world.World`.

Frames follow REP-103: x forward, y left, angles counter-clockwise; lengths in metres, and
degrees only in the keys named ``*_deg``.

World file (TOML, read with :mod:`tomllib`)::

    name = "optional string"            # default: the file's stem ("" for text or a mapping)
    [vehicle]
    pose = [x_m, y_m, yaw_deg]          # optional; default [0, 0, 0]
    [[wall]]
    points = [[x, y], [x, y], ...]      # a polyline of at least 2 points
    reflectivity = 1.0                  # optional; 1.0 = off-white cardboard; > 0
    [[box]]
    center = [x, y]
    size = [length, width]              # along the box's own x and y axes; > 0
    yaw_deg = 0.0                       # optional
    reflectivity = 1.0                  # optional
    [[cylinder]]
    center = [x, y]
    radius = 0.1                        # > 0
    reflectivity = 1.0                  # optional

Every problem in a world raises :class:`~agent.errors.WorldFileError` with a one-line message
naming the file and the entry (entries are numbered from 1), e.g.
``world file w.toml: [[box]] 2: size must be two positive numbers, got [0.4, -1]``.

Obstacle ids follow the file: walls first, then boxes, then cylinders, each in file order.
"""

from __future__ import annotations

import math
import tomllib
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from agent.errors import WorldFileError
from agent.sim.world import ObstacleKind, Point, Pose, World, assemble_world
from agent.sim.world_checks import WorldChecker, show_value

__all__ = ["load_world", "parse_world"]

DEFAULT_REFLECTIVITY = 1.0
"""Reflectivity of an entry that gives none: off-white cardboard, the reference surface."""

_KINDS: tuple[ObstacleKind, ...] = ("wall", "box", "cylinder")
_TOP_LEVEL_KEYS = ("name", "vehicle", *_KINDS)
_ENTRY_KEYS: dict[ObstacleKind, tuple[str, ...]] = {
    "wall": ("points", "reflectivity"),
    "box": ("center", "size", "yaw_deg", "reflectivity"),
    "cylinder": ("center", "radius", "reflectivity"),
}
_REQUIRED_KEYS: dict[ObstacleKind, tuple[str, ...]] = {
    "wall": ("points",),
    "box": ("center", "size"),
    "cylinder": ("center", "radius"),
}
_VEHICLE_KEYS = ("pose",)


def _parse_mapping(doc: Mapping[str, Any], path: str | Path | None) -> World:
    chk = WorldChecker(path)
    if not isinstance(doc, Mapping):
        chk.fail("", f"a world must be a table, got {show_value(doc)}")
    for key in doc:
        if key not in _TOP_LEVEL_KEYS:
            chk.fail(
                "",
                f"unknown top-level key {show_value(key)}; "
                f"allowed keys: {', '.join(_TOP_LEVEL_KEYS)}",
            )

    name = doc.get("name", Path(path).stem if path is not None else "")
    if not isinstance(name, str):
        chk.fail("", f"name must be a string, got {show_value(name)}")

    pose: Pose = (0.0, 0.0, 0.0)
    if "vehicle" in doc:
        vehicle = chk.table(doc["vehicle"], "[vehicle]", _VEHICLE_KEYS)
        if "pose" in vehicle:
            x, y, yaw_deg = chk.numbers(
                vehicle["pose"], 3, "[vehicle]", "pose", "[x_m, y_m, yaw_deg]"
            )
            pose = (x, y, math.radians(yaw_deg))

    entries: dict[ObstacleKind, list[Mapping[str, Any]]] = {}
    for kind in _KINDS:
        raw = doc.get(kind, [])
        if not isinstance(raw, list | tuple):
            chk.fail("", f"{kind} must be an array of tables [[{kind}]], got {show_value(raw)}")
        tables: list[Mapping[str, Any]] = []
        for i, entry in enumerate(raw):
            where = f"[[{kind}]] {i + 1}"
            table = chk.table(entry, where, _ENTRY_KEYS[kind])
            for key in _REQUIRED_KEYS[kind]:
                if key not in table:
                    chk.fail(where, f"missing key {show_value(key)}")
            tables.append(table)
        entries[kind] = tables

    def refl(table: Mapping[str, Any], where: str) -> float:
        return chk.positive(table.get("reflectivity", DEFAULT_REFLECTIVITY), where, "reflectivity")

    walls = [
        (chk.polyline(t["points"], f"[[wall]] {i + 1}"), refl(t, f"[[wall]] {i + 1}"))
        for i, t in enumerate(entries["wall"])
    ]
    boxes: list[tuple[Point, Point, float, float]] = []
    for i, t in enumerate(entries["box"]):
        where = f"[[box]] {i + 1}"
        boxes.append(
            (
                chk.point(t["center"], where, "center"),
                chk.positive_pair(t["size"], where, "size"),
                math.radians(chk.finite(t.get("yaw_deg", 0.0), where, "yaw_deg")),
                refl(t, where),
            )
        )
    cylinders: list[tuple[Point, float, float]] = []
    for i, t in enumerate(entries["cylinder"]):
        where = f"[[cylinder]] {i + 1}"
        cylinders.append(
            (
                chk.point(t["center"], where, "center"),
                chk.positive(t["radius"], where, "radius"),
                refl(t, where),
            )
        )
    return assemble_world(walls, boxes, cylinders, pose, name)


def parse_world(text_or_mapping: str | Mapping[str, Any], path: str | Path | None = None) -> World:
    """Build a world from TOML text or from an already parsed mapping.

    Parameters
    ----------
    text_or_mapping
        TOML text, or a mapping shaped like :func:`tomllib.loads`'s result.
    path
        The file the text came from, used in error messages and as the default name.

    Returns
    -------
    World

    Raises
    ------
    WorldFileError
        If the text is not TOML or does not describe a valid world.
    """
    if isinstance(text_or_mapping, str):
        try:
            doc: Mapping[str, Any] = tomllib.loads(text_or_mapping)
        except tomllib.TOMLDecodeError as exc:
            raise WorldFileError(path, "not valid TOML: " + " ".join(str(exc).split())) from None
    else:
        doc = text_or_mapping
    return _parse_mapping(doc, path)


def load_world(path: str | Path) -> World:
    """Read and parse a world file.

    Parameters
    ----------
    path
        A TOML world file (UTF-8).

    Returns
    -------
    World
        Named after ``name`` in the file, else after the file's stem.

    Raises
    ------
    WorldFileError
        If the file cannot be read, is not TOML, or does not describe a valid world.
    """
    try:
        data = Path(path).read_bytes()
    except FileNotFoundError:
        raise WorldFileError(path, "no such file") from None
    except OSError as exc:
        raise WorldFileError(path, f"cannot read: {exc.strerror or type(exc).__name__}") from None
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise WorldFileError(path, f"not UTF-8 text (byte {exc.start})") from None
    return parse_world(text, path)
