"""Friction estimators: one interface for every model (thesis sec. 2-3/5, Indri & Trapani sec. III).

:func:`fit_friction` fits ``tau ~ X_extra @ beta + model(theta).torque(qd, qdd, dt)``, where the
columns of ``X_extra`` are nuisance terms estimated jointly (e.g. the thesis's one-link regressor
``[qdd, -sin q, cos q]`` of eq. 2-4 for inertia and gravity; Indri & Trapani instead subtract the
inverse dynamics, eq. 25-26, and pass no extra columns).

The strategy is chosen from the model's declared interface (:class:`ident.friction.base.FrictionModel`;
:func:`strategy_for`), each a small object with a ``fit`` method:

* models linear in all parameters (``cv``, thesis eq. 2-5): linear least squares
  (:class:`LinearStrategy`);
* models with nonlinear parameters (``stribeck`` eq. 2-6, ``hyperbolic`` eq. 2-7, ``dm1``/``dm2``
  eq. 5-9/24): bounded ``scipy.optimize.least_squares`` over the nonlinear parameters only, with
  ``beta`` and the parameters the model is linear in eliminated by variable projection (solved
  by linear least squares inside each residual evaluation); positive scale parameters are
  searched in log coordinates; seeded multi-start (start 0 at the model's data-scaled hint or
  ``x0``, the others uniform in the (log) bounds) (:class:`VarProStrategy`). If ``bounds``
  constrain a linear parameter or an extra column, all parameters are fitted jointly instead
  (:class:`JointStrategy`);
* static models with a ``vp_grid`` and ``design_grad`` (Stribeck, hyperbolic; issue 13's speed
  work): the extra columns are projected out once; the starts and a grid over the nonlinear
  parameters (48 values of ``Vc``; 20^3 of ``g2 > g3, g5`` plus the hump's limit
  ``g3 -> g2``) are scored by their profiled residual in array operations (every grid point
  from one Gram matrix of shared basis columns); only the ``n_refine`` (4) best distinct
  candidates among the starts and the grid's local minima are refined, with the analytic
  variable-projection Jacobian (Golub & Pereyra; through the SVD of the scaled design), the
  later ones with a 100-evaluation probe that continues only when below the best so far
  (:class:`GridVarProStrategy`);
* ``arctan`` (Indri & Trapani eq. 1-2, ``fit_method = "delta_grid"``): the delta grid search of
  eq. 27-28, :func:`fit_arctan` (:class:`DeltaGridStrategy`).

Uncertainty: the Jacobian of the prediction with respect to every parameter and extra at the
optimum, ``cov = sigma^2 (J^T W J)^-1`` with ``sigma^2 = RSS_w / (N - p)``. ``cond`` is the
condition number of the column-normalised weighted Jacobian (scale free). ``degenerate`` names
the degenerate form the fitted parameters take on these data (from the model's own check, a
nonlinear parameter at a bound, or a near-singular Jacobian).
"""
from __future__ import annotations

import functools
import inspect
from dataclasses import dataclass, field

import numpy as np
from scipy.ndimage import minimum_filter
from scipy.optimize import least_squares

from ident.friction.base import CoulombViscous, FrictionModel
from ident.friction.constants import KV_DEFAULT
from ident.friction.static import Arctan, _2_PI, s0
from ident.signals.blas import one_blas_thread

DELTA_GRID_STEP = 0.1
COND_DEGENERATE = 1e10


def default_delta_grid() -> np.ndarray:
    """Indri & Trapani sec. III-A: delta over [0, 100] with step 0.1."""
    return np.round(np.arange(0.0, 100.0 + 1e-9, DELTA_GRID_STEP), 10)


# --------------------------------------------------------------------------------------------
@dataclass(frozen=True, eq=False)
class FrictionFit:
    """A fitted friction model with its nuisance coefficients and diagnostics.

    The one result type of every friction fit: Indri & Trapani's [1]_, and the thesis's
    one-link fits of eq. 2-4 [2]_, whose extra columns are the rigid parameters
    ``I, mglx, mgly`` (:attr:`rigid`). :meth:`to_dict` gives the fits.json layout.

    Attributes
    ----------
    model : FrictionModel
        The fitted model (canonical representative of equivalent parameter sets).
    extra : dict
        Extra column name -> coefficient.
    stderr : dict
        Every parameter and extra -> standard error.
    cov : numpy.ndarray
        Covariance over ``names``, ``sigma^2 (J^T W J)^-1``.
    names : tuple
        ``param_names`` then the extra names.
    rms : float
        RMS of the residual (N m), weighted by ``weights`` when given.
    n : int
        Samples used.
    cond : float
        Condition number of the column-normalised weighted Jacobian.
    nfev : int
        Residual evaluations over all starts.
    converged : bool
        Whether the best start's optimiser converged.
    degenerate : str or None
        Sentences naming what these data do not determine; None: nothing.
    residuals : numpy.ndarray
        The residual ``tau - prediction`` per sample.
    diagnostics : dict
        The strategy used, starts and their costs, bounds and grid sizes.
    form : str or None
        The name of the thesis's degenerate form the parameters take
        (:func:`ident.model.onelink.name_degenerate`), or None.
    flags : tuple
        Physically impossible values (the model's ``violations``: a negative Coulomb or
        Stribeck level, wrong hyperbolic signs); a flagged fit is kept out of condition means.
    eiv : dict or None
        Errors-in-variables bias of the parameters implied by the regressor noise
        (:func:`eiv_bias`), or None.

    References
    ----------
    .. [1] Indri & Trapani 2020 (seeds 001), sec. III.
    .. [2] PA10 thesis (seeds 002), eq. 2-4 and Tables 5-1 to 5-3.
    """

    model: FrictionModel
    extra: dict                 # extra column name -> coefficient
    stderr: dict                # every parameter and extra -> standard error
    cov: np.ndarray             # covariance over ``names``
    names: tuple                # param_names then extra names
    rms: float                  # RMS of the residual (weighted mean square if weights), N m
    n: int                      # samples used
    cond: float                 # condition number of the column-normalised Jacobian
    nfev: int                   # residual evaluations over all starts
    converged: bool
    degenerate: str | None
    residuals: np.ndarray = field(repr=False)
    diagnostics: dict = field(default_factory=dict)
    form: str | None = None
    flags: tuple = ()
    eiv: dict | None = None

    @property
    def params(self) -> dict:
        return self.model.params

    @property
    def rigid(self) -> dict:
        """The one-link rigid parameters (``I, mglx, mgly``) among the extra coefficients."""
        return {k: v for k, v in self.extra.items() if k in ("I", "mglx", "mgly")}

    @property
    def note(self) -> str | None:
        return self.degenerate

    @property
    def valid(self) -> bool:
        """False when the fit carries a physical-validity flag."""
        return not self.flags

    def friction(self) -> FrictionModel:
        """The fitted friction model object."""
        return self.model

    def to_dict(self) -> dict:
        """fits.json layout for one model (params, stderr, rms) plus diagnostics."""
        pn = self.model.param_names
        d = {"params": self.model.params,
             "stderr": {k: _json_float(self.stderr[k]) for k in pn},
             "rms": float(self.rms),
             "model": self.model.name,
             "extra": {k: float(v) for k, v in self.extra.items()},
             "extra_stderr": {k: _json_float(self.stderr[k]) for k in self.extra},
             "n": int(self.n), "cond": _json_float(self.cond), "nfev": int(self.nfev),
             "converged": bool(self.converged), "degenerate": self.degenerate,
             "form": self.form, "flags": list(self.flags), "valid": self.valid,
             "eiv": self.eiv, "names": list(self.names),
             "cov": [[_json_float(x) for x in row] for row in np.asarray(self.cov)]}
        if self.rigid:
            d["rigid"] = dict(self.rigid)
        md = self.model.to_dict()
        if "settings" in md:
            d["settings"] = md["settings"]
        d.update({k: v for k, v in self.diagnostics.items() if k not in d})
        return d


