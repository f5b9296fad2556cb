"""``jointlab synth OUT``: simulate a campaign of the PA10 with one withheld effect.

Writes a FORMAT v1 campaign into OUT and the ground truth beside it (``OUT.truth.json`` and
``OUT.truth.npz``, or under ``--truth PREFIX``), never inside the campaign.
"""
from __future__ import annotations

import json
import shlex
from pathlib import Path

from mocap.io.errors import InputError

from ident.cli.main import add_common


def _numbers(s: str, what: str, kind=float) -> tuple:
    """A comma-separated list of ``kind`` values, or a one-line error naming the option."""
    noun = "numbers" if kind is float else "integers"
    try:
        vals = tuple(kind(x) for x in s.split(",") if x.strip())
    except ValueError:
        raise InputError(f"{what}: expected comma-separated {noun}, got {s!r}") from None
    if not vals:
        raise InputError(f"{what}: empty list")
    return vals


def _floats(s: str, what: str) -> tuple[float, ...]:
    return _numbers(s, what, float)


def _ints(s: str, what: str) -> tuple[int, ...]:
    return _numbers(s, what, int)


def _mpl(s: str) -> tuple[int, int]:
    v = _ints(s, "--markers-per-link")
    return (v[0], v[-1])


INPUT_ARGS = ()                     # OUT is created, not read
OUTPUT_ARGS = ("campaign", "truth", "rrd")


def register(sub):
    from ident.sim.effects import EFFECTS

    p = sub.add_parser("synth", help="simulate a campaign (PA10, flexible joints, one withheld effect) "
                                     "and write its ground truth beside it")
    p.add_argument("campaign", type=Path, metavar="OUT", help="campaign folder to create")
    p.add_argument("--effect", default="none", choices=EFFECTS, help="the withheld effect")
    p.add_argument("--magnitude", type=float, default=1.0, help="effect magnitude M (1 = typical size)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--joints", default="5", help="joints under study, e.g. 5 or 2,3,5 (default 5)")
    p.add_argument("--loads", default="0,3.373", help="end-effector loads in kg (default 0,3.373)")
    p.add_argument("--vmax", default="0.3,0.6,1.0", help="peak speed fractions (default 0.3,0.6,1.0)")
    p.add_argument("--reps", type=int, default=5, help="repetitions (default 5)")
    p.add_argument("--duration", type=float, default=20.0, help="excitation trial length, s (default 20)")
    p.add_argument("--kinds", default="excitation",
                   help="trial kinds: excitation,reversals,constant_velocity,coastdown")
    p.add_argument("--together", action="store_true",
                   help="move all --joints together in each trial (several-joint mode, slower)")
    p.add_argument("--robot", default="pa10", choices=("pa10", "perturbed"),
                   help="simulate the bundled PA10 or a perturbed copy (the campaign always "
                        "declares the bundled URDF)")
    p.add_argument("--marker-rate", type=float, default=100.0, help="marker rate, Hz (default 100)")
    p.add_argument("--log-rate", type=float, default=200.0, help="robot log rate, Hz (default 200)")
    p.add_argument("--label-swaps", type=int, default=0, help="label swaps per marker file")
    p.add_argument("--markers-per-link", default="3,4", metavar="MIN,MAX",
                   help="markers glued on each link, drawn in MIN..MAX (default 3,4)")
    p.add_argument("--truth", type=Path, metavar="PREFIX",
                   help="truth files PREFIX.truth.json/.npz (default: OUT.truth.json beside OUT)")
    p.add_argument("--overwrite", action="store_true", help="replace an existing OUT")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    add_common(p, out=False)
    return p


def canonical_command(args, out: str = "OUT") -> str:
    """The full command line (every option spelled out); OUT a placeholder unless given."""
    parts = ["jointlab", "synth", out, "--effect", args.effect, "--magnitude", repr(args.magnitude),
             "--seed", str(args.seed), "--joints", args.joints, "--loads", args.loads, "--vmax", args.vmax,
             "--reps", str(args.reps), "--duration", repr(args.duration), "--kinds", args.kinds,
             "--robot", args.robot, "--marker-rate", repr(args.marker_rate),
             "--log-rate", repr(args.log_rate)]
    if args.markers_per_link != "3,4":
        parts += ["--markers-per-link", args.markers_per_link]
    if args.together:
        parts.append("--together")
    if args.label_swaps:
        parts += ["--label-swaps", str(args.label_swaps)]
    if out != "OUT" and args.truth is not None:
        parts += ["--truth", str(args.truth)]
    return shlex.join(parts)


def run(args) -> int:
    from mocap.io.plausibility import check_synth_options

    from ident.sim.campaign_synth import CampaignSynth, SynthConfig

    # ranges and a memory estimate, before any work
    check_synth_options(magnitude=args.magnitude, seed=args.seed, loads=args.loads, vmax=args.vmax,
                        joints=args.joints, duration=args.duration, marker_rate=args.marker_rate,
                        log_rate=args.log_rate, reps=args.reps, label_swaps=args.label_swaps)
    cfg = SynthConfig(joints=_ints(args.joints, "--joints"), loads=_floats(args.loads, "--loads"),
                      vmax=_floats(args.vmax, "--vmax"), reps=args.reps, duration=args.duration,
                      kinds=tuple(k.strip() for k in args.kinds.split(",") if k.strip()),
                      robot=args.robot, effect=args.effect, magnitude=args.magnitude, seed=args.seed,
                      marker_rate=args.marker_rate, log_rate=args.log_rate,
                      label_swaps=args.label_swaps,
                      markers_per_link=_mpl(args.markers_per_link), together=args.together,
                      name=args.campaign.name)
    cfg.validate()
    if args.rrd or args.spawn:
        from viz import make_sink

        sink = make_sink(str(args.rrd) if args.rrd else None, args.spawn)
    else:
        sink = None
    try:
        summary = CampaignSynth(cfg).write(args.campaign, args.truth, overwrite=args.overwrite,
                                           progress=not args.quiet,
                                           sink=sink, command=canonical_command(args),
                                           regenerate=canonical_command(args, str(args.campaign)))
    finally:
        if sink is not None:
            sink.close()
    if args.json:
        print(json.dumps(summary, indent=1))
    else:
        print(f"wrote {summary['recordings']} recordings ({summary['campaign_seconds']:.0f} s of "
              f"campaign clock) to {summary['out']}; truth in {summary['truth']}")
    return 0
