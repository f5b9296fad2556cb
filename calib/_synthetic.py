"""Synthetic calibration sweeps for tests and the benchmark (not part of the public API).

Markers are glued to chosen links at 0.1-0.3 m from the axis of the joint that carries the
link; joint ``j`` is swept ``q_rest_j + A sin(2 pi t / duration)`` (so it covers +-A) with the
other joints held; the markers are seen from a random camera pose ``T_camera_base`` with
Gaussian noise (3-D RMS ``noise_mm``, per-axis ``noise_mm / sqrt(3)``), occlusion gaps and
optional gross outliers. The robot log is on the same clock, at its own rate, longer than
the marker recording on both ends, with encoder quantisation (and optionally a clock offset).
"""
from __future__ import annotations

import shutil
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from mocap.kinematics import apply_transform, invert_transform, make_transform
from mocap.synth import MarkerSet, add_noise, marker_positions, random_orientation
from mocap.io.recording import MarkerRecording
from mocap.io.campaign import write_manifest
from mocap.io.markers import write_markers
from mocap.io.robotlog import RobotLog, write_robot_log


@dataclass(frozen=True, eq=False)
class SyntheticSweep:
    joint: int
    markers: MarkerRecording   # camera frame, metres
    log: RobotLog
    q_markers: np.ndarray      # (T, n) true link angles at the marker frames


@dataclass(frozen=True, eq=False)
class SyntheticCalib:
    T_camera_base: np.ndarray
    sweeps: tuple
    markers: dict              # link -> tuple of labels
    p_link: dict               # label -> (3,) position in its link frame
    q_rest: np.ndarray
    noise_mm: float
    extra: dict = field(default_factory=dict)


def random_camera_pose(rng) -> np.ndarray:
    """A camera 2.5-3.5 m from the robot base, random orientation."""
    return make_transform(random_orientation(rng),
                          np.array([rng.uniform(-0.5, 0.5), rng.uniform(-0.5, 0.5), rng.uniform(2.5, 3.5)]))


def place_markers(chain, links_counts: dict, rng, radii=(0.1, 0.3), axial=(-0.05, 0.25)) -> dict:
    """Label -> (link, p_link): markers at radius ``radii`` from the axis of the joint carrying
    each link, spread along the axis over ``axial`` metres."""
    out = {}
    for link, count in links_counts.items():
        j, T_jf = chain.frames[link]
        ax = chain.axes[j]
        e1 = np.cross(ax, [1.0, 0, 0]) if abs(ax[0]) < 0.9 else np.cross(ax, [0, 1.0, 0])
        e1 /= np.linalg.norm(e1)
        e2 = np.cross(ax, e1)
        phases = rng.uniform(0, 2 * np.pi) + np.arange(count) * 2 * np.pi / count \
            + rng.uniform(-0.3, 0.3, count)
        r = rng.uniform(*radii, count)
        h = rng.uniform(*axial, count)
        p_joint = r[:, None] * (np.cos(phases)[:, None] * e1 + np.sin(phases)[:, None] * e2) \
            + h[:, None] * ax
        p_link = apply_transform(invert_transform(T_jf), p_joint)
        tag = "".join(ch for ch in link if ch.isdigit()) or link
        for k in range(count):
            out[f"L{tag}{chr(65 + k)}"] = (link, p_link[k])
    return out


