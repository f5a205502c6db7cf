"""Walkers the vector no longer holds: where on its line each may be, until seen again.

A mover whose track ends is not gone. Most often the sensor lost it where it cannot see
(beside the window, nearer than the near limit, behind the vehicle) and it walks on; the
worlds' walkers walk their lines to and fro, blindly. The controller used to keep such a
walker for 2 s, swept both ways along its last velocity; measured in ``evaluate``'s random
runs 0-47 of seed 0 (``active``, perfect odometry, the seen profiles recorded, with
:mod:`agent.control.give_way`), 20 of the 21 walkers that met the vehicle had been tracked
as movers before, most of them 5-10 s before. Kept for 8 s instead (as an ablation), the
collisions fell from 21 to 2, and the vehicle yielded two thirds of the time: a walker
remembered where it is not stops the vehicle as surely as one that is there, and only
looking tells which.

So each walker that leaves the vector, having been a mover in at least
``walkway_min_sightings`` vectors (a static pillar's track may pass for a mover for a vector
or two), is kept as the set of places on its **walk** (the line through its last position
``p`` along its last velocity ``v``, speed ``s = |v|``) where it may be, on cells of
``walkway_cell_m`` out to ``walkway_reach_m`` either way:

* at first, the cell it was in;
* each vector, the set grows by ``s·Δt`` the way it walks (**walking on**, below);
* and loses every cell the vector's free-space profile now vouches clear: the profile is
  aged for movers from every place one could hide, so a cell clear in it holds no walker's
  centre now. Looking along a walk is what frees it.

**Walking on.** The worlds' walkers walk to their walk's end before they turn back. A walk
(:class:`agent.control.walk_lines.WalkRegistry`, the places of all its walker's tracks)
shows which way the walker went when it was lost (its track's places 0.5 s apart, at least
0.15 m apart along the line; or, for a track shorter than that or a slow walker, its first
and last places 0.3 s or more apart, at least 0.08 m apart along the line the way its
velocity goes: a walker near the far limit is tracked in pieces of 0.5-0.7 s, and at
0.28 m/s none showed its way, so each was taken to walk back at once; else not known)
and the furthest places it was ever seen at each way, at or beyond which its walk ends.
The set is kept as two: the cells where it may be walking on, and those where it may be
walking back. Each vector the first grows the way it walks and the second the other way;
a cell of either at or beyond the furthest place that way (less two cells of slack) may
be where it turned, and joins the other. A walker lost walking away from the vehicle's
way, at the near end of a walk it was seen to walk further along before, cannot be back
before it has walked to that end and back: kept growing both ways (as before, and still
when its way or its walk is not known), it could be back at once. Where its walk shows
it turning back at (about) the furthest place it was seen that way
(:class:`~agent.control.walk_lines.Walk`'s ``turns``), it walks no further than that place
and two cells of slack, and its capsules are not swept beyond. Stated limits: a walker
that turns back short of where its walk was seen to reach, or walks on past where it was
seen to turn.

It is forgotten when no cell is left, after ``walkway_memory_s`` without being seen, when
a mover in the vector walks where it may be along the same line (seen again, under a new
track), or when its own track stands in the vector, seen and static, for
``walkway_standing_s`` (a post whose track passed for a mover, or a walker that stopped).
A walker lost before its places fitted a line, where a fitted walk's line passes
(:meth:`~agent.control.walk_lines.WalkRegistry.find`: another track of it fitted it, before
or since), is that walk's walker: kept on its line, and forgotten when the walk's walker
is in the vector (kept on its velocity's line, known to tens of degrees, it stood at the
1.5 m cap for 30 s: in ``evaluate``'s random runs 0-23 of seed 0, ``active``, such
walkers alone kept the vehicle yielding in a quarter of its yielding commands). Stated
limit: where two walks cross at the place it was lost, it is taken for the walker of the
one whose line passes nearer.

Each run of possible cells, lengthened both ways by ``s·mover_horizon_s`` (where it
may be by the end of the braking horizon), is a chain of moving capsules at most 0.5 m long,
each inflated by 3σ of its place across the line, at most ``mover_inflation_cap_m``. On a
fitted walk, the line's own (:meth:`agent.control.walk_lines.LineFit.across_sigma_m`: the
places' spread about it and its direction's σ times the piece's farthest reach from its
centre; one capsule for the run took its farthest reach, metres out, beside the vehicle
too, and kept it yielding 1 m from a walk it knew to a few cm): the walker
keeps to its line, which its places show to a few cm, better than any one track's place
(3σ of a young track's: 0.3-0.6 m; measured, runs 0-3 of seed 0: the remembered walks'
inflation was 0.72 m at the median on fitted lines). Otherwise its position's σ when last
seen and its direction's σ (its velocity's σ across the line over its speed) times the
run's farthest reach along it. The tracks' walkers are known to tens of degrees near the
vehicle (their velocity σ across the line 0.3-0.8 m/s, measured in the random runs), so
that is mostly the cap: a narrow capsule (at most 0.25 m, tried first) missed walkers that
turned off the estimated line, and 18 of the 48 runs above ended in a collision.
For giving way (:mod:`agent.control.give_way`) a run is a remembered walker at its middle,
aged so that walking either way it spans the run.

Not modelled, a stated limit: a walker that walks further than ``walkway_reach_m`` from
where it was last seen, or off its line by more than the inflation.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from agent.arrays import BoolArray, FloatArray, largest_sigma
from agent.control.give_way import Walkers
from agent.control.obstacles import Capsules
from agent.control.settings import ControllerSettings
from agent.control.view import EnvironmentView
from agent.control.walk_lines import LineFit, Walk, WalkRegistry
from agent.kinematics.vehicle import VehicleSpec

__all__ = ["WalkwayMemory"]

_PARALLEL = math.cos(math.radians(25.0))  # a mover along the same line, within this angle
_SAME_LINE_M = 0.5  # ... and this near the line and its possible cells
_SENSE_SPAN_S = 0.5  # which way a walker walks: its places this long apart ...
_SENSE_MIN_M = 0.15  # ... this far apart along its line (the places' noise: a few cm)
_SHORT_SPAN_S = 0.3  # or a shorter track's places this long apart ...
_SHORT_MIN_M = 0.08  # ... this far apart the way its velocity goes (3σ of 2-3 cm places)
_TURN_SLACK_CELLS = 2  # a walk's end may lie this many cells short of its furthest place
_PIECE_M = 0.5  # a run of possible cells is this long a capsule at most
_TURNED_AT_END_M = 0.3  # a turn this near a walk's furthest place that way is its end


@dataclass
class _Walk:
    """One remembered walker: its line, and where on it it may be."""

    origin: FloatArray  # (2,) its last position
    direction: FloatArray  # (2,) unit, its last velocity's
    speed: float  # the fastest it was seen to walk
    radius: float
    sigma_m: float  # its position's largest σ when last seen
    sigma_rad: float  # its line's direction σ then (velocity σ across it over its speed)
    seen_s: float  # when last in a vector
    updated_s: float  # when the set last grew
    carry_m: float  # growth not yet a whole cell
    ahead: BoolArray  # (n,) over the cells along the line: where it may be walking on
    back: BoolArray  # (n,) ... where it may be walking back (against ``direction``)
    turn_ahead: int = 0  # the first cell at which it may turn back (its walk's end)
    turn_back: int = 0  # ... the last at which, walking back, it may turn again
    stop_ahead: int = 10**9  # the last cell it may reach walking on (it turns there)
    stop_back: int = 0  # ... the first it may reach walking back
    sightings: int = 1  # vectors in which it was a mover
    walk: Walk | None = None  # its walk (:class:`WalkRegistry`), across tracks
    line: LineFit | None = None  # its walk's fitted line when last seen (else its velocity's)
    standing_s: float | None = None  # since when its own track, seen, stands still

    @property
    def possible(self) -> BoolArray:
        """(n,) the cells where it may be, walking either way."""
        return self.ahead | self.back


def _runs(mask: BoolArray) -> list[tuple[int, int]]:
    """Contiguous runs of ``True`` in ``mask``, as (first, last) indices."""
    edges = np.diff(np.concatenate([[0], mask.astype(np.int8), [0]]))
    starts = np.flatnonzero(edges == 1)
    ends = np.flatnonzero(edges == -1) - 1
    return list(zip(starts.tolist(), ends.tolist(), strict=True))


def _spread(mask: BoolArray, cells: int, sense: int) -> BoolArray:
    """``mask`` grown by ``cells`` one way: toward higher indices (``sense`` 1) or lower
    (-1); held at the array's end."""
    if cells <= 0 or not mask.any():
        return mask
    reached = np.cumsum(mask[::sense]) > 0  # at or past the first set cell, that way
    idx = np.arange(mask.size)[::sense]
    last = np.maximum.accumulate(np.where(mask[::sense], idx * sense, -(10**9)))
    within = reached & (idx * sense - last <= cells)
    return np.asarray(within[::sense], dtype=np.bool_)


