"""`jointlab view` logs a campaign to an .rrd: markers per frame of every recording, the robot's
links posed over time and the joint signals (read back with rerun's RrdReader)."""
import pytest

from ident.cli.main import main
from mocap.io.campaign import load_campaign
from mocap.io.markers import read_markers
from tests_paths import DEMO
from test_viz import read_rrd


def test_view_demo_campaign(tmp_path, capsys):
    if not (DEMO / "campaign.toml").is_file():
        pytest.skip("demo campaign absent")
    rrd = tmp_path / "view.rrd"
    assert main(["view", str(DEMO), "--rrd", str(rrd)]) == 0
    ents = read_rrd(rrd)
    camp = load_campaign(DEMO)
    tr = camp.trials[0]
    markers = [e for e in ents if e.endswith("/markers") and tr.id in e]
    assert len(markers) == 1
    assert ents[markers[0]]["rows"] == read_markers(tr.markers).n_frames
    assert any(e.endswith(f"{tr.id}/robot/link5") for e in ents)
    assert any(tr.id in e and "/signals/" in e and e.endswith("tau_5") for e in ents)
    assert "logged" in capsys.readouterr().out
