"""FORMAT.md's ``time_offset`` (t_robot = t_marker + time_offset) is honoured by the angle
solve: a trial whose marker clock is shifted by -1000 s and declares time_offset = 1000 gives
the same link angles as the unshifted trial (issue 17)."""
from __future__ import annotations

import csv
import dataclasses
import shutil
from pathlib import Path

import numpy as np

from ident.cli.main import main
from mocap.io.trc import read_trc, write_trc

DEMO = Path(__file__).resolve().parents[1] / "fixtures" / "demo"
TRIAL = "j5-load0-v100-r1"


def _angles(path: Path) -> dict:
    with path.open() as fh:
        rows = list(csv.DictReader(fh))
    return {k: np.array([float(r[k]) if r[k] else np.nan for r in rows]) for k in rows[0]}


def _keep_one_trial(camp: Path, offset: float | None) -> None:
    text = (camp / "campaign.toml").read_text()
    head, *trials = text.split("[[trial]]")
    keep = [t for t in trials if f'id = "{TRIAL}"' in t]
    extra = "" if offset is None else f"time_offset = {offset!r}\n"
    (camp / "campaign.toml").write_text(head + "[[trial]]\n" + extra + keep[0].lstrip("\n"))


def test_declared_time_offset_aligns_a_shifted_marker_clock(tmp_path):
    ref, shifted = tmp_path / "ref", tmp_path / "shifted"
    shutil.copytree(DEMO, ref)
    shutil.copytree(DEMO, shifted)
    _keep_one_trial(ref, None)
    _keep_one_trial(shifted, 1000.0)
    trc = shifted / "trials" / f"{TRIAL}.trc"
    rec = read_trc(trc)
    trc.unlink()
    write_trc(trc, dataclasses.replace(rec, time=rec.time - 1000.0))
    for camp in (ref, shifted):
        assert main(["mocap", str(camp), "--out", str(tmp_path / f"out-{camp.name}")]) == 0
    a = _angles(tmp_path / "out-ref" / "angles" / f"{TRIAL}.csv")
    b = _angles(tmp_path / "out-shifted" / "angles" / f"{TRIAL}.csv")
    valid = np.isfinite(a["q_5"])
    assert valid.mean() > 0.9
    np.testing.assert_array_equal(np.isfinite(b["q_5"]), valid)
    np.testing.assert_allclose(b["time"] + 1000.0, a["time"], atol=1e-6)
    np.testing.assert_allclose(b["q_5"][valid], a["q_5"][valid], atol=1e-7)
