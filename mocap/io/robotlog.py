"""Robot controller logs (FORMAT.md, "Robot log (.csv)")."""
from __future__ import annotations

import os
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from mocap.io.errors import InputError, check_control_chars, read_text

_QM = re.compile(r"^qm_(\d+)$")
_TAU = re.compile(r"^tau_(\d+)$")
_QD = re.compile(r"^qd_(\d+)$")
_ROW_BLOCK = 1 << 20          # rows per block where a whole-log check would copy the table


@dataclass(frozen=True)
class SamplingStats:
    """How a log was sampled: time steps and repeated rows (a controller that logs the same
    state again under a new time stamp). ``warnings`` says what a fit has to take care of."""

    n_samples: int
    step_min: float
    step_median: float
    step_max: float
    n_repeated: int              # rows whose every signal equals the previous row's
    irregular: bool              # steps vary by more than 1 % around the median

    @property
    def warnings(self) -> list[str]:
        out = []
        if self.irregular:
            out.append(f"irregular sampling: steps {self.step_min * 1e3:.3g} .. "
                       f"{self.step_max * 1e3:.3g} ms (median {self.step_median * 1e3:.3g} ms); "
                       "fits resample to a uniform grid")
        if self.n_repeated:
            out.append(f"{self.n_repeated} repeated rows ({100.0 * self.n_repeated / self.n_samples:.2g} %) "
                       "repeat the previous state under a new time stamp; fits drop them")
        return out

    def to_dict(self) -> dict:
        return {"n_samples": self.n_samples, "step_min_s": self.step_min,
                "step_median_s": self.step_median, "step_max_s": self.step_max,
                "rate_hz": 1.0 / self.step_median if self.step_median > 0 else float("nan"),
                "n_repeated": self.n_repeated, "irregular": self.irregular,
                "warnings": self.warnings}


