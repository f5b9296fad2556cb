"""The ``coastdown`` stage: the coast-down estimator on the ``kind = "coastdown"`` trials
(:func:`ident.coastdown.campaign_analysis.analyse_campaign`), written as ``coastdown.json``,
``coastdown.md`` and its plots (``coastdown/`` in a study)."""
from __future__ import annotations

from ident.coastdown.campaign_analysis import analyse_campaign, coastdown_trials, write_coastdown
from ident.pipeline.stage import Stage


def skip(ctx) -> str | None:
    """No coast-down trials."""
    return None if coastdown_trials(ctx.campaign) else "no coast-down trials"


def inputs(ctx) -> dict:
    """The campaign and the plots switch."""
    return {"campaign": ctx.campaign, "plots": ctx.settings.plots}


def run(inp: dict, rt):
    """:func:`ident.coastdown.campaign_analysis.analyse_campaign`."""
    return analyse_campaign(inp["campaign"], progress=rt.progress)


def write(result, inp: dict, folder, rt) -> dict:
    """:func:`ident.coastdown.campaign_analysis.write_coastdown`."""
    return write_coastdown(result, folder, rt.sink, plots=inp["plots"])


STAGE = Stage("coastdown", inputs, run, write, skip=skip, output="coastdown/coastdown.json")
