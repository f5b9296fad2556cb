"""Friction laws, one function each: the single definition every part of jointlab evaluates.

Link side, SI (N m, rad, rad/s). Each law is a plain function of the velocity and the law's
parameters; the ones a solver or a linear fit needs also come as their slope or as the
columns that multiply their linear parameters. The model classes
(:mod:`ident.friction.static`, :mod:`ident.friction.dynamic`), both simulator paths
(:mod:`ident.sim.plant`), the rigid-body fit (:mod:`ident.model.rigidbody`) and the link-state
estimator call these functions (never a written-out copy), so a change here changes all of
them (tests/test_friction_laws.py checks that by patching a law).

Callers look the functions up through the module (``laws.coulomb_viscous(...)``) at call
time. Functions that a scalar simulator calls per step take the elementary function
(``exp``) as an argument, so that plain Python floats stay plain floats there.

Equations: Coulomb + viscous, thesis eq. 2-5; Stribeck, thesis eq. 2-6 (and the simulator's
``sign(qd) (c + S exp(-|qd|/Vc))`` form of the same law); hyperbolic, thesis eq. 2-7 (Makkar et
al. 2005); arctangent, Indri & Trapani 2020 eq. 1-2, 8, 9 with the smooth sign/abs eq. 2, 7;
LuGre bristle dynamics, Indri & Trapani eq. 5 (the classical LuGre model for the exact
sign). Named thresholds: :mod:`ident.friction.constants`.
"""
from __future__ import annotations

import numpy as np

from ident.friction.constants import KV_DEFAULT, SIGN_WIDTH

_2_PI = 2.0 / np.pi

__all__ = ["smooth_sign", "s0", "s1", "coulomb_viscous",
           "coulomb_viscous_columns", "stribeck_drop", "stribeck_columns", "stribeck_excess",
           "stribeck_excess_slope", "hyperbolic_columns", "arctan_columns", "arctan_g",
           "arctan_viscous", "lugre_rates", "lugre_implicit_step"]


# --------------------------------------------------------------------------------------------
# signs
# --------------------------------------------------------------------------------------------
def smooth_sign(v, width: float = SIGN_WIDTH):
    """``tanh(v / width)``: a continuous ``sign(v)`` with slope ``1/width`` at 0
    (:data:`ident.friction.constants.SIGN_WIDTH`)."""
    return np.tanh(v / width)


def s0(v, Kv: float = KV_DEFAULT) -> np.ndarray:
    r"""Smooth sign of Indri & Trapani eq. 2: a continuous ``sign(v)``.

    .. math::

        S_0(v) = \frac{2}{\pi} \arctan(K_v v)

    the arctangent approximation of the sign that the arctan static model and the LuGre-type
    dynamic models use [1]_; it tends to ``sign(v)`` as ``Kv`` grows.

    Parameters
    ----------
    v : array_like
        Velocity (rad/s).
    Kv : float, optional
        Steepness of the arctangent (s/rad); default
        :data:`ident.friction.constants.KV_DEFAULT` (the paper's 1000).

    Returns
    -------
    numpy.ndarray
        ``S0(v)``, in (-1, 1), shaped like ``v``.

    References
    ----------
    .. [1] Indri & Trapani 2020 (seeds 001), eq. 2.

    Examples
    --------
    >>> s0([-1.0, 0.0, 1.0], Kv=1000.0).round(4).tolist()
    [-0.9994, 0.0, 0.9994]
    """
    return _2_PI * np.arctan(Kv * np.asarray(v, float))


def s1(v, Kv: float = KV_DEFAULT) -> np.ndarray:
    r"""Smooth absolute value of Indri & Trapani eq. 7: a continuous ``|v|``, never negative.

    .. math::

        S_1(v) = S_0(v)\, v

    with :math:`S_0` the smooth sign :func:`s0` (eq. 2) [1]_.

    Parameters
    ----------
    v : array_like
        Velocity (rad/s).
    Kv : float, optional
        Steepness of the arctangent of :func:`s0` (s/rad); default
        :data:`ident.friction.constants.KV_DEFAULT` (the paper's 1000).

    Returns
    -------
    numpy.ndarray
        ``S1(v) >= 0`` (rad/s), shaped like ``v``.

    References
    ----------
    .. [1] Indri & Trapani 2020 (seeds 001), eq. 7.

    Examples
    --------
    >>> s1([-2.0, 0.0, 2.0], Kv=1000.0).round(4).tolist()
    [1.9994, 0.0, 1.9994]
    """
    v = np.asarray(v, float)
    return s0(v, Kv) * v


# --------------------------------------------------------------------------------------------
# static laws
# --------------------------------------------------------------------------------------------
def coulomb_viscous_columns(qd, sign=np.sign) -> np.ndarray:
    """Thesis eq. 2-5's regressor: (T, 2) columns ``[sign(qd), qd]`` multiplying ``(c, v)``,
    the law :func:`coulomb_viscous` at unit parameters. ``sign``: the sign function (default
    exact; :func:`smooth_sign` for a regularised one)."""
    qd = np.asarray(qd, float)
    return np.column_stack([coulomb_viscous(qd, 1.0, 0.0, sign), coulomb_viscous(qd, 0.0, 1.0, sign)])


def coulomb_viscous(qd, c, v, sign=np.sign):
    """Thesis eq. 2-5: ``f = c sign(qd) + v qd`` (broadcasts over ``qd`` and the parameters)."""
    qd = np.asarray(qd, float)
    return c * sign(qd) + v * qd


