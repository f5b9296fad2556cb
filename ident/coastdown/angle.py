"""Coast-down identification from a quantised encoder angle (source 000, eq. 3-4, fitted on
the angle instead of a differentiated velocity).

A controller log gives the motor angle ``qm`` (link side, quantised by the encoder) and the
drive torque at a controller rate (200 Hz-1 kHz). A coast of a joint with strong friction
lasts a few samples, so the velocity of paper eq. 4 cannot be measured sample by sample
without a derivative that biases the fit. Here the ANGLE is the measurement, and the model is
the integral of eq. 4 with the stop, joined continuously to the motion before the cut:

- before the cut (``t <= t_c``), a quadratic in time over a short window (the drive moves the
  joint smoothly: a constant-acceleration ramp or a cruise);
- at the cut the angle ``q_c`` and the velocity ``v_c`` carry over; the cut instant ``t_c``
  lies between the last sample with the drive on and the first with it off (a bounded
  parameter, found by the fit);
- after the cut, in the direction ``s = sign(v_c)`` and ``x = s (q - q_c)``, ``w = |v_c|``::

      J x'' = -Kv x' - Kc' ,  Kc' = Kc - s u      (paper eq. 3, plus a constant external torque u)
      x(tau) = w tau phi(z) - (Kc'/J) tau^2 psi(z),  z = Kv tau / J     (eq. 4 integrated)
      phi(z) = (1 - exp(-z)) / z,  psi(z) = (z - 1 + exp(-z)) / z^2
      tau_s  = (J / Kv) ln(1 + Kv w / Kc')                              (paper eq. 3's stop)

  and the joint rests at ``x(tau_s)`` afterwards (stiction holds it).

``u`` is the torque acting on the joint during the coast other than friction: the logged
drive torque after the cut (about 0 for a drive that is switched off, a gravity compensation
for a controller that keeps one) minus the URDF gravity torque. It is measured (mean over the
coast and the first rest samples, standard error from their scatter) and enters the fit as a
parameter with that prior, so its uncertainty reaches the standard error of ``Kc``.

A flexible transmission (the drive's declared nominal ``stiffness`` K, FORMAT.md; link
inertia from the URDF, motor inertia and viscous from the drive; the internal damping ``d``
fitted, so the spring may ring or be overdamped): the encoder is on the motor, and what it
shows at the stop depends on the side whose Coulomb friction holds the joint.

- Link side (``stick = "link"``, :func:`two_mass_coast`): the coast is the exact solution of
  the linear two-mass dynamics with a constant Coulomb torque from the quasi-static deflection
  before the cut (modal, 3 x 3 per coast, complex or real roots); the link stops where its
  speed is 0 and sticks, and the motor then settles on it (the deflection relaxes to the
  external torque's), moving back by about ``(J_m / J) Kc' / K``.
- Motor side (``stick = "motor"``): the coast moves the centre of inertia; the encoder sees in
  addition ``I_link / J`` of the deflection's change, quasi-static ``(I_link (a - a0) +
  b_link (w - w0)) / K`` (``a`` the deceleration, ``b_link = Kv - motor_viscous``), reached
  from the cut along the two-mass mode (:func:`free_response`); the motor sticks at the stop.

With a declared stiffness the fit keeps the flexible model (of the two sides, the one with
the smaller residual; they have the same parameters) unless the rigid one fits better
(:meth:`AngleCoastFit.fit_records`).

All coasts of a record share ``Kc`` and ``Kv`` (the total viscous coefficient, link and motor
side); each has its own ``(q, v, a)`` before the cut, its cut instant and its ``u``. The fit
is maximum likelihood under white angle noise (nonlinear least squares, numerical Jacobian,
bounds ``Kc, Kv >= 0``); the noise level is estimated from the angle residuals (floored at
the quantisation level ``res / sqrt(12)``) and the covariance is ``(G^T G)^-1`` of the
whitened problem. Coasts at one speed barely separate ``Kc`` from ``Kv``: the result says so
(``separable``) and carries the standard errors and the correlation that show it.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import least_squares

from mocap.io.errors import InputError
from mocap.numerics import phi, psi
from ident.signals.smoothing import one_blas_thread

__all__ = ["Flex", "CoastWindow", "AngleCoastFit", "AngleCoastResult", "find_coasts", "coast_angle", "coast_speed",
           "free_response", "two_mass_coast",
           "interval_velocity"]


# -- the model ----------------------------------------------------------------------------
def _log1p_over(y):
    y = np.asarray(y, float)
    small = np.abs(y) < 1e-6
    ys = np.where(small, 1.0, y)
    return np.where(small, 1.0 - y / 2.0 + y * y / 3.0, np.log1p(ys) / ys)


def free_response(tau, omega, zeta):
    """Free response ``x(tau)`` of ``x'' + 2 zeta omega x' + omega^2 x = 0`` from ``x(0) = 1``,
    ``x'(0) = 0`` (0 for ``tau < 0``), exact in every regime: ``exp(-zeta omega tau) (cosh(b tau) +
    zeta omega sinh(b tau) / b)`` with ``b = omega sqrt(zeta^2 - 1)`` (imaginary when
    underdamped: the ringing; real when overdamped: two exponential relaxations; the limit
    ``b -> 0`` at critical damping). Written with exponents <= 0 (no overflow). Broadcasts.

    Parameters
    ----------
    tau : array_like
        Times (s).
    omega : float or array_like
        Natural angular frequency (rad/s).
    zeta : float or array_like
        Damping ratio (0: undamped, 1: critical).

    Returns
    -------
    numpy.ndarray
        ``x(tau)``, broadcast over the arguments.

    Examples
    --------
    Undamped, the response is ``cos(omega tau)``:

    >>> free_response(np.array([0.0, np.pi / 2, np.pi]), 1.0, 0.0).round(12).tolist()
    [1.0, 0.0, -1.0]
    """
    tau = np.asarray(tau, float)
    tt = np.maximum(tau, 0.0)
    sg = zeta * omega
    b = omega * np.sqrt((np.asarray(zeta, float) ** 2 - 1.0).astype(complex))
    cosh_b = np.real(0.5 * (np.exp((b - sg) * tt) + np.exp((-b - sg) * tt)))
    return np.where(tau < 0, 1.0, cosh_b + sg * _free_response_v(tau, omega, zeta))


def _free_response_v(tau, omega, zeta):
    """Free response of ``x'' + 2 zeta omega x' + omega^2 x = 0`` from ``x(0) = 0``,
    ``x'(0) = 1``: ``exp(-zeta omega tau) sinh(b tau) / b`` (see :func:`free_response`)."""
    tt = np.maximum(np.asarray(tau, float), 0.0)
    sg = zeta * omega
    b = omega * np.sqrt((np.asarray(zeta, float) ** 2 - 1.0).astype(complex))
    ep = np.exp((b - sg) * tt)
    em = np.exp((-b - sg) * tt)
    small = np.abs(b) * tt < 1e-6
    bs = np.where(np.abs(b) > 0, b, 1.0)
    return np.real(np.where(small, tt * np.exp(-sg * tt), (ep - em) / (2.0 * bs)))


