"""Base placement from measured joint axes and the URDF (thesis section 3.2, generalised).

The thesis intersects the axes of joints 1 and 2 to find the base. Here the URDF gives each
swept joint's axis line in the base frame at the encoder angles held during its sweep; the
rigid transform ``T_camera_base`` that maps those lines onto the measured ones is found by
weighted least squares on the lines' chart coordinates (each measured axis weighted by the
inverse of its covariance). This uses the intersection when the axes intersect (PA10) and
works equally when they are offset. Needs two axes that are not parallel.

Covariances of the result are first-order propagations of the axis covariances (and, with
the axis Cramer-Rao bounds in place of the covariances, the bound on ``T_camera_base``).
Perturbations are ``R = exp([w]) R_hat``, ``p = p_hat + dp`` in the camera frame, so
``origin_std_mm`` is the 3-D RMS of the base origin in the camera frame and
``rotation_std_deg`` the RMS rotation angle.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares

from mocap.io.errors import InputError

from calib.geometry import chart_coords, line_distance
from mocap.kinematics import rotation_angle, rotvec_to_matrix, unit


@dataclass(frozen=True, eq=False)
class BasePlacement:
    """``T_camera_base`` with its covariance (6x6, order ``w`` rad then ``p`` m) and bound."""

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
    model_error_mm: float = 0.0   # model-error line offset per URDF axis line (0: no misfit, none declared)

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
            "warnings": list(self.warnings),
            "iterations": self.iterations,
            "converged": self.converged,
            "cond": self.cond,
        }


#: draws of the Monte Carlo reference distribution behind the 95 % thresholds (fixed seed)
REGION_DRAWS = 20000


def region95(parts, nus, level: float = 0.95, draws: int = REGION_DRAWS) -> dict:
    """The 95 % region of ``T_camera_base`` when its covariance is a sum of ``parts`` (6x6) each
    scaled by a variance estimated with ``nus`` degrees of freedom (inf: known).

    The threshold on the squared Mahalanobis distance ``x' C^-1 x`` of each block (origin,
    rotation, the 6-D pose) is the ``level`` quantile of its reference distribution, drawn by
    Monte Carlo (GUM Supplement 1 style, fixed seed): ``x ~ N(0, sum_j P_j)`` and the estimated
    ``C = sum_j u_j P_j`` with ``u_j ~ chi2(nu_j) / nu_j`` (1 for known variances); with one part
    this is Hotelling's ``p F(level; p, nu)``, with all variances known ``chi2(level; p)``. The
    effective degrees of freedom of each block follow Welch-Satterthwaite on the whitened traces,
    ``nu = (sum t_j)^2 / sum(t_j^2 / nu_j)`` with ``t_j = tr(C_block^-1 P_j,block)``, and ``k95``
    is the Student factor ``t(0.975; nu)`` for one coordinate.
    """
    from scipy.stats import chi2 as chi2_dist
    from scipy.stats import t as t_dist

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
        Cb = C[idx, idx]
        p = Cb.shape[0]
        Pb = np.stack([P[idx, idx] for P in parts])                     # (J, p, p)
        Wi = np.linalg.inv(Cb)
        t = np.einsum("ij,kji->k", Wi, Pb)
        den = float(np.sum(t[fin] ** 2 / np.maximum(nu_arr[fin], 1e-9)))
        nu = float(np.sum(t) ** 2 / den) if den > 0 else float("inf")
        if fin.any():
            x = z[:, :p] @ np.linalg.cholesky(Cb + 1e-30 * np.eye(p)).T  # (D, p) ~ N(0, Cb)
            Chat = np.einsum("dk,kij->dij", u, Pb)                       # (D, p, p)
            d2 = np.einsum("di,di->d", x, np.linalg.solve(Chat, x[..., None])[..., 0])
            q = float(np.quantile(d2, level))
        else:
            q = float(chi2_dist.ppf(level, p))
        out[f"{name}_dof"] = nu if np.isfinite(nu) else None
        out[f"{name}_d2"] = q
        out[f"{name}_k95"] = float(t_dist.ppf(0.5 + level / 2, nu)) if np.isfinite(nu) else 1.959963984540054
    return out


def pose_errors(T_est: np.ndarray, T_true: np.ndarray) -> tuple[float, float]:
    """Origin error (mm) and rotation error (deg) between two ``T_camera_base``."""
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


#: below this p-value of the base solve's chi2 the axes do not fit the URDF: a warning names the
#: mismatch
MISFIT_P = 0.01
#: below this p-value (chi2 of the base solve) a model-error term is estimated and added to the
#: covariance: the same evidence that raises the misfit warning
MODEL_ERROR_P = 0.01
#: lever arm (m) that turns the model error's line shift tau into a tilt tau / L of the axis
MODEL_ERROR_LENGTH_M = 1.0


def place_base(axes, urdf_lines, use: str = "cov", misfit_p: float = MISFIT_P,
               model_error_p: float = MODEL_ERROR_P, urdf_tol_m: float = 0.0,
               with_region: bool = True) -> BasePlacement:
    """Solve ``T_camera_base`` from measured axes and the URDF's axis lines.

    ``axes``: fitted :class:`calib.axis.AxisFit` (camera frame, with ``joint`` set, the
    direction's sign matching the joint's positive rotation); ``urdf_lines``: for each, the
    ``(point, direction)`` of the same joint's axis in the base frame at the sweep's held
    angles. ``use`` picks the weights (``"cov"`` or ``"crb"``). ``urdf_tol_m`` is the declared
    standard uncertainty of each URDF axis line's placement (a type-B model error, the floor of
    the one estimated from chi2). ``with_region`` computes the 95 % region (:func:`region95`).
    """
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

    def whitening(C):
        C = 0.5 * (C + C.T)
        w, V = np.linalg.eigh(C)
        w = np.maximum(w, 1e-12 * max(w.max(), 1e-30))
        return (V / np.sqrt(w)).T

    def solve(covs):
        Ls = [whitening(C) for C in covs]
        R0, p0 = _initial_pose(meas, urdf)

        def resid(x):
            R = rotvec_to_matrix(x[:3]) @ R0
            p = p0 + x[3:]
            out = []
            for f, (b, m), L in zip(axes, urdf, Ls):
                c = chart_coords(R @ b + p, R @ m, f.point, f.direction, *f.basis)
                out.append(L @ c)
            return np.concatenate(out)

        sol = least_squares(resid, np.zeros(6), method="lm", xtol=1e-15, ftol=1e-15, gtol=1e-15)
        J = sol.jac
        JtJ = J.T @ J
        cov = np.linalg.inv(JtJ)
        R = rotvec_to_matrix(sol.x[:3]) @ R0
        T = np.eye(4)
        T[:3, :3] = R
        T[:3, 3] = p0 + sol.x[3:]
        r = resid(sol.x).reshape(len(axes), 4)
        # unwhitened chart Jacobians A_j = L_j^-1 J_j, for splitting the covariance by source
        A = [np.linalg.solve(L, Jj) for L, Jj in zip(Ls, J.reshape(len(axes), 4, 6))]
        return T, cov, r, sol, float(np.linalg.cond(JtJ)), A, Ls

    def split(cov, A, Ls, blocks):
        """cov = sum_j G A_j' W_j B_j W_j A_j G for covariance blocks B_j (W_j = L_j' L_j)."""
        out = []
        for Aj, L, B in zip(A, Ls, blocks):
            W = L.T @ L
            out.append(cov @ Aj.T @ W @ B @ W @ Aj @ cov)
        return out

    from scipy.optimize import brentq
    from scipy.stats import chi2 as chi2_dist

    covs = [f.cov if use == "cov" else f.crb for f in axes]
    dof = 4 * len(axes) - 6
    T, cov, r, sol, cond, A, Ls = solve(covs)
    chi2 = float(np.sum(r ** 2))
    p_value = float(chi2_dist.sf(chi2, dof)) if dof > 0 else float("nan")
    if all(np.all(np.isfinite(f.crb)) for f in axes):
        # the bound at the same estimate: rebuild the whitened Jacobian with the CRB weights
        crb = solve([f.crb for f in axes])[1]
    else:
        crb = np.full((6, 6), np.nan)
    # model error (random effect): each URDF axis line is off the real one by an unknown line
    # offset of covariance tau^2 S (S = diag(1/L^2, 1/L^2, 1, 1): tilt tau/L, shift tau per
    # direction); tau^2 is the value at which the re-solved chi2 equals its degrees of freedom
    # (Paule-Mandel); estimated where chi2 rejects the URDF at ``model_error_p``
    tau = 0.0
    S = np.diag([1.0 / MODEL_ERROR_LENGTH_M ** 2] * 2 + [1.0, 1.0])
    nus = [f.dof for f in axes] if use == "cov" else [np.inf] * len(axes)
    if use == "cov" and dof > 0 and p_value < model_error_p:
        def excess(log_tau):
            t2 = np.exp(2 * log_tau)
            return float(np.sum(solve([C + t2 * S for C in covs])[2] ** 2)) - dof

        scale = max(np.sqrt(max(np.trace(C[2:, 2:]) for C in covs)), 1e-9)
        lo, hi = np.log(scale * 1e-4), np.log(scale * 1e4)
        if excess(lo) > 0 > excess(hi):
            tau = float(np.exp(brentq(excess, lo, hi, xtol=1e-6)))
    # the declared URDF tolerance (type B, known) is the floor of the model error
    tau_b = float(urdf_tol_m) if use == "cov" else 0.0
    typeb = tau_b >= tau and tau_b > 0
    if typeb:       # a declared length tolerance shifts the lines; it does not tilt them
        S = np.diag([0.0, 0.0, 1.0, 1.0])
    tau = max(tau, tau_b)
    if tau > 0:
        T, cov, r, sol, cond, A, Ls = solve([C + tau ** 2 * S for C in covs])
    parts = split(cov, A, Ls, covs)
    if tau > 0:
        parts.append(sum(split(cov, A, Ls, [tau ** 2 * S] * len(axes))))
        nus = list(nus) + [float("inf") if typeb else float(dof)]
    inflation = 1.0
    if tau > 0:     # RMS growth of the standard deviations over the noise-only solve
        inflation = float(np.sqrt(np.trace(cov) / max(np.trace(sum(parts[:len(axes)])), 1e-300)))
    warnings = []
    if dof > 0 and p_value < misfit_p:
        j1, j2 = axes[0].joint, axes[1].joint
        warnings.append(
            f"the measured axes do not fit the URDF: chi2 = {chi2:.1f} on {dof} degrees of freedom "
            f"(p = {p_value:.1e}); J{j1}-J{j2} offset measured {1e3 * dist_m:.3f} mm at {ang_m:.3f} deg, "
            f"URDF {1e3 * dist_u:.3f} mm at {ang_u_signed:.3f} deg; a model error of {1e3 * tau:.3f} mm "
            f"per axis line is added (standard deviations x{inflation:.2f})")
    reg = region95(parts, nus) if with_region else None
    if not sol.success:
        warnings.append(f"the base solve did not converge ({sol.message})")
    return BasePlacement(T_camera_base=T, cov=cov, crb=crb,
                         residual_chart={f.joint: rr for f, rr in zip(axes, r)},
                         axis_distance_mm=1e3 * dist_m, urdf_axis_distance_mm=1e3 * dist_u,
                         axis_angle_deg=ang_m, urdf_axis_angle_deg=ang_u_signed,
                         chi2=chi2, iterations=int(sol.nfev), converged=bool(sol.success),
                         cond=cond, dof=dof, p_value=p_value, inflation=inflation, warnings=tuple(warnings),
                         region95=reg, model_error_mm=1e3 * tau)
