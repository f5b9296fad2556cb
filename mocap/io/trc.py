"""TRC marker files (Motion Analysis text format), FORMAT.md "Marker file (.trc)".

Layout (tab separated; comma separated files exported by other tools are accepted too)::

    line 1  PathFileType  4  (X/Y/Z)  <name>
    line 2  DataRate CameraRate NumFrames NumMarkers Units OrigDataRate OrigDataStartFrame OrigNumFrames
    line 3  the values of line 2
    line 4  Frame#  Time  <label 1>  ''  ''  <label 2> ...   (padded: each label spans 3 columns;
                                                            compact lists, one cell per label, are accepted)
    line 5  ''  ''  X1  Y1  Z1  X2 ...                        (optional)
    line 6  blank                                             (optional)
    then    one row per frame: frame number, time, 3 coordinates per marker

An occluded marker is empty (or ``NaN``) cells; a marker with any of its three cells empty is
missing in that frame (all three coordinates NaN). Coordinates are converted once, here, from
the declared ``Units`` (``mm``, ``cm`` or ``m``) to metres; ``rec.units`` keeps the declared unit.

Header fields are kept in ``rec.meta`` under their own names (``NumFrames`` is the *header*
value). The rows are the data: when the header disagrees with them (``NumFrames`` is often the
length of the original take, not of the exported excerpt) the rows win and
``meta["header_mismatch"]`` says what disagreed. ``meta["first_frame"]`` is the frame number of
the first row, ``meta["n_rows"]`` the number of data rows, ``meta["delimiter"]`` the separator.

Parsing is vectorised, with no Python loop over rows or cells on the happy path: blank lines
and per-row cell counts are found on the raw bytes with numpy (``reduceat`` over line
segments), empty cells become ``nan`` by string replacement, and numpy's C text parser
(``np.loadtxt``) converts the whole block. Ragged rows (trailing separators on some rows only)
or odd cells take a careful path that splits per line into a string array; only the error path
looks at single cells, to name the bad one.
"""
from __future__ import annotations

import contextlib
import io
import re
from pathlib import Path

import numpy as np

from mocap.io.errors import InputError, check_control_chars, read_bytes
from mocap.io.recording import MarkerRecording

HEADER_KEYS = ("DataRate", "CameraRate", "NumFrames", "NumMarkers", "Units",
               "OrigDataRate", "OrigDataStartFrame", "OrigNumFrames")

#: metres per declared unit
UNIT_SCALE = {"mm": 1e-3, "cm": 1e-2, "m": 1.0}
#: spellings seen in exported files, mapped to the short unit name kept in ``rec.units``
UNIT_ALIASES = {"millimeters": "mm", "millimetres": "mm", "millimeter": "mm", "millimetre": "mm",
                "centimeters": "cm", "centimetres": "cm", "meters": "m", "metres": "m",
                "meter": "m", "metre": "m"}


def normalise_units(units) -> str | None:
    """``'MM'``, ``' mm '``, ``'millimeters'`` -> ``'mm'``; None if not a known length unit."""
    u = str(units).strip().lower()
    u = UNIT_ALIASES.get(u, u)
    return u if u in UNIT_SCALE else None

_COORD_RE = re.compile(r"^([XYZ])(\d+)$", re.IGNORECASE)


def _header_value(s: str):
    """A header cell as int, float or (stripped) string."""
    s = s.strip()
    try:
        return int(s)
    except ValueError:
        pass
    try:
        return float(s)
    except ValueError:
        return s


def _decode(path: Path) -> str:
    raw = read_bytes(path)
    try:
        text = raw.decode("utf-8-sig")
    except UnicodeDecodeError:
        text = raw.decode("latin-1")
    return text.replace("\r\n", "\n").replace("\r", "\n")


def _sniff_delimiter(lines: list[str], path: Path) -> str:
    """Tab if the key line (line 2) has tabs, else comma."""
    probe = lines[1] if len(lines) > 1 else lines[0]
    if "\t" in probe:
        return "\t"
    if "," in probe:
        return ","
    raise InputError("cannot tell the column separator (expected tabs or commas in the header "
                     "line 'DataRate CameraRate NumFrames ...')", path=path, line=2)


