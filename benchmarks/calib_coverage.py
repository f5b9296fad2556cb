"""Coverage of the calibration's reported uncertainty on laser-tracker geometries (issues 28, 46).

Default cells (issue 46), ``wide{1,3}-{exact,offset}``: every run draws its geometry as widely as
users set it up (:func:`make_wide_campaign`): the bundled PA10 (J1 and J2 axes intersecting) or an
industrial arm of the FANUC R-2000iC class (312 mm J1-J2 offset, J3 logged relative to J2 and
declared as ``[robot] coupling`` in half of its runs); the tracker 3-5 m from the base at any
heading, levelled within 1 deg; per swept joint 4-8 stop-and-go poses over 40-120 deg, centred
anywhere in the joint's range, evenly spaced or at random angles; the other joints at random
angles within their limits (so the reflector's radius about each axis ranges from millimetres to
metres); 1 or 3 reflectors 30-330 mm from the flange centre in any direction; 0.02-0.05 mm noise
per coordinate, white or a tracker's line-of-sight noise 0.3-1x the transverse noise; the URDF
exact (``exact``) or the real J1-J2 offset 0-1 mm off the URDF's (``offset``). Goal: 90-98 % in
every cell (origin, rotation, pose).

The PA10 cells of issue 28 (``--cells pa10``, or any of them by name): Monte Carlo over stop-and-go sweeps of joints 1 and 2 of the bundled PA10, as a laser tracker
measures them: each run draws the poses per joint (cell), 1 or 3 reflectors on the flange
(cell), a swept angle of 40-120 deg per joint, a 3-D RMS noise of 0.02-0.05 mm that is NOT white
(line-of-sight noise half the transverse noise, as a tracker's distance meter beats its angle
encoders), a random tracker pose 2-4 m away, a random rest posture, and - in the ``mismatch``
cells - a real J1-J2 axis offset that differs from the URDF's by 0-1 mm (joint 2 moved along the
common perpendicular of the two axes; a shift of joint 2 along joint 1's axis would move the
base's origin by as much without any trace in the data, see docs/calibration.md).

The data are written the way a user gets them: forward kinematics by pinocchio on the real
(perturbed) model, plain-text TRC (mm) and CSV logs, a campaign.toml; nothing of jointlab's
estimator is used to make them. The campaign is then calibrated with ``calib.pipeline.calibrate``
(the library behind ``jointlab calib``) and judged only from what ``calib.json`` reports:

* coverage: the true ``T_camera_base`` inside the reported 95 % region - origin (3-D), rotation
  (3-D) and the 6-D pose - using the reported covariance ``base_solve.cov_rotvec_origin`` and
  the reported region thresholds ``region95`` (Mahalanobis squared distances; chi2 quantiles
  when a result does not report them). Goal: 90-98 % in every ``exact`` and ``mismatch`` cell,
  at least 90 % in the ``declared`` cells (a declared tolerance is a conservative type-B bound).
* the Gaussian reading (issue 46, every cell; a goal of 90-98 % in the wide cells): the same
  covariance read as a Gaussian one, chi2(0.95; 3) and chi2(0.95; 6) thresholds whatever
  ``region95`` says, as a user or checker without the region's thresholds reads it. This is how
  the issue's one-reflector figures (78 / 83 %) are reproduced: on the tree before issue 46's
  changes (e82ca8f) the wide one-reflector cells read 80 / 81 % (URDF exact) and 80 / 83 % (offset
  off) this way, 96 / 98 % and 92 / 93 % in ``region95`` (100 runs each).
* cells: ``NxM-exact`` (N poses per joint, M reflectors, the URDF exact), ``NxM-mismatch`` (the
  real J1-J2 axis offset 0-1 mm off the URDF's - the issue's "URDF axis offsets mismatched by
  0-1 mm" - with default settings: the model error is what the estimator makes of the measured
  J1-J2 discrepancy), ``NxM-declared`` (the same robots, the user declares the URDF's tolerance
  with ``--urdf-tol-mm 0.289``, the RMS of the offsets drawn per line and direction),
  ``NxM-trusted`` (the URDF exact and the user says so: ``jointlab calib --trust-urdf``, no
  model error estimated; goal 90-98 % as for ``exact``, and its RMS error against the
  ``exact`` cell's is the precision the default gives up) and ``NxM-trustmis`` (``--trust-urdf``
  on a URDF 0-1 mm off: informational - how often the chi2 misfit warning fires, and the
  coverage of the runs it does not fire on), ``NxM-deflect`` (the URDF exact, but the real arm's
  joints deflect under gravity at the stiffness of drives.toml and the log holds the motor-side
  angles, as on a large industrial arm: informational, a limitation the default does not model)
  and ``NxM-deflecttol`` (the same with ``--urdf-tol-mm 0.289`` declared), ``NxM-deflectcomp``
  (the same calibrated with ``--deflection``: the deflection undone at the declared stiffness;
  goal 90-98 % as for ``exact``).
* at 3 poses: the reported per-axis standard deviation (RMS over runs) against the empirical
  spread of the error on that axis (origin x, y, z; rotation x, y, z); goal: within 1.5x in the
  ``exact`` and ``mismatch`` cells.

The truth is the real robot's base frame (where the URDF's J1-J2 geometry is off, the fit of
the URDF's axis lines cannot know which of the two is wrong: the reported region must cover
that too).

    python benchmarks/calib_coverage.py                 # the 4 wide cells, 200 runs each (~8 min on one core)
    python benchmarks/calib_coverage.py --quick         # 40 runs per cell, about 1.5 min
    python benchmarks/calib_coverage.py --cells pa10    # the 30 PA10 cells of issue 28 (~11 min)
    python benchmarks/calib_coverage.py --runs 300 --cells 6x1-exact,3x3-mismatch
"""
from __future__ import annotations

