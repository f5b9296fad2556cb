"""The one-link flexible-joint model of the thesis (002, eq. 2-4) and its friction fits.

Eq. 2-4 moves the motor side to the right-hand side::

    I qdd - m g lx sin(q) + m g ly cos(q) + f(qd) = u - J qmdd - B qmd      (2-4)

so the target is ``y = u - J qmdd - B qmd`` (``J``, ``B`` from drives.toml, link side) and the
regressor uses link-angle derivatives: ``[qdd, -sin q, cos q]`` for the rigid parameters
``(I, mglx, mgly)`` followed by the friction model's columns (for Coulomb + viscous, eq. 2-5,
``[sign qd, qd]``: the thesis's ``R``).

Friction models (FORMAT.md names): ``cv`` by linear least squares; ``stribeck`` (eq. 2-6)
and ``hyperbolic`` (eq. 2-7) by bounded nonlinear least squares, multi-start, with the initial
guess from the Coulomb + viscous fit, through :func:`ident.friction.fit.fit_friction`: the
parameters the model is linear in (``Fk, Fv, Fs``; ``g1, g4, g6``) and the rigid ones are
eliminated by variable projection, so only the nonlinear ones (``Vc``; ``g2, g3, g5``) are
searched, from a start scaled by the Coulomb + viscous fit and the data's peak speed.

Degenerate forms the thesis reports (ch. 5) are detected and named (:func:`name_degenerate`):

- ``stribeck_as_cv``: ``Fs`` ~ 0 (under 2 % of the friction scale or within two standard
  errors of 0), the Stribeck model is Coulomb + viscous (thesis joint 3);
- ``stribeck_coulomb_in_Fs``: ``Fk`` ~ 0 with small ``Vc`` and negative ``Fs``: Coulomb
  friction is carried by ``-Fs`` (thesis joint 5). When ``Vc`` falls below the slowest
  sampled speeds only ``Fk - Fs`` is identifiable and the fit is reported in this form
  (``Fk = 0``);
- ``stribeck_Vc_at_bound``: ``Vc`` sits on a bound (thesis joints 2, 3: ``Vc = 1.00``, CV 0);
- ``hyperbolic_stribeck_nonunique``: ``g1``, ``g2``, ``g3`` poorly determined (relative
  standard error > 50 %, or ``g2`` ~ ``g3`` so the Stribeck term vanishes): non-unique
  combinations give the same curve (thesis, hyperbolic model discussion);
- ``<model>_degenerate``: none of the above, but :func:`ident.friction.fit.fit_friction`
  flagged the fit (a nonlinear parameter at a bound, a near-singular Jacobian); its sentence
  is kept in ``FrictionFit.note``. ``stribeck_Vc_at_bound`` needs user ``bounds`` on ``Vc``.
"""
from __future__ import annotations

import dataclasses

import numpy as np

from ident.friction import MODELS
from ident.friction.base import CoulombViscous
from ident.friction.constants import REST_FRAC
from ident.friction.fit import FrictionFit, eiv_bias, fit_friction
from ident.friction.presliding import presliding_length, reversal_displacement
from ident.signals.blas import one_blas_thread


def model_class(name: str):
    """The friction model class registered under a name of the data format.

    ``cv``, ``stribeck``, ``hyperbolic`` (thesis eq. 2-5 to 2-7 [1]_), ``arctan``, ``dm1``,
    ``dm2`` (Indri & Trapani [2]_): the keys of ``ident.friction.MODELS`` [3]_.

    Parameters
    ----------
    name : str
        The model's name.

    Returns
    -------
    type
        The :class:`ident.friction.FrictionModel` subclass.

    Raises
    ------
    KeyError
        If no model is registered under ``name`` (the message lists the known ones).

    References
    ----------
    .. [1] PA10 thesis (seeds 002), eq. 2-5 to 2-7.
    .. [2] Indri & Trapani 2020 (seeds 001), eq. 1-2, 5-9.
    .. [3] jointlab data format (docs/format.md), sec. What the workbench writes.

    Examples
    --------
    >>> model_class("cv").__name__
    'CoulombViscous'
    """
    if name in MODELS:
        return MODELS[name]
    raise KeyError(f"unknown friction model {name!r} (known: {', '.join(sorted(MODELS))})")


