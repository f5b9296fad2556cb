"""Every class of bad input in issue 17, through the command line: exit status 2, one stderr
line (``jointlab: error: <file>[, line N]: ...``) naming the file at fault, no traceback, and no
byte of the input campaign changed. Each case damages one file of a copy of the demo campaign."""
from __future__ import annotations

import hashlib
import shutil
from pathlib import Path

import pytest

from ident.cli.main import main
from tests_paths import DEMO, set_first_trial_key

TRIAL = "trials/j5-load0-v50-r1"          # the first trial of the manifest


def _digest(folder: Path) -> dict:
    return {str(p.relative_to(folder)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(folder.rglob("*")) if p.is_file()}


def _error_lines(err: str) -> list[str]:
    """stderr without progress bars (tqdm redraws a line with carriage returns)."""
    lines = [ln.split("\r")[-1].strip() for ln in err.split("\n")]
    return [ln for ln in lines if ln]


@pytest.fixture()
def camp(tmp_path):
    dst = tmp_path / "camp"
    shutil.copytree(DEMO, dst)
    return dst


# ---- damage helpers: each edits one file of the copied campaign and returns its path
def _csv_cell(camp, row: int, column: str, value: str) -> Path:
    p = camp / f"{TRIAL}.csv"
    lines = p.read_text().split("\n")
    k = lines[0].split(",").index(column)
    cells = lines[row - 1].split(",")
    cells[k] = value
    lines[row - 1] = ",".join(cells)
    p.write_text("\n".join(lines))
    return p


def _csv_drop(camp, column: str) -> Path:
    p = camp / f"{TRIAL}.csv"
    lines = p.read_text().split("\n")
    k = lines[0].split(",").index(column)
    p.write_text("\n".join(",".join(c for i, c in enumerate(ln.split(",")) if i != k) if ln else ln
                           for ln in lines))
    return p


def _replace(path: Path, old: str, new: str, count: int = 1) -> Path:
    text = path.read_text()
    assert old in text
    path.write_text(text.replace(old, new, count))
    return path


def _trial_key(camp, key: str, value: str) -> Path:
    return set_first_trial_key(camp / "campaign.toml", key, value)


def _trc_rows(camp, keep: int) -> Path:
    p = camp / f"{TRIAL}.trc"
    p.write_text("\n".join(p.read_text().split("\n")[:keep]) + "\n")
    return p


CASES = {
    # encoding
    "non-utf8 header": (lambda c: _write_bytes(c / f"{TRIAL}.csv", 1, 2, b"\xe9"),
                        ["info"], "line 1: byte 0xe9 in column 3 is not utf-8-sig text"),
    "nul byte in a trc row": (lambda c: _write_bytes(c / f"{TRIAL}.trc", 8, 5, b"\x00"),
                              ["info"], "line 8: control character"),
    # empty and short files
    "empty log": (lambda c: _write_bytes(c / f"{TRIAL}.csv", None, None, b""), ["info"],
                  "robot log is empty"),
    "log with only its header": (lambda c: _keep_lines(c / f"{TRIAL}.csv", 1), ["info"],
                                 "robot log has a header but no samples"),
    "trc with only its header": (lambda c: _trc_rows(c, 6), ["info"],
                                 "no data rows: the file has only its header"),
    "truncated trc row": (lambda c: _cut_line(c / f"{TRIAL}.trc", 10, 40), ["info"],
                          "line 10: row has"),
    # headers that would shift or lose columns
    "renamed column of a braked joint": (lambda c: _replace(c / f"{TRIAL}.csv", "qm_3", "qm3"),
                                         ["info"], "line 1: column 4 'qm3' is not a FORMAT.md name; "
                                                   "did you mean 'qm_3'?"),
    "duplicated column": (lambda c: _replace(c / f"{TRIAL}.csv", "tau_4", "tau_5"),
                          ["info"], "line 1: column 12 'tau_5' repeats column 11's name"),
    "header lost a separator": (lambda c: _replace(c / f"{TRIAL}.csv", "qm_1,qm_2", "qm_1qm_2"),
                                ["info"], "line 1: the header names 13 columns but every row has 14"),
    "row with an extra cell": (lambda c: _cut_line(c / f"{TRIAL}.csv", 40, None, ",0"), ["info"],
                               "line 40: expected 14 cells, found 15"),
    # NaN / inf / absurd values
    "1e308 torque": (lambda c: _csv_cell(c, 101, "tau_5", "1e308"), ["info"],
                     "line 101: column 12 ('tau_5') has an absurd value 1e+308"),
    "infinite angle": (lambda c: _csv_cell(c, 7, "qm_5", "inf"), ["info"],
                       "line 7: column 6 ('qm_5') has an infinite value inf"),
    "torque beyond the drive": (lambda c: _csv_cell(c, 55, "tau_5", "1e6"), ["info"],
                                "line 55: column tau_5 has 1e+06 N m, more than 100 times the drive limit"),
    "infinite marker coordinate": (lambda c: _trc_cell(c, 9, 4, "inf"), ["info"],
                                   "line 9: cell inf in column 4 (L1A Y) is infinite"),
    "load_kg inf": (lambda c: _trial_key(c, "load_kg", "inf"), ["info"],
                    "'load_kg' must be a finite number"),
    # wrong types
    "vmax_frac as text": (lambda c: _trial_key(c, "vmax_frac", '"fast"'), ["info"],
                          "'vmax_frac' must be a number, got 'fast'"),
    "joints as text": (lambda c: _trial_key(c, "joints", '"5"'), ["info"],
                       "'joints' must be a non-empty list of joint numbers"),
    # units that do not fit the robot
    "trc in mm declared as m": (lambda c: _replace(c / f"{TRIAL}.trc", "\tmm\t", "\tm\t"), ["info"],
                                "units suspected"),
    "angles in degrees": (lambda c: _csv_cell(c, 30, "qm_5", "57.3"), ["info"], "degrees suspected"),
    # paths escaping the campaign
    "marker path leaves the campaign": (lambda c: _trial_key(c, "markers", '"../demo/x.trc"'), ["info"],
                                        "markers path '../demo/x.trc' leaves the campaign folder"),
    # a trial's moving joint without torques: every command reading the trial says so
    "no tau column (diagnose)": (lambda c: _csv_drop(c, "tau_5"), ["diagnose", "--out", "{t}/d"],
                                 "line 1: no tau_5 values, but trial 'j5-load0-v50-r1' moves joint 5"),
    "no tau column (fit)": (lambda c: _csv_drop(c, "tau_5"), ["fit", "--out", "{t}/f", "--models", "cv"],
                            "no tau_5 values"),
    "no qm column of a braked joint (mocap)": (lambda c: _csv_drop(c, "qm_3"), ["mocap", "--out", "{t}/m"],
                                               "no qm_3 values: trial 'j5-load0-v50-r1' needs joint 3"),
}


def _write_bytes(path: Path, line, col, data: bytes) -> Path:
    if line is None:
        path.write_bytes(data)
        return path
    lines = path.read_bytes().split(b"\n")
    lines[line - 1] = lines[line - 1][:col] + data + lines[line - 1][col:]
    path.write_bytes(b"\n".join(lines))
    return path


def _keep_lines(path: Path, n: int) -> Path:
    path.write_text("\n".join(path.read_text().split("\n")[:n]) + "\n")
    return path


def _cut_line(path: Path, line: int, at, append: str = "") -> Path:
    lines = path.read_text().split("\n")
    lines[line - 1] = lines[line - 1][:at] + append
    path.write_text("\n".join(lines))
    return path


def _trc_cell(camp, line: int, column: int, value: str) -> Path:
    p = camp / f"{TRIAL}.trc"
    lines = p.read_text().split("\n")
    cells = lines[line - 1].split("\t")
    cells[column - 1] = value
    lines[line - 1] = "\t".join(cells)
    p.write_text("\n".join(lines))
    return p


@pytest.mark.parametrize("case", list(CASES))
def test_bad_input_is_one_line_exit_2_and_nothing_written(case, camp, tmp_path, capsys):
    damage, argv, says = CASES[case]
    path = damage(camp)
    before = _digest(camp)
    argv = [argv[0], str(camp)] + [a.format(t=tmp_path) for a in argv[1:]]
    assert main(argv) == 2
    err = _error_lines(capsys.readouterr().err)
    assert len(err) == 1, err
    assert err[0].startswith(f"jointlab: error: {path}") and says in err[0], err[0]
    assert "Traceback" not in err[0]
    assert _digest(camp) == before


def test_unreadable_input_is_one_line(camp, capsys, monkeypatch):
    """Permissions: root ignores mode bits, so the refusal is simulated where the file is read."""
    before = _digest(camp)
    target = (camp / f"{TRIAL}.trc").resolve()
    real = Path.read_bytes

    def read_bytes(self):
        if self.resolve() == target:
            raise PermissionError(13, "Permission denied", str(self))
        return real(self)

    monkeypatch.setattr(Path, "read_bytes", read_bytes)
    assert main(["info", str(camp)]) == 2
    monkeypatch.undo()
    err = _error_lines(capsys.readouterr().err)
    assert len(err) == 1 and err[0].endswith("permission denied (cannot read)"), err
    assert str(camp / f"{TRIAL}.trc") in err[0]
    assert _digest(camp) == before


@pytest.mark.parametrize("argv", [["info", "{c}", "--rrd", "{c}/" + TRIAL + ".csv"],
                                  ["view", "{c}", "--rrd", "{c}/campaign.toml"]])
def test_rrd_onto_an_input_is_one_line(argv, camp, capsys):
    before = _digest(camp)
    assert main([a.format(c=camp) for a in argv]) == 2
    err = _error_lines(capsys.readouterr().err)
    assert len(err) == 1 and err[0].startswith("jointlab: error:") and "choose another path" in err[0]
    assert _digest(camp) == before
