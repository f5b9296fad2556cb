"""Candidate effects: parametric augmentations of the nominal model, several families per
vocabulary name (the registry :mod:`ident.effects` says which family stands for which effect).

Each candidate adds regressor columns to one channel's nominal model. Nonlinear shape
parameters (a Stribeck velocity and exponent, a ripple order, a warm-up time constant, a
presliding length, a dead-band width) are searched over wide grids, scaled to the joint's
speed and torque ranges; the amplitudes are linear. The families span the forms of the
literature (Stribeck: exponential / Gaussian / power-exponential (Tustin, Bo-Pavelescu) and
rational (Lorentzian) drops; presliding: Dahl/LuGre bristles and elasto-plastic Maxwell-slip
elements; position: additive ripple and friction-level modulation incl. harmonic-drive orders;
load: linear and saturating in the transmitted torque; thermal: time-, motion- and
power-driven; compliance: linear and hardening; backlash: dead band and smooth contact;
torque scale: gain and direction-dependent efficiency; time offset: with and without clock
skew), none of them one simulator's equation. Each family states the physically meaningful sign
of its amplitude (``physical``): a best fit with the other sign is not that effect.

Channels: ``torque`` (motor torque against the rigid Coulomb+viscous model) and
``transmission`` (link angle from markers minus motor angle).
"""
from __future__ import annotations

from contextlib import contextmanager
from contextvars import ContextVar
from dataclasses import dataclass
from typing import Callable

import numpy as np

from ident.friction import laws

from ident.effects import REGISTRY
from ident.friction.dynamic import linear_scan

V_EPS = 2e-3  # rad/s: width of the smoothed sign used for Coulomb-type terms


def ssign(qd: np.ndarray) -> np.ndarray:
    """Smoothed sign of velocity (Coulomb direction), :func:`ident.friction.laws.smooth_sign` at
    the width :data:`V_EPS`."""
    return laws.smooth_sign(qd, V_EPS)


def _sg(d) -> np.ndarray:
    """``ssign(d.qd)``, cached on the data where it can be."""
    return d.sgn if hasattr(d, "sgn") else ssign(d.qd)


def _sabs(d) -> np.ndarray:
    """``|ssign(d.qd)|`` through the same filter as :func:`_sg` (``JointData.sabs``)."""
    return d.sabs if hasattr(d, "sabs") else np.abs(ssign(d.qd))


class SharedIntermediates:
    """Intermediates of candidate columns that do not depend on the shape parameter, or that
    several shapes and families share (a sort by time, the bristle's displacement steps, the
    sines of an angle multiple), computed once while :func:`shared_intermediates` is active,
    up to a memory budget: an intermediate beyond it is computed again where it is needed (the
    same values), so the memory does not grow with the samples beyond ``budget_bytes``.

    Each entry keeps the arrays it was computed from (``anchors``) and is used only for those
    same objects."""

    def __init__(self, budget_bytes: float):
        self.budget = float(budget_bytes)
        self.store: dict = {}
        self.used = 0

    def get(self, key, anchors: tuple, build: Callable):
        hit = self.store.get(key)
        if hit is not None and len(hit[0]) == len(anchors) and all(a is b for a, b in zip(hit[0], anchors)):
            return hit[1]
        value = build()
        nbytes = sum(getattr(v, "nbytes", 0) for v in (value if isinstance(value, tuple) else (value,)))
        if hit is not None:
            self.discard(key)
        if self.used + nbytes <= self.budget:
            self.store[key] = (anchors, value, nbytes)
            self.used += nbytes
        return value

    def discard(self, key) -> None:
        hit = self.store.pop(key, None)
        if hit is not None:
            self.used -= hit[2]

    def discard_below(self, kind: str, level: float = np.inf) -> None:
        """Drop the entries ``(kind, x)`` with ``x < level`` (a sweep over increasing ``x`` no
        longer needs them; all of that kind by default)."""
        for key in [k for k in self.store if k[0] == kind and k[1] < level]:
            self.discard(key)


_SHARED: ContextVar = ContextVar("gap_shared_intermediates", default=None)


@contextmanager
def shared_intermediates(store: SharedIntermediates):
    """Candidate columns built within share the intermediates held in ``store``."""
    token = _SHARED.set(store)
    try:
        yield store
    finally:
        _SHARED.reset(token)


def _shared(key, anchors: tuple, build: Callable):
    """``build()``, or the value an active :class:`SharedIntermediates` holds for ``key`` and
    the same ``anchors``."""
    store = _SHARED.get()
    return build() if store is None else store.get(key, anchors, build)


def _bristle_steps(q: np.ndarray, qd: np.ndarray, trial: np.ndarray):
    """The shape-independent part of :func:`bristle_sign`: ``|dq|``, the start of each trial
    and the direction of each step (the trial's start direction at a trial's first step)."""
    dq = np.diff(q)
    new_trial = trial[1:] != trial[:-1]
    sgn = np.sign(dq)
    sgn = np.where(sgn == 0, np.sign(qd[1:]), sgn)
    sgn = np.where(new_trial, np.where(qd[1:] >= 0, 1.0, -1.0), sgn)
    return np.abs(dq), new_trial, sgn