def two_mass_coast(tau, J, I_link, J_m, K, B_m, d, Kc, Kv, Kc_eff, w, a0, kk=None, n_grid: int = 256,
                   side: str = "link"):
    """Motor-angle displacement along the coast (rad) of a flexible joint whose Coulomb
    friction acts on the LINK, at times ``tau`` (n,) after the cut of coast ``kk`` (n,) (the
    per-coast arguments are (K,) arrays, or scalars; ``kk`` None: one coast per sample, all
    arrays (n,)). Exact for the linear two-mass dynamics with a
    constant Coulomb torque while the link moves (direction coordinates, external torque on
    the motor, ``Kc_eff = Kc - s u``)::

        I q''   = K delta + d delta' - Kc - b_l q'           (b_l = Kv - B_m)
        J_m m'' = s u - B_m m' - K delta - d delta'          (delta = m - q)

    in the centre of inertia ``X`` and the deflection: ``v = (X', delta, delta')`` obeys
    ``v' = A v + b`` (3 x 3, eigen-decomposition per coast, complex roots where the spring
    rings, real where it is overdamped), from the quasi-static state before the cut (``K
    delta0 = I a0 + Kc + b_l w``, ``delta0' = 0``, ``X' = w``). The link stops at the first
    zero of ``q' = X' - (J_m / J) delta'`` (grid of ``n_grid`` points over ``[0, tau.max()]``,
    linear interpolation); then it sticks and the motor settles on it (``J_m delta'' + (B_m +
    d) delta' + K delta = s u`` from the deflection and speed at the stop). Returns ``(m,
    tau_stop)`` with ``m(0) = 0`` and ``tau_stop`` (n,) (inf where the link does not stop).

    ``side = "motor"``: the Coulomb friction acts on the motor instead (``J_m m'' = s u - Kc -
    ..``, ``K delta0 = I a0 + b_l w``); the coast ends where the MOTOR's speed ``X' + (I_link /
    J) delta'`` is 0, and the motor sticks (the encoder holds its angle; the link may still
    move on the spring).

    Parameters
    ----------
    tau : array_like
        Times after the cut (s), (n,).
    J, I_link, J_m : float or array_like
        Total, link and motor inertia (kg m^2, link side), per coast.
    K, B_m, d : float or array_like
        Spring stiffness (N m/rad), motor viscous (N m s/rad), internal damping (N m s/rad).
    Kc, Kv, Kc_eff : float or array_like
        Coulomb level (N m), total viscous (N m s/rad), Coulomb level less the external torque.
    w, a0 : float or array_like
        Speed (rad/s) and acceleration (rad/s^2) at the cut.
    kk : array_like of int, optional
        Coast index of each time.
    n_grid : int, optional
        Grid points of the stop search.
    side : {"link", "motor"}, optional
        Where the Coulomb friction acts.

    Returns
    -------
    m : numpy.ndarray
        Motor-angle displacement (rad), (n,).
    tau_stop : numpy.ndarray
        Stop time of each sample's coast (s), (n,).

    References
    ----------
    .. [1] Coast-down friction identification (seeds 000), eq. 3 (the rigid coast this extends to
       two masses).
    """
    tau = np.asarray(tau, float)
    kk = np.arange(tau.size) if kk is None else np.asarray(kk)
    n = int(kk.max()) + 1 if kk.size else 0
    J, I_link, J_m, K, B_m, d, Kc, Kv, Kc_eff, w, a0 = (
        np.broadcast_to(np.asarray(x, float), (n,)) for x in (J, I_link, J_m, K, B_m, d, Kc, Kv, Kc_eff, w, a0))
    bl = np.maximum(Kv - B_m, 0.0)
    mu = I_link * J_m / J
    Kv_e = np.maximum(Kv, 1e-6 * J)      # keeps A invertible at Kv = 0 (1e-6 of J per second)
    A = np.zeros((n, 3, 3))
    A[:, 0, 0] = -Kv_e / J
    A[:, 0, 2] = -(B_m * I_link - bl * J_m) / (J * J)
    A[:, 1, 2] = 1.0
    A[:, 2, 0] = -B_m / J_m + bl / I_link
    A[:, 2, 1] = -K / mu
    A[:, 2, 2] = -d / mu - B_m * I_link / (J * J_m) - bl * J_m / (I_link * J)
    su = Kc - Kc_eff                     # s u, the external torque (on the motor)
    motor = side == "motor"
    b = np.stack([-Kc_eff / J, np.zeros(n), (su - Kc) / J_m if motor else su / J_m + Kc / I_link], axis=1)
    lam, V = np.linalg.eig(A)
    v_inf = -np.linalg.solve(A, b[..., None])[..., 0]
    v0 = np.stack([w, (I_link * a0 + (0.0 if motor else Kc) + bl * w) / K, np.zeros(n)], axis=1)
    c = np.linalg.solve(V, (v0 - v_inf).astype(complex)[..., None])[..., 0]   # (n, 3)

    cvs = V * c[:, None, :]                                             # (K, 3 comp, 3 modes)

    def state(tt, ix, speeds_only=False):
        """(X - X0, delta, delta') of coasts ix (r,) at times tt (r, m); (X', delta') with
        ``speeds_only``."""
        la = lam[ix][:, None, :]
        e = np.exp(la * tt[..., None])                                  # (r, m, 3)
        cv = cvs[ix][:, None, :, :]                                     # (r, 1, 3 comp, 3 modes)
        vi = v_inf[ix]
        dd = vi[:, 2, None] + np.real(np.sum(cv[..., 2, :] * e, axis=-1))
        if speeds_only:
            return vi[:, 0, None] + np.real(np.sum(cv[..., 0, :] * e, axis=-1)), dd
        # int_0^t e^{lambda s} ds = t phi(-lambda t) (t at lambda = 0), complex lambda
        ie = tt[..., None] * phi(-la * tt[..., None])
        X = vi[:, 0, None] * tt + np.real(np.sum(cv[..., 0, :] * ie, axis=-1))
        dl = vi[:, 1, None] + np.real(np.sum(cv[..., 1, :] * e, axis=-1))
        return X, dl, dd

    # the link's stop: first zero of q' on a grid per coast (the same grid for all rows)
    T = max(float(np.max(tau)), 1e-9)
    g = np.linspace(0.0, T, n_grid)[None, :] * np.ones((n, 1))
    Xdg, ddg = state(g, np.arange(n), speeds_only=True)
    qd = Xdg + (I_link / J)[:, None] * ddg if motor else Xdg - (J_m / J)[:, None] * ddg
    neg = qd <= 0
    first = np.where(neg.any(axis=1), np.argmax(neg, axis=1), -1)
    i1 = np.maximum(first, 1)
    q0, q1 = qd[np.arange(n), i1 - 1], qd[np.arange(n), i1]
    t0, t1 = g[np.arange(n), i1 - 1], g[np.arange(n), i1]
    ts = np.where(first > 0, t0 + (t1 - t0) * q0 / np.where(q0 - q1 > 0, q0 - q1, 1.0), np.inf)
    ts = np.where(first == 0, 0.0, ts)
    tsk = ts[kk]
    tt = np.clip(tau, 0.0, tsk)
    X, dl, dd = state(tt[:, None], kk)
    X, dl, dd = X[:, 0], dl[:, 0], dd[:, 0]
    r = I_link[kk] / J[kk]
    m = X + r * (dl - v0[kk, 1])
    if motor:   # the motor sticks: the encoder holds the angle it stopped at
        return m, ts
    # after the stop: the link holds, the motor settles on it
    om = np.sqrt(K / J_m)[kk]
    zm = ((B_m + d) / (2.0 * np.sqrt(K * J_m)))[kk]
    after = np.maximum(tau - tsk, 0.0)
    d_inf = (su / K)[kk]
    dl_after = d_inf + (dl - d_inf) * free_response(after, om, zm) + dd * _free_response_v(after, om, zm)
    m_after = X - (J_m[kk] / J[kk]) * dl + dl_after - r * v0[kk, 1]
    return np.where(tau > tsk, m_after, m), ts


