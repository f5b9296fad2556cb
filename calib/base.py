"""Base placement from measured joint axes and the URDF (thesis section 3.2, generalised).

The thesis intersects the axes of joints 1 and 2 to find the base. Here the URDF gives each
swept joint's axis line in the base frame at the encoder angles held during its sweep; the
rigid transform ``T_camera_base`` that maps those lines onto the measured ones is found by
weighted least squares on the lines' chart coordinates (each measured axis weighted by the
inverse of its covariance). This uses the intersection when the axes intersect (PA10) and
works equally when they are offset. Needs two axes that are not parallel.

Covariances of the result are first-order propagations of the axis covariances (and, with
the axis Cramer-Rao bounds in place of the covariances, the bound on ``T_camera_base``), plus
the URDF model error estimated from the measured J1-J2 discrepancy (:func:`model_error_terms`),
which also enters the weights.
Perturbations are ``R = exp([w]) R_hat``, ``p = p_hat + dp`` in the camera frame, so
``origin_std_mm`` is the 3-D RMS of the base origin in the camera frame and
``rotation_std_deg`` the RMS rotation angle.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares

from mocap.io.errors import InputError

from calib.geometry import chart_coords, chart_line, line_distance
from mocap.kinematics import rotation_angle, rotvec_to_matrix, unit


@dataclass(frozen=True, eq=False)
class BasePlacement:
    """``T_camera_base`` with its covariance (6x6, order ``w`` rad then ``p`` m) and bound.

    What :func:`place_base` returns: the rigid transform that maps the URDF's axis lines onto
    the measured ones [1]_ [2]_, its covariance and Cramer-Rao bound under the perturbation
    ``R = exp([w]) R_hat``, ``p = p_hat + dp`` (camera frame), the fit's misfit statistics and
    the uncertainty budget. The properties ``origin_std_mm`` (3-D RMS of the base origin) and
    ``rotation_std_deg`` (RMS rotation angle) summarise ``cov``; ``crb_origin_mm`` and
    ``crb_rotation_deg`` the bound.

    Attributes
    ----------
    T_camera_base : numpy.ndarray
        (4, 4) homogeneous transform, ``p_camera = T @ p_base`` (m).
    cov : numpy.ndarray
        (6, 6) covariance of ``(w, dp)`` (rad, m), noise and model-error parts together, each
        noise part at the variance of the t distribution its estimated variance implies
        (:func:`t_variance_factor`, ``nu / (nu - 2)`` times the propagated ``s^2`` part).
    crb : numpy.ndarray
        (6, 6) the same propagated from the axes' Cramer-Rao bounds (NaN where an axis has
        none).
    residual_chart : dict
        Joint -> (4,) whitened chart residual of its axis line.
    axis_distance_mm : float
        Distance between the two measured axes (mm; 0 if they intersect).
    urdf_axis_distance_mm : float
        The same in the URDF (mm).
    axis_angle_deg : float
        Angle between the measured axes (deg).
    urdf_axis_angle_deg : float
        The same in the URDF (deg).
    chi2 : float
        Sum of the squared whitened residuals of the first (noise-only) solve.
    iterations : int
        Residual evaluations of the least-squares solve.
    converged : bool
        Whether the solve reported success.
    cond : float
        Condition number of ``J^T J`` of the whitened solve.
    dof : int, optional
        Degrees of freedom of ``chi2``: 4 per axis - 6.
    p_value : float, optional
        Upper-tail probability of ``chi2`` on ``dof`` (NaN without redundancy).
    inflation : float, optional
        RMS growth of the standard deviations from the model-error term (1: none).
    warnings : tuple of str, optional
        Model mismatch (``p_value`` below the threshold) and non-convergence.
    region95 : dict or None, optional
        95 % region thresholds and effective degrees of freedom (:func:`region95`).
    model_error_mm : float, optional
        Model-error shift per URDF axis line and direction (mm, :func:`model_error_terms`).
    model_error_deg : float, optional
        Model-error tilt per URDF axis line and direction (deg).
    budget : dict or None, optional
        Origin and rotation standard deviations of the noise part and of the model-error
        part.
    urdf_trusted : bool, optional
        True when the model error estimated from the J1-J2 discrepancy was left out (the URDF's
        J1-J2 geometry trusted: ``place_base(model_error=False)``, ``jointlab calib
        --trust-urdf``); default False.

    References
    ----------
    .. [1] PA10 thesis (seeds 002), sec. 3.2 (Estimation of Link Position): the base from the
       axes of joints 1 and 2.
    .. [2] jointlab calibration (docs/calibration.md).
    """

    T_camera_base: np.ndarray
    cov: np.ndarray
    crb: np.ndarray
    residual_chart: dict          # joint -> whitened chart residual (4,)
    axis_distance_mm: float       # distance between the two measured axes (0 if they intersect)
    urdf_axis_distance_mm: float  # the same in the URDF
    axis_angle_deg: float         # angle between the measured axes
    urdf_axis_angle_deg: float
    chi2: float
    iterations: int
    converged: bool
    cond: float
    dof: int = 0                  # 4 per axis - 6
    p_value: float = float("nan")  # of chi2 on dof
    inflation: float = 1.0        # RMS growth of the std from the model-error term (1: none)
    warnings: tuple = ()
    region95: dict = None         # 95 % region thresholds and effective degrees of freedom (region95())
    model_error_mm: float = 0.0   # model-error shift per URDF axis line and direction (model_error_terms)
    model_error_deg: float = 0.0  # model-error tilt per URDF axis line and direction
    budget: dict = None           # origin / rotation std of the noise part and the model-error part
    urdf_trusted: bool = False    # the estimated model error left out (model_error=False, --trust-urdf)

    @staticmethod
    def _stds(C):
        return (float(1e3 * np.sqrt(np.trace(C[3:, 3:]))), float(np.degrees(np.sqrt(np.trace(C[:3, :3])))))

    @property
    def origin_std_mm(self) -> float:
        return self._stds(self.cov)[0]

    @property
    def rotation_std_deg(self) -> float:
        return self._stds(self.cov)[1]

    @property
    def crb_origin_mm(self) -> float:
        return self._stds(self.crb)[0]

    @property
    def crb_rotation_deg(self) -> float:
        return self._stds(self.crb)[1]

    def to_dict(self) -> dict:
        return {
            "T_camera_base": [[float(x) for x in row] for row in self.T_camera_base],
            "origin_std_mm": self.origin_std_mm,
            "rotation_std_deg": self.rotation_std_deg,
            "crb_origin_std_mm": self.crb_origin_mm,
            "crb_rotation_std_deg": self.crb_rotation_deg,
            "cov_rotvec_origin": self.cov.tolist(),
            "crb_rotvec_origin": self.crb.tolist(),
            "residual_chart_whitened": {str(k): [float(x) for x in v] for k, v in self.residual_chart.items()},
            "axis_distance_mm": self.axis_distance_mm,
            "urdf_axis_distance_mm": self.urdf_axis_distance_mm,
            "axis_angle_deg": self.axis_angle_deg,
            "urdf_axis_angle_deg": self.urdf_axis_angle_deg,
            "chi2": self.chi2,
            "dof": self.dof,
            "chi2_per_dof": self.chi2 / self.dof if self.dof > 0 else None,
            "p_value": self.p_value,
            "std_inflation": self.inflation,
            "region95": self.region95,
            "model_error_mm": self.model_error_mm,
            "model_error_deg": self.model_error_deg,
            "budget": self.budget,
            "urdf_trusted": self.urdf_trusted,
            "warnings": list(self.warnings),
            "iterations": self.iterations,
            "converged": self.converged,
            "cond": self.cond,
        }


#: draws of the Monte Carlo reference distribution behind the 95 % thresholds (fixed seed)
REGION_DRAWS = 20000


#: degrees of freedom below which :func:`t_variance_factor` stays at its value for this many (the
#: variance of Student's t is infinite at 2 and below)
T_FACTOR_MIN_DOF = 3.0


def t_variance_factor(nu) -> np.ndarray:
    r"""``nu / (nu - 2)``: the variance of Student's t on ``nu`` degrees of freedom, the factor
    from a variance estimated on ``nu`` degrees of freedom to the standard uncertainty's square.

    GUM Supplement 1 (JCGM 101:2008, 6.4.9.4): a quantity known from an estimate ``s^2`` of its
    variance on ``nu`` degrees of freedom has a scaled-and-shifted t distribution, of variance
    ``nu / (nu - 2) s^2``. Reported as a covariance, ``s^2 H^-1`` alone is too small for a user
    who reads it as a Gaussian one (a chi2 region or +-1.96 std): with 4-10 degrees of freedom,
    as one reflector's few poses leave, such a region held the truth in 78-83 % of the runs of
    issue 46. ``nu`` is floored at :data:`T_FACTOR_MIN_DOF` (the factor 3 there; the t variance
    is infinite at 2); infinite ``nu`` (a known variance) gives 1.
    """
    nu = np.asarray(nu, float)
    with np.errstate(divide="ignore", invalid="ignore"):
        nu_f = np.maximum(nu, T_FACTOR_MIN_DOF)
        return np.where(np.isfinite(nu), nu_f / (nu_f - 2.0), 1.0)


def region95(parts, nus, level: float = 0.95, draws: int = REGION_DRAWS, scale=None) -> dict:
    """The 95 % region of ``T_camera_base`` when its covariance is a sum of ``parts`` (6x6) each
    scaled by a variance estimated with ``nus`` degrees of freedom (inf: known).

    The threshold on the squared Mahalanobis distance ``x' C^-1 x`` of each block (origin,
    rotation, the 6-D pose) is the ``level`` quantile of its reference distribution, drawn by
    Monte Carlo (GUM Supplement 1 style, fixed seed): ``x ~ N(0, sum_j P_j)`` and the estimated
    ``C = sum_j c_j u_j P_j`` with ``u_j ~ chi2(nu_j) / nu_j`` (1 for known variances) and
    ``c_j`` the reporting factors ``scale`` (default 1; :func:`t_variance_factor` for the
    reported covariance); with one part and ``c = 1`` this is Hotelling's ``p F(level; p, nu)``,
    with all variances known ``chi2(level; p)``. The effective degrees of freedom of each block
    follow Welch-Satterthwaite on the whitened traces, ``nu = (sum t_j)^2 / sum(t_j^2 / nu_j)``
    with ``t_j = tr(C_block^-1 P_j,block)``, and ``k95`` is the factor for one coordinate:
    the Student factor ``t(0.975; nu)`` times the block's ``sqrt(tr P / tr C)`` (``P = sum_j
    P_j``, ``C = sum_j c_j P_j``), so that ``+- k95 * std`` of the reported covariance is the
    Student interval.
    """
    from scipy.stats import chi2 as chi2_dist
    from scipy.stats import t as t_dist

    scale = np.ones(len(parts)) if scale is None else np.asarray(scale, float)
    C0 = sum(parts)
    parts = [c * P for c, P in zip(scale, parts)]
    C = sum(parts)
    nu_arr = np.asarray(nus, float)
    fin = np.isfinite(nu_arr)
    rng = np.random.default_rng(20260528)
    u = np.ones((draws, len(parts)))
    if fin.any():
        nu_f = np.maximum(nu_arr[fin], 1e-3)
        u[:, fin] = rng.chisquare(nu_f, (draws, int(fin.sum()))) / nu_f
    z = rng.standard_normal((draws, 6))
    out = {"level": level}
    for name, idx in (("origin", slice(3, 6)), ("rotation", slice(0, 3)), ("pose", slice(0, 6))):
        Cb, C0b = C[idx, idx], C0[idx, idx]
        p = Cb.shape[0]
        Pb = np.stack([P[idx, idx] for P in parts])                     # (J, p, p)
        P0b = Pb / scale[:, None, None]
        Wi = np.linalg.inv(C0b)
        t = np.einsum("ij,kji->k", Wi, P0b)
        den = float(np.sum(t[fin] ** 2 / np.maximum(nu_arr[fin], 1e-9)))
        nu = float(np.sum(t) ** 2 / den) if den > 0 else float("inf")
        if fin.any() or np.any(scale != 1.0):
            x = z[:, :p] @ np.linalg.cholesky(C0b + 1e-30 * np.eye(p)).T  # (D, p) ~ N(0, sum P_j)
            Chat = np.einsum("dk,kij->dij", u, Pb)                       # (D, p, p)
            d2 = np.einsum("di,di->d", x, np.linalg.solve(Chat, x[..., None])[..., 0])
            q = float(np.quantile(d2, level))
        else:
            q = float(chi2_dist.ppf(level, p))
        shrink = float(np.sqrt(np.trace(C0b) / np.trace(Cb)))
        out[f"{name}_dof"] = nu if np.isfinite(nu) else None
        out[f"{name}_d2"] = q
        out[f"{name}_k95"] = shrink * (float(t_dist.ppf(0.5 + level / 2, nu)) if np.isfinite(nu)
                                       else 1.959963984540054)
    return out


def pose_errors(T_est: np.ndarray, T_true: np.ndarray) -> tuple[float, float]:
    """Origin error (mm) and rotation error (deg) between two ``T_camera_base``.

    The origin error is the distance between the translations, the rotation error the angle
    of ``R_est R_true^T`` (the geodesic distance on SO(3) [1]_), as the calibration benchmarks
    and the hand-eye cross-check report them [2]_.

    Parameters
    ----------
    T_est, T_true : numpy.ndarray
        (4, 4) homogeneous transforms (m).

    Returns
    -------
    origin_mm : float
        ``|p_est - p_true|`` (mm).
    rotation_deg : float
        Rotation angle of ``R_est R_true^T`` (deg).

    References
    ----------
    .. [1] Huynh 2009, metrics for 3D rotations: comparison and analysis, J. Math. Imaging
       Vis. 35, 155-164.
    .. [2] jointlab calibration (docs/calibration.md).

    Examples
    --------
    >>> T = np.eye(4)
    >>> T[:3, 3] = [0.001, 0.0, 0.0]
    >>> T[:3, :3] = rotvec_to_matrix(np.radians([0.0, 0.0, 1.0]))
    >>> tuple(round(x, 6) for x in pose_errors(T, np.eye(4)))
    (1.0, 1.0)
    """
    dp = 1e3 * float(np.linalg.norm(T_est[:3, 3] - T_true[:3, 3]))
    dr = float(np.degrees(rotation_angle(T_est[:3, :3] @ T_true[:3, :3].T)))
    return dp, dr


def _initial_pose(meas, urdf):
    """Rotation by aligning directions (and their cross product), translation by linear LS."""
    (p1, n1), (p2, n2) = meas[:2]
    (b1, m1), (b2, m2) = urdf[:2]
    A = np.stack([m1, m2, unit(np.cross(m1, m2))])
    B = np.stack([n1, n2, unit(np.cross(n1, n2))])
    H = B.T @ A
    U, _, Vt = np.linalg.svd(H)
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt))])
    R = U @ D @ Vt
    M = np.zeros((3, 3))
    rhs = np.zeros(3)
    for (p, n), (b, m) in zip(meas, urdf):
        P = np.eye(3) - np.outer(n, n)
        M += P
        rhs += P @ (p - R @ b)
    return R, np.linalg.solve(M, rhs)


def _pooled(fit) -> bool:
    """Whether an axis fit's noise variance is the one pooled over the sweeps
    (:func:`calib.pipeline.pool_noise`)."""
    return bool(getattr(fit, "extra", {}).get("noise_pooled"))


#: below this p-value of the base solve's chi2 the axes do not fit the URDF: a warning names the
#: mismatch
MISFIT_P = 0.01
def _pair_invariants(p1, n1, p2, n2) -> np.ndarray:
    """Signed common-normal distance (m, along ``n1 x n2``) and angle (rad) between two lines."""
    c = np.cross(n1, n2)
    return np.array([float((p2 - p1) @ c) / np.linalg.norm(c), float(np.arccos(np.clip(n1 @ n2, -1, 1)))])


def model_error_terms(axes, urdf_lines, covs, tol_m: float = 0.0, estimate: bool = True):
    """The URDF-model error per axis line, from the discrepancy between the measured and the
    URDF's J1-J2 geometry: shift ``tau_s`` (m), tilt ``tau_t`` (rad), the 4x4 chart covariances
    of each line's model error (shift part ``Vs_j``, tilt part ``Vt_j``) and the degrees of
    freedom of the two mean squares.

    A pair of axes has two invariants that no rigid placement changes: the signed common-normal
    distance ``d`` (along ``n1 x n2``) and the angle ``a``. Their discrepancies
    ``D = inv(measured) - inv(URDF)`` are all the data show of the URDF's error (the base
    solve's chi2 tests them); each is measured with the standard uncertainty ``u`` propagated
    from the axis covariances ``covs`` (first order, numerical derivatives in the chart
    coordinates). The discrepancy is not corrected (the data cannot say which line, or the base,
    is off), so it enters as an uncorrected systematic effect of mean square ``D^2 + u^2`` (GUM
    JCGM 100:2008 F.2.4.5; also the second moment of the discrepancy given its measurement
    under a flat prior): a discrepancy the sweep cannot resolve (small ``D``, large ``u``)
    still counts with the size ``u`` it cannot exclude. It goes to the URDF element that holds
    the J1-J2 geometry, the later joint's origin (in a URDF, joint 2's ``<origin>`` in link 1;
    joint 1's origin in the base link is what defines the base frame, and an error there is a
    rigid move of both lines that no sweep sees): the later joint's line gets a shift along the
    common normal, ``tau_s^2 = D_d^2 + u_d^2``, and a tilt in the plane of the two directions
    about the common normal's foot (it changes the angle, not the distance),
    ``tau_t^2 = D_a^2 + u_a^2``. The other lines get none.

    ``tol_m`` is a declared URDF tolerance (type B, per line and direction across it): each
    line's shift variance is at least ``tol_m^2`` in both directions across it (every line). ``estimate``
    False leaves only the declared part. The degrees of freedom of each mean square follow
    Welch-Satterthwaite on its estimated part: ``u^2 = sum_j u_j^2`` with ``u_j^2`` from axis
    ``j``'s covariance on ``nu_j`` degrees of freedom and ``D^2`` taken as known,
    ``nu = (D^2 + u^2)^2 / sum_j (u_j^4 / nu_j)`` (infinite where the declared tolerance
    dominates).
    """

    (b1, m1), (b2, m2) = urdf_lines[:2]
    f1, f2 = axes[:2]
    lines = [(f1.point, f1.direction), (f2.point, f2.direction)]
    inv_u = _pair_invariants(b1, m1, b2, m2)
    inv_m = _pair_invariants(*lines[0], *lines[1])
    var = np.zeros(2)
    var2_nu = np.zeros(2)                    # sum_j u_j^4 / nu_j
    pooled_var = np.zeros(2)                 # the u_j^2 of axes sharing one pooled variance
    h = 1e-7
    for k, (f, C) in enumerate(zip((f1, f2), covs[:2])):
        G = np.empty((2, 4))
        for i in range(4):
            pert = list(lines)
            pert[k] = chart_line(h * np.eye(4)[i], f.point, f.direction, *f.basis)
            G[:, i] = (_pair_invariants(*pert[0], *pert[1]) - inv_m) / h
        uj2 = np.einsum("ij,jk,ik->i", G, C, G)
        var += uj2
        pooled_var = pooled_var + uj2 if _pooled(f) else pooled_var
        var2_nu += 0.0 if _pooled(f) else uj2 ** 2 / max(float(f.dof), 1e-9)
    if any(_pooled(f) for f in (f1, f2)):     # one pooled variance: its parts add before squaring
        var2_nu += pooled_var ** 2 / max(float(next(f.dof for f in (f1, f2) if _pooled(f))), 1e-9)
    total = (inv_m - inv_u) ** 2 + var
    ms = total if estimate else np.zeros(2)         # the later line: shift m^2, tilt rad^2
    later = 1 if f2.joint is None or f1.joint is None or f2.joint > f1.joint else 0
    tol2 = float(tol_m) ** 2
    with np.errstate(divide="ignore"):
        nus = np.where(var2_nu > 0, total ** 2 / np.maximum(var2_nu, 1e-300), np.inf)
    if tol2 >= ms[0]:
        nus[0] = np.inf
    c = unit(np.cross(f1.direction, f2.direction))
    Vs, Vt = [], []
    for k, f in enumerate((f1, f2)):
        u, v = f.basis
        p_o, n_o = lines[1 - k]
        t = unit(n_o - (n_o @ f.direction) * f.direction)
        w = f.point - p_o
        cb = f.direction @ n_o
        s_f = (cb * (n_o @ w) - f.direction @ w) / (1.0 - cb ** 2)    # foot of the common normal
        g = np.array([0.0, 0.0, c @ u, c @ v])                         # shift along the normal
        a = np.array([t @ u, t @ v, -s_f * (t @ u), -s_f * (t @ v)])   # tilt about the foot
        e = np.array([0.0, 0.0, -(c @ v), c @ u])                     # shift across both
        mk = ms if k == later else np.zeros(2)
        Vs.append(max(mk[0], tol2) * np.outer(g, g) + tol2 * np.outer(e, e))
        Vt.append(mk[1] * np.outer(a, a))
    Vs += [tol2 * np.diag([0.0, 0.0, 1.0, 1.0])] * (len(axes) - 2)
    Vt += [np.zeros((4, 4))] * (len(axes) - 2)
    return float(np.sqrt(max(ms[0], tol2))), float(np.sqrt(ms[1])), Vs, Vt, [float(x) for x in nus]


def _pair_geometry(axes, urdf_lines):
    """The measured lines ``(point, direction)`` of the fitted ``axes``, the URDF lines (unit
    directions) and the J1-J2 pair's geometry ``(measured distance (m), URDF distance (m),
    measured angle (deg), URDF angle (deg))``; the two URDF axes must be 5 deg apart or more."""
    if len(axes) < 2 or len(axes) != len(urdf_lines):
        raise InputError(f"base placement needs at least two swept joints, got {len(axes)}")
    meas = [(f.point, f.direction) for f in axes]
    urdf = [(np.asarray(b, float), unit(m)) for b, m in urdf_lines]
    ang_u = float(np.degrees(np.arccos(np.clip(abs(urdf[0][1] @ urdf[1][1]), 0, 1))))
    if ang_u < 5.0:
        raise InputError(f"the URDF axes of joints {axes[0].joint} and {axes[1].joint} are parallel "
                         f"({ang_u:.2f} deg apart): they cannot place the base")
    ang_m = float(np.degrees(np.arccos(np.clip(meas[0][1] @ meas[1][1], -1, 1))))
    ang_u_signed = float(np.degrees(np.arccos(np.clip(urdf[0][1] @ urdf[1][1], -1, 1))))
    dist_m, _ = line_distance(meas[0][0], meas[0][1], meas[1][0], meas[1][1])
    dist_u, _ = line_distance(urdf[0][0], urdf[0][1], urdf[1][0], urdf[1][1])
    return meas, urdf, (dist_m, dist_u, ang_m, ang_u_signed)


def _whitening(C):
    """``L`` with ``L^T L = C^-1`` (eigenvalues floored at 1e-12 of the largest)."""
    C = 0.5 * (C + C.T)
    w, V = np.linalg.eigh(C)
    w = np.maximum(w, 1e-12 * max(w.max(), 1e-30))
    return (V / np.sqrt(w)).T


def _line_residuals(x, axes, urdf, Ls, R0, p0):
    """Whitened chart coordinates of the URDF lines ``urdf`` moved by ``R = exp([x_0:3]) R0``,
    ``p = p0 + x_3:6`` against the measured ``axes`` (the objective of :func:`place_base`)."""
    R = rotvec_to_matrix(x[:3]) @ R0
    p = p0 + x[3:]
    out = []
    for f, (b, m), L in zip(axes, urdf, Ls):
        c = chart_coords(R @ b + p, R @ m, f.point, f.direction, *f.basis)
        out.append(L @ c)
    return np.concatenate(out)


def _solve_lines(axes, meas, urdf, covs):
    """The weighted least-squares placement of :func:`place_base` with the line covariances
    ``covs``: ``T_camera_base``, its covariance, the whitened residuals (n, 4), the solver's
    result, cond(J^T J), the unwhitened chart Jacobians ``A_j`` and the whitening ``L_j``."""
    Ls = [_whitening(C) for C in covs]
    R0, p0 = _initial_pose(meas, urdf)
    sol = least_squares(_line_residuals, np.zeros(6), method="lm", xtol=1e-15, ftol=1e-15,
                        gtol=1e-15, args=(axes, urdf, Ls, R0, p0))
    J = sol.jac
    JtJ = J.T @ J
    cov = np.linalg.inv(JtJ)
    R = rotvec_to_matrix(sol.x[:3]) @ R0
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = p0 + sol.x[3:]
    r = _line_residuals(sol.x, axes, urdf, Ls, R0, p0).reshape(len(axes), 4)
    # unwhitened chart Jacobians A_j = L_j^-1 J_j, for splitting the covariance by source
    A = [np.linalg.solve(L, Jj) for L, Jj in zip(Ls, J.reshape(len(axes), 4, 6))]
    return T, cov, r, sol, float(np.linalg.cond(JtJ)), A, Ls


def _split_cov(cov, A, Ls, blocks):
    """cov = sum_j G A_j' W_j B_j W_j A_j G for covariance blocks B_j (W_j = L_j' L_j)."""
    out = []
    for Aj, L, B in zip(A, Ls, blocks):
        W = L.T @ L
        out.append(cov @ Aj.T @ W @ B @ W @ Aj @ cov)
    return out


def _covariance_parts(axes, use, cov, A, Ls, covs, nus, model_terms):
    """The placement's covariance split by source: one noise part per axis (the axes that share
    one pooled variance as one part), then a part per model-error term ``(tau, V_j, nu)`` of
    ``model_terms`` with ``tau > 0``. Returns the parts, their degrees of freedom and the number
    of noise parts."""
    parts = _split_cov(cov, A, Ls, covs)
    pooled = [k for k, f in enumerate(axes) if _pooled(f) and use == "cov"]
    if len(pooled) > 1:           # one pooled variance scales these axes' parts together: one part
        keep = [k for k in range(len(axes)) if k not in pooled]
        parts = [parts[k] for k in keep] + [sum(parts[k] for k in pooled)]
        nus = [nus[k] for k in keep] + [nus[pooled[0]]]
    n_noise = len(parts)
    for tau_k, Vk, nu_k in model_terms:
        if tau_k > 0:
            parts.append(sum(_split_cov(cov, A, Ls, Vk)))
            nus = list(nus) + [nu_k]
    return parts, nus, n_noise


def _reported_covariance(parts, nus, n_noise, model_error: bool):
    """The reported covariance of the placement from its ``parts`` (the first ``n_noise`` from
    noise, on ``nus`` degrees of freedom): each noise part at the variance of the t distribution
    its estimated variance implies (GUM Supplement 1, 6.4.9.4: nu / (nu - 2)); the model-error
    parts are mean squares D^2 + u^2 already (the second moment given the measured discrepancy)
    and stay; the 95 % region is the same region (region95 draws its reference distribution with
    the same factors). Returns the covariance, the factors, the budget by source and the
    inflation (RMS growth of the standard deviations over noise alone; 1 without ``model_error``)."""
    fac = np.r_[t_variance_factor(nus[:n_noise]), np.ones(len(parts) - n_noise)]
    cov = sum(c * P for c, P in zip(fac, parts))
    noise_cov = sum(c * P for c, P in zip(fac[:n_noise], parts[:n_noise]))
    model_cov = sum((c * P for c, P in zip(fac[n_noise:], parts[n_noise:])), np.zeros((6, 6)))
    budget = {name: dict(zip(("origin_std_mm", "rotation_std_deg"), BasePlacement._stds(P)))
              for name, P in (("noise", noise_cov), ("model_error", model_cov))}
    inflation = 1.0
    if model_error:     # RMS growth of the standard deviations over the noise-only solve
        inflation = float(np.sqrt(np.trace(cov) / max(np.trace(noise_cov), 1e-300)))
    return cov, fac, budget, inflation


def _misfit_warning(axes, pair, chi2, dof, p_value, trusted, tau_s, tau_t, inflation) -> str:
    """The warning that the measured axes do not fit the URDF: the test, the J1-J2 geometry
    measured and declared (``pair``, :func:`_pair_geometry`), and what the placement did."""
    dist_m, dist_u, ang_m, ang_u_signed = pair
    j1, j2 = axes[0].joint, axes[1].joint
    what = (f"the URDF's J{j1}-J{j2} geometry is trusted (--trust-urdf): the base absorbs the "
            "discrepancy and the reported uncertainty leaves it out; calibrate without --trust-urdf"
            if trusted else
            f"a model error of {1e3 * tau_s:.3f} mm and {np.degrees(tau_t):.4f} deg per axis line is "
            f"included (standard deviations x{inflation:.2f})")
    return (f"the measured axes do not fit the URDF: chi2 = {chi2:.1f} on {dof} degrees of freedom "
            f"(p = {p_value:.1e}); J{j1}-J{j2} offset measured {1e3 * dist_m:.3f} mm at {ang_m:.3f} deg, "
            f"URDF {1e3 * dist_u:.3f} mm at {ang_u_signed:.3f} deg; {what}")


def place_base(axes, urdf_lines, use: str = "cov", misfit_p: float = MISFIT_P,
               model_error: bool = True, urdf_tol_m: float = 0.0,
               with_region: bool = True) -> BasePlacement:
    r"""Solve ``T_camera_base`` from measured axes and the URDF's axis lines.

    The thesis intersects the axes of joints 1 and 2 [1]_; here the rigid transform
    ``(R, p)`` that maps each URDF axis line ``(b_j, m_j)`` onto the measured line ``j`` is
    found by weighted least squares on the lines' chart coordinates (:mod:`calib.geometry`):

    .. math::

        \min_{R, p} \sum_j c_j^T (C_j + V_j)^{-1} c_j, \qquad
        c_j = \mathrm{chart}_j(R\,b_j + p,\ R\,m_j)

    started from the rotation that aligns the directions (and their cross product, Umeyama
    [2]_) and the translation by linear least squares, refined by Levenberg-Marquardt over
    ``R = exp([w]) R_0``, ``p = p_0 + dp``. This uses the intersection when the axes intersect
    (PA10) and works equally when they are offset. The covariance is the first-order
    propagation of the axis covariances ``C_j`` (with the Cramer-Rao bounds in their place, the
    bound on ``T_camera_base``), split by source; each noise part is reported at the variance
    of the t distribution on its degrees of freedom (:func:`t_variance_factor`, GUM Supplement 1
    6.4.9.4 [5]_), and the 95 % region (:func:`region95`) is drawn with the same factors. ``model_error`` includes the URDF-model error
    estimated from the J1-J2 discrepancy (:func:`model_error_terms`, GUM [3]_): the lines are
    weighted by the inverse of ``C_j + V_j`` (the best linear estimate when the URDF lines
    carry random errors of covariance ``V_j``) and the covariance includes ``V_j``, as a known
    (type B) part. A ``chi2`` p-value below ``misfit_p`` adds a warning that the measured axes
    do not fit the URDF [4]_.

    Parameters
    ----------
    axes : sequence of calib.axis.AxisFit
        Fitted axes (camera frame, with ``joint`` set, the direction's sign matching the
        joint's positive rotation); the first two are the J1-J2 pair.
    urdf_lines : sequence of tuple
        For each axis, the ``(point, direction)`` of the same joint's axis in the base frame at
        the sweep's held angles (m).
    use : {"cov", "crb"}, optional
        The weights: the axes' covariances (default) or their Cramer-Rao bounds (no model
        error then).
    misfit_p : float, optional
        p-value of ``chi2`` below which a warning names the mismatch; default
        :data:`MISFIT_P`.
    model_error : bool, optional
        Include the URDF-model error estimated from the J1-J2 discrepancy; default True.
    urdf_tol_m : float, optional
        Declared standard uncertainty of each URDF axis line's placement across it (m; type B,
        both directions, the floor of the estimated shift); default 0.
    with_region : bool, optional
        Compute the 95 % region (:func:`region95`); default True.

    Returns
    -------
    BasePlacement
        ``T_camera_base``, its covariance, bound, misfit statistics and budget.

    Raises
    ------
    mocap.io.errors.InputError
        If fewer than two axes are given, ``axes`` and ``urdf_lines`` differ in length, or the
        first two URDF axes are parallel (less than 5 deg apart).

    References
    ----------
    .. [1] PA10 thesis (seeds 002), sec. 3.2 (Estimation of Link Position): the base from the
       intersection of the axes of joints 1 and 2.
    .. [2] Umeyama 1991, least-squares estimation of transformation parameters between two
       point patterns, IEEE TPAMI 13(4).
    .. [3] GUM, JCGM 100:2008, evaluation of measurement data - guide to the expression of
       uncertainty in measurement, F.2.4.5 and G.4 (Welch-Satterthwaite).
    .. [4] jointlab calibration (docs/calibration.md).
    .. [5] GUM Supplement 1, JCGM 101:2008, propagation of distributions using a Monte Carlo
       method, 6.4.9 (the t distribution of a quantity known from a few observations).
    """
    meas, urdf, pair = _pair_geometry(axes, urdf_lines)
    from scipy.stats import chi2 as chi2_dist

    covs = [f.cov if use == "cov" else f.crb for f in axes]
    dof = 4 * len(axes) - 6
    T, cov, r, sol, cond, A, Ls = _solve_lines(axes, meas, urdf, covs)
    chi2 = float(np.sum(r ** 2))
    p_value = float(chi2_dist.sf(chi2, dof)) if dof > 0 else float("nan")
    if all(np.all(np.isfinite(f.crb)) for f in axes):
        # the bound at the same estimate: rebuild the whitened Jacobian with the CRB weights
        crb = _solve_lines(axes, meas, urdf, [f.crb for f in axes])[1]
    else:
        crb = np.full((6, 6), np.nan)
    # model error: the URDF axis lines are off the real ones by unknown shifts and tilts of
    # covariance V_j (model_error_terms, with the declared tolerance as a floor); the base is
    # re-solved with the lines' covariances C + V (best linear estimate under that error) and the
    # covariance includes V as its own (type B) parts, shift and tilt (region95 degrees of freedom)
    zero = [np.zeros((4, 4))] * len(axes)
    tau_s, tau_t, Vs, Vt, nu_me = (model_error_terms(axes, urdf, covs, urdf_tol_m, model_error) if use == "cov"
                                   else (0.0, 0.0, zero, zero, [np.inf, np.inf]))
    nus = [f.dof for f in axes] if use == "cov" else [np.inf] * len(axes)
    if tau_s > 0 or tau_t > 0:
        T, cov, r, sol, cond, A, Ls = _solve_lines(axes, meas, urdf,
                                                   [C + Vj + Wj for C, Vj, Wj in zip(covs, Vs, Vt)])
    parts, nus, n_noise = _covariance_parts(axes, use, cov, A, Ls, covs, nus,
                                            ((tau_s, Vs, nu_me[0]), (tau_t, Vt, nu_me[1])))
    cov, fac, budget, inflation = _reported_covariance(parts, nus, n_noise, tau_s > 0 or tau_t > 0)
    trusted = use == "cov" and not model_error
    warnings = []
    if dof > 0 and p_value < misfit_p:
        warnings.append(_misfit_warning(axes, pair, chi2, dof, p_value, trusted, tau_s, tau_t,
                                        inflation))
    reg = region95(parts, nus, scale=fac) if with_region else None
    if not sol.success:
        warnings.append(f"the base solve did not converge ({sol.message})")
    dist_m, dist_u, ang_m, ang_u_signed = pair
    return BasePlacement(T_camera_base=T, cov=cov, crb=crb,
                         residual_chart={f.joint: rr for f, rr in zip(axes, r)},
                         axis_distance_mm=1e3 * dist_m, urdf_axis_distance_mm=1e3 * dist_u,
                         axis_angle_deg=ang_m, urdf_axis_angle_deg=ang_u_signed,
                         chi2=chi2, iterations=int(sol.nfev), converged=bool(sol.success),
                         cond=cond, dof=dof, p_value=p_value, inflation=inflation, warnings=tuple(warnings),
                         region95=reg, model_error_mm=1e3 * tau_s,
                         model_error_deg=float(np.degrees(tau_t)), budget=budget, urdf_trusted=trusted)
