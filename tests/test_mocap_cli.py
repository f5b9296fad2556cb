"""``jointlab mocap`` on synthetic campaigns written in the FORMAT v1 layout, and bad input."""
from __future__ import annotations

import json
import re

import numpy as np
import pytest

from ident.cli.main import main
from mocap._synthetic import write_campaign
from mocap.io.campaign import load_campaign
from mocap.references import build_references
from mocap.solve import solve_trial

TRIALS = ({"id": "j2-r1", "joints": [2]}, {"id": "j35-r1", "joints": [3, 5]})


@pytest.fixture(scope="module")
def campaign(tmp_path_factory):
    root = tmp_path_factory.mktemp("camp") / "c"
    truth = write_campaign(root, trials=TRIALS, duration_s=4.0, missing_frac=0.1,
                           outlier_frac=0.005)
    return root, truth


def _read_angles(path):
    lines = path.read_text().splitlines()
    header = lines[0].split(",")
    rows = [[float(c) if c else np.nan for c in ln.split(",")] for ln in lines[1:]]
    return header, np.array(rows)


def test_cli_writes_angles_and_summary(campaign, tmp_path, capsys):
    root, truth = campaign
    out = tmp_path / "out"
    (tmp_path / "cal").mkdir()
    calib = tmp_path / "cal" / "calib.json"
    calib.write_text(json.dumps({"format": 1, "T_camera_base": truth["T_camera_base"].tolist()}))
    rrd = tmp_path / "view.rrd"
    runs = ([], ["--calib", str(calib)],
            ["--calib", str(calib), "--refine", "--refine-geometry", "--rrd", str(rrd)])
    for extra in runs:
        assert main(["mocap", str(root), "--out", str(out)] + extra) == 0
        summ = json.loads((out / "mocap.json").read_text())
        for tr in TRIALS:
            header, data = _read_angles(out / "angles" / f"{tr['id']}.csv")
            assert header == ["time"] + [f"q_{j}" for j in tr["joints"]] + ["rms_mm", "n_markers"]
            q_true = truth["trials"][tr["id"]]["q_link"][:, [j - 1 for j in tr["joints"]]]
            assert np.allclose(data[:, 0], truth["trials"][tr["id"]]["time"])
            q = data[:, 1:1 + len(tr["joints"])]
            ok = np.all(np.isfinite(q), axis=1)
            assert ok.mean() > 0.95
            s = summ["trials"][tr["id"]]
            # errors at the solver's own standard error (the Cramer-Rao level, see
            # test_mocap_solve); the stderr itself is the geometry's (short wrist levers)
            rmse = np.sqrt(np.mean((q[ok] - q_true[ok]) ** 2, axis=0))
            assert np.all(rmse < 1.3 * np.array(s["median_stderr_rad"])), (rmse, s["median_stderr_rad"])
            assert np.all(np.array(s["median_stderr_rad"]) < 5e-3)
            assert s["frames"] == data.shape[0]
            assert 0.5 < s["rms_mm"] < 1.2
            assert s["flagged_frames"] == int((~ok).sum())
            if tr["id"] == "j35-r1":  # link2 is not moved: its markers sit at their reference
                assert 0.6 < s["fixed_markers"]["rms_mm"] < 1.1
        source = "given" if extra else "static_poses"
        assert summ["references"]["camera_source"] == source
        assert summ["camera_from"] == ("calib.json" if extra else "static_poses")
    assert "camera pose from calib.json" in capsys.readouterr().out
    assert rrd.is_file() and rrd.stat().st_size > 10000