def read_trc(path: str | Path) -> MarkerRecording:
    """Read a TRC marker file into a :class:`MarkerRecording` (time-first, metres, NaN = occluded).

    The marker file of the data format [1]_ in the TRC layout [2]_ (module docstring); the
    declared units are converted to metres once, here.

    Parameters
    ----------
    path : str or pathlib.Path
        The ``.trc`` file.

    Returns
    -------
    MarkerRecording
        The labelled marker trajectories.

    Raises
    ------
    InputError
        Naming the file and line for anything that does not fit the layout: a missing file
        or header, unknown units, a data row with fewer cells than ``2 + 3 * n_markers`` or
        with non-empty cells beyond them, a cell that is not a number, a blank or
        non-increasing time.

    References
    ----------
    .. [1] jointlab data format (docs/format.md), sec. Marker file (.trc).
    .. [2] Motion Analysis Corporation, TRC (track row column) file format.
    """
    path = Path(path)
    if not path.is_file():
        raise InputError("TRC file not found", path=path)
    try:   # small files: the careful parser is as quick
        fast = _read_fast(path) if path.stat().st_size >= STREAM_MIN_BYTES else None
    except OSError:
        fast = None
    if fast is not None:
        return fast
    text = _decode(path)
    check_control_chars(text, path)
    lines = text.split("\n")
    h = _parse_header(lines, path)
    sep, n_markers, labels, data_start = h["sep"], h["n_markers"], h["labels"], h["data_start"]

    # ---- data rows (blank lines, such as the usual line 6 and a final newline, are skipped)
    n_cols = 2 + 3 * n_markers
    body_text, line_no, n_cells = _scan_body("\n".join(lines[data_start:]), sep, data_start + 1)
    short = np.flatnonzero(n_cells < n_cols)
    if short.size:
        i = short[0]
        raise InputError(f"row has {n_cells[i]} cells, expected {n_cols} (Frame#, Time and 3 per "
                         f"marker for {n_markers} markers)", path=path, line=int(line_no[i]))
    values = None
    if line_no.size and np.all(n_cells == n_cells[0]):
        values = _fast_values(body_text, sep, line_no.size)   # C parser; None if a cell needs care
        if values is not None and values.shape[1] > n_cols:
            bad_rows = np.flatnonzero(np.any(~np.isnan(values[:, n_cols:]), axis=1))
            if bad_rows.size:
                _raise_extra(n_cells, bad_rows[0], n_cols, n_markers, line_no, path)
            values = values[:, :n_cols]
    if values is None:
        body = body_text.split("\n") if line_no.size else []
        values = _careful_values(body, n_cells, sep, n_cols, n_markers, labels, line_no, path)
    return _finish(values, n_cells, line_no, h, path)


_LINE_END = re.compile(rb"\r\n|\r|\n")
#: files from this size on stream through :func:`_read_fast` (the quicker reader from here on)
STREAM_MIN_BYTES = 1 << 17
#: files up to this size are read into memory in one piece by :func:`_read_fast`, larger ones in blocks
WHOLE_MAX_BYTES = 16 << 20
#: cells the streaming reader reads as an occlusion (empty or ``nan`` in any case)
_NAN_SPELLINGS = ["", "nan", "naN", "nAn", "nAN", "Nan", "NaN", "NAn", "NAN"]


