"""LuGre-type dynamic friction of Indri & Trapani 2020 (eq. 5-9) with bristle damping variants.

State ``z`` (average bristle deflection, rad):

    dz/dt = S0(v)^2 v - sigma0 S1(v) / g(v) z                                  (eq. 5)
    tau_f = sigma0 z + f_sigma1(.) dz/dt + tau_fv(v)                            (eq. 6)

with ``S0``, ``S1`` the smooth sign/abs (eq. 2, 7), ``g`` the Stribeck curve (eq. 8) and
``tau_fv`` the viscous part (eq. 9), all taken from the static :class:`Arctan` model given as the
``static`` setting (its five parameters are fixed here; identify them first, step 1 of the
paper). At constant velocity z settles at ``S0(v) g(v) / sigma0`` and the friction equals
``S0(v) g(v) + tau_fv(v)``, the static arctan curve up to the smooth-sign approximation
(``S0(v) arctan(S1(v) delta)`` vs ``arctan(v delta)``: relative difference ~ 1 - S0(v), i.e.
about 0.13% at 0.5 rad/s with Kv = 1000).

Models:
  * ``dm1`` (sigma0, sigma1): ``f_sigma1`` selected by the ``damping`` setting:
    ``"constant"`` (sigma1, standard LuGre, phase 2-A of the paper), ``"eq10"``
    (sigma1 g(v)/|v|), ``"eq11"`` (sigma1/|v|, the paper's DM1 of Tables I-II) or ``"eq12"``
    (sigma1 (1 - 2/pi arctan(|v| delta))). In eq. 10-12 ``|v|`` is the smooth ``S1(v)``;
    because ``dz/dt = S1(v) (S0(v) - sigma0 z / g(v))`` exactly, eq. 10 and 11 become the
    bounded, continuous ``sigma1 (g S0 - sigma0 z)`` and ``sigma1 (S0 - sigma0 z / g)``.
  * ``dm2`` (sigma0, alpha, beta, gamma): the proposed acceleration-dependent damping eq. 24,
    ``f_sigma1 = alpha / sqrt(gamma (r v)^2 + a^2) + beta`` with ``r = a_max / v_max``
    (setting ``accel_ratio``; None: taken from the signals of each ``torque`` call, as the
    paper defines it from the acquisition). ``accel_floor`` (rad/s^2, default 1e-6) keeps the
    root positive when v = a = 0.

Standstill (setting ``rest_speed``, rad/s, default 0 = the paper's model): with eq. 5 the state
freezes when the joint stops (``S0(0) = S1(0) = 0``), so the model keeps its last friction
``sigma0 z = +-g`` through a standstill, while the static model gives ``tau_s S0(0) = 0``: at
v = 0, a steady state too, the two then differ by up to g. Which is right is a property of the
joint (a bristle that holds its deflection, or friction that relaxes as the joint creeps),
so jointlab makes it identifiable: ``a = sigma0 (S1(v) + rest_speed)/g(v)`` relaxes the
bristle at standstill with the time constant ``g/(sigma0 rest_speed)`` and changes the
moving steady state by the factor ``S1/(S1 + rest_speed)`` (1 for |v| >> rest_speed).
Measured on an independent simulator without presliding (tanh-regularised Coulomb, 1.5 s
rests): the frozen state alone made DM2's RMS 2-4 times the static model's over the rests.

Sampled signals (setting ``hold``): eq. 5 is ``dz/dt = a(v) (z_ss(v) - z)`` with
``a = sigma0 S1(v)/g(v)`` (eq. 30) and the steady deflection ``z_ss = S0(v) g(v)/sigma0``.

* ``hold="zero"``: the paper's exact discretisation eq. 29-30, the velocity held at ``v_k``
  over each step. The state then lags the continuous one by about Ts/2 when the velocity
  ramps, and where ``a Ts >> 1`` (a stiff bristle, ``sigma0 |v| Ts >> g``: at 1 kHz any
  sigma0 above ~1e4 at 1 rad/s) ``z_{k}`` is the steady state of ``v_{k-1}``, one sample late:
  ``dz/dt = b_k - a_k z_k`` is then a spike of ``a_k (z_ss(v_k) - z_ss(v_{k-1}))`` at every
  velocity change, which the damping term multiplies (measured on an independent simulator:
  DM2 7-40 % worse than the static model on a joint without presliding).
* ``hold="first"`` (default): exponential integration with ``a`` averaged over the step
  (trapezoid) and ``z_ss`` linear between the samples (first-order hold):

      z_{k+1} = e^{-x} z_k + (1 - e^{-x}) zss_k + (zss_{k+1} - zss_k) (1 - (1 - e^{-x})/x),
      x = Ts (a_k + a_{k+1}) / 2.

  Second-order accurate where ``a Ts << 1`` (no Ts/2 lag), and exact in the stiff limit:
  ``z_{k+1} -> zss_{k+1}`` and ``dz/dt -> (zss_{k+1} - zss_k)/Ts``, the derivative of the
  steady deflection, so a stiff bristle reduces DM1/DM2 to the static model sample by sample
  (not only in steady state). It needs ``v_{k+1}``, which a controller has when it computes
  the friction of sample k+1 (the C export keeps the previous velocity).

Either way the z recursion is linear for a known velocity sequence and is solved by
:func:`linear_scan` without a per-sample loop; the torque at sample k uses ``z_k``, ``v_k``,
``a_k`` and ``dz/dt_k = a_k (zss_k - z_k)``. ``state_derivative``/``output`` serve
continuous-time integrators.
"""
from __future__ import annotations

