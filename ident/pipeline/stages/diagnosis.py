"""The ``diagnosis`` stage: the sim-to-real gap diagnosis of every joint, single-joint trials per
joint and multi-joint records over their motion cycles, one document
(:func:`ident.workflow.diagnose_campaign`), written as ``diagnosis.json``, ``diagnosis.md`` and
its plots."""
from __future__ import annotations

from ident import workflow
from ident.pipeline.stage import Stage
from ident.pipeline.stages.fits import angles_folder


def enabled(settings) -> bool:
    """``settings.diagnose``."""
    return bool(settings.diagnose)


def inputs(ctx) -> dict:
    """The campaign, the link angles (``settings.angles``, the ``mocap`` stage's, else solved
    here when ``markers`` and ``mocap``), the diagnosis settings, the joints."""
    s = ctx.settings
    return {"campaign": ctx.campaign, "angles": angles_folder(ctx), "markers": s.markers and s.mocap,
            "settings": s.diagnosis, "joints": None if s.joints is None else list(s.joints)}


def run(inp: dict, rt) -> workflow.CampaignDiagnosis:
    """:func:`ident.workflow.diagnose_campaign`."""
    return workflow.diagnose_campaign(inp["campaign"], angles=inp["angles"], markers=inp["markers"],
                                      settings=inp["settings"], joints=inp["joints"], sink=rt.sink,
                                      progress=rt.progress)


def write(result: workflow.CampaignDiagnosis, inp: dict, folder, rt) -> dict:
    """``diagnosis.json`` (its one writer,
    :meth:`ident.gap.campaign_diagnosis.CampaignDiagnosis.to_dict`), ``diagnosis.md``, the plots."""
    return result.write(folder, rt.sink)


STAGE = Stage("diagnosis", inputs, run, write, enabled=enabled, output="diagnosis/diagnosis.json")