def _read_fast(path: Path) -> MarkerRecording | None:
    """The streaming reader: the header's five lines parsed by :func:`_parse_header`, the data
    rows by pyarrow's CSV reader in blocks straight into one float64 array (files up to
    :data:`WHOLE_MAX_BYTES` are read into memory in one piece, larger ones block by block; no
    per-cell Python object). It takes only a well-formed file: UTF-8 header lines, every row as wide as the first
    (at least ``2 + 3 * markers`` cells, the ones beyond empty), cells that are numbers or
    occlusions (:data:`_NAN_SPELLINGS`), finite values within :data:`ABSURD_M`, a strictly
    increasing time, and no partly empty marker in rows wider than the header. Anything else
    returns None and :func:`read_trc` reads the file with its careful parser, which names the
    line and the cell at fault."""
    try:
        import pyarrow as pa
        import pyarrow.csv as pacsv
    except ImportError:                                  # pragma: no cover - pyarrow optional
        return None
    size = path.stat().st_size
    whole = None
    if size <= WHOLE_MAX_BYTES:                   # read once: the header, the row count, the rows
        whole = read_bytes(path)                  # a file that cannot be read: one InputError
        head = whole[:1 << 20]
    else:
        try:
            with open(path, "rb") as fh:
                head = fh.read(1 << 20)
        except OSError:
            return None                           # the careful reader says why, naming the file
    start = 3 if head.startswith(b"\xef\xbb\xbf") else 0
    ends = []
    for m in _LINE_END.finditer(head, start):   # the header's lines and the first rows
        ends.append(m)
        if len(ends) == 64:
            break
    if len(ends) < 6:
        return None
    try:
        lines, pos = [], start
        for m in ends[:5]:
            lines.append(head[pos:m.start()].decode("utf-8"))
            pos = m.end()
        check_control_chars("\n".join(lines), path)
        h = _parse_header(lines, path)
    except (UnicodeDecodeError, InputError):
        return None
    body_at = ends[h["data_start"] - 1].end()
    n_cols = 2 + 3 * h["n_markers"]
    sep = h["sep"]
    first = next((head[a.end():b.start()] for a, b in zip(ends[h["data_start"] - 1:], ends[h["data_start"]:])
                  if head[a.end():b.start()].strip(b" \t,")), None)
    if first is None:
        return None
    k = first.count(sep.encode()) + 1
    if k < n_cols:
        return None
    names = [f"c{i}" for i in range(k)]
    if whole is not None:                       # rows at most: the line ends below the header
        body = memoryview(whole)[body_at:]
        rows_max = whole.count(b"\n", body_at) + whole.count(b"\r", body_at) + 1
    else:
        with open(path, "rb") as fh:
            fh.seek(body_at)
            n_lf = n_cr = 0
            while True:
                chunk = fh.read(1 << 24)
                if not chunk:
                    break
                n_lf += chunk.count(b"\n")
                n_cr += chunk.count(b"\r")
            rows_max = n_lf + n_cr + 1
    values = np.empty((rows_max, n_cols))
    pool = pa.system_memory_pool()
    try:
        with (contextlib.nullcontext(pa.BufferReader(body)) if whole is not None
              else open(path, "rb")) as fh:
            if whole is None:
                fh.seek(body_at)
            reader = pacsv.open_csv(
                fh, memory_pool=pool,
                read_options=pacsv.ReadOptions(column_names=names, block_size=1 << 20),
                parse_options=pacsv.ParseOptions(delimiter=sep, quote_char=False,
                                                 ignore_empty_lines=True),
                convert_options=pacsv.ConvertOptions(column_types={c: pa.float64() for c in names},
                                                     null_values=_NAN_SPELLINGS,
                                                     strings_can_be_null=False))
            n = 0
            for batch in reader:
                b = batch.num_rows
                if n + b > rows_max:
                    return None
                for i, col in enumerate(batch.columns):
                    if i < n_cols:
                        values[n:n + b, i] = col.to_numpy(zero_copy_only=False)
                    elif col.null_count != b:
                        return None                     # values beyond the last marker
                n += b
    except pa.ArrowException:
        return None                                     # a cell that is no number, a row's width
    finally:
        pool.release_unused()
    values = values[:n]
    if n == 0:
        return None
    scale = UNIT_SCALE[h["units"]]
    a = np.abs(values)
    with np.errstate(invalid="ignore"):
        if (a == np.inf).any() or (a[:, 2:] * scale > ABSURD_M).any():
            return None
    del a
    t = values[:, 1]
    if not np.isfinite(t).all() or (np.diff(t) <= 0).any():
        return None
    if k > n_cols:
        fin = np.isfinite(values[:, 2:].reshape(n, -1, 3)).sum(axis=2)
        if ((fin > 0) & (fin < 3)).any():
            return None                                 # partly empty marker in a wide row
    return _finish(values, np.full(n, k), np.arange(n), h, path, checked=True)


