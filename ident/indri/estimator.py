"""The friction identification framework of Indri & Trapani 2020 (paper 001 in the seeds).

Pieces, in the order of the paper:

* residual torques ``tau_res = tau_m - tau_dm`` (eq. 25-26) from pinocchio's inverse dynamics
  without friction, for one joint moving alone (exact and vectorised, through
  :meth:`mocap.robot.Robot.single_joint_dynamics`) or several joints (RNEA);
* step 1, the static arctan model (eq. 1-2) by least squares with ``Kv = 1000`` and the delta
  grid [0, 100] step 0.1 (eq. 27-28): :func:`ident.friction.fit_arctan`, all grid values at once;
* step 2, the dynamic part (eq. 5-9) by prediction error on the exact discretisation
  (eq. 29-30, :class:`ident.friction.LuGreDM1` / :class:`ident.friction.LuGreDM2`):
  phase 2-A fits ``sigma0`` and a constant ``sigma1`` to each data set of reversals at one
  acceleration and reports its critical acceleration (eq. 22); phase 2-B fits ``alpha``,
  ``beta`` of eq. 23 by (non-negative) least squares over the ``sigma1`` trend (Figure 3), takes
  ``a_max / v_max`` from the fastest data set, fits ``gamma`` of eq. 24 by prediction error on a
  further, more varied acquisition, and keeps the ``sigma0`` of the slowest data set (DM2).
  DM1 (the paper's eq. 11 damping) is fitted by prediction error on the slowest data set;
* phase 2-C (jointlab's addition, :meth:`IndriTrapani.refine_damping`): eq. 24's alpha, beta
  (>= 0), gamma, its acceleration floor and the bristle's standstill relaxation by prediction
  error over every trial at once, each trial counting by its RMS ratio to the static model;
  the damping is shrunk so that no trial ends more than 5 % worse than the static model, and
  the bristle's static limit (sigma0 -> infinity, no damping) is a candidate too, so DM2
  reduces to the static model wherever the data do not support the bristle dynamics;
* performance indices RMS, M, IN of ``tau_res - tau_f`` and the relative errors Err% of
  Tables I-II, as CSV and Markdown; the torque time histories of Figures 2, 4 and 5 (PNG and
  through a :class:`viz.sink.Sink`);
* synthetic ground truth: :func:`simulate_reversal_datasets` and friends simulate a LuGre-type
  joint (any forward friction model, sampled 10x finer than the returned 1 kHz data).

Prediction error (phases 2-A and 2-B): for a fixed ``sigma0`` the bristle states follow from
the measured velocity alone (eq. 29-30, one vectorised linear scan) and the torque is linear in
the damping coefficients, so the search is one-dimensional in ``log sigma0`` (a coarse grid,
then :func:`ident.friction.fit_friction` refines from the best grid point and supplies the
standard errors); ``gamma`` does not change the states at all, so its search reuses one scan.

Discretisation (tests/test_indri.py): with the paper's eq. 29 the velocity is held over each
sample, so on a joint whose velocity ramps within the sample the discrete state lags the
continuous one by about Ts/2 and a constant-sigma1 fit returned ``sigma1 + sigma0 Ts/2``; with a
stiff bristle the lag became one sample and the damping term a spike at every velocity change.
The models use the first-order hold of :mod:`ident.friction.dynamic` by default (``hold``),
which has neither defect; the C export implements the same step.
"""
from __future__ import annotations

import csv
import io
import json
import time as _time
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from ident.common import to_jsonable as _jsonable
from scipy.optimize import minimize_scalar, nnls

from ident.friction import Arctan, FrictionFit, FrictionModel, LuGreDM1, LuGreDM2, fit_arctan, fit_friction
from ident.friction.constants import KV_DEFAULT

PI_NAMES = ("RMS", "M", "IN")


# ============================================================================================
# data
# ============================================================================================
@dataclass(frozen=True, eq=False)
class FrictionData:
    """One joint's acquisition, time first: ``time`` (T,) s, ``qd`` (T,) rad/s, ``qdd`` (T,)
    rad/s^2 and the residual torque ``tau`` (T,) N m (eq. 25). ``accel``: the nominal reversal
    acceleration of a phase 2-A data set (None: taken from the signal)."""

    time: np.ndarray
    qd: np.ndarray
    qdd: np.ndarray
    tau: np.ndarray
    label: str = ""
    accel: float | None = None
    truth: np.ndarray | None = field(default=None, repr=False)   # noise-free friction (synthetic)

    def __post_init__(self):
        t = np.asarray(self.time, float)
        for name in ("qd", "qdd", "tau"):
            a = np.asarray(getattr(self, name), float)
            if a.shape != t.shape or a.ndim != 1:
                raise ValueError(f"FrictionData {self.label!r}: {name} has shape {a.shape}, "
                                 f"time has {t.shape} (both must be (T,))")
            bad = ~np.isfinite(a)
            if bad.any():
                raise ValueError(f"FrictionData {self.label!r}: {name} is not finite at sample "
                                 f"{int(np.argmax(bad))}")
        if t.size < 3 or np.any(np.diff(t) <= 0):
            raise ValueError(f"FrictionData {self.label!r}: time must be strictly increasing with "
                             "at least 3 samples")

    @property
    def dt(self) -> np.ndarray:
        """The (T-1,) sample steps (the exact discretisation accepts uneven steps)."""
        return np.diff(np.asarray(self.time, float))

    @property
    def n(self) -> int:
        return int(np.asarray(self.time).shape[0])

    @property
    def reversal_accel(self) -> float:
        """``accel`` if given, else the 99th percentile of |qdd| (robust maximum)."""
        if self.accel is not None:
            return float(self.accel)
        return float(np.percentile(np.abs(self.qdd), 99.0))

    @property
    def v_max(self) -> float:
        return float(np.max(np.abs(self.qd)))


# ============================================================================================
# eq. 25-26: residual torques
# ============================================================================================
def residual_torques(robot, q, qd, qdd, tau_m, *, joint: int | None = None,
                     still_tol: float = 1e-9) -> np.ndarray:
    """Indri & Trapani eq. 25-26: ``tau_res = tau_m - tau_dm``, ``tau_dm = M(q) qdd + C(q, qd) qd
    + g(q)`` from the URDF without friction (link side: the gear ratio ``K_tr`` of eq. 26 is
    already folded into ``tau_m``, FORMAT.md).

    ``q``, ``qd``, ``qdd``, ``tau_m``: (T, n). With ``joint`` (0-based) returns that joint's
    (T,) residual; when every other joint is still (its q varies less than ``still_tol`` and
    its qd, qdd are within ``still_tol``) the exact single-joint form ``I qdd + a sin q + b cos q``
    is used (vectorised; Coriolis and centrifugal terms on the moving joint vanish), otherwise
    pinocchio's RNEA. Without ``joint``: the full (T, n) residual by RNEA.
    """
    q, qd, qdd, tau_m = (np.atleast_2d(np.asarray(a, float)) for a in (q, qd, qdd, tau_m))
    n = robot.n
    for name, a in (("q", q), ("qd", qd), ("qdd", qdd), ("tau_m", tau_m)):
        if a.ndim != 2 or a.shape[1] != n or a.shape[0] != q.shape[0]:
            raise ValueError(f"residual_torques: {name} must be (T, {n}) with T = {q.shape[0]}, "
                             f"got {a.shape}")
    if joint is not None:
        if not 0 <= joint < n:
            raise ValueError(f"residual_torques: joint must be in 0..{n - 1}, got {joint}")
        others = np.arange(n) != joint
        still = (np.all(np.ptp(q[:, others], axis=0) <= still_tol)
                 and np.all(np.abs(qd[:, others]) <= still_tol)
                 and np.all(np.abs(qdd[:, others]) <= still_tol))
        if still:
            I, a, b = robot.single_joint_dynamics(joint, q[0])
            qj = q[:, joint]
            return tau_m[:, joint] - (I * qdd[:, joint] + a * np.sin(qj) + b * np.cos(qj))
        return tau_m[:, joint] - robot.rnea(q, qd, qdd).reshape(q.shape)[:, joint]
    return tau_m - robot.rnea(q, qd, qdd).reshape(q.shape)