RIGID_NAMES = ("I", "mglx", "mgly")

__all__ = ["RIGID_NAMES", "onelink_target", "onelink_regressor",
           "OneLinkIdentifier", "fit_cv_linear", "name_degenerate", "initial_guess", "with_eiv"]


def onelink_target(u, qmd, qmdd, J: float, B: float) -> np.ndarray:
    r"""Torque left for the link side: the right-hand side of thesis eq. 2-4.

    .. math::

        y = u - J \ddot{q}_m - B \dot{q}_m

    the drive torque less the motor side's inertia and viscous torques [1]_.

    Parameters
    ----------
    u : array_like
        (T,) drive torque (N m).
    qmd, qmdd : array_like
        (T,) motor velocity (rad/s) and acceleration (rad/s^2), link side.
    J : float
        Motor inertia, link side (kg m^2).
    B : float
        Motor viscous coefficient, link side (N m s/rad).

    Returns
    -------
    numpy.ndarray
        (T,) the target ``y`` (N m).

    References
    ----------
    .. [1] PA10 thesis (seeds 002), eq. 2-4.

    Examples
    --------
    >>> onelink_target([1.0], qmd=[2.0], qmdd=[10.0], J=0.05, B=0.1).tolist()
    [0.3]
    """
    return np.asarray(u, float) - J * np.asarray(qmdd, float) - B * np.asarray(qmd, float)


def onelink_regressor(q, qdd) -> np.ndarray:
    """The rigid-body columns of the one-link regressor of thesis eq. 2-4.

    ``[qdd, -sin q, cos q]`` for the parameters ``(I, mglx, mgly)`` of
    ``I qdd - m g lx sin q + m g ly cos q`` [1]_; the friction model's columns follow them.

    Parameters
    ----------
    q : array_like
        (T,) link angle (rad).
    qdd : array_like
        (T,) link acceleration (rad/s^2).

    Returns
    -------
    numpy.ndarray
        (T, 3) regressor columns.

    References
    ----------
    .. [1] PA10 thesis (seeds 002), eq. 2-4.
    """
    q = np.asarray(q, float)
    return np.column_stack([np.asarray(qdd, float), -np.sin(q), np.cos(q)])


def fit_cv_linear(q, qd, qdd, y, weights=None) -> FrictionFit:
    """Fit Coulomb + viscous friction through eq. 2-4 by linear least squares.

    The thesis's regressor ``R = [qdd, -sin q, cos q, sign qd, qd]`` (after eq. 2-5 [1]_) for
    ``(I, mglx, mgly, c, v)``, through :func:`ident.friction.fit.fit_friction`.

    Parameters
    ----------
    q, qd, qdd : array_like
        (T,) link angle (rad), velocity (rad/s), acceleration (rad/s^2).
    y : array_like
        (T,) target torque (:func:`onelink_target`, N m).
    weights : array_like, optional
        (T,) per-sample weights.

    Returns
    -------
    FrictionFit
        The friction parameters ``c``, ``v``, the rigid ones in ``rigid``, and ``flags``
        (physically impossible values).

    References
    ----------
    .. [1] PA10 thesis (seeds 002), eq. 2-4, 2-5.
    """
    f = fit_friction(CoulombViscous, qd, y, X_extra=onelink_regressor(q, qdd), extra_names=RIGID_NAMES,
                     weights=weights)
    return dataclasses.replace(f, flags=f.model.violations())


