"""C3D marker files through ezc3d (FORMAT.md: marker files may be ``.trc`` or ``.c3d``).

Reading is two steps:

1. :func:`check_c3d_structure` validates the 512-byte header and walks the parameter section
   in pure Python, with bounds checks on every record, before ezc3d sees the file. It rejects
   with one clear :class:`InputError` what the C3D specification forbids and ezc3d does not
   catch: a first frame of 0 (frames are numbered from 1), a parameter section that overlaps
   the data section, ``POINT:DATA_START`` or ``POINT:USED`` disagreeing with the header, an
   unknown processor type, parameter records that run out of their section.
   ``read_NOTworking2.c3d`` of the ezc3d test files is rejected here (first frame 0, its
   8 parameter blocks overlap the data from block 5, ``POINT:DATA_START`` 0 vs header 5);
   ezc3d 1.7 itself reads it without complaint.
2. ezc3d decodes the data **in a subprocess with a timeout** (``isolate=True``, the default).
   Why: ezc3d is C++; on corrupted files it can segfault (killing the interpreter, and with it
   a whole batch) or loop forever. Measured here with ezc3d 1.7 on random byte flips in the
   header/parameter blocks of real files: of 60 Optotrak.c3d mutants, read bare, 1 segfaulted
   and 1 hung (both now rejected by step 1); of 140 further mutants (Qualisys.c3d and
   Optotrak.c3d) step 1 rejected 17, and of the 123 it let through 1 segfaulted and 2 hung
   inside ezc3d. Step 1 catches what we can name; the subprocess turns the rest into an
   :class:`InputError` instead of a dead interpreter. Cost: about 0.17 s per file for the interpreter start (Vicon.c3d: 0.21 s
   isolated vs 0.045 s in-process). ``isolate=False`` reads in-process, for trusted files.

Conventions of the returned :class:`MarkerRecording`:

* positions (T, M, 3) in metres, converted once from ``POINT:UNITS`` (``mm``, ``cm`` or ``m``);
  ``rec.units`` keeps the declared unit;
* a point is missing (all three coordinates NaN) in frames where its residual is negative or
  any coordinate is not finite;
* markers are the first ``POINT:USED`` labels of ``POINT:LABELS`` (continued in ``LABELS2``,
  ...), minus model outputs listed in ``POINT:ANGLES/FORCES/MOMENTS/POWERS/SCALARS/REACTIONS``
  (kept in ``meta["excluded_points"]``);
* ``time = (first_frame - 1 + arange(T)) / rate``, computed here from the header's 1-based first
  frame (ezc3d reports it 0-based), so frame 1 is at t = 0 and a file starting at frame 705 at
  200 Hz starts at 3.52 s. ``meta["first_frame"]`` is the 1-based number of the first frame;
* ``rate_hz`` is ``POINT:RATE`` (the header's rate if the parameter is absent);
* when the data section holds fewer frames than the header declares (a truncated file), the
  frames present are returned and ``meta["header_mismatch"]`` says so.
"""
from __future__ import annotations

import json
import os
import struct
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

from mocap.io.errors import InputError, read_bytes
from mocap.io.recording import MarkerRecording
from mocap.io.trc import ABSURD_M, UNIT_SCALE, check_writable, normalise_units

#: POINT parameters that list non-marker (model output) points
NON_MARKER_GROUPS = ("ANGLES", "FORCES", "MOMENTS", "POWERS", "SCALARS", "REACTIONS")
_PROCESSORS = {84: "intel", 85: "dec", 86: "mips"}
_TYPE_SIZE = {-1: 1, 1: 1, 2: 2, 4: 4}
#: what the isolated reader runs (``python -c _CHILD_CODE <c3d path> <output folder>``)
_CHILD_CODE = "from mocap.io.c3d import _child_main; _child_main()"


# ----------------------------------------------------------------------------- structure check

