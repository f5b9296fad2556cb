"""Marker file dispatch: the extension decides the reader (FORMAT.md)."""
from __future__ import annotations

from pathlib import Path

from mocap.io.errors import InputError, warn_input
from mocap.io.recording import MarkerRecording
from mocap.io.c3d import read_c3d, write_c3d
from mocap.io.trc import read_trc, write_trc


def read_markers(path: str | Path, **kw) -> MarkerRecording:
    """Read a ``.trc`` or ``.c3d`` marker file into a :class:`MarkerRecording` (metres).

    Keyword arguments go to the C3D reader (``isolate``, ``timeout_s``)."""
    path = Path(path)
    if not path.is_file():
        raise InputError("marker file not found", path=path)
    ext = path.suffix.lower()
    if ext == ".trc":
        rec = read_trc(path)
    elif ext == ".c3d":
        rec = read_c3d(path, **kw)
    else:
        raise InputError(f"unknown marker file extension {ext!r} (expected .trc or .c3d)", path=path)
    for msg in rec.meta.get("header_mismatch", []):   # e.g. a truncated C3D: every command says so
        warn_input(f"{msg}; using the {rec.n_frames} frames present", path)
    return rec


def write_markers(path: str | Path, rec: MarkerRecording, overwrite: bool = False, **kw) -> Path:
    path = Path(path)
    ext = path.suffix.lower()
    if ext == ".trc":
        return write_trc(path, rec, overwrite=overwrite, **kw)
    if ext == ".c3d":
        return write_c3d(path, rec, overwrite=overwrite, **kw)
    raise InputError(f"cannot write marker files with extension {ext!r}", path=path)
