"""Tests of the limits a world file is held to, and of walls that meet themselves.

Each limit is tested at the boundary: the largest (or smallest) value allowed loads, the next
one is refused with one line naming the entry.
"""

from __future__ import annotations

import itertools
from fractions import Fraction
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from agent.errors import WorldFileError
from agent.sim.world_checks import (
    MAX_OBSTACLES,
    MAX_TOTAL_WALL_POINTS,
    MAX_WALL_POINTS,
    first_wall_contact,
)
from agent.sim.world_file import load_world, parse_world
from cli.main import main
from tests.unit.sim.conftest import check_single_line_error

pytestmark = pytest.mark.filterwarnings("error")


def _refused(doc: str | dict[str, Any], *fragments: str) -> None:
    with pytest.raises(WorldFileError) as info:
        parse_world(doc)
    check_single_line_error(info.value, None, *fragments)


def _cylinder(x: float = 1.0, radius: float = 0.1, **extra: Any) -> dict[str, Any]:
    return {"center": [x, 0.0], "radius": radius, **extra}


def _zigzag(n: int, y0: float = 0.0) -> list[list[float]]:
    """A wall of ``n`` points 1 cm apart in x, alternately 1 cm up and down: never self-meeting."""
    return [[0.01 * j, y0 + 0.01 * (j % 2)] for j in range(n)]


# --------------------------------------------------------------------------------------------
# Counts
# --------------------------------------------------------------------------------------------


def test_obstacle_count_limit() -> None:
    at_limit = [_cylinder(0.5 * (i % 1000)) for i in range(MAX_OBSTACLES)]
    assert parse_world({"cylinder": at_limit}).n_obstacles == MAX_OBSTACLES
    _refused(
        {"cylinder": at_limit[:-1], "box": [{"center": [0, 0], "size": [1, 1]}] * 2},
        f"world: {MAX_OBSTACLES + 1} obstacles is more than the limit of {MAX_OBSTACLES}",
    )


def test_points_per_wall_limit() -> None:
    world = parse_world({"wall": [{"points": _zigzag(MAX_WALL_POINTS)}]})
    assert world.segments_start.shape == (MAX_WALL_POINTS - 1, 2)
    _refused(
        {"wall": [{"points": [[0, 0], [1, 0]]}, {"points": _zigzag(MAX_WALL_POINTS + 1)}]},
        f"[[wall]] 2: {MAX_WALL_POINTS + 1} points is more than the limit of {MAX_WALL_POINTS}",
    )


def test_points_in_all_walls_limit() -> None:
    n_walls = MAX_TOTAL_WALL_POINTS // MAX_WALL_POINTS
    walls = [{"points": _zigzag(MAX_WALL_POINTS, 0.05 * w)} for w in range(n_walls)]
    # The most pairs of segments the self-meeting test can be given: all of them tested.
    world = parse_world({"wall": walls})
    assert world.segments_start.shape[0] == n_walls * (MAX_WALL_POINTS - 1)
    _refused(
        {"wall": [*walls, {"points": [[0, -1], [1, -1]]}]},
        f"{MAX_TOTAL_WALL_POINTS + 2} points in walls is more than the limit",
    )


# --------------------------------------------------------------------------------------------
# Magnitudes
# --------------------------------------------------------------------------------------------

BOX = "[[box]]\ncenter = [0, 0]\nsize = [0.4, 0.4]\n"