import argparse
import json
import os
import shutil
import sys
import tempfile
import time
import warnings
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
PA10 = REPO / "fixtures" / "robots" / "pa10"

#: 95 % quantiles of chi2 with 3 and 6 degrees of freedom (fallback when no region95 is reported)
CHI2_95 = {3: 7.814727903251178, 6: 12.591587243743977}
#: the URDF tolerance the user declares in the ``declared`` cells (``jointlab calib --urdf-tol-mm``,
#: a standard uncertainty per axis line and per direction across it): the 0-1 mm offset drawn has
#: an RMS of 1/sqrt(3) mm and falls on one of the 2 lines x 2 directions, 1/sqrt(3)/2 mm each
URDF_TOL_MM = 1.0 / np.sqrt(3.0) / 2.0
#: line-of-sight noise over transverse noise of the simulated tracker
LOS_RATIO = 0.5
#: the wide cells (issue 46): 1 or 3 reflectors, the URDF exact or its J1-J2 offset 0-1 mm off,
#: every other draw of :func:`make_wide_campaign` per run (4-8 poses per sweep)
WIDE_CELLS = ["wide1-exact", "wide1-offset", "wide3-exact", "wide3-offset"]
#: the bundled PA10's cells of issue 28 (``--cells pa10``)
CELLS = [f"{n}x{m}-{w}" for w in ("exact", "mismatch") for m in (1, 3) for n in (4, 6, 8)] + \
        ["3x3-exact", "3x3-mismatch", "6x1-declared", "6x3-declared", "3x3-declared"] + \
        [f"{c}-trusted" for c in ("4x1", "8x1", "4x3", "8x3", "3x3")] + ["4x1-trustmis", "8x3-trustmis"] + \
        ["6x1-deflect", "6x3-deflect", "6x1-deflecttol", "6x3-deflecttol", "6x1-deflectcomp", "6x3-deflectcomp"]


# ---------------------------------------------------------------------------------------
# data generation: pinocchio forward kinematics + plain text (no jointlab code)
# ---------------------------------------------------------------------------------------
def _rot(axis, a):
    axis = np.asarray(axis, float) / np.linalg.norm(axis)
    K = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + np.sin(a) * K + (1 - np.cos(a)) * K @ K


def _write_trc(path, t, P_mm, labels):
    M = len(labels)
    head = ["PathFileType\t4\t(X/Y/Z)\t" + path.name,
            "DataRate\tCameraRate\tNumFrames\tNumMarkers\tUnits\tOrigDataRate\tOrigDataStartFrame\tOrigNumFrames",
            f"1\t1\t{len(t)}\t{M}\tmm\t1\t1\t{len(t)}",
            "Frame#\tTime\t" + "\t".join(f"{lb}\t\t" for lb in labels),
            "\t\t" + "\t".join(f"X{k + 1}\tY{k + 1}\tZ{k + 1}" for k in range(M)), ""]
    rows = [f"{k + 1}\t{tt:.4f}\t" + "\t".join(f"{x:.5f}" for x in p.reshape(-1))
            for k, (tt, p) in enumerate(zip(t, P_mm))]
    path.write_text("\n".join(head + rows) + "\n")


