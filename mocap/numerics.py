"""The numerical ground floor that ``mocap``, ``calib`` and ``ident`` share: one definition each.

- **Rotations**: :func:`skew` (the cross-product matrix), :func:`rodrigues_terms` and
  :func:`rodrigues_combine` (Rodrigues' formula, its one writing), :func:`rotation_about_axis`
  (Rodrigues' formula about a unit axis), :func:`rodrigues_axis_derivative` (its derivative
  with respect to the axis), :func:`rotvec_to_matrix` (the exponential map of a rotation
  vector) and :func:`matrix_to_rotvec` (its logarithm), :func:`rotate_about_axis` (Rodrigues'
  formula applied to vectors).
- **Savitzky-Golay differentiation**: :func:`savgol` (one filter, from cached kernels),
  :func:`savgol_kernel`, :func:`savgol_window` (the one window rule) and :func:`differentiate`
  (jointlab's differentiator, re-exported by :mod:`ident.signals.smoothing`).
- **Exponential integrator** of ``dz/dt = -a z + u``: :func:`phi`, :func:`psi` and the exact
  step's input terms :func:`zoh_drive` and :func:`foh_drive` (the LuGre bristle step of
  :mod:`ident.friction.dynamic`, the coast-down's free response of :mod:`ident.coastdown.angle`).

This module sits in ``mocap`` (the bottom of the package graph: ``calib`` depends on ``mocap``,
``ident`` on both) and imports nothing of the project but :mod:`mocap.io.errors`.
"""
from __future__ import annotations

import functools
import math

import numpy as np
from scipy.signal import savgol_coeffs, savgol_filter

from mocap.io.errors import InputError

__all__ = ["skew", "rodrigues_terms", "rodrigues_combine", "rodrigues_axis_derivative",
           "rotation_about_axis", "rotate_about_axis", "rotvec_to_matrix", "matrix_to_rotvec",
           "savgol", "savgol_kernel", "savgol_window", "differentiate", "phi", "psi", "zoh_drive",
           "foh_drive"]


# ---------------------------------------------------------------------------------------------
# rotations
# ---------------------------------------------------------------------------------------------
def skew(w: np.ndarray) -> np.ndarray:
    """Cross-product matrices (..., 3, 3) of vectors (..., 3): ``skew(w) @ x == cross(w, x)``."""
    w = np.asarray(w, float)
    K = np.zeros(w.shape[:-1] + (3, 3))
    K[..., 0, 1], K[..., 0, 2] = -w[..., 2], w[..., 1]
    K[..., 1, 0], K[..., 1, 2] = w[..., 2], -w[..., 0]
    K[..., 2, 0], K[..., 2, 1] = -w[..., 1], w[..., 0]
    return K


def rodrigues_terms(axis: np.ndarray) -> np.ndarray:
    r"""The three constant terms of Rodrigues' formula about a unit axis: ``(I, K, K^2)``.

    ``R(\theta) = I + \sin\theta\, K + (1 - \cos\theta)\, K^2`` with ``K`` the
    cross-product matrix of ``axis`` (:func:`skew`); the terms are computed once per axis and
    combined per angle by :func:`rodrigues_combine` (a chain pre-multiplies them by its fixed
    placements, :class:`mocap.kinematics.Chain`) [1]_.

    Parameters
    ----------
    axis : array_like
        (3,) unit rotation axis.

    Returns
    -------
    numpy.ndarray
        (3, 3, 3): ``I``, ``K`` and ``K @ K`` stacked along the first axis.

    References
    ----------
    .. [1] PA10 thesis (seeds 002), eq. 3-3.

    Examples
    --------
    >>> I, K, K2 = rodrigues_terms([0.0, 0.0, 1.0])
    >>> K2.diagonal().tolist()
    [-1.0, -1.0, 0.0]
    """
    K = skew(np.asarray(axis, float))
    return np.stack([np.eye(3), K, K @ K])


