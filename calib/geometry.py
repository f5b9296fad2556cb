"""Small geometry kernels shared by the calibration estimators (pure numpy, batched).

Lines are ``(point, direction)`` pairs with a unit direction. A line near a reference line
``(p0, n0)`` is described by four *chart* coordinates ``(alpha, beta, gamma, delta)``:
its direction is ``normalize(n0 + alpha u + beta v)`` and it crosses the plane through
``p0`` perpendicular to ``n0`` at ``p0 + gamma u + delta v`` (``u, v`` an orthonormal basis
of that plane). Covariances of fitted axes are expressed in these coordinates.
"""
from __future__ import annotations

import numpy as np


def unit(v: np.ndarray) -> np.ndarray:
    v = np.asarray(v, float)
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def perp_basis(n: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """An orthonormal pair ``(u, v)`` perpendicular to the unit vector ``n`` (right-handed u, v, n)."""
    n = unit(n)
    e = np.zeros(3)
    e[int(np.argmin(np.abs(n)))] = 1.0
    u = unit(np.cross(n, e))
    v = np.cross(n, u)
    return u, v


def skew(w: np.ndarray) -> np.ndarray:
    w = np.asarray(w, float)
    K = np.zeros(w.shape[:-1] + (3, 3))
    K[..., 0, 1], K[..., 0, 2] = -w[..., 2], w[..., 1]
    K[..., 1, 0], K[..., 1, 2] = w[..., 2], -w[..., 0]
    K[..., 2, 0], K[..., 2, 1] = -w[..., 1], w[..., 0]
    return K


def rotvec_to_matrix(w: np.ndarray) -> np.ndarray:
    """Rodrigues' formula for rotation vectors (..., 3) -> (..., 3, 3)."""
    w = np.asarray(w, float)
    th = np.linalg.norm(w, axis=-1)[..., None, None]
    K = skew(w)
    small = th < 1e-12
    ths = np.where(small, 1.0, th)
    a = np.where(small, 1.0, np.sin(ths) / ths)
    b = np.where(small, 0.5, (1.0 - np.cos(ths)) / ths ** 2)
    return np.eye(3) + a * K + b * (K @ K)


def rotation_angle(R: np.ndarray) -> np.ndarray:
    """Rotation angle(s) in radians of rotation matrices (..., 3, 3)."""
    c = (np.trace(R, axis1=-2, axis2=-1) - 1.0) / 2.0
    s = np.linalg.norm(np.stack([R[..., 2, 1] - R[..., 1, 2], R[..., 0, 2] - R[..., 2, 0],
                                 R[..., 1, 0] - R[..., 0, 1]], -1), axis=-1) / 2.0
    return np.arctan2(s, np.clip(c, -1.0, 1.0))


def angle_about(R: np.ndarray, n: np.ndarray) -> np.ndarray:
    """Signed rotation angle of R (..., 3, 3) about the unit axis ``n`` (right-hand rule)."""
    vee = np.stack([R[..., 2, 1] - R[..., 1, 2], R[..., 0, 2] - R[..., 2, 0],
                    R[..., 1, 0] - R[..., 0, 1]], -1) / 2.0
    c = (np.trace(R, axis1=-2, axis2=-1) - 1.0) / 2.0
    return np.arctan2(vee @ n, c)


def rotations_about(n: np.ndarray, theta: np.ndarray) -> np.ndarray:
    """Rotation matrices (T, 3, 3) by angles ``theta`` (T,) about the unit axis ``n`` (3,)."""
    K = skew(n)
    s = np.sin(theta)[:, None, None]
    c = np.cos(theta)[:, None, None]
    return np.eye(3) + s * K + (1.0 - c) * (K @ K)


def kabsch_batch(ref: np.ndarray, obs: np.ndarray, w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Weighted least-squares rigid transforms, batched over frames.

    ``ref`` (M, 3) reference marker positions, ``obs`` (T, M, 3) observed positions (NaN
    allowed where ``w`` is 0), ``w`` (T, M) non-negative weights. Returns ``R`` (T, 3, 3) and
    ``t`` (T, 3) minimising ``sum_k w_tk |obs_tk - (R_t ref_k + t_t)|^2`` (Kabsch/Umeyama,
    with the reflection fix). Frames with less than 3 weighted markers give NaN.
    """
    w = np.asarray(w, float)
    obs = np.where(w[..., None] > 0, obs, 0.0)
    W = w.sum(axis=1)
    ok = (w > 0).sum(axis=1) >= 3
    Wsafe = np.where(W > 0, W, 1.0)
    cr = np.einsum("tm,mi->ti", w, ref) / Wsafe[:, None]
    co = np.einsum("tm,tmi->ti", w, obs) / Wsafe[:, None]
    H = np.einsum("tm,tmi,tmj->tij", w, obs - co[:, None], ref[None] - cr[:, None])
    U, _, Vt = np.linalg.svd(H)
    d = np.sign(np.linalg.det(U @ Vt))
    D = np.ones((H.shape[0], 3))
    D[:, 2] = d
    R = np.einsum("tij,tj,tjk->tik", U, D, Vt)
    t = co - np.einsum("tij,tj->ti", R, cr)
    R[~ok] = np.nan
    t[~ok] = np.nan
    return R, t


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
