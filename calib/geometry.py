"""Line geometry shared by the calibration estimators (pure numpy; rotations and Kabsch are in
:mod:`mocap.kinematics`).

Lines are ``(point, direction)`` pairs with a unit direction. A line near a reference line
``(p0, n0)`` is described by four *chart* coordinates ``(alpha, beta, gamma, delta)``:
its direction is ``normalize(n0 + alpha u + beta v)`` and it crosses the plane through
``p0`` perpendicular to ``n0`` at ``p0 + gamma u + delta v`` (``u, v`` an orthonormal basis
of that plane). Covariances of fitted axes are expressed in these coordinates.
"""
from __future__ import annotations

import numpy as np

from mocap.kinematics import unit


def chart_coords(q: np.ndarray, m: np.ndarray, p0: np.ndarray, n0: np.ndarray,
                 u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Chart coordinates (4,) of the line ``(q, m)`` around the reference line ``(p0, n0)``."""
    m = np.asarray(m, float)
    if m @ n0 < 0:
        m = -m
    mn = m @ n0
    s = ((p0 - q) @ n0) / mn
    x = q + s * m - p0
    return np.array([m @ u / mn, m @ v / mn, x @ u, x @ v])


def chart_line(phi: np.ndarray, p0: np.ndarray, n0: np.ndarray, u: np.ndarray,
               v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The line ``(point, unit direction)`` at chart coordinates ``phi`` (inverse of chart_coords)."""
    n = unit(n0 + phi[0] * u + phi[1] * v)
    return p0 + phi[2] * u + phi[3] * v, n


def closest_point_to(point: np.ndarray, line_point: np.ndarray, n: np.ndarray) -> np.ndarray:
    """Projection of ``point`` onto the line through ``line_point`` along the unit ``n``."""
    return line_point + ((point - line_point) @ n) * n


def line_distance(p1, n1, p2, n2) -> tuple[float, np.ndarray]:
    """Shortest distance between two lines and the midpoint of the common perpendicular."""
    w = p1 - p2
    b = n1 @ n2
    d = 1.0 - b * b
    if d < 1e-12:  # parallel
        x = w - (w @ n2) * n2
        return float(np.linalg.norm(x)), p1
    s = (b * (n2 @ w) - (n1 @ w)) / d
    t = ((n2 @ w) - b * (n1 @ w)) / d
    a, c = p1 + s * n1, p2 + t * n2
    return float(np.linalg.norm(a - c)), (a + c) / 2.0
