"""The angles file ``angles/<trial id>.csv`` (FORMAT.md): its reader.

The writer is :meth:`mocap.solve.AnglesResult.write_csv`; the columns are ``time`` (marker clock),
``q_<j>`` (rad), ``rms_mm`` and ``n_markers``, empty cells NaN.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from mocap.io.errors import InputError

__all__ = ["AngleTrack", "angles_path", "read_angles"]

#: the bytes of a data row the fast reader takes: digits, sign, point, exponent, separator, newline
_PLAIN = np.zeros(256, bool)
_PLAIN[np.frombuffer(b"0123456789.+-eE,\n", np.uint8)] = True


@dataclass(frozen=True, eq=False)
class AngleTrack:
    """``angles/<trial id>.csv``: ``time`` (marker clock), ``q`` {joint: (T,)}, ``rms_mm``,
    ``n_markers``."""

    time: np.ndarray
    q: dict
    rms_mm: np.ndarray
    n_markers: np.ndarray
    source: Path | None = None


def angles_path(angles_dir: str | Path, trial_id: str) -> Path:
    """``<angles_dir>/<trial id>.csv``, or a clear error when the angle solve has not run."""
    p = Path(angles_dir) / f"{trial_id}.csv"
    if not p.is_file():
        raise InputError(f"no angles file for trial {trial_id!r} (run the angle solve first, "
                         "or leave out --angles to use motor angles)", path=p)
    return p


def read_angles(path: str | Path) -> AngleTrack:
    """Read an angles CSV (FORMAT.md: columns ``time``, ``q_<j>``, ``rms_mm``, ``n_markers``;
    empty cells are NaN)."""
    path = Path(path)
    if not path.is_file():
        raise InputError("angles file not found", path=path)
    fast = _read_fast(path)
    if fast is not None:
        return fast
    lines = path.read_text(encoding="utf-8").splitlines()
    while lines and not lines[-1].strip():
        lines.pop()
    if not lines:
        raise InputError("empty angles file", path=path)
    header = [h.strip() for h in lines[0].split(",")]
    if "time" not in header:
        raise InputError("no 'time' column", path=path, line=1)
    qcols = {int(h[2:]): k for k, h in enumerate(header) if h.startswith("q_") and h[2:].isdigit()}
    if not qcols:
        raise InputError("no q_<j> column", path=path, line=1)
    body = np.array(lines[1:], dtype=str)
    n_cells = np.char.count(body, ",") + 1 if body.size else np.zeros(0, int)
    bad = np.flatnonzero(n_cells != len(header))
    if bad.size:
        i = int(bad[0])
        raise InputError(f"{int(n_cells[i])} cells, header has {len(header)}", path=path, line=i + 2)
    cells = np.char.strip(np.array(",".join(lines[1:]).split(",") if body.size else [], dtype=str))
    cells = np.where(cells == "", "nan", cells)
    try:
        data = cells.astype(float).reshape(body.size, len(header))
    except ValueError:
        data = None
    if data is None:                       # the error path only: find the offending cell
        for k, cell in enumerate(cells):
            try:
                float(cell)
            except ValueError:
                raise InputError(f"not a number: {str(cell)!r}", path=path, line=k // len(header) + 2,
                                 label=header[k % len(header)]) from None
    return _track(data, header, qcols, path)


def _track(data: np.ndarray, header: list, qcols: dict, path: Path) -> AngleTrack:
    time = data[:, header.index("time")]
    if not np.all(np.diff(time) > 0):
        bad = int(np.argmax(np.diff(time) <= 0)) + 3
        raise InputError("time is not strictly increasing", path=path, line=bad)
    col = lambda name: data[:, header.index(name)] if name in header else np.full(time.shape, np.nan)  # noqa: E731
    return AngleTrack(time, {j: data[:, k] for j, k in sorted(qcols.items())}, col("rms_mm"),
                      col("n_markers"), path)


def _read_fast(path: Path) -> AngleTrack | None:
    """The columnar reader (pyarrow's CSV parser, no per-cell Python object) of a plain angles
    file: a header naming ``time`` and a ``q_<j>``, then rows of only plain decimal numbers or
    empty cells (bytes in :data:`_PLAIN`), each row as wide as the header, no blank line but
    at the end. Anything else (or pyarrow missing) returns None and :func:`read_angles` reads
    the file with its careful parser, which names the line and the cell at fault."""
    try:
        import pyarrow as pa
        import pyarrow.csv as pacsv
    except ImportError:                                  # pragma: no cover - pyarrow optional
        return None
    try:
        raw = path.read_bytes()
    except OSError:
        return None
    cut = raw.find(b"\n")
    if cut < 0:
        return None
    try:
        header = [h.strip() for h in raw[:cut].decode("utf-8").split(",")]
    except UnicodeDecodeError:
        return None
    qcols = {int(h[2:]): k for k, h in enumerate(header) if h.startswith("q_") and h[2:].isdigit()}
    body = raw[cut + 1:].rstrip(b"\n")
    if ("time" not in header or not qcols or len(set(header)) != len(header) or not body
            or b"\n\n" in body or not _PLAIN[np.frombuffer(body, np.uint8)].all()):
        return None
    names = [f"c{k}" for k in range(len(header))]
    try:
        tab = pacsv.read_csv(
            pa.BufferReader(body),
            read_options=pacsv.ReadOptions(column_names=names, use_threads=False),
            parse_options=pacsv.ParseOptions(delimiter=",", quote_char=False, double_quote=False,
                                             escape_char=False, ignore_empty_lines=False),
            convert_options=pacsv.ConvertOptions(column_types={c: pa.float64() for c in names},
                                                 null_values=[""], strings_can_be_null=False))
    except pa.ArrowException:
        return None                         # a cell that is no number, a row's width
    data = np.empty((tab.num_rows, len(header)))
    for k, col in enumerate(tab.columns):
        data[:, k] = col.to_numpy(zero_copy_only=False)
    if data.shape[0] != body.count(b"\n") + 1:
        return None
    return _track(data, header, qcols, path)