def test_library_api_with_sink(campaign):
    from viz.sink import Sink

    class Recorder(Sink):
        enabled = True

        def __init__(self):
            self.paths = []

        def points_over_time(self, path, *a, **k):
            self.paths.append(path)

        def scalars(self, path, *a, **k):
            self.paths.append(path)

        def transforms_over_time(self, path, *a, **k):
            self.paths.append(path)

    root, truth = campaign
    camp = load_campaign(root)
    robot = camp.load_robot()
    refs = build_references(camp, robot, truth["T_camera_base"])
    sink = Recorder()
    res = solve_trial(camp, "j2-r1", refs, sink=sink, robot=robot)
    assert res.joints == (2,) and res.q_link.shape == (res.time.size, 1)
    assert any(p.endswith("markers_measured") for p in sink.paths)
    assert any(p.endswith("markers_model") for p in sink.paths)
    assert any("residual_rms_mm" in p for p in sink.paths)
    assert any("/links/" in p for p in sink.paths)


def _edit_manifest(root, tmp_path, fn):
    import shutil

    dst = tmp_path / "edited"
    shutil.copytree(root, dst)
    m = dst / "campaign.toml"
    m.write_text(fn(m.read_text()))
    return dst


@pytest.mark.parametrize("edit,message", [
    (lambda s: re.sub(r"\n\[\[static\]\]\nmarkers = \"static/pose-0\d.trc\"\nlog = \"static/pose-0\d.csv\"\n",
                      "\n", s), "no \\[\\[static\\]\\]"),
    (lambda s: s.replace('link2 = ["LINK2_1", "LINK2_2", "LINK2_3"]', 'link2 = ["LINK2_1", "LINK2_2"]'),
     "at least 3"),
    (lambda s: s.replace('"LINK3_4"', '"LINK3_4", "NOT_THERE"'), "NOT_THERE"),
])
def test_bad_input_one_clear_message(campaign, tmp_path, capsys, edit, message):
    root, _ = campaign
    dst = _edit_manifest(root, tmp_path, edit)
    rc = main(["mocap", str(dst), "--out", str(tmp_path / "o")])
    err = capsys.readouterr().err
    assert rc == 2
    assert re.search(message, err), err
    assert err.count("\n") == 1
    assert not (tmp_path / "o" / "angles").exists()


def test_single_static_pose_needs_calib(campaign, tmp_path, capsys):
    root, _ = campaign
    dst = _edit_manifest(root, tmp_path, lambda s: s.replace(
        '\n[[static]]\nmarkers = "static/pose-02.trc"\nlog = "static/pose-02.csv"\n', "\n"))
    assert main(["mocap", str(dst), "--out", str(tmp_path / "o")]) == 2
    assert "--calib" in capsys.readouterr().err


def test_out_inside_input_refused(campaign, capsys):
    root, _ = campaign
    assert main(["mocap", str(root), "--out", str(root / "out")]) == 2
    assert "inside the input folder" in capsys.readouterr().err


@pytest.mark.slow
def test_demo_campaign_end_to_end(tmp_path):
    """The bundled demo campaign (one static pose, joint 1/2 sweeps): without --calib the camera
    comes from the sweeps; the link angles match the simulator's truth at the solver's stderr."""
    from pathlib import Path

    demo = Path(__file__).resolve().parents[1] / "fixtures" / "demo"
    truth = demo.parent / "demo-truth" / "demo.truth.npz"
    if not (demo / "campaign.toml").is_file() or not truth.is_file():
        pytest.skip("demo campaign not present")
    tid = "j5-load0-v50-r1"
    out = tmp_path / "out"
    assert main(["mocap", str(demo), "--out", str(out), "--trial", tid]) == 0
    summ = json.loads((out / "mocap.json").read_text())
    assert summ["camera_from"] == "calib_sweeps"
    header, data = _read_angles(out / "angles" / f"{tid}.csv")
    z = np.load(truth)
    q_true = np.interp(data[:, 0], z[f"{tid}/time"], z[f"{tid}/q"])
    rmse = np.sqrt(np.nanmean((data[:, 1] - q_true) ** 2))
    assert rmse < 1.3 * summ["trials"][tid]["median_stderr_rad"][0]
