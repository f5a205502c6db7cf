"""The ingest's compiled kernels (capsules, forgetting movers' hits) against their numpy
references, on random inputs: equal to the bit (the closed loop's runs must not change)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from agent.control.clearance import forget_movers_hits, forget_movers_hits_reference
from agent.control.obstacles import capsules_from_view, capsules_from_view_reference
from agent.control.settings import ControllerSettings
from agent.control.view import EnvironmentView

SETTINGS = ControllerSettings()


def _random_view(rng: np.random.Generator, k: int) -> EnvironmentView:
    """``k`` obstacles of every kind, half of them moving, with random covariances (some
    with negative eigenvalues, some not finite) and extents."""
    root = rng.normal(0.0, 0.2, (k, 4, 4))
    cov = root @ np.swapaxes(root, 1, 2) + rng.normal(0.0, 0.01, (k, 4, 4))
    cov[rng.random(k) < 0.1, 0, 0] = -1.0
    cov[rng.random(k) < 0.05, 1, 1] = np.nan
    vel = rng.normal(0.0, 0.5, (k, 2)) * (rng.random((k, 1)) < 0.5)
    bearings = np.linspace(-np.pi, np.pi, 360, endpoint=False)
    return EnvironmentView(
        stamp_s=0.0, valid_for_s=0.5, sensor_ok=True, obstacle_id=np.arange(k, dtype=np.int64),
        kind=rng.integers(0, 5, k).astype(np.uint8), position_xy=rng.normal(0.0, 3.0, (k, 2)),
        velocity_xy=vel, covariance=cov, extent=rng.normal(0.0, 2.0, (k, 4)),
        reflectivity=rng.random(k), free_bearing_rad=bearings, free_range_m=np.zeros(360),
    )  # fmt: skip


@pytest.mark.parametrize("seed", range(20))
def test_the_compiled_capsules_equal_the_numpy_ones(seed: int) -> None:
    rng = np.random.default_rng(seed)
    view = _random_view(rng, int(rng.choice([0, 1, 7, 60])))
    if seed % 2:  # an agent that gives each segment's across-line σ
        view = dataclasses.replace(view, across_sigma_m=rng.random(view.kind.size) * 0.1)
    got = capsules_from_view(view, SETTINGS)
    want = capsules_from_view_reference(view, SETTINGS)
    for name in ("a", "b", "radius", "inflation", "moving", "obstacle_id"):
        np.testing.assert_array_equal(getattr(got, name), getattr(want, name), err_msg=name)
        assert getattr(got, name).dtype == getattr(want, name).dtype, name


def _wall_view(across: np.ndarray | None) -> EnvironmentView:
    """One static 0.8 m wall along x at y = 1, its ends unseen: its midpoint's σ 0.23 m along
    the line (0.8 / √12), 2 mm across it; and a cylinder of the same covariance."""
    cov = np.tile(np.diag([0.8**2 / 12.0, 0.002**2, 1e-6, 1e-6]), (2, 1, 1))
    bearings = np.linspace(-np.pi, np.pi, 360, endpoint=False)
    return EnvironmentView(
        stamp_s=0.0, valid_for_s=0.3, sensor_ok=True, obstacle_id=np.array([1, 2]),
        kind=np.array([0, 3], dtype=np.uint8), position_xy=np.array([[0.0, 1.0], [2.0, 0.0]]),
        velocity_xy=np.zeros((2, 2)), covariance=cov,
        extent=np.array([[-0.4, 1.0, 0.4, 1.0], [0.1, 0.0, 0.0, 0.0]]),
        reflectivity=np.ones(2), free_bearing_rad=bearings, free_range_m=np.zeros(360),
        across_sigma_m=np.zeros(0) if across is None else across,
    )  # fmt: skip


def test_a_wall_is_inflated_by_its_place_across_its_line_not_its_extents_spread() -> None:
    """With the agent's across-line σ, a wall grows by 3 of them (plus the margin), not by
    its midpoint's spread along it; other kinds keep their covariance's; an older agent's
    vector (no field) keeps the largest σ, capped."""
    margin = SETTINGS.obstacle_margin_m
    given = capsules_from_view(_wall_view(np.array([0.002, 0.0])), SETTINGS)
    assert given.inflation[0] == pytest.approx(3 * 0.002 + margin)
    older = capsules_from_view(_wall_view(None), SETTINGS)
    assert older.inflation[0] == pytest.approx(SETTINGS.inflation_cap_m + margin)
    for capsules in (given, older):  # the cylinder: its covariance's largest σ, capped
        assert capsules.inflation[1] == pytest.approx(SETTINGS.inflation_cap_m + margin)


@pytest.mark.parametrize("seed", range(10))
def test_forgetting_movers_hits_in_place_equals_the_masked_one(seed: int) -> None:
    rng = np.random.default_rng(seed)
    capsules = capsules_from_view(_random_view(rng, 30), SETTINGS)
    suspect = np.where(rng.random((120, 120)) < 0.5, rng.random((120, 120)), -np.inf)
    origin = np.array([-3.0, -3.0]) + rng.normal(0.0, 0.01, 2)
    want = suspect.copy()
    forget_movers_hits_reference(want, origin, 0.05, capsules, SETTINGS)
    forget_movers_hits(suspect, origin, 0.05, capsules, SETTINGS)
    np.testing.assert_array_equal(suspect, want)
    assert capsules.moving.any()


def walker_view(stamp_s: float, ids: list[int]) -> EnvironmentView:
    """Cylinders of radius 0.2 at (1, 0) walking at (0.5, 0) m/s, one per id; σ 2 cm."""
    k = len(ids)
    cov = np.tile(np.diag([4e-4, 4e-4, 1e-4, 1e-4]), (k, 1, 1))
    extent = np.zeros((k, 4))
    extent[:, 0] = 0.2
    bearings = np.linspace(-np.pi, np.pi, 360, endpoint=False)
    return EnvironmentView(
        stamp_s=stamp_s, valid_for_s=0.3, sensor_ok=True,
        obstacle_id=np.array(ids, dtype=np.int64), kind=np.full(k, 3, dtype=np.uint8),
        position_xy=np.tile([1.0, 0.0], (k, 1)), velocity_xy=np.tile([0.5, 0.0], (k, 1)),
        covariance=cov, extent=extent, reflectivity=np.ones(k), free_bearing_rad=bearings,
        free_range_m=np.zeros(360),
    )  # fmt: skip


def test_a_mover_of_uncertain_heading_is_inflated_past_the_static_cap() -> None:
    # A walker at 0.6 m/s glimpsed for a few scans: velocity σ 0.25 m/s each way, so 1.5 s
    # on it may be 3 · 0.375 m from where its estimate puts it. A pillar with the same
    # position σ as that prediction is held to the static cap.
    view = dataclasses.replace(
        walker_view(0.0, [1, 2]),
        velocity_xy=np.array([[0.6, 0.0], [0.0, 0.0]]),
        covariance=np.tile(np.diag([1e-4, 1e-4, 0.0625, 0.0625]), (2, 1, 1)),
    )
    view.covariance[1, :2, :2] = np.diag([0.375**2, 0.375**2])
    for caps in (capsules_from_view(view, SETTINGS), capsules_from_view_reference(view, SETTINGS)):
        assert list(caps.moving) == [True, False]
        T = SETTINGS.mover_horizon_s
        sigma = np.sqrt(1e-4 + T * T * 0.0625)
        assert caps.inflation[0] == pytest.approx(
            min(SETTINGS.covariance_sigmas * sigma, SETTINGS.mover_inflation_cap_m)
            + SETTINGS.obstacle_margin_m
        )
        assert caps.inflation[0] > 1.0
        assert caps.inflation[1] == pytest.approx(
            SETTINGS.inflation_cap_m + SETTINGS.obstacle_margin_m
        )


def test_a_velocity_within_its_own_spread_makes_no_mover() -> None:
    """Three cylinders at 0.3 m/s: with velocity σ 0.1 m/s a mover; with 0.5 m/s (a fresh
    track's prior, speed/σ 0.6) still one; with 0.7 m/s (0.43) not: it is taken as static.
    Only the σ along the velocity counts."""
    view = dataclasses.replace(
        walker_view(0.0, [1, 2, 3, 4]),
        velocity_xy=np.tile([0.3, 0.0], (4, 1)),
        covariance=np.stack([np.diag([1e-4, 1e-4, s_x**2, s_y**2])
                             for s_x, s_y in ((0.1, 0.1), (0.5, 0.5), (0.7, 0.7), (0.1, 2.0))]),
    )  # fmt: skip
    for caps in (capsules_from_view(view, SETTINGS), capsules_from_view_reference(view, SETTINGS)):
        assert list(caps.moving) == [True, True, False, True]
