"""Coulomb + viscous friction from a coast-down (the TDM/FDM paper, seeds/000_*).

A rotor of known inertia ``J`` is released at speed ``v0`` and decelerates under
``J dv/dt + Kv v + Kc = 0`` (paper eq. 3) until it stops. While it moves (paper eq. 4)::

    v(t) = (v0 + Kc/Kv) exp(-Kv t / J) - Kc/Kv,        0 <= t < t_s
    v(t) = 0,                                          t >= t_s
    t_s  = (J/Kv) ln(1 + Kv v0 / Kc)                   (the stop time, where eq. 4 reaches 0)

Estimators (all take the coast record ``t`` (s, from the release), ``v`` (rad/s, positive
while coasting) and ``J``; ``t`` is shifted so the release is ``t[0]``):

- :func:`tdm`: the paper's time-domain method. Least squares on eq. 4: ``Kc(Kv)`` from
  eq. 5, then a search for the root of eq. 6 (``dS/dKv = 0``) in ``Kv``.
- :func:`fdm`: the paper's frequency-domain method. The record's Fourier transform
  ``V_e(jw)`` is fitted to eq. 8 by the weighted least squares eq. 9, solved in closed
  form by eqs. 10-11.
- :func:`nls`: maximum likelihood under white Gaussian velocity noise (= nonlinear least
  squares) on the analytic solution WITH the stop time (samples after ``t_s`` are 0), and
  ``v0`` estimated unless given. Analytic Jacobian; scipy's trust-region reflective solver
  with ``Kv > 0, Kc >= 0``; started from an exact-discretisation linear regression.
- :func:`crb`: the Cramer-Rao bound of (Kv, Kc[, v0]) for the same model and sampling.

Ambiguities in the published text (an OCR of the paper) and how they are resolved here:

1. Eq. 5 prints the denominator ``sum(1 - e_i)``; the least-squares solution of eq. 4 for
   ``Kc`` at fixed ``Kv`` has ``sum((1 - e_i)^2)`` (``e_i = exp(-Kv t_i/J)``). The printed
   form is not a least-squares estimate: on noise-free data it misses Kc by -32 % and Kv by
   +1.2 % (measured), far from Table 2's 90 dB figures, so the square is taken as lost in
   the print. ``tdm(..., literal_eq5=True)`` keeps the printed form for comparison.
2. Eq. 6 prints exponents without their minus sign and ``+ v0 f/J e`` for the first term
   of ``dv/dKv``; it is read as ``sum(res_i * dv_i/dKv) = 0`` with the exact derivative
   ``dv/dKv = -(v0 + Kc/Kv)(t/J) e - (Kc/Kv^2) e + Kc/Kv^2`` (the normal equation of
   the same least squares, so that eqs. 5-6 together are the LS fit of eq. 4).
3. "The search method is applied to eq. 6": a scan of eq. 6 over a Kv grid for the sign
   change where the profiled cost has its minimum, refined by Brent's method. With
   ``kv_step`` the grid point of least ``|eq. 6|`` next to that root is returned, as a
   fixed-step search would: a step of 1e-5 N m s/rad is one grid cell = 0.083 % of Kv =
   0.01203, which is exactly Table 2's 90 dB TDM Kv error (and 0.17 % at 60 dB is two
   cells).
4. FDM: the paper does not say how ``V_e(jw_k)`` is obtained from samples nor which
   frequencies are used. Here ``V_e`` is the exact Fourier integral of the piecewise-linear
   interpolant of the record (FFT zero-padded ``pad`` times, so ``w_k = 2 pi k / (pad T)``),
   at the ``M`` frequencies ``0 < w_k <= w_max`` (``w = 0`` is excluded: ``D*(0) = 0``),
   and eqs. 10-11 divide by that ``M``. Eq. 8 is the transform of the solution of eq. 3
   continued for ever; a real record stops at ``t_s``, and its transform obeys
   ``V D* - N* = Kc exp(-j w t_s)`` instead of 0. The published FDM therefore carries an
   intrinsic bias on Kc that only averages out over many frequencies (a dense grid, a wide
   band) while the noise enters eq. 10 multiplied by ``w^2``. This is a property of the
   published method, measured by ``benchmarks/coastdown.py``, not corrected here.

Measured accuracy against the Cramer-Rao bound: ``docs/validation.md`` (coast-down estimators).

SNR (paper Table 2, :func:`simulate_sdof_coastdown`): ``SNR = 10 log10(P_signal / P_noise)``
with ``P_signal`` the mean square of the noise-free velocity over the record and
``P_noise = sigma^2`` of white Gaussian noise.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import brentq, least_squares

from mocap.io.errors import InputError
from mocap.numerics import phi

__all__ = ["CoastdownResult", "CoastdownBound", "CoastdownSim", "coast_velocity", "stop_time",
           "tdm", "fdm", "fdm_batch", "record_spectrum", "nls", "crb", "simulate_sdof_coastdown",
           "coast_segments", "coastdown_from_trial"]


# -- results ------------------------------------------------------------------------------
@dataclass(frozen=True)
class CoastdownResult:
    r"""Identified viscous and Coulomb friction of a coast-down, and the release speed.

    The parameters of the coast-down's velocity, eq. 4 of the coast-down paper [1]_ with the
    stop,

    .. math::

        v(t) = \max\left((v_0 + K_c/K_v)\, e^{-K_v t / J} - K_c/K_v,\; 0\right)

    as every estimator of this module returns them (:func:`tdm`, :func:`fdm`, :func:`nls`).

    Attributes
    ----------
    Kv : float
        Viscous coefficient (N m s/rad).
    Kc : float
        Coulomb level (N m).
    v0 : float
        Speed at the release (rad/s).
    stderr : dict
        Parameter name -> standard error (from the time-domain residuals and the analytic
        Jacobian; NaN where the method gives none).
    rms : float
        RMS of the velocity residual of eq. 4 with the stop (rad/s).
    method : str
        The estimator (``"tdm"``, ``"fdm"``, ``"nls"``).
    converged : bool
        Whether the estimator's iteration converged.
    iterations : int
        Its iterations.
    cond : float
        Condition number of the estimator's normal matrix (NaN: none).
    t_stop : float
        Predicted stop time after ``t0`` (s).
    t0 : float
        The release time on the caller's clock (s).
    n_samples : int
        Samples used.
    direction : int
        Sign of the coasting velocity in the caller's data.
    diagnostics : dict
        Estimator-specific details.

    References
    ----------
    .. [1] Coast-down friction identification (seeds 000), eq. 1-4.
    """

    Kv: float
    Kc: float
    v0: float
    stderr: dict
    rms: float
    method: str
    converged: bool
    iterations: int = 0
    cond: float = float("nan")
    t_stop: float = float("nan")
    t0: float = 0.0
    n_samples: int = 0
    direction: int = 1
    diagnostics: dict = field(default_factory=dict)

    def to_dict(self) -> dict:
        return {"method": self.method, "params": {"Kv": self.Kv, "Kc": self.Kc, "v0": self.v0},
                "stderr": dict(self.stderr), "rms": self.rms, "converged": self.converged,
                "iterations": self.iterations, "cond": self.cond, "t_stop": self.t_stop,
                "t0": self.t0, "n_samples": self.n_samples, "direction": self.direction,
                "diagnostics": dict(self.diagnostics)}


@dataclass(frozen=True)
class CoastdownBound:
    """Cramer-Rao bound: ``cov`` (p, p) over ``names``; ``std`` and ``rel`` (std / |value|)
    per name; ``fisher`` the Fisher information; ``cond`` its condition number."""

    names: tuple
    values: dict
    cov: np.ndarray
    fisher: np.ndarray
    sigma: float

    @property
    def std(self) -> dict:
        return {k: float(np.sqrt(self.cov[i, i])) for i, k in enumerate(self.names)}

    @property
    def rel(self) -> dict:
        return {k: s / abs(self.values[k]) for k, s in self.std.items()}

    @property
    def cond(self) -> float:
        return float(np.linalg.cond(self.fisher))

    def to_dict(self) -> dict:
        return {"names": list(self.names), "values": dict(self.values), "std": self.std,
                "rel": self.rel, "cov": self.cov.tolist(), "sigma": self.sigma, "cond": self.cond}


@dataclass(frozen=True)
class CoastdownSim:
    """A simulated coast-down: ``t`` (N,), noisy ``v`` ((N,) or (runs, N)), ``v_clean``,
    noise ``sigma`` (rad/s) and the true ``t_stop``."""

    t: np.ndarray
    v: np.ndarray
    v_clean: np.ndarray
    sigma: float
    t_stop: float
    snr_db: float

    def to_dict(self) -> dict:
        return {"n_samples": int(self.t.size), "sigma": self.sigma, "t_stop": self.t_stop,
                "snr_db": self.snr_db}


# -- the model ----------------------------------------------------------------------------
def stop_time(J: float, Kv: float, Kc: float, v0: float) -> float:
    """Stop time of a coast, ``t_s = (J/Kv) ln(1 + Kv v0 / Kc)``: where eq. 4 reaches zero [1]_.

    Parameters
    ----------
    J : float
        Inertia of the rotor (kg m^2).
    Kv : float
        Viscous coefficient (N m s/rad), > 0.
    Kc : float
        Coulomb level (N m); ``Kc <= 0`` never stops.
    v0 : float
        Speed at the release (rad/s), > 0.

    Returns
    -------
    float
        The stop time after the release (s); ``inf`` for ``Kc <= 0``.

    References
    ----------
    .. [1] Coast-down friction identification (seeds 000), eq. 3-4.

    Examples
    --------
    The rotor of the paper's Table 1 stops after about 3.55 s:

    >>> round(stop_time(J=0.01, Kv=0.01203, Kc=0.0017, v0=10.0), 4)
    3.5523
    """
    if Kc <= 0.0:
        return float("inf")
    return float(J / Kv * np.log1p(Kv * v0 / Kc))


def coast_velocity(t, J: float, Kv: float, Kc: float, v0: float, stop: bool = True) -> np.ndarray:
    """Velocity of a coasting rotor: paper eq. 4 [1]_, at rest after the stop unless ``stop=False``.

    ``v(t) = (v0 + Kc/Kv) exp(-Kv t / J) - Kc/Kv`` solves ``J dv/dt + Kv v + Kc = 0`` (eq. 3).

    Parameters
    ----------
    t : array_like
        Times after the release (s).
    J, Kv, Kc, v0 : float
        Inertia (kg m^2), viscous coefficient (N m s/rad), Coulomb level (N m), release
        speed (rad/s).
    stop : bool, optional
        Hold the rotor at 0 after the stop time (default); ``False`` gives eq. 4 continued
        to negative speeds.

    Returns
    -------
    numpy.ndarray
        The velocity (rad/s), shaped like ``t``.

    References
    ----------
    .. [1] Coast-down friction identification (seeds 000), eq. 3-4.

    Examples
    --------
    >>> coast_velocity([0.0, 1.0, 5.0], J=0.01, Kv=0.01203, Kc=0.0017, v0=10.0).round(3).tolist()
    [10.0, 2.904, 0.0]
    """
    t = np.asarray(t, float)
    r = Kc / Kv
    v = (v0 + r) * np.exp(-Kv * t / J) - r
    return np.maximum(v, 0.0) if stop else v


def _model_jac(t, J, Kv, Kc, v0, stop=True):
    """Eq. 4 (with the stop) and its analytic Jacobian (N, 3) in (Kv, Kc, v0)."""
    e = np.exp(-Kv * t / J)
    r = Kc / Kv
    v = (v0 + r) * e - r
    G = np.empty((t.size, 3))
    G[:, 0] = -(v0 + r) * (t / J) * e + (Kc / Kv ** 2) * (1.0 - e)
    G[:, 1] = (e - 1.0) / Kv
    G[:, 2] = e
    if stop:
        moving = v > 0.0
        v = np.where(moving, v, 0.0)
        G[~moving] = 0.0
    return v, G


def _check(t, v, name, uniform=False):
    t = np.asarray(t, float)
    v = np.asarray(v, float)
    if t.ndim != 1 or v.shape != t.shape:
        raise InputError(f"{name}: t and v must be 1-D of equal length, got {t.shape} and {v.shape}")
    if t.size < 4:
        raise InputError(f"{name}: a coast-down needs at least 4 samples, got {t.size}")
    if not (np.all(np.isfinite(t)) and np.all(np.isfinite(v))):
        bad = int(np.flatnonzero(~(np.isfinite(t) & np.isfinite(v)))[0])
        raise InputError(f"{name}: non-finite time or velocity at sample {bad}")
    dt = np.diff(t)
    if np.any(dt <= 0):
        raise InputError(f"{name}: time is not strictly increasing at sample "
                         f"{int(np.flatnonzero(dt <= 0)[0]) + 1}")
    if uniform and np.ptp(dt) > 1e-6 * np.mean(dt):
        raise InputError(f"{name}: needs uniform sampling (dt from {dt.min():.6g} to {dt.max():.6g} s)")
    return t - t[0], v, float(t[0])


def _time_domain_stats(tr, v, J, Kv, Kc, v0, free_v0, stop=True):
    """RMS of the residual and standard errors s^2 (G^T G)^-1 from the time-domain model."""
    vm, G = _model_jac(tr, J, Kv, Kc, v0, stop)
    res = v - vm
    names = ("Kv", "Kc", "v0") if free_v0 else ("Kv", "Kc")
    G = G[:, : len(names)]
    dof = max(tr.size - len(names), 1)
    s2 = float(res @ res) / dof
    scale = np.abs(np.array([Kv, Kc, v0])[: len(names)])
    scale[scale == 0.0] = 1.0
    Gs = G * scale
    try:
        cov = s2 * np.linalg.inv(Gs.T @ Gs) * np.outer(scale, scale)
        se = {k: float(np.sqrt(max(cov[i, i], 0.0))) for i, k in enumerate(names)}
        cond = float(np.linalg.cond(Gs))
    except np.linalg.LinAlgError:
        se, cond = {k: float("nan") for k in names}, float("inf")
    if not free_v0:
        se["v0"] = 0.0
    return float(np.sqrt(np.mean(res ** 2))), se, cond


# -- TDM ----------------------------------------------------------------------------------
def _tdm_kc(Kv, t, v, v0, J, literal, e=None):
    """Paper eq. 5, vectorised over a column of Kv values (K, 1)."""
    e = np.exp(-Kv * t / J) if e is None else e
    one_e = 1.0 - e
    den = np.sum(one_e, axis=-1) if literal else np.sum(one_e * one_e, axis=-1)
    return Kv[..., 0] * np.einsum("...i,...i->...", v0 * e - v, one_e) / den


def _tdm_eq6(Kv, t, v, v0, J, literal):
    """Paper eq. 6 (``sum res_i dv_i/dKv``) with ``Kc`` from eq. 5; Kv of shape (K, 1)."""
    e = np.exp(-Kv * t / J)
    Kc = _tdm_kc(Kv, t, v, v0, J, literal, e)[..., None]
    r = Kc / Kv
    res = (v0 + r) * e - r - v
    d = -(v0 + r) * (t / J) * e + (Kc / Kv ** 2) * (1.0 - e)
    return np.einsum("...i,...i->...", res, d)


def tdm(t, v, J: float, v0: float | None = None, *, kv_range=None, n_grid: int = 60,
        kv_step: float | None = None, kv_grid_origin: float = 0.0,
        literal_eq5: bool = False) -> CoastdownResult:
    """The paper's time-domain method (TDM, eqs. 4-6 of [1]_), ``J`` and ``v0`` known.

    ``v0`` defaults to the first measured sample. ``kv_range`` (default ``J/T/50 .. 50 J/T``
    with ``T`` the record length) is scanned on ``n_grid`` log-spaced points for the sign
    change (- to +) of eq. 6 (without ``kv_range``, a 9-point scan over a factor 2 either
    side of an exact-discretisation guess comes first), then refined by Brent's method; among several minima the one
    of least squared residual is kept. ``kv_step`` instead scans a uniform grid of that step
    (``kv_grid_origin + k kv_step``) and returns the point of least ``|eq. 6|`` next to the
    root (the published fixed-step search, e.g. ``kv_step=1e-5`` for Table 2; the refined
    root stays in ``diagnostics["Kv_root"]``). Eq. 4 is
    fitted without the stop: pass the record up to the stop only.

    Parameters
    ----------
    t, v : array_like
        Sample times (s, the release at ``t[0]``) and coasting velocity (rad/s, > 0), (N,).
    J : float
        Inertia (kg m^2).
    v0 : float, optional
        Release speed (rad/s); the first sample when omitted.
    kv_range : (float, float), optional
        Search range of ``Kv`` (N m s/rad).
    n_grid : int, optional
        Log-spaced points of the scan.
    kv_step, kv_grid_origin : float, optional
        The fixed-step search's step and origin (see above).
    literal_eq5 : bool, optional
        Use eq. 5 as printed (denominator without the square).

    Returns
    -------
    CoastdownResult
        ``Kv``, ``Kc``, standard errors, residual RMS and the search's diagnostics.

    References
    ----------
    .. [1] Coast-down friction identification (seeds 000), eq. 4-6 and Table 2.

    Examples
    --------
    On the noise-free coast of the paper's Table 1 the TDM returns the true values:

    >>> from ident.coastdown.estimators import simulate_sdof_coastdown
    >>> import numpy as np
    >>> sim = simulate_sdof_coastdown(0.01, 0.01203, 0.0017, 10.0, fs=1000.0, duration=None,
    ...                               snr_db=60.0, rng=np.random.default_rng(0))
    >>> r = tdm(sim.t, sim.v_clean, J=0.01)
    >>> print(f"Kv = {r.Kv:.5f} N m s/rad, Kc = {r.Kc:.4f} N m")
    Kv = 0.01203 N m s/rad, Kc = 0.0017 N m
    """
    tr, v, t0 = _check(t, v, "tdm")
    v0 = float(v[0]) if v0 is None else float(v0)
    T = float(tr[-1])
    lo, hi = kv_range if kv_range is not None else (J / T / 50.0, 50.0 * J / T)
    args = (tr, v, v0, J, literal_eq5)

    def cost(kv):
        kc = float(_tdm_kc(np.array([[kv]]), *args[:3], J, literal_eq5)[0])
        res = coast_velocity(tr, J, kv, kc, v0, stop=False) - v
        return float(res @ res), kc

    iterations = 0
    # scan a narrow bracket around a cheap guess first, the whole range if it holds no root
    kv_g = _initial_guess(tr, v, J, v0)[0] if kv_range is None else None
    for grid in ([np.geomspace(kv_g / 2, kv_g * 2, 9)] if kv_g and lo < kv_g < hi else []) \
            + [np.geomspace(lo, hi, n_grid)]:
        grid = grid[:, None]
        g = _tdm_eq6(grid, *args)
        idx = np.flatnonzero((g[:-1] < 0) & (g[1:] >= 0))
        if idx.size:
            break
    best = None
    for i in idx:
        root, info = brentq(lambda k: float(_tdm_eq6(np.array([[k]]), *args)[0]),
                            float(grid[i, 0]), float(grid[i + 1, 0]), xtol=1e-15,
                            rtol=4 * np.finfo(float).eps, full_output=True)
        iterations += info.iterations
        c = cost(root)[0]
        if best is None or c < best[0]:
            best = (c, root, info.converged)
    if best is None:     # no interior minimum: the edge of the range with the lower cost
        Kv = min((float(grid[0, 0]), float(grid[-1, 0])), key=lambda k: cost(k)[0])
        converged = False
    else:
        _, Kv, converged = best
    Kv_root = Kv
    if kv_step is not None:
        # the fixed-step search on the grid k * kv_step: the grid point of least |eq. 6|
        # next to the root (the same point a full scan finds where eq. 6 is monotone there)
        k0 = np.floor((Kv - kv_grid_origin) / kv_step)
        cand = kv_grid_origin + (k0 + np.arange(-1, 3))[:, None] * kv_step
        cand = cand[cand[:, 0] > 0]
        Kv = float(cand[np.argmin(np.abs(_tdm_eq6(cand, *args))), 0])
    Kc = cost(Kv)[1]
    rms, se, cond = _time_domain_stats(tr, v, J, Kv, Kc, v0, False, stop=False)
    res = coast_velocity(tr, J, Kv, max(Kc, 0.0), v0) - v
    return CoastdownResult(Kv=Kv, Kc=Kc, v0=v0, stderr=se, rms=rms,
                           method="tdm", converged=bool(converged), iterations=int(iterations),
                           cond=cond, t_stop=stop_time(J, Kv, Kc, v0) if Kc > 0 else float("inf"),
                           t0=t0, n_samples=int(tr.size),
                           diagnostics={"kv_step": kv_step, "kv_grid_origin": kv_grid_origin, "literal_eq5": literal_eq5,
                                        "kv_range": [lo, hi],
                                        "rms_with_stop": float(np.sqrt(np.mean(res ** 2))),
                                        "Kv_root": Kv_root, "Kc_root": cost(Kv_root)[1]})


# -- FDM ----------------------------------------------------------------------------------
def record_spectrum(t, v, w_max: float, pad: int = 64):
    """Spectrum ``V_e(jw)`` of a record at the FDM's frequencies (the input of eqs. 7-8 of [1]_).

    The Fourier integral ``V(jw) = int v(t) exp(-j w t) dt`` over the record, exact for the
    piecewise-linear interpolant of uniform samples (zero outside the record), at
    ``w_k = k dw`` with ``dw = 2 pi / (pad N dt)`` and ``0 <= w_k <= w_max`` (the grid of an
    FFT zero-padded ``pad`` times, computed by a chirp-z transform).

    Parameters
    ----------
    t : array_like
        Uniform sample times (s), (N,).
    v : array_like
        Velocity records (rad/s), (N,) or (runs, N).
    w_max : float
        Highest frequency (rad/s).
    pad : int, optional
        Zero-padding factor of the frequency grid.

    Returns
    -------
    w : numpy.ndarray
        Frequencies (rad/s), (K,).
    V : numpy.ndarray
        Complex spectrum, ``v.shape[:-1] + (K,)``.

    References
    ----------
    .. [1] Coast-down friction identification (seeds 000), eq. 7-8.

    Examples
    --------
    A constant 1 rad/s over 1 s has ``V(0) = 1`` rad:

    >>> w, V = record_spectrum(np.linspace(0.0, 1.0, 101), np.ones(101), w_max=10.0)
    >>> round(float(V[0].real), 6), bool(w[1] > 0)
    (1.0, True)
    """
    from scipy.signal import czt

    tr = np.asarray(t, float) - float(np.asarray(t, float)[0])
    v = np.asarray(v, float)
    n = tr.size
    dt = float(tr[-1] / (n - 1))
    dw = 2.0 * np.pi / (int(pad) * n * dt)
    K = int(np.floor(w_max / dw)) + 1
    w = dw * np.arange(K)
    u = v.copy()
    u[..., 0] = 0.0
    u[..., -1] = 0.0
    # interior hats: dt sinc^2(w dt/2) e^{-j w t_i}; the two end samples carry half-hats
    hat = dt * np.sinc(w * dt / (2.0 * np.pi)) ** 2
    V = hat * czt(u, m=K, w=np.exp(-1j * dw * dt), a=1.0, axis=-1)
    s = 1j * w[1:]
    # int_0^dt (1 - t/dt) e^-st dt = (1 - phi(s dt)) / s and the last half-hat's
    # e^-sT (phi(-s dt) - 1) / s, phi(x) = (1 - e^-x) / x (mocap.numerics.phi, complex x)
    first = (1.0 - phi(s * dt)) / s
    last = np.exp(-s * tr[-1]) * (phi(-s * dt) - 1.0) / s
    V[..., 1:] += v[..., :1] * first + v[..., -1:] * last
    V[..., 0] = dt * (np.sum(v, axis=-1) - 0.5 * (v[..., 0] + v[..., -1]))
    return w, V


def fdm_batch(t, v, J: float, v0, *, w_max: float = 30.0, pad: int = 64):
    """The FDM's closed form, eqs. 10-11 of [1]_, for many records at once.

    Parameters
    ----------
    t : array_like
        Uniform sample times (s), (N,).
    v : array_like
        Velocity records (rad/s), (runs, N).
    J : float
        Inertia (kg m^2).
    v0 : float or array_like
        Release speed(s) (rad/s), scalar or (runs,).
    w_max : float, optional
        Highest frequency used (rad/s).
    pad : int, optional
        Zero-padding factor of :func:`record_spectrum`.

    Returns
    -------
    Kv, Kc : numpy.ndarray
        Estimates, (runs,).
    M : int
        Number of frequencies used.

    References
    ----------
    .. [1] Coast-down friction identification (seeds 000), eq. 9-11.
    """
    v = np.atleast_2d(np.asarray(v, float))
    _check(t, v[0], "fdm", uniform=True)
    if not np.all(np.isfinite(v)):
        raise InputError("fdm: non-finite velocity samples")
    v0 = np.broadcast_to(np.asarray(v0, float), v.shape[:1])
    w, V = record_spectrum(t, v, w_max, pad)
    sel = w > 0.0
    w, R, I = w[sel], V.real[:, sel], V.imag[:, sel]
    M = w.size
    SR = np.sum(R * J * w ** 2, axis=-1)
    SI = np.sum(I * w, axis=-1)
    num = M * np.sum(R * J * w ** 2, axis=-1) * v0 + SR * SI                   # eq. 11
    den = M * np.sum((I ** 2 + R ** 2) * w ** 2, axis=-1) - SI * SI
    Kv = num / den
    Kc = (SR + Kv * SI) / M                                                    # eq. 10
    return Kv, Kc, M


def fdm(t, v, J: float, v0: float | None = None, *, w_max: float | None = None,
        pad: int = 64) -> CoastdownResult:
    """The paper's frequency-domain method: eq. 9 solved by eqs. 10-11 (``J``, ``v0`` known).

    ``V_e(jw_k) = R_k + j I_k`` is :func:`record_spectrum` (uniform samples needed) at the
    ``M`` frequencies ``0 < w_k <= w_max`` rad/s (default ``100 / T`` for a record of
    length ``T``: 28 rad/s, 16 cycles over the paper's 3.55 s coast); ``v0`` defaults to the
    first sample. See the module docstring (item 4) for the bias of eq. 8 on a record that
    stops, and the benchmark for its sensitivity to ``v0``.

    Parameters
    ----------
    t, v : array_like
        Uniform sample times (s, release at ``t[0]``) and coasting velocity (rad/s), (N,).
    J : float
        Inertia (kg m^2).
    v0 : float, optional
        Release speed (rad/s); the first sample when omitted.
    w_max : float, optional
        Highest frequency used (rad/s).
    pad : int, optional
        Zero-padding factor of the frequency grid.

    Returns
    -------
    CoastdownResult
        ``Kv`` and ``Kc`` (no standard errors: the method gives none).

    References
    ----------
    .. [1] Coast-down friction identification (seeds 000), eq. 7-11.

    Examples
    --------
    >>> from ident.coastdown.estimators import simulate_sdof_coastdown
    >>> sim = simulate_sdof_coastdown(0.01, 0.01203, 0.0017, 10.0, fs=1000.0, duration=None,
    ...                               snr_db=60.0, rng=np.random.default_rng(0))
    >>> r = fdm(sim.t, sim.v_clean, J=0.01)
    >>> print(f"Kv = {r.Kv:.4f} N m s/rad, Kc = {r.Kc:.4f} N m")
    Kv = 0.0120 N m s/rad, Kc = 0.0017 N m
    """
    tr, v, t0 = _check(t, v, "fdm", uniform=True)
    v0 = float(v[0]) if v0 is None else float(v0)
    w_max = 100.0 / float(tr[-1]) if w_max is None else float(w_max)
    Kv, Kc, M = fdm_batch(tr, v, J, v0, w_max=w_max, pad=pad)
    if M < 2:
        raise InputError(f"fdm: only {M} frequencies in (0, {w_max}] rad/s; "
                         f"raise w_max or pad (record {tr[-1]:.3g} s)")
    Kv, Kc = float(Kv[0]), float(Kc[0])
    ok = bool(np.isfinite(Kv) and np.isfinite(Kc) and Kv > 0)
    rms = float(np.sqrt(np.mean((v - coast_velocity(tr, J, Kv, Kc, v0, stop=Kc > 0)) ** 2))) if ok \
        else float("nan")
    return CoastdownResult(Kv=Kv, Kc=Kc, v0=v0,
                           stderr={"Kv": float("nan"), "Kc": float("nan"), "v0": 0.0},
                           rms=rms, method="fdm", converged=ok, iterations=0,
                           t_stop=stop_time(J, Kv, Kc, v0) if ok and Kc > 0 else float("inf"),
                           t0=t0, n_samples=int(tr.size),
                           diagnostics={"M": M, "w_max": w_max, "pad": pad})


# -- NLS / ML -----------------------------------------------------------------------------
def _initial_guess(tr, v, J, v0):
    """Exact discretisation ``v_{i+1} = a v_i - b`` (uniform dt) regressed on the samples
    that are clearly moving: ``Kv = -J ln(a)/dt``, ``Kc = Kv b/(1 - a)``."""
    dt = np.diff(tr)
    vmax = float(np.max(v))
    mov = np.flatnonzero((v[:-1] > 0.2 * vmax) & (v[1:] > 0.2 * vmax))
    guess = None
    if mov.size >= 3 and np.ptp(dt) <= 1e-6 * np.mean(dt):
        A = np.column_stack([v[mov], -np.ones(mov.size)])
        (a, b), *_ = np.linalg.lstsq(A, v[mov + 1], rcond=None)
        if 0.0 < a < 1.0:
            h = float(np.mean(dt))
            Kv = -J * np.log(a) / h
            Kc = Kv * b / (1.0 - a)
            guess = (Kv, max(Kc, 1e-3 * Kv * vmax))
    if guess is None:       # e-folding time of the fall from v0
        T = float(tr[np.argmax(v < v0 / np.e)]) if np.any(v < v0 / np.e) else float(tr[-1])
        guess = (J / max(T, 1e-9), 1e-2 * J / max(T, 1e-9) * abs(v0))
    return guess


def nls(t, v, J: float, v0: float | None = None, *, x0=None, max_nfev: int = 200) -> CoastdownResult:
    """Fit a coast-down's friction by nonlinear least squares on eq. 4 with the stop.

    Maximum likelihood in white Gaussian noise: ``v = max((v0 + Kc/Kv) exp(-Kv t/J) - Kc/Kv,
    0)`` [1]_; estimates (Kv, Kc) and ``v0`` unless ``v0`` is given. The record may extend
    past the stop. ``x0`` optionally starts the solver at (Kv, Kc[, v0]).

    Parameters
    ----------
    t, v : array_like
        Sample times (s, release at ``t[0]``) and velocity (rad/s, positive while coasting), (N,).
    J : float
        Inertia (kg m^2).
    v0 : float, optional
        Release speed (rad/s); estimated when omitted.
    x0 : sequence of float, optional
        Start of the solver, (Kv, Kc[, v0]); an exact-discretisation regression by default.
    max_nfev : int, optional
        Most function evaluations of the solver.

    Returns
    -------
    CoastdownResult
        ``Kv``, ``Kc``, ``v0``, their standard errors, residual RMS and the stop time.

    References
    ----------
    .. [1] Coast-down friction identification (seeds 000), eq. 4 with the stop.

    Examples
    --------
    Table 1's rotor at 60 dB SNR, 1 kHz; ``v0`` estimated with the friction:

    >>> from ident.coastdown.estimators import simulate_sdof_coastdown
    >>> sim = simulate_sdof_coastdown(0.01, 0.01203, 0.0017, 10.0, fs=1000.0, duration=None,
    ...                               snr_db=60.0, rng=np.random.default_rng(0))
    >>> r = nls(sim.t, sim.v, J=0.01)
    >>> print(f"Kv = {r.Kv:.5f}, Kc = {r.Kc:.5f}, v0 = {r.v0:.3f}")
    Kv = 0.01203, Kc = 0.00170, v0 = 10.000
    >>> abs(r.Kv - 0.01203) < 3 * r.stderr["Kv"]
    True
    """
    tr, v, t0 = _check(t, v, "nls")
    free_v0 = v0 is None
    v0_init = float(v[0]) if free_v0 else float(v0)
    if x0 is None:
        kv0, kc0 = _initial_guess(tr, v, J, v0_init)
        x0 = [kv0, kc0] + ([v0_init] if free_v0 else [])
    x0 = np.asarray(x0, float)
    scale = np.abs(x0).copy()
    scale[scale == 0] = 1.0
    p = len(x0)

    def unpack(z):
        x = z * scale
        return x[0], x[1], (x[2] if free_v0 else v0_init)

    def fun(z):
        Kv, Kc, vv = unpack(z)
        return coast_velocity(tr, J, Kv, Kc, vv) - v

    def jac(z):
        Kv, Kc, vv = unpack(z)
        return _model_jac(tr, J, Kv, Kc, vv)[1][:, :p] * scale

    lb = np.array([1e-12, 0.0, -np.inf][:p]) / scale
    z0 = np.clip(x0 / scale, lb + 1e-12, np.inf)
    sol = least_squares(fun, z0, jac=jac, bounds=(lb, np.full(p, np.inf)), method="trf",
                        x_scale=1.0, xtol=1e-12, ftol=1e-12, gtol=1e-12, max_nfev=max_nfev)
    Kv, Kc, vv = (float(x) for x in unpack(sol.x))
    rms, se, cond = _time_domain_stats(tr, v, J, Kv, Kc, vv, free_v0)
    return CoastdownResult(Kv=Kv, Kc=Kc, v0=vv, stderr=se, rms=rms,
                           method="nls", converged=bool(sol.success), iterations=int(sol.nfev),
                           cond=cond, t_stop=stop_time(J, Kv, Kc, vv), t0=t0,
                           n_samples=int(tr.size),
                           diagnostics={"v0_estimated": free_v0, "status": int(sol.status),
                                        "message": str(sol.message),
                                        "active_bounds": [int(a) for a in sol.active_mask]})


# -- Cramer-Rao bound ---------------------------------------------------------------------
def crb(t, J: float, Kv: float, Kc: float, v0: float, sigma: float, *,
        estimate_v0: bool = False) -> CoastdownBound:
    r"""Cramer-Rao bound of the coast-down parameters (Kv, Kc[, v0]).

    For samples at ``t`` (release at ``t[0]``) of eq. 4 with the stop [1]_, in white
    Gaussian noise of standard deviation ``sigma``:

    .. math::

        \operatorname{cov} \succeq \left(G^T G / \sigma^2\right)^{-1}

    with ``G`` the analytic Jacobian of the model.

    Parameters
    ----------
    t : array_like
        Sample times (s), (N,).
    J, Kv, Kc, v0 : float
        Inertia (kg m^2) and the true parameters (N m s/rad, N m, rad/s).
    sigma : float
        Standard deviation of the velocity noise (rad/s).
    estimate_v0 : bool, optional
        Bound ``v0`` as a third unknown.

    Returns
    -------
    CoastdownBound
        Covariance bound, its standard deviations and relative values.

    References
    ----------
    .. [1] Coast-down friction identification (seeds 000), eq. 4 and Table 2 (the relative
       errors this bounds).

    Examples
    --------
    >>> b = crb(np.arange(3553) / 1000.0, 0.01, 0.01203, 0.0017, 10.0, sigma=0.0034)
    >>> b.rel["Kc"] < 1e-3 and b.rel["Kv"] < b.rel["Kc"]
    True
    """
    tr = np.asarray(t, float) - float(np.asarray(t, float)[0])
    names = ("Kv", "Kc", "v0") if estimate_v0 else ("Kv", "Kc")
    G = _model_jac(tr, J, Kv, Kc, v0)[1][:, : len(names)]
    F = G.T @ G / sigma ** 2
    scale = np.array([Kv, Kc, v0])[: len(names)]
    Fs = F * np.outer(scale, scale)
    cov = np.linalg.inv(Fs) * np.outer(scale, scale)
    return CoastdownBound(names=names, values={"Kv": Kv, "Kc": Kc, "v0": v0}, cov=cov,
                          fisher=F, sigma=float(sigma))


# -- simulation ---------------------------------------------------------------------------
def simulate_sdof_coastdown(J: float, Kv: float, Kc: float, v0: float, fs: float,
                       duration: float | None, snr_db: float, rng: np.random.Generator,
                       runs: int | None = None) -> CoastdownSim:
    """Samples ``t = k/fs`` over ``[0, duration]`` (``None``: up to the stop time) of eq. 4
    with the stop, plus white Gaussian noise at ``snr_db`` (module docstring definition).
    ``runs`` draws that many independent noise records at once (``v`` of shape (runs, N)).

    Parameters
    ----------
    J, Kv, Kc, v0 : float
        Inertia (kg m^2), viscous coefficient (N m s/rad), Coulomb level (N m), release
        speed (rad/s); the paper's Table 1 is ``0.01, 0.01203, 0.0017, 10``.
    fs : float
        Sample rate (Hz).
    duration : float or None
        Record length (s); ``None`` ends it at the stop.
    snr_db : float
        Signal-to-noise ratio (dB).
    rng : numpy.random.Generator
        Source of the noise.
    runs : int, optional
        Independent noise records to draw.

    Returns
    -------
    CoastdownSim
        Times, noisy and clean velocity, the noise level and the stop time.

    References
    ----------
    .. [1] Coast-down friction identification (seeds 000), Table 1 (the simulated rotor) and Table
       2 (the SNRs).

    Examples
    --------
    >>> sim = simulate_sdof_coastdown(0.01, 0.01203, 0.0017, 10.0, fs=1000.0, duration=None,
    ...                               snr_db=20.0, rng=np.random.default_rng(1), runs=3)
    >>> sim.v.shape, round(sim.t_stop, 2)
    ((3, 3553), 3.55)
    """
    ts = stop_time(J, Kv, Kc, v0)
    T = ts if duration is None else float(duration)
    n = int(np.floor(T * fs + 1e-9)) + 1
    t = np.arange(n) / fs
    vc = coast_velocity(t, J, Kv, Kc, v0)
    sigma = float(np.sqrt(np.mean(vc ** 2) * 10.0 ** (-snr_db / 10.0)))
    shape = (n,) if runs is None else (int(runs), n)
    v = vc + sigma * rng.standard_normal(shape)
    return CoastdownSim(t=t, v=v, v_clean=vc, sigma=sigma, t_stop=ts, snr_db=float(snr_db))


# -- campaign trials ----------------------------------------------------------------------
_ESTIMATORS = {"tdm": tdm, "fdm": fdm, "nls": nls}


def coast_segments(t, qd, tau=None, coasting=None, *, tau_tol: float | None = None,
                   min_samples: int = 20):
    """Index ranges ``[(start, stop), ...]`` (stop exclusive) of the coast phases.

    The drive is off where ``coasting`` is True, or else where ``|tau| <= tau_tol``
    (default 2 % of ``max |tau|``); without either the whole record is one phase, started
    at its sample of largest ``|qd|``. A phase starts at its first sample (the release: not
    at the largest noisy ``|qd|``, which would bias the measured ``v0`` upwards, and TDM/FDM
    take ``v0`` as known) and runs to its end (the rest after the stop included).

    Parameters
    ----------
    t, qd : array_like
        Times (s) and velocity (rad/s), (N,).
    tau : array_like, optional
        Drive torque (N m), (N,).
    coasting : array_like of bool, optional
        Where the drive is off, (N,).
    tau_tol : float, optional
        Torque below which the drive counts as off (N m).
    min_samples : int, optional
        Shortest phase kept.

    Returns
    -------
    list of (int, int)
        ``(start, stop)`` sample ranges, stop exclusive.

    Examples
    --------
    >>> coast_segments(np.arange(100) * 0.01, np.ones(100), tau=np.r_[np.ones(40), np.zeros(60)])
    [(40, 100)]
    """
    qd = np.asarray(qd, float)
    n = qd.size
    if coasting is not None:
        off = np.asarray(coasting, bool)
    elif tau is not None:
        tau = np.asarray(tau, float)
        tol = 0.02 * float(np.nanmax(np.abs(tau))) if tau_tol is None else float(tau_tol)
        off = np.abs(tau) <= tol
    else:
        off = np.ones(n, bool)
    if off.shape != (n,):
        raise InputError(f"coast_segments: mask/torque of shape {off.shape} for {n} velocity samples")
    edges = np.flatnonzero(np.diff(np.concatenate([[0], off.astype(np.int8), [0]])))
    segs = []
    for a, b in zip(edges[::2], edges[1::2]):
        if b - a < min_samples:
            continue
        if coasting is None and tau is None:
            a = a + int(np.argmax(np.abs(qd[a:b])))
        if b - a >= min_samples:
            segs.append((int(a), int(b)))
    return segs


def coastdown_from_trial(t, qd, J: float, tau=None, coasting=None, *, method: str = "nls",
                         tau_tol: float | None = None, min_speed: float = 0.0,
                         **kwargs) -> list:
    """Identify (Kv, Kc) from each coast phase of a ``kind = "coastdown"`` trial.

    ``t`` (s), ``qd`` (rad/s, link or motor velocity of one joint; link side), ``J`` the
    inertia seen by that velocity (kg m^2), ``tau`` the drive torque of the joint (N m) or
    a boolean ``coasting`` mask (e.g. the controller mode). The phases are found by
    :func:`coast_segments` (drive torque switched off, i.e. ``|tau|`` drops to about 0);
    each is mirrored to positive velocity and passed to ``method`` ("nls", "tdm" or "fdm";
    TDM and FDM get the phase cut at the first sample at or below zero speed, as eq. 4 has
    no stop). Phases released slower than ``min_speed`` are skipped.

    Parameters
    ----------
    t, qd : array_like
        Times (s) and velocity (rad/s) of one joint, (N,).
    J : float
        Inertia seen by ``qd`` (kg m^2).
    tau : array_like, optional
        Drive torque (N m), (N,).
    coasting : array_like of bool, optional
        Where the drive is off, (N,).
    method : {"nls", "tdm", "fdm"}, optional
        Estimator of each phase.
    tau_tol : float, optional
        Torque below which the drive counts as off (N m).
    min_speed : float, optional
        Slowest release kept (rad/s).
    **kwargs
        Passed to the estimator.

    Returns
    -------
    list of CoastdownResult
        One per phase (``t0`` = release time, ``direction`` = +-1).

    References
    ----------
    .. [1] Coast-down friction identification (seeds 000), eq. 3-4.

    Examples
    --------
    A record that drives at 10 rad/s, then coasts (torque 0) to rest:

    >>> t = np.arange(4000) / 1000.0
    >>> on = t < 0.3
    >>> qd = np.where(on, 10.0, coast_velocity(t - 0.3, 0.01, 0.01203, 0.0017, 10.0))
    >>> tau = np.where(on, 0.12, 0.0)
    >>> [r] = coastdown_from_trial(t, qd, 0.01, tau=tau)
    >>> print(f"Kc = {r.Kc:.4f} N m, released at {r.t0:.1f} s")
    Kc = 0.0017 N m, released at 0.3 s
    """
    if method not in _ESTIMATORS:
        raise InputError(f"coastdown: unknown method {method!r}; one of {sorted(_ESTIMATORS)}")
    t = np.asarray(t, float)
    qd = np.asarray(qd, float)
    if t.shape != qd.shape or t.ndim != 1:
        raise InputError(f"coastdown: t {t.shape} and qd {qd.shape} must be 1-D of equal length")
    out = []
    for a, b in coast_segments(t, qd, tau, coasting, tau_tol=tau_tol):
        sgn = 1 if qd[a] >= 0 else -1
        v = sgn * qd[a:b]
        if v[0] <= min_speed:
            continue
        tt = t[a:b]
        if method != "nls":
            below = np.flatnonzero(v <= 0.0)
            end = int(below[0]) if below.size else v.size
            tt, v = tt[:end], v[:end]
        r = _ESTIMATORS[method](tt, v, J, **kwargs)
        out.append(CoastdownResult(**{**r.__dict__, "direction": sgn}))
    return out
