"""Signals for identification: one time base, finite Fourier fits, analytic derivatives.

The thesis (002, ch. 3-4) fits finite Fourier series (eq. 3-2) to the motor angle ``qm``
(robot clock) and to the link angle ``q`` (motion-capture clock) and differentiates the
series analytically; the fit error it reports is under 0.05 deg for motor angles and 0.2 deg
for link angles. This module does the same and puts everything on the robot log's samples.

How a fit is chosen (:class:`FourierSmoother`):

1. **Fundamental** ``wf`` (:func:`estimate_fundamental`): candidates are ``2 pi k / D`` for a
   trial of duration ``D`` holding ``k = 1..8`` whole periods, and ``w_peak / h`` for the
   periodogram's highest peak ``w_peak`` (``h = 1..6``). Each candidate is scored by BIC with
   its best number of harmonics; the winner is refined by a bounded 1-D search of the
   residual over +-half a frequency bin (``pi / D``).
2. **Harmonics** ``N``: the Bayesian information criterion ``n log(RSS/n) + (2N+1) log n``
   over ``N = 1..max_harmonics`` (all ``N`` from one Cholesky factorisation of the
   design's Gram matrix).
3. **Rests**: samples before the first and after the last one moving faster than 1 % of the
   peak speed (the still holds around the excitation) are left out of the Fourier fit.
4. **Non-periodic fallback**: if the Fourier residual RMS exceeds ``periodic_ratio`` times the
   noise level (the residual of the smoother below) plus ``periodic_atol``, the trial is not
   one or more periods of a finite Fourier series and :class:`SavGolSmoother` is used:
   a Savitzky-Golay filter (cubic, ``window_s`` long) on a uniform grid at the median sample
   interval, whose local polynomials also give the velocity and acceleration.

Time bases: the robot log clock is the reference. Link angles come on the marker clock;
``t_robot = t_marker + time_offset`` (FORMAT.md: 0 unless the trial says otherwise; it may be
estimated with :func:`estimate_time_offset`).
"""
from __future__ import annotations

import dataclasses
import functools
from dataclasses import dataclass, field

import numpy as np
from scipy.linalg import lapack
from scipy.optimize import minimize_scalar

from mocap.io.errors import InputError
from mocap.numerics import differentiate, savgol, savgol_kernel, savgol_window  # noqa: F401  (re-exported: the one differentiator)

from ident.friction.constants import REST_FRAC
from ident.signals.blas import one_blas_thread  # noqa: F401  (re-exported)
from ident.signals.fourier import FourierSeries, design_matrices

__all__ = ["savgol_window", "differentiate", "SmoothFit", "FourierSmoother", "SavGolSmoother", "estimate_fundamental",
           "select_harmonics", "estimate_time_offset", "JointSignals",
           "one_blas_thread"]


# ---------------------------------------------------------------------------------------------
# uniform grids
# ---------------------------------------------------------------------------------------------
def _clean(t, q):
    t = np.asarray(t, float)
    q = np.asarray(q, float)
    if t.ndim != 1 or q.shape != t.shape:
        raise ValueError(f"time {t.shape} and signal {q.shape} must be 1-D of equal length")
    ok = np.isfinite(t) & np.isfinite(q)
    if ok.sum() < 8:
        raise InputError(f"only {int(ok.sum())} finite samples; at least 8 are needed to fit a signal")
    return t[ok], q[ok]


_GRIDS: dict = {}      # sample times (bytes) -> (uniform grid, interval): a few recent ones


def _grid(t):
    """``(tu, dt)``: the uniform grid at the median interval of the sample times ``t``. The
    grid of the last few time bases is remembered (a search smooths many signals, or one
    signal at many windows, on the same samples)."""
    key = t.tobytes()
    hit = _GRIDS.get(key)
    if hit is None:
        dt = float(np.median(np.diff(t)))
        n = int(np.floor((t[-1] - t[0]) / dt)) + 1
        hit = (t[0] + dt * np.arange(n), dt)
        hit[0].setflags(write=False)
        if len(_GRIDS) >= 8:
            _GRIDS.pop(next(iter(_GRIDS)))
        _GRIDS[key] = hit
    return hit


