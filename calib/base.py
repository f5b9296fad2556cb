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
    inflation: float = 1.0        # factor applied to cov's std when chi2 says the model does not fit
    warnings: tuple = ()

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
            "warnings": list(self.warnings),
            "iterations": self.iterations,
            "converged": self.converged,
            "cond": self.cond,
        }


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


#: below this p-value of the base solve's chi2 the axes do not fit the URDF: the covariance is
#: scaled by chi2/dof (the Birge ratio) and a warning names the mismatch
MISFIT_P = 0.01


def place_base(axes, urdf_lines, use: str = "cov", misfit_p: float = MISFIT_P) -> BasePlacement:
    """Solve ``T_camera_base`` from measured axes and the URDF's axis lines.

    ``axes``: fitted :class:`calib.axis.AxisFit` (camera frame, with ``joint`` set, the
    direction's sign matching the joint's positive rotation); ``urdf_lines``: for each, the
    ``(point, direction)`` of the same joint's axis in the base frame at the sweep's held
    angles. ``use`` picks the weights (``"cov"`` or ``"crb"``).
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
        return T, cov, r, sol, float(np.linalg.cond(JtJ))

    covs = [f.cov if use == "cov" else f.crb for f in axes]
    T, cov, r, sol, cond = solve(covs)
    if all(np.all(np.isfinite(f.crb)) for f in axes):
        # the bound at the same estimate: rebuild the whitened Jacobian with the CRB weights
        _, crb, _, _, _ = solve([f.crb for f in axes])
    else:
        crb = np.full((6, 6), np.nan)
    from scipy.stats import chi2 as chi2_dist

    chi2 = float(np.sum(r ** 2))
    dof = 4 * len(axes) - 6
    p_value = float(chi2_dist.sf(chi2, dof)) if dof > 0 else float("nan")
    inflation, warnings = 1.0, []
    if dof > 0 and p_value < misfit_p:
        inflation = float(np.sqrt(chi2 / dof))
        cov = cov * inflation ** 2
        j1, j2 = axes[0].joint, axes[1].joint
        warnings.append(
            f"the measured axes do not fit the URDF: chi2 = {chi2:.1f} on {dof} degrees of freedom "
            f"(p = {p_value:.1e}); J{j1}-J{j2} offset measured {1e3 * dist_m:.3f} mm at {ang_m:.3f} deg, "
            f"URDF {1e3 * dist_u:.3f} mm at {ang_u_signed:.3f} deg; standard deviations inflated "
            f"x{inflation:.2f}")
    if not sol.success:
        warnings.append(f"the base solve did not converge ({sol.message})")
    return BasePlacement(T_camera_base=T, cov=cov, crb=crb,
                         residual_chart={f.joint: rr for f, rr in zip(axes, r)},
                         axis_distance_mm=1e3 * dist_m, urdf_axis_distance_mm=1e3 * dist_u,
                         axis_angle_deg=ang_m, urdf_axis_angle_deg=ang_u_signed,
                         chi2=chi2, iterations=int(sol.nfev), converged=bool(sol.success),
                         cond=cond, dof=dof, p_value=p_value, inflation=inflation, warnings=tuple(warnings))