def rodrigues_combine(T0: np.ndarray, T1: np.ndarray, T2: np.ndarray, s: np.ndarray,
                      c: np.ndarray, out: np.ndarray | None = None,
                      scratch: np.ndarray | None = None) -> np.ndarray:
    r"""Rodrigues' formula from its terms: ``T0 + s T1 + (1 - c) T2``, ``s = sin q``, ``c = cos q``.

    With ``(T0, T1, T2) = (I, K, K^2)`` (:func:`rodrigues_terms`) this is the rotation about the
    axis; with the terms pre-multiplied by a fixed matrix ``A`` it is ``A R(q)`` (the joint step
    of the forward kinematics, thesis eq. 3-3 [1]_). The one place where the formula is written:
    :func:`rotation_about_axis` and :class:`mocap.kinematics.Chain` call it.

    Parameters
    ----------
    T0, T1, T2 : numpy.ndarray
        The terms, broadcast against ``s`` and ``c``.
    s, c : numpy.ndarray
        Sines and cosines of the angles, shaped to broadcast against the terms.
    out : numpy.ndarray, optional
        Where to write the result (in place, no temporary of the result's size but ``scratch``).
    scratch : numpy.ndarray, optional
        A buffer of the result's shape used with ``out``.

    Returns
    -------
    numpy.ndarray
        The combination (``out`` when given).

    References
    ----------
    .. [1] PA10 thesis (seeds 002), eq. 3-3.

    Examples
    --------
    >>> I, K, K2 = rodrigues_terms([0.0, 0.0, 1.0])
    >>> np.round(rodrigues_combine(I, K, K2, 1.0, 0.0) @ [1.0, 0.0, 0.0], 12).tolist()
    [0.0, 1.0, 0.0]
    """
    if out is None:
        return T0 + s * T1 + (1.0 - c) * T2
    np.multiply(T1, s, out=out)
    out += T0
    np.multiply(T2, 1.0 - c, out=scratch)
    out += scratch
    return out


def rodrigues_axis_derivative(e: np.ndarray, d: np.ndarray, axis: np.ndarray,
                              s: np.ndarray, c: np.ndarray) -> np.ndarray:
    r"""Derivative of ``R(n, q) d`` (Rodrigues) as the unit axis ``n`` moves along ``e``, ``e \perp n``.

    .. math::

        \frac{\partial}{\partial \epsilon} R(n + \epsilon e, q)\, d
        = \sin q\, (e \times d) + (1 - \cos q) \left(e\, (n \cdot d) + n\, (e \cdot d)\right)

    (the derivative of ``sin q K + (1 - cos q) K^2`` with ``K = [n]_x``, using
    ``[e]_x [n]_x + [n]_x [e]_x = n e^T + e n^T - 2 (e . n) I`` and ``e . n = 0``): the axis
    columns of the rigid-sweep Jacobian of :class:`calib.axis.ClusterAxisEstimator` [1]_.

    Parameters
    ----------
    e : numpy.ndarray
        (3,) direction of the axis' motion, perpendicular to ``axis``.
    d : numpy.ndarray
        (K, 3) vectors rotated.
    axis : numpy.ndarray
        (3,) unit rotation axis ``n``.
    s, c : numpy.ndarray
        (K, 1) sines and cosines of the angles.

    Returns
    -------
    numpy.ndarray
        (K, 3) the derivative of each rotated vector.

    References
    ----------
    .. [1] PA10 thesis (seeds 002), eq. 3-3 (the joint rotation).
    """
    return s * np.cross(e, d) + (1.0 - c) * (e[None] * (d @ axis)[:, None]
                                             + axis[None] * (d @ e)[:, None])


