"""The navigation field: cost-to-go toward the goal over a grid in ``odom``, with a memory.

A local planner that scores arcs on the straight distance to the goal stops in front of the
first concave obstacle (a U, a corner between two boxes): every arc makes things worse. The
cure is a cost-to-go without local minima, a *navigation function* in the sense of
Brock & Khatib's global dynamic window (1999): the arcs are scored on the field's value where
they end, and the field leads round what was seen, out of dead ends.

**The map.** A grid (``nav_cell_m``, covering vehicle and goal with ``nav_margin_m`` about
them) remembers, per cell, when a profile last showed it clear, when a static obstacle's
core was last in it (segments and docking targets along their length, corners and edges at
their point, cylinders round their rim; movers are left to the local check), and when a
profile last showed a possible surface there (not where a tracked mover is: its own hits).
A cell is *occupied* when an obstacle (or, within ``suspect_memory_s``, a possible surface)
was seen there no earlier than it was seen clear: the memory outlives the tracks (which
vanish after 30 s of coasting) until the sensor sees the place clear again.

**The field.** With ``D(c)`` the distance from cell ``c`` to the nearest occupied cell (a
Euclidean distance transform), ``r_in`` the vehicle's half-width plus ``nav_clearance_m``
and ``r_out`` its circumradius plus the same, each cell costs, per metre crossed,

    k(c) = L                                             if D < r_in   (lethal)
    k(c) = u(c) · (1 + N · (r_out − D)/(r_out − r_in))   if r_in <= D < r_out
    k(c) = u(c)                                          otherwise

with ``u = nav_unknown_cost`` for a cell never seen clear and 1 for one seen clear: unknown
space is passable at a higher cost. Lethal cells cost ``L`` (finite), so the field still
leads out of one. The cost-to-go is the shortest path over the 8-connected grid, each step
costing its length times the mean of its two cells' costs,

    C(c) = min over paths c → goal of  Σ |Δ| · (k(c_i) + k(c_{i+1}))/2

(Dijkstra from the goal, ``scipy.sparse.csgraph.dijkstra``; a virtual source joins the
goal's cells at their distance from the goal, so C is continuous about it). C has no local
minimum but the goal: from every cell some neighbour is cheaper.
"""

from __future__ import annotations

import math

import numpy as np
from scipy import ndimage
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import dijkstra

from agent.arrays import FloatArray
from agent.control import navigation_kernels as kernels
from agent.control.clearance import forget_movers_hits, record_profile
from agent.control.obstacles import Capsules
from agent.control.settings import ControllerSettings
from agent.control.view import EnvironmentView
from agent.kinematics.vehicle import VehicleSpec

__all__ = ["NavigationField", "core_points"]

_NEIGHBOURS = ((0, 1), (1, 0), (0, -1), (-1, 0), (1, 1), (1, -1), (-1, 1), (-1, -1))
_FAR = 1e9  # the virtual source's edges to cells that are not the goal's


