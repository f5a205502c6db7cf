"""A walker's line from its trail: the line through the places the vector put one mover.

The vector's velocity of a walker says which way it goes to tens of degrees. Measured in
``evaluate``'s random runs 0-3, 7 and 8 of seed 0 (``active``, the odometry's drift), over
the 1,042 vectors in which a mover of the controller (:func:`capsules_from_view`) was a
true walker: its velocity's direction was 23° off the walker's at the median (47° at the
90th percentile), no better for tracks 20 vectors old than for new ones, and its covariance
said 58° (1σ) at the median. Swept over the braking horizon and inflated by 3σ of that,
every walker's capsule was the 1.5 m cap wide, and a vehicle 1.5 m beside a walk stood
"yielding" for as long as the walker walked it.

The worlds' walkers keep to their lines, and the places the vector gave one mover lie along
its line whichever way it walked: the line fitted to the last ``trail_n`` of them
(:func:`fit_line`, the principal axis of the places) was 1.0° off at the median (5.4° at
the 90th percentile) where it could be fitted (at least ``min_points`` places spanning
``min_span_m`` along it: 66 % of those vectors).

**Its σ.** With ``s_i`` the places along the line from their mean and ``e`` the RMS of their
offsets across it (at least ``floor_m``, the places' own noise), the direction's σ is

    σ_θ = c · e / √(Σ s_i²)

the least-squares slope's, times ``c`` = 2: the places are the tracker's filtered
estimates, each correlated with the last, and the formula for independent ones (``c`` = 1)
put 4.3 % of the errors beyond 3σ; with ``c`` = 2, 0.4 % (on the vectors above).

**A mover on its line** (:func:`movers_on_lines`): its velocity is taken along the line
(the vector's velocity projected on it: ``s = v·u``) and its capsule swept ``s·T`` along
it; inflated by 3σ of its place *across* the line at the horizon's end,
``hypot(σ_across, σ_θ·s·T)``, and lengthened at each end by what 3σ of its place *along*
the line (position and speed, ``P(T)``) adds beyond that: it may be ahead of or behind its
estimate along its line, not off it.

**One walk, many tracks** (:class:`WalkRegistry`). The tracker loses a walker each time it
leaves the window for a second or two and starts a new track when it comes back (measured:
random run 0 of seed 0, three walkers about the vehicle, a new mover id every 1-2 s), so a
trail per track rarely holds the 5 places a line needs, and a walker lost unfitted was kept
on its velocity's line, tens of degrees off, at the 1.5 m inflation cap. A walker walks the
same line on every pass: a new track whose place lies on a known walk's line (within
``gate_m`` across it, or 3σ of the line there, and within ``reach_m`` of its walked part
along it) and whose velocity does not cross it (within 60°, either sense: the tracks' velocities are
23° off at the median, 47° at the 90th percentile) is taken as that
walk's walker, and its places join the walk's. ``reach_m`` is 3 m, the walkway memory's reach
(:mod:`agent.control.walkways`): at 1.5 m, in the demo world, a walker seen on the south half
of its 4.4 m walk and found again 1.6 m beyond on the north half began a walk of its own,
unfitted, and was kept at the 1.5 m inflation cap across the vehicle's way. The walk's line
is fitted to the places of all its tracks (the last ``trail_n``), and its **pace** is how
fast the places show it walking along its line (the 90th percentile of the distances
between two places of one track at least ``pace_span_s`` apart over their time; the tracks'
velocities overstate it: a 0.64 m/s walker was taken at 1.0 m/s). A walk no track has
joined for ``memory_s`` is forgotten.

**One walk from short tracks.** A walker near the far limit, or one the head turns to
and from, is tracked in pieces: in ``evaluate``'s random run 83 of seed 0 (``active``) a
walker 2.3-2.7 m off was a new track every 1.2-1.9 s, each 5-7 vectors and 0.1-0.2 m
long, never the 0.3 m a line needs; no walk was fitted, none could be joined, and each
lost piece was kept on its velocity's line (74-109° σ) at the 1.5 m inflation cap, across
the standing vehicle 2 m from the true walk, for the whole run. An unfitted walk is now
joined too, by its provisional line (:func:`fit_line` of at least ``join_points`` places
spanning ``join_span_m``: 3 and 0.1 m, a direction to about 10° from places 1-2 cm off
it), within ``gate_m`` across it (not 3σ there, as for a fitted line: a provisional line
is tens of centimetres uncertain a metre out, and two walkers on walks 0.6 m apart, as in
random run 67, would be one), within what its walker could have walked since its last
place (``gate_m`` plus ``join_speed_m_s``, 1 m/s, the movers' speed bound, times the gap)
along it, and only while none of its tracks is in the vector (a second mover beside a
tracked one is a second walker). In run 83 the walk was fitted 4 s in, 19° ± 1.4° against
the true 19°.

**Two walks of one walker.** A track whose first velocity crossed its walk's line, or
that was found while another track of its walker was still in the vector (the tracker
sometimes holds two), begins a walk of its own, which its places then fit on the same
line: in random run 68 of seed 0 one walker had three walks, and the walkway memory kept
a walker on each, the oldest possible anywhere 3 m along its line for 30 s, beside the
vehicle's way. A new track that lies on several walks joins the nearest, and the others
whose tracks are not in the vector, whose lines lie within 10° of its walk's and pass
within ``gate_m`` of the track, are merged into it (their places, ends and turns;
:meth:`WalkRegistry.current` follows a merged walk to the one it joined).

**Where it turns** (:attr:`Walk.turns`). Where its places along the line rise by at least
``turn_rise_m`` to one and fall by as much after it, within ``turn_span_s`` each side, with
none beyond it between, the walker turned back there: the walk's end that way. The places
may be of two tracks (the tracker often loses a walker as it turns, and a new track finds
it walking back), but not where two tracks hold places at one time (two walkers, or one
seen twice, their places interleaved would make turns of noise). Between the places either
side of the turn the walker was unseen and may have walked further out: half of what it
walks at its pace (else ``turn_speed_m_s``) in the longer gap is added. The furthest turn
each way is kept, beyond the trail, as the walk's ends are. Where a walker was seen to turn
at (about) the furthest place it was ever seen that way, a walker lost on the walk is taken
to turn there again (:mod:`agent.control.walkways`): measured in ``evaluate``'s random runs
0-23 of seed 0 (``active``), the vehicle stood "yielding" for a walker kept walking on
past such an end in a fifth of its yielding commands, the true walk 0.6 m or more from the
vehicle's outline.

Stated limits: a walker that leaves its line (a path with a corner) is off the fitted line by
more than the capsule holds until the trail has turned with it; the worlds' random walkers
walk straight lines. Two walkers on one line are one walk (their places agree on the line).
A walker seen to turn at its walk's end is taken to turn there every time: a person who
paces a corridor and then walks on past its end is not.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from agent.arrays import FloatArray
from agent.control.obstacles import Capsules

__all__ = ["LineFit", "Walk", "WalkRegistry", "fit_line", "movers_on_lines", "turn_points"]

_CORRELATION = 2.0  # c above
_CROSSING_COS = math.cos(math.radians(60.0))  # a new track's velocity along a walk's line
_MERGE_COS = math.cos(math.radians(10.0))  # two walks' lines this near parallel may be one


@dataclass(frozen=True)
class LineFit:
    """A trail's line: ``direction`` (2,) unit (either sense), ``sigma_rad`` its σ; the
    places' mean ``centre`` (2,) it passes through (``None``: not given) and their RMS
    offset across it, ``spread_m``."""

    direction: FloatArray
    sigma_rad: float
    centre: FloatArray | None = None
    spread_m: float = 0.0

    def across_sigma_m(self, along_m: float) -> float:
        """The σ across the line of a walker on it ``along_m`` from its centre: the places'
        spread (the walker's sway and the places' noise: not divided by their number, as
        consecutive places are correlated) and the direction's error that far out."""
        return math.hypot(self.spread_m, self.sigma_rad * along_m)

    def toward(self, velocity: FloatArray) -> FloatArray:
        """(2,) the line's unit direction in the sense of ``velocity`` (2,)."""
        sense = 1.0 if float(self.direction @ velocity) >= 0.0 else -1.0
        return np.asarray(sense * self.direction, dtype=np.float64)


