"""The ``jointlab`` command line.

Subcommands live in :mod:`ident.cli.commands`, one module each, with ``register(subparsers)``
and ``run(args) -> int``. Common flags (``--out``, ``--rrd``, ``--spawn``, ``--json``) come
from :func:`add_common`. User input errors print one line and exit 2, without a traceback.
"""
from __future__ import annotations

import sys

INTERRUPTED = "jointlab: interrupted; rerun to resume"
TERMINATED = "jointlab: terminated (SIGTERM); rerun to resume"

try:        # a Ctrl-C while the modules load (seconds on a cold disk): one line, exit 130
    import argparse
    import importlib
    import json
    import pkgutil
    import signal
    import warnings
    from pathlib import Path

    from mocap.io.errors import InputError, InputWarning

    from ident.cli import commands
    from ident.outputs import LOCK, MANIFEST, STAGE_DIR, check_out_dir as _check_out_dir
    from ident.study.executor import WorkerLost
except KeyboardInterrupt:
    print(INTERRUPTED, file=sys.stderr)
    raise SystemExit(130) from None


class Terminated(KeyboardInterrupt):
    """SIGTERM (a scheduler's or an OOM killer's polite stop), raised in the main thread like
    Ctrl-C: the same cleanup (pool workers stopped, temporary files removed, the finished
    items' records kept), then one line and exit status 143 (128 + 15)."""


def _on_sigterm(signum, frame):
    raise Terminated()


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
    """Create ``out``; refuse an output folder that is an input folder or inside one (or inside
    an input's campaign). ``--out`` folders go through :class:`ident.outputs.OutputDir`, which
    also refuses one that contains an input."""
    return _check_out_dir(out, inputs, contain=False)


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


def _nearest_existing(path: Path) -> Path:
    for p in (path, *path.parents):
        if p.exists():
            return p
    return path


def guard_outputs(args) -> None:
    """Refuse any output path (``--out``, ``--rrd``, ``--export-c``, a command's own outputs)
    that equals an input, lies inside an input folder, an input's campaign folder or any other
    campaign folder, or (``--out``) contains an input's folder."""
    inputs = [getattr(args, a, None) for a in getattr(args, "_inputs", _INPUT_ARGS)]
    inputs = [Path(p) for p in inputs if isinstance(p, (str, Path)) and Path(p).exists()]
    regions = [r for p in inputs for r in _protected(p)]
    for attr in getattr(args, "_outputs", _OUTPUT_ARGS):
        out = getattr(args, attr, None)
        if not isinstance(out, (str, Path)):
            continue
        out = Path(out).resolve()
        flag = "--" + attr.replace("_", "-") if attr != "campaign" else "the campaign folder"
        for region in regions:
            if out == region or region in out.parents:
                what = "an input" if out == region else f"inside the input folder {region}"
                raise InputError(f"{flag} {out} is {what}; nothing is written there, choose another path",
                                 path=out)
            if attr == "out" and out in region.parents:
                raise InputError(f"{flag} {out} contains the input folder {region}; nothing is written "
                                 "around an input, choose another folder", path=out)
        # nothing is ever written into a campaign (synth's own campaign may be rewritten itself)
        near = _nearest_existing(out if attr != "campaign" else out.parent)
        root = _campaign_root(near) if near.exists() else None
        if root is not None:
            raise InputError(f"{flag} {out} is inside the campaign folder {root}; nothing is written "
                             "into a campaign, choose another path", path=out)


def _command_modules():
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
    with _sigterm_raises():
        try:
            parser = build_parser()
            args = parser.parse_args(argv)
        except Terminated:
            print(TERMINATED, file=sys.stderr)
            return 143
        except KeyboardInterrupt:
            print(INTERRUPTED, file=sys.stderr)
            return 130
        with warnings.catch_warnings():
            warnings.simplefilter("default", InputWarning)       # each distinct warning once
            warnings.showwarning = _show_input_warning
            return _run(args)


class _sigterm_raises:
    """SIGTERM raises :class:`Terminated` while a command runs (main thread only; the previous
    handler is restored afterwards, so a program calling :func:`main` keeps its own)."""

    def __enter__(self):
        self.old = None
        try:
            self.old = signal.signal(signal.SIGTERM, _on_sigterm)
        except (ValueError, OSError, AttributeError):      # not the main thread
            pass
        return self

    def __exit__(self, *exc):
        if self.old is not None:
            try:
                signal.signal(signal.SIGTERM, self.old)
            except (ValueError, OSError):
                pass
        return False


def _show_input_warning(message, category, filename, lineno, file=None, line=None):
    if issubclass(category, InputWarning):
        print(f"jointlab: warning: {message}", file=sys.stderr)
    else:
        sys.stderr.write(warnings.formatwarning(message, category, filename, lineno, line))


def _os_error_line(exc: OSError) -> str:
    """One line for an OS error: the file and the reason (read-only, disk full, name too long,
    no permission, ...)."""
    import errno

    reasons = {errno.EROFS: "read-only file system", errno.ENOSPC: "no space left on the device",
               errno.ENAMETOOLONG: "file name too long", errno.EACCES: "permission denied",
               errno.EPERM: "operation not permitted", errno.EDQUOT: "disk quota exceeded",
               errno.EISDIR: "is a folder", errno.ENOTDIR: "not a folder", errno.EEXIST: "exists",
               errno.ENOENT: "no such file or folder"}
    what = reasons.get(exc.errno) or exc.strerror or type(exc).__name__
    where = exc.filename if exc.filename else None
    text = f"{where}: {what}" if where else (f"{what}" if exc.strerror else str(exc) or what)
    return " ".join(str(text).split())


def _run(args) -> int:
    out = getattr(args, "out", None)
    out_existed = out is None or Path(out).exists()
    created = []                       # the folders a failed run may leave behind, deepest first
    if not out_existed:
        p = Path(out).absolute()
        while not p.exists() and p != p.parent:
            created.append(p)
            p = p.parent
    status = 1
    try:
        guard_outputs(args)
        status = int(args._run(args) or 0)
        return status
    except InputError as exc:
        print(f"jointlab: error: {' '.join(str(exc).split())}", file=sys.stderr)
        status = 2
        return status
    except WorkerLost as exc:
        print(f"jointlab: error: {exc}", file=sys.stderr)
        status = 1
        return status
    except OSError as exc:
        print(f"jointlab: error: {_os_error_line(exc)}", file=sys.stderr)
        status = 2
        return status
    except Terminated:
        print(TERMINATED, file=sys.stderr)
        status = 143
        return status
    except KeyboardInterrupt:
        print(INTERRUPTED, file=sys.stderr)
        status = 130
        return status
    finally:
        if status != 0 and not out_existed:
            _remove_if_empty(Path(out))
            for folder in created[1:]:
                _remove_if_empty(folder)


def _remove_if_empty(folder: Path) -> None:
    """A failed run leaves no empty output folder behind (never removes anything with content;
    the output bookkeeping of a run that wrote nothing goes with it)."""
    try:
        names = {p.name for p in folder.iterdir()}
        if names <= {LOCK, MANIFEST, STAGE_DIR}:
            if MANIFEST in names and json.loads((folder / MANIFEST).read_text()).get("files"):
                return
            for n in (LOCK, MANIFEST):
                (folder / n).unlink(missing_ok=True)
            (folder / STAGE_DIR).rmdir() if (folder / STAGE_DIR).exists() else None
        folder.rmdir()
    except (OSError, ValueError, AttributeError):
        pass


if __name__ == "__main__":
    sys.exit(main())
