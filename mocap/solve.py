"""Per-frame link-angle solve (thesis eq. 3-5), batched over all frames of a trial.

Eq. 3-5 minimises, per frame ``p``, the distance between the measured markers expressed in their
link frame and the static-pose references of eq. 3-4. This module minimises the equivalent
distance in the robot base frame (the transform is rigid, so the cost is the same):

    E(q) = sum_m rho(| T_base_link(m)(q) p_link_m - T_base_camera p_camera_m |)

over the joints that move in the trial, the others held at their (braked) log angles. All frames
are solved together with numpy:

* one moving joint: the weighted least-squares problem has a closed form (a 1-D Wahba problem:
  ``q = atan2(S, C)``), iterated a few times only to re-weight against outliers;
* several joints: Levenberg-Marquardt with analytic Jacobians (``d p / d q_i = w_i x (p - o_i)``),
  vectorised over frames (the frame index last in memory), frames leave the loop as they
  converge; a frame whose next step, estimated with the previous iteration's Cholesky factor, is
  below ``tol`` takes it and stops without another ``J^T J`` (docs/performance.md).

Robustness: a plain least-squares pass from the motor angle; the marker noise is estimated from
the median residual; frames with a marker beyond ``reject_sigma`` times that level are solved again
from the motor angle with a Cauchy-loss IRLS, the offending markers are rejected and the frame is
polished by least squares on its inliers (so clean frames get the efficient estimate and cost one
pass). Missing markers (NaN) get weight 0 per frame. Pairs of rejected markers whose measurements
fit each other's predictions are label swaps: they are swapped back, used, and reported. Frames
with too few markers on the moving links, an ill-conditioned geometry, no motor angle to start
from, or no convergence are returned as NaN with a flag bit set.

Frames. Everything is solved in the robot base frame: the caller maps the camera-frame markers
with ``T_base_camera`` (from ``calib.json``, or estimated from the static poses by
:mod:`mocap.references`). Braked joints are held at their median log angle over the trial.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from mocap.io.payload import payload_com
from mocap.io.errors import InputError
from mocap.io.plausibility import check_trial_rigid_fit
from mocap.numerics import rotate_about_axis, savgol
from mocap.kinematics import (Chain, apply_transform, invert_transform, make_transform, perp_basis,
                              rotation_about_axis)

# flag bits of SolveResult.flags ---------------------------------------------------------------
FLAG_TOO_FEW_MARKERS = 1
FLAG_ILL_CONDITIONED = 2
FLAG_NOT_CONVERGED = 4
FLAG_NO_GUESS = 8
FLAG_OUTLIERS_REJECTED = 16  # informational: the angle is valid
FLAG_SWAP_REPAIRED = 32      # informational: the angle is valid
FLAG_NAMES = {FLAG_TOO_FEW_MARKERS: "too_few_markers", FLAG_ILL_CONDITIONED: "ill_conditioned",
              FLAG_NOT_CONVERGED: "not_converged", FLAG_NO_GUESS: "no_motor_angle",
              FLAG_OUTLIERS_REJECTED: "outliers_rejected", FLAG_SWAP_REPAIRED: "swap_repaired"}
INVALID_FLAGS = FLAG_TOO_FEW_MARKERS | FLAG_ILL_CONDITIONED | FLAG_NOT_CONVERGED | FLAG_NO_GUESS

_CHI3_MEDIAN = 1.5382  # median of the norm of a 3-D standard normal vector


@dataclass(frozen=True, eq=False)
class SolveResult:
    """Angles and diagnostics of a batched per-frame solve.

    What :meth:`MarkerSolver.fit` returns: the minimiser of thesis eq. 3-5 [1]_ in every frame,
    with the residuals, inliers and flags that say which frames to trust [2]_.

    Attributes
    ----------
    q : numpy.ndarray
        (T, n) joint angles (rad); solved columns from the markers (NaN where :attr:`valid` is
        False), held columns the values used.
    joints : tuple of int
        The solved joints, 0-based.
    labels : tuple of str
        The M marker labels, in column order.
    residual_m : numpy.ndarray
        (T, M) residual norm of each marker (m; NaN where missing or not used).
    inlier : numpy.ndarray
        (T, M) bool, markers used in the final least-squares polish.
    rms_m : numpy.ndarray
        (T,) RMS residual of the inlier markers (m).
    n_markers : numpy.ndarray
        (T,) inlier count.
    stderr : numpy.ndarray
        (T, S) standard error of the solved angles (rad; pooled noise, per-frame geometry).
    flags : numpy.ndarray
        (T,) bit field, see ``FLAG_NAMES``.
    swaps : tuple
        ``(frame, label_a, label_b)`` label swaps repaired.
    iterations : int
        Gauss-Newton iterations of the final stage.
    sigma_m : float
        Estimated per-axis marker noise (m).
    reject_m : float
        The inlier threshold used (m).
    method : str
        ``"closed_form"`` (one joint) or the iterative method's name.
    model_markers : numpy.ndarray or None
        (T, M, 3) the model's marker positions at the solved angles (m), when kept.
    cond : numpy.ndarray or None
        (T,) bound on the condition number of ``J^T J``.

    References
    ----------
    .. [1] PA10 thesis (seeds 002), eq. 3-5.
    .. [2] jointlab data format (docs/format.md), sec. What the workbench writes.
    """

    q: np.ndarray
    joints: tuple[int, ...]
    labels: tuple[str, ...]
    residual_m: np.ndarray
    inlier: np.ndarray
    rms_m: np.ndarray
    n_markers: np.ndarray
    stderr: np.ndarray
    flags: np.ndarray
    swaps: tuple = ()
    iterations: int = 0
    sigma_m: float = float("nan")
    reject_m: float = float("nan")
    method: str = ""
    model_markers: np.ndarray | None = field(default=None, repr=False)
    cond: np.ndarray | None = field(default=None, repr=False)  # (T,) bound on cond(J^T J)

    @property
    def valid(self) -> np.ndarray:
        return (self.flags & INVALID_FLAGS) == 0

    def flag_counts(self) -> dict[str, int]:
        return {name: int(np.count_nonzero(self.flags & bit)) for bit, name in FLAG_NAMES.items()}

    def to_dict(self) -> dict:
        v = self.valid
        rms = self.rms_m[v]
        return {
            "method": self.method,
            "joints": [j + 1 for j in self.joints],
            "frames": int(self.flags.shape[0]),
            "valid_frames": int(np.count_nonzero(v)),
            "flagged_frames": int(np.count_nonzero(~v)),
            "flag_counts": self.flag_counts(),
            "rms_mm": float(1e3 * np.sqrt(np.mean(rms ** 2))) if rms.size else None,
            "max_rms_mm": float(1e3 * rms.max()) if rms.size else None,
            "noise_sigma_mm": float(1e3 * self.sigma_m),
            "reject_threshold_mm": float(1e3 * self.reject_m),
            "median_stderr_rad": [float(x) for x in np.nanmedian(self.stderr[v], axis=0)]
            if rms.size else None,
            "markers_rejected": int(np.count_nonzero(np.isfinite(self.residual_m) & ~self.inlier)),
            "swaps": len(self.swaps),
            "swap_pairs": sorted({f"{a}<->{b}" for _, a, b in self.swaps}),
            "iterations": int(self.iterations),
            "median_cond": float(np.median(self.cond[v])) if self.cond is not None and rms.size
            else None,
            "max_cond": float(np.max(self.cond[v])) if self.cond is not None and rms.size else None,
        }


class MarkerSolver:
    r"""Batched per-frame solve of the link angles from markers (thesis eq. 3-5).

    In every frame ``t``, the solved joints' angles minimise the distance between the measured
    markers and the static-pose references carried by the chain [1]_:

    .. math::

        \hat{q}_t = \arg\min_q \sum_m \rho\left(\lVert p_{m,t} - T_{b,j(m)}(q)\,
        r_m \rVert\right)

    (``p`` in the base frame, ``r_m`` the eq. 3-4 reference of marker ``m`` in the frame of its
    joint ``j(m)``); a robust Cauchy stage ``rho`` first, then least squares on the inliers.

    Parameters
    ----------
    chain : mocap.kinematics.Chain
        The kinematic chain.
    joints : sequence of int
        Solved joints, 0-based; the others are held at the guess.
    marker_joint : array_like
        (M,) the joint that carries each marker's link (-1: the base).
    p_joint : array_like
        (M, 3) each marker in the frame of that joint (eq. 3-4 references, re-expressed; m).
    labels : sequence of str, optional
        M marker labels (for reports); default ``m0, m1, ...``.
    robust_scale_m : float, optional
        Cauchy scale of the first, robust stage (m).
    reject_sigma : float, optional
        Final inlier threshold in units of the estimated per-axis noise (3-D norm).
    reject_floor_m : float, optional
        The threshold never goes below this (m).
    min_markers : int, optional
        A frame needs at least this many inlier markers distal to each solved joint.
    max_iter : int, optional
        Gauss-Newton iterations per stage, at most.
    irls_iter : int, optional
        Reweighting rounds of the robust stage.
    tol : float, optional
        Step size (rad) below which the iteration stops.
    max_cond : float, optional
        Frames whose normal matrix is worse conditioned are flagged.
    detect_swaps : bool, optional
        Repair label swaps between pairs of rejected markers.
    closed_form : bool, optional
        Use the exact 1-D solution when one joint is solved.

    Raises
    ------
    ValueError
        If ``joints`` is empty, repeats or is out of range, or ``marker_joint`` and
        ``p_joint`` disagree on the number of markers.

    References
    ----------
    .. [1] PA10 thesis (seeds 002), eq. 3-4, 3-5.
    """

    def __init__(self, chain, joints, marker_joint, p_joint, labels=None, *,
                 robust_scale_m: float = 0.004, reject_sigma: float = 5.0,
                 reject_floor_m: float = 0.0015, min_markers: int = 2, max_iter: int = 30,
                 irls_iter: int = 4, tol: float = 1e-6, max_cond: float = 1e8,
                 detect_swaps: bool = True, closed_form: bool = True):
        self.chain = chain
        self.joints = tuple(int(j) for j in joints)
        if not self.joints:
            raise ValueError("no joint to solve")
        if len(set(self.joints)) != len(self.joints) or not all(0 <= j < chain.n for j in self.joints):
            raise ValueError(f"joints {self.joints} must be distinct and in 0..{chain.n - 1}")
        self.joints = tuple(sorted(self.joints))
        self.marker_joint = np.asarray(marker_joint, int)
        self.p_joint = np.asarray(p_joint, float).reshape(-1, 3)
        if self.marker_joint.shape[0] != self.p_joint.shape[0]:
            raise ValueError("marker_joint and p_joint disagree on the number of markers")
        M = self.p_joint.shape[0]
        self.labels = tuple(labels) if labels is not None else tuple(f"m{k}" for k in range(M))
        self.robust_scale_m = float(robust_scale_m)
        self.reject_sigma = float(reject_sigma)
        self.reject_floor_m = float(reject_floor_m)
        self.min_markers = int(min_markers)
        self.max_iter = int(max_iter)
        self.irls_iter = int(irls_iter)
        self.tol = float(tol)
        self.max_cond = float(max_cond)
        self.detect_swaps = bool(detect_swaps)
        self.closed_form = bool(closed_form)

    # ------------------------------------------------------------------------------------------
    def fit(self, p_base: np.ndarray, q_guess: np.ndarray) -> SolveResult:
        """Solve every frame: the minimiser of thesis eq. 3-5 [1]_ per frame.

        Parameters
        ----------
        p_base : numpy.ndarray
            (T, M, 3) measured markers in the base frame (m; NaN: missing).
        q_guess : numpy.ndarray
            (T, n) motor angles (the initial guess of eq. 3-5) and the held angles (rad).

        Returns
        -------
        SolveResult
            The angles and the per-frame diagnostics.

        Raises
        ------
        ValueError
            If ``p_base`` is not (T, M, 3) or ``q_guess`` not (T, n).

        References
        ----------
        .. [1] PA10 thesis (seeds 002), eq. 3-5.
        """
        Y, q0, vis, flags, no_guess = self._prepare(p_base, q_guess)
        if len(self.joints) == 1 and self.closed_form:
            model = _SingleJoint(self, q0)
            method = "closed_form_1d"
        else:
            model = _Chain(self, q0)
            method = "levenberg_marquardt"
        qs, P, inl, thr, iters = self._robust_stages(model, q0, Y, vis)
        swaps = []
        if self.detect_swaps:
            Y, inl, swaps, touched = self._repair_swaps(P, Y, vis, inl, thr)
            if touched.any():
                qs_t, _ = model.solve(qs, Y, inl, loss="linear", scale=1.0, max_iter=self.max_iter,
                                      frames=touched)
                qs[touched] = qs_t[touched]
                P[touched] = model.model_markers(qs, np.flatnonzero(touched))
                flags[touched] |= FLAG_SWAP_REPAIRED
        r = P - Y
        res = np.where(vis, _norm3(r), np.nan)
        n_in = inl.sum(axis=1)
        rms = np.sqrt((np.where(inl, res, 0.0) ** 2).sum(axis=1) / np.maximum(n_in, 1))
        flags[(vis & ~inl).any(axis=1)] |= FLAG_OUTLIERS_REJECTED
        Hinv, cond = self._flag_frames(model, qs, inl, n_in, no_guess, flags)
        valid = (flags & INVALID_FLAGS) == 0
        sig_axis, stderr = _standard_errors(res, inl, n_in, valid, Hinv, len(self.joints))
        q = q0.copy()
        q[:, self.joints] = np.where(valid[:, None], qs, np.nan)
        return SolveResult(q=q, joints=self.joints, labels=self.labels, residual_m=res, inlier=inl,
                           rms_m=np.where(valid, rms, np.nan), n_markers=n_in.astype(int),
                           stderr=stderr, flags=flags, swaps=tuple(swaps),
                           iterations=int(iters), sigma_m=sig_axis, reject_m=thr,
                           method=method, model_markers=P, cond=cond)

    def _prepare(self, p_base, q_guess):
        """The checked inputs of :meth:`fit`: markers ``Y`` (T, M, 3) zeroed where not visible,
        the start ``q0`` (T, n) (0 where the guess is missing), the visibility (T, M) of the
        markers the solved joints move, the flags (T,) and the frames without a guess."""
        Y = np.array(p_base, float)
        q_guess = np.atleast_2d(np.asarray(q_guess, float))
        T, M = Y.shape[0], self.p_joint.shape[0]
        if Y.shape != (T, M, 3):
            raise ValueError(f"p_base must be (T, {M}, 3), got {Y.shape}")
        if q_guess.shape != (T, self.chain.n):
            raise ValueError(f"q_guess must be ({T}, {self.chain.n}), got {q_guess.shape}")
        used = self.marker_joint >= self.joints[0]  # the others do not depend on the solved joints
        vis = np.isfinite(Y[..., 0]) & np.isfinite(Y[..., 1]) & np.isfinite(Y[..., 2]) & used[None, :]
        flags = np.zeros(T, np.int64)
        no_guess = ~np.all(np.isfinite(q_guess), axis=1)
        flags[no_guess] |= FLAG_NO_GUESS
        q0 = np.where(np.isfinite(q_guess), q_guess, 0.0)
        vis[no_guess] = False
        Y = np.where(vis[..., None], Y, 0.0)
        return Y, q0, vis, flags, no_guess

    def _robust_stages(self, model, q0, Y, vis):
        """Stages 1 and 2 of eq. 3-5's solve: least squares on every visible marker from the
        motor angles, then, on the frames with a marker beyond the threshold, robust (Cauchy)
        IRLS, hard rejection and a least-squares polish on the inliers. Returns the solved
        angles (T, S), the model markers (T, M, 3), the inliers (T, M), the threshold (m) and
        the iterations."""
        qs = q0[:, self.joints].copy()
        # stage 1: plain least squares on every visible marker, from the motor angle (eq. 3-5)
        qs, iters = model.solve(qs, Y, vis, loss="linear", scale=1.0, max_iter=self.max_iter)
        P = model.model_markers(qs)
        res = np.where(vis, _norm3(P - Y), np.nan)
        sigma = self._noise_level(res)
        thr = max(self.reject_floor_m, self.reject_sigma * sigma)
        inl = vis & (res < thr)
        sus = (vis & ~inl).any(axis=1)
        if sus.any():
            # stage 2, frames with a suspicious marker only: robust (Cauchy) IRLS from the motor
            # angle, hard rejection at the threshold, least-squares polish on the inliers
            idx = np.flatnonzero(sus)
            q_start = q0[:, self.joints].copy()
            qr, it2 = model.solve(q_start, Y, vis, loss="cauchy", scale=self.robust_scale_m,
                                  max_iter=max(self.irls_iter, 1), frames=sus)
            res_r = _norm3(model.predict(qr[idx], idx) - Y[idx])
            inl[idx] = vis[idx] & (res_r < thr)
            qp, it3 = model.solve(qr, Y, inl, loss="linear", scale=1.0, max_iter=self.max_iter,
                                  frames=sus)
            qs[idx] = qp[idx]
            P[idx] = model.model_markers(qs, idx)
            iters += it2 + it3
        return qs, P, inl, thr, iters

    def _flag_frames(self, model, qs, inl, n_in, no_guess, flags):
        """Validity of each frame: enough markers distal to each solved joint, redundancy,
        conditioning of the final normal matrix and convergence (``flags`` updated in place).
        Returns the inverse normal matrices (T, S, S) and the bound on their condition (T,)."""
        S = len(self.joints)
        few = 3 * n_in < S + 1
        for j in self.joints:
            few |= inl[:, self.marker_joint >= j].sum(axis=1) < self.min_markers
        flags[few & ~no_guess] |= FLAG_TOO_FEW_MARKERS
        H = model.final_normal_matrix(qs, inl)
        ok_h = np.all(np.isfinite(H), axis=(1, 2)) & (n_in > 0)
        H = np.where(ok_h[:, None, None], H, np.eye(S))
        Hinv = _spd_inverse(H)
        npd = ~np.all(np.isfinite(Hinv), axis=(1, 2))
        if npd.any():  # not positive definite (a joint without markers...): LU, else pseudo-inverse
            try:
                Hinv[npd] = np.linalg.inv(H[npd])
            except np.linalg.LinAlgError:
                Hinv[npd] = np.linalg.pinv(H[npd])
        # cond(H) <= |H|_F |H^-1|_F and lambda_min(H) >= 1 / |H^-1|_F: cheap, conservative tests
        nf = np.linalg.norm(H, axis=(1, 2))
        nfi = np.linalg.norm(Hinv, axis=(1, 2))
        lever2 = np.maximum(n_in, 1) * (1e-3) ** 2  # 1 mm of lever per marker at least
        bad = ~ok_h | ~np.isfinite(nfi) | (nf * nfi > self.max_cond) | (1.0 / nfi < lever2)
        flags[bad & (n_in > 0)] |= FLAG_ILL_CONDITIONED
        flags[~model.converged] |= FLAG_NOT_CONVERGED
        return Hinv, nf * nfi

    # ------------------------------------------------------------------------------------------
    def _noise_level(self, res: np.ndarray) -> float:
        """Per-axis noise from the median residual norm (robust to outliers)."""
        r = res[np.isfinite(res)]
        if r.size == 0:
            return 0.0
        return float(np.median(r) / _CHI3_MEDIAN)

    def _repair_swaps(self, P, Y, vis, inl, thr):
        """Swap back pairs of rejected markers that fit each other's predictions."""
        rej = vis & ~inl
        touched = np.zeros(Y.shape[0], bool)
        swaps = []
        cand = np.flatnonzero(rej.any(axis=0))
        if cand.size < 2:
            return Y, inl, swaps, touched
        Y = Y.copy()
        inl = inl.copy()
        for ia, a in enumerate(cand):  # loop over marker pairs, vectorised over frames
            for b in cand[ia + 1:]:
                both = rej[:, a] & rej[:, b] & ~inl[:, a] & ~inl[:, b]
                if not both.any():
                    continue
                fit = both & (np.linalg.norm(P[:, a] - Y[:, b], axis=1) < thr) & \
                    (np.linalg.norm(P[:, b] - Y[:, a], axis=1) < thr)
                if not fit.any():
                    continue
                ya = Y[fit, a].copy()
                Y[fit, a] = Y[fit, b]
                Y[fit, b] = ya
                inl[fit, a] = True
                inl[fit, b] = True
                touched |= fit
                swaps += [(int(t), self.labels[a], self.labels[b]) for t in np.flatnonzero(fit)]
        return Y, inl, swaps, touched