def _json_float(x):
    x = float(x)
    return x if np.isfinite(x) else None


# --------------------------------------------------------------------------------------------
# helpers
# --------------------------------------------------------------------------------------------
def _check_inputs(qd, tau, X_extra, extra_names, weights, param_names):
    qd = np.asarray(qd, float)
    tau = np.asarray(tau, float)
    if qd.ndim != 1 or tau.shape != qd.shape:
        raise ValueError(f"qd and tau must be 1-D of equal length, got {qd.shape} and {tau.shape}")
    T = qd.shape[0]
    if X_extra is None:
        X = np.zeros((T, 0))
    else:
        X = np.asarray(X_extra, float)
        if X.ndim == 1:
            X = X[:, None]
        if X.ndim != 2 or X.shape[0] != T:
            raise ValueError(f"X_extra must be (T, e) with T = {T}, got {X.shape}")
    names = tuple(extra_names) if extra_names else tuple(f"extra_{i + 1}" for i in range(X.shape[1]))
    if len(names) != X.shape[1]:
        raise ValueError(f"extra_names has {len(names)} names for {X.shape[1]} X_extra columns")
    clash = set(names) & set(param_names)
    if clash or len(set(names)) != len(names):
        raise ValueError(f"extra_names must be distinct and differ from {param_names}: {names}")
    for lab, arr in (("qd", qd), ("tau", tau), ("X_extra", X)):
        bad = ~np.isfinite(arr)
        if bad.any():
            i = int(np.argwhere(bad)[0][0])
            raise ValueError(f"{lab} has a non-finite value at sample {i}")
    if weights is None:
        sw = np.ones(T)
    else:
        w = np.asarray(weights, float)
        if w.shape != (T,) or np.any(~np.isfinite(w)) or np.any(w < 0):
            raise ValueError(f"weights must be (T,) finite and >= 0, got shape {w.shape}")
        sw = np.sqrt(w)
    return qd, tau, X, names, sw


def _linear_names(model_cls) -> tuple:
    return model_cls.linear_params()


def _design(model, qd, qdd, dt):
    """(Phi, offset) of a model instance: torque = Phi @ linear params + offset."""
    return model.linear_design(qd, qdd, dt)


def _wlstsq(A, y, sw=None):
    """Weighted linear least squares: column-scaled normal equations (fast for the few columns
    here), falling back to an SVD solve when they are ill conditioned. ``sw``: square roots of
    the weights (None: unweighted)."""
    if A.shape[1] == 0:
        return np.zeros(0)
    Aw = A if sw is None else A * sw[:, None]
    yw = y if sw is None else y * sw
    nrm = np.sqrt(np.einsum("ij,ij->j", Aw, Aw))
    if np.all(nrm > 0):
        As = Aw / nrm
        G = As.T @ As
        ev = np.linalg.eigvalsh(G)
        if ev[0] > 1e-10 * ev[-1]:
            return np.linalg.solve(G, As.T @ yw) / nrm
    return np.linalg.lstsq(Aw, yw, rcond=None)[0]


def _ls_svd(A, y):
    """Least squares ``A b ~ y`` for a tall ``A`` of few columns through the SVD of the
    column-scaled ``A`` (singular values under machine precision times the size dropped, as
    lstsq): ``(b, U, s, V, nrm)`` with ``A = U diag(s) V^T diag(nrm)`` on the kept span. The
    orthonormal ``U`` keeps projections accurate when the design is nearly rank deficient."""
    m = A.shape[1]
    nrm = np.empty(m)
    for j in range(m):                      # loop over the few columns: their squared norms
        nrm[j] = np.einsum("i,i->", A[:, j], A[:, j])
    np.sqrt(nrm, out=nrm)
    nrm[~(nrm > 0)] = 1.0
    As = np.empty((m, A.shape[0]))          # the scaled columns, as rows (LAPACK reads columns)
    for j in range(m):
        np.divide(A[:, j], nrm[j], out=As[j])
    U, sv, Vt = np.linalg.svd(As.T, full_matrices=False)
    keep = sv > sv[0] * np.finfo(float).eps * max(A.shape) if sv[0] > 0 else sv > 0
    if keep.all():                          # the kept span: U by columns, V = Vt^T
        U, V = np.asfortranarray(U), Vt.copy().T
    else:
        U, sv, V = U[:, keep], sv[keep], Vt[keep].T
    return (V @ ((U.T @ y) / sv)) / nrm, U, sv, V, nrm


class _Projector:
    """The orthogonal complement of the (weighted) extra columns: ``P(A) = A - Q Q^T A``.

    Projecting the extras out once per fit leaves each variable-projection evaluation a solve
    over the model's few linear columns; its residual equals that of the joint weighted least
    squares over ``[X, Phi]`` (the spans are the same)."""

    def __init__(self, X, sw):
        Xw = X * sw[:, None]
        if Xw.shape[1] == 0:
            self.Q, self.s, self.V = np.zeros((X.shape[0], 0)), np.zeros(0), np.zeros((0, 0))
        else:
            U, s, Vt = np.linalg.svd(Xw, full_matrices=False)
            keep = s > s[0] * 1e-12 if s[0] > 0 else s > 0
            self.Q, self.s, self.V = U[:, keep], s[keep], Vt[keep].T

    def __call__(self, A, out=None):
        """``P(A)``; ``out`` (``A`` itself allowed) receives it."""
        if self.Q.shape[1]:
            return np.subtract(A, self.Q @ (self.Q.T @ A), out=out)
        if out is None:
            return A
        out[...] = A
        return out

    def coefficients(self, rw):
        """Least-squares coefficients of the (weighted) extra columns for the weighted target
        ``rw`` (minimum norm when they are rank deficient)."""
        return self.V @ ((self.Q.T @ rw) / self.s) if self.Q.shape[1] else np.zeros(self.V.shape[0])


