"""`jointlab info FILE --json` on every real marker file, and the bad C3D's one-line error."""
from __future__ import annotations

import json
from pathlib import Path

import ezc3d
import numpy as np
import pytest

from ident.cli.main import main
from tests_paths import real_file, real_names

REAL = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "real"
BAD_NAME = "read_NOTworking2.c3d"
TRC_NAMES = real_names("trc", "*.trc")                # ../shared, else fixtures/real
C3D_NAMES = [n for n in real_names("c3d", "*.c3d") if n != BAD_NAME]
KEYS = {"n_frames", "n_markers", "labels", "rate_hz", "units", "missing_fraction"}


def info_json(capsys, path: Path) -> dict:
    rc = main(["info", str(path), "--json"])
    out = capsys.readouterr()
    assert rc == 0, out.err
    d = json.loads(out.out)
    assert KEYS <= set(d)
    return d


def trc_header(path: Path) -> dict:
    """Header, labels and per-marker blank fraction from a plain text split."""
    lines = path.read_text().splitlines()
    sep = "\t" if "\t" in lines[1] else ","
    hdr = {k.strip(): v.strip() for k, v in zip(lines[1].split(sep), lines[2].split(sep)) if k.strip()}
    labels = [c.strip() for c in lines[3].split(sep)[2:] if c.strip()]
    rows = [ln.split(sep) for ln in lines[4:] if ln.split(sep)[0].strip().isdigit()]
    blank = np.array([[any(not r[2 + 3 * m + a].strip() for a in range(3)) for m in range(len(labels))]
                      for r in rows])
    return {"hdr": hdr, "labels": labels, "n_rows": len(rows), "missing": blank.mean(axis=0)}


@pytest.mark.parametrize("name", TRC_NAMES)
def test_info_trc(capsys, name):
    path = real_file(f"trc/{name}")
    d = info_json(capsys, path)
    h = trc_header(path)
    assert d["n_markers"] == int(h["hdr"]["NumMarkers"]) == len(d["labels"])
    assert d["labels"] == h["labels"]
    assert d["rate_hz"] == float(h["hdr"]["DataRate"])
    assert d["units"] == h["hdr"]["Units"].lower()
    # frames: the rows in the file (the header's NumFrames is the original take's length in
    # two of the three files; the reader keeps it in meta, see test_trc)
    assert d["n_frames"] == h["n_rows"]
    if int(h["hdr"]["NumFrames"]) == h["n_rows"]:
        assert d["n_frames"] == int(h["hdr"]["NumFrames"])
    assert list(d["missing_fraction"]) == d["labels"]
    np.testing.assert_allclose([d["missing_fraction"][lb] for lb in d["labels"]], h["missing"], atol=1e-15)


@pytest.mark.parametrize("name", C3D_NAMES)
def test_info_c3d(capsys, name):
    path = real_file(f"c3d/{name}")
    d = info_json(capsys, path)
    c = ezc3d.c3d(str(path))
    hdr, point = c["header"]["points"], c["parameters"]["POINT"]
    used = int(point["USED"]["value"][0])
    assert d["n_frames"] == hdr["last_frame"] - hdr["first_frame"] + 1
    assert d["n_markers"] == used == hdr["size"]
    assert d["labels"] == [s.strip() for s in point["LABELS"]["value"][:used]]
    assert d["rate_hz"] == float(point["RATE"]["value"][0])
    assert d["units"] == point["UNITS"]["value"][0].strip()
    invalid = c["data"]["meta_points"]["residuals"][0] < 0          # (N, T)
    np.testing.assert_allclose([d["missing_fraction"][lb] for lb in d["labels"]], invalid.mean(axis=1),
                               atol=1e-15)
    assert d["first_time"] == pytest.approx(hdr["first_frame"] / float(point["RATE"]["value"][0]), abs=1e-12)


def test_info_bad_c3d_exit_2_one_line(real_dir, capsys):
    path = real_dir / "c3d" / BAD_NAME
    if not path.is_file():
        pytest.skip(f"{BAD_NAME} absent")
    rc = main(["info", str(path), "--json"])
    out = capsys.readouterr()
    assert rc == 2
    assert out.out == ""
    lines = out.err.strip().splitlines()
    assert len(lines) == 1
    assert lines[0].startswith("jointlab: error: ") and BAD_NAME in lines[0]
    assert "not a valid C3D file" in lines[0]


def test_info_urdf_prints_text_unless_json(pa10_dir, capsys):
    """Issue 16: `info` on a URDF prints one line per joint (with its limits); --json gives JSON."""
    assert main(["info", str(pa10_dir / "pa10.urdf")]) == 0
    out = capsys.readouterr().out
    assert out.startswith("robot ") and "6 revolute joints" in out
    lines = [ln for ln in out.splitlines() if ln.strip().startswith("joint ")]
    assert len(lines) == 6 and "[-1.641, +1.641] rad" in lines[1]
    assert main(["info", str(pa10_dir / "pa10.urdf"), "--json"]) == 0
    d = json.loads(capsys.readouterr().out)
    assert d["n_joints"] == 6 and abs(d["joints"][1]["upper"] - 1.6406) < 1e-3
