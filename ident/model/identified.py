"""The identified rigid body of continuous multi-joint records: the nominal the gap diagnosis
measures a record against, and the payload's inertial parameters.

A record in which every joint moves (an identification experiment) determines the arm's base
inertial parameters, so the nominal is the identified model rather than the URDF with a few
corrections: each joint's torque row of the regressor ``tau = Y(q, qd, qdd) pi`` (thesis eq. 2-1,
:class:`ident.model.regressor.ChainDynamics`) enters the nominal with free amplitudes, fitted on
the training folds like every other nominal column. The URDF's torque stays the reference the
columns correct (``tau_urdf``), so a campaign with few samples keeps the URDF's values where the
data say nothing.

A payload (FORMAT.md ``load_kg``, ``payload_com``) is a body attached to the flange: its mass is
as declared; a declared ``payload_com`` fixes its centre of mass (a point mass there); a COM
that is ``"unknown"`` or absent frees the payload's first moments and inertia about the flange
joint (the last nine of the flange body's ten standard parameters, on the records that carry that
payload, shared across them): the payload's torque is then identified on every joint, which the
single-joint ``[qdd, sin q, cos q]`` corrections cannot represent on a 6-axis arm.
"""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from scipy.linalg import qr

from ident.gap.candidates import ssign
from mocap.io.payload import payload_com, payload_com_unknown

#: names of the payload's free parameters (standard parameters of the flange body less the mass)
PAYLOAD_PARAMS = ("mcx", "mcy", "mcz", "Ixx", "Ixy", "Iyy", "Ixz", "Iyz", "Izz")


def payload_declared(trial) -> bool:
    """Whether a loaded trial declares its payload's centre of mass (a value, not ``"unknown"``
    and not absent)."""
    v = (getattr(trial, "extra", None) or {}).get("payload_com")
    return v is not None and not payload_com_unknown(trial)


def payload_key(trial):
    """The payload a trial carries, as a key shared by the records that carry the same one (its
    mass, rounded to the gram), or None when unloaded or its COM is declared (nothing free)."""
    m = float(getattr(trial, "load_kg", 0.0) or 0.0)
    if m <= 0 or payload_declared(trial):
        return None
    return round(m, 3)


@dataclass(frozen=True, eq=False)
class RecordRigidBody:
    """One record's rigid-body terms: ``tau_fixed`` (T, n), the URDF's inverse dynamics with the
    declared payload mass (at its declared COM, or the flange origin); ``Y`` (T, n, 10 n) the
    regressor of the arm's standard parameters; ``payload`` (T, n, 9) the regressor of the free
    payload parameters (zeros when none), and its key."""

    tau_fixed: np.ndarray
    Y: np.ndarray
    payload: np.ndarray | None
    payload_key: object
    flange_joint: int                 # 0-based joint the payload body is attached to


def record_rigid_body(robot, chain, q, qd, qdd, trial) -> RecordRigidBody:
    """The rigid-body terms of one record (see :class:`RecordRigidBody`).

    Parameters
    ----------
    robot : mocap.robot.Robot
        The campaign's robot (without payload).
    chain : ident.model.regressor.ChainDynamics
        ``ChainDynamics.from_model(robot.model)``.
    q, qd, qdd : numpy.ndarray
        (T, n) states of the record, URDF coordinates.
    trial : mocap.io.campaign.Trial
        The record's trial (``load_kg``, ``payload_com``).
    """
    m = float(getattr(trial, "load_kg", 0.0) or 0.0)
    rb = robot.with_payload(m, payload_com(trial)) if m > 0 else robot
    tau_fixed = rb.rnea(q, qd, qdd)
    Y = chain.regressor(q, qd, qdd)
    jp, _ = robot.chain.frames[robot.tip_link]
    key = payload_key(trial)
    P = Y[:, :, 10 * jp + 1:10 * jp + 10].copy() if key is not None else None
    return RecordRigidBody(tau_fixed, Y, P, key, int(jp))