def fit_line(
    xy: FloatArray, min_points: int = 5, min_span_m: float = 0.3, floor_m: float = 0.02
) -> LineFit | None:
    """The line through the places ``xy`` (n, 2) (module docstring), or ``None`` when
    there are fewer than ``min_points`` or they span less than ``min_span_m`` along it."""
    xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
    if len(xy) < min_points:
        return None
    centred = xy - xy.mean(axis=0)
    # The principal axis: the eigenvector of the places' scatter with the larger eigenvalue.
    _, vectors = np.linalg.eigh(centred.T @ centred)
    u = vectors[:, 1]
    along = centred @ u
    if float(along.max() - along.min()) < min_span_m:
        return None
    across = centred @ np.array([-u[1], u[0]])
    e = max(math.sqrt(float(np.mean(across * across))), floor_m)
    sigma = _CORRELATION * e / math.sqrt(float(np.sum(along * along)))
    return LineFit(np.asarray(u, dtype=np.float64), sigma, xy.mean(axis=0), e)


def movers_on_lines(
    capsules: Capsules,
    velocity_xy: FloatArray,
    covariance: FloatArray,
    lines: dict[int, LineFit],
    horizon_s: float,
    sigmas: float,
    cap_m: float,
    margin_m: float,
    turns: dict[int, FloatArray] | None = None,
) -> tuple[Capsules, FloatArray]:
    """The movers of ``capsules`` whose id has a line in ``lines`` re-swept along it
    (module docstring), and every obstacle's velocity (``velocity_xy`` (k, 2), the
    vector's, with those movers' taken along their lines). ``covariance`` (k, 4, 4) the
    vector's; the others are returned as they were. ``turns``: by id, the places (m, 2)
    on its line where a mover turns back (its walk's ends, :mod:`agent.control.walkways`):
    its capsule is not swept past them."""
    velocity = np.array(velocity_xy, dtype=np.float64, copy=True)
    rows = [
        k for k in np.flatnonzero(capsules.moving).tolist()
        if int(capsules.obstacle_id[k]) in lines
    ]  # fmt: skip
    if not rows:
        return capsules, velocity
    a, b = capsules.a.copy(), capsules.b.copy()
    inflation = capsules.inflation.copy()
    T = horizon_s
    for k in rows:
        line = lines[int(capsules.obstacle_id[k])]
        u = line.toward(velocity[k])
        n = np.array([-u[1], u[0]])
        s = float(u @ velocity[k])
        P = covariance[k]
        P_future = P[:2, :2] + T * (P[:2, 2:] + P[2:, :2]) + T * T * P[2:, 2:]
        across = math.hypot(math.sqrt(max(float(n @ P[:2, :2] @ n), 0.0)), line.sigma_rad * s * T)
        along_now = math.sqrt(max(float(u @ P[:2, :2] @ u), 0.0))
        along_then = math.sqrt(max(float(u @ P_future @ u), 0.0))
        grow = min(sigmas * across, cap_m)
        p = capsules.a[k]
        behind = min(max(sigmas * along_now - grow, 0.0), cap_m)
        ahead = s * T + min(max(sigmas * along_then - grow, 0.0), cap_m)
        ends = None if turns is None else turns.get(int(capsules.obstacle_id[k]))
        if ends is not None and len(ends):
            at = (ends - p) @ u
            if (at >= 0.0).any():
                ahead = min(ahead, float(at[at >= 0.0].min()))
            if (at <= 0.0).any():
                behind = min(behind, float(-at[at <= 0.0].max()))
        a[k] = p - behind * u
        b[k] = p + ahead * u
        inflation[k] = grow + margin_m
        velocity[k] = s * u
    refined = Capsules(a, b, capsules.radius, inflation, capsules.moving, capsules.obstacle_id)
    return refined, velocity


