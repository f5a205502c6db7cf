"""Synthetic scenes for the tracker's tests: walls and cylinders (some moving), a vehicle whose
wheel odometry drifts with a covariance the test knows, a head that pans, ray-cast scans and
features drawn from the truth with known noise.

Odometry: ``odom_{k+1} = odom_k ⊕ (u_k + n_k)``, ``u_k`` the true motion in the vehicle
frame over the step and ``n_k ~ N(0, diag(a·ds, a·ds, b·ds))`` (along, across, yaw) for a
step of length ``ds``: a random walk in the vehicle frame, propagated as
``Σ_{k+1} = F·Σ_k·Fᵀ + G·N·Gᵀ`` (F: the pose-composition Jacobian, G: the noise rotated into
``odom``), as real dead reckoning is. ``a = (2 cm)²/m`` and ``b = (1.5°)²/m``: after 10 m,
σ ≈ 6 cm and 4.7° (wheel odometry of about 1-2 % of distance, ~3°/m heading at worst).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from agent.arrays import FloatArray, wrap_angle
from agent.tracking.geometry import rotation
from agent.tracking.poses import PoseSample
from agent.tracking.tracker import (
    KIND_CORNER,
    KIND_CYLINDER,
    KIND_SEGMENT,
    FeatureBatch,
    ScanView,
)

MOUNT_X_M = 0.30
N_BEAMS = 256
HALF_WINDOW_RAD = math.radians(20.0)
MIN_RANGE_M, MAX_RANGE_M = 0.4, 2.5
CORNER_SIGMA_M = 0.01
CYLINDER_SIGMA_M = 0.01
RADIUS_SIGMA_M = 0.005
ALPHA_SIGMA_RAD = 0.005
RHO_SIGMA_M = 0.005
SWEEP_RATE_RAD_S = math.radians(40.0) / 0.1  # as the sensor's (TrackerSettings)


def beam_times(t: float, scan_angle_rad: FloatArray) -> FloatArray:
    """Each beam's time: the sweep runs at ``SWEEP_RATE_RAD_S`` and ends at ``t``."""
    return np.asarray(t - np.abs(scan_angle_rad[-1] - scan_angle_rad) / SWEEP_RATE_RAD_S)


@dataclass
class Scene:
    """Truth in the world frame. ``walls`` (w, 2, 2); ``corners`` (c, 2) (the truth of corner
    features; the walls make them visible); ``pillars`` (p, 3) static (cx, cy, r);
    ``movers``: functions t ↦ (x, y, vx, vy) with a radius each."""

    walls: FloatArray = field(default_factory=lambda: np.zeros((0, 2, 2)))
    corners: FloatArray = field(default_factory=lambda: np.zeros((0, 2)))
    pillars: FloatArray = field(default_factory=lambda: np.zeros((0, 3)))
    movers: list[tuple[Callable[[float], FloatArray], float]] = field(default_factory=list)

    def circles(self, t: float) -> FloatArray:
        ms = [np.array([*f(t)[:2], r]) for f, r in self.movers]
        return np.vstack([self.pillars, *ms]) if ms else self.pillars


def corner_walls(apex: tuple[float, float], toward: float, arm_m: float = 0.6) -> FloatArray:
    """Two walls meeting at ``apex`` in a right angle that opens toward bearing ``toward``."""
    ax, ay = apex
    walls = []
    for s in (-1.0, 1.0):
        a = toward + s * math.pi / 4
        walls.append([[ax, ay], [ax + arm_m * math.cos(a), ay + arm_m * math.sin(a)]])
    return np.array(walls)


def compose(p: FloatArray, u: FloatArray) -> FloatArray:
    """Pose ``p`` ⊕ relative motion ``u`` (both x, y, yaw)."""
    c, s = math.cos(p[2]), math.sin(p[2])
    return np.array([p[0] + c * u[0] - s * u[1], p[1] + s * u[0] + c * u[1], p[2] + u[2]])


def relative(p: FloatArray, q: FloatArray) -> FloatArray:
    """The motion ``u`` with ``p ⊕ u = q``."""
    d = rotation(float(p[2])).T @ (q[:2] - p[:2])
    return np.array([d[0], d[1], float(wrap_angle(np.array(q[2] - p[2])))])


