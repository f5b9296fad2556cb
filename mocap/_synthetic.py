"""Seeded synthetic marker data for the mocap solver's tests and benchmark.

A PA10-6C-like arm (shoulder height 0.317 m, upper arm 0.45 m, forearm 0.48 m, wrist-to-flange
0.07 m), markers glued to its links, a camera pose, link angles = motor angles + a small
elastic deflection, marker noise of a given 3-D RMS, random occlusions, gross outliers and
label swaps. Everything random takes a ``seed``.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from mocap.kinematics import apply_transform, make_transform, rotation_about_axis

# (joint name, parent link, child link, origin xyz, axis, child mass)
PA10_LIKE = (
    ("joint1", "base_link", "link1", (0.0, 0.0, 0.0), (0, 0, 1), 9.0),
    ("joint2", "link1", "link2", (0.0, 0.0, 0.317), (0, 1, 0), 8.0),
    ("joint3", "link2", "link3", (0.0, 0.0, 0.45), (0, 1, 0), 4.0),
    ("joint4", "link3", "link4", (0.0, 0.0, 0.20), (0, 0, 1), 3.0),
    ("joint5", "link4", "link5", (0.0, 0.0, 0.28), (0, 1, 0), 1.5),
    ("joint6", "link5", "link6", (0.0, 0.0, 0.07), (0, 0, 1), 0.5),
)
LINK_LENGTH = {"link1": 0.317, "link2": 0.45, "link3": 0.20, "link4": 0.28, "link5": 0.07,
               "link6": 0.05}


def pa10_like_urdf(path: str | Path) -> Path:
    """Write the PA10-like URDF used by the synthetic data; returns its path."""
    out = ['<?xml version="1.0"?>', '<robot name="pa10_like">',
           '  <link name="base_link"><inertial><mass value="10"/><origin xyz="0 0 0.05"/>'
           '<inertia ixx="0.1" iyy="0.1" izz="0.1" ixy="0" ixz="0" iyz="0"/></inertial></link>']
    for name, parent, child, xyz, axis, mass in PA10_LIKE:
        L = LINK_LENGTH[child]
        out.append(f'  <link name="{child}"><inertial><mass value="{mass}"/>'
                   f'<origin xyz="0 0 {L / 2:.4f}"/><inertia ixx="{mass * L * L / 12 + 0.01:.5f}" '
                   f'iyy="{mass * L * L / 12 + 0.01:.5f}" izz="0.01" ixy="0" ixz="0" iyz="0"/>'
                   '</inertial></link>')
        out.append(f'  <joint name="{name}" type="revolute"><parent link="{parent}"/>'
                   f'<child link="{child}"/><origin xyz="{xyz[0]} {xyz[1]} {xyz[2]}" rpy="0 0 0"/>'
                   f'<axis xyz="{axis[0]} {axis[1]} {axis[2]}"/>'
                   '<limit lower="-3.0" upper="3.0" effort="100" velocity="2.0"/></joint>')
    out.append("</robot>")
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("\n".join(out) + "\n", encoding="utf-8")
    return path


def pa10_like_drives(path: str | Path) -> Path:
    from mocap.robot import Drive, write_drives

    drives = [Drive(name=j[0], gear_ratio=100.0, motor_inertia=0.2, motor_viscous=0.5,
                    max_velocity=2.0, max_torque=100.0, encoder_resolution=1e-5) for j in PA10_LIKE]
    return write_drives(path, drives, overwrite=True)


def pa10_like_robot(tmpdir: str | Path):
    from mocap.robot import Robot

    tmpdir = Path(tmpdir)
    return Robot.from_urdf(pa10_like_urdf(tmpdir / "arm.urdf"), pa10_like_drives(tmpdir / "drives.toml"))


def place_markers(robot, counts: dict, seed: int = 0, radius=(0.07, 0.12)) -> dict:
    """Random marker positions on the named links: ``{link: k}`` -> ``{label: (link, p_link)}``.

    Markers lie on a shell around the link's z axis (off the joint axes), spread along the link."""
    rng = np.random.default_rng(seed)
    out = {}
    for link, k in counts.items():
        L = LINK_LENGTH.get(link, 0.1)
        ang = rng.uniform(0, 2 * np.pi) + 2 * np.pi * np.arange(k) / k + rng.normal(0, 0.3, k)
        rad = rng.uniform(*radius, k)
        z = rng.uniform(0.15 * L, 0.85 * L, k) if L > 0.1 else rng.uniform(0.0, 0.06, k)
        for i in range(k):
            out[f"{link.upper()}_{i + 1}"] = (link, np.array([rad[i] * np.cos(ang[i]),
                                                              rad[i] * np.sin(ang[i]), z[i]]))
    return out