def _write_log(path, t, q):
    n = q.shape[1]
    lines = [",".join(["time"] + [f"qm_{j}" for j in range(1, n + 1)] + [f"tau_{j}" for j in range(1, n + 1)])]
    lines += [",".join([f"{tt:.4f}"] + [f"{x:.12f}" for x in qq] + ["0"] * n) for tt, qq in zip(t, q)]
    path.write_text("\n".join(lines) + "\n")


def make_campaign(root: Path, seed: int, n_poses: int, n_reflectors: int, mismatch: bool,
                  sweep_deg=(40.0, 120.0), noise_mm=(0.02, 0.05), offset_mm=(0.0, 1.0),
                  angle_scale: float = 1.0, angle_sign=(1, 1), urdf_scale: float = 1.0,
                  los_ratio: float = 0.5, deflect: bool = False) -> dict:
    """Write one tracker campaign under ``root``; return the truth and the draws.

    ``deflect``: the real arm's joints deflect under gravity, ``q_link = q_motor - g(q_link) / K``
    with ``K`` the stiffness of drives.toml and ``g`` the gradient of pinocchio's potential energy
    (central differences; fixed point), and the log holds the motor-side angles; the URDF is exact.

    ``angle_scale`` / ``angle_sign`` corrupt the logged angle of the swept joint (a gear-ratio or
    sign mistake in the log), ``urdf_scale`` writes the URDF's lengths multiplied (1000: a URDF
    in millimetres); the data always come from the correct model."""
    import pinocchio as pin

    rng = np.random.default_rng(seed)
    (root / "robot").mkdir(parents=True)
    (root / "calib").mkdir()
    urdf_text = (PA10 / "pa10.urdf").read_text()
    shutil.copy(PA10 / "drives.toml", root / "robot" / "drives.toml")
    (root / "robot" / "arm.urdf").write_text(urdf_text)
    model = pin.buildModelFromUrdf(str(root / "robot" / "arm.urdf"))
    if urdf_scale != 1.0:
        import re

        def scale(m):
            vals = [float(x) * urdf_scale for x in m.group(1).split()]
            return 'xyz="' + " ".join(f"{v:.6g}" for v in vals) + '"'
        (root / "robot" / "arm.urdf").write_text(re.sub(r'xyz="([^"]*)"', lambda m: scale(m)
                                                        if "axis" not in m.string[max(0, m.start() - 6):m.start()]
                                                        else m.group(0), urdf_text))
    delta = np.zeros(3)
    if mismatch:
        # the real J1-J2 axis offset differs from the URDF's: joint 2 moved along the common
        # perpendicular of the two axes (link-1 frame: J1 along z, J2 along y -> x)
        delta = rng.choice([-1.0, 1.0]) * rng.uniform(*offset_mm) * 1e-3 * np.array([1.0, 0.0, 0.0])
        model.jointPlacements[2].translation = model.jointPlacements[2].translation + delta
    data = model.createData()
    if deflect:
        import tomllib
        stiffness = np.array([d["stiffness"] for d in tomllib.loads((PA10 / "drives.toml").read_text())["joint"]])
    R_cb = _rot(rng.normal(size=3), rng.uniform(0.0, np.pi))
    dist = rng.uniform(2.0, 4.0)
    view = rng.normal(size=3)
    view /= np.linalg.norm(view)
    p_cb = dist * view                      # tracker at the camera origin, the robot 2-4 m away
    q_rest = np.array([rng.uniform(-1, 1), rng.uniform(-0.3, 0.6), rng.uniform(0.4, 1.4),
                       rng.uniform(-1, 1), rng.uniform(0.3, 1.2), rng.uniform(-1, 1)])
    refl = np.array([[0.03, -0.02, 0.09], [-0.06, 0.05, 0.04], [0.05, 0.07, -0.03]])[:n_reflectors]
    labels = [f"SMR{k + 1}" for k in range(n_reflectors)]
    noise = rng.uniform(*noise_mm) * 1e-3
    sw = {}
    for j in (1, 2):
        span = np.radians(rng.uniform(*sweep_deg))
        offs = np.linspace(-span / 2, span / 2, n_poses) + rng.uniform(-0.2, 0.2) * span / n_poses
        t = np.cumsum(rng.uniform(5.0, 9.0, n_poses)) + 100.0 * j
        Q = np.tile(q_rest, (n_poses, 1))
        Q[:, j - 1] += offs
        P = np.empty((n_poses, n_reflectors, 3))
        for i, q in enumerate(Q):
            if deflect:
                # static equilibrium K (q_motor - q_link) = dV/dq(q_link), the gravity torque as the
                # gradient of the potential energy (central differences; not the estimator's RNEA),
                # solved by fixed point
                q = q.copy()
                q0 = q.copy()
                for _ in range(4):
                    h = 1e-6
                    grad = np.array([(pin.computePotentialEnergy(model, data, q + h * e)
                                      - pin.computePotentialEnergy(model, data, q - h * e)) / (2 * h)
                                     for e in np.eye(len(q))])
                    q = q0 - grad / stiffness
            pin.forwardKinematics(model, data, q)
            M = data.oMi[model.njoints - 1]
            P[i] = (R_cb @ (M.rotation @ refl.T + M.translation[:, None])).T + p_cb
        # tracker noise: transverse (angle encoders) twice the line-of-sight (distance meter) noise
        los = P / np.linalg.norm(P, axis=2, keepdims=True)
        e = rng.normal(size=P.shape)
        e_los = np.sum(e * los, axis=2, keepdims=True) * los
        s_t = noise / np.sqrt(2 + los_ratio ** 2)        # 3-D RMS = noise
        P = P + s_t * (e - e_los) + los_ratio * s_t * e_los
        q_log = Q.copy()
        q_log[:, j - 1] = q_rest[j - 1] + angle_sign[j - 1] * angle_scale * offs
        _write_trc(root / "calib" / f"joint-{j}.trc", t, 1e3 * P, labels)
        _write_log(root / "calib" / f"joint-{j}.csv", t, q_log)
        sw[j] = float(np.degrees(span))
    (root / "campaign.toml").write_text(
        'format = 1\nname = "tracker"\n\n[robot]\nurdf = "robot/arm.urdf"\ndrives = "robot/drives.toml"\n\n'
        f"[markers]\nlink6 = [{', '.join(repr(lb).replace(chr(39), chr(34)) for lb in labels)}]\n\n"
        '[[calib]]\njoint = 1\nmarkers = "calib/joint-1.trc"\nlog = "calib/joint-1.csv"\n\n'
        '[[calib]]\njoint = 2\nmarkers = "calib/joint-2.trc"\nlog = "calib/joint-2.csv"\n')
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R_cb, p_cb
    return {"T": T, "noise_mm": 1e3 * noise, "sweep_deg": sw, "offset_mm": 1e3 * float(np.linalg.norm(delta))}


