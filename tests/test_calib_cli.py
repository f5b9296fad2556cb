"""``jointlab calib`` on a FORMAT v1 campaign written to disk, and its bad-input messages."""
from __future__ import annotations

import json

import numpy as np
import pytest

from calib.base import pose_errors
from mocap.io.errors import InputError
from viz.sink import Sink


@pytest.fixture(scope="module")
def pa10(pa10_dir):
    from mocap.robot import Robot

    return Robot.from_urdf(pa10_dir / "pa10.urdf", pa10_dir / "drives.toml")


@pytest.fixture(scope="module")
def campaign(pa10, pa10_dir, tmp_path_factory):
    from calib._synthetic import simulate_sweeps, write_campaign

    sim = simulate_sweeps(pa10, seed=21, duration_s=6.0)
    root = tmp_path_factory.mktemp("calib") / "camp"
    write_campaign(root, sim, pa10_dir / "pa10.urdf", pa10_dir / "drives.toml")
    return root, sim


def _manifest(path, camp_root, calib, markers):
    """A variant manifest in its own folder, the campaign's data copied in (FORMAT.md: paths
    are relative and stay inside the campaign folder; links leading out of it are refused)."""
    import shutil

    from mocap.io.campaign import write_manifest

    path.mkdir(parents=True, exist_ok=True)
    for sub in ("robot", "calib"):
        shutil.copytree(camp_root / sub, path / sub)
    doc = {"format": 1, "name": "variant",
           "robot": {"urdf": "robot/arm.urdf", "drives": "robot/drives.toml"},
           "markers": markers,
           "calib": [{"joint": j, "markers": f"calib/joint-{j}.trc", "log": log or f"calib/joint-{j}.csv"}
                     for j, log in calib]}
    write_manifest(path / "campaign.toml", doc)
    return path


def test_cli_writes_calib_json(campaign, tmp_path, capsys):
    from ident.cli.main import main

    root, sim = campaign
    out = tmp_path / "out"
    assert main(["calib", str(root), "--out", str(out), "--cross-check"]) == 0
    doc = json.loads((out / "calib.json").read_text())
    assert doc["format"] == 1
    for key in ("T_camera_base", "axes", "origin_std_mm", "rotation_std_deg", "crb", "method"):
        assert key in doc
    T = np.array(doc["T_camera_base"])
    assert T.shape == (4, 4)
    dp, dr = pose_errors(T, sim.T_camera_base)
    assert dp < 0.5 and dr < 0.05
    assert [a["joint"] for a in doc["axes"]] == [1, 2]
    for a in doc["axes"]:
        assert 0.6 < a["rms_mm"] < 1.1
        n = np.array(a["direction_camera"])
        assert abs(np.linalg.norm(n) - 1) < 1e-12
    # the direction follows the joint's positive rotation: it is the URDF axis mapped by T
    from mocap.io.campaign import load_campaign

    chain = load_campaign(root).load_robot().chain
    p, d = chain.joint_axis_lines(sim.q_rest)
    for a in doc["axes"]:
        assert np.array(a["direction_camera"]) @ (sim.T_camera_base[:3, :3] @ d[a["joint"] - 1]) > 0.9999
    assert 0.5 * doc["crb"]["origin_std_mm"] < doc["origin_std_mm"] < 2 * doc["crb"]["origin_std_mm"]
    assert "Cramer-Rao" in capsys.readouterr().out
    he = doc["handeye"]                       # the peer agrees on the same data
    assert he["link"] == "link2" and he["difference_origin_mm"] < 0.3 and he["difference_rotation_deg"] < 0.03


def test_cli_refuses_out_inside_campaign(campaign, capsys):
    from ident.cli.main import main

    root, _ = campaign
    assert main(["calib", str(root), "--out", str(root / "out")]) == 2
    assert "inside the input folder" in capsys.readouterr().err


def test_missing_calibration_entry(campaign, tmp_path):
    from calib.pipeline import calibrate
    from mocap.io.campaign import load_campaign

    root, sim = campaign
    var = _manifest(tmp_path / "v", root, [(1, None)], {k: list(v) for k, v in sim.markers.items()})
    camp = load_campaign(var)
    with pytest.raises(InputError, match=r"no \[\[calib\]\] entry for joint 2 \(found: 1\)"):
        calibrate(camp)


