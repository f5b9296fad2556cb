"""Issue 45: manifest and drives values are range-checked when read (mocap.io.ranges.RANGES):
exit 2, one line naming the file and the key, before any computation. Each case damages one
value of a copy of the demo campaign."""
from __future__ import annotations

import re
import shutil

import pytest

from ident.cli.main import main
from mocap.robot import Drive, read_drives, write_drives
from test_bad_inputs import _error_lines
from tests_paths import DEMO, set_first_trial_key


@pytest.fixture()
def camp(tmp_path):
    dst = tmp_path / "camp"
    shutil.copytree(DEMO, dst)
    return dst


def _set_first_drive(camp, key, value):
    p = camp / "robot" / "drives.toml"
    text = p.read_text()
    new, n = re.subn(rf"^{key} = .*$", f"{key} = {value}", text, count=1, flags=re.M)
    assert n == 1
    p.write_text(new)
    return p


def _refused(camp, capsys, file, key):
    rc = main(["info", str(camp)])
    err = _error_lines(capsys.readouterr().err)
    assert rc == 2, err
    assert len(err) == 1 and err[0].startswith("jointlab: error:"), err
    assert file in err[0] and key in err[0], err[0]
    return err[0]


@pytest.mark.parametrize("key,value", [("load_kg", "1e308"), ("load_kg", "-1.0"),
                                       ("repetition", "-1"), ("repetition", "0"),
                                       ("vmax_frac", "inf"), ("time_offset", "nan"),
                                       ("joints", "[0]")])
def test_trial_value_out_of_range_is_refused_naming_the_key(camp, capsys, key, value):
    set_first_trial_key(camp / "campaign.toml", key, value)
    _refused(camp, capsys, "campaign.toml", key)


@pytest.mark.parametrize("grav", ["[0.0, 0.0, -1e13]", "[0.0, inf, -9.81]"])
def test_gravity_out_of_range_is_refused(camp, capsys, grav):
    p = camp / "campaign.toml"
    p.write_text(p.read_text().replace("gravity = [0.0, 0.0, -9.81]", f"gravity = {grav}"))
    _refused(camp, capsys, "campaign.toml", "gravity")


@pytest.mark.parametrize("key,value", [("motor_viscous", "1e300"), ("motor_inertia", "1e300"),
                                       ("max_velocity", "inf"), ("max_torque", "1e300"),
                                       ("encoder_resolution", "0"), ("encoder_resolution", "0.5"),
                                       ("gear_ratio", "1e9")])
def test_drive_value_out_of_range_is_refused_naming_the_key(camp, capsys, key, value):
    _set_first_drive(camp, key, value)
    line = _refused(camp, capsys, "drives.toml", key)
    assert "joint1" in line


def test_values_at_the_edges_of_their_ranges_are_accepted(camp, capsys):
    set_first_trial_key(camp / "campaign.toml", "load_kg", "0")
    set_first_trial_key(camp / "campaign.toml", "vmax_frac", "1.5")
    _set_first_drive(camp, "motor_viscous", "0")
    assert main(["info", str(camp)]) == 0, capsys.readouterr().err


def test_written_drives_read_back_without_their_unknown_limits(tmp_path):
    d = (Drive(name="a", gear_ratio=50.0, direction=-1),
         Drive(name="b", max_torque=20.0, encoder_resolution=1e-4))
    back = read_drives(write_drives(tmp_path / "d.toml", d))
    assert back == d


def test_every_range_is_documented():
    from mocap.io.ranges import RANGES
    from tests_paths import REPO

    text = (REPO / "docs" / "inputs.md").read_text()
    sec = text[text.index("## Declared ranges"):text.index("## Fits checked against their inputs")]
    for (_, key), r in RANGES.items():
        row = next((ln for ln in sec.splitlines() if f"`{key}`" in ln or f"{key}`" in ln), None)
        assert row is not None, key
        forms = {f"{r.hi:g}", f"{r.hi:.0e}".replace("e+0", "e").replace("e+", "e"), f"{int(r.hi)}"}
        assert any(f" {s} " in row for s in forms), (key, row)    # the upper bound as in the table
