"""``jointlab info PATH``: what is in a campaign, a marker file or a robot log."""
from __future__ import annotations

import json
from pathlib import Path

from mocap.io.errors import InputError

from ident.cli.main import add_common


def register(sub):
    p = sub.add_parser("info", help="describe a campaign folder, a .trc/.c3d marker file or a robot log .csv")
    p.add_argument("path", type=Path, help="campaign folder (or campaign.toml), .trc, .c3d, .csv or .urdf")
    add_common(p, out=False)
    return p


def marker_info(path: Path) -> dict:
    from mocap.io.markers import read_markers

    return read_markers(path).summary()


def log_info(path: Path) -> dict:
    from mocap.io.robotlog import read_robot_log

    log = read_robot_log(path)
    samp = log.sampling().to_dict()
    return {"path": str(path), "n_samples": log.n_samples, "n_joints": log.n_joints,
            "rate_hz": log.rate_hz, "first_time": float(log.time[0]), "last_time": float(log.time[-1]),
            "sampling": samp, "warnings": samp["warnings"], "columns": list(log.columns())}


def _trial_motion(camp, trial, log, n: int) -> tuple[dict, list]:
    """Peak-to-peak motion per URDF joint and a warning when a joint the trial declares braked
    moves (``fit`` and ``diagnose`` refuse such a trial)."""
    import numpy as np

    from ident.model.record import check_braked

    q = log.qm                                  # URDF joints (Campaign.read_log)
    try:
        return check_braked(trial, q, path=log.source), []
    except InputError as exc:
        lo, hi = np.nanpercentile(q, [0.1, 99.9], axis=0)
        return {str(j + 1): float(hi[j] - lo[j]) for j in range(n)}, [str(exc)]


def campaign_info(path: Path) -> dict:
    from mocap.io.campaign import load_campaign

    camp = load_campaign(path)
    robot = camp.load_robot()
    entries = []
    for kind, name, rec in camp.recordings():
        log = camp.read_log(rec, robot)
        samp = log.sampling()
        e = {"kind": kind, "id": name,
             "markers": str(rec.markers.relative_to(camp.root)) if rec.markers else None,
             "log": str(rec.log.relative_to(camp.root)),
             "duration_s": float(log.time[-1] - log.time[0]),
             "marker_frames": 0, "marker_rate_hz": None,
             "log_samples": log.n_samples, "log_rate_hz": log.rate_hz,
             "sampling": samp.to_dict(), "warnings": list(samp.warnings), "markers_used": 0}
        if rec.markers is not None:
            m = camp.read_markers(rec, robot)
            if kind == "trial":
                _check_trial_labels(camp, rec, m)
            e.update({"marker_frames": m.n_frames, "marker_rate_hz": m.rate_hz,
                      "markers_used": len([lb for lb in camp.link_of_label() if lb in m.labels])})
        if kind == "trial":
            e.update({"joints": list(rec.joints), "load_kg": rec.load_kg, "vmax_frac": rec.vmax_frac,
                      "repetition": rec.repetition, "trial_kind": rec.kind,
                      "unlogged_torque": list(rec.unlogged_torque)})
            p2p, warn = _trial_motion(camp, rec, log, robot.n)
            e["peak_to_peak_rad"] = p2p
            e["warnings"] += warn
        entries.append(e)
    from mocap.urdf import missing_meshes

    from ident.workflow import plan

    p = plan(camp)
    return {"campaign": camp.name, "root": str(camp.root), "robot": robot.describe(),
            "paths": {k: p.reasons[k] for k in p.paths},
            "missing_meshes": missing_meshes(camp.urdf),
            "coupling": None if camp.coupling is None else [list(r) for r in camp.coupling],
            "markers": {k: list(v) for k, v in camp.markers.items()}, "recordings": entries}


def _check_trial_labels(camp, trial, rec) -> None:
    """Every label of a link on a moving joint's side must be in the trial's marker file."""
    missing = [lb for labels in camp.markers.values() for lb in labels if lb not in rec.labels]
    if missing and len(missing) == sum(len(v) for v in camp.markers.values()):
        raise InputError(f"none of the campaign's marker labels is in this file (first: {missing[0]!r}; "
                         f"file has {', '.join(rec.labels[:8])}...)", path=trial.markers, label=missing[0])


def _print_marker(d: dict) -> None:
    print(f"{d['path']}: {d['n_frames']} frames, {d['n_markers']} markers at {d['rate_hz']:g} Hz, "
          f"units {d['units']} (stored as m), time {d['first_time']:.4f} .. {d['last_time']:.4f} s")
    # a header that disagrees with the rows was already said once, as the reader's warning
    # (stderr); it stays in the --json output under header_mismatch
    width = max((len(lb) for lb in d["labels"]), default=5)
    for lb in d["labels"]:
        print(f"  {lb:<{width}}  missing {100 * d['missing_fraction'][lb]:6.2f} %")


def _num(x, spec: str, none: str) -> str:
    """A limit of ``describe()`` for the console: ``none`` where it is null (no limit)."""
    return none if x is None else format(x, spec)