def friction_data_from_signals(sig, robot, q_rest, *, accel: float | None = None,
                               label: str = "", subtract_motor_viscous: bool = False,
                               velocity: str = "motor") -> FrictionData:
    """One trial's joint as :class:`FrictionData` for the framework (eq. 25-26).

    ``sig``: an :class:`ident.signals.smoothing.JointSignals` (joint 1-based, link-side q/qd/qdd, motor-side
    qm/qmd/qmdd, motor torque tau); ``robot``: :class:`mocap.robot.Robot`; ``q_rest`` (n,): the
    angles of the braked joints. The residual is ``tau - tau_dm - J qmdd`` (the rotor inertia
    ``J`` of the drive belongs to the dynamic model of eq. 26) and, with
    ``subtract_motor_viscous``, ``- B qmd``; the friction velocity ``v`` is the motor velocity
    (link side), as in the paper; ``velocity="link"``: the link velocity and acceleration
    ``sig.qd``, ``sig.qdd`` instead (a flexible joint whose friction acts on the link: the
    link state of the encoder plus the declared spring's deflection, see
    :func:`ident.indri.campaign.joint_dynamic_data`)."""
    if velocity not in ("motor", "link"):
        raise ValueError(f"velocity must be 'motor' or 'link', got {velocity!r}")
    j0 = int(sig.joint) - 1
    n = robot.n
    T = np.asarray(sig.time).shape[0]
    q = np.tile(np.asarray(q_rest, float), (T, 1))
    if q.shape != (T, n):
        raise ValueError(f"q_rest must have {n} angles, got {np.shape(q_rest)}")
    qd = np.zeros((T, n))
    qdd = np.zeros((T, n))
    q[:, j0], qd[:, j0], qdd[:, j0] = sig.q, sig.qd, sig.qdd
    tau = np.zeros((T, n))
    tau[:, j0] = sig.tau
    res = residual_torques(robot, q, qd, qdd, tau, joint=j0)
    drive = robot.drives[j0]
    res = res - drive.motor_inertia * np.asarray(sig.qmdd, float)
    if subtract_motor_viscous:
        res = res - drive.motor_viscous * np.asarray(sig.qmd, float)
    v, a = (sig.qmd, sig.qmdd) if velocity == "motor" else (sig.qd, sig.qdd)
    return FrictionData(np.asarray(sig.time, float), np.asarray(v, float),
                        np.asarray(a, float), res, label=label, accel=accel)


# ============================================================================================
# synthetic ground truth: profiles and a LuGre-type joint
# ============================================================================================
def piecewise_linear_velocity(knots_t, knots_v, dt: float):
    """Sample a piecewise-linear velocity (knots (K,)) every ``dt``: ``(t, qd, qdd)``; qdd is
    the slope of the segment a sample lies in (the right one at a knot)."""
    kt = np.asarray(knots_t, float)
    kv = np.asarray(knots_v, float)
    if kt.ndim != 1 or kt.shape != kv.shape or kt.size < 2 or np.any(np.diff(kt) <= 0):
        raise ValueError("knots_t must be strictly increasing and match knots_v")
    n = int(np.floor((kt[-1] - kt[0]) / dt + 1e-9)) + 1
    t = kt[0] + dt * np.arange(n)
    qd = np.interp(t, kt, kv)
    slope = np.diff(kv) / np.diff(kt)
    seg = np.clip(np.searchsorted(kt, t, side="right") - 1, 0, slope.size - 1)
    return t, qd, slope[seg]


def reversal_knots(accel: float, vmax: float, n_cycles: int = 3, cruise: float = 0.5):
    """Knots of a cyclic motion between two points (phase 2-A): start at rest, reach +vmax,
    then ``n_cycles`` reversals +vmax -> -vmax -> +vmax at ``accel``, each speed held for
    ``cruise`` s, and back to rest."""
    if not (accel > 0 and vmax > 0 and cruise >= 0 and n_cycles >= 1):
        raise ValueError("reversal_knots: accel, vmax > 0, cruise >= 0, n_cycles >= 1")
    tr = vmax / accel
    kt, kv = [0.0, tr], [0.0, vmax]
    sign = 1.0
    for _ in range(2 * n_cycles):
        kt += [kt[-1] + cruise, kt[-1] + cruise + 2 * tr]
        kv += [sign * vmax, -sign * vmax]
        sign = -sign
    kt += [kt[-1] + cruise, kt[-1] + cruise + tr]
    kv += [sign * vmax, 0.0]
    return np.array(kt), np.array(kv)


def random_knots(duration: float, v_range, a_range, hold_range=(0.1, 0.6), seed: int = 0,
                 p_reverse: float = 0.6):
    """Knots of a random test profile (Tables I-II): successive target speeds drawn in
    ``v_range`` (magnitude, log-uniform) with a sign change with probability ``p_reverse``,
    reached at an acceleration drawn in ``a_range`` and held for a time in ``hold_range``."""
    rng = np.random.default_rng(seed)
    kt, kv = [0.0], [0.0]
    sign = 1.0
    while kt[-1] < duration:
        v = sign * np.exp(rng.uniform(np.log(v_range[0]), np.log(v_range[1])))
        a = np.exp(rng.uniform(np.log(a_range[0]), np.log(a_range[1])))
        kt.append(kt[-1] + abs(v - kv[-1]) / a + 1e-9)
        kv.append(v)
        kt.append(kt[-1] + rng.uniform(*hold_range))
        kv.append(v)
        if rng.uniform() < p_reverse:
            sign = -sign
    a = a_range[1]
    kt.append(kt[-1] + abs(kv[-1]) / a + 1e-9)
    kv.append(0.0)
    return np.array(kt), np.array(kv)


TEST_PROFILES = {
    # name: (speed range rad/s, acceleration range rad/s^2) at the scale of a ~2 rad/s joint
    "random": ((0.02, 2.0), (2.0, 40.0)),
    "medium": ((0.2, 1.0), (0.5, 8.0)),
    "low": ((0.005, 0.05), (0.05, 0.5)),
}


def test_profile_knots(kind: str, duration: float = 10.0, seed: int = 0):
    """Knots of the random / medium / low speed test profiles of Table I (see TEST_PROFILES)."""
    if kind not in TEST_PROFILES:
        raise ValueError(f"unknown test profile {kind!r}; choose from {sorted(TEST_PROFILES)}")
    v_range, a_range = TEST_PROFILES[kind]
    hold = (0.1, 0.6) if kind != "low" else (0.3, 1.5)
    return random_knots(duration, v_range, a_range, hold_range=hold, seed=seed)


test_profile_knots.__test__ = False          # not a pytest test


def figure1_knots(slow: float = 15.0, vmax: float = 1.5, accels=(2.0, 5.0, 10.0, 20.0, 40.0)):
    """Knots like the paper's Figure 1: ``slow`` seconds of very low, slowly growing speed
    reversals (the conditions of the dynamic identification), then reversals at increasing
    accelerations up to ``vmax``."""
    kt, kv = [0.0], [0.0]
    n_slow = 6
    for i in range(n_slow):
        v = 0.01 * (i + 1) * (1 if i % 2 == 0 else -1)
        kt += [kt[-1] + slow / n_slow * 0.5, kt[-1] + slow / n_slow]
        kv += [v, v]
    for a in accels:
        for s in (1.0, -1.0):
            kt += [kt[-1] + abs(s * vmax - kv[-1]) / a, kt[-1] + abs(s * vmax - kv[-1]) / a + 0.6]
            kv += [s * vmax, s * vmax]
    kt.append(kt[-1] + vmax / accels[-1])
    kv.append(0.0)
    return np.array(kt), np.array(kv)


def static_knots(speeds=None, accel: float = 20.0, settle_disp: float = 0.08,
                 min_hold: float = 0.3):
    """Knots of a step-1 acquisition (sec. III-A): constant-speed runs at many speeds, both
    directions, denser at low speed; each held long enough to cover ``settle_disp`` rad."""
    speeds = np.geomspace(0.01, 2.0, 12) if speeds is None else np.asarray(speeds, float)
    kt, kv = [0.0], [0.0]
    for v in speeds:
        for s in (1.0, -1.0):
            tgt = s * v
            kt.append(kt[-1] + abs(tgt - kv[-1]) / accel)
            kv.append(tgt)
            kt.append(kt[-1] + max(min_hold, 2.0 * settle_disp / v))
            kv.append(tgt)
    kt.append(kt[-1] + abs(kv[-1]) / accel)
    kv.append(0.0)
    return np.array(kt), np.array(kv)


def simulate_friction(model: FrictionModel, knots, dt: float = 1e-3, *, noise_std: float = 0.0,
                      seed: int = 0, oversample: int = 10, label: str = "",
                      accel: float | None = None) -> FrictionData:
    """Residual torque of a joint whose friction is ``model`` (any forward model; dynamic ones
    through their exact discretisation) along the piecewise-linear velocity ``knots``, computed
    ``oversample`` times finer than ``dt`` and sampled every ``dt``, plus white noise of
    ``noise_std`` N m (seeded). The noise-free torque is kept in ``truth``."""
    if oversample < 1:
        raise ValueError("oversample must be >= 1")
    kt, kv = knots
    t, qd, qdd = piecewise_linear_velocity(kt, kv, dt / oversample)
    tau = model.torque(qd, qdd, dt / oversample) if model.dynamic else model.torque(qd)
    t, qd, qdd, tau = t[::oversample], qd[::oversample], qdd[::oversample], tau[::oversample]
    rng = np.random.default_rng(seed)
    noisy = tau + noise_std * rng.standard_normal(tau.shape)
    return FrictionData(t, qd, qdd, noisy, label=label, accel=accel, truth=tau)


