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
    """Chart coordinates (4,) of the line ``(q, m)`` around the reference line ``(p0, n0)``.

    Parameters
    ----------
    q, m : numpy.ndarray
        A point of the line and its direction (3,); the direction's sign is ignored.
    p0, n0 : numpy.ndarray
        The reference line's point and unit direction (3,).
    u, v : numpy.ndarray
        Orthonormal basis (3,) of the plane perpendicular to ``n0``.

    Returns
    -------
    numpy.ndarray
        ``(alpha, beta, gamma, delta)``: the direction's tilt along ``u`` and ``v`` and the
        crossing point of the plane through ``p0`` (m).

    Examples
    --------
    The z axis shifted by 2 cm along x, around the z axis:

    >>> e = np.eye(3)
    >>> c = chart_coords(np.array([0.02, 0.0, 0.5]), e[2], np.zeros(3), e[2], e[0], e[1])
    >>> (c.round(12) + 0.0).tolist()
    [0.0, 0.0, 0.02, 0.0]
    """
    m = np.asarray(m, float)
    if m @ n0 < 0:
        m = -m
    mn = m @ n0
    s = ((p0 - q) @ n0) / mn
    x = q + s * m - p0
    return np.array([m @ u / mn, m @ v / mn, x @ u, x @ v])


def chart_line(phi: np.ndarray, p0: np.ndarray, n0: np.ndarray, u: np.ndarray,
               v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The line ``(point, unit direction)`` at chart coordinates ``phi`` (inverse of chart_coords).

    Parameters
    ----------
    phi : numpy.ndarray
        Chart coordinates ``(alpha, beta, gamma, delta)``.
    p0, n0, u, v : numpy.ndarray
        The reference line and the basis of its normal plane, as in :func:`chart_coords`.

    Returns
    -------
    point : numpy.ndarray
        Where the line crosses the plane through ``p0`` (3,).
    direction : numpy.ndarray
        Its unit direction (3,).

    Examples
    --------
    >>> e = np.eye(3)
    >>> point, n = chart_line(np.array([0.0, 0.0, 0.02, 0.0]), np.zeros(3), e[2], e[0], e[1])
    >>> (point.round(12) + 0.0).tolist(), (n.round(12) + 0.0).tolist()
    ([0.02, 0.0, 0.0], [0.0, 0.0, 1.0])
    """
    n = unit(n0 + phi[0] * u + phi[1] * v)
    return p0 + phi[2] * u + phi[3] * v, n


def closest_point_to(point: np.ndarray, line_point: np.ndarray, n: np.ndarray) -> np.ndarray:
    """Projection of ``point`` onto the line through ``line_point`` along the unit ``n``.

    Parameters
    ----------
    point, line_point, n : numpy.ndarray
        The point, a point of the line and its unit direction (3,).

    Returns
    -------
    numpy.ndarray
        The closest point of the line (3,).

    Examples
    --------
    >>> closest_point_to(np.array([1.0, 2.0, 3.0]), np.zeros(3), np.array([0.0, 0.0, 1.0])).tolist()
    [0.0, 0.0, 3.0]
    """
    return line_point + ((point - line_point) @ n) * n


def line_distance(p1, n1, p2, n2) -> tuple[float, np.ndarray]:
    """Shortest distance between two lines and the midpoint of the common perpendicular.

    Parameters
    ----------
    p1, n1 : numpy.ndarray
        A point and the unit direction of the first line (3,).
    p2, n2 : numpy.ndarray
        The same for the second line.

    Returns
    -------
    distance : float
        The shortest distance (m).
    midpoint : numpy.ndarray
        Midpoint of the common perpendicular (3,); ``p1`` for parallel lines.

    Examples
    --------
    The x axis and a line along y through z = 1:

    >>> d, mid = line_distance(np.zeros(3), np.array([1.0, 0, 0]), np.array([0, 0, 1.0]),
    ...                        np.array([0, 1.0, 0]))
    >>> round(float(d), 12), (mid.round(12) + 0.0).tolist()
    (1.0, [0.0, 0.0, 0.5])
    """
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
