"""No command writes into its inputs: an output equal to an input, or inside an input's
folder or campaign, is a one-line error (exit 2) and no input byte changes (issue 17)."""
from __future__ import annotations

import hashlib
import re
import shutil
from pathlib import Path

import pytest

from ident.cli.main import main
from tests_paths import set_first_trial_key

DEMO = Path(__file__).resolve().parents[1] / "fixtures" / "demo"


def _digest(folder: Path) -> dict:
    return {str(p.relative_to(folder)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(folder.rglob("*")) if p.is_file()}


@pytest.fixture()
def camp(tmp_path):
    dst = tmp_path / "camp"
    shutil.copytree(DEMO, dst)
    return dst


@pytest.mark.parametrize("argv", [
    ["calib", "{c}", "--out", "{t}/o", "--rrd", "{c}/campaign.toml"],
    ["calib", "{c}", "--out", "{c}/out"],
    ["info", "{c}/trials/j5-load0-v100-r1.trc", "--rrd", "{c}/trials/j5-load0-v100-r1.trc"],
    ["info", "{c}/trials/j5-load0-v100-r1.trc", "--rrd", "{c}/new.rrd"],
    ["view", "{c}", "--rrd", "{c}/robot/arm.rrd"],
    ["fit", "{c}", "--out", "{t}/f", "--models", "cv", "--rrd", "{c}/trials/x.rrd"],
])
def test_output_inside_an_input_is_refused(camp, tmp_path, capsys, argv):
    before = _digest(camp)
    argv = [a.format(c=camp, t=tmp_path) for a in argv]
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "choose another path" in err[0]
    assert _digest(camp) == before
    assert not (tmp_path / "o").exists() and not (tmp_path / "f").exists()


def test_failed_run_leaves_no_empty_output_folder(tmp_path, capsys):
    out = tmp_path / "never"
    assert main(["calib", str(tmp_path / "missing"), "--out", str(out)]) == 2
    assert len(capsys.readouterr().err.strip().splitlines()) == 1
    assert not out.exists()


def test_unwritable_output_is_one_line(camp, tmp_path, capsys, monkeypatch):
    """An --out the user may not create (root ignores mode bits, so the refusal is simulated at
    the mkdir the command makes) is one line naming the folder."""
    real_mkdir = Path.mkdir
    target = tmp_path / "locked" / "o"

    def mkdir(self, *a, **k):
        if self == target.resolve():
            raise PermissionError(13, "Permission denied", str(self))
        return real_mkdir(self, *a, **k)

    monkeypatch.setattr(Path, "mkdir", mkdir)
    assert main(["calib", str(camp), "--out", str(target)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [f"jointlab: error: {target.resolve()}: permission denied"]


@pytest.mark.parametrize("target, line", [("campaign.toml", 2), ("trials/j5-load0-v100-r1.csv", 1)])
def test_non_utf8_byte_is_one_line_naming_file_and_line(camp, tmp_path, capsys, target, line):
    path = camp / target
    lines = path.read_bytes().split(b"\n")
    lines[line - 1] = lines[line - 1][:3] + b"\xff" + lines[line - 1][3:]
    path.write_bytes(b"\n".join(lines))
    before = _digest(camp)
    assert main(["fit", str(camp), "--out", str(tmp_path / "f"), "--models", "cv"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [f"jointlab: error: {path}, line {line}: byte 0xff in column 4 is not "
                   f"{'utf-8-sig' if target.endswith('.csv') else 'utf-8'} text"]
    assert _digest(camp) == before


@pytest.mark.parametrize("bad", ["../../../../etc/passwd", "/etc/passwd", "trials/../../x.csv"])
def test_manifest_paths_stay_inside_the_campaign(camp, tmp_path, capsys, bad):
    toml = camp / "campaign.toml"
    text = toml.read_text()
    first = text.index('log = "')
    end = text.index('"', first + 7)
    toml.write_text(text[:first] + f'log = "{bad}"' + text[end + 1:])
    assert main(["info", str(camp)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and bad in err[0] and str(toml) in err[0]
    assert ("leaves the campaign folder" in err[0]) or ("is absolute" in err[0])
    assert "root:" not in err[0]          # nothing of the foreign file is echoed


@pytest.mark.parametrize("key, value, says", [
    ("load_kg", "-5", "load_kg must be >= 0"),
    ("load_kg", "nan", "finite number"),
    ("payload_com", "[0.1, 0.2]", "payload_com must be [x, y, z]"),
    ("time_offset", '"0.1s"', "'time_offset' must be a number"),
])
def test_bad_trial_values_are_one_line(camp, capsys, key, value, says):
    """The first trial gets the bad value (replaced when the key is there, added otherwise)."""
    toml = set_first_trial_key(camp / "campaign.toml", key, value)
    assert main(["info", str(camp)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and says in err[0] and str(toml) in err[0]


@pytest.mark.parametrize("key, value", [("max_velocity", "-3.0"), ("max_torque", "0.0"),
                                         ("motor_inertia", "nan")])
def test_bad_drive_values_are_one_line(camp, capsys, key, value):
    drives = camp / "robot" / "drives.toml"
    text = drives.read_text()
    drives.write_text(re.sub(rf"^{key} = .*$", f"{key} = {value}", text, count=1, flags=re.M))
    assert main(["info", str(camp)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and key in err[0] and str(drives) in err[0]


def test_zero_urdf_axis_is_one_line(camp, capsys):
    urdf = next((camp / "robot").glob("*.urdf"))
    text = urdf.read_text()
    urdf.write_text(re.sub(r'<axis xyz="[^"]*"', '<axis xyz="0 0 0"', text, count=1))
    assert main(["info", str(camp)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "non-zero direction" in err[0] and str(urdf) in err[0]