def simulate_reversal_datasets(model: FrictionModel, accels=(2.0, 4.0, 8.0, 12.0, 16.0, 20.0),
                               vmax: float = 1.5, dt: float = 1e-3, *, n_cycles: int = 2,
                               cruise: float = 0.4, noise_std: float = 0.0, seed: int = 0,
                               oversample: int = 10) -> list[FrictionData]:
    """Phase 2-A acquisitions (sec. III-B): one data set of cyclic reversals per acceleration of
    ``accels`` (rad/s^2) at top speed ``vmax``, simulated with ``model`` (see
    :func:`simulate_friction`); data set ``i`` uses the noise seed ``(seed, i)``."""
    out = []
    for i, a in enumerate(accels):
        ss = int(np.random.SeedSequence([seed, i]).generate_state(1)[0])
        out.append(simulate_friction(model, reversal_knots(a, vmax, n_cycles, cruise), dt,
                                     noise_std=noise_std, seed=ss, oversample=oversample,
                                     label=f"reversals-a{a:g}", accel=float(a)))
    return out


def steady_mask(data: FrictionData, settle_disp: float = 0.03,
                accel_tol: float | None = None) -> np.ndarray:
    """Samples of constant speed (|qdd| <= ``accel_tol``; None: 2% of the 99th percentile of
    |qdd|) after the joint has moved ``settle_disp`` rad since the last acceleration phase (the
    bristle transient is over): the step-1 samples (sec. III-A)."""
    qd = np.asarray(data.qd, float)
    aq = np.abs(np.asarray(data.qdd, float))
    tol = 0.02 * float(np.percentile(aq, 99.0)) if accel_tol is None else float(accel_tol)
    cruise = aq <= tol
    disp = np.concatenate([[0.0], np.cumsum(np.abs(qd[:-1]) * data.dt)])
    idx = np.arange(qd.size)
    start = np.maximum.accumulate(np.where(~cruise, idx, 0))
    return cruise & (disp - disp[start] >= settle_disp) & (np.abs(qd) > 0)


def concat_data(datas, label: str = "") -> FrictionData:
    """Join acquisitions end to end (times shifted to follow each other, one median step apart),
    e.g. several constant-speed trials for step 1. Only for step 1: the bristle state of a dynamic
    model is not continuous across the joins."""
    datas = list(datas)
    if not datas:
        raise ValueError("concat_data: nothing to join")
    ts, t_end = [], None
    for d in datas:
        t = np.asarray(d.time, float)
        t = t - t[0] if t_end is None else t - t[0] + t_end + float(np.median(d.dt))
        ts.append(t)
        t_end = t[-1]
    cat = [np.concatenate([np.asarray(getattr(d, k), float) for d in datas])
           for k in ("qd", "qdd", "tau")]
    truth = (np.concatenate([d.truth for d in datas])
             if all(d.truth is not None for d in datas) else None)
    return FrictionData(np.concatenate(ts), *cat, label=label or "+".join(d.label for d in datas),
                        truth=truth)


# ============================================================================================
# identification
# ============================================================================================
@dataclass(frozen=True, eq=False)
class Phase2AFit:
    """Phase 2-A on one data set: sigma0 and a constant sigma1 (or another DM1 damping) by
    prediction error, with the critical acceleration of eq. 22 at the data set's top speed."""

    label: str
    accel: float                  # reversal acceleration, rad/s^2
    v_max: float                  # top speed, rad/s
    fit: FrictionFit
    v_m: float                    # the "not negligible" speed of eq. 15-22, rad/s
    critical_accel: float         # eq. 22 at v_m
    grid_rss: np.ndarray = field(repr=False)   # the coarse log-sigma0 profile (diagnostic)

    @property
    def sigma0(self) -> float:
        return self.fit.model.sigma0

    @property
    def sigma1(self) -> float:
        return self.fit.model.sigma1

    @property
    def above_critical(self) -> bool:
        return self.accel >= self.critical_accel

    def to_dict(self) -> dict:
        return {"label": self.label, "accel": self.accel, "v_max": self.v_max,
                "sigma0": self.sigma0, "sigma1": self.sigma1,
                "stderr": {k: self.fit.stderr[k] for k in ("sigma0", "sigma1")},
                "rms": self.fit.rms, "cond": self.fit.cond, "n": self.fit.n,
                "v_m": self.v_m, "critical_accel": self.critical_accel,
                "above_critical": self.above_critical,
                "damping": self.fit.model.damping, "degenerate": self.fit.degenerate}


@dataclass(frozen=True, eq=False)
class IndriResult:
    """The complete two-step identification: static (step 1), phase 2-A per data set, phase 2-B
    (alpha, beta, a_max/v_max, gamma, sigma0) and the DM1 comparison model."""

    static: FrictionFit
    phase2a: tuple
    alpha: float
    beta: float
    accel_ratio: float
    gamma: float
    sigma0: float
    dm1: FrictionFit
    trend_rms: float               # RMS of sigma1 - (alpha/|a| + beta) over the data sets
    trend_r2: float                # its coefficient of determination
    gamma_rms: float               # prediction-error RMS on the phase 2-B data set, N m
    gamma_stderr: float
    gamma_grid: np.ndarray = field(repr=False)
    gamma_grid_rss: np.ndarray = field(repr=False)
    diagnostics: dict = field(default_factory=dict)
    trend_alpha: float | None = None   # eq. 23 over the phase 2-A trend (None: = alpha)
    trend_beta: float | None = None
    refinement: dict | None = None     # phase 2-C (prediction error on every data set)
    stiffness: float | None = None     # declared transmission stiffness K (drives.toml)
    phase2a_link: tuple = ()           # phase 2-A on the link velocity (K declared)

    @property
    def sigma0_bristle(self) -> float | None:
        """The bristle's own stiffness, behind the declared spring: phase 2-A's sigma0 of the
        slowest data set on the link velocity (inf when it is at the stiff end of its search:
        no bristle, the spring alone); None without a declared stiffness. ``sigma0`` (the
        DM2's, on the motor velocity) is the apparent one, the bristle in series with the
        spring as the motor encoder sees them."""
        if self.stiffness is None or not self.phase2a_link:
            return None
        if (self.refinement or {}).get("bristle") == "declared spring":
            return float("inf")
        return float(self.phase2a_link[self._slowest].sigma0)

    @property
    def sigma0_series_corrected(self) -> float | None:
        """The motor-side sigma0 corrected by the series law ``1/(1/sigma0 - 1/K)`` (inf when
        sigma0 >= K); exact only where the bristle's local stiffness is sigma0 (z = 0: LuGre's
        ``sigma0 (1 - sigma0 z sgn(v)/g)`` runs from 2 sigma0 to 0 over a reversal), so it
        is reported beside :attr:`sigma0_bristle` as a check, not used."""
        if self.stiffness is None:
            return None
        k = 1.0 / self.sigma0 - 1.0 / self.stiffness
        return float(1.0 / k) if k > 0 else float("inf")

    @property
    def sigma1_trend(self) -> tuple:
        """(alpha, beta) of eq. 23 fitted to the phase 2-A sigma1 values (Figure 3)."""
        return (self.alpha if self.trend_alpha is None else self.trend_alpha,
                self.beta if self.trend_beta is None else self.trend_beta)

    @property
    def dm2(self) -> LuGreDM2:
        extra = {} if self.refinement is None else {
            "accel_floor": self.refinement["accel_floor"],
            "rest_speed": self.refinement["rest_speed"]}
        return LuGreDM2(static=self.static.model, accel_ratio=self.accel_ratio, sigma0=self.sigma0,
                        alpha=self.alpha, beta=self.beta, gamma=self.gamma, **extra)

    @property
    def models(self) -> dict:
        """The three models of Tables I-II: ``{"DM2": ..., "DM1": ..., "SM": ...}``."""
        return {"DM2": self.dm2, "DM1": self.dm1.model, "SM": self.static.model}

    def fits_json(self) -> dict:
        """fits.json entries of one joint (FORMAT.md): ``{"arctan": ..., "dm1": ..., "dm2": ...}``."""
        dm2 = {"params": self.dm2.params,
               "stderr": {"sigma0": (self.phase2a[self._slowest].fit.stderr["sigma0"]
                                     if self.sigma0 == self.phase2a[self._slowest].sigma0
                                     and (self.refinement or {}).get("bristle_resolved", True)
                                     else None),
                          "alpha": (self.diagnostics.get("alpha_stderr") if self.refinement is None
                                    else None),
                          "beta": (self.diagnostics.get("beta_stderr") if self.refinement is None
                                   else None),
                          "gamma": self.gamma_stderr},
               "rms": self.gamma_rms, "model": "dm2",
               "settings": {"accel_ratio": self.accel_ratio, "accel_floor": self.dm2.accel_floor,
                            "rest_speed": self.dm2.rest_speed,
                            "static": self.static.model.to_dict(),
                            "stiffness": self.stiffness,
                            "bristle": (self.refinement or {}).get("bristle", "identified"),
                            "sigma0_apparent": self.sigma0,
                            "sigma0_bristle": self.sigma0_bristle,
                            "sigma0_bristle_stderr": (
                                self.phase2a_link[self._slowest].fit.stderr["sigma0"]
                                if self.sigma0_bristle is not None
                                and np.isfinite(self.sigma0_bristle) else None),
                            "sigma0_series_corrected": self.sigma0_series_corrected}}
        return {"arctan": self.static.to_dict(), "dm1": self.dm1.to_dict(), "dm2": _jsonable(dm2)}

    @property
    def _slowest(self) -> int:
        return int(np.argmin([p.accel for p in self.phase2a]))

    def to_dict(self) -> dict:
        return _jsonable({
            "static": self.static.to_dict(),
            "phase2a": [p.to_dict() for p in self.phase2a],
            "phase2b": {"alpha": self.alpha, "beta": self.beta, "accel_ratio": self.accel_ratio,
                        "gamma": self.gamma, "gamma_stderr": self.gamma_stderr,
                        "sigma0": self.sigma0, "trend_rms": self.trend_rms,
                        "trend_r2": self.trend_r2, "gamma_rms": self.gamma_rms,
                        "alpha_stderr": self.diagnostics.get("alpha_stderr"),
                        "beta_stderr": self.diagnostics.get("beta_stderr"),
                        "trend_alpha": self.sigma1_trend[0], "trend_beta": self.sigma1_trend[1]},
            "phase2c": self.refinement,
            "stiffness": self.stiffness, "sigma0_bristle": self.sigma0_bristle,
            "sigma0_series_corrected": self.sigma0_series_corrected,
            "phase2a_link": [p.to_dict() for p in self.phase2a_link],
            "dm1": self.dm1.to_dict(), "dm2": self.dm2.to_dict(),
            "diagnostics": self.diagnostics})