def _standard_errors(res, inl, n_in, valid, Hinv, S):
    """Pooled per-axis noise ``sigma`` over the valid frames' inlier residuals ``res`` (T, M)
    (``S`` angles per frame) and the per-frame standard errors ``sigma sqrt(diag H^-1)`` (T, S),
    NaN where a frame is not valid."""
    dof = 3 * n_in[valid].sum() - S * np.count_nonzero(valid)
    ss = (np.where(inl, res, 0.0) ** 2).sum(axis=1)[valid].sum()
    sig_axis = float(np.sqrt(ss / dof)) if dof > 0 else float("nan")
    stderr = sig_axis * np.sqrt(np.maximum(np.diagonal(Hinv, axis1=1, axis2=2), 0.0))
    stderr[~valid] = np.nan
    return sig_axis, stderr


def _frames(idx: np.ndarray):
    """Sorted frame indices as a slice where they are a contiguous run (a view, no copy)."""
    if idx.size and idx[-1] - idx[0] + 1 == idx.size:
        return slice(int(idx[0]), int(idx[-1]) + 1)
    return idx


def _norm3(d: np.ndarray) -> np.ndarray:
    """Euclidean norms over the last axis of length 3 (what ``np.linalg.norm(d, axis=-1)``
    computes, several times faster on (T, M, 3) arrays)."""
    return np.sqrt(d[..., 0] * d[..., 0] + d[..., 1] * d[..., 1] + d[..., 2] * d[..., 2])