def bristle_sign(q: np.ndarray, qd: np.ndarray, trial: np.ndarray, x0: float) -> np.ndarray:
    """Normalised bristle deflection ``s = z / x0`` of a LuGre-type contact, driven by the
    joint's displacement: ``ds = (sign(dq) - s) |dq| / x0`` solved exactly between samples,
    ``s[k+1] = e^{-|dq|/x0} s[k] + (1 - e^{-|dq|/x0}) sign(dq)`` (rate independent, so samples
    left out of the channel in between are bridged exactly). Saturated at each trial's start.
    Vectorised with :func:`ident.friction.dynamic.linear_scan`."""
    n = q.shape[0]
    if n == 0:
        return np.zeros(0)
    adq, new_trial, sgn = _shared(("bristle_steps",), (q, qd, trial), lambda: _bristle_steps(q, qd, trial))
    decay = adq / x0
    decay = np.where(new_trial, 60.0, np.minimum(decay, 60.0))
    drive = -np.expm1(-decay) * sgn
    s0 = 1.0 if qd[0] >= 0 else -1.0
    return linear_scan(decay, drive, s0)[:n]


@dataclass(frozen=True)
class Candidate:
    name: str                          # the effect it stands for
    channel: str
    grid: tuple
    columns: Callable                  # (data view, hp) -> (N, k)
    describe: Callable = lambda hp: ""  # noqa: E731
    family: str = ""
    physical: Callable = lambda hp, theta, d: True  # noqa: E731  (hp, amplitudes, data) -> physical
    coulomb: tuple = ()                # columns that are Coulomb-level terms: sgn(qd) x a level factor
    viscous: tuple = ()                # columns that are viscous terms: (a function of) qd x a level factor


@dataclass(frozen=True)
class Family:
    """One candidate form of an effect: the channel it lives in, its shape-parameter grid (a
    function of the joint's gear ratio), its columns ``(data view, hp) -> (N, k)`` with free
    amplitudes, a one-line description of a shape, and which amplitudes are physical
    ``(hp, amplitudes) -> bool`` (the sign an effect of this kind has)."""

    channel: str
    grid: Callable
    columns: Callable
    describe: Callable
    physical: Callable


def _pos(k=0):
    """Physical when amplitude ``k`` is positive."""
    return lambda hp, th, d: th.shape[0] > k and th[k] > 0


def _neg(k=0):
    """Physical when amplitude ``k`` is negative."""
    return lambda hp, th, d: th.shape[0] > k and th[k] < 0


def _any_sign(hp, th, d) -> bool:
    """Every amplitude is physical (the effect has no sign of its own)."""
    return True


def _vref(d):
    v = d.vmax if np.isfinite(d.vmax) else np.percentile(np.abs(d.qd), 99)
    return max(float(v), 1e-6)


def _tref(x):
    return max(float(np.percentile(np.abs(x), 95)), 1e-12) if x.size else 1.0


# --- Stribeck: friction above the Coulomb level at low speed, same direction as motion --------
def _stribeck_exp(d, hp):
    fv, delta = hp
    return (_sg(d) * np.exp(-(np.abs(d.qd) / (fv * _vref(d))) ** delta))[:, None]


def _stribeck_rational(d, hp):
    fv, delta = hp
    return (_sg(d) / (1.0 + (np.abs(d.qd) / (fv * _vref(d))) ** delta))[:, None]


_STRIBECK_GRID = tuple((fv, de) for fv in np.geomspace(0.002, 0.3, 11) for de in (0.5, 1.0, 2.0, 3.0))


# --- presliding: friction builds up over a displacement after each reversal --------------------
def _presliding(d, hp):
    """Bristle deflection minus the Coulomb direction, and its rate (the bristle damping
    ``sigma1 dz/dt`` of LuGre-type models)."""
    s = bristle_sign(d.q, d.qd, d.trial, hp)
    ds = np.zeros_like(s)
    if s.size > 2:
        span, still = _shared(("bristle_rate",), (d.t, d.trial), lambda: _rate_steps(d.t, d.trial))
        ds[1:-1] = (s[2:] - s[:-2]) / span
        ds[still] = 0.0
    return np.column_stack([s - _sg(d), ds * hp])


def _rate_steps(t: np.ndarray, trial: np.ndarray):
    """The shape-independent part of the bristle rate of :func:`_presliding`: the central
    difference's time span, and the samples whose rate is set to 0 (a trial's first and last
    sample, the two sides of a gap in the clock longer than 3 median steps)."""
    span = np.maximum(t[2:] - t[:-2], 1e-9)
    still = np.r_[True, trial[1:] != trial[:-1]] | np.r_[trial[1:] != trial[:-1], True]
    gap = np.r_[False, np.diff(t) > 3 * np.median(np.diff(t))]
    return span, still | gap | np.r_[gap[1:], False]


