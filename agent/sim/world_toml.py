"""A world and its task as world-file TOML text (:mod:`agent.sim.world_file` reads it back).

Frames follow REP-103; metres; degrees only in the keys named ``*_deg``, as the file format
has them.

Numbers are written with ``repr``, which gives back the same float when read, so
:func:`~agent.sim.world_file.parse_world` gives back the same walls, cylinders, movers,
positions and task values bit for bit. Angles are radians inside and degrees in the file:
``math.radians(math.degrees(a))`` differs from ``a`` by an ulp in about one case in seven
(neighbouring degree values map more than an ulp apart in radians, so no degree value need
give ``a`` back), which moves a box's corners by about 1e-16 m.

A world cut down by :meth:`~agent.sim.world.World.nearby` is written with what it holds;
read back, its obstacles are numbered afresh.
"""

from __future__ import annotations

import json
import math
from collections.abc import Iterable

import numpy as np

from agent.sim.world import World
from agent.task import Task

__all__ = ["world_toml"]


def _num(value: float) -> str:
    text = repr(float(value))
    if not math.isfinite(float(value)):
        raise ValueError(f"world_toml: a value is not finite: {text}")
    return text


def _pair(xy: Iterable[float]) -> str:
    x, y = (float(v) for v in xy)
    return f"[{_num(x)}, {_num(y)}]"


def _points(points: Iterable[Iterable[float]]) -> str:
    return "[" + ", ".join(_pair(p) for p in points) + "]"


def _string(text: str) -> str:
    """A TOML basic string: JSON's escapes are TOML's, bar DEL, which TOML wants escaped."""
    return json.dumps(text, ensure_ascii=False).replace("\x7f", "\\u007f")


def _task_lines(task: Task) -> list[str]:
    lines = ["[task]", f"kind = {_string(task.kind)}", f"goal = {_pair(task.goal)}"]
    if task.kind == "park" and task.goal_yaw_rad is not None:
        lines.append(f"goal_yaw_deg = {_num(math.degrees(task.goal_yaw_rad))}")
    lines.append(f"tolerance_m = {_num(task.tolerance_m)}")
    if task.kind == "park":
        lines.append(f"tolerance_deg = {_num(math.degrees(task.tolerance_rad))}")
    lines.append(f"time_limit_s = {_num(task.time_limit_s)}")
    if task.kind == "dock":
        lines.append(f"dock_distance_m = {_num(task.dock_distance_m)}")
    return lines


def world_toml(world: World, task: Task | None = None) -> str:
    """``world`` and ``task`` as world-file text.

    Parameters
    ----------
    world
        Its name, vehicle pose, walls, boxes, cylinders and movers are written.
    task
        Written as the ``[task]`` table with the keys ``kind``, ``goal``, ``goal_yaw_deg``
        (park only), ``tolerance_m``, ``tolerance_deg`` (park only), ``time_limit_s`` and
        ``dock_distance_m`` (dock only). ``None``: the world's own
        :attr:`~agent.sim.world.World.task`, if any.

    Returns
    -------
    str
        TOML text, UTF-8 safe, ending in a newline.

    Raises
    ------
    ValueError
        If a value to write is not finite.
    """
    task = task if task is not None else world.task
    x, y, yaw = world.vehicle_pose
    lines = [
        f"name = {_string(world.name)}",
        "",
        "[vehicle]",
        f"pose = [{_num(x)}, {_num(y)}, {_num(math.degrees(yaw))}]",
    ]
    for o in world.obstacles:
        lines += ["", f"[[{o.kind}]]"]
        if o.kind == "wall":
            lines.append(f"points = {_points(o.points)}")
        elif o.kind == "box" and o.center is not None and o.size is not None:
            lines += [
                f"center = {_pair(o.center)}",
                f"size = {_pair(o.size)}",
                f"yaw_deg = {_num(math.degrees(o.yaw_rad))}",
            ]
        elif o.center is not None and o.radius is not None:
            lines += [f"center = {_pair(o.center)}", f"radius = {_num(o.radius)}"]
        lines.append(f"reflectivity = {_num(o.reflectivity)}")
    for m in world.movers:
        lines += [
            "",
            "[[mover]]",
            f"radius = {_num(m.radius_m)}",
            f"reflectivity = {_num(m.reflectivity)}",
            f"path = {_points(np.asarray(m.path).tolist())}",
            f"speed = {_num(m.speed_m_s)}",
        ]
    if task is not None:
        lines += ["", *_task_lines(task)]
    return "\n".join(lines) + "\n"