def _regressor_noise(q, errors: dict) -> np.ndarray:
    """(T, 5, 5) per-sample covariance of the cv regressor's columns ``[qdd, -sin q, cos q,
    sign qd, qd]`` from independent errors of standard deviation ``errors`` q, qd, qdd (rad,
    rad/s, rad/s^2); the sign column is taken as exact (slow samples are left out)."""
    q = np.asarray(q, float)
    sq, sqd, sqdd = (float(errors.get(k, 0.0) or 0.0) for k in ("q", "qd", "qdd"))
    S = np.zeros((q.size, 5, 5))
    S[:, 0, 0] = sqdd ** 2
    c, s_ = np.cos(q), np.sin(q)
    S[:, 1, 1] = sq ** 2 * c ** 2                      # d(-sin q) = -cos q dq
    S[:, 2, 2] = sq ** 2 * s_ ** 2                     # d(cos q) = -sin q dq
    S[:, 1, 2] = S[:, 2, 1] = sq ** 2 * c * s_
    S[:, 4, 4] = sqd ** 2
    return S


def with_eiv(fit: FrictionFit, q, qd, qdd, errors: dict) -> FrictionFit:
    """``fit`` (cv, eq. 2-4) with its errors-in-variables bias (:func:`ident.friction.fit.eiv_bias`)
    for link-state errors ``errors``; the bias per parameter, its ratio to the standard error
    and whether any exceeds it go into ``fit.eiv`` (and a sentence into ``degenerate``)."""
    X = np.hstack([onelink_regressor(q, qdd), CoulombViscous.regressor(qd)])
    names = RIGID_NAMES + CoulombViscous.param_names
    vals = {**fit.rigid, **fit.params}
    beta = np.array([vals[k] for k in names])
    se = np.array([fit.stderr[k] for k in names])
    b = eiv_bias(X, beta, se, _regressor_noise(q, errors))
    eiv = {"errors": {k: float(v) for k, v in errors.items()},
           "bias": dict(zip(names, map(float, b["bias"]))),
           "bias_over_se": dict(zip(names, map(float, b["ratio"]))), "exceeds_se": b["exceeds_se"]}
    deg = fit.degenerate
    if b["exceeds_se"]:
        worst = names[int(np.argmax(b["ratio"]))]
        msg = (f"errors in variables: the regressor noise biases {worst} by "
               f"{b['bias'][names.index(worst)]:.3g} ({b['ratio'].max():.1f} standard errors)")
        deg = f"{deg}; {msg}" if deg else msg
    return dataclasses.replace(fit, eiv=eiv, degenerate=deg)


def initial_guess(model: str, cv: FrictionFit, qd) -> dict:
    """Start of the nonlinear fits from the Coulomb + viscous fit (thesis: "an initial guess
    from the Coulomb + Viscous model"): the model's ``initial_guess``."""
    vmax = float(np.max(np.abs(qd))) if np.size(qd) else 1.0
    return model_class(model).initial_guess(cv.params["c"], cv.params["v"], vmax)


def name_degenerate(model: str, params: dict, stderr: dict, qd=None, bounds=None,
                    fit_scale: float | None = None) -> str | None:
    """Name the thesis's degenerate forms (module docstring) or return ``None``: the one
    classifier of one-link fits (``FrictionFit.form``), the model's ``degenerate_form``.
    ``bounds``: {param: (lo, hi)} the fit was given; ``fit_scale``: the torque scale "~ 0" is
    judged against (the fits pass the 99th percentile of the friction torque, the scale of the
    models' own ``degeneracy`` sentences); default ``max(|Fk|, |Fs|)``."""
    return model_class(model).degenerate_form(params, stderr, qd, bounds, fit_scale)