def _profile_rss(Br, yr, S) -> np.ndarray:
    """Variable-projection residual sum of squares of every grid point at once: the design of
    point k is ``Br @ S_k`` (extras already projected out of ``Br`` and ``yr``; ``S`` sparse as
    in ``vp_grid``), so its normal equations are ``S_k^T (Br^T Br) S_k``, built from one Gram
    matrix. Rank-deficient points
    (e.g. a Stribeck hump that vanishes on the grid) get the residual of their column span, as
    an SVD solve would."""
    G = Br.T @ Br
    h = Br.T @ yr
    yy = float(yr @ yr)
    cols, coefs = S
    # Gk[k, a, b] = sum_pq coefs[k,a,p] coefs[k,b,q] G[cols[k,a,p], cols[k,b,q]]
    Gk = np.einsum("kap,kbq,kabpq->kab", coefs, coefs,
                   G[cols[:, :, None, :, None], cols[:, None, :, None, :]])
    hk = np.einsum("kap,kap->ka", coefs, h[cols])
    d = np.sqrt(np.maximum(np.einsum("kaa->ka", Gk), 0.0))
    d = np.where(d > 0, d, 1.0)
    w, V = np.linalg.eigh(Gk / (d[:, :, None] * d[:, None, :]))
    keep = w > 1e-10 * w[:, -1:]
    pr = np.einsum("kam,ka->km", V, hk / d)
    explained = np.sum(np.where(keep, pr ** 2 / np.where(keep, w, 1.0), 0.0), axis=1)
    return np.maximum(yy - explained, 0.0)


EXACT_GRID_MAX = 256     # grids this small are scored by an SVD solve per point


def _grid_rss_exact(Br, yr, S) -> np.ndarray:
    """:func:`_profile_rss` by one SVD least-squares solve per grid point (small grids): it
    also resolves columns that differ by less than the Gram matrix can (a Stribeck drop whose
    ``Vc`` is far below the slowest sampled speed is the sign column to 1e-9; the fit may still
    use that difference, and so did the per-start search before the grid)."""
    cols, coefs = S
    out = np.empty(cols.shape[0])
    for k in range(cols.shape[0]):  # loop over grid points (at most EXACT_GRID_MAX)
        A = np.einsum("tap,ap->ta", Br[:, cols[k]], coefs[k])
        b = _ls_svd(A, yr)[0]
        r = yr - A @ b
        out[k] = float(r @ r)
    return out


def _grid_local_minima(U, rss) -> np.ndarray:
    """Indices of the grid points (rows of ``U``, a full or partial tensor grid) whose profiled
    residual is no larger than any neighbour's (one step in each coordinate, diagonals too)."""
    idx = tuple(np.unique(U[:, j], return_inverse=True)[1].ravel() for j in range(U.shape[1]))
    C = np.full([int(i.max()) + 1 for i in idx], np.inf)
    C[idx] = rss
    mf = minimum_filter(C, size=3, mode="constant", cval=np.inf)
    return np.flatnonzero(rss <= mf[idx])


class _VarPro:
    """The variable-projection residual over the nonlinear parameters ``u`` (transformed
    coordinates) of a model with ``design_grad`` and zero offset, and its analytic Jacobian
    (Golub & Pereyra 1973: ``dr/du_j = -(P_perp dA_j b + A^+T dA_j^T r)``), the extras projected
    out once. The pieces of the last few evaluations are remembered by ``u``: the Jacobian
    reuses those of the residual at the same ``u`` (the trust region asks for it right after
    accepting a step), and a point evaluated again soon after is not recomputed."""

    KEEP = 4            # evaluations remembered (each holds a few (T, n) arrays)

    def __init__(self, model_cls, nl, tr, qd, tau, sw, proj):
        self.cls, self.nl, self.tr, self.qd, self.proj, self.tau = model_cls, nl, tr, qd, proj, tau
        self.sw = None if np.all(sw == 1.0) else sw
        self.yr = proj(tau if self.sw is None else sw * tau)
        self.all_log = bool(np.all(tr.log))
        self.m = len(model_cls.linear_params())
        self.k = self.m + len(nl)
        try:
            self.into = "out" in inspect.signature(model_cls.design_grad).parameters
        except (TypeError, ValueError):
            self.into = False
        self._states: dict = {}

    def _evaluate(self, u):
        """``(U, sv, V, nrm, A, x, cols, b, r)`` at ``u``: the SVD pieces of the projected
        (weighted) linear design ``A[:, :m]``, the projected design with its derivative
        columns ``A[:, m:]`` (d design / dx), the nonlinear values ``x``, the linear solution
        ``b`` and the residual ``r``."""
        u = np.asarray(u, float)
        key = u.tobytes()
        st = self._states.get(key)
        if st is not None:
            return st
        x = np.exp(u) if self.all_log else self.tr.to_x(u)
        nlv = dict(zip(self.nl, x))
        if self.into:
            A = np.empty((self.qd.size, self.k))
            _, _, cols = self.cls.design_grad(self.qd, nlv, out=A)
        else:
            Phi, dPhi, cols = self.cls.design_grad(self.qd, nlv)
            A = np.concatenate([Phi, dPhi], axis=1)
        m = self.m
        if self.sw is not None:
            np.multiply(A, self.sw[:, None], out=A)
        A = self.proj(A, out=A)
        Pr = A[:, :m]
        b, U, sv, V, nrm = _ls_svd(Pr, self.yr)
        r = self.yr - Pr @ b
        # d(column cols[j]) / du_j, A[:, m:] * dx/du, is formed when the Jacobian asks for it
        # (a step the trust region rejects needs only the residual)
        st = (U, sv, V, nrm, A, x, cols, b, r)
        if len(self._states) >= self.KEEP:
            self._states.pop(next(iter(self._states)))
        self._states[key] = st
        return st

    def resid(self, u):
        return self._evaluate(u)[-1].copy()

    def solution(self, u):
        """``(extra coefficients, linear parameters)`` at ``u``: the same least-squares
        solution the residual used (the extras from the target minus the model's columns)."""
        u = np.asarray(u, float)
        b = self._evaluate(u)[7]
        Phi = np.ascontiguousarray(self.cls.design_grad(self.qd, dict(zip(self.nl, self.tr.to_x(u))))[0])
        rw = self.tau - Phi @ b
        return self.proj.coefficients(rw if self.sw is None else self.sw * rw), b

    def jac(self, u):
        U, sv, V, nrm, A, x, cols, b, r = self._evaluate(u)
        m = self.m
        n = A.shape[1] - m
        dxdu = x if self.all_log else np.where(self.tr.log, x, 1.0)
        dA = np.empty((A.shape[0], n))
        t1 = np.empty((A.shape[0], n))
        for j in range(n):          # loop over the few nonlinear parameters
            np.multiply(A[:, m + j], dxdu[j], out=dA[:, j])
            np.multiply(dA[:, j], b[cols[j]], out=t1[:, j])     # dA_j b, (T, n_nl)
        c = np.zeros((nrm.size, n))                           # dA_j^T r, (m, n_nl)
        c[cols, np.arange(n)] = r @ dA
        # P_perp dA_j b + A^+T dA_j^T r with A^+T = U diag(1/s) V^T diag(1/nrm)
        J = np.subtract(t1, U @ (U.T @ t1), out=t1)
        J += U @ ((V.T @ (c / nrm[:, None])) / sv[:, None])
        return np.negative(J, out=J)