def _weights(r2: np.ndarray, mask: np.ndarray, loss: str, scale: float) -> np.ndarray:
    if loss == "cauchy":
        return mask / (1.0 + r2 / scale ** 2)
    return mask.astype(float)


def _cost(r2: np.ndarray, mask: np.ndarray, loss: str, scale: float, axis: int = 1) -> np.ndarray:
    if loss == "cauchy":
        return (np.where(mask, np.log1p(r2 / scale ** 2), 0.0) * scale ** 2).sum(axis=axis)
    return np.where(mask, r2, 0.0).sum(axis=axis)


class _SingleJoint:
    """One moving joint j: markers rotate about one fixed axis, the problem is 1-D per frame.

    In the frame of joint j at q_j = 0 a marker is at x_m (fixed by the held joints) and is
    measured at y_m; the weighted cost sum w |Rot(a, q) x - y|^2 is minimal at
    q = atan2(sum w y.(a x x), sum w y_perp.x_perp) (Rodrigues' formula; exact)."""

    def __init__(self, solver: MarkerSolver, q0: np.ndarray):
        ch = solver.chain
        j = solver.joints[0]
        self.j = j
        self.a = ch.axes[j]
        qh = q0.copy()
        qh[:, j] = 0.0
        held = np.delete(qh, j, axis=1)
        const = held.shape[1] == 0 or bool(np.all(np.ptp(held, axis=0) == 0))
        qk = qh[:1] if const else qh
        R, o = ch.joint_frames(qk)
        mj = np.clip(solver.marker_joint, 0, None)
        Pm = o[:, mj] + np.einsum("tmij,mj->tmi", R[:, mj], solver.p_joint)  # (Tk, M, 3)
        self.Rj = R[:, j]      # (Tk, 3, 3): the joint-j frame at q_j = 0 in the base frame
        self.oj = o[:, j]
        self.x = np.einsum("tji,tmj->tmi", self.Rj, Pm - self.oj[:, None, :])  # (Tk, M, 3)
        self.x_perp = self.x - self.x @ self.a[:, None] * self.a
        self.ax = np.cross(self.a, self.x)
        self.converged = np.ones(q0.shape[0], bool)
        self.q_ref = q0[:, j]
        self._Y = None
        self._y = None

    def _local(self, Y):
        if self._Y is not Y:
            self._Y = Y
            self._y = np.einsum("tji,tmj->tmi", self.Rj, Y - self.oj[:, None, :])
        return self._y

    def _rot(self, qs):
        a = self.a
        xa = (self.x @ a)[..., None] * a
        return rotate_about_axis(self.x_perp, self.ax, xa, qs)  # Rot(a, q) x, (T, M, 3)

    def predict(self, qs, idx=None):
        qs = np.asarray(qs).reshape(-1)
        x, xp, ax = self.x, self.x_perp, self.ax
        Rj, oj = self.Rj, self.oj
        if idx is not None and Rj.shape[0] > 1:
            x, xp, ax, Rj, oj = x[idx], xp[idx], ax[idx], Rj[idx], oj[idx]
        p = rotate_about_axis(xp, ax, (x @ self.a)[..., None] * self.a, qs)
        return np.einsum("tij,tmj->tmi", Rj, p) + oj[:, None, :]

    def model_markers(self, qs, idx=None):
        """Model markers (T, M, 3) at ``qs`` (T, 1), or (K, M, 3) at the frames ``idx``."""
        if idx is None:
            return self.predict(qs)
        return self.predict(np.asarray(qs).reshape(-1)[idx], idx)

    def final_normal_matrix(self, qs, mask):
        return self.normal_matrix(qs, mask)

    def solve(self, qs, Y, mask, loss, scale, max_iter, frames=None):
        y = self._local(Y)
        qs = np.asarray(qs, float).reshape(-1).copy()
        yp = y - (y @ self.a)[..., None] * self.a
        cy = np.einsum("tmi,tmi->tm", yp, np.broadcast_to(self.x_perp, y.shape))
        sy = np.einsum("tmi,tmi->tm", y, np.broadcast_to(self.ax, y.shape))
        n = 1 if loss == "linear" else max_iter
        for _ in range(n):
            if loss == "linear":
                w = mask.astype(float)
            else:
                r2 = ((self._rot(qs) - y) ** 2).sum(axis=2)
                w = _weights(r2, mask, loss, scale)
            C = (w * cy).sum(axis=1)
            Sn = (w * sy).sum(axis=1)
            qn = np.arctan2(Sn, C)
            qn = self.q_ref + (qn - self.q_ref + np.pi) % (2 * np.pi) - np.pi  # nearest the guess
            qs = np.where(w.sum(axis=1) > 0, qn, qs)
        return qs[:, None], n

    def normal_matrix(self, qs, mask):
        xp2 = np.broadcast_to((self.x_perp ** 2).sum(axis=2), mask.shape)
        return (mask * xp2).sum(axis=1)[:, None, None]