def _float(b: bytes, proc: str) -> float:
    if proc == "intel":
        return struct.unpack("<f", b)[0]
    if proc == "mips":
        return struct.unpack(">f", b)[0]
    # DEC F-float: 16-bit words high first, exponent bias 2 higher than IEEE -> IEEE / 4
    return struct.unpack("<f", b[2:4] + b[0:2])[0] / 4.0


def _param_value(data: bytes, ptype: int, dims: list[int], proc: str):
    """Decode a parameter's data (the C3D parameter record, spec section 'Parameter format')."""
    end = "<" if proc in ("intel", "dec") else ">"
    if ptype == -1:
        if len(dims) <= 1:
            return [data.decode("latin-1").strip()]
        width = dims[0]
        if width == 0:
            return []
        return [data[i:i + width].decode("latin-1").strip() for i in range(0, len(data), width)]
    n = len(data) // _TYPE_SIZE[ptype]
    if ptype == 1:
        return list(struct.unpack(f"{n}b", data))
    if ptype == 2:
        return list(struct.unpack(f"{end}{n}h", data))
    return [_float(data[4 * i:4 * i + 4], proc) for i in range(n)]


def check_c3d_structure(path: str | Path) -> dict:
    """Validate a C3D file's header and parameter section without ezc3d.

    Returns a summary: ``processor``, ``n_points``, ``first_frame`` (1-based), ``last_frame``,
    ``rate``, ``scale``, ``data_start`` (block), ``frames_in_file`` (complete frames the data
    section holds) and ``point`` (the POINT group's parameters, decoded). Raises
    :class:`InputError` listing every structural problem found, on one line.
    """
    path = Path(path)
    if not path.is_file():
        raise InputError("C3D file not found", path=path)
    raw = read_bytes(path)
    size = len(raw)
    if size < 1024:
        raise InputError(f"not a C3D file: {size} bytes, shorter than the header and one "
                         "parameter block (1024 bytes)", path=path)
    pblock, key = raw[0], raw[1]
    if key != 0x50:
        raise InputError(f"not a C3D file: header byte 2 is {key:#04x}, expected 0x50", path=path)
    if pblock < 2 or (pblock - 1) * 512 + 4 > size:
        raise InputError(f"not a C3D file: parameter section at block {pblock} is outside the "
                         f"file ({size} bytes)", path=path)
    p0 = (pblock - 1) * 512
    n_pblocks, proc_byte = raw[p0 + 2], raw[p0 + 3]
    proc = _PROCESSORS.get(proc_byte)
    if proc is None:
        raise InputError(f"not a valid C3D file: unknown processor type {proc_byte} in the "
                         "parameter section (expected 84 Intel, 85 DEC or 86 MIPS)", path=path)
    end = "<" if proc in ("intel", "dec") else ">"
    n_points, n_analog, first, last, _gap = struct.unpack(f"{end}5H", raw[2:12])
    scale = _float(raw[12:16], proc)
    data_start = struct.unpack(f"{end}H", raw[16:18])[0]
    rate = _float(raw[20:24], proc)

    problems = []
    if first == 0:
        problems.append("header first frame is 0 (C3D frames are numbered from 1)")
    if last < first:
        problems.append(f"header last frame {last} is before first frame {first}")
    if not (np.isfinite(rate) and rate > 0):
        problems.append(f"header frame rate is {rate!r}")
    if n_pblocks == 0:
        problems.append("parameter section declares 0 blocks")
    if data_start < pblock + max(n_pblocks, 1):
        problems.append(f"parameter section declares {n_pblocks} blocks from block {pblock} but the "
                        f"data section starts at block {data_start}")
    if (data_start - 1) * 512 > size:
        problems.append(f"data section starts at block {data_start}, past the end of the file")

    # walk the parameter records, bounded by the declared section and the file
    p_end = min(size, p0 + 512 * max(n_pblocks, 1))
    groups: dict[int, str] = {}
    params: list[tuple[int, str, object]] = []
    pos = p0 + 4
    n_records = 0
    n_before_walk = len(problems)
    while pos + 2 <= p_end:
        n_records += 1
        if n_records > 100_000:
            problems.append("parameter section has no end")
            break
        name_len = abs(struct.unpack("b", raw[pos:pos + 1])[0])
        gid = struct.unpack("b", raw[pos + 1:pos + 2])[0]
        if name_len == 0 or gid == 0:
            break
        name_b = raw[pos + 2:pos + 2 + name_len]
        if pos + 4 + name_len > p_end or not all(c >= 32 and c != 127 for c in name_b):
            problems.append(f"parameter record at byte {pos} has a bad name {name_b[:20]!r}")
            break
        name = name_b.decode("latin-1").strip().upper()
        off_pos = pos + 2 + name_len
        offset = struct.unpack(f"{end}h", raw[off_pos:off_pos + 2])[0]
        nxt = off_pos + offset if offset > 0 else p_end
        if offset < 0 or nxt > p_end:
            problems.append(f"parameter {name!r} points past its section (offset {offset})")
            break
        q = off_pos + 2
        if gid < 0:
            groups[-gid] = name
        else:
            if q + 2 > nxt:
                problems.append(f"parameter {name!r} is truncated")
                break
            ptype = struct.unpack("b", raw[q:q + 1])[0]
            ndim = raw[q + 1]
            if ptype not in _TYPE_SIZE or ndim > 7:
                problems.append(f"parameter {name!r} has type {ptype} and {ndim} dimensions")
                break
            dims = list(raw[q + 2:q + 2 + ndim])
            nbytes = _TYPE_SIZE[ptype] * int(np.prod(dims, dtype=np.int64))
            dstart = q + 2 + ndim
            if dstart + nbytes > nxt:
                problems.append(f"parameter {name!r} data ({nbytes} bytes) runs past its record")
                break
            params.append((gid, name, _param_value(raw[dstart:dstart + nbytes], ptype, dims, proc)))
        if offset == 0:
            break
        pos = nxt

    point = {name: val for gid, name, val in params if groups.get(gid) == "POINT"}
    if len(problems) == n_before_walk:  # the walk itself went through
        if "POINT" not in groups.values():
            problems.append("no POINT parameter group")
        used = point.get("USED")
        if used is not None and len(used) == 1 and used[0] != n_points:
            problems.append(f"POINT:USED is {used[0]} but the header says {n_points} points")
        ds = point.get("DATA_START")
        if ds is not None and len(ds) == 1 and ds[0] != data_start:
            problems.append(f"POINT:DATA_START is {ds[0]} but the header says {data_start}")
    if problems:
        raise InputError("not a valid C3D file: " + "; ".join(problems), path=path)

    word = 2 if scale >= 0 else 4
    frame_bytes = (4 * n_points + n_analog) * word
    data_bytes = size - (data_start - 1) * 512
    frames_in_file = data_bytes // frame_bytes if frame_bytes else 0
    return {"processor": proc, "n_points": n_points, "n_analog": n_analog, "first_frame": first,
            "last_frame": last, "rate": rate, "scale": scale, "data_start": data_start,
            "frames_declared": last - first + 1, "frames_in_file": int(frames_in_file),
            "point": point}


