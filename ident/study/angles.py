"""Link angles for a whole campaign: camera pose, static-pose references, per-trial solves.

The camera pose comes from, in order: a given ``T_camera_base`` (calib.json), the static poses
when they fix it (two or more poses differing in two non-parallel joints), or the campaign's
``[[calib]]`` sweeps (joint 1 then joint 2, the thesis's method).
"""
from __future__ import annotations

from calib.pipeline import calibrate
from mocap.io.errors import InputError
from mocap.references import build_references
from mocap.solve import solve_trial


def campaign_references(campaign, robot, T_camera_base=None):
    """(References, where the camera pose came from)."""

    try:
        return build_references(campaign, robot, T_camera_base), (
            "calib.json" if T_camera_base is not None else "static_poses")
    except InputError as exc:
        # one static pose does not fix the camera; the thesis's way is the joint 1/2 sweeps
        if T_camera_base is not None or not campaign.calib or "cannot be estimated" not in str(exc):
            raise

    T_cb = calibrate(campaign, robot).T_camera_base
    return build_references(campaign, robot, T_cb), "calib_sweeps"


def solve_campaign_angles(campaign, robot, T_camera_base=None, sink=None, progress=True,
                          trials=None) -> dict:
    """trial id -> (marker time, {joint: link angle}) for every trial (flagged frames NaN)."""

    refs, _ = campaign_references(campaign, robot, T_camera_base)
    trials = list(campaign.trials if trials is None else trials)
    it = trials
    if progress:
        from tqdm import tqdm
        it = tqdm(trials, desc="mocap", unit="trial", leave=False)
    out = {}
    for tr in it:
        res = solve_trial(campaign, tr, refs, sink=sink, robot=robot)
        out[tr.id] = (res.time, {j: res.q_link[:, k] for k, j in enumerate(res.joints)})
    return out
