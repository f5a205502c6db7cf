"""Where the world is in ``odom``: the odometry's drift, measured on static obstacles.

The task's goal is in the world frame, which is ``odom`` as it was at the start; wheel
odometry drifts from it (the simulated base: wheel-scale, wheel-ratio and track errors fixed
for a run, and slip), most of all in heading while the vehicle turns on the spot (about 7°
a full turn at the track error's 2 %). A goal taken in ``odom`` as it stands is then where
the drift put it: measured in ``evaluate``'s random runs, vehicles that stopped on their
goal in ``odom`` were up to a metre from it in the world.

Everything the controller knows comes in ``odom`` and stays consistent there; only what is
given in the world frame (the goal, a park's heading) must be carried into it. So the
controller keeps an estimate of the transform ``E`` from the world to ``odom`` now,

    p_odom = R(θ)·p_world + t

from the static obstacles of the vector (:class:`DriftEstimate`):

* **Anchors.** A static corner or cylinder (not a mover), or a static segment, whose
  position σ is at most ``anchor_sigma_m`` when first seen is *anchored*: its place in the
  world, ``Ê⁻¹`` of where the vector puts it, with the covariance of both. A segment is
  anchored as a point on its line, the line's normal and its direction: only its place
  across the line and its direction are kept (a wall's extent grows as more of it is seen;
  its ends say nothing).
* **The estimate.** Each vector, ``(t, θ)`` is the weighted least-squares fit of the
  anchors to where the vector puts their obstacles now (Gauss-Newton from the last
  estimate): a point's residual ``z − (R·w + t)`` (2-D, covariance the vector's plus the
  anchor's), a segment's the predicted anchor point's distance from the line the vector
  gives (σ its ``across_sigma_m`` and the anchor's) and the line's direction less the
  anchor's turned by θ (σ at most ``across_sigma_m`` over half its length, the σ across
  at an end being at least the direction's times that; and the anchor's). A wall's
  direction alone gives the heading: with the across offset only, one wall in view (a
  head looking where the vehicle goes sees one or two obstacles at a time) left the
  heading unknown and the estimate still (random run 25 of seed 0, no walkers: 14° of
  drift, none of it estimated). Residuals beyond the χ² 99 % gate are left out and the
  fit redone; an anchor gated out ``drop_after`` times in a row
  is forgotten (its track took another obstacle). A prior on the last estimate keeps
  the fit defined with a single anchor: weak on the place (``prior_sigma_m``); on the
  heading, the last fit's σ grown with the motion since (``heading_growth_rad_per_m``,
  ``heading_growth_rad_per_rad``), so the estimate holds while the vehicle stands and
  follows the walls while it drives.
  Only obstacles the newest scan updated are used (the vector's ``seen_age_s``): a
  coasting track's obstacle stays where the odometry put it when it was last seen, and
  during a turn on the spot (the drift's fastest) such anchors held the estimate where it
  had been (measured on random run 18 of seed 0: 7° of drift unseen).
* **The place, dead reckoned** (``dead_reckon_place``). The anchors fit ``(t, θ)``, but
  the place kept is the vehicle's own, dead reckoned in the world: each odometry step
  between vectors turned by the heading as then estimated, ``t`` then what puts the
  vehicle there. The obstacles anchored while the estimate is already wrong carry its
  error (the drift is measured against what was seen, not against a map of the world, and
  without loop closure the anchors form a chain); in the place, that chain's error
  compounded (each anchor placed by the fit its predecessors made), where the odometry's
  steps turned by a good heading are off only by the wheels' scale error. Measured on
  ``evaluate``'s random runs 0-95 of seed 0 without walkers (``active``), the place fitted
  / dead reckoned: a goto or park that ended where the controller put its goal ended
  0.43 / 0.36 m (goto) and 0.47 / 0.32 m (park) from it in truth, on average, and 21 / 28
  of the 68 were done. Not always better: a scene of posts passed one after another,
  handed on as anchors, with a 2 % scale error, keeps the fitted place nearer (the steps
  carry the scale error whole).
* **The heading, from the place** (dead reckoned). The place being known, the fit's prior
  on ``t`` is no longer the weak one about the last estimate but what puts the vehicle at
  its dead reckoned place with the heading being fitted, ``t_DR(θ) = p_odom − R(θ)·p̂``,
  to ``place_sigma_m`` (the place's error over the few metres an anchor is in view; one
  error common to every anchor, so their places relative to one another count whole).
  With the weak prior, what a single post said (the vehicle sees one or two things at a
  time) went into ``t``, which the dead reckoning then overwrote: measured on random run
  77 of seed 0 (no walkers), the odometry's heading drifted 17° in 20 s and the
  estimate followed 1.4° of it. A post's bearing from a known place gives the heading.
* **The heading's drift** (``estimate_rates``). The wheels' systematic errors turn the
  odometry's heading by a fixed amount per metre driven (the right-minus-left scale error
  over the track: ``ratio_sigma/track_m``, 1.7°/m RMS on the simulated base, 3.4°/m at 2σ)
  and per radian turned (the track's error less the mean scale's). So the heading is the
  first of three states, ``x = (θ, a, c)``, predicted with each odometry step ``Δs`` along
  its heading and turn ``Δφ``:

      θ ← θ + a·Δs + c·Δφ,   P ← F P Fᵀ + Q,   F = [[1, Δs, Δφ], [0, 1, 0], [0, 0, 1]]

  ``Q`` the slip's random walk (``heading_noise_rad_per_sqrt_m``² per metre or radian);
  ``a``, ``c`` start at 0 with σ ``heading_growth_rad_per_m``, ``heading_growth_rad_per_rad``
  and θ at 0 exactly (the world is ``odom`` at the start). The fit's heading prior is the
  prediction; what the anchors alone said (the fit's posterior divided by that prior) is
  the measurement of θ, and through ``P``'s cross terms it corrects ``a`` and ``c``. Where
  nothing is in view the heading goes on drifting as the wheels make it drift, not held
  where it was last seen.
* **The scale** (``estimate_scale``). A static obstacle anchored at travel ``D₀`` (the
  odometry's steps turned into the world, summed) and correction ``C₀`` (the scale
  corrections applied to them) and seen now, with ``D``, ``C`` the travel and correction
  since, is off its anchor (in the world's axes) by ``r = C − δ·D`` where ``δ`` is the
  wheels' true distance per unit reading less one: each measures ``δ`` along its travel
  (a point) or across its line (a segment), once it has ``scale_min_travel_m`` of travel
  that way, with the variance of its residual over that travel squared. The estimate is
  the measurements' weighted mean with the prior ``N(0, scale_sigma²)`` (each anchor's
  latest, kept after it is forgotten), and each dead reckoned step is ``(1 + δ̂)`` times the
  odometry's. Measurements of more than ``scale_max`` are taken for a track that moved to
  another obstacle and left out.

Angles in radians (REP-103), metres.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from agent.arrays import BoolArray, FloatArray
from agent.control.view import EnvironmentView
from agent.planning.environment import CORNER, CYLINDER, DOCKING, SEGMENT

__all__ = ["DriftEstimate", "DriftSettings"]

_GATE_2 = 9.21  # χ² 99 %, 2 dof
_GATE_1 = 6.63  # χ² 99 %, 1 dof


@dataclass(frozen=True)
class DriftSettings:
    """The drift estimate's constants (module docstring).

    dead_reckon_place
        The place from the odometry's steps turned by the estimated heading, the anchors
        fitting the heading (module docstring); off: the anchors fit the place as well.
    anchor_sigma_m
        An obstacle is anchored only if its position's largest σ is at most this (3 cm:
        a feature seen a few times at the sensor's range; a wall's across its line).
    heading_growth_rad_per_m, heading_growth_rad_per_rad, heading_floor_rad
        The heading's prior is the last fit's σ grown by these per metre driven and per
        radian turned since (twice the simulated base's wheel-ratio and track errors, 3 %
        and 2 %: a base two σ out is still covered), at least the floor, at most
        ``prior_sigma_rad``: a segment's direction gives the heading in one vector, and
        each vector's noise then moved the estimate, and the goal with it, by up to a
        degree (15 cm at 8 m) while the vehicle stood (random run 33 of seed 0).
    prior_sigma_m, prior_sigma_rad
        The weak prior on the last estimate (0.5 m, 0.2 rad): far wider than what anchors
        say, it only holds the unobserved directions.
    fresh_s
        Only obstacles updated by a scan this recent (the vector's ``seen_age_s``; 0.15 s:
        the newest scan's) are fitted or anchored.
    drop_after
        An anchor gated out this many vectors in a row is forgotten.
    max_sigma_rad
        A fit moves the estimate only when it knows the heading to this σ (0.03 rad,
        1.7°): two anchors a metre apart, seen to a centimetre, give a tenth of that.
    max_cylinder_radius_m
        Larger cylinders are not anchored (0.5 m: what the tracker fits to a wall's bend
        is not a post).
    place_sigma_m
        Dead reckoned, the place's σ over the metres an anchor is in view (5 cm: 1.5 %
        of 3 m): the fit's prior on ``t``, about what puts the vehicle at its dead
        reckoned place (module docstring, *the heading, from the place*).
    estimate_rates, heading_noise_rad_per_sqrt_m
        The heading's drift per metre driven and per radian turned estimated with it
        (module docstring, *the heading's drift*), their prior σ
        ``heading_growth_rad_per_m`` and ``heading_growth_rad_per_rad``; the drift's
        random part (the wheels' slip: 0.5° per √m on the simulated base) grows the
        heading's variance by this squared per metre driven or radian turned.
    estimate_scale, scale_sigma, scale_min_travel_m, scale_max
        The wheels' scale error estimated from the anchors and taken out of the dead
        reckoned place (module docstring, *the scale*): its prior σ (0.015, the 1-2 % of
        distance a small base's wheel odometry reads off), the least travel (along the
        measured direction) an anchor must have been seen across to measure it (0.5 m),
        and the largest error a measurement may show before it is taken for a wrong
        association (0.1).
    """

    anchor_sigma_m: float = 0.03
    fresh_s: float = 0.15
    dead_reckon_place: bool = True
    prior_sigma_m: float = 0.5
    prior_sigma_rad: float = 0.2
    heading_growth_rad_per_m: float = 0.06
    heading_growth_rad_per_rad: float = 0.04
    heading_floor_rad: float = 0.003
    drop_after: int = 5
    max_sigma_rad: float = 0.03
    max_cylinder_radius_m: float = 0.5
    place_sigma_m: float = 0.05
    estimate_rates: bool = True
    heading_noise_rad_per_sqrt_m: float = 0.01
    estimate_scale: bool = True
    scale_sigma: float = 0.015
    scale_min_travel_m: float = 0.5
    scale_max: float = 0.1


@dataclass
class _Anchors:
    """The anchors as arrays over ``k``: world place ``w`` (k, 2), its covariance ``cov``
    (k, 2, 2) (a segment's: its σ across its line, both ways), a segment's direction in
    the world ``phi`` (k,) rad and its variance ``phi_var`` (k,) (0 and inf for a point),
    ``misses`` (k,)."""

    ids: list[int]
    w: FloatArray
    cov: FloatArray
    phi: FloatArray
    phi_var: FloatArray
    misses: FloatArray
    travel: FloatArray  # (k, 2) the travel, and the correction, when it was anchored
    corrected: FloatArray
    scale: FloatArray  # (k,) its latest measurement of the scale error, and the variance
    scale_var: FloatArray

    @classmethod
    def empty(cls) -> _Anchors:
        z2, z = np.zeros((0, 2)), np.zeros(0)
        return cls([], z2, np.zeros((0, 2, 2)), z, z, z, z2, z2, z, z)

    def select(self, keep: BoolArray) -> None:
        """Keep only the anchors ``keep`` (k,) marks."""
        self.ids = [i for i, k in zip(self.ids, keep, strict=True) if k]
        for name in ("w", "cov", "phi", "phi_var", "misses", "travel", "corrected", "scale",
                     "scale_var"):  # fmt: skip
            setattr(self, name, getattr(self, name)[keep])


def _line_angle(angle: FloatArray) -> FloatArray:
    """Angles of undirected lines, wrapped to [−π/2, π/2)."""
    return np.asarray((angle + 0.5 * np.pi) % np.pi - 0.5 * np.pi, dtype=np.float64)


def _rot(theta: float) -> FloatArray:
    c, s = math.cos(theta), math.sin(theta)
    return np.array([[c, -s], [s, c]])


def _rot_derivative(theta: float) -> FloatArray:
    """d R(θ) / d θ."""
    c, s = math.cos(theta), math.sin(theta)
    return np.array([[-s, -c], [c, -s]])


class DriftEstimate:
    """The world's place in ``odom`` now, from static obstacles (module docstring)."""

    def __init__(self, settings: DriftSettings | None = None) -> None:
        self.settings = settings if settings is not None else DriftSettings()
        self.t = np.zeros(2)
        self.theta = 0.0
        self.covariance = np.zeros((3, 3))  # of (tx, ty, θ), from the anchors alone
        self.used = 0  # anchors in the last fit
        self._pose: FloatArray | None = None  # the odometry's at the last vector
        self._moved_m = 0.0  # path length since the last fit that moved the estimate
        self._turned_rad = 0.0  # ... and turn (absolute)
        self._anchors = _Anchors.empty()
        self._world: FloatArray | None = None  # the vehicle's place in the world, dead reckoned
        self._index: dict[int, int] = {}
        # The scale error (module docstring, *the scale*): the odometry's steps turned into
        # the world, summed (``D``), and the corrections applied to them (``C``); the
        # information and weighted sum of the measurements of anchors forgotten.
        self.scale = 0.0
        self.scale_sigma = self.settings.scale_sigma
        self._travel = np.zeros(2)
        self._corrected = np.zeros(2)
        self._retired = np.zeros(2)  # (Σ 1/var, Σ δ/var)
        # The heading's drift per metre driven and per radian turned, and the covariance
        # of (θ, those two) (module docstring, *the heading's drift*).
        self.rates = np.zeros(2)
        st = self.settings
        # The world is ``odom`` as it was at the start: the heading is known there.
        self.rates_covariance = np.diag(
            [0.0, st.heading_growth_rad_per_m**2, st.heading_growth_rad_per_rad**2]
        )

    def __len__(self) -> int:
        return len(self._anchors.ids)

    def to_odom(self, xy_world: FloatArray) -> FloatArray:
        """Points (…, 2) in the world frame, in ``odom``."""
        return np.asarray(np.asarray(xy_world) @ _rot(self.theta).T + self.t, dtype=np.float64)

    def update(
        self, view: EnvironmentView, moving: BoolArray, pose: FloatArray | None = None
    ) -> None:
        """Fit the estimate to the vector's anchored obstacles, then anchor new ones.
        ``moving`` (k,) marks the vector's movers (never anchored, never fitted); ``pose``
        (3,), the odometry's at the vector's stamp, measures the motion since the last fit
        (the heading prior's growth); without it, the prior is the weak one."""
        st = self.settings
        if pose is not None:
            if self._pose is not None:
                step = pose[:2] - self._pose[:2]
                self._moved_m += float(np.hypot(*step))
                turn = math.remainder(float(pose[2] - self._pose[2]), math.tau)
                self._turned_rad += abs(turn)
                if st.estimate_rates:
                    yaw = float(self._pose[2])
                    ahead = float(step[0] * math.cos(yaw) + step[1] * math.sin(yaw))
                    self._predict_heading(ahead, turn)
                if self._world is not None:  # the step, turned by the heading as estimated
                    turned = _rot(-self.theta) @ step
                    self._world = self._world + (1.0 + self.scale) * turned
                    self._travel = self._travel + turned
                    self._corrected = self._corrected + self.scale * turned
            elif st.dead_reckon_place:
                self._world = (np.asarray(pose[:2], dtype=np.float64) - self.t) @ _rot(self.theta)
            self._pose = np.array(pose[:3], dtype=np.float64)
        else:  # the motion unknown: the weak prior
            self._moved_m = math.inf
            P = self.rates_covariance
            P[0, :] = P[:, 0] = 0.0
            P[0, 0] = st.prior_sigma_rad**2
        kind = np.asarray(view.kind)
        P = np.asarray(view.covariance, dtype=np.float64)[:, :2, :2]
        sig = np.sqrt(np.maximum(np.linalg.eigvalsh(P)[:, -1], 0.0)) if len(kind) else np.zeros(0)
        segment = (kind == SEGMENT) | (kind == DOCKING)
        across = np.asarray(view.across_sigma_m, dtype=np.float64)
        if across.size != kind.size:
            across = sig
        sig = np.where(segment, across, sig)
        radius = np.abs(np.asarray(view.extent, dtype=np.float64)[:, 0]) if len(kind) else sig
        # Only obstacles the newest scan updated: a coasting track stays where the odometry
        # put it when it was last seen, and would hold the estimate there.
        age = np.asarray(view.seen_age_s, dtype=np.float64)
        fresh = age <= st.fresh_s if age.size == kind.size else np.ones(kind.size, dtype=bool)
        usable = fresh & ~np.asarray(moving, dtype=bool) & np.isfinite(sig) & (
            (kind == CORNER) | segment
            | ((kind == CYLINDER) & (radius <= st.max_cylinder_radius_m))
        )  # fmt: skip
        ext = np.asarray(view.extent, dtype=np.float64)
        pos = np.asarray(view.position_xy, dtype=np.float64)
        normal = np.zeros_like(pos)
        phi, phi_var = np.zeros(kind.size), np.full(kind.size, np.inf)
        if segment.any():
            d = ext[segment, 2:4] - ext[segment, 0:2]
            length = np.maximum(np.hypot(d[:, 0], d[:, 1]), 1e-9)
            normal[segment] = np.stack([-d[:, 1], d[:, 0]], axis=1) / length[:, None]
            # Its direction, and (at most) its σ: the σ across the line at the ends is at
            # least the direction's σ times half the length.
            phi[segment] = np.arctan2(d[:, 1], d[:, 0])
            phi_var[segment] = (sig[segment] / (0.5 * length)) ** 2
        rows = [
            k for k in np.flatnonzero(usable).tolist() if int(view.obstacle_id[k]) in self._index
        ]
        ids = np.asarray(view.obstacle_id, dtype=np.int64)
        kept = np.zeros(0, dtype=bool)
        if rows:
            a = np.array([self._index[int(i)] for i in ids[rows]])
            kept = self._fit(a, np.array(rows), pos, normal, phi, phi_var, P, sig, segment)
        if self._world is not None and self._pose is not None:  # the place dead reckoned
            self.t = self._pose[:2] - _rot(self.theta) @ self._world
            if st.estimate_scale and kept.any():
                rows_kept = np.array(rows)[kept]
                a = np.array([self._index[int(i)] for i in ids[rows_kept]])
                self._measure_scale(a, pos[rows_kept], normal[rows_kept], P[rows_kept],
                                    sig[rows_kept], segment[rows_kept])  # fmt: skip
        # Anchor the new ones, with the estimate as it now stands.
        new = [
            k for k in np.flatnonzero(usable & (sig <= st.anchor_sigma_m)).tolist()
            if int(view.obstacle_id[k]) not in self._index
        ]  # fmt: skip
        if new:
            self._anchor(np.array(new), view, pos, phi, phi_var, P, sig, segment)

    # ------------------------------------------------------------------------ the fit
    def _residuals(
        self, t: FloatArray, theta: float, a: np.ndarray, z: FloatArray, zn: FloatArray,
        zphi: FloatArray, seg: np.ndarray,
    ) -> tuple[FloatArray, FloatArray]:  # fmt: skip
        """Per anchor row ``a``: residual (m, 2) (segments: across the line, and of the
        line's direction), and the Jacobians of the prediction (m, 2, 3)."""
        A = self._anchors
        R = _rot(theta)
        dR = _rot_derivative(theta)
        w = A.w[a]
        pred = w @ R.T + t
        H = np.zeros((len(a), 2, 3))
        H[:, 0, 0] = H[:, 1, 1] = 1.0
        H[:, :, 2] = w @ dR.T
        r = z - pred
        # A segment: the predicted point's offset from the measured line, along its normal.
        r_seg = np.einsum("ij,ij->i", zn, r)
        H_seg = np.einsum("ij,ijk->ik", zn, H)
        # ... and its direction: the world's, turned by θ.
        r_phi = _line_angle(zphi - (A.phi[a] + theta))
        r = np.where(seg[:, None], np.stack([r_seg, r_phi], axis=1), r)
        H[seg, 0, :] = H_seg[seg]
        H[seg, 1, :] = np.array([0.0, 0.0, 1.0])
        return r, H

    def _fit(
        self, a: np.ndarray, rows: np.ndarray, pos: FloatArray, normal: FloatArray,
        phi: FloatArray, phi_var: FloatArray, P: FloatArray, sig: FloatArray,
        segment: np.ndarray,
    ) -> BoolArray:  # fmt: skip
        """Fit ``(t, θ)`` to anchors ``a`` seen as the vector's obstacles ``rows``; which
        of them the gate kept."""
        st = self.settings
        A = self._anchors
        z, zn, zphi, seg = pos[rows], normal[rows], phi[rows], segment[rows]
        R = _rot(self.theta)
        # Each residual's covariance: the vector's and the anchor's (rotated into odom); a
        # point's weight is its inverse, a segment's the inverse of its variance across.
        anchored = R @ A.cov[a] @ R.T
        S_inv = np.linalg.inv(P[rows] + anchored + 1e-12 * np.eye(2))
        s_seg = sig[rows] ** 2 + np.einsum("ij,ijk,ik->i", zn, anchored, zn)
        s_phi = phi_var[rows] + A.phi_var[a]
        weight = S_inv.copy()
        weight[seg] = 0.0
        weight[seg, 0, 0] = 1.0 / s_seg[seg]
        weight[seg, 1, 1] = 1.0 / s_phi[seg]  # 0 where unknown (inf)
        keep = np.ones(len(a), dtype=bool)
        t, theta = self.t.copy(), self.theta
        x_last = np.array([self.t[0], self.t[1], self.theta])
        # The heading's prior: the prediction's σ (the rates), or the last fit's grown with
        # the motion since (the base's wheel errors, taken twice).
        if st.estimate_rates:
            grown = math.sqrt(max(float(self.rates_covariance[0, 0]), 0.0))
        else:
            grown = (
                math.sqrt(max(float(self.covariance[2, 2]), 0.0))
                + st.heading_growth_rad_per_m * self._moved_m
                + st.heading_growth_rad_per_rad * self._turned_rad
            )
        sigma_rad = min(max(grown, st.heading_floor_rad), st.prior_sigma_rad)
        # Dead reckoned, the place is known to ``place_sigma_m``: the prior on ``t`` is
        # what puts the vehicle at its dead reckoned place with the heading being fitted
        # (below), not the weak one about the last estimate.
        reckoned = self._world is not None and self._pose is not None
        weak = 0.0 if reckoned else st.prior_sigma_m**-2
        prior = np.diag([weak, weak, sigma_rad**-2])
        info = prior
        for it in range(6):
            r, H = self._residuals(t, theta, a, z, zn, zphi, seg)
            d2 = np.einsum("ij,ijk,ik->i", r, weight, r)
            if it >= 2:  # gate once the fit has settled from the last estimate
                keep = d2 <= np.where(seg & ~np.isfinite(s_phi), _GATE_1, _GATE_2)
            W = np.where(keep[:, None, None], weight, 0.0)
            info = prior + np.einsum("mji,mjk,mkl->il", H, W, H)
            x = np.array([t[0], t[1], theta])
            grad = np.einsum("mji,mjk,mk->i", H, W, r) - prior @ (x - x_last)
            if reckoned:
                assert self._world is not None and self._pose is not None
                e = t - (self._pose[:2] - _rot(theta) @ self._world)
                G = np.zeros((2, 3))
                G[:, :2] = np.eye(2)
                G[:, 2] = _rot_derivative(theta) @ self._world  # − d t_DR / d θ
                tie = 1.0 / st.place_sigma_m**2
                info = info + tie * G.T @ G
                grad = grad - tie * G.T @ e
            step = np.linalg.solve(info, grad)
            t, theta = t + step[:2], theta + float(step[2])
            if float(np.abs(step).max()) < 1e-7:
                break
        covariance = np.linalg.inv(info)
        self.used = int(keep.sum())
        # Only a fit that pins the heading moves the estimate: one post fixes where the world
        # is, not how it is turned, and the weak prior then let the heading wander with the
        # post's noise (measured: random run 10 of seed 0, the estimate 2.5° the wrong way).
        if math.sqrt(max(float(covariance[2, 2]), 0.0)) <= st.max_sigma_rad:
            if st.estimate_rates:
                self._update_heading(theta, float(covariance[2, 2]), sigma_rad**2)
            self.t, self.theta = t, math.atan2(math.sin(theta), math.cos(theta))
            self.covariance = covariance
            self._moved_m = self._turned_rad = 0.0
        A.misses[a] = np.where(keep, 0.0, A.misses[a] + 1.0)
        gone = np.flatnonzero(A.misses >= st.drop_after)
        if gone.size:
            self._forget(gone)
        return keep

    # ------------------------------------------------------------------ the heading's drift
    def _predict_heading(self, ahead_m: float, turn_rad: float) -> None:
        """The odometry moved ``ahead_m`` along its heading and turned ``turn_rad``: the
        heading drifts by the rates times those; its variance grows with them and with
        the random part."""
        st = self.settings
        F = np.array([[1.0, ahead_m, turn_rad], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])
        Q = np.zeros((3, 3))
        Q[0, 0] = st.heading_noise_rad_per_sqrt_m**2 * (abs(ahead_m) + abs(turn_rad))
        self.theta += float(self.rates[0] * ahead_m + self.rates[1] * turn_rad)
        self.rates_covariance = F @ self.rates_covariance @ F.T + Q

    def _update_heading(self, theta_post: float, var_post: float, var_prior: float) -> None:
        """The fit took the heading from the prediction (variance ``var_prior``) to
        ``theta_post`` (``var_post``): what the anchors alone said (the fit's posterior
        divided by its prior) updates the heading and, through their covariance, the
        rates."""
        if not 0.0 < var_post < var_prior * (1.0 - 1e-9):
            return
        var_anchors = 1.0 / (1.0 / var_post - 1.0 / var_prior)
        gain = var_prior / (var_prior + var_anchors)
        innovation = math.remainder(theta_post - self.theta, math.tau) / gain
        P = self.rates_covariance
        S = float(P[0, 0]) + var_anchors
        K = P[:, 0] / S
        self.rates = self.rates + K[1:] * innovation
        self.rates_covariance = P - np.outer(K, P[0, :])

    # ------------------------------------------------------------------------ the scale
    def _measure_scale(
        self, a: np.ndarray, z: FloatArray, zn: FloatArray, P: FloatArray, sig: FloatArray,
        seg: np.ndarray,
    ) -> None:  # fmt: skip
        """Each anchor ``a`` seen at ``z`` (m, 2) now measures the scale error over the
        travel since it was anchored; the estimate is their weighted mean with the prior
        (module docstring, *the scale*)."""
        st = self.settings
        A = self._anchors
        R = _rot(self.theta)
        # The residual against the place dead reckoned, in the world's axes.
        r = (z - (A.w[a] @ R.T + self.t)) @ R
        D = self._travel - A.travel[a]
        C = self._corrected - A.corrected[a]
        cov = R.T @ P @ R + A.cov[a]
        # A point: along its travel. A segment: across its line (the world's normal).
        length = np.hypot(D[:, 0], D[:, 1])
        u = np.where(seg[:, None], zn @ R, D / np.maximum(length, 1e-9)[:, None])
        across = np.einsum("ij,ij->i", u, D)
        var_r = np.where(seg, sig**2 + np.einsum("ij,ijk,ik->i", u, A.cov[a], u),
                         np.einsum("ij,ijk,ik->i", u, cov, u))  # fmt: skip
        with np.errstate(divide="ignore", invalid="ignore"):
            delta = np.einsum("ij,ij->i", u, C - r) / across
            var = var_r / across**2
        ok = (np.abs(across) >= st.scale_min_travel_m) & (np.abs(delta) <= st.scale_max)
        A.scale[a[ok]] = delta[ok]
        A.scale_var[a[ok]] = var[ok]
        self._update_scale()

    def _update_scale(self) -> None:
        A = self._anchors
        known = np.isfinite(A.scale_var) & (A.scale_var > 0.0)
        info = 1.0 / self.settings.scale_sigma**2 + self._retired[0]
        total = self._retired[1]
        if known.any():
            info += float((1.0 / A.scale_var[known]).sum())
            total += float((A.scale[known] / A.scale_var[known]).sum())
        self.scale, self.scale_sigma = total / info, math.sqrt(1.0 / info)

    # ----------------------------------------------------------------------- anchors
    def _anchor(
        self, rows: np.ndarray, view: EnvironmentView, pos: FloatArray, phi: FloatArray,
        phi_var: FloatArray, P: FloatArray, sig: FloatArray, segment: np.ndarray,
    ) -> None:  # fmt: skip
        A = self._anchors
        Rt = _rot(-self.theta)
        w = (pos[rows] - self.t) @ Rt.T
        # The anchor's covariance: the vector's, and the estimate's carried to its place.
        J = np.zeros((len(rows), 2, 3))
        J[:, 0, 0] = J[:, 1, 1] = 1.0
        rel = pos[rows] - self.t
        J[:, 0, 2], J[:, 1, 2] = -rel[:, 1], rel[:, 0]
        cov = Rt @ (P[rows] + J @ self.covariance @ J.transpose(0, 2, 1)) @ Rt.T
        seg = segment[rows]
        cov[seg] = np.eye(2) * (sig[rows][seg] ** 2)[:, None, None]
        for k, i in enumerate(view.obstacle_id[rows].tolist()):
            self._index[int(i)] = len(A.ids) + k
        A.ids.extend(int(i) for i in view.obstacle_id[rows])
        A.w = np.concatenate([A.w, w])
        A.cov = np.concatenate([A.cov, cov])
        # A segment's direction in the world: the estimate's heading taken off, its
        # variance added.
        A.phi = np.concatenate([A.phi, _line_angle(phi[rows] - self.theta)])
        A.phi_var = np.concatenate([A.phi_var, phi_var[rows] + self.covariance[2, 2]])
        A.misses = np.concatenate([A.misses, np.zeros(len(rows))])
        A.travel = np.concatenate([A.travel, np.tile(self._travel, (len(rows), 1))])
        A.corrected = np.concatenate([A.corrected, np.tile(self._corrected, (len(rows), 1))])
        A.scale = np.concatenate([A.scale, np.zeros(len(rows))])
        A.scale_var = np.concatenate([A.scale_var, np.full(len(rows), np.inf)])

    def _forget(self, gone: np.ndarray) -> None:
        A = self._anchors
        keep = np.ones(len(A.ids), dtype=bool)
        keep[gone] = False
        # A forgotten anchor's last measurement of the scale stays in the estimate.
        var = A.scale_var[gone]
        known = np.isfinite(var) & (var > 0.0)
        self._retired += [float((1.0 / var[known]).sum()),
                          float((A.scale[gone][known] / var[known]).sum())]  # fmt: skip
        A.select(keep)
        self._index = {i: j for j, i in enumerate(A.ids)}
