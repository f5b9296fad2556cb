"""A small closed-form joint world for gap-diagnosis unit tests, independent of ident.sim.plant.

Rigid single-joint motion along a finite-Fourier reference, torque from the rigid-body model of
a 2-joint test robot plus Coulomb+viscous friction, plus one effect written here in forms that
differ on purpose from both the simulator's and the diagnosis's candidate shapes.
"""
from __future__ import annotations

from types import SimpleNamespace

import numpy as np

from ident.signals.fourier import FourierSeries
from mocap.io.robotlog import RobotLog

URDF = """<?xml version="1.0"?>
<robot name="two">
  <link name="base_link"/>
  <link name="link1"><inertial><mass value="4"/><origin xyz="0 0 0.1"/>
    <inertia ixx="0.05" iyy="0.05" izz="0.05" ixy="0" ixz="0" iyz="0"/></inertial></link>
  <link name="link2"><inertial><mass value="3"/><origin xyz="0.25 0 0"/>
    <inertia ixx="0.02" iyy="0.05" izz="0.05" ixy="0" ixz="0" iyz="0"/></inertial></link>
  <joint name="joint1" type="revolute"><parent link="base_link"/><child link="link1"/>
    <origin xyz="0 0 0.3"/><axis xyz="0 0 1"/><limit lower="-3" upper="3" effort="80" velocity="1"/></joint>
  <joint name="joint2" type="revolute"><parent link="link1"/><child link="link2"/>
    <origin xyz="0 0 0.2"/><axis xyz="0 1 0"/><limit lower="-2" upper="2" effort="60" velocity="1.5"/></joint>
  <link name="tool"/>
  <joint name="tool_joint" type="fixed"><parent link="link2"/><child link="tool"/><origin xyz="0.45 0 0"/></joint>
</robot>
"""
DRIVES = "".join(f"""
[[joint]]
name = "joint{k}"
gear_ratio = 100.0
motor_inertia = 0.3
motor_viscous = 0.4
max_velocity = {v}
max_torque = {m}
encoder_resolution = 1.9e-4
""" for k, v, m in ((1, 1.0, 80.0), (2, 1.5, 60.0)))

EFFECTS = ("none", "stribeck", "presliding", "position_ripple", "load_dependent", "thermal_drift",
           "torque_scale", "asymmetry", "nonlinear_viscous", "compliance", "backlash", "time_offset")


def robot(tmp_path):
    from mocap.robot import Robot

    (tmp_path / "two.urdf").write_text(URDF)
    (tmp_path / "two.toml").write_text(DRIVES)
    return Robot.from_urdf(tmp_path / "two.urdf", tmp_path / "two.toml")


def _reference(rng, vmax_frac, vmax, period, duration, t):
    n = 5
    a, b = rng.normal(size=n), rng.normal(size=n)
    wf = 2 * np.pi / period
    fs = FourierSeries(a, b, wf, 0.0)
    tt = np.linspace(0, period, 2000)
    _, qd, _ = fs.evaluate(tt)
    s = vmax_frac * vmax / np.abs(qd).max()
    fs = FourierSeries(a * s, b * s, wf, 0.0)
    q, qd, qdd = fs.evaluate(t)
    return q - q.mean() + 1.3, qd, qdd