def default_camera_pose(seed: int = 0) -> np.ndarray:
    """``T_camera_base``: the base seen from ~2.5 m, a few degrees of tilt."""
    rng = np.random.default_rng(seed)
    R = rotation_about_axis(np.array([0.0, 0.0, 1.0]), rng.uniform(-np.pi, np.pi)) @ \
        rotation_about_axis(np.array([1.0, 0.0, 0.0]), rng.uniform(-0.1, 0.1))
    return make_transform(R, np.array([rng.uniform(-0.5, 0.5), rng.uniform(-0.5, 0.5), 2.5]))


def excitation(time: np.ndarray, n: int, joints, q_rest, amplitude: float = 0.8,
               seed: int = 0, harmonics: int = 5, f0: float = 0.1) -> np.ndarray:
    """Finite Fourier excitation (thesis eq. 3-1) on ``joints`` (0-based) around ``q_rest``."""
    rng = np.random.default_rng(seed)
    q = np.tile(np.asarray(q_rest, float), (time.shape[0], 1))
    k = np.arange(1, harmonics + 1)
    for j in joints:
        a = rng.normal(0, 1, harmonics) / k
        b = rng.normal(0, 1, harmonics) / k
        w = 2 * np.pi * f0 * k
        s = np.sin(np.outer(time, w)) @ a + np.cos(np.outer(time, w)) @ b
        q[:, j] += amplitude * s / np.max(np.abs(s))
    return q


@dataclass(frozen=True, eq=False)
class SyntheticMarkers:
    """Simulated measurements plus the truth that produced them."""

    p_camera: np.ndarray        # (T, M, 3) measured, NaN = occluded
    p_camera_true: np.ndarray   # (T, M, 3) noise-free
    labels: tuple[str, ...]
    outlier: np.ndarray         # (T, M) gross outliers injected
    swapped: np.ndarray         # (T, M) markers involved in an injected label swap


def simulate_markers(robot, q_link: np.ndarray, markers: dict, T_camera_base: np.ndarray,
                     noise_rms_m: float = 0.85e-3, missing_frac: float = 0.0,
                     outlier_frac: float = 0.0, outlier_range_m=(0.02, 0.2), swap_frac: float = 0.0,
                     seed: int = 0) -> SyntheticMarkers:
    """Markers (camera frame) for link angles ``q_link`` (T, n); ``markers`` as from
    :func:`place_markers`. ``noise_rms_m`` is the 3-D RMS (per-axis sigma = rms / sqrt 3)."""
    rng = np.random.default_rng(seed)
    q_link = np.atleast_2d(q_link)
    T = q_link.shape[0]
    labels = tuple(markers)
    Tj = robot.chain.joint_transforms(q_link)
    P = np.empty((T, len(labels), 3))
    for m, lb in enumerate(labels):  # loop over markers, vectorised over frames
        link, p = markers[lb]
        j, T_jf = robot.chain.frames[link]
        T_bl = Tj[:, j] @ T_jf if j >= 0 else np.broadcast_to(T_jf, (T, 4, 4))
        P[:, m] = apply_transform(T_bl, p)
    Pc = apply_transform(T_camera_base, P)
    meas = Pc + rng.normal(0.0, noise_rms_m / np.sqrt(3.0), Pc.shape)
    M = len(labels)
    outl = rng.random((T, M)) < outlier_frac
    if outl.any():
        d = rng.normal(size=(int(outl.sum()), 3))
        d *= (rng.uniform(*outlier_range_m, d.shape[0]) / np.linalg.norm(d, axis=1))[:, None]
        meas[outl] += d
    swapped = np.zeros((T, M), bool)
    if swap_frac > 0 and M >= 2:
        frames = np.flatnonzero(rng.random(T) < swap_frac)
        for t in frames:  # few frames
            a, b = rng.choice(M, 2, replace=False)
            meas[t, [a, b]] = meas[t, [b, a]]
            swapped[t, [a, b]] = True
    miss = rng.random((T, M)) < missing_frac
    meas[miss] = np.nan
    return SyntheticMarkers(meas, Pc, labels, outl & ~miss, swapped & ~miss)


