"""Hand-eye / robot-world cross-check: a marker cluster on a distal link plus forward kinematics.

The camera sees markers ``s_k`` fixed in link ``L``; the robot reports ``q_t``. Then
``p_tk = Z T_base_L(q_t) s_k`` with ``Z = T_camera_base`` unknown (the robot-world half of
``A X = Z B``). The solve here does not need OpenCV (whose 5.x wheels lack
``calibrateRobotWorldHandEye``):

1. cluster poses ``A_t`` by Kabsch against a reference frame; with ``C_t = B_t B_ref^-1``
   (``B_t = T_base_L(q_t)``) the relation is ``A_t Z = Z C_t``;
2. rotation of ``Z`` by aligning the rotation vectors of ``A_t`` and ``C_t`` (Kabsch), then
   translation by linear least squares on ``(R_A - I) t_Z = R_Z t_C - t_A`` (Park & Martin 1994);
3. refinement by variable projection: for a given ``Z`` the marker positions ``s_k`` are the
   mean of the back-transformed observations (rigid maps preserve norms), so least squares
   runs over the 6 pose parameters only, with a robust loss.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares

from mocap.io.errors import InputError
from mocap.kinematics import invert_transform, kabsch_batch, matrix_to_rotvec, rotvec_to_matrix



@dataclass(frozen=True, eq=False)
class HandEyeResult:
    """``T_camera_base`` from the hand-eye / robot-world solve, with the link-frame markers.

    What :meth:`HandEyeEstimator.fit` returns: the robot-world transform ``Z`` of
    ``p_tk = Z T_base_L(q_t) s_k`` [1]_ [2]_, the marker positions ``s_k`` in the link frame
    and the fit's diagnostics; the properties ``origin_std_mm`` and ``rotation_std_deg``
    summarise ``cov`` as :class:`calib.base.BasePlacement` does [3]_.

    Attributes
    ----------
    T_camera_base : numpy.ndarray
        (4, 4) homogeneous transform ``Z``, ``p_camera = T @ p_base`` (m).
    p_link : dict
        Marker label -> (3,) position in the link frame (m).
    link : str
        The URDF link that carries the markers.
    rms_mm : float
        RMS 3-D residual of the refined fit (mm).
    cov : numpy.ndarray
        (6, 6) covariance of the rotation vector (rad) then origin (m), camera frame.
    n_frames : int
        Frames with joint angles used.
    iterations : int
        Residual evaluations of the refinement.
    converged : bool
        Whether the refinement reported success.

    References
    ----------
    .. [1] Park & Martin 1994, robot sensor calibration: solving AX = XB on the Euclidean
       group, IEEE Trans. Robot. Autom. 10(5).
    .. [2] Zhuang, Roth & Sudhakar 1994, simultaneous robot/world and tool/flange calibration
       by solving homogeneous transformation equations of the form AX = YB, IEEE Trans.
       Robot. Autom. 10(4).
    .. [3] jointlab calibration (docs/calibration.md), the hand-eye peer.
    """

    T_camera_base: np.ndarray
    p_link: dict            # label -> (3,) marker position in the link frame
    link: str
    rms_mm: float
    cov: np.ndarray         # 6x6, rotation vector (rad) then origin (m), camera frame
    n_frames: int
    iterations: int
    converged: bool

    @property
    def origin_std_mm(self) -> float:
        return float(1e3 * np.sqrt(np.trace(self.cov[3:, 3:])))

    @property
    def rotation_std_deg(self) -> float:
        return float(np.degrees(np.sqrt(np.trace(self.cov[:3, :3]))))

    def to_dict(self) -> dict:
        return {"T_camera_base": self.T_camera_base.tolist(), "link": self.link,
                "p_link": {k: v.tolist() for k, v in self.p_link.items()},
                "rms_mm": self.rms_mm, "origin_std_mm": self.origin_std_mm,
                "rotation_std_deg": self.rotation_std_deg, "n_frames": self.n_frames,
                "iterations": self.iterations, "converged": self.converged}


class HandEyeEstimator:
    r"""Robot-world calibration from a marker cluster on ``link`` and joint angles.

    The peer of the sweep-axis calibration (``jointlab calib --cross-check`` [4]_): the camera
    sees markers ``s_k`` fixed in link ``L`` while the robot reports ``q_t``, so

    .. math::

        p_{tk} = Z\,T_{base,L}(q_t)\,s_k, \qquad A_t Z = Z C_t, \quad
        C_t = B_t B_{ref}^{-1}

    with ``Z = T_camera_base`` unknown (the robot-world half of ``A X = Z B`` [2]_), ``A_t``
    the cluster's pose in frame ``t`` relative to a reference frame (Kabsch/Umeyama) and
    ``B_t = T_base_L(q_t)``. The rotation of ``Z`` aligns the rotation vectors of ``A_t`` and
    ``C_t``, the translation solves ``(R_A - I) t_Z = R_Z t_C - t_A`` by linear least squares
    (Park & Martin [1]_); the refinement is variable projection [3]_: for a given ``Z`` the
    marker positions ``s_k`` are the mean of the back-transformed observations, so least
    squares runs over the 6 pose parameters only, with a robust loss. No OpenCV needed.

    Parameters
    ----------
    robust : bool, optional
        Soft-L1 loss at ``3 sigma`` in the refinement; default True.
    min_markers : int, optional
        Markers a frame must share with the reference frame to enter the Kabsch
        initialisation (at least 3, the Kabsch fit's own minimum,
        :func:`mocap.kinematics.kabsch_batch`); default 3.

    References
    ----------
    .. [1] Park & Martin 1994, robot sensor calibration: solving AX = XB on the Euclidean
       group, IEEE Trans. Robot. Autom. 10(5).
    .. [2] Zhuang, Roth & Sudhakar 1994, simultaneous robot/world and tool/flange calibration
       by solving homogeneous transformation equations of the form AX = YB, IEEE Trans.
       Robot. Autom. 10(4).
    .. [3] Golub & Pereyra 1973, the differentiation of pseudo-inverses and nonlinear least
       squares problems whose variables separate (variable projection).
    .. [4] jointlab calibration (docs/calibration.md).
    """

    def __init__(self, robust: bool = True, min_markers: int = 3):
        if int(min_markers) < 3:
            raise InputError(f"hand-eye min_markers must be >= 3 (a rigid pose needs 3 markers), "
                             f"got {min_markers}")
        self.robust = robust
        self.min_markers = int(min_markers)

    def fit(self, chain, link: str, positions, q, labels=None) -> HandEyeResult:
        """Solve ``T_camera_base`` from markers on ``link`` and the joint angles.

        Parameters
        ----------
        chain : mocap.kinematics.Chain
            The kinematic chain (URDF), for ``T_base_L(q)``.
        link : str
            The link that carries the markers.
        positions : array_like
            (T, M, 3) camera-frame markers on ``link`` (m; NaN = occluded).
        q : array_like
            (T, n) joint angles at the same frames (rad; frames with NaN angles are dropped).
        labels : sequence of str, optional
            M marker labels; default ``m0, m1, ...``.

        Returns
        -------
        HandEyeResult
            ``T_camera_base``, the link-frame markers and the fit's diagnostics.

        Raises
        ------
        mocap.io.errors.InputError
            If fewer than 3 markers or fewer than 10 frames with joint angles are given.

        References
        ----------
        .. [1] Park & Martin 1994, robot sensor calibration: solving AX = XB on the Euclidean
           group, IEEE Trans. Robot. Autom. 10(5).
        """
        P = np.asarray(positions, float)
        Q = np.asarray(q, float)
        labels = tuple(labels) if labels is not None else tuple(f"m{k}" for k in range(P.shape[1]))
        ok_q = np.all(np.isfinite(Q), axis=1)
        P, Q = P[ok_q], Q[ok_q]
        vis = np.all(np.isfinite(P), axis=2)
        if P.shape[1] < 3 or P.shape[0] < 10:
            raise InputError(f"hand-eye needs >= 3 markers on {link!r} and >= 10 frames with joint "
                             f"angles, got {P.shape[1]} markers, {P.shape[0]} frames")
        B = chain.frame_transform(link, Q)                       # (T, 4, 4) T_base_link
        ref = int(np.argmax(vis.sum(axis=1)))
        w = (vis & vis[ref][None]).astype(float)
        RA, tA = kabsch_batch(np.where(vis[ref][:, None], P[ref], 0.0), P, w)
        good = np.all(np.isfinite(RA), axis=(1, 2)) & (w.sum(axis=1) >= self.min_markers)
        if good.sum() < 2:
            raise InputError(f"hand-eye: fewer than 2 frames share {self.min_markers} markers on "
                             f"{link!r} with the best-seen frame")
        C = B @ invert_transform(B[ref])[None]
        Rz, tz = _park_martin(RA[good], tA[good], C[good])
        t_idx, k_idx = np.nonzero(vis)
        M = P.shape[1]
        # the observations and the link poses behind them, for the refinement
        obs = (P[t_idx, k_idx], B[t_idx, :3, :3], B[t_idx, :3, 3], k_idx, np.bincount(k_idx, minlength=M))
        r0 = _handeye_residuals(np.zeros(6), Rz, tz, *obs)
        scale = max(float(np.median(np.abs(r0))) / 0.6745, 1e-5)
        sol = least_squares(_handeye_residuals, np.zeros(6), method="trf", loss="soft_l1" if self.robust else "linear",
                            f_scale=3 * scale, x_scale=np.array([1e-3] * 3 + [1e-3] * 3),
                            xtol=1e-12, ftol=1e-12, gtol=1e-12, args=(Rz, tz, *obs))
        R, p, s = _project_markers(sol.x, Rz, tz, *obs)
        r = _handeye_residuals(sol.x, Rz, tz, *obs).reshape(-1, 3)
        J = sol.jac
        dof = max(r.size - 6 - 3 * M, 1)
        sig2 = float(np.sum(r ** 2) / dof)
        cov = sig2 * np.linalg.pinv(J.T @ J)
        T = np.eye(4)
        T[:3, :3], T[:3, 3] = R, p
        return HandEyeResult(T, {lb: s[k] for k, lb in enumerate(labels)}, link,
                             float(1e3 * np.sqrt(np.mean(np.sum(r ** 2, axis=1)))), cov,
                             int(P.shape[0]), int(sol.nfev), bool(sol.success))


def _park_martin(RA, tA, C):
    """The closed-form start of ``A X = X B`` (Park & Martin 1994): the rotation ``Rz`` aligning
    the rotation vectors of the camera-frame motions ``RA`` (T, 3, 3) with those of the
    base-frame motions ``C`` (T, 4, 4) (SVD of their correlation), then the translation ``tz``
    by linear least squares ``(RA - I) tz = Rz c_t - tA``."""
    a = matrix_to_rotvec(RA)
    c = matrix_to_rotvec(C[:, :3, :3])
    H = a.T @ c
    U, _, Vt = np.linalg.svd(H)
    Rz = U @ np.diag([1, 1, np.sign(np.linalg.det(U @ Vt))]) @ Vt
    Ab = RA - np.eye(3)
    rhs = np.einsum("ij,tj->ti", Rz, C[:, :3, 3]) - tA
    tz = np.linalg.lstsq(Ab.reshape(-1, 3), rhs.reshape(-1), rcond=None)[0]
    return Rz, tz


def _project_markers(x, Rz, tz, obs, Rb, pb, k_idx, cnt):
    """The pose ``R = exp([x_0:3]) Rz``, ``p = tz + x_3:6`` and the link-frame markers (M, 3)
    it implies: the observations ``obs`` (K, 3) of marker ``k_idx`` carried back to the link
    frame (``Rb``, ``pb`` the link pose of each), ``s = Rb^T (R^T (obs - p) - pb)``, averaged
    over each marker's ``cnt`` observations."""
    M = cnt.shape[0]
    R = rotvec_to_matrix(x[:3]) @ Rz
    p = tz + x[3:]
    back = np.einsum("kji,kj->ki", Rb, (obs - p) @ R - pb)
    s = np.stack([np.bincount(k_idx, weights=back[:, i], minlength=M) for i in range(3)], 1) \
        / np.maximum(cnt, 1)[:, None]
    return R, p, s


def _handeye_residuals(x, Rz, tz, obs, Rb, pb, k_idx, cnt):
    """Camera-frame residuals (3 K,) of the observations to the link-frame markers of
    :func:`_project_markers` carried forward by the link poses and the pose ``x``."""
    R, p, s = _project_markers(x, Rz, tz, obs, Rb, pb, k_idx, cnt)
    model = (np.einsum("kij,kj->ki", Rb, s[k_idx]) + pb) @ R.T + p
    return (obs - model).ravel()