def turn_points(
    along: FloatArray, times: FloatArray, rise_m: float, span_s: float, speed_m_s: float
) -> tuple[NDArray[np.bool_], FloatArray]:
    """Where a walker's places (``along`` its line (n,), at ``times`` (n,), oldest first,
    of any of its walk's tracks) show it turning back (module docstring: *where it
    turns*): the farthest out within ``span_s`` either side, with places at least
    ``rise_m`` short of it both before and after; either way along the line. Not where a
    time in that span holds two places (two tracks at once: two walkers, or one seen
    twice). Also, for each, how much further out the walker may have turned, unseen
    between the places either side at ``speed_m_s`` (half of what it walks in the longer
    gap), signed the way it turned (+1 along ``along``'s sense)."""
    dt = times[None, :] - times[:, None]  # [j, i]: place i's time from place j's
    before = (dt < 0.0) & (dt >= -span_s)
    after = (dt > 0.0) & (dt <= span_s)
    window = before | after
    twice = np.isin(times, times[np.flatnonzero(np.diff(times) == 0.0)])
    single = ~np.any((window | (dt == 0.0)) & twice[None, :], axis=1)
    way = np.zeros(along.size)
    for sense in (1.0, -1.0):
        x = sense * along
        lead = x[:, None] - x[None, :]  # [j, i]: how far place j lies out beyond place i
        top = ~np.any(window & (lead < 0.0), axis=1)
        rose = np.any(before & (lead >= rise_m), axis=1)
        fell = np.any(after & (lead >= rise_m), axis=1)
        way[top & rose & fell & single] = sense
    gaps = np.diff(times)
    longer = np.maximum(np.concatenate([[0.0], gaps]), np.concatenate([gaps, [0.0]]))
    return way != 0.0, way * 0.5 * speed_m_s * longer


