"""``jointlab fit CAMPAIGN --out DIR [--angles DIR] --models cv,stribeck,hyperbolic,arctan,dm1,dm2
[--export-c DIR [--export-dt S]] [--rrd FILE]``:

* ``cv``, ``stribeck``, ``hyperbolic``: friction fits through the one-link model (thesis eq. 2-4)
  for every trial and moving joint (:func:`ident.thesis.campaign_fit.fit_onelink_campaign`), written as
  ``fits.json`` (FORMAT.md), ``fits_diagnostics.json``, the thesis tables (``tables/``: Tables
  5-1..5-3, A, B as CSV and Markdown) and friction-vs-speed plots (``plots/``);
* ``arctan``, ``dm1``, ``dm2``: the Indri & Trapani 2020 identification per joint from the
  campaign's constant_velocity, reversals and excitation trials
  (:func:`ident.indri.campaign_fit.fit_campaign_dynamic`), merged into the same ``fits.json``
  (trial entries plus the joint-level ``joints`` key) with the Indri report in
  ``indri/joint<j>/``;
* ``--export-c DIR``: C99 header and source (:func:`ident.indri.codegen.export_models_c`) with every
  fitted model C can represent (the dynamic models, and the per-trial ``cv`` fits), dynamic
  models at the sample time ``--export-dt`` (default: the identification data's).

Both sets of models may be asked at once. A campaign of multi-joint records is fitted with the
URDF rigid-body model and per-joint friction of every asked model (:mod:`ident.model.rigidbody`).
Which path a campaign and each model take is :func:`ident.workflow.plan`'s decision; this module
parses the arguments, runs :func:`ident.workflow.fit_campaign`, writes and prints."""
from __future__ import annotations

import json
from pathlib import Path

from ident.cli.main import add_common
from ident.outputs import OutputDir, cap_workers


def register(sub):
    p = sub.add_parser("fit", help="fit friction models to every trial of a campaign (eq. 2-4) and tabulate")
    p.add_argument("campaign", type=Path, help="campaign folder or campaign.toml")
    p.add_argument("--angles", type=Path, default=None,
                   help="folder of angles/<trial id>.csv link angles (default: motor angles stand in)")
    p.add_argument("--models", default=None,
                   help="comma-separated friction models: cv, stribeck, hyperbolic (one-link, per "
                        "trial) and arctan, dm1, dm2 (Indri & Trapani, per joint); default "
                        "cv,stribeck,hyperbolic, or cv alone for a multi-joint campaign without markers")
    p.add_argument("--starts", type=int, default=8, help="multi-start count of the nonlinear fits")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--sync", choices=("clock", "estimate"), default="clock",
                   help="marker-to-robot clock: as recorded (+ the trial's time_offset) or estimated")
    p.add_argument("--workers", type=int, default=1, help="processes (1: serial)")
    p.add_argument("--no-plots", action="store_true", help="skip the PNG plots")
    p.add_argument("--derivatives", choices=("savgol", "logged"), default="savgol",
                   help="multi-joint records: velocities from the angles (Savitzky-Golay) or the "
                        "logged qd_<j>")
    p.add_argument("--window", default="auto", metavar="S",
                   help="multi-joint records: Savitzky-Golay window, s, or 'auto' (per joint, the "
                        "longest window whose residual stays at the angle noise level)")
    p.add_argument("--v-zero", default="auto", metavar="FRAC",
                   help="multi-joint records: the low-speed cut; 'auto' (default): per joint, the "
                        "largest of the velocity noise floor, the residual knee and the end of the "
                        "friction's sign transition, and for static laws the rows still in the "
                        "presliding rise after each velocity reversal (docs/vendor.md); a number: "
                        "rows slower than FRAC x the joint's 99th-percentile speed are left out of "
                        "the friction fit")
    p.add_argument("--export-c", type=Path, default=None, metavar="DIR",
                   help="write the fitted models as C99 (jl_friction.h/.c) into DIR")
    p.add_argument("--export-dt", type=float, default=None, metavar="S",
                   help="controller sample time of the exported dynamic models, s (default: the "
                        "sample time of the identification data)")
    add_common(p, out_required=True)
    return p