def _uniform(t, q):
    """Resample onto a uniform grid at the median interval (linear interpolation over gaps)."""
    tu, dt = _grid(t)
    return tu, np.interp(tu, t, q), dt


# ---------------------------------------------------------------------------------------------
# results
# ---------------------------------------------------------------------------------------------
@dataclass(frozen=True, eq=False)
class SmoothFit:
    """A smooth model of one signal: evaluate it (and its derivatives) at any time.

    ``method`` is ``"fourier"`` (``series`` set) or ``"savgol"`` (grid values set).
    ``rms``/``max_abs`` are the residuals against the samples (signal units, rad).
    """

    method: str
    rms: float
    max_abs: float
    n_samples: int
    t_start: float
    t_end: float
    series: FourierSeries | None = None
    cond: float = float("nan")
    noise_rms: float = float("nan")
    grid: tuple = field(default=(), repr=False)  # (t, q, qd, qdd) for the smoother
    window_s: float = float("nan")      # savgol window (s); NaN for Fourier
    sigma: float = float("nan")         # noise level of the signal (rad)
    qd_noise: float = float("nan")      # standard deviation the noise implies for qd (rad/s)
    qdd_noise: float = float("nan")     # ... and for qdd (rad/s^2)
    bandwidth_hz: float = float("nan")  # highest Fourier harmonic, or the savgol -3 dB frequency

    @property
    def wf(self) -> float:
        return float(self.series.wf) if self.series is not None else float("nan")

    @property
    def n_harmonics(self) -> int:
        return self.series.n_harmonics if self.series is not None else 0

    def evaluate(self, t, order: int = 2):
        """(q, qd, qdd) at ``t`` (rad, rad/s, rad/s^2); ``order`` limits how many are returned."""
        t = np.asarray(t, float)
        if self.series is not None:
            return self.series.evaluate(t, order)
        tg = self.grid[0]
        return tuple(np.interp(t, tg, g) for g in self.grid[1:2 + order])

    def to_dict(self) -> dict:
        d = {"method": self.method, "rms": self.rms, "rms_deg": float(np.degrees(self.rms)),
             "max_abs": self.max_abs, "n_samples": self.n_samples, "noise_rms": self.noise_rms,
             "t_start": self.t_start, "t_end": self.t_end, "window_s": self.window_s,
             "bandwidth_hz": self.bandwidth_hz, "sigma": self.sigma, "qd_noise": self.qd_noise,
             "qdd_noise": self.qdd_noise}
        if self.series is not None:
            d.update({"wf": self.wf, "n_harmonics": self.n_harmonics, "cond": self.cond,
                      "q0": float(self.series.q0), "a": np.asarray(self.series.a).tolist(),
                      "b": np.asarray(self.series.b).tolist()})
        return d