# ---------------------------------------------------------------------------------------
# the wide generator (issue 46): geometry drawn as widely as users set it up
# ---------------------------------------------------------------------------------------
#: an industrial arm of the FANUC R-2000iC class (J1-J2 offset 312 mm, upper arm 1075 mm, elbow
#: offset 225 mm, forearm 1280 mm, flange 215 mm): xyz of each joint's origin in its parent,
#: axis, limits (rad)
IND_JOINTS = [((0.0, 0.0, 0.450), (0, 0, 1), (-3.2, 3.2)),
              ((0.312, 0.0, 0.220), (0, 1, 0), (-1.05, 1.33)),
              ((0.0, 0.0, 1.075), (0, -1, 0), (-1.4, 2.6)),
              ((0.0, 0.0, 0.225), (-1, 0, 0), (-3.5, 3.5)),
              ((1.280, 0.0, 0.0), (0, -1, 0), (-2.2, 2.2)),
              ((0.215, 0.0, 0.0), (-1, 0, 0), (-3.5, 3.5))]


def industrial_urdf() -> str:
    """URDF text of :data:`IND_JOINTS` (rough solid-cylinder inertias; calibration uses none)."""
    masses = (600.0, 250.0, 120.0, 60.0, 15.0, 5.0, 1.0)
    links = [f'  <link name="{"base_link" if k == 0 else f"link{k}"}">\n'
             f'    <inertial><origin xyz="0 0 0.05"/><mass value="{m}"/>'
             f'<inertia ixx="{0.05 * m:.3f}" iyy="{0.05 * m:.3f}" izz="{0.02 * m:.3f}" ixy="0" ixz="0" iyz="0"/>'
             '</inertial>\n  </link>' for k, m in enumerate(masses)]
    joints = [f'  <joint name="joint{k + 1}" type="revolute">\n    <parent link="{"base_link" if k == 0 else f"link{k}"}"/>'
              f'<child link="link{k + 1}"/>\n    <origin xyz="{" ".join(map(str, xyz))}" rpy="0 0 0"/>'
              f'<axis xyz="{" ".join(map(str, ax))}"/>\n    <limit lower="{lo}" upper="{hi}" velocity="2" effort="1000"/>\n'
              '  </joint>' for k, (xyz, ax, (lo, hi)) in enumerate(IND_JOINTS)]
    return '<?xml version="1.0"?>\n<robot name="ind6">\n' + "\n".join(links + joints) + "\n</robot>\n"


