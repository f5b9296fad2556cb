"""Reference trajectories for one joint: ``sample(t) -> (q, qd, qdd)``, vectorised over t.

- :class:`FourierReference`: finite Fourier excitation, thesis eq. 3-2, with zero speed and
  acceleration at both ends and a peak speed of ``vmax_frac`` times the joint's maximum speed.
- :class:`PiecewiseAccel`: piecewise-constant acceleration (exact q, qd): reversals at several
  accelerations (:func:`reversals`) and constant-velocity sweeps (:func:`constant_velocity`).
- :class:`MinJerkPath`: minimum-jerk moves through waypoints with holds (static poses,
  calibration sweeps, coast-down approach moves).

All times are relative to the start of the trajectory; angles in rad.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ident.signals.fourier import FourierSeries


class Reference:
    duration: float = 0.0

    def sample(self, t) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        raise NotImplementedError

    def to_dict(self) -> dict:
        return {"type": type(self).__name__, "duration": float(self.duration)}


@dataclass(frozen=True, eq=False)
class FourierReference(Reference):
    """Thesis eq. 3-2: ``qd(t) = sum_l a_l cos(w l t) + b_l sin(w l t)`` over ``n_periods``
    periods, with holds of ``hold`` seconds before and after (so the trial starts and ends at
    rest). Constraints ``sum a_l = 0`` and ``sum l b_l = 0`` make speed and acceleration zero at
    both ends (eq. 3-2 evaluated at t = 0 and t = n_periods 2 pi / w)."""

    a: np.ndarray
    b: np.ndarray
    w: float
    q0: float
    n_periods: int
    hold: float = 0.5

    @property
    def duration(self) -> float:
        return float(self.n_periods * 2 * np.pi / self.w + 2 * self.hold)

    def sample(self, t):
        t = np.asarray(t, float)
        tt = np.clip(t - self.hold, 0.0, self.n_periods * 2 * np.pi / self.w)
        moving = (t >= self.hold) & (t <= self.duration - self.hold)
        q, qd, qdd = FourierSeries(self.a, self.b, self.w, self.q0).evaluate(tt)
        return q, qd * moving, qdd * moving

    def to_dict(self):
        return {"type": "fourier", "duration": self.duration, "a": self.a.tolist(),
                "b": self.b.tolist(), "w_f": self.w, "q0": self.q0, "n_periods": self.n_periods,
                "hold": self.hold}


def fourier_excitation(rng: np.random.Generator, vmax: float, vmax_frac: float, duration: float,
                       q_center: float, q_halfrange: float, n_harmonics: int = 5,
                       period: float = 10.0, hold: float = 0.5) -> FourierReference:
    """A random finite-Fourier excitation (thesis eq. 3-2) with peak speed ``vmax_frac * vmax``.

    Coefficients are drawn from ``rng`` (decaying as 1/l), projected onto the end constraints,
    scaled to the peak speed; the number of periods in ``duration - 2 hold`` is doubled until
    the position stays within ``q_center +- q_halfrange``.

    Parameters
    ----------
    rng : numpy.random.Generator
        Source of the coefficients.
    vmax : float
        The joint's maximum speed (rad/s).
    vmax_frac : float
        Peak speed as a fraction of ``vmax``, in (0, 1.5].
    duration : float
        Length of the trajectory, holds included (s).
    q_center, q_halfrange : float
        Centre and half-width of the allowed range (rad).
    n_harmonics : int, optional
        Harmonics of eq. 3-2.
    period : float, optional
        Nominal period (s).
    hold : float, optional
        Rest before and after the motion (s).

    Returns
    -------
    FourierReference
        The trajectory; ``sample(t)`` gives ``(q, qd, qdd)``.

    References
    ----------
    .. [1] PA10 thesis (seeds 002), eq. 3-2.

    Examples
    --------
    >>> ref = fourier_excitation(np.random.default_rng(0), vmax=2.0, vmax_frac=0.5, duration=21.0,
    ...                          q_center=0.0, q_halfrange=1.0)
    >>> t = np.linspace(0.0, ref.duration, 20001)
    >>> q, qd, qdd = ref.sample(t)
    >>> round(float(np.abs(qd).max()), 3), bool(np.abs(q).max() <= 1.0), float(qd[0]) == 0.0
    (1.0, True, True)
    """
    if not 0 < vmax_frac <= 1.5:
        raise ValueError(f"vmax_frac must be in (0, 1.5], got {vmax_frac}")
    L = int(n_harmonics)
    l = np.arange(1, L + 1)
    a = rng.standard_normal(L) / l
    b = rng.standard_normal(L) / l
    # zero speed at t=0: sum a = 0; zero acceleration: sum l b = 0 (least-change projection)
    a -= a.sum() / L
    b -= l * (l @ b) / (l @ l)
    target = vmax_frac * vmax
    moving = max(duration - 2 * hold, 1e-3)
    n_periods = max(1, int(round(moving / period)))
    while True:
        w = 2 * np.pi * n_periods / moving
        ref = FourierReference(a, b, w, 0.0, n_periods, hold)
        tg = np.linspace(0.0, ref.duration, 4001)
        _, qd, _ = ref.sample(tg)
        scale = target / np.max(np.abs(qd))
        q, _, _ = FourierReference(a * scale, b * scale, w, 0.0, n_periods, hold).sample(tg)
        half = 0.5 * (q.max() - q.min())
        if half <= q_halfrange or n_periods >= 64:
            break
        n_periods *= 2
    mid = 0.5 * (q.max() + q.min())
    return FourierReference(a * scale, b * scale, w, q_center - mid, n_periods, hold)


@dataclass(frozen=True, eq=False)
class PiecewiseAccel(Reference):
    """Piecewise-constant acceleration ``acc[i]`` on ``[t[i], t[i+1])`` from ``q0`` at rest;
    q and qd are exact (integrated in closed form)."""

    t: np.ndarray      # (K+1,) breakpoints, t[0] = 0
    acc: np.ndarray    # (K,)
    q0: float

    def __post_init__(self):
        t = np.asarray(self.t, float)
        acc = np.asarray(self.acc, float)
        dt = np.diff(t)
        v = np.concatenate([[0.0], np.cumsum(acc * dt)])
        q = np.concatenate([[self.q0], self.q0 + np.cumsum(v[:-1] * dt + 0.5 * acc * dt ** 2)])
        object.__setattr__(self, "t", t)
        object.__setattr__(self, "acc", acc)
        object.__setattr__(self, "_v", v)
        object.__setattr__(self, "_q", q)

    @property
    def duration(self) -> float:
        return float(self.t[-1])

    def sample(self, t):
        t = np.clip(np.asarray(t, float), 0.0, self.t[-1])
        i = np.clip(np.searchsorted(self.t, t, side="right") - 1, 0, self.acc.size - 1)
        tau = t - self.t[i]
        a = self.acc[i]
        qd = self._v[i] + a * tau
        q = self._q[i] + self._v[i] * tau + 0.5 * a * tau ** 2
        at_end = t >= self.t[-1]
        return q, qd, np.where(at_end, 0.0, a)

    @property
    def q_range(self) -> tuple[float, float]:
        q, _, _ = self.sample(np.linspace(0, self.duration, 20001))
        return float(q.min()), float(q.max())

    def shifted(self, q0: float) -> "PiecewiseAccel":
        return PiecewiseAccel(self.t, self.acc, q0)

    def to_dict(self):
        return {"type": "piecewise_accel", "duration": self.duration, "t": self.t.tolist(),
                "acc": self.acc.tolist(), "q0": self.q0}


def _from_segments(segs, q0=0.0) -> PiecewiseAccel:
    """segs: list of (duration, acceleration)."""
    d = np.array([s[0] for s in segs], float)
    a = np.array([s[1] for s in segs], float)
    keep = d > 0
    return PiecewiseAccel(np.concatenate([[0.0], np.cumsum(d[keep])]), a[keep], q0)


def _centre(ref: PiecewiseAccel, q_center: float) -> PiecewiseAccel:
    lo, hi = ref.q_range
    return ref.shifted(ref.q0 + q_center - 0.5 * (lo + hi))


def reversals(vmax: float, vmax_frac: float, q_center: float, q_halfrange: float,
              accel_factors=(1.0, 2.0, 4.0), cycles: int = 3, hold: float = 0.5) -> PiecewiseAccel:
    """Velocity reversals (triangle waves between +v and -v, v = vmax_frac vmax) at several
    constant accelerations ``a_k = f_k a_min``; ``a_min`` keeps the swing within
    ``q_halfrange``. Each block: 0 -> +v, ``cycles`` x (+v -> -v -> +v), +v -> 0, back to the
    start at the same acceleration, hold.

    Parameters
    ----------
    vmax : float
        The joint's maximum speed (rad/s).
    vmax_frac : float
        Reversal speed as a fraction of ``vmax``.
    q_center, q_halfrange : float
        Centre and half-width of the allowed range (rad).
    accel_factors : sequence of float, optional
        Accelerations in units of the smallest one that keeps the swing in range.
    cycles : int, optional
        Reversal cycles per acceleration.
    hold : float, optional
        Rest between blocks (s).

    Returns
    -------
    PiecewiseAccel
        The trajectory (exact ``q``, ``qd``; piecewise-constant ``qdd``).

    Examples
    --------
    >>> ref = reversals(vmax=2.0, vmax_frac=0.5, q_center=0.0, q_halfrange=0.5)
    >>> q, qd, qdd = ref.sample(np.linspace(0.0, ref.duration, 20001))
    >>> ref.duration, float(np.abs(qd).max()), ref.q_range
    (17.5, 1.0, (-0.25, 0.25))
    """
    v = vmax_frac * vmax
    a_min = v * v / max(q_halfrange, 1e-3)
    segs = [(hold, 0.0)]
    for f in accel_factors:
        a = f * a_min
        tr = v / a
        blk = [(tr, a)]
        for _ in range(cycles):
            blk += [(2 * tr, -a), (2 * tr, a)]
        blk += [(tr, -a)]
        segs += blk + [(hold, 0.0)]
        # net displacement of blk is v^2/a (the +v excursion); return symmetrically
        segs += [(tr, -a), (tr, a), (hold, 0.0)]
    return _centre(_from_segments(segs), q_center)


def constant_velocity(vmax: float, vmax_frac: float, q_center: float, q_halfrange: float,
                      speed_fractions=(0.05, 0.1, 0.2, 0.4, 0.7, 1.0), accel: float | None = None,
                      max_cruise: float = 2.5, hold: float = 0.3) -> PiecewiseAccel:
    """Constant-velocity sweeps: for each speed ``f vmax_frac vmax``, accelerate, cruise over
    up to ``1.6 q_halfrange`` (at most ``max_cruise`` s), stop, hold, and come back at the same
    speed (both directions, as in Kennedy et al. 2003's PA-10 friction maps).

    Parameters
    ----------
    vmax : float
        The joint's maximum speed (rad/s).
    vmax_frac : float
        Top sweep speed as a fraction of ``vmax``.
    q_center, q_halfrange : float
        Centre and half-width of the allowed range (rad).
    speed_fractions : sequence of float, optional
        Sweep speeds as fractions of the top speed.
    accel : float, optional
        Acceleration of the ramps (rad/s^2); ``max(2 v_top, 1)`` by default.
    max_cruise : float, optional
        Longest cruise (s).
    hold : float, optional
        Rest between sweeps (s).

    Returns
    -------
    PiecewiseAccel
        The trajectory.

    Examples
    --------
    >>> ref = constant_velocity(vmax=2.0, vmax_frac=0.5, q_center=0.0, q_halfrange=0.5)
    >>> lo, hi = ref.q_range
    >>> round(lo, 9), round(hi, 9)
    (-0.4, 0.4)
    """
    vtop = vmax_frac * vmax
    a = accel if accel is not None else max(2.0 * vtop, 1.0)
    span = 1.6 * q_halfrange
    segs = [(hold, 0.0)]
    for f in speed_fractions:
        v = f * vtop
        tr = v / a
        cruise = max(min((span - v * tr) / v, max_cruise), 0.0)
        segs += [(tr, a), (cruise, 0.0), (tr, -a), (hold, 0.0),
                 (tr, -a), (cruise, 0.0), (tr, a), (hold, 0.0)]
    return _centre(_from_segments(segs), q_center)


@dataclass(frozen=True, eq=False)
class MinJerkPath(Reference):
    """Minimum-jerk moves between ``waypoints`` (each move ``durations[i]`` s), each followed by
    a hold of ``hold`` s; a hold of ``hold`` s also precedes the first move."""

    waypoints: np.ndarray
    durations: np.ndarray
    hold: float = 0.5

    @property
    def duration(self) -> float:
        return float(np.sum(self.durations) + self.hold * len(self.durations) + self.hold)

    def sample(self, t):
        t = np.asarray(t, float)
        wp = np.asarray(self.waypoints, float)
        T = np.asarray(self.durations, float)
        starts = self.hold + np.concatenate([[0.0], np.cumsum(T + self.hold)[:-1]])
        q = np.full(t.shape, wp[0])
        qd = np.zeros(t.shape)
        qdd = np.zeros(t.shape)
        for i in range(T.size):  # loop over moves (few), vectorised over samples
            s = np.clip((t - starts[i]) / T[i], 0.0, 1.0)
            dq = wp[i + 1] - wp[i]
            after = t >= starts[i]
            pos = 10 * s ** 3 - 15 * s ** 4 + 6 * s ** 5
            vel = (30 * s ** 2 - 60 * s ** 3 + 30 * s ** 4) / T[i]
            acc = (60 * s - 180 * s ** 2 + 120 * s ** 3) / T[i] ** 2
            inside = after & (t <= starts[i] + T[i])
            q = np.where(after, wp[i] + dq * pos, q)
            qd = np.where(inside, dq * vel, qd)
            qdd = np.where(inside, dq * acc, qdd)
        return q, qd, qdd

    def to_dict(self):
        return {"type": "min_jerk", "duration": self.duration,
                "waypoints": np.asarray(self.waypoints).tolist(),
                "durations": np.asarray(self.durations).tolist(), "hold": self.hold}


def min_jerk_path(waypoints, vmax: float, amax: float, hold: float = 0.5) -> MinJerkPath:
    """Minimum-jerk moves through ``waypoints`` respecting peak speed and acceleration.

    Each move of ``dq`` lasts ``max(1.875 dq / vmax, sqrt(5.7735 dq / amax), 0.2)`` s, the
    peak speed and acceleration of the quintic ``10 s^3 - 15 s^4 + 6 s^5``.

    Parameters
    ----------
    waypoints : array_like
        Joint angles to pass through (rad), (P,).
    vmax, amax : float
        Peak speed (rad/s) and acceleration (rad/s^2).
    hold : float, optional
        Rest before the first move and after each (s).

    Returns
    -------
    MinJerkPath
        The trajectory.

    References
    ----------
    .. [1] Flash & Hogan 1985, the minimum-jerk model of point-to-point movements.
    .. [2] jointlab data format (docs/format.md), sec. Campaign format (trial kinds).

    Examples
    --------
    >>> path = min_jerk_path([0.0, 1.0, 0.0], vmax=1.0, amax=2.0)
    >>> path.durations.tolist(), path.duration
    ([1.875, 1.875], 5.25)
    >>> q, qd, qdd = path.sample(np.array([0.0, 0.5 + 1.875]))
    >>> q.tolist(), qd.tolist()
    ([0.0, 1.0], [0.0, 0.0])
    """
    wp = np.asarray(waypoints, float)
    dq = np.abs(np.diff(wp))
    T = np.maximum(np.maximum(1.875 * dq / vmax, np.sqrt(5.7735 * dq / amax)), 0.2)
    return MinJerkPath(wp, T, hold)