def make_world(tmp_path, effect="none", magnitude=1.0, seed=0, joint=2, loads=(0.0, 2.0),
               vmaxs=(0.3, 0.6, 1.0), reps=3, duration=10.0, rate=200.0, marker_rate=100.0,
               torque_noise=0.05, angle_noise=3e-4, payload_com=(0.0, 0.0, 0.0), declare_com=True):
    """Returns (robot, trials, logs, angles, truth). The payload sits at ``payload_com`` (flange
    frame); the trials declare it when ``declare_com`` is True, omit the key when False (FORMAT.md
    then declares it at the flange origin) and say ``"unknown"`` when it is that string."""
    rb = robot(tmp_path)
    j0 = joint - 1
    rng = np.random.default_rng(seed)
    c, v = 3.0, 2.0
    drive = rb.drives[j0]
    J, B = drive.motor_inertia, drive.motor_viscous
    vmax = drive.max_velocity
    M = magnitude
    trials, logs, angles = [], [], {}
    clock = 100.0
    ref_rng = np.random.default_rng(seed + 1000)
    refs = {vf: ref_rng.integers(1 << 30) for vf in vmaxs}
    k = 0
    for load in loads:
        rbl = rb.with_payload(load, tuple(payload_com)) if load > 0 else rb
        I, a, b = rbl.single_joint_dynamics(j0, np.zeros(rb.n))
        for vf in vmaxs:
            for r in range(1, reps + 1):
                t = np.arange(0, duration, 1 / rate)
                q, qd, qdd = _reference(np.random.default_rng(refs[vf]), vf, vmax, duration / 2, duration, t)
                tg = a * np.sin(q) + b * np.cos(q) + I * qdd
                sgn = np.tanh(qd / 1e-3)
                fr = c * sgn + v * qd
                tcamp = clock + t
                if effect == "stribeck":
                    fr += M * 0.5 * c * sgn * np.exp(-np.abs(qd) / 0.06)
                elif effect == "presliding":
                    # first-order lag of the Coulomb direction in time (not the candidate's form)
                    alpha = np.exp(-(1 / rate) / 0.04)
                    from scipy.signal import lfilter
                    lag = lfilter([1 - alpha], [1, -alpha], sgn, zi=[alpha * sgn[0]])[0]
                    fr += M * c * (lag - sgn)
                elif effect == "position_ripple":
                    fr += M * 0.15 * c * np.sin(7 * q + 0.3)
                elif effect == "load_dependent":
                    fr += M * 0.08 * sgn * np.abs(tg)
                elif effect == "thermal_drift":
                    fr *= 1 + M * 0.35 * np.exp(-(tcamp - 100.0) / 400.0)
                elif effect == "asymmetry":
                    fr += M * 0.25 * np.where(qd > 0, c + v * qd, -0.0)
                elif effect == "nonlinear_viscous":
                    fr += M * 0.3 * v * qd * np.abs(qd) / vmax
                y = tg + fr
                tau = y + J * qdd + B * qd
                if effect == "torque_scale":
                    tau = tau / (1 + M * 0.15)
                tau = tau + rng.normal(0, torque_noise, t.shape)
                qm = np.round(q / 1.9e-4) * 1.9e-4
                # link angle seen by the markers
                tmk = np.arange(0.013, duration - 0.05, 1 / marker_rate)
                tq = tmk + (M * 0.02 if effect == "time_offset" else 0.0)
                ql = np.interp(tq, t, q)
                yl = np.interp(tq, t, y)
                if effect == "compliance":
                    ql = ql - M * yl / 3000.0
                elif effect == "backlash":
                    ql = ql - M * 0.5 * np.deg2rad(0.25) * np.tanh(yl / 0.3)
                ql = ql + rng.normal(0, angle_noise, tmk.shape)
                qm_all = np.zeros((t.size, rb.n))
                tau_all = np.zeros((t.size, rb.n))
                qm_all[:, j0] = qm
                tau_all[:, j0] = tau
                logs.append(RobotLog(tcamp, qm_all, tau_all))
                angles[f"t{k}"] = (tmk + clock, ql)
                trials.append(SimpleNamespace(id=f"t{k}", joints=(joint,), load_kg=load, vmax_frac=vf,
                                              repetition=r, kind="excitation",
                                              extra={"payload_com": [float(x) for x in payload_com]}
                                              if declare_com is True else {"payload_com": "unknown"}
                                              if declare_com == "unknown" else {}))
                clock += duration + 5.0
                k += 1
    return rb, trials, logs, angles, {"c": c, "v": v}