def elastoplastic_sign(q: np.ndarray, qd: np.ndarray, trial: np.ndarray, x0: float) -> np.ndarray:
    """Normalised deflection of one elasto-plastic (Maxwell-slip) element of break-away
    displacement ``x0``: linear in the displacement since the last reversal, saturated at +-1
    (the element is assumed saturated at each reversal and at each trial's start).
    Vectorised over monotone stretches (cumulative sums per stretch)."""
    n = q.shape[0]
    if n == 0:
        return np.zeros(0)
    dirn = np.where(qd >= 0, 1.0, -1.0)
    start = np.r_[True, (dirn[1:] != dirn[:-1]) | (trial[1:] != trial[:-1])]
    seg = np.cumsum(start) - 1
    q0 = q[start][seg]
    return np.clip(-dirn + (q - q0) / x0, -1.0, 1.0)


def _elastoplastic(d, hp):
    """Two elasto-plastic elements (lengths ``x0`` and ``4 x0``): a two-element Maxwell-slip model."""
    return np.column_stack([elastoplastic_sign(d.q, d.qd, d.trial, hp) - _sg(d),
                            elastoplastic_sign(d.q, d.qd, d.trial, 4 * hp) - _sg(d)])


def _presliding_sum_pos(hp, th, d):
    """A bristle's presliding friction opposes the motion: a positive amplitude."""
    return th.shape[0] > 0 and th[0] > 0


def _maxwell_pos(hp, th, d):
    """Elasto-plastic elements oppose the motion: a positive total, neither element much
    negative."""
    return th.shape[0] > 1 and th[0] + th[1] > 0 and min(th[0], th[1]) > -0.25 * (abs(th[0]) + abs(th[1]))


_PRESLIDING_GRID = tuple(float(x) for x in np.geomspace(5e-5, 3e-2, 11))


# --- position dependence -------------------------------------------------------------------
def _ripple_grid(gear_ratio):
    """Orders 2..48 per joint revolution (and the gear ratio's, when higher). Not 1: a term once
    per revolution has gravity's period - added to the torque it is the nominal's gravity
    correction (``sin q, cos q``), on the friction level it is friction growing with the gravity
    torque (load dependence) wherever that torque keeps its sign over the motion."""
    ks = list(range(2, 49))
    if gear_ratio and gear_ratio > 48:
        ks += [gear_ratio, 2 * gear_ratio]
    return tuple(float(k) for k in ks)


def _sin_cos(a: np.ndarray) -> tuple:
    return np.sin(a), np.cos(a)


def _no_tiny(q: np.ndarray) -> bool:
    """Whether no multiple ``k q`` (k >= 1) is subnormal: then ``2 (k q) == (2 k) q`` exactly."""
    return not bool(np.any((q != 0) & (np.abs(q) < 1e-300)))


def _angle_harmonics(q: np.ndarray, hp: float, second: bool = True) -> tuple:
    """``sin, cos`` of ``hp q`` and (``second``) of ``2 hp q``. A sweep over increasing orders
    shares them (:class:`SharedIntermediates`): an order's double is the fundamental of a later
    order, and the ripple families of one order use the same fundamental."""
    store = _SHARED.get()
    if store is None:
        a = hp * q
        return _sin_cos(a) + (_sin_cos(2 * a) if second else ())
    store.discard_below("trig", float(hp))
    store.discard_below("trig2", float(hp))
    a = None

    def fundamental():
        nonlocal a
        a = hp * q
        return _sin_cos(a)

    s1 = store.get(("trig", float(hp)), (q,), fundamental)
    if not second:
        return s1
    exact = store.get(("no_tiny",), (q,), lambda: _no_tiny(q))
    key2 = ("trig", float(2 * hp)) if exact else ("trig2", float(hp))
    s2 = store.get(key2, (q,), lambda: _sin_cos(2 * (hp * q if a is None else a)))
    return s1 + s2


def _ripple(d, hp):
    """A torque periodic in the angle with ``hp`` periods per joint revolution, to its second
    harmonic (a ripple is rarely a pure sine: harmonic-drive orders come with their double)."""
    return np.column_stack(_angle_harmonics(d.q, hp))


def _modulation(d, hp):
    """Friction level modulated along the angle: ``c (1 + m sin(n q + p))`` -> ``sgn(qd) sin, cos``."""
    sg = _sg(d)
    s, c = _angle_harmonics(d.q, hp, second=False)
    return np.column_stack([sg * s, sg * c])


# --- load dependence: Coulomb level growing with the transmitted torque ---------------------
def _load(d, hp):
    src, sat = hp
    tau = d.tau_grav if src == "gravity" else d.tau_urdf
    x = np.abs(tau)
    if sat:
        T = sat * _tref(tau)
        x = T * np.tanh(x / T)
    return (_sg(d) * x)[:, None]