@dataclass
class Odometry:
    """The drifting odometry of a true trajectory (module docstring)."""

    rng: np.random.Generator
    a_m: float = 0.02**2  # m² per m travelled, along and across
    b_rad2_per_m: float = math.radians(1.5) ** 2
    noise: bool = True
    pose: FloatArray = field(default_factory=lambda: np.zeros(3))
    cov: FloatArray = field(default_factory=lambda: np.zeros((3, 3)))
    true_pose: FloatArray | None = None

    def step(self, true_pose: FloatArray) -> None:
        if self.true_pose is None:
            self.true_pose = true_pose.copy()
            self.pose = true_pose.copy()
            return
        u = relative(self.true_pose, true_pose)
        self.true_pose = true_pose.copy()
        ds = math.hypot(u[0], u[1]) + 0.3 * abs(u[2])  # turning on the spot slips too
        N = np.diag([self.a_m * ds, self.a_m * ds, self.b_rad2_per_m * ds])
        n = self.rng.multivariate_normal(np.zeros(3), N) if self.noise else np.zeros(3)
        new = compose(self.pose, u + n)
        d = new[:2] - self.pose[:2]
        F = np.array([[1.0, 0.0, -d[1]], [0.0, 1.0, d[0]], [0.0, 0.0, 1.0]])
        G = np.eye(3)
        G[:2, :2] = rotation(float(self.pose[2]))
        self.cov = F @ self.cov @ F.T + G @ N @ G.T
        self.pose = new

    def to_odom(self, world_xy: FloatArray) -> FloatArray:
        """World points (k, 2) in ``odom`` now: odom pose ∘ true pose⁻¹."""
        assert self.true_pose is not None
        base = (world_xy - self.true_pose[:2]) @ rotation(float(self.true_pose[2]))
        return np.asarray(base @ rotation(float(self.pose[2])).T + self.pose[:2])

    def sample(self) -> PoseSample:
        return PoseSample(self.pose.copy(), self.cov.copy(), 0.0)


def to_base(pose: FloatArray, xy: FloatArray) -> FloatArray:
    return np.asarray((xy - pose[:2]) @ rotation(float(pose[2])))


def cast(
    pose: FloatArray, scene: Scene, t: float, pan: float, window: tuple[float, float]
) -> tuple[ScanView, FloatArray]:
    """A ray-cast scan from the true ``pose`` (range noise-free; the tracker reads only
    ranges for visibility), each beam meeting the movers where they are at its own time
    (:func:`beam_times`; the vehicle is taken where it is at ``t``, as a motion-compensated
    scan puts it). Returns the scan and each beam's hit object: wall index, or
    ``1000 + circle index``, or -1."""
    n = max(2, round(N_BEAMS * (window[1] - window[0]) / (2 * HALF_WINDOW_RAD)))
    theta = np.linspace(window[0], window[1], n)
    h = pan + theta
    hx, hy = np.cos(h), np.sin(h)
    origin = np.array([MOUNT_X_M, 0.0])
    best = np.full(n, np.inf)
    hit = np.full(n, -1)
    walls = scene.walls
    if walls.size:
        p0 = to_base(pose, walls[:, 0])
        p1 = to_base(pose, walls[:, 1])
        ex, ey = (p1 - p0)[:, 0], (p1 - p0)[:, 1]
        wx, wy = (p0 - origin)[:, 0], (p0 - origin)[:, 1]
        den = hx[:, None] * (-ey[None]) - hy[:, None] * (-ex[None])
        with np.errstate(divide="ignore", invalid="ignore"):
            tt = (wx[None] * (-ey[None]) - wy[None] * (-ex[None])) / den
            ss = (hx[:, None] * wy[None] - hy[:, None] * wx[None]) / den
        ok = np.isfinite(tt) & (tt > 0) & (ss >= 0) & (ss <= 1)
        tt = np.where(ok, tt, np.inf)
        j = np.argmin(tt, axis=1)
        tb = tt[np.arange(n), j]
        better = tb < best
        best = np.where(better, tb, best)
        hit = np.where(better, j, hit)
    if scene.circles(t).size:
        per_beam = np.stack([scene.circles(tb) for tb in beam_times(t, theta)])  # (n, c, 3)
        c = to_base(pose, per_beam[..., :2].reshape(-1, 2)).reshape(n, -1, 2) - origin
        r = per_beam[..., 2]
        b = hx[:, None] * c[..., 0] + hy[:, None] * c[..., 1]
        disc = b * b - ((c * c).sum(axis=2) - r * r)
        with np.errstate(invalid="ignore"):
            tt = np.where(disc >= 0, b - np.sqrt(disc), np.inf)
        tt = np.where(tt > 0, tt, np.inf)
        j = np.argmin(tt, axis=1)
        tb = tt[np.arange(n), j]
        better = tb < best
        best = np.where(better, tb, best)
        hit = np.where(better, 1000 + j, hit)
    valid = (best >= MIN_RANGE_M) & (best <= MAX_RANGE_M)
    flag = np.where(valid, 0, np.where(np.isfinite(best), 3, 1)).astype(np.uint8)
    rng_m = np.where(np.isfinite(best), best, np.nan)
    pts = origin + rng_m[:, None] * np.stack([hx, hy], axis=1)
    pts[~valid] = np.nan
    scan = ScanView(
        points_xy=pts,
        origin_xy=np.tile(origin, (n, 1)),
        scan_angle_rad=theta,
        range_m=np.where(valid | (flag == 3), rng_m, np.nan),
        flag=flag,
    )
    return scan, np.where(valid, hit, -1)