@dataclass(frozen=True, eq=False)
class RobotLog:
    """A robot log: time, motor-side angles and joint torques, column j-1 for joint j.

    The robot log of the data format [1]_: the encoder angles ``q_m`` and the torque ``u`` of
    thesis eq. 2-4 [2]_, on the link side. Joints whose columns are absent are NaN.

    Attributes
    ----------
    time : numpy.ndarray
        (T,) sample times (s), strictly increasing.
    qm : numpy.ndarray
        (T, n) motor angles on the link side (rad); column j-1 holds ``qm_j``.
    tau : numpy.ndarray
        (T, n) joint torques (N m); column j-1 holds ``tau_j``.
    extra : dict
        Every other column, by name: (T,) arrays.
    source : pathlib.Path or None
        The file it was read from, if any.
    line_numbers : numpy.ndarray or range or None
        (T,) the file line of each sample, for messages.

    References
    ----------
    .. [1] jointlab data format (docs/format.md), sec. Robot log (.csv).
    .. [2] PA10 thesis (seeds 002), eq. 2-4.
    """

    time: np.ndarray
    qm: np.ndarray
    tau: np.ndarray
    extra: dict = field(default_factory=dict)
    source: Path | None = None
    line_numbers: np.ndarray | range | None = None   # (T,) the file line of each sample, for messages

    def line_of(self, i: int) -> int | None:
        """The file line of sample ``i`` (None for a log not read from a file)."""
        return None if self.line_numbers is None else int(self.line_numbers[i])

    @property
    def n_samples(self) -> int:
        return int(self.time.shape[0])

    @property
    def n_joints(self) -> int:
        return int(self.qm.shape[1])

    @property
    def rate_hz(self) -> float:
        return (float(1.0 / np.median(np.diff(self.time), overwrite_input=True))
                if self.n_samples > 1 else float("nan"))

    def coupled(self, coupling) -> "RobotLog":
        """The log in URDF joints for a controller with coupled joints (FORMAT.md ``[robot]
        coupling``): ``q_urdf = coupling @ q_log`` (also ``qd_<j>``) and ``tau_urdf =
        inverse(coupling)^T @ tau_log``. A URDF joint is NaN where a log joint it depends on is."""
        C = np.asarray(coupling, float)
        n = self.n_joints
        if C.shape != (n, n):
            raise InputError(f"[robot] coupling is {C.shape[0]}x{C.shape[1]}, the log has {n} joints",
                             path=self.source, label="coupling")
        Ct = np.linalg.inv(C).T

        def apply(M, A):  # rows are samples: x_urdf = M @ x_log, NaN where an input used is NaN
            bad = np.isnan(A).astype(float) @ (M != 0).T.astype(float) > 0
            return np.where(bad, np.nan, np.nan_to_num(A) @ M.T)

        extra = dict(self.extra)
        qd = [f"qd_{j + 1}" for j in range(n)]
        if any(k in extra for k in qd):
            QD = np.column_stack([np.asarray(extra.get(k, np.full(self.n_samples, np.nan)), float)
                                  for k in qd])
            extra.update({k: v for k, v in zip(qd, apply(C, QD).T)})
        return RobotLog(self.time, apply(C, self.qm), apply(Ct, self.tau), extra, self.source,
                        self.line_numbers)

    def check_limits(self, lower, upper, names=()) -> None:
        """Refuse angles far beyond the URDF's joint limits (by more than 10 % of the range plus
        0.05 rad): the log is then almost surely in degrees. ``lower``/``upper`` (n,) rad."""
        lo, hi = np.asarray(lower, float), np.asarray(upper, float)
        margin = 0.05 + 0.1 * np.where(np.isfinite(hi - lo), hi - lo, 0.0)
        with np.errstate(invalid="ignore"):
            q_hi = np.nanmax(np.where(np.isfinite(self.qm), self.qm, -np.inf), axis=0)
            q_lo = np.nanmin(np.where(np.isfinite(self.qm), self.qm, np.inf), axis=0)
        bad = np.flatnonzero((q_hi > hi + margin) | (q_lo < lo - margin))
        if bad.size:
            j = int(bad[0])
            v = q_hi[j] if q_hi[j] > hi[j] + margin[j] else q_lo[j]
            name = names[j] if j < len(names) else f"joint {j + 1}"
            raise InputError(f"column qm_{j + 1} reaches {v:.4g} rad, beyond the URDF limits of {name} "
                             f"[{lo[j]:.3f}, {hi[j]:.3f}] rad: degrees suspected (the format wants radians)",
                             path=self.source, label=f"qm_{j + 1}")

    def check_drive_limits(self, max_torque, max_velocity, names=(), factor: float = 100.0) -> None:
        """Refuse torques (``tau_<j>``) or logged velocities (``qd_<j>``) beyond ``factor`` times
        the drive's limit (a damaged cell, or a unit far off): ``max_torque``/``max_velocity``
        (n,) link side, inf where unknown."""
        for sym, X, lim, unit in (("tau", self.tau, max_torque, "N m"),
                                  ("qd", self.qd, max_velocity, "rad/s")):
            if X is None:
                continue
            lim = np.asarray(lim, float)
            lim = factor * np.where(lim > 0, lim, np.inf)            # 0: no limit given
            with np.errstate(invalid="ignore"):
                bad = np.abs(X) > lim[None, :]
            if bad.any():
                i, j = (int(x[0]) for x in np.nonzero(bad))
                name = names[j] if j < len(names) else f"joint {j + 1}"
                raise InputError(f"column {sym}_{j + 1} has {X[i, j]:.4g} {unit}, more than {factor:g} "
                                 f"times the drive limit of {name} ({lim[j] / factor:.4g} {unit}): a "
                                 "damaged value or the wrong unit", path=self.source,
                                 line=self.line_of(i), label=f"{sym}_{j + 1}")

    def check_joints_logged(self, joints, what: str = "the trial") -> None:
        """Every joint in ``joints`` (1-based) needs ``qm_<j>`` and ``tau_<j>`` values."""
        for j in joints:
            for sym, X in (("qm", self.qm), ("tau", self.tau)):
                if j > X.shape[1] or not np.isfinite(X[:, j - 1]).any():
                    raise InputError(f"no {sym}_{j} values, but {what} moves joint {j}",
                                     path=self.source, line=1, label=f"{sym}_{j}")

    @property
    def qd(self) -> np.ndarray | None:
        """(T, n) logged joint velocities ``qd_<j>`` (NaN for joints without one), or None when
        the log has none."""
        cols = {int(m.group(1)): v for k, v in self.extra.items() for m in [_QD.match(k)] if m}
        if not cols:
            return None
        out = np.full(self.qm.shape, np.nan)
        for j, v in cols.items():
            if 1 <= j <= self.n_joints:
                out[:, j - 1] = v
        return out

    def repeated_rows(self) -> np.ndarray:
        """(T,) True where a row repeats the previous row's values (all but ``time``; NaN equal
        to NaN): a stale sample logged again. The first signal is compared over a block of rows,
        the others only on the rows still equal, so that a long log needs no copy of its table."""
        cols = [self.qm[:, j] for j in range(self.n_joints)] + \
               [self.tau[:, j] for j in range(self.n_joints)] + \
               [np.asarray(v, float) for k, v in self.extra.items()
                for m in [_QD.match(k)] if m and 1 <= int(m.group(1)) <= self.n_joints]
        T = self.n_samples
        out = np.zeros(T, bool)
        if not cols:
            out[1:] = True
            return out
        for a in range(1, T, _ROW_BLOCK):
            b = min(T, a + _ROW_BLOCK)
            cur, prev = cols[0][a:b], cols[0][a - 1:b - 1]
            i = a + np.flatnonzero((cur == prev) | (np.isnan(cur) & np.isnan(prev)))
            for x in cols[1:]:
                if not i.size:
                    break
                cur, prev = x[i], x[i - 1]
                i = i[(cur == prev) | (np.isnan(cur) & np.isnan(prev))]
            out[i] = True
        return out

    def sampling(self) -> SamplingStats:
        dt = np.diff(self.time)
        if dt.size == 0:
            return SamplingStats(self.n_samples, float("nan"), float("nan"), float("nan"), 0, False)
        lo, hi = float(dt.min()), float(dt.max())
        med = float(np.median(dt, overwrite_input=True))
        irregular = max(hi - med, med - lo) > 0.01 * med        # the largest |dt - median|
        return SamplingStats(self.n_samples, lo, med, hi, int(self.repeated_rows().sum()),
                             bool(irregular))

    def columns(self) -> dict[str, np.ndarray]:
        cols = {"time": self.time}
        for j in range(self.n_joints):
            cols[f"qm_{j + 1}"] = self.qm[:, j]
        for j in range(self.n_joints):
            cols[f"tau_{j + 1}"] = self.tau[:, j]
        cols.update(self.extra)
        return cols