class _Counter:
    def __init__(self):
        self.n = 0
        self.samples = 0


class IndriTrapani:
    """The two-step identification of Indri & Trapani sec. III (settings here, learning in
    :meth:`fit`).

    ``Kv``, ``delta_grid``: step 1 (eq. 27-28; default grid [0, 100] step 0.1).
    ``deflection_range``: the steady bristle deflections ``g/sigma0`` (rad) searched in phase
    2-A, i.e. ``sigma0`` in ``[g/hi, g/lo]``; ``n_grid`` log-spaced points, then a bounded
    least-squares refinement. ``gamma_range``, ``n_gamma``: the same for gamma of eq. 24.
    ``dm1_damping``: the damping of the DM1 comparison model (the paper's eq. 11).
    ``static_settle``: displacement (rad) after which a constant-speed sample is steady (step 1).
    ``critical_speed``: the speed ``v_m`` of eq. 22 (a "not negligible" speed with
    ``S0(v_m) ~ 1``); None: the speed where ``S0 = 0.99``, i.e. ``tan(0.99 pi/2) / Kv``.
    ``refine``: run phase 2-C (:meth:`refine_damping`, jointlab's addition) when
    :meth:`fit` is given the data sets to check on; False: the paper's alpha, beta, gamma.
    ``select_static``: step 1 chooses between the arctan model and the same without the
    Stribeck term (:meth:`_select_static`, jointlab's addition); False: the paper's fit alone.
    """

    def __init__(self, *, Kv: float = KV_DEFAULT, delta_grid=None, deflection_range=(1e-7, 0.3),
                 n_grid: int = 20, gamma_range=(1e-3, 1e3), n_gamma: int = 25,
                 dm1_damping: str = "eq11", static_settle: float = 0.03,
                 critical_speed: float | None = None, refine: bool = True,
                 select_static: bool = True):
        if dm1_damping not in LuGreDM1.DAMPING:
            raise ValueError(f"dm1_damping must be one of {LuGreDM1.DAMPING}")
        if not (0 < deflection_range[0] < deflection_range[1]):
            raise ValueError("deflection_range must be 0 < lo < hi")
        if not (0 < gamma_range[0] < gamma_range[1]):
            raise ValueError("gamma_range must be 0 < lo < hi")
        if n_grid < 3 or n_gamma < 3:
            raise ValueError("n_grid and n_gamma must be >= 3")
        self.Kv = float(Kv)
        self.delta_grid = delta_grid
        self.deflection_range = tuple(map(float, deflection_range))
        self.n_grid = int(n_grid)
        self.gamma_range = tuple(map(float, gamma_range))
        self.n_gamma = int(n_gamma)
        self.dm1_damping = dm1_damping
        self.static_settle = float(static_settle)
        if critical_speed is not None and not critical_speed > 0:
            raise ValueError("critical_speed must be positive")
        self.critical_speed = (float(np.tan(0.99 * np.pi / 2) / self.Kv) if critical_speed is None
                               else float(critical_speed))
        self.refine = bool(refine)
        self.select_static = bool(select_static)

    # ---- step 1 ---------------------------------------------------------------------------
    def fit_static(self, data: FrictionData, mask=None) -> FrictionFit:
        """Step 1 (eq. 27-28) on the steady samples of ``data`` (``mask`` or
        :func:`steady_mask`)."""
        m = steady_mask(data, self.static_settle) if mask is None else np.asarray(mask, bool)
        if m.sum() < 10:
            raise ValueError(f"step 1: only {int(m.sum())} steady constant-speed samples in "
                             f"{data.label!r}; need constant-speed runs")
        qd, tau = np.asarray(data.qd)[m], np.asarray(data.tau)[m]
        full = fit_arctan(qd, tau, Kv=self.Kv, delta_grid=self.delta_grid)
        if not self.select_static:
            return full
        return self._select_static(full, fit_arctan(qd, tau, Kv=self.Kv, delta_grid=[0.0]))

    @staticmethod
    def _select_static(full: FrictionFit, plain: FrictionFit) -> FrictionFit:
        """Step 1's model choice (jointlab's addition to sec. III-A): the paper's arctan model
        (``full``) or the same without the Stribeck term (``plain``: delta = 0, tau_sc = 0),
        by Schwarz's criterion ``n ln(RSS/n) + k ln n`` (k = 5 or 3) among the physically
        possible ones: a negative viscous coefficient ``tau_v`` is not (the viscous friction of
        the lubricant opposes the motion at every speed). The rejected candidate and the reason
        go to the diagnostics (``static_choice``); when neither is possible the full fit is
        kept with a flag.

        Why: ``tau_sc 2/pi arctan(delta v)`` with a small delta is nearly ``tau_sc 2 delta v /
        pi``, so on a joint without a Stribeck drop tau_sc, tau_v and tau_nlv trade against
        each other at the noise level; on jointlab synth (Coulomb + viscous 0.99, six speed
        levels 0.12-2.4 rad/s, level means within 0.005 N m of the truth) the paper's fit
        chose tau_sc 5.1, delta 0.5, tau_v -0.80, tau_nlv 0.24: the same curve within the
        noise over the speeds logged, physically impossible, and a different static curve
        g(v) for the dynamic models."""
        def bic(f):
            n = max(f.n, 1)
            k = 5 if f is full else 3
            return n * np.log(max(f.rms, 1e-300) ** 2) + k * np.log(n)

        def valid(f):
            return f.model.params["tau_v"] >= 0
        cands = [f for f in (full, plain) if valid(f)]
        if not cands:
            return replace(full, flags=tuple(full.flags) + (
                f"tau_v = {full.model.params['tau_v']:.3g} < 0: a negative viscous coefficient "
                "is physically impossible (with and without the Stribeck term)",),
                diagnostics={**full.diagnostics, "static_choice": {
                    "chosen": "full", "reason": "no physically possible candidate",
                    "bic_full": bic(full), "bic_no_stribeck": bic(plain)}})
        best = min(cands, key=bic)
        other = plain if best is full else full
        why = ("negative viscous coefficient" if not valid(other)
               else "larger Schwarz criterion")
        info = {"chosen": "full" if best is full else "no_stribeck",
                "rejected": "no_stribeck" if best is full else "full",
                "reason": f"rejected: {why}", "bic_full": bic(full), "bic_no_stribeck": bic(plain),
                "rejected_params": other.model.params}
        return replace(best, diagnostics={**best.diagnostics, "static_choice": info})

    # ---- phase 2-A --------------------------------------------------------------------------
    def _sigma0_bounds(self, static: Arctan, data: FrictionData):
        g = static.g(np.array([0.0, data.v_max]))
        gmin, gmax = float(np.min(g)), float(np.max(g))
        if gmin <= 0:
            raise ValueError("the static curve g(v) must be positive for the dynamic model")
        return gmin / self.deflection_range[1], gmax / self.deflection_range[0]

    def fit_dm1(self, static: Arctan, data: FrictionData, damping: str = "constant",
                counter: _Counter | None = None) -> Phase2AFit:
        """Prediction-error fit of (sigma0, sigma1) of eq. 5-9 with the DM1 ``damping`` to one
        data set: a log grid over sigma0 (sigma1 by linear least squares for each), then
        :func:`ident.friction.fit_friction` from the best grid point within its neighbours."""
        counter = counter or _Counter()
        qd, qdd, tau, dt = (np.asarray(data.qd, float), np.asarray(data.qdd, float),
                            np.asarray(data.tau, float), data.dt)
        lo, hi = self._sigma0_bounds(static, data)
        grid = np.geomspace(lo, hi, self.n_grid)
        rss = np.empty(grid.size)
        for i, s in enumerate(grid):              # loop over the (few) grid values
            m = LuGreDM1(static=static, damping=damping, sigma0=s, sigma1=0.0)
            Phi, off = m.linear_design(qd, qdd, dt)
            counter.n += 1
            counter.samples += qd.size
            y = tau - off
            c, *_ = np.linalg.lstsq(Phi, y, rcond=None)
            r = y - Phi @ c
            rss[i] = r @ r
        i = int(np.argmin(rss))
        blo, bhi = grid[max(i - 2, 0)], grid[min(i + 2, grid.size - 1)]
        if blo == bhi:
            bhi = blo * 1.0001
        fit = fit_friction(LuGreDM1, qd, tau, qdd=qdd, dt=dt, n_starts=1,
                           x0={"sigma0": float(grid[i])}, bounds={"sigma0": (blo, bhi)},
                           settings={"static": static, "damping": damping})
        counter.n += fit.nfev + 4                 # fit_friction: nfev + Jacobian + final + rms
        counter.samples += (fit.nfev + 4) * qd.size
        crit = float(fit.model.critical_acceleration(self.critical_speed))
        return Phase2AFit(label=data.label, accel=data.reversal_accel, v_max=data.v_max, fit=fit,
                          v_m=self.critical_speed, critical_accel=crit, grid_rss=rss)

    def phase_2a(self, static: Arctan, datasets, counter: _Counter | None = None) -> tuple:
        """Phase 2-A: constant-sigma1 LuGre fits, one per reversal data set (Figure 3)."""
        return tuple(self.fit_dm1(static, d, "constant", counter) for d in datasets)

    # ---- phase 2-B --------------------------------------------------------------------------
    @staticmethod
    def fit_trend(accels, sigma1s):
        """Phase 2-B (i): eq. 23 ``sigma1 = alpha/|a| + beta`` by least squares over the phase
        2-A values, with alpha, beta >= 0 (non-negative least squares: a negative damping is
        not physical). Returns (alpha, beta, rms, r2, (alpha_stderr, beta_stderr))."""
        a = np.abs(np.asarray(accels, float))
        s = np.asarray(sigma1s, float)
        if a.size < 2 or np.any(a <= 0):
            raise ValueError("phase 2-B needs at least two data sets with nonzero accelerations")
        A = np.column_stack([1.0 / a, np.ones_like(a)])
        (alpha, beta), _ = nnls(A, s)
        r = s - A @ np.array([alpha, beta])
        rms = float(np.sqrt(np.mean(r ** 2)))
        ss = float(np.sum((s - s.mean()) ** 2))
        r2 = 1.0 - float(r @ r) / ss if ss > 0 else 1.0
        dof = max(a.size - 2, 1)
        try:
            cov = (r @ r) / dof * np.linalg.inv(A.T @ A)
            se = (float(np.sqrt(cov[0, 0])), float(np.sqrt(cov[1, 1])))
        except np.linalg.LinAlgError:
            se = (np.inf, np.inf)
        return float(alpha), float(beta), rms, r2, se

    def fit_gamma(self, static: Arctan, sigma0: float, alpha: float, beta: float,
                  ratio: float, data: FrictionData, counter: _Counter | None = None):
        """Phase 2-B (iii): gamma of eq. 24 by prediction error with every other parameter
        fixed. The states do not depend on gamma: one scan, then a log grid and a bounded
        scalar refinement. Returns (gamma, rms, stderr, grid, grid_rss)."""
        counter = counter or _Counter()
        qd, qdd, tau = (np.asarray(data.qd, float), np.asarray(data.qdd, float),
                        np.asarray(data.tau, float))

        def model(g):
            return LuGreDM2(static=static, accel_ratio=ratio, sigma0=sigma0, alpha=alpha,
                            beta=beta, gamma=g)

        z = model(1.0).states(qd, data.dt)
        counter.n += 1
        counter.samples += qd.size

        def rss(lg):
            r = tau - model(float(np.exp(lg))).output(z, qd, qdd)
            return float(r @ r)

        lgrid = np.linspace(np.log(self.gamma_range[0]), np.log(self.gamma_range[1]), self.n_gamma)
        grss = np.array([rss(u) for u in lgrid])
        i = int(np.argmin(grss))
        lo, hi = lgrid[max(i - 1, 0)], lgrid[min(i + 1, lgrid.size - 1)]
        res = minimize_scalar(rss, bounds=(lo, hi), method="bounded",
                              options={"xatol": 1e-6})
        lg = float(res.x) if res.fun <= grss[i] else float(lgrid[i])
        gamma = float(np.exp(lg))
        resid = tau - model(gamma).output(z, qd, qdd)
        h = 1e-4 * gamma
        d = (model(gamma + h).output(z, qd, qdd) - model(max(gamma - h, 0.0)).output(z, qd, qdd)) \
            / (gamma + h - max(gamma - h, 0.0))
        s2 = float(resid @ resid) / max(qd.size - 1, 1)
        dd = float(d @ d)
        se = float(np.sqrt(s2 / dd)) if dd > 0 else np.inf
        return gamma, float(np.sqrt(np.mean(resid ** 2))), se, np.exp(lgrid), grss

    # ---- phase 2-C (jointlab) ------------------------------------------------------------------
    def refine_damping(self, static: Arctan, sigma0: float, ratio: float, datasets,
                       counter: _Counter | None = None, rest_times=(np.inf, 0.3, 0.03, 0.003),
                       floor_fracs=(0.0, 0.003, 0.01, 0.03, 0.1),
                       n_gamma: int = 9, max_ratio: float = 1.05,
                       static_limit_deflection: float = 1e-9, identify: bool = True) -> dict:
        """Phase 2-C, jointlab's addition to sec. III-B: alpha, beta >= 0 and gamma of eq. 24,
        the acceleration floor of eq. 24's root, the standstill relaxation of the bristle
        (:mod:`ident.friction.dynamic`, ``rest_speed``) and whether the data support the
        bristle at all, by prediction error over every data set (each with its own state
        scan, so no state crosses a join); ``a_max/v_max`` stays the paper's.

        Why: phase 2-B (i) fits eq. 23 to the sigma1 values of phase 2-A, each identified where
        one acceleration dominates; nothing checks what ``f_sigma1(v, a)`` then does elsewhere,
        e.g. at constant low speed or at standstill, where ``alpha / sqrt(gamma (r v)^2 + a^2)``
        has no bound but the floor; eq. 5 freezes the bristle at standstill, which holds
        +-g where the joint's friction may relax (measured on an independent simulator: DM2
        up to 40 % worse than the static model on some trial kinds, 2-4x over the rests); and
        on a joint without presliding phase 2-A still returns a finite sigma0 (its slowest
        data set cannot tell a stiff bristle from none), whose lag at the velocity reversals
        of fast trials made DM2 up to 1.9x worse than the static model (jointlab synth, no
        effect, 200 Hz).

        Objective: the sum over the data sets of ``rho_k^2 = RSS_k(DM2) / RSS_k(static)``,
        the squared ratio of each data set's residual RMS to the static model's (step 1's
        arctan on the same data), so each data set counts by how much DM2 improves on the
        static model there, not by its length or residual level (with the pooled RSS, long
        trials with large residuals at rest chose a relaxation that bends the low-speed steady
        curve by ``S1/(S1 + rest_speed)`` and doubled the error of excitation trials whose
        static residual is at the noise level).

        Candidates: sigma0 of phase 2-A (the paper's; :meth:`fit` passes the declared spring's
        K instead when the spring explains phase 2-A's apparent bristle: the spring-only
        model) with the grid below, and the bristle's
        static limit (sigma0 = max g / ``static_limit_deflection``: with the first-order hold
        DM2 is then the static curve ``S0(v) g(v) + tau_fv(v)`` sample by sample), undamped
        and unrelaxed, plus the damping fit. Constraint: no data set may end above
        ``cap_k = max(max_ratio, rho_k(static limit))``; the damping found by the weighted
        least squares, ``(alpha, beta)``, is scaled by the largest ``s`` in [0, 1] that meets
        every bound (each ``rho_k^2(s)`` is a quadratic in s), and a candidate that meets it
        at no s is dropped. The static limit without damping always meets it, so DM2 falls
        back to the static model where the data do not support the dynamics, and is never
        more than ``max_ratio`` times worse than it on any data set used here.

        Grid (phase 2-A's sigma0): the standstill relaxation time ``g(0)/(sigma0 rest_speed)``
        over ``rest_times`` (s; inf: rest_speed 0, the paper's eq. 5), the floor over
        ``floor_fracs`` of ``a_max`` (0: the 1e-6 numerical floor), gamma over ``n_gamma`` log
        points of the estimator's range. For each the torque is linear in (alpha, beta), so
        the non-negative least squares over the weighted 2x2 normal equations is exact (its
        four active sets enumerated); alpha = beta = 0 is always a candidate. The best gamma is
        refined by a bounded 1-D search. Returns ``{"sigma0", "bristle" ("identified" or
        "static limit"), "alpha", "beta", "gamma", "accel_floor", "rest_speed", "rest_time",
        "shrink", "ratio_rms", "ratio_rms_no_damping" (quadratic mean of rho_k over the data
        sets, with and without the damping), "ratios" (rho_k), "ratios_identified" (the best
        admissible candidate with phase 2-A's sigma0, None if none is), "ratios_static_limit",
        "rms", "rms_no_damping", "rms_static" (pooled, N m), "n", "n_datasets", "grid"}``.
        """
        counter = counter or _Counter()
        datasets = list(datasets)
        K = len(datasets)
        g0 = float(static.g(np.array([0.0]))[0])
        vmax = max(float(np.max(np.abs(d.qd))) for d in datasets)
        a_max = ratio * vmax
        floors = [1e-6 if f == 0 else f * a_max for f in floor_fracs]
        v = np.concatenate([np.asarray(d.qd, float) for d in datasets])
        acc = np.concatenate([np.asarray(d.qdd, float) for d in datasets])
        tau = np.concatenate([np.asarray(d.tau, float) for d in datasets])
        rv2 = (ratio * v) ** 2
        starts = np.cumsum([0] + [d.n for d in datasets[:-1]])
        # per-sample weights: 1 / RSS of the static model on the sample's data set
        rss_st = np.array([float(np.sum((np.asarray(d.tau, float)
                                         - static.torque(np.asarray(d.qd, float))) ** 2))
                           for d in datasets])
        rss_st = np.maximum(rss_st, 1e-12 * max(float(rss_st.max()), 1e-300))
        sw = np.repeat(1.0 / np.sqrt(rss_st), [d.n for d in datasets])
        lgrid = np.linspace(np.log(self.gamma_range[0]), np.log(self.gamma_range[1]), n_gamma)

        def seg(x):
            return np.add.reduceat(x, starts)

        def nnls2(G, h, yy):
            cands = [np.zeros(2)]
            if G[0, 0] > 0:
                cands.append(np.array([max(h[0] / G[0, 0], 0.0), 0.0]))
            if G[1, 1] > 0:
                cands.append(np.array([0.0, max(h[1] / G[1, 1], 0.0)]))
            try:
                th = np.linalg.solve(G, h)
                if np.all(th >= 0):
                    cands.append(th)
            except np.linalg.LinAlgError:
                pass
            rss = [yy - 2 * th @ h + th @ G @ th for th in cands]
            return cands[int(np.argmin(rss))]

        def largest_shrink(a, b, c):
            """Largest s in [0, 1] with a s^2 - 2 b s + c <= 0 for every k (a >= 0), or None."""
            lo, hi = 0.0, 1.0
            for ak, bk, ck in zip(a, b, c):                  # loop over data sets (tens)
                if ak <= 1e-15 * max(abs(bk), abs(ck), 1e-300):
                    if bk > 0:
                        lo = max(lo, ck / (2 * bk))
                    elif ck > 0:
                        return None
                    continue
                disc = bk * bk - ak * ck
                if disc < 0:
                    return None
                r = np.sqrt(disc)
                lo, hi = max(lo, (bk - r) / ak), min(hi, (bk + r) / ak)
            return hi if lo <= hi else None

        def states(s0, t_rest):
            vr = 0.0 if not np.isfinite(t_rest) else g0 / (s0 * t_rest)
            bm = LuGreDM2(static=static, accel_ratio=ratio, sigma0=s0, alpha=0.0,
                          beta=0.0, gamma=1.0, rest_speed=vr)
            zs, zds = [], []
            for d in datasets:                               # loop over data sets (tens)
                qd = np.asarray(d.qd, float)
                z = bm.states(qd, d.dt)
                a, b, _ = bm._ab(qd)
                zs.append(z)
                zds.append(b - a * z)
                counter.n += 1
                counter.samples += qd.size
            z, zdot = np.concatenate(zs), np.concatenate(zds)
            return vr, zdot, tau - s0 * z - static.viscous(v)

        def make_solve(fl, zdot, y, cap2):
            """The constrained, weighted fit of (alpha, beta) at one (sigma0, rest time, floor)
            as a function of gamma: (objective, (alpha, beta), shrink, rho_k^2); everything it
            needs bound here (it is called again after the grid loops)."""
            zw, yw = sw * zdot, sw * y
            yyk, h2k, g22k = seg(yw * yw), seg(zw * yw), seg(zw * zw)

            def solve(gamma):
                c1 = zw / np.sqrt(gamma * rv2 + acc ** 2 + fl ** 2)
                g11k, g12k, h1k = seg(c1 * c1), seg(c1 * zw), seg(c1 * yw)
                G = np.array([[g11k.sum(), g12k.sum()], [g12k.sum(), g22k.sum()]])
                th = nnls2(G, np.array([h1k.sum(), h2k.sum()]), yyk.sum())
                a = th[0] ** 2 * g11k + 2 * th[0] * th[1] * g12k + th[1] ** 2 * g22k
                b = th[0] * h1k + th[1] * h2k
                s = largest_shrink(a, b, yyk - cap2)
                if s is None:
                    return np.inf, (0.0, 0.0), 0.0, yyk
                q = yyk - 2 * s * b + s * s * a
                return float(q.sum()), (float(s * th[0]), float(s * th[1])), float(s), q
            return solve, yyk

        # the static limit first: its ratios set the bound of every candidate, and it is the
        # fallback (no damping: zdot of a stiff bristle is numerical, not a bristle velocity)
        s_lim = float(np.max(static.g(np.array([0.0, vmax])))) / static_limit_deflection
        _, zdot_l, y_l = states(s_lim, np.inf)
        q_lim = seg((sw * y_l) ** 2)
        ratios_lim = np.sqrt(q_lim)
        cap2 = np.maximum(max_ratio, ratios_lim) ** 2 * (1.0 + 1e-9)
        best = (float(q_lim.sum()), "static limit", s_lim, np.inf, 0.0, 1e-6, 1.0, (0.0, 0.0),
                0.0, q_lim, q_lim, zdot_l, y_l)
        table, ident = [], None
        if identify and sigma0 < s_lim:                      # phase 2-A's sigma0 and the grid
            cb = None
            for t_rest in rest_times:                        # loop over the grid (~25 points)
                vr, zdot, y = states(float(sigma0), t_rest)
                for fl in floors:
                    solve, yyk = make_solve(fl, zdot, y, cap2)
                    sols = [solve(float(np.exp(u)))[0] for u in lgrid]
                    i = int(np.argmin(sols))
                    table.append((t_rest, fl, float(np.exp(lgrid[i])), sols[i], float(yyk.sum())))
                    if np.isfinite(sols[i]) and (cb is None or sols[i] < cb[0]):
                        cb = (sols[i], t_rest, vr, fl, i, solve, yyk, zdot, y)
            if cb is not None:
                _, t_rest, vr, fl, i, solve, yyk, zdot, y = cb
                lo, hi = lgrid[max(i - 1, 0)], lgrid[min(i + 1, lgrid.size - 1)]
                pen = 1e30 * max(K, 1)                       # finite: the search subtracts values

                def f(u):
                    o = solve(float(np.exp(u)))[0]
                    return o if np.isfinite(o) else pen
                res = minimize_scalar(f, bounds=(lo, hi), method="bounded",
                                      options={"xatol": 1e-4})
                lg = float(res.x) if res.fun <= cb[0] else float(lgrid[i])
                obj, th, shrink, q = solve(float(np.exp(lg)))
                ident = np.sqrt(np.maximum(q, 0.0)).tolist()
                if obj < best[0]:
                    best = (obj, "identified", float(sigma0), t_rest, vr, fl, float(np.exp(lg)),
                            th, shrink, q, yyk, zdot, y)
        obj, name, s0, t_rest, vr, fl, gamma, (alpha, beta), shrink, q, yyk, zdot, y = best
        r = y - (alpha / np.sqrt(gamma * rv2 + acc ** 2 + fl ** 2) + beta) * zdot
        k = max(K, 1)
        return {"sigma0": float(s0), "bristle": name, "alpha": alpha, "beta": beta,
                "gamma": gamma, "accel_floor": float(fl), "rest_speed": float(vr),
                "rest_time": float(t_rest), "shrink": shrink, "max_ratio": float(max_ratio),
                "ratio_rms": float(np.sqrt(obj / k)),
                "ratio_rms_no_damping": float(np.sqrt(yyk.sum() / k)),
                "ratios": np.sqrt(np.maximum(q, 0.0)).tolist(), "ratios_identified": ident,
                "ratios_static_limit": ratios_lim.tolist(),
                "rms": float(np.sqrt(np.mean(r ** 2))),
                "rms_no_damping": float(np.sqrt(np.mean(y ** 2))),
                "rms_static": float(np.sqrt(rss_st.sum() / max(tau.size, 1))),
                "n": int(tau.size), "n_datasets": K,
                "grid": [{"rest_time": rt, "accel_floor": f, "gamma": g,
                          "ratio_rms": float(np.sqrt(qq / k)),
                          "ratio_rms_no_damping": float(np.sqrt(w / k))}
                         for rt, f, g, qq, w in table]}

    # ---- everything -------------------------------------------------------------------------
    def fit(self, static_data: FrictionData, reversal_datasets, variable_data: FrictionData,
            static: FrictionFit | None = None, refine_datasets=None,
            stiffness: float | None = None, link_datasets=None) -> IndriResult:
        """Steps 1, 2-A and 2-B (sec. III) plus the DM1 comparison model, and phase 2-C
        (:meth:`refine_damping`) when ``refine`` is set and ``refine_datasets`` are given.

        ``static_data``: constant-speed runs (step 1; ignored if ``static`` is given);
        ``reversal_datasets``: phase 2-A data sets, one acceleration each (at least two);
        ``variable_data``: the further acquisition with varied speeds and accelerations used to
        identify gamma (phase 2-B iii); ``refine_datasets``: the acquisitions phase 2-C pools
        (e.g. every constant-velocity, reversal and excitation trial, each whole);
        ``stiffness``, ``link_datasets``: the declared transmission stiffness K (N m/rad) and
        the reversal data sets on the link velocity (the same spans, the motor encoder's
        velocity minus the spring's nominal deflection rate,
        :func:`ident.indri.campaign.nominal_link_state`). The bristle acts on the link, behind
        the spring, so the motor encoder sees both in series: the DM2 (on the motor velocity,
        the controller's signal) keeps the apparent sigma0, and phase 2-A on the link sets
        gives the bristle's own (:attr:`IndriResult.sigma0_bristle`). When that one is at the
        stiff end of its search, no bristle sits behind the spring: the spring alone explains
        the apparent one, and phase 2-C's candidate is the spring-only model (sigma0 = K,
        named ``"declared spring"``) instead of phase 2-A's apparent bristle.

        A motor-side phase 2-A sigma0 at the stiff end of its search (steady deflection at the
        lower end of ``deflection_range``) is no bristle the data resolve: phase 2-C's choice is
        then named ``"static limit"`` or ``"stiff bound"`` (never ``"identified"``), with
        ``bristle_resolved`` False and a note, and sigma0 has no standard error.
        """
        datasets = list(reversal_datasets)
        if len(datasets) < 2:
            raise ValueError("phase 2-A/2-B need at least two reversal data sets")
        counter = _Counter()
        tic = _time.perf_counter()
        st_fit = self.fit_static(static_data) if static is None else static
        t1 = _time.perf_counter()
        st = st_fit.model
        p2a = self.phase_2a(st, datasets, counter)
        t2 = _time.perf_counter()
        accels = np.array([p.accel for p in p2a])
        alpha, beta, trend_rms, r2, (se_a, se_b) = self.fit_trend(accels, [p.sigma1 for p in p2a])
        fastest = datasets[int(np.argmax(accels))]
        ratio = LuGreDM2.ratio_from_data(fastest.qd, fastest.qdd)
        slow = int(np.argmin(accels))
        sigma0 = p2a[slow].sigma0
        gamma, g_rms, g_se, ggrid, grss = self.fit_gamma(st, sigma0, alpha, beta, ratio,
                                                         variable_data, counter)
        trend = (alpha, beta)
        refinement = None
        p2a_link, behind = (), True
        link = list(link_datasets or ())
        if stiffness is not None and len(link) == len(datasets):
            p2a_link = self.phase_2a(st, link, counter)
            s_hi_l = self._sigma0_bounds(st, link[slow])[1]
            behind = p2a_link[slow].sigma0 < (1.0 - 1e-3) * s_hi_l
        if self.refine and refine_datasets:
            s_hi = self._sigma0_bounds(st, datasets[slow])[1]
            resolved = sigma0 < (1.0 - 1e-3) * s_hi
            # a bristle in series with the spring is softer than the spring: an apparent
            # sigma0 >= K, or none on the link side, is the spring's, not a bristle's
            spring_only = bool(p2a_link) and resolved and (not behind or sigma0 >= stiffness)
            refinement = self.refine_damping(st, float(stiffness) if spring_only else sigma0,
                                             ratio, list(refine_datasets), counter)
            refinement["bristle_resolved"] = bool(resolved)
            refinement["bristle_behind_spring"] = bool(behind)
            if spring_only:
                if refinement["bristle"] == "identified":
                    refinement["bristle"] = "declared spring"
                why = (f"phase 2-A on the link velocity: sigma0 {p2a_link[slow].sigma0:.3g} at the "
                       f"stiff end of its search ({s_hi_l:.3g})" if not behind else
                       f"the apparent sigma0 {sigma0:.3g} is not below K (a bristle in series "
                       "with the spring is softer than the spring)")
                refinement["note"] = (
                    f"{why}: no bristle behind the spring; the declared spring (K = "
                    f"{stiffness:.4g} N m/rad) explains the apparent bristle of the motor side: "
                    "phase 2-C's candidate is the spring-only model, sigma0 = K")
            elif not resolved:
                if refinement["bristle"] == "identified":
                    refinement["bristle"] = "stiff bound"
                refinement["note"] = (
                    f"phase 2-A's sigma0 {sigma0:.3g} is at the stiff end of its search "
                    f"({s_hi:.3g}: deflection {self.deflection_range[0]:.3g} rad): no bristle")
            refinement["phase2b"] = {"alpha": alpha, "beta": beta, "gamma": gamma,
                                     "sigma0": sigma0}
            alpha, beta, gamma = (refinement["alpha"], refinement["beta"], refinement["gamma"])
            sigma0 = refinement["sigma0"]
            g_rms = float(np.sqrt(np.mean((np.asarray(variable_data.tau) - LuGreDM2(
                static=st, accel_ratio=ratio, sigma0=sigma0, alpha=alpha, beta=beta,
                gamma=gamma, accel_floor=refinement["accel_floor"],
                rest_speed=refinement["rest_speed"]).torque(
                    variable_data.qd, variable_data.qdd, variable_data.dt)) ** 2)))
            g_se = float("nan")
        t3 = _time.perf_counter()
        dm1 = self.fit_dm1(st, datasets[slow], self.dm1_damping, counter).fit
        t4 = _time.perf_counter()
        diag = {"alpha_stderr": se_a, "beta_stderr": se_b, "slowest_dataset": datasets[slow].label,
                "fastest_dataset": fastest.label, "n_state_evals": counter.n,
                "state_eval_samples": counter.samples,
                "n_samples": int(static_data.n + sum(d.n for d in datasets) + variable_data.n),
                "seconds": {"step1": t1 - tic, "phase2a": t2 - t1, "phase2b": t3 - t2,
                            "dm1": t4 - t3, "total": t4 - tic},
                "dm1_damping": self.dm1_damping}
        return IndriResult(static=st_fit, phase2a=p2a, alpha=alpha, beta=beta, accel_ratio=ratio,
                           gamma=gamma, sigma0=sigma0, dm1=dm1, trend_rms=trend_rms, trend_r2=r2,
                           gamma_rms=g_rms, gamma_stderr=g_se, gamma_grid=ggrid,
                           gamma_grid_rss=grss, diagnostics=diag, trend_alpha=trend[0],
                           trend_beta=trend[1], refinement=refinement,
                           stiffness=None if stiffness is None else float(stiffness),
                           phase2a_link=tuple(p2a_link))