def make_wide_campaign(root: Path, seed: int, n_reflectors: int, mismatch: bool,
                       poses=(4, 8), sweep_deg=(40.0, 120.0), noise_mm=(0.02, 0.05),
                       offset_mm=(0.0, 1.0), robot: str | None = None, angle_sign=(1, 1),
                       sign_in_all_logs: bool = False) -> dict:
    """Write one tracker campaign drawn widely under ``root``; return the truth and the draws.

    Each run draws: the robot (the bundled PA10, its J1 and J2 axes intersecting, or an
    industrial arm with a 312 mm J1-J2 offset whose controller logs J3 relative to J2, declared
    as ``[robot] coupling``, in half of its runs); the tracker 3-5 m from the base at any
    heading and -0.5..1.5 m above it, levelled within 1 deg; per swept joint 4-8 stop-and-go
    poses (``poses``) over 40-120 deg, centred anywhere in the joint's range, evenly spaced with
    jitter or at random angles, in either order; the other joints held at random angles within
    their limits (drawn anew per sweep); ``n_reflectors`` reflectors fixed on the flange or a
    tool, each 30-330 mm from the flange centre in a random direction; noise 0.02-0.05 mm per
    coordinate, white or (half of the runs) a tracker's line-of-sight noise 0.3-1x its
    transverse noise; ``mismatch``: the real J1-J2 offset 0-1 mm off the URDF's (joint 2 moved
    along the common perpendicular of the two axes). Forward kinematics by pinocchio on the real
    model; nothing of jointlab is used. ``angle_sign`` negates a joint's logged angle in its own
    sweep's log (``sign_in_all_logs``: in both logs)."""
    import pinocchio as pin

    rng = np.random.default_rng(seed)
    robot = robot or ("pa10" if rng.uniform() < 0.5 else "ind")
    (root / "robot").mkdir(parents=True)
    (root / "calib").mkdir()
    urdf_text = (PA10 / "pa10.urdf").read_text() if robot == "pa10" else industrial_urdf()
    (root / "robot" / "arm.urdf").write_text(urdf_text)
    shutil.copy(PA10 / "drives.toml", root / "robot" / "drives.toml")
    model = pin.buildModelFromUrdf(str(root / "robot" / "arm.urdf"))
    nq = model.nq
    lo, hi = model.lowerPositionLimit.copy(), model.upperPositionLimit.copy()
    coupled = robot == "ind" and rng.uniform() < 0.5
    C = np.eye(nq)
    if coupled:
        C[2, 1] = -1.0          # q3_urdf = q3_log - q2_log (J2 and J3 axes point opposite ways here)
    delta = np.zeros(3)
    if mismatch:
        # both URDFs: J1 along z, J2 along y in link 1, so the common perpendicular is x
        delta = rng.choice([-1.0, 1.0]) * rng.uniform(*offset_mm) * 1e-3 * np.array([1.0, 0.0, 0.0])
        model.jointPlacements[2].translation = model.jointPlacements[2].translation + delta
    data = model.createData()
    heading = rng.uniform(-np.pi, np.pi)
    tilt_axis = np.r_[rng.normal(size=2), 0.0]
    R_cb = _rot(tilt_axis, np.radians(rng.uniform(0.0, 1.0))) @ _rot([0, 0, 1], heading)
    bearing = rng.uniform(-np.pi, np.pi)
    dist = rng.uniform(3.0, 5.0)
    p_cb = np.array([dist * np.cos(bearing), dist * np.sin(bearing), rng.uniform(-0.5, 1.5)])
    dirs = rng.normal(size=(n_reflectors, 3))
    refl = dirs / np.linalg.norm(dirs, axis=1, keepdims=True) * rng.uniform(0.03, 0.33, (n_reflectors, 1))
    labels = [f"SMR{k + 1}" for k in range(n_reflectors)]
    noise = rng.uniform(*noise_mm) * 1e-3
    los_ratio = 1.0 if rng.uniform() < 0.5 else rng.uniform(0.3, 1.0)
    tip = model.getJointId("joint6")
    draws = {}
    for j in (1, 2):
        n = int(rng.integers(poses[0], poses[1] + 1))
        span = np.radians(rng.uniform(*sweep_deg))
        lo_j, hi_j = lo[j - 1], hi[j - 1]
        centre = rng.uniform(lo_j + span / 2, hi_j - span / 2)
        if rng.uniform() < 0.5:
            offs = np.linspace(-span / 2, span / 2, n) + rng.uniform(-0.1, 0.1, n) * span / n
        else:
            offs = np.sort(np.r_[-span / 2, span / 2, rng.uniform(-span / 2, span / 2, n - 2)])
        if rng.uniform() < 0.5:
            offs = offs[::-1]
        q_held = rng.uniform(lo + 0.05 * (hi - lo), hi - 0.05 * (hi - lo))
        Q = np.tile(q_held, (n, 1))
        Q[:, j - 1] = centre + offs
        t = np.cumsum(rng.uniform(5.0, 9.0, n)) + 100.0 * j
        P = np.empty((n, n_reflectors, 3))
        for i, q in enumerate(Q):
            pin.forwardKinematics(model, data, q)
            M = data.oMi[tip]
            P[i] = (R_cb @ (M.rotation @ refl.T + M.translation[:, None])).T + p_cb
        los = P / np.linalg.norm(P, axis=2, keepdims=True)
        e = rng.normal(size=P.shape)
        e_los = np.sum(e * los, axis=2, keepdims=True) * los
        s_t = noise * np.sqrt(3.0 / (2 + los_ratio ** 2))      # 3-D RMS = sqrt(3) x noise per coordinate
        P = P + s_t * (e - e_los) + los_ratio * s_t * e_los
        q_urdf = Q.copy()
        for k in ((0, 1) if sign_in_all_logs else (j - 1,)):    # a sign flipped in the log: -q
            q_urdf[:, k] = angle_sign[k] * q_urdf[:, k]
        q_log = np.linalg.solve(C, q_urdf.T).T
        _write_trc(root / "calib" / f"joint-{j}.trc", t, 1e3 * P, labels)
        _write_log(root / "calib" / f"joint-{j}.csv", t, q_log)
        draws[j] = {"poses": n, "sweep_deg": float(np.degrees(span))}
    coupling = ("coupling = [" + ", ".join("[" + ", ".join(f"{x:g}" for x in row) + "]" for row in C) + "]\n"
                if coupled else "")
    (root / "campaign.toml").write_text(
        'format = 1\nname = "tracker"\n\n[robot]\nurdf = "robot/arm.urdf"\ndrives = "robot/drives.toml"\n'
        + coupling + "\n"
        f"[markers]\nlink6 = [{', '.join(chr(34) + lb + chr(34) for lb in labels)}]\n\n"
        '[[calib]]\njoint = 1\nmarkers = "calib/joint-1.trc"\nlog = "calib/joint-1.csv"\n\n'
        '[[calib]]\njoint = 2\nmarkers = "calib/joint-2.trc"\nlog = "calib/joint-2.csv"\n')
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R_cb, p_cb
    return {"T": T, "noise_mm": 1e3 * noise, "los_ratio": los_ratio, "robot": robot, "coupled": coupled, "draws": draws,
            "offset_mm": 1e3 * float(np.linalg.norm(delta))}