def _parse_float_table(rows: list[list[str]], header: list[str], path: Path,
                       line_no: np.ndarray) -> np.ndarray:
    arr = np.array(rows, dtype=object)
    strs = np.char.strip(arr.astype(str))
    empty = (strs == "") | (np.char.lower(strs) == "nan")
    strs = np.where(empty, "nan", strs)
    try:
        return strs.astype(float)
    except ValueError:
        # locate the offending cell for the message (rare path)
        for i, row in enumerate(strs):
            for k, cell in enumerate(row):
                try:
                    float(cell)
                except ValueError:
                    raise InputError(f"column {k + 1} ({header[k]!r}) has a non-numeric value {cell!r}",
                                     path=path, line=int(line_no[i])) from None
        raise


#: the names FORMAT.md gives a robot log's columns
_CANONICAL = re.compile(r"^(time|(qm|tau|qd)_([1-9]\d*))$")
#: a name that is a FORMAT.md name in another spelling: qm3, QM_3, tau-3, qd_03, "tau 3"
_LOOKALIKE = re.compile(r"^(qm|tau|qd)[\W_]*0*(\d+)$", re.IGNORECASE)
#: a FORMAT.md prefix followed by a damaged joint index: qm_1e30, tau_inf, qd_2x
_DAMAGED_INDEX = re.compile(r"^(qm|tau|qd)[\W_]*(\d|inf|nan)", re.IGNORECASE)
#: an extra column named after a joint's signal: tau_1_filtered, qm_2_ref
_SUFFIXED = re.compile(r"^(qm|tau|qd)_[1-9]\d*_[A-Za-z]")
#: values no joint angle (rad), torque (N m) or velocity (rad/s) of any robot reaches; a
#: campaign's reader checks torques and velocities against the robot's own limits too
ABSURD = 1e9