def _parse_header(lines: list[str], path: Path) -> dict:
    """Lines 1-5 of a TRC file (``lines``: at least its first five, newline-free): the separator,
    the header fields (``meta``), rate, units, labels, the number of markers and the index of
    the first line after the header (``data_start``, 0-based)."""
    if len(lines) < 4 or not lines[0].strip():
        raise InputError("too short for a TRC file (needs at least 4 header lines)", path=path)
    sep = _sniff_delimiter(lines, path)

    # ---- line 1: PathFileType 4 (X/Y/Z) <name>
    first = [c.strip() for c in lines[0].split(sep)]
    if first[0].lower() != "pathfiletype":
        raise InputError(f"not a TRC file: line 1 starts with {first[0][:40]!r}, expected 'PathFileType'",
                         path=path, line=1)
    first = [c for c in first if c]
    meta: dict = {"PathFileType": _header_value(first[1]) if len(first) > 1 else None,
                  "path_type": first[2] if len(first) > 2 else None,
                  "name": sep.join(first[3:]) if len(first) > 3 else None,
                  "delimiter": sep}

    # ---- lines 2-3: header keys and values
    keys = [c.strip() for c in lines[1].split(sep)]
    vals = [c.strip() for c in lines[2].split(sep)]
    header = {}
    for k, v in zip(keys, vals + [""] * max(0, len(keys) - len(vals))):
        if k:
            header[k] = _header_value(v)
    if "DataRate" not in header:
        raise InputError("header has no DataRate key (line 2 should list DataRate CameraRate "
                         "NumFrames NumMarkers Units ...)", path=path, line=2)
    rate = header["DataRate"]
    if not isinstance(rate, (int, float)) or not np.isfinite(rate) or rate <= 0:
        raise InputError(f"DataRate must be a positive number, got {rate!r}", path=path, line=3)
    units_raw = header.get("Units")
    if units_raw is None or str(units_raw).strip() == "":
        raise InputError("header has no Units value (expected mm, cm or m)", path=path, line=3)
    units = normalise_units(units_raw)
    if units is None:
        raise InputError(f"unknown Units {units_raw!r} (expected one of mm, cm, m)", path=path, line=3)
    meta.update(header)

    # ---- line 4: Frame#, Time, labels
    cells4 = [c.strip() for c in lines[3].split(sep)]
    if len(cells4) < 2 or cells4[0].lower().rstrip("#") not in ("frame", "frame#") \
            or cells4[1].lower() != "time":
        raise InputError(f"line 4 must start with 'Frame#' and 'Time', got {cells4[:2]}",
                         path=path, line=4)
    labels = [c for c in cells4[2:] if c]

    # ---- line 5: optional X1 Y1 Z1 ... line
    data_start = 4  # 0-based index of the first line after the header
    n_markers = len(labels)
    if len(lines) > 4:
        cells5 = [c.strip() for c in lines[4].split(sep)]
        coord = [c for c in cells5[2:] if c]
        if coord and _COORD_RE.match(coord[0]):
            data_start = 5
            if len(coord) % 3:
                raise InputError(f"line 5 has {len(coord)} coordinate names, not a multiple of 3",
                                 path=path, line=5)
            n_markers = len(coord) // 3
            expected = [f"{a}{k}" for k in range(1, n_markers + 1) for a in "XYZ"]
            got = [c.upper() for c in coord]
            if got != expected:
                bad = next(i for i, (g, e) in enumerate(zip(got, expected)) if g != e)
                raise InputError(f"line 5: coordinate column {bad + 3} is {coord[bad]!r}, expected "
                                 f"{expected[bad]!r} (X1 Y1 Z1 X2 ... in order)", path=path, line=5)
    if n_markers != len(labels):
        raise InputError(f"line 4 names {len(labels)} markers but the coordinate line 5 has columns "
                         f"for {n_markers}", path=path, line=4)
    if n_markers == 0:
        raise InputError("no marker labels on line 4", path=path, line=4)
    if isinstance(header.get("NumMarkers"), int) and header["NumMarkers"] != n_markers:
        raise InputError(f"header NumMarkers is {header['NumMarkers']} but line 4 names {n_markers} "
                         f"markers ({', '.join(labels[:5])}...)", path=path, line=3)

    return {"sep": sep, "meta": meta, "header": header, "rate": rate, "units": units,
            "labels": labels, "n_markers": n_markers, "data_start": data_start}


