"""``jointlab diagnose CAMPAIGN --out DIR``: where the sim-to-real gap lies and which effect causes it."""
from __future__ import annotations

import json
from pathlib import Path

from ident.cli.main import add_common
from ident.outputs import OutputDir


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
                        "rigid-body corrections refitted")
    p.add_argument("--angles", type=Path, metavar="DIR",
                   help="link angles from `jointlab mocap` (angles/<trial>.csv); default: solve them here")
    p.add_argument("--no-markers", action="store_true", help="torque channel only (ignore marker files)")
    p.add_argument("--joints", type=lambda s: [int(x) for x in s.split(",")], help="joints to diagnose, e.g. 5 or 2,3")
    p.add_argument("--seed", type=int, default=0, help="seed of the randomisation tests and bootstrap")
    return p


def link_angles(campaign, robot, angles_dir=None, sink=None, progress=True):
    """trial id -> (t, {joint: q_link}): from an angles folder, or solved from the markers."""
    from ident.gap.campaign_diagnosis import load_angles_dir

    if angles_dir is not None:
        return load_angles_dir(angles_dir, campaign.trials)
    from ident.study.angles import solve_campaign_angles

    return solve_campaign_angles(campaign, robot, sink=sink, progress=progress)


def _diagnose(camp, robot, angles, settings, joints):
    """Single-joint trials through ``diagnose_campaign``; multi-joint records (one continuous
    record of several joints) through :func:`ident.model.multijoint.diagnose_records`."""
    from ident.gap.campaign_diagnosis import diagnose_campaign
    from ident.model.multijoint import diagnose_records, multijoint_trials

    from ident.model.record import check_campaign_motion

    check_campaign_motion(camp, robot.n)
    multi = multijoint_trials(camp)
    if not multi:
        return diagnose_campaign(camp, robot, angles, settings, joints=joints, progress=True)
    if len(multi) < len(camp.trials):
        report, series = diagnose_campaign(camp, robot, angles, settings, joints=joints, progress=True)
    else:
        report = {"format": 1, "campaign": camp.name, "settings": settings.to_dict(), "joints": {},
                  "skipped_trials": [], "link_angles": False}
        series = {}
    rj, rs = diagnose_records(camp, robot, settings, joints=joints)
    report["joints"].update(rj)
    series.update(rs)
    report["multi_joint_trials"] = [t.id for t in multi]
    report["skipped_trials"] = [t for t in report.get("skipped_trials", []) if t not in set(report["multi_joint_trials"])]
    return report, series


def run(args) -> int:
    from mocap.io.campaign import load_campaign
    from viz import make_sink

    from ident.gap import DiagnosisSettings
    from ident.gap.report import write_report

    from ident.gap.nominal import check_nominal

    camp = load_campaign(args.campaign)
    joints = {j for t in camp.trials for j in t.joints if not args.joints or j in args.joints}
    check_nominal(args.nominal, joints)      # a bad --nominal fails before any work
    from ident.gap.campaign_diagnosis import check_diagnose_options

    check_diagnose_options(args, camp)       # held --nominal values, --joints, --angles
    with OutputDir(args.out, "diagnose", [camp.root] + ([args.angles] if args.angles else [])) as od:
        od.check_early(["diagnosis.json", "diagnosis.md"])
        out = od.root
        robot = camp.load_robot()
        with make_sink(str(args.rrd) if args.rrd else None, args.spawn, app_id="jointlab-diagnose") as sink:
            no_markers = args.no_markers or not camp.has_markers   # marker-less campaigns
            angles = None if no_markers else link_angles(camp, robot, args.angles, sink)
            report, series = _diagnose(camp, robot, angles, DiagnosisSettings(seed=args.seed, nominal=args.nominal), args.joints)
            stage = od.stage()
            paths = write_report(report, series, stage, sink)
        paths = {k: od.final(v) if isinstance(v, (str, Path)) else v for k, v in paths.items()}
        od.commit(stage)
    summary = {j: {"verdict": r["verdict"], "verdict_status": r.get("verdict_status"),
                   "verdict_text": r.get("verdict_text", r["verdict"]),
                   "heldout_rms_nominal": r.get("heldout_rms_nominal")}
               for j, r in report["joints"].items()}
    if args.json:
        print(json.dumps({"out": str(out), "joints": summary}, indent=1))
    else:
        for j, s in summary.items():
            print(f"joint {j}: {s['verdict_text']}")
        print(f"wrote {paths['json']} and {paths['md']}")
    return 0
