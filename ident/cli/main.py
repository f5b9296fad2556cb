"""The ``jointlab`` command line.

Subcommands live in :mod:`ident.cli.commands`, one module each, with ``register(subparsers)``
and ``run(args) -> int``. Common flags (``--out``, ``--rrd``, ``--spawn``, ``--json``) come
from :func:`add_common`. User input errors print one line and exit 2, without a traceback.
"""
from __future__ import annotations

import argparse
import importlib
import pkgutil
import sys
from pathlib import Path

from mocap.io.errors import InputError


def add_common(p: argparse.ArgumentParser, out: bool = True, out_required: bool = False,
               json: bool = True) -> None:
    """The flags every command shares (DESIGN.md: rerun's --save/--spawn conventions)."""
    if out:
        p.add_argument("--out", type=Path, required=out_required, metavar="DIR",
                       help="output folder (never the input's folder)")
    p.add_argument("--rrd", type=Path, metavar="FILE", help="save a rerun recording to FILE")
    p.add_argument("--spawn", action="store_true", help="open the rerun viewer")
    if json:
        p.add_argument("--json", action="store_true", help="print the summary as JSON")


def check_out_dir(out: Path, inputs=()) -> Path:
    """Create ``out``; refuse an output folder that is an input folder or inside one."""
    out = Path(out).resolve()
    for inp in inputs:
        inp = Path(inp).resolve()
        root = inp if inp.is_dir() else inp.parent
        if out == root or root in out.parents:
            raise InputError(f"--out {out} is inside the input folder {root}; choose another folder",
                             path=out)
    out.mkdir(parents=True, exist_ok=True)
    return out


def _command_modules():
    from ident.cli import commands

    for info in sorted(pkgutil.iter_modules(commands.__path__), key=lambda m: m.name):
        if not info.name.startswith("_"):
            yield importlib.import_module(f"{commands.__name__}.{info.name}")


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="jointlab",
        description="Motion capture + controller logs -> joint angles, calibrated frames, "
                    "friction models and sim-to-real gap diagnosis.")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True
    for mod in _command_modules():
        p = mod.register(sub)
        p.set_defaults(_run=mod.run)
    return parser


def main(argv=None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return int(args._run(args) or 0)
    except InputError as exc:
        print(f"jointlab: error: {exc}", file=sys.stderr)
        return 2
    except FileExistsError as exc:
        print(f"jointlab: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("jointlab: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
