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
import warnings
from pathlib import Path

from mocap.io.errors import InputError, InputWarning


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


_INPUT_ARGS = ("campaign", "path", "calib", "angles", "robot", "nominal")
_OUTPUT_ARGS = ("out", "rrd", "export_c")


def _campaign_root(path: Path) -> Path | None:
    for folder in (path, *path.parents) if path.is_dir() else path.parents:
        if (folder / "campaign.toml").is_file():
            return folder
    return None


def _protected(path: Path) -> list[Path]:
    """What an input protects: a folder its whole subtree, a file itself and, when it lies in a
    campaign folder, that folder (nothing is ever written into a campaign)."""
    path = path.resolve()
    regions = [path]
    root = _campaign_root(path)
    if root is not None:
        regions.append(root)
    return regions


def guard_outputs(args) -> None:
    """Refuse any output path (``--out``, ``--rrd``, ``--export-c``, a command's own outputs)
    that equals an input or lies inside an input folder or an input's campaign folder."""
    inputs = [getattr(args, a, None) for a in getattr(args, "_inputs", _INPUT_ARGS)]
    inputs = [Path(p) for p in inputs if isinstance(p, (str, Path)) and Path(p).exists()]
    regions = [r for p in inputs for r in _protected(p)]
    for attr in getattr(args, "_outputs", _OUTPUT_ARGS):
        out = getattr(args, attr, None)
        if not isinstance(out, (str, Path)):
            continue
        out = Path(out).resolve()
        for region in regions:
            if out == region or region in out.parents:
                flag = "--" + attr.replace("_", "-")
                what = "an input" if out == region else f"inside the input folder {region}"
                raise InputError(f"{flag} {out} is {what}; nothing is written there, choose another path",
                                 path=out)


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
        p.set_defaults(_run=mod.run, _inputs=getattr(mod, "INPUT_ARGS", _INPUT_ARGS),
                       _outputs=getattr(mod, "OUTPUT_ARGS", _OUTPUT_ARGS))
    return parser


def main(argv=None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    with warnings.catch_warnings():
        warnings.simplefilter("default", InputWarning)       # each distinct warning once
        warnings.showwarning = _show_input_warning
        return _run(args)


def _show_input_warning(message, category, filename, lineno, file=None, line=None):
    if issubclass(category, InputWarning):
        print(f"jointlab: warning: {message}", file=sys.stderr)
    else:
        sys.stderr.write(warnings.formatwarning(message, category, filename, lineno, line))


def _run(args) -> int:
    out = getattr(args, "out", None)
    out_existed = out is None or Path(out).exists()
    status = 1
    try:
        guard_outputs(args)
        status = int(args._run(args) or 0)
        return status
    except InputError as exc:
        print(f"jointlab: error: {exc}", file=sys.stderr)
        status = 2
        return status
    except (FileExistsError, PermissionError, IsADirectoryError, NotADirectoryError) as exc:
        what = next(w for cls, w in ((PermissionError, "permission denied"),
                                     (IsADirectoryError, "is a folder"),
                                     (NotADirectoryError, "not a folder"),
                                     (FileExistsError, "exists")) if isinstance(exc, cls))
        where = exc.filename if exc.filename else str(exc)
        msg = f"{where}: {what}" if exc.filename else str(exc)
        print(f"jointlab: error: {msg}", file=sys.stderr)
        status = 2
        return status
    except KeyboardInterrupt:
        print("jointlab: interrupted", file=sys.stderr)
        status = 130
        return status
    finally:
        if status != 0 and not out_existed:
            _remove_if_empty(Path(out))


def _remove_if_empty(folder: Path) -> None:
    """A failed run leaves no empty output folder behind (never removes anything with content)."""
    try:
        folder.rmdir()
    except OSError:
        pass


if __name__ == "__main__":
    sys.exit(main())