def coast_stop(J, Kv, Kc_eff, w):
    """Stop time ``tau_s = (J/Kv) ln(1 + Kv w / Kc_eff)`` (inf where ``Kc_eff <= 0``).

    Parameters
    ----------
    J, Kv, Kc_eff : float or array_like
        Inertia (kg m^2), viscous coefficient (N m s/rad), Coulomb level less the external
        torque (N m).
    w : float or array_like
        Speed at the release (rad/s).

    Returns
    -------
    numpy.ndarray
        Stop times (s).
    """
    Kc_eff = np.asarray(Kc_eff, float)
    w = np.maximum(np.asarray(w, float), 0.0)
    pos = Kc_eff > 0
    y = Kv * w / np.where(pos, Kc_eff, 1.0)
    return np.where(pos, J * w / np.where(pos, Kc_eff, 1.0) * _log1p_over(y), np.inf)


def coast_angle(tau, J, Kv, Kc_eff, w):
    r"""Angle travelled after a release at speed ``w > 0``: the coast-down's eq. 4 integrated.

    .. math::

        x(\tau) = \frac{J}{K_v}\left(w + \frac{K_c}{K_v}\right)
        \left(1 - e^{-K_v \tau / J}\right) - \frac{K_c}{K_v}\, \tau

    held at its value at the stop ``tau_s`` (no stop where ``Kc_eff <= 0``) [1]_, with
    ``K_c = Kc_eff``. Broadcasts.

    Parameters
    ----------
    tau : array_like
        Times after the release (s).
    J : float
        Inertia (kg m^2).
    Kv : float
        Viscous coefficient (N m s/rad).
    Kc_eff : float or array_like
        Coulomb level less the external torque along the motion (N m).
    w : float or array_like
        Speed at the release (rad/s).

    Returns
    -------
    x : numpy.ndarray
        Angle travelled since the release (rad).
    tau_s : numpy.ndarray
        Stop time (s).

    References
    ----------
    .. [1] Coast-down friction identification (seeds 000), eq. 3-4.

    Examples
    --------
    >>> x, tau_s = coast_angle(np.array([0.0, 0.1, 1.0]), J=0.05, Kv=0.05, Kc_eff=0.2, w=1.0)
    >>> x.round(5).tolist(), round(float(tau_s), 4)
    ([0.0, 0.07581, 0.10743], 0.2231)
    """
    tau = np.asarray(tau, float)
    Kc_eff = np.asarray(Kc_eff, float)
    w = np.maximum(np.asarray(w, float), 0.0)
    tau_s = coast_stop(J, Kv, Kc_eff, w)
    tt = np.clip(tau, 0.0, tau_s)
    z = Kv * tt / J
    x = w * tt * phi(z) - Kc_eff / J * tt * tt * psi(z)
    return x, tau_s


def coast_speed(tau, J, Kv, Kc_eff, w):
    """Speed ``x'(tau)`` of :func:`coast_angle` (paper eq. 4, 0 after the stop).

    Parameters
    ----------
    tau : array_like
        Times after the release (s).
    J, Kv, Kc_eff, w : float
        As in :func:`coast_angle`.

    Returns
    -------
    numpy.ndarray
        Speed (rad/s), 0 after the stop.

    Examples
    --------
    >>> coast_speed(np.array([0.0, 1.0]), J=0.05, Kv=0.05, Kc_eff=0.2, w=1.0).tolist()
    [1.0, 0.0]
    """
    x, tau_s = coast_angle(tau, J, Kv, Kc_eff, w)
    tt = np.clip(np.asarray(tau, float), 0.0, tau_s)
    z = Kv * tt / J
    v = np.maximum(w, 0.0) * np.exp(-z) - Kc_eff / J * tt * phi(z)
    return np.where(np.asarray(tau, float) < tau_s, v, 0.0)