def _distinct_best(costs, U, span, n: int, sep: float = 0.1) -> list:
    """Indices of the ``n`` lowest costs whose points differ from each other by more than
    ``sep`` of the search span in some coordinate (distinct basins, not one basin twice)."""
    order = np.argsort(costs, kind="stable")
    out = []
    for i in order:  # loop over candidates until n are found (stops early)
        if not np.isfinite(costs[i]):
            break
        if all(np.max(np.abs(U[i] - U[j]) / span) > sep for j in out):
            out.append(int(i))
            if len(out) == n:
                break
    return out


def _build(model_cls, values: dict, settings: dict):
    return model_cls(**values, **settings)


class _Transform:
    """Log coordinates for nonlinear parameters whose lower bound is positive."""

    def __init__(self, names, bounds):
        self.names = names
        self.lo = np.array([bounds[k][0] for k in names], float)
        self.hi = np.array([bounds[k][1] for k in names], float)
        if np.any(~(self.lo < self.hi)):
            raise ValueError(f"bounds must have lo < hi: { {k: bounds[k] for k in names} }")
        self.log = self.lo > 0

    def to_u(self, x):
        x = np.asarray(x, float)
        return np.where(self.log, np.log(np.where(self.log, x, 1.0)), x)

    def to_x(self, u):
        u = np.asarray(u, float)
        return np.where(self.log, np.exp(np.where(self.log, u, 0.0)), u)

    def ubounds(self):
        return self.to_u(self.lo), self.to_u(self.hi)

    def clip_inside(self, u):
        ulo, uhi = self.ubounds()
        span = uhi - ulo
        span = np.where(np.isfinite(span), span, 1.0)
        return np.clip(u, ulo + 1e-9 * span, uhi - 1e-9 * span)

    def sample(self, rng, u0):
        ulo, uhi = self.ubounds()
        fin = np.isfinite(ulo) & np.isfinite(uhi)
        return np.where(fin, rng.uniform(np.where(fin, ulo, 0), np.where(fin, uhi, 1)),
                        u0 + rng.normal(size=u0.shape) * np.maximum(np.abs(u0), 1.0))


def _jacobian(model, qd, qdd, dt, X, Phi):
    """d prediction / d (param_names..., extras...) at a fitted model (T, p + e)."""
    pn = model.param_names
    lin = _linear_names(type(model))
    cols = {}
    for i, k in enumerate(lin):
        cols[k] = Phi[:, i]
    settings = model.settings
    base = model.params
    for k in pn:
        if k in cols:
            continue
        v = base[k]
        h = 1e-6 * max(abs(v), 1e-6)
        up = _build(type(model), {**base, k: v + h}, settings).torque(qd, qdd, dt)
        try:                                    # central difference; forward at a constraint
            dn = _build(type(model), {**base, k: v - h}, settings).torque(qd, qdd, dt)
            cols[k] = (up - dn) / (2 * h)
        except ValueError:
            cols[k] = (up - model.torque(qd, qdd, dt)) / h
    J = np.column_stack([cols[k] for k in pn] + [X[:, i] for i in range(X.shape[1])])
    return J


def param_jacobian(model, qd, qdd=None, dt=None) -> np.ndarray:
    """``d torque / d params`` of a fitted law at the samples, (T, len(param_names)) in
    ``param_names`` order: the linear parameters' columns of its design, central differences for
    the others (forward at a constraint), as the fits' covariances use it."""
    Phi, _ = _design(model, qd, qdd, dt)
    return _jacobian(model, qd, qdd, dt, np.zeros((np.shape(qd)[0], 0)), Phi)


def _finish(model, qd, tau, X, extra_names, sw, qdd, dt, *, nfev, converged, at_bound,
            diagnostics, beta_extra, jac_override=None):
    pred_f = model.torque(qd, qdd, dt)
    resid = tau - X @ beta_extra - pred_f
    Phi, _ = _design(model, qd, qdd, dt)
    J = _jacobian(model, qd, qdd, dt, X, Phi) if jac_override is None else jac_override
    Jw = J * sw[:, None]
    rw = resid * sw
    p = Jw.shape[1]
    dof = max(int(np.count_nonzero(sw)) - p, 1)
    sigma2 = float(rw @ rw) / dof
    scale = np.linalg.norm(Jw, axis=0)
    scale = np.where(scale > 0, scale, 1.0)
    _, s, Vt = np.linalg.svd(Jw / scale, full_matrices=False)
    cond = float(s[0] / s[-1]) if s[-1] > 0 else np.inf
    keep = s > s[0] * 1e-14
    inv = (Vt[keep].T / s[keep] ** 2) @ Vt[keep]
    cov = sigma2 * inv / np.outer(scale, scale)
    if not keep.all():
        cov = cov + np.diag(np.where(np.abs(Vt[~keep]).sum(0) > 1e-8, np.inf, 0.0))
    names = tuple(model.param_names) + tuple(extra_names)
    stderr = {k: float(np.sqrt(cov[i, i])) if np.isfinite(cov[i, i]) else np.inf
              for i, k in enumerate(names)}
    # degeneracy ---------------------------------------------------------------------------
    f_data = tau - X @ beta_extra
    fit_scale = float(np.percentile(np.abs(f_data), 99.0)) if f_data.size else 0.0
    msgs = []
    m = model.degeneracy(qd, fit_scale)
    if m:
        msgs.append(m)
    msgs.extend(at_bound)
    lin = set(_linear_names(type(model)))
    loose = [k for k in model.param_names if k not in lin and not stderr[k] < abs(model.params[k])]
    if loose:
        msgs.append(f"{', '.join(loose)} not determined by these data (standard error exceeds "
                    "the value)")
    if not np.isfinite(cond) or cond > COND_DEGENERATE:
        msgs.append(f"the Jacobian is nearly singular (cond {cond:.3g}): some parameters are not "
                    "separately identifiable from these data")
    return FrictionFit(model=model, extra=dict(zip(extra_names, map(float, beta_extra))),
                       stderr=stderr, cov=cov, names=names,
                       rms=float(np.sqrt(np.sum(sw ** 2 * resid ** 2) / np.sum(sw ** 2))),
                       n=int(qd.shape[0]), cond=cond,
                       nfev=int(nfev), converged=bool(converged),
                       degenerate="; ".join(msgs) if msgs else None, residuals=resid,
                       diagnostics=dict(diagnostics))


def _rms_cv(qd, tau, X, sw):
    A = np.hstack([X, CoulombViscous.regressor(qd)])
    b = _wlstsq(A, tau, sw)
    return float(np.sqrt(np.sum((sw * (tau - A @ b)) ** 2) / np.sum(sw ** 2)))


# --------------------------------------------------------------------------------------------
# the estimator
# --------------------------------------------------------------------------------------------
def _one_blas_thread(fn):
    """Run with one BLAS thread: the solves here are tall and thin (a few columns), where BLAS
    threads only add overhead (DESIGN.md measured 2-10x on 2-core machines; here 4x)."""
    @functools.wraps(fn)
    def wrapper(*args, **kwargs):
        with one_blas_thread():
            return fn(*args, **kwargs)
    return wrapper