def _distance_at_most_one(a: str, b: str) -> bool:
    """True when ``a`` becomes ``b`` by at most one edit (insert, delete, substitute, swap)."""
    if a == b:
        return True
    la, lb = len(a), len(b)
    if abs(la - lb) > 1:
        return False
    i = 0
    while i < min(la, lb) and a[i] == b[i]:
        i += 1
    if la == lb:
        return a[i + 1:] == b[i + 1:] or (a[i + 2:] == b[i + 2:] and a[i:i + 2] == b[i:i + 2][::-1])
    return (a[i + 1:] == b[i:]) if la > lb else (a[i:] == b[i + 1:])


def check_header(header: list[str], path: Path, n_joints: int | None = None) -> None:
    """Refuse a header whose names cannot be read without guessing (FORMAT.md names ``time``,
    ``qm_<j>``, ``tau_<j>``, ``qd_<j>``; any other name is an extra column): an empty or
    unprintable name, a name used twice, or a damaged FORMAT.md name (``qm3``, ``tua_5``,
    ``qm_``: one edit from ``qm_<j>``), which would otherwise be kept as an extra column
    while its joint reads as NaN."""
    seen = {}
    idx = [int(m.group(3)) for h in header for m in [_CANONICAL.match(h)] if m and m.group(3)]
    top = max([n_joints or 0, 9] + idx)
    for k, h in enumerate(header, 1):
        where = f"column {k}"
        if not h:
            raise InputError(f"{where} has no name (a damaged header or a doubled separator?)",
                             path=path, line=1)
        if not h.isprintable():
            raise InputError(f"{where} name {h!r} has a control character (a damaged header)",
                             path=path, line=1)
        if h in seen:
            raise InputError(f"{where} {h!r} repeats column {seen[h]}'s name", path=path, line=1)
        seen[h] = k
        if _CANONICAL.match(h):
            continue
        m = _LOOKALIKE.match(h.strip())
        if m:
            want = f"{m.group(1).lower()}_{int(m.group(2))}"
            if int(m.group(2)) == 0:
                raise InputError(f"{where} {h!r}: joint indices start at 1 (qm_1, tau_1, ...)",
                                 path=path, line=1)
        else:
            digits = re.findall(r"\d+", h)
            js = {int(d) for d in digits if len(d) < 6} | set(range(1, top + 1))
            cands = ["time"] + [f"{p}_{j}" for p in ("qm", "tau", "qd") for j in sorted(js)]
            want = next((c for c in cands if _distance_at_most_one(h.lower(), c)), None)
        if want is None and _DAMAGED_INDEX.match(h) and not _SUFFIXED.match(h):
            raise InputError(f"{where} {h!r} is not a FORMAT.md name: a damaged joint index? "
                             "(time, qm_<j>, tau_<j>, qd_<j> with j = 1, 2, ...; names such as "
                             "tau_1_filtered are kept as extra columns)", path=path, line=1)
        if want is not None:
            raise InputError(f"{where} {h!r} is not a FORMAT.md name; did you mean {want!r}? "
                             "(time, qm_<j>, tau_<j>, qd_<j>; other names are kept as extra "
                             "columns, so a misspelt one would lose its joint)", path=path, line=1)