@pytest.mark.parametrize(
    ("allowed", "refused", "fragments"),
    [
        (
            "[[cylinder]]\ncenter = [1000, -1000]\nradius = 0.1\n",
            "[[cylinder]]\ncenter = [1000.001, 0]\nradius = 0.1\n",
            ["[[cylinder]] 1: center must lie within 1000 m of the origin", "got [1000.001, 0.0]"],
        ),
        (
            "[[box]]\ncenter = [-1000, 0]\nsize = [1, 1]\n",
            "[[box]]\ncenter = [0, -1e300]\nsize = [1, 1]\n",
            ["[[box]] 1: center must lie within 1000 m"],
        ),
        (
            "[[wall]]\npoints = [[0, 0], [1000, 0]]\n",
            "[[wall]]\npoints = [[0, 0], [1, 0], [1, 1e9]]\n",
            ["[[wall]] 1: point 3 of points must lie within 1000 m", "got [1.0, 1000000000.0]"],
        ),
        (
            "[vehicle]\npose = [-1000, 1000, 0]\n",
            "[vehicle]\npose = [0, 1001, 0]\n",
            ["[vehicle]: pose must lie within 1000 m"],
        ),
        (
            "[[box]]\ncenter = [0, 0]\nsize = [0.001, 1000]\n",
            "[[box]]\ncenter = [0, 0]\nsize = [0.0009, 1]\n",
            ["[[box]] 1: size's length must be from 1 mm to 1000 m, got 0.0009"],
        ),
        (
            "[[box]]\ncenter = [0, 0]\nsize = [0.001, 1000]\n",
            "[[box]]\ncenter = [0, 0]\nsize = [1, 1000.5]\n",
            ["[[box]] 1: size's width must be from 1 mm to 1000 m, got 1000.5"],
        ),
        (
            "[[cylinder]]\ncenter = [0, 0]\nradius = 0.001\n",
            "[[cylinder]]\ncenter = [0, 0]\nradius = 1e-300\n",
            ["[[cylinder]] 1: radius must be from 1 mm to 1000 m, got 1e-300"],
        ),
        (
            "[[cylinder]]\ncenter = [0, 0]\nradius = 1000\n",
            "[[cylinder]]\ncenter = [0, 0]\nradius = 1e6\n",
            ["[[cylinder]] 1: radius must be from 1 mm to 1000 m, got 1000000.0"],
        ),
        (
            "[[wall]]\npoints = [[0, 0], [0.001, 0]]\n",
            "[[wall]]\npoints = [[0, 0], [1, 0], [1, 0.0005]]\n",
            ["[[wall]] 1: segment 2 (points 2 to 3) is 0.0005 m long, shorter than 1 mm"],
        ),
        (
            BOX + "reflectivity = 1000\n",
            BOX + "reflectivity = 1000.5\n",
            ["[[box]] 1: reflectivity must be at most 1000", "got 1000.5"],
        ),
        (
            "[[wall]]\npoints = [[0, 0], [1, 0]]\nreflectivity = 1e-3\n",
            "[[wall]]\npoints = [[0, 0], [1, 0]]\nreflectivity = 1e9\n",
            ["[[wall]] 1: reflectivity must be at most 1000"],
        ),
        (
            BOX + "yaw_deg = -360\n",
            BOX + "yaw_deg = 1e20\n",
            ["[[box]] 1: yaw_deg must be within ±360 deg, got 1e+20"],
        ),
        (
            "[vehicle]\npose = [0, 0, 360]\n",
            "[vehicle]\npose = [0, 0, 361]\n",
            ["[vehicle]: pose's yaw_deg must be within ±360 deg, got 361.0"],
        ),
        (
            'name = "' + "n" * 256 + '"\n',
            'name = "' + "n" * 257 + '"\n',
            ["world: name must be one line of at most 256 characters"],
        ),
        ('name = "a b"\n', 'name = "a\\nb"\n', ["name must be one line"]),
    ],
)
def test_magnitude_limits(tmp_path: Path, allowed: str, refused: str, fragments: list[str]) -> None:
    parse_world(allowed)
    _refused(refused, *fragments)
    path = tmp_path / "w.toml"
    path.write_text(refused, encoding="utf-8")
    with pytest.raises(WorldFileError) as info:
        load_world(path)
    check_single_line_error(info.value, path, *[f.removeprefix("world: ") for f in fragments])