# ---------------------------------------------------------------------------------------
# judging from calib.json alone
# ---------------------------------------------------------------------------------------
def _log_rotation(R):
    """Rotation vector of R (inverse Rodrigues)."""
    c = np.clip((np.trace(R) - 1) / 2, -1, 1)
    a = np.arccos(c)
    w = np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]])
    if a < 1e-9:
        return 0.5 * w
    return a / (2 * np.sin(a)) * w


def judge(doc: dict, T_true: np.ndarray) -> dict:
    """Mahalanobis distances of the truth under the reported covariance (order rotvec, origin;
    perturbation ``R_true = exp([w]) R_est``, ``p_true = p_est + dp``, camera frame)."""
    T = np.array(doc["T_camera_base"])
    C = np.array(doc["base_solve"]["cov_rotvec_origin"])
    w = _log_rotation(T_true[:3, :3] @ T[:3, :3].T)
    dp = T_true[:3, 3] - T[:3, 3]
    x = np.r_[w, dp]
    reg = doc.get("region95") or {}
    q3o = reg.get("origin_d2", CHI2_95[3])
    q3r = reg.get("rotation_d2", CHI2_95[3])
    q6 = reg.get("pose_d2", CHI2_95[6])
    d_o = float(dp @ np.linalg.solve(C[3:, 3:], dp))
    d_r = float(w @ np.linalg.solve(C[:3, :3], w))
    d_p = float(x @ np.linalg.solve(C, x))
    warned = any("do not fit the URDF" in w for w in doc.get("warnings", ()))
    # the Gaussian reading (issue 46): the reported covariance taken as a Gaussian one, chi2
    # quantiles whatever region95 says, as a user without the region's thresholds reads it
    gauss = {"g_origin": d_o <= CHI2_95[3], "g_rotation": d_r <= CHI2_95[3], "g_pose": d_p <= CHI2_95[6]}
    return {**gauss, "in_origin": d_o <= q3o, "in_rotation": d_r <= q3r, "in_pose": d_p <= q6,
            "ratio_origin": d_o / q3o, "ratio_rotation": d_r / q3r,
            "err": x, "std": np.sqrt(np.diag(C)), "misfit_warned": warned}