def _finish(values, n_cells, line_no, h: dict, path: Path, checked: bool = False) -> MarkerRecording:
    """The recording from the parsed data cells ``values`` (rows, 2 + 3 markers): checks of the
    cells and the time, occlusions, units, the header's agreement with the rows. ``checked``:
    the cells are known finite or NaN and within :data:`ABSURD_M` (:func:`_check_finite` passes)."""
    labels, n_markers, header, meta = h["labels"], h["n_markers"], h["header"], h["meta"]
    units, rate = h["units"], h["rate"]
    n_cols = 2 + 3 * n_markers
    if values.shape[0] == 0:
        raise InputError("no data rows: the file has only its header", path=path)
    if not checked:
        _check_finite(values, UNIT_SCALE[units], labels, line_no, path)
    frame_col, time = values[:, 0], values[:, 1]
    bad_t = np.flatnonzero(~np.isfinite(time))
    if bad_t.size:
        raise InputError("the Time cell is empty or not finite", path=path, line=int(line_no[bad_t[0]]))
    back = np.flatnonzero(np.diff(time) <= 0)
    if back.size:
        i = back[0] + 1
        raise InputError(f"Time {time[i]:g} is not after the previous row's {time[i - 1]:g} "
                         "(time must increase strictly)", path=path, line=int(line_no[i]))

    xyz = values[:, 2:].reshape(-1, n_markers, 3)
    finite = np.isfinite(xyz)
    n_fin = finite[..., 0].astype(np.int8) + finite[..., 1] + finite[..., 2]   # (T, M) finite axes
    partial = (n_fin > 0) & (n_fin < 3)
    shifted = partial & (n_cells > n_cols)[:, None]
    if shifted.any():
        # an occluded marker is three empty cells (FORMAT.md); a row with more cells than the
        # header names and a marker with one or two empty cells is a damaged row (a doubled
        # separator shifts every later cell): never guess
        r, m = (int(x[0]) for x in np.nonzero(shifted))
        axes = "".join(a for a, ok in zip("XYZ", finite[r, m]) if not ok)
        raise InputError(f"marker {labels[m]} has an empty or non-numeric {axes} cell but not all "
                         f"three (columns {3 + 3 * m}-{5 + 3 * m}): a damaged row (doubled or "
                         "missing separator?) would shift every later marker", path=path,
                         line=int(line_no[r]), label=labels[m])
    missing = n_fin < 3                 # a blank/NaN cell: the marker is out for that frame
    meta["partial_markers"] = int(partial.sum())   # frames x markers with 1-2 blank cells
    xyz[missing] = np.nan
    positions = xyz * UNIT_SCALE[units]

    n_rows = int(time.shape[0])
    meta["n_rows"] = n_rows
    meta["first_frame"] = int(frame_col[0]) if n_rows and np.isfinite(frame_col[0]) else None
    mismatch = []
    if isinstance(header.get("NumFrames"), int) and header["NumFrames"] != n_rows:
        mismatch.append(f"NumFrames: header {header['NumFrames']}, file has {n_rows} rows")
    meta["header_mismatch"] = mismatch
    return MarkerRecording(time=time, positions=positions, labels=tuple(labels), rate_hz=float(rate),
                           units=units, source=path, meta=meta)


def _scan_body(text: str, sep: str, first_line: int):
    """Drop blank lines (only separators/spaces) from the data block, vectorised over bytes.

    Returns the kept lines joined by newlines, their 1-based line numbers in the file, and
    the number of cells on each.
    """
    buf = np.frombuffer((text + "\n").encode("utf-8"), dtype=np.uint8)
    nl = np.flatnonzero(buf == 10)
    starts = np.r_[0, nl[:-1] + 1]
    is_sep = buf == ord(sep)
    filler = is_sep | (buf == 32) | (buf == 9) | (buf == 10)
    # each segment starts[i]..nl[i] is one line with its newline, so none is empty
    keep = np.logical_or.reduceat(~filler, starts)
    n_cells = np.add.reduceat(is_sep, starts, dtype=np.int64)[keep] + 1
    line_no = (first_line + np.arange(nl.size))[keep]
    char_keep = np.repeat(keep, nl - starts + 1)
    kept = buf[char_keep].tobytes().decode("utf-8")[:-1] if keep.any() else ""
    return kept, line_no, n_cells