@_one_blas_thread
def _multistart(name: str, resid, starts, bounds, x_scale, max_nfev: int, jac="2-point",
                probe_nfev: int | None = None):
    """Bounded ``least_squares`` from every start; (best result, total nfev, cost per start).
    A start that fails numerically counts as infinite cost; all failing is an error.
    ``probe_nfev``: the starts after the first (ranked best) get this many evaluations; one
    that has not converged by then is continued to ``max_nfev`` only if it is already below
    the best so far (a start crawling along a flat valley above the best stops early)."""
    best, nfev, costs, last_error = None, 0, [], None
    opts = dict(jac=jac, bounds=bounds, method="trf", x_scale=x_scale,
                ftol=1e-12, xtol=1e-12, gtol=1e-12)
    for i, x0 in enumerate(starts):  # loop over starts (a handful)
        cap = max_nfev if (i == 0 or probe_nfev is None) else min(probe_nfev, max_nfev)
        try:
            r = least_squares(resid, x0, max_nfev=cap, **opts)
            if r.status == 0 and cap < max_nfev and (best is None or r.cost < best.cost):
                nfev += r.nfev
                r = least_squares(resid, r.x, max_nfev=max_nfev - r.nfev, **opts)
        except (ValueError, FloatingPointError, np.linalg.LinAlgError) as exc:
            costs.append(np.inf)
            last_error = exc
            continue
        nfev += r.nfev
        costs.append(float(r.cost))
        if best is None or r.cost < best.cost:
            best = r
    if best is None:
        raise RuntimeError(f"{name}: every start failed; last error: {last_error}")
    return best, nfev, costs


@_one_blas_thread
def fit_friction(model_cls, qd, tau, *, X_extra=None, extra_names=(), qdd=None, dt=None,
                 bounds=None, x0=None, n_starts: int = 8, seed: int = 0, weights=None,
                 settings=None, n_refine: int = 4) -> FrictionFit:
    r"""Fit a friction model, and nuisance columns with it, to a torque record.

    .. math::

        \tau \approx X_{extra} \beta + f_\theta(\dot{q}, \ddot{q}, \Delta t)

    with ``f_theta = model_cls(theta, **settings).torque``, by weighted least squares: the
    thesis's one-link fit of eq. 2-4 with the friction of eq. 2-5 to 2-7 [1]_ (``X_extra`` the
    columns ``[qdd, -sin q, cos q]``), or Indri & Trapani's residual torques of eq. 25-26 with
    no extra columns [2]_. Dynamic models without a ``static`` setting get an arctan model
    fitted to the same data first (step 1 of Indri & Trapani); the model's
    ``complete_settings`` fills in what the data determine (dm2: a_max/v_max from
    ``qd``/``qdd``). The strategy is chosen from the model's declared interface
    (:func:`strategy_for`; variable projection [3]_ for the nonlinear parameters); see the
    module docstring.

    Parameters
    ----------
    model_cls : type
        A :class:`ident.friction.base.FrictionModel` subclass (e.g. a value of
        ``ident.friction.MODELS``).
    qd : array_like
        (T,) joint velocity (rad/s).
    tau : array_like
        (T,) torque to explain (N m).
    X_extra : array_like, optional
        (T, e) nuisance columns estimated jointly (or (T,)); None: none.
    extra_names : sequence of str, optional
        Names of the ``X_extra`` columns, distinct from the model's parameters; default
        ``extra_1, ...``.
    qdd : array_like, optional
        (T,) acceleration (rad/s^2), for models that need it (dm2).
    dt : float or array_like, optional
        Sample period (s) or the (T-1,) steps, for dynamic models.
    bounds : dict, optional
        {name: (lo, hi)} overriding the model's data-scaled defaults; bounds on a linear
        parameter or an extra column make the fit joint.
    x0 : dict or array_like, optional
        {name: value} (or an array over ``param_names``) for the first start.
    n_starts : int, optional
        Seeded starts of the nonlinear search (default 8).
    seed : int, optional
        Seed of the starts (default 0).
    weights : array_like, optional
        (T,) per-sample weights (inverse variances up to a scale), finite and >= 0.
    settings : dict, optional
        Model constructor settings (``Kv`` for arctan, which may also carry ``delta_grid``;
        ``static``/``damping``/``z0`` for dm1; ``static``/``accel_ratio`` for dm2).
    n_refine : int, optional
        How many of the grid-scored candidates are refined (models with a ``vp_grid``; at
        most ``n_starts``; the others refine every start); default 4.

    Returns
    -------
    FrictionFit
        The fitted model, the extra coefficients, standard errors, covariance and diagnostics.

    Raises
    ------
    ValueError
        If the signals' shapes disagree or hold non-finite values, ``extra_names`` or
        ``bounds`` name unknown or clashing parameters, or a dynamic model lacks ``dt``.

    References
    ----------
    .. [1] PA10 thesis (seeds 002), eq. 2-4 to 2-7.
    .. [2] Indri & Trapani 2020 (seeds 001), eq. 25-28 and sec. III.
    .. [3] Golub & Pereyra 1973, variable projection.

    Examples
    --------
    >>> from ident.friction import CoulombViscous
    >>> qd = np.linspace(-1.0, 1.0, 201)
    >>> fit = fit_friction(CoulombViscous, qd, 2.0 * np.sign(qd) + 0.5 * qd)
    >>> {k: round(v, 6) for k, v in fit.params.items()}
    {'c': 2.0, 'v': 0.5}
    """
    settings = dict(settings or {})
    qd, tau, X, enames, sw = _check_inputs(qd, tau, X_extra, extra_names, weights,
                                           model_cls.param_names)
    pb = _Problem(model_cls, qd, tau, X, enames, sw, weights, settings, bounds, n_refine)
    if model_cls.fit_method != "delta_grid":
        pb.prepare(qdd, dt, x0, n_starts, seed)
    return strategy_for(pb).fit(pb)


def _dynamic_settings(model_cls, qd, qdd, tau, X, enames, sw, weights, dt, settings,
                      diagnostics) -> dict:
    """The settings of a dynamic (LuGre-type) model: the static arctan model of step 1 (fitted
    to the same data when not given) and what the model takes from the data."""
    if dt is None:
        raise ValueError(f"{model_cls.name} is dynamic: fit_friction needs dt")
    if "static" not in settings:
        st = fit_arctan(qd, tau, X_extra=X, extra_names=enames,
                        weights=None if weights is None else sw ** 2)
        settings["static"] = st.model
        diagnostics["static_fitted_on_same_data"] = True
    gmin = float(np.min(settings["static"].g(qd)))
    if not gmin > 0:
        src = ("fitted to these same data" if diagnostics.get("static_fitted_on_same_data")
               else "given in settings")
        raise ValueError(f"{model_cls.name}: the static arctan model ({src}) has "
                         f"g(v) = tau_s + tau_sc 2/pi arctan(|v| delta) <= 0 (min {gmin:.3g}) "
                         "on these data; identify the static part first on constant-velocity "
                         "data (Indri & Trapani step 1) and pass settings={'static': ...}")
    return model_cls.complete_settings(qd, qdd, settings)


