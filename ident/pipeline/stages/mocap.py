"""The ``mocap`` stage: link angles of every trial from its markers (thesis eq. 3-4 references,
eq. 3-5 per-frame solve; :func:`ident.workflow.solve_angles`), written as
``angles/<trial>.csv``, ``references.json`` and ``mocap.json``."""
from __future__ import annotations

import numpy as np

from ident import workflow
from ident.pipeline.stage import Stage
from mocap.references import read_calib


def skip(ctx) -> str | None:
    """No markers, or the angle solve switched off."""
    if not ctx.settings.mocap:
        return "switched off: motor angles stand in for link angles"
    if not ctx.campaign.has_markers:
        return "no motion capture in this campaign: the logged angles are the link angles"
    return None


def camera_pose(ctx):
    """``T_camera_base``: the ``calib`` stage's of this run, else ``settings.calib_file``'s, else
    None (the static poses or the sweeps, :func:`ident.workflow.references`)."""
    if "calib" in ctx.results:
        return np.asarray(ctx.results["calib"].T_camera_base, float)
    if ctx.settings.calib_file is not None:
        return np.asarray(read_calib(ctx.settings.calib_file), float)
    return None


def inputs(ctx) -> dict:
    """The campaign, the camera pose, the trials to solve and the solver's settings."""
    s = ctx.settings
    return {"campaign": ctx.campaign, "T_camera_base": camera_pose(ctx),
            "trials": None if s.trials is None else tuple(s.trials), "solver": dict(s.solver)}


def run(inp: dict, rt) -> workflow.CampaignAngles:
    """References then :func:`ident.workflow.solve_angles`."""
    camp = inp["campaign"]
    robot = camp.load_robot()
    refs = workflow.references(camp, robot=robot, T_camera_base=inp["T_camera_base"])
    trials = None if inp["trials"] is None else [camp.trial(t) for t in inp["trials"]]
    return workflow.solve_angles(camp, robot=robot, refs=refs, trials=trials, sink=rt.sink,
                                 progress=rt.progress, **inp["solver"])


def write(result: workflow.CampaignAngles, inp: dict, folder, rt) -> dict:
    """``angles/<trial>.csv``, ``references.json``, ``mocap.json``."""
    return result.write(folder)


STAGE = Stage("mocap", inputs, run, write, skip=skip, output="mocap.json")