@dataclass
class Detection:
    """Which truth object a feature came from: ("corner"|"pillar"|"mover"|"wall", index)."""

    what: str
    index: int


def features(
    pose: FloatArray,
    scene: Scene,
    t: float,
    scan: ScanView,
    hits: FloatArray,
    rng: np.random.Generator,
    min_points: int = 8,
) -> tuple[FeatureBatch, list[Detection]]:
    """Features drawn from the truth for the objects the scan hit with ``min_points`` beams
    or more (corners: both walls hit near the apex), in ``base_link`` with known noise; a
    cylinder where it was at the mean time of the beams that hit it."""
    kinds: list[int] = []
    params: list[FloatArray] = []
    covs: list[FloatArray] = []
    ends: list[FloatArray] = []
    det: list[Detection] = []
    pts = scan.points_xy
    circles = scene.circles(t)
    for j in range(circles.shape[0]):
        if (hits == 1000 + j).sum() < min_points:
            continue
        times = beam_times(t, scan.scan_angle_rad)[hits == 1000 + j]
        t_f = float(times.mean())
        c = to_base(pose, scene.circles(t_f)[j : j + 1, :2])[0]
        cov = np.diag([CYLINDER_SIGMA_M**2, CYLINDER_SIGMA_M**2, RADIUS_SIGMA_M**2])
        z = np.array([*c, circles[j, 2]]) + rng.multivariate_normal(np.zeros(3), cov)
        # A circle fitted to samples of a mover taken over a spread of times errs along its
        # motion by about the speed times that spread (the tracker's model of it:
        # agent.tracking.tracker.feature_times).
        np_ = scene.pillars.shape[0]
        if j >= np_:
            v = scene.movers[j - np_][0](t_f)[2:4] @ rotation(float(pose[2]))
            z[:2] += v * float(times.std()) * rng.standard_normal()
        kinds.append(KIND_CYLINDER)
        params.append(z)
        covs.append(cov)
        ends.append(np.full((2, 2), np.nan))
        np_ = scene.pillars.shape[0]
        det.append(Detection("pillar", j) if j < np_ else Detection("mover", j - np_))
    for w in range(scene.walls.shape[0]):
        on = np.flatnonzero(hits == w)
        if on.size < min_points:
            continue
        p0, p1 = to_base(pose, scene.walls[w, 0:1])[0], to_base(pose, scene.walls[w, 1:2])[0]
        d = p1 - p0
        nrm = np.array([d[1], -d[0]]) / np.hypot(*d)
        rho = float(nrm @ p0)
        if rho < 0:
            nrm, rho = -nrm, -rho
        alpha = math.atan2(nrm[1], nrm[0])
        cov = np.diag([ALPHA_SIGMA_RAD**2, RHO_SIGMA_M**2])
        z = np.array([alpha, rho]) + rng.multivariate_normal(np.zeros(2), cov)
        tang = np.array([-math.sin(z[0]), math.cos(z[0])])
        foot = z[1] * np.array([math.cos(z[0]), math.sin(z[0])])
        e = np.array([foot + (pts[i] @ tang) * tang for i in (on[0], on[-1])])
        kinds.append(KIND_SEGMENT)
        params.append(np.array([z[0], z[1], np.nan]))
        c3 = np.full((3, 3), np.nan)
        c3[:2, :2] = cov
        covs.append(c3)
        ends.append(e)
        det.append(Detection("wall", w))
    for c in range(scene.corners.shape[0]):
        apex = scene.corners[c : c + 1]
        ab = to_base(pose, apex)[0]
        near = np.isfinite(pts).all(axis=1) & (np.hypot(*(pts - ab).T) < 0.15)
        if near.sum() < min_points:
            continue
        # Both walls of the corner seen near the apex.
        walls_hit = {int(h) for h in hits[near]}
        if len(walls_hit) < 2:
            continue
        cov = np.diag([CORNER_SIGMA_M**2, CORNER_SIGMA_M**2])
        z = ab + rng.multivariate_normal(np.zeros(2), cov)
        kinds.append(KIND_CORNER)
        params.append(np.array([z[0], z[1], np.nan]))
        c3 = np.full((3, 3), np.nan)
        c3[:2, :2] = cov
        covs.append(c3)
        ends.append(np.full((2, 2), np.nan))
        det.append(Detection("corner", c))
    k = len(kinds)
    batch = FeatureBatch(
        kind=np.array(kinds, dtype=np.uint8),
        params=np.array(params).reshape(k, 3) if k else np.zeros((0, 3)),
        covariance=np.array(covs).reshape(k, 3, 3) if k else np.zeros((0, 3, 3)),
        endpoints=np.array(ends).reshape(k, 2, 2) if k else np.zeros((0, 2, 2)),
        reflectivity=np.ones(k),
    )
    return batch, det