class _Problem:
    """The data and settings of one :func:`fit_friction` call, shared by the strategies.
    :meth:`prepare` (every strategy but the delta grid) checks ``qdd``, completes the settings
    of dynamic models, splits the parameters into linear and nonlinear ones and sets the
    start and bounds of the nonlinear ones (the model's ``fit_hints`` overridden by
    ``bounds``/``x0``) and whether ``bounds`` constrain a linear parameter or an extra column
    (then the fit is joint)."""

    def __init__(self, model_cls, qd, tau, X, enames, sw, weights, settings, bounds, n_refine):
        self.cls, self.qd, self.tau, self.X, self.enames, self.sw = model_cls, qd, tau, X, enames, sw
        self.weights, self.settings, self.n_refine = weights, settings, n_refine
        self.bounds = dict(bounds or {})
        self.e = X.shape[1]
        self.qdd = self.dt = self.tr = self.starts = None
        self.diagnostics = {}

    def prepare(self, qdd, dt, x0, n_starts, seed):
        cls, qd = self.cls, self.qd
        if qdd is not None:
            qdd = np.asarray(qdd, float)
            if qdd.shape != qd.shape or not np.all(np.isfinite(qdd)):
                raise ValueError(f"qdd must be finite and shaped like qd {qd.shape}, got {qdd.shape}")
        self.qdd, self.dt = qdd, dt
        self.diagnostics = {"rms_cv": _rms_cv(qd, self.tau, self.X, self.sw)}
        if cls.dynamic:
            self.settings = _dynamic_settings(cls, qd, qdd, self.tau, self.X, self.enames, self.sw,
                                              self.weights, dt, self.settings, self.diagnostics)
        if n_starts < 1:
            raise ValueError("n_starts must be >= 1")
        self.n_starts, self.seed = n_starts, seed
        pn = cls.param_names
        self.lin = cls.linear_params()
        self.nl = cls.nonlinear_params()
        hint0, hint_b = cls.fit_hints(qd, self.settings)
        unknown = set(self.bounds) - set(pn) - set(self.enames)
        if unknown:
            raise ValueError(f"bounds name unknown parameters {sorted(unknown)}")
        if x0 is not None and not isinstance(x0, dict):
            x0 = dict(zip(pn, np.asarray(x0, float)))
        x0 = dict(x0 or {})
        self.start = {**hint0, **{k: float(v) for k, v in x0.items() if k in self.nl}}
        self.nl_bounds = {k: tuple(self.bounds.get(k, hint_b.get(k, (-np.inf, np.inf))))
                          for k in self.nl}
        self.joint = (any(k in self.bounds for k in self.lin)
                      or any(k in self.bounds for k in self.enames))

    def model_at(self, nlvals: dict, linvals=None):
        vals = {k: 0.0 for k in self.lin} if linvals is None else dict(zip(self.lin, linvals))
        return _build(self.cls, {**vals, **nlvals}, self.settings)

    def make_starts(self):
        """The log/linear coordinates of the nonlinear parameters and the seeded starts:
        start 0 at the hint (or ``x0``), the others uniform in the (log) bounds."""
        missing = [k for k in self.nl if k not in self.start]
        if missing:
            raise ValueError(f"{self.cls.name}: give x0 for {missing}")
        tr = _Transform(self.nl, self.nl_bounds)
        rng = np.random.default_rng(self.seed)
        u0 = tr.clip_inside(tr.to_u([self.start[k] for k in self.nl]))
        self.tr = tr
        self.starts = [u0] + [tr.clip_inside(tr.sample(rng, u0)) for _ in range(self.n_starts - 1)]
        return tr, self.starts

    def vp_solve(self, u):
        """Design, offset and joint least-squares coefficients ``[extras, linear]`` at ``u``."""
        m = self.model_at(dict(zip(self.nl, self.tr.to_x(u))))
        Phi, off = _design(m, self.qd, self.qdd, self.dt)
        A = np.hstack([self.X, Phi])
        b = _wlstsq(A, self.tau - off, self.sw)
        return A, off, b

    def finish(self, u_best, linvals, beta_extra, best, nfev, costs, method):
        """The fitted model (canonical representative), the nonlinear parameters at a bound,
        and :func:`_finish`."""
        tr, cls = self.tr, self.cls
        nlvals = dict(zip(self.nl, tr.to_x(u_best)))
        params = cls.canonical({**dict(zip(self.lin, linvals)), **nlvals})
        model = _build(cls, params, self.settings)
        at_bound = []
        for k, lo, hi in zip(self.nl, tr.lo, tr.hi):
            v = model.params[k]
            for side, bd in (("lower", lo), ("upper", hi)):
                if np.isfinite(bd) and abs(v - bd) <= 1e-6 * max(abs(bd), 1e-12) + 1e-12:
                    at_bound.append(f"{k} = {v:.3g} is at its {side} bound (the data push it "
                                    "there or do not determine it)")
        self.diagnostics.update({"method": method, "n_starts": len(self.starts),
                                 "start_costs": costs,
                                 "bounds": {k: list(map(float, v))
                                            for k, v in self.nl_bounds.items()}})
        return _finish(model, self.qd, self.tau, self.X, self.enames, self.sw, self.qdd, self.dt,
                       nfev=nfev, converged=best.success, at_bound=at_bound,
                       diagnostics=self.diagnostics, beta_extra=beta_extra)


class LinearStrategy:
    """A model linear in all its parameters (``cv``, thesis eq. 2-5): one weighted linear
    least-squares solve over ``[X_extra, design]``."""

    name = "linear least squares"

    def fit(self, pb: _Problem) -> FrictionFit:
        m0 = pb.model_at({})
        Phi, off = _design(m0, pb.qd, pb.qdd, pb.dt)
        A = np.hstack([pb.X, Phi])
        b = _wlstsq(A, pb.tau - off, pb.sw)
        model = pb.model_at({}, b[pb.e:])
        return _finish(model, pb.qd, pb.tau, pb.X, pb.enames, pb.sw, pb.qdd, pb.dt, nfev=1,
                       converged=True, at_bound=[],
                       diagnostics={**pb.diagnostics, "method": self.name},
                       beta_extra=b[:pb.e])


class GridVarProStrategy:
    """Static models with a ``vp_grid`` and ``design_grad`` (Stribeck, hyperbolic): the starts
    and the grid scored by their profiled residual in array operations, the best ``n_refine``
    distinct local minima refined with the analytic variable-projection Jacobian."""

    name = "variable projection: grid-scored starts, bounded least squares from the best"

    def __init__(self, grid):
        self.grid = grid

    def fit(self, pb: _Problem) -> FrictionFit:
        tr, starts = pb.tr, pb.starts
        proj = _Projector(pb.X, pb.sw)
        vp = _VarPro(pb.cls, pb.nl, tr, pb.qd, pb.tau, pb.sw, proj)
        B, Ug, S, *blocks = self.grid
        Br = proj(B * pb.sw[:, None])
        grid_rss = (_profile_rss(Br, vp.yr, S) if Ug.shape[0] > EXACT_GRID_MAX
                    else _grid_rss_exact(Br, vp.yr, S))
        blocks = blocks[0] if blocks else np.zeros(Ug.shape[0], int)
        loc = np.concatenate([np.flatnonzero(blocks == k)[_grid_local_minima(
            Ug[blocks == k], grid_rss[blocks == k])] for k in np.unique(blocks)])
        start_rss = np.array([float(np.sum(vp.resid(u) ** 2)) for u in starts])   # a handful
        cand = np.vstack([np.array(starts), tr.to_u(Ug[loc])])
        rss = np.concatenate([start_rss, grid_rss[loc]])
        ulo, uhi = tr.ubounds()
        pick = _distinct_best(rss, cand, uhi - ulo, max(1, min(pb.n_refine, pb.n_starts)))
        best, nfev, refined = _multistart(pb.cls.name, vp.resid,
                                          [tr.clip_inside(cand[i]) for i in pick], tr.ubounds(),
                                          x_scale=1.0, max_nfev=400, jac=vp.jac, probe_nfev=100)
        nfev += len(starts)
        costs = [float(0.5 * c) for c in start_rss]
        beta_extra, linvals = vp.solution(best.x)
        pb.diagnostics.update({"grid_size": int(grid_rss.size), "grid_local_minima": int(loc.size),
                               "n_refined": len(pick), "refined_costs": refined})
        return pb.finish(best.x, linvals, beta_extra, best, nfev, costs, self.name)