# ---------------------------------------------------------------------------------------------
# Savitzky-Golay smoother (non-periodic fallback)
# ---------------------------------------------------------------------------------------------
class SavGolSmoother:
    r"""Savitzky-Golay smoothing and differentiation on a uniform grid.

    The fallback of :class:`FourierSmoother` for non-periodic trials [1]_. With
    ``window_s="auto"`` the window is chosen from the data by generalised cross-validation
    [2]_ over ``n_windows`` lengths spaced geometrically from ``min_window_s`` to
    ``max_window_s``:

    .. math::

        \mathrm{GCV}(w) = \frac{n\, \mathrm{RSS}}{(n - \operatorname{tr} H)^2}

    with ``tr H = n h_0(w)`` (the filter's centre weight), the classical data-driven choice
    of a linear smoother's bandwidth.

    The fit reports the window and the noise level ``sigma = sqrt(RSS / (n - tr H))`` and,
    from the filter coefficients, the standard deviation the noise implies for the velocity
    and acceleration (``qd_noise = sigma ||h_1||``, ``qdd_noise = sigma ||h_2||``); bias from
    too wide a window is what GCV balances against that noise.

    Parameters
    ----------
    window_s : float or {"auto"}, optional
        Window length (s), default 0.1, or ``"auto"``.
    polyorder : int, optional
        Local polynomial degree (>= 2; default 3).
    min_window_s, max_window_s : float, optional
        Range of the GCV search (s).
    n_windows : int, optional
        Window lengths tried by the GCV search (>= 2).

    Raises
    ------
    ValueError
        If a setting is out of range.

    References
    ----------
    .. [1] Savitzky & Golay 1964, smoothing and differentiation of data by simplified least
       squares procedures.
    .. [2] Craven & Wahba 1979, smoothing noisy data with spline functions (GCV).
    """

    def __init__(self, window_s: float | str = 0.1, polyorder: int = 3, min_window_s: float = 0.004,
                 max_window_s: float = 0.4, n_windows: int = 14):
        auto = isinstance(window_s, str)
        if auto and window_s != "auto":
            raise ValueError(f"window_s must be seconds or 'auto', got {window_s!r}")
        if (not auto and window_s <= 0) or polyorder < 2:
            raise ValueError("window_s must be > 0 (or 'auto') and polyorder >= 2")
        if not 0 < min_window_s < max_window_s or n_windows < 2:
            raise ValueError("need 0 < min_window_s < max_window_s and n_windows >= 2")
        self.window_s = window_s if auto else float(window_s)
        self.polyorder = int(polyorder)
        self.min_window_s = float(min_window_s)
        self.max_window_s = float(max_window_s)
        self.n_windows = int(n_windows)

    def _window(self, dt: float, n: int, window_s: float | None = None) -> int:
        return savgol_window(self.window_s if window_s is None else window_s, dt, n,
                             self.polyorder)

    @staticmethod
    def grid_of(t, q) -> tuple[float, int]:
        """``(dt, n)``: the uniform grid :meth:`fit` resamples ``(t, q)`` onto (interval and
        number of samples)."""
        t, q = _clean(t, q)
        tu, dt = _grid(t)
        return dt, int(tu.size)

    def window_samples(self, dt: float, n: int) -> int | None:
        """The window (samples) :meth:`fit` uses on a grid of ``n`` samples at ``dt``
        (:meth:`grid_of`) with a fixed ``window_s`` (None with ``window_s="auto"``, chosen
        from the data). Two fits whose windows in samples agree on the same samples are the
        same fit."""
        return None if self.window_s == "auto" else self._window(dt, n)

    def _gcv_window(self, qu, dt):
        """(window, sigma) minimising GCV over the candidate windows."""
        n = qu.size
        cands = sorted({self._window(dt, n, ws) for ws in
                        np.geomspace(self.min_window_s, self.max_window_s, self.n_windows)})
        best = None
        for w in cands:  # a dozen candidate windows, each one vectorised filter
            if w <= self.polyorder:
                continue
            g0 = savgol(qu, w, self.polyorder)
            rss = float(np.sum((qu - g0) ** 2))
            h0 = float(savgol_kernel(w, self.polyorder)[w // 2])
            dof = n * (1.0 - h0)
            if dof <= 0:
                continue
            gcv = n * rss / dof ** 2
            if best is None or gcv < best[0]:
                best = (gcv, w, np.sqrt(rss / dof))
        if best is None:
            raise InputError(f"{n} samples are too few for a Savitzky-Golay window")
        return best[1], float(best[2])

    def fit(self, t, q) -> SmoothFit:
        t, q = _clean(t, q)
        tu, qu, dt = _uniform(t, q)
        if self.window_s == "auto":
            w, sigma = self._gcv_window(qu, dt)
        else:
            w, sigma = self._window(dt, tu.size), float("nan")
        if w <= self.polyorder:
            raise InputError(f"{tu.size} samples are too few for a Savitzky-Golay window")
        g0, g1, g2 = (savgol(qu, w, self.polyorder, k, dt) for k in (0, 1, 2))
        r = q - np.interp(t, tu, g0)
        rms = float(np.sqrt(np.mean(r ** 2)))
        if not np.isfinite(sigma):
            h0 = float(savgol_kernel(w, self.polyorder)[w // 2])
            sigma = rms / np.sqrt(max(1.0 - h0, 1e-12))
        h1 = savgol_kernel(w, self.polyorder, 1, dt)
        h2 = savgol_kernel(w, self.polyorder, 2, dt)
        return SmoothFit("savgol", rms, float(np.max(np.abs(r))), int(t.size), float(t[0]),
                         float(t[-1]), None, float("nan"), rms, (tu, g0, g1, g2), window_s=w * dt,
                         bandwidth_hz=(self.polyorder + 1) / (3.2 * w - 4.6) / dt, sigma=sigma, qd_noise=float(sigma * np.linalg.norm(h1)),
                         qdd_noise=float(sigma * np.linalg.norm(h2)))


# ---------------------------------------------------------------------------------------------
# Fourier: harmonics and fundamental
# ---------------------------------------------------------------------------------------------
def _ordered_design_T(t, wf, n, extra=None):
    """The TRANSPOSED design ``[1, s1, c1, s2, c2, ...]`` (rows; a permutation of the columns
    of design_matrix) so that the first 2N+1 rows are the model with N harmonics, with
    ``extra`` appended as a last row. Built from the powers of ``exp(i wf t)`` (one complex
    exponential and N products over the samples instead of 2N sines and cosines; the same
    values to rounding). Transposed so that ``.T`` is the Fortran-ordered design LAPACK
    factorises in place."""
    t = np.asarray(t, float)
    wl = wf * np.arange(1, n + 1)
    e = np.exp(1j * wf * t)
    E = np.empty((n, t.size), complex)
    E[0] = e
    for k in range(1, n):  # loop over harmonics (a few dozen), vectorised over the samples
        np.multiply(E[k - 1], e, out=E[k])
    XT = np.empty((2 * n + 1 + (extra is not None), t.size))
    XT[0] = 1.0
    np.divide(E.imag, wl[:, None], out=XT[1:2 * n + 1:2])
    np.divide(E.real, -wl[:, None], out=XT[2:2 * n + 1:2])    # -(c / w) exactly
    if extra is not None:
        XT[-1] = extra
    return XT


def _rss_by_harmonics(t, q, wf, n_max):
    """RSS of the eq. 3-2 fit for N = 1..n_max harmonics.

    The span of ``[1, sin(l wf t), cos(l wf t)]`` (l = 1..n_max) does not depend on the
    columns' scale, so the unscaled columns are used: they are close to orthogonal over one or
    more periods, and their Gram matrix is well conditioned. Its entries follow from the sums
    ``S_k = sum_i exp(i k wf t_i)`` (k = 0..2 n_max) by the product-to-sum identities
    (``sin a sin b = (cos(a-b) - cos(a+b)) / 2`` and its two siblings), the right-hand side
    from ``sum_i q_i exp(i l wf t_i)``; one Cholesky factorisation ``G = L L^T`` and
    ``z = L^-1 X^T q`` give every nested fit at once (``RSS_N = q^T q - sum_{k <= 2N+1} z_k^2``,
    as the last column of R in a QR factorisation of ``[X, q]``). A Gram matrix that is not
    well conditioned (the Cholesky factor's diagonal spread over more than four decades,
    ``cond(G) > 1e8``, where the RSS would lose more than 1e-8 of ``q^T q``: a harmonic near the
    Nyquist rate) falls back to that QR factorisation (:func:`_rss_by_harmonics_qr`).
    """
    x = np.asarray(t, float) - t[0]
    q = np.asarray(q, float)
    q = q - q.mean()          # the constant is in the model: the same RSS, less cancellation
    m, p = x.size, 2 * n_max + 1
    if m <= p:
        return _rss_by_harmonics_qr(t, q, wf, n_max)
    e = np.exp(1j * wf * x)
    E = np.empty((2 * n_max, m), complex)
    E[0] = e
    for k in range(1, 2 * n_max):  # powers of e (a few dozen), vectorised over the samples
        np.multiply(E[k - 1], e, out=E[k])
    S = np.empty(2 * n_max + 1, complex)
    S[0] = m
    E.sum(axis=1, out=S[1:])
    bq = E[:n_max] @ q
    a, b = _gram_index(n_max)
    d, s = np.abs(a - b), a + b
    re_d, re_s = S.real[d], S.real[s]
    sc = 0.5 * (S.imag[s] + np.sign(a - b) * S.imag[d])      # sum sin(a x) cos(b x)
    G = np.empty((p, p))
    G[0, 0] = m
    G[0, 1::2] = G[1::2, 0] = S.imag[1:n_max + 1]
    G[0, 2::2] = G[2::2, 0] = S.real[1:n_max + 1]
    G[1::2, 1::2] = 0.5 * (re_d - re_s)
    G[2::2, 2::2] = 0.5 * (re_d + re_s)
    G[1::2, 2::2] = sc
    G[2::2, 1::2] = sc.T
    rhs = np.empty(p)
    rhs[0] = q.sum()
    rhs[1::2] = bq.imag
    rhs[2::2] = bq.real
    L, info = lapack.dpotrf(G, lower=1, clean=0)
    diag = np.diag(L) if info == 0 else None
    if diag is None or not np.all(diag > 1e-4 * diag.max()):
        return _rss_by_harmonics_qr(t, q, wf, n_max)
    z, info = lapack.dtrtrs(L, rhs, lower=1)
    if info != 0:
        return _rss_by_harmonics_qr(t, q, wf, n_max)
    cums = np.cumsum(z ** 2)
    return np.maximum(float(q @ q) - cums[2 * np.arange(1, n_max + 1)], 1e-300)


@functools.lru_cache(maxsize=64)
def _gram_index(n):
    """Harmonic numbers ``(a, b)`` of the sine/cosine blocks of the Gram matrix (n x n each)."""
    a = np.arange(1, n + 1)
    return np.meshgrid(a, a, indexing="ij")


def _rss_by_harmonics_qr(t, q, wf, n_max):
    """RSS of the eq. 3-2 fit for N = 1..n_max harmonics, from one QR factorisation of the
    design with ``q`` appended (its last column of R is ``Q^T q``: Q is never formed; LAPACK
    factorises the freshly built array in place)."""
    p = 2 * n_max + 1
    A = _ordered_design_T(t - t[0], wf, n_max, q).T
    if A.shape[0] <= p:
        R = np.linalg.qr(A, mode="r")
    else:
        qr, _, _, info = lapack.dgeqrf(A, overwrite_a=1)
        if info != 0:
            raise np.linalg.LinAlgError(f"QR failed (LAPACK info {info})")
        R = qr[:p + 1]
    d = np.abs(np.diag(R)[:p])
    proj = R[:p, p] ** 2
    # guard against rank loss (a harmonic above Nyquist): drop tiny diagonal entries
    ok = d > 1e-10 * d[0]
    proj = np.where(ok, proj, 0.0)
    total = float(q @ q)
    cums = np.cumsum(proj)
    return np.maximum(total - cums[2 * np.arange(1, n_max + 1)], 1e-300)


def _bic(rss, n, k):
    return n * np.log(rss / n) + k * np.log(n)


def _max_harmonics(t, wf, cap, dt=None):
    dt = float(np.median(np.diff(t))) if dt is None else dt
    nyq = np.pi / dt
    n_samples_cap = (t.size - 2) // 4
    return int(max(1, min(cap, np.floor(0.8 * nyq / wf), n_samples_cap)))


def select_harmonics(t, q, wf: float, max_harmonics: int = 20) -> tuple[int, float]:
    """Number of harmonics of eq. 3-2 by BIC; returns ``(N, rss)``."""
    t, q = _clean(t, q)
    nmax = _max_harmonics(t, wf, max_harmonics)
    rss = _rss_by_harmonics(t, q, wf, nmax)
    n = np.arange(1, nmax + 1)
    k = int(np.argmin(_bic(rss, t.size, 2 * n + 1)))
    return int(n[k]), float(rss[k])


def _best_bic(t, q, wf, max_harmonics, dt=None):
    nmax = _max_harmonics(t, wf, max_harmonics, dt)
    rss = _rss_by_harmonics(t, q, wf, nmax)
    b = _bic(rss, t.size, 2 * np.arange(1, nmax + 1) + 1)
    k = int(np.argmin(b))
    return float(b[k]), k + 1


def estimate_fundamental(t, q, max_harmonics: int = 20, max_periods: int = 8,
                         max_samples: int = 1500, n_refine: int = 3) -> float:
    """Fundamental ``wf`` (rad/s) of a signal made of one or more periods of eq. 3-2.

    Candidates ``2 pi k / D`` (k = 1..max_periods, ``D`` = duration plus one sample) and
    ``w_peak / h`` (h = 1..6, ``w_peak`` the periodogram's highest peak) are scored by BIC
    (each with its best N); the ``n_refine`` best are refined by a 9-point grid over
    +-``pi / D`` and a bounded 1-D search of the BIC, and the best refined one is returned.
    At most ``max_samples`` evenly strided samples are used for the search.
    """
    with one_blas_thread():
        return _estimate_fundamental(t, q, max_harmonics, max_periods, max_samples, n_refine)


def _estimate_fundamental(t, q, max_harmonics, max_periods, max_samples, n_refine):
    t, q = _clean(t, q)
    dt_med = float(np.median(np.diff(t)))
    D = float(t[-1] - t[0]) + dt_med
    if t[-1] <= t[0]:
        raise InputError("a signal with zero duration has no fundamental")
    tu, qu, dt = _uniform(t, q)
    x = qu - qu.mean()
    nfft = 8 * int(2 ** np.ceil(np.log2(x.size)))
    spec = np.abs(np.fft.rfft(x * np.hanning(x.size), nfft)) ** 2
    freqs = 2 * np.pi * np.fft.rfftfreq(nfft, dt)
    spec[freqs < np.pi / D] = 0.0
    w_peak = float(freqs[int(np.argmax(spec))])
    stride = max(1, t.size // max_samples)
    ts, qs = t[::stride], q[::stride]
    cands = {2 * np.pi * k / D for k in range(1, max_periods + 1)}
    cands |= {w_peak / h for h in range(1, 7) if w_peak / h >= 2 * np.pi / D}
    dt_s = float(np.median(np.diff(ts)))
    memo: dict = {}

    def bic(w):
        """The best BIC at ``w`` (remembered: a refinement grid holds its own centre)."""
        w = float(w)
        if w not in memo:
            memo[w] = _best_bic(ts, qs, w, max_harmonics, dt_s)[0]
        return memo[w]

    scored = sorted((bic(w), w) for w in cands)
    half_bin = np.pi / D
    best = None
    for _, w0 in scored[:n_refine]:
        grid = np.linspace(max(w0 - half_bin, 0.95 * 2 * np.pi / D), w0 + half_bin, 9)
        vals = np.array([bic(w) for w in grid])
        k = int(np.argmin(vals))
        lo, hi = grid[max(k - 1, 0)], grid[min(k + 1, grid.size - 1)]
        res = minimize_scalar(bic, bounds=(lo, hi), method="bounded", options={"xatol": 1e-6 * w0})
        cand = (float(res.fun), float(res.x)) if res.fun <= vals[k] else (float(vals[k]), float(grid[k]))
        if best is None or cand[0] < best[0]:
            best = cand
    return best[1]


class FourierSmoother:
    r"""Smoother that fits the finite Fourier series of thesis eq. 3-2 to a signal.

    .. math::

        q(t) = \sum_{l=1}^N \frac{a_l}{w_f l} \sin(w_f l t)
        - \frac{b_l}{w_f l} \cos(w_f l t) + q_0

    differentiated analytically [1]_, with the fundamental and harmonics estimated when not
    given (see the module docstring), falling back to ``fallback`` when the signal is not
    periodic. The Fourier series is fitted from the first to the last sample moving faster
    than ``rest_frac`` of the peak speed when ``trim_rest`` (a trial holds still before and
    after its periods; a rest is not part of eq. 3-2); the fit's ``t_start``/``t_end`` say
    which span it covers.

    Parameters
    ----------
    wf : float, optional
        Fundamental (rad/s); None: estimated (:func:`estimate_fundamental`).
    n_harmonics : int, optional
        Harmonics ``N``; None: chosen by BIC up to ``max_harmonics``.
    max_harmonics : int, optional
        Most harmonics tried (default 20).
    periodic : bool or None, optional
        None (default) decides from the residual; True always uses Fourier; False always
        uses the fallback.
    periodic_ratio, periodic_atol : float, optional
        The signal is periodic when the Fourier residual RMS is at most ``periodic_ratio``
        times the fallback's noise level plus ``periodic_atol`` (rad).
    fallback : object, optional
        Smoother with a ``fit(t, q)`` method; default :class:`SavGolSmoother`.
    trim_rest : bool, optional
        Leave the rests before and after the motion out of the Fourier fit (default True).
    rest_frac : float, optional
        Speed fraction of the peak below which a sample rests.

    References
    ----------
    .. [1] PA10 thesis (seeds 002), eq. 3-2 and ch. 4.
    """

    def __init__(self, wf: float | None = None, n_harmonics: int | None = None,
                 max_harmonics: int = 20, periodic: bool | None = None,
                 periodic_ratio: float = 2.0, periodic_atol: float = 2e-5, fallback=None,
                 trim_rest: bool = True, rest_frac: float = REST_FRAC):
        self.wf = wf
        self.n_harmonics = n_harmonics
        self.max_harmonics = int(max_harmonics)
        self.periodic = periodic
        self.periodic_ratio = float(periodic_ratio)
        self.periodic_atol = float(periodic_atol)
        self.fallback = fallback if fallback is not None else SavGolSmoother()
        self.trim_rest = bool(trim_rest)
        self.rest_frac = float(rest_frac)

    def fit_fourier(self, t, q) -> SmoothFit:
        t, q = _clean(t, q)
        wf = float(self.wf) if self.wf else estimate_fundamental(t, q, self.max_harmonics)
        n = int(self.n_harmonics) if self.n_harmonics else select_harmonics(t, q, wf, self.max_harmonics)[0]
        X, D1, D2 = design_matrices(t, wf, n)
        coef, _, _, sv = np.linalg.lstsq(X, q, rcond=None)
        r = q - X @ coef
        series = FourierSeries(coef[1:1 + n], coef[1 + n:], wf, float(coef[0]))
        sigma = float(np.sqrt(r @ r / max(t.size - X.shape[1], 1)))
        C = np.linalg.pinv(X.T @ X)
        sd = [sigma * np.sqrt(np.mean(np.sum((D @ C) * D, axis=1))) for D in (D1, D2)]
        # condition number: the singular values the least-squares solve computed
        cond = float(sv[0] / sv[-1]) if sv[-1] > 0 else float("inf")
        return SmoothFit("fourier", float(np.sqrt(np.mean(r ** 2))), float(np.max(np.abs(r))),
                         int(t.size), float(t[0]), float(t[-1]), series, cond,
                         sigma=sigma, qd_noise=float(sd[0]), qdd_noise=float(sd[1]),
                         bandwidth_hz=float(wf * n / (2 * np.pi)))

    def fit(self, t, q) -> SmoothFit:
        """Fit the signal ``q(t)``: eq. 3-2 [1]_, or the fallback when it is not periodic.

        Parameters
        ----------
        t : array_like
            (T,) sample times (s).
        q : array_like
            (T,) the signal (rad).

        Returns
        -------
        SmoothFit
            The smooth model (evaluate it and its derivatives at any time) and its residuals.

        References
        ----------
        .. [1] PA10 thesis (seeds 002), eq. 3-2.
        """
        with one_blas_thread():
            return self._fit(t, q)

    def _moving_span(self, t, smooth):
        """Indices [i0, i1] from the first to the last sample whose smoothed speed exceeds
        ``rest_frac`` of the peak speed (the rests before and after the excitation)."""
        qd = smooth.evaluate(t, order=1)[1]
        peak = float(np.max(np.abs(qd)))
        moving = np.flatnonzero(np.abs(qd) > self.rest_frac * peak) if peak > 0 else np.array([], int)
        if moving.size < 8:
            return 0, t.size - 1
        return int(moving[0]), int(moving[-1])

    def _fit(self, t, q) -> SmoothFit:
        t, q = _clean(t, q)
        if self.periodic is False:
            return self.fallback.fit(t, q)
        smooth = None
        if self.trim_rest or self.periodic is None:
            smooth = self.fallback.fit(t, q)
        if self.trim_rest:
            i0, i1 = self._moving_span(t, smooth)
            if i1 - i0 + 1 < t.size:
                t, q = t[i0:i1 + 1], q[i0:i1 + 1]
        four = self.fit_fourier(t, q)
        if self.periodic is True:
            return four
        noise = smooth.rms
        if four.rms <= self.periodic_ratio * noise + self.periodic_atol:
            return dataclasses.replace(four, noise_rms=noise)
        return smooth


# ---------------------------------------------------------------------------------------------
# synchronisation
# ---------------------------------------------------------------------------------------------
def estimate_time_offset(t_link, q_link, motor_fit: SmoothFit, max_shift: float = 0.5) -> float:
    """Offset ``d`` (s) with ``t_robot = t_marker + d`` that best aligns the link angle with the
    smooth motor angle (least squares over a grid at 1/4 sample, then bounded refinement;
    the constant deflection is removed)."""
    t, q = _clean(t_link, q_link)
    dt = float(np.median(np.diff(t)))

    def cost(d):
        qm = motor_fit.evaluate(t + d, order=0)[0]
        inside = (t + d >= motor_fit.t_start) & (t + d <= motor_fit.t_end)
        if inside.sum() < 8:
            return np.inf
        r = q[inside] - qm[inside]
        return float(np.mean((r - r.mean()) ** 2))

    grid = np.arange(-max_shift, max_shift + dt / 8, dt / 4)
    costs = np.array([cost(d) for d in grid])
    k = int(np.argmin(costs))
    res = minimize_scalar(cost, bounds=(grid[max(k - 1, 0)], grid[min(k + 1, grid.size - 1)]),
                          method="bounded", options={"xatol": dt * 1e-4})
    return float(res.x) if res.fun <= costs[k] else float(grid[k])


@dataclass(frozen=True, eq=False)
class JointSignals:
    """All signals of one joint of one trial on the robot log's samples (link side, SI).

    The link angle ``q`` and motor angle ``q_m`` of thesis eq. 2-2 to 2-4 [1]_ with their
    derivatives from eq. 3-2 fits, and the torque ``u``, on one time base (the robot clock;
    ``t_robot = t_marker + time_offset`` [2]_).

    Attributes
    ----------
    joint : int
        The joint, 1-based.
    time : numpy.ndarray
        (T,) the robot log's sample times (s).
    q, qd, qdd : numpy.ndarray
        (T,) link angle (rad), velocity (rad/s), acceleration (rad/s^2).
    qm, qmd, qmdd : numpy.ndarray
        (T,) motor angle on the link side and its derivatives.
    tau : numpy.ndarray
        (T,) joint torque (N m).
    link_fit, motor_fit : SmoothFit
        The smooth models of the link and motor angles.
    link_source : str
        ``"mocap"`` or ``"motor"`` (motor angle used as the link angle).
    time_offset : float
        Marker clock to robot clock (s).
    link_state : dict or None
        ``LinkState.to_dict()`` where the link angle came from the encoder plus a
        marker-estimated deflection.

    References
    ----------
    .. [1] PA10 thesis (seeds 002), eq. 2-2 to 2-4, 3-2.
    .. [2] jointlab data format (docs/format.md), sec. campaign.toml.
    """

    joint: int
    time: np.ndarray
    q: np.ndarray
    qd: np.ndarray
    qdd: np.ndarray
    qm: np.ndarray
    qmd: np.ndarray
    qmdd: np.ndarray
    tau: np.ndarray
    link_fit: SmoothFit
    motor_fit: SmoothFit
    link_source: str = "mocap"
    time_offset: float = 0.0
    link_state: dict | None = None      # LinkState.to_dict() of the encoder+deflection method

    @property
    def errors(self) -> dict:
        """Standard deviations the smoothing implies for the link q, qd, qdd (rad, /s, /s^2)."""
        f = self.link_fit
        return {"q": f.sigma, "qd": f.qd_noise, "qdd": f.qdd_noise}

    def to_dict(self) -> dict:
        return {"joint": self.joint, "n_samples": int(self.time.size), "link_source": self.link_source,
                "time_offset": self.time_offset, "link_state": self.link_state, "errors": self.errors, "link_fit": self.link_fit.to_dict(),
                "motor_fit": self.motor_fit.to_dict(),
                "link_fit_rms_deg": float(np.degrees(self.link_fit.rms)),
                "motor_fit_rms_deg": float(np.degrees(self.motor_fit.rms)),
                "peak_speed": float(np.max(np.abs(self.qd))) if self.qd.size else float("nan"),
                "max_abs_tau": float(np.max(np.abs(self.tau))) if self.tau.size else float("nan")}