def joint_rigid_columns(parts: list, j0: int, keys: list) -> tuple[np.ndarray, list]:
    """Joint ``j0``'s free rigid-body columns over the records ``parts`` (each ``(Y_j, P_j, key)``
    with ``Y_j`` (N_r, 10 n) its regressor row on the kept samples, ``P_j`` (N_r, 9) or None its
    payload row): the arm's standard parameters, then nine per payload key in ``keys`` (zero on the
    records without that payload). Returns (N, k) stacked over the records and the names."""
    n10 = parts[0][0].shape[1]
    names = [f"pi_{i // 10 + 1}_{('m', 'mcx', 'mcy', 'mcz', 'Ixx', 'Ixy', 'Iyy', 'Ixz', 'Iyz', 'Izz')[i % 10]}"
             for i in range(n10)]
    names += [f"payload_{k}kg_{p}" for k in keys for p in PAYLOAD_PARAMS]
    rows = []
    for Yj, Pj, key in parts:
        blocks = [Yj]
        for k in keys:
            blocks.append(Pj if (Pj is not None and key == k) else np.zeros((Yj.shape[0], 9)))
        rows.append(np.column_stack(blocks))
    return np.concatenate(rows), names


def independent_columns(A: np.ndarray, tol: float = 1e-7, max_rows: int = 6000) -> np.ndarray:
    """Indices of a maximal set of linearly independent columns of ``A`` (N, k): QR with column
    pivoting of the unit-RMS columns on at most ``max_rows`` evenly spaced rows (Gautier's
    numerical base parameters, on the record's own states); columns whose RMS is below ``tol``
    times the largest are dropped first."""
    if A.shape[1] == 0:
        return np.zeros(0, int)
    step = max(1, A.shape[0] // max_rows)
    S = A[::step]
    rms = np.sqrt(np.mean(S ** 2, axis=0))
    live = np.flatnonzero(rms > tol * max(float(rms.max()), 1e-300))
    if live.size == 0:
        return live
    _, R, piv = qr(S[:, live] / rms[live], mode="economic", pivoting=True)
    d = np.abs(np.diag(R))
    r = int(np.sum(d > tol * max(d[0], 1e-300)))
    return np.sort(live[piv[:r]])


@dataclass(frozen=True, eq=False)
class PooledRigidBody:
    """The rigid body identified on every joint of every record at once (weighted least squares
    of the joints' torques on the shared inertial parameters, :func:`identify_rigid_body`).

    ``torque[k]`` (T_k, n): record ``k``'s identified rigid-body torque (the URDF's with the
    declared payload, corrected by the fitted parameters; friction, offsets and armatures left
    out). ``payload``: per free payload key, its identified centre of mass in the flange frame
    (m) with standard errors and its inertia about that centre in the flange frame (kg m^2; the
    standard errors of the free inertia parameters beside it), or a note."""

    torque: list
    names: tuple
    theta: np.ndarray
    stderr: np.ndarray
    sigma: np.ndarray               # (n,) per-joint residual RMS (the weights' noise)
    payload: dict
    n_samples: int
    design: Callable | None = None          # (k, j, rows) -> (rows, p_live) scaled design rows
    gram_inv: np.ndarray | None = None      # (p_live, p_live) inverse of the weighted Gram matrix
    weight_sigma: np.ndarray | None = None  # (n,) the per-joint noise the Gram matrix was weighted by

    def nuisance(self, k: int, j: int, rows: np.ndarray) -> tuple | None:
        """The weighted least-squares projection onto the identified parameters for joint ``j``
        (0-based) of record ``k`` at the samples ``rows``: ``(A, M)`` with ``A`` the design rows and
        ``M = G^{-1} / sigma_j^2``, so that a column ``x`` of that joint's torque less what the
        pooled fit would absorb of it is ``x - A M A^T x`` (Frisch-Waugh-Lovell: testing ``x``
        against the pooled fit's residual is then the joint fit of ``x`` with every identified
        parameter, restricted to joint ``j``'s rows). None where the fit kept no design."""
        if self.design is None or self.gram_inv is None:
            return None
        return self.design(k, j, np.asarray(rows)), self.gram_inv / self.weight_sigma[j] ** 2


def identify_rigid_body(robot, rigid: list, records: list, keeps: list, armature=None) -> PooledRigidBody:
    """Identify the arm's inertial parameters and any free payload on every joint at once.

    The torque of joint ``j`` of record ``k``, less the URDF's with the declared payload
    (``rigid[k].tau_fixed``) and the drive's motor inertia (``armature``), is

    .. math::

        \\tau_j - \\tau_{j,\\mathrm{URDF}} = Y_j \\,\\Delta\\pi + P_j\\, \\theta_{payload}
            + c_j\\, \\mathrm{sgn}(\\dot q_j) + b_j \\dot q_j + o_j + a_j \\ddot q_j

    (thesis eq. 2-1 with Coulomb + viscous friction eq. 2-5): ``Y_j`` the regressor row of the
    arm's standard parameters, ``P_j`` that of the free payload parameters (on the records that
    carry it), per-joint friction, offset and armature. The columns that the records determine
    are chosen by QR with pivoting (:func:`independent_columns`); weighted least squares with
    each joint's residual variance (two passes) gives the parameters and their covariance.

    Parameters
    ----------
    robot : mocap.robot.Robot
        The campaign's robot.
    rigid : list of RecordRigidBody
        Each record's rigid-body terms (:func:`record_rigid_body`).
    records : list
        Each record's ``(qd, qdd, tau)``, (T, n) URDF coordinates.
    keeps : list
        Each record's (T, n) mask of the samples of each joint that enter the fit (moving).
    armature : array_like, optional
        (n,) the drives' motor inertia at the link (subtracted).
    """
    n = robot.n
    arm = np.zeros(n) if armature is None else np.asarray(armature, float)
    keys = sorted({r.payload_key for r in rigid if r.payload_key is not None})
    n10 = 10 * n
    n_shared = n10 + 9 * len(keys)
    p = n_shared + 4 * n

    def design(k, j, rows):
        rb = rigid[k]
        qd, qdd, tau = records[k]
        Yj, _ = joint_rigid_columns([(rb.Y[rows, j, :], None if rb.payload is None else rb.payload[rows, j, :],
                                      rb.payload_key)], j, keys)
        A = np.zeros((rows.size, p))
        A[:, :n_shared] = Yj
        A[:, n_shared + 4 * j:n_shared + 4 * j + 4] = np.column_stack(
            [ssign(qd[rows, j]), qd[rows, j], np.ones(rows.size), qdd[rows, j]])
        y = tau[rows, j] - arm[j] * qdd[rows, j] - rb.tau_fixed[rows, j]
        return A, y

    blocks = [(k, j, np.flatnonzero(keeps[k][:, j])) for k in range(len(rigid)) for j in range(n)
              if keeps[k][:, j].sum() > 10]
    # the columns the records determine: QR with pivoting on evenly thinned rows of every block
    sample = [design(k, j, rows[::max(1, rows.size // 1500)])[0] for k, j, rows in blocks]
    S = np.concatenate(sample) if sample else np.zeros((0, p))
    live = independent_columns(S, tol=1e-6, max_rows=S.shape[0] + 1)
    scale = np.sqrt(np.mean(S[:, live] ** 2, axis=0))
    scale[scale <= 0] = 1.0
    # per (record, joint) block: its Gram matrix, moment and energy (built once; the weights of
    # the two passes only scale them)
    grams = []
    for k, j, rows in blocks:   # loop over (record, joint) blocks, vectorised over samples
        A, y = design(k, j, rows)
        A = A[:, live] / scale
        grams.append((j, A.T @ A, A.T @ y, float(y @ y), rows.size))
    sigma = np.ones(n)
    for _ in range(2):   # unweighted, then weighted by each joint's residual variance
        sigma_w = sigma.copy()
        G = sum(g / sigma[j] ** 2 for j, g, _, _, _ in grams)
        b = sum(v / sigma[j] ** 2 for j, _, v, _, _ in grams)
        lam = 1e-10 * np.trace(G) / max(G.shape[0], 1)
        Gi = np.linalg.pinv(G + lam * np.eye(G.shape[0]))
        th = Gi @ b
        sse, cnt = np.zeros(n), np.zeros(n)
        for j, g, v, yy, m in grams:
            sse[j] += max(yy - 2 * th @ v + th @ g @ th, 0.0)
            cnt[j] += m
        sigma = np.where(cnt > 0, np.sqrt(sse / np.maximum(cnt, 1)), 1.0)
    theta = np.zeros(p)
    theta[live] = th / scale
    se = np.full(p, np.nan)
    se[live] = np.sqrt(np.maximum(np.diag(Gi), 0.0)) / scale
    cov = np.zeros((p, p))
    cov[np.ix_(live, live)] = Gi / np.outer(scale, scale)
    torque = []
    for k, rb in enumerate(rigid):
        tau_k = rb.tau_fixed + np.einsum("tji,i->tj", rb.Y, theta[:n10])
        if rb.payload is not None:
            g = keys.index(rb.payload_key)
            tau_k = tau_k + np.einsum("tji,i->tj", rb.payload, theta[n10 + 9 * g:n10 + 9 * g + 9])
        torque.append(tau_k)
    payload = {}
    jp = rigid[0].flange_joint if rigid else n - 1
    _, T_jf = robot.chain.frames[robot.tip_link]
    R = np.asarray(T_jf)[:3, :3]
    for g, key in enumerate(keys):
        idx = np.arange(n10 + 9 * g, n10 + 9 * g + 9)
        ok = np.isin(idx, live)
        m = float(key)
        entry = {"mass_kg": m, "records": [k for k, rb in enumerate(rigid) if rb.payload_key == key]}
        if not ok[:3].all():
            entry["note"] = ("the payload's centre of mass is not separable from the flange link's on these "
                             "records (record the same motion without the payload too)")
        else:
            C = cov[np.ix_(idx[:3], idx[:3])]
            com = R.T @ theta[idx[:3]] / m
            entry["com_flange_m"] = com.tolist()
            entry["com_stderr_m"] = (np.sqrt(np.maximum(np.diag(R.T @ C @ R), 0.0)) / m).tolist()
        if ok.all():
            # the free parameters are the payload's beyond a point mass at the flange origin: its
            # inertia about its own centre of mass, in the flange frame, by the parallel-axis theorem
            t = np.asarray(T_jf)[:3, 3]
            c = t + theta[idx[:3]] / m                          # COM in the joint frame
            xx, xy, yy, xz, yz, zz = theta[idx[3:]]
            I_excess = np.array([[xx, xy, xz], [xy, yy, yz], [xz, yz, zz]])
            I_origin = m * (t @ t * np.eye(3) - np.outer(t, t)) + I_excess
            I_com = R.T @ (I_origin - m * (c @ c * np.eye(3) - np.outer(c, c))) @ R
            entry["inertia_about_com_flange"] = I_com.tolist()
            entry["inertia_excess_stderr"] = dict(zip(PAYLOAD_PARAMS[3:], se[idx[3:]].tolist()))
        payload[key] = entry
    names = tuple(joint_rigid_columns([(np.zeros((1, n10)), None, None)], 0, keys)[1]) + tuple(
        f"{x}_{j + 1}" for j in range(n) for x in ("coulomb", "viscous", "offset", "armature"))
    def scaled_design(k, j, rows):
        return design(k, j, rows)[0][:, live] / scale

    return PooledRigidBody(torque, names, theta, se, sigma, payload, int(sum(r.size for _, _, r in blocks)),
                           scaled_design, Gi, sigma_w)
