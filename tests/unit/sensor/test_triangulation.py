"""Triangulation geometry: round trips, and gains against finite differences (eq. 6.1-6.7)."""

from __future__ import annotations

import numpy as np
import pytest

from agent.sensor import triangulation as g

FD, F, D = 0.0044, 0.05, 0.095
THETA = np.radians(np.linspace(-20.0, 20.0, 9))[:, None]
Z = np.linspace(0.4, 2.5, 12)[None, :]


def test_synchronised_round_trip_depth() -> None:
    p = g.synchronised_image_position(Z, THETA, FD, D)
    np.testing.assert_allclose(
        g.synchronised_depth(p, THETA, FD, D), Z * np.ones_like(THETA), rtol=1e-12
    )


def test_synchronised_round_trip_range() -> None:
    r = Z / np.cos(THETA)
    p = g.synchronised_image_position_from_range(r, THETA, FD, D)
    np.testing.assert_allclose(g.synchronised_range(p, THETA, FD, D), r, rtol=1e-12)
    # The same image position through the depth form: r = z / cos θ.
    np.testing.assert_allclose(p, g.synchronised_image_position(Z, THETA, FD, D), rtol=1e-12)


def test_synchronised_on_axis_is_fd_over_p() -> None:
    assert g.synchronised_depth(0.0044, 0.0, FD, D) == pytest.approx(1.0)


def test_synchronised_image_gain_matches_finite_difference() -> None:
    h = 1e-7
    p_plus = g.synchronised_image_position(Z + h, THETA, FD, D)
    p_minus = g.synchronised_image_position(Z - h, THETA, FD, D)
    numeric = np.abs(p_plus - p_minus) / (2 * h)
    np.testing.assert_allclose(g.synchronised_image_gain(Z, THETA, FD, D), numeric, rtol=1e-6)


def test_synchronised_range_gain_matches_finite_difference() -> None:
    h = 1e-7
    r = Z / np.cos(THETA)
    numeric = np.abs(
        g.synchronised_image_position_from_range(r + h, THETA, FD, D)
        - g.synchronised_image_position_from_range(r - h, THETA, FD, D)
    ) / (2 * h)
    np.testing.assert_allclose(g.synchronised_range_gain(r, THETA, FD, D), numeric, rtol=1e-6)


def test_synchronised_angle_gain_matches_finite_difference() -> None:
    h = 1e-7
    p = g.synchronised_image_position(Z, THETA, FD, D)  # hold image position fixed
    dz = g.synchronised_depth(p, THETA + h, FD, D) - g.synchronised_depth(p, THETA - h, FD, D)
    numeric = 1.0 / np.abs(dz / (2 * h))
    np.testing.assert_allclose(g.synchronised_angle_gain(Z, THETA, FD, D), numeric, rtol=1e-6)


def test_chapter_forms_agree_on_axis_and_approximate_at_edges() -> None:
    z = Z[0]
    np.testing.assert_allclose(
        g.synchronised_image_gain_chapter(z, 0.0, FD),
        g.synchronised_image_gain(z, 0.0, FD, D),
        rtol=1e-12,
    )
    np.testing.assert_allclose(
        g.synchronised_angle_gain_chapter(z, 0.0, D),
        g.synchronised_angle_gain(z, 0.0, FD, D),
        rtol=1e-12,
    )
    # Eq. 6.6 replaces z − (d/2)·sin 2θ by z, eq. 6.7 replaces d by d·cos 2θ: the printed
    # forms differ from the exact ones by exactly these factors (up to 22 % at 0.4 m, ±20°).
    shift = 1.0 - 0.5 * D * np.sin(2 * THETA) / Z
    np.testing.assert_allclose(
        g.synchronised_image_gain_chapter(Z, THETA, FD) * shift**-2,
        g.synchronised_image_gain(Z, THETA, FD, D),
        rtol=1e-12,
    )
    ratio = (D * np.cos(2 * THETA) - 2 * Z * np.tan(THETA)) / (D - 2 * Z * np.tan(THETA))
    np.testing.assert_allclose(
        g.synchronised_angle_gain_chapter(Z, THETA, D) * np.abs(ratio),
        g.synchronised_angle_gain(Z, THETA, FD, D),
        rtol=1e-12,
    )


def test_conventional_round_trip_and_gains() -> None:
    p = g.conventional_image_position(Z, THETA, F, D)
    np.testing.assert_allclose(
        g.conventional_depth(p, THETA, F, D), Z * np.ones_like(THETA), rtol=1e-12
    )
    h = 1e-7
    numeric_p = np.abs(
        g.conventional_image_position(Z + h, THETA, F, D)
        - g.conventional_image_position(Z - h, THETA, F, D)
    ) / (2 * h)
    np.testing.assert_allclose(
        g.conventional_image_gain(Z, F, D) * np.ones_like(THETA), numeric_p, rtol=1e-6
    )
    dz = g.conventional_depth(p, THETA + h, F, D) - g.conventional_depth(p, THETA - h, F, D)
    np.testing.assert_allclose(
        g.conventional_angle_gain(Z, THETA, D), np.abs(2 * h / dz), rtol=1e-6
    )


def test_synchronised_is_less_sensitive_to_scan_angle_error() -> None:
    # Section 6.2.2: the benefit of synchronised scanning; compare ∂z/∂θ (1/G_θ) at the edges.
    theta = np.radians(20.0)
    z = np.linspace(0.5, 2.5, 5)
    depth_error_sync = 1.0 / g.synchronised_angle_gain(z, theta, FD, D)
    depth_error_conv = 1.0 / g.conventional_angle_gain(z, theta, D)
    assert np.all(depth_error_sync < depth_error_conv)


def test_lateral_offset() -> None:
    assert g.lateral_offset(2.0, np.radians(45.0)) == pytest.approx(2.0)