def interval_velocity(t, q):
    """First differences ``(q[i+1] - q[i]) / (t[i+1] - t[i])`` at the interval midpoints: the
    exact mean velocity over each interval (no derivative filter, so no bias beyond the
    midpoint rule, ``(dt/T)^2 / 24`` relative for eq. 4 with time constant ``T = J/Kv``).

    Parameters
    ----------
    t, q : array_like
        Times (s) and angles (rad), (N,).

    Returns
    -------
    t_mid : numpy.ndarray
        Interval midpoints (s), (N - 1,).
    v : numpy.ndarray
        Mean velocity over each interval (rad/s), (N - 1,).

    Examples
    --------
    >>> t_mid, v = interval_velocity([0.0, 0.1, 0.2], [0.0, 0.1, 0.3])
    >>> t_mid.round(3).tolist(), v.round(6).tolist()
    ([0.05, 0.15], [1.0, 2.0])
    """
    t = np.asarray(t, float)
    q = np.asarray(q, float)
    return 0.5 * (t[1:] + t[:-1]), np.diff(q) / np.diff(t)


@dataclass(frozen=True)
class Flex:
    """A flexible transmission as the drive declares it (FORMAT.md, link side): nominal
    ``stiffness`` K (N m/rad), ``motor_inertia`` and ``motor_viscous``. The motor encoder sees
    the link angle plus the spring's deflection, which changes when the drive is cut."""

    stiffness: float
    motor_inertia: float
    motor_viscous: float


# -- segmentation --------------------------------------------------------------------------
@dataclass(frozen=True)
class CoastWindow:
    """One coast found in a log (sample indices into the joint's valid samples).

    ``pre`` = first sample of the pre-cut window, ``on`` = last sample with the drive on (the
    cut lies in ``(t[on], t[on + 1]]``), ``rest`` = first sample at rest (the last one fitted;
    equal to the last coast sample where the joint did not come to rest), ``direction`` the
    sign of the velocity at the cut, ``u``/``u_se`` the external torque during the coast and
    its standard error, ``tau_drive`` the logged torque at ``on`` minus the coast level."""

    pre: int
    on: int
    rest: int
    stopped: bool
    direction: int
    u: float
    u_se: float
    tau_drive: float
    speed: float

    def to_dict(self) -> dict:
        return dict(self.__dict__)


