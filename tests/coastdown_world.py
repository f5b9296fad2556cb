"""An independent coast-down world for the tests: FORMAT v1 campaigns of a one-joint robot
written from the physics in plain numpy/scipy (it imports nothing from ident or mocap).

The joint (vertical axis, no gravity) is flexible, with friction on the MOTOR side of the
spring (jointlab's simulator puts it on the link side) and viscous damping on both sides::

    I  q''  = k (qm - q) + d (qm' - q') - b_link q'
    Jm qm'' = u - B qm' - Fc sgn(qm') - k (qm - q) - d (qm' - q')

The controller ticks at ``f_ctrl``; the drive brings the joint to speed along a constant
acceleration and holds it (cruise), then the command drops to 0 at a tick and the current
decays with a first-order lag ``tau_e`` (an amplifier), and the joint coasts until the motor
stops (it sticks: the spring torque left is far below Fc). The coast is integrated by
``scipy.integrate.solve_ivp`` (DOP853, a stop event); the drive phases are kinematic (the
motor follows the ramp, the log torque is the rigid inverse dynamics). The log (rate
``f_log``, dividing ``f_ctrl``, random phase) holds the encoder angle quantised to ``res`` and
the command held over the control period plus white noise. Truth: ``Kc = Fc``,
``Kv = B + b_link``, ``J = I + Jm``.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
from scipy.integrate import solve_ivp

URDF = """<?xml version="1.0"?>
<robot name="coaster">
  <link name="base_link"/>
  <link name="arm"><inertial><mass value="{m}"/><origin xyz="{r} 0 0"/>
    <inertia ixx="0.001" iyy="0.001" izz="{izz}" ixy="0" ixz="0" iyz="0"/></inertial></link>
  <joint name="joint1" type="revolute"><parent link="base_link"/><child link="arm"/>
    <origin xyz="0 0 0.2"/><axis xyz="0 0 1"/><limit lower="-100" upper="100" effort="{tmax}" velocity="{vmax}"/></joint>
