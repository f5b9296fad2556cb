"""Campaign-level gap diagnosis: group single-joint trials by joint and diagnose each joint."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from mocap.io.angles import read_angles
from mocap.io.errors import InputError
from mocap.io.plausibility import check_angles_dir, check_joints_option, check_seed

from ident.gap.data import build_joint_data, joint_log
from ident.gap.diagnose import DiagnosisSettings, diagnose_joint
from ident.gap.nominal import check_held_nominal, check_nominal
from ident.study.executor import progress_bars


def read_angles_csv(path: str | Path) -> tuple[np.ndarray, dict]:
    """An ``angles/<trial id>.csv`` (FORMAT.md) -> (t, {j: q}), read by the one angles reader
    :func:`mocap.io.angles.read_angles`."""
    tr = read_angles(path)
    return tr.time, tr.q


def load_angles_dir(angles_dir: str | Path, trials) -> dict:
    """trial id -> (t, {joint: q}) for every trial with a CSV in ``angles_dir``."""
    angles_dir = Path(angles_dir)
    out = {}
    for t in trials:
        p = angles_dir / f"{t.id}.csv"
        if p.is_file():
            out[t.id] = read_angles_csv(p)
    return out


def diagnose_single_joint_campaign(campaign, robot=None, angles: dict | None = None,
                      settings: DiagnosisSettings = DiagnosisSettings(), joints=None,
                      progress: bool = False) -> tuple[dict, dict]:
    """Diagnose every joint that has single-joint trials.

    ``angles`` maps trial id -> (t_marker, {joint: q_link}) (from ``jointlab mocap`` or the
    mocap solver); without it only the torque channel is diagnosed.
    """
    robot = robot or campaign.load_robot()
    # a joint whose torque was not logged (FORMAT.md ``unlogged_torque``) has nothing to diagnose
    single = [t for t in campaign.trials if len(t.joints) == 1
              and t.joints[0] not in tuple(getattr(t, "unlogged_torque", ()) or ())]
    skipped = [t.id for t in campaign.trials if len(t.joints) != 1]
    by_joint: dict[int, list] = {}
    for t in single:
        by_joint.setdefault(t.joints[0], []).append(t)
    if joints:
        by_joint = {j: v for j, v in by_joint.items() if j in set(joints)}
    if not by_joint:
        raise InputError("no single-joint trials to diagnose", path=campaign.manifest)

    nominal = check_nominal(settings.nominal, by_joint)
    report = {"format": 1, "campaign": campaign.name, "settings": settings.to_dict(), "joints": {},
              "skipped_trials": skipped, "link_angles": angles is not None and bool(angles),
              "nominal": nominal.describe()}
    items = sorted(by_joint.items())
    if progress_bars(progress):   # a bar on a terminal only, not in captured logs
        from tqdm import tqdm
        items = tqdm(items, desc="diagnose", unit="joint")
    series = {}
    for j, trials in items:
        # one log read at a time, only the joint's columns kept (JointLog)
        logs = [joint_log(campaign.read_log(t, robot), j) for t in trials]
        ang = None
        if angles:
            ang = {tid: (tq[0], tq[1][j]) for tid, tq in angles.items() if j in tq[1]}
        d = build_joint_data(j, trials, logs, robot, ang)
        res = diagnose_joint(d, settings, gear_ratio=robot.drives[j - 1].gear_ratio)
        rep = res.to_dict()
        rep["nominal"] = nominal.describe(d)
        k = float(robot.drives[j - 1].extra.get("stiffness", 0.0) or 0.0)
        rep["nominal"]["joint_model"] = (
            {"kind": "rigid", "text": "no stiffness declared: rigid joint, everything on the motor state"}
            if d.friction_side == "rigid" else
            {"kind": "flexible", "stiffness": k, "friction_side": d.friction_side,
             "text": f"flexible joint at the declared stiffness {k:g} N m/rad (thesis eq. 2-1, 2-2): "
                     f"rigid-body terms on the link state, friction at the {d.friction_side} side of the "
                     "spring (chosen by the held-out nominal RMS)"})
        if not d.has_transmission:
            rep["note_transmission"] = "no link angles: transmission channel (compliance, backlash, time_offset) not diagnosed"
        series[str(j)] = res.series
        report["joints"][str(j)] = rep
    return report, series


def check_diagnose_options(campaign, *, nominal, seed, joints=None, angles=None) -> None:
    """``jointlab diagnose``: held ``--nominal`` values, ``--joints`` of the robot, an
    ``--angles`` folder that fits the campaign."""
    check_held_nominal(nominal)
    check_seed(seed)
    if not joints and angles is None:
        return
    robot = campaign.load_robot()
    check_joints_option(joints, robot)
    if angles is not None:
        check_angles_dir(angles, campaign, robot)
