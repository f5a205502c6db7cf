"""A tiny closed loop for the controller's tests: a unicycle and perfect environment vectors.

The vehicle integrates the commanded twist exactly (a circular arc per step), its speed and
yaw rate changing no faster than the :class:`VehicleSpec` accelerations allow and clamped to
its limits; the odometry is the true pose (no drift). Environment vectors come straight from
the known geometry, not from the sensor simulation:

* obstacles exactly where they are, with 1 cm position σ (1 cm/s velocity σ); an obstacle
  joins the vector once a ray of the scanned window has hit it within the depth of field
  (0.4-2.5 m) and stays (a perfect tracker that coasts for ever), or from the start with
  ``all_known``;
* the free-space profile: for each 1° bearing within ±``window_deg`` of the heading, from
  the centre of scanning, the smallest distance to a surface over three rays (the sector's
  centre and edges), less 3 cm, at most 2.5 m; 0 when a surface is nearer than 0.4 m (too
  near to see) or when the clear distance ends within the vehicle's outline; 0 elsewhere.

Times: physics every 10 ms, odometry every 20 ms, a vector every 100 ms (stamped when made,
valid for 0.3 s), a command every 50 ms.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field

import numpy as np

from agent.arrays import FloatArray
from agent.control.controller import Controller, ControllerSettings, ControlOutput
from agent.control.geometry import point_segment_distance
from agent.control.view import EnvironmentView
from agent.kinematics.vehicle import VehicleSpec
from agent.task import Task

# The controller told that the base's odometry does not drift (the harness's is the truth).
NO_DRIFT = {"drift_ratio_rad_per_m": 0.0, "drift_track_per_rad": 0.0, "drift_slip_rad2_per_m": 0.0}

DT = 0.01
ODOMETRY_EVERY = 2
VECTOR_EVERY = 10
COMMAND_EVERY = 5


@dataclass
class Mover:
    """A disc walking back and forth between ``a`` and ``b`` at ``speed``, from ``a`` at
    ``start_s``; still before it."""

    a: tuple[float, float]
    b: tuple[float, float]
    radius: float
    speed: float
    start_s: float = 0.0

    def state(self, t: float) -> tuple[FloatArray, FloatArray]:
        a, b = np.array(self.a), np.array(self.b)
        length = float(np.hypot(*(b - a)))
        u = (b - a) / length
        s = max(t - self.start_s, 0.0) * self.speed
        lap = s % (2 * length)
        moving = t >= self.start_s
        if lap <= length:
            return a + lap * u, u * self.speed * moving
        return b - (lap - length) * u, -u * self.speed * moving


@dataclass
class Scene:
    """Walls (segments), cylinders, movers and docking plates (segments, kind 4)."""

    segments: list[tuple[tuple[float, float], tuple[float, float]]] = field(default_factory=list)
    cylinders: list[tuple[float, float, float]] = field(default_factory=list)
    movers: list[Mover] = field(default_factory=list)
    plates: list[tuple[tuple[float, float], tuple[float, float]]] = field(default_factory=list)

    def box(self, cx: float, cy: float, sx: float, sy: float) -> None:
        c = [(cx - sx / 2, cy - sy / 2), (cx + sx / 2, cy - sy / 2),
             (cx + sx / 2, cy + sy / 2), (cx - sx / 2, cy + sy / 2)]  # fmt: skip
        for i in range(4):
            self.segments.append((c[i], c[(i + 1) % 4]))


def start_clearance(
    scene: Scene, pose: tuple[float, float, float], spec: VehicleSpec, most_m: float = 0.42
) -> float:
    """What ``scene`` keeps clear of the vehicle's turning circle at ``pose`` (walls, plates
    and cylinders; at most ``most_m``), less 2 cm: the controller's ``start_clear_m`` for
    the scene, as the random worlds promise theirs."""
    centre = np.array(pose[:2], dtype=np.float64)
    segments = np.array([*scene.segments, *scene.plates], dtype=np.float64).reshape(-1, 2, 2)
    cylinders = np.array(scene.cylinders, dtype=np.float64).reshape(-1, 3)
    nearest = min(
        np.min(point_segment_distance(centre, segments[:, 0], segments[:, 1]), initial=np.inf),
        np.min(np.hypot(*(cylinders[:, :2] - centre).T) - cylinders[:, 2], initial=np.inf),
    )
    gap = min(float(nearest) - spec.circumradius_m, most_m + 0.02)
    return max(gap - 0.02, 1e-3)


@dataclass
class Record:
    t: list[float] = field(default_factory=list)
    pose: list[FloatArray] = field(default_factory=list)
    twist: list[tuple[float, float]] = field(default_factory=list)
    outputs: list[ControlOutput] = field(default_factory=list)
    min_clearance_m: float = math.inf
    collided: bool = False
    collided_moving: bool = False
    arrived_s: float | None = None


class Harness:
    """The closed loop (module docstring)."""

    def __init__(
        self,
        scene: Scene,
        task: Task,
        pose: tuple[float, float, float] = (0.0, 0.0, 0.0),
        planner: str = "default",
        settings: ControllerSettings | None = None,
        window_deg: float = 20.0,
        all_known: bool = False,
        spec: VehicleSpec | None = None,
    ) -> None:
        self.scene = scene
        self.spec = spec or VehicleSpec()
        if settings is None:  # tell the controller what the scene keeps clear at the start
            settings = ControllerSettings(start_clear_m=start_clearance(scene, pose, self.spec))
        # The harness's odometry is the true pose: a base that does not drift.
        settings = dataclasses.replace(settings, **NO_DRIFT)
        self.controller = Controller(task, self.spec, settings, planner=planner)  # type: ignore[arg-type]
        self.pose = np.array(pose, dtype=np.float64)
        self.v = self.w = 0.0
        self.command = (0.0, 0.0)
        self.window_deg = window_deg
        n_seg = len(scene.segments) + len(scene.plates)
        n_obj = n_seg + len(scene.cylinders) + len(scene.movers)
        self.seen = np.full(n_obj, all_known)
        self.tick = 0
        self.record = Record()
        self.sensor_ok = True
        self.deliver_vectors = True

    @property
    def t(self) -> float:
        return self.tick * DT

    # ------------------------------------------------------------------ geometry
    def _segments(self) -> FloatArray:
        segs = self.scene.segments + self.scene.plates
        return np.array(segs, dtype=np.float64).reshape(-1, 2, 2)

    def _circles(self, t: float) -> FloatArray:
        rows = [list(c) for c in self.scene.cylinders]
        for m in self.scene.movers:
            p, _ = m.state(t)
            rows.append([p[0], p[1], m.radius])
        return np.array(rows, dtype=np.float64).reshape(-1, 3)

    def cast(
        self, origin: FloatArray, angles: FloatArray, t: float
    ) -> tuple[FloatArray, FloatArray]:
        """Distance along rays from ``origin`` to the first surface (inf if none) and the
        index of what it hits (segments, then circles; −1 if nothing)."""
        d = np.stack([np.cos(angles), np.sin(angles)], 1)
        best = np.full(angles.size, np.inf)
        who = np.full(angles.size, -1)
        segs = self._segments()
        if len(segs):
            a, b = segs[:, 0], segs[:, 1]
            e = b - a
            den = d[:, None, 0] * e[None, :, 1] - d[:, None, 1] * e[None, :, 0]
            ao = a[None] - origin
            with np.errstate(divide="ignore", invalid="ignore"):
                t_ray = (ao[..., 0] * e[None, :, 1] - ao[..., 1] * e[None, :, 0]) / den
                s_seg = (ao[..., 0] * d[:, None, 1] - ao[..., 1] * d[:, None, 0]) / den
            ok = (np.abs(den) > 1e-12) & (t_ray > 0) & (s_seg >= 0) & (s_seg <= 1)
            t_ray = np.where(ok, t_ray, np.inf)
            j = np.argmin(t_ray, axis=1)
            tj = t_ray[np.arange(angles.size), j]
            better = tj < best
            best = np.where(better, tj, best)
            who = np.where(better, j, who)
        circles = self._circles(t)
        if len(circles):
            oc = origin - circles[:, :2]
            bq = d @ oc.T
            cq = np.sum(oc * oc, axis=1) - circles[:, 2] ** 2
            disc = bq * bq - cq[None]
            root = -bq - np.sqrt(np.maximum(disc, 0.0))
            root = np.where((disc >= 0) & (root > 0), root, np.inf)
            j = np.argmin(root, axis=1)
            tj = root[np.arange(angles.size), j]
            better = tj < best
            best = np.where(better, tj, best)
            who = np.where(better, len(segs) + j, who)
        return best, who

    def clearance(self, t: float) -> float:
        """Smallest distance between the outline and any surface (≤ 0: touching)."""
        x, y, yaw = self.pose
        c, s = math.cos(yaw), math.sin(yaw)
        hx, hy = 0.5 * self.spec.length_m, 0.5 * self.spec.width_m

        def to_body(p: FloatArray) -> FloatArray:
            dx, dy = p[..., 0] - x, p[..., 1] - y
            return np.stack([c * dx + s * dy, -s * dx + c * dy], -1)

        def rect_dist(q: FloatArray) -> FloatArray:
            ex = np.maximum(np.abs(q[..., 0]) - hx, 0.0)
            ey = np.maximum(np.abs(q[..., 1]) - hy, 0.0)
            inside = (np.abs(q[..., 0]) <= hx) & (np.abs(q[..., 1]) <= hy)
            return np.where(inside, -1.0, np.hypot(ex, ey))

        best = math.inf
        segs = self._segments()
        if len(segs):
            f = np.linspace(0.0, 1.0, 400)[None, :, None]
            pts = segs[:, None, 0] + f * (segs[:, None, 1] - segs[:, None, 0])
            best = min(best, float(rect_dist(to_body(pts)).min()))
        circles = self._circles(t)
        if len(circles):
            q = to_body(circles[:, :2])
            best = min(best, float((rect_dist(q) - circles[:, 2]).min()))
        return best

    # ------------------------------------------------------------------ the vector
    def vector(self, t: float) -> EnvironmentView:
        x, y, yaw = self.pose
        h = self.spec.head_offset_m
        head = np.array([x + h * math.cos(yaw), y + h * math.sin(yaw)])
        bearings_deg = np.arange(-180, 180)
        ranges = np.zeros(360)
        lit = np.abs(bearings_deg) <= self.window_deg
        centres = np.radians(bearings_deg[lit])
        rays = (centres[:, None] + np.radians([-0.5, 0.0, 0.5])[None]).ravel()
        dist, who = self.cast(head, yaw + rays, t)
        seen_now = (dist >= 0.4) & (dist <= 2.5) & (who >= 0)
        self.seen[who[seen_now]] = True
        dist = dist.reshape(-1, 3)
        near = dist.min(axis=1)
        r = np.minimum(near - 0.03, 2.5)
        r = np.where(near < 0.4, 0.0, r)
        # Clear no further than the outline: unknown.
        edge = (0.5 * self.spec.length_m - h) / np.maximum(np.cos(centres), 1e-6)
        edge = np.minimum(edge, 0.5 * self.spec.width_m / np.maximum(np.abs(np.sin(centres)), 1e-6))
        r = np.where(r <= edge, 0.0, r)
        ranges[lit] = np.maximum(r, 0.0)
        return self._view(t, ranges)

    def _view(self, t: float, ranges: FloatArray) -> EnvironmentView:
        ids, kinds, pos, vel, ext = [], [], [], [], []
        segs = self.scene.segments + self.scene.plates
        n_plain = len(self.scene.segments)
        for i, (a, b) in enumerate(segs):
            if self.seen[i]:
                ids.append(i)
                kinds.append(4 if i >= n_plain else 0)
                pos.append(((a[0] + b[0]) / 2, (a[1] + b[1]) / 2))
                vel.append((0.0, 0.0))
                ext.append((a[0], a[1], b[0], b[1]))
        base = len(segs)
        for j, (cx, cy, r) in enumerate(self.scene.cylinders):
            if self.seen[base + j]:
                ids.append(base + j)
                kinds.append(3)
                pos.append((cx, cy))
                vel.append((0.0, 0.0))
                ext.append((r, 0.0, 0.0, 0.0))
        base += len(self.scene.cylinders)
        for j, m in enumerate(self.scene.movers):
            if self.seen[base + j]:
                p, v = m.state(t)
                ids.append(base + j)
                kinds.append(3)
                pos.append(tuple(p))
                vel.append(tuple(v))
                ext.append((m.radius, 0.0, 0.0, 0.0))
        k = len(ids)
        cov = np.tile(np.diag([1e-4, 1e-4, 1e-4, 1e-4]), (k, 1, 1))
        return EnvironmentView(
            stamp_s=t, valid_for_s=0.3, sensor_ok=self.sensor_ok,
            obstacle_id=np.array(ids, dtype=np.int64), kind=np.array(kinds, dtype=np.uint8),
            position_xy=np.array(pos, dtype=np.float64).reshape(k, 2),
            velocity_xy=np.array(vel, dtype=np.float64).reshape(k, 2),
            covariance=cov, extent=np.array(ext, dtype=np.float64).reshape(k, 4),
            reflectivity=np.where(np.array(kinds) == 4, 3.0, 1.0).astype(np.float64),
            free_bearing_rad=np.radians(np.arange(-180, 180, dtype=np.float64)),
            free_range_m=ranges,
        )  # fmt: skip

    # ------------------------------------------------------------------ the loop
    def step(self) -> None:
        t = self.t
        ctl = self.controller
        if self.tick % ODOMETRY_EVERY == 0:
            ctl.update_odometry(t, self.pose.copy(), np.eye(3) * 1e-6, self.v, self.w)
        if self.tick % VECTOR_EVERY == 0 and self.deliver_vectors:
            ctl.update_environment(self.vector(t))
        if self.tick % COMMAND_EVERY == 0:
            out = ctl.command(t)
            self.command = (out.speed_m_s, out.yaw_rate_rad_s)
            rec = self.record
            rec.t.append(t)
            rec.pose.append(self.pose.copy())
            rec.twist.append((self.v, self.w))
            rec.outputs.append(out)
            if out.arrived and rec.arrived_s is None:
                rec.arrived_s = t
        self._integrate()
        gap = self.clearance(self.t)
        rec = self.record
        rec.min_clearance_m = min(rec.min_clearance_m, gap)
        if gap <= 0.0:
            rec.collided = True
            rec.collided_moving |= abs(self.v) > self.spec.moving_speed_m_s
        self.tick += 1

    def _integrate(self) -> None:
        spec = self.spec
        v_cmd = max(-spec.max_speed_m_s, min(spec.max_speed_m_s, self.command[0]))
        w_cmd = max(-spec.max_yaw_rate_rad_s, min(spec.max_yaw_rate_rad_s, self.command[1]))
        dv, dw = spec.max_accel_m_s2 * DT, spec.max_yaw_accel_rad_s2 * DT
        self.v = min(max(v_cmd, self.v - dv), self.v + dv)
        self.w = min(max(w_cmd, self.w - dw), self.w + dw)
        x, y, yaw = self.pose
        if abs(self.w) < 1e-9:
            x += self.v * DT * math.cos(yaw)
            y += self.v * DT * math.sin(yaw)
        else:
            y2 = yaw + self.w * DT
            x += self.v / self.w * (math.sin(y2) - math.sin(yaw))
            y -= self.v / self.w * (math.cos(y2) - math.cos(yaw))
            yaw = y2
        self.pose = np.array([x, y, math.remainder(yaw, math.tau)])

    def run(self, until_s: float, stop_on_arrival: bool = True) -> Record:
        while self.t < until_s:
            self.step()
            if stop_on_arrival and self.record.arrived_s is not None:
                break
        return self.record