import numpy as np

from ident.friction import laws
from ident.friction.base import FrictionModel
from ident.friction.laws import _2_PI, s0, s1
from ident.friction.static import Arctan
from mocap.numerics import foh_drive, zoh_drive


# --------------------------------------------------------------------------------------------
# the vectorised linear recursion
# --------------------------------------------------------------------------------------------
def _scan_small(decay, drive, z0):
    """Direct solution for one short sequence: (n+1,) states."""
    n = decay.shape[0]
    D = np.concatenate([[0.0], np.cumsum(decay)])
    k = np.arange(n + 1)[:, None]
    j = np.arange(n)[None, :]
    mask = k > j
    E = np.where(mask, D[:, None] - D[None, 1:], 0.0)
    W = np.where(mask, np.exp(-E), 0.0)
    return W @ drive + np.exp(-D) * z0


def _weight_pairs(block: int) -> tuple:
    """The (k, j) pairs with k > j of a block's weight matrix (block+1, block): ``k``,
    ``j + 1`` and the flat index ``k block + j``."""
    k, j = np.nonzero(np.arange(block + 1)[:, None] > np.arange(block)[None, :])
    return k, j + 1, k * block + j


def linear_scan(decay, drive, z0: float, block: int = 8, max_chunks: int = 1024) -> np.ndarray:
    r"""Solve the linear recursion of the bristle state, eq. 29, without a loop over samples.

    .. math::

        z_{k+1} = e^{-d_k} z_k + u_k, \qquad z_0 = z0, \qquad k = 0, \dots, n-1

    with ``d = decay`` >= 0 (a contraction, as in eq. 29 with a_k >= 0 [1]_) and
    ``u = drive``. The sequence is cut into blocks of ``block`` steps; inside a block every
    state is a weighted sum of the drives with weights ``exp(-(D_k - D_{j+1})) <= 1`` formed
    from block-local cumulative decays (no cumulative product, so nothing under- or overflows
    and no precision is lost to large cumulative sums); the block-to-block carries form the
    same recursion on n/block elements, solved recursively. Work O(n block), depth
    log_block(n), no Python loop over samples.

    Parameters
    ----------
    decay : array_like
        (n,) decays ``d_k`` (e.g. ``a_k Ts``), finite and >= 0.
    drive : array_like
        (n,) drives ``u_k``.
    z0 : float
        The initial state.
    block : int, optional
        Steps per block (default 8).
    max_chunks : int, optional
        Blocks processed together, which bounds the memory (default 1024: the weights of a
        group stay in the processor's cache). The states do not depend on it.

    Returns
    -------
    numpy.ndarray
        The (n+1,) states ``z_0 ... z_n``.

    Raises
    ------
    ValueError
        If ``decay`` and ``drive`` are not equal 1-D shapes, or a decay is negative or not
        finite.

    References
    ----------
    .. [1] Indri & Trapani 2020 (seeds 001), eq. 29-30.

    Examples
    --------
    >>> linear_scan([0.0, 0.0, 0.0], [1.0, 1.0, 1.0], z0=0.5).tolist()
    [0.5, 1.5, 2.5, 3.5]
    """
    decay = np.asarray(decay, float)
    drive = np.asarray(drive, float)
    if decay.shape != drive.shape or decay.ndim != 1:
        raise ValueError(f"linear_scan: decay {decay.shape} and drive {drive.shape} must be equal 1-D")
    if np.any(decay < 0) or not np.all(np.isfinite(decay)):
        raise ValueError("linear_scan: decay must be finite and >= 0")
    n = decay.shape[0]
    if n <= block:
        return _scan_small(decay, drive, float(z0))
    nb = -(-n // block)
    pad = nb * block - n
    dec = np.concatenate([decay, np.zeros(pad)]).reshape(nb, block)
    drv = np.concatenate([drive, np.zeros(pad)]).reshape(nb, block)
    D = np.zeros((nb, block + 1))                     # block-local cumulative decays
    np.cumsum(dec, axis=1, out=D[:, 1:])
    k, j1, flat = _weight_pairs(block)
    loc = np.empty((nb, block + 1))
    W = np.zeros((min(nb, max(int(max_chunks), 1)), (block + 1) * block))   # zero where k <= j
    for g0 in range(0, nb, max(int(max_chunks), 1)):  # groups of blocks bound the memory
        Dg = D[g0:g0 + W.shape[0]]
        w = W[:Dg.shape[0]]
        w[:, flat] = np.exp(-(Dg[:, k] - Dg[:, j1]))   # exp(-(D_k - D_{j+1})), k > j
        np.matmul(w.reshape(-1, block + 1, block), drv[g0:g0 + W.shape[0], :, None],
                  out=loc[g0:g0 + W.shape[0], :, None])
    carry = linear_scan(D[:, block], loc[:, block], z0, block, max_chunks)   # (nb+1,)
    z = loc[:, :block] + np.exp(-D[:, :block]) * carry[:nb, None]
    return np.concatenate([z.ravel(), carry[nb:]])[: n + 1]


# --------------------------------------------------------------------------------------------
class _LuGre(FrictionModel):
    """Common machinery of eq. 5-9; subclasses define the damping term (eq. 6's f_sigma1 dz/dt)."""

    dynamic = True
    linear_names: tuple[str, ...] = ()

    HOLDS = ("first", "zero")

    def __init__(self, *, static: Arctan, z0: float | None = None, hold: str = "first",
                 rest_speed: float = 0.0, **params):
        super().__init__(**params)
        if not isinstance(static, Arctan):
            raise TypeError(f"{type(self).__name__}: static must be an Arctan model, got {static!r}")
        if not self._p["sigma0"] > 0:
            raise ValueError(f"{type(self).__name__}: sigma0 must be positive, got {self._p['sigma0']}")
        if hold not in self.HOLDS:
            raise ValueError(f"{type(self).__name__}: hold must be one of {self.HOLDS}, got {hold!r}")
        if not (np.isfinite(rest_speed) and rest_speed >= 0):
            raise ValueError(f"{type(self).__name__}: rest_speed must be >= 0, got {rest_speed}")
        self.static = static
        self.z0 = None if z0 is None else float(z0)
        self.hold = hold
        self.rest_speed = float(rest_speed)

    @property
    def settings(self) -> dict:
        return {"static": self.static, "z0": self.z0, "hold": self.hold,
                "rest_speed": self.rest_speed}

    def to_dict(self) -> dict:
        d = super().to_dict()
        d["settings"] = {k: (v.to_dict() if isinstance(v, FrictionModel) else v)
                         for k, v in self.settings.items()}
        return d

    # -- eq. 5 pieces --------------------------------------------------------------------
    def _g(self, v):
        g = self.static.g(v)
        if np.any(g <= 0):
            raise ValueError(f"{type(self).__name__}: the static curve g(v) = tau_s + tau_sc ... "
                             f"must be positive (min {np.min(g):.3g}); check the static parameters")
        return g

    def _ab(self, v):
        """Eq. 30: ``a = sigma0 (S1(v) + rest_speed)/g(v)`` (1/s) and ``b = S0(v)^2 v``;
        dz/dt = b - a z (``rest_speed`` 0: the paper's eq. 30)."""
        g = self._g(v)
        a, b = laws.lugre_rates(v, self._p["sigma0"], g, self.static.Kv, self.rest_speed)
        return a, b, g

    def _zss(self, v, g):
        """``b/a``: ``S0 g/sigma0`` times ``S1/(S1 + rest_speed)`` (1 when rest_speed = 0)."""
        v = np.asarray(v, float)
        z = s0(v, self.static.Kv) * g / self._p["sigma0"]
        if self.rest_speed > 0:
            S1 = s1(v, self.static.Kv)
            z = z * S1 / (S1 + self.rest_speed)
        return z

    def steady_state(self, v) -> np.ndarray:
        """z where dz/dt = 0 at constant velocity v: ``S0(v) g(v) / sigma0`` (with a
        ``rest_speed``, times ``S1/(S1 + rest_speed)``: 0 at standstill)."""
        return self._zss(v, self._g(v))

    def state_derivative(self, z, qd, qdd=None) -> np.ndarray:
        """Eq. 5: ``dz/dt = S0(v)^2 v - sigma0 S1(v)/g(v) z`` (broadcasts)."""
        a, b, _ = self._ab(np.asarray(qd, float))
        return b - a * np.asarray(z, float)

    def _damping_design(self, z, v, acc, zdot, g, ratio) -> np.ndarray:
        """(T, len(linear_names)) columns: ``f_sigma1 dz/dt = columns @ linear params``."""
        raise NotImplementedError

    def _ratio(self, qd, qdd):
        return None

    def _parts(self, z, qd, qdd, ratio=None):
        v = np.asarray(qd, float)
        z = np.asarray(z, float)
        a, b, g = self._ab(v)
        zdot = b - a * z
        acc = None if qdd is None else np.asarray(qdd, float)
        Dm = self._damping_design(z, v, acc, zdot, g, ratio)
        offset = self._p["sigma0"] * z + self.static.viscous(v)
        return Dm, offset

    def output(self, z, qd, qdd=None) -> np.ndarray:
        """Eq. 6: ``tau_f = sigma0 z + f_sigma1(.) dz/dt + tau_fv(v)`` (broadcasts)."""
        Dm, off = self._parts(z, qd, qdd, self._ratio(qd, qdd))
        return Dm @ np.array([self._p[k] for k in self.linear_names]) + off

    # -- eq. 29-30 -------------------------------------------------------------------------
    def step(self, z, qd, dt, qd_next=None) -> np.ndarray:
        """One step of the discretisation: z after ``dt`` from the velocity ``qd`` at the
        start of the step (eq. 29 with ``hold="zero"`` or without ``qd_next``) or, with
        ``hold="first"`` and ``qd_next`` (the velocity at the end of the step), the
        first-order-hold step of :meth:`states` (for closed-loop simulators that know the
        velocity only one step at a time; broadcasts)."""
        qd = np.asarray(qd, float)
        z = np.asarray(z, float)
        if self.hold == "zero" or qd_next is None:
            a, b, _ = self._ab(qd)
            x = a * np.asarray(dt, float)
            return np.exp(-x) * z + zoh_drive(x, dt, b)
        v1 = np.asarray(qd_next, float)
        a0, _, g0 = self._ab(qd)
        a1, _, g1 = self._ab(v1)
        zs0, zs1 = self._zss(qd, g0), self._zss(v1, g1)
        x = 0.5 * np.asarray(dt, float) * (a0 + a1)
        return np.exp(-x) * z + foh_drive(x, zs0, zs1)

    def states(self, qd, dt) -> np.ndarray:
        """Bristle states z (T,) at the samples of ``qd`` by the exact discretisation eq. 29-30.

        ``dt``: the sample period (scalar) or the (T-1,) steps; the velocity is held over each
        step. ``z[0]`` is the ``z0`` setting, or the steady state of ``qd[0]`` when None.
        """
        v = np.asarray(qd, float)
        if v.ndim != 1:
            raise ValueError(f"{type(self).__name__}: qd must be 1-D (T,), got shape {v.shape}")
        if dt is None:
            raise ValueError(f"{type(self).__name__} is dynamic: torque/states need dt")
        T = v.shape[0]
        if T == 0:
            raise ValueError(f"{type(self).__name__}: qd has no samples")
        steps = np.broadcast_to(np.asarray(dt, float), (max(T - 1, 0),))
        if np.any(steps <= 0):
            raise ValueError(f"{type(self).__name__}: time steps must be positive")
        z0 = float(self.steady_state(v[0])) if self.z0 is None else self.z0
        if self.hold == "zero":                                   # eq. 29-30 as printed
            a, b, _ = self._ab(v[:-1])
            x = a * steps
            return linear_scan(x, zoh_drive(x, steps, b), z0)
        a, _, g = self._ab(v)                                     # first-order hold
        zss = self._zss(v, g)
        x = 0.5 * steps * (a[:-1] + a[1:])
        return linear_scan(x, foh_drive(x, zss[:-1], zss[1:]), z0)

    def linear_design(self, qd, qdd=None, dt=None):
        """``(Phi, offset)`` with ``torque = Phi @ (linear params) + offset`` for sampled signals."""
        z = self.states(qd, dt)
        return self._parts(z, qd, qdd, self._ratio(qd, qdd))

    def torque(self, qd, qdd=None, dt=None) -> np.ndarray:
        """Friction torque (T,) for a sampled velocity (eq. 29-30 then eq. 6)."""
        Dm, off = self.linear_design(qd, qdd, dt)
        return Dm @ np.array([self._p[k] for k in self.linear_names]) + off

    def critical_acceleration(self, v_m) -> np.ndarray:
        """Eq. 22: ``a_m = sigma0 v_m^2 / (log 2 g(v_m))``; faster reversals give damping peaks."""
        v_m = np.asarray(v_m, float)
        return self._p["sigma0"] * v_m ** 2 / (np.log(2.0) * self._g(v_m))

    @classmethod
    def fit_hints(cls, qd, settings):
        """sigma0 bounded so the steady deflection g/sigma0 lies in [1e-8, 1] rad."""
        st = settings["static"]
        gs = float(np.max(np.abs(st.g(np.array([0.0, float(np.max(np.abs(qd)))])))))
        gs = max(gs, 1e-12)
        return {"sigma0": gs * 1e4}, {"sigma0": (gs, gs * 1e8)}


class LuGreDM1(_LuGre):
    r"""LuGre-type dynamic friction DM1 of Indri & Trapani eq. 5-9, bristle damping eq. 10-12.

    .. math::

        \dot{z} = S_0(v)^2 v - \sigma_0 \frac{S_1(v)}{g(v)} z, \qquad
        \tau_f = \sigma_0 z + f_{\sigma_1}(\cdot) \dot{z} + \tau_{fv}(v)

    with the damping :math:`f_{\sigma_1}` chosen by ``damping``: ``"constant"``
    (:math:`\sigma_1`, standard LuGre, phase 2-A of the paper), ``"eq10"``
    (:math:`\sigma_1 g(v)/|v|`), ``"eq11"`` (:math:`\sigma_1/|v|`, the paper's DM1 of
    Tables I-II) or ``"eq12"`` (:math:`\sigma_1 (1 - 2/\pi \arctan(|v| \delta))`) [1]_. In
    eq. 10-12 ``|v|`` is the smooth ``S1(v)``; since ``dz/dt = S1(v) (S0(v) - sigma0 z / g(v))``
    exactly, eq. 10 and 11 are evaluated as the bounded, continuous ``sigma1 (g S0 - sigma0 z)``
    and ``sigma1 (S0 - sigma0 z / g)``. ``S0``, ``S1``, ``g`` (eq. 8) and ``tau_fv`` (eq. 9)
    come from the ``static`` arctan model. Sampled signals use the discretisation of eq. 29-30
    (:meth:`states`); :meth:`critical_acceleration` is eq. 22. The module docstring gives the
    standstill and hold conventions.

    Parameters
    ----------
    static : Arctan
        The identified static model (step 1 of the paper) that gives ``S0``, ``S1``, ``g``
        and ``tau_fv``; its parameters are fixed here.
    damping : {"constant", "eq10", "eq11", "eq12"}, optional
        The bristle damping term (default ``"constant"``).
    z0 : float or None, optional
        Bristle state at the first sample (rad); None (default): the steady state of the first
        velocity.
    hold : {"first", "zero"}, optional
        Discretisation of sampled signals: ``"first"`` (default) exponential integration with
        a first-order hold, exact in the stiff limit; ``"zero"`` the paper's eq. 29-30 with the
        velocity held over each step (see the module docstring).
    rest_speed : float, optional
        Standstill relaxation (rad/s), >= 0; 0 (default) is the paper's model, in which the
        state freezes when the joint stops (see the module docstring).
    **params : float
        ``sigma0`` (bristle stiffness, N m/rad, > 0) and ``sigma1`` (damping coefficient; its
        unit follows ``damping``), by keyword.

    Raises
    ------
    ValueError
        If ``damping`` or ``hold`` is unknown, ``sigma0`` is not positive, ``rest_speed`` is
        negative, or ``rest_speed > 0`` with ``damping`` ``"eq10"``/``"eq11"`` (which divide by
        ``|v|`` through eq. 5).
    TypeError
        If ``static`` is not an :class:`ident.friction.static.Arctan`.

    References
    ----------
    .. [1] Indri & Trapani 2020 (seeds 001), eq. 5-12, 22, 29-30.
    """

    name = "dm1"
    param_names = ("sigma0", "sigma1")
    linear_names = ("sigma1",)
    DAMPING = ("constant", "eq10", "eq11", "eq12")

    def __init__(self, *, static: Arctan, damping: str = "constant", z0: float | None = None,
                 hold: str = "first", rest_speed: float = 0.0, **params):
        if damping not in self.DAMPING:
            raise ValueError(f"dm1: damping must be one of {self.DAMPING}, got {damping!r}")
        if rest_speed > 0 and damping in ("eq10", "eq11"):
            raise ValueError(f"dm1: damping {damping} divides by |v| through eq. 5 and needs "
                             "rest_speed = 0")
        self.damping = damping
        super().__init__(static=static, z0=z0, hold=hold, rest_speed=rest_speed, **params)

    @property
    def settings(self) -> dict:
        return {**super().settings, "damping": self.damping}

    def _damping_design(self, z, v, acc, zdot, g, ratio):
        Kv = self.static.Kv
        if self.damping == "constant":
            col = zdot
        elif self.damping == "eq10":            # sigma1 g/S1 * zdot = sigma1 (g S0 - sigma0 z)
            col = g * s0(v, Kv) - self._p["sigma0"] * z
        elif self.damping == "eq11":            # sigma1 / S1 * zdot = sigma1 (S0 - sigma0 z / g)
            col = s0(v, Kv) - self._p["sigma0"] * z / g
        else:                                   # eq. 12
            col = (1.0 - _2_PI * np.arctan(s1(v, Kv) * self.static.delta)) * zdot
        return np.asarray(col, float)[..., None]


class LuGreDM2(_LuGre):
    r"""LuGre-type dynamic friction DM2 of Indri & Trapani eq. 5-9 with damping eq. 24.

    .. math::

        f_{\sigma_1}(v, a) = \frac{\alpha}{\sqrt{\gamma \left(\frac{a_{max}}{v_{max}} v
        \right)^2 + a^2}} + \beta

    the paper's proposed acceleration-dependent bristle damping [1]_, in the model
    ``dz/dt = S0(v)^2 v - sigma0 S1(v)/g(v) z``, ``tau_f = sigma0 z + f_sigma1 dz/dt +
    tau_fv(v)`` of eq. 5-9 (see :class:`LuGreDM1`). ``accel_floor`` is added in quadrature
    under the root so that it stays positive when v = a = 0. The torque needs the
    acceleration ``qdd``.

    Parameters
    ----------
    static : Arctan
        The identified static model (step 1 of the paper) that gives ``S0``, ``S1``, ``g``
        and ``tau_fv``; its parameters are fixed here.
    accel_ratio : float or None, optional
        ``a_max / v_max`` of eq. 24 (1/s), > 0; None (default): taken from the signals of each
        ``torque`` call, as the paper defines it from the acquisition
        (:meth:`ratio_from_data`).
    accel_floor : float, optional
        Acceleration floor under the root (rad/s^2); default 1e-6.
    z0 : float or None, optional
        Bristle state at the first sample (rad); None (default): the steady state of the first
        velocity.
    hold : {"first", "zero"}, optional
        Discretisation of sampled signals: ``"first"`` (default) exponential integration with
        a first-order hold, exact in the stiff limit; ``"zero"`` the paper's eq. 29-30 with the
        velocity held over each step (see the module docstring).
    rest_speed : float, optional
        Standstill relaxation (rad/s), >= 0; 0 (default) is the paper's model, in which the
        state freezes when the joint stops (see the module docstring).
    **params : float
        ``sigma0`` (bristle stiffness, N m/rad, > 0), ``alpha``, ``beta`` (damping
        coefficients) and ``gamma`` (velocity weight, >= 0), by keyword.

    Raises
    ------
    ValueError
        If ``accel_ratio`` is not positive, ``gamma`` is negative, ``sigma0`` is not positive,
        ``hold`` is unknown or ``rest_speed`` is negative.
    TypeError
        If ``static`` is not an :class:`ident.friction.static.Arctan`.

    References
    ----------
    .. [1] Indri & Trapani 2020 (seeds 001), eq. 5-9, 23-24, 29-30.
    """

    name = "dm2"
    param_names = ("sigma0", "alpha", "beta", "gamma")
    linear_names = ("alpha", "beta")

    def __init__(self, *, static: Arctan, accel_ratio: float | None = None,
                 accel_floor: float = 1e-6, z0: float | None = None, hold: str = "first",
                 rest_speed: float = 0.0, **params):
        if accel_ratio is not None and not accel_ratio > 0:
            raise ValueError(f"dm2: accel_ratio (a_max/v_max) must be positive, got {accel_ratio}")
        self.accel_ratio = None if accel_ratio is None else float(accel_ratio)
        self.accel_floor = float(accel_floor)
        super().__init__(static=static, z0=z0, hold=hold, rest_speed=rest_speed, **params)
        if self._p["gamma"] < 0:
            raise ValueError(f"dm2: gamma must be >= 0, got {self._p['gamma']}")

    @property
    def settings(self) -> dict:
        return {**super().settings, "accel_ratio": self.accel_ratio, "accel_floor": self.accel_floor}

    @classmethod
    def fit_hints(cls, qd, settings):
        x0, b = super().fit_hints(qd, settings)
        return {**x0, "gamma": 1.0}, {**b, "gamma": (1e-4, 1e4)}

    @classmethod
    def complete_settings(cls, qd, qdd, settings):
        """``accel_ratio`` a_max/v_max from ``qd``/``qdd`` when the settings have none."""
        if settings.get("accel_ratio") is not None:
            return settings
        if qdd is None:
            raise ValueError(f"{cls.name} needs qdd")
        return {**settings, "accel_ratio": cls.ratio_from_data(qd, qdd)}

    @staticmethod
    def ratio_from_data(qd, qdd) -> float:
        """``a_max / v_max`` of eq. 24 from the signals of an acquisition."""
        vmax = float(np.max(np.abs(qd)))
        amax = float(np.max(np.abs(qdd)))
        if vmax <= 0 or amax <= 0:
            raise ValueError("dm2: a_max/v_max needs a moving, accelerating signal")
        return amax / vmax

    def _ratio(self, qd, qdd):
        if self.accel_ratio is not None:
            return self.accel_ratio
        if qdd is None:
            raise ValueError("dm2 needs qdd (eq. 24 depends on the acceleration)")
        return self.ratio_from_data(qd, qdd)

    def _damping_design(self, z, v, acc, zdot, g, ratio):
        if acc is None:
            raise ValueError("dm2 needs qdd (eq. 24 depends on the acceleration)")
        den = np.sqrt(self._p["gamma"] * (ratio * v) ** 2 + acc ** 2 + self.accel_floor ** 2)
        zdot = np.broadcast_to(zdot, np.broadcast_shapes(np.shape(zdot), np.shape(den)))
        return np.stack([zdot / den, zdot], axis=-1)
