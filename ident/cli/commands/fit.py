"""``jointlab fit CAMPAIGN --out DIR [--angles DIR] --models cv,stribeck,hyperbolic,arctan,dm1,dm2
[--export-c DIR [--export-dt S]] [--rrd FILE]``:

* ``cv``, ``stribeck``, ``hyperbolic``: friction fits through the one-link model (thesis eq. 2-4)
  for every trial and moving joint (:func:`ident.thesis.campaign_fit.fit_campaign`), written as
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

Both sets of models may be asked at once."""
from __future__ import annotations

import json
from pathlib import Path

from mocap.io.errors import InputError

from ident.cli.main import add_common
from ident.outputs import OutputDir, cap_workers


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
    p.add_argument("--v-zero", default="auto", metavar="FRAC",
                   help="multi-joint records: the low-speed cut; 'auto' (default): per joint, the "
                        "largest of the velocity noise floor, the residual knee and the end of the "
                        "friction's sign transition (docs/vendor.md); a number: rows slower than "
                        "FRAC x the joint's 99th-percentile speed are left out of the friction fit")
    p.add_argument("--export-c", type=Path, default=None, metavar="DIR",
                   help="write the fitted models as C99 (jl_friction.h/.c) into DIR")
    p.add_argument("--export-dt", type=float, default=None, metavar="S",
                   help="controller sample time of the exported dynamic models, s (default: the "
                        "sample time of the identification data)")
    add_common(p, out_required=True)
    return p


def run(args) -> int:
    from mocap.io.campaign import load_campaign

    from ident.indri.campaign_fit import DYNAMIC_MODELS
    from ident.model.onelink import model_class

    args.workers = cap_workers(args.workers)
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
    route_note = None
    if "arctan" in dyn_models and not any(t.kind == "constant_velocity" and len(t.joints) == 1
                                          for t in camp.trials):
        # Indri & Trapani fit arctan to constant-velocity moves (data set 1); without them the
        # static arctan law is fitted per trial like the thesis's static laws (eq. 2-4)
        dyn_models = tuple(m for m in dyn_models if m != "arctan")
        one_models = one_models + ("arctan",)
        route_note = ("arctan: no constant_velocity trials (Indri & Trapani data set 1): fitted "
                      "per trial through the one-link model (eq. 2-4) with the static laws")
    dyn_skip_note = None
    if dyn_models:
        from ident.indri.campaign_fit import feasible_models, missing_data_sets

        kinds = {t.kind for t in camp.trials if len(t.joints) == 1}
        if not feasible_models(dyn_models, kinds):
            dyn_skip_note = (f"{', '.join(dyn_models)} not identified "
                             f"({missing_data_sets(dyn_models, kinds)})")
            if not one_models:
                raise InputError(dyn_skip_note, path=camp.manifest)
            dyn_models = ()
    inputs = [camp.root] + ([args.angles] if args.angles else [])
    if args.angles is not None and not args.angles.is_dir():
        raise InputError("--angles must be a folder", path=args.angles)
    with OutputDir(args.out, "fit", inputs) as od:
        od.check_early(["fits.json"])
        if args.export_c is None:
            return _run_single(args, camp, models, one_models, dyn_models, od, None,
                               (route_note, dyn_skip_note))
        with OutputDir(args.export_c, "fit", inputs, flag="--export-c") as oc:
            return _run_single(args, camp, models, one_models, dyn_models, od, oc,
                               (route_note, dyn_skip_note))


def _run_single(args, camp, models, one_models, dyn_models, od, oc, notes=()) -> int:
    from ident.thesis.campaign_fit import fit_campaign
    from ident.indri.campaign_fit import fit_campaign_dynamic, merge_fits_json

    out, stage = od.root, od.stage()
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
            paths = res.write(stage, plots=not args.no_plots) if res is not None else {}
            if dyn is not None:
                doc = res.to_dict() if res is not None else {"format": 1, "trials": {}, "summary": []}
                paths["fits"] = stage / "fits.json"
                paths["fits"].write_text(json.dumps(merge_fits_json(doc, dyn), indent=1,
                                                    allow_nan=False), encoding="utf-8")
                paths["indri"] = dyn.write_reports(stage, sink=sink)
    finally:
        if executor is not None:
            executor.close()
    paths = {k: od.final(v) if isinstance(v, (str, Path)) else v for k, v in paths.items()}
    exported, export_note = [], None
    if oc is not None:
        cstage = oc.stage()
        exported, export_note = _export_c(cstage, res, dyn, args.export_dt)
        exported = [oc.final(p) for p in exported]
        oc.commit(cstage)
    od.commit(stage)
    if args.json:
        doc = res.to_dict() if res is not None else {"format": 1, "trials": {}, "summary": []}
        if dyn is not None:
            doc = merge_fits_json(doc, dyn)
        print(json.dumps(doc, indent=1, allow_nan=False))
        return 0
    for n in notes:
        if n:
            print(f"note: {n}")
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
        from ident.friction.plausibility import meaning_line

        for m in one_models:
            if meaning_line(m):
                print(f"({meaning_line(m)})")
    if dyn is not None:
        print(f"Indri & Trapani ({', '.join(dyn_models)}) for joints {', '.join(map(str, dyn))} "
              f"-> {paths['fits']}, {out / 'indri'}")
        for n in getattr(dyn, "notes", []):
            print(f"note: {n}")
        for j in dyn:
            ents = dyn.joint_entries(j)
            d = dyn.data[j]
            from ident.friction.plausibility import meaning_line
            from ident.model.multijoint import _pv

            for m, e in ents.items():
                fl = e.get("flags", {})
                pv = ", ".join(f"{k} {_pv(v, fl.get(k))}" for k, v in e["params"].items())
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

    bad = [m for m in models if m not in MODELS]
    if bad:
        raise InputError(f"unknown friction model {bad[0]!r} (known: {', '.join(MODELS)})", label=bad[0])
    if args.export_c is not None:
        raise InputError("--export-c is not available for multi-joint records")
    with OutputDir(args.out, "fit", [camp.root]) as od:
        od.check_early(["fits.json"])
        return _run_multijoint_in(args, camp, models, od)