# --- thermal drift ------------------------------------------------------------------------
def _heat(d, hp):
    """First-order thermal state driven by a power proxy (``src``: ``motion`` = |qd|, ``power`` =
    |y qd|) with time constant ``tau`` on the campaign clock (cooling between samples)."""
    src, tau = hp
    if d.t.size == 0:
        return np.zeros(0)
    order, dt, P1, ratio = _shared(("heat", src), (d.t, d.qd, d.y), lambda: _heat_steps(d, src))
    decay = dt / tau
    drive = -np.expm1(-decay) * P1 * ratio
    h = linear_scan(decay, drive, 0.0)
    h = h / max(np.max(np.abs(h)), 1e-300)
    if order is None:      # the samples are in time order
        return h
    out = np.empty_like(h)
    out[order] = h
    return out


def _heat_steps(d, src: str):
    """The shape-independent part of :func:`_heat`: the time order of the samples (None when
    they are in it), the time steps, the power proxy driving each step, and the share of each
    step counted as heating (a step longer than 5 median steps heats for 5)."""
    order = np.argsort(d.t, kind="stable")
    t = d.t[order]
    P = np.abs(d.qd[order]) if src == "motion" else np.abs(d.y[order] * d.qd[order])
    dt = np.diff(t)
    dts = np.minimum(dt, 5 * np.median(dt)) if dt.size else dt
    if np.array_equal(order, np.arange(order.size)):
        order = None
    return order, dt, P[1:], dts / np.maximum(dt, 1e-12)


def _thermal(d, hp):
    kind = hp[0]
    if kind == "time":
        tt = _shared(("elapsed",), (d.t,), lambda: d.t - d.t.min())
        w = np.exp(-tt / hp[1]) if np.isfinite(hp[1]) else 1.0 - tt / max(tt.max(), 1e-9)
    else:
        w = -_heat(d, hp)   # warmer -> less friction: w = -h has the sign of a cold excess
    return np.column_stack([_sg(d) * w, d.qd * w])


def _thermal_physical(hp, th, d):
    """Friction falls as the joint warms: the cold excess of the Coulomb (or, if that is nil,
    the viscous) level is positive."""
    return th.shape[0] > 1 and (th[0] > 0 or (abs(th[0]) < 0.1 * abs(th[1]) and th[1] > 0))


_THERMAL_GRID = (tuple(("time", float(x)) for x in np.geomspace(20, 5000, 10)) + (("time", np.inf),)
                 + tuple((src, float(x)) for src in ("motion", "power") for x in np.geomspace(30, 3000, 7)))


# --- torque scale ----------------------------------------------------------------------------
def _motor_torque(d) -> np.ndarray:
    """The torque the gear passes: rigid-body torque plus the joint's Coulomb + viscous friction
    (a three-parameter least-squares fit of the logged torque, smooth, so the torque noise does not
    enter the regressor)."""
    sign = lambda _: _sg(d)  # noqa: E731  (the smoothed Coulomb direction)
    X = np.column_stack([d.tau_urdf, laws.coulomb_viscous_columns(d.qd, sign=sign)])
    th = np.linalg.lstsq(X, d.y, rcond=None)[0]
    return d.tau_urdf + laws.coulomb_viscous(d.qd, th[1], th[2], sign=sign)


def _scale(d, hp):
    """A constant gain on the rigid-body torque (a torque-constant error; its friction part is
    the nominal's), or a direction-dependent efficiency of the gear: the whole torque it passes
    (load and friction) scaled differently when motoring and when back-driven. The efficiency
    acts on the motor torque, friction included, where load-dependent friction grows with the
    transmitted (link-side) torque alone: the two differ where friction is a fair part of it."""
    if hp == "gain":
        return d.tau_urdf[:, None]
    tau = _motor_torque(d)
    motoring = (tau * d.qd) > 0
    return np.column_stack([tau * motoring, tau * ~motoring])


# --- asymmetry, nonlinear viscous ------------------------------------------------------------
def _asym(d, hp):
    pos = d.qd > 0
    return np.column_stack([_sabs(d), d.qd * pos])


def _nlv(d, hp):
    kind, x = hp
    if kind == "power":
        v = _vref(d)
        return (np.sign(d.qd) * v * np.abs(d.qd / v) ** x)[:, None]
    vr = x * _vref(d)
    return (d.qd / (1.0 + np.abs(d.qd) / vr))[:, None]


_NLV_GRID = (tuple(("power", float(p)) for p in (0.3, 0.45, 0.6, 0.75, 1.3, 1.6, 2.0, 2.5, 3.0))
             + tuple(("saturating", float(x)) for x in (0.1, 0.3, 1.0)))


# --- transmission channel: q_link - q_motor beyond the declared stiffness ---------------------
def _torque_m(d, src):
    return d.tau_m if src == "rigid" else d.y_m