def settings_from_args(args):
    """The :class:`ident.pipeline.plan.PipelineSettings` of ``jointlab fit``'s options (checked
    at construction; ``models`` None: the campaign's default, :func:`ident.workflow.default_models`),
    after ``--export-dt`` (an option of the export, not a setting)."""
    from ident.friction.registry import parse_models
    from ident.pipeline.plan import PipelineSettings
    from ident.settings import Interval, check_option
    from ident.workflow import FitSettings

    models = parse_models(args.models) if args.models is not None else None
    check_option(args.export_dt, "--export-dt", Interval(0, closed="right", none=True, note="s"))
    fit = FitSettings(n_starts=args.starts, seed=args.seed, sync=args.sync, derivatives=args.derivatives,
                      window=args.window, v_zero=args.v_zero)
    return PipelineSettings(models=models, fit=fit, angles=args.angles, plots=not args.no_plots)


def run(args) -> int:
    from dataclasses import replace

    from mocap.io.campaign import load_campaign

    from ident import workflow

    workers = cap_workers(args.workers)
    settings = settings_from_args(args)
    camp = load_campaign(args.campaign, check_files=False)  # marker files are not needed here
    models = settings.models
    if models is None:        # the default follows the campaign's shape (workflow.default_models)
        models, why = workflow.default_models(camp)
        if why:
            print(f"fit: {why}")
    plan = workflow.prepare_fit(camp, models, angles=args.angles, export_c=args.export_c is not None)
    angles = args.angles if plan.uses_angles else None
    # the checked plan routes the models to the fits or the rigidbody stage
    settings = replace(settings, models=tuple(m for ms in plan.models.values() for m in ms) or None,
                       fit_plan=plan, angles=angles)
    inputs = [camp.root] + ([angles] if angles else [])
    with OutputDir(args.out, "fit", inputs) as od:
        od.check_early(["fits.json"])
        if args.export_c is None:
            return _run(args, camp, settings, workers, od, None)
        with OutputDir(args.export_c, "fit", inputs, flag="--export-c") as oc:
            return _run(args, camp, settings, workers, od, oc)


def _run(args, camp, ps, workers, od, oc) -> int:
    """Fit (the pipeline's fits or rigidbody stage: :func:`ident.workflow.fit_campaign`), write,
    export, print."""
    from viz import make_sink

    from ident.pipeline.plan import plan as stage_list, stage_named
    from ident.pipeline.stage import Context, Runtime, run_stages

    plan = ps.fit_plan
    stage = od.stage()
    executor = None
    if workers > 1 and plan.models.get("single_joint"):
        from ident.study.executor import make_executor

        executor = make_executor(workers, progress=False)
    try:
        with make_sink(str(args.rrd) if args.rrd else None, args.spawn) as sink:
            done = run_stages(stage_named(stage_list(camp, ps), "fits", "rigidbody"),
                              Context(camp, ps, stage), Runtime(sink=sink, executor=executor))
            name = "rigidbody" if "multi_joint" in plan.models else "fits"
            result, paths = done[name], done.stages[name].paths
    finally:
        if executor is not None:
            executor.close()
    paths = {k: od.final(v) if isinstance(v, (str, Path)) else v for k, v in paths.items()}
    exported, export_note = [], None
    if oc is not None:
        cstage = oc.stage()
        exported, export_note = result.export_c(cstage, args.export_dt)
        exported = [oc.final(p) for p in exported]
        oc.commit(cstage)
    od.commit(stage)
    if args.json:
        print(json.dumps(result.to_dict(), indent=1, allow_nan=False))
        return 0
    if result.rigidbody is not None:
        _print_rigidbody(result.rigidbody, plan.models["multi_joint"], od.root, paths)
        return 0
    for n in plan.notes:
        print(f"note: {n}")
    if result.onelink is not None:
        _print_onelink(result.onelink, plan.models["single_joint"], paths)
    if result.indri is not None:
        _print_indri(result.indri, plan.models["indri"], od.root, paths)
    if exported:
        print(f"C export -> {', '.join(str(p) for p in exported)}")
    if export_note:
        print(f"note: {export_note}")
    return 0


