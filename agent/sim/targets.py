"""Target worlds for measuring the head, placed in a head-centred world.

The vehicle stands so that the centre of scanning is at the origin, looking along +x
(:func:`head_centred_pose`); targets are set out from there at known ranges.
"""

from __future__ import annotations

import math

from agent.kinematics.trajectory import StaticPose
from agent.sensor.params import SensorParameters
from agent.sim.world import World

__all__ = ["arc_world", "head_centred_pose", "plane_world", "tilted_target_world"]


def head_centred_pose(params: SensorParameters) -> StaticPose:
    """Vehicle pose that puts the centre of scanning at the world origin, facing +x."""
    return StaticPose(-params.mount_offset_m, 0.0, 0.0)


def plane_world(
    distance_m: float, half_width_m: float | None = None, reflectivity: float = 1.0
) -> World:
    """A planar cardboard target perpendicular to +x at ``distance_m`` from the origin."""
    half = half_width_m if half_width_m is not None else distance_m * math.tan(0.5) + 0.5
    return World.build(walls=[(((distance_m, -half), (distance_m, half)), reflectivity)])


def tilted_target_world(
    range_m: float, scan_angle_rad: float, half_width_m: float = 0.3, reflectivity: float = 1.0
) -> World:
    """A target at beam range ``range_m`` along scan angle θ, facing along -x like a wall ahead."""
    cx, cy = range_m * math.cos(scan_angle_rad), range_m * math.sin(scan_angle_rad)
    return World.build(walls=[(((cx, cy - half_width_m), (cx, cy + half_width_m)), reflectivity)])


def arc_world(range_m: float, reflectivity: float = 1.0) -> World:
    """A concave circular target centred on the centre of scanning: every beam has range r."""
    return World.build(cylinders=[((0.0, 0.0), range_m, reflectivity)])