@dataclass
class Walk:
    """One walker's walk: the places its tracks were given (``odom``), their times and
    track ids, oldest first (the last ``trail_n``); its fitted line (``None`` until one
    fits), pace (m/s, 0 until two places of one track are far enough apart in time) and
    the furthest places it was seen at each way along its line (its walk's ends lie at or
    beyond them)."""

    places: FloatArray  # (k, 2)
    times: FloatArray  # (k,)
    ids: NDArray[np.int64]  # (k,)
    line: LineFit | None = None
    pace: float = 0.0
    ends: FloatArray | None = None  # (2, 2) its furthest places each way along its line, ever
    turns: FloatArray | None = None  # (k, 2), k <= 2: the furthest places it turned, each way
    merged_into: Walk | None = None  # the walk it was found to be and joined (``None``: live)

    @property
    def centre(self) -> FloatArray:
        return np.asarray(self.places.mean(axis=0), dtype=np.float64)


class WalkRegistry:
    """The walks the vector's movers walk, across the tracker's tracks (module docstring)."""

    def __init__(
        self,
        trail_n: int = 40,
        min_points: int = 5,
        min_span_m: float = 0.3,
        gate_m: float = 0.3,
        reach_m: float = 3.0,
        pace_span_s: float = 0.8,
        memory_s: float = 30.0,
        turn_rise_m: float = 0.2,
        turn_span_s: float = 3.0,
        turn_speed_m_s: float = 1.0,
        join_points: int = 3,
        join_span_m: float = 0.1,
        join_speed_m_s: float = 1.0,
    ) -> None:
        self.trail_n = trail_n
        self.min_points = min_points
        self.min_span_m = min_span_m
        self.gate_m = gate_m
        self.reach_m = reach_m
        self.pace_span_s = pace_span_s
        self.memory_s = memory_s
        self.turn_rise_m = turn_rise_m
        self.turn_span_s = turn_span_s
        self.turn_speed_m_s = turn_speed_m_s
        self.join_points = join_points
        self.join_span_m = join_span_m
        self.join_speed_m_s = join_speed_m_s
        self._walks: list[Walk] = []
        self._of_id: dict[int, Walk] = {}

    def __len__(self) -> int:
        return len(self._walks)

    def walk_of(self, track_id: int) -> Walk | None:
        """The walk track ``track_id`` walks, if it was seen."""
        return self._of_id.get(track_id)

    def observe(
        self, t_s: float, ids: NDArray[np.int64], places: FloatArray, velocities: FloatArray
    ) -> None:
        """The movers of a vector at ``t_s``: their track ids (m,), places (m, 2) and
        velocities (m, 2). Each joins its walk (found for a new track, or begun)."""
        live = frozenset(ids.tolist())
        for i, p, v in zip(ids.tolist(), places, velocities, strict=True):
            walk = self._of_id.get(i)
            if walk is None:
                found = self._candidates(p, v, t_s, live)
                if found:
                    walk = found[0]
                    for other in found[1:]:
                        if live.isdisjoint(other.ids.tolist()) and self._one_line(walk, other, p):
                            self._merge(walk, other)
                else:
                    walk = Walk(np.zeros((0, 2)), np.zeros(0), np.zeros(0, dtype=np.int64))
                    self._walks.append(walk)
                self._of_id[i] = walk
            n = self.trail_n
            walk.places = np.concatenate([walk.places, p[None]])[-n:]
            walk.times = np.concatenate([walk.times, [t_s]])[-n:]
            walk.ids = np.concatenate([walk.ids, [i]])[-n:]
        for walk in self._walks:
            if walk.times.size and walk.times[-1] == t_s:
                self._refit(walk)
        old = [w for w in self._walks if t_s - float(w.times[-1]) > self.memory_s]
        if old:
            self._walks = [w for w in self._walks if t_s - float(w.times[-1]) <= self.memory_s]
            gone = {id(w) for w in old}
            self._of_id = {i: w for i, w in self._of_id.items() if id(w) not in gone}

    def find(
        self,
        place: FloatArray,
        velocity: FloatArray,
        t_s: float | None = None,
        live: frozenset[int] = frozenset(),
    ) -> Walk | None:
        """The walk whose line ``place`` lies on, near its walked part, that a track at
        ``velocity`` may walk (module docstring; any way for a zero velocity); the nearest
        across, or None. A fitted walk's line; given ``t_s`` (a new track's first place),
        also an unfitted walk's provisional line, within what its walker could have walked
        since its last place, if none of its tracks is among ``live`` (the vector's
        movers): *one walk from short tracks*."""
        found = self._candidates(place, velocity, t_s, live)
        return found[0] if found else None

    def current(self, walk: Walk) -> Walk:
        """The live walk ``walk`` is, or was merged into (*one walk, many tracks*)."""
        while walk.merged_into is not None:
            walk = walk.merged_into
        return walk

    def _one_line(self, walk: Walk, other: Walk, place: FloatArray) -> bool:
        """Whether two fitted walks are one line: within 10° of each other (``_MERGE_COS``),
        ``place`` within ``gate_m`` of both (not the 3σ a metre out a track joins by: two
        walkers on walks 0.6 m apart and 10° apart were merged so, random run 49 of seed 0,
        ``sweep``, and the one lost walked into the vehicle)."""
        if walk.line is None or other.line is None:
            return False
        if abs(float(walk.line.direction @ other.line.direction)) < _MERGE_COS:
            return False
        for w, line in ((walk, walk.line), (other, other.line)):
            u, rel = line.direction, place - w.centre
            if abs(float(rel[0] * u[1] - rel[1] * u[0])) > self.gate_m:
                return False
        return True

    def _merge(self, walk: Walk, other: Walk) -> None:
        """``other`` is ``walk``'s walker's too: its places, ends and turns join ``walk``."""
        order = np.argsort(np.concatenate([walk.times, other.times]), kind="stable")
        n = self.trail_n
        walk.places = np.concatenate([walk.places, other.places])[order][-n:]
        walk.times = np.concatenate([walk.times, other.times])[order][-n:]
        walk.ids = np.concatenate([walk.ids, other.ids])[order][-n:]
        ends = [e for e in (walk.ends, other.ends) if e is not None]
        walk.ends = np.concatenate(ends) if ends else None
        turns = [e for e in (walk.turns, other.turns) if e is not None]
        walk.turns = np.concatenate(turns) if turns else None
        self._walks = [w for w in self._walks if w is not other]
        self._of_id = {i: (walk if w is other else w) for i, w in self._of_id.items()}
        other.merged_into = walk
        self._refit(walk)
        if walk.line is not None and walk.turns is not None:
            walk.turns = _furthest(walk.turns, walk.line.direction)

    def _candidates(
        self,
        place: FloatArray,
        velocity: FloatArray,
        t_s: float | None = None,
        live: frozenset[int] = frozenset(),
    ) -> list[Walk]:
        """Every walk :meth:`find` may take, the nearest across first."""
        found: list[tuple[float, Walk]] = []
        speed = float(np.hypot(velocity[0], velocity[1]))
        for walk in self._walks:
            line, reach, fitted = walk.line, self.reach_m, walk.line is not None
            if line is None:
                if t_s is None or not live.isdisjoint(walk.ids.tolist()):
                    continue
                line = fit_line(walk.places, self.join_points, self.join_span_m)
                if line is None:
                    continue
                gap_s = max(t_s - float(walk.times[-1]), 0.0)
                reach = min(reach, self.gate_m + self.join_speed_m_s * gap_s)
            u = line.direction
            centre = walk.centre
            rel = place - centre
            along = float(rel @ u)
            across = abs(float(rel[0] * u[1] - rel[1] * u[0]))
            s = (walk.places - centre) @ u
            if not (float(s.min()) - reach <= along <= float(s.max()) + reach):
                continue
            if across > (max(self.gate_m, 3.0 * line.sigma_rad * abs(along)) if fitted
                         else self.gate_m):  # fmt: skip
                continue
            if speed > 0.0 and abs(float(velocity @ u)) < _CROSSING_COS * speed:
                continue
            found.append((across, walk))
        return [walk for _, walk in sorted(found, key=lambda f: f[0])]  # stable: ties in order

    def _refit(self, walk: Walk) -> None:
        walk.line = fit_line(walk.places, self.min_points, self.min_span_m)
        if walk.line is None:
            return
        # Its furthest places each way, kept beyond the trail: where its walk may end.
        known = walk.places if walk.ends is None else np.concatenate([walk.ends, walk.places])
        along = known @ walk.line.direction
        walk.ends = known[[int(np.argmin(along)), int(np.argmax(along))]].copy()
        s = walk.places @ walk.line.direction
        speeds = []
        for i in np.unique(walk.ids).tolist():
            mine = walk.ids == i
            t, x = walk.times[mine], s[mine]
            # Each place against the latest of the same track at least pace_span_s older.
            j = np.searchsorted(t, t - self.pace_span_s, side="right") - 1
            ok = j >= 0
            speeds.append(np.abs(x[ok] - x[j[ok]]) / (t[ok] - t[j[ok]]))
        found = np.concatenate(speeds) if speeds else np.zeros(0)
        if found.size:
            # The 90th percentile: the walker's pace (it slows only to turn at its ends),
            # above the places' noise (a few cm over 0.8 s: ±0.05 m/s).
            walk.pace = float(np.percentile(found, 90.0))
        # Where it turned: each turn moved out by what it may have walked unseen (at its
        # pace, else ``turn_speed_m_s``), the furthest each way kept.
        u = walk.line.direction
        speed = walk.pace if walk.pace > 0.0 else self.turn_speed_m_s
        turn, out = turn_points(s, walk.times, self.turn_rise_m, self.turn_span_s, speed)
        if turn.any():
            turned = walk.places[turn] + out[turn, None] * u
            if walk.turns is not None:
                turned = np.concatenate([walk.turns, turned])
            walk.turns = _furthest(turned, u)


def _furthest(points: FloatArray, u: FloatArray) -> FloatArray:
    """The places of ``points`` (k, 2) furthest each way along ``u`` (one or two rows)."""
    along = points @ u
    keep = sorted({int(np.argmin(along)), int(np.argmax(along))})
    return np.asarray(points[keep], dtype=np.float64).copy()
