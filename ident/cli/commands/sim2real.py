"""``jointlab sim2real CAMPAIGN --out DIR [--mjcf FILE] [--diagnosis FILE]``: replay the records in
MuJoCo, fit the native joint parameters, add the named effects, export the corrected model.

A shell over the pipeline's ``sim2real`` stage (:mod:`ident.pipeline.stages.sim2real`:
:func:`ident.sim2real.pipeline.sim2real_campaign`, docs/sim2real.md), run once."""
from __future__ import annotations

import json
from pathlib import Path

from ident.cli.main import add_common
from ident.outputs import OutputDir

INPUT_ARGS = ("campaign", "mjcf", "diagnosis")
OUTPUT_ARGS = ("out",)


def register(sub):
    p = sub.add_parser("sim2real", help="replay the records in MuJoCo: the model as given, its fitted "
                                         "native parameters and the named effects; export the model")
    p.add_argument("campaign", type=Path)
    add_common(p, out_required=True)
    p.add_argument("--mjcf", type=Path, metavar="FILE",
                   help="the user's MuJoCo model (default: [robot] mjcf, else MuJoCo's compile of the URDF)")
    p.add_argument("--effects", metavar="SPEC",
                   help="effects to export instead of the diagnosis's: NAME (every joint) or J:NAME,J:NAME")
    p.add_argument("--diagnosis", type=Path, metavar="FILE",
                   help="reuse an earlier diagnosis of this campaign (a diagnosis.json of jointlab "
                        "diagnose or of an earlier sim2real run) instead of running it again")
    p.add_argument("--no-sysid", action="store_true", help="do not run mujoco.sysid beside")
    p.add_argument("--threads", type=int, default=1, help="mujoco.rollout threads (default 1)")
    return p


def settings_from_args(args):
    """The :class:`ident.pipeline.plan.PipelineSettings` of ``jointlab sim2real``'s options
    (checked at construction; ``--effects`` against the robot and ``--diagnosis`` against the
    campaign once they are loaded)."""
    from ident.pipeline.plan import PipelineSettings

    return PipelineSettings(sim2real=True, sim2real_mjcf=args.mjcf, sim2real_effects=args.effects,
                            sim2real_diagnosis=args.diagnosis, sim2real_sysid=not args.no_sysid,
                            sim2real_threads=args.threads)


def run(args) -> int:
    from mocap.io.campaign import load_campaign
    from mocap.io.errors import InputError

    settings = settings_from_args(args)              # option values, before anything else
    try:
        import mujoco  # noqa: F401
    except ImportError:
        raise InputError("jointlab sim2real needs MuJoCo: pip install 'jointlab[mujoco]'") from None
    from ident.pipeline.plan import plan, stage_named
    from ident.pipeline.stage import Context, Runtime, run_stages
    from ident.sim2real.pipeline import parse_effects, read_diagnosis

    camp = load_campaign(args.campaign)
    if args.mjcf is not None and not args.mjcf.is_file():
        raise InputError("MJCF not found", path=args.mjcf)
    robot = camp.load_robot()
    parse_effects(args.effects, robot.n)          # a bad --effects or --diagnosis fails before any work
    if args.diagnosis is not None:
        read_diagnosis(args.diagnosis, camp, robot.n)
    inputs = [camp.root] + [p for p in (args.mjcf, args.diagnosis) if p is not None]
    with OutputDir(args.out, "sim2real", inputs) as od:
        od.check_early(["sim2real.json", "sim2real.md"])
        stage = od.stage()
        # the pipeline's sim2real stage (ident.pipeline.stages.sim2real), run once; forced: the
        # command replays single-joint records too, which a study's stage skips
        done = run_stages(stage_named(plan(camp, settings), "sim2real"), Context(camp, settings, Path(stage)),
                          Runtime(), force=("sim2real",))
        result, paths = done["sim2real"], done.stages["sim2real"].paths
        paths = {k: od.final(v) if isinstance(v, (str, Path)) else v for k, v in paths.items()}
        od.commit(stage)
    rep = result.report
    if args.json:
        print(json.dumps({"out": str(od.root), "errors_0.5": rep["errors"].get("native_effects", {}).get("0.5"),
                          "effects": rep["effects"]["named"]}, indent=1))
    else:
        e = rep["errors"]
        for j in rep["scored_joints"]:
            vals = ", ".join(f"{m} {e[m]['0.5'][str(j)]['pos_rms'] * 1e3:.3g}" for m in e
                             if e[m].get("0.5") and str(j) in e[m]["0.5"])
            print(f"joint {j}: held-out position RMS at 0.5 s (mrad): {vals}")
        print(f"wrote {paths['json']}, {paths['md']} and the model folder")
    return 0