def run_one(cell: str, seed: int, tmp: Path) -> dict:
    from calib.pipeline import calibrate
    from mocap.io.campaign import load_campaign
    from mocap.io.errors import InputError

    shape, kind = cell.split("-")
    root = tmp / f"{cell}-{seed}"
    if shape.startswith("wide"):
        truth = make_wide_campaign(root, seed, int(shape[4:]), kind == "offset")
        kind = "exact"
    else:
        n, m = (int(x) for x in shape.split("x"))
        truth = make_campaign(root, seed, n, m, kind in ("mismatch", "declared", "trustmis"),
                              los_ratio=LOS_RATIO, deflect=kind.startswith("deflect"))
    opts = ({"urdf_tol_mm": URDF_TOL_MM} if kind in ("declared", "deflecttol") else
            {"urdf_model_error": False} if kind in ("trusted", "trustmis") else
            {"deflection": True} if kind == "deflectcomp" else {})
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("error", RuntimeWarning)      # a leaking numpy warning fails the run
            res = calibrate(load_campaign(root), **opts)
        doc = json.loads(json.dumps(res.to_dict()))
    except InputError as exc:
        return {"refused": str(exc)}
    finally:
        shutil.rmtree(root, ignore_errors=True)
    out = judge(doc, truth["T"])
    out["truth"] = {k: v for k, v in truth.items() if k != "T"}
    out["d2"] = doc["region95"]
    return out


