"""``jointlab coastdown CAMPAIGN --out DIR``: Coulomb and viscous friction from coast-down trials.

A shell over the pipeline's ``coastdown`` stage (:mod:`ident.pipeline.stages.coastdown`: the
estimator of :func:`ident.coastdown.campaign_analysis.analyse_campaign`), run once."""
from __future__ import annotations

import json
from pathlib import Path

from ident.cli.main import add_common
from ident.outputs import OutputDir


def register(sub):
    p = sub.add_parser("coastdown", help="Coulomb + viscous friction from the kind = \"coastdown\" trials "
                                         "(coastdown.json, coastdown.md, plots)")
    p.add_argument("campaign", type=Path, help="campaign folder (or its campaign.toml)")
    add_common(p, out_required=True)
    p.add_argument("--joints", type=lambda s: tuple(int(x) for x in s.split(",")),
                   default=(), help="joints to identify, e.g. 5 or 1,5 (default: all)")
    p.add_argument("--no-plots", action="store_true", help="skip the PNG decay curves")
    return p


def settings_from_args(args):
    """The :class:`ident.pipeline.plan.PipelineSettings` of ``jointlab coastdown``'s options
    (checked at construction; whether the robot has the ``--joints`` is checked once it is
    loaded)."""
    from ident.pipeline.plan import PipelineSettings

    return PipelineSettings(joints=tuple(args.joints) or None, plots=not args.no_plots)


def run(args) -> int:
    from mocap.io.campaign import load_campaign
    from viz import make_sink

    from ident.pipeline.plan import plan, stage_named
    from ident.pipeline.stage import Context, Runtime, run_stages
    from mocap.io.plausibility import check_coastdown_campaign

    settings = settings_from_args(args)
    camp = load_campaign(args.campaign)
    check_coastdown_campaign(camp, settings.joints)   # --joints of the robot, every coast-down trial's log
    with OutputDir(args.out, "coastdown", [camp.root]) as od:
        out = od.root
        stage = od.stage()
        with make_sink(str(args.rrd) if args.rrd else None, args.spawn, app_id="jointlab-coastdown") as sink:
            # the pipeline's coastdown stage (ident.pipeline.stages.coastdown), run once
            done = run_stages(stage_named(plan(camp, settings), "coastdown"), Context(camp, settings, stage),
                              Runtime(sink=sink, progress=not args.json), force=("coastdown",))
            report, paths = done["coastdown"], done.stages["coastdown"].paths
        paths = {k: od.final(v) if isinstance(v, (str, Path)) else v for k, v in paths.items()}
        od.commit(stage)
    if args.json:
        d = report.to_dict()
        print(json.dumps({"out": str(out), "joints": d["joints"] and {
            j: {k: v[k] for k in ("Kc", "Kv", "stderr", "separable")} for j, v in d["joints"].items()},
            "trials": {tid: {j: {k: e[k] for k in ("Kc", "Kv", "J", "stderr", "method")} for j, e in js.items()}
                       for tid, js in d["trials"].items()}}, indent=1))
    else:
        for j, r in sorted(report.joints.items()):
            print(f"joint {j}: Kc = {r.Kc:.4g} ± {r.stderr['Kc']:.2g} N m, Kv = {r.Kv:.4g} ± "
                  f"{r.stderr['Kv']:.2g} N m s/rad from {len(r.coasts)} coasts"
                  + ("" if r.separable else " (Kc and Kv not separable)"))
        print(f"wrote {paths['json']} and {paths['md']}")
    return 0