def _print_onelink(res, one_models, paths) -> None:
    from ident.friction.plausibility import meaning_line

    print(f"{len(res.entries)} trial-joint fits of {len(one_models)} models -> {paths['fits']}")
    own = "presliding cut:"                 # per trial-joint figures, printed under its line
    notes = sorted({n for e in res.entries for n in e.notes if not n.startswith(own)})
    for n in notes:
        print(f"note: {n}")
    if res.skipped:
        print(f"skipped (coast-down): {', '.join(res.skipped)}")
    for e in res.entries:
        line = ", ".join(f"{m} rms {f.rms:.3g}" + (f" [{f.form}]" if f.form else "")
                         + (f" [INVALID: {'; '.join(f.flags)}]" if f.flags else "")
                         for m, f in e.fits.items())
        lf = e.signals["link_fit"]
        print(f"  {e.task.trial} joint {e.task.joint}: link {lf['method']} ({e.signals['link_fit_rms_deg']:.3f} deg "
              f"vs markers), motor {e.signals['motor_fit']['method']} "
              f"{e.signals['motor_fit']['bandwidth_hz']:.3g} Hz; {line}")
        for n in e.notes:
            if n.startswith(own):
                print(f"    {n}")
        for m, fl in getattr(e, "param_flags", {}).items():
            groups: dict = {}
            for k, f in fl.items():       # one line per reason
                val = ("not identifiable" if f["flag"] == "unidentifiable"
                       else f"{e.fits[m].params[k]:.4g} [{f['flag']}]")
                groups.setdefault((f["flag"], f["reason"]), []).append((k, val))
            for (kind, why), kv in groups.items():
                if kind == "unidentifiable":
                    print(f"    {m} {', '.join(k for k, _ in kv)}: not identifiable ({why})")
                else:
                    print(f"    {m} " + ", ".join(f"{k} {v}" for k, v in kv) + f" ({why})")
    for m in one_models:
        if meaning_line(m):
            print(f"({meaning_line(m)})")


def _print_indri(dyn, dyn_models, out, paths) -> None:
    from ident.friction.plausibility import meaning_line
    from ident.model.multijoint import param_cell

    print(f"Indri & Trapani ({', '.join(dyn_models)}) for joints {', '.join(map(str, dyn))} "
          f"-> {paths['fits']}, {out / 'indri'}")
    for n in getattr(dyn, "notes", []):
        print(f"note: {n}")
    for j in dyn:
        ents = dyn.joint_entries(j)
        d = dyn.data[j]
        for m, e in ents.items():
            fl = e.get("flags", {})
            pv = ", ".join(f"{k} {param_cell(v, fl.get(k))}" for k, v in e["params"].items())
            print(f"  joint {j} {m}: {pv}")
            why = {}
            for k, f in fl.items():
                why.setdefault(f["reason"], []).append(k)
            for r, ks in why.items():
                print(f"    {', '.join(ks)}: {r}")
        for m in ents:
            if meaning_line(m):
                print(f"  ({meaning_line(m)})")
        if d.reversals:
            print(f"  joint {j} reversal data sets: "
                  + ", ".join(f"{r.accel:.3g}" for r in d.reversals) + " rad/s^2")
        for n in d.notes:
            print(f"note: {n}")


def _print_rigidbody(res, models, out, paths) -> None:
    """The multi-joint rigid-body fits (:mod:`ident.model.rigidbody`): per record and model the
    per-joint friction, offsets, armatures and coupled motors."""
    from ident.friction.plausibility import meaning_line
    from ident.model.multijoint import armature_cell, param_cell

    print(f"{len(res.fits)} multi-joint record(s), models {', '.join(models)} -> {out / 'fits.json'}, "
          f"{paths['rigidbody']}, {paths['rigidbody_report']}")
    shown: set = set()
    for tid, by_model in res.fits.items():
        pre = res.preprocessing[tid]
        print(f"  {tid}: {res.seconds[tid]:.1f} s; " + "; ".join(pre.get("steps", [])))
        for w in pre.get("warnings", []):
            print(f"  warning: {w}")
        for m, fit in by_model.items():
            if meaning_line(m):
                print(f"    ({meaning_line(m)})")
            for j, e in fit.joints.items():
                fl = e.get("flags", {})
                pv = ", ".join(f"{k} {param_cell(v, fl.get(k))}" for k, v in e["params"].items())
                arm = armature_cell(e["armature"], fl.get("armature"))
                print(f"    joint {j} {m}: {pv}; offset {e['offset']:.4g}, armature "
                      f"{arm}; rms {e['rms']:.4g}, held-out {e['heldout_rms']:.4g} N m"
                      + (f" [{e['implausible']}]" if e.get("implausible") else ""))
            for k, v in fit.motors.items():
                print(f"    coupled motor {k} ({m} fit): " + ", ".join(f"{kk} {vv:.4g}" for kk, vv in v.items()))
            for n in fit.notes:
                if n not in shown:             # a note shared by every model, printed once
                    print(f"note: {n}")
                    shown.add(n)
