"""The friction identification framework of Indri & Trapani 2020 (paper 001 in the seeds).

The estimator (:class:`IndriTrapani`) and its results (:class:`IndriResult`,
:class:`Phase2AFit`), in the order of the paper:

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
  reduces to the static model wherever the data do not support the bristle dynamics.

The framework's other pieces: residual torques (eq. 25-26) in :mod:`ident.indri.data`, the
performance indices, Tables I-II and Figures 2, 4, 5 in :mod:`ident.indri.report`, the velocity
profiles of the acquisitions in :mod:`ident.excitation.profiles` and the synthetic ground truth
(a LuGre-type joint) in :mod:`ident.sim.friction`.

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

import time as _time
from dataclasses import dataclass, field, replace

import numpy as np
from scipy.optimize import minimize_scalar, nnls

from ident.common import to_jsonable as _jsonable
from ident.friction import Arctan, FrictionFit, LuGreDM1, LuGreDM2, fit_arctan, fit_friction
from ident.friction.constants import KV_DEFAULT
from ident.friction.data import FrictionData
from ident.indri.data import steady_mask

__all__ = ["Phase2AFit", "IndriResult", "IndriTrapani"]


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
        :func:`ident.indri.campaign_fit.nominal_link_state`). The bristle acts on the link, behind
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
