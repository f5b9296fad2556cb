"""``jointlab view CAMPAIGN|RRD [--calib calib.json] [--rrd FILE] [--spawn]``: look at a campaign
(markers, the robot posed by its motor angles and placed by the calibration, joint signals) or
open a saved recording (e.g. a study's ``study.rrd``) in the rerun viewer."""
from __future__ import annotations

import subprocess
from pathlib import Path

from mocap.io.errors import InputError

from ident.cli.main import add_common, check_out_dir


def register(sub):
    p = sub.add_parser("view", help="show a campaign or a saved .rrd recording in the rerun viewer")
    p.add_argument("path", type=Path, metavar="CAMPAIGN|RRD",
                   help="campaign folder (or its campaign.toml), or an .rrd file to open")
    p.add_argument("--calib", type=Path, metavar="JSON",
                   help="calib.json: place the robot base in the camera frame (default: identity)")
    add_common(p, out=False, json=False)
    return p


def open_rrd(rrd: Path) -> int:
    """Open an .rrd in a (new, detached) rerun viewer."""
    from viz.screenshot import viewer_executable

    exe = viewer_executable()
    if exe is None:
        raise InputError("no 'rerun' viewer executable found (it comes with rerun-sdk)", path=rrd)
    subprocess.Popen([exe, str(rrd)], start_new_session=True, stdin=subprocess.DEVNULL)
    print(f"opened {rrd} in the rerun viewer")
    return 0


def run(args) -> int:
    path = args.path
    if path.suffix == ".rrd":
        if not path.is_file():
            raise InputError("recording not found", path=path)
        if args.calib is not None or args.rrd is not None:
            raise InputError("--calib and --rrd apply to a campaign, not to an .rrd file", path=path)
        from mocap.io.plausibility import check_rrd

        check_rrd(path)
        return open_rrd(path)
    from mocap.io.campaign import load_campaign
    from mocap.references import read_calib
    from viz import make_sink

    from ident.study.view import log_campaign

    camp = load_campaign(path)
    if args.calib is not None:
        from mocap.io.plausibility import check_calib_json

        check_calib_json(args.calib)
    T_cb = read_calib(args.calib) if args.calib is not None else None
    spawn = args.spawn or args.rrd is None   # nothing asked for: show it
    if args.rrd is not None:
        check_out_dir(Path(args.rrd).resolve().parent, [camp.root])
    with make_sink(str(args.rrd) if args.rrd else None, spawn, app_id="jointlab-view") as sink:
        logged = log_campaign(camp, sink, T_camera_base=T_cb)
    where = f" to {args.rrd}" if args.rrd else ""
    print(f"logged {len(logged)} recordings of campaign {camp.name!r}{where}"
          + (" (viewer spawned)" if spawn else ""))
    return 0