# ----------------------------------------------------------------------------- ezc3d decode

def _ezc3d_extract(path: str) -> tuple[dict, dict]:
    """Run ezc3d on ``path``: (arrays, info), all plain types (crosses a process boundary)."""
    import ezc3d

    c = ezc3d.c3d(str(path))
    pts = np.asarray(c["data"]["points"], dtype=float)[:3]            # (3, N, T)
    meta_points = c["data"].get("meta_points") or {}
    if "residuals" in meta_points:
        res = np.asarray(meta_points["residuals"], dtype=float)[0]        # (N, T)
    else:
        res = np.zeros(pts.shape[1:])
    point = {}
    for k, v in c["parameters"]["POINT"].items():
        if k.startswith("__"):
            continue
        val = v["value"]
        point[k] = [str(x) for x in val] if isinstance(val, list) else np.asarray(val).tolist()
    hdr = c["header"]["points"]
    info = {"first_frame0": int(hdr["first_frame"]), "last_frame0": int(hdr["last_frame"]),
            "frame_rate": float(hdr["frame_rate"]), "size": int(hdr["size"]), "point": point}
    return {"points": pts, "residuals": res}, info


def _child_main() -> None:  # pragma: no cover - runs in the subprocess
    src, out = sys.argv[1], sys.argv[2]
    try:
        arrays, info = _ezc3d_extract(src)
    except Exception as exc:  # noqa: BLE001 - reported to the parent as text
        sys.stderr.write(f"{type(exc).__name__}: {exc}".replace("\n", " ")[:500])
        sys.exit(3)
    np.savez(os.path.join(out, "arrays.npz"), **arrays)
    with open(os.path.join(out, "info.json"), "w") as f:
        json.dump(info, f)


