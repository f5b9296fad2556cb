"""TRC reader/writer: real files against an independent text parse, synthetic edge cases, round trips."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from mocap.io.errors import InputError
from mocap.io.recording import MarkerRecording
from mocap.io.trc import read_trc, write_trc
from tests_paths import real_file, real_names

REAL_TRC = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "real" / "trc"
REAL_NAMES = real_names("trc", "*.trc")      # ../shared, else the copies in fixtures/real
SCALE = {"mm": 1e-3, "cm": 1e-2, "m": 1.0}


# ----------------------------------------------------------------------------- helpers

def raw_parse(path: Path) -> dict:
    """An independent, deliberately naive parse: split lines and cells, no numpy tricks."""
    lines = path.read_text().splitlines()
    sep = "\t" if "\t" in lines[1] else ","
    header = {k.strip(): v.strip() for k, v in zip(lines[1].split(sep), lines[2].split(sep)) if k.strip()}
    labels = [c.strip() for c in lines[3].split(sep)[2:] if c.strip()]
    rows = []
    for ln in lines[4:]:
        cells = ln.split(sep)
        if cells and cells[0].strip().lstrip("-").isdigit():  # data rows start with a frame number
            rows.append(cells)
    return {"header": header, "labels": labels, "rows": rows, "sep": sep}


def make_trc(tmp_path: Path, body: list[str], labels=("A", "B", "C"), units="mm", sep="\t",
             name="t.trc", num_frames=None, line5=True, line6=True, compact_labels=False) -> Path:
    m = len(labels)
    n = num_frames if num_frames is not None else len(body)
    head = [sep.join(["PathFileType", "4", "(X/Y/Z)", name]),
            sep.join(["DataRate", "CameraRate", "NumFrames", "NumMarkers", "Units", "OrigDataRate",
                      "OrigDataStartFrame", "OrigNumFrames"]),
            sep.join(["100", "100", str(n), str(m), units, "100", "1", str(n)])]
    if compact_labels:
        head.append(sep.join(["Frame#", "Time", *labels]))
    else:
        head.append(sep.join(["Frame#", "Time"] + [f"{lb}{sep}{sep}" for lb in labels]))
    if line5:
        head.append(sep.join(["", ""] + [f"{a}{k}" for k in range(1, m + 1) for a in "XYZ"]))
    if line6:
        head.append("")
    p = tmp_path / name
    p.write_text("\n".join(head + body) + "\n")
    return p


def random_recording(seed: int, T=50, M=4, rate=120.0, t0=2.5, gaps=0.1) -> MarkerRecording:
    rng = np.random.default_rng(seed)
    pos = rng.uniform(-2.0, 2.0, size=(T, M, 3))
    pos[rng.random((T, M)) < gaps] = np.nan
    labels = tuple(f"mk {k} side" for k in range(M))   # labels with spaces
    return MarkerRecording(t0 + np.arange(T) / rate, pos, labels, rate, meta={"first_frame": 301})


# ----------------------------------------------------------------------------- real files

@pytest.mark.parametrize("name", REAL_NAMES)
def test_real_trc_matches_independent_parse(name):
    path = real_file(f"trc/{name}")
    rec = read_trc(path)
    raw = raw_parse(path)
    hdr = raw["header"]
    assert rec.n_markers == int(hdr["NumMarkers"])
    assert list(rec.labels) == raw["labels"]
    assert rec.n_frames == len(raw["rows"])
    assert rec.meta["NumFrames"] == int(hdr["NumFrames"])        # header value kept as written
    assert (rec.meta["NumFrames"] == rec.n_frames) == (rec.meta["header_mismatch"] == [])
    assert rec.rate_hz == float(hdr["DataRate"])
    assert rec.units == hdr["Units"].lower()
    scale = SCALE[rec.units]
    # time column, exactly
    np.testing.assert_array_equal(rec.time, [float(r[1]) for r in raw["rows"]])
    # a few sampled coordinate cells, exactly as the text says (times the unit)
    rng = np.random.default_rng(0)
    for _ in range(30):
        t = int(rng.integers(rec.n_frames))
        m = int(rng.integers(rec.n_markers))
        a = int(rng.integers(3))
        cell = raw["rows"][t][2 + 3 * m + a].strip()
        if cell:
            assert rec.positions[t, m, a] == float(cell) * scale
    # gaps are NaN exactly where the text has a blank cell in a marker's triple
    blank = np.array([[any(not r[2 + 3 * m + a].strip() for a in range(3)) for m in range(rec.n_markers)]
                      for r in raw["rows"]])
    np.testing.assert_array_equal(rec.missing, blank)
    assert np.all(np.isfinite(rec.positions[~blank]))


def test_real_header_mismatch_is_explicit():
    rec = read_trc(real_file("trc/biobuddy_static.trc"))
    assert rec.meta["NumFrames"] == 1300 and rec.n_frames == 138 and rec.meta["n_rows"] == 138
    assert rec.meta["header_mismatch"] == ["NumFrames: header 1300, file has 138 rows"]
    assert rec.meta["OrigDataStartFrame"] == 1163
    assert rec.units == "m" and rec.positions[0, 0, 0] == 0.62772


def test_real_comma_file():
    rec = read_trc(real_file("trc/pyomeca_markers.trc"))
    assert rec.meta["delimiter"] == ","
    assert rec.n_markers == 51 and rec.n_frames == 93
    assert rec.positions[0, 0, 0] == pytest.approx(0.7337041, abs=1e-12)   # 733.7041 mm
    assert rec.time[1] == 0.01


# ----------------------------------------------------------------------------- synthetic

def test_gaps_never_shift_columns(tmp_path):
    body = ["1\t0.00\t1\t2\t3\t4\t5\t6\t7\t8\t9",
            "2\t0.01\t\t\t\t14\t15\t16\t17\t18\t19",       # A occluded (first marker)
            "3\t0.02\t21\t22\t23\t\t\t\t27\t28\t29",       # B occluded (middle)
            "4\t0.03\t31\t32\t33\t34\t35\t36\t\t\t",       # C occluded (last, trailing blanks)
            "5\t0.04\t41\t\t43\t44\tNaN\t46\t47\t48\t49",  # one blank / one NaN cell: whole marker out
            "6\t0.05\t\t\t\t\t\t\t\t\t"]                   # all occluded
    rec = read_trc(make_trc(tmp_path, body))
    assert rec.n_frames == 6
    exp_missing = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1], [1, 1, 0], [1, 1, 1]], bool)
    np.testing.assert_array_equal(rec.missing, exp_missing)
    assert np.all(np.isnan(rec.positions[exp_missing]))
    np.testing.assert_allclose(rec.positions[1, 1], [0.014, 0.015, 0.016], rtol=1e-15)
    np.testing.assert_allclose(rec.positions[2, 2], [0.027, 0.028, 0.029], rtol=1e-15)
    np.testing.assert_allclose(rec.positions[3, 0], [0.031, 0.032, 0.033], rtol=1e-15)
    np.testing.assert_allclose(rec.positions[4, 2], [0.047, 0.048, 0.049], rtol=1e-15)
    assert rec.missing_fraction() == {"A": 0.5, "B": 0.5, "C": 2 / 6}


def test_comma_separated_with_trailing_columns_and_blank_line6(tmp_path):
    body = ["1,0.0,1,2,3,4,5,6,,,", "2,0.01,7,8,9,,,,,,"]
    p = make_trc(tmp_path, body, labels=("A", "B"), sep=",", line6=False)
    text = p.read_text().splitlines()
    # a line 6 made of commas only, and trailing empty columns on every header line
    text = [ln + ",,," for ln in text[:5]] + [",,,,,,,,,,"] + text[5:]
    p.write_text("\n".join(text) + "\n")
    rec = read_trc(p)
    assert rec.meta["delimiter"] == ","
    assert rec.labels == ("A", "B") and rec.n_frames == 2
    np.testing.assert_allclose(rec.positions[0], [[0.001, 0.002, 0.003], [0.004, 0.005, 0.006]], rtol=1e-15)
    np.testing.assert_array_equal(rec.missing, [[False, False], [False, True]])


def test_no_blank_line6_no_line5_compact_labels_and_crlf(tmp_path):
    body = ["1163\t0.0\t1\t2\t3\t4\t5\t6", "1164\t0.01\t7\t8\t9\t10\t11\t12"]
    labels = ("left hip", "right hip")   # spaces in labels
    for kw in ({"line6": False}, {"line6": False, "line5": False}, {"compact_labels": True}):
        p = make_trc(tmp_path, body, labels=labels, **kw)
        p.write_bytes(p.read_bytes().replace(b"\n", b"\r\n"))
        rec = read_trc(p)
        assert rec.labels == labels, kw
        assert rec.n_frames == 2 and rec.meta["first_frame"] == 1163, kw
        np.testing.assert_allclose(rec.marker("right hip")[1], [0.010, 0.011, 0.012], rtol=1e-15)
        np.testing.assert_array_equal(rec.time, [0.0, 0.01])


def test_ragged_rows_some_with_trailing_tabs(tmp_path):
    body = ["1\t0.0\t1\t2\t3\t4\t5\t6\t7\t8\t9\t", "2\t0.01\t1\t2\t3\t4\t5\t6\t7\t8\t9",
            "3\t0.02\t1\t2\t3\t\t\t\t7\t8\t9\t\t\t"]
    rec = read_trc(make_trc(tmp_path, body))
    assert rec.n_frames == 3
    np.testing.assert_array_equal(rec.missing[:, 1], [False, False, True])
    np.testing.assert_allclose(rec.positions[2, 2], [0.007, 0.008, 0.009], rtol=1e-15)


@pytest.mark.parametrize("units,short,scale", [("mm", "mm", 1e-3), ("cm", "cm", 1e-2), ("m", "m", 1.0),
                                               ("MM", "mm", 1e-3), ("meters", "m", 1.0)])
def test_unit_conversion(tmp_path, units, short, scale):
    rec = read_trc(make_trc(tmp_path, ["1\t0\t1.5\t-2\t250\t0\t0\t0\t7\t8\t9"], units=units))
    assert rec.units == short
    np.testing.assert_allclose(rec.positions[0, 0], np.array([1.5, -2.0, 250.0]) * scale, rtol=1e-15)


def test_header_numframes_disagrees_rows_win(tmp_path):
    rec = read_trc(make_trc(tmp_path, ["1\t0\t1\t2\t3\t4\t5\t6\t7\t8\t9"], num_frames=10))
    assert rec.n_frames == 1 and rec.meta["NumFrames"] == 10
    assert rec.meta["header_mismatch"] == ["NumFrames: header 10, file has 1 rows"]


@pytest.mark.parametrize("units,fmt,tol", [("mm", "%.5f", 0.5e-5 * 1e-3), ("m", "%.8f", 0.5e-8)])
def test_round_trip(tmp_path, units, fmt, tol):
    rec = random_recording(3)
    p = write_trc(tmp_path / "rt.trc", rec, units=units, fmt=fmt)
    back = read_trc(p)
    assert back.labels == rec.labels and back.units == units
    assert back.rate_hz == rec.rate_hz and back.n_frames == rec.n_frames
    assert back.meta["first_frame"] == 301 and back.meta["NumFrames"] == rec.n_frames
    np.testing.assert_array_equal(back.missing, rec.missing)
    np.testing.assert_allclose(back.time, rec.time, rtol=0, atol=1e-11)
    ok = ~rec.missing
    assert np.max(np.abs(back.positions[ok] - rec.positions[ok])) <= tol * (1 + 1e-9)
    # NaN gaps are written as empty cells, not 'nan'
    assert "nan" not in p.read_text().lower().split("\n", 6)[6]
    # and a second round trip is exact
    back2 = read_trc(write_trc(tmp_path / "rt2.trc", back, units=units, fmt=fmt))
    np.testing.assert_array_equal(back2.positions, back.positions)


def test_write_refuses_overwrite(tmp_path):
    rec = random_recording(1, T=5, M=2)
    p = write_trc(tmp_path / "new" / "a.trc", rec)      # missing parent folders are created
    before = p.read_bytes()
    with pytest.raises(FileExistsError, match="a.trc"):
        write_trc(p, random_recording(2, T=5, M=2))
    assert p.read_bytes() == before
    write_trc(p, random_recording(2, T=5, M=2), overwrite=True)
    assert p.read_bytes() != before


def test_write_rejects_bad_units_and_labels(tmp_path):
    rec = random_recording(1, T=3, M=2)
    with pytest.raises(InputError, match="units"):
        write_trc(tmp_path / "u.trc", rec, units="inch")
    bad = MarkerRecording(rec.time, rec.positions, ("a\tb", "c"), rec.rate_hz)
    with pytest.raises(InputError, match="tab"):
        write_trc(tmp_path / "l.trc", bad)


@pytest.mark.parametrize("row,line,match", [
    ("3\t0.02\t1\t2\t3\t4\t5\t6\t7\t8", 9, "row has 10 cells, expected 11"),
    ("3\t0.02\t1\t2\t3\t4\t5\t6\t7\t8\t9\t10", 9, "beyond the 11 expected"),
    ("3\t0.02\t1\t2\t3\t4\tfoo\t6\t7\t8\t9", 9, r"'foo' in column 7 \(B Y\)"),
    ("3\t0.005\t1\t2\t3\t4\t5\t6\t7\t8\t9", 9, "not after"),
    ("3\t\t1\t2\t3\t4\t5\t6\t7\t8\t9", 9, "Time cell is empty"),
])
def test_bad_rows_name_file_and_line(tmp_path, row, line, match):
    body = ["1\t0.0\t1\t2\t3\t4\t5\t6\t7\t8\t9", "2\t0.01\t1\t2\t3\t4\t5\t6\t7\t8\t9", row,
            "4\t0.03\t1\t2\t3\t4\t5\t6\t7\t8\t9"]
    p = make_trc(tmp_path, body)
    with pytest.raises(InputError, match=match) as ei:
        read_trc(p)
    assert ei.value.line == line and ei.value.path == p
    assert f"t.trc, line {line}:" in str(ei.value)


def test_values_beyond_last_marker_on_every_row(tmp_path):
    """Equal-length rows (the fast path) with a stray 12th value: an error, not a silent drop."""
    body = ["1\t0.0\t1\t2\t3\t4\t5\t6\t7\t8\t9\t", "2\t0.01\t1\t2\t3\t4\t5\t6\t7\t8\t9\t99"]
    with pytest.raises(InputError, match="beyond the 11 expected") as ei:
        read_trc(make_trc(tmp_path, body))
    assert ei.value.line == 8


@pytest.mark.parametrize("edit,match", [
    (lambda t: t.replace("PathFileType", "Hello"), "not a TRC file"),
    (lambda t: t.replace("\tmm\t", "\tfurlong\t"), "unknown Units 'furlong'"),
    (lambda t: t.replace("DataRate", "Rate", 1), "no DataRate"),
    (lambda t: t.replace("\t3\tmm", "\t4\tmm"), "NumMarkers is 4"),
    (lambda t: t.replace("Y2", "Q2"), "coordinate column"),
])
def test_bad_headers(tmp_path, edit, match):
    p = make_trc(tmp_path, ["1\t0.0\t1\t2\t3\t4\t5\t6\t7\t8\t9"])
    p.write_text(edit(p.read_text()))
    with pytest.raises(InputError, match=match):
        read_trc(p)


def test_missing_file(tmp_path):
    with pytest.raises(InputError, match="not found"):
        read_trc(tmp_path / "nope.trc")


def test_large_file_parses_vectorised(tmp_path):
    """10 000 frames x 40 markers with 5 % gaps: read back identical to the written values."""
    rec = random_recording(7, T=10_000, M=40, rate=200.0, t0=0.0, gaps=0.05)
    p = write_trc(tmp_path / "big.trc", rec)
    back = read_trc(p)
    np.testing.assert_array_equal(back.missing, rec.missing)
    assert np.nanmax(np.abs(back.positions - rec.positions)) <= 0.5e-8 * (1 + 1e-9)


def test_doubled_separator_in_a_row_is_an_error_not_a_shift(tmp_path):
    """A doubled tab in a row whose last marker is occluded used to shift every later marker by
    one coordinate silently (the extra cell was empty); now the row is refused, naming it."""
    from mocap.io.errors import InputError
    from mocap.io.trc import read_trc

    rows = ["PathFileType\t4\t(X/Y/Z)\tx.trc",
            "DataRate\tCameraRate\tNumFrames\tNumMarkers\tUnits\tOrigDataRate\tOrigDataStartFrame\tOrigNumFrames",
            "100\t100\t2\t3\tmm\t100\t1\t2",
            "Frame#\tTime\tA\t\t\tB\t\t\tC\t\t",
            "\t\tX1\tY1\tZ1\tX2\tY2\tZ2\tX3\tY3\tZ3",
            "",
            "1\t0.00\t1.0\t2.0\t3.0\t4.0\t5.0\t6.0\t7.0\t8.0\t9.0",
            "2\t0.01\t1.0\t2.0\t\t3.0\t4.0\t5.0\t6.0\t\t\t"]       # doubled tab after A's Y; C occluded
    path = tmp_path / "x.trc"
    path.write_text("\n".join(rows) + "\n")
    with pytest.raises(InputError, match=r"x.trc, line 8: marker A has an empty or non-numeric Z"):
        read_trc(path)
    rows[-1] = "2\t0.01\t1.0\t2.0\t3.0\t4.0\t5.0\t6.0\t\t\t"          # C occluded, nothing shifted
    path.write_text("\n".join(rows) + "\n")
    rec = read_trc(path)
    assert np.isnan(rec.positions[1, 2]).all() and rec.positions[1, 1, 2] == pytest.approx(6e-3)


# ----------------------------------------------------------------------------- streaming reader
from mocap.io import trc as trc_mod  # noqa: E402

_ROWS = ["1\t0.00\t1\t2\t3\t4\t5\t6\t7\t8\t9",
         "2\t0.01\t\t\t\t14\t15\t16\t17\t18\t19",
         "3\t0.02\t21\t22\t23\tnan\tNaN\tNAN\t27\t28\t29",
         "4\t0.03\t31\t32\t33\t34\t35\t36\t\t\t",
         "5\t0.04\t41\t\t43\t44\t-4.5e1\t46\t47\t48\t49"]


def _careful(p):
    fast = trc_mod._read_fast
    trc_mod._read_fast = lambda path: None
    try:
        return read_trc(p)
    finally:
        trc_mod._read_fast = fast


@pytest.mark.parametrize("edit, wide", [
    (lambda b: b, False),                                      # the usual layout
    (lambda b: b.replace(b"\n", b"\r\n"), False),              # CRLF
    (lambda b: b"\xef\xbb\xbf" + b, False),                    # BOM
    (lambda b: b.replace(b"\n1\t", b"\n\n1\t"), False),        # one more blank line
    (lambda b: b, True),                                       # two empty cells past the markers
])
def test_streaming_reader_equals_careful_parser(tmp_path, edit, wide):
    p = make_trc(tmp_path, [r + "\t\t" for r in _ROWS[:4]] if wide else _ROWS)   # row 5: partial
    p.write_bytes(edit(p.read_bytes()))
    fast = trc_mod._read_fast(p)
    assert fast is not None
    slow = _careful(p)
    np.testing.assert_array_equal(fast.time, slow.time)
    np.testing.assert_array_equal(fast.positions, slow.positions)
    assert fast.labels == slow.labels and fast.meta == slow.meta and fast.units == slow.units


@pytest.mark.parametrize("row", [
    "6\t0.05\t1\t2\t3\t4\t5\t6\t7\t8",          # a short row
    "6\t0.05\t1\t2\t3\t4\t5\t6\t7\t8\t9\t10",   # a value past the last marker
    "6\t0.05\t1\t2\t3\t4\t5\t6\t7\tx\t9",       # a word
    "6\t0.04\t1\t2\t3\t4\t5\t6\t7\t8\t9",       # time not increasing
    "6\t0.05\t1\t2\t3\t4\t5\t6\t7\t8\tinf",     # infinite
    "6\t\t1\t2\t3\t4\t5\t6\t7\t8\t9",           # no time
])
def test_streaming_reader_declines_what_the_careful_parser_judges(tmp_path, row):
    p = make_trc(tmp_path, _ROWS + [row])
    assert trc_mod._read_fast(p) is None
    with pytest.raises(InputError):
        read_trc(p)


def test_streaming_reader_on_a_written_file(tmp_path):
    rec = random_recording(4, T=3000, M=6)
    p = write_trc(tmp_path / "w.trc", rec)
    fast = trc_mod._read_fast(p)
    assert fast is not None
    slow = _careful(p)
    np.testing.assert_array_equal(fast.positions, slow.positions)
    np.testing.assert_array_equal(fast.time, slow.time)
    assert fast.meta == slow.meta


def test_files_from_a_megabyte_on_stream(tmp_path, monkeypatch):
    rec = random_recording(6, T=6000, M=8)
    p = write_trc(tmp_path / "big.trc", rec)
    assert p.stat().st_size >= trc_mod.STREAM_MIN_BYTES
    slow = _careful(p)

    def refuse(path):
        raise AssertionError("the careful parser read a well-formed long file")

    monkeypatch.setattr(trc_mod, "_decode", refuse)
    fast = read_trc(p)
    np.testing.assert_array_equal(fast.positions, slow.positions)
    assert fast.meta == slow.meta
