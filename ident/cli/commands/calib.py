"""``jointlab calib CAMPAIGN --out DIR``: camera-to-base calibration from the joint 1/2 sweeps."""
from __future__ import annotations

import json
import sys
from pathlib import Path

from ident.cli.main import add_common
from ident.outputs import OutputDir


def register(sub):
    p = sub.add_parser("calib", help="place the robot base in the camera frame from the [[calib]] sweeps "
                                     "(writes calib.json)")
    p.add_argument("campaign", type=Path, help="campaign folder (or its campaign.toml)")
    add_common(p, out_required=True)
    p.add_argument("--method", choices=("auto", "cluster", "circle"), default="auto",
                   help="axis estimator: rigid-cluster screw axis, per-marker circles (one marker: the "
                        "circle-point method), or auto (default: cluster with 3+ markers, else circle)")
    p.add_argument("--noise-mm", type=float, default=None, metavar="MM",
                   help="3-D RMS marker noise for the Cramer-Rao bound (default: estimated from the fit "
                        "residuals; e.g. 0.85 for the thesis's mocap system, ~0.05 for a laser tracker)")
    p.add_argument("--urdf-tol-mm", type=float, default=0.0, metavar="MM",
                   help="declared standard uncertainty of the URDF's joint-axis placement (each axis line's "
                        "shift per direction across it): a floor on the model error estimated from the "
                        "measured J1-J2 discrepancy (default 0: the estimated one only; see "
                        "docs/calibration.md)")
    p.add_argument("--trust-urdf", action="store_true",
                   help="trust the URDF's J1-J2 axis offset and angle as exact (a kinematically "
                        "calibrated robot): no model error is estimated from the measured J1-J2 "
                        "discrepancy, so the base is more precise when the URDF is right and biased, "
                        "with an uncertainty that leaves the bias out, when it is not (a chi2 misfit "
                        "then warns); --urdf-tol-mm still applies (docs/calibration.md)")
    p.add_argument("--deflection", action="store_true",
                   help="undo the joints' static deflection under gravity at the stiffness declared in "
                        "drives.toml before placing the base (markers on links beyond the swept joint "
                        "of an arm that gives under gravity; a first placement, the markers moved, a "
                        "second placement; docs/calibration.md)")
    p.add_argument("--min-sweep-deg", type=float, default=15.0, metavar="DEG",
                   help="refuse sweeps shorter than this (default 15)")
    p.add_argument("--cross-check", action="store_true",
                   help="also solve the hand-eye/robot-world peer (distal marker cluster + encoder "
                        "angles) and report the difference in calib.json")
    return p


def settings_from_args(args):
    """The :class:`ident.pipeline.plan.PipelineSettings` of ``jointlab calib``'s options (checked
    at construction: ``--noise-mm``, ``--min-sweep-deg``, ``--urdf-tol-mm`` ranges)."""
    from ident.pipeline.plan import PipelineSettings

    return PipelineSettings(calib_method=args.method, calib_noise_mm=args.noise_mm,
                            calib_min_sweep_deg=args.min_sweep_deg, calib_cross_check=args.cross_check,
                            calib_urdf_tol_mm=args.urdf_tol_mm, calib_trust_urdf=args.trust_urdf,
                            calib_deflection=args.deflection)


def run(args) -> int:
    from mocap.io.campaign import load_campaign
    from viz import make_sink

    from ident.pipeline.plan import plan, stage_named
    from ident.pipeline.stage import Context, Runtime, run_stages

    settings = settings_from_args(args)
    camp = load_campaign(args.campaign)
    with OutputDir(args.out, "calib", [camp.root]) as od:
        od.check_early(["calib.json"])
        stage = od.stage()
        with make_sink(str(args.rrd) if args.rrd else None, args.spawn) as sink:
            # the pipeline's calib stage (ident.pipeline.stages.calib), run once
            done = run_stages(stage_named(plan(camp, settings), "calib"), Context(camp, settings, stage),
                              Runtime(sink=sink), force=("calib",))
        result = done["calib"]
        path = od.final(done.stages["calib"].paths["calib"])
        od.commit(stage)
    for w in result.warnings:
        print(f"jointlab: warning: {w}", file=sys.stderr)
    if args.json:
        print(json.dumps(result.to_dict(), indent=1))
    else:
        print(result.markdown(warnings=False))
        he = result.result.extra.get("handeye")
        if he:
            print(f"\nhand-eye cross-check ({he['link']}): {he['difference_origin_mm']:.4f} mm, "
                  f"{he['difference_rotation_deg']:.5f} deg from the axis solution; marker rms {he['rms_mm']:.3f} mm")
        print(f"\nwrote {path}")
    return 0
