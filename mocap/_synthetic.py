"""Seeded synthetic marker data for the mocap solver's tests and benchmark.

The PA10-6C of ``fixtures/robots/pa10`` (the project's one PA10 model), markers glued to its
links, a camera pose, link angles = motor angles + a small elastic deflection, marker noise of a
given 3-D RMS, random occlusions, gross outliers and label swaps. Marker positions come from the
one marker synthesis, :func:`mocap.synth.marker_positions`. Everything random takes a ``seed``.
"""
from __future__ import annotations

import shutil
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from mocap.kinematics import make_transform, rotation_about_axis
from mocap.synth import MarkerSet, add_noise, marker_positions
from mocap.io.campaign import write_manifest
from mocap.io.markers import write_markers
from mocap.io.recording import MarkerRecording
from mocap.io.robotlog import RobotLog, write_robot_log
from mocap.robot import Robot

PA10_DIR = Path(__file__).resolve().parents[1] / "fixtures" / "robots" / "pa10"


def pa10_robot(folder: str | Path, stiffness: bool = False):
    """The fixture PA10 (URDF and drives copied into ``folder``, which a campaign may use as its
    ``robot/`` folder), loaded as a :class:`mocap.robot.Robot`. These synthetic worlds are
    kinematic (held joints do not give, logged torques are zero), so the drives declare no
    ``stiffness`` (FORMAT.md: absent = rigid) unless ``stiffness``."""
    import re

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    shutil.copy(PA10_DIR / "pa10.urdf", folder / "arm.urdf")
    text = (PA10_DIR / "drives.toml").read_text()
    if not stiffness:
        text = re.sub(r"(?m)^stiffness\s*=.*\n", "", text)
    (folder / "drives.toml").write_text(text)
    return Robot.from_urdf(folder / "arm.urdf", folder / "drives.toml")


def _link_length(chain, link: str) -> float:
    """Distance from a link's frame to the next joint's origin (0.1 m past the last joint)."""
    j, _ = chain.frames[link]
    if j < 0 or j + 1 >= chain.n:
        return 0.1
    return float(np.linalg.norm(chain.T_parent_joint[j + 1, :3, 3]))


def place_markers(robot, counts: dict, seed: int = 0, radius=(0.07, 0.12)) -> dict:
    """Random marker positions on the named links: ``{link: k}`` -> ``{label: (link, p_link)}``.

    Markers lie on a shell around the link's z axis (off the joint axes), spread along the link."""
    rng = np.random.default_rng(seed)
    out = {}
    for link, k in counts.items():
        L = _link_length(robot.chain, link)
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
    mset = MarkerSet(labels, tuple(markers[lb][0] for lb in labels),
                     np.array([markers[lb][1] for lb in labels]).reshape(-1, 3))
    Pc = marker_positions(robot.chain, mset, q_link, T_camera_base)
    meas = add_noise(Pc, noise_rms_m, rng)
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
    """Write a FORMAT v1 campaign with the fixture PA10; returns the truth
    (``T_camera_base``, marker positions, per-trial link angles at the marker times)."""
    root = Path(root)
    rng = np.random.default_rng(seed)
    robot = pa10_robot(root / "robot")
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