def hardening_deflection(u, c: float) -> np.ndarray:
    r"""The deflection ``s`` of a hardening (Duffing) spring under the normalised torque ``u``:
    the real root of :math:`s + c s^3 = u` (Cardano), odd in ``u``, slope 1 at zero load and
    :math:`(u / c)^{1/3}` at high load; ``c`` is the cubic stiffness over the linear one at the
    reference torque, :math:`k_3 T^2 / k_1^3` for :math:`\tau = k_1 x + k_3 x^3`."""
    u = np.asarray(u, float)
    h = 0.5 * u / c
    r = np.sqrt(h * h + (1.0 / (3.0 * c)) ** 3)
    return np.cbrt(h + r) + np.cbrt(h - r)


#: cubic-over-linear stiffness ratios of the hardening springs tried (k3 T^2 / k1^3)
_HARDENING_C = (0.25, 1.0, 4.0)


def _compliance(d, hp):
    """Deflection beyond the declared stiffness, growing with the transmitted torque: linear (a
    softer spring) or hardening (a finite stiffness at zero load that grows with the deflection):
    the deflection's cubic term in the torque (``"hardening"``, a mild hardening), or the exact
    deflection of a hardening spring ``tau = k1 x + k3 x^3`` (:func:`hardening_deflection`,
    ``("hardening", c)``), each beside a linear column (the declared stiffness's error)."""
    src, kind = hp[:2]
    tau = _torque_m(d, src)
    if kind == "linear":
        return tau[:, None]
    T = _tref(tau)
    if len(hp) > 2:
        return np.column_stack([tau, T * hardening_deflection(tau / T, hp[2])])
    return np.column_stack([tau, tau * (tau / T) ** 2])


def _compliance_physical(hp, th, d):
    """A softer joint lags more: q_link - q_motor = -tau / K, so the extra deflection's slope at
    zero load (the extra compliance) is negative; and the whole deflection, the declared
    spring's ``-tau / K`` (``d.stiffness``; none for a rigid joint) plus the extra, may not turn
    back within the torque range: its slope keeps its sign up to 95 % of the torque (a
    hardening spring, softer than declared at zero load, may be stiffer at high load)."""
    if th.shape[0] == 0:
        return False
    k = float(d.stiffness)
    declared = 1.0 / k if k > 0 else 0.0
    if len(hp) > 2:
        s1 = hardening_deflection(1.0, hp[2])
        slope_T = 1.0 / (1.0 + 3.0 * hp[2] * s1 * s1)          # ds/du at u = 1
        return th[0] + th[1] < 0 and th[0] + th[1] * slope_T < declared
    if th[0] >= 0:
        return False
    return th.shape[0] < 2 or th[0] + 3.0 * th[1] < declared


def _backlash(d, hp):
    """Lost motion that switches with the torque (or motion) direction, independent of the load:
    a dead band entered over a small torque width (``tanh`` step), or a smooth contact whose
    deflection grows as a power below one of the torque (Hertz point contact: 2/3; a contact's
    deflection has no finite stiffness at zero load, unlike a spring's)."""
    kind, src, width = hp
    if kind == "motion":
        return laws.smooth_sign(d.qd_m, width * max(_tref(d.qd_m), 1e-9))[:, None]
    tau = _torque_m(d, src)
    T = _tref(tau)
    if kind == "contact":
        return (np.sign(tau) * np.abs(tau / T) ** width)[:, None]
    return laws.smooth_sign(tau, width * T)[:, None]


_BACKLASH_GRID = (tuple(("torque", src, w) for src in ("rigid", "motor") for w in (0.002, 0.005, 0.02, 0.05))
                  + tuple(("contact", "rigid", p) for p in (0.4, 0.5, 2.0 / 3.0))
                  + tuple(("motion", "", w) for w in (0.002, 0.01)))


#: delays between the logged torque and the logged position tested on continuous records, s
#: (sensor, current-loop or logging latency); the column's sign says which signal is late
DELAY_GRID_S = tuple(float(x) for x in np.round(np.r_[np.arange(0.0005, 0.0051, 0.0005), np.arange(0.006, 0.0201, 0.001),
                                                      0.025, 0.030], 4))
#: second-order low-passes of the logged torque (cut-off Hz, damping) tested against the delay
LOWPASS_GRID = tuple((fc, z) for fc in (6.0, 8.0, 10.0, 13.0, 16.0, 20.0, 25.0, 32.0, 40.0, 50.0)
                     for z in (0.5, 0.7, 0.9))


def _torque_delay(d, hp):
    """A delay ``hp`` (s) of the logged torque against the logged position: ``p(t - hp) - p(t)``
    with ``p`` the record's rigid-body fit (:func:`ident.gap.data._record_signal_columns`);
    amplitude 1 at the true delay. No column where the data hold none (single-joint campaigns:
    their time offset is the marker clock's, in the transmission channel)."""
    cols = getattr(d, "delay_cols", None)
    if cols is None:
        return np.zeros((d.y.shape[0], 0))
    return cols[:, [DELAY_GRID_S.index(hp)]]


