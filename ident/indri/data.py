"""The Indri & Trapani 2020 framework's data (paper 001): residual torques
``tau_res = tau_m - tau_dm`` (eq. 25-26) from pinocchio's inverse dynamics without friction, for
one joint moving alone (exact and vectorised, through
:meth:`mocap.robot.Robot.single_joint_dynamics`) or several joints (RNEA), as
:class:`ident.friction.data.FrictionData`; the steady samples of step 1 and the joining of
step-1 acquisitions."""
from __future__ import annotations

import numpy as np

from ident.friction.data import FrictionData

__all__ = ["residual_torques", "friction_data_from_signals", "steady_mask", "concat_data"]


def residual_torques(robot, q, qd, qdd, tau_m, *, joint: int | None = None,
                     still_tol: float = 1e-9) -> np.ndarray:
    """Indri & Trapani eq. 25-26: ``tau_res = tau_m - tau_dm``, ``tau_dm = M(q) qdd + C(q, qd) qd
    + g(q)`` from the URDF without friction (link side: the gear ratio ``K_tr`` of eq. 26 is
    already folded into ``tau_m``, FORMAT.md).

    ``q``, ``qd``, ``qdd``, ``tau_m``: (T, n). With ``joint`` (0-based) returns that joint's
    (T,) residual; when every other joint is still (its q varies less than ``still_tol`` and
    its qd, qdd are within ``still_tol``) the exact single-joint form ``I qdd + a sin q + b cos q``
    is used (vectorised; Coriolis and centrifugal terms on the moving joint vanish), otherwise
    pinocchio's RNEA. Without ``joint``: the full (T, n) residual by RNEA.
    """
    q, qd, qdd, tau_m = (np.atleast_2d(np.asarray(a, float)) for a in (q, qd, qdd, tau_m))
    n = robot.n
    for name, a in (("q", q), ("qd", qd), ("qdd", qdd), ("tau_m", tau_m)):
        if a.ndim != 2 or a.shape[1] != n or a.shape[0] != q.shape[0]:
            raise ValueError(f"residual_torques: {name} must be (T, {n}) with T = {q.shape[0]}, "
                             f"got {a.shape}")
    if joint is not None:
        if not 0 <= joint < n:
            raise ValueError(f"residual_torques: joint must be in 0..{n - 1}, got {joint}")
        others = np.arange(n) != joint
        still = (np.all(np.ptp(q[:, others], axis=0) <= still_tol)
                 and np.all(np.abs(qd[:, others]) <= still_tol)
                 and np.all(np.abs(qdd[:, others]) <= still_tol))
        if still:
            I, a, b = robot.single_joint_dynamics(joint, q[0])
            qj = q[:, joint]
            return tau_m[:, joint] - (I * qdd[:, joint] + a * np.sin(qj) + b * np.cos(qj))
        return tau_m[:, joint] - robot.rnea(q, qd, qdd).reshape(q.shape)[:, joint]
    return tau_m - robot.rnea(q, qd, qdd).reshape(q.shape)


def friction_data_from_signals(sig, robot, q_rest, *, accel: float | None = None,
                               label: str = "", subtract_motor_viscous: bool = False,
                               velocity: str = "motor") -> FrictionData:
    """One trial's joint as :class:`FrictionData` for the framework (eq. 25-26).

    ``sig``: an :class:`ident.signals.smoothing.JointSignals` (joint 1-based, link-side q/qd/qdd, motor-side
    qm/qmd/qmdd, motor torque tau); ``robot``: :class:`mocap.robot.Robot`; ``q_rest`` (n,): the
    angles of the braked joints. The residual is ``tau - tau_dm - J qmdd`` (the rotor inertia
    ``J`` of the drive belongs to the dynamic model of eq. 26) and, with
    ``subtract_motor_viscous``, ``- B qmd``; the friction velocity ``v`` is the motor velocity
    (link side), as in the paper; ``velocity="link"``: the link velocity and acceleration
    ``sig.qd``, ``sig.qdd`` instead (a flexible joint whose friction acts on the link: the
    link state of the encoder plus the declared spring's deflection, see
    :func:`ident.indri.campaign_fit.joint_dynamic_data`)."""
    if velocity not in ("motor", "link"):
        raise ValueError(f"velocity must be 'motor' or 'link', got {velocity!r}")
    j0 = int(sig.joint) - 1
    n = robot.n
    T = np.asarray(sig.time).shape[0]
    q = np.tile(np.asarray(q_rest, float), (T, 1))
    if q.shape != (T, n):
        raise ValueError(f"q_rest must have {n} angles, got {np.shape(q_rest)}")
    qd = np.zeros((T, n))
    qdd = np.zeros((T, n))
    q[:, j0], qd[:, j0], qdd[:, j0] = sig.q, sig.qd, sig.qdd
    tau = np.zeros((T, n))
    tau[:, j0] = sig.tau
    res = residual_torques(robot, q, qd, qdd, tau, joint=j0)
    drive = robot.drives[j0]
    res = res - drive.motor_inertia * np.asarray(sig.qmdd, float)
    if subtract_motor_viscous:
        res = res - drive.motor_viscous * np.asarray(sig.qmd, float)
    v, a = (sig.qmd, sig.qmdd) if velocity == "motor" else (sig.qd, sig.qdd)
    return FrictionData(np.asarray(sig.time, float), np.asarray(v, float),
                        np.asarray(a, float), res, label=label, accel=accel)


def steady_mask(data: FrictionData, settle_disp: float = 0.03,
                accel_tol: float | None = None) -> np.ndarray:
    """Samples of constant speed (|qdd| <= ``accel_tol``; None: 2% of the 99th percentile of
    |qdd|) after the joint has moved ``settle_disp`` rad since the last acceleration phase (the
    bristle transient is over): the step-1 samples (sec. III-A)."""
    qd = np.asarray(data.qd, float)
    aq = np.abs(np.asarray(data.qdd, float))
    tol = 0.02 * float(np.percentile(aq, 99.0)) if accel_tol is None else float(accel_tol)
    cruise = aq <= tol
    disp = np.concatenate([[0.0], np.cumsum(np.abs(qd[:-1]) * data.dt)])
    idx = np.arange(qd.size)
    start = np.maximum.accumulate(np.where(~cruise, idx, 0))
    return cruise & (disp - disp[start] >= settle_disp) & (np.abs(qd) > 0)


def concat_data(datas, label: str = "") -> FrictionData:
    """Join acquisitions end to end (times shifted to follow each other, one median step apart),
    e.g. several constant-speed trials for step 1. Only for step 1: the bristle state of a dynamic
    model is not continuous across the joins."""
    datas = list(datas)
    if not datas:
        raise ValueError("concat_data: nothing to join")
    ts, t_end = [], None
    for d in datas:
        t = np.asarray(d.time, float)
        t = t - t[0] if t_end is None else t - t[0] + t_end + float(np.median(d.dt))
        ts.append(t)
        t_end = t[-1]
    cat = [np.concatenate([np.asarray(getattr(d, k), float) for d in datas])
           for k in ("qd", "qdd", "tau")]
    truth = (np.concatenate([d.truth for d in datas])
             if all(d.truth is not None for d in datas) else None)
    return FrictionData(np.concatenate(ts), *cat, label=label or "+".join(d.label for d in datas),
                        truth=truth)