# --------------------------------------------------------------------------------------------
# Walls that meet themselves
# --------------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("points", "problem"),
    [
        # A bow tie: a closed wall whose second and fourth segments cross.
        ([[0, 0], [1, 0], [0, 1], [1, 1], [0, 0]], "segments 2 and 4 cross"),
        # An open zigzag whose last segment crosses its first.
        ([[0, 0], [2, 0], [2, 1], [1, 1], [1, -1]], "segments 1 and 4 cross"),
        # A T: the last point lands on the first segment.
        ([[0, 0], [2, 0], [2, 1], [1, 1], [1, 0]], "segments 1 and 4 touch"),
        # A point visited twice, not as the closing point.
        ([[0, 0], [1, 0], [1, 1], [0, 0], [0, -1]], "segments 1 and 3 touch"),
        # Collinear segments that overlap without being neighbours.
        ([[0, 0], [3, 0], [3, 1], [2, 1], [2, 0], [1, 0]], "segments 1 and 4 touch"),
        # A spike: the wall runs back along itself.
        ([[0, 0], [2, 0], [1, 0]], "segments 1 and 2 turn back on each other"),
        # A closed wall of no area.
        ([[0, 0], [1, 0], [2, 0], [0, 0]], "segments 1 and 3 turn back on each other"),
        ([[0, 0], [1, 0], [0, 0]], "segments 1 and 2 turn back on each other"),
        # A closed wall whose closing corner is a spike.
        ([[0, 0], [1, 0], [1, 1], [2, 0], [0, 0]], "segments 1 and 4 turn back on each other"),
    ],
)
def test_walls_that_meet_themselves_are_refused(points: list[list[float]], problem: str) -> None:
    good = {"points": [[5, 5], [6, 5], [6, 6], [5, 6], [5, 5]]}
    _refused({"wall": [good, {"points": points}]}, f"world: [[wall]] 2: {problem}")


@pytest.mark.parametrize(
    "points",
    [
        [[0, 0], [1, 0]],
        [[0, 0], [1, 0], [2, 0]],  # straight on through a point
        [[0, 0], [1, 0], [0.5, 1], [0, 0]],  # a closed triangle
        [[-1.0, -2.0], [5.0, -2.0], [5.0, 2.5], [-1.0, 2.5], [-1.0, -2.0]],  # a room
        [[0, 0], [1, 0], [1, 1], [0, 1], [0, 0.5]],  # nearly closed
        [[0, 0], [1, 0], [1, 1e-3], [0, 1e-3]],  # a narrow hairpin, 1 mm wide
    ],
)
def test_simple_walls_are_accepted(points: list[list[float]]) -> None:
    assert parse_world({"wall": [{"points": points}]}).n_obstacles == 1


def test_the_first_wall_in_file_order_is_named() -> None:
    crossing4 = [[0, 0], [1, 1], [1, 0], [0, 1]]
    crossing5 = [[0, 0], [2, 0], [2, 1], [1, 1], [1, -1]]
    square4 = [[0, 0], [1, 0], [1, 1], [0, 1]]
    # Walls of four points are tested together, before those of five: wall 2 still comes first.
    walls = [{"points": square4}, {"points": crossing5}, {"points": crossing4}]
    _refused({"wall": walls}, "[[wall]] 2: segments 1 and 4 cross")