class OneLinkIdentifier:
    r"""Identifier of friction models through the one-link model of thesis eq. 2-4.

    .. math::

        I \ddot{q} - m g l_x \sin q + m g l_y \cos q + f(\dot{q})
        = u - J \ddot{q}_m - B \dot{q}_m

    with ``f`` one of the friction models (eq. 2-5 to 2-7 [1]_): Coulomb + viscous by linear
    least squares, the others by multi-start nonlinear least squares started from it
    (module docstring). Samples slower than ``rest_frac`` of the peak speed are left out: at
    standstill the friction is static (it holds whatever the gravity and motor torques
    leave), which eq. 2-5 to 2-7 do not describe (``sign(0) = 0``), and a smoothed speed's
    sign there is noise; near reversals a real joint sticks for a moment, which a smooth
    (Fourier) speed cannot resolve. With ``presliding`` (default) the samples still in the
    friction's rise after a velocity reversal are left out too: the rise with the displacement
    since the reversal is fitted to the friction a Coulomb + viscous fit shows
    (:func:`ident.friction.presliding.presliding_length`) and, where it explains at least 1 %
    of that fit's residual, the samples closer to the reversal than its end are dropped
    (``presliding_``: the rise, its end, the Coulomb level without the cut and the fraction of
    the samples above the rest cut kept, after :meth:`fit`; None without one).

    The viscous coefficient is in the LINK-ONLY basis: the motor viscous ``B`` of drives.toml is
    removed in the target ``y = u - J qmdd - B qmd``, so ``v`` (``Fv``, ``g6``) is the viscous
    friction beyond the declared motor viscous; link + motor viscous is ``v + B``.

    Parameters
    ----------
    models : sequence of str, optional
        Friction models by their data-format names [2]_ (default cv, stribeck, hyperbolic).
    n_starts : int, optional
        Starts of the multi-start nonlinear fits (default 8).
    seed : int, optional
        Seed of the starts (default 0).
    bounds : dict, optional
        {model: {param: (lo, hi)}}; default the models' own data-scaled bounds (the thesis
        bounded ``Vc`` to ``(0, 1]``).
    rest_frac : float, optional
        Speed fraction of the peak below which samples are left out.
    presliding : bool, optional
        Leave out the samples still in the presliding rise after each velocity reversal
        (default True).

    References
    ----------
    .. [1] PA10 thesis (seeds 002), eq. 2-4 to 2-7.
    .. [2] jointlab data format (docs/format.md), sec. What the workbench writes.
    """

    def __init__(self, models=("cv", "stribeck", "hyperbolic"), n_starts: int = 8, seed: int = 0,
                 bounds: dict | None = None, rest_frac: float = REST_FRAC, presliding: bool = True):
        self.models = tuple(models)
        self.n_starts = int(n_starts)
        self.seed = int(seed)
        self.bounds = dict(bounds) if bounds else {}
        self.rest_frac = float(rest_frac)
        self.presliding = bool(presliding)
        self.presliding_ = None

    def fit_signals(self, sig, J: float, B: float) -> dict:
        """Fit every model to one joint's signals, the target built by eq. 2-4 [1]_.

        :func:`onelink_target` from the signals, then :meth:`fit` with the link state's
        errors (the cv fit's errors-in-variables bias).

        Parameters
        ----------
        sig : ident.signals.smoothing.JointSignals
            The joint's signals on one time base.
        J : float
            Motor inertia, link side (kg m^2).
        B : float
            Motor viscous coefficient, link side (N m s/rad).

        Returns
        -------
        dict
            {model name: FrictionFit}, as :meth:`fit`.

        References
        ----------
        .. [1] PA10 thesis (seeds 002), eq. 2-4.
        """
        y = onelink_target(sig.tau, sig.qmd, sig.qmdd, J, B)
        return self.fit(sig.q, sig.qd, sig.qdd, y, errors=sig.errors)

    def fit(self, q, qd, qdd, y, errors: dict | None = None) -> dict:
        """Fit every model through eq. 2-4 [1]_ to a target torque.

        Parameters
        ----------
        q, qd, qdd : array_like
            (T,) link angle (rad), velocity (rad/s), acceleration (rad/s^2).
        y : array_like
            (T,) target torque (:func:`onelink_target`, N m).
        errors : dict, optional
            Standard deviations of ``q``, ``qd``, ``qdd`` (keys ``"q"``, ``"qd"``, ``"qdd"``);
            given, the cv fit carries its errors-in-variables bias in ``eiv``.

        Returns
        -------
        dict
            {model name: FrictionFit} with ``form`` (the degenerate form's name, see the module
            docstring) and ``flags`` (physically impossible values).

        References
        ----------
        .. [1] PA10 thesis (seeds 002), eq. 2-4 to 2-7.
        """
        with one_blas_thread():
            return self._fit(q, qd, qdd, y, errors)

    def _fit(self, q, qd, qdd, y, errors=None) -> dict:
        q, qd, qdd, y = (np.asarray(a, float) for a in (q, qd, qdd, y))
        v_cut = self.rest_frac * float(np.max(np.abs(qd))) if self.rest_frac > 0 and qd.size else 0.0
        keep = np.abs(qd) >= v_cut if v_cut > 0 else np.ones(qd.size, bool)
        self.presliding_ = None
        cv = None                           # the Coulomb + viscous fit on the rows kept
        if self.presliding and int(keep.sum()) >= 20:
            keep, cv = self._presliding_rows(q, qd, qdd, y, keep, v_cut)
        q, qd, qdd, y = q[keep], qd[keep], qdd[keep], y[keep]
        if cv is None:
            cv = fit_cv_linear(q, qd, qdd, y)
        if errors and all(np.isfinite(float(errors.get(k, np.nan))) for k in ("q", "qd", "qdd")):
            cv = with_eiv(cv, q, qd, qdd, errors)
        out = {}
        for name in self.models:
            if name == "cv":
                out["cv"] = cv
                continue
            out[name] = self._fit_nonlinear(name, q, qd, qdd, y, cv)
        return out

    def _presliding_rows(self, q, qd, qdd, y, keep, v_cut):
        """``(keep less the samples still in the presliding rise after a velocity reversal, the
        Coulomb + viscous fit on those rows or None where the cut removed some)`` (the class
        docstring); sets ``presliding_``."""
        cv0 = fit_cv_linear(q[keep], qd[keep], qdd[keep], y[keep])
        f = y - onelink_regressor(q, qdd) @ np.array([cv0.extra[k] for k in RIGID_NAMES])
        s = reversal_displacement(q, qd, v_cut)
        p = presliding_length(s[keep], qd[keep], f[keep], v_cut)
        if p["end"] is None:
            return keep, cv0
        out = keep & (s >= p["end"])
        self.presliding_ = {**p, "coulomb_without_cut": float(cv0.model.params["c"]),
                            "kept": float(out.sum() / max(int(keep.sum()), 1))}
        return out, None

    def _fit_nonlinear(self, name, q, qd, qdd, y, cv) -> FrictionFit:
        cls = model_class(name)
        X = onelink_regressor(q, qdd)
        lin = cls.linear_params()
        x0 = {k: v for k, v in initial_guess(name, cv, qd).items() if k not in lin}
        bounds = self.bounds.get(name)
        ff = fit_friction(cls, qd, y, X_extra=X, extra_names=RIGID_NAMES, bounds=bounds, x0=x0 or None,
                          n_starts=self.n_starts, seed=self.seed)
        params = dict(ff.model.params)          # fit_friction returns the canonical representative
        se = {k: float(v) for k, v in ff.stderr.items()}
        params, se = cls.report_form(params, se, ff.cov, ff.names, qd)
        f_data = y - X @ np.array([ff.extra[k] for k in RIGID_NAMES])
        fit_scale = float(np.percentile(np.abs(f_data), 99.0)) if f_data.size else None
        deg = name_degenerate(name, params, se, qd, bounds, fit_scale)
        if deg is None and ff.degenerate:
            deg = f"{name}_degenerate"
        model = cls(**params)
        return dataclasses.replace(ff, model=model, stderr=se, form=deg, flags=model.violations(deg))