# ============================================================================================
# performance indices and tables (Tables I-II)
# ============================================================================================
def performance_indices(tau_res, tau_f) -> dict:
    """Sec. V: RMS, mean (M, of the absolute value) and infinite norm (IN) of
    ``tau_diff = tau_res - tau_f``."""
    d = np.asarray(tau_res, float) - np.asarray(tau_f, float)
    return {"RMS": float(np.sqrt(np.mean(d ** 2))), "M": float(np.mean(np.abs(d))),
            "IN": float(np.max(np.abs(d)))}


def err_percent(pi_ref: float, pi_other: float) -> float:
    """Table I's relative percentage error of the reference model (DM2) against another:
    ``100 (PI_ref - PI_other) / PI_ref`` (negative: the reference is better)."""
    return 100.0 * (pi_ref - pi_other) / pi_ref if pi_ref != 0 else float("nan")


def model_torque(model: FrictionModel, data: FrictionData) -> np.ndarray:
    """Friction torque of ``model`` along ``data`` (dynamic models: eq. 29-30 on its steps)."""
    qd = np.asarray(data.qd, float)
    if model.dynamic:
        return model.torque(qd, np.asarray(data.qdd, float), data.dt)
    return model.torque(qd)


@dataclass(frozen=True)
class PerformanceTable:
    """Tables I-II: one row per (test, index) with each model's value and Err% of the reference
    model against every other one."""

    rows: tuple                   # ({"test", "PI", <model>: value, ..., "Err% <other>": ...}, ...)
    models: tuple                 # model names, reference first
    reference: str
    group: str = "Tests"

    @property
    def columns(self) -> tuple:
        return (self.group, "PI") + self.models + tuple(f"Err% {m}" for m in self.models[1:])

    def value(self, test: str, pi: str, model: str) -> float:
        for r in self.rows:
            if r["test"] == test and r["PI"] == pi:
                return r[model]
        raise KeyError((test, pi))

    def to_csv(self) -> str:
        buf = io.StringIO()
        w = csv.writer(buf, lineterminator="\n")
        w.writerow(self.columns)
        for r in self.rows:
            w.writerow([r["test"], r["PI"]] + [f"{r[m]:.6g}" for m in self.models]
                       + [f"{r['Err% ' + m]:.1f}" for m in self.models[1:]])
        return buf.getvalue()

    def to_markdown(self, title: str | None = None) -> str:
        cols = self.columns
        lines = [] if title is None else [f"**{title}**", ""]
        lines.append("| " + " | ".join(cols) + " |")
        lines.append("|" + "|".join(["---"] * 2 + ["---:"] * (len(cols) - 2)) + "|")
        last = None
        for r in self.rows:
            name = r["test"] if r["test"] != last else ""
            last = r["test"]
            lines.append("| " + " | ".join([name, r["PI"]] + [f"{r[m]:.4g}" for m in self.models]
                                           + [f"{r['Err% ' + m]:.1f}" for m in self.models[1:]])
                         + " |")
        return "\n".join(lines) + "\n"

    def to_dict(self) -> dict:
        return _jsonable({"group": self.group, "reference": self.reference,
                          "models": list(self.models), "rows": [dict(r) for r in self.rows]})