def _check_values(data: np.ndarray, header: list[str], path: Path, line_no: np.ndarray) -> None:
    """Infinite cells anywhere, and angles, torques or velocities beyond :data:`ABSURD`."""
    bad = np.isinf(data)
    signal = np.array([bool(_CANONICAL.match(h)) and h != "time" for h in header])
    with np.errstate(invalid="ignore"):
        bad |= signal[None, :] & (np.abs(data) > ABSURD)
    if bad.any():
        i, k = (int(x[0]) for x in np.nonzero(bad))
        what = "infinite" if np.isinf(data[i, k]) else "absurd"
        raise InputError(f"column {k + 1} ({header[k]!r}) has an {what} value {data[i, k]:.6g}",
                         path=path, line=int(line_no[i]), label=header[k])


#: cells the streaming reader reads as a missing sample (the careful parser: empty or ``nan`` in
#: any case); every other cell must be a number pyarrow's float parser takes whole
_NAN_SPELLINGS = ["", "nan", "naN", "nAn", "nAN", "Nan", "NaN", "NAn", "NAN"]
_CHUNK = 1 << 24
_TAIL = 1 << 20          # bytes at the end of a file whose mean line length bounds the row count
#: files from this size on stream through :func:`_read_fast` (the quicker reader from here on)
STREAM_MIN_BYTES = 1 << 17


def _count_rows(fh, first: bytes) -> int | None:
    """Lines below the header of an open file positioned after it (``first``: bytes already read
    past the header), counted by their line feeds in blocks of 16 MiB; None when a carriage
    return is not followed by a line feed (a line break the count would miss)."""
    n_lf, n_cr, n_crlf, prev, last = 0, 0, 0, b"", b""
    chunk = first
    while chunk:
        n_lf += chunk.count(b"\n")
        n_cr += chunk.count(b"\r")
        n_crlf += chunk.count(b"\r\n") + (prev == b"\r" and chunk[:1] == b"\n")
        prev = last = chunk[-1:]
        chunk = fh.read(_CHUNK)
    if n_cr != n_crlf:
        return None
    return n_lf + (0 if last in (b"\n", b"") else 1)


def _row_capacity(fh, body: bytes, start: int) -> int | None:
    """The number of rows to allocate for the lines below the header (``start``: the header's
    end in bytes; ``body``: the bytes read past it). Exact when ``body`` holds the whole file or
    the file has carriage returns (:func:`_count_rows`); otherwise an upper estimate from the
    shortest mean line length of the first block and of the last MiB, so that the file is read
    once, not counted first (the streaming reader grows its arrays in the rare file whose lines
    are shorter in between). None: no row."""
    size = os.fstat(fh.fileno()).st_size
    if start + len(body) >= size or b"\r" in body:
        return _count_rows(fh, body)
    fh.seek(max(start + len(body), size - _TAIL))
    tail = fh.read()
    if b"\r" in tail:
        fh.seek(start + len(body))
        return _count_rows(fh, body)
    tail = tail[tail.find(b"\n") + 1:]
    lens = [len(b[:b.rfind(b"\n") + 1]) / b.count(b"\n") for b in (body, tail) if b.count(b"\n")]
    if not lens:
        return None
    return int((size - start) / min(lens) * 1.01) + 64


