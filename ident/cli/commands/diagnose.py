"""``jointlab diagnose CAMPAIGN --out DIR``: where the sim-to-real gap lies and which effect causes it.

A shell over :func:`ident.workflow.diagnose_campaign` (single-joint trials per joint, multi-joint
records per joint over their motion cycles, as :func:`ident.workflow.plan` decides)."""
from __future__ import annotations

import json
import warnings
from pathlib import Path

from ident.cli.main import add_common
from ident.outputs import OutputDir
from mocap.io.errors import InputWarning


def register(sub):
    p = sub.add_parser("diagnose", help="diagnose the sim-to-real gap of a campaign (diagnosis.json, .md, plots)")
    p.add_argument("campaign", type=Path)
    add_common(p, out_required=True)
    p.add_argument("--nominal", default="cv", metavar="SPEC",
                   help="the simulator's friction model the gap is measured against: cv (Coulomb + "
                        "viscous, default), cv_asym, or any model of the friction registry (stribeck, "
                        "hyperbolic, arctan, dm1, dm2: shape parameters fitted on the joint's samples, "
                        "or held with NAME:k=v,...; amplitudes free); or a fits.json (FILE or "
                        "FILE:MODEL): the friction fixed to the file's values per joint, only the "
                        "rigid-body corrections refitted; or mjcf:PATH (a campaign folder or an MJCF "
                        "inside one): the friction fixed to the MuJoCo model's damping, frictionloss "
                        "and armature")
    p.add_argument("--angles", type=Path, metavar="DIR",
                   help="link angles from `jointlab mocap` (angles/<trial>.csv); default: solve them here")
    p.add_argument("--no-markers", action="store_true", help="torque channel only (ignore marker files)")
    p.add_argument("--joints", type=lambda s: [int(x) for x in s.split(",")], help="joints to diagnose, e.g. 5 or 2,3")
    p.add_argument("--seed", type=int, default=0, help="seed of the randomisation tests and bootstrap")
    return p


def _diagnose(camp, robot, angles, settings, joints):
    """(report, series) of :func:`ident.workflow.diagnose_campaign` with ``angles`` already
    solved (trial id -> (t, {joint: q})) or None (torque channel only)."""
    from ident.workflow import diagnose_campaign

    d = diagnose_campaign(camp, robot=robot, angles=angles, markers=angles is not None,
                          settings=settings, joints=joints)
    return d.report, d.series


def settings_from_args(args, camp):
    """The :class:`ident.pipeline.plan.PipelineSettings` of ``jointlab diagnose``'s options
    (checked at construction); ``--nominal mjcf`` names the campaign's own MuJoCo model
    (``[robot] mjcf``, or its URDF compiled)."""
    from ident.gap import DiagnosisSettings
    from ident.pipeline.plan import PipelineSettings

    nominal = f"mjcf:{camp.root}" if args.nominal == "mjcf" else args.nominal
    return PipelineSettings(angles=args.angles, markers=not args.no_markers, joints=args.joints,
                            diagnosis=DiagnosisSettings(seed=args.seed, nominal=nominal))


def run(args) -> int:
    from mocap.io.campaign import load_campaign
    from ident.gap.campaign_diagnosis import check_diagnose_options
    from viz import make_sink

    from ident.gap.nominal import check_nominal
    from ident.pipeline.plan import plan, stage_named
    from ident.pipeline.stage import Context, Runtime, run_stages

    camp = load_campaign(args.campaign)
    settings = settings_from_args(args, camp)
    nominal = settings.diagnosis.nominal
    joints = {j for t in camp.trials for j in t.joints if not settings.joints or j in settings.joints}
    check_nominal(nominal, joints)      # a bad --nominal fails before any work
    # held --nominal values, --joints of the robot, --angles against the campaign
    check_diagnose_options(camp, nominal=nominal, joints=settings.joints, angles=settings.angles)
    with OutputDir(args.out, "diagnose", [camp.root] + ([args.angles] if args.angles else [])) as od:
        od.check_early(["diagnosis.json", "diagnosis.md"])
        out = od.root
        stage = od.stage()
        with make_sink(str(args.rrd) if args.rrd else None, args.spawn, app_id="jointlab-diagnose") as sink:
            # the pipeline's diagnosis stage (ident.pipeline.stages.diagnosis), run once
            done = run_stages(stage_named(plan(camp, settings), "diagnosis"), Context(camp, settings, stage),
                              Runtime(sink=sink, progress=True))
            result, paths = done["diagnosis"], done.stages["diagnosis"].paths
        paths = {k: od.final(v) if isinstance(v, (str, Path)) else v for k, v in paths.items()}
        od.commit(stage)
    summary = result.summary()
    if args.json:
        print(json.dumps({"out": str(out), "joints": summary}, indent=1))
    else:
        for j, s in summary.items():
            print(f"joint {j}: {s['verdict_text']}")
            for note in s["notes"]:
                warnings.warn(InputWarning(f"joint {j}: {note}"))
        print(f"wrote {paths['json']} and {paths['md']}")
    return 0