def _extract_isolated(path: Path, timeout_s: float) -> tuple[dict, dict]:
    pkg_root = str(Path(__file__).resolve().parents[2])
    env = dict(os.environ)
    env["PYTHONPATH"] = pkg_root + (os.pathsep + env["PYTHONPATH"] if env.get("PYTHONPATH") else "")
    with tempfile.TemporaryDirectory(prefix="jointlab-c3d-") as tmp:
        cmd = [sys.executable, "-c", _CHILD_CODE, str(path), tmp]
        try:
            proc = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout_s, env=env)
        except subprocess.TimeoutExpired:
            raise InputError(f"ezc3d did not finish reading within {timeout_s:g} s; the file is "
                             "probably corrupt", path=path) from None
        if proc.returncode < 0:
            raise InputError(f"ezc3d crashed (signal {-proc.returncode}) reading the file; it is "
                             "probably corrupt", path=path)
        if proc.returncode != 0:
            msg = (proc.stderr.strip().splitlines() or ["no message"])[-1]
            raise InputError(f"ezc3d cannot read the file: {msg}", path=path)
        if not os.path.isfile(os.path.join(tmp, "info.json")):
            raise InputError("ezc3d returned no data for the file", path=path)
        with np.load(os.path.join(tmp, "arrays.npz")) as z:
            arrays = {k: z[k] for k in z.files}
        with open(os.path.join(tmp, "info.json")) as f:
            info = json.load(f)
    return arrays, info