def _read_fast(path: Path, n_joints: int | None) -> RobotLog | None:
    """The streaming reader: the log read block by block by pyarrow's CSV reader straight into
    the float64 arrays of the :class:`RobotLog` (no text copy of the file, no per-cell Python
    object). It takes only a well-formed log: a valid header (:func:`check_header`), rows of
    numbers or missing cells (:data:`_NAN_SPELLINGS`) as wide as the header, no blank line,
    finite values, signals within :data:`ABSURD`, strictly increasing time. Anything
    else returns None and :func:`read_robot_log` reads the file with the careful parser, which
    names the file, the line and the cell at fault."""
    try:
        import pyarrow as pa
        import pyarrow.csv as pacsv
    except ImportError:                                  # pragma: no cover - pyarrow optional
        return None
    try:
        fh = open(path, "rb")
    except OSError:
        return None                              # the careful parser says why, naming the file
    with fh:
        head = fh.read(_CHUNK)
        bom = 3 if head.startswith(b"\xef\xbb\xbf") else 0
        head = head[bom:]
        cut = head.find(b"\n")
        if cut < 0:
            return None
        try:
            line1 = head[:cut].decode("utf-8")
        except UnicodeDecodeError:
            return None
        line1 = line1[:-1] if line1.endswith("\r") else line1
        if any(c in line1 for c in "\r\x85\u2028\u2029") or not line1.strip():
            return None
        header = [h.strip() for h in line1.split(",")]
        try:
            check_control_chars(line1, path)
            if "time" not in header:
                return None
            check_header(header, path, n_joints)
        except InputError:
            return None
        T = _row_capacity(fh, head[cut + 1:], bom + cut + 1)
    if not T:
        return None
    joint_cols = [(h, m) for h in header for m in [_QM.match(h) or _TAU.match(h)] if m]
    n_found = max((int(m.group(1)) for _, m in joint_cols), default=0)
    if n_joints is None:
        n_joints = n_found
    elif n_found > n_joints:
        return None
    def alloc(cap):
        """The arrays of ``cap`` rows and, per file column, the array (or column view) it fills."""
        time = np.empty(cap)
        qm, tau = np.empty((cap, n_joints)), np.empty((cap, n_joints))
        extra, dest = {}, []
        for h in header:
            m_q, m_t = _QM.match(h), _TAU.match(h)
            if h == "time":
                dest.append(time)
            elif m_q:
                dest.append(qm[:, int(m_q.group(1)) - 1])
            elif m_t:
                dest.append(tau[:, int(m_t.group(1)) - 1])
            else:
                extra[h] = np.empty(cap)
                dest.append(extra[h])
        for X, p in ((qm, _QM), (tau, _TAU)):
            have = {int(m.group(1)) for h in header for m in [p.match(h)] if m}
            for j in range(n_joints):
                if j + 1 not in have:
                    X[:, j] = np.nan
        return time, qm, tau, extra, dest

    cap = T
    time, qm, tau, extra, dest = alloc(cap)
    names = [f"c{k}" for k in range(len(header))]
    kind = [0 if h == "time" else 1 if _CANONICAL.match(h) else 2 for h in header]
    pool = pa.system_memory_pool()                      # gives freed blocks back at once
    try:
        reader = pacsv.open_csv(
            path, memory_pool=pool,
            read_options=pacsv.ReadOptions(column_names=names, skip_rows=1, block_size=1 << 20),
            parse_options=pacsv.ParseOptions(delimiter=",", quote_char=False,
                                             ignore_empty_lines=False),
            convert_options=pacsv.ConvertOptions(column_types={c: pa.float64() for c in names},
                                                 null_values=_NAN_SPELLINGS,
                                                 strings_can_be_null=False))
        pos = 0
        for batch in reader:
            n = batch.num_rows
            if pos + n > cap:                       # lines shorter than the estimate's: grow
                cap = max(int(cap * 1.25), pos + n)
                old = (time, qm, tau, extra)
                time, qm, tau, extra, dest = alloc(cap)
                time[:pos], qm[:pos], tau[:pos] = old[0][:pos], old[1][:pos], old[2][:pos]
                for h in extra:
                    extra[h][:pos] = old[3][h][:pos]
                del old
            for k, col in enumerate(batch.columns):
                c = col.to_numpy(zero_copy_only=False)
                if kind[k] == 0 and not (np.isfinite(c).all() and (pos == 0 or c[0] > time[pos - 1])
                                         and (c[1:] > c[:-1]).all()):
                    return None                         # a missing time, time not increasing
                with np.errstate(invalid="ignore"):
                    if (kind[k] == 1 and (np.abs(c) > ABSURD).any()) or (kind[k] == 2 and np.isinf(c).any()):
                        return None                     # infinite or absurd values
                dest[k][pos:pos + n] = c
            pos += n
    except pa.ArrowException:
        return None                                     # a cell that is no number, a row's width
    finally:
        pool.release_unused()
    if pos == 0:
        return None
    return RobotLog(time[:pos], qm[:pos], tau[:pos], {h: v[:pos] for h, v in extra.items()},
                    path, range(2, pos + 2))