def simulate_sweeps(robot, seed: int = 0, joints=(1, 2), amplitude_deg: float = 60.0,
                    duration_s: float = 12.0, rate_hz: float = 100.0, log_rate_hz: float = 200.0,
                    noise_mm: float = 0.85, markers_per_link=None, radii=(0.1, 0.3),
                    gap_fraction: float = 0.05, outlier_fraction: float = 0.0,
                    q_rest=None, T_camera_base=None, encoder_resolution: float = 1e-5,
                    marker_layout: dict | None = None, clock_offset_s: float = 0.0,
                    joint_stiffness=None, poses: int = 0) -> SyntheticCalib:
    """Simulate single-joint calibration sweeps of ``robot`` (anything with a ``.chain``).

    ``markers_per_link`` maps link name -> count (default 4 on the links of joints 1 and 2);
    ``marker_layout`` (label -> (link, p_link)) overrides the random placement;
    ``clock_offset_s`` shifts the robot log's time stamps against the marker clock (a
    synchronisation error: the log says ``q(t)`` at time ``t + clock_offset_s``);
    ``joint_stiffness`` (N m/rad, scalar or (n,), needs ``robot.gravity_torque``) makes the
    joints compliant: the log has the motor-side angle ``q_m`` and the links sit at
    ``q_m - g(q_m) / K`` (the static flexible joint, thesis eq. 2-1 to 2-4, first order).
    ``poses`` > 0 makes stop-and-go sweeps instead (a laser tracker's): that many poses evenly
    over +-A at irregular instants, one marker row per pose (no gaps) and log rows at the same
    instants.
    """
    rng = np.random.default_rng(seed)
    chain = robot.chain
    n = chain.n
    if markers_per_link is None:
        inv = {j: name for name, (j, T) in chain.frames.items() if np.allclose(T, np.eye(4))}
        markers_per_link = {inv.get(0, "link1"): 4, inv.get(1, "link2"): 4}
    layout = marker_layout or place_markers(chain, markers_per_link, rng, radii)
    T_cb = random_camera_pose(rng) if T_camera_base is None else np.asarray(T_camera_base, float)
    if q_rest is None:
        q_rest = rng.uniform(-0.5, 0.5, n)
    q_rest = np.asarray(q_rest, float)
    labels = tuple(layout)
    links = {}
    for lb, (link, _) in layout.items():
        links.setdefault(link, []).append(lb)
    mset = MarkerSet(labels, tuple(layout[lb][0] for lb in labels),
                     np.array([layout[lb][1] for lb in labels]).reshape(-1, 3))
    A = np.radians(amplitude_deg)
    sweeps = []
    for j in joints:
        if poses:
            t = np.cumsum(rng.uniform(4.0, 8.0, poses)) + rng.uniform(0, 5)
            t0 = t[0]
            prof = lambda tt: np.interp(tt, t, np.linspace(-A, A, poses))  # noqa: E731
        else:
            t = np.arange(int(round(duration_s * rate_hz))) / rate_hz + rng.uniform(0, 5)
            t0 = t[0]
            prof = lambda tt: A * np.sin(2 * np.pi * np.clip(tt - t0, 0, duration_s) / duration_s)  # noqa: E731
        q = np.tile(q_rest, (t.size, 1))
        q[:, j - 1] += prof(t)
        if joint_stiffness is not None:
            q = q - robot.gravity_torque(q) / np.broadcast_to(np.asarray(joint_stiffness, float), (n,))
        P = add_noise(marker_positions(chain, mset, q, T_cb), noise_mm * 1e-3, rng)
        if outlier_fraction > 0:
            bad = rng.random(P.shape[:2]) < outlier_fraction
            P[bad] += rng.normal(0, 0.02, (int(bad.sum()), 3))
        if gap_fraction > 0 and not poses:
            for k in range(len(labels)):
                n_gaps = rng.integers(1, 4)
                for _ in range(n_gaps):
                    L = int(gap_fraction * t.size / n_gaps)
                    s0 = rng.integers(0, max(t.size - L, 1))
                    P[s0:s0 + L, k] = np.nan
        rec = MarkerRecording(t, P, labels, rate_hz, "mm", None, {})
        tl = t.copy() if poses else np.arange(t0 - 0.5, t[-1] + 0.5, 1.0 / log_rate_hz)
        ql = np.tile(q_rest, (tl.size, 1))
        ql[:, j - 1] += prof(tl)
        if encoder_resolution > 0:
            ql = np.round(ql / encoder_resolution) * encoder_resolution
        log = RobotLog(tl + clock_offset_s, ql, np.zeros_like(ql), {}, None)
        sweeps.append(SyntheticSweep(j, rec, log, q))
    return SyntheticCalib(T_cb, tuple(sweeps), {k: tuple(v) for k, v in links.items()},
                          {lb: p for lb, (_, p) in layout.items()}, q_rest, noise_mm)


def write_campaign(root, sim: SyntheticCalib, urdf, drives, overwrite: bool = False) -> Path:
    """Write ``sim`` as a FORMAT v1 campaign at ``root`` (robot files copied in)."""

    root = Path(root)
    (root / "robot").mkdir(parents=True, exist_ok=True)
    (root / "calib").mkdir(parents=True, exist_ok=True)
    shutil.copy(urdf, root / "robot" / "arm.urdf")
    shutil.copy(drives, root / "robot" / "drives.toml")
    meshes = Path(urdf).parent / "meshes"
    if meshes.is_dir() and not (root / "robot" / "meshes").exists():
        shutil.copytree(meshes, root / "robot" / "meshes")
    calib = []
    for sw in sim.sweeps:
        mk = f"calib/joint-{sw.joint}.trc"
        lg = f"calib/joint-{sw.joint}.csv"
        write_markers(root / mk, sw.markers, overwrite=overwrite, fmt="%.6f")
        write_robot_log(root / lg, sw.log, overwrite=overwrite, fmt="%.10g")
        calib.append({"joint": sw.joint, "markers": mk, "log": lg})
    doc = {"format": 1, "name": "synthetic-calib",
           "robot": {"urdf": "robot/arm.urdf", "drives": "robot/drives.toml",
                     "gravity": [0.0, 0.0, -9.81]},
           "markers": {k: list(v) for k, v in sim.markers.items()},
           "calib": calib}
    return write_manifest(root / "campaign.toml", doc, overwrite=overwrite)