def performance_table(models: dict, tests: dict, reference: str = "DM2",
                      group: str = "Tests") -> PerformanceTable:
    """Evaluate every model of ``models`` (name -> model, e.g. :attr:`IndriResult.models`) on
    every data set of ``tests`` (name -> :class:`FrictionData`) and lay out Table I (or Table II
    with ``group="Axis"``)."""
    if reference not in models:
        raise ValueError(f"reference model {reference!r} not among {list(models)}")
    names = (reference,) + tuple(m for m in models if m != reference)
    rows = []
    for tname, data in tests.items():
        pis = {m: performance_indices(data.tau, model_torque(models[m], data)) for m in names}
        for pi in PI_NAMES:
            row = {"test": tname, "PI": pi}
            row.update({m: pis[m][pi] for m in names})
            row.update({f"Err% {m}": err_percent(pis[reference][pi], pis[m][pi])
                        for m in names[1:]})
            rows.append(row)
    return PerformanceTable(rows=tuple(rows), models=names, reference=reference, group=group)


# ============================================================================================
# Figures 2, 4, 5
# ============================================================================================
def damping_term(model, data: FrictionData) -> np.ndarray:
    """The ``f_sigma1(.) dz/dt`` term of eq. 6 along ``data`` (Figure 5): the torque minus the
    spring ``sigma0 z`` and the viscous part (eq. 9)."""
    qd = np.asarray(data.qd, float)
    z = model.states(qd, data.dt)
    return model_torque(model, data) - model.sigma0 * z - model.static.viscous(qd)