def read_robot_log(path: str | Path, n_joints: int | None = None) -> RobotLog:
    """Read a robot log CSV into a :class:`RobotLog`.

    The layout of the data format [1]_ (``time, qm_<j>..., tau_<j>...`` and any other
    columns). The header is checked by :func:`check_header`; every row must have as many cells
    as the header has names (never shifted). A well-formed log streams through a fast reader
    (memory: the float64 arrays only); any other goes through a careful one, whose errors name
    the file and the line.

    Parameters
    ----------
    path : str or pathlib.Path
        The ``.csv`` log.
    n_joints : int, optional
        Width of ``qm``/``tau`` (from the URDF); a log naming a joint beyond it is an error.
        None: the highest joint index found.

    Returns
    -------
    RobotLog
        The log; absent joints' columns NaN.

    Raises
    ------
    InputError
        If the file is missing, the header is invalid, a row has the wrong number of cells,
        or a cell is not a number, infinite or absurd (:data:`ABSURD`), naming file and line.

    References
    ----------
    .. [1] jointlab data format (docs/format.md), sec. Robot log (.csv).
    .. [2] PA10 thesis (seeds 002), eq. 2-4.
    """
    path = Path(path)
    if not path.is_file():
        raise InputError("robot log not found", path=path)
    try:   # small files: the careful parser is as quick
        fast = _read_fast(path, n_joints) if path.stat().st_size >= STREAM_MIN_BYTES else None
    except OSError:
        fast = None
    return fast if fast is not None else _read_careful(path, n_joints)


