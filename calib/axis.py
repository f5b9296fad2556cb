"""Rotation-axis estimation from a single-joint sweep (thesis section 3.2, after Halvorsen 2003).

A joint is rotated alone while markers glued to the links it carries are recorded. Every
marker then moves on a circle about the joint axis. Two estimators are offered, both
returning an :class:`AxisFit` in the camera frame:

* :class:`CircleAxisEstimator` fits each marker's circle on its own (plane + the
  bias-compensated least-squares centre of Halvorsen et al. 2003,
  ``c = 1/2 (C - sigma^2 I)^-1 (s - 2 sigma^2 pbar)``), combines the markers with weights
  from radius, arc and noise, then refines one common axis by orthogonal-distance least
  squares (robust IRLS).
* :class:`ClusterAxisEstimator` fits per-frame rigid transforms of the marker cluster
  (Kabsch), takes their common screw axis, then refines by maximum likelihood of the rigid
  sweep model ``p_tk = a + R(n, theta_t) (s_k - a)`` (bundle adjustment with a Schur
  complement over the per-frame angles, robust IRLS, per-marker noise weights).

:func:`sweep_crb` evaluates the Cramer-Rao bound of the axis for the sweep geometry
(the Fisher information of the same rigid model with the per-frame angles and marker
positions as nuisance parameters, marginalised by the Schur complement).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from mocap.io.errors import InputError
from mocap.kinematics import angle_about, kabsch_batch, perp_basis, rotation_about_axis, unit
from mocap.numerics import rodrigues_axis_derivative

from calib.geometry import chart_coords, chart_line

#: the thesis's 3-D residual of the motion-capture system, 0.845 mm RMS (section 4.1)
DEFAULT_NOISE_MM = 0.85
#: fewest frames (stop-and-go poses) a marker must be seen in
MIN_POSES = 3
#: iteration cap of the refinements (a tracker's few poses can need ~60 Gauss-Newton steps)
MAX_ITER = 500
#: fewest frames per marker for data-driven weights (Huber IRLS, per-marker noise weights): with
#: fewer (stop-and-go poses) a residual scale or a marker's own variance rests on a handful of
#: residuals, and weights built from it make the covariance overconfident; plain least squares then
WEIGHTS_MIN_FRAMES = 20


@dataclass(frozen=True, eq=False)
class AxisFit:
    """A fitted joint axis in the camera frame.

    What :class:`ClusterAxisEstimator` and :class:`CircleAxisEstimator` return: the axis line
    ``(point, direction)`` of one single-joint sweep [1]_ [2]_ with its uncertainty. ``point``
    is the point of the axis nearest to the centroid of the moving markers; ``cov`` and ``crb``
    are 4x4 covariances of the chart coordinates (``alpha, beta`` direction tilts in rad along
    ``basis[0], basis[1]``; ``gamma, delta`` point shifts in metres), see :mod:`calib.geometry`
    and [3]_.

    Attributes
    ----------
    point : numpy.ndarray
        (3,) point of the axis nearest to the moving markers' centroid (m, camera frame).
    direction : numpy.ndarray
        (3,) unit direction; after :meth:`with_joint` its sign follows the joint's positive
        rotation.
    basis : tuple of numpy.ndarray
        ``(u, v)``, two unit vectors across the axis with ``u x v = direction``: the chart.
    cov : numpy.ndarray
        (4, 4) covariance of the chart coordinates ``(alpha, beta, gamma, delta)`` (rad, rad,
        m, m), the residual variance times the inverse normal matrix.
    crb : numpy.ndarray
        (4, 4) Cramer-Rao bound of the same coordinates for the sweep geometry at the noise
        given to the estimator (:func:`sweep_crb`).
    rms_mm : float
        RMS 3-D residual of the observations (mm).
    sigma_mm : float
        Estimated 3-D RMS marker noise (mm), from the weighted residuals (the given
        ``noise_mm`` where they leave no degree of freedom).
    marker_rms_mm : dict
        Marker label -> RMS residual (mm).
    marker_radius_m : dict
        Marker label -> radius of its circle about the axis (m).
    sweep_deg : float
        Angle swept by the markers about the axis (deg).
    n_frames : int
        Frames (or poses) used.
    n_observations : int
        Marker observations used (frame, marker pairs).
    n_outliers : int
        Observations whose residual exceeds 4 robust standard deviations.
    iterations : int
        Iterations of the refinement.
    converged : bool
        Whether the refinement met its step tolerance before the iteration cap.
    cond : float
        Condition number of the axis part of the normal matrix (cluster: its Schur complement
        onto the 4 chart coordinates).
    method : str
        ``"cluster"`` or ``"circle"``.
    joint : int or None, optional
        The joint, 1-based, once labelled (:meth:`with_joint`).
    extra : dict, optional
        Estimator-specific diagnostics (per-marker weights, BCLS radii).
    dof : float, optional
        Degrees of freedom of the noise estimate behind ``cov`` (inf: noise given).

    References
    ----------
    .. [1] PA10 thesis (seeds 002), sec. 3.2 (Estimation of Link Position), the axis of
       rotation of a single-joint sweep (after Halvorsen 2003).
    .. [2] Halvorsen 2003, bias compensated least squares estimate of the center of rotation,
       J. Biomech. 36, 999-1008.
    .. [3] jointlab calibration (docs/calibration.md).
    """

    point: np.ndarray
    direction: np.ndarray
    basis: tuple
    cov: np.ndarray
    crb: np.ndarray
    rms_mm: float
    sigma_mm: float
    marker_rms_mm: dict
    marker_radius_m: dict
    sweep_deg: float
    n_frames: int
    n_observations: int
    n_outliers: int
    iterations: int
    converged: bool
    cond: float
    method: str
    joint: int | None = None
    extra: dict = field(default_factory=dict)
    dof: float = float("inf")    # degrees of freedom of the noise estimate behind ``cov`` (inf: noise given)

    def with_joint(self, joint: int, flip: bool = False) -> "AxisFit":
        """A copy labelled with its joint; ``flip`` reverses the direction (same line)."""
        d = -self.direction if flip else self.direction
        basis = (self.basis[1], self.basis[0]) if flip else self.basis  # keeps u x v = n
        cov = self.cov[np.ix_([1, 0, 3, 2], [1, 0, 3, 2])] if flip else self.cov
        crb = self.crb[np.ix_([1, 0, 3, 2], [1, 0, 3, 2])] if flip else self.crb
        return AxisFit(self.point, d, basis, cov, crb, self.rms_mm, self.sigma_mm,
                       self.marker_rms_mm, self.marker_radius_m, self.sweep_deg, self.n_frames,
                       self.n_observations, self.n_outliers, self.iterations, self.converged,
                       self.cond, self.method, joint, dict(self.extra), self.dof)

    @property
    def direction_std_deg(self) -> float:
        return float(np.degrees(np.sqrt(self.cov[0, 0] + self.cov[1, 1])))

    @property
    def point_std_mm(self) -> float:
        return float(1e3 * np.sqrt(self.cov[2, 2] + self.cov[3, 3]))

    def to_dict(self) -> dict:
        return {
            "joint": self.joint,
            "point_camera": [float(x) for x in self.point],
            "direction_camera": [float(x) for x in self.direction],
            "rms_mm": float(self.rms_mm),
            "method": self.method,
            "sigma_mm": float(self.sigma_mm),
            "sweep_deg": float(self.sweep_deg),
            "point_std_mm": self.point_std_mm,
            "direction_std_deg": self.direction_std_deg,
            "crb_point_std_mm": float(1e3 * np.sqrt(self.crb[2, 2] + self.crb[3, 3])),
            "crb_direction_std_deg": float(np.degrees(np.sqrt(self.crb[0, 0] + self.crb[1, 1]))),
            "chart_basis_camera": [[float(x) for x in b] for b in self.basis],
            "cov_chart": self.cov.tolist(),
            "crb_chart": self.crb.tolist(),
            "marker_rms_mm": {k: float(v) for k, v in self.marker_rms_mm.items()},
            "marker_radius_m": {k: float(v) for k, v in self.marker_radius_m.items()},
            "n_frames": self.n_frames,
            "n_observations": self.n_observations,
            "n_outliers": self.n_outliers,
            "iterations": self.iterations,
            "converged": self.converged,
            "cond": float(self.cond),
            "dof": float(self.dof) if np.isfinite(self.dof) else None,
            **self.extra,
        }


# ---------------------------------------------------------------------------------------
# input checks
# ---------------------------------------------------------------------------------------
def _prepare(positions, labels, min_frames: int, min_markers: int):
    P = np.asarray(positions, float)
    if P.ndim != 3 or P.shape[2] != 3:
        raise InputError(f"marker positions must have shape (T, M, 3), got {P.shape}")
    labels = tuple(labels) if labels is not None else tuple(f"m{k}" for k in range(P.shape[1]))
    if len(labels) != P.shape[1]:
        raise InputError(f"{len(labels)} labels for {P.shape[1]} markers")
    vis = np.all(np.isfinite(P), axis=2)
    keep = vis.sum(axis=0) >= min_frames
    if keep.sum() < min_markers:
        seen = ", ".join(f"{lb} ({int(c)} frames)" for lb, c in zip(labels, vis.sum(axis=0)))
        raise InputError(f"only {int(keep.sum())} markers are visible in at least {min_frames} frames "
                         f"(need {min_markers}): {seen or 'none'}")
    return P[:, keep], tuple(lb for lb, k in zip(labels, keep) if k), vis[:, keep]


def _huber_weights(r_norm: np.ndarray, scale: float, k: float) -> np.ndarray:
    c = k * scale
    w = np.ones_like(r_norm)
    big = r_norm > c
    w[big] = c / r_norm[big]
    return w


def _robust_scale(r_norm: np.ndarray, dof: int = 3) -> float:
    """Per-axis sigma from the median 3-D residual norm (chi distribution median, dof 3 or 2)."""
    med = {3: 1.5382, 2: 1.1774, 1: 0.6745}[dof]
    return float(np.median(r_norm) / med) if r_norm.size else float("nan")


# ---------------------------------------------------------------------------------------
# the rigid sweep model: p_tk = a + R(n, theta_t) (s_k - a)
# ---------------------------------------------------------------------------------------
class _RigidSweep:
    """Bundle adjustment of the rigid sweep model with the per-frame angles eliminated by a
    Schur complement (their block of the normal matrix is diagonal)."""

    def __init__(self, P, vis):
        self.P = P
        self.T, self.M = P.shape[:2]
        self.t_idx, self.k_idx = np.nonzero(vis)
        self.obs = P[self.t_idx, self.k_idx]
        self.G = 4 + 3 * self.M

    def jacobian(self, a, n, u, v, theta, s):
        """Model points and the Jacobians w.r.t. the global block (chart of the axis around
        ``(a, n)`` + marker positions) and the per-frame angles."""
        ti, ki = self.t_idx, self.k_idx
        R = rotation_about_axis(n, theta)[ti]                       # (K, 3, 3)
        d = s[ki] - a                                          # (K, 3)
        Rd = np.einsum("kij,kj->ki", R, d)
        model = a + Rd
        K = len(ti)
        Jg = np.zeros((K, 3, self.G))
        st = np.sin(theta[ti])[:, None]
        ct = np.cos(theta[ti])[:, None]
        for col, e in ((0, u), (1, v)):
            Jg[:, :, col] = rodrigues_axis_derivative(e, d, n, st, ct)
        IR = np.eye(3) - R
        Jg[:, :, 2] = IR @ u
        Jg[:, :, 3] = IR @ v
        cols = 4 + 3 * ki[:, None] + np.arange(3)[None]        # (K, 3)
        Jg[np.arange(K)[:, None, None], np.arange(3)[None, :, None], cols[:, None, :]] = R
        Jt = np.cross(n[None], Rd)                             # (K, 3)
        return model, Jg, Jt

    def normal_equations(self, Jg, Jt, r, w, ref):
        ti = self.t_idx
        K = len(ti)
        J2 = Jg.reshape(3 * K, self.G)
        Jw = J2 * np.repeat(w, 3)[:, None]
        Hgg = Jw.T @ J2
        bg = Jw.T @ r.reshape(-1)
        per = np.einsum("kig,ki->kg", Jw.reshape(K, 3, self.G), Jt)
        Hgt = np.zeros((self.T, self.G))
        starts = np.flatnonzero(np.r_[True, np.diff(ti) != 0])   # t_idx is sorted (np.nonzero)
        Hgt[ti[starts]] = np.add.reduceat(per, starts, axis=0)
        htt = np.bincount(ti, weights=w * np.einsum("ki,ki->k", Jt, Jt), minlength=self.T)
        btt = np.bincount(ti, weights=w * np.einsum("ki,ki->k", Jt, r), minlength=self.T)
        free = htt > 1e-12 * max(htt.max(), 1e-300)
        free[ref] = False
        hinv = np.where(free, 1.0 / np.where(free, htt, 1.0), 0.0)
        S = Hgg - (Hgt * hinv[:, None]).T @ Hgt
        rhs = bg - Hgt.T @ (btt * hinv)
        return S, rhs, Hgt, btt, hinv

    def init(self, P, vis):
        """Kabsch per frame against the most complete frame, then the common screw axis."""
        ref = int(np.argmax(vis.sum(axis=1) + 1e-6 * np.arange(self.T)[::-1]))
        S0 = P[ref]
        w = (vis & vis[ref][None]).astype(float)
        R, t = kabsch_batch(np.where(vis[ref][:, None], S0, 0.0), P, w)
        ok = np.all(np.isfinite(R), axis=(1, 2))
        if ok.sum() < 3:
            raise InputError("fewer than 3 frames see 3 markers of the reference frame; "
                             "cannot form the rigid cluster")
        # reference positions of markers hidden in the reference frame: average back-mapped
        if not vis[ref].all():
            Rt = np.swapaxes(R[ok], 1, 2)
            back = np.einsum("tij,tmj->tmi", Rt, P[ok] - t[ok][:, None])
            vv = vis[ok]
            cnt = vv.sum(axis=0)
            mean = np.nansum(np.where(vv[..., None], back, 0.0), axis=0) / np.maximum(cnt, 1)[:, None]
            S0 = np.where(vis[ref][:, None], S0, mean)
        A = R[ok] - np.eye(3)
        H = np.einsum("tji,tjk->ik", A, A)
        evals, evecs = np.linalg.eigh(H)
        n = evecs[:, 0]
        c = S0.mean(axis=0)
        IR = -A
        Hx = np.einsum("tji,tjk->ik", IR, IR) + np.outer(n, n) * max(evals[-1], 1e-9)
        bx = np.einsum("tji,tj->i", IR, t[ok]) + n * (n @ c) * max(evals[-1], 1e-9)
        a = np.linalg.solve(Hx, bx)
        theta = np.zeros(self.T)
        theta[ok] = angle_about(R[ok], n)
        # frames without a Kabsch pose: angle from the nearest good frame
        if not ok.all():
            idx = np.flatnonzero(ok)
            theta = np.interp(np.arange(self.T), idx, theta[ok])
        theta = np.unwrap(theta)             # sweeps past +-180 deg from the reference frame
        theta -= theta[ref]
        return a, n, theta, S0, ref

    def solve(self, a, n, theta, s, ref, robust=True, huber_k=2.5, marker_weights=True,
              max_iter=50, tol=1e-10):
        K = len(self.t_idx)
        w_rob = np.ones(K)
        w_mk = np.ones(self.M)
        it = 0
        converged = False
        c = s.mean(axis=0)
        for it in range(1, max_iter + 1):
            a = a + ((c - a) @ n) * n
            u, v = perp_basis(n)
            model, Jg, Jt = self.jacobian(a, n, u, v, theta, s)
            r = self.obs - model
            rn = np.linalg.norm(r, axis=1)
            if robust and it > 1:
                scale = _robust_scale(rn)
                w_rob = _huber_weights(rn, scale, huber_k)
            if marker_weights and it > 2:
                ss = np.bincount(self.k_idx, weights=w_rob * rn ** 2, minlength=self.M)
                cnt = np.bincount(self.k_idx, weights=w_rob, minlength=self.M)
                var = ss / np.maximum(3 * cnt, 1e-12)
                w_mk = np.median(var) / np.maximum(var, 1e-3 * np.median(var))
            w = w_rob * w_mk[self.k_idx]
            S, rhs, Hgt, btt, hinv = self.normal_equations(Jg, Jt, r, w, ref)
            dg = np.linalg.lstsq(S, rhs, rcond=None)[0]
            dth = (btt - Hgt @ dg) * hinv
            n_new = unit(n + dg[0] * u + dg[1] * v)
            a = a + dg[2] * u + dg[3] * v
            n = n_new
            s = s + dg[4:].reshape(self.M, 3)
            theta = theta + dth
            step = np.abs(dg[:4]).max() + np.abs(dg[4:]).max(initial=0) + np.abs(dth).max()
            if step < tol and it > 3:
                converged = True
                break
        a = a + ((c - a) @ n) * n
        u, v = perp_basis(n)
        model, Jg, Jt = self.jacobian(a, n, u, v, theta, s)
        r = self.obs - model
        return a, n, theta, s, r, w_rob, w_mk, it, converged, (Jg, Jt, u, v)

    def axis_information(self, Jg, Jt, w, ref):
        """Schur complement of the normal matrix onto the 4 axis chart coordinates."""
        S, *_ = self.normal_equations(Jg, Jt, np.zeros((len(self.t_idx), 3)), w, ref)
        Saa, Sas, Sss = S[:4, :4], S[:4, 4:], S[4:, 4:]
        info = Saa - Sas @ np.linalg.solve(Sss, Sas.T)
        return info


def marker_angles(positions: np.ndarray, point: np.ndarray, direction: np.ndarray) -> np.ndarray:
    """Angle (T, M) of each marker about the axis ``(point, unit direction)`` (right-hand rule),
    unwrapped along the frames (consecutive frames or poses less than 180 deg apart); NaN where
    a marker is not seen."""
    u, v = perp_basis(direction)
    d = np.asarray(positions, float) - point
    th = np.arctan2(d @ v, d @ u)
    out = np.full(th.shape, np.nan)
    for k in range(th.shape[1]):  # loop over markers (few)
        ok = np.isfinite(th[:, k])
        out[ok, k] = np.unwrap(th[ok, k])
    return out


def _marker_stats(r, k_idx, M, labels, a, n, s, w_rob):
    rms = np.sqrt(np.bincount(k_idx, weights=np.sum(r ** 2, axis=1), minlength=M)
                  / np.maximum(np.bincount(k_idx, minlength=M), 1))
    d = s - a
    rad = np.linalg.norm(d - np.outer(d @ n, n), axis=1)
    return ({lb: 1e3 * x for lb, x in zip(labels, rms)},
            {lb: float(x) for lb, x in zip(labels, rad)})


def sweep_crb(positions, labels=None, sigma_mm: float = DEFAULT_NOISE_MM, fit: "AxisFit" = None):
    r"""Cramer-Rao bound (4x4, chart coordinates of ``fit``'s axis) for a sweep's axis.

    The rigid sweep model

    .. math::

        p_{tk} = a + R(n, \theta_t)\,(s_k - a) + e_{tk}, \qquad
        e_{tk} \sim N(0, \tfrac{\sigma^2}{3} I_3)

    is linearised at its own estimate (:class:`ClusterAxisEstimator` without the robust
    weights); the per-frame angles ``theta_t`` and the marker positions ``s_k`` are nuisance
    parameters, marginalised by the Schur complement of the Fisher information [1]_:

    .. math::

        \mathrm{CRB} = \frac{\sigma^2}{3}\left(S_{aa} - S_{a\eta} S_{\eta\eta}^{-1}
        S_{\eta a}\right)^{-1}

    with ``S = J^T J`` split into the 4 chart coordinates ``a`` of the axis and the nuisance
    block ``eta``. ``sigma_mm`` is the 3-D RMS marker noise (per-axis sigma = sigma_mm /
    sqrt(3)); the base's bound that ``calib.json`` reports under ``crb`` is propagated from it [3]_.

    Parameters
    ----------
    positions : array_like
        (T, M, 3) marker positions (m, camera frame), NaN where occluded.
    labels : sequence of str, optional
        M marker labels; default ``m0, m1, ...``.
    sigma_mm : float, optional
        3-D RMS marker noise (mm); default :data:`DEFAULT_NOISE_MM`, the thesis's residual of
        the motion-capture system [2]_.
    fit : AxisFit, optional
        Express the bound in this fit's chart (first-order change of chart); None: the chart of
        the model's own estimate.

    Returns
    -------
    numpy.ndarray
        (4, 4) bound on the covariance of ``(alpha, beta, gamma, delta)`` (rad, rad, m, m).

    Raises
    ------
    mocap.io.errors.InputError
        If the positions are not (T, M, 3) or fewer than 3 markers are seen in
        :data:`MIN_POSES` frames.

    References
    ----------
    .. [1] Kay 1993, Fundamentals of Statistical Signal Processing: Estimation Theory, ch. 3
       (the Cramer-Rao bound with nuisance parameters).
    .. [2] PA10 thesis (seeds 002), ch. 4 (the 3-D residual of the motion-capture system).
    .. [3] jointlab calibration (docs/calibration.md), the reported Cramer-Rao bound.
    """
    est = ClusterAxisEstimator(robust=False, noise_mm=sigma_mm, marker_weights=False)
    f = est.fit(positions, labels)
    crb = f.crb
    if fit is not None:
        crb = _rebase_cov(crb, f, fit)
    return crb


def _rebase_cov(cov, src: AxisFit, dst: AxisFit) -> np.ndarray:
    """Express a chart covariance of ``src``'s axis in ``dst``'s chart (numerical Jacobian)."""

    u0, v0 = src.basis
    u1, v1 = dst.basis
    J = np.zeros((4, 4))
    h = 1e-7
    for i in range(4):
        e = np.zeros(4)
        e[i] = h
        q, m = chart_line(e, src.point, src.direction, u0, v0)
        qm, mm = chart_line(-e, src.point, src.direction, u0, v0)
        J[:, i] = (chart_coords(q, m, dst.point, dst.direction, u1, v1)
                   - chart_coords(qm, mm, dst.point, dst.direction, u1, v1)) / (2 * h)
    return J @ cov @ J.T


class ClusterAxisEstimator:
    r"""Rigid-cluster axis estimator (Kabsch per frame -> screw axis -> rigid-sweep ML).

    The camera-frame axis of a single-joint sweep [1]_: per-frame rigid transforms of the
    marker cluster against the most complete frame (Kabsch/Umeyama [2]_), their common screw
    axis as the start, then the maximum-likelihood fit of the rigid sweep model

    .. math::

        p_{tk} = a + R(n, \theta_t)\,(s_k - a)

    (axis point ``a``, unit direction ``n``, per-frame angles ``theta_t``, marker positions
    ``s_k``) by Gauss-Newton bundle adjustment [3]_ with the angles eliminated by a Schur
    complement, Huber IRLS [4]_ and per-marker noise weights. With fewer than
    :data:`WEIGHTS_MIN_FRAMES` frames per marker (stop-and-go poses) the data-driven weights
    are off and the fit is plain least squares: weights built from a handful of residuals make
    the covariance overconfident [5]_. Needs 3 markers seen in ``min_frames`` frames.

    Parameters
    ----------
    robust : bool, optional
        Huber IRLS on the per-observation 3-D residual (gross errors, swaps); default True.
    huber_k : float, optional
        Huber threshold in units of the robust per-axis sigma; default 2.5.
    marker_weights : bool, optional
        Weight markers by their own residual variance (noisy markers count less); default
        True.
    noise_mm : float or None, optional
        3-D RMS marker noise used for the Cramer-Rao bound (None: the noise estimated from the
        residuals); default :data:`DEFAULT_NOISE_MM`.
    min_frames : int, optional
        Frames (poses) a marker must be seen in to be used; default :data:`MIN_POSES`.
    max_iter : int, optional
        Iteration cap of the refinement; default :data:`MAX_ITER`.

    References
    ----------
    .. [1] PA10 thesis (seeds 002), sec. 3.2 (Estimation of Link Position): the axis of
       rotation from a single-joint sweep (after Halvorsen 2003).
    .. [2] Umeyama 1991, least-squares estimation of transformation parameters between two
       point patterns, IEEE TPAMI 13(4).
    .. [3] Triggs, McLauchlan, Hartley & Fitzgibbon 2000, bundle adjustment: a modern
       synthesis (Schur complement of the reduced camera system).
    .. [4] Huber 1981, Robust Statistics (the Huber loss by iteratively reweighted least
       squares).
    .. [5] jointlab calibration (docs/calibration.md), the reported uncertainty.

    Examples
    --------
    >>> rng = np.random.default_rng(0)
    >>> s = np.array([[0.3, 0.0, 0.1], [0.0, 0.25, 0.2], [-0.2, -0.1, 0.3]])
    >>> th = np.linspace(0.0, 1.5, 40)
    >>> R = rotation_about_axis(np.array([0.0, 0.0, 1.0]), th)
    >>> P = np.einsum("tij,kj->tki", R, s) + 1e-4 * rng.standard_normal((40, 3, 3))
    >>> fit = ClusterAxisEstimator().fit(P)
    >>> bool(abs(fit.direction[2]) > 0.9999), round(fit.sweep_deg)
    (True, 86)
    """

    method = "cluster"

    def __init__(self, robust: bool = True, huber_k: float = 2.5, marker_weights: bool = True,
                 noise_mm: float | None = DEFAULT_NOISE_MM, min_frames: int = MIN_POSES,
                 max_iter: int = MAX_ITER):
        self.robust = robust
        self.huber_k = huber_k
        self.marker_weights = marker_weights
        self.noise_mm = noise_mm
        self.min_frames = min_frames
        self.max_iter = max_iter

    def fit(self, positions, labels=None) -> AxisFit:
        """Fit the axis of a sweep.

        Parameters
        ----------
        positions : array_like
            (T, M, 3) marker positions (m, camera frame), NaN where occluded.
        labels : sequence of str, optional
            M marker labels; default ``m0, m1, ...``.

        Returns
        -------
        AxisFit
            The axis, its covariance (``dof`` residual degrees of freedom) and bound.

        Raises
        ------
        mocap.io.errors.InputError
            If the positions are not (T, M, 3), fewer than 3 markers are seen in
            ``min_frames`` frames, or fewer than 3 frames see 3 markers of the reference frame.

        References
        ----------
        .. [1] PA10 thesis (seeds 002), sec. 3.2 (Estimation of Link Position).
        """
        P, labels, vis = _prepare(positions, labels, self.min_frames, 3)
        model = _RigidSweep(P, vis)
        a, n, theta, s, ref = model.init(P, vis)
        many = int(vis.sum(axis=0).min()) >= WEIGHTS_MIN_FRAMES
        a, n, theta, s, r, w_rob, w_mk, it, conv, (Jg, Jt, u, v) = model.solve(
            a, n, theta, s, ref, robust=self.robust and many, huber_k=self.huber_k,
            marker_weights=self.marker_weights and many, max_iter=self.max_iter)
        w = w_rob * w_mk[model.k_idx]
        K = len(model.t_idx)
        dof = max(3 * K - (model.G + int(np.sum(np.bincount(model.t_idx, minlength=model.T) > 0)) - 1), 1)
        sig2 = float(np.sum(w * np.sum(r ** 2, axis=1)) / dof)
        info = model.axis_information(Jg, Jt, w, ref)
        cov = sig2 * np.linalg.inv(info)
        info1 = model.axis_information(Jg, Jt, np.ones(K), ref)
        noise_m = np.sqrt(3 * sig2) if self.noise_mm is None else self.noise_mm * 1e-3
        crb = noise_m ** 2 / 3.0 * np.linalg.inv(info1)
        rn = np.linalg.norm(r, axis=1)
        scale = _robust_scale(rn)
        outl = int(np.sum(rn > 4.0 * scale)) if np.isfinite(scale) else 0
        mrms, mrad = _marker_stats(r, model.k_idx, model.M, labels, a, n, s, w_rob)
        used = np.bincount(model.t_idx, minlength=model.T) > 0
        th = theta[used]
        return AxisFit(point=a, direction=n, basis=(u, v), cov=cov, crb=crb,
                       rms_mm=float(1e3 * np.sqrt(np.mean(np.sum(r ** 2, axis=1)))),
                       sigma_mm=float(1e3 * np.sqrt(3 * sig2)), marker_rms_mm=mrms,
                       marker_radius_m=mrad, sweep_deg=float(np.degrees(th.max() - th.min())),
                       n_frames=int(used.sum()), n_observations=K, n_outliers=outl,
                       iterations=it, converged=conv, cond=float(np.linalg.cond(info)),
                       method=self.method,
                       extra={"marker_weight": {lb: float(x) for lb, x in zip(labels, w_mk)}},
                       dof=float(dof))


# ---------------------------------------------------------------------------------------
# per-marker circles (Halvorsen bias-compensated least squares) + joint refinement
# ---------------------------------------------------------------------------------------
def fit_circle_bcls(points: np.ndarray, sigma2: float | None = None):
    r"""One marker's circle: plane by PCA, centre by bias-compensated least squares.

    Implements Halvorsen (2003) [1]_ in the plane of the arc (the thesis's axis of rotation
    from a single marker [2]_):

    .. math::

        c = \tfrac{1}{2}\,(C - \sigma^2 I)^{-1} s, \qquad
        r^2 = \overline{\lVert x - c \rVert^2} - 2\sigma^2

    with ``C`` the in-plane covariance and ``s = mean(|x|^2 (x - xbar))`` in centred
    coordinates (the ``2 sigma^2 xbar`` term of the general form vanishes there). Without the
    ``sigma^2`` terms this is the plain (Kasa) least-squares circle, whose centre and radius
    are biased on short arcs.

    Parameters
    ----------
    points : array_like
        (N, 3) positions of one marker (m); rows with NaN are dropped.
    sigma2 : float, optional
        Per-axis noise variance (m^2); default: the out-of-plane variance
        (smallest eigenvalue of the covariance, times ``N / (N - 3)``).

    Returns
    -------
    centre : numpy.ndarray
        (3,) circle centre, a point of the axis (m).
    normal : numpy.ndarray
        (3,) unit normal of the plane, the axis direction (sign arbitrary).
    radius : float
        Circle radius (m).
    sigma2 : float
        The per-axis noise variance used (m^2).
    lambda_min_in_plane : float
        Smaller in-plane eigenvalue of the covariance (m^2), the arc's spread.
    n_points : int
        Points used.

    Raises
    ------
    mocap.io.errors.InputError
        If fewer than 3 finite points remain.

    References
    ----------
    .. [1] Halvorsen 2003, bias compensated least squares estimate of the center of rotation,
       J. Biomech. 36, 999-1008.
    .. [2] PA10 thesis (seeds 002), sec. 3.2 (Estimation of Link Position).

    Examples
    --------
    >>> t = np.linspace(0.0, 2.0, 50)
    >>> pts = np.stack([0.1 + 0.2 * np.cos(t), 0.2 * np.sin(t), np.full_like(t, 0.3)], axis=1)
    >>> centre, normal, radius, *_ = fit_circle_bcls(pts, sigma2=0.0)
    >>> (np.round(centre, 6) + 0.0).tolist(), round(radius, 6)
    ([0.1, 0.0, 0.3], 0.2)
    """
    X = np.asarray(points, float)
    X = X[np.all(np.isfinite(X), axis=1)]
    N = X.shape[0]
    if N < 3:
        raise InputError(f"a circle needs at least 3 points, got {N}")
    mu = X.mean(axis=0)
    Y = X - mu
    C = Y.T @ Y / N
    evals, evecs = np.linalg.eigh(C)
    nrm = evecs[:, 0]
    B = evecs[:, 1:]                    # in-plane basis
    if sigma2 is None:
        sigma2 = float(evals[0] * N / max(N - 3, 1))
    x = Y @ B
    C2 = x.T @ x / N
    s2 = np.mean(np.sum(x ** 2, axis=1)[:, None] * x, axis=0)
    A = C2 - sigma2 * np.eye(2)
    c2 = 0.5 * np.linalg.solve(A, s2)
    r2 = np.mean(np.sum((x - c2) ** 2, axis=1)) - 2.0 * sigma2
    centre = mu + B @ c2
    return centre, nrm, float(np.sqrt(max(r2, 0.0))), float(sigma2), float(evals[1]), N


class CircleAxisEstimator:
    """Per-marker circle estimator (Halvorsen BCLS) with a common-axis refinement.

    The camera-frame axis of a single-joint sweep [1]_: each marker's circle by
    :func:`fit_circle_bcls` [2]_, the circles combined with weights from radius, arc and noise
    (normals by their information ``N lambda / sigma^2``, centres by ``N lambda / (sigma^2
    r^2)``), then one common axis refined by orthogonal distance (radial and axial residual to
    each marker's circle) with Huber IRLS [3]_ and per-marker noise weights (both off below
    :data:`WEIGHTS_MIN_FRAMES` frames per marker [4]_). The Cramer-Rao bound is the rigid sweep
    model's (:func:`sweep_crb`) where 3 markers allow it, else the circle model's own.

    With a single marker this is the classic circle-point method (one point's circle: plane,
    centre, radius), which needs at least 3 poses (4 for a residual, hence an uncertainty).

    Parameters
    ----------
    refine : bool, optional
        After combining the per-marker circles, fit one axis to all markers by orthogonal
        distance (radial and axial residual to each marker's circle), robust IRLS; default
        True.
    robust : bool, optional
        Huber IRLS in the refinement; default True.
    huber_k : float, optional
        Huber threshold in units of the robust per-axis sigma; default 2.5.
    sigma_mm : float or None, optional
        Known 3-D RMS noise for the bias compensation (default: estimated per marker from the
        out-of-plane scatter).
    noise_mm : float or None, optional
        3-D RMS noise used for the Cramer-Rao bound (rigid sweep model; None: the noise
        estimated from the residuals); also the noise of a fit that leaves no residual;
        default :data:`DEFAULT_NOISE_MM`.
    min_frames : int, optional
        Frames (poses) a marker must be seen in to be used; default :data:`MIN_POSES`.
    max_iter : int, optional
        Iteration cap of the refinement; default :data:`MAX_ITER`.

    References
    ----------
    .. [1] PA10 thesis (seeds 002), sec. 3.2 (Estimation of Link Position): the axis of
       rotation from a single-joint sweep (after Halvorsen 2003).
    .. [2] Halvorsen 2003, bias compensated least squares estimate of the center of rotation,
       J. Biomech. 36, 999-1008.
    .. [3] Huber 1981, Robust Statistics (the Huber loss by iteratively reweighted least
       squares).
    .. [4] jointlab calibration (docs/calibration.md), the reported uncertainty.
    """

    method = "circle"

    def __init__(self, refine: bool = True, robust: bool = True, huber_k: float = 2.5,
                 sigma_mm: float | None = None, noise_mm: float | None = DEFAULT_NOISE_MM,
                 min_frames: int = MIN_POSES, max_iter: int = MAX_ITER):
        self.refine = refine
        self.robust = robust
        self.huber_k = huber_k
        self.sigma_mm = sigma_mm
        self.noise_mm = noise_mm
        self.min_frames = min_frames
        self.max_iter = max_iter

    def combine(self, P, vis):
        """Weighted combination of the per-marker BCLS circles: direction and axis point."""
        sig2 = None if self.sigma_mm is None else (self.sigma_mm * 1e-3) ** 2 / 3.0
        circles = [fit_circle_bcls(P[vis[:, k], k], sig2) for k in range(P.shape[1])]
        cen = np.array([c[0] for c in circles])
        nrm = np.array([c[1] for c in circles])
        rad = np.array([c[2] for c in circles])
        s2 = np.maximum(np.array([c[3] for c in circles]), 1e-14)
        lam = np.array([c[4] for c in circles])
        N = np.array([c[5] for c in circles], float)
        w_dir = N * lam / s2                  # information on the plane normal
        Hn = np.einsum("k,ki,kj->ij", w_dir, nrm, nrm)
        n = np.linalg.eigh(Hn)[1][:, -1]
        w_c = N * lam / (s2 * np.maximum(rad, 1e-6) ** 2)   # centre precision ~ N lambda / (sigma^2 r^2)
        Pn = np.eye(3) - np.outer(n, n)
        a = (w_c @ (cen @ Pn)) / w_c.sum()
        return a, n, rad, circles

    def fit(self, positions, labels=None) -> AxisFit:
        """Fit the axis of a sweep.

        Parameters
        ----------
        positions : array_like
            (T, M, 3) marker positions (m, camera frame), NaN where occluded.
        labels : sequence of str, optional
            M marker labels; default ``m0, m1, ...``.

        Returns
        -------
        AxisFit
            The axis, its covariance (``dof`` residual degrees of freedom) and bound.

        Raises
        ------
        mocap.io.errors.InputError
            If the positions are not (T, M, 3), no marker is seen in ``min_frames`` frames, or
            the observations leave no residual and ``noise_mm`` is None.

        References
        ----------
        .. [1] Halvorsen 2003, bias compensated least squares estimate of the center of
           rotation, J. Biomech. 36, 999-1008.
        """
        P, labels, vis = _prepare(positions, labels, self.min_frames, 1)
        M = P.shape[1]
        a, n, rad, circles = self.combine(P, vis)
        t_idx, k_idx = np.nonzero(vis)
        X = P[t_idx, k_idx]
        c = X.mean(axis=0)
        hk = np.bincount(k_idx, weights=(X - c) @ n, minlength=M) / np.bincount(k_idx, minlength=M)
        many = int(vis.sum(axis=0).min()) >= WEIGHTS_MIN_FRAMES
        a, n, rad, hk, w_rob, w_mk, it, conv = self._refine_axis(X, k_idx, a, n, rad, hk, c, many)
        a = a + ((c - a) @ n) * n
        u, v = perp_basis(n)
        r, J = self._residual_jacobian(X, k_idx, a, n, u, v, rad, hk, M, c)
        w = w_rob * w_mk[k_idx]
        H = np.einsum("k,kig,kih->gh", w, J, J)
        sig2, nu = self._noise_variance(r, w, len(k_idx), M)
        cov = sig2 * np.linalg.pinv(H)[:4, :4]
        crb, sweep = self._bound(P, labels, a, n, (u, v), cov, J, sig2)
        # 3-D residual per observation: in-plane tangential component is not modelled
        rn = np.linalg.norm(r, axis=1)
        scale = _robust_scale(rn, 2)
        mrms = np.sqrt(np.bincount(k_idx, weights=rn ** 2, minlength=M) / np.bincount(k_idx, minlength=M))
        return AxisFit(point=a, direction=n, basis=(u, v), cov=cov, crb=crb,
                       rms_mm=float(1e3 * np.sqrt(np.mean(rn ** 2))),
                       sigma_mm=float(1e3 * np.sqrt(3 * sig2)),
                       marker_rms_mm={lb: 1e3 * float(x) for lb, x in zip(labels, mrms)},
                       marker_radius_m={lb: float(x) for lb, x in zip(labels, rad)},
                       sweep_deg=sweep, n_frames=int(np.any(vis, axis=1).sum()),
                       n_observations=len(k_idx), n_outliers=int(np.sum(rn > 4 * scale)),
                       iterations=it, converged=conv or not self.refine,
                       cond=float(np.linalg.cond(H[:4, :4])), method=self.method,
                       extra={"bcls_radius_m": {lb: c[2] for lb, c in zip(labels, circles)},
                              "marker_weight": {lb: float(x) for lb, x in zip(labels, w_mk)}},
                       dof=nu)

    def _refine_axis(self, X, k_idx, a, n, rad, hk, c, many):
        """The common-axis refinement: Gauss-Newton on the radial and axial residuals of the
        observations ``X`` (K, 3) (marker ``k_idx``) to their markers' circles, from the axis
        ``(a, n)``, radii ``rad`` and axial offsets ``hk`` (from the centroid ``c``), with Huber
        IRLS and per-marker noise weights where every marker has ``many`` frames (one
        evaluation without :attr:`refine`). Returns the axis, radii, offsets, the robust and
        marker weights, the iterations and whether it converged."""
        M = rad.shape[0]
        w_rob = np.ones(len(k_idx))
        w_mk = np.ones(M)
        it, conv = 0, False
        iters = self.max_iter if self.refine else 1
        for it in range(1, iters + 1):
            a = a + ((c - a) @ n) * n
            u, v = perp_basis(n)
            r, J = self._residual_jacobian(X, k_idx, a, n, u, v, rad, hk, M, c)
            if not self.refine:
                break
            rn = np.linalg.norm(r, axis=1)
            if self.robust and many and it > 1:
                w_rob = _huber_weights(rn, _robust_scale(rn, 2), self.huber_k)
            if many and it > 2:
                ss = np.bincount(k_idx, weights=w_rob * rn ** 2, minlength=M)
                cnt = np.bincount(k_idx, weights=w_rob, minlength=M)
                var = ss / np.maximum(2 * cnt, 1e-12)
                w_mk = np.median(var) / np.maximum(var, 1e-3 * np.median(var))
            w = w_rob * w_mk[k_idx]
            H = np.einsum("k,kig,kih->gh", w, J, J)
            b = np.einsum("k,kig,ki->g", w, J, r)
            dx = np.linalg.lstsq(H, b, rcond=None)[0]
            n = unit(n + dx[0] * u + dx[1] * v)
            a = a + dx[2] * u + dx[3] * v
            rad = rad + dx[4:4 + M]
            hk = hk + dx[4 + M:]
            if np.abs(dx).max() < 1e-11 and it > 3:
                conv = True
                break
        return a, n, rad, hk, w_rob, w_mk, it, conv

    def _noise_variance(self, r, w, K, M):
        """Per-axis noise variance and its degrees of freedom: from the weighted residuals ``r``
        (K, 2) of ``K`` observations of ``M`` markers (``2 K - 4 - 2 M`` degrees of freedom), or
        :attr:`noise_mm` (infinite degrees of freedom) when they leave no residual."""
        dof = 2 * K - (4 + 2 * M)
        if dof >= 1:
            return float(np.sum(w * np.sum(r ** 2, axis=1)) / dof), float(dof)
        if self.noise_mm is not None:
            return (self.noise_mm * 1e-3) ** 2 / 3.0, float("inf")
        raise InputError(f"{K} observations of {M} marker(s) leave no residual to estimate "
                         "the noise from: give the noise (--noise-mm) or add poses")

    def _bound(self, P, labels, a, n, basis, cov, J, sig2):
        """The Cramer-Rao bound (4, 4) of the axis ``(a, n)`` and the sweep (deg): the rigid
        sweep model's (:func:`sweep_crb` through :class:`ClusterAxisEstimator`) re-expressed in
        this fit's chart, or with fewer than 3 markers the circle model's own (Jacobian ``J``,
        noise ``sig2`` per axis unless :attr:`noise_mm`)."""
        fit0 = AxisFit(point=a, direction=n, basis=basis, cov=cov, crb=np.full((4, 4), np.nan),
                       rms_mm=0.0, sigma_mm=0.0, marker_rms_mm={}, marker_radius_m={},
                       sweep_deg=0.0, n_frames=0, n_observations=0, n_outliers=0, iterations=0,
                       converged=True, cond=0.0, method=self.method)
        try:
            rigid = ClusterAxisEstimator(robust=False, marker_weights=False, noise_mm=self.noise_mm,
                                         min_frames=self.min_frames).fit(P, labels)
            return _rebase_cov(rigid.crb, rigid, fit0), rigid.sweep_deg
        except InputError:          # fewer than 3 markers: the bound of the circle model itself
            H1 = np.einsum("kig,kih->gh", J, J)
            noise_m = np.sqrt(3 * sig2) if self.noise_mm is None else self.noise_mm * 1e-3
            crb = noise_m ** 2 / 3.0 * np.linalg.pinv(H1)[:4, :4]
            th = marker_angles(P, a, n)
            return crb, float(np.degrees(np.nanmax(np.nanmax(th, axis=0) - np.nanmin(th, axis=0))))

    @staticmethod
    def _residual_jacobian(X, k_idx, a, n, u, v, rad, hk, M, c):
        """Radial and axial residuals (K, 2) to each marker's circle and their Jacobian
        (K, 2, 4 + 2M) w.r.t. the axis chart, the radii and the axial offsets."""
        d = X - a
        z = d @ n
        e = d - z[:, None] * n
        rho = np.linalg.norm(e, axis=1)
        eh = e / np.maximum(rho, 1e-12)[:, None]
        xc = X - c
        r = np.stack([rho - rad[k_idx], xc @ n - hk[k_idx]], axis=1)
        K = len(k_idx)
        # J is d(model)/d(params) = -d(r)/d(params), so the Gauss-Newton step is H^-1 J^T r.
        # A tilt of n by b (b = u or v) about the fixed point a: d(rho) = -z (eh . b);
        # the axial coordinate is measured from the fixed centroid c: d((X - c).n) = (X - c).b
        J = np.zeros((K, 2, 4 + 2 * M))
        for col, b in ((0, u), (1, v)):
            J[:, 1, col] = -(xc @ b)
            J[:, 0, col] = z * (eh @ b)
        for col, b in ((2, u), (3, v)):
            J[:, 0, col] = eh @ b
            J[:, 1, col] = 0.0
        J[np.arange(K), 0, 4 + k_idx] = 1.0
        J[np.arange(K), 1, 4 + M + k_idx] = 1.0
        return r, J