def _fast_values(body_text: str, sep: str, n_rows: int) -> np.ndarray | None:
    """All data cells as floats with numpy's C text parser (rows of equal length only).

    Empty cells become ``nan`` by plain string replacement first (two passes catch runs of
    separators). Returns None if the parser refuses a cell; the careful path then names it.
    """
    text = "\n" + body_text + "\n"
    dbl = sep + sep
    text = text.replace(dbl, sep + "nan" + sep).replace(dbl, sep + "nan" + sep)
    text = text.replace(sep + "\n", sep + "nan\n").replace("\n" + sep, "\nnan" + sep)
    try:
        values = np.loadtxt(io.StringIO(text), delimiter=sep, comments=None, ndmin=2, dtype=np.float64)
    except ValueError:
        return None
    return values if values.shape[0] == n_rows else None


def _careful_values(body, n_cells, sep, n_cols, n_markers, labels, line_no, path) -> np.ndarray:
    """Split into a string array (handles ragged rows and whitespace cells) and convert."""
    if len(body) == 0:
        return np.empty((0, n_cols))
    parts = [ln.split(sep, n_cols) for ln in body]
    extra = np.array([p[n_cols] if len(p) > n_cols else "" for p in parts], dtype=str)
    extra = np.strings.strip(np.strings.replace(extra, sep, ""))
    bad_rows = np.flatnonzero((np.strings.str_len(extra) > 0) & (np.strings.lower(extra) != "nan"))
    if bad_rows.size:
        _raise_extra(n_cells, bad_rows[0], n_cols, n_markers, line_no, path)
    cells = np.strings.strip(np.array([p[:n_cols] for p in parts], dtype=str).reshape(len(body), n_cols))
    blank = np.strings.str_len(cells) == 0
    try:
        return np.where(blank, "nan", cells).astype(np.float64)
    except ValueError:
        _raise_bad_cell(cells, blank, labels, line_no, path)


#: coordinates farther than this from the camera origin (m) are no measurement
ABSURD_M = 1e4