def write_campaign(root: str | Path, *, seed: int = 0, trials=({"id": "j2-r1", "joints": [2]},),
                   counts=None, rate_hz: float = 100.0, duration_s: float = 6.0,
                   log_rate_hz: float = 500.0, noise_rms_m: float = 0.85e-3,
                   missing_frac: float = 0.0, outlier_frac: float = 0.0, swap_frac: float = 0.0,
                   n_static: int = 2, deflection_rad: float = 2e-3, units: str = "mm") -> dict:
    """Write a FORMAT v1 campaign with the PA10-like arm; returns the truth
    (``T_camera_base``, marker positions, per-trial link angles at the marker times)."""
    from mocap.io.campaign import write_manifest
    from mocap.io.markers import write_markers
    from mocap.io.recording import MarkerRecording
    from mocap.io.robotlog import RobotLog, write_robot_log

    root = Path(root)
    rng = np.random.default_rng(seed)
    robot = pa10_like_robot(root / "robot")
    counts = counts or {"link2": 3, "link3": 4, "link5": 4}
    markers = place_markers(robot, counts, seed=seed)
    T_cb = default_camera_pose(seed)
    truth = {"T_camera_base": T_cb, "markers": markers, "trials": {}}
    n = robot.n
    base_pose = np.array([0.2, 0.4, 0.9, 0.1, 0.6, 0.0])[:n]

    def _write(rel, t_m, q_link, q_motor, t_log, sseed, **noise):
        sim = simulate_markers(robot, q_link, markers, T_cb, noise_rms_m=noise_rms_m, seed=sseed,
                               **noise)
        rec = MarkerRecording(t_m, sim.p_camera, sim.labels, rate_hz, units=units)
        (root / rel).parent.mkdir(parents=True, exist_ok=True)
        write_markers(root / f"{rel}.trc", rec, overwrite=True, units=units)
        log = RobotLog(t_log, q_motor, np.zeros_like(q_motor))
        write_robot_log(root / f"{rel}.csv", log, overwrite=True)
        return sim

    doc = {"format": 1, "name": "synthetic-mocap",
           "robot": {"urdf": "robot/arm.urdf", "drives": "robot/drives.toml",
                     "gravity": [0.0, 0.0, -9.81]},
           "markers": {}, "static": [], "trial": []}
    for lb, (link, _) in markers.items():
        doc["markers"].setdefault(link, []).append(lb)
    for k in range(n_static):
        q_s = base_pose + (rng.uniform(-0.6, 0.6, n) if k else 0.0)
        t_m = np.arange(int(2.0 * rate_hz)) / rate_hz + 10.0 * k
        t_l = np.arange(int(2.2 * log_rate_hz)) / log_rate_hz + 10.0 * k - 0.1
        q_l = np.tile(q_s, (t_m.size, 1))
        _write(f"static/pose-{k + 1:02d}", t_m, q_l, np.tile(q_s, (t_l.size, 1)), t_l, seed + 100 + k)
        doc["static"].append({"markers": f"static/pose-{k + 1:02d}.trc",
                              "log": f"static/pose-{k + 1:02d}.csv"})
    for k, tr in enumerate(trials):
        joints0 = [j - 1 for j in tr["joints"]]
        t_l = np.arange(int(duration_s * log_rate_hz)) / log_rate_hz + 100.0 + 50 * k
        q_motor = excitation(t_l, n, joints0, base_pose, seed=seed + 200 + k)
        defl = np.zeros_like(q_motor)
        for j in joints0:
            defl[:, j] = deflection_rad * np.sin(2 * np.pi * 0.7 * t_l + j)
        t_m = np.arange(int((duration_s - 0.4) * rate_hz)) / rate_hz + t_l[0] + 0.2
        q_link_m = np.column_stack([np.interp(t_m, t_l, (q_motor + defl)[:, j]) for j in range(n)])
        sim = _write(f"trials/{tr['id']}", t_m, q_link_m, q_motor, t_l, seed + 300 + k,
                     missing_frac=missing_frac, outlier_frac=outlier_frac, swap_frac=swap_frac)
        truth["trials"][tr["id"]] = {"time": t_m, "q_link": q_link_m, "sim": sim}
        doc["trial"].append({"id": tr["id"], "joints": list(tr["joints"]), "load_kg": 0.0,
                             "vmax_frac": 1.0, "repetition": 1,
                             "markers": f"trials/{tr['id']}.trc", "log": f"trials/{tr['id']}.csv"})
    write_manifest(root / "campaign.toml", doc, overwrite=True)
    return truth