def read_c3d(path: str | Path, *, isolate: bool = True, timeout_s: float = 60.0) -> MarkerRecording:
    """Read the marker points of a C3D file into a :class:`MarkerRecording`.

    The marker file of the data format [1]_ in the C3D layout [2]_ (conventions in the module
    docstring): the header and parameter section are checked here first
    (:func:`check_c3d_structure`), the points read with ezc3d, converted to metres.

    Parameters
    ----------
    path : str or pathlib.Path
        The ``.c3d`` file.
    isolate : bool, optional
        Run ezc3d in a subprocess killed after ``timeout_s`` seconds, so a corrupt file that
        crashes or hangs ezc3d becomes an :class:`InputError` (default True).
    timeout_s : float, optional
        Time limit of the isolated read (s); default 60.

    Returns
    -------
    MarkerRecording
        The labelled marker trajectories (NaN where a marker is missing).

    Raises
    ------
    InputError
        If the file is missing, its structure or parameters are invalid, or ezc3d fails.

    References
    ----------
    .. [1] jointlab data format (docs/format.md), sec. Marker file (.trc).
    .. [2] C3D.ORG, the C3D file format user guide; ezc3d (Michaud & Begon 2021).
    """
    path = Path(path)
    struct_info = check_c3d_structure(path)
    if isolate:
        arrays, info = _extract_isolated(path, timeout_s)
    else:
        try:
            arrays, info = _ezc3d_extract(str(path))
        except (RuntimeError, OSError, ValueError) as exc:
            raise InputError(f"ezc3d cannot read the file: {exc}".replace("\n", " "), path=path) from None
    point = info["point"]
    pts, res = arrays["points"], arrays["residuals"]
    n_points, n_frames = pts.shape[1], pts.shape[2]

    used = point.get("USED", [n_points])
    used = int(used[0]) if len(used) else n_points
    labels: list[str] = []
    for key in ["LABELS"] + [f"LABELS{k}" for k in range(2, 100)]:
        if key not in point:
            break
        labels += [str(x).strip() for x in point[key]]
    n_real = min(used, n_points)
    meta: dict = {}
    if len(labels) < n_real:
        meta["unlabelled_points"] = list(range(len(labels) + 1, n_real + 1))
        labels += [f"point{k}" for k in range(len(labels) + 1, n_real + 1)]
    labels = labels[:n_real]
    model_outputs = {str(x).strip() for g in NON_MARKER_GROUPS for x in point.get(g, []) if str(x).strip()}
    keep = [i for i, lb in enumerate(labels) if lb not in model_outputs]
    meta["excluded_points"] = [labels[i] for i in range(n_real) if i not in keep]

    units_list = sorted({normalise_units(u) for u in point.get("UNITS", []) if str(u).strip()},
                        key=str)
    if len(units_list) != 1 or units_list[0] is None:
        raise InputError(f"POINT:UNITS is {point.get('UNITS')!r}; expected one of mm, cm, m", path=path)
    units = units_list[0]
    rate_l = point.get("RATE", [])
    rate = float(rate_l[0]) if len(rate_l) and float(rate_l[0]) > 0 else info["frame_rate"]
    if not (np.isfinite(rate) and rate > 0):
        raise InputError(f"the point rate is {rate!r}; expected a positive number", path=path)
    hdr_rate = float(info["frame_rate"])
    if np.isfinite(hdr_rate) and hdr_rate > 0 and abs(hdr_rate - rate) > 0.01 * rate:
        raise InputError(f"POINT:RATE is {rate:g} Hz but the header says {hdr_rate:g} Hz (ratio "
                         f"{rate / hdr_rate:.3g}): the point rate was changed", path=path, label="RATE")

    xyz = np.transpose(pts[:, keep, :], (2, 1, 0)).copy()              # (T, M, 3)
    invalid = (res[keep, :].T < 0) | ~np.all(np.isfinite(xyz), axis=2)
    xyz[invalid] = np.nan
    first0 = info["first_frame0"]
    time = (first0 + np.arange(n_frames)) / rate
    if n_frames == 0 or not keep:
        raise InputError("no marker data: the file holds no frames" if n_frames == 0 else
                         "no marker points (only model outputs)", path=path)
    with np.errstate(invalid="ignore"):
        far = np.abs(xyz) * UNIT_SCALE[units] > ABSURD_M
    if far.any():
        f, m, a = (int(x[0]) for x in np.nonzero(far))
        raise InputError(f"frame {first0 + 1 + f}: marker {labels[keep[m]]!r} {'XYZ'[a]} is "
                         f"{xyz[f, m, a]:.6g} {units}, absurd (beyond {ABSURD_M:g} m): a damaged file",
                         path=path, label=labels[keep[m]])

    mismatch = []
    if struct_info["frames_declared"] != n_frames:
        mismatch.append(f"header declares frames {struct_info['first_frame']}..{struct_info['last_frame']} "
                        f"({struct_info['frames_declared']}) but the file holds {n_frames}")
    meta.update({"first_frame": first0 + 1, "n_points": n_points, "POINT:USED": used,
                 "header_first_frame": struct_info["first_frame"],
                 "header_last_frame": struct_info["last_frame"], "processor": struct_info["processor"],
                 "scale": struct_info["scale"], "header_mismatch": mismatch})
    return MarkerRecording(time=time, positions=xyz * UNIT_SCALE[units],
                           labels=tuple(labels[i] for i in keep), rate_hz=rate, units=units,
                           source=path, meta=meta)