def _print_robot(r: dict, missing_meshes=()) -> None:
    unbounded = sum(1 for j in r["joints"] if j["lower"] is None and j["upper"] is None)
    print(f"robot {r['urdf']}: {r['n_joints']} revolute joints"
          + (f" ({unbounded} continuous: no position limits)" if unbounded else "")
          + f", gravity {r['gravity']}")
    ch = r.get("chain")
    if ch:
        nz = {k: v for k, v in ch["fixed"].items() if v != 0}
        fx = ", ".join(f"{k} = {v:g}" for k, v in nz.items())
        rest = len(ch["fixed"]) - len(nz)
        print(f"  chain {ch['base_link']} -> {ch['tip_link']}; every other joint fixed"
              + (f": {fx}" if fx else "") + (f"{'; ' if fx else ': '}{rest} more at 0" if rest else ""))
    for k, j in enumerate(r["joints"], 1):
        sign = " (motor turns the other way: negative gear ratio)" \
            if r.get("direction") and r["direction"][k - 1] < 0 else ""
        print(f"  joint {k} {j['name']:<12} [{_num(j['lower'], '+.3f', '-inf')}, "
              f"{_num(j['upper'], '+.3f', '+inf')}] rad, max {_num(j['max_velocity'], '.3g', 'inf')} rad/s, "
              f"{_num(j['max_torque'], '.3g', 'inf')} N m, link {j['link']}{sign}")
    if missing_meshes:
        print(f"  meshes: {len(missing_meshes)} mesh file(s) not found (first: {missing_meshes[0]}); "
              "optional: the viewer draws the URDF's primitive shapes or link frames")


def _print_log(d: dict) -> None:
    sp = d["sampling"]
    print(f"{d['path']}: {d['n_samples']} samples of {d['n_joints']} joints, time {d['first_time']:.4f} .. "
          f"{d['last_time']:.4f} s")
    print(f"  step min/median/max {sp['step_min_s'] * 1e3:.4g}/{sp['step_median_s'] * 1e3:.4g}/"
          f"{sp['step_max_s'] * 1e3:.4g} ms (median rate {sp['rate_hz']:.4g} Hz), "
          f"{sp['n_repeated']} repeated rows")
    for w in d["warnings"]:
        print(f"  warning: {w}")
    print(f"  columns: {', '.join(d['columns'])}")


def _print_campaign(d: dict) -> None:
    print(f"campaign {d['campaign']!r} at {d['root']}")
    _print_robot(d["robot"], d.get("missing_meshes", ()))
    if d.get("coupling"):
        print(f"  coupling (q_urdf = coupling @ q_log): {d['coupling']}")
    if d["markers"]:
        print("markers:")
        for link, labels in d["markers"].items():
            print(f"  {link}: {', '.join(labels)}")
    else:
        print("markers: none (a campaign without motion capture: the logged angles are the link angles)")
    print("recordings:")
    for e in d["recordings"]:
        extra = ""
        if e["kind"] == "trial":
            extra = (f" joints {e['joints']} load {e['load_kg']:g} kg vmax {e['vmax_frac']:g} "
                     f"rep {e['repetition']} {e['trial_kind']}")
            if e.get("unlogged_torque"):
                extra += (f"; torque not logged on joints {e['unlogged_torque']} (their angles "
                          "drive the kinematics; nothing is identified for them)")
        mk = (f"{e['marker_frames']} frames @ {e['marker_rate_hz']:g} Hz, " if e["markers"] else "")
        sp = e["sampling"]
        print(f"  {e['kind']:<6} {e['id']:<28} {e['duration_s']:8.2f} s  {mk}{e['log_samples']} log "
              f"samples, step min/median/max {sp['step_min_s'] * 1e3:.3g}/{sp['step_median_s'] * 1e3:.3g}/"
              f"{sp['step_max_s'] * 1e3:.3g} ms, {sp['n_repeated']} repeated rows{extra}")
        for w in e["warnings"]:
            print(f"    warning: {w}")
    if d.get("paths"):
        print("identification paths (ident.workflow.plan): "
              + "; ".join(f"{k} ({why})" for k, why in d["paths"].items()))


def run(args) -> int:
    path: Path = args.path
    if not path.exists():
        raise InputError("no such file or folder", path=path)
    ext = path.suffix.lower()
    if path.is_dir() or path.name == "campaign.toml":
        d = campaign_info(path)
        if args.rrd or args.spawn:
            from mocap.io.campaign import load_campaign
            from viz import make_sink

            from ident.study.view import log_campaign

            with make_sink(str(args.rrd) if args.rrd else None, args.spawn) as sink:
                log_campaign(load_campaign(path), sink)
        printer = _print_campaign
    elif ext in (".trc", ".c3d"):
        d = marker_info(path)
        if args.rrd or args.spawn:
            from mocap.io.markers import read_markers
            from viz import make_sink

            rec = read_markers(path)
            with make_sink(str(args.rrd) if args.rrd else None, args.spawn) as sink:
                sink.points_over_time("markers", rec.time, rec.positions, labels=rec.labels)
        printer = _print_marker
    elif ext == ".csv":
        d = log_info(path)
        printer = _print_log
    elif ext == ".urdf":
        from mocap.robot import Robot

        d = Robot.from_urdf(path).describe()
        printer = _print_robot
    else:
        raise InputError(f"cannot describe a {ext or 'extension-less'} file "
                         "(expected a campaign folder, .trc, .c3d, .csv or .urdf)", path=path)
    if args.json:
        print(json.dumps(d, indent=1))
    else:
        printer(d)
    return 0
