"""The viewer: the demo study's .rrd opened by rerun's headless viewer (ViewerClient), a
screenshot of every view of the blueprint; no view reports an error and no image is blank.
Skips, with the viewer's own reason, where no graphics adapter exists (rerun 0.41 needs a GPU
driver or a software Vulkan rasterizer such as Mesa's lavapipe: mesa-vulkan-drivers)."""
from __future__ import annotations

import json

import numpy as np
import pytest

from ident.cli.main import main
from viz.screenshot import is_blank

DEMO_ARGS = ["--workers", "1", "--models", "cv,stribeck", "--starts", "2", "--quiet"]


@pytest.fixture(scope="module")
def viewer(tmp_path_factory):
    from viz.screenshot import probe_viewer

    reason = probe_viewer(tmp_path_factory.mktemp("probe"))
    if reason is not None:
        pytest.skip(f"rerun's headless viewer cannot render on this machine: {reason} (it needs a "
                    "GPU driver or a software Vulkan rasterizer, e.g. apt-get install mesa-vulkan-drivers)")
    return True


def test_is_blank_detects_single_colour_images():
    img = np.full((60, 80, 3), 17, np.uint8)
    assert is_blank(img)
    img[10:30, 20:50] = (200, 40, 40)
    assert not is_blank(img)


def test_view_command_logs_a_campaign(tmp_path):
    from ident.cli.commands.demo import demo_campaign
    from rerun.chunk import RrdReader

    camp = demo_campaign()
    if not (camp / "campaign.toml").is_file():
        pytest.skip("fixtures/demo is not there")
    rrd = tmp_path / "camp.rrd"
    assert main(["view", str(camp), "--rrd", str(rrd)]) == 0
    ents = {ch.entity_path for ch in RrdReader(rrd).stream()}
    assert any(e.endswith("/markers") for e in ents) and "/campaign/README" in ents
    assert main(["view", str(rrd), "--rrd", str(tmp_path / "x.rrd")]) == 2


@pytest.mark.slow  # about 25 s on 2 cores with a software rasterizer (the demo study + the viewer)
def test_demo_recording_in_the_headless_viewer(viewer, tmp_path):
    from ident.cli.commands.demo import demo_campaign
    from viz.screenshot import screenshot_rrd

    if not (demo_campaign() / "campaign.toml").is_file():
        pytest.skip("fixtures/demo is not there")
    out = tmp_path / "demo"
    assert main(["demo", "--out", str(out)] + DEMO_ARGS) == 0
    shots = screenshot_rrd(out / "study.rrd", tmp_path / "shots")
    (tmp_path / "shots" / "shots.json").write_text(json.dumps(shots.to_dict(), indent=1))
    classes = sorted(v.view_class for v in shots.views)
    assert {"3D", "TimeSeries", "TextDocument"} <= set(classes), classes
    assert classes.count("TimeSeries") == 4   # joint signals, link angles, fits, diagnosis
    for v in shots.views:
        assert v.errors == [], (v.name, v.reports)
        assert v.png is not None and v.png.stat().st_size > 0, v.name
        assert v.blank is False, v.name
    assert not shots.full_blank
    assert shots.log_errors == ()
