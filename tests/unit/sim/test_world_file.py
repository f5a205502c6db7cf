"""Tests of agent.sim.world_file: example and test world files, and their error messages."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from agent.errors import WorldFileError
from agent.sim.raycast import cast_rays, ray_directions
from agent.sim.world_file import load_world, parse_world
from tests.unit.sim.conftest import EXAMPLE_WORLDS, TEST_WORLDS, check_single_line_error, one_ray

pytestmark = pytest.mark.filterwarnings("error")


@pytest.mark.parametrize("name", ["box_before_wall.toml", "cylinder.toml", "office.toml"])
def test_example_worlds_load(name: str) -> None:
    world = load_world(EXAMPLE_WORLDS / name)
    assert world.n_obstacles >= 2
    assert world.vehicle_pose[:2] == (0.0, 0.0)
    assert world.name
    # The vehicle sees something in every direction it faces.
    hits = cast_rays(world, np.zeros(2), ray_directions(np.linspace(-0.5, 0.5, 21)))
    assert hits.hit.all()


def test_example_worlds_geometry() -> None:
    cylinder = load_world(EXAMPLE_WORLDS / "cylinder.toml")
    assert one_ray(cylinder, (0.0, 0.0), 0.0)[0] == pytest.approx(1.1)
    office = load_world(EXAMPLE_WORLDS / "office.toml")
    assert office.vehicle_pose[2] == pytest.approx(math.radians(-20.0))  # toward the crate
    plates = [o for o in office.obstacles if o.kind == "box" and o.reflectivity == 3.0]
    assert len(plates) == 1 and plates[0].size is not None and min(plates[0].size) <= 0.05
    assert len({o.reflectivity for o in office.obstacles}) >= 4
    assert {o.kind for o in office.obstacles} == {"wall", "box", "cylinder"}


def test_defaults_are_applied() -> None:
    world = load_world(TEST_WORLDS / "minimal.toml")
    assert world.name == "minimal"  # the file's stem
    assert world.vehicle_pose == (0.0, 0.0, 0.0)
    (cyl,) = world.obstacles
    assert (cyl.kind, cyl.center, cyl.radius) == ("cylinder", (1.0, 0.0), 0.1)
    assert cyl.reflectivity == 1.0
    assert parse_world("[[box]]\ncenter = [0, 0]\nsize = [1, 2]").obstacles[0].yaw_rad == 0.0
    assert parse_world("").name == ""


def test_full_world_file() -> None:
    world = load_world(TEST_WORLDS / "full.toml")
    assert world.name == "every key"
    x, y, yaw = world.vehicle_pose
    assert (x, y) == (0.5, -0.25) and yaw == pytest.approx(math.pi / 2)
    assert [(o.kind, o.index) for o in world.obstacles] == [
        ("wall", 0),
        ("box", 0),
        ("box", 1),
        ("cylinder", 0),
    ]
    wall, box, plain_box, cyl = world.obstacles
    assert wall.points == ((3.0, -1.0), (3.0, 1.0), (2.0, 2.0)) and wall.reflectivity == 0.5
    assert box.yaw_rad == pytest.approx(math.pi / 2) and box.size == (0.4, 0.2)
    assert plain_box.reflectivity == 1.0
    assert cyl.radius == 0.25 and cyl.reflectivity == 0.3
    assert world.segments_start.shape == (2 + 4 + 4, 2)
    # The box turned by 90 degrees shows its 0.2 m side along x.
    assert one_ray(world, (0.0, 0.0), 0.0)[0] == pytest.approx(1.4)


def test_empty_world_is_valid() -> None:
    world = load_world(TEST_WORLDS / "empty.toml")
    assert world.n_obstacles == 0 and world.name == "nothing"
    assert world.segments_start.shape == (0, 2) and world.circles_center.shape == (0, 2)
    assert world.nearby((0.0, 0.0), 1.0).n_obstacles == 0


def test_parse_world_accepts_a_mapping() -> None:
    doc: dict[str, Any] = {"cylinder": [{"center": [1.0, 2.0], "radius": 0.5}]}
    world = parse_world(doc)
    assert world.circles_center.tolist() == [[1.0, 2.0]]
    with pytest.raises(WorldFileError) as info:
        parse_world({"cylinder": [{"center": [1.0, 2.0], "radius": -0.5}]})
    check_single_line_error(info.value, None, "[[cylinder]] 1: radius")


@pytest.mark.parametrize(
    ("file", "fragments"),
    [
        ("bad_syntax.toml", ["not valid TOML", "line 4"]),
        ("unknown_key.toml", ['[[box]] 2: unknown key "colour"', "center, size, yaw_deg"]),
        ("boolean_radius.toml", ["[[cylinder]] 1: radius must be", "got true"]),
    ],
)
def test_malformed_test_worlds(file: str, fragments: list[str]) -> None:
    path = TEST_WORLDS / file
    with pytest.raises(WorldFileError) as info:
        load_world(path)
    check_single_line_error(info.value, path, *fragments)
    assert info.value.path == path


def test_missing_and_unreadable_files(tmp_path: Path) -> None:
    missing = tmp_path / "nope.toml"
    with pytest.raises(WorldFileError) as info:
        load_world(missing)
    check_single_line_error(info.value, missing, "no such file")
    with pytest.raises(WorldFileError) as info:
        load_world(tmp_path)  # a directory
    check_single_line_error(info.value, tmp_path, "not a regular file")
    binary = tmp_path / "binary.toml"
    binary.write_bytes(b"name = '\xff\xfe'\n")
    with pytest.raises(WorldFileError) as info:
        load_world(binary)
    check_single_line_error(info.value, binary, "not UTF-8")


BOX = "[[box]]\ncenter = [0, 0]\nsize = [0.4, 0.4]\n"


@pytest.mark.parametrize(
    ("text", "fragments"),
    [
        # Unknown keys and tables.
        ("foo = 1\n", ['unknown top-level key "foo"', "allowed keys: name, vehicle, wall"]),
        ("[robot]\nx = 1\n", ['unknown top-level key "robot"']),
        ("[vehicle]\nyaw = 1\n", ['[vehicle]: unknown key "yaw"; allowed keys: pose']),
        (
            "[[cylinder]]\ncenter = [0, 0]\nradius = 1\ncolor = 2\n",
            ['[[cylinder]] 1: unknown key "color"', "allowed keys: center, radius, reflectivity"],
        ),
        # Missing keys.
        ("[[cylinder]]\ncenter = [0, 0]\n", ['[[cylinder]] 1: missing key "radius"']),
        ("[[wall]]\nreflectivity = 1\n", ['[[wall]] 1: missing key "points"']),
        (BOX + "[[box]]\ncenter = [1, 1]\n", ['[[box]] 2: missing key "size"']),
        # Wrong types.
        ('[[cylinder]]\ncenter = [0, 0]\nradius = "big"\n', ["radius must be", 'got "big"']),
        ("name = 3\n", ["name must be a string, got 3"]),
        ("wall = 3\n", ["wall must be an array of tables [[wall]]"]),
        ("[box]\ncenter = [0, 0]\nsize = [1, 1]\n", ["box must be an array of tables"]),
        ("vehicle = 1\n", ["[vehicle]: must be a table, got 1"]),
        ('[[wall]]\npoints = "line"\n', ["[[wall]] 1: points must be a list of [x, y] pairs"]),
        ('[[wall]]\npoints = [[0, 0], [1, "a"]]\n', ["point 2 of points must be two finite"]),
        # Booleans are not numbers.
        ("[[box]]\ncenter = [true, 0]\nsize = [1, 1]\n", ["center must be two finite numbers"]),
        (BOX + "yaw_deg = false\n", ["[[box]] 1: yaw_deg must be a finite number, got false"]),
        (BOX + "reflectivity = true\n", ["reflectivity must be a finite positive number"]),
        # Wrong array lengths.
        ("[[cylinder]]\ncenter = [0, 0, 0]\nradius = 1\n", ["center must be two finite numbers"]),
        ("[[box]]\ncenter = [0, 0]\nsize = [1]\n", ["size must be two positive numbers, got [1]"]),
        ("[vehicle]\npose = [0, 0]\n", ["[vehicle]: pose must be three finite numbers"]),
        # Non-finite numbers.
        ("[[cylinder]]\ncenter = [0, 0]\nradius = inf\n", ["radius must be a finite positive"]),
        ("[[cylinder]]\ncenter = [nan, 0]\nradius = 1\n", ["center must be two finite numbers"]),
        (BOX + "yaw_deg = -inf\n", ["yaw_deg must be a finite number, got -inf"]),
        (BOX + "yaw_deg = 1" + "0" * 400 + "\n", ["yaw_deg must be a finite number, got 1000"]),
        ("[vehicle]\npose = [0, 0, nan]\n", ["pose must be three finite numbers", "nan"]),
        # Non-positive sizes, radii, reflectivities.
        (
            BOX + "[[box]]\ncenter = [1, 0]\nsize = [0.4, -1]\n",
            ["[[box]] 2: size must be two positive numbers, got [0.4, -1]"],
        ),
        ("[[box]]\ncenter = [0, 0]\nsize = [0, 1]\n", ["size must be two positive numbers"]),
        ("[[cylinder]]\ncenter = [0, 0]\nradius = 0\n", ["radius must be a finite positive"]),
        (BOX + "reflectivity = 0\n", ["[[box]] 1: reflectivity must be a finite positive"]),
        (
            "[[wall]]\npoints = [[0, 0], [1, 0]]\nreflectivity = -1\n",
            ["[[wall]] 1: reflectivity must be a finite positive number, got -1"],
        ),
        # Polylines.
        ("[[wall]]\npoints = [[0, 0]]\n", ["points must hold at least 2 points, got 1"]),
        ("[[wall]]\npoints = []\n", ["points must hold at least 2 points, got 0"]),
        (
            "[[wall]]\npoints = [[0, 0], [1, 0]]\n[[wall]]\npoints = [[0, 0], [1, 0], [1, 0]]\n",
            ["[[wall]] 2: zero-length segment: points 2 and 3 are both [1.0, 0.0]"],
        ),
        # Not TOML.
        ("[[box]\n", ["not valid TOML"]),
        ('name = "a\nb"\n', ["not valid TOML"]),
    ],
)
def test_world_file_errors(tmp_path: Path, text: str, fragments: list[str]) -> None:
    path = tmp_path / "w.toml"
    path.write_text(text, encoding="utf-8")
    with pytest.raises(WorldFileError) as info:
        load_world(path)
    check_single_line_error(info.value, path, *fragments)
    with pytest.raises(WorldFileError) as info:
        parse_world(text)
    check_single_line_error(info.value, None, *fragments)