def _exact_first_contact(points: list[tuple[int, int]]) -> tuple[int, int, str] | None:
    """The first pair of segments that meet, by exact rational arithmetic, pair by pair."""
    pts = [(Fraction(x), Fraction(y)) for x, y in points]
    n = len(pts) - 1
    closed = n >= 3 and pts[0] == pts[-1]

    def orient(o: Any, u: Any, v: Any) -> int:
        value: Fraction = (u[0] - o[0]) * (v[1] - o[1]) - (u[1] - o[1]) * (v[0] - o[0])
        return int(value > 0) - int(value < 0)

    def on(o: Any, u: Any, v: Any) -> bool:
        return orient(o, u, v) == 0 and all(
            min(o[c], u[c]) <= v[c] <= max(o[c], u[c]) for c in (0, 1)
        )

    for i, j in itertools.combinations(range(n), 2):
        p1, p2, q1, q2 = pts[i], pts[i + 1], pts[j], pts[j + 1]
        if j == i + 1 or (closed and (i, j) == (0, n - 1)):
            u = (p2[0] - p1[0], p2[1] - p1[1])
            v = (q2[0] - q1[0], q2[1] - q1[1])
            if u[0] * v[1] - u[1] * v[0] == 0 and u[0] * v[0] + u[1] * v[1] < 0:
                return i, j, "turn back on each other"
            continue
        d = orient(q1, q2, p1), orient(q1, q2, p2), orient(p1, p2, q1), orient(p1, p2, q2)
        if d[0] * d[1] < 0 and d[2] * d[3] < 0:
            return i, j, "cross"
        if on(q1, q2, p1) or on(q1, q2, p2) or on(p1, p2, q1) or on(p1, p2, q2):
            return i, j, "touch"
    return None


def test_vectorised_test_matches_an_exact_pairwise_one(rng: np.random.Generator) -> None:
    # Random walks on a small integer grid: collinear runs, touching ends and revisited points
    # are common, and float arithmetic on them is exact.
    walls: list[list[tuple[int, int]]] = []
    while len(walls) < 600:
        n = int(rng.integers(3, 9))
        steps = rng.integers(-2, 3, (n - 1, 2))
        if rng.random() < 0.3:  # close some of them
            steps[-1] = -steps[:-1].sum(axis=0)
        if np.any(np.all(steps == 0, axis=1)):
            continue  # repeated points are refused before this test
        walls.append([(0, 0), *map(tuple, np.cumsum(steps, axis=0).tolist())])
    kinds = set()
    for wall in walls:
        expected = _exact_first_contact(wall)
        found = first_wall_contact([wall])
        assert (None if found is None else found[1:]) == expected, wall
        kinds.add(None if expected is None else expected[2])
    assert kinds == {None, "cross", "touch", "turn back on each other"}
    # Together, in one call, the first bad wall is named.
    bad = [w for w, wall in enumerate(walls) if _exact_first_contact(wall) is not None]
    result = first_wall_contact(walls)
    assert result is not None and result[0] == bad[0]


def test_many_walls_are_tested_in_chunks() -> None:
    # 1000 walls of 64 points (two million pairs of segments, several chunks), the last bad.
    walls = [np.array(_zigzag(64, 0.05 * w)) for w in range(1000)]
    assert first_wall_contact(walls) is None
    walls[-1][-1] = walls[-1][0] + [0.005, 0.008]  # back across the first segment
    assert first_wall_contact(walls) == (999, 0, 62, "cross")


# --------------------------------------------------------------------------------------------
# The file as a whole, through the command line
# --------------------------------------------------------------------------------------------


def test_deeply_nested_world_file_is_one_line_and_status_2(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    deep = tmp_path / "deep.toml"
    deep.write_text("a = " + "[" * 100_000 + "]" * 100_000 + "\n")
    assert main(["scan", "--world", str(deep)]) == 2
    captured = capsys.readouterr()
    assert captured.out == ""
    assert captured.err == (
        f"sensor-agent: world file {deep}: not valid TOML: arrays or inline tables nested too "
        "deeply\n"
    )


def test_oversized_world_file_is_refused(tmp_path: Path) -> None:
    big = tmp_path / "big.toml"
    big.write_text("# padding\n" * 110_000)  # 1.1 MB of comments: valid TOML, but too large
    with pytest.raises(WorldFileError) as info:
        load_world(big)
    check_single_line_error(info.value, big, "larger than the 1048576-byte limit (1100000 bytes)")