def _read_careful(path: Path, n_joints: int | None) -> RobotLog:
    """The careful reader: the whole text checked and parsed line by line, every error naming
    the file, the line and the cell (the reader of any log the streaming reader declines)."""
    text = read_text(path, "utf-8-sig")
    check_control_chars(text, path, also="\x85\u2028\u2029")   # splitlines would break there
    lines = text.splitlines()
    if not lines or not lines[0].strip():
        raise InputError("robot log is empty" if not lines else "line 1 (the header) is empty",
                         path=path, line=None if not lines else 1)
    header = [h.strip() for h in lines[0].split(",")]
    if "time" not in header:
        raise InputError(f"no 'time' column in the header (found {header[:12]})", path=path, line=1)
    body = np.array(lines[1:], dtype=str)
    keep = np.char.str_len(np.char.strip(body)) > 0
    line_no = np.flatnonzero(keep) + 2
    body = body[keep]
    if body.size == 0:
        raise InputError("robot log has a header but no samples", path=path)
    n_cells = np.char.count(body, ",") + 1
    if np.any(n_cells != len(header)):
        if np.all(n_cells == n_cells[0]):
            raise InputError(f"the header names {len(header)} columns but every row has {n_cells[0]} "
                             "cells (a lost or extra separator in the header?)", path=path, line=1)
        i = int(np.flatnonzero(n_cells != len(header))[0])
        raise InputError(f"expected {len(header)} cells, found {n_cells[i]}", path=path,
                         line=int(line_no[i]))
    check_header(header, path, n_joints)
    data = None
    try:  # fast path: a complete numeric table (C parser); anything unusual takes the slow path
        data = np.loadtxt(list(body), delimiter=",", dtype=float, ndmin=2)
        if data.shape != (body.size, len(header)):
            data = None
    except ValueError:
        data = None
    if data is None:
        data = _parse_float_table([ln.split(",") for ln in body], header, path, line_no)
    _check_values(data, header, path, line_no)
    col = {h: data[:, k] for k, h in enumerate(header)}
    t = col["time"]
    bad = np.flatnonzero(~np.isfinite(t))
    if bad.size:
        raise InputError("missing time value", path=path, line=int(line_no[bad[0]]))
    nonmono = np.flatnonzero(np.diff(t) <= 0)
    if nonmono.size:
        i = int(nonmono[0]) + 1
        raise InputError(f"time is not strictly increasing ({t[i - 1]!r} then {t[i]!r})",
                         path=path, line=int(line_no[i]))
    idx = [int(m.group(1)) for h in header for m in [_QM.match(h) or _TAU.match(h)] if m]
    if any(j < 1 for j in idx):
        raise InputError("joint indices start at 1 (qm_1, tau_1, ...)", path=path, line=1)
    n_found = max(idx, default=0)
    if n_joints is None:
        n_joints = n_found
    elif n_found > n_joints:
        raise InputError(f"log has columns for joint {n_found} but the robot has {n_joints} joints",
                         path=path, line=1)
    T = t.shape[0]
    qm = np.full((T, n_joints), np.nan)
    tau = np.full((T, n_joints), np.nan)
    extra = {}
    for h in header:
        if h == "time":
            continue
        m_q, m_t = _QM.match(h), _TAU.match(h)
        if m_q:
            qm[:, int(m_q.group(1)) - 1] = col[h]
        elif m_t:
            tau[:, int(m_t.group(1)) - 1] = col[h]
        else:
            extra[h] = col[h]
    return RobotLog(t, qm, tau, extra, path, line_no)


def write_robot_log(path: str | Path, log: RobotLog, joints=None, overwrite: bool = False,
                    fmt: str = "%.9g") -> Path:
    """Write a robot log CSV, the inverse of :func:`read_robot_log` [1]_ [2]_.

    NaN is written as an empty cell; missing parent folders are created.

    Parameters
    ----------
    path : str or pathlib.Path
        The file to write.
    log : RobotLog
        The log.
    joints : sequence of int, optional
        The joints (1-based) whose columns are written; default all.
    overwrite : bool, optional
        Replace an existing file (default False).
    fmt : str, optional
        printf format of a value (default ``"%.9g"``).

    Returns
    -------
    pathlib.Path
        The path written.

    Raises
    ------
    FileExistsError
        If ``path`` exists and ``overwrite`` is False.

    References
    ----------
    .. [1] jointlab data format (docs/format.md), sec. Robot log (.csv).
    .. [2] PA10 thesis (seeds 002), eq. 2-4.
    """
    path = Path(path)
    if path.exists() and not overwrite:
        raise FileExistsError(f"{path} exists; refusing to overwrite")
    joints = range(1, log.n_joints + 1) if joints is None else list(joints)
    names = ["time"] + [f"qm_{j}" for j in joints] + [f"tau_{j}" for j in joints] + list(log.extra)
    cols = [log.time] + [log.qm[:, j - 1] for j in joints] + [log.tau[:, j - 1] for j in joints] \
        + [np.asarray(v, float) for v in log.extra.values()]
    data = np.column_stack(cols)
    body = np.char.mod(fmt, data)
    body[~np.isfinite(data)] = ""
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "w", encoding="utf-8", newline="\n") as fh:
        fh.write(",".join(names) + "\n")
        fh.write("\n".join(",".join(r) for r in body))
        fh.write("\n")
    return path
