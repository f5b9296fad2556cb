"""``jointlab mocap CAMPAIGN --out DIR``: link angles of every trial from its markers.

Static-pose references (thesis eq. 3-4), then the batched per-frame solve (eq. 3-5). Writes
``angles/<trial id>.csv`` (FORMAT.md), ``references.json`` and the summary ``mocap.json``
(per trial: frames, RMS residual, flagged frames, per-marker residuals, label swaps).
Without ``--calib`` the camera pose is estimated from the static poses (needs two or more poses
that differ in two non-parallel joints; see :mod:`mocap.references`), else from the campaign's
``[[calib]]`` sweeps with :func:`calib.pipeline.calibrate` (the thesis's joint 1/2 axes).
"""
from __future__ import annotations

import json
from pathlib import Path

from ident.cli.main import add_common
from ident.outputs import OutputDir


def register(sub):
    p = sub.add_parser("mocap", help="link angles of every trial from the markers (static-pose "
                                     "references + batched per-frame solve)")
    p.add_argument("campaign", type=Path, help="campaign folder (or its campaign.toml)")
    p.add_argument("--calib", type=Path, metavar="JSON",
                   help="calib.json with T_camera_base (default: estimate it from the static poses)")
    p.add_argument("--trial", action="append", metavar="ID", help="solve only this trial (repeatable)")
    p.add_argument("--min-markers", type=int, default=2,
                   help="inlier markers needed distal to each solved joint (default 2)")
    p.add_argument("--reject-sigma", type=float, default=5.0,
                   help="outlier threshold in units of the estimated marker noise (default 5)")
    p.add_argument("--refine", action="store_true",
                   help="re-estimate marker positions over each trial's frames (anchored by the "
                        "static poses) together with the angles")
    p.add_argument("--refine-geometry", action="store_true",
                   help="with --refine: also fit small placement offsets (axis tilt and position) "
                        "of the moving joints")
    add_common(p, out_required=True)
    return p


def settings_from_args(args):
    """The :class:`ident.pipeline.plan.PipelineSettings` of ``jointlab mocap``'s options (checked
    at construction: ``--trial`` ids, ``--min-markers``, ``--reject-sigma``)."""
    from ident.pipeline.plan import PipelineSettings

    return PipelineSettings(calib_file=args.calib, trials=tuple(args.trial) if args.trial else None,
                            solver=dict(refine=args.refine, refine_geometry=args.refine_geometry,
                                        min_markers=args.min_markers, reject_sigma=args.reject_sigma))


def run(args) -> int:
    from mocap.io.campaign import load_campaign
    from mocap.io.plausibility import check_calib_json

    settings = settings_from_args(args)       # --trial ids and ranges, before any work
    if args.calib:
        check_calib_json(args.calib)
    camp = load_campaign(args.campaign)
    trials = [camp.trial(t) for t in args.trial] if args.trial else list(camp.trials)
    with OutputDir(args.out, "mocap", [camp.root] + ([args.calib] if args.calib else [])) as od:
        od.check_early(["references.json", "mocap.json"] + [f"angles/{t.id}.csv" for t in trials])
        return _run(args, camp, trials, settings, od)


def _run(args, camp, trials, settings, od) -> int:
    from viz import make_sink

    from ident.pipeline.plan import plan, stage_named
    from ident.pipeline.stage import Context, Runtime, run_stages

    out, stage = od.root, od.stage()
    if args.calib is None and not args.json:
        print("camera pose: from the static pose(s) if they fix it, else from the [[calib]] sweeps "
              "(save it with `jointlab calib`)")
    with make_sink(str(args.rrd) if args.rrd else None, args.spawn) as sink:
        # the pipeline's mocap stage (ident.pipeline.stages.mocap): solve, then write into the stage
        result = run_stages(stage_named(plan(camp, settings), "mocap"), Context(camp, settings, stage),
                            Runtime(sink=sink), force=("mocap",))["mocap"]
    refs, doc = result.references, result.summary()
    od.commit(stage)
    if args.json:
        print(json.dumps(doc, indent=1))
    else:
        import numpy as np

        fit = f", static fit RMS {1e3 * refs.fit_rms_m:.3f} mm" if len(refs.poses) > 1 else ""
        print(f"references: {len(refs.labels)} markers from {len(refs.poses)} static pose(s), camera "
              f"pose from {result.camera_from}{fit}, marker scatter while still "
              f"{1e3 * np.nanmedian(refs.scatter_m):.3f} mm (median)")
        for r in result.trials:
            d = r.to_dict()
            rms = "n/a" if d["rms_mm"] is None else f"{d['rms_mm']:.3f} mm"
            fx = d.get("fixed_markers")
            fx = "" if not fx or fx["rms_mm"] is None else f", fixed links {fx['rms_mm']:.3f} mm"
            print(f"  {r.trial_id:<28} joints {list(r.joints)}  {d['frames']} frames, RMS {rms}, "
                  f"{d['flagged_frames']} flagged, {d['swaps']} swaps repaired{fx}")
        print(f"wrote {out / 'angles'}/*.csv, {out / 'mocap.json'}")
    return 0