def rotation_about_axis(axis: np.ndarray, angle: np.ndarray) -> np.ndarray:
    r"""Rotation matrices about a unit axis (Rodrigues' formula).

    .. math::

        R = I + \sin\theta\, K + (1 - \cos\theta)\, K^2

    with ``K`` the cross-product matrix of ``axis`` (:func:`skew`): the joint rotation of the
    forward kinematics behind thesis eq. 3-3 [1]_ (:func:`rodrigues_terms` combined by
    :func:`rodrigues_combine`).

    Parameters
    ----------
    axis : array_like
        (3,) unit rotation axis.
    angle : array_like
        (...) angles (rad).

    Returns
    -------
    numpy.ndarray
        (..., 3, 3) rotation matrices.

    References
    ----------
    .. [1] PA10 thesis (seeds 002), eq. 3-3.

    Examples
    --------
    >>> np.round(rotation_about_axis([0.0, 0.0, 1.0], np.pi / 2) @ [1.0, 0.0, 0.0], 12)
    array([0., 1., 0.])
    """
    I, K, K2 = rodrigues_terms(axis)
    angle = np.asarray(angle, float)
    return rodrigues_combine(I, K, K2, np.sin(angle)[..., None, None], np.cos(angle)[..., None, None])


def rotate_about_axis(x_perp: np.ndarray, a_cross_x: np.ndarray, x_along: np.ndarray,
                      angle: np.ndarray) -> np.ndarray:
    r"""Vectors rotated about a unit axis ``a`` by ``angle`` (Rodrigues' formula on vectors).

    .. math::

        R(a, \theta)\, x = \cos\theta\, x_\perp + \sin\theta\, (a \times x)
        + (x \cdot a)\, a

    from the vector's parts, computed once per vector: ``x_perp`` (the part perpendicular to
    ``a``), ``a_cross_x`` and ``x_along`` (``(x . a) a``); ``angle`` (T,) broadcasts over
    leading axes, the parts (..., 3) over trailing ones (the marker solve's per-frame model,
    thesis eq. 3-5).

    Returns
    -------
    numpy.ndarray
        (T, ..., 3).

    Examples
    --------
    >>> r = rotate_about_axis(np.array([[1.0, 0, 0]]), np.array([[0, 1.0, 0]]), np.zeros((1, 3)),
    ...                       np.array([np.pi / 2]))
    >>> np.round(r, 12).tolist()
    [[[0.0, 1.0, 0.0]]]
    """
    angle = np.asarray(angle, float)
    c = np.cos(angle)[:, None, None]
    s = np.sin(angle)[:, None, None]
    return c * x_perp + s * a_cross_x + x_along


def rotvec_to_matrix(w: np.ndarray) -> np.ndarray:
    """Rodrigues' formula for rotation vectors (..., 3) -> (..., 3, 3) (the exponential map of
    SO(3); ``I`` at the zero vector)."""
    w = np.asarray(w, float)
    th = np.linalg.norm(w, axis=-1)[..., None, None]
    K = skew(w)
    small = th < 1e-12
    ths = np.where(small, 1.0, th)
    a = np.where(small, 1.0, np.sin(ths) / ths)
    b = np.where(small, 0.5, (1.0 - np.cos(ths)) / ths ** 2)
    return np.eye(3) + a * K + b * (K @ K)


def matrix_to_rotvec(R: np.ndarray) -> np.ndarray:
    """Rotation vectors (..., 3) of rotation matrices (..., 3, 3): the logarithm of SO(3), the
    inverse of :func:`rotvec_to_matrix` (``scipy.spatial.transform.Rotation``'s, angles in
    [0, pi])."""
    from scipy.spatial.transform import Rotation

    R = np.asarray(R, float)
    return Rotation.from_matrix(R.reshape(-1, 3, 3)).as_rotvec().reshape(R.shape[:-2] + (3,))


# ---------------------------------------------------------------------------------------------
# Savitzky-Golay differentiation
# ---------------------------------------------------------------------------------------------
@functools.lru_cache(maxsize=512)
def _savgol_plan(w: int, p: int, deriv: int, delta: float):
    """Cached linear maps of a Savitzky-Golay filter (``scipy.signal.savgol_filter``'s, mode
    ``"interp"``): the interior coefficients (``savgol_coeffs``, dot order) and the matrices
    that evaluate the polynomial fitted to the first / last ``w`` samples (or its ``deriv``-th
    derivative) at the first / last ``w // 2`` positions."""
    c = savgol_coeffs(w, p, deriv=deriv, delta=delta, use="dot")
    h = w // 2
    mid = (w - 1) / 2.0
    k = np.arange(p + 1)
    V = ((np.arange(w) - mid) / max(h, 1))[:, None] ** k          # scaled positions in [-1, 1]
    P = np.linalg.pinv(V)                                           # samples -> poly coefficients
    fac = np.array([math.perm(int(j), deriv) for j in k], float)   # d^deriv u^j = j!/(j-deriv)! u^(j-deriv)

    def at(pos):
        u = (pos - mid) / max(h, 1)
        pw = np.where(k >= deriv, u[:, None] ** np.maximum(k - deriv, 0), 0.0) * fac
        return pw @ P / (max(h, 1) * delta) ** deriv

    return c, at(np.arange(h, dtype=float)), at(np.arange(w - h, w, dtype=float))