</robot>
"""


def draw_joint(rng: np.random.Generator, stiffness_scale: float = 1.0, damping_ratio=None) -> dict:
    """Random joint constants (SI, link side); ``stiffness_scale`` multiplies the spring;
    ``damping_ratio`` (optional) replaces the drawn 0.05-0.15 of the two-mass mode (e.g. 3:
    an overdamped transmission, whose deflection relaxes instead of ringing)."""
    m, r = rng.uniform(2.0, 8.0), rng.uniform(0.1, 0.3)
    izz = rng.uniform(0.01, 0.05)
    I = izz + m * r * r
    Jm = rng.uniform(0.05, 0.4)
    Fc = rng.uniform(2.0, 12.0)
    B, b_link = rng.uniform(0.2, 2.0), rng.uniform(0.0, 1.5)
    tmax = 4.0 * (Fc + (B + b_link) * 2.0)
    k = stiffness_scale * tmax / np.radians(rng.uniform(0.06, 0.10))   # 0.06-0.1 deg at max torque
    zeta = rng.uniform(0.05, 0.15)
    if damping_ratio is not None:
        zeta = float(damping_ratio)
    mu = I * Jm / (I + Jm)
    return {"m": m, "r": r, "izz": izz, "I": I, "Jm": Jm, "Fc": Fc, "B": B, "b_link": b_link,
            "k": k, "d": 2.0 * zeta * np.sqrt(k * mu), "vmax": 2.0, "tmax": tmax,
            "res": rng.choice([2 * np.pi / 2 ** 15, 2 * np.pi / 2 ** 16]) / 1.0,
            "tau_noise": 0.003 * tmax, "tau_e": rng.uniform(1e-4, 5e-4)}


def _coast(p, t_cut, qm0, v0, u0, t_end):
    """Integrate the coast from the cruise state at the cut; returns a dense solution for the
    motor angle over [t_cut, t_stop] and t_stop."""
    I, Jm, k, d, B, bl, Fc, te = (p[x] for x in ("I", "Jm", "k", "d", "B", "b_link", "Fc", "tau_e"))
    s = np.sign(v0)
    delta0 = bl * v0 / k                                    # cruise: spring carries the link viscous

    def f(t, y):
        q, qd, qm, qmd = y
        u = u0 * np.exp(-(t - t_cut) / te)
        spring = k * (qm - q) + d * (qmd - qd)
        return [qd, (spring - bl * qd) / I, qmd, (u - B * qmd - Fc * s - spring) / Jm]

    def stop(t, y):
        return y[3] * s
    stop.terminal, stop.direction = True, -1
    sol = solve_ivp(f, (t_cut, t_end), [qm0 - delta0, v0, qm0, v0], method="DOP853", rtol=1e-10,
                    atol=1e-12, events=stop, dense_output=True, max_step=1e-3)
    t_stop = float(sol.t_events[0][0]) if sol.t_events[0].size else float(sol.t[-1])
    return sol, t_stop


def simulate_trial(p: dict, speeds, rng: np.random.Generator, f_ctrl: float, f_log: float,
                   rest: float = 0.4, ramp_acc: float = 8.0, cruise: float = 0.4):
    """One record with a coast at each signed speed; returns (time, qm_logged, tau_logged,
    releases [(t_cut, v0)])."""
    Jt, Kv, Fc = p["I"] + p["Jm"], p["B"] + p["b_link"], p["Fc"]
    n_div = int(round(f_ctrl / f_log))
    dt_c = 1.0 / f_ctrl
    T0 = rng.uniform(0.0, dt_c * n_div)                      # log phase
    pieces_t, pieces_q, pieces_u = [], [], []               # piecewise functions of time
    t, q = 0.0, rng.uniform(-0.5, 0.5)
    releases = []
    for v0 in speeds:  # loop over coasts (a handful)
        s = np.sign(v0)
        t_ramp = abs(v0) / ramp_acc
        # rest then ramp then cruise; the cut lands on a control tick
        t_a = t + rest
        t_b = t_a + t_ramp
        t_cut = np.ceil((t_b + cruise) / dt_c) * dt_c
        q_a = q
        q_b = q_a + 0.5 * s * ramp_acc * t_ramp ** 2
        pieces_t.append((t, t_a, lambda tt, q_=q: np.full_like(tt, q_), lambda tt: np.zeros_like(tt)))
        pieces_t.append((t_a, t_b, lambda tt, qa=q_a, ta=t_a, s=s: qa + 0.5 * s * ramp_acc * (tt - ta) ** 2,
                         lambda tt, ta=t_a, s=s: s * (Jt * ramp_acc + Fc) + Kv * s * ramp_acc * (tt - ta)))
        pieces_t.append((t_b, t_cut, lambda tt, qb=q_b, tb=t_b, v=v0: qb + v * (tt - tb),
                         lambda tt, v=v0: np.full_like(tt, np.sign(v) * Fc + Kv * v)))
        q_cut = q_b + v0 * (t_cut - t_b)
        u0 = s * Fc + Kv * v0
        sol, t_stop = _coast(p, t_cut, q_cut, v0, u0, t_cut + 20.0)
        q_stop = float(sol.sol(t_stop)[2])
        pieces_t.append((t_cut, t_stop, lambda tt, so=sol: so.sol(tt)[2], lambda tt: np.zeros_like(tt)))
        releases.append((t_cut, v0))
        t, q = t_stop, q_stop
    pieces_t.append((t, t + rest, lambda tt, q_=q: np.full_like(tt, q_), lambda tt: np.zeros_like(tt)))
    t_end = t + rest
    t_log = T0 + np.arange(int((t_end - T0) * f_log)) / f_log
    qm = np.empty_like(t_log)
    u = np.empty_like(t_log)
    # the command logged at a log tick is the one issued at that control tick: the target
    # torque in the drive phases, 0 from the cut on (the current's lag is the amplifier's)
    for a, b, fq, fu in pieces_t:  # loop over phases (a few per coast)
        sel = (t_log >= a) & (t_log < b)
        qm[sel] = fq(t_log[sel])
        u[sel] = fu(t_log[sel])
    res = p["res"]
    qm_log = np.round(qm / res) * res
    tau_log = u + rng.normal(0.0, p["tau_noise"], t_log.size)
    return t_log, qm_log, tau_log, releases


def _write_trc(path: Path, t, q_link, r: float) -> None:
    """Three markers on the arm (m, camera = base frame) at 100 Hz: the manifest reader of
    this version wants a marker file per trial even where the command needs none."""
    tm = np.arange(t[0], t[-1], 0.01)
    q = np.interp(tm, t, q_link)
    pts = [(r, 0.0, 0.25), (r, 0.05, 0.22), (0.5 * r, -0.04, 0.24)]
    cols = []
    for x, y, z in pts:
        c, s_ = np.cos(q), np.sin(q)
        cols += [c * x - s_ * y, s_ * x + c * y, np.full_like(q, z)]
    head = ["PathFileType\t4\t(X/Y/Z)\t" + path.name,
            "DataRate\tCameraRate\tNumFrames\tNumMarkers\tUnits\tOrigDataRate\tOrigDataStartFrame\tOrigNumFrames",
            f"100\t100\t{tm.size}\t3\tm\t100\t1\t{tm.size}",
            "Frame#\tTime\tA1\t\t\tA2\t\t\tA3\t\t",
            "\t\t" + "\t".join(f"{a}{i}" for i in (1, 2, 3) for a in "XYZ")]
    rows = [f"{k + 1}\t{tm[k]:.4f}\t" + "\t".join(f"{c[k]:.6f}" for c in cols) for k in range(tm.size)]
    path.write_text("\n".join(head + rows) + "\n")


def write_campaign(root: Path, seed: int, f_log: float = 500.0, f_ctrl: float = 1000.0,
                   speed_fracs=(0.3, 0.6, 1.0), trials: int = 1, stiffness_scale: float = 1.0,
                   damping_ratio=None) -> dict:
    """A robot-only FORMAT v1 campaign with ``trials`` coast-down trials of joint 1 (each with
    a coast at every speed fraction, both directions); returns the truth."""
    rng = np.random.default_rng([seed, 424242])
    p = draw_joint(rng, stiffness_scale, damping_ratio)
    root = Path(root)
    (root / "robot").mkdir(parents=True)
    (root / "trials").mkdir()
    (root / "robot" / "arm.urdf").write_text(URDF.format(m=p["m"], r=p["r"], izz=p["izz"],
                                                         tmax=p["tmax"], vmax=p["vmax"]))
    (root / "robot" / "drives.toml").write_text(
        f'[[joint]]\nname = "joint1"\ngear_ratio = 100.0\nmotor_inertia = {float(p["Jm"])!r}\n'
        f'motor_viscous = {float(p["B"])!r}\nmax_velocity = {float(p["vmax"])!r}\nmax_torque = {float(p["tmax"])!r}\n'
        f'encoder_resolution = {float(p["res"])!r}\nstiffness = {float(p["k"])!r}\n')
    toml = ['format = 1', f'name = "coaster-{seed}"', "", "[robot]", 'urdf = "robot/arm.urdf"',
            'drives = "robot/drives.toml"', "gravity = [0.0, 0.0, -9.81]", "", "[markers]",
            'arm = ["A1", "A2", "A3"]', ""]
    truth = {"Kc": p["Fc"], "Kv": p["B"] + p["b_link"], "J": p["I"] + p["Jm"], "params": p, "trials": {}}
    for i in range(trials):  # loop over trials
        speeds = [s * f * p["vmax"] for f in speed_fracs for s in (1.0, -1.0)]
        t, qm, tau, rel = simulate_trial(p, speeds, rng, f_ctrl, f_log)
        tid = f"cd-{i + 1}"
        body = np.column_stack([t + 100.0, qm, tau])
        np.savetxt(root / "trials" / f"{tid}.csv", body, delimiter=",", header="time,qm_1,tau_1",
                   comments="", fmt=["%.6f", "%.9f", "%.5f"])
        _write_trc(root / "trials" / f"{tid}.trc", t + 100.0, qm, p["r"])
        toml += ["[[trial]]", f'id = "{tid}"', "joints = [1]", "load_kg = 0.0", "vmax_frac = 1.0",
                 f"repetition = {i + 1}", 'kind = "coastdown"', f'log = "trials/{tid}.csv"',
                 f'markers = "trials/{tid}.trc"', ""]
        truth["trials"][tid] = [(tc + 100.0, v) for tc, v in rel]
    (root / "campaign.toml").write_text("\n".join(toml))
    return truth