def figure_curves(result: IndriResult, data: FrictionData) -> dict:
    """The curves of Figures 2, 4 and 5 along ``data`` (e.g. :func:`figure1_knots`).

    Figure 2: friction with ``f_sigma1 = sigma1`` (constant), eq. 11 and eq. 12, sigma1 being
    the value identified at the lowest acceleration (phase 2-A), as in the paper. Figures 4/5:
    friction and damping term with eq. 11 and the largest / smallest phase 2-A sigma1, and with
    the identified eq. 24 (DM2). Returns ``{"fig2": {label: torque}, "fig4": ..., "fig5": ...}``.
    """
    st = result.static.model
    p2a = result.phase2a
    s0 = result.sigma0
    s_slow = p2a[result._slowest].sigma1
    s1s = [p.sigma1 for p in p2a]
    mk = {
        "constant sigma1": LuGreDM1(static=st, damping="constant", sigma0=s0, sigma1=s_slow),
        "eq. 11": LuGreDM1(static=st, damping="eq11", sigma0=s0, sigma1=s_slow),
        "eq. 12": LuGreDM1(static=st, damping="eq12", sigma0=s0, sigma1=s_slow),
    }
    mk4 = {
        "eq. 11, max sigma1": LuGreDM1(static=st, damping="eq11", sigma0=s0, sigma1=max(s1s)),
        "eq. 11, min sigma1": LuGreDM1(static=st, damping="eq11", sigma0=s0, sigma1=min(s1s)),
        "eq. 24 (DM2)": result.dm2,
    }
    return {"time": np.asarray(data.time, float), "qd": np.asarray(data.qd, float),
            "tau_res": np.asarray(data.tau, float),
            "fig2": {k: model_torque(m, data) for k, m in mk.items()},
            "fig4": {k: model_torque(m, data) for k, m in mk4.items()},
            "fig5": {k: damping_term(m, data) for k, m in mk4.items()}}