def find_coasts(t, qm, tau, *, resolution: float, v_min: float, J: float, gravity=None,
                pre_s: float = 0.15, rest_s: float = 0.05, min_pre: int = 5,
                jump_sigmas: float = 8.0) -> list[CoastWindow]:
    """Find the coast phases of a one-joint record.

    A coast: the drive torque drops to a level it keeps while the joint, moving at
    ``|v| >= v_min`` at the cut, comes to rest (the free deceleration of the coast-down
    paper's eq. 3 [1]_). The joint is at rest from sample ``s`` when the angle stays within one encoder step
    (``resolution``) for ``rest_s`` seconds (at least 3 samples). For each such start of rest,
    the torque level ``L`` of the coast is the median of the logged torque over the first rest
    samples, its noise the scaled MAD; walking back from ``s``, the last sample whose torque
    differs from ``L`` by more than half the drive's level before it (and by ``jump_sigmas``
    noise levels) is the drive's last sample ``on``; the coasting samples after it must stay
    within 5 noise levels (or a quarter of the drive's level) of ``L``. It is a coast when the
    drive-on torque differs from ``L`` by at least that much and the speed before the cut is at
    least ``v_min``, and is a coast's
    (not a controlled stop's): the drive torque pushes along the motion, the joint is not
    already slowing down (speed at the cut >= 0.7 x the largest speed of the pre-cut window;
    speeds over as many intervals as span 3 encoder steps),
    and it comes to rest within 3 times the distance ``J v^2 / (2 |drive torque|)`` that the
    friction the drive was overcoming would stop it in (a friction that falls with speed
    gives at most twice that), which must be at least one encoder step. ``gravity`` (a
    callable q -> torque) is subtracted from the logged torque to give the external torque
    ``u`` of the coast. Vectorised over samples; one small loop over rest starts.

    Parameters
    ----------
    t, qm, tau : array_like
        Times (s), encoder angle (rad, link side) and drive torque (N m) of one joint, (N,).
    resolution : float
        Encoder step (rad, link side).
    v_min : float
        Slowest speed at the cut that counts (rad/s).
    J : float
        Inertia of the joint (kg m^2).
    gravity : callable, optional
        ``q -> torque`` (N m) subtracted from the logged torque.
    pre_s, rest_s : float, optional
        Length of the pre-cut window and of the rest that ends a coast (s).
    min_pre : int, optional
        Fewest samples of the pre-cut window.
    jump_sigmas : float, optional
        Torque step at the cut in noise levels.

    Returns
    -------
    list of CoastWindow
        One per coast, in time order.

    References
    ----------
    .. [1] Coast-down friction identification (seeds 000), eq. 3 (the coast the drive's cut
       starts).

    Examples
    --------
    A joint driven at 1 rad/s, its drive cut at 0.5 s, logged at 1 kHz by a 1e-5 rad encoder:

    >>> t = np.arange(1000) / 1000.0
    >>> q = np.where(t <= 0.5, t, 0.5 + coast_angle(t - 0.5, 0.05, 0.05, 0.2, 1.0)[0])
    >>> qm = np.round(q / 1e-5) * 1e-5
    >>> tau = np.where(t <= 0.5, 0.25, 0.0)
    >>> [w] = find_coasts(t, qm, tau, resolution=1e-5, v_min=0.1, J=0.05)
    >>> w.on, w.stopped, w.direction
    (500, True, 1)
    """
    t = np.asarray(t, float)
    qm = np.asarray(qm, float)
    tau = np.asarray(tau, float)
    n = t.size
    if n < 8:
        return []
    dt = float(np.median(np.diff(t)))
    m = max(3, int(round(rest_s / dt)))
    step = np.abs(np.diff(qm))
    # still[i]: the angle stays within one encoder step over samples i .. i + m
    lim = 1.01 * max(resolution, 1e-12)
    qs = np.lib.stride_tricks.sliding_window_view(qm, m + 1)
    still = np.zeros(n, bool)
    still[: n - m] = (qs.max(axis=1) - qs.min(axis=1)) <= lim
    starts = np.flatnonzero(still[1:] & ~still[:-1]) + 1
    out, last_rest = [], -1
    for s in starts:  # loop over stops (a handful per record)
        lvl_idx = np.arange(s, min(n, s + m + 1))
        L = float(np.median(tau[lvl_idx]))
        # torque noise from the rest that follows (up to 0.3 s, differences: robust to drift)
        still_run = np.flatnonzero(~still[s: min(n, s + int(round(0.3 / dt)) + 1)])
        n_rest = int(still_run[0]) if still_run.size else min(n - s, int(round(0.3 / dt)) + 1)
        tr_ = tau[s: s + max(n_rest, m) + 1]
        sig = max(1.4826 * float(np.median(np.abs(np.diff(tr_) - np.median(np.diff(tr_))))) / np.sqrt(2.0),
                  1e-9)
        lo = max(last_rest + 1, 0)
        dev = np.abs(tau[lo:s] - L)
        back = np.flatnonzero(dev > jump_sigmas * sig)
        if back.size == 0:
            continue
        # the drive's level before the cut; the cut is where the torque leaves half of it
        on1 = lo + int(back[-1])
        D = float(np.median(dev[max(0, on1 - lo - int(round(pre_s / dt))): on1 - lo + 1]))
        on = lo + int(np.flatnonzero(dev > max(0.5 * D, jump_sigmas * sig))[-1])
        if on + 1 > s or on < 1:
            continue
        # while it coasts the torque keeps the level (a gravity compensation may drift a little)
        if s > on + 1 and float(np.max(dev[on + 1 - lo:])) > max(5.0 * sig, 0.25 * D):
            continue
        # speeds over k intervals spanning a few encoder steps (a slow joint at a fast log
        # moves about one step per sample: one-interval differences are mostly quantisation)
        n_pre = max(min_pre, int(round(pre_s / dt)))
        k0 = max(0, on - n_pre)
        v_est = abs(qm[on] - qm[k0]) / max(t[on] - t[k0], 1e-12)
        k = int(np.clip(np.ceil(3.0 * resolution / max(v_est * dt, 1e-12)), 1, max(1, (on - k0) // 3)))
        if on - k < 0:
            continue
        speed = (qm[on] - qm[on - k]) / (t[on] - t[on - k])
        if abs(speed) < v_min:
            continue
        direction = 1 if speed > 0 else -1
        tau_drive = float(tau[on] - L)
        if direction * tau_drive <= 0:
            continue
        d_exp = J * speed * speed / (2.0 * abs(tau_drive))
        d_act = abs(qm[s] - qm[on])
        if d_exp < resolution or d_act > 3.0 * d_exp + 2.0 * resolution:
            continue
        # pre-cut window: the drive on and the joint moving the same way (over k intervals)
        seg = qm[k0: on + 1]
        mv = direction * (seg[k:] - seg[:-k]) > 0
        bad = np.flatnonzero(~mv)
        pre = k0 + (int(bad[-1]) + 1 if bad.size else 0)
        if on - pre + 1 < max(min_pre, k + 1):
            continue
        v_pre = np.abs((qm[pre + k: on + 1] - qm[pre: on + 1 - k]) / (t[pre + k: on + 1] - t[pre: on + 1 - k]))
        if abs(speed) < 0.7 * float(v_pre.max()):
            continue
        idx = np.arange(on + 1, min(n, s + m + 1))
        g = gravity(qm[idx]) if gravity is not None else 0.0
        u_all = tau[idx] - g
        u = float(np.mean(u_all))
        u_se = float(np.std(u_all, ddof=1) / np.sqrt(idx.size)) if idx.size > 1 else sig
        out.append(CoastWindow(pre=int(pre), on=int(on), rest=int(s), stopped=True,
                               direction=direction, u=u, u_se=max(u_se, 1e-12),
                               tau_drive=tau_drive, speed=float(abs(speed))))
        last_rest = s
    return out


# -- the estimator -------------------------------------------------------------------------
@dataclass(frozen=True)
class AngleCoastResult:
    """``Kc`` (N m) and ``Kv`` (N m s/rad, total) shared by the coasts of a record, with
    standard errors, their correlation and whether the record separates them; per coast the
    cut instant, the speed at the cut, the stop time and distance, the external torque and the
    angle residual RMS. ``sigma_q`` is the estimated angle noise (rad)."""

    Kc: float
    Kv: float
    J: float
    stderr: dict
    corr: float
    separable: bool
    sigma_q: float
    rms: float
    n_samples: int
    converged: bool
    coasts: tuple
    cov: np.ndarray = field(repr=False, default=None)
    notes: tuple = ()
    x: np.ndarray = field(repr=False, default=None)     # all fitted parameters (restarts)
    transmission: str = "rigid"     # or "flexible": the declared stiffness's deflection modelled
    stick: str = ""                 # flexible: the side that sticks at the stop ("motor" or "link")

    def to_dict(self) -> dict:
        return {"Kc": self.Kc, "Kv": self.Kv, "J": self.J, "stderr": dict(self.stderr),
                "corr_Kc_Kv": self.corr, "separable": self.separable, "sigma_q": self.sigma_q,
                "rms": self.rms, "n_samples": self.n_samples, "converged": self.converged,
                "coasts": [dict(c) for c in self.coasts], "notes": list(self.notes),
                "transmission": self.transmission, "stick": self.stick}


class AngleCoastFit:
    """Maximum-likelihood coast-down fit on the encoder angle (module docstring).

    ``resolution``: encoder step (rad, link side; 0 if unknown); ``cut_lead``: the cut may
    lie this many log intervals before the last sample whose torque shows the drive on (-1: a
    log whose torque is an interval mean, or lags the angle, shows an intermediate torque
    after the cut; the fit finds the cut from the angle); ``kv_starts``: starting
    values of ``Kv`` as multiples of ``Kc / mean speed`` (multi-start, least cost kept);
    ``sep_rel``: the record separates ``Kc`` from ``Kv`` when the standard error of ``Kc``
    and that of the viscous torque ``Kv v`` at the fastest cut are both within ``sep_rel``
    times ``Kc``.

    Parameters
    ----------
    resolution : float, optional
        Encoder step (rad, link side).
    kv_starts : sequence of float, optional
        Starting values of ``Kv`` in units of ``Kc / mean speed``.
    sep_rel : float, optional
        Relative standard error below which ``Kc`` and ``Kv`` count as separated.
    max_nfev : int, optional
        Most function evaluations per start.
    cut_lead : float, optional
        Log intervals the cut may lie before the last drive-on sample.

    References
    ----------
    .. [1] Coast-down friction identification (seeds 000), sec. 3 (maximum likelihood on eq. 4,
       here integrated to the angle).

    Examples
    --------
    The coast of :func:`find_coasts`' example gives back its friction:

    >>> t = np.arange(1000) / 1000.0
    >>> q = np.where(t <= 0.5, t, 0.5 + coast_angle(t - 0.5, 0.05, 0.05, 0.2, 1.0)[0])
    >>> qm = np.round(q / 1e-5) * 1e-5
    >>> tau = np.where(t <= 0.5, 0.25, 0.0)
    >>> windows = find_coasts(t, qm, tau, resolution=1e-5, v_min=0.1, J=0.05)
    >>> r = AngleCoastFit(resolution=1e-5).fit(t, qm, windows, J=0.05)
    >>> print(f"Kc = {r.Kc:.3f} N m, Kv = {r.Kv:.3f} N m s/rad, separable: {r.separable}")
    Kc = 0.200 N m, Kv = 0.050 N m s/rad, separable: True
    """

    def __init__(self, resolution: float = 0.0, kv_starts=(0.05, 0.5, 2.0), sep_rel: float = 0.2,
                 max_nfev: int = 400, cut_lead: float = -1.0):
        self.cut_lead = float(cut_lead)
        self.resolution = float(resolution)
        self.kv_starts = tuple(kv_starts)
        self.sep_rel = float(sep_rel)
        self.max_nfev = int(max_nfev)

    def fit(self, t, qm, windows, J: float) -> AngleCoastResult:
        """Fit the coasts ``windows`` (from :func:`find_coasts`) of one record ``t``, ``qm``
        with total inertia ``J``.

        Parameters
        ----------
        t, qm : array_like
            Times (s) and encoder angle (rad, link side), (N,).
        windows : list of CoastWindow
            The record's coasts.
        J : float
            Inertia of the joint (kg m^2).

        Returns
        -------
        AngleCoastResult
            ``Kc``, ``Kv``, their standard errors and correlation, per-coast details.
        """
        return self.fit_records([(t, qm, windows, J)])

    def fit_records(self, records, starts=None, kv_fixed: float | None = None,
                    flexible: bool | None = None, stick: str | None = None) -> AngleCoastResult:
        """Fit shared ``Kc``, ``Kv`` to the coasts of several records ``[(t, qm, windows, J),
        ...]`` or ``[(t, qm, windows, J, flex), ...]`` (e.g. every coast-down trial of one
        joint; ``J`` may differ per record; ``flex`` a :class:`Flex` or None for a rigid
        transmission). ``starts``: optional fits of the same records one by one
        (:class:`AngleCoastResult` each, in order): the pooled fit starts from them (one
        start, sparse Jacobian). ``kv_fixed``: hold ``Kv`` at this value and fit ``Kc`` alone
        (its standard error is then conditional on ``Kv``; ``stderr["Kv"]`` is 0).

        ``flexible``: True uses the declared stiffness, False treats the transmission as
        rigid, None (default, where a record declares one) fits both and keeps the flexible one
        unless its residual ends above the rigid one's, or the friction torque's deflection
        ``(Kc + Kv v_max) / K`` of the rigid fit is under 0.2 of the angle noise (a stiff
        spring: the rigid fit is kept, no flexible one is tried). The flexible model holds the rigid one
        (a large internal damping ``d`` locks the spring, so a declared stiffness far softer
        than the joint costs nothing but ``d``), and a Schwarz criterion kept the rigid model
        on records whose deflection is a fraction of an encoder step, where it biases ``Kv`` by
        3-4 standard errors (an overdamped transmission).
        ``stick``: the side whose Coulomb friction holds the joint at the stop, ``"motor"`` or
        ``"link"``; None fits both (same parameters) and keeps the better. ``transmission``
        and ``stick`` in the result say which.

        Parameters
        ----------
        records : list of tuple
            ``(t, qm, windows, J)`` or ``(t, qm, windows, J, flex)`` per record.
        starts : list of AngleCoastResult, optional
            Fits of the records one by one, to start from.
        kv_fixed : float, optional
            Hold ``Kv`` at this value (N m s/rad).
        flexible : bool, optional
            Use the declared stiffness (True), ignore it (False), or choose (None).
        stick : {"motor", "link"}, optional
            The side that sticks at the stop; both tried when None.

        Returns
        -------
        AngleCoastResult
            The shared ``Kc``, ``Kv`` and the per-coast details.
        """
        recs = [tuple(r) + (None,) * (5 - len(r)) for r in records]
        rigid = [r[:4] + (None,) for r in recs]
        declared = any(r[4] is not None for r in recs)
        sticks = ("motor", "link") if stick is None else (stick,)
        with one_blas_thread():   # small dense solves: one BLAS thread is several times faster
            if not declared or flexible is False:
                return self._fit_records(rigid, starts, kv_fixed)
            if not flexible:
                a = self._fit_records(rigid, starts, kv_fixed)
                # the friction torque's deflection, (Kc + Kv v) / K, under a fifth of the angle
                # noise: the spring is invisible (the flexible model would only fit d)
                v_top = max(abs(c["v_cut"]) for c in a.coasts)
                k_min = min(r[4].stiffness for r in recs if r[4] is not None)
                if (a.Kc + a.Kv * v_top) / k_min < 0.2 * a.sigma_q:
                    return a
            flex = [self._fit_records(recs, starts, kv_fixed, stick=sk) for sk in sticks]
            best = flex[int(np.argmin([f.rms for f in flex]))]
            if flexible:
                return best
            # the flexible model holds the rigid one (d -> inf locks the spring): it is kept
            # unless its fit ends worse than the rigid one's (a start that did not converge)
            return best if best.rms <= a.rms * (1.0 + 1e-6) else a

    def _fit_records(self, records, starts, kv_fixed=None, stick: str = "motor") -> AngleCoastResult:
        if stick not in ("motor", "link"):
            raise ValueError(f"stick must be 'motor' or 'link', not {stick!r}")
        recs = [tuple(r) + (None,) * (5 - len(r)) for r in records]
        parts = [(np.asarray(t, float), np.asarray(q, float), w, float(J), fx)
                 for t, q, ws, J, fx in recs for w in ws]
        if not parts:
            raise InputError("coastdown: no coast to fit")
        K = len(parts)
        windows = [p[2] for p in parts]
        idx = [np.arange(w.pre, w.rest + 1) for w in windows]
        kk = np.concatenate([np.full(i.size, k) for k, i in enumerate(idx)])
        ts = np.concatenate([p[0][i] for p, i in zip(parts, idx)])
        ys = np.concatenate([p[1][i] for p, i in zip(parts, idx)])
        Jk = np.array([p[3] for p in parts])
        Jkk = Jk[kk]
        # flexible transmission (declared stiffness): compliance 1/K, link inertia, motor viscous
        cK = np.array([0.0 if p[4] is None else 1.0 / p[4].stiffness for p in parts])
        Il = np.array([0.0 if p[4] is None else max(p[3] - p[4].motor_inertia, 0.0) for p in parts])
        Bm = np.array([0.0 if p[4] is None else p[4].motor_viscous for p in parts])
        flexible = bool(np.any(cK > 0))
        Jmot = np.array([1.0 if p[4] is None else max(p[4].motor_inertia, 1e-12) for p in parts])
        Kst = np.where(cK > 0, 1.0 / np.where(cK > 0, cK, 1.0), 0.0)
        # the two-mass mode (both moving): reduced inertia mu = I_link J_m / J
        mu = np.maximum(Il, 1e-12) * Jmot / (np.maximum(Il, 1e-12) + Jmot)
        d_scale = float(np.median(2.0 * np.sqrt(np.maximum(Kst * mu, 1e-12)))) if flexible else 1.0
        t_r = np.array([p[0][w.on] for p, w in zip(parts, windows)])
        h = np.array([p[0][w.on + 1] - p[0][w.on] for p, w in zip(parts, windows)])
        sgn = np.array([w.direction for w in windows], float)
        u_bar = np.array([w.u for w in windows])
        u_se = np.array([w.u_se for w in windows])
        q_on = np.array([p[1][w.on] for p, w in zip(parts, windows)])
        tau_pre = ts - t_r[kk]
        # starting values per coast: quadratic through the pre window, cut mid-interval
        p_init = np.zeros((K, 3))
        for k, (tk, qk, w, _, _) in enumerate(parts):  # loop over coasts
            sel = np.arange(w.pre, w.on + 1)
            deg = 2 if sel.size >= 4 else 1
            c = np.polyfit(tk[sel] - t_r[k], qk[sel] - q_on[k], deg)[::-1]
            p_init[k, : deg + 1] = c
        p_init[:, 2] *= 2.0                        # a = 2 c2
        sig_floor = (self.resolution / np.sqrt(12.0)) if self.resolution > 0 else 1e-9
        # Coulomb guess from the stop distances with Kv = 0
        v_c0 = np.abs(p_init[:, 1] + p_init[:, 2] * 0.5 * h)
        d0 = np.array([abs(p[1][w.rest] - q_on[k]) for k, (p, w) in enumerate(zip(parts, windows))])
        d0 = np.maximum(d0 - 0.5 * v_c0 * h, 0.5 * max(self.resolution, 1e-9))
        kc0 = float(np.median(Jk * v_c0 ** 2 / (2.0 * d0) + sgn * u_bar))
        kc0 = max(kc0, 1e-6)
        vbar = float(np.mean(v_c0))

        fixed = kv_fixed is not None

        def full(x):
            return np.insert(x, 1, float(kv_fixed)) if fixed else x

        def unpack(x):
            Kc, Kv = x[0], x[1]
            P = x[2: 2 + 5 * K].reshape(K, 5)
            return Kc, Kv, P

        def model(x):
            Kc, Kv, P = unpack(x)
            p0, p1, p2, th, u = (P[:, i] for i in range(5))
            tc_rel = th * h                                     # cut after t_r, per coast
            qc = p0 + p1 * tc_rel + 0.5 * p2 * tc_rel ** 2
            vc = p1 + p2 * tc_rel
            w = sgn * vc
            kce = Kc - sgn * u
            tp = tau_pre
            pre = p0[kk] + p1[kk] * tp + 0.5 * p2[kk] * tp * tp
            after = tp > tc_rel[kk]
            if flexible:     # exact two-mass coast, the link or the motor sticks
                x_c, _ = two_mass_coast(tp - tc_rel[kk], Jk, Il, Jmot, Kst, Bm, x[-1], Kc, Kv, kce, w,
                                        sgn * p2, kk=kk, side=stick)
            else:
                x_c, _ = coast_angle(tp - tc_rel[kk], Jkk, Kv, kce[kk], w[kk])
            post = qc[kk] + sgn[kk] * x_c
            return q_on[kk] + np.where(after, post, pre), (qc, vc, kce, w)

        def resid(xr, sig_q):
            x = full(xr)
            qhat, _ = model(x)
            r_q = (ys - qhat) / sig_q
            r_u = (x[2: 2 + 5 * K].reshape(K, 5)[:, 4] - u_bar) / u_se
            return np.concatenate([r_q, r_u])

        nz = int(flexible)     # the transmission's internal damping d, last parameter, where flexible
        d0 = d_scale * (1.0 if stick == "link" else 0.1)   # start: mode damping ratio 0.5 / 0.05
        lb = np.concatenate([[0.0, 0.0], np.tile([-np.inf, -np.inf, -np.inf, self.cut_lead, -np.inf], K), [0.0] * nz])
        # the cut lies near the last drive-on sample: up to one interval before it (a torque
        # logged as an interval mean or with a lag), up to 1.5 after (an amplifier's current
        # lag can carry the torque a little past the first sample that logs the cut)
        ub = np.concatenate([[np.inf, np.inf], np.tile([np.inf, np.inf, np.inf, 1.5, np.inf], K), [np.inf] * nz])
        base = np.column_stack([p_init, np.full(K, 0.5), u_bar]).ravel()
        scale = np.concatenate([[kc0, kc0 / max(vbar, 1e-6)],
                                np.tile([max(self.resolution, 1e-6), max(vbar, 1e-3), 1.0, 1.0, 1.0], K),
                                [d_scale] * nz])
        scale[6::5] = np.maximum(u_se * 3, 1e-6)
        sig_q = max(sig_floor, 1e-9)
        opts = dict(bounds=(lb, ub), x_scale=scale, method="trf", max_nfev=self.max_nfev,
                    xtol=1e-9, ftol=1e-9)
        if K > 12:   # many coasts: each coast's parameters touch only its own rows
            from scipy.sparse import lil_matrix

            sp = lil_matrix((ys.size + K, 2 + 5 * K + nz), dtype=np.int8)
            sp[: ys.size, :2] = 1
            sp[: ys.size, 2 + 5 * K:] = 1
            for k in range(K):  # loop over coasts
                rows = np.flatnonzero(kk == k)
                sp[rows[0]: rows[-1] + 1, 2 + 5 * k: 7 + 5 * k] = 1
                sp[ys.size + k, 6 + 5 * k] = 1
            opts.update(jac_sparsity=sp.tocsr(), tr_solver="lsmr")
        if starts is not None:
            xs = [np.asarray(r.x, float) for r in starts]
            x0s = [np.concatenate([[np.median([x[0] for x in xs]), np.median([x[1] for x in xs])]]
                                  + [x[2: 2 + 5 * K0] for x, K0 in zip(xs, (len(r.coasts) for r in starts))]
                                  + [[np.median([x[-1] if r.transmission == "flexible" else d0
                                                 for x, r in zip(xs, starts)])]] * nz)]
        else:
            x0s = [np.concatenate([[kc0, ks * kc0 / max(vbar, 1e-6)], base, [d0] * nz])
                   for ks in self.kv_starts]
        keep = np.ones(2 + 5 * K + nz, bool)
        if fixed:   # Kv held: drop its column
            keep[1] = False
            x0s = x0s[:1]
            opts["bounds"] = (lb[keep], ub[keep])
            opts["x_scale"] = scale[keep]
            if "jac_sparsity" in opts:
                opts["jac_sparsity"] = opts["jac_sparsity"][:, keep]
        best = None
        for x0 in x0s:  # a few starts
            x0 = np.clip(x0, lb, ub)[keep]
            sol = least_squares(resid, x0, args=(sig_q,), **opts)
            if best is None or sol.cost < best.cost:
                best = sol
        n_ang = ys.size
        p_ang = 2 + 4 * K + nz - int(fixed)
        r_ang = (ys - model(full(best.x))[0])
        s_hat = float(np.sqrt(np.sum(r_ang ** 2) / max(n_ang - p_ang, 1)))
        sig_q = max(s_hat, sig_floor)
        best = least_squares(resid, best.x, args=(sig_q,), **opts)
        x = full(best.x)
        r_ang = ys - model(x)[0]
        G = best.jac.toarray() if hasattr(best.jac, "toarray") else np.asarray(best.jac)
        try:
            cov_r = np.linalg.pinv(G.T @ G)
        except np.linalg.LinAlgError:
            cov_r = np.full((G.shape[1], G.shape[1]), np.nan)
        cov = np.zeros((x.size, x.size))
        cov[np.ix_(keep, keep)] = cov_r
        se = np.sqrt(np.clip(np.diag(cov), 0.0, None))
        Kc, Kv, P = unpack(x)
        corr = float(cov[0, 1] / (se[0] * se[1])) if se[0] > 0 and se[1] > 0 else float("nan")
        v_top = float(np.max(np.abs(vc_all := model(x)[1][1])))
        separable = bool(np.isfinite(se[1]) and se[1] * v_top <= self.sep_rel * Kc
                         and se[0] <= self.sep_rel * Kc)
        notes = []
        if fixed:
            notes.append(f"Kv held at {Kv:.4g} N m s/rad; stderr(Kc) conditional on it")
        elif not separable:
            notes.append(f"the record cannot separate Kc from Kv: stderr(Kv) = {se[1]:.3g} N m s/rad "
                         f"against Kv = {Kv:.3g} (corr(Kc, Kv) = {corr:+.2f}); coasts from several "
                         "speeds, or longer coasts, separate them")
        if Kv <= 1e-12:
            notes.append("Kv at its bound 0")
        _, (qc, vc, kce, w) = model(x)
        tau_s = coast_stop(Jk, Kv, kce, w)
        coasts = []
        for k, (tk, _, wd, _, _) in enumerate(parts):  # loop over coasts (report only)
            rk = r_ang[kk == k]
            x_s = coast_angle(tau_s[k], Jk[k], Kv, kce[k], w[k])[0] if np.isfinite(tau_s[k]) else np.inf
            coasts.append({"t_cut": float(t_r[k] + P[k, 3] * h[k]), "v_cut": float(vc[k]),
                           "direction": int(wd.direction), "t_stop": float(tau_s[k]),
                           "distance": float(x_s), "u": float(P[k, 4]), "u_measured": float(u_bar[k]),
                           "u_se": float(u_se[k]), "rms": float(np.sqrt(np.mean(rk ** 2))),
                           "samples_coasting": int(wd.rest - wd.on), "samples_pre": int(wd.on - wd.pre + 1),
                           "cut_bounds": [float(tk[wd.on]), float(tk[wd.on + 1])], "J": float(Jk[k]),
                           "q_cut": float(q_on[k] + qc[k]), "window": [int(wd.pre), int(wd.rest)]})
        return AngleCoastResult(Kc=float(Kc), Kv=float(Kv), J=float(np.mean(Jk)),
                                stderr={"Kc": float(se[0]), "Kv": float(se[1])}, corr=corr,
                                separable=separable, sigma_q=sig_q,
                                rms=float(np.sqrt(np.mean(r_ang ** 2))), n_samples=int(n_ang),
                                converged=bool(best.success), coasts=tuple(coasts),
                                cov=cov[:2, :2].copy(), notes=tuple(notes), x=x.copy(),
                                transmission="flexible" if flexible else "rigid",
                                stick=stick if flexible else "")
