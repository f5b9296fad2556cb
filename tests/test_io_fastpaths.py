"""The quick readers give what the careful ones give (the same float64 bits, the same errors),
and a trial's robot log is read once when its marker check and the solve both need it."""
from __future__ import annotations

import numpy as np
import pytest

import mocap.io.angles as angles_mod
import mocap.io.campaign as campaign_mod
import mocap.io.robotlog as robotlog_mod
from mocap.io.angles import read_angles
from mocap.io.campaign import load_campaign
from mocap.io.errors import InputError
from tests_paths import DEMO


def _bits(x):
    return np.asarray(x, float).view(np.int64)


def _careful_angles(path, monkeypatch):
    with monkeypatch.context() as m:
        m.setattr(angles_mod, "_read_fast", lambda p: None)
        try:
            return read_angles(path)
        except InputError as exc:
            return str(exc)


def _angles_text(rng, rows=300, holes=True):
    """An angles CSV as FORMAT.md describes it, written here with Python's own formatting."""
    t = np.cumsum(rng.uniform(0.004, 0.006, rows))
    q1, q3 = rng.normal(0, 1.3, rows), rng.normal(0, 1e-7, rows)
    rms, n = rng.uniform(0, 3, rows), rng.integers(3, 9, rows)
    out = ["time,q_1,q_3,rms_mm,n_markers"]
    for k in range(rows):
        cells = [repr(float(t[k])), f"{q1[k]:.10g}", f"{q3[k]:.17e}", f"{rms[k]:.6f}", str(n[k])]
        if holes and k % 17 == 5:
            cells[1] = cells[2] = cells[3] = ""
        out.append(",".join(cells))
    return "\n".join(out) + "\n"


def test_angles_quick_reader_equals_careful_reader(tmp_path, monkeypatch):
    rng = np.random.default_rng(7)
    p = tmp_path / "a.csv"
    p.write_text(_angles_text(rng), encoding="utf-8")
    assert angles_mod._read_fast(p) is not None          # the quick reader takes a plain file
    quick, careful = read_angles(p), _careful_angles(p, monkeypatch)
    assert np.isnan(quick.q[1]).sum() == 18
    for a, b in [(quick.time, careful.time), (quick.rms_mm, careful.rms_mm),
                 (quick.n_markers, careful.n_markers)] + [(quick.q[j], careful.q[j]) for j in (1, 3)]:
        assert np.array_equal(_bits(a), _bits(b))
    assert sorted(quick.q) == [1, 3]


@pytest.mark.parametrize("cell", ["1.2.3", "-", "1e", " 0.5", "nan", "inf", "0x10", "1,5"])
def test_angles_unusual_cell_read_as_the_careful_reader_reads_it(cell, tmp_path, monkeypatch):
    text = _angles_text(np.random.default_rng(3), rows=40, holes=False).split("\n")
    row = text[12].split(",")
    row[1] = cell
    text[12] = ",".join(row)
    p = tmp_path / "a.csv"
    p.write_text("\n".join(text), encoding="utf-8")
    careful = _careful_angles(p, monkeypatch)
    try:
        got = read_angles(p)
    except InputError as exc:
        got = str(exc)
    if isinstance(careful, str):
        assert got == careful and "line" in careful
    else:
        assert not isinstance(got, str)
        assert np.array_equal(_bits(got.q[1]), _bits(careful.q[1]))


def test_trial_log_read_once_for_marker_check_and_solve(tmp_path, monkeypatch):
    import shutil

    camp_dir = tmp_path / "camp"
    shutil.copytree(DEMO, camp_dir)
    camp = load_campaign(camp_dir / "campaign.toml")
    robot = camp.load_robot()
    trial = camp.trials[0]
    reads = []
    real = robotlog_mod.read_robot_log

    def counting(path, n_joints=None):
        reads.append(str(path))
        return real(path, n_joints=n_joints)

    monkeypatch.setattr(campaign_mod, "read_robot_log", counting)
    camp.read_markers(trial, robot)
    log = camp.read_log(trial, robot)
    assert reads == [str(trial.log)]                      # the marker check's read is reused
    fresh = real(trial.log, n_joints=robot.n)
    for a, b in [(log.time, fresh.time), (log.qm, fresh.qm), (log.tau, fresh.tau)]:
        assert a.shape == b.shape and np.array_equal(_bits(a), _bits(b))
    assert list(log.line_numbers) == list(fresh.line_numbers)

    # a log changed between the two reads is read again, and its error is the reader's
    camp.read_markers(trial, robot)
    text = trial.log.read_text().split("\n")
    text[3] = text[3].replace(",", ",,", 1)
    trial.log.write_text("\n".join(text) + "\n")
    with pytest.raises(InputError, match="line 4"):
        camp.read_log(trial, robot)