#: correlation of two delay columns above which they are one term, one column scaled: to rounding
#: (a delay under one sample period interpolates the logged samples linearly, so every such
#: column is ``dt / T_s`` times the one-sample difference, and which grid point carries the fit is
#: decided by rounding). Columns correlated less than this, however closely, keep their own band:
#: their second-order difference carries the shape (a low-pass of the logged torque fits a grid
#: delay at an amplitude 2 zeta^2 / (4 zeta^2 - 1), not 1; docs/gap-diagnosis.md): measured on
#: the foreign world's sensor_lag records, a band on the term for columns correlated above 0.999
#: named 3 more of 7 low-passes `time_offset` and 1 more of 19 delays
SAME_DELAY_TERM = 1.0 - 1e-9


def _delay_physical(hp, th, d) -> bool:
    """A delay's column has amplitude 1 at the true delay (the torque late), -1 when the
    position is the late one (to first order ``p(t) - p(t - dt) = p(t + dt) - p(t)``); to first
    order the amplitude scales the delay, and a logged torque whose transitions are sharper than
    the model's fits a shorter grid delay at a larger amplitude: within 0.4-2.5 of either sign,
    else the shape is not a delay.

    Where the chosen column is ``k`` times another grid delay's column to rounding
    (:data:`SAME_DELAY_TERM`: delays under one sample period), the fitted term is that column at
    amplitude ``k a`` as well, and the shape is a delay when any such amplitude lies in the band:
    which of those identical columns carries the fit is decided by rounding, so its amplitude
    alone cannot decide (measured on a 250 Hz foreign ind6 record: 4.73 on the 1 ms column,
    1.89 on the 2.5 ms one, correlated to 1 - 2e-15)."""
    if th.shape[0] == 0:
        return False
    a = float(th[0])
    if 0.4 < abs(a) < 2.5:
        return True
    cols = getattr(d, "delay_cols", None)
    if cols is None or hp not in DELAY_GRID_S:
        return False
    c = cols[:, DELAY_GRID_S.index(hp)]
    cc = float(c @ c)
    norms = np.einsum("ij,ij->j", cols, cols)
    dots = cols.T @ c
    live = (norms > 0) & (cc > 0)
    corr = np.where(live, dots / np.sqrt(np.where(live, norms * cc, 1.0)), 0.0)
    b = np.abs(a * np.where(live, dots / np.where(live, norms, 1.0), 0.0))   # the amplitude on each
    return bool(np.any((corr >= SAME_DELAY_TERM) & (b > 0.4) & (b < 2.5)))


def _time_offset(d, hp):
    if hp == "offset":
        return d.qd_m[:, None]
    tt = d.t_m - (d.t_m.min() if d.t_m.size else 0.0)
    return np.column_stack([d.qd_m, d.qd_m * tt])


