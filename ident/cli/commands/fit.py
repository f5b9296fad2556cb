"""``jointlab fit CAMPAIGN --out DIR [--angles DIR] --models cv,stribeck,hyperbolic,arctan,dm1,dm2
[--export-c DIR [--export-dt S]] [--rrd FILE]``:

* ``cv``, ``stribeck``, ``hyperbolic``: friction fits through the one-link model (thesis eq. 2-4)
  for every trial and moving joint (:func:`ident.thesis.campaign.fit_campaign`), written as
  ``fits.json`` (FORMAT.md), ``fits_diagnostics.json``, the thesis tables (``tables/``: Tables
  5-1..5-3, A, B as CSV and Markdown) and friction-vs-speed plots (``plots/``);
* ``arctan``, ``dm1``, ``dm2``: the Indri & Trapani 2020 identification per joint from the
  campaign's constant_velocity, reversals and excitation trials
  (:func:`ident.indri.campaign.fit_campaign_dynamic`), merged into the same ``fits.json``
  (trial entries plus the joint-level ``joints`` key) with the Indri report in
  ``indri/joint<j>/``;
* ``--export-c DIR``: C99 header and source (:func:`ident.indri.codegen.export_models_c`) with every
  fitted model C can represent (the dynamic models, and the per-trial ``cv`` fits), dynamic
  models at the sample time ``--export-dt`` (default: the identification data's).

Both sets of models may be asked at once."""
from __future__ import annotations

import json
from pathlib import Path

from mocap.io.errors import InputError

from ident.cli.main import add_common, check_out_dir


def register(sub):
    p = sub.add_parser("fit", help="fit friction models to every trial of a campaign (eq. 2-4) and tabulate")
    p.add_argument("campaign", type=Path, help="campaign folder or campaign.toml")
    p.add_argument("--angles", type=Path, default=None,
                   help="folder of angles/<trial id>.csv link angles (default: motor angles stand in)")
    p.add_argument("--models", default="cv,stribeck,hyperbolic",
                   help="comma-separated friction models: cv, stribeck, hyperbolic (one-link, per "
                        "trial) and arctan, dm1, dm2 (Indri & Trapani, per joint)")
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
    p.add_argument("--v-zero", type=float, default=0.02, metavar="FRAC",
                   help="multi-joint records: rows slower than FRAC x the joint's 99th-percentile "
                        "speed are left out of the friction fit")
    p.add_argument("--export-c", type=Path, default=None, metavar="DIR",
                   help="write the fitted models as C99 (jl_friction.h/.c) into DIR")
    p.add_argument("--export-dt", type=float, default=None, metavar="S",
                   help="controller sample time of the exported dynamic models, s (default: the "
                        "sample time of the identification data)")
    add_common(p, out_required=True)
    return p


def run(args) -> int:
    from mocap.io.campaign import load_campaign

    from ident.thesis.campaign import fit_campaign
    from ident.indri.campaign import DYNAMIC_MODELS, fit_campaign_dynamic, merge_fits_json
    from ident.model.onelink import model_class

    models = tuple(dict.fromkeys(m.strip() for m in args.models.split(",") if m.strip()))
    if not models:
        raise InputError("--models is empty")
    dyn_models = tuple(m for m in models if m in DYNAMIC_MODELS)
    one_models = tuple(m for m in models if m not in DYNAMIC_MODELS)
    for m in one_models:
        try:
            model_class(m)
        except KeyError as exc:
            raise InputError(str(exc.args[0]), label=m) from None
    if args.export_dt is not None and not args.export_dt > 0:
        raise InputError("--export-dt must be a positive number of seconds")
    camp = load_campaign(args.campaign, check_files=False)  # marker files are not needed here
    from ident.model.multijoint import multijoint_trials
    from ident.model.record import check_campaign_motion

    check_campaign_motion(camp, camp.load_robot().n)    # braked joints must stay still
    from mocap.io.plausibility import check_campaign_inputs

    check_campaign_inputs(camp, markers=False)          # units, swaps, no motion: one line
    multi = multijoint_trials(camp)
    if multi:
        import dataclasses

        camp_multi = camp
        camp = dataclasses.replace(camp, trials=tuple(t for t in camp.trials if t not in multi))
        if not camp.trials:
            return _run_multijoint(args, camp_multi, models)
        raise InputError(f"the campaign mixes multi-joint trials ({multi[0].id!r}, ...) with "
                         "single-joint ones; fit them from two manifests", path=camp.manifest)
    inputs = [camp.root] + ([args.angles] if args.angles else [])
    if args.angles is not None and not args.angles.is_dir():
        raise InputError("--angles must be a folder", path=args.angles)
    out = check_out_dir(args.out, inputs)
    if args.export_c is not None:
        check_out_dir(args.export_c, inputs)
    executor = None
    if args.workers > 1 and one_models:
        from ident.study.executor import make_executor

        executor = make_executor(args.workers, progress=False)
    from viz import make_sink

    res = dyn = None
    try:
        with make_sink(str(args.rrd) if args.rrd else None, args.spawn) as sink:
            if one_models:
                res = fit_campaign(camp, args.angles, one_models, sink=sink, executor=executor,
                                   n_starts=args.starts, seed=args.seed, sync=args.sync)
            if dyn_models:
                dyn = fit_campaign_dynamic(camp, angles_dir=args.angles, sink=sink, models=dyn_models)
            paths = res.write(out, plots=not args.no_plots) if res is not None else {}
            if dyn is not None:
                doc = res.to_dict() if res is not None else {"format": 1, "trials": {}, "summary": []}
                paths["fits"] = out / "fits.json"
                paths["fits"].write_text(json.dumps(merge_fits_json(doc, dyn), indent=1,
                                                    allow_nan=False), encoding="utf-8")
                paths["indri"] = dyn.write_reports(out, sink=sink)
    finally:
        if executor is not None:
            executor.close()
    exported, export_note = [], None
    if args.export_c is not None:
        exported, export_note = _export_c(args.export_c, res, dyn, args.export_dt)
    if args.json:
        doc = res.to_dict() if res is not None else {"format": 1, "trials": {}, "summary": []}
        if dyn is not None:
            doc = merge_fits_json(doc, dyn)
        print(json.dumps(doc, indent=1, allow_nan=False))
        return 0
    if res is not None:
        print(f"{len(res.entries)} trial-joint fits of {len(one_models)} models -> {paths['fits']}")
        notes = sorted({n for e in res.entries for n in e.notes})
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
    if dyn is not None:
        print(f"Indri & Trapani ({', '.join(dyn_models)}) for joints {', '.join(map(str, dyn))} "
              f"-> {paths['fits']}, {out / 'indri'}")
        for j in dyn:
            ents = dyn.joint_entries(j)
            d = dyn.data[j]
            for m, e in ents.items():
                pv = ", ".join(f"{k} {v:.4g}" for k, v in e["params"].items())
                print(f"  joint {j} {m}: {pv}")
            if d.reversals:
                print(f"  joint {j} reversal data sets: "
                      + ", ".join(f"{r.accel:.3g}" for r in d.reversals) + " rad/s^2")
            for n in d.notes:
                print(f"note: {n}")
    if exported:
        print(f"C export -> {', '.join(str(p) for p in exported)}")
    if export_note:
        print(f"note: {export_note}")
    return 0