def _run_multijoint_in(args, camp, models, od) -> int:
    from ident.model.multijoint import fit_multijoint_campaign
    from ident.model.record import RecordSettings

    out, stage = od.root, od.stage()
    try:
        window = args.window if args.window == "auto" else float(args.window)
    except ValueError:
        raise InputError(f"--window must be 'auto' or seconds, got {args.window!r}") from None
    rs = RecordSettings(derivatives=args.derivatives, window_s=window)
    v_zero = args.v_zero
    if v_zero != "auto":
        try:
            v_zero = float(v_zero)
        except ValueError:
            raise InputError(f"--v-zero must be 'auto' or a fraction, got {args.v_zero!r}") from None
        if not 0 <= v_zero < 1:
            raise InputError(f"--v-zero must be 'auto' or a fraction in [0, 1), got {args.v_zero!r}")
    res = fit_multijoint_campaign(camp, models, record=rs, seed=args.seed, v_zero=v_zero,
                                  n_starts=args.starts)
    doc = res.merge_into({"format": 1, "trials": {}, "summary": []})
    (stage / "fits.json").write_text(json.dumps(doc, indent=1, allow_nan=False), encoding="utf-8")
    paths = {k: od.final(v) if isinstance(v, (str, Path)) else v for k, v in res.write(stage).items()}
    od.commit(stage)
    if args.json:
        print(json.dumps(doc, indent=1, allow_nan=False))
        return 0
    print(f"{len(res.fits)} multi-joint record(s), models {', '.join(models)} -> {out / 'fits.json'}, "
          f"{paths['rigidbody']}, {paths['rigidbody_report']}")
    shown: set = set()
    for tid, by_model in res.fits.items():
        pre = res.preprocessing[tid]
        print(f"  {tid}: {res.seconds[tid]:.1f} s; " + "; ".join(pre.get("steps", [])))
        for w in pre.get("warnings", []):
            print(f"  warning: {w}")
        from ident.friction.plausibility import meaning_line
        from ident.model.multijoint import _arm, _pv

        for m, fit in by_model.items():
            if meaning_line(m):
                print(f"    ({meaning_line(m)})")
            for j, e in fit.joints.items():
                fl = e.get("flags", {})
                pv = ", ".join(f"{k} {_pv(v, fl.get(k))}" for k, v in e["params"].items())
                arm = _arm(e["armature"], fl.get("armature"))
                print(f"    joint {j} {m}: {pv}; offset {e['offset']:.4g}, armature "
                      f"{arm}; rms {e['rms']:.4g}, held-out {e['heldout_rms']:.4g} N m"
                      + (f" [{e['implausible']}]" if e.get("implausible") else ""))
            for k, v in fit.motors.items():
                print(f"    coupled motor {k} ({m} fit): " + ", ".join(f"{kk} {vv:.4g}" for kk, vv in v.items()))
            for n in fit.notes:
                if n not in shown:             # a note shared by every model, printed once
                    print(f"note: {n}")
                    shown.add(n)
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
                    "Ts/2 (ident.indri.estimator), re-identify at the controller's rate")
    if res is not None:
        for e in res.entries:
            tree.setdefault(e.task.trial, {}).setdefault(str(e.task.joint), {}).update(
                {m: f for m, f in e.fits.items() if m == "cv"})
    try:
        return export_models_c(tree, out_dir, dt=dt), note
    except ValueError as exc:
        raise InputError(f"--export-c: {exc}", path=out_dir) from None