def stribeck_drop(qd, Vc):
    """The Stribeck column of thesis eq. 2-6, ``-sign(qd) (1 - exp(-|qd| / Vc))``
    (broadcasts: a (T, 1) ``qd`` and (K,) ``Vc`` give the (T, K) columns of K values)."""
    qd = np.asarray(qd, float)
    return np.sign(qd) * np.expm1(-np.abs(qd) / Vc)


def stribeck_columns(qd, Vc: float) -> np.ndarray:
    """Thesis eq. 2-6, ``f = Fk sign(qd) + Fv qd - sign(qd) Fs (1 - exp(-|qd| / Vc))``: the
    (T, 3) columns multiplying ``(Fk, Fv, Fs)`` for a fixed ``Vc >= 0`` (``Vc = 0`` is the
    limit ``Vc -> 0+``, where the drop is a second sign column)."""
    qd = np.asarray(qd, float)
    sgn = np.sign(qd)
    if Vc < 0 or not np.isfinite(Vc):
        raise ValueError(f"stribeck: Vc must be finite and >= 0, got {Vc}")
    drop = -sgn if Vc == 0 else stribeck_drop(qd, Vc)
    return np.stack([sgn, qd, drop], axis=-1)


def stribeck_excess(speed, S, Vc, exp=np.exp):
    """The Stribeck law as the simulator writes it, ``f = sign(qd) (c + S exp(-|qd|/Vc)) +
    v qd`` (thesis eq. 2-6 with ``c = Fk - Fs``, ``S = Fs``): the excess ``S exp(-speed / Vc)``
    over the Coulomb level at ``speed = |qd|``. ``exp``: ``math.exp`` for scalar callers."""
    return S * exp(-speed / Vc)


def stribeck_excess_slope(speed, S, Vc, exp=np.exp):
    """``d/dspeed`` of :func:`stribeck_excess`: ``-S/Vc exp(-speed / Vc)``."""
    return -S / Vc * exp(-speed / Vc)


def hyperbolic_columns(qd, g2: float, g3: float, g5: float) -> np.ndarray:
    """Thesis eq. 2-7, ``f = g1 (tanh(g2 qd) - tanh(g3 qd)) + g4 tanh(g5 qd) + g6 qd``: the
    (T, 3) columns multiplying ``(g1, g4, g6)`` for fixed ``(g2, g3, g5)``."""
    qd = np.asarray(qd, float)
    return np.stack([np.tanh(g2 * qd) - np.tanh(g3 * qd), np.tanh(g5 * qd), qd], axis=-1)


def arctan_columns(qd, delta: float, Kv: float = KV_DEFAULT) -> np.ndarray:
    """Indri & Trapani eq. 1-2 (regressor eq. 28), ``tau_f = tau_s S0(v) + tau_sc 2/pi
    arctan(delta v) + tau_v v + tau_nlv v^2 S0(v)``: the (T, 4) columns multiplying
    ``(tau_s, tau_sc, tau_v, tau_nlv)``."""
    qd = np.asarray(qd, float)
    sg = s0(qd, Kv)
    return np.stack([sg, _2_PI * np.arctan(qd * delta), qd, qd * qd * sg], axis=-1)


def arctan_g(v, tau_s, tau_sc, delta, Kv: float = KV_DEFAULT):
    """Indri & Trapani eq. 8, the Stribeck curve of the dynamic models:
    ``g(v) = tau_s + tau_sc 2/pi arctan(S1(v) delta)``."""
    return tau_s + tau_sc * _2_PI * np.arctan(s1(v, Kv) * delta)


def arctan_viscous(v, tau_v, tau_nlv, Kv: float = KV_DEFAULT):
    """Indri & Trapani eq. 9: ``tau_fv(v) = tau_v v + tau_nlv v^2 S0(v)``."""
    v = np.asarray(v, float)
    return tau_v * v + tau_nlv * v * v * s0(v, Kv)


# --------------------------------------------------------------------------------------------
# LuGre bristle dynamics (eq. 5): dz/dt = b - a z
# --------------------------------------------------------------------------------------------
def lugre_rates(v, sigma0, g, Kv: float = KV_DEFAULT, rest_speed: float = 0.0):
    """Indri & Trapani eq. 5 (and 30) written ``dz/dt = b - a z``: ``(a, b)`` with
    ``a = sigma0 (S1(v) + rest_speed) / g(v)`` (1/s) and ``b = S0(v)^2 v``
    (``rest_speed`` 0: the paper's law; see :mod:`ident.friction.dynamic`)."""
    return sigma0 * (s1(v, Kv) + rest_speed) / g, s0(v, Kv) ** 2 * v


def lugre_implicit_step(z, x, dt, sigma0, g):
    """One backward-Euler step of the classical LuGre law ``dz/dt = x - sigma0 |x| z / g``
    (eq. 5 with the exact sign: ``S0 = sign``, ``S1 = |x|``) for the end-of-step velocity
    ``x``: ``(z1, dz1/dx)`` with ``z1 = (z + dt x) / (1 + dt sigma0 |x| / g)``. The slope is
    what the simulator's Newton solve for ``x`` needs (scalar or array arguments)."""
    sg = (x >= 0.0) * 2.0 - 1.0
    Dz = 1.0 + dt * sigma0 * abs(x) / g
    Nz = z + dt * x
    return Nz / Dz, (dt * Dz - Nz * dt * sigma0 * sg / g) / (Dz * Dz)