class VarProStrategy:
    """Models with nonlinear parameters and no grid (dm1, dm2): bounded least squares over the
    nonlinear parameters from every start, the linear ones and the extras eliminated by
    variable projection in each residual evaluation."""

    name = "variable projection + bounded least squares"

    def fit(self, pb: _Problem) -> FrictionFit:
        def resid(u):
            A, off, b = pb.vp_solve(u)
            return pb.sw * (pb.tau - off - A @ b)

        best, nfev, costs = _multistart(pb.cls.name, resid, pb.starts, pb.tr.ubounds(),
                                        x_scale=1.0, max_nfev=400)
        _, _, b = pb.vp_solve(best.x)
        return pb.finish(best.x, b[pb.e:], b[:pb.e], best, nfev, costs, self.name)


class JointStrategy:
    """``bounds`` on a linear parameter or an extra column: bounded least squares over
    ``[extras, linear, nonlinear]`` together, each start's linear part from variable
    projection."""

    name = "joint bounded least squares"

    def fit(self, pb: _Problem) -> FrictionFit:
        tr, e, lin, nl = pb.tr, pb.e, pb.lin, pb.nl
        allb = {**{k: (-np.inf, np.inf) for k in pb.enames + lin}, **pb.bounds, **pb.nl_bounds}
        jn = tuple(pb.enames) + lin
        jlo = np.array([allb[k][0] for k in jn], float)
        jhi = np.array([allb[k][1] for k in jn], float)

        def split(w):
            return w[:len(jn)], w[len(jn):]

        def resid(w):
            lb, u = split(w)
            m = pb.model_at(dict(zip(nl, tr.to_x(u))), lb[e:])
            return pb.sw * (pb.tau - pb.X @ lb[:e] - m.torque(pb.qd, pb.qdd, pb.dt))

        ulo, uhi = tr.ubounds()
        span = np.where(np.isfinite(jhi - jlo), jhi - jlo, 1.0)
        w0s = [np.concatenate([np.clip(pb.vp_solve(us)[2], jlo + 1e-9 * span, jhi - 1e-9 * span),
                               us]) for us in pb.starts]
        best, nfev, costs = _multistart(pb.cls.name, resid, w0s,
                                        (np.concatenate([jlo, ulo]), np.concatenate([jhi, uhi])),
                                        x_scale="jac", max_nfev=400 * (len(w0s[0]) + 1))
        lb, u_best = split(best.x)
        return pb.finish(u_best, lb[e:], lb[:e], best, nfev, costs, self.name)


class DeltaGridStrategy:
    """Models declaring ``fit_method = "delta_grid"`` (arctan, Indri & Trapani eq. 27-28):
    :func:`fit_arctan`'s grid search, ``bounds`` restricting only the grid of ``delta``."""

    name = "delta grid search + linear least squares"

    def fit(self, pb: _Problem) -> FrictionFit:
        grid = pb.settings.get("delta_grid")
        grid = default_delta_grid() if grid is None else np.asarray(grid, float).ravel()
        if pb.bounds:
            if set(pb.bounds) - {"delta"}:
                raise ValueError(f"{pb.cls.name} is fitted by the delta grid search (linear "
                                 "least squares for the rest): bounds may only restrict delta, "
                                 f"got {sorted(pb.bounds)}")
            lo, hi = pb.bounds["delta"]
            grid = grid[(grid >= lo) & (grid <= hi)]
        return fit_arctan(pb.qd, pb.tau, Kv=pb.settings.get("Kv", KV_DEFAULT), delta_grid=grid,
                          X_extra=pb.X, extra_names=pb.enames,
                          weights=None if pb.weights is None else pb.sw ** 2)


def strategy_for(pb: _Problem):
    """The strategy of a fit from the model's declared interface: ``fit_method = "delta_grid"``
    -> :class:`DeltaGridStrategy`; all linear (and no bounds on linear parameters or extras)
    -> :class:`LinearStrategy`; bounds on linear parameters or extras -> :class:`JointStrategy`;
    a ``vp_grid`` -> :class:`GridVarProStrategy`; else :class:`VarProStrategy`. Prepares the
    starts of the nonlinear strategies."""
    if pb.cls.fit_method == "delta_grid":
        return DeltaGridStrategy()
    if not pb.nl and not pb.joint:
        return LinearStrategy()
    pb.make_starts()
    if pb.joint:
        return JointStrategy()
    grid = pb.cls.vp_grid(pb.qd, pb.nl_bounds)
    return VarProStrategy() if grid is None else GridVarProStrategy(grid)