def ring_scene() -> Scene:
    """Three right-angled corners (two 0.6 m walls each) at 3.3 m and three 0.1 m pillars at
    3.2 m around the origin, alternating every 60°."""
    walls, corners, pillars = [], [], []
    for i in range(6):
        b = 2 * math.pi * i / 6
        if i % 2 == 0:
            apex = (3.3 * math.cos(b), 3.3 * math.sin(b))
            walls.append(corner_walls(apex, b + math.pi))
            corners.append(apex)
        else:
            pillars.append([3.2 * math.cos(b), 3.2 * math.sin(b), 0.1])
    return Scene(np.concatenate(walls), np.array(corners), np.array(pillars))


@dataclass
class DriveResult:
    """Per truth object (("corner"|"pillar", index)): the track ids that followed it, and
    the 2-dof position NEES of its confirmed track at every scan (coasting included)."""

    ids: dict[tuple[str, int], set[int]]
    nees: dict[str, list[float]]
    sq_error: dict[str, list[float]]
    odometry_sigma: FloatArray
    distance_m: float


def drive_circle(
    seed: int, scans: int = 300, speed_m_s: float = 0.5, radius_m: float = 2.0
) -> DriveResult:
    """The vehicle drives a circle inside :func:`ring_scene`, its head sweeping outward
    (pan -60° ± 80° over 4 s), odometry drifting; the tracker follows the scene. This
    odometry is a random walk (module docstring), so the tracker is told so
    (``systematic_drift`` off: :meth:`agent.tracking.tracker.Tracker._drift_increment`)."""
    from agent.tracking.tracker import STATUS_TENTATIVE, Tracker, TrackerSettings

    rng = np.random.default_rng(seed)
    scene = ring_scene()
    odo = Odometry(rng)
    tracker = Tracker(TrackerSettings(systematic_drift=False))
    result = DriveResult({}, {"corner": [], "pillar": []}, {"corner": [], "pillar": []},
                         np.zeros(3), 0.0)  # fmt: skip
    for k in range(scans):
        t = 0.1 * k
        ang = speed_m_s * t / radius_m
        true = np.array([radius_m * math.cos(ang), radius_m * math.sin(ang), ang + math.pi / 2])
        odo.step(true)
        pan = float(np.clip(math.radians(80) * math.sin(2 * math.pi * t / 4) - math.radians(60),
                            -math.pi / 2, math.pi / 2))  # fmt: skip
        scan, hits = cast(true, scene, t, pan, (-HALF_WINDOW_RAD, HALF_WINDOW_RAD))
        batch, _ = features(true, scene, t, scan, hits, rng)
        ts = tracker.update(round(t * 1e9), odo.sample(), batch, scan)
        truth = {"corner": odo.to_odom(scene.corners), "pillar": odo.to_odom(scene.pillars[:, :2])}
        for i in range(len(ts)):
            name = {KIND_CORNER: "corner", KIND_CYLINDER: "pillar"}.get(int(ts.kind[i]))
            if name is None or ts.status[i] == STATUS_TENTATIVE:
                continue
            d = np.hypot(*(truth[name] - ts.state[i, :2]).T)
            j = int(np.argmin(d))
            if d[j] > 0.5:
                continue
            result.ids.setdefault((name, j), set()).add(int(ts.track_id[i]))
            e = ts.state[i, :2] - truth[name][j]
            result.nees[name].append(float(e @ np.linalg.solve(ts.covariance[i, :2, :2], e)))
            result.sq_error[name].append(float(e @ e))
    result.odometry_sigma = np.sqrt(np.diag(odo.cov))
    result.distance_m = speed_m_s * 0.1 * (scans - 1)
    return result