_FIG_TITLES = {"fig2": "Figure 2: friction torque with three bristle dampings",
               "fig4": "Figure 4: friction torque, eq. 11 (max/min sigma1) and eq. 24",
               "fig5": "Figure 5: damping term f_sigma1 dz/dt"}


def save_figures(curves: dict, out_dir, sink=None, prefix: str = "indri") -> dict:
    """Write Figures 2, 4 and 5 as PNG into ``out_dir`` (matplotlib, Agg) and log the same
    curves as scalar series to ``sink`` (a :class:`viz.sink.Sink`; rerun when enabled).
    Returns ``{"fig2": path, ...}``."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    t = curves["time"]
    qd = curves["qd"]
    # the zoom (as in the paper's insets): around the fastest velocity reversal
    cross = np.flatnonzero(np.sign(qd[:-1]) * np.sign(qd[1:]) < 0)
    if cross.size:
        k = cross[int(np.argmax(np.abs(qd[cross + 1] - qd[cross])))]
        zoom = (t[k] - 0.05, t[k] + 0.15)
    else:
        zoom = (t[0], t[-1])
    zm = (t >= zoom[0]) & (t <= zoom[1])
    paths = {}
    for key in ("fig2", "fig4", "fig5"):
        fig, (ax0, ax1, ax2) = plt.subplots(3, 1, figsize=(9, 7.5),
                                            gridspec_kw={"height_ratios": [1, 3, 2]})
        ax0.plot(t, qd, color="0.3", lw=0.8)
        ax0.set_ylabel("qd [rad/s]")
        for ax, sel in ((ax1, slice(None)), (ax2, zm)):
            if key != "fig5":
                ax.plot(t[sel], curves["tau_res"][sel], color="0.75", lw=0.6,
                        label="residual torque")
            for lab, y in curves[key].items():
                ax.plot(t[sel], y[sel], lw=1.0, label=lab)
            ax.set_ylabel("torque [N m]")
        ax1.axvspan(*zoom, color="0.9", zorder=0)
        ax2.set_xlabel("time [s] (zoom on the fastest reversal)")
        ax1.legend(loc="upper left", fontsize=8)
        ax0.set_title(_FIG_TITLES[key], fontsize=10)
        fig.tight_layout()
        p = out_dir / f"{prefix}_{key}.png"
        fig.savefig(p, dpi=110)
        if sink is not None:
            fig.canvas.draw()
            sink.image(f"indri/{key}_plot", np.ascontiguousarray(
                np.asarray(fig.canvas.buffer_rgba())[..., :3]))
        plt.close(fig)
        paths[key] = p
        if sink is not None:
            names = list(curves[key])
            sink.scalars(f"indri/{key}", t, np.column_stack([curves[key][k] for k in names]),
                         names=names)
    if sink is not None:
        sink.scalars("indri/qd", t, curves["qd"])
        sink.scalars("indri/tau_res", t, curves["tau_res"])
    return paths


# ============================================================================================
# report
# ============================================================================================
def write_report(result: IndriResult, out_dir, tables: dict | None = None,
                 curves: dict | None = None, sink=None) -> dict:
    """Write ``indri.json`` (the full result), ``phase2a.csv`` (Figure 3's sigma1 trend with
    the critical accelerations), each table of ``tables`` (name -> PerformanceTable) as
    ``<name>.csv`` and ``<name>.md``, and Figures 2/4/5 when ``curves`` are given. Returns the
    written paths by name."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    paths = {}
    p = out / "indri.json"
    doc = {"format": 1, "result": result.to_dict()}
    if tables:
        doc["tables"] = {k: v.to_dict() for k, v in tables.items()}
    p.write_text(json.dumps(_jsonable(doc), indent=1))
    paths["json"] = p
    p = out / "phase2a.csv"
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(["label", "accel", "v_max", "sigma0", "sigma1", "sigma1_trend", "rms",
                "v_m", "critical_accel", "above_critical"])
    for f in result.phase2a:
        w.writerow([f.label, f"{f.accel:.6g}", f"{f.v_max:.6g}", f"{f.sigma0:.6g}",
                    f"{f.sigma1:.6g}", f"{result.sigma1_trend[0] / f.accel + result.sigma1_trend[1]:.6g}",
                    f"{f.fit.rms:.6g}", f"{f.v_m:.6g}", f"{f.critical_accel:.6g}",
                    int(f.above_critical)])
    p.write_text(buf.getvalue())
    paths["phase2a"] = p
    for name, tab in (tables or {}).items():
        (out / f"{name}.csv").write_text(tab.to_csv())
        (out / f"{name}.md").write_text(tab.to_markdown(title=name))
        paths[f"{name}.csv"] = out / f"{name}.csv"
        paths[f"{name}.md"] = out / f"{name}.md"
    if curves is not None:
        paths.update(save_figures(curves, out, sink=sink))
    if sink is not None and tables:
        sink.text("indri/tables", "\n".join(t.to_markdown(title=k) for k, t in tables.items()))
    return paths
