"""``jointlab fit CAMPAIGN --out DIR [--angles DIR] --models cv,stribeck,hyperbolic [--rrd FILE]``:
friction fits through the one-link model (thesis eq. 2-4) for every trial and moving joint,
written as ``fits.json`` (FORMAT.md), ``fits_diagnostics.json``, the thesis tables
(``tables/``: Tables 5-1..5-3, A, B as CSV and Markdown) and friction-vs-speed plots
(``plots/``)."""
from __future__ import annotations

import json
from pathlib import Path

from mocap.errors import InputError

from ..cli import add_common, check_out_dir


def register(sub):
    p = sub.add_parser("fit", help="fit friction models to every trial of a campaign (eq. 2-4) and tabulate")
    p.add_argument("campaign", type=Path, help="campaign folder or campaign.toml")
    p.add_argument("--angles", type=Path, default=None,
                   help="folder of angles/<trial id>.csv link angles (default: motor angles stand in)")
    p.add_argument("--models", default="cv,stribeck,hyperbolic", help="comma-separated friction models")
    p.add_argument("--starts", type=int, default=8, help="multi-start count of the nonlinear fits")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--sync", choices=("clock", "estimate"), default="clock",
                   help="marker-to-robot clock: as recorded (+ the trial's time_offset) or estimated")
    p.add_argument("--workers", type=int, default=1, help="processes (1: serial)")
    p.add_argument("--no-plots", action="store_true", help="skip the PNG plots")
    add_common(p, out_required=True)
    return p


def run(args) -> int:
    from mocap.campaign import load_campaign

    from ..fitting import fit_campaign
    from ..onelink import model_class

    models = tuple(m.strip() for m in args.models.split(",") if m.strip())
    if not models:
        raise InputError("--models is empty")
    for m in models:
        try:
            model_class(m)
        except KeyError as exc:
            raise InputError(str(exc.args[0]), label=m) from None
    camp = load_campaign(args.campaign, check_files=False)  # marker files are not needed here
    inputs = [camp.root] + ([args.angles] if args.angles else [])
    if args.angles is not None and not args.angles.is_dir():
        raise InputError("--angles must be a folder", path=args.angles)
    out = check_out_dir(args.out, inputs)
    executor = None
    if args.workers > 1:
        from concurrent.futures import ProcessPoolExecutor

        executor = ProcessPoolExecutor(max_workers=args.workers)
    from viz import make_sink

    try:
        with make_sink(str(args.rrd) if args.rrd else None, args.spawn) as sink:
            res = fit_campaign(camp, args.angles, models, sink=sink, executor=executor,
                               n_starts=args.starts, seed=args.seed, sync=args.sync)
    finally:
        if executor is not None:
            executor.shutdown()
    paths = res.write(out, plots=not args.no_plots)
    if args.json:
        print(json.dumps(res.to_dict(), indent=1, allow_nan=False))
        return 0
    print(f"{len(res.entries)} trial-joint fits of {len(models)} models -> {paths['fits']}")
    notes = sorted({n for e in res.entries for n in e.notes})
    for n in notes:
        print(f"note: {n}")
    if res.skipped:
        print(f"skipped (coast-down): {', '.join(res.skipped)}")
    for e in res.entries:
        line = ", ".join(f"{m} rms {f.rms:.3g}" + (f" [{f.degenerate}]" if f.degenerate else "")
                         for m, f in e.fits.items())
        print(f"  {e.task.trial} joint {e.task.joint}: link fit {e.signals['link_fit_rms_deg']:.3f} deg, "
              f"motor fit {e.signals['motor_fit_rms_deg']:.3f} deg; {line}")
    return 0