# --------------------------------------------------------------------------------------------
@_one_blas_thread
def fit_arctan(qd, tau, Kv: float = KV_DEFAULT, delta_grid=None, X_extra=None, extra_names=(),
               weights=None) -> FrictionFit:
    """Fit the arctan static model by the delta grid search of Indri & Trapani eq. 27-28.

    For every delta of ``delta_grid`` (default [0, 100] step 0.1, sec. III-A [1]_) the linear
    parameters (tau_s, tau_sc, tau_v, tau_nlv) and the extra columns are the least-squares
    solution of the regressor of eq. 28; the delta with the smallest residual wins. All grid
    values are solved at once: the columns that do not depend on delta are projected out once
    (QR), after which each delta's residual sum of squares is a closed-form rank-one update
    (blocks of grid values bound the memory; no loop per grid value). The standard error of
    delta comes from the Jacobian like the others.

    Parameters
    ----------
    qd : array_like
        (T,) joint velocity (rad/s).
    tau : array_like
        (T,) friction (residual) torque (N m), eq. 25-26.
    Kv : float, optional
        Steepness of the smooth sign ``S0`` (s/rad); default
        :data:`ident.friction.constants.KV_DEFAULT` (the paper's 1000).
    delta_grid : array_like, optional
        The delta values searched (s/rad), finite and >= 0; default [0, 100] step 0.1.
    X_extra : array_like, optional
        (T, e) nuisance columns estimated jointly; None: none.
    extra_names : sequence of str, optional
        Names of the ``X_extra`` columns.
    weights : array_like, optional
        (T,) per-sample weights, finite and >= 0.

    Returns
    -------
    FrictionFit
        The fitted :class:`ident.friction.static.Arctan`; a ``delta`` on the edge of the grid is
        named in ``degenerate``.

    Raises
    ------
    ValueError
        If ``delta_grid`` is empty, not finite or negative, or the signals' shapes disagree
        or hold non-finite values.

    References
    ----------
    .. [1] Indri & Trapani 2020 (seeds 001), eq. 1-2, 27-28 and sec. III-A.

    Examples
    --------
    >>> from ident.friction import Arctan
    >>> qd = np.linspace(-1.0, 1.0, 201)
    >>> truth = Arctan(tau_s=2.0, tau_sc=-0.5, tau_v=0.3, tau_nlv=0.0, delta=5.0)
    >>> fit = fit_arctan(qd, truth.torque(qd))
    >>> {k: round(v, 4) + 0.0 for k, v in fit.params.items()}
    {'tau_s': 2.0, 'tau_sc': -0.5, 'tau_v': 0.3, 'tau_nlv': 0.0, 'delta': 5.0}
    """
    qd, tau, X, enames, sw = _check_inputs(qd, tau, X_extra, extra_names, weights,
                                           Arctan.param_names)
    grid = default_delta_grid() if delta_grid is None else np.asarray(delta_grid, float).ravel()
    if grid.size == 0 or np.any(~np.isfinite(grid)) or np.any(grid < 0):
        raise ValueError("delta_grid must be a non-empty set of finite values >= 0")
    sg = s0(qd, Kv)
    M0 = np.column_stack([X, sg, qd, qd * qd * sg]) * sw[:, None]
    Q, _ = np.linalg.qr(M0)
    y = tau * sw
    yr = y - Q @ (Q.T @ y)
    yy = float(yr @ yr)
    rss = np.empty(grid.size)
    T = qd.shape[0]
    blk = max(1, int(4_000_000 // max(T, 1)))
    for g0 in range(0, grid.size, blk):                     # blocks of the grid, memory bound
        dg = grid[g0:g0 + blk]
        C = _2_PI * np.arctan(np.multiply.outer(qd, dg)) * sw[:, None]
        R = C - Q @ (Q.T @ C)
        num = yr @ R
        den = np.einsum("ij,ij->j", R, R)
        cc = np.einsum("ij,ij->j", C, C)
        ok = den > 1e-12 * np.maximum(cc, 1e-300)
        rss[g0:g0 + blk] = np.where(ok, yy - np.where(ok, num, 0) ** 2 / np.where(ok, den, 1), yy)
    i = int(np.argmin(rss))
    delta = float(grid[i])
    A = np.column_stack([X, Arctan.regressor(qd, delta, Kv)])
    b = _wlstsq(A, tau, sw)
    e = X.shape[1]
    model = Arctan(Kv=Kv, **dict(zip(Arctan.linear_names, b[e:])), delta=delta)
    Phi = A[:, e:]
    ddelta = model.tau_sc * _2_PI * qd / (1.0 + (qd * delta) ** 2)
    J = np.column_stack([Phi, ddelta, X])
    at_bound = []
    if grid.size > 1 and (i == 0 or i == grid.size - 1):
        at_bound.append(f"delta = {delta:.3g} is at the edge of the grid "
                        f"[{grid[0]:.3g}, {grid[-1]:.3g}]")
    diagnostics = {"method": "delta grid search + linear least squares (Indri & Trapani eq. 27-28)",
                   "rms_cv": _rms_cv(qd, tau, X, sw), "grid_size": int(grid.size),
                   "grid_min": float(grid[0]), "grid_max": float(grid[-1]),
                   "rss_profile_min": float(rss[i])}
    return _finish(model, qd, tau, X, enames, sw, None, None, nfev=int(grid.size), converged=True,
                   at_bound=at_bound, diagnostics=diagnostics, beta_extra=b[:e], jac_override=J)


def eiv_bias(X, beta, se, col_var) -> dict:
    """Errors-in-variables bias of a linear least-squares fit ``y ~ X beta`` whose regressor
    columns carry zero-mean noise of per-sample covariance ``col_var`` ((T, p, p) or the (T, p)
    diagonal): with ``X`` the observed (noisy) regressor, ``E[X'X] = X0'X0 + sum_t S_t`` and
    the large-sample bias is ``-(X'X)^-1 (sum_t S_t) beta`` (attenuation). Returns ``{"bias": (p,), "ratio":
    |bias| / se (p,), "exceeds_se": bool}``: a bias above its standard error is reported."""
    X = np.asarray(X, float)
    S = np.asarray(col_var, float)
    S = np.einsum("tk,kl->kl", S, np.eye(S.shape[1])) if S.ndim == 2 else S.sum(axis=0)
    bias = -np.linalg.pinv(X.T @ X) @ S @ np.asarray(beta, float)
    ratio = np.abs(bias) / np.maximum(np.asarray(se, float), 1e-300)
    return {"bias": bias, "ratio": ratio, "exceeds_se": bool(np.any(ratio > 1.0))}


def predict(fit: FrictionFit, qd, X_extra=None, *, qdd=None, dt=None) -> np.ndarray:
    """Torque a fit predicts: its friction plus its extra columns.

    ``fit.model.torque(qd, qdd, dt) + X_extra @ extra``, the right side of the fitted
    equation (the thesis's eq. 2-4 with its friction model [1]_; Indri & Trapani's friction
    model, eq. 1 or 6 [2]_). Without ``X_extra`` only the friction torque is returned.

    Parameters
    ----------
    fit : FrictionFit
        A result of :func:`fit_friction` or :func:`fit_arctan`.
    qd : array_like
        (T,) joint velocity (rad/s).
    X_extra : array_like, optional
        (T, e) extra columns, in the fit's ``extra`` order; None: friction only.
    qdd : array_like, optional
        (T,) acceleration (rad/s^2), for models that need it (dm2).
    dt : float or array_like, optional
        Sample period (s) or the (T-1,) steps, for dynamic models.

    Returns
    -------
    numpy.ndarray
        (T,) predicted torque (N m).

    Raises
    ------
    ValueError
        If ``X_extra`` is not (T, number of extras).

    References
    ----------
    .. [1] PA10 thesis (seeds 002), eq. 2-4.
    .. [2] Indri & Trapani 2020 (seeds 001), eq. 1, 6.

    Examples
    --------
    >>> from ident.friction import CoulombViscous
    >>> qd = np.linspace(-1.0, 1.0, 201)
    >>> fit = fit_friction(CoulombViscous, qd, 2.0 * np.sign(qd) + 0.5 * qd)
    >>> predict(fit, [0.5]).round(6).tolist()
    [2.25]
    """
    tau = fit.model.torque(np.asarray(qd, float), qdd, dt)
    if X_extra is not None:
        X = np.asarray(X_extra, float)
        if X.ndim == 1:
            X = X[:, None]
        if X.shape != (tau.shape[0], len(fit.extra)):
            raise ValueError(f"X_extra must be {(tau.shape[0], len(fit.extra))}, got {X.shape}")
        tau = tau + X @ np.array(list(fit.extra.values()))
    return tau