def savgol(x, w: int, p: int, deriv: int = 0, delta: float = 1.0) -> np.ndarray:
    """``scipy.signal.savgol_filter(x, w, p, deriv, delta, mode="interp")`` (the same values to
    rounding) from cached coefficients: a valid correlation in the interior and the edge
    polynomials as two small matrix products."""
    x = np.asarray(x, float)
    n = x.size
    if w > n:
        raise ValueError(f"window {w} is longer than the {n} samples")
    c, Ms, Me = _savgol_plan(int(w), int(p), int(deriv), float(delta))
    h = w // 2
    y = np.empty(n)
    y[h:n - h] = np.correlate(x, c, mode="valid")
    y[:h] = Ms @ x[:w]
    y[n - h:] = Me @ x[n - w:]
    return y


def savgol_window(window_s: float, dt: float, n: int, polyorder: int = 3) -> int:
    """The one window rule of jointlab's Savitzky-Golay filters, in samples.

    ``window_s`` seconds at the sample period ``dt`` rounded to an odd number of samples, at
    least ``polyorder + 2`` (odd) and at most the ``n`` samples (odd) [1]_.

    Parameters
    ----------
    window_s : float
        Window length (s).
    dt : float
        Sample period (s).
    n : int
        Number of samples.
    polyorder : int, optional
        Local polynomial degree (default 3).

    Returns
    -------
    int
        The odd window length in samples.

    References
    ----------
    .. [1] Savitzky & Golay 1964, smoothing and differentiation of data by simplified least
       squares procedures.

    Examples
    --------
    >>> savgol_window(0.05, 0.01, 1000), savgol_window(0.05, 0.01, 4)
    (5, 3)
    """
    w = int(round(window_s / dt)) | 1
    w = max(w, polyorder + 2 + (polyorder % 2 == 0))
    return min(w, n if n % 2 else n - 1)


def differentiate(x, dt: float, window_s: float, deriv: int = 1, polyorder: int = 3) -> np.ndarray:
    """Differentiate uniform samples by a Savitzky-Golay filter: jointlab's one differentiator.

    The ``deriv``-th derivative (0: the smoothed signal) of the local least-squares
    polynomials of degree ``polyorder`` [1]_ over :func:`savgol_window`
    (``scipy.signal.savgol_filter``, mode ``"interp"``; 1-D signals through the cached kernel,
    the same values to rounding).

    Parameters
    ----------
    x : array_like
        Uniform samples, along axis 0.
    dt : float
        Sample period (s).
    window_s : float
        Window length (s).
    deriv : int, optional
        Derivative order (default 1).
    polyorder : int, optional
        Local polynomial degree (default 3).

    Returns
    -------
    numpy.ndarray
        The derivative, the shape of ``x`` (units of ``x`` per s^deriv).

    Raises
    ------
    InputError
        If the samples are too few for the window.

    References
    ----------
    .. [1] Savitzky & Golay 1964, smoothing and differentiation of data by simplified least
       squares procedures.

    Examples
    --------
    >>> t = np.arange(50) * 0.01
    >>> round(float(differentiate(t ** 2, 0.01, 0.05)[10]), 9)
    0.2
    """
    x = np.asarray(x, float)
    n = x.shape[0]
    w = savgol_window(window_s, dt, n, polyorder)
    if w < polyorder + 2:
        raise InputError(f"{n} samples are too few to differentiate")
    if x.ndim == 1:
        return savgol(x, w, polyorder, deriv, dt)
    return savgol_filter(x, w, polyorder, deriv=deriv, delta=dt, axis=0, mode="interp")