def _dilate(mask: BoolArray, cells: int) -> BoolArray:
    """``mask`` grown by ``cells`` both ways."""
    if cells <= 0 or not mask.any():
        return mask
    kernel = np.ones(2 * cells + 1)
    return np.convolve(mask.astype(np.float64), kernel, mode="same") > 0.5


def profile_clear(view: EnvironmentView, ranges: FloatArray, pose: FloatArray,
                  head_offset_m: float, points: FloatArray) -> BoolArray:  # fmt: skip
    """Which ``points`` (n, 2), ``odom``, a profile of ``view`` (``ranges`` over its
    bearings) holds clear, the vehicle at ``pose`` (3,) at its stamp (bearings from the
    centre of scanning)."""
    bearings = view.free_bearing_rad
    if not bearings.size or not points.size:
        return np.zeros(len(points), dtype=np.bool_)
    c, s = math.cos(pose[2]), math.sin(pose[2])
    centre = np.array([pose[0] + head_offset_m * c, pose[1] + head_offset_m * s])
    d = points - centre
    r = np.hypot(d[:, 0], d[:, 1])
    bearing = np.arctan2(d[:, 1], d[:, 0]) - pose[2]
    step = 2.0 * math.pi / bearings.size
    # Bearings are the sectors' centres.
    k = np.floor(np.mod(bearing - bearings[0] + 0.5 * step, 2.0 * math.pi) / step).astype(np.int64)
    k = np.clip(k, 0, bearings.size - 1)
    return np.asarray(r <= ranges[k], dtype=np.bool_)