def summarise(cell: str, rows: list) -> dict:
    ok = [r for r in rows if "refused" not in r]
    out = {"cell": cell, "runs": len(rows), "refused": len(rows) - len(ok)}
    if not ok:
        return out
    for k in ("origin", "rotation", "pose"):
        out[k] = 100.0 * np.mean([r[f"in_{k}"] for r in ok])
        out[f"gauss_{k}"] = 100.0 * np.mean([r[f"g_{k}"] for r in ok])
    E = np.array([r["err"] for r in ok])
    S = np.array([r["std"] for r in ok])
    emp = np.sqrt(np.mean(E ** 2, axis=0))          # empirical spread per axis (RMS about the truth)
    rep = np.sqrt(np.mean(S ** 2, axis=0))          # reported std per axis (RMS over runs)
    out["std_ratio"] = (rep / emp).tolist()         # rotvec x, y, z then origin x, y, z
    out["origin_err_mm"] = 1e3 * float(np.sqrt(np.mean(np.sum(E[:, 3:] ** 2, axis=1))))
    out["rot_err_deg"] = float(np.degrees(np.sqrt(np.mean(np.sum(E[:, :3] ** 2, axis=1)))))
    warned = np.array([r["misfit_warned"] for r in ok])
    out["warned"] = 100.0 * float(np.mean(warned))
    quiet = [r for r, w in zip(ok, warned) if not w]
    out["quiet_pose"] = 100.0 * float(np.mean([r["in_pose"] for r in quiet])) if quiet else float("nan")
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="40 runs per cell")
    ap.add_argument("--runs", type=int, default=None, help="runs per cell (default 200, --quick 40)")
    ap.add_argument("--cells", default=",".join(WIDE_CELLS),
                    help="comma-separated cells: wide{1,3}-{exact,offset} (default), POSESxREFLECTORS-KIND "
                         "(the PA10 cells), or 'pa10' for all the PA10 cells")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--los-ratio", type=float, default=0.5,
                    help="line-of-sight over transverse noise (1: white noise; default 0.5)")
    args = ap.parse_args(argv)
    globals()["LOS_RATIO"] = args.los_ratio
    runs = args.runs or (40 if args.quick else 200)
    cells = [x for c in args.cells.split(",") if c for x in (CELLS if c == "pa10" else [c])]
    print(f"== coverage of the reported 95 % region: {runs} runs per cell (tracker sweeps) ==")
    print("cell            runs refused  origin rotation   pose | reported/empirical std: "
          "rot x,y,z  origin x,y,z | rms err mm  deg   s | Gaussian reading: origin rotation pose")
    t_all = time.time()
    fails = {k: [] for k in ("exact", "mismatch", "offset", "declared", "trusted", "trustmis", "deflect",
                             "deflecttol", "deflectcomp")}
    with tempfile.TemporaryDirectory() as td:
        for ci, cell in enumerate(cells):
            t0 = time.time()
            kind = cell.split("-")[1]
            rows = [run_one(cell, 100000 * (ci + 1) + args.seed * 10007 + s, Path(td)) for s in range(runs)]
            s = summarise(cell, rows)
            if "origin" not in s:
                print(f"{cell:15s} {s['runs']:4d} {s['refused']:7d}  (all refused)")
                fails[kind].append(cell)
                continue
            ratio = " ".join(f"{x:4.2f}" for x in s["std_ratio"])
            print(f"{cell:15s} {s['runs']:4d} {s['refused']:7d} {s['origin']:6.1f}% {s['rotation']:7.1f}% "
                  f"{s['pose']:5.1f}% | {ratio} | {s['origin_err_mm']:9.4f} {s['rot_err_deg']:.5f} "
                  f"{time.time() - t0:4.0f} | {s['gauss_origin']:5.1f}% {s['gauss_rotation']:5.1f}% "
                  f"{s['gauss_pose']:5.1f}%"
                  + (f" | chi2 misfit warned in {s['warned']:.1f} % of runs; pose covered in "
                     f"{s['quiet_pose']:.1f} % of the others" if kind == "trustmis" else ""), flush=True)
            if kind in ("trustmis", "deflect", "deflecttol"):     # informational cells: no goal
                continue
            cov = [s[k] for k in ("origin", "rotation", "pose")]
            # declared tolerances are type-B bounds: judged as conservative (>= 90 %) only
            if cell.startswith("wide"):     # issue 46: the Gaussian reading holds too
                cov += [s[f"gauss_{k}"] for k in ("origin", "rotation", "pose")]
            cov_ok = all(90.0 <= c <= (100.0 if kind == "declared" else 98.0) for c in cov)
            std_ok = not cell.startswith("3x") or kind in ("declared", "trusted") or \
                all(1 / 1.5 <= x <= 1.5 for x in s["std_ratio"])
            if not (cov_ok and std_ok and s["refused"] == 0):
                fails[kind].append(cell)
    for kind, what in (("exact", "URDF exact (PA10 cells and wide geometry): coverage 90-98 % (origin, rotation, "
                                 "pose; wide cells also in the Gaussian reading), at 3 poses std within 1.5x of "
                                 "the spread"),
                       ("offset", "wide geometry, J1-J2 offset 0-1 mm off the URDF: coverage 90-98 % (origin, rotation, "
                                  "pose; region95 and the Gaussian reading)"),
                       ("mismatch", "J1-J2 offset 0-1 mm off the URDF, default settings: coverage 90-98 % "
                                    "(origin, rotation, pose), at 3 poses std within 1.5x of the spread"),
                       ("declared", "the same with --urdf-tol-mm declared: coverage >= 90 % (conservative)"),
                       ("trusted", "URDF exact and trusted (--trust-urdf): coverage 90-98 %"),
                       ("deflectcomp", "arm deflecting under gravity, --deflection: coverage 90-98 %")):
        if any(c.endswith("-" + kind) for c in cells):
            print(f"goal: {what}: {'PASS' if not fails[kind] else 'FAIL ' + ', '.join(fails[kind])}")
    print(f"total {time.time() - t_all:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
