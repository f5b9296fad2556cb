"""The ``rigidbody`` stage: the multi-joint records' URDF rigid-body model with per-joint friction
(:func:`ident.workflow.fit_campaign` on the ``multi_joint`` path), written as ``fits.json``,
``rigidbody.json`` and ``rigidbody.md`` (``rigidbody/`` in a study)."""
from __future__ import annotations

from ident import workflow
from ident.pipeline.stage import Stage
from ident.pipeline.stages.fits import fit_plan, part


def skip(ctx) -> str | None:
    """No multi-joint records."""
    return None if fit_plan(ctx, multi=True) is not None else "no multi-joint records"


def inputs(ctx) -> dict:
    """The records' part of the campaign, its fit plan, the fit settings."""
    p = fit_plan(ctx, multi=True)
    return {"campaign": part(ctx.campaign, p.multi_joint), "plan": p, "settings": ctx.settings.fit}


def run(inp: dict, rt) -> workflow.FitResult:
    """:func:`ident.workflow.fit_campaign` on the records."""
    return workflow.fit_campaign(inp["campaign"], plan=inp["plan"], settings=inp["settings"],
                                 sink=rt.sink)


def write(result: workflow.FitResult, inp: dict, folder, rt) -> dict:
    """``fits.json``, ``rigidbody.json``, ``rigidbody.md``."""
    return result.write(folder, sink=rt.sink)


STAGE = Stage("rigidbody", inputs, run, write, skip=skip, output="rigidbody/rigidbody.json")
