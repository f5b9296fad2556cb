"""The ``fits`` stage: the friction fits of the single-joint trials, the one-link model (thesis
eq. 2-4) per trial and joint and the Indri & Trapani models per joint
(:func:`ident.workflow.fit_campaign`), written as ``fits.json`` (+ ``tables/``, ``plots/``,
``indri/``). The multi-joint records are the ``rigidbody`` stage's."""
from __future__ import annotations

from ident import workflow
from ident.pipeline.stage import Stage


def fit_plan(ctx, multi: bool):
    """The fit plan (:func:`ident.workflow.fit_plans`, or ``settings.fit_plan`` a command checked
    before opening its output) of the multi-joint records (``multi``) or of the other trials;
    None when no model goes there."""
    s = ctx.settings
    if s.fit_plan is not None:
        plans = (s.fit_plan,)
    else:
        plans = workflow.fit_plans(ctx.campaign, s.models or workflow.default_models(ctx.campaign)[0])
    for p in plans:
        if ("multi_joint" in p.models) == multi and any(p.models.values()):
            return p
    return None


def part(campaign, ids):
    """The campaign itself when ``ids`` are all its trials, else the copy holding those."""
    if set(ids) == {t.id for t in campaign.trials}:
        return campaign
    return workflow.subset(campaign, ids)


def angles_folder(ctx):
    """The link angles the fits read: ``settings.angles``, else the ``mocap`` stage's folder of
    this run, else None (motor angles stand in)."""
    if ctx.settings.angles is not None:
        return ctx.settings.angles
    if "mocap" in ctx.results:
        return ctx.folder / "angles"
    return None


def skip(ctx) -> str | None:
    """No model routed to the single-joint or Indri & Trapani paths."""
    if fit_plan(ctx, multi=False) is None:
        return "no single-joint trials to fit"
    return None


def inputs(ctx) -> dict:
    """The campaign part, its fit plan, the link angles, the fit settings, the plots switch."""
    p = fit_plan(ctx, multi=False)
    return {"campaign": part(ctx.campaign, p.single_joint), "plan": p,
            "angles": angles_folder(ctx) if p.uses_angles else None,
            "settings": ctx.settings.fit, "plots": ctx.settings.plots}


def run(inp: dict, rt) -> workflow.FitResult:
    """:func:`ident.workflow.fit_campaign` along the plan."""
    return workflow.fit_campaign(inp["campaign"], plan=inp["plan"], angles=inp["angles"],
                                 settings=inp["settings"], sink=rt.sink, executor=rt.executor)


def write(result: workflow.FitResult, inp: dict, folder, rt) -> dict:
    """``fits.json`` and the paths' reports (:meth:`ident.workflow.FitResult.write`)."""
    return result.write(folder, plots=inp["plots"], sink=rt.sink)


STAGE = Stage("fits", inputs, run, write, skip=skip, output="fits/fits.json")