def _cholesky_solve(L: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``x`` with ``L L^T x = b`` for K factored systems, frames last: ``L`` (S, S, K) from
    :func:`_cholesky` (lower triangle), ``b`` (S, K) or (S, R, K)."""
    S = L.shape[0]
    y = np.array(b, float)

    def below(j):  # column j of L under the diagonal, shaped to broadcast against y[j + 1:]
        c = L[j + 1:, j]
        return c[:, None] if y.ndim == 3 else c

    for j in range(S):  # forward substitution, L y = b
        y[j] /= L[j, j]
        if j + 1 < S:
            y[j + 1:] -= below(j) * y[j]
    for j in reversed(range(S)):  # back substitution, L^T x = y
        if j + 1 < S:
            y[j] -= (below(j) * y[j + 1:]).sum(axis=0)
        y[j] /= L[j, j]
    return y


def _cholesky(A: np.ndarray) -> np.ndarray:
    """In-place Cholesky factor ``L`` (lower triangle; the upper one is left as is) of K
    symmetric positive-definite S x S matrices, frames last (A (S, S, K); only the lower triangle
    is read). Vectorised over frames: at S <= 7 LAPACK's per-matrix call costs more than the
    arithmetic. A matrix that is not positive definite gets NaN (its step is then rejected)."""
    S = A.shape[0]
    with np.errstate(invalid="ignore", divide="ignore"):
        for j in range(S):  # right-looking, one column at a time
            np.sqrt(A[j, j], out=A[j, j])
            if j + 1 < S:
                c = A[j + 1:, j]
                c /= A[j, j]
                A[j + 1:, j + 1:] -= c[:, None] * c[None, :]
    return A


def _spd_inverse(H: np.ndarray) -> np.ndarray:
    """Inverses of symmetric positive-definite matrices (T, S, S) -> (T, S, S) by a Cholesky
    factorisation vectorised over the matrices (NaN where one is not positive definite)."""
    S = H.shape[1]
    L = _cholesky(np.moveaxis(H, 0, 2).copy())
    eye = np.broadcast_to(np.eye(S)[:, :, None], (S, S, H.shape[0]))
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.moveaxis(_cholesky_solve(L, eye), 2, 0)


def _symmetrise_lower(H: np.ndarray) -> np.ndarray:
    """Copy the lower triangle of (S, S, K) matrices onto the upper one, in place."""
    iu, ju = np.triu_indices(H.shape[0], 1)
    H[iu, ju] = H[ju, iu]
    return H


class _Chain:
    """Several solved joints: Levenberg-Marquardt, analytic Jacobian, vectorised over frames.

    Internally the frame index is the last axis (structure of arrays: markers (3, M, K),
    twists (6, S, K), normal matrices (S, S, K)), so that every per-frame operation is a
    contiguous elementwise operation or one GEMM; the frame of the joint before the first solved
    one (held joints only) is computed once (:meth:`mocap.kinematics.Chain.joint_frames_soa`);
    the 6 x 6 systems are solved by a Cholesky factorisation vectorised over frames."""

    def __init__(self, solver: MarkerSolver, q0: np.ndarray):
        self.s = solver
        self.q0 = q0
        mj = solver.marker_joint
        J = solver.joints
        T, M, S = q0.shape[0], solver.p_joint.shape[0], len(J)
        used = mj >= J[0]
        self.first = J[0]
        self.last = int(max(J[-1], mj[used].max() if used.any() else J[-1]))
        self.solved_rows = np.array(J) - self.first
        self.held = [(j - self.first, j) for j in range(self.first, self.last + 1) if j not in J]
        self.q0T = np.ascontiguousarray(q0.T) if self.held else None
        self.F_pre = None
        if self.first > 0:  # the held part of the chain before the first solved joint, once
            R, o = solver.chain.joint_frames(q0)
            self.F_pre = np.empty((3, 4, T))
            self.F_pre[:, :3] = np.moveaxis(R[:, self.first - 1], 0, 2)
            self.F_pre[:, 3] = o[:, self.first - 1].T
        # markers grouped by the joint that carries them (one GEMM per group, [p, 1] @ [R | o])
        self.groups = []
        for jj in np.unique(mj[used]):  # loop over marked links
            sel = np.flatnonzero(mj == jj)
            if sel.size and np.all(np.diff(sel) == 1):
                sel = slice(int(sel[0]), int(sel[-1]) + 1)
            ph = np.hstack([solver.p_joint[mj == jj], np.ones((int(np.sum(mj == jj)), 1))])
            self.groups.append((int(jj) - self.first, sel, ph))
        self.unused = np.flatnonzero(~used)
        # the sums over the markers that each solved joint moves: where every link's markers are
        # a contiguous run (the usual layout) a row sum per link and a running sum from the
        # distal link (several times faster than the GEMM with the (S, M) mask at S = 6)
        self.runs = None
        if self.groups and all(isinstance(sel, slice) for _, sel, _ in self.groups):
            jjs = [row + self.first for row, _, _ in self.groups]
            self.runs = [(sel.start, sel.stop) for _, sel, _ in self.groups]
            self.run_of_joint = [next((g for g, jj in enumerate(jjs) if jj >= j), None) for j in J]
        self.P_last = np.zeros((3, M, T))
        self.H_last = np.zeros((S, S, T))
        self.has_last = np.zeros(T, bool)
        # solved joint k moves marker m iff k <= the joint carrying m
        self.mmaskT = np.ascontiguousarray((np.array(J)[None, :] <= mj[:, None]).T.astype(float))
        self.converged = np.ones(T, bool)
        self._Y = None
        self._Yc = None

    def _components(self, Y):
        """``Y`` (T, M, 3) as (3, M, T), converted once per array."""
        if self._Y is not Y:
            self._Y = Y
            self._Yc = np.ascontiguousarray(np.transpose(Y, (2, 1, 0)))
        return self._Yc

    def _eval(self, qT, idx, jac: bool):
        """Model markers P (3, M, K) and the joint twists X (6, S, K) at the solved angles
        ``qT`` (S, K) of frames ``idx``: for a marker distal to solved joint k,
        dP/dq_k = w_k x P + o_k x w_k = [-[P]x | I] X[:, k] (Plucker form)."""
        K = qT.shape[1]
        if self.held:
            ang = np.empty((self.last - self.first + 1, K))
            ang[self.solved_rows] = qT
            for row, j in self.held:  # loop over held joints inside the solved range
                ang[row] = self.q0T[j, _frames(idx)]
        else:
            ang = qT
        F_prev = None if self.F_pre is None else self.F_pre[:, :, _frames(idx)]
        F, W = self.s.chain.joint_frames_soa(ang, self.first, F_prev)
        M = self.s.p_joint.shape[0]
        P = np.empty((3, M, K))
        if self.unused.size:
            P[:, self.unused] = 0.0
        for row, sel, ph in self.groups:  # loop over marked links
            if isinstance(sel, slice):
                np.matmul(ph, F[row], out=P[:, sel])
            else:
                P[:, sel] = np.matmul(ph, F[row])
        if not jac:
            return P, None
        S = len(self.s.joints)
        X = np.empty((6, S, K))
        rows = self.solved_rows
        X[:3] = np.swapaxes(W[rows], 0, 1)                 # w_k, the axes in the base frame
        o = F[rows, :, 3]                                  # (S, 3, K) origins
        wx, wy, wz = X[0], X[1], X[2]
        np.subtract(o[:, 1] * wz, o[:, 2] * wy, out=X[3])  # v = o x w
        np.subtract(o[:, 2] * wx, o[:, 0] * wz, out=X[4])
        np.subtract(o[:, 0] * wy, o[:, 1] * wx, out=X[5])
        return P, X

    def _normal(self, P, X, r, w, hess: bool = True):
        """H = J^T W J (S, S, K) and g = J^T W r (S, K), with J_mk = w_k x P_m + v_k = A_m X_k:
        the Plucker twist X_k = (w_k, v_k = o_k x w_k) of solved joint k applied to marker m
        through A_m = [-[P_m]x | I] (zero if k does not move m). Marker m enters H_kl when both
        k and l move it, so H_kl = X_k^T C_max(k,l) X_l and g_k = X_k^T f_k with the sums over
        the markers that joint i moves (those on joint i and beyond):
        ``C_i = sum w_m A_m^T A_m = [[tr(S2) I - S2, [s1]x], [-[s1]x, s0 I]]`` (``s0 = sum w``,
        ``s1 = sum w P``, ``S2 = sum w P P^T``) and ``f_i = sum w_m A_m^T r_m = sum w (P x r, r)``:
        a 6 x 6 matrix and a wrench per joint instead of a (3M x S) Jacobian per frame (the sums
        over markers: per link, then running over the links). ``hess=False``: g only (H is
        None)."""
        M, K = w.shape
        S = X.shape[1]
        nf = 16 if hess else 6
        feat = np.empty((M, nf, K))
        Px, Py, Pz = P
        rx, ry, rz = r
        o = 10 if hess else 0           # features 0-9: H, the last 6: g
        wPx = np.multiply(w, Px, out=feat[:, 1] if hess else None)
        wPy = np.multiply(w, Py, out=feat[:, 2] if hess else None)
        wPz = np.multiply(w, Pz, out=feat[:, 3] if hess else None)
        if hess:
            feat[:, 0] = w
            np.multiply(wPx, Px, out=feat[:, 4])
            np.multiply(wPx, Py, out=feat[:, 5])
            np.multiply(wPx, Pz, out=feat[:, 6])
            np.multiply(wPy, Py, out=feat[:, 7])
            np.multiply(wPy, Pz, out=feat[:, 8])
            np.multiply(wPz, Pz, out=feat[:, 9])
        np.subtract(wPy * rz, wPz * ry, out=feat[:, o])      # w P x r
        np.subtract(wPz * rx, wPx * rz, out=feat[:, o + 1])
        np.subtract(wPx * ry, wPy * rx, out=feat[:, o + 2])
        np.multiply(w, rx, out=feat[:, o + 3])
        np.multiply(w, ry, out=feat[:, o + 4])
        np.multiply(w, rz, out=feat[:, o + 5])
        # sums over the markers each solved joint moves: per link, then from the distal link
        # back (or one matrix product with the mask)
        if self.runs is None:
            suffix = (self.mmaskT @ feat.reshape(M, nf * K)).reshape(S, nf, K)
        else:
            acc, run = [None] * len(self.runs), None
            for gi in reversed(range(len(self.runs))):  # loop over marked links
                a, b = self.runs[gi]
                part = np.add.reduce(feat[a:b], axis=0)
                run = part if run is None else np.add(run, part, out=part)
                acc[gi] = run
            suffix = np.empty((S, nf, K))
            for k, gi in enumerate(self.run_of_joint):  # loop over solved joints
                suffix[k] = 0.0 if gi is None else acc[gi]
        g = X[0] * suffix[:, o]
        for a in range(1, 6):  # g_k = X_k^T f_k
            g += X[a] * suffix[:, o + a]
        if not hess:
            return None, g
        s0 = suffix[:, 0]
        sx, sy, sz = suffix[:, 1], suffix[:, 2], suffix[:, 3]
        xx, xy, xz, yy, yz, zz = (suffix[:, i] for i in range(4, 10))
        ax, ay, az, bx, by, bz = X                         # (S, K) each: w_k, v_k
        tr = xx + yy + zz
        # Z_i = C_i X_i: top (tr S2 - S2) w + s1 x v, bottom -s1 x w + s0 v
        Z = np.empty((6, S, K))
        Z[0] = (tr - xx) * ax - xy * ay - xz * az + (sy * bz - sz * by)
        Z[1] = -xy * ax + (tr - yy) * ay - yz * az + (sz * bx - sx * bz)
        Z[2] = -xz * ax - yz * ay + (tr - zz) * az + (sx * by - sy * bx)
        Z[3] = -(sy * az - sz * ay) + s0 * bx
        Z[4] = -(sz * ax - sx * az) + s0 * by
        Z[5] = -(sx * ay - sy * ax) + s0 * bz
        # H_kl = X_l^T C_k X_k = Z_k^T X_l for k >= l: the lower triangle is H's (the upper one
        # is not, see _symmetrise_lower; the Cholesky factorisation reads the lower one only)
        return np.einsum("akt,alt->klt", Z, X), g

    def predict(self, qs, idx=None, chunk: int = 2048):
        """Model markers (K, M, 3) for ``qs`` (K, S) at frames ``idx`` (default all)."""
        idx = np.arange(qs.shape[0]) if idx is None else np.asarray(idx)
        out = np.empty((idx.size, self.s.p_joint.shape[0], 3))
        for b in np.array_split(np.arange(idx.size), max(1, -(-idx.size // chunk))):
            out[b] = np.transpose(self._eval(qs[b].T, idx[b], False)[0], (2, 1, 0))
        return out

    def model_markers(self, qs, idx=None):
        """Model markers (T, M, 3) stored at each frame's last evaluation (within ``tol`` of the
        solution: < 1 um), computed afresh where a frame was never iterated; (K, M, 3) at the
        sorted frames ``idx`` only, when given."""
        at = slice(None) if idx is None else np.asarray(idx)
        P = np.transpose(self.P_last[:, :, at], (2, 1, 0)).copy()
        fresh = ~self.has_last[at]
        if fresh.any():
            f = np.flatnonzero(fresh) if idx is None else at[fresh]
            P[fresh] = self.predict(qs[f], f)
        return P

    def final_normal_matrix(self, qs, mask):
        """J^T J (T, S, S) at the solution: the last LM iteration's (same inliers), else computed."""
        H = np.moveaxis(_symmetrise_lower(self.H_last.copy()), 2, 0).copy()
        fresh = ~self.has_last
        if fresh.any():
            H[fresh] = self.normal_matrix(qs[fresh], mask[fresh], idx=np.flatnonzero(fresh))
        return H

    def normal_matrix(self, qs, mask, chunk: int = 2048, idx=None):
        """J^T J (T, S, S) at ``qs`` (T, S) with the markers of ``mask`` (T, M)."""
        S = qs.shape[1]
        idx = np.arange(qs.shape[0]) if idx is None else np.asarray(idx)
        out = np.empty((qs.shape[0], S, S))
        for b in np.array_split(np.arange(qs.shape[0]), max(1, -(-qs.shape[0] // chunk))):
            P, X = self._eval(qs[b].T, idx[b], True)
            w = np.ascontiguousarray(mask[b].T, float)
            out[b] = np.moveaxis(_symmetrise_lower(self._normal(P, X, np.zeros_like(P), w)[0]), 2, 0)
        return out

    def solve(self, qs, Y, mask, loss, scale, max_iter, frames=None, chunk: int = 2048):
        """Levenberg-Marquardt on every frame (or ``frames``), in blocks of ``chunk`` frames
        (cache-sized temporaries); frames leave the loop as they converge."""
        qs = np.array(qs, float)
        T = qs.shape[0]
        act = np.arange(T) if frames is None else np.flatnonzero(frames)
        act = act[mask[act].any(axis=1)]
        conv = np.ones(T, bool)
        its = 0
        Yc = self._components(Y)
        maskT = np.ascontiguousarray(mask.T)
        for block in np.array_split(act, max(1, -(-act.size // chunk))):
            its = max(its, self._solve_block(qs, Yc, maskT, loss, scale, max_iter, block, conv))
        if frames is None:
            self.converged = conv
        else:
            self.converged[frames] = conv[frames]
        return qs, its

    def _solve_block(self, qs, Yc, maskT, loss, scale, max_iter, act, conv) -> int:
        """Levenberg-Marquardt on the frames ``act``; writes ``qs`` and ``conv``. A frame stops
        when its step is below ``tol``. After an accepted step below ``sqrt(tol)`` the next step
        is first estimated with the new gradient and the factor of the normal matrix just used
        (that matrix moves by O(|step|) relative, so an estimate below ``tol`` differs from the
        exact step by < tol^1.5 rad, far below the noise); the normal matrix is recomputed only
        for the frames whose estimate is not small."""
        lin = loss == "linear"
        tol = self.s.tol
        q = np.ascontiguousarray(qs[act].T)               # (S, K)
        y = Yc[:, :, _frames(act)]                         # (3, M, K)
        m = maskT[:, _frames(act)]                         # (M, K)
        P, X = self._eval(q, act, True)
        r = P - y
        r2 = r[0] * r[0] + r[1] * r[1] + r[2] * r[2]
        st = _BlockState(act=act, q=q, y=y, m=m, w=m.astype(float) if lin else None, P=P, X=X,
                         r=r, r2=r2, cost=_cost(r2, m, loss, scale, axis=0),
                         lam=np.full(act.size, 1e-6), H=None)
        conv[act] = False
        it = 0
        while st.act.size and it < max_iter:
            it += 1
            step, L = self._damped_step(st, loss, scale)
            # a step below tol (1e-6 rad: 1000x under the marker noise) is taken without
            # checking it: the frame has converged
            small = np.abs(step).max(axis=0) < tol
            if small.any():
                st.q[:, small] += step[:, small]
                self._leave(st, small, qs, conv, lin)
                keep = ~small
                st.keep(keep)
                step, L = step[:, keep], L[..., keep]
                if not st.act.size:
                    break
            done = self._accept(st, step, loss, scale)
            if lin:
                self._step_with_old_factor(st, step, L, done, tol)
            if done.any():
                self._leave(st, done, qs, conv, lin)
                st.keep(~done)
        if st.act.size:  # max_iter reached: the state so far, not converged
            qs[st.act] = st.q.T
            if lin and st.H is not None:
                self.P_last[:, :, st.act] = st.P
                self.H_last[:, :, st.act] = st.H
                self.has_last[st.act] = True
        return it

    def _damped_step(self, st, loss, scale):
        """The Levenberg-Marquardt step of every frame of ``st`` (:class:`_BlockState`; its
        normal matrix ``H`` updated): ``(H + lam (diag(H) + 1e-12)) step = -g`` by Cholesky.
        Returns the step (S, K) and the factor (S, S, K)."""
        S = st.q.shape[0]
        st.H, g = self._normal(st.P, st.X, st.r, st.w if loss == "linear"
                               else _weights(st.r2, st.m, loss, scale))
        L = st.H.copy()
        Ld = L.reshape(S * S, -1)[::S + 1]                 # the diagonal, a view
        Ld += st.lam * (Ld + 1e-12)                        # A = H + lam (diag(H) + 1e-12)
        _cholesky(L)
        return -_cholesky_solve(L, g), L

    def _accept(self, st, step, loss, scale) -> np.ndarray:
        """Take ``step`` where it lowers the cost (the damping ``lam`` down tenfold there, up
        tenfold elsewhere); returns the frames that have converged (an accepted step that no
        longer lowers the cost, or damping beyond 1e8)."""
        qn = st.q + step
        Pn, Xn = self._eval(qn, st.act, True)
        rn = Pn - st.y
        r2n = rn[0] * rn[0] + rn[1] * rn[1] + rn[2] * rn[2]
        cn = _cost(r2n, st.m, loss, scale, axis=0)
        acc = cn <= st.cost
        flat = (st.cost - cn) <= 1e-12 * st.cost + 1e-30
        st.lam = np.where(acc, np.maximum(st.lam * 0.1, 1e-12), st.lam * 10.0)
        if acc.all():                   # the usual case: take the new state whole
            st.q, st.P, st.X, st.r, st.r2, st.cost = qn, Pn, Xn, rn, r2n, cn
        else:
            st.q[:, acc] = qn[:, acc]
            st.P[..., acc], st.X[..., acc], st.r[..., acc] = Pn[..., acc], Xn[..., acc], rn[..., acc]
            st.r2[:, acc], st.cost[acc] = r2n[:, acc], cn[acc]
        st.accepted = acc
        return (acc & flat) | (st.lam > 1e8)

    def _step_with_old_factor(self, st, step, L, done, tol) -> None:
        """The next step at the new state with this iteration's factor ``L``, after an accepted
        ``step`` below sqrt(tol) (the next one is then ~|step|^2 or ~1e-3 |step|, the
        Gauss-Newton rate at this noise level): where it is below ``tol`` it is taken and the
        frame is marked ``done`` without a new J^T J (least squares only)."""
        chk = np.flatnonzero(st.accepted & ~done & (np.abs(step).max(axis=0) < np.sqrt(tol)))
        if chk.size:
            _, gq = self._normal(st.P[..., chk], st.X[..., chk], st.r[..., chk], st.w[:, chk],
                                 hess=False)
            sq = -_cholesky_solve(L[..., chk], gq)
            ok = np.abs(sq).max(axis=0) < tol
            st.q[:, chk[ok]] += sq[:, ok]
            done[chk[ok]] = True

    def _leave(self, st, sel, qs, conv, lin) -> None:
        """Frames ``sel`` (bool over the block ``st``) have converged: write their angles into
        ``qs``, mark them in ``conv`` and (least squares) keep their model markers and normal
        matrix for the final one."""
        every = bool(sel.all())     # the usual case: the whole rest of the block at once
        at = _frames(st.act) if every else st.act[sel]
        conv[at] = True
        qs[at] = (st.q if every else st.q[:, sel]).T
        if lin:
            self.P_last[:, :, at] = st.P if every else st.P[:, :, sel]
            self.H_last[:, :, at] = st.H if every else st.H[:, :, sel]
            self.has_last[at] = True


class _BlockState:
    """The per-frame state of :meth:`_Chain._solve_block` over a block of frames, the frame
    the last axis of every array: frame indices ``act`` (K,), angles ``q`` (S, K), measured
    markers ``y`` (3, M, K), mask ``m`` and weights ``w`` (M, K), model markers ``P``, twists
    ``X``, residuals ``r`` and their squares ``r2``, cost and damping ``lam`` (K,), normal
    matrices ``H`` (S, S, K), and which frames the last step was ``accepted`` on."""

    __slots__ = ("act", "q", "y", "m", "w", "P", "X", "r", "r2", "cost", "lam", "H", "accepted")

    def __init__(self, **fields):
        self.accepted = None
        for k, v in fields.items():
            setattr(self, k, v)

    def keep(self, sel) -> None:
        """Only the frames ``sel`` (bool over the block) stay."""
        for k in ("act", "q", "y", "m", "w", "P", "X", "r", "r2", "cost", "lam", "H"):
            v = getattr(self, k)
            if v is not None:
                setattr(self, k, v[..., sel])


# ---- campaign level --------------------------------------------------------------------------
@dataclass(frozen=True, eq=False)
class AnglesResult:
    """Link angles of one trial with the solve diagnostics.

    What :func:`solve_trial` returns and ``angles/<trial id>.csv`` holds (:meth:`write_csv`)
    [1]_: the per-frame solution of thesis eq. 3-5 [2]_.

    Attributes
    ----------
    trial_id : str
        The trial's id in the manifest.
    time : numpy.ndarray
        (T,) marker times (s).
    joints : tuple of int
        The trial's joints, 1-based as in the manifest.
    q_link : numpy.ndarray
        (T, S) link angles of the trial's joints (rad; NaN in flagged frames).
    q_motor : numpy.ndarray
        (T, S) the motor angles interpolated onto the marker times (the initial guess).
    rms_m : numpy.ndarray
        (T,) RMS marker residual (m).
    n_markers : numpy.ndarray
        (T,) inlier markers per frame.
    flags : numpy.ndarray
        (T,) bit field, see ``FLAG_NAMES``.
    solve : SolveResult
        The full solve.
    absent_labels : tuple of str
        Markers of the moving links missing from the marker file.
    refinement : dict or None
        Summary of the marker refinement (:func:`refine_markers`), when run.
    fixed_markers : dict or None
        Residuals of markers on links the trial does not move (a drift check).

    References
    ----------
    .. [1] jointlab data format (docs/format.md), sec. What the workbench writes.
    .. [2] PA10 thesis (seeds 002), eq. 3-5.
    """

    trial_id: str
    time: np.ndarray
    joints: tuple[int, ...]     # 1-based, as in the manifest
    q_link: np.ndarray
    q_motor: np.ndarray
    rms_m: np.ndarray
    n_markers: np.ndarray
    flags: np.ndarray
    solve: SolveResult
    absent_labels: tuple[str, ...] = ()
    refinement: dict | None = None
    fixed_markers: dict | None = None  # markers on links the trial does not move (drift check)

    @property
    def valid(self) -> np.ndarray:
        return self.solve.valid

    def to_dict(self) -> dict:
        d = {"trial": self.trial_id, "frames": int(self.time.shape[0]),
             "first_time": float(self.time[0]) if self.time.size else None,
             "last_time": float(self.time[-1]) if self.time.size else None,
             "absent_labels": list(self.absent_labels)}
        d.update(self.solve.to_dict())
        if self.refinement is not None:
            d["refinement"] = self.refinement
        if self.fixed_markers is not None:
            d["fixed_markers"] = self.fixed_markers
        bad = ~self.valid
        d["flagged_times"] = [float(t) for t in self.time[bad][:1000]]
        dq = self.q_link - self.q_motor
        d["link_minus_motor_rms_rad"] = [float(np.sqrt(np.nanmean(c ** 2))) if np.isfinite(c).any()
                                         else None for c in dq.T]
        return d

    def write_csv(self, path, overwrite: bool = False):
        """``time, q_<j>..., rms_mm, n_markers``; flagged frames have empty angle cells."""
        from pathlib import Path

        path = Path(path)
        if path.exists() and not overwrite:
            raise FileExistsError(f"{path} exists; refusing to overwrite")
        names = ["time"] + [f"q_{j}" for j in self.joints] + ["rms_mm", "n_markers"]
        data = np.column_stack([self.time, self.q_link, 1e3 * self.rms_m])
        counts = self.n_markers.astype(int).tolist()
        full = np.isfinite(data).all(axis=1).tolist()
        row = ",".join(["%.10g"] * data.shape[1]) + ",%d"     # one format per row, not per cell
        lines = [row % (*v, n) if ok else
                 ",".join("%.10g" % x if np.isfinite(x) else "" for x in v) + f",{n}"
                 for v, n, ok in zip(data.tolist(), counts, full)]
        path.parent.mkdir(parents=True, exist_ok=True)
        with open(path, "w", encoding="utf-8", newline="\n") as fh:
            fh.write(",".join(names) + "\n")
            if lines:
                fh.write("\n".join(lines) + "\n")
        return path


def motor_guess(log, time: np.ndarray, moving) -> np.ndarray:
    """Initial guess (T, n) at the marker times: moving joints' ``qm`` interpolated (NaN outside
    the log), braked joints at their median log angle over the marker span (constant)."""
    n = log.qm.shape[1]
    q = np.empty((time.shape[0], n))
    span = (log.time >= time[0]) & (log.time <= time[-1]) if time.size else np.zeros(0, bool)
    for j in range(n):  # loop over joints
        ok = np.isfinite(log.qm[:, j])
        if not ok.any():
            q[:, j] = np.nan
        elif j in moving:
            q[:, j] = np.interp(time, log.time[ok], log.qm[ok, j], left=np.nan, right=np.nan)
        else:
            sel = ok & span if (ok & span).any() else ok
            q[:, j] = np.median(log.qm[sel, j])
    return q


def held_placement(robot, trial, log, time: np.ndarray, q_guess: np.ndarray, moving) -> np.ndarray:
    """The initial guess with the braked joints at their nominal link angle.

    ``q_guess`` with each braked joint at its encoder angle less the deflection of the declared
    stiffness under the torque it carries (gravity and the coupling from the moving joints,
    payload included; :meth:`mocap.robot.Robot.held_deflection`, the spring of thesis eq. 2-1
    [1]_). A braked joint's motor is held but its link gives (``stiffness`` in the data format
    [2]_); placing its markers at the encoder angle would put that deflection into the solved
    angle of a moving joint whose axis is parallel. Unchanged when no joint declares a
    stiffness.

    Parameters
    ----------
    robot : mocap.robot.Robot or None
        The robot (None: unchanged).
    trial : mocap.io.campaign.Trial
        The trial (its payload ``load_kg`` and centre of mass).
    log : mocap.io.robotlog.RobotLog
        The trial's robot log (the moving joints' velocity and acceleration).
    time : numpy.ndarray
        (T,) marker times on the log's clock (s).
    q_guess : numpy.ndarray
        (T, n) motor angles at ``time`` (rad).
    moving : sequence of int
        The trial's moving joints, 0-based.

    Returns
    -------
    numpy.ndarray
        (T, n) ``q_guess`` with the held joints' columns corrected.

    References
    ----------
    .. [1] PA10 thesis (seeds 002), eq. 2-1.
    .. [2] jointlab data format (docs/format.md), sec. robot/drives.toml.
    """
    if robot is None or not (robot.stiffness > 0).any() or time.size == 0:
        return q_guess
    moving = list(moving)
    T, n = q_guess.shape
    qd, qdd = np.zeros((T, n)), np.zeros((T, n))
    lt = log.time
    dt = float(np.median(np.diff(lt))) if lt.size > 1 else 0.0
    for j in moving:  # loop over moving joints, vectorised over samples
        ok = np.isfinite(log.qm[:, j])
        if dt <= 0 or ok.sum() < 7:
            continue
        x = np.interp(lt, lt[ok], log.qm[ok, j])
        w = max(int(round(0.04 / dt)) | 1, 7)
        if w > x.size:
            w = x.size if x.size % 2 else x.size - 1
        qd[:, j] = np.interp(time, lt, savgol(x, w, 3, deriv=1, delta=dt))
        qdd[:, j] = np.interp(time, lt, savgol(x, w, 3, deriv=2, delta=dt))
    load = float(getattr(trial, "load_kg", 0.0) or 0.0)
    com = payload_com(trial)
    rb = robot.with_payload(load, com) if load > 0 else robot
    ok = np.all(np.isfinite(q_guess), axis=1)
    out = q_guess.copy()
    if ok.any():
        out[ok] = q_guess[ok] + rb.held_deflection(q_guess[ok], qd[ok], qdd[ok], moving)
    return out


def solve_trial(campaign, trial, references, T_camera_base=None, sink=None, robot=None,
                refine: bool = False, refine_geometry: bool = False,
                **solver_settings) -> AnglesResult:
    """Solve the link angles of one trial from its marker file and robot log.

    The per-frame minimisation of thesis eq. 3-5 [1]_ (:class:`MarkerSolver`), started from the
    motor angles. The markers are moved into the robot base frame; only markers on links moved
    by the trial's joints are used; the log's clock is ``t_marker + time_offset`` [2]_.

    Parameters
    ----------
    campaign : mocap.io.campaign.Campaign
        The loaded campaign.
    trial : mocap.io.campaign.Trial or str
        The trial or its id.
    references : mocap.references.References
        The static-pose marker references (:func:`mocap.references.build_references`).
    T_camera_base : array_like, optional
        (4, 4) base pose in the camera frame; default the one the references were built with
        (pass another only if the references were built with it too).
    sink : viz.Sink, optional
        Where to log the solve for viewing; None: nowhere.
    robot : mocap.robot.Robot, optional
        The robot; default ``campaign.load_robot()``.
    refine : bool, optional
        Re-estimate the marker positions over the trial's frames, anchored by the static poses
        (:func:`refine_markers`).
    refine_geometry : bool, optional
        Also fit small placement offsets of the moving joints (axis tilt and position).
    **solver_settings
        Keyword settings of :class:`MarkerSolver`.

    Returns
    -------
    AnglesResult
        The link angles of the trial's joints at the marker times, with diagnostics.

    Raises
    ------
    InputError
        If a link has fewer than 3 markers, no marked link moves, a marker lacks a static
        reference, none of the moving links' markers is in the marker file, or the log lacks
        a joint angle needed to place the markers.

    References
    ----------
    .. [1] PA10 thesis (seeds 002), eq. 3-3 to 3-5.
    .. [2] jointlab data format (docs/format.md), sec. campaign.toml.
    """

    if isinstance(trial, str):
        trial = campaign.trial(trial)
    robot = robot or campaign.load_robot()
    chain = robot.chain
    joints0 = tuple(sorted(j - 1 for j in trial.joints))
    T_cb = references.T_camera_base if T_camera_base is None else np.asarray(T_camera_base, float)
    link_of = campaign.link_of_label()
    used = _trial_markers(campaign, trial, chain, references, link_of, joints0)
    rec = campaign.read_markers(trial, robot)
    log = campaign.read_log(trial, robot)

    check_trial_rigid_fit(rec, log, references, robot, trial, T_cb)
    p_base, absent = _markers_in_base(rec, used, T_cb, trial.markers)
    q_guess = _trial_guess(robot, trial, log, rec.time, joints0,
                           max(chain.frames[link_of[lb]][0] for lb in used))
    fixed = _fixed_marker_check(chain, references, link_of, joints0, rec, T_cb, q_guess)
    res, refinement = _solve_markers(chain, joints0, used, references, T_cb, p_base, q_guess,
                                     refine, refine_geometry, solver_settings)
    out = AnglesResult(trial.id, rec.time, tuple(j + 1 for j in joints0), res.q[:, list(joints0)],
                       q_guess[:, list(joints0)], res.rms_m, res.n_markers, res.flags, res, absent,
                       refinement, fixed)
    if sink is not None and getattr(sink, "enabled", False):
        log_trial(sink, robot, out, p_base, q_guess, used, link_of)
    return out


def _markers_in_base(rec, used, T_cb, source):
    """The markers ``used`` of the recording ``rec`` in the base frame, (T, M, 3) with NaN where
    a marker is missing, and the labels absent from the marker file ``source`` (not all)."""
    absent = tuple(lb for lb in used if lb not in rec.labels)
    if len(absent) == len(used):
        raise InputError(f"none of the markers on the moving links ({', '.join(used[:6])}) is in the "
                         "marker file", path=source, label=used[0])
    Y = np.full((rec.n_frames, len(used), 3), np.nan)
    for k, lb in enumerate(used):  # loop over markers
        if lb in rec.labels:
            Y[:, k] = rec.positions[:, rec.labels.index(lb)]
    return apply_transform(invert_transform(T_cb), Y), absent


def _trial_markers(campaign, trial, chain, references, link_of, joints0) -> list:
    """The labels of the markers on the links the trial's joints ``joints0`` (0-based) move,
    checked: at least 3 markers per link, a marked moving link, a static reference for each."""
    for link, labels in campaign.markers.items():
        if len(labels) < 3:
            raise InputError(f"link {link!r} has {len(labels)} marker(s); at least 3 per link are "
                             "needed", path=campaign.manifest, label=link)
    used = [lb for lb in link_of if chain.frames[link_of[lb]][0] >= joints0[0]]
    if not used:
        raise InputError(f"trial {trial.id!r} moves joint(s) {list(trial.joints)} but no marked link "
                         "is moved by them", path=campaign.manifest, label=trial.id)
    norefs = [lb for lb in used if lb not in references.labels]
    if norefs:
        raise InputError(f"trial {trial.id!r}: marker {norefs[0]!r} has no static reference (it is "
                         "not in the static pose)", path=campaign.manifest, label=norefs[0])
    return used


def _solve_markers(chain, joints0, used, references, T_cb, p_base, q_guess, refine,
                   refine_geometry, solver_settings):
    """The angles of the joints ``joints0`` from the markers ``used`` (``p_base`` (T, M, 3) in
    the base frame): one :class:`MarkerSolver` fit, or with ``refine``/``refine_geometry`` the
    refinement anchored by the static poses (:func:`refine_markers`). Returns the
    :class:`SolveResult` and the refinement's summary (None without)."""
    mj, pj = references.for_chain(chain, used)
    if not (refine or refine_geometry):
        return MarkerSolver(chain, joints0, mj, pj, labels=used, **solver_settings).fit(p_base, q_guess), None
    T_bc = invert_transform(T_cb)
    ri = [references.index(lb) for lb in used]
    static = [(p.q, apply_transform(T_bc, p.p_camera[ri]), p.n_frames[ri].astype(float))
              for p in references.poses]
    rr = refine_markers(chain, joints0, mj, pj, p_base, q_guess, static=static, labels=used,
                        geometry=refine_geometry, **solver_settings)
    refinement = {k: v for k, v in rr.to_dict().items() if k != "solve"}
    refinement["labels"] = list(used)
    return rr.solve, refinement


def _trial_guess(robot, trial, log, t_marker, joints0, deepest) -> np.ndarray:
    """The start of eq. 3-5 at the marker times ``t_marker``: the motor angles of the solved
    joints ``joints0`` and the held placement of the others (FORMAT.md: ``t_robot = t_marker +
    time_offset``); every joint up to ``deepest`` (the deepest marked joint) needs angles."""
    offset = float(getattr(trial, "extra", {}).get("time_offset", 0.0))
    q_guess = motor_guess(log, t_marker + offset, joints0)
    q_guess = held_placement(robot, trial, log, t_marker + offset, q_guess, joints0)
    lost = [j for j in range(deepest + 1) if not np.isfinite(log.qm[:, j]).any()]
    if lost:   # a braked joint without angles would flag every frame
        raise InputError(f"no qm_{lost[0] + 1} values: trial {trial.id!r} needs joint {lost[0] + 1}'s "
                         "angle to place its markers", path=log.source, line=1, label=f"qm_{lost[0] + 1}")
    return q_guess


def _fixed_marker_check(chain, references, link_of, joints0, rec, T_cb, q_guess):
    """Markers on links the trial does not move must stay at their static reference: their RMS
    distance from it (base frame, held angles; distances of 10 mm or more counted in ``far_frac``)
    checks the camera pose and that nothing was bumped."""
    labels = [lb for lb in link_of if chain.frames[link_of[lb]][0] < joints0[0]
              and lb in rec.labels and lb in references.labels]
    if not labels or rec.n_frames == 0:
        return None
    q_held = np.nanmedian(q_guess, axis=0)
    if not np.all(np.isfinite(q_held)):
        return None
    mj, pj = references.for_chain(chain, labels)
    R, o = chain.joint_frames(q_held[None])
    jj = np.clip(mj, 0, None)
    pred = np.where((mj >= 0)[:, None], o[0, jj] + np.einsum("mij,mj->mi", R[0, jj], pj), pj)
    meas = apply_transform(invert_transform(T_cb),
                           rec.positions[:, [rec.labels.index(lb) for lb in labels]])
    d = np.linalg.norm(meas - pred, axis=2)
    fin = np.isfinite(d)
    near = fin & (d < 0.01)  # gross outliers (>= 10 mm) are counted, not averaged
    per = {lb: (float(1e3 * np.sqrt(np.mean(d[near[:, k], k] ** 2))) if near[:, k].any() else None)
           for k, lb in enumerate(labels)}
    return {"rms_mm": float(1e3 * np.sqrt(np.mean(d[near] ** 2))) if near.any() else None,
            "median_mm": float(1e3 * np.median(d[fin])) if fin.any() else None,
            "far_frac": float(np.mean(~near[fin])) if fin.any() else None,
            "per_marker_rms_mm": per}


def log_trial(sink, robot, result: AnglesResult, p_base, q_guess, labels, link_of) -> None:
    """Rerun view of a solved trial: measured vs model markers, residuals, link frames."""
    base = f"trials/{result.trial_id}"
    t = result.time
    if t.size == 0:
        return
    sink.points_over_time(f"world/{base}/markers_measured", t, p_base, labels=list(labels),
                          colors=(0.9, 0.2, 0.2), radii=0.006)
    model = result.solve.model_markers
    if model is not None:
        mm = np.where(result.valid[:, None, None], model, np.nan)
        sink.points_over_time(f"world/{base}/markers_model", t, mm, labels=list(labels),
                              colors=(0.2, 0.8, 0.2), radii=0.004)
    sink.scalars(f"{base}/residual_rms_mm", t, 1e3 * result.rms_m)
    sink.scalars(f"{base}/n_markers", t, result.n_markers.astype(float))
    for k, j in enumerate(result.joints):
        sink.scalars(f"{base}/q_{j}", t, np.column_stack([result.q_link[:, k], result.q_motor[:, k]]),
                     names=["link", "motor"])
    q = np.where(np.isfinite(result.solve.q), result.solve.q, q_guess)
    q = np.where(np.isfinite(q), q, 0.0)
    for link in sorted(set(link_of.values())):
        j, _ = robot.chain.frames[link]
        if j >= min(result.joints) - 1:
            sink.transforms_over_time(f"world/{base}/links/{link}", t, robot.chain.frame_transform(link, q))


# ---- refinement over many frames (the thesis's suggestion after eq. 3-5) ----------------------
@dataclass(frozen=True, eq=False)
class RefineResult:
    """Marker positions (and optionally joint-placement offsets) re-estimated together with the
    angles over all frames of a trial."""

    p_joint: np.ndarray           # (M, 3) refined, in the frame of each marker's joint
    p_joint_initial: np.ndarray   # (M, 3) the static-pose references it started from
    solve: SolveResult            # the final per-frame solve with the refined model
    rms_history_m: tuple          # RMS residual after each outer iteration
    shift_m: np.ndarray           # (M,) how far each marker moved
    offsets: np.ndarray | None = None  # (S, 4) per solved joint: tilt about e1, e2 (rad), shift along e1, e2 (m)
    chain: object = None          # the chain with the offsets applied

    def to_dict(self) -> dict:
        d = {"iterations": len(self.rms_history_m),
             "rms_history_mm": [float(1e3 * x) for x in self.rms_history_m],
             "marker_shift_mm": [float(1e3 * x) for x in self.shift_m],
             "solve": self.solve.to_dict()}
        if self.offsets is not None:
            d["joint_offsets"] = {str(j + 1): {"tilt_deg": [float(np.degrees(x)) for x in o[:2]],
                                               "shift_mm": [float(1e3 * x) for x in o[2:]]}
                                  for j, o in zip(self.solve.joints, self.offsets)}
        return d


def offset_chain(chain, joints, offsets):
    """A copy of ``chain`` whose solved joints' placements are corrected by ``offsets`` (S, 4):
    the joint frame tilted about the two directions e1, e2 perpendicular to its axis and shifted
    along them (the 4 placement errors that markers on the link cannot absorb)."""
    Tp = np.array(chain.T_parent_joint, float)
    for k, j in enumerate(joints):  # loop over solved joints
        e1, e2 = perp_basis(chain.axes[j])
        d = np.asarray(offsets[k], float)
        R = rotation_about_axis(e1, d[0]) @ rotation_about_axis(e2, d[1])
        Tp[j] = Tp[j] @ make_transform(R, d[2] * e1 + d[3] * e2)
    return Chain(Tp, chain.axes, chain.joint_names, chain.frames)


def _static_model(chain, mj, p_joint, q_s):
    R, o = chain.joint_frames(np.asarray(q_s, float)[None])
    jj = np.clip(mj, 0, None)
    return o[0, jj] + np.einsum("mij,mj->mi", R[0, jj], p_joint)


def _marker_update(chain, joints, mj, p_joint, res, Yb, static):
    """One closed-form update of the marker references ``p_joint`` (M, 3): eq. 3-4 averaged
    over the valid frames of the solve ``res`` (inliers of ``Yb`` back-projected into each
    marker's joint frame, ``R^T (y - o)``) and over the ``static`` poses (their weights); markers
    the solved ``joints`` do not move keep their references."""
    jj = np.clip(mj, 0, None)
    ok = res.valid
    R, o = chain.joint_frames(res.q[ok])
    y = np.where(res.inlier[ok][..., None], Yb[ok], 0.0)
    loc = np.einsum("tmji,tmj->tmi", R[:, jj], y - o[:, jj])  # back-projected: R^T (y - o)
    w = res.inlier[ok].astype(float)
    num = (loc * w[..., None]).sum(axis=0)
    den = w.sum(axis=0)
    for q_s, p_s, w_s in static:  # loop over static poses
        Rs, os_ = chain.joint_frames(np.asarray(q_s, float)[None])
        ps = np.asarray(p_s, float)
        fin = np.all(np.isfinite(ps), axis=1)
        ls = np.einsum("mji,mj->mi", Rs[0, jj], np.where(fin[:, None], ps, 0.0) - os_[0, jj])
        ws = np.where(fin, np.asarray(w_s, float), 0.0)
        num += ls * ws[:, None]
        den += ws
    used = (den > 0) & (mj >= joints[0])
    p_joint = p_joint.copy()
    p_joint[used] = num[used] / den[used, None]
    return p_joint


def _unpack_geometry(x, p_joint, free, S):
    """The geometry fit's vector ``x`` as ``(offsets (S, 4), p_joint (M, 3))``: the offsets first,
    then the free markers' positions (the others from ``p_joint``)."""
    pj = p_joint.copy()
    pj[free] = x[4 * S:].reshape(-1, 3)
    return x[:4 * S].reshape(S, 4), pj


def _geometry_residuals(x, chain, joints, mj, p_joint, free, qg, Ysub, msub, anchors, sig,
                        solver_settings):
    """Residuals of the geometry fit at ``x`` (:func:`_unpack_geometry`): the trial frames'
    marker residuals with the angles re-solved on the offset chain (variable projection), the
    static poses' at their known angles ``anchors`` (weighted), and a weak prior that keeps the
    offsets small (``sig`` the noise, 0.05 the prior's scale)."""
    S = len(joints)
    off, pj = _unpack_geometry(x, p_joint, free, S)
    c2 = offset_chain(chain, joints, off)
    sv = MarkerSolver(c2, joints, mj, pj, **solver_settings)
    model = _SingleJoint(sv, qg) if S == 1 and sv.closed_form else _Chain(sv, qg)
    qs, _ = model.solve(qg[:, list(joints)].copy(), Ysub, msub, loss="linear", scale=1.0,
                        max_iter=sv.max_iter)
    out = [np.where(msub[..., None], model.predict(qs) - Ysub, 0.0).ravel()]
    for q_s, p_s, w_s in anchors:  # static poses: known angles
        fin = np.all(np.isfinite(p_s), axis=1) & (mj >= joints[0])
        d = _static_model(c2, mj, pj, q_s) - np.where(fin[:, None], p_s, 0.0)
        out.append((np.where(fin[:, None], d, 0.0) * np.sqrt(w_s)[:, None]).ravel())
    out.append(sig * x[:4 * S] / 0.05)  # weak prior: offsets are small (bounds gauges)
    return np.concatenate(out)


def _geometry_fit(chain, joints, mj, p_joint, Yb, q_guess, res, static, max_frames, max_nfev,
                  solver_settings):
    """Joint least squares over the placement offsets of the solved joints and the marker
    positions, the angles re-solved inside every evaluation (variable projection), on at most
    ``max_frames`` valid frames of the solve ``res``. Returns ``(offsets (S, 4), p_joint)``."""
    from scipy.optimize import least_squares

    sub = np.flatnonzero(res.valid)
    if sub.size:
        sub = sub[np.linspace(0, sub.size - 1, min(max_frames, sub.size)).astype(int)]
    Ysub = np.where(res.inlier[sub][..., None], Yb[sub], 0.0)
    msub = res.inlier[sub]
    qg = q_guess[sub]
    sig = res.sigma_m if np.isfinite(res.sigma_m) and res.sigma_m > 0 else 1e-3
    anchors = [(q_s, np.asarray(p_s, float), np.asarray(w_s, float)) for q_s, p_s, w_s in static]
    free = np.flatnonzero(mj >= joints[0])
    x0 = np.concatenate([np.zeros(4 * len(joints)), p_joint[free].ravel()])
    sol = least_squares(_geometry_residuals, x0, method="trf", x_scale=1e-3, diff_step=1e-5,
                        max_nfev=max_nfev, args=(chain, joints, mj, p_joint, free, qg, Ysub, msub,
                                                 anchors, sig, solver_settings))
    return _unpack_geometry(sol.x, p_joint, free, len(joints))


def refine_markers(chain, joints, marker_joint, p_joint, p_base, q_guess, static=(),
                   iterations: int = 4, labels=None, geometry: bool = False,
                   max_frames: int = 1500, max_nfev: int = 8, **solver_settings) -> RefineResult:
    """Re-estimate the marker references together with the angles over a trial's frames.

    Alternates the batched angle solve (thesis eq. 3-5 [1]_) with the closed-form update of
    every marker's position in its link frame (eq. 3-4 averaged over all trial frames, inliers
    only); then, with ``geometry``, a joint least-squares fit of small placement offsets of the
    solved joints (axis tilt and position, :func:`offset_chain`) and the marker positions, the
    angles re-solved inside every evaluation (variable projection [2]_, on at most
    ``max_frames`` frames; finite-difference Jacobian, so this costs ~(4 S + 3 M) batched
    solves per iteration). The static poses anchor the gauge (a rotation of a link's markers
    about the joint axis is otherwise indistinguishable from an angle offset).

    Parameters
    ----------
    chain : mocap.kinematics.Chain
        The kinematic chain.
    joints : sequence of int
        Solved joints, 0-based.
    marker_joint : array_like
        (M,) the joint carrying each marker (-1: the base).
    p_joint : array_like
        (M, 3) starting references in the frame of each marker's joint (m).
    p_base : numpy.ndarray
        (T, M, 3) measured markers in the base frame (m; NaN: missing).
    q_guess : numpy.ndarray
        (T, n) initial and held angles (rad).
    static : sequence of tuple, optional
        ``(q (n,), p_base (M, 3), weight (M,))`` per static pose, with its known encoder
        angles.
    iterations : int, optional
        Outer iterations (default 4).
    labels : sequence of str, optional
        Marker labels (for reports).
    geometry : bool, optional
        Also fit the joint placement offsets.
    max_frames : int, optional
        Frames used by the geometry fit, at most.
    max_nfev : int, optional
        Function evaluations of the geometry fit per iteration.
    **solver_settings
        Keyword settings of :class:`MarkerSolver`.

    Returns
    -------
    RefineResult
        The refined references, offsets and the final solve.

    References
    ----------
    .. [1] PA10 thesis (seeds 002), eq. 3-4, 3-5.
    .. [2] Golub & Pereyra 1973, variable projection.
    """
    joints = tuple(sorted(int(j) for j in joints))
    p_joint = np.asarray(p_joint, float).copy()
    p0 = p_joint.copy()
    mj = np.asarray(marker_joint, int)
    Yb = np.asarray(p_base, float)
    offsets = np.zeros((len(joints), 4))
    ch = chain
    hist = []
    res = None
    for _ in range(iterations):  # outer alternation, a handful of passes
        res = MarkerSolver(ch, joints, mj, p_joint, labels=labels, **solver_settings).fit(Yb, q_guess)
        hist.append(float(np.sqrt(np.nanmean(res.rms_m ** 2))))
        p_joint = _marker_update(ch, joints, mj, p_joint, res, Yb, static)
    if geometry:
        offsets, p_joint = _geometry_fit(chain, joints, mj, p_joint, Yb, q_guess, res, static,
                                         max_frames, max_nfev, solver_settings)
        ch = offset_chain(chain, joints, offsets)
    res = MarkerSolver(ch, joints, mj, p_joint, labels=labels, **solver_settings).fit(Yb, q_guess)
    hist.append(float(np.sqrt(np.nanmean(res.rms_m ** 2))))
    return RefineResult(p_joint, p0, res, tuple(hist), np.linalg.norm(p_joint - p0, axis=1),
                        offsets if geometry else None, ch)
