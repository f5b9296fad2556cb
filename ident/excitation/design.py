"""Excitation design (thesis 002, eq. 3-1): a finite Fourier trajectory (eq. 3-2) for one joint
that minimises the condition number of the one-link regressor

    R = [qdd, -sin q, cos q, sign qd, qd]          (thesis, after eq. 2-5)

subject to ``q_lower <= q(t) <= q_upper``, ``|qd(t)| <= qd_limit``, ``|qdd(t)| <= qdd_limit``,
zero speed and acceleration at both ends of the period, and the peak speed equal to
``vmax_frac`` times the joint's maximum speed (the thesis's 100 %, 50 %, 25 % trajectories).

Parametrisation. The end conditions are linear: ``qd(0) = sum a_l = 0`` and
``qdd(0) = wf sum l b_l = 0`` (the series is periodic, so they also hold at ``t = T``); the
coefficients are ``a = Na u``, ``b = Nb w`` with ``Na``, ``Nb`` orthonormal null-space bases.
The peak speed fixes the scale: ``(a, b) <- s (a, b)`` with ``s = v_peak / max|qd|``. ``q0``
centres the motion in the joint range (or at ``q_center``). What is left, the direction of
``(u, w)``, is searched by Powell's method from ``n_starts`` seeded random directions, on
``log cond(R) + penalty`` (quadratic penalties for the position and acceleration limits,
evaluated on ``n_samples`` points of one period).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.linalg import null_space
from scipy.optimize import minimize

from ident.friction.base import CoulombViscous
from ident.model.onelink import onelink_regressor
from ident.signals.fourier import FourierSeries, design_matrix

__all__ = ["DesignLimits", "ExcitationDesign", "ExcitationDesigner", "regressor_cond",
           "limits_from_robot"]


@dataclass(frozen=True)
class DesignLimits:
    """Joint limits for the design (rad, rad/s, rad/s^2)."""

    q_lower: float
    q_upper: float
    qd_max: float
    qdd_max: float = float("inf")

    def __post_init__(self):
        if not self.q_upper > self.q_lower:
            raise ValueError(f"q_upper {self.q_upper} must exceed q_lower {self.q_lower}")
        if not self.qd_max > 0 or not self.qdd_max > 0:
            raise ValueError("speed and acceleration limits must be positive")


def regressor_cond(q, qd, qdd) -> float:
    """cond(R) of the thesis's one-link regressor ``[qdd, -sin q, cos q, sign qd, qd]`` [1]_.

    Parameters
    ----------
    q, qd, qdd : array_like
        Joint angle (rad), speed (rad/s) and acceleration (rad/s^2) samples, (T,).

    Returns
    -------
    float
        The 2-norm condition number of the (T, 5) regressor, the objective of eq. 3-1.

    References
    ----------
    .. [1] PA10 thesis (seeds 002), eq. 2-4, 2-5 and 3-1.

    Examples
    --------
    >>> t = np.linspace(0.0, 2.0 * np.pi, 200)
    >>> round(regressor_cond(np.sin(t), np.cos(t), -np.sin(t)), 1)
    57.9
    """
    R = np.hstack([onelink_regressor(q, qdd), CoulombViscous.regressor(qd)])
    return float(np.linalg.cond(R))


@dataclass(frozen=True, eq=False)
class ExcitationDesign:
    """A designed trajectory: the eq. 3-2 ``series`` and its diagnostics."""

    series: FourierSeries
    joint: int
    vmax_frac: float
    cond: float
    peak_speed: float
    max_acc: float
    q_min: float
    q_max: float
    feasible: bool
    limits: DesignLimits
    nfev: int
    n_starts: int

    @property
    def period(self) -> float:
        return self.series.period

    def trajectory(self, n: int | None = None, dt: float | None = None):
        """(t, q, qd, qdd) over one period: ``n`` samples or a step ``dt``.

        Parameters
        ----------
        n : int, optional
            Samples over the period (1001 by default).
        dt : float, optional
            Sample step (s), instead of ``n``.

        Returns
        -------
        t, q, qd, qdd : numpy.ndarray
            Times (s), angle (rad), speed (rad/s), acceleration (rad/s^2).
        """
        T = self.period
        t = np.arange(0.0, T + 1e-12, dt) if dt else np.linspace(0.0, T, n or 1001)
        q, qd, qdd = self.series.evaluate(t)
        return t, q, qd, qdd

    def to_dict(self) -> dict:
        s = self.series
        return {"format": 1, "equation": "thesis 3-1 / 3-2", "joint": self.joint,
                "vmax_frac": self.vmax_frac, "wf": float(s.wf), "period": float(self.period),
                "n_harmonics": s.n_harmonics, "q0": float(s.q0), "a": np.asarray(s.a).tolist(),
                "b": np.asarray(s.b).tolist(), "cond": self.cond, "peak_speed": self.peak_speed,
                "max_acc": self.max_acc, "q_min": self.q_min, "q_max": self.q_max,
                "feasible": self.feasible, "nfev": self.nfev, "n_starts": self.n_starts,
                "limits": {"q_lower": self.limits.q_lower, "q_upper": self.limits.q_upper,
                           "qd_max": self.limits.qd_max, "qdd_max": _f(self.limits.qdd_max)}}


def _f(x):
    return float(x) if np.isfinite(x) else None


class ExcitationDesigner:
    """Minimise cond(R) (eq. 3-1) over eq. 3-2 trajectories; see the module docstring.

    Settings: ``n_harmonics`` (N), ``period`` (s, ``wf = 2 pi / period``), ``n_samples`` per
    period for the constraints and ``R``, ``n_starts`` and ``seed`` for the multi-start,
    ``margin`` (fraction of the joint range kept free at each end), ``q_center`` (None:
    middle of the range), ``maxiter`` per start.

    Parameters
    ----------
    n_harmonics : int, optional
        Harmonics ``N`` of eq. 3-2 (at least 2).
    period : float, optional
        Period of the trajectory (s).
    n_samples : int, optional
        Samples per period for the constraints and ``R``.
    n_starts : int, optional
        Random starts of the search.
    seed : int, optional
        Seed of the starts.
    margin : float, optional
        Fraction of the joint range kept free at each end.
    q_center : float, optional
        Centre of the motion (rad); the middle of the range by default.
    maxiter : int, optional
        Iterations of Powell's method per start.

    References
    ----------
    .. [1] PA10 thesis (seeds 002), eq. 3-1 and 3-2.

    Examples
    --------
    A joint of +-1 rad, 2 rad/s and 10 rad/s^2, excited at half its speed:

    >>> limits = DesignLimits(q_lower=-1.0, q_upper=1.0, qd_max=2.0, qdd_max=10.0)
    >>> design = ExcitationDesigner(n_starts=2, seed=0).fit(limits, vmax_frac=0.5)
    >>> design.feasible, abs(design.peak_speed - 1.0) < 1e-3, design.cond < 10.0
    (True, True, True)
    >>> t, q, qd, qdd = design.trajectory(n=501)
    >>> bool(-1.0 <= q.min() and q.max() <= 1.0), round(float(abs(qd[0])), 9)
    (True, 0.0)
    """

    def __init__(self, n_harmonics: int = 5, period: float = 10.0, n_samples: int = 400,
                 n_starts: int = 8, seed: int = 0, margin: float = 0.05, q_center: float | None = None,
                 maxiter: int = 3000):
        if n_harmonics < 2:
            raise ValueError("n_harmonics must be >= 2 (the end conditions take two degrees of freedom)")
        self.n_harmonics = int(n_harmonics)
        self.period = float(period)
        self.n_samples = int(n_samples)
        self.n_starts = int(n_starts)
        self.seed = int(seed)
        self.margin = float(margin)
        self.q_center = q_center
        self.maxiter = int(maxiter)

    def _bases(self):
        N = self.n_harmonics
        Na = null_space(np.ones((1, N)))
        Nb = null_space(np.arange(1, N + 1, dtype=float)[None, :])
        return Na, Nb

    def _shapes(self, t, wf):
        """The eq. 3-2 design matrices of q, qd, qdd on the grid ``t`` (without the q0 column)."""
        return tuple(design_matrix(t, wf, self.n_harmonics, order)[:, 1:] for order in (0, 1, 2))

    def _build(self, x, limits, vmax_frac, Na, Nb, wf, shapes):
        """Coefficients for direction x: scaled to the peak speed, centred. ``shapes`` holds the
        per-harmonic sin/cos tables on the grid."""
        D0, D1, D2 = shapes                   # eq. 3-2 design matrices without the q0 column
        k = Na.shape[1]
        a, b = Na @ x[:k], Nb @ x[k:]
        qd = D1 @ np.concatenate([a, b])
        peak = float(np.max(np.abs(qd)))
        if peak < 1e-12:
            return None
        s = vmax_frac * limits.qd_max / peak
        a, b = s * a, s * b
        ab = np.concatenate([a, b])
        q_sh = D0 @ ab
        lo, hi = limits.q_lower, limits.q_upper
        centre = 0.5 * (lo + hi) if self.q_center is None else float(self.q_center)
        q0 = centre - 0.5 * (q_sh.max() + q_sh.min())
        q = q_sh + q0
        qdd = D2 @ ab
        return a, b, q0, q, s * qd, qdd

    def _objective(self, x, limits, vmax_frac, Na, Nb, wf, shapes):
        out = self._build(x, limits, vmax_frac, Na, Nb, wf, shapes)
        if out is None:
            return 1e6
        a, b, q0, q, qd, qdd = out
        lo, hi = limits.q_lower, limits.q_upper
        m = self.margin * (hi - lo)
        pen = np.sum(np.maximum(q - (hi - m), 0) ** 2) + np.sum(np.maximum((lo + m) - q, 0) ** 2)
        pen = pen / (hi - lo) ** 2
        if np.isfinite(limits.qdd_max):
            pen += np.sum(np.maximum(np.abs(qdd) - limits.qdd_max, 0) ** 2) / limits.qdd_max ** 2
        c = regressor_cond(q, qd, qdd)
        return float(np.log(c) + 1e3 * pen)

    def fit(self, limits: DesignLimits, vmax_frac: float = 1.0, joint: int = 0) -> ExcitationDesign:
        """Design the trajectory for ``limits`` at ``vmax_frac`` of the maximum speed.

        Parameters
        ----------
        limits : DesignLimits
            The joint's position, speed and acceleration limits.
        vmax_frac : float, optional
            Peak speed as a fraction of ``limits.qd_max``, in (0, 1].
        joint : int, optional
            Joint index recorded in the result.

        Returns
        -------
        ExcitationDesign
            The eq. 3-2 series, its cond(R), peak speed, acceleration, range and feasibility.
        """
        if not 0 < vmax_frac <= 1:
            raise ValueError(f"vmax_frac must be in (0, 1], got {vmax_frac}")
        N = self.n_harmonics
        wf = 2 * np.pi / self.period
        t = np.linspace(0.0, self.period, self.n_samples, endpoint=False)
        shapes = self._shapes(t, wf)
        Na, Nb = self._bases()
        rng = np.random.default_rng(self.seed)
        best, nfev = None, 0
        args = (limits, vmax_frac, Na, Nb, wf, shapes)
        for _ in range(self.n_starts):
            # decaying harmonic amplitudes: smoother starts are more often feasible
            x0 = rng.normal(size=Na.shape[1] + Nb.shape[1])
            res = minimize(self._objective, x0, args=args, method="Powell",
                           options={"maxiter": self.maxiter, "xtol": 1e-4, "ftol": 1e-6})
            nfev += int(res.nfev)
            if best is None or res.fun < best.fun:
                best = res
        a, b, q0, q, qd, qdd = self._build(best.x, *args)
        series = FourierSeries(a, b, wf, float(q0))
        # check on a finer grid than the optimisation used
        tf = np.linspace(0.0, self.period, 4 * self.n_samples + 1)
        qf, qdf, qddf = series.evaluate(tf)
        tol = 1e-6
        feasible = bool(qf.min() >= limits.q_lower - tol and qf.max() <= limits.q_upper + tol
                        and np.max(np.abs(qdf)) <= limits.qd_max * (1 + 1e-3)
                        and np.max(np.abs(qddf)) <= limits.qdd_max * (1 + 1e-3))
        return ExcitationDesign(series, int(joint), float(vmax_frac), regressor_cond(q, qd, qdd),
                                float(np.max(np.abs(qdf))), float(np.max(np.abs(qddf))),
                                float(qf.min()), float(qf.max()), feasible, limits, nfev, self.n_starts)


def limits_from_robot(robot, joint: int, qdd_max: float | None = None, q_rest=None) -> DesignLimits:
    """The position, speed and acceleration limits of one joint, from the robot.

    The constraints of the excitation design of thesis eq. 3-1 [1]_: position and speed from
    the URDF and ``drives.toml`` [2]_; acceleration ``qdd_max`` if given, else the drive's
    ``max_acceleration`` extra key, else half the torque limit over the link-side inertia
    ``I + J`` about the axis at ``q_rest`` (zeros).

    Parameters
    ----------
    robot : mocap.robot.Robot
        The robot (URDF and drives).
    joint : int
        Joint number, from 1.
    qdd_max : float, optional
        Acceleration limit (rad/s^2).
    q_rest : array_like, optional
        Configuration at which the inertia is taken (rad), (n,).

    Returns
    -------
    DesignLimits
        The limits for :meth:`ExcitationDesigner.fit`.

    Raises
    ------
    ValueError
        If ``joint`` is not one of the robot's joints.

    References
    ----------
    .. [1] PA10 thesis (seeds 002), eq. 3-1.
    .. [2] jointlab data format (docs/format.md), sec. robot/drives.toml.
    """
    j0 = joint - 1
    if not 0 <= j0 < robot.n:
        raise ValueError(f"joint {joint} is not in 1..{robot.n}")
    d = robot.drives[j0]
    if qdd_max is None:
        qdd_max = d.extra.get("max_acceleration") if isinstance(d.extra, dict) else None
    if qdd_max is None:
        q_rest = np.zeros(robot.n) if q_rest is None else np.asarray(q_rest, float)
        I = robot.single_joint_dynamics(j0, q_rest)[0]
        qdd_max = 0.5 * float(robot.max_torque[j0]) / (I + float(d.motor_inertia))
    lo, hi = float(robot.lower[j0]), float(robot.upper[j0])
    if not (np.isfinite(lo) and np.isfinite(hi)):
        lo, hi = -np.pi, np.pi
    return DesignLimits(lo, hi, float(robot.max_velocity[j0]), float(qdd_max))
