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
    return {"path": str(path), "n_samples": log.n_samples, "n_joints": log.n_joints,
            "rate_hz": log.rate_hz, "first_time": float(log.time[0]), "last_time": float(log.time[-1]),
            "columns": list(log.columns())}


def campaign_info(path: Path) -> dict:
    from mocap.io.campaign import load_campaign
    from mocap.io.markers import read_markers

    camp = load_campaign(path)
    robot = camp.load_robot()
    entries = []
    for kind, name, rec in camp.recordings():
        m = read_markers(rec.markers)
        log = camp.read_log(rec, robot)
        wanted = [lb for lb in camp.link_of_label() if lb in m.labels]
        if kind == "trial":
            _check_trial_labels(camp, rec, m)
        e = {"kind": kind, "id": name, "markers": str(rec.markers.relative_to(camp.root)),
             "log": str(rec.log.relative_to(camp.root)),
             "duration_s": float(log.time[-1] - log.time[0]),
             "marker_frames": m.n_frames, "marker_rate_hz": m.rate_hz,
             "log_samples": log.n_samples, "log_rate_hz": log.rate_hz,
             "markers_used": len(wanted)}
        if kind == "trial":
            e.update({"joints": list(rec.joints), "load_kg": rec.load_kg, "vmax_frac": rec.vmax_frac,
                      "repetition": rec.repetition, "trial_kind": rec.kind})
        entries.append(e)
    return {"campaign": camp.name, "root": str(camp.root), "robot": robot.describe(),
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
    for msg in d.get("header_mismatch", []):
        print(f"  note: {msg}")
    width = max((len(lb) for lb in d["labels"]), default=5)
    for lb in d["labels"]:
        print(f"  {lb:<{width}}  missing {100 * d['missing_fraction'][lb]:6.2f} %")


def _print_robot(r: dict) -> None:
    print(f"robot {r['urdf']}: {r['n_joints']} revolute joints, gravity {r['gravity']}")
    for k, j in enumerate(r["joints"], 1):
        print(f"  joint {k} {j['name']:<12} [{j['lower']:+.3f}, {j['upper']:+.3f}] rad, "
              f"max {j['max_velocity']:.3g} rad/s, {j['max_torque']:.3g} N m, link {j['link']}")


def _print_log(d: dict) -> None:
    print(f"{d['path']}: {d['n_samples']} samples of {d['n_joints']} joints at {d['rate_hz']:.4g} Hz, "
          f"time {d['first_time']:.4f} .. {d['last_time']:.4f} s")
    print(f"  columns: {', '.join(d['columns'])}")


def _print_campaign(d: dict) -> None:
    print(f"campaign {d['campaign']!r} at {d['root']}")
    _print_robot(d["robot"])
    if d.get("coupling"):
        print(f"  coupling (q_urdf = coupling @ q_log): {d['coupling']}")
    print("markers:")
    for link, labels in d["markers"].items():
        print(f"  {link}: {', '.join(labels)}")
    print("recordings:")
    for e in d["recordings"]:
        extra = ""
        if e["kind"] == "trial":
            extra = (f" joints {e['joints']} load {e['load_kg']:g} kg vmax {e['vmax_frac']:g} "
                     f"rep {e['repetition']} {e['trial_kind']}")
        print(f"  {e['kind']:<6} {e['id']:<28} {e['duration_s']:8.2f} s  {e['marker_frames']} frames "
              f"@ {e['marker_rate_hz']:g} Hz, {e['log_samples']} log samples @ {e['log_rate_hz']:.4g} Hz{extra}")


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
