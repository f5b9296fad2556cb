"""Link state (q, qd, qdd) of a flexible joint from the encoder and the markers together.

The thesis (002, ch. 3-4) measures the link angle by motion capture to capture the flexible
joint of eq. 2-1..2-4 and differentiates a Fourier fit of it. On real records the link angle
per marker frame is noisy (0.1-0.2 deg: markers 0.5-1 mm a few cm from the axis) while the
link-motor deflection is small (0.01-0.03 deg on a stiff drive), so a derivative of the
marker angle is mostly noise and its noise in ``qd``, ``qdd`` biases the eq. 2-4 regression
(errors in variables). The estimator here uses each sensor for what it measures well::

    q(t) = qm(t) + delta(t),   delta(t) = delta0 + g delta_nom(t) + r(t)

* ``qm``: the encoder angle smoothed at a bandwidth chosen from its own data
  (:class:`ident.signals.smoothing.FourierSmoother`: a Fourier fit on the detected periodic
  window when the record is one, else a Savitzky-Golay window chosen by GCV) or, when the
  raw encoder samples are given, re-smoothed by Savitzky-Golay at a wider window together
  with the nominal deflection (one window for ``qm + delta_nom``) where eq. 2-4 says so: on
  a soft joint the motor keeps turning while the link sticks, so the motor angle kinks at
  every stick-slip transition while the link angle does not; the encoder's own fit follows
  the kinks (GCV: a narrow window; Fourier: a smooth curve through them) and its velocity
  error near zero speed biases the Coulomb + viscous fit (PA10 j5 at the declared
  5000 N m/rad, half-speed trials: viscous +10..35 %);
* ``delta_nom = -tau_s / K``: the nominal deflection under the transmitted torque and the
  declared ``stiffness`` ``K`` of drives.toml (spring law ``tau_s = K (qm - q)``):
  ``tau_s = y = u - J qmdd - B qmd`` (the right-hand side of eq. 2-4) when friction acts on the
  link side, ``y - f(qmd)`` when it acts on the motor side; the side and the smoothing window
  are those whose link acceleration best explains eq. 2-4 (the markers cannot see the fast
  part of the deflection, a transmission resonance of 0.001 deg; the dynamics can);
* ``delta0`` (the constant offset between the marker frame and the encoder zero), the gain
  ``g`` (1 for a drive as stiff as declared) and ``r(t)``, a slow deflection the nominal law
  misses, are fitted to the marker-minus-encoder samples: ``r`` is a cosine series over the
  record whose number of terms (hence its bandwidth, ``M / (2 D)`` Hz) is chosen by BIC, so
  that the markers only contribute the bandwidth their noise supports. Marker gaps (NaN) and
  rests are simply samples with or without data.

The result says which method and bandwidths were used and the standard deviation they imply
for ``q``, ``qd`` and ``qdd`` (``LinkState.errors``), which the identification uses to
quantify the errors-in-variables bias (:mod:`ident.model.onelink`).
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from mocap.io.errors import InputError

from ident.friction import laws
from ident.friction.base import CoulombViscous
from ident.friction.constants import REST_FRAC
from ident.model.onelink import onelink_regressor
from ident.signals.smoothing import (FourierSmoother, JointSignals, SavGolSmoother, SmoothFit,
                                     estimate_time_offset)

__all__ = ["DeflectionFit", "LinkState", "LinkStateEstimator", "prepare_joint_signals"]


def _cosine_basis(t, t0: float, D: float, M: int, order: int = 0) -> np.ndarray:
    """``cos(pi m (t - t0) / D)``, m = 1..M, and its ``order``-th time derivative, (T, M).
    Built from the powers of ``exp(i pi (t - t0) / D)`` (one complex exponential and M
    products over the samples instead of M cosines; the same values to rounding)."""
    if order not in (0, 1, 2):
        raise ValueError("order must be 0, 1 or 2")
    x = np.asarray(t, float) - t0
    if M == 0:
        return np.zeros((x.size, 0))
    w = np.pi * np.arange(1, M + 1) / D
    e = np.exp(1j * (np.pi / D) * x)
    E = np.empty((M, x.size), complex)
    E[0] = e
    for m in range(1, M):  # loop over the terms (up to a few hundred), vectorised over samples
        np.multiply(E[m - 1], e, out=E[m])
    if order == 0:
        return E.real.T
    if order == 1:
        return (-E.imag * w[:, None]).T
    return (-E.real * (w ** 2)[:, None]).T


def _crossfit_grids(t, x) -> tuple:
    """The uniform grids ``(dt, n)`` of the two halves of :func:`_crossfit_smooth` on
    ``t, x`` (:meth:`SavGolSmoother.grid_of`)."""
    t = np.asarray(t, float)
    x = np.asarray(x, float)
    return tuple(SavGolSmoother.grid_of(t[p::2], x[p::2]) for p in (0, 1))


def _crossfit_windows(grids, window_s: float) -> tuple:
    """The Savitzky-Golay windows (samples) of the two halves of :func:`_crossfit_smooth`
    at ``window_s`` on their ``grids`` (:func:`_crossfit_grids`): two calls on the same
    ``t, x`` whose windows agree give the same fit."""
    sm = SavGolSmoother(window_s)
    return tuple(sm.window_samples(dt, n) for dt, n in grids)


def _crossfit_smooth(t, x, window_s: float) -> SmoothFit:
    """Savitzky-Golay smoothing of ``x`` in which the value (and derivatives) at every sample
    come from the OTHER samples only: the even samples are smoothed and evaluated at the odd
    ones and vice versa. The nominal deflection is built from the torque ``y`` that eq. 2-4
    also regresses on; without this split a sample's torque noise would enter its own
    regressor (through the filter's centre weight), a spurious fit that favours the narrowest
    window and biases the estimates."""
    t = np.asarray(t, float)
    x = np.asarray(x, float)
    out = [np.empty_like(x) for _ in range(3)]
    fits = []
    for p in (0, 1):
        src, dst = np.arange(p, t.size, 2), np.arange(1 - p, t.size, 2)
        f = SavGolSmoother(window_s).fit(t[src], x[src])
        fits.append(f)
        for k, v in enumerate(f.evaluate(t[dst])):
            out[k][dst] = v
    f = fits[0]
    r = x - out[0]
    return SmoothFit("savgol_crossfit", float(np.sqrt(np.mean(r ** 2))), float(np.max(np.abs(r))), int(t.size),
                     float(t[0]), float(t[-1]), None, float("nan"), f.noise_rms, (t, *out),
                     window_s=f.window_s, sigma=f.sigma, qd_noise=f.qd_noise, qdd_noise=f.qdd_noise,
                     bandwidth_hz=f.bandwidth_hz)


def _ordered_projections(X, y) -> np.ndarray:
    """Squared components of ``y`` along the columns of ``X`` orthogonalised in order (the last
    column of the triangular factor ``R`` of ``[X, y]``, squared); 0 for a column that adds no
    direction (``|R_jj|`` under 1e-10 of the largest). ``R`` comes from the Cholesky factor of
    the Gram matrix of the unit-scaled columns (a fraction of a QR's work for the slow cosine
    series here, whose columns are near orthogonal); a QR of ``[X, y]`` when a column is near
    dependent on the earlier ones (scaled pivot under 1e-4 of the largest, where the Gram
    matrix would lose the digits the projections need) or drops out."""
    p = X.shape[1]
    Xa = np.column_stack([X, y])
    nrm = np.sqrt(np.einsum("ij,ij->j", Xa, Xa))
    if np.all(nrm > 0) and np.all(np.isfinite(nrm)):
        Xs = Xa / nrm
        try:
            L = np.linalg.cholesky(Xs.T @ Xs)
        except np.linalg.LinAlgError:
            L = None
        if L is not None:
            ds = np.abs(np.diag(L)[:p])
            d = ds * nrm[:p]                       # the diagonal of the unscaled factor
            if ds.min() > 1e-4 * ds.max() and d.min() > 1e-10 * d.max():
                return (L[p, :p] * nrm[p]) ** 2
    R = np.linalg.qr(Xa, mode="r")
    d = np.abs(np.diag(R)[:p])
    return np.where(d > 1e-10 * d.max(), R[:p, p] ** 2, 0.0)


@dataclass(frozen=True, eq=False)
class DeflectionFit:
    """``delta(t) = offset + gain delta_nom(t) + sum_m c_m cos(pi m (t - t0) / D)``."""

    offset: float
    gain: float                 # NaN without a declared stiffness; 1 (se 0) when fixed at the declared K
    gain_se: float
    coef: np.ndarray            # cosine coefficients (M,)
    cov: np.ndarray = field(repr=False)   # covariance over [offset, (gain), coef]
    t0: float = 0.0
    duration: float = 1.0
    marker_sigma: float = float("nan")   # per-frame noise of the marker angle (rad)
    n_markers: int = 0
    rms_nominal_deflection: float = float("nan")

    @property
    def n_terms(self) -> int:
        return int(np.asarray(self.coef).size)

    @property
    def bandwidth_hz(self) -> float:
        """Highest frequency of the fitted slow deflection ``r(t)`` (0: a constant offset)."""
        return self.n_terms / (2.0 * self.duration)

    def to_dict(self) -> dict:
        return {"offset": self.offset, "gain": self.gain, "gain_se": self.gain_se,
                "n_terms": self.n_terms, "bandwidth_hz": self.bandwidth_hz,
                "marker_sigma": self.marker_sigma, "marker_sigma_deg": float(np.degrees(self.marker_sigma)),
                "n_markers": self.n_markers, "rms_nominal_deflection": self.rms_nominal_deflection,
                "rms_nominal_deflection_deg": float(np.degrees(self.rms_nominal_deflection))}


@dataclass(frozen=True, eq=False)
class LinkState:
    """Link angle and derivatives on the robot-log samples ``time`` (rad, rad/s, rad/s^2).

    ``method``: ``"encoder+deflection"`` (encoder plus the deflection seen by the markers),
    ``"encoder"`` (no markers: rigid joint). ``errors``: the standard deviation (RMS over the
    samples) the smoothing implies for q, qd, qdd; ``marker_rms``: markers minus the estimate.
    """

    time: np.ndarray
    q: np.ndarray
    qd: np.ndarray
    qdd: np.ndarray
    method: str
    motor_fit: SmoothFit
    deflection: DeflectionFit | None
    errors: dict
    marker_rms: float = float("nan")
    nominal_fit: SmoothFit | None = None
    friction_side: str | None = None    # side of the spring the selected nominal deflection puts friction

    def to_dict(self) -> dict:
        return {"method": self.method, "errors": dict(self.errors), "marker_rms": self.marker_rms,
                "marker_rms_deg": float(np.degrees(self.marker_rms)),
                "motor_method": self.motor_fit.method, "motor_bandwidth_hz": self.motor_fit.bandwidth_hz,
                "deflection": self.deflection.to_dict() if self.deflection is not None else None,
                "nominal_window_s": self.nominal_fit.window_s if self.nominal_fit is not None else None,
                "nominal_bandwidth_hz": self.nominal_fit.bandwidth_hz if self.nominal_fit is not None else None,
                "friction_side": self.friction_side}

    def as_smooth_fit(self) -> SmoothFit:
        """The link angle as a :class:`SmoothFit` (grid values on the log samples)."""
        t = self.time
        return SmoothFit(self.method, self.marker_rms, self.marker_rms, int(t.size), float(t[0]),
                         float(t[-1]), None, float("nan"), self.marker_rms, (t, self.q, self.qd, self.qdd),
                         window_s=self.motor_fit.window_s, sigma=self.errors["q"],
                         qd_noise=self.errors["qd"], qdd_noise=self.errors["qdd"],
                         bandwidth_hz=self.motor_fit.bandwidth_hz)


class LinkStateEstimator:
    r"""Estimator of a flexible joint's link state from the encoder angle plus a deflection.

    .. math::

        q(t) = q_m(t) + \delta(t), \qquad
        \delta(t) = \delta_0 + g\, \delta_{nom}(t) + r(t)

    with ``delta_nom = -tau_s / K`` the nominal deflection of the spring of thesis eq. 2-1,
    2-2 [1]_ under the transmitted torque (the right-hand side of eq. 2-4) and ``r`` a slow
    cosine series fitted to the marker-minus-encoder samples (module docstring). The
    attribute ``encoder_windows_s`` holds the Savitzky-Golay windows at which the raw encoder
    angle is re-smoothed with the nominal deflection (empty: the encoder as ``motor_fit``
    smoothed it).

    Parameters
    ----------
    max_bandwidth_hz : float, optional
        Cap of the slow deflection's bandwidth (Hz, >= 0; default 5): the candidates are
        ``M = 0, 1, 2, 4, ...`` cosine terms up to it and up to a tenth of the marker samples,
        chosen by BIC.
    fit_gain : bool, optional
        Fit the gain ``g`` of the nominal deflection when the markers determine it (a gain
        within two standard errors of 1, or one with which eq. 2-4 leaves more residual than
        with the declared stiffness, is fixed at the declared 1); default True.
    nominal_smoother : object, optional
        Smoother of the nominal deflection; None (default): the window and the friction side
        chosen by the eq. 2-4 residual.

    Raises
    ------
    ValueError
        If ``max_bandwidth_hz`` is negative.

    References
    ----------
    .. [1] PA10 thesis (seeds 002), eq. 2-1, 2-2, 2-4.
    """

    def __init__(self, max_bandwidth_hz: float = 5.0, fit_gain: bool = True, nominal_smoother=None):
        if not max_bandwidth_hz >= 0:
            raise ValueError("max_bandwidth_hz must be >= 0")
        self.max_bandwidth_hz = float(max_bandwidth_hz)
        self.fit_gain = bool(fit_gain)
        self.nominal_smoother = nominal_smoother
        self.windows_s = tuple(np.geomspace(0.004, 0.128, 11))
        self.encoder_windows_s = tuple(np.geomspace(0.032, 0.256, 7))
        self.rest_frac = REST_FRAC

    @staticmethod
    def _eq24_rss(q, qd, qdd, y, keep, coef: bool = True):
        """(RSS, coefficients) of the Coulomb + viscous regression of eq. 2-4 on ``keep``.
        ``coef=False``: the RSS alone (coefficients None), from the triangular factor of the
        design with ``y`` appended (its last diagonal entry is the residual norm), unless the
        design is near rank deficient (then the minimum-norm least-squares solve)."""
        p = 5
        qk = q[keep]
        if not coef and qk.size > p:
            XT = np.empty((p + 1, qk.size))     # the rows of [qdd, -sin q, cos q, sign qd, qd, y]
            XT[0] = qdd[keep]
            np.negative(np.sin(qk), out=XT[1])
            np.cos(qk, out=XT[2])
            XT[3:5] = CoulombViscous.regressor(qd[keep]).T
            XT[5] = y[keep]
            R = np.linalg.qr(XT.T, mode="r")
            d = np.abs(np.diag(R)[:p])
            if d.min() > 1e-10 * d.max():
                return float(R[p, p] ** 2), None
        X = np.hstack([onelink_regressor(qk, qdd[keep]), CoulombViscous.regressor(qd[keep]),
                       y[keep][:, None]])
        b, *_ = np.linalg.lstsq(X[:, :p], X[:, p], rcond=None)
        r = X[:, p] - X[:, :p] @ b
        return float(r @ r), b

    def _encoder_candidates(self, t, motor_fit: SmoothFit, qm_samples=None) -> list:
        """The encoder angle as smoothed by ``motor_fit`` and re-smoothed by Savitzky-Golay
        at each window of ``encoder_windows_s`` wider than ``motor_fit``'s (any of them when
        ``motor_fit`` is a Fourier fit and the raw samples are given). The motor angle's
        own bandwidth (GCV) is set by its sharpest features: on a soft joint the motor keeps
        turning while the link sticks, so the encoder angle kinks at every stick-slip
        transition and GCV keeps a narrow window whose velocity noise, on slow trials
        comparable to the speed itself, biases the Coulomb + viscous fit of eq. 2-4 (errors
        in variables near zero speed). The link angle ``qm + delta`` is smoother than either
        part (the deflection takes the kinks up), so its window is chosen with the
        deflection's by the eq. 2-4 residual (:meth:`_nominal_deflection`).
        ``qm_samples``: the raw encoder angle on ``t`` (else a Savitzky-Golay ``motor_fit``'s
        values are re-smoothed, and a Fourier one is kept). The noise level of a re-smoothed
        fit is ``motor_fit``'s through the wider filter."""
        cands = [motor_fit]
        savgol = str(motor_fit.method).startswith("savgol")
        if (not savgol and qm_samples is None) or t.size < 32:
            return cands
        w0 = float(motor_fit.window_s) if savgol and np.isfinite(motor_fit.window_s) else 0.0
        src = np.asarray(qm_samples, float) if qm_samples is not None else motor_fit.evaluate(t, order=0)[0]
        ok = np.isfinite(src)
        if ok.sum() < 32:
            return cands
        s0 = float(motor_fit.sigma)
        for w in self.encoder_windows_s:
            if w > 1.2 * w0:
                f = SavGolSmoother(float(w)).fit(t[ok], src[ok])
                if np.isfinite(s0) and f.sigma > 0:
                    # the residual of a window wider than GCV's holds the motor's kinks, not
                    # noise: the encoder noise is GCV's, through this window's filter
                    r = s0 / f.sigma
                    f = replace(f, sigma=s0, noise_rms=s0, qd_noise=f.qd_noise * r, qdd_noise=f.qdd_noise * r)
                cands.append(f)
        return cands

    def _nominal_deflection(self, t, qm, qmd, qmdd, y, K, encoders=None):
        """The nominal deflection ``-tau_s / K`` smoothed at the window (and with the friction
        on the side of the spring) that best explains eq. 2-4: the transmitted torque is
        ``tau_s = y`` when the friction acts on the link (thesis eq. 2-1..2-3) and
        ``y - f(qmd)`` when it acts on the motor side; the link acceleration
        ``qmdd + delta''`` of each candidate enters the Coulomb + viscous regression of eq. 2-4
        and the candidate with the smallest residual wins. (The markers cannot see the
        deflection's fast part: 0.001 deg at a 40 Hz transmission resonance, under their noise;
        the dynamics can.) ``encoders``: further smoothings of the encoder angle
        (:meth:`_encoder_candidates`, each a SmoothFit with a window): each is tried with
        the deflection smoothed at its own window (the link angle ``qm + delta`` smoothed as
        one signal) and alone. Returns (SmoothFit of the nominal deflection, side, index of
        the encoder smoothing: 0 the given ``qm``, k the ``encoders[k - 1]``)."""
        peak = float(np.max(np.abs(qmd))) if qmd.size else 0.0
        keep = np.abs(qmd) >= self.rest_frac * peak
        if keep.sum() < 16 or peak <= 0:
            return SavGolSmoother("auto").fit(t, -y / K), "link", 0

        def rss_of(q, qd, qdd):
            return self._eq24_rss(q, qd, qdd, y, keep, coef=False)

        rss0, b0 = self._eq24_rss(qm, qmd, qmdd, y, keep)
        eps = self.rest_frac * peak
        f_motor = laws.coulomb_viscous(qmd, b0[3], b0[4], sign=lambda v: laws.smooth_sign(v, eps))
        sides = {"link": -y / K, "motor": -(y - f_motor) / K}
        fits: dict = {}     # (side, windows in samples) -> the crossfit smoothing
        grids = {side: _crossfit_grids(t, x) for side, x in sides.items()}

        def crossfit(side, w):
            """(smoothing of the side's deflection at ``w``, whether it is new): windows that
            round to the same samples share one smoothing."""
            key = (side,) + _crossfit_windows(grids[side], w)
            new = key not in fits
            if new:
                fits[key] = _crossfit_smooth(t, sides[side], w)
            return fits[key], new

        best = (rss0, None, None, 0)            # no deflection unless one explains eq. 2-4 better
        for side in sides:                      # 2 sides x a few windows: each one vectorised
            for w in self.windows_s:
                sm, new = crossfit(side, float(w))
                if not new:                     # the same candidate again: the same residual
                    continue
                d0, d1, d2 = sm.grid[1:]              # (sm is on the samples t)
                rss, _ = rss_of(qm + d0, qmd + d1, qmdd + d2)
                if rss < best[0]:
                    best = (rss, sm, side, 0)
        for k, enc in enumerate(encoders or (), start=1):
            em, emd, emdd = enc.evaluate(t)
            rss, _ = rss_of(em, emd, emdd)
            if rss < best[0]:
                best = (rss, None, None, k)
            for side in sides:
                sm, _ = crossfit(side, float(enc.window_s))
                d0, d1, d2 = sm.grid[1:]              # (sm is on the samples t)
                rss, _ = rss_of(em + d0, emd + d1, emdd + d2)
                if rss < best[0]:
                    best = (rss, sm, side, k)
        if best[1] is None:
            zero = np.zeros_like(t)
            return SmoothFit("none", 0.0, 0.0, int(t.size), float(t[0]), float(t[-1]), None, float("nan"),
                             0.0, (t, zero, zero, zero), sigma=0.0, qd_noise=0.0, qdd_noise=0.0,
                             bandwidth_hz=0.0), None, best[3]
        return best[1], best[2], best[3]

    def fit(self, time, motor_fit: SmoothFit, t_marker=None, q_marker=None, y=None,
            stiffness: float | None = None, _nominal=None, qm_samples=None,
            _motor=None, _markers=None) -> LinkState:
        """``time``: robot-log samples where the state is wanted (inside ``motor_fit``'s span);
        ``t_marker`` (already on the robot clock), ``q_marker``: marker link angle (NaN in gaps);
        ``y``: the transmitted torque on ``time`` (eq. 2-4 right-hand side), with ``stiffness``
        the declared K (N m/rad); without them the deflection is offset + slow part only.
        ``qm_samples``: the raw encoder angle on ``time`` (optional): with ``y`` and
        ``stiffness`` the encoder is re-smoothed at the window that, with the deflection's,
        best explains eq. 2-4 (:meth:`_encoder_candidates`); the state's ``motor_fit`` is the
        smoothing used. ``_motor``: ``motor_fit.evaluate(time)`` when the caller has it;
        ``_markers``: ``(markers minus motor_fit, the cosine basis at the marker times)`` when a
        refit of the same call has them."""
        t = np.asarray(time, float)
        qm, qmd, qmdd = motor_fit.evaluate(t) if _motor is None else _motor
        mq, mqd, mqdd = (motor_fit.sigma, motor_fit.qd_noise, motor_fit.qdd_noise)

        def nominal_and_encoder():
            """(nominal, side, encoder fit, its q, qd, qdd) chosen by eq. 2-4."""
            encs = self._encoder_candidates(t, motor_fit, qm_samples)[1:]
            nom, sd, k = self._nominal_deflection(t, qm, qmd, qmdd, np.asarray(y, float), float(stiffness),
                                                  encs)
            if k == 0:
                return nom, sd, motor_fit, qm, qmd, qmdd
            return (nom, sd, encs[k - 1]) + tuple(encs[k - 1].evaluate(t))
        if q_marker is None:
            if y is None or stiffness is None or not stiffness > 0:
                errs = {"q": float(mq), "qd": float(mqd), "qdd": float(mqdd)}
                return LinkState(t, qm, qmd, qmdd, "encoder", motor_fit, None, errs)
            # no markers: the encoder plus the nominal deflection (declared stiffness, gain 1)
            if self.nominal_smoother is None:
                nominal, side, motor_fit, qm, qmd, qmdd = nominal_and_encoder()
                mq, mqd, mqdd = (motor_fit.sigma, motor_fit.qd_noise, motor_fit.qdd_noise)
            else:
                nominal, side = self.nominal_smoother.fit(t, -np.asarray(y, float) / float(stiffness)), None
            d = nominal.evaluate(t)
            errs = {"q": float(np.hypot(mq, nominal.sigma)), "qd": float(np.hypot(mqd, nominal.qd_noise)),
                    "qdd": float(np.hypot(mqdd, nominal.qdd_noise))}
            return LinkState(t, qm + d[0], qmd + d[1], qmdd + d[2], "encoder+nominal_deflection", motor_fit,
                             None, errs, float("nan"), nominal, side)
        tm = np.asarray(t_marker, float)
        qk = np.asarray(q_marker, float)
        ok = np.isfinite(tm) & np.isfinite(qk) & (tm >= t[0]) & (tm <= t[-1])
        if ok.sum() < 8:
            raise InputError(f"only {int(ok.sum())} marker samples overlap the robot log")
        tm, qk = tm[ok], qk[ok]
        nominal = none_fit = None
        side = None
        use_gain = self.fit_gain and y is not None and stiffness is not None and stiffness > 0
        if y is not None and stiffness is not None and stiffness > 0:
            if _nominal is not None:
                nominal, side = _nominal
            elif self.nominal_smoother is None:
                nominal, side, motor_fit, qm, qmd, qmdd = nominal_and_encoder()
                mq, mqd, mqdd = (motor_fit.sigma, motor_fit.qd_noise, motor_fit.qdd_noise)
            else:
                nominal = self.nominal_smoother.fit(t, -np.asarray(y, float) / float(stiffness))
            if nominal.method == "none" and use_gain:
                # the dynamics see no deflection at the declared stiffness; the markers may still
                # see one (a drive softer than declared): offer them the slow nominal deflection
                none_fit = nominal
                nominal = _crossfit_smooth(t, -np.asarray(y, float) / float(stiffness), self.windows_s[-1])
            elif nominal.method == "none":
                use_gain = False
            dn = nominal.evaluate(t)
            dn_m = nominal.evaluate(tm, order=0)[0]
        else:
            dn = (np.zeros_like(t),) * 3
            dn_m = np.zeros_like(tm)
        t0, D = float(t[0]), float(max(t[-1] - t[0], 1e-9))
        m_cap = int(min(np.floor(2 * D * self.max_bandwidth_hz), tm.size // 10))
        cands = [0] + [m for m in 2 ** np.arange(0, 16) if m <= m_cap]
        if _markers is None:
            _markers = (qk - motor_fit.evaluate(tm, order=0)[0], _cosine_basis(tm, t0, D, cands[-1]))
        d_meas, basis = _markers
        fixed = [np.ones_like(tm)] + ([dn_m] if use_gain else [])
        target = d_meas - (0.0 if use_gain else dn_m)
        X = np.column_stack(fixed + [basis])
        # all candidate sizes from one triangular factor (columns ordered by frequency) of the
        # design with the target appended: its last column is Q^T target
        cum = np.cumsum(_ordered_projections(X, target))
        total = float(target @ target)
        nf = len(fixed)
        n = tm.size
        ks = np.array([nf + m for m in cands])
        rss = np.maximum(total - cum[ks - 1], 1e-300)
        bic = n * np.log(rss / n) + ks * np.log(n)
        M = int(cands[int(np.argmin(bic))])
        Xm = X[:, :nf + M]
        coef, *_ = np.linalg.lstsq(Xm, target, rcond=None)
        r = target - Xm @ coef
        sigma = float(np.sqrt(r @ r / max(n - Xm.shape[1], 1)))
        cov = sigma ** 2 * np.linalg.pinv(Xm.T @ Xm)
        offset = float(coef[0])
        gain = float(coef[1]) if use_gain else 1.0
        gain_se = float(np.sqrt(cov[1, 1])) if use_gain else 0.0
        c = coef[nf:]
        # deflection and its derivatives on the log samples, with their standard deviations
        parts, sds = [], []
        for k in range(3):
            B = _cosine_basis(t, t0, D, M, k) if M else np.zeros((t.size, 0))
            cols = [np.full(t.size, 1.0 if k == 0 else 0.0)] + ([dn[k]] if use_gain else []) + [B]
            Xe = np.column_stack(cols)
            val = Xe @ coef + (0.0 if use_gain else dn[k])
            parts.append(val)
            sds.append(float(np.sqrt(np.mean(np.sum((Xe @ cov) * Xe, axis=1)))))
        fixed_gain = 1.0 if nominal is not None else float("nan")
        defl = DeflectionFit(offset, gain if use_gain else fixed_gain, gain_se if use_gain else 0.0 * fixed_gain,
                             np.asarray(c, float), cov, t0, D, sigma, int(n),
                             float(np.sqrt(np.mean(dn[0] ** 2))) if nominal is not None else float("nan"))
        q, qd, qdd = qm + parts[0], qmd + parts[1], qmdd + parts[2]
        nom_sd = (0.0, 0.0, 0.0)
        if nominal is not None:       # noise of the smoothed nominal deflection, scaled by the gain
            nom_sd = (nominal.sigma, nominal.qd_noise, nominal.qdd_noise)
        g = abs(gain)
        errs = {"q": float(np.sqrt(mq ** 2 + sds[0] ** 2 + (g * nom_sd[0]) ** 2)),
                "qd": float(np.sqrt(mqd ** 2 + sds[1] ** 2 + (g * nom_sd[1]) ** 2)),
                "qdd": float(np.sqrt(mqdd ** 2 + sds[2] ** 2 + (g * nom_sd[2]) ** 2))}
        marker_rms = float(np.sqrt(np.mean(r ** 2)))
        if use_gain:
            # is the gain determined by the markers? judged on offset + gain alone (the slow
            # cosines are collinear with a slow deflection and would hide it)
            X0 = X[:, :nf]
            b0, *_ = np.linalg.lstsq(X0, target, rcond=None)
            r0 = target - X0 @ b0
            s0 = float(np.sqrt(r0 @ r0 / max(n - nf, 1)))
            se0 = s0 * float(np.sqrt(np.linalg.pinv(X0.T @ X0)[1, 1]))
            refit = abs(float(b0[1]) - 1.0) < 2.0 * se0
        else:
            refit = False
        if use_gain and not refit:
            # the markers see the slow deflection only (their noise hides the transmission's
            # fast part): keep their gain only if the dynamics (eq. 2-4) agree better with it
            # than with the declared stiffness
            yy = np.asarray(y, float)
            keep = np.abs(qmd) >= self.rest_frac * float(np.max(np.abs(qmd)))
            alt = 0.0 if none_fit is not None else 1.0      # the dynamics' own choice
            d1 = qm + parts[0] - (gain - alt) * dn[0], qmd + parts[1] - (gain - alt) * dn[1], \
                qmdd + parts[2] - (gain - alt) * dn[2]
            refit = (self._eq24_rss(*d1, yy, keep, coef=False)[0]
                     <= self._eq24_rss(q, qd, qdd, yy, keep, coef=False)[0])
        if refit and none_fit is not None:
            return LinkStateEstimator(self.max_bandwidth_hz, False, self.nominal_smoother).fit(
                time, motor_fit, t_marker, q_marker, y, stiffness, _nominal=(none_fit, None),
                _motor=(qm, qmd, qmdd), _markers=_markers)
        if refit:
            # the markers do not tell the gain from the declared stiffness's: keep K as declared
            return LinkStateEstimator(self.max_bandwidth_hz, False, self.nominal_smoother).fit(
                time, motor_fit, t_marker, q_marker, y, stiffness, _nominal=(nominal, side),
                _motor=(qm, qmd, qmdd), _markers=_markers)
        return LinkState(t, q, qd, qdd, "encoder+deflection", motor_fit, defl, errs, marker_rms, nominal,
                         side)


def prepare_joint_signals(joint: int, log_time, qm, tau, angle_time=None, q_link=None,
                          time_offset: float | str = 0.0, smoother=None,
                          link_smoother=None, link_method: str = "markers",
                          drive: tuple | None = None, link_estimator=None) -> JointSignals:
    """Put one joint's link angle, motor angle and torque on the robot log's samples.

    The link angle (marker clock, ``t_robot = t_marker + time_offset`` [1]_) and the motor
    angle and torque (robot clock) on the log's samples, both smoothed with eq. 3-2 fits and
    differentiated analytically [2]_. For ``"markers"`` the link fit reuses the motor fit's
    fundamental (same commanded trajectory) and chooses its own number of harmonics. Samples
    outside the span of both signals are dropped.

    Parameters
    ----------
    joint : int
        The joint, 1-based (for naming only).
    log_time : array_like
        (T,) the robot log's sample times (s).
    qm, tau : array_like
        (T,) that joint's motor angle (rad, link side) and torque (N m) columns.
    angle_time : array_like, optional
        Marker times of ``q_link`` (s, marker clock).
    q_link : array_like, optional
        Link angle from the markers (rad; NaN in gaps); None: the motor angle stands in for
        the link angle (``link_source="motor"``).
    time_offset : float or {"estimate"}, optional
        Seconds added to marker times (default 0), or ``"estimate"``
        (:func:`ident.signals.smoothing.estimate_time_offset`).
    smoother : object, optional
        Smoother of the motor angle; default :class:`ident.signals.smoothing.FourierSmoother`.
    link_smoother : object, optional
        Smoother of the link angle; default a Fourier smoother at the motor fit's fundamental.
    link_method : {"markers", "encoder+deflection"}, optional
        ``"markers"`` (default, the thesis's own way: the marker angle smoothed and
        differentiated by itself) or ``"encoder+deflection"`` (:class:`LinkStateEstimator`:
        the smoothed encoder angle plus the deflection the markers support).
    drive : tuple, optional
        ``(J, B, K)``: motor inertia, viscous coefficient and declared stiffness (K NaN or
        None: no nominal deflection) for the nominal deflection ``-(u - J qmdd - B qmd) / K``.
    link_estimator : LinkStateEstimator, optional
        The estimator of ``"encoder+deflection"``; default settings.

    Returns
    -------
    ident.signals.smoothing.JointSignals
        The joint's signals on the log's samples, with the fits and their errors.

    Raises
    ------
    ValueError
        If ``link_method`` is unknown.

    References
    ----------
    .. [1] jointlab data format (docs/format.md), sec. campaign.toml.
    .. [2] PA10 thesis (seeds 002), eq. 2-4, 3-2.
    """
    smoother = smoother if smoother is not None else FourierSmoother()
    log_time = np.asarray(log_time, float)
    qm = np.asarray(qm, float)
    tau = np.asarray(tau, float)
    fm = smoother.fit(log_time, qm)
    if q_link is None and link_method == "encoder+deflection" and drive is not None \
            and drive[2] is not None and np.isfinite(drive[2]) and drive[2] > 0:
        return _encoder_deflection_signals(joint, log_time, qm, tau, None, None, fm, 0.0, drive,
                                           link_estimator)
    if q_link is None:
        fl, source, offset = fm, "motor", 0.0
    else:
        ta = np.asarray(angle_time, float)
        offset = estimate_time_offset(ta, q_link, fm) if time_offset == "estimate" else float(time_offset)
        ta = ta + offset
        ql = np.asarray(q_link, float)
        if link_method == "encoder+deflection" and link_smoother is None:
            return _encoder_deflection_signals(joint, log_time, qm, tau, ta, ql, fm, offset, drive,
                                               link_estimator)
        if link_method not in ("markers", "encoder+deflection"):
            raise ValueError(f"link_method must be 'encoder+deflection' or 'markers', got {link_method!r}")
        if link_smoother is None and isinstance(smoother, FourierSmoother):
            # same commanded trajectory: the motor fit's fundamental and moving span (the
            # noisier link angle would blur the rest detection)
            link_smoother = FourierSmoother(
                wf=fm.wf if fm.method == "fourier" else None, max_harmonics=smoother.max_harmonics,
                periodic=None if fm.method == "fourier" else False,
                periodic_ratio=smoother.periodic_ratio, periodic_atol=smoother.periodic_atol,
                fallback=smoother.fallback, trim_rest=False)
            if fm.method == "fourier":
                inside = (ta >= fm.t_start) & (ta <= fm.t_end)
                ta, ql = ta[inside], ql[inside]
        elif link_smoother is None:
            link_smoother = smoother
        fl = link_smoother.fit(ta, ql)
        source = "mocap"
    lo, hi = max(fm.t_start, fl.t_start), min(fm.t_end, fl.t_end)
    keep = (log_time >= lo) & (log_time <= hi) & np.isfinite(tau) & np.isfinite(qm)
    t = log_time[keep]
    if t.size < 8:
        raise InputError(f"joint {joint}: the link angles and the robot log overlap in only {t.size} samples")
    q, qd, qdd = fl.evaluate(t)
    qms, qmd, qmdd = fm.evaluate(t)
    return JointSignals(joint, t, q, qd, qdd, qms, qmd, qmdd, tau[keep], fl, fm, source, offset)


def _encoder_deflection_signals(joint, log_time, qm, tau, ta, ql, fm, offset, drive, estimator):
    """:func:`prepare_joint_signals` with the link state of :class:`LinkStateEstimator`."""
    if ql is None:                     # no markers: encoder + nominal deflection
        lo, hi = fm.t_start, fm.t_end
    else:
        fin = np.isfinite(ta) & np.isfinite(ql)
        if fin.sum() < 8:
            raise InputError(f"joint {joint}: only {int(fin.sum())} finite link-angle samples")
        lo, hi = max(fm.t_start, float(ta[fin][0])), min(fm.t_end, float(ta[fin][-1]))
    keep = (log_time >= lo) & (log_time <= hi) & np.isfinite(tau) & np.isfinite(qm)
    t = log_time[keep]
    if t.size < 8:
        raise InputError(f"joint {joint}: the link angles and the robot log overlap in only {t.size} samples")
    qms, qmd, qmdd = fm.evaluate(t)
    y = K = None
    if drive is not None:
        J, B, K = (float(x) if x is not None else float("nan") for x in drive)
        y = tau[keep] - J * qmdd - B * qmd
        K = K if np.isfinite(K) and K > 0 else None
    est = estimator if estimator is not None else LinkStateEstimator()
    st = est.fit(t, fm, ta, ql, y if K is not None else None, K, qm_samples=qm[keep],
                 _motor=(qms, qmd, qmdd))
    return JointSignals(joint, t, st.q, st.qd, st.qdd, qms, qmd, qmdd, tau[keep], st.as_smooth_fit(), fm,
                        "mocap" if ql is not None else "motor", offset, st.to_dict())