# Candidate families by name; ident.effects declares which effect each one stands for.
# name -> (channel, grid(gear_ratio), columns, describe, physical)
FAMILIES = {
    "stribeck_exponential": Family(
        "torque", lambda g: _STRIBECK_GRID, _stribeck_exp,
        lambda hp: f"exp(-(|qd|/vs)^{hp[1]:g}) drop, vs = {hp[0]:.3g} vmax", _pos()),
    "stribeck_rational": Family(
        "torque", lambda g: _STRIBECK_GRID, _stribeck_rational,
        lambda hp: f"1/(1 + (|qd|/vs)^{hp[1]:g}) drop, vs = {hp[0]:.3g} vmax", _pos()),
    "presliding_bristle": Family("torque", lambda g: _PRESLIDING_GRID, _presliding,
                           lambda hp: f"Dahl/LuGre bristle, presliding length {hp:.2e} rad", _presliding_sum_pos),
    "presliding_maxwell": Family("torque", lambda g: _PRESLIDING_GRID, _elastoplastic,
                           lambda hp: f"elasto-plastic (Maxwell-slip) elements, break-away {hp:.2e} and "
                                      f"{4 * hp:.2e} rad", _maxwell_pos),
    "ripple_additive": Family("torque", _ripple_grid, _ripple, lambda hp: f"additive ripple, {hp:g} cycles per joint revolution (and its 2nd harmonic)",
                        _any_sign),
    "ripple_modulation": Family("torque", _ripple_grid, _modulation,
                          lambda hp: f"friction level modulated {hp:g} times per joint revolution",
                          _any_sign),
    "load_transmitted": Family("torque", lambda g: tuple((src, sat) for src in ("rigid", "gravity") for sat in (0, 0.5, 1.5)),
                         _load, lambda hp: f"Coulomb level growing with |{'gravity' if hp[0] == 'gravity' else 'transmitted'}"
                                           f" torque|" + (f", saturating at {hp[1]:g} x its 95th percentile" if hp[1] else ""),
                         _pos()),
    "thermal": Family("torque", lambda g: _THERMAL_GRID, _thermal,
                lambda hp: ("linear drift over the campaign" if hp[0] == "time" and not np.isfinite(hp[1])
                            else f"warm-up time constant {hp[1]:.0f} s" if hp[0] == "time"
                            else f"heating by {hp[0]}, time constant {hp[1]:.0f} s"), _thermal_physical),
    "torque_gain": Family("torque", lambda g: ("gain", "efficiency"), _scale,
                    lambda hp: "torque proportional to rigid-body torque" if hp == "gain"
                    else "direction-dependent efficiency (motoring / back-driven)", _any_sign),
    "asymmetry": Family("torque", lambda g: (None,), _asym, lambda hp: "direction-dependent Coulomb and viscous",
                  _any_sign),
    "nonlinear_viscous": Family("torque", lambda g: _NLV_GRID, _nlv,
                          lambda hp: f"viscous term |qd|^{hp[1]:g}" if hp[0] == "power"
                          else f"saturating viscous, knee {hp[1]:g} vmax", _any_sign),
    "compliance": Family("transmission", lambda g: tuple((src, k) for src in ("rigid", "motor") for k in ("linear", "hardening"))
                   + tuple((src, "hardening", c) for src in ("rigid", "motor") for c in _HARDENING_C),
                   _compliance, lambda hp: (f"{hp[1]} deflection with the {'transmitted' if hp[0] == 'rigid' else 'motor'} torque"
                                            + (f" (spring k3 T^2 / k1^3 = {hp[2]:g})" if len(hp) > 2 else "")),
                   _compliance_physical),
    "backlash": Family("transmission", lambda g: _BACKLASH_GRID, _backlash,
                 lambda hp: (f"smooth contact, deflection ~ |transmitted torque|^{hp[2]:.2g}" if hp[0] == "contact" else
                             f"lost motion switching with the {hp[0] if hp[0] == 'motion' else hp[1] + ' torque'} sign"),
                 _neg()),
    "torque_delay": Family("torque", lambda g: DELAY_GRID_S, _torque_delay,
                           lambda hp: f"a delay of {hp * 1e3:.3g} ms between the logged torque and the logged "
                                      "position", _delay_physical),
    "time_offset": Family("transmission", lambda g: ("offset", "skew"), _time_offset,
                    lambda hp: "marker clock shifted: q_link(t) = q(t + dt)" if hp == "offset"
                    else "marker clock shifted and running at another rate", _any_sign),
}


#: Columns of each family that modify the Coulomb level (``sgn(qd) x`` a factor of speed, angle,
#: transmitted torque, temperature, direction or displacement since a reversal) and the viscous
#: level (``qd`` or a function of it, x such a factor). Friction models of the literature compose
#: such factors by product (a load-dependent level is asymmetric too when the Coulomb level is; a
#: warm joint's Stribeck excess and nonlinear viscous term fall with its levels), so once one of
#: them is selected, a later candidate is tested with its product with the selected level as well
#: (:func:`level_interactions`).
COULOMB_COLUMNS = {"stribeck_exponential": (0,), "stribeck_rational": (0,), "presliding_bristle": (0,),
                   "presliding_maxwell": (0, 1), "ripple_modulation": (0, 1), "load_transmitted": (0,),
                   "thermal": (0,), "asymmetry": (0,)}
VISCOUS_COLUMNS = {"thermal": (1,), "asymmetry": (1,), "nonlinear_viscous": (0,)}


def selected_levels(C: np.ndarray, theta: np.ndarray, cand: "Candidate", d) -> tuple:
    """(Coulomb level, viscous level factor) of a selected candidate's fitted columns ``C @ theta``:
    the Coulomb-type columns' torque over ``sgn(qd)`` (so ``sgn a`` gives ``a``), the viscous-type
    columns' torque over ``qd`` (speeds below 5 % of the reference speed held at it). Either None
    when the family has no such column."""
    sg = _sg(d)
    cou = C[:, list(cand.coulomb)] @ theta[list(cand.coulomb)] * sg if cand.coulomb else None
    vis = None
    if cand.viscous:
        eps = 0.05 * _vref(d)
        qd = np.where(d.qd >= 0, 1.0, -1.0) * np.maximum(np.abs(d.qd), eps)
        vis = C[:, list(cand.viscous)] @ theta[list(cand.viscous)] / qd
    return cou, vis


