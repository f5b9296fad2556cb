"""``jointlab design --robot ROBOT --joint J --vmax-frac F --out DIR``: an excitation trajectory
(thesis eq. 3-1: minimum cond(R) under position, speed and acceleration limits, zero speed and
acceleration at both ends, peak speed at the given fraction of the joint's maximum)."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from mocap.io.errors import InputError

from ident.cli.main import add_common
from ident.outputs import OutputDir


def register(sub):
    p = sub.add_parser("design", help="design a finite-Fourier excitation trajectory for one joint (eq. 3-1)")
    p.add_argument("--robot", type=Path, required=True,
                   help="URDF (drives.toml beside it is used when present), a folder holding one, or a campaign")
    p.add_argument("--joint", type=int, required=True, help="joint number, from 1")
    p.add_argument("--vmax-frac", type=float, default=1.0, help="peak speed as a fraction of the joint's maximum")
    p.add_argument("--period", type=float, default=10.0, help="trajectory period in s (wf = 2 pi / period)")
    p.add_argument("--harmonics", type=int, default=5, help="number of harmonics N of eq. 3-2")
    p.add_argument("--amax", type=float, default=None, help="acceleration limit, rad/s^2 (default: from the drive)")
    p.add_argument("--starts", type=int, default=8, help="random starts of the search")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--dt", type=float, default=0.005, help="sample step of trajectory.csv, s")
    add_common(p, out_required=True)
    return p


def load_robot_arg(path: Path):
    """A Robot from a URDF, a folder with one URDF (and drives.toml), or a campaign."""
    from mocap.robot import Robot

    if not path.exists():
        raise InputError("no such file or folder", path=path)
    if path.name == "campaign.toml" or (path.is_dir() and (path / "campaign.toml").is_file()):
        from mocap.io.campaign import load_campaign

        return load_campaign(path).load_robot()
    if path.is_dir():
        urdfs = sorted(path.glob("*.urdf"))
        if len(urdfs) != 1:
            raise InputError(f"expected one .urdf in the folder, found {len(urdfs)}", path=path)
        path = urdfs[0]
    if path.suffix.lower() != ".urdf":
        raise InputError("--robot must be a .urdf, a folder holding one, or a campaign", path=path)
    drives = path.parent / "drives.toml"
    from mocap.io.plausibility import check_drives_count
    from mocap.urdf import check_urdf

    check_urdf(path)                      # one line, before pinocchio prints its own
    if drives.is_file():                  # a count that differs names drives.toml
        check_drives_count(drives, Robot.from_urdf(path).n)
    return Robot.from_urdf(path, drives if drives.is_file() else None)


def run(args) -> int:
    from ident.excitation.design import ExcitationDesigner, limits_from_robot

    from mocap.io.plausibility import check_design_options

    # ranges and a memory estimate, before any work
    check_design_options(seed=args.seed, period=args.period, harmonics=args.harmonics,
                         starts=args.starts, dt=args.dt, amax=args.amax)
    robot = load_robot_arg(args.robot)
    if not 1 <= args.joint <= robot.n:
        raise InputError(f"--joint {args.joint}: the robot has joints 1..{robot.n}", path=args.robot)
    if not 0 < args.vmax_frac <= 1:
        raise InputError(f"--vmax-frac must be in (0, 1], got {args.vmax_frac}")
    with OutputDir(args.out, "design", [args.robot]) as od:
        od.check_early(["design.json", "trajectory.csv", "design.png"])
        out = od.root
        limits = limits_from_robot(robot, args.joint, args.amax)
        design = ExcitationDesigner(n_harmonics=args.harmonics, period=args.period, n_starts=args.starts,
                                    seed=args.seed).fit(limits, args.vmax_frac, args.joint)
        d = design.to_dict()
        stage = od.stage()
        (stage / "design.json").write_text(json.dumps(d, indent=1), encoding="utf-8")
        t, q, qd, qdd = design.trajectory(dt=args.dt)
        np.savetxt(stage / "trajectory.csv", np.column_stack([t, q, qd, qdd]), delimiter=",",
                   header="time,q,qd,qdd", comments="", fmt="%.9g")
        _plot(stage / "design.png", t, q, qd, qdd, design)
        od.commit(stage)
    if args.rrd or args.spawn:
        from viz import make_sink

        with make_sink(str(args.rrd) if args.rrd else None, args.spawn) as sink:
            sink.scalars(f"design/joint{args.joint}", t, np.column_stack([q, qd, qdd]), names=["q", "qd", "qdd"])
    if args.json:
        print(json.dumps(d, indent=1))
    else:
        print(f"joint {args.joint}: cond(R) = {design.cond:.3f}, peak speed {design.peak_speed:.4g} rad/s "
              f"({100 * args.vmax_frac:g} % of {limits.qd_max:g}), max acc {design.max_acc:.4g} rad/s^2, "
              f"q in [{design.q_min:.3f}, {design.q_max:.3f}] rad, "
              f"{'feasible' if design.feasible else 'LIMITS VIOLATED'}")
        print(f"wrote {out / 'design.json'}, {out / 'trajectory.csv'}, {out / 'design.png'}")
    return 0 if design.feasible else 1


def _plot(path, t, q, qd, qdd, design):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axs = plt.subplots(3, 1, figsize=(6.4, 6), sharex=True, dpi=100)
    lim = design.limits
    for ax, y, lab, bound in ((axs[0], q, "q (rad)", (lim.q_lower, lim.q_upper)),
                              (axs[1], qd, "qd (rad/s)", (-lim.qd_max, lim.qd_max)),
                              (axs[2], qdd, "qdd (rad/s^2)", (-lim.qdd_max, lim.qdd_max))):
        ax.plot(t, y)
        for b in bound:
            if np.isfinite(b) and abs(b) < 5 * np.max(np.abs(y)):
                ax.axhline(b, color="r", lw=0.8, ls="--")
        ax.set_ylabel(lab)
    axs[2].set_xlabel("time (s)")
    axs[0].set_title(f"joint {design.joint}: cond(R) = {design.cond:.3f}", fontsize=9)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)