class NavigationField:
    """The map and its cost-to-go (module docstring). Frame ``odom``; metres."""

    def __init__(self, spec: VehicleSpec, settings: ControllerSettings) -> None:
        self.spec = spec
        self.settings = settings
        self.origin_xy = np.zeros(2)
        self.cell_m = settings.nav_cell_m
        self.shape = (0, 0)
        self.clear_s = np.zeros((0, 0))
        self.obstacle_s = np.zeros((0, 0))
        self.suspect_s = np.zeros((0, 0))
        self.cost_to_go: FloatArray | None = None
        self.next_cell: np.ndarray | None = None
        self.computed_s = -math.inf
        self._occupied: np.ndarray | None = None
        self._goal: tuple[float, float, float] | None = None
        self._graph: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray,
                           np.ndarray] | None = None  # fmt: skip
        self._limit = math.inf
        self._top = 0.0

    # ------------------------------------------------------------------ the grid
    def covers(self, xy: FloatArray, border_m: float) -> bool:
        """Whether ``xy`` (2,) lies in the grid at least ``border_m`` from its edge."""
        # In floats, not 2-element arrays: four calls a command at 12 µs each were 3 % of a
        # command's time; the same arithmetic in the same order.
        if self.shape == (0, 0):
            return False
        n_y, n_x = self.shape
        ox, oy = float(self.origin_xy[0]), float(self.origin_xy[1])
        x, y = float(xy[0]), float(xy[1])
        return (
            ox + border_m <= x <= ox + n_x * self.cell_m - border_m
            and oy + border_m <= y <= oy + n_y * self.cell_m - border_m
        )

    def fit(self, vehicle_xy: FloatArray, goal_xy: FloatArray) -> None:
        """Make the grid cover vehicle and goal with the margin, keeping what it holds."""
        st = self.settings
        lo = np.minimum(vehicle_xy, goal_xy) - st.nav_margin_m
        hi = np.maximum(vehicle_xy, goal_xy) + st.nav_margin_m
        cell = max(st.nav_cell_m, float(np.max(hi - lo)) / st.nav_max_cells)
        origin = np.floor(lo / cell) * cell
        n_x, n_y = (int(v) for v in np.ceil((hi - origin) / cell))
        old = (self.origin_xy, self.cell_m, self.shape, self.clear_s, self.obstacle_s,
               self.suspect_s)  # fmt: skip
        self.origin_xy, self.cell_m, self.shape = origin, cell, (n_y, n_x)
        self.clear_s = np.full(self.shape, -np.inf)
        self.obstacle_s = np.full(self.shape, -np.inf)
        self.suspect_s = np.full(self.shape, -np.inf)
        if old[2] != (0, 0):  # carry the memory over, nearest cell
            ys = origin[1] + (np.arange(n_y) + 0.5) * cell
            xs = origin[0] + (np.arange(n_x) + 0.5) * cell
            oy = np.floor((ys - old[0][1]) / old[1]).astype(np.int64)
            ox = np.floor((xs - old[0][0]) / old[1]).astype(np.int64)
            in_y = (oy >= 0) & (oy < old[2][0])
            in_x = (ox >= 0) & (ox < old[2][1])
            rows, cols = np.ix_(np.nonzero(in_y)[0], np.nonzero(in_x)[0])
            src = np.ix_(oy[in_y], ox[in_x])
            self.clear_s[rows, cols] = old[3][src]
            self.obstacle_s[rows, cols] = old[4][src]
            self.suspect_s[rows, cols] = old[5][src]
        self.cost_to_go = None
        self.next_cell = None
        self._occupied = None
        self._graph = None
        self._goal = None
        self._limit = math.inf

    # ------------------------------------------------------------------ the memory
    def add_view(
        self, view: EnvironmentView, pose_at_stamp: FloatArray, capsules: Capsules
    ) -> None:
        """Record a vector: the space its profile shows clear, its possible surfaces, and
        its static obstacles' cores."""
        if self.shape == (0, 0):
            return
        t = view.stamp_s
        record_profile(
            view, pose_at_stamp, self.origin_xy, self.cell_m, self.clear_s, self.suspect_s,
            self.spec.head_offset_m, self.settings,
        )  # fmt: skip
        forget_movers_hits(self.suspect_s, self.origin_xy, self.cell_m, capsules, self.settings)
        static = capsules.select(~capsules.moving)
        if not len(static):
            return
        kernels.mark_cores(
            self.obstacle_s, t, float(self.origin_xy[0]), float(self.origin_xy[1]),
            self.cell_m, static.a, static.b, static.radius,
        )  # fmt: skip

    def occupied(self, now_s: float) -> np.ndarray:
        """(ny, nx) bool: cells holding an obstacle (or a recent possible surface) seen
        there no earlier than the cell was last seen clear."""
        obstacle = (self.obstacle_s > -np.inf) & (self.obstacle_s >= self.clear_s)
        recent = self.suspect_s >= now_s - self.settings.suspect_memory_s
        return np.asarray(obstacle | (recent & (self.suspect_s >= self.clear_s)))

    # ------------------------------------------------------------------ the field
    def update(
        self, now_s: float, goal_xy: FloatArray, goal_radius_m: float, vehicle_xy: FloatArray
    ) -> bool:
        """Recompute the field if the goal moved, or if the map changed and the last
        computation is ``nav_period_s`` old. Returns whether it was recomputed."""
        goal = (float(goal_xy[0]), float(goal_xy[1]), float(goal_radius_m))
        moved = (
            self.cost_to_go is None
            or self._goal is None
            or math.hypot(goal[0] - self._goal[0], goal[1] - self._goal[1]) > 0.05
            or goal[2] != self._goal[2]
        )
        if not moved and now_s - self.computed_s < self.settings.nav_period_s:
            return False
        occupied = self.occupied(now_s)
        if not moved and self._occupied is not None and np.array_equal(occupied, self._occupied):
            self.computed_s = now_s
            return False
        self._compute(occupied, goal, vehicle_xy)
        self._occupied = occupied
        self._goal = goal
        self.computed_s = now_s
        return True

    def _compute(
        self, occupied: np.ndarray, goal: tuple[float, float, float], vehicle_xy: FloatArray
    ) -> None:
        st = self.settings
        n_y, n_x = self.shape
        n = n_y * n_x
        cell = self.cell_m
        if occupied.any():
            D = ndimage.distance_transform_edt(~occupied) * cell
        else:
            D = np.full(self.shape, np.inf)
        r_in = 0.5 * min(self.spec.width_m, self.spec.length_m) + st.nav_clearance_m
        r_out = self.spec.circumradius_m + st.nav_clearance_m
        unknown = np.where(self.clear_s > -np.inf, 1.0, st.nav_unknown_cost)
        near = np.clip((r_out - D) / (r_out - r_in), 0.0, 1.0)
        k = np.where(r_in > D, st.nav_lethal_cost, unknown * (1.0 + st.nav_near_cost * near))
        rows, cols, lengths, indptr, indices, perm = self._structure()
        k_flat = np.append(k.ravel(), 0.0)
        weights = lengths * 0.5 * (k_flat[rows] + k_flat[cols])
        # The virtual source (node n) joins the goal's cells.
        xs = self.origin_xy[0] + (np.arange(n_x) + 0.5) * cell
        ys = self.origin_xy[1] + (np.arange(n_y) + 0.5) * cell
        gx, gy, radius = goal
        dist = np.hypot(xs[None, :] - gx, ys[:, None] - gy).ravel()
        ring = np.maximum(dist - radius, 0.0)
        sources = ring <= max(0.75 * cell, 1e-9)
        if radius > 0.0:
            sources &= k.ravel() < st.nav_lethal_cost
        if not sources.any():
            sources = dist <= dist.min() + 1e-9
        weights[-n:] = np.where(sources, ring * k.ravel(), _FAR)
        graph = csr_matrix((weights[perm], indices, indptr), shape=(n + 1, n + 1))
        source = np.array([n])
        cost = dijkstra(graph, directed=True, indices=source, limit=self._limit)[0, :n]
        vi = self._cell_index(vehicle_xy)
        if self._limit < math.inf and (vi is None or not np.isfinite(cost[vi])):
            cost = dijkstra(graph, directed=True, indices=source)[0, :n]
        C = cost.reshape(self.shape)
        finite = np.isfinite(C)
        top = float(C[finite].max()) if finite.any() else 0.0
        C = np.where(finite, C, top + st.nav_lethal_cost)
        self.cost_to_go = C
        self._top = float(C.max())
        self._goal = goal
        # Pointers to each cell's cheapest neighbour, for the intended path.
        padded = np.pad(C, 1, constant_values=np.inf)
        best = np.full(self.shape, np.inf)
        nxt = np.arange(n).reshape(self.shape)
        flat = nxt.copy()
        for dy, dx in _NEIGHBOURS:
            cand = padded[1 + dy : 1 + dy + n_y, 1 + dx : 1 + dx + n_x]
            better = (cand < best) & (cand < C)
            best = np.where(better, cand, best)
            nxt = np.where(better, flat + dy * n_x + dx, nxt)
        self.next_cell = nxt.ravel()
        vehicle_cost = self.value(vehicle_xy[None])[0]
        self._limit = vehicle_cost * 1.5 + 5.0

    def _cell_index(self, xy: FloatArray) -> int | None:
        ix = math.floor((xy[0] - self.origin_xy[0]) / self.cell_m)
        iy = math.floor((xy[1] - self.origin_xy[1]) / self.cell_m)
        if 0 <= ix < self.shape[1] and 0 <= iy < self.shape[0]:
            return int(iy * self.shape[1] + ix)
        return None

    def _structure(
        self,
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """The 8-connected grid graph with a virtual source: edge rows, columns and lengths
        (in the order weights are given), and the CSR structure with the permutation that
        puts weights in its order. Built once per grid shape."""
        if self._graph is not None:
            return self._graph
        n_y, n_x = self.shape
        n = n_y * n_x
        index = np.arange(n).reshape(self.shape)
        rows, cols, lengths = [], [], []
        for dy, dx in _NEIGHBOURS:
            ys, xs = np.mgrid[0:n_y, 0:n_x]
            y2, x2 = ys + dy, xs + dx
            ok = (y2 >= 0) & (y2 < n_y) & (x2 >= 0) & (x2 < n_x)
            rows.append(index[ok])
            cols.append(index[y2[ok], x2[ok]])
            lengths.append(np.full(int(ok.sum()), math.hypot(dx, dy) * self.cell_m))
        rows.append(np.full(n, n))
        cols.append(np.arange(n))
        lengths.append(np.ones(n))
        r, c, ln = np.concatenate(rows), np.concatenate(cols), np.concatenate(lengths)
        order = csr_matrix((np.arange(1.0, r.size + 1.0), (r, c)), shape=(n + 1, n + 1))
        perm = order.data.astype(np.int64) - 1
        self._graph = (r, c, ln, order.indptr, order.indices, perm)
        return self._graph

    # ------------------------------------------------------------------ queries
    def value(self, xy: FloatArray) -> FloatArray:
        """The cost-to-go (m) at points ``(n, 2)``, bilinear between cell centres; outside
        the grid, the largest value plus the distance to the goal."""
        return kernels.field_values(*self._lookup_args(xy))

    def descent(self, xy: FloatArray) -> FloatArray:
        """The direction of steepest descent of the field (rad, ``odom``) at ``(n, 2)``,
        from central differences one cell apart."""
        return kernels.field_descent(*self._lookup_args(xy))

    def _lookup_args(
        self, xy: FloatArray
    ) -> tuple[FloatArray, float, float, float, FloatArray, float, float, float]:
        C = self.cost_to_go
        if C is None or self._goal is None:
            raise ValueError("NavigationField: no field computed yet")
        return (
            C, float(self.origin_xy[0]), float(self.origin_xy[1]), self.cell_m,
            np.ascontiguousarray(xy, dtype=np.float64), self._top, self._goal[0], self._goal[1],
        )  # fmt: skip

    def lookahead(self, xy: FloatArray, length_m: float) -> FloatArray:
        """The point (2,) about ``length_m`` down the field from ``xy`` (2,) along its
        cheapest neighbours (the goal, or ``xy``, if the path is shorter)."""
        path = self.path(xy, length_m, length_m)
        return np.asarray(path[-1] if len(path) else xy, dtype=np.float64)

    def path(self, xy: FloatArray, length_m: float, spacing_m: float) -> FloatArray:
        """Waypoints ``(p, 2)`` down the field from ``xy`` (2,), about ``spacing_m`` apart,
        for about ``length_m``; the first is ``xy``'s cell's centre (compiled:
        :func:`~agent.control.navigation_kernels.path_points`, the walk :meth:`path_reference`
        takes cell by cell in Python, 35 µs a call and two calls a command)."""
        if self.next_cell is None:
            return np.zeros((0, 2))
        n_y, n_x = self.shape
        return kernels.path_points(
            self.next_cell, n_y, n_x, float(self.origin_xy[0]), float(self.origin_xy[1]),
            self.cell_m, float(xy[0]), float(xy[1]), int(length_m / self.cell_m),
            max(1, round(spacing_m / self.cell_m)),
        )  # fmt: skip

    def path_reference(self, xy: FloatArray, length_m: float, spacing_m: float) -> FloatArray:
        """:meth:`path` in Python and numpy."""
        if self.next_cell is None:
            return np.zeros((0, 2))
        i = self._cell_index(xy)
        if i is None:
            return np.zeros((0, 2))
        n_x = self.shape[1]
        cells = [i]
        every = max(1, round(spacing_m / self.cell_m))
        for _ in range(int(length_m / self.cell_m)):
            j = int(self.next_cell[cells[-1]])
            if j == cells[-1]:
                break
            cells.append(j)
        picked = np.array(cells[::every] + ([cells[-1]] if (len(cells) - 1) % every else []))
        return np.stack(
            [
                self.origin_xy[0] + (picked % n_x + 0.5) * self.cell_m,
                self.origin_xy[1] + (picked // n_x + 0.5) * self.cell_m,
            ],
            axis=1,
        )


def core_points(capsules: Capsules, spacing_m: float) -> FloatArray:
    """Points ``(q, 2)`` at most ``spacing_m`` apart along each capsule's core, and round
    the rim of those with a radius (cylinders): the numpy reference of
    :func:`~agent.control.navigation_kernels.mark_cores`."""
    length = np.hypot(*(capsules.b - capsules.a).T)
    count = np.ceil(length / spacing_m).astype(np.int64) + 1
    owner = np.repeat(np.arange(len(capsules)), count)
    start = np.cumsum(count) - count
    f = (np.arange(int(count.sum())) - start[owner]) / np.maximum(count - 1, 1)[owner]
    along = capsules.a[owner] + f[:, None] * (capsules.b - capsules.a)[owner]
    rim_count = np.where(
        capsules.radius > 0.0, np.ceil(2 * np.pi * capsules.radius / spacing_m), 0
    ).astype(np.int64)
    if not rim_count.any():
        return np.asarray(along, dtype=np.float64)
    owner = np.repeat(np.arange(len(capsules)), rim_count)
    start = np.cumsum(rim_count) - rim_count
    angle = 2 * np.pi * (np.arange(int(rim_count.sum())) - start[owner]) / rim_count[owner]
    rim = capsules.a[owner] + capsules.radius[owner, None] * np.stack(
        [np.cos(angle), np.sin(angle)], 1
    )
    return np.asarray(np.concatenate([along, rim]), dtype=np.float64)
