"""Forward simulator of the rigid-link flexible-joint robot (thesis eq. 2-1 and 2-2).

Plant of one joint (link side, gear folded in)::

    link:   I qdd  + g(q) + f(qd, z) + tau_r(q) = k (qm - q) + d (qmd - qd)          (2-1)
    motor:  J qmdd + B qmd + k (qm - q) + d (qmd - qd) = u                            (2-2)

with ``g(q) = a sin q + b cos q`` (exact for one joint moving alone, see
:meth:`mocap.robot.Robot.single_joint_dynamics`), the friction ``f`` and the transmission
(stiffness, damping, backlash) of :class:`ident.sim.effects.JointEffects`. ``u`` comes from a
motor-side PD plus feed-forward controller (:class:`Controller`) built on the NOMINAL model.

Integrator (one step of ``dt``, default 0.5 ms = 2 kHz):

- conservative spring: trapezoidal rule (Newmark average acceleration; exactly energy
  conserving for the linear spring), positions ``x1 = x0 + dt (v0 + v1) / 2``;
- dissipative terms (d, B, viscous, friction): backward Euler in the new velocities;
- Coulomb/static friction: set-valued and solved exactly (stick when the required torque is
  inside the static band, Moreau time-stepping); Stribeck, quadratic viscous and LuGre
  bristle dynamics by a safeguarded Newton solve of the scalar equation ``A qd1 + F(qd1) = R``
  obtained by eliminating the motor velocity from the 2x2 implicit system;
- gravity and position ripple: explicit at the predicted mid-step angle;
- the motor PD: implicit in the end-of-step motor state (stable for any gain).

With friction, damping and input off the scheme conserves the energy
``I qd^2/2 + J qmd^2/2 + k (qm-q)^2/2 + V(q)`` to O(dt^2) without drift (tested).

The single-joint loop is scalar Python float math (no numpy, no pinocchio per step): 50-100x
real time on one core (benchmarks/sim.py). The several-joint mode (:func:`simulate_multi`)
calls pinocchio and a small dense solve each step: about 2x real time, 30-50x slower.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ident.excitation.trajectories import min_jerk_path
from ident.friction import laws
from ident.friction.constants import SIGN_WIDTH
from ident.sim.effects import JointEffects


@dataclass(frozen=True)
class JointPlant:
    """Constants of one joint moving alone: link ``I`` and gravity ``a sin q + b cos q``
    (from the ACTUAL robot with its payload), motor ``J``, ``B``, effects ``fx`` and the
    campaign-clock origin ``t_ref`` of thermal drift."""

    I: float
    a: float
    b: float
    J: float
    B: float
    fx: JointEffects
    t_ref: float = 0.0

    def potential(self, q):
        """Gravity potential V with dV/dq = a sin q + b cos q."""
        return -self.a * np.cos(q) + self.b * np.sin(q)

    def to_dict(self) -> dict:
        return {"I": self.I, "a": self.a, "b": self.b, "J": self.J, "B": self.B,
                "t_ref": self.t_ref, "effects": self.fx.to_dict()}


@dataclass(frozen=True)
class Controller:
    """Motor-side PD plus feed-forward on the NOMINAL model, ``k`` the declared stiffness (thesis:
    the feed-forward controller of the experiment): ``u = kp (qm_r - qm) + kd (qmd_r - qmd) + u_ff`` with
    ``u_ff = (I + J) qdd_r + B qd_r + a sin q_r + b cos q_r + c sign(qd_r) + v qd_r`` and
    ``qm_r = q_r + (u_ff - J qdd_r - B qd_r) / k``. When disabled (coast-down) the motor only
    compensates the nominal gravity at the motor angle. In the simulator the PD acts on the
    end-of-step motor state (implicit), so any bandwidth is stable; default 30 Hz."""

    kp: float
    kd: float
    I: float
    a: float
    b: float
    J: float
    B: float
    c: float
    v: float
    k: float

    @classmethod
    def tuned(cls, I, a, b, J, B, c, v, k, bandwidth_hz: float = 30.0, zeta: float = 0.9):
        w = 2 * math.pi * bandwidth_hz
        m = I + J
        return cls(kp=m * w * w, kd=2 * zeta * m * w, I=I, a=a, b=b, J=J, B=B, c=c, v=v, k=k)

    def feedforward(self, q_r, qd_r, qdd_r):
        """Vectorised (u_ff, qm_r, qmd_r) over the reference samples."""
        link = self.I * qdd_r + self.a * np.sin(q_r) + self.b * np.cos(q_r) \
            + laws.coulomb_viscous(qd_r, self.c, self.v)
        u_ff = link + self.J * qdd_r + self.B * qd_r
        qm_r = q_r + link / self.k
        return u_ff, qm_r, qd_r

    def to_dict(self) -> dict:
        return dict(self.__dict__)


@dataclass
class JointState:
    q: float = 0.0
    qd: float = 0.0
    qm: float = 0.0
    qmd: float = 0.0
    z: float = 0.0
    tau_t: float = 0.0


def rest_state(plant: JointPlant, qm: float) -> JointState:
    """The joint at rest with the motor at ``qm`` and the link deflected by gravity."""
    fx = plant.fx
    q = qm
    for _ in range(50):
        g = plant.a * math.sin(q) + plant.b * math.cos(q)
        off = math.copysign(fx.beta, g) if g != 0 else 0.0
        q_new = qm - off - g / fx.k
        if abs(q_new - q) < 1e-15:
            break
        q = q_new
    g = plant.a * math.sin(q) + plant.b * math.cos(q)
    return JointState(q=q, qd=0.0, qm=qm, qmd=0.0, z=0.0, tau_t=g)


@dataclass(frozen=True, eq=False)
class SimResult:
    """Full-rate signals of one simulated segment (all (N,) arrays, time on the campaign
    clock). ``f`` is the friction torque acting on the link, ``u`` the true motor torque,
    ``tau_t`` the transmitted (spring) torque."""

    time: np.ndarray
    q: np.ndarray
    qd: np.ndarray
    qm: np.ndarray
    qmd: np.ndarray
    u: np.ndarray
    f: np.ndarray
    tau_t: np.ndarray
    final: JointState
    newton_max_iter: int = 0

    def qdd(self) -> np.ndarray:
        return np.gradient(self.qd, self.time)

    def qmdd(self) -> np.ndarray:
        return np.gradient(self.qmd, self.time)

    @staticmethod
    def concat(parts) -> "SimResult":
        parts = list(parts)
        cat = {k: np.concatenate([getattr(p, k) for p in parts])
               for k in ("time", "q", "qd", "qm", "qmd", "u", "f", "tau_t")}
        return SimResult(**cat, final=parts[-1].final,
                         newton_max_iter=max(p.newton_max_iter for p in parts))


def simulate_single(plant: JointPlant, ctrl: Controller, q_r, qd_r, qdd_r, enable,
                    state: JointState, t0: float, dt: float = 5e-4,
                    input_torque=None) -> SimResult:
    """Simulate one joint over the reference samples (one per step, spacing ``dt``).

    ``enable[i]`` False switches the controller to gravity compensation (coast-down).
    ``input_torque`` (optional (N,) array) replaces the controller entirely (open loop; used
    by the energy test). Returns the state AFTER each step; ``time[i] = t0 + (i + 1) dt``.
    """
    fx = plant.fx
    q_r, qd_r, qdd_r = (np.asarray(x, float).reshape(-1) for x in (q_r, qd_r, qdd_r))
    N = int(q_r.size)
    # the implicit PD targets the reference at the END of the step (sample i + 1); the last
    # step's target is the reference extrapolated by one step (constant acceleration), not the
    # last sample repeated: a repeated target brakes the joint for one step before each cut
    # (coast-down release) by about kp qd dt
    if N:
        q_r = np.append(q_r, q_r[-1] + dt * qd_r[-1] + 0.5 * dt * dt * qdd_r[-1])
        qd_r = np.append(qd_r, qd_r[-1] + dt * qdd_r[-1])
        qdd_r = np.append(qdd_r, qdd_r[-1])
    u_ff, qm_r, qmd_r = ctrl.feedforward(q_r, qd_r, qdd_r)
    ffl = u_ff[:N].tolist()
    qmrl = qm_r[1:].tolist()
    qmdrl = qmd_r[1:].tolist()
    enl = [bool(e) for e in np.broadcast_to(np.asarray(enable, bool), (N,))]
    open_loop = input_torque is not None
    uinl = np.asarray(input_torque, float).tolist() if open_loop else None
    kp, kd, an, bn = ctrl.kp, ctrl.kd, ctrl.a, ctrl.b
    I, a, b, J, B = plant.I, plant.a, plant.b, plant.J, plant.B
    k, d0, beta = fx.k, fx.d, fx.beta
    c_pos, c_neg, v, S, Vc, w = fx.c_pos, fx.c_neg, fx.v, fx.S, fx.Vc, fx.w
    vp, vn = v * (1.0 + 0.5 * fx.va), v * (1.0 - 0.5 * fx.va)
    s0, s1 = fx.sigma0, fx.sigma1
    rA, rn, rphi = fx.ripple_A, float(fx.ripple_n), fx.ripple_phi
    mu, th_h, th_tau = fx.mu, fx.thermal_h, fx.thermal_tau
    lugre = s0 > 0.0
    lugre_step = laws.lugre_implicit_step
    excess, excess_slope = laws.stribeck_excess, laws.stribeck_excess_slope
    S_rest = excess(0.0, S, Vc, math.exp) if S != 0.0 else 0.0     # the Stribeck excess at rest
    smooth = (S > 0.0) or (w > 0.0)
    sin, cos, exp, fabs = math.sin, math.cos, math.exp, abs
    hdt = 0.5 * dt
    Idt, Jdt = I / dt, J / dt
    q, qd, qm, qmd, z, tau_t = state.q, state.qd, state.qm, state.qmd, state.z, state.tau_t
    out_q = [0.0] * N
    out_qd = [0.0] * N
    out_qm = [0.0] * N
    out_qmd = [0.0] * N
    out_u = [0.0] * N
    out_f = [0.0] * N
    out_tt = [0.0] * N
    nmax = 0
    th = 1.0
    t_th0 = t0 - plant.t_ref
    for i in range(N):
        # --- controller: the PD acts on the end-of-step motor state (implicit, trapezoidal in
        # qm), u = u0 - kc qmd1, so any gain is stable; feed-forward and gravity comp explicit
        if open_loop:
            u0, kc = uinl[i], 0.0
        elif enl[i]:
            u0 = kp * (qmrl[i] - qm - hdt * qmd) + kd * qmdrl[i] + ffl[i]
            kc = kd + kp * hdt
        else:
            u0, kc = an * sin(qm) + bn * cos(qm), 0.0
        # --- explicit link torques at the predicted mid-step angle
        qh = q + hdt * qd
        grav = a * sin(qh) + b * cos(qh)
        Lx = -grav
        if rA != 0.0:
            Lx -= rA * sin(rn * qh + rphi)
        # --- transmission (backlash: dead band +-beta in qm - q)
        delta = qm - q
        if beta > 0.0:
            if delta > beta:
                ks, off, dd = k, beta, d0
            elif delta < -beta:
                ks, off, dd = k, -beta, d0
            else:
                ks, off, dd = 0.0, 0.0, 0.0
        else:
            ks, off, dd = k, 0.0, d0
        e = ks * dt * 0.25
        g = e + dd
        spring = ks * (delta - off) + e * (qmd - qd)
        Rl = Idt * qd + spring + Lx
        Rm = Jdt * qmd + u0 - spring
        Dm = Jdt + B + g + kc
        A = Idt + g - g * g / Dm
        R = Rl + g * Rm / Dm
        # --- friction levels (thermal drift on the campaign clock, load dependence)
        if th_h != 0.0:
            th = 1.0 + th_h * exp(-(t_th0 + i * dt) / th_tau)
        cp = c_pos * th
        cn = c_neg * th
        if mu != 0.0:
            cl = mu * fabs(grav)
            cp += cl
            cn += cl
        ve = v * th
        vep, ven = vp * th, vn * th
        # --- implicit velocity solve with friction
        if lugre:
            # LuGre (DM1): z1 = (z + dt x) / (1 + dt s0 |x| / c(x)); F = s0 z1 + s1 (z1 - z)/dt + ve x
            x = qd
            lo, hi = -1e9, 1e9
            s01 = s0 + s1 / dt
            for it in range(60):
                cx = cp if x >= 0.0 else cn
                z1, dz = lugre_step(z, x, dt, s0, cx)
                h = A * x + s0 * z1 + s1 * (z1 - z) / dt + ve * x - R
                if h > 0.0:
                    hi = x if x < hi else hi
                else:
                    lo = x if x > lo else lo
                hp = A + s01 * dz + ve
                step = h / hp if hp > 0.0 else 0.0
                xn = x - step
                if hp <= 0.0 or not (lo <= xn <= hi):
                    xn = 0.5 * (lo + hi) if (lo > -1e9 and hi < 1e9) else x - h / (A + ve)
                if fabs(xn - x) <= 1e-14 + 1e-11 * fabs(x):
                    x = xn
                    break
                x = xn
            if it > nmax:
                nmax = it
            cx = cp if x >= 0.0 else cn
            z1 = lugre_step(z, x, dt, s0, cx)[0]
            F = s0 * z1 + s1 * (z1 - z) / dt + ve * x
            z = z1
            qd1 = x
        else:
            if -(cn + S_rest) <= R <= cp + S_rest:
                qd1 = 0.0
                F = R
            else:
                if R > 0.0:
                    sg, cc, Ap = 1.0, cp, A + vep
                else:
                    sg, cc, Ap = -1.0, cn, A + ven
                r = sg * R - cc          # > S_rest >= 0
                x = (r - S_rest) / Ap        # x >= 0 in the direction of motion
                if smooth:
                    # safeguarded Newton on the bracket [0, r/Ap]: h(0) = S - r < 0 <= h(r/Ap)
                    # (h may be non-monotone when the Stribeck slope S/Vc exceeds Ap)
                    lo, hi = 0.0, r / Ap
                    xp = sg * qd                 # warm start: the previous velocity
                    if lo < xp < hi:
                        x = xp
                    elif not (lo < x < hi):
                        x = 0.5 * hi
                    for it in range(100):
                        if S > 0.0:
                            ex, dex = excess(x, S, Vc, exp), excess_slope(x, S, Vc, exp)
                        else:
                            ex, dex = 0.0, 0.0
                        h = Ap * x + ex + w * x * x - r
                        if h < 0.0:
                            lo = x
                        else:
                            hi = x
                        hp = Ap + dex + 2.0 * w * x
                        xn = x - h / hp if hp > 0.0 else -1.0
                        if not (lo <= xn <= hi):
                            xn = 0.5 * (lo + hi)
                        if fabs(xn - x) <= 1e-15 + 1e-12 * x or hi - lo <= 1e-15 + 1e-12 * hi:
                            x = xn
                            break
                        x = xn
                    if it > nmax:
                        nmax = it
                qd1 = sg * x
                F = R - A * qd1
        qmd1 = (Rm + g * qd1) / Dm
        u = u0 - kc * qmd1
        q += hdt * (qd + qd1)
        qm += hdt * (qmd + qmd1)
        qd, qmd = qd1, qmd1
        # transmitted torque at the end of the step (for the truth)
        delta = qm - q
        if beta > 0.0:
            tau_t = k * (delta - beta) if delta > beta else (k * (delta + beta) if delta < -beta else 0.0)
        else:
            tau_t = k * delta
        out_q[i] = q
        out_qd[i] = qd
        out_qm[i] = qm
        out_qmd[i] = qmd
        out_u[i] = u
        out_f[i] = F
        out_tt[i] = tau_t
    time = t0 + dt * np.arange(1, N + 1)
    return SimResult(time, np.array(out_q), np.array(out_qd), np.array(out_qm), np.array(out_qmd),
                     np.array(out_u), np.array(out_f), np.array(out_tt),
                     JointState(q, qd, qm, qmd, z, tau_t), nmax)


def energy(plant: JointPlant, res: SimResult) -> np.ndarray:
    """Mechanical energy of the single-joint plant along ``res`` (kinetic + spring + gravity)."""
    k = plant.fx.k
    return (0.5 * plant.I * res.qd ** 2 + 0.5 * plant.J * res.qmd ** 2
            + 0.5 * k * (res.qm - res.q) ** 2 + plant.potential(res.q))


def simulate_reference(plant: JointPlant, ctrl: Controller, ref, t0: float, dt: float = 5e-4,
                       state: JointState | None = None) -> SimResult:
    """Track a :mod:`ident.excitation.trajectories` trajectory from rest at its start (or from ``state``)."""
    n = int(round(ref.duration / dt))
    tr = dt * np.arange(n)
    q_r, qd_r, qdd_r = ref.sample(tr)
    if state is None:
        u0, qm0, _ = ctrl.feedforward(q_r[:1], qd_r[:1], qdd_r[:1])
        state = rest_state(plant, float(qm0[0]))
    return simulate_single(plant, ctrl, q_r, qd_r, qdd_r, True, state, t0, dt)


# ---------------------------------------------------------------------------------------------
# several joints together (pinocchio per step)
# ---------------------------------------------------------------------------------------------

def regularised_friction(qd, c_dir, v_dir, S, Vc, w, width: float = SIGN_WIDTH):
    """The friction of the several-joint mode and its slope (for the implicit linearisation):
    ``F = (c_dir + S exp(-|qd|/Vc)) tanh(qd / width) + v_dir qd + w qd |qd|``, the Stribeck
    law of the single-joint mode (:func:`ident.friction.laws.stribeck_excess`) with
    the Coulomb + viscous law (:func:`ident.friction.laws.coulomb_viscous`) under the smooth
    sign :func:`ident.friction.laws.smooth_sign`. ``c_dir``/``v_dir``: the Coulomb level and
    viscous coefficient of the direction of ``qd``. Returns ``(F, dF/dqd >= 0)``. As
    ``qd -> 0+`` (``0-``) ``F`` tends to ``c_dir + S``, the edges of the single-joint mode's
    static band; at ``qd = 0``, ``F = 0``."""
    a = np.abs(qd)
    level = c_dir + laws.stribeck_excess(a, S, Vc)
    th_ = laws.smooth_sign(qd, width)
    F = laws.coulomb_viscous(qd, level, v_dir, sign=lambda x: th_) + w * qd * a
    # d tanh(qd/width)/dqd = (1 - tanh^2)/width
    dF = level * (1 - th_ ** 2) / width \
        + laws.stribeck_excess_slope(a, S, Vc) * np.abs(th_) + v_dir + 2 * w * a
    return F, np.maximum(dF, 0.0)


def simulate_multi(robot, joints, fxs, J, B, q_rest, refs, ctrl_robot=None, t0: float = 0.0,
                   dt: float = 5e-4, bandwidth_hz: float = 15.0, c_nom=None, v_nom=None,
                   t_ref: float = 0.0, k_nom=None):
    """Several joints (0-based ``joints``) moving together, the others held at ``q_rest``.

    Link dynamics ``M(q) qdd + h(q, qd)`` from pinocchio (crba + nonLinearEffects) each step
    for the moving block; motor side, spring, damping and friction as in the single-joint
    mode, but with the Coulomb friction regularised (``c tanh(qd / 1e-3)``) and linearised
    implicitly. Stribeck, quadratic viscous, ripple, asymmetry, load dependence and thermal
    drift are supported; LuGre and backlash only in the single-joint mode.
    ``robot`` is the actual plant (with payload); ``ctrl_robot`` the controller's nominal model,
    ``c_nom``/``v_nom``/``k_nom`` its friction and (declared) stiffness per moving joint (default:
    the plant's own, i.e. a controller that knows the effect).
    Returns a dict of full-rate (N, m) arrays. Speed: about 0.4-0.5 ms per step (2x real time,
    see benchmarks/sim.py).
    """
    import pinocchio as pin

    ctrl_robot = ctrl_robot or robot
    joints = list(joints)
    m = len(joints)
    model, data = robot.model, robot.model.createData()
    cm, cd = ctrl_robot.model, ctrl_robot.model.createData()
    duration = max(r.duration for r in refs)
    N = int(round(duration / dt))
    tr = dt * np.arange(N)
    QR = np.full((N, robot.n), np.asarray(q_rest, float))
    QDR = np.zeros((N, robot.n))
    QDDR = np.zeros((N, robot.n))
    for k_, (j, r) in enumerate(zip(joints, refs)):
        QR[:, j], QDR[:, j], QDDR[:, j] = r.sample(tr)
    Jv, Bv = np.asarray(J, float), np.asarray(B, float)
    kv = np.array([f.k for f in fxs])
    dv = np.array([f.d for f in fxs])
    c_nom = np.array([0.5 * (f.c_pos + f.c_neg) for f in fxs]) if c_nom is None else np.asarray(c_nom)
    v_nom = np.array([f.v for f in fxs]) if v_nom is None else np.asarray(v_nom)
    # nominal feed-forward (rigid) and PD gains from the nominal inertia at the start
    Mn = pin.crba(cm, cd, QR[0].copy())
    Mn = np.triu(Mn) + np.triu(Mn, 1).T
    wc = 2 * np.pi * bandwidth_hz
    Mdiag = np.diag(Mn)[joints] + Jv
    kp, kdg = Mdiag * wc * wc, 2 * 0.9 * Mdiag * wc
    tau_link_ff = np.atleast_2d(ctrl_robot.rnea(QR, QDR, QDDR))[:, joints] if N else np.zeros((0, m))
    qd_sel = QDR[:, joints]
    link_ff = tau_link_ff + laws.coulomb_viscous(qd_sel, c_nom, v_nom)
    u_ff = link_ff + Jv * QDDR[:, joints] + Bv * qd_sel
    k_ff = kv if k_nom is None else np.asarray(k_nom, float)
    qm_ref = QR[:, joints] + link_ff / k_ff
    cpos = np.array([f.c_pos for f in fxs])
    cneg = np.array([f.c_neg for f in fxs])
    Sv = np.array([f.S for f in fxs])
    Vcv = np.array([f.Vc for f in fxs])
    wv = np.array([f.w for f in fxs])
    rA = np.array([f.ripple_A for f in fxs])
    rn = np.array([f.ripple_n for f in fxs], float)
    rph = np.array([f.ripple_phi for f in fxs])
    muv = np.array([f.mu for f in fxs])
    thh = np.array([f.thermal_h for f in fxs])
    thtau = np.array([f.thermal_tau for f in fxs])
    eps = SIGN_WIDTH
    qfull = QR[0].copy()
    g0 = pin.computeGeneralizedGravity(model, data, qfull)[joints]
    q = QR[0, joints].copy() - g0 / kv
    qm = QR[0, joints].copy()
    qd = np.zeros(m)
    qmd = np.zeros(m)
    tau_t = g0.copy()
    out = {k_: np.zeros((N, m)) for k_ in ("q", "qd", "qm", "qmd", "u", "f", "tau_t")}
    vzero = np.zeros(robot.n)
    for i in range(N):
        u = kp * (qm_ref[i] - qm) + kdg * (qd_sel[i] - qmd) + u_ff[i]
        qfull[joints] = q + 0.5 * dt * qd
        vfull = vzero.copy()
        vfull[joints] = qd
        Mf = pin.crba(model, data, qfull)
        Mb = np.triu(Mf) + np.triu(Mf, 1).T
        Mb = Mb[np.ix_(joints, joints)]
        h = pin.nonLinearEffects(model, data, qfull, vfull)[joints]
        th = 1.0 + thh * np.exp(-(t0 - t_ref + i * dt) / thtau)
        if muv.any():
            gload = np.abs(pin.computeGeneralizedGravity(model, data, qfull)[joints])
        else:
            gload = 0.0
        cp = cpos * th + muv * gload
        cn = cneg * th + muv * gload
        vav = np.array([f.va for f in fxs])
        ve = np.array([f.v for f in fxs]) * th * (1.0 + 0.5 * vav * np.where(qd >= 0, 1.0, -1.0))
        Ff, dF = regularised_friction(qd, np.where(qd >= 0, cp, cn), ve, Sv, Vcv, wv, eps)
        Lx = -h - rA * np.sin(rn * qfull[joints] + rph)
        e = kv * dt * 0.25
        gg = e + dv
        spring = kv * (qm - q) + e * (qmd - qd)
        # implicit 2m system in (qd1, qmd1)
        Mt = np.zeros((2 * m, 2 * m))
        Mt[:m, :m] = Mb / dt + np.diag(gg + dF)
        Mt[:m, m:] = -np.diag(gg)
        Mt[m:, :m] = -np.diag(gg)
        Mt[m:, m:] = np.diag(Jv / dt + Bv + gg)
        rhs = np.concatenate([Mb @ qd / dt + spring + Lx - Ff + dF * qd,
                              Jv * qmd / dt + u - spring])
        sol = np.linalg.solve(Mt, rhs)
        qd1, qmd1 = sol[:m], sol[m:]
        Fa = Ff + dF * (qd1 - qd)
        q = q + 0.5 * dt * (qd + qd1)
        qm = qm + 0.5 * dt * (qmd + qmd1)
        qd, qmd = qd1, qmd1
        tau_t = kv * (qm - q)
        out["q"][i], out["qd"][i], out["qm"][i], out["qmd"][i] = q, qd, qm, qmd
        out["u"][i], out["f"][i], out["tau_t"][i] = u, Fa, tau_t
    out["time"] = t0 + dt * np.arange(1, N + 1)
    out["q_ref"] = QR[:, joints]
    out["qd_ref"] = qd_sel
    return out


def simulate_coastdown(plant: JointPlant, ctrl: Controller, q_center: float, q_halfrange: float,
                       vmax: float, vmax_frac: float, t0: float, dt: float = 5e-4,
                       speed_fractions=(0.4, 0.7, 1.0), coast_s: float = 1.5,
                       hold: float = 0.5) -> tuple[SimResult, np.ndarray, list]:
    """Coast-down runs (the TDM/FDM experiment of the coast-down paper, eq. 4-6): for each
    speed and both directions, move to the start, accelerate at constant acceleration to the
    speed over ``1.2 q_halfrange``, then switch the controller off (gravity compensation only)
    for ``coast_s`` s while friction stops the joint, then take over again at rest.

    Returns the concatenated result, the controller mode per step (1 tracking, 0 coasting)
    and the release events ``[(time, speed), ...]``.
    """
    parts, modes, events = [], [], []
    u0, qm0, _ = ctrl.feedforward(np.array([q_center]), np.zeros(1), np.zeros(1))
    state = rest_state(plant, float(qm0[0]))
    t = t0
    amax = max(2.0 * vmax_frac * vmax, 1.0)

    def run(q_r, qd_r, qdd_r, en):
        nonlocal state, t
        res = simulate_single(plant, ctrl, q_r, qd_r, qdd_r, en, state, t, dt)
        parts.append(res)
        modes.append(np.asarray(en, np.int8) * np.ones(len(q_r), np.int8))
        state = res.final
        t = float(res.time[-1])

    for f in speed_fractions:
        for sgn in (1.0, -1.0):
            v = f * vmax_frac * vmax
            dist = 1.2 * q_halfrange
            start = q_center - sgn * 0.6 * q_halfrange
            # approach from the current position (min-jerk), hold
            path = min_jerk_path([state.qm, start], vmax * vmax_frac, amax, hold=hold)
            n = int(round(path.duration / dt))
            q_r, qd_r, qdd_r = path.sample(dt * np.arange(n))
            run(q_r, qd_r, qdd_r, True)
            # constant acceleration up to speed v over `dist`
            a = v * v / (2.0 * dist)
            n = int(round((v / a) / dt))
            tt = dt * np.arange(n)
            run(start + sgn * 0.5 * a * tt ** 2, sgn * a * tt, np.full(n, sgn * a), True)
            events.append([t, sgn * v])
            # coast with the controller off
            n = int(round(coast_s / dt))
            z = np.zeros(n)
            run(z, z, z, False)
            # take over at rest where it stopped
            n = int(round(hold / dt))
            qm_hold = state.qm
            q_hold = qm_hold - (ctrl.a * math.sin(qm_hold) + ctrl.b * math.cos(qm_hold)) / ctrl.k
            run(np.full(n, q_hold), np.zeros(n), np.zeros(n), True)
    return SimResult.concat(parts), np.concatenate(modes), events