def level_interactions(C: np.ndarray, cand: "Candidate", levels: tuple) -> np.ndarray:
    """``C`` with the products of its Coulomb-type columns with the selected Coulomb level, and of
    its viscous-type columns with the selected viscous level factor (``levels``, from
    :func:`selected_levels`, summed over the selected effects): a column ``sgn a`` and a selected
    ``sgn b`` give ``sgn a b``, the cross term of ``c sgn (1 + a)(1 + b)``. Unchanged when nothing
    is selected or the family has no such column."""
    extra = []
    for kind, idx, lev in (("coulomb", cand.coulomb, levels[0]), ("viscous", cand.viscous, levels[1])):
        if lev is None or not idx or C.shape[0] != lev.shape[0]:
            continue
        factor = _shared(("level", kind), (lev,), lambda: _unit_rms(lev))
        if factor is not None:
            extra.append((list(idx), factor))
    if not extra:
        return C
    out = np.empty((C.shape[0], C.shape[1] + sum(len(idx) for idx, _ in extra)))
    out[:, :C.shape[1]] = C
    k = C.shape[1]
    for idx, factor in extra:
        np.multiply(C[:, idx], factor[:, None], out=out[:, k:k + len(idx)])
        k += len(idx)
    return out


def _unit_rms(lev: np.ndarray):
    """``lev`` over its RMS (None when it is all zero)."""
    scale = float(np.sqrt(np.mean(lev ** 2)))
    return lev / scale if scale > 0 else None


#: torque-channel families whose columns live at low speed and at velocity reversals, where the
#: nominal model's own errors are largest (friction transients through the controller and the
#: velocity filter): on effect-free foreign campaigns they removed up to 0.062 of the noise floor
#: (white noise), the other torque families (slow in time, global in position, load or direction)
#: at most 0.012. The diagnosis gives each group its own effect-size floor.
REVERSAL_SHAPED = frozenset({"stribeck_exponential", "stribeck_rational", "presliding_bristle",
                             "presliding_maxwell", "nonlinear_viscous"})


#: a ripple order is tested only if the motion covers at least this share of its period: over less,
#: a periodic term is a smooth trend in the angle (the shape of gravity, of a URDF error and of
#: friction growing with the gravity torque), not a ripple the data can show
MIN_RIPPLE_PERIODS = 0.5


def _observable_orders(grid: tuple, q_range: float | None) -> tuple:
    if q_range is None or not np.isfinite(q_range) or q_range <= 0:
        return grid
    return tuple(n for n in grid if n * q_range >= 2 * np.pi * MIN_RIPPLE_PERIODS)


def candidate_effects(gear_ratio: float | None = None, q_range: float | None = None) -> list[Candidate]:
    """The candidate effects the gap diagnosis tests: one per (effect, family) of the registry.

    The registry is :mod:`ident.effects`; a candidate's ``name`` is the effect it stands for,
    ``family`` the form tested, and its columns augment one channel's nominal model (the
    rigid-body torque with the Coulomb + viscous friction of thesis eq. 2-4, 2-5 [1]_ in the
    torque channel; the link-motor deflection in the transmission channel). The families span
    the literature's forms (module docstring; the presliding family is the LuGre-type bristle
    of Indri & Trapani eq. 5 [2]_ with the exact sign) [3]_.

    Parameters
    ----------
    gear_ratio : float or None, optional
        The joint's gear ratio, which sets the ripple orders tested (the wave generator's and
        its harmonics); None: the generic orders.
    q_range : float or None, optional
        The joint's range of motion (rad), which bounds the ripple orders tested from below
        (:data:`MIN_RIPPLE_PERIODS`); None: no bound.

    Returns
    -------
    list of Candidate
        One candidate per (effect, family); a ripple family with no observable order keeps
        an empty grid (reported as not identifiable).

    References
    ----------
    .. [1] PA10 thesis (seeds 002), eq. 2-4, 2-5.
    .. [2] Indri & Trapani 2020 (seeds 001), eq. 5.
    .. [3] jointlab gap diagnosis (docs/gap-diagnosis.md), the candidate families.
    """
    out = []
    for spec in REGISTRY.values():
        for fam in spec.families:
            f = FAMILIES[fam]
            channel, columns, describe, physical = f.channel, f.columns, f.describe, f.physical
            g = f.grid(gear_ratio)
            if fam.startswith("ripple_"):
                g = _observable_orders(g, q_range)   # none left: reported as not identifiable
            out.append(Candidate(spec.name, channel, g, columns, describe, fam, physical,
                                 COULOMB_COLUMNS.get(fam, ()), VISCOUS_COLUMNS.get(fam, ())))
    return out


def confounders(name: str) -> tuple[list, str]:
    """(effects confused with ``name``, the experiment that separates them), from the registry.

    Confusion is symmetric: an effect that names ``name`` among its confounders is one of
    ``name``'s too (after ``name``'s own, in registry order)."""
    sp = REGISTRY.get(name)
    if sp is None:
        return [], ""
    back = [n for n, o in REGISTRY.items() if name in o.confounders and n not in sp.confounders and n != name]
    return list(sp.confounders) + back, sp.separating_experiment


#: name -> (confounders, separating experiment), read from the registry
CONFOUNDERS = {n: confounders(n) for n, sp in REGISTRY.items() if sp.families}
