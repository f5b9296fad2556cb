"""The ``coastdown`` stage: the coast-down estimator on the ``kind = "coastdown"`` trials
(:func:`ident.coastdown.campaign_analysis.analyse_campaign`), written as ``coastdown.json``,
``coastdown.md`` and its plots (``coastdown/`` in a study)."""
from __future__ import annotations

from ident.coastdown.campaign_analysis import (CoastdownSettings, analyse_campaign, coastdown_trials,
                                               write_coastdown)
from ident.pipeline.stage import Stage


def skip(ctx) -> str | None:
    """No coast-down trials."""
    return None if coastdown_trials(ctx.campaign) else "no coast-down trials"


def inputs(ctx) -> dict:
    """The campaign, the plots switch and, where ``settings.joints`` restricts them
    (``jointlab coastdown --joints``), the joints (absent otherwise: a study's cache key of the
    stage is what it was before the key existed)."""
    out = {"campaign": ctx.campaign, "plots": ctx.settings.plots}
    if ctx.settings.joints:
        out["joints"] = [int(j) for j in ctx.settings.joints]
    return out


def run(inp: dict, rt):
    """:func:`ident.coastdown.campaign_analysis.analyse_campaign` (on ``joints`` where given)."""
    return analyse_campaign(inp["campaign"], settings=CoastdownSettings(joints=tuple(inp.get("joints", ()))),
                            progress=rt.progress)


def write(result, inp: dict, folder, rt) -> dict:
    """:func:`ident.coastdown.campaign_analysis.write_coastdown`."""
    return write_coastdown(result, folder, rt.sink, plots=inp["plots"])


STAGE = Stage("coastdown", inputs, run, write, skip=skip, output="coastdown/coastdown.json")