def _run_multijoint(args, camp, models) -> int:
    """Multi-joint continuous records: the URDF rigid-body model jointly with per-joint friction
    of every asked model, torque offsets, actuator inertias and coupled motors
    (:mod:`ident.model.rigidbody`)."""
    from ident.friction import MODELS
    from ident.model.multijoint import fit_multijoint_campaign
    from ident.model.record import RecordSettings

    bad = [m for m in models if m not in MODELS]
    if bad:
        raise InputError(f"unknown friction model {bad[0]!r} (known: {', '.join(MODELS)})", label=bad[0])
    if args.export_c is not None:
        raise InputError("--export-c is not available for multi-joint records")
    out = check_out_dir(args.out, [camp.root])
    try:
        window = args.window if args.window == "auto" else float(args.window)
    except ValueError:
        raise InputError(f"--window must be 'auto' or seconds, got {args.window!r}") from None
    rs = RecordSettings(derivatives=args.derivatives, window_s=window)
    res = fit_multijoint_campaign(camp, models, record=rs, seed=args.seed, v_zero_frac=args.v_zero,
                                  n_starts=args.starts)
    doc = res.merge_into({"format": 1, "trials": {}, "summary": []})
    (out / "fits.json").write_text(json.dumps(doc, indent=1, allow_nan=False), encoding="utf-8")
    paths = res.write(out)
    if args.json:
        print(json.dumps(doc, indent=1, allow_nan=False))
        return 0
    print(f"{len(res.fits)} multi-joint record(s), models {', '.join(models)} -> {out / 'fits.json'}, "
          f"{paths['rigidbody']}, {paths['rigidbody_report']}")
    for tid, by_model in res.fits.items():
        pre = res.preprocessing[tid]
        print(f"  {tid}: {res.seconds[tid]:.1f} s; " + "; ".join(pre.get("steps", [])))
        for w in pre.get("warnings", []):
            print(f"  warning: {w}")
        for m, fit in by_model.items():
            for j, e in fit.joints.items():
                pv = ", ".join(f"{k} {v:.4g}" for k, v in e["params"].items())
                arm = "merged" if e["armature"] is None else f"{e['armature']:.4g}"
                print(f"    joint {j} {m}: {pv}; offset {e['offset']:.4g}, armature "
                      f"{arm}; rms {e['rms']:.4g}, held-out {e['heldout_rms']:.4g} N m"
                      + (f" [{e['implausible']}]" if e.get("implausible") else ""))
            for k, v in fit.motors.items():
                print(f"    coupled motor {k} ({m} fit): " + ", ".join(f"{kk} {vv:.4g}" for kk, vv in v.items()))
            for n in fit.notes:
                print(f"note: {n}")
    return 0


def _export_c(out_dir, res, dyn, dt):
    """C export of every representable model: the dynamic models (``joint<j>_<model>``) and
    the per-trial one-link ``cv`` fits (``<trial>_<joint>_cv``)."""
    from ident.indri.codegen import export_models_c

    tree, note = {}, None
    if dyn is not None:
        tree.update(dyn.export_models())
        ident_dt = sorted({round(d.dt, 12) for d in dyn.data.values()})
        if dt is None:
            if len(ident_dt) > 1:
                raise InputError("the joints were identified at different sample times "
                                 f"{ident_dt}; give --export-dt")
            dt = ident_dt[0]
        elif any(abs(dt - x) > 1e-9 * max(dt, x) for x in ident_dt):
            note = (f"--export-dt {dt:g} s differs from the identification sample time "
                    f"{', '.join(f'{x:g}' for x in ident_dt)} s: the discrete damping absorbs "
                    "Ts/2 (ident.indri.framework), re-identify at the controller's rate")
    if res is not None:
        for e in res.entries:
            tree.setdefault(e.task.trial, {}).setdefault(str(e.task.joint), {}).update(
                {m: f for m, f in e.fits.items() if m == "cv"})
    try:
        return export_models_c(tree, out_dir, dt=dt), note
    except ValueError as exc:
        raise InputError(f"--export-c: {exc}", path=out_dir) from None