def _check_finite(values, scale, labels, line_no, path):
    """Refuse infinite cells (they are neither a number nor an occlusion) and coordinates beyond
    :data:`ABSURD_M`, naming the line and the column."""
    bad = np.isinf(values)
    with np.errstate(invalid="ignore"):
        bad[:, 2:] |= np.abs(values[:, 2:]) * scale > ABSURD_M
    if not bad.any():
        return
    r, c = (int(x[0]) for x in np.nonzero(bad))
    col = ("Frame#", "Time")[c] if c < 2 else f"{labels[(c - 2) // 3]} {'XYZ'[(c - 2) % 3]}"
    what = "infinite" if np.isinf(values[r, c]) else f"absurd (beyond {ABSURD_M:g} m)"
    raise InputError(f"cell {values[r, c]:.6g} in column {c + 1} ({col}) is {what}", path=path,
                     line=int(line_no[r]), label=labels[(c - 2) // 3] if c >= 2 else None)


def _raise_extra(n_cells, i, n_cols, n_markers, line_no, path):
    raise InputError(f"row has {n_cells[i]} cells with values beyond the {n_cols} expected "
                     f"(Frame#, Time and 3 per marker for {n_markers} markers)",
                     path=path, line=int(line_no[i]))


def _raise_bad_cell(cells, blank, labels, line_no, path):
    """Error path only: find the first cell that is not a number and name it."""
    flat = np.where(blank, "nan", cells)
    for r in range(flat.shape[0]):
        for c in range(flat.shape[1]):
            try:
                float(flat[r, c])
            except ValueError:
                col = ("Frame#", "Time")[c] if c < 2 else f"{labels[(c - 2) // 3]} {'XYZ'[(c - 2) % 3]}"
                raise InputError(f"cell {flat[r, c][:30]!r} in column {c + 1} ({col}) is not a number",
                                 path=path, line=int(line_no[r]),
                                 label=labels[(c - 2) // 3] if c >= 2 else None) from None
    raise InputError("a cell is not a number", path=path)  # pragma: no cover


def check_writable(path, overwrite: bool, units: str) -> tuple[Path, str]:
    """Shared checks of the marker writers: no silent overwrite, a known unit.
    Returns the path and the normalised unit."""
    path = Path(path)
    if path.exists() and not overwrite:
        raise FileExistsError(f"{path} exists; pass overwrite=True to replace it")
    norm = normalise_units(units)
    if norm is None:
        raise InputError(f"cannot write units {units!r} (expected one of mm, cm, m)", path=path)
    return path, norm


def write_trc(path: str | Path, rec: MarkerRecording, units: str = "mm", overwrite: bool = False,
              fmt: str = "%.5f") -> Path:
    """Write a marker recording as a tab-separated TRC file (the layout in the module docstring).

    The inverse of :func:`read_trc` [1]_ [2]_. Missing markers (NaN, or any non-finite
    coordinate) are three empty cells. Time is written with 12 significant digits. Frame
    numbers start at ``rec.meta["first_frame"]`` (default 1); the ``CameraRate``,
    ``OrigDataRate``, ``OrigDataStartFrame`` and ``OrigNumFrames`` header fields are kept from
    ``rec.meta`` when present. Creates missing parent folders.

    Parameters
    ----------
    path : str or pathlib.Path
        The file to write.
    rec : MarkerRecording
        The recording (metres).
    units : str, optional
        Unit of the written coordinates: ``"mm"`` (default), ``"cm"`` or ``"m"``.
    overwrite : bool, optional
        Replace an existing file (default False).
    fmt : str, optional
        printf format of a coordinate (default ``"%.5f"``).

    Returns
    -------
    pathlib.Path
        The path written.

    Raises
    ------
    FileExistsError
        If ``path`` exists and ``overwrite`` is False.
    InputError
        For an unknown unit, a label that is empty or holds tabs or newlines, or a
        non-finite time.

    References
    ----------
    .. [1] jointlab data format (docs/format.md), sec. Marker file (.trc).
    .. [2] Motion Analysis Corporation, TRC (track row column) file format.
    """
    path, units = check_writable(path, overwrite, units)
    for lb in rec.labels:
        if any(ch in lb for ch in "\t\n\r") or not lb.strip():
            raise InputError("a TRC label cannot be empty or contain tabs or newlines",
                             path=path, label=lb)
    T, M = rec.n_frames, rec.n_markers
    time = np.asarray(rec.time, dtype=float)
    if not np.all(np.isfinite(time)):
        raise InputError("cannot write a recording with non-finite times", path=path)
    first_frame = rec.meta.get("first_frame")
    first_frame = 1 if first_frame is None else int(first_frame)

    def meta_num(key, default):
        v = rec.meta.get(key)
        return v if isinstance(v, (int, float)) and not isinstance(v, bool) else default

    rate = f"{float(rec.rate_hz):.10g}"
    head = [
        "\t".join(["PathFileType", "4", "(X/Y/Z)", path.name]),
        "\t".join(HEADER_KEYS),
        "\t".join([rate, f"{float(meta_num('CameraRate', rec.rate_hz)):.10g}", str(T), str(M), units,
                   f"{float(meta_num('OrigDataRate', rec.rate_hz)):.10g}",
                   str(int(meta_num("OrigDataStartFrame", first_frame))),
                   str(int(meta_num("OrigNumFrames", T)))]),
        "\t".join(["Frame#", "Time"] + [f"{lb}\t\t" for lb in rec.labels]),
        "\t".join(["", ""] + [f"{a}{k}" for k in range(1, M + 1) for a in "XYZ"]),
        "",
    ]
    xyz = np.array(rec.positions, dtype=float) / UNIT_SCALE[units]
    xyz[~np.all(np.isfinite(xyz), axis=2)] = np.nan
    table = np.empty((T, 2 + 3 * M))
    table[:, 0] = first_frame + np.arange(T)
    table[:, 1] = time
    table[:, 2:] = xyz.reshape(T, 3 * M)
    row_fmt = "%d\t%.12g" + ("\t" + fmt) * (3 * M) + "\n"
    chunks = []
    chunk = max(1, 200_000 // (2 + 3 * M))
    for s in range(0, T, chunk):  # loop over blocks of rows; each block is one C-level format
        block = table[s:s + chunk]
        chunks.append((row_fmt * block.shape[0]) % tuple(block.ravel().tolist()))
    body = "".join(chunks)
    # fmt turns NaN into 'nan' (and only NaN into a word starting with 'nan'): make them empty cells
    body = body.replace("\tnan", "\t")
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "w", encoding="utf-8", newline="\n") as f:
        f.write("\n".join(head) + "\n")
        f.write(body)
    return path
