"""World files: TOML text to a :class:`~agent.sim.world.World`.

Frames follow REP-103: x forward, y left, angles counter-clockwise; lengths in metres, and
degrees only in the keys named ``*_deg``.

World file (TOML, UTF-8, at most 1 MiB, read by :mod:`agent.toml_files`)::

    name = "optional string"            # default: the file's stem ("" for text or a mapping);
                                        # one line, at most 256 characters
    [vehicle]
    pose = [x_m, y_m, yaw_deg]          # optional; default [0, 0, 0]; yaw within ±360
    [[wall]]
    points = [[x, y], [x, y], ...]      # a simple polyline of 2 to 128 points
    reflectivity = 1.0                  # optional; 1.0 = off-white cardboard; (0, 1000]
    [[box]]
    center = [x, y]
    size = [length, width]              # along the box's own x and y axes; 1 mm to 1000 m
    yaw_deg = 0.0                       # optional; within ±360
    reflectivity = 1.0                  # optional
    [[cylinder]]
    center = [x, y]
    radius = 0.1                        # 1 mm to 1000 m
    reflectivity = 1.0                  # optional
    [[mover]]                           # a moving cylinder (agent.sim.movers)
    radius = 0.2                        # 1 mm to 1000 m
    reflectivity = 0.8                  # optional
    path = [[1.0, -1.0], [1.0, 1.5]]    # 2 to 128 waypoints, walked back and forth
    speed = 0.4                         # m/s along the path, 0 to 3
    [task]                              # optional: what the vehicle must do (agent.task)
    kind = "dock"                       # "goto", "park" or "dock"
    goal = [x, y]                       # m, world frame (dock: near the docking target)
    goal_yaw_deg = 90.0                 # park only, and required there; within ±360
    tolerance_m = 0.3                   # optional; success radius (goto, park)
    tolerance_deg = 5.0                 # optional; park's heading tolerance, at most 180
    time_limit_s = 120.0                # optional
    dock_distance_m = 0.5               # dock only, optional: the head's centre of scanning
                                        # this far from the target's face, square to it

Limits (their reasons are in :mod:`agent.sim.world_checks`): at most 10 000 obstacles, 128
points in a wall and 65 536 in all walls; every x and y within 1000 m of the origin; wall
segments at least 1 mm long; at most 64 movers, at 0 to 3 m/s, on paths of 2 to 128 points
with no two neighbours equal (all equal, a mover standing still, only at speed 0). A wall may
not meet itself: segments that are not neighbours may not cross or touch, and neighbours may
not turn back along each other; a wall whose last point repeats its first is closed (a
polygon, such as a room's outline).

Every problem in a world raises :class:`~agent.errors.WorldFileError` with a one-line message
naming the file and the entry (entries are numbered from 1), e.g.
``world file w.toml: [[box]] 2: size must be two positive numbers, got [0.4, -1]`` or
``world file w.toml: [[wall]] 3: segments 1 and 4 cross`` (segment ``j`` joins points ``j``
and ``j + 1``). Unreadable, oversized, non-UTF-8 and non-TOML files, and TOML nested too deeply
to parse, are refused the same way.

A ``[task]`` is parsed into :attr:`World.task <agent.sim.world.World.task>` (radians
inside), e.g. ``world file w.toml: [task]: goal_yaw_deg is for kind "park" only, not
"goto"``; its values must be finite and positive, its ``goal`` within 1000 m.

Obstacle ids follow the file: walls first, then boxes, then cylinders, each in file order;
movers after them all, in file order.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from agent.errors import WorldFileError
from agent.sim.movers import Mover
from agent.sim.world import ObstacleKind, Point, Pose, World, assemble_world
from agent.sim.world_checks import (
    MAX_MOVERS,
    MAX_OBSTACLES,
    MAX_TOTAL_WALL_POINTS,
    MAX_WALL_POINTS,
    WorldChecker,
    first_wall_contact,
    show_value,
)
from agent.toml_files import load_toml, parse_toml

__all__ = ["load_world", "parse_world"]

DEFAULT_REFLECTIVITY = 1.0
"""Reflectivity of an entry that gives none: off-white cardboard, the reference surface."""

_KINDS: tuple[ObstacleKind, ...] = ("wall", "box", "cylinder")
_TOP_LEVEL_KEYS = ("name", "vehicle", *_KINDS, "mover", "task")
_MOVER_KEYS = ("radius", "reflectivity", "path", "speed")
_MOVER_REQUIRED_KEYS = ("radius", "path", "speed")
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
    chk.name(name)

    pose: Pose = (0.0, 0.0, 0.0)
    if "vehicle" in doc:
        vehicle = chk.table(doc["vehicle"], "[vehicle]", _VEHICLE_KEYS)
        if "pose" in vehicle:
            x, y, yaw_deg = chk.numbers(
                vehicle["pose"], 3, "[vehicle]", "pose", "[x_m, y_m, yaw_deg]"
            )
            chk.coordinates((x, y), "[vehicle]", "pose")
            chk.angle_deg(yaw_deg, "[vehicle]", "pose's yaw_deg")
            pose = (x, y, math.radians(yaw_deg))

    raws: dict[ObstacleKind, list[Any] | tuple[Any, ...]] = {}
    for kind in _KINDS:
        raw = doc.get(kind, [])
        if not isinstance(raw, list | tuple):
            chk.fail("", f"{kind} must be an array of tables [[{kind}]], got {show_value(raw)}")
        raws[kind] = raw
    chk.count(sum(len(raw) for raw in raws.values()), MAX_OBSTACLES, "", "obstacles")
    entries: dict[ObstacleKind, list[Mapping[str, Any]]] = {}
    for kind, raw in raws.items():
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
        x = chk.positive(table.get("reflectivity", DEFAULT_REFLECTIVITY), where, "reflectivity")
        chk.reflectivity(x, where)
        return x

    def center(table: Mapping[str, Any], where: str) -> Point:
        xy = chk.point(table["center"], where, "center")
        chk.coordinates(xy, where, "center")
        return xy

    n_wall_points = 0
    for i, t in enumerate(entries["wall"]):
        if isinstance(t["points"], list | tuple):
            where = f"[[wall]] {i + 1}"
            chk.count(len(t["points"]), MAX_WALL_POINTS, where, "points")
            n_wall_points += len(t["points"])
    chk.count(n_wall_points, MAX_TOTAL_WALL_POINTS, "", "points in walls")
    wall_points = []
    walls: list[tuple[tuple[Point, ...], float]] = []
    for i, t in enumerate(entries["wall"]):
        where = f"[[wall]] {i + 1}"
        points = chk.wall(t["points"], where)
        wall_points.append(points)
        walls.append((tuple((x, y) for x, y in points.tolist()), refl(t, where)))
    contact = first_wall_contact(wall_points)
    if contact is not None:
        w, a, b, how = contact
        chk.fail(f"[[wall]] {w + 1}", f"segments {a + 1} and {b + 1} {how}")
    boxes: list[tuple[Point, Point, float, float]] = []
    for i, t in enumerate(entries["box"]):
        where = f"[[box]] {i + 1}"
        xy = center(t, where)
        size = chk.positive_pair(t["size"], where, "size")
        chk.size(size[0], where, "size's length")
        chk.size(size[1], where, "size's width")
        yaw_deg = chk.finite(t.get("yaw_deg", 0.0), where, "yaw_deg")
        chk.angle_deg(yaw_deg, where, "yaw_deg")
        boxes.append((xy, size, math.radians(yaw_deg), refl(t, where)))
    cylinders: list[tuple[Point, float, float]] = []
    for i, t in enumerate(entries["cylinder"]):
        where = f"[[cylinder]] {i + 1}"
        xy = center(t, where)
        radius = chk.positive(t["radius"], where, "radius")
        chk.size(radius, where, "radius")
        cylinders.append((xy, radius, refl(t, where)))
    movers = _movers(doc.get("mover", []), chk, refl)
    task = chk.task(doc["task"]) if "task" in doc else None
    return assemble_world(walls, boxes, cylinders, pose, name, movers, task)


def _movers(raw: Any, chk: WorldChecker, refl: Any) -> list[Mover]:
    """The ``[[mover]]`` entries, checked."""
    if not isinstance(raw, list | tuple):
        chk.fail("", f"mover must be an array of tables [[mover]], got {show_value(raw)}")
    chk.count(len(raw), MAX_MOVERS, "", "movers")
    movers = []
    for i, entry in enumerate(raw):
        where = f"[[mover]] {i + 1}"
        table = chk.table(entry, where, _MOVER_KEYS)
        for key in _MOVER_REQUIRED_KEYS:
            if key not in table:
                chk.fail(where, f"missing key {show_value(key)}")
        path, radius, speed = chk.mover(table, where, file_limits=True)
        movers.append(Mover(radius, refl(table, where), path, speed))
    return movers


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
        doc: Mapping[str, Any] = parse_toml(
            text_or_mapping, functools.partial(WorldFileError, path)
        )
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
    return _parse_mapping(load_toml(path, functools.partial(WorldFileError, path)), path)
