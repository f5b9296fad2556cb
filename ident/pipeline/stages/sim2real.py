"""The ``sim2real`` stage: the records replayed in MuJoCo, the model as given, its fitted native
joint parameters and the effects the gap diagnosis names
(:func:`ident.sim2real.pipeline.sim2real_campaign`), written as ``jointlab sim2real`` writes it
(:func:`ident.sim2real.report.write_report`: ``sim2real.json``, ``sim2real.md``, the plots,
``model/``; ``sim2real/`` in a study). Asked for with ``settings.sim2real``
(``jointlab study --sim2real``)."""
from __future__ import annotations

import importlib.util

from ident import workflow
from ident.pipeline.stage import Stage
from ident.sim2real.model import captured_warnings
from ident.sim2real.pipeline import parse_effects, read_diagnosis, sim2real_campaign
from ident.sim2real.report import write_report


def enabled(settings) -> bool:
    """``settings.sim2real``."""
    return bool(settings.sim2real)


def skip(ctx) -> str | None:
    """MuJoCo absent, or no multi-joint record to replay."""
    if importlib.util.find_spec("mujoco") is None:
        return "MuJoCo is not installed (pip install 'jointlab[mujoco]')"
    if not workflow.plan(ctx.campaign).multi_joint:
        return "no multi-joint records to replay"
    return None


def inputs(ctx) -> dict:
    """The campaign (its MJCF included), the user's MJCF, the effects, an earlier diagnosis, the
    ``mujoco.sysid`` switch and the rollout threads (``jointlab sim2real``'s options)."""
    s = ctx.settings
    return {"campaign": ctx.campaign, "mjcf": s.sim2real_mjcf, "effects": s.sim2real_effects,
            "diagnosis": s.sim2real_diagnosis, "sysid": s.sim2real_sysid,
            "threads": max(1, int(s.sim2real_threads))}


def run(inp: dict, rt):
    """:func:`ident.sim2real.pipeline.sim2real_campaign` as ``jointlab sim2real`` calls it."""
    camp = inp["campaign"]
    robot = camp.load_robot()
    effects = parse_effects(inp["effects"], robot.n)
    diagnosis = read_diagnosis(inp["diagnosis"], camp, robot.n) if inp["diagnosis"] is not None else None
    return sim2real_campaign(camp, robot, mjcf=inp["mjcf"], effects=effects, diagnosis=diagnosis,
                             sysid=inp["sysid"], nthread=inp["threads"])


def write(result, inp: dict, folder, rt) -> dict:
    """:func:`ident.sim2real.report.write_report` (MuJoCo's warnings captured)."""
    with captured_warnings([]):             # no MUJOCO_LOG.TXT in the working directory
        return write_report(result, folder)


STAGE = Stage("sim2real", inputs, run, write, skip=skip, enabled=enabled, output="sim2real/sim2real.json")
