"""``jointlab study CAMPAIGN --out DIR [--workers N | --scheduler tcp://HOST:PORT]``: the whole
study of a campaign (calibration, link angles, friction fits, gap diagnosis, report, one .rrd),
resumable: a rerun skips every item whose record verifies, whose input hashes match and whose
outputs are byte for byte what the study wrote (docs/outputs.md)."""
from __future__ import annotations

import json
import sys
from pathlib import Path

from mocap.io.errors import InputError

from ident.cli.main import add_common, check_out_dir


def add_study_options(p) -> None:
    """Options shared by ``study`` and ``demo``."""
    g = p.add_mutually_exclusive_group()
    g.add_argument("--workers", type=int, default=None, metavar="N",
                   help="local worker processes (default: one per core; 1: serial, in this process)")
    g.add_argument("--scheduler", metavar="URL",
                   help="run on a Dask cluster, e.g. tcp://host:8786 (needs the 'dask' extra; the "
                        "campaign and --out must be on a file system every worker sees)")
    p.add_argument("--models", default="cv,stribeck,hyperbolic", help="comma-separated friction models")
    p.add_argument("--starts", type=int, default=8, help="multi-start count of the nonlinear fits")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--sync", choices=("clock", "estimate"), default="clock",
                   help="marker-to-robot clock: as recorded (+ the trial's time_offset) or estimated")
    p.add_argument("--no-mocap", action="store_true", help="skip the angle solve (motor angles stand in)")
    p.add_argument("--no-diagnosis", action="store_true", help="skip the gap diagnosis")
    p.add_argument("--no-plots", action="store_true", help="skip the PNG plots")
    p.add_argument("--no-rrd", action="store_true", help="do not write DIR/study.rrd")
    p.add_argument("--rrd-trials", choices=("first", "all"), default="first",
                   help="trials in the recording: the first repetition of each condition (default) or all")
    p.add_argument("--diagnosis-reps", type=int, default=None, metavar="R",
                   help="the gap diagnosis reads the first R repetitions of every condition (0: all; "
                        "default: the most repetitions within 200000 samples per joint, which keeps "
                        "the study's memory flat in its number of trials)")
    p.add_argument("--urdf-tol-mm", type=float, default=0.0, metavar="MM",
                   help="calibration: declared standard uncertainty of the URDF's joint-axis placement "
                        "(as jointlab calib --urdf-tol-mm)")
    p.add_argument("--trust-urdf", action="store_true",
                   help="calibration: trust the URDF's J1-J2 geometry as exact (as jointlab calib --trust-urdf)")
    p.add_argument("--deflection", action="store_true",
                   help="calibration: undo the joints' static deflection under gravity at the declared "
                        "stiffness (as jointlab calib --deflection)")
    p.add_argument("--sim2real", action="store_true",
                   help="also replay the multi-joint records in MuJoCo (as jointlab sim2real; "
                        "sim2real/, needs the 'mujoco' extra; skipped with the reason otherwise)")
    p.add_argument("--quiet", action="store_true", help="no progress bars")


def register(sub):
    p = sub.add_parser("study", help="run calibration, link angles, friction fits and the gap diagnosis "
                                     "over every trial; report + one .rrd (resumable)")
    p.add_argument("campaign", type=Path, help="campaign folder (or its campaign.toml)")
    add_common(p, out_required=True)
    add_study_options(p)
    return p


def settings_from_args(args):
    """The :class:`ident.study.study.StudySettings` of ``jointlab study``'s options (checked at
    construction), after ``--workers`` (an execution option, not a setting)."""
    from ident.friction.registry import parse_models
    from ident.settings import Interval, check_option
    from ident.study.study import StudySettings

    check_option(args.workers, "--workers", Interval(1, integer=True, none=True))
    return StudySettings(models=parse_models(args.models), n_starts=args.starts, seed=args.seed, sync=args.sync,
                         mocap=not args.no_mocap, diagnose=not args.no_diagnosis, plots=not args.no_plots,
                         rrd=not args.no_rrd, rrd_trials=args.rrd_trials,
                         diagnosis_reps=args.diagnosis_reps, calib_urdf_tol_mm=args.urdf_tol_mm,
                         calib_trust_urdf=args.trust_urdf, calib_deflection=args.deflection,
                         sim2real=getattr(args, "sim2real", False))


def run_from_args(args, campaign_path: Path) -> int:
    from mocap.io.campaign import load_campaign

    from ident.study.executor import make_executor
    from ident.study.study import Study

    settings = settings_from_args(args)
    camp = load_campaign(campaign_path)
    from ident.outputs import check_out_dir as check_study_out
    from mocap.io.plausibility import check_campaign_inputs

    check_campaign_inputs(camp, markers=settings.mocap)      # parseable-but-wrong inputs, first
    if settings.calib_deflection and camp.calib:
        from calib.pipeline import check_deflection_stiffness

        check_deflection_stiffness(camp)
    out = check_study_out(args.out, [camp.root])
    if args.rrd is not None:
        check_out_dir(Path(args.rrd).resolve().parent, [camp.root])
    try:
        executor = make_executor(args.workers, args.scheduler, progress=not args.quiet)
    except ImportError as exc:
        raise InputError(str(exc)) from None
    except (OSError, ValueError, TimeoutError) as exc:
        msg = " ".join(str(exc).split()) or type(exc).__name__
        raise InputError(f"--scheduler: cannot reach the Dask scheduler {args.scheduler}: {msg}") from None
    try:
        res = Study(settings, executor, progress=not args.quiet).run(camp, out, rrd=args.rrd,
                                                                      spawn=args.spawn)
    except BaseException:      # failing or interrupted (Ctrl-C, SIGTERM): stop the workers now
        getattr(executor, "abort", executor.close)()
        raise
    executor.close()
    status = 1 if res.errors else 0        # something failed: say so in the exit status
    if args.json:
        print(json.dumps(res.to_dict(), indent=1))
        return status
    for name, st in res.stages.items():
        extra = f" ({st['note']})" if st["note"] else ""
        print(f"{name:<10} computed {st['computed']:>3}, reused {st['reused']:>3}, failed {st['failed']:>2}, "
              f"{st['seconds']:7.1f} s{extra}")
    for k, v in res.errors.items():
        print(f"failed: {k}: {v}")
    for j, v in res.verdicts.items():
        print(f"joint {j}: {res.verdict_lines.get(j, v)}")
    print(f"wrote {res.paths.get('report')}" + (f" and {res.paths['rrd']}" if "rrd" in res.paths else ""))
    if res.errors:
        print(f"jointlab: {len(res.errors)} item(s) failed (see above and the report)", file=sys.stderr)
    return status


def run(args) -> int:
    return run_from_args(args, args.campaign)