class WalkwayMemory:
    """The walkers of recent vectors, kept on their walks after they leave it (module
    docstring)."""

    def __init__(self, spec: VehicleSpec, settings: ControllerSettings) -> None:
        self.spec = spec
        self.settings = settings
        n = 2 * round(settings.walkway_reach_m / settings.walkway_cell_m) + 1
        self._s = (np.arange(n) - n // 2) * settings.walkway_cell_m  # along the line, m
        self._walks: dict[int, _Walk] = {}
        self.walkers = Walkers.none()
        self.lines: dict[int, LineFit] = {}  # the vector's movers' fitted lines, by id
        self.turns: dict[int, FloatArray] = {}  # ... where on them they turn back, by id
        # ... which way each walks (unit, ``odom``), how far on before it may turn back (0
        # where the way is not known), and how far back and on its walk ends where it was
        # seen to turn (else ∓inf): :class:`Walkers`' ``onward`` and ``span``
        self.ends: dict[int, tuple[FloatArray, float, float, float]] = {}
        self._in_view: set[int] = set()
        self.registry = WalkRegistry(
            trail_n=settings.walk_trail_n, min_points=settings.walk_fit_points,
            min_span_m=settings.walk_fit_span_m, memory_s=settings.walkway_memory_s,
        )  # fmt: skip

    def __len__(self) -> int:
        return len(self._walks)

    def update(self, view: EnvironmentView, capsules: Capsules, pose: FloatArray) -> Capsules:
        """Remember the view's movers (``capsules``: :func:`capsules_from_view`'s), grow and
        clear the others' walks with the view's profile (the vehicle at ``pose`` at its
        stamp); the remembered walkers' possible places as moving capsules. Sets
        :attr:`walkers` for giving way."""
        st = self.settings
        now = view.stamp_s
        moving = np.flatnonzero(capsules.moving)
        velocity = np.asarray(view.velocity_xy, dtype=np.float64)
        covariance = np.asarray(view.covariance, dtype=np.float64)
        here = np.zeros(self._s.size, dtype=np.bool_)
        here[self._s.size // 2] = True
        in_view: set[int] = set()
        self.lines = {}
        self.turns = {}
        self.ends = {}
        self.registry.observe(
            now, capsules.obstacle_id[moving], capsules.a[moving], velocity[moving]
        )
        for k in moving.tolist():
            i = int(capsules.obstacle_id[k])
            v = velocity[k]
            speed = float(np.hypot(v[0], v[1]))
            before = self._walks.get(i)
            place = capsules.a[k].copy()
            walk_of = self.registry.walk_of(i)
            line = None if walk_of is None else walk_of.line
            if line is not None:
                # Its walk's line (:mod:`agent.control.walk_lines`).
                self.lines[i] = line
                direction = line.toward(v)
                sigma_rad = line.sigma_rad
            else:
                direction = v / speed
                normal = np.array([-direction[1], direction[0]])
                sigma_rad = math.sqrt(max(float(normal @ covariance[k, 2:, 2:] @ normal), 0.0))
                sigma_rad /= speed
            in_view.add(i)
            # The fastest it was seen to walk: a walker turning back at its walk's end is
            # seen slow for a vector or two, and walks on at its pace (measured: random run
            # 29 of seed 0, a walker lost while it turned, kept growing at 0.3 m/s, walked
            # back at 0.73 m/s into the vehicle's flank).
            # Its walk's pace where its places show it (:class:`WalkRegistry`), else its
            # velocity's, the fastest seen.
            pace = speed if before is None else max(speed, before.speed)
            if walk_of is not None and walk_of.pace > 0.0:
                pace = walk_of.pace
            # Which way it walks on its line, where it may turn back and where it must
            # (walking on).
            sense, turn_ahead, turn_back, stop_ahead, stop_back = self._bearing_on(
                walk_of, i, place, direction
            )
            heading = -direction if sense < 0 else direction
            onward = float(self._s[turn_ahead]) if sense != 0 else 0.0
            self.ends[i] = (heading, onward, *self._span(*self._ends(stop_back, stop_ahead), 0.0))
            back = here.copy() if sense == 0 else np.zeros_like(here)
            stops = [s for s in (stop_back, stop_ahead) if 0 < s < self._s.size - 1]
            if stops:
                self.turns[i] = place + self._s[stops, None] * heading
            # A walker is kept once a mover in enough vectors, whichever of its walk's
            # tracks they were (a new track that joins a known walk takes over its
            # walker's memory, ``_walked_again``).
            sightings = 1 if before is None else before.sightings + 1
            if walk_of is not None:
                sightings = max(sightings, len(walk_of.places))
            self._walks[i] = _Walk(
                place, heading, pace, float(capsules.radius[k]),
                float(largest_sigma(covariance[k : k + 1, :2, :2])[0]), sigma_rad, now, now,
                0.0, here.copy(), back, turn_ahead, turn_back, stop_ahead, stop_back,
                sightings, walk_of, line,
            )  # fmt: skip
        standing = self._standing(view, capsules)
        for i in [i for i in self._walks if i not in in_view]:
            walk = self._walks[i]
            if walk.line is None:
                self._adopt(walk)
            if i not in standing:
                walk.standing_s = None
            elif walk.standing_s is None:
                walk.standing_s = now
            again = self._seen_again(
                walk, capsules.obstacle_id[moving], capsules.a[moving], velocity[moving]
            )
            for j in again:
                # The track it is seen again by is its walker's: a walker, however few
                # the vectors of that track (random run 1 of seed 0: found again beside
                # the vehicle for two vectors, then lost, the walker was forgotten and
                # walked into the vehicle as it drove off).
                self._walks[j].sightings = max(self._walks[j].sightings, walk.sightings)
            if (
                walk.sightings < st.walkway_min_sightings
                or (walk.standing_s is not None and now - walk.standing_s >= st.walkway_standing_s)
                or now - walk.seen_s > st.walkway_memory_s
                or (walk.line is None and now - walk.seen_s > st.walkway_unfitted_memory_s)
                or again
                or self._walked_again(walk, in_view)
            ):
                del self._walks[i]
                continue
            walk.carry_m += walk.speed * max(now - walk.updated_s, 0.0)
            walk.updated_s = now
            # (0.5 // 0.1 is 4.0 in floating point: a hair's allowance)
            grow = math.floor(walk.carry_m / st.walkway_cell_m + 1e-9)
            walk.carry_m -= grow * st.walkway_cell_m
            self._walk_on(walk, grow)
            clear = self._seen_clear(view, pose, walk)
            walk.ahead &= ~clear
            walk.back &= ~clear
            if not walk.possible.any():
                del self._walks[i]
        self._in_view = in_view
        return self._capsules(in_view, now)

    def _standing(self, view: EnvironmentView, capsules: Capsules) -> set[int]:
        """The ids of the vector's obstacles that a scan of the last ``walkway_seen_age_s``
        updated and that do not move: a remembered walker whose own track is among them
        stands where it is seen (a static post's track that passed for a mover for a few
        vectors, or a walker that stopped), and is not walking its walk. None at all when
        the vector does not say how old its obstacles' sightings are (an older agent)."""
        age = view.seen_age_s
        if age.size != capsules.obstacle_id.size:
            return set()
        still = ~capsules.moving & (age <= self.settings.walkway_seen_age_s)
        return set(capsules.obstacle_id[still].tolist())

    def _bearing_on(
        self, walk: Walk | None, track: int, place: FloatArray, direction: FloatArray
    ) -> tuple[int, int, int, int, int]:
        """Which way along ``direction`` a walker at ``place`` walks (1 along it, -1 against
        it, 0 not known); the cells of :attr:`_s` from which it may turn back walking that
        way and the other, and the last cells it may reach each way (module docstring:
        *walking on*)."""
        centre = self._s.size // 2
        last = self._s.size - 1
        if walk is None or walk.line is None:
            return 0, centre, centre, last, 0
        cell = self.settings.walkway_cell_m
        mine = walk.ids == track
        t, xy = walk.times[mine], walk.places[mine]
        s_track = (xy - place) @ direction
        sense = 0
        earlier = np.flatnonzero(t <= t[-1] - _SENSE_SPAN_S)
        if earlier.size:
            moved = -float(s_track[earlier[-1]])  # from that place to here
            if abs(moved) >= _SENSE_MIN_M:
                sense = 1 if moved > 0.0 else -1
        short = float(t[-1] - t[0]) >= _SHORT_SPAN_S and -float(s_track[0]) >= _SHORT_MIN_M
        if sense == 0 and short:  # ``direction`` is its velocity's way
            sense = 1
        seen = walk.places if walk.ends is None else np.concatenate([walk.ends, walk.places])
        along = (seen - place) @ direction * (sense if sense else 1)
        far = math.floor(float(along.max()) / cell) - _TURN_SLACK_CELLS
        near = math.ceil(float(along.min()) / cell) + _TURN_SLACK_CELLS
        stop_ahead, stop_back = last, 0
        if walk.turns is not None:
            # An end where it was seen to turn, at about its furthest place that way: it
            # turns there again, a little beyond at most.
            turned = (walk.turns - place) @ direction * (sense if sense else 1)
            hi, lo = float(along.max()), float(along.min())
            if float(turned.max()) >= hi - _TURNED_AT_END_M:
                hi = max(hi, float(turned.max()))
                stop_ahead = centre + math.ceil(hi / cell) + _TURN_SLACK_CELLS
            if float(turned.min()) <= lo + _TURNED_AT_END_M:
                lo = min(lo, float(turned.min()))
                stop_back = centre + math.floor(lo / cell) - _TURN_SLACK_CELLS
        return (
            sense, min(max(centre + far, centre), last), max(min(centre + near, centre), 0),
            min(max(stop_ahead, centre), last), max(min(stop_back, centre), 0),
        )  # fmt: skip

    def _walk_on(self, walk: _Walk, cells: int) -> None:
        """Its walker walks on ``cells`` either way it may be walking, turning back where
        its walk may end (at or beyond the furthest place its walk was seen at, each way;
        at the reach's ends)."""
        if cells <= 0:
            return
        idx = np.arange(self._s.size)
        ahead = _spread(walk.ahead, cells, 1)
        back = _spread(walk.back, cells, -1)
        turned_back = ahead & ((idx >= walk.turn_ahead) | (idx == idx[-1]))
        turned_ahead = back & ((idx <= walk.turn_back) | (idx == 0))
        walk.ahead = ahead | _spread(turned_ahead, cells, 1)
        walk.back = back | _spread(turned_back, cells, -1)
        # Not past an end where it was seen to turn (it turned back there: the cells it
        # would have reached beyond joined the other way's).
        beyond = (idx > walk.stop_ahead) | (idx < walk.stop_back)
        walk.ahead &= ~beyond
        walk.back &= ~beyond

    def _ends(self, stop_back: int, stop_ahead: int) -> tuple[float, float]:
        """Where a walk ends back and on (m along its line from where its walker was last
        seen): the cells of :attr:`_s` where it was seen to turn (``stop_back``,
        ``stop_ahead``), ``∓inf`` where not (the array's ends)."""
        floor = float(self._s[stop_back]) if stop_back > 0 else -math.inf
        top = float(self._s[stop_ahead]) if stop_ahead < self._s.size - 1 else math.inf
        return floor, top

    @staticmethod
    def _span(floor: float, top: float, mid: float) -> tuple[float, float]:
        """How far back and on from ``mid`` (m along its line) a walker's centre may go,
        its walk ending at ``floor`` and ``top`` (:meth:`_ends`)."""
        return min(floor - mid, 0.0), max(top - mid, 0.0)

    def possible_places(self, xy: FloatArray, reach_m: float, limit: int) -> FloatArray:
        """(k, 2) ``odom``: the places where the remembered walkers may be (their possible
        cells' centres) within ``reach_m`` of ``xy``, nearest first, at most ``limit``:
        where a look would find them, or free their walks."""
        points = [
            walk.origin + self._s[walk.possible, None] * walk.direction
            for i, walk in self._walks.items()
            if i not in self._in_view
        ]
        if not points:
            return np.zeros((0, 2))
        places = np.concatenate(points)
        gap = np.hypot(places[:, 0] - xy[0], places[:, 1] - xy[1])
        order = np.argsort(gap, kind="stable")
        order = order[gap[order] <= reach_m][:limit]
        return np.asarray(places[order], dtype=np.float64)

    def _seen_clear(self, view: EnvironmentView, pose: FloatArray, walk: _Walk) -> BoolArray:
        """The cells of ``walk`` where its walker cannot be now: seen clear by the scans of
        the last ``walkway_seen_age_s`` (the vector's seen profile; the aged profile for an
        agent that sends none), less the way it could have walked into them since."""
        st = self.settings
        points = walk.origin + self._s[:, None] * walk.direction
        seen = view.seen_range_m.size == view.free_bearing_rad.size
        ranges = view.seen_range_m if seen else view.free_range_m
        clear = profile_clear(view, ranges, pose, self.spec.head_offset_m, points)
        if seen:
            reach = math.ceil(walk.speed * st.walkway_seen_age_s / st.walkway_cell_m)
            clear &= ~_dilate(~clear, reach)
        return clear

    def _adopt(self, walk: _Walk) -> None:
        """A walker lost before its line could be fitted, where a fitted walk's line
        passes (:meth:`WalkRegistry.find`, any way): kept on that walk's line, and
        forgotten, as any walker of a known walk, when the walk's walker is in the vector
        again (module docstring)."""
        found = self.registry.find(walk.origin, np.zeros(2))
        if found is None or found.line is None:
            return
        walk.walk, walk.line = found, found.line
        walk.direction = found.line.toward(walk.direction)
        walk.sigma_rad = found.line.sigma_rad

    def _walked_again(self, walk: _Walk, in_view: set[int]) -> bool:
        """Whether a mover of the vector walks ``walk``'s walk (a new track of its walker)."""
        if walk.walk is None:
            return False
        mine = self.registry.current(walk.walk)
        return any(self.registry.walk_of(i) is mine for i in in_view)

    def _seen_again(
        self, walk: _Walk, ids: NDArray[np.int64], position: FloatArray, velocity: FloatArray
    ) -> list[int]:
        """The movers of the vector (track ``ids``) that walk where ``walk``'s walker may
        be, along its line; not one whose track walks another fitted walk than the
        walker's (two walkers on walks 0.6 m apart, random run 67 of seed 0: the one in
        view took the other's place in the memory, and the other walked into the
        vehicle)."""
        mine = None if walk.walk is None else self.registry.current(walk.walk)
        if mine is not None and mine.line is not None:
            other = [
                (w := self.registry.walk_of(i)) is not None
                and w is not mine and w.line is not None
                for i in ids.tolist()
            ]  # fmt: skip
            keep = ~np.asarray(other, dtype=np.bool_)
            ids, position, velocity = ids[keep], position[keep], velocity[keep]
        if not len(position):
            return []
        rel = position - walk.origin
        along = rel @ walk.direction
        across = np.abs(rel[:, 0] * walk.direction[1] - rel[:, 1] * walk.direction[0])
        speed = np.maximum(np.hypot(velocity[:, 0], velocity[:, 1]), 1e-9)
        parallel = np.abs(velocity @ walk.direction) / speed >= _PARALLEL
        cells = np.round(along / self.settings.walkway_cell_m).astype(np.int64) + self._s.size // 2
        near = _dilate(walk.possible, round(_SAME_LINE_M / self.settings.walkway_cell_m))
        inside = (cells >= 0) & (cells < self._s.size)
        on_walk = np.zeros(len(position), dtype=np.bool_)
        on_walk[inside] = near[cells[inside]]
        return [int(i) for i in ids[parallel & (across < _SAME_LINE_M) & on_walk]]

    def _capsules(self, in_view: set[int], now: float) -> Capsules:
        st = self.settings
        a, b, radius, inflation, ids = [], [], [], [], []
        w_pos, w_vel, w_rad, w_age, w_span = [], [], [], [], []
        for i, walk in self._walks.items():
            if i in in_view:
                continue
            sweep = walk.speed * st.mover_horizon_s
            # Reaches are from the fitted line's centre, else from where it was last seen.
            line, mid = walk.line, 0.0
            if line is not None and line.centre is not None:
                mid = float((line.centre - walk.origin) @ walk.direction)
            else:
                line = None
            # Not swept past an end where it turns (:meth:`_walk_on`).
            floor, top = self._ends(walk.stop_back, walk.stop_ahead)
            for first, last in _runs(walk.possible):
                s0, s1 = self._s[first], self._s[last]
                lo_s, hi_s = max(s0 - sweep, min(floor, s0)), min(s1 + sweep, max(top, s1))
                # In pieces, each inflated for its own farthest reach: one capsule took the
                # whole run's, metres out along the line, even beside the vehicle.
                n = max(math.ceil((hi_s - lo_s) / _PIECE_M), 1)
                ends = np.linspace(lo_s, hi_s, n + 1)
                for lo, hi in itertools.pairwise(ends.tolist()):
                    a.append(walk.origin + lo * walk.direction)
                    b.append(walk.origin + hi * walk.direction)
                    radius.append(walk.radius)
                    # Its place across the line: where it was, and the direction's error
                    # over the piece's farthest reach along it.
                    reach = max(abs(lo - mid), abs(hi - mid))
                    if line is not None:  # on its fitted line: the line's own σ across
                        spread = st.covariance_sigmas * line.across_sigma_m(reach)
                    else:
                        spread = st.covariance_sigmas * math.hypot(
                            walk.sigma_m, walk.sigma_rad * reach
                        )
                    inflation.append(min(spread, st.mover_inflation_cap_m) + st.obstacle_margin_m)
                    ids.append(i)
                w_pos.append(walk.origin + 0.5 * (s0 + s1) * walk.direction)
                w_vel.append(walk.speed * walk.direction)
                w_rad.append(walk.radius)
                w_age.append(max(0.5 * (s1 - s0) / walk.speed, 1e-6))
                w_span.append(self._span(floor, top, 0.5 * (s0 + s1)))
        m, k = len(w_pos), len(a)
        self.walkers = Walkers(
            np.array(w_pos).reshape(m, 2), np.array(w_vel).reshape(m, 2), np.array(w_rad),
            np.array(w_age), now, np.zeros(m), np.array(w_span).reshape(m, 2),
        )  # fmt: skip
        return Capsules(
            np.array(a).reshape(k, 2), np.array(b).reshape(k, 2), np.array(radius),
            np.array(inflation), np.ones(k, dtype=np.bool_), np.array(ids, dtype=np.int64),
        )  # fmt: skip