@functools.lru_cache(maxsize=512)
def savgol_kernel(w: int, p: int, deriv: int = 0, delta: float = 1.0) -> np.ndarray:
    """The Savitzky-Golay kernel of window ``w``, degree ``p``, derivative ``deriv`` at step
    ``delta`` (``scipy.signal.savgol_coeffs``, convolution order), cached and read-only."""
    c = savgol_coeffs(w, p, deriv=deriv, delta=delta)
    c.setflags(write=False)
    return c


# ---------------------------------------------------------------------------------------------
# exponential integrator of dz/dt = -a z + u
# ---------------------------------------------------------------------------------------------
#: below this |x| the series of :func:`phi` replaces its closed form (truncation x^3/24: below
#: the closed form's rounding; the closed form has no cancellation)
_PHI_SERIES_BELOW = 1e-5
#: below this |x| the series of :func:`psi` replaces its closed form, whose cancellation costs
#: about 2 eps / x (the series' truncation, x^3/120, balances it near here)
_PSI_SERIES_BELOW = 1e-3


def phi(x):
    r"""``phi(x) = (1 - e^{-x}) / x``, 1 at ``x = 0``: the exact integral
    :math:`\frac{1}{h}\int_0^h e^{-a (h - s)} ds` of a step ``h`` at ``x = a h`` (the input
    weight of the exact discretisation of a first-order linear system, Indri & Trapani eq. 29).

    A complex ``x`` (a complex rate, or ``x = s h`` of a Laplace/Fourier variable ``s``) gives the
    complex value by the same two branches (numpy's complex ``expm1``); ``t phi(-lambda t)`` is
    :math:`\int_0^t e^{\lambda s} ds` for any complex ``lambda``. A real ``x`` stays real.

    Examples
    --------
    >>> float(phi(0.0)), round(float(phi(1.0)), 12)
    (1.0, 0.632120558829)
    >>> complex(np.round(phi(1j), 12))          # (1 - e^{-i}) / i = sin 1 - i (1 - cos 1)
    (0.841470984808-0.459697694132j)
    """
    x = np.asarray(x, complex if np.iscomplexobj(x) else float)
    small = np.abs(x) < _PHI_SERIES_BELOW
    xs = np.where(small, 1.0, x)
    return np.where(small, 1.0 - x / 2.0 + x * x / 6.0, -np.expm1(-xs) / xs)


def psi(x):
    r"""``psi(x) = (x - 1 + e^{-x}) / x^2``, 1/2 at ``x = 0``: the second-order companion of
    :func:`phi` (``phi(x) = 1 - x psi(x)``), the weight of a ramp input in the exact step.

    Examples
    --------
    >>> float(psi(0.0))
    0.5
    """
    x = np.asarray(x, float)
    small = np.abs(x) < _PSI_SERIES_BELOW
    xs = np.where(small, 1.0, x)
    return np.where(small, 0.5 - x / 6.0 + x * x / 24.0, (xs + np.expm1(-xs)) / (xs * xs))


def zoh_drive(x, h, b):
    r"""The input term of the exact step of ``dz/dt = -a z + b`` over a step ``h`` with ``b``
    held: ``z(h) = e^{-x} z(0) + h phi(x) b``, ``x = a h`` (Indri & Trapani eq. 29-30, the
    LuGre bristle state with the velocity held over the step)."""
    return h * phi(x) * b


def foh_drive(x, zs0, zs1):
    r"""The input term of the exact step of ``dz/dt = -a (z - z_ss(t))`` with ``z_ss`` linear
    over the step from ``zs0`` to ``zs1`` and ``x`` the step's integrated rate:
    ``z(h) = e^{-x} z(0) + (1 - e^{-x}) zs0 + (zs1 - zs0) (1 - phi(x))`` (first-order hold)."""
    return -np.expm1(-x) * zs0 + (zs1 - zs0) * (1.0 - phi(x))
