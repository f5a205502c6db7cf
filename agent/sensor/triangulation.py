"""Triangulation geometry: image position against range, and its gains (eq. 6.1-6.7).

Coordinates follow the chapter: ``z`` is depth along the sensor's optical axis (the head
frame's x), ``x = z·tan θ`` is lateral offset (eq. 6.2), ``θ`` is the projection (scan)
angle, and ``p`` is the image position on the detector in metres. The beam range, the
distance along the beam from the centre of scanning, is ``r = z / cos θ``.

Synchronised scanning (eq. 6.5) is the sensor's geometry. It follows from placing the virtual
collecting lens a baseline ``d`` to the side of the centre of scanning (towards positive θ)
with its optical axis kept parallel to the projected beam: a spot at range ``r`` images at
``p = fd·cos θ / (r − d·sin θ)``. Conventional scanning (eq. 6.1), with a fixed lens axis, is
kept for comparison.

Gains are magnitudes of exact partial derivatives. Where the chapter prints a simplified form
(eq. 6.6 and 6.7 drop terms of order ``d·sin θ / z``, a few per cent at the scan edges), that
form is given beside the exact one with the suffix ``_chapter``.

All functions are NumPy-vectorised: arguments broadcast together.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from agent.arrays import FloatArray


def _f(a: ArrayLike) -> FloatArray:
    return np.asarray(a, dtype=np.float64)


# ------------------------------------------------------------------ synchronised (eq. 6.5-6.7)
def synchronised_depth(p: ArrayLike, theta: ArrayLike, fd: ArrayLike, d: ArrayLike) -> FloatArray:
    """Depth from image position, ``z = (fd/p)·cos²θ + (d/2)·sin 2θ`` (eq. 6.5).

    Parameters
    ----------
    p : image position on the detector, m. theta : scan angle, rad. fd : m². d : baseline, m.
    """
    p, theta = _f(p), _f(theta)
    return _f(fd) / p * np.square(np.cos(theta)) + 0.5 * _f(d) * np.sin(2.0 * theta)


def synchronised_image_position(
    z: ArrayLike, theta: ArrayLike, fd: ArrayLike, d: ArrayLike
) -> FloatArray:
    """Image position from depth, the inverse of eq. 6.5: ``p = fd·cos²θ / (z − (d/2)·sin 2θ)``."""
    z, theta = _f(z), _f(theta)
    return _f(fd) * np.square(np.cos(theta)) / (z - 0.5 * _f(d) * np.sin(2.0 * theta))


def synchronised_range(p: ArrayLike, theta: ArrayLike, fd: ArrayLike, d: ArrayLike) -> FloatArray:
    """Beam range from image position: ``r = z/cos θ = (fd/p)·cos θ + d·sin θ`` (eq. 6.5)."""
    p, theta = _f(p), _f(theta)
    return _f(fd) / p * np.cos(theta) + _f(d) * np.sin(theta)


def synchronised_image_position_from_range(
    r: ArrayLike, theta: ArrayLike, fd: ArrayLike, d: ArrayLike
) -> FloatArray:
    """Image position of a spot at beam range ``r``: ``p = fd·cos θ / (r − d·sin θ)``."""
    r, theta = _f(r), _f(theta)
    return _f(fd) * np.cos(theta) / (r - _f(d) * np.sin(theta))


def synchronised_image_gain(
    z: ArrayLike, theta: ArrayLike, fd: ArrayLike, d: ArrayLike
) -> FloatArray:
    """Triangulation gain ``G_p = |∂p/∂z|`` at fixed θ, exact: ``p² / (fd·cos²θ)``.

    The chapter's eq. 6.6 (:func:`synchronised_image_gain_chapter`) replaces
    ``z − (d/2)·sin 2θ`` by ``z``.
    """
    p = synchronised_image_position(z, theta, fd, d)
    return np.square(p) / (_f(fd) * np.square(np.cos(_f(theta))))


def synchronised_image_gain_chapter(z: ArrayLike, theta: ArrayLike, fd: ArrayLike) -> FloatArray:
    """Eq. 6.6 as printed: ``G_p = fd·cos²θ / z²``."""
    return _f(fd) * np.square(np.cos(_f(theta))) / np.square(_f(z))


def synchronised_range_gain(
    r: ArrayLike, theta: ArrayLike, fd: ArrayLike, d: ArrayLike
) -> FloatArray:
    """``|∂p/∂r|`` at fixed θ, for beam range r: ``fd·cos θ / (r − d·sin θ)²``.

    This is the gain that turns image-position noise into beam-range noise.
    """
    r, theta = _f(r), _f(theta)
    return _f(fd) * np.cos(theta) / (r - _f(d) * np.sin(theta)) ** 2


def synchronised_angle_gain(
    z: ArrayLike, theta: ArrayLike, fd: ArrayLike, d: ArrayLike
) -> FloatArray:
    """``G_θ = |∂θ/∂z|`` at fixed image position, exact: ``1 / |d − 2z·tan θ|``.

    ``fd`` does not appear in the exact result; it is accepted for a uniform signature. The
    chapter's eq. 6.7 (:func:`synchronised_angle_gain_chapter`) has ``d·cos 2θ`` for ``d``, the
    result of replacing ``fd/p`` by ``z/cos²θ`` in the derivative.
    """
    del fd
    z, theta = _f(z), _f(theta)
    return 1.0 / np.abs(_f(d) - 2.0 * z * np.tan(theta))


def synchronised_angle_gain_chapter(z: ArrayLike, theta: ArrayLike, d: ArrayLike) -> FloatArray:
    """Eq. 6.7 as printed: ``G_θ = 1 / (d·cos 2θ − 2z·tan θ)`` (magnitude)."""
    z, theta = _f(z), _f(theta)
    return 1.0 / np.abs(_f(d) * np.cos(2.0 * theta) - 2.0 * z * np.tan(theta))


# -------------------------------------------------------------------- conventional (eq. 6.1-6.4)
def conventional_depth(p: ArrayLike, theta: ArrayLike, f: ArrayLike, d: ArrayLike) -> FloatArray:
    """Depth for a fixed lens axis, ``z = fd / (p + f·tan θ)`` (eq. 6.1)."""
    f, d = _f(f), _f(d)
    return f * d / (_f(p) + f * np.tan(_f(theta)))


def conventional_image_position(
    z: ArrayLike, theta: ArrayLike, f: ArrayLike, d: ArrayLike
) -> FloatArray:
    """Inverse of eq. 6.1: ``p = fd/z − f·tan θ``."""
    f, d = _f(f), _f(d)
    return f * d / _f(z) - f * np.tan(_f(theta))


def conventional_image_gain(z: ArrayLike, f: ArrayLike, d: ArrayLike) -> FloatArray:
    """``G_p = |∂p/∂z| = fd / z²`` (eq. 6.3, exact)."""
    return _f(f) * _f(d) / np.square(_f(z))


def conventional_angle_gain(z: ArrayLike, theta: ArrayLike, d: ArrayLike) -> FloatArray:
    """``G_θ = |∂θ/∂z| = d·cos²θ / z²`` (eq. 6.4, exact)."""
    return _f(d) * np.square(np.cos(_f(theta))) / np.square(_f(z))


def lateral_offset(z: ArrayLike, theta: ArrayLike) -> FloatArray:
    """``x = z·tan θ`` (eq. 6.2)."""
    return _f(z) * np.tan(_f(theta))