def test_two_markers_calibrate_and_none_is_refused(campaign, tmp_path):
    from calib.pipeline import calibrate
    from mocap.io.campaign import load_campaign

    root, sim = campaign
    markers = {"link1": list(sim.markers["link1"]), "link2": list(sim.markers["link2"][:2])}
    camp = load_campaign(_manifest(tmp_path / "v", root, [(1, None), (2, None)], markers))
    res = calibrate(camp)                  # joint 2 from two markers: the circle method
    assert [f.method for f in res.axes] == ["cluster", "circle"]
    dp, dr = pose_errors(res.T_camera_base, sim.T_camera_base)
    assert dp < 1.5 and dr < 0.1
    camp = load_campaign(_manifest(tmp_path / "w", root, [(1, None), (2, None)],
                                   {"link1": list(sim.markers["link1"])}))
    with pytest.raises(InputError, match=r"joint 2: only 0 markers on the links it moves \(none\)") as exc:
        calibrate(camp)
    assert "joint-2.trc" in str(exc.value)


def test_two_joints_moving_and_short_sweep(pa10, campaign):
    from calib.pipeline import prepare_sweep
    from mocap.io.robotlog import RobotLog

    _, sim = campaign
    sw = sim.sweeps[0]
    qm = sw.log.qm.copy()
    qm[:, 1] += np.radians(5.0) * np.sin(np.linspace(0, 3, len(qm)))
    both = RobotLog(sw.log.time, qm, sw.log.tau, {}, None)
    with pytest.raises(InputError, match=r"more than one joint moves \(joint 1 120\.0 deg, joint 2 "):
        prepare_sweep(1, sw.markers, both, pa10.chain, sim.markers)
    qm = sw.log.qm.copy()
    qm[:, 1] += qm[:, 0] - sim.q_rest[0]          # joint 2 does joint 1's sweep ...
    qm[:, 0] = sim.q_rest[0]                      # ... and joint 1 stands still
    wrong = RobotLog(sw.log.time, qm, sw.log.tau, {}, None)
    with pytest.raises(InputError, match=r"the log moves joint 2 120\.0 deg, not joint 1 \(0\.0 deg\)"):
        prepare_sweep(1, sw.markers, wrong, pa10.chain, sim.markers)
    qm = sw.log.qm.copy()
    qm[:, 0] = sim.q_rest[0] + (qm[:, 0] - sim.q_rest[0]) * (10.0 / 120.0)
    short = RobotLog(sw.log.time, qm, sw.log.tau, {}, None)
    with pytest.raises(InputError, match=r"covers only 10\.0 deg; the axis fit needs at least 15 deg"):
        prepare_sweep(1, sw.markers, short, pa10.chain, sim.markers)


class _RecordingSink(Sink):
    enabled = True

    def __init__(self):
        self.calls = []

    def __getattribute__(self, name):
        if name in ("points_over_time", "lines", "arrows", "transform", "text"):
            calls = object.__getattribute__(self, "calls")
            return lambda path, *a, **k: calls.append((name, path, a, k))
        return object.__getattribute__(self, name)


def test_sink_gets_arcs_axes_and_base(campaign):
    from calib.pipeline import calibrate
    from mocap.io.campaign import load_campaign

    root, sim = campaign
    sink = _RecordingSink()
    res = calibrate(load_campaign(root), method="circle", sink=sink)
    names = {(c[0], c[1]) for c in sink.calls}
    for j in (1, 2):
        assert ("points_over_time", f"calib/joint-{j}/markers") in names
        assert ("lines", f"calib/joint-{j}/arcs") in names
        assert ("lines", f"calib/joint-{j}/axis") in names
    T = [c for c in sink.calls if c[0] == "transform"][0][2][0]
    np.testing.assert_array_equal(T, res.T_camera_base)
    dp, dr = pose_errors(res.T_camera_base, sim.T_camera_base)
    assert dp < 0.5 and dr < 0.05


def test_cli_rrd_has_arcs_axes_and_base(campaign, tmp_path):
    pytest.importorskip("rerun")
    from rerun.chunk import RrdReader

    from ident.cli.main import main

    root, _ = campaign
    rrd = tmp_path / "calib.rrd"
    assert main(["calib", str(root), "--out", str(tmp_path / "o"), "--rrd", str(rrd), "--method", "circle"]) == 0
    paths = {str(ch.entity_path) for ch in RrdReader(rrd).stream()}
    for p in ("/calib/base", "/calib/base/frame", "/calib/joint-1/arcs", "/calib/joint-2/axis",
              "/calib/joint-2/markers", "/calib/summary"):
        assert p in paths