def write_c3d(path: str | Path, rec: MarkerRecording, overwrite: bool = False, units: str = "mm") -> Path:
    """Write a marker recording as a C3D file (float data, Intel) with ezc3d.

    The inverse of :func:`read_c3d` [1]_ [2]_. C3D stores a uniform frame grid starting at a
    whole frame number, so ``rec.time`` must be ``(first_frame - 1 + arange(T)) / rate_hz``
    with an integer ``first_frame >= 1`` (within 1e-6 of a frame). Missing markers are
    written with residual -1. Creates missing parent folders.

    Parameters
    ----------
    path : str or pathlib.Path
        The file to write.
    rec : MarkerRecording
        The recording (metres).
    overwrite : bool, optional
        Replace an existing file (default False).
    units : str, optional
        Unit of the written points: ``"mm"`` (default), ``"cm"`` or ``"m"``.

    Returns
    -------
    pathlib.Path
        The path written.

    Raises
    ------
    FileExistsError
        If ``path`` exists and ``overwrite`` is False.
    InputError
        For an unknown unit, a rate that is not positive, or a time that is not on a
        uniform frame grid (instead of moving the samples).

    References
    ----------
    .. [1] jointlab data format (docs/format.md), sec. Marker file (.trc).
    .. [2] C3D.ORG, the C3D file format user guide; ezc3d (Michaud & Begon 2021).
    """
    import ezc3d

    path, units = check_writable(path, overwrite, units)
    rate = float(rec.rate_hz)
    if not (np.isfinite(rate) and rate > 0):
        raise InputError(f"rate_hz must be positive to write C3D, got {rate!r}", path=path)
    T = rec.n_frames
    if T == 0:
        raise InputError("cannot write an empty recording to C3D", path=path)
    frames = rec.time * rate
    f0 = int(np.round(frames[0]))
    grid_err = np.max(np.abs(frames - (f0 + np.arange(T))))
    if f0 < 0 or grid_err > 1e-6:
        raise InputError(f"C3D needs time on the frame grid (first_frame - 1 + k) / rate_hz with "
                         f"first_frame >= 1; this recording is {grid_err:.3g} frames off it "
                         f"(first time {rec.time[0]:g} s at {rate:g} Hz)", path=path)
    if f0 + T > 65535:
        raise InputError(f"C3D frame numbers stop at 65535; this recording ends at frame {f0 + T}",
                         path=path)
    xyz = np.array(rec.positions, dtype=float) / UNIT_SCALE[units]
    missing = ~np.all(np.isfinite(xyz), axis=2)                        # (T, M)
    xyz[missing] = 0.0
    pts = np.ones((4, rec.n_markers, T))
    pts[:3] = np.transpose(xyz, (2, 1, 0))
    residuals = np.where(missing.T, -1.0, 0.0)[None]                   # (1, M, T)

    c = ezc3d.c3d()
    c["parameters"]["POINT"]["RATE"]["value"] = [rate]
    c["parameters"]["POINT"]["LABELS"]["value"] = list(rec.labels)
    c["parameters"]["POINT"]["DESCRIPTIONS"]["value"] = [""] * rec.n_markers
    c["parameters"]["POINT"]["UNITS"]["value"] = [units]
    c["data"]["points"] = pts
    c["data"]["meta_points"] = {"residuals": residuals,
                                "camera_masks": np.zeros((7, rec.n_markers, T), dtype=bool)}
    c["header"]["points"]["first_frame"] = f0
    path.parent.mkdir(parents=True, exist_ok=True)
    c.write(str(path))
    return path
