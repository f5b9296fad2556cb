"""The ``calib`` stage: the camera-to-base calibration from the ``[[calib]]`` sweeps (thesis ch. 3,
eq. 3-1 to 3-3; :func:`ident.workflow.calibrate`), written as ``calib.json``."""
from __future__ import annotations

from ident import workflow
from ident.pipeline.stage import Stage


def skip(ctx) -> str | None:
    """No sweeps: nothing to calibrate."""
    return None if ctx.campaign.calib else "no [[calib]] sweeps"


def inputs(ctx) -> dict:
    """The campaign (its sweeps and robot) and the calibration's options."""
    s = ctx.settings
    return {"campaign": ctx.campaign, "method": s.calib_method, "noise_mm": s.calib_noise_mm,
            "min_sweep_deg": s.calib_min_sweep_deg, "cross_check": s.calib_cross_check,
            "urdf_tol_mm": s.calib_urdf_tol_mm, "trust_urdf": s.calib_trust_urdf,
            "deflection": s.calib_deflection}


def run(inp: dict, rt) -> workflow.CalibrationResult:
    """:func:`ident.workflow.calibrate` on the declared inputs."""
    inp = dict(inp)
    return workflow.calibrate(inp.pop("campaign"), sink=rt.sink, **inp)


def write(result: workflow.CalibrationResult, inp: dict, folder, rt) -> dict:
    """``calib.json``."""
    return {"calib": result.write(folder)}


STAGE = Stage("calib", inputs, run, write, skip=skip, output="calib.json")
