"""``jointlab synth``: the campaign writer (ident.sim.campaign_synth) and the marker synthesis (mocap.synth)."""
from __future__ import annotations

import json
import math

import numpy as np
import pytest

from ident.sim.campaign_synth import CampaignSynth, SynthConfig, file_hashes

SMALL = dict(joints=(5,), loads=(0.0,), vmax=(1.0,), reps=1, duration=4.0)


def make(tmp, name="camp", truth=None, **kw):
    cfg = SynthConfig(**{**SMALL, **kw})
    out = tmp / name
    summary = CampaignSynth(cfg).write(out, truth, progress=False, command="test")
    return out, summary


@pytest.fixture(scope="module")
def small(tmp_path_factory, pa10_dir):
    tmp = tmp_path_factory.mktemp("synth")
    out, _ = make(tmp, seed=3)
    truth = json.loads((tmp / "camp.truth.json").read_text())
    npz = np.load(tmp / "camp.truth.npz")
    return out, truth, npz


def _reproject(truth, rec_id, t_marker, npz, chain, shift=0.0):
    """Marker positions predicted from the truth: link angles interpolated at t - shift."""
    from mocap.synth import MarkerSet, marker_positions

    info = truth["trials"][rec_id]
    q = np.tile(np.array(info["q_rest"]), (t_marker.size, 1))
    key = f"{rec_id}/marker_q_held"
    if key in npz:   # held joints give at their declared stiffness (the links the markers are on)
        held = [j for j in range(q.shape[1]) if j + 1 != info["joint"]]
        q[:, held] = npz[key]
    if info["joint"]:
        j0 = info["joint"] - 1
        q[:, j0] = np.interp(t_marker - shift, npz[f"{rec_id}/time"], npz[f"{rec_id}/q"])
    m = truth["markers"]
    ms = MarkerSet(tuple(m["labels"]), tuple(m["links"]), np.array(m["p_link"]))
    return marker_positions(chain, ms, q, np.array(truth["T_camera_base"]))


def test_campaign_follows_format(small):
    from mocap.io.campaign import load_campaign
    from mocap.io.markers import read_markers
    from mocap.io.robotlog import read_robot_log

    out, truth, _ = small
    camp = load_campaign(out)
    robot = camp.load_robot()
    assert robot.n == 6 and len(camp.static) == 1 and [c.joint for c in camp.calib] == [1, 2]
    assert len(camp.trials) == 1 and camp.trials[0].joints == (5,)
    assert set(camp.markers) == {f"link{k}" for k in range(1, 7)}
    assert all(3 <= len(v) <= 4 for v in camp.markers.values())
    t_prev = -np.inf
    for kind, name, rec in camp.recordings():
        log = read_robot_log(rec.log, n_joints=6)
        m = read_markers(rec.markers)
        assert np.all(np.isfinite(log.qm)) and np.all(np.isfinite(log.tau))
        assert log.rate_hz == pytest.approx(200.0, rel=1e-6) and m.rate_hz == pytest.approx(100.0)
        assert m.units == "mm" and set(m.labels) == set(camp.link_of_label())
        # streams on their own clocks: markers start later and stop earlier than the log
        assert log.time[0] < m.time[0] < log.time[0] + 0.5 and m.time[-1] < log.time[-1]
        # one campaign-wide clock: recordings follow each other
        assert log.time[0] > t_prev
        t_prev = log.time[-1]
        # encoder quantisation 0.011 deg
        res = math.radians(0.011)
        k = log.qm / res
        assert np.max(np.abs(k - np.round(k))) < 0.01   # written with 1e-6 rad precision
        assert 0.0 < np.mean(m.missing) < 0.06
    assert "qd_ref_5" in read_robot_log(camp.trials[0].log).extra
    # truth beside the campaign, never inside
    assert not list(out.rglob("*.truth.*"))


def test_truth_contents(small):
    out, truth, npz = small
    for key in ("seed", "command", "robot", "effect", "joints", "T_camera_base", "markers", "trials"):
        assert key in truth
    assert truth["joints"]["5"]["nominal"]["cv"] == {"c": 3.90, "v": 0.84}
    assert truth["effect"]["name"] == "none"
    tid = "j5-load0-v100-r1"
    for name in ("time", "q", "qd", "qdd", "qm", "qmd", "f", "u", "tau_t", "q_ref"):
        assert f"{tid}/{name}" in npz.files
    # tracking error of the motor-side controller below 0.1 deg
    assert np.degrees(np.max(np.abs(npz[f"{tid}/qm"] - npz[f"{tid}/q_ref"]))) < 0.1
    T = np.array(truth["T_camera_base"])
    np.testing.assert_allclose(T[:3, :3] @ T[:3, :3].T, np.eye(3), atol=1e-12)


def test_markers_reproject_within_noise(small, pa10_dir):
    from mocap.io.markers import read_markers
    from mocap.robot import Robot

    out, truth, npz = small
    chain = Robot.from_urdf(pa10_dir / "pa10.urdf").chain
    for rec_id in ("static-1", "calib-joint-1", "j5-load0-v100-r1"):
        info = truth["trials"][rec_id]
        m = read_markers(out / info["markers"])
        if info["joint"] == 0:
            continue
        pred = _reproject(truth, rec_id, m.time, npz, chain)
        err = np.linalg.norm(m.positions - pred, axis=2)
        rms = np.sqrt(np.nanmean(err ** 2))
        assert rms == pytest.approx(0.85e-3, rel=0.1), rec_id
    # static: the robot stands at its pose
    m = read_markers(out / "static/pose-01.trc")
    t = truth["trials"]["static-1"]
    from mocap.synth import MarkerSet, marker_positions

    ms = MarkerSet(tuple(truth["markers"]["labels"]), tuple(truth["markers"]["links"]),
                   np.array(truth["markers"]["p_link"]))
    q_static = np.tile(t["q_rest"], (m.n_frames, 1))
    q_static[:] = npz["static-1/marker_q_held"]   # every joint held: each link gives under gravity
    assert 1e-4 < np.max(np.abs(q_static[0] - np.array(t["q_rest"]))) < 1e-2   # at the declared stiffness
    pred = marker_positions(chain, ms, q_static, np.array(truth["T_camera_base"]))
    assert np.sqrt(np.nanmean(np.sum((m.positions - pred) ** 2, axis=2))) == pytest.approx(0.85e-3, rel=0.1)


def test_same_seed_same_bytes(tmp_path, pa10_dir):
    a, _ = make(tmp_path / "a", seed=11, effect="backlash")
    b, _ = make(tmp_path / "b", seed=11, effect="backlash")
    ha, hb = file_hashes(a), file_hashes(b)
    assert ha == hb and len(ha) > 10
    for ext in (".truth.npz", ".truth.json"):
        assert (tmp_path / "a" / f"camp{ext}").read_bytes() == (tmp_path / "b" / f"camp{ext}").read_bytes()
    c, _ = make(tmp_path / "c", seed=12, effect="backlash")
    assert file_hashes(c)["trials/j5-load0-v100-r1.csv"] != ha["trials/j5-load0-v100-r1.csv"]


def test_time_offset_shifts_marker_time(tmp_path, pa10_dir):
    from mocap.io.markers import read_markers
    from mocap.robot import Robot

    out, _ = make(tmp_path, effect="time_offset", magnitude=1.0, seed=5)
    truth = json.loads((tmp_path / "camp.truth.json").read_text())
    npz = np.load(tmp_path / "camp.truth.npz")
    chain = Robot.from_urdf(pa10_dir / "pa10.urdf").chain
    tid = "j5-load0-v100-r1"
    assert truth["trials"][tid]["time_offset_s"] == pytest.approx(0.020)
    m = read_markers(out / truth["trials"][tid]["markers"])
    rms = {}
    wrist = [i for i, lk in enumerate(truth["markers"]["links"]) if lk in ("link5", "link6")]
    for shift in (-0.01, 0.0, 0.01, 0.020, 0.03):
        pred = _reproject(truth, tid, m.time, npz, chain, shift=shift)
        d = (m.positions - pred)[:, wrist]
        rms[shift] = np.sqrt(np.nanmean(np.sum(d ** 2, axis=2)))
    assert rms[0.020] == pytest.approx(0.85e-3, rel=0.1)
    assert rms[0.0] > 1.5 * rms[0.020]
    assert min(rms, key=rms.get) == 0.020


def test_torque_scale_scales_logged_torque(tmp_path, pa10_dir):
    from mocap.io.robotlog import read_robot_log

    out, _ = make(tmp_path, effect="torque_scale", magnitude=1.0, seed=5)
    npz = np.load(tmp_path / "camp.truth.npz")
    tid = "j5-load0-v100-r1"
    log = read_robot_log(out / f"trials/{tid}.csv")
    u = npz[f"{tid}/u"]
    assert np.allclose(log.time, npz[f"{tid}/time"])
    gain = np.sum(log.tau[:, 4] * u) / np.sum(u * u)
    assert gain == pytest.approx(1.15, rel=0.01)


def test_compliance_visible_between_markers_and_encoder(tmp_path, pa10_dir):
    out, _ = make(tmp_path, effect="compliance", magnitude=1.0, seed=5)
    npz = np.load(tmp_path / "camp.truth.npz")
    tid = "j5-load0-v100-r1"
    defl = npz[f"{tid}/qm"] - npz[f"{tid}/q"]
    slope = np.polyfit(npz[f"{tid}/tau_t"], defl, 1)[0]
    # softer than declared: 0.4 deg at rated torque (14.5 N m) beyond the declared 5000 N m/rad
    # of drives.toml (itself 0.166 deg at rated torque)
    from mocap.robot import Robot

    k_decl = Robot.from_urdf(out / "robot/arm.urdf", out / "robot/drives.toml").drives[4].extra["stiffness"]
    assert k_decl == 5000.0
    assert math.degrees((slope - 1.0 / k_decl) * 14.5) == pytest.approx(0.4, rel=0.05)


def test_nominal_plant_at_the_declared_stiffness(small):
    """FORMAT.md: the campaign's drives.toml stiffness is what the simulator used: the true
    deflection of the nominal plant is tau_t / K_declared on every joint's record."""
    from mocap.robot import Robot

    out, truth, npz = small
    assert truth["effect"]["name"] == "none"
    robot = Robot.from_urdf(out / "robot/arm.urdf", out / "robot/drives.toml")
    tid = "j5-load0-v100-r1"
    k_decl = robot.drives[4].extra["stiffness"]
    defl = npz[f"{tid}/qm"] - npz[f"{tid}/q"]
    np.testing.assert_allclose(defl, npz[f"{tid}/tau_t"] / k_decl, rtol=0, atol=1e-9)
    # visible: the wrist deflects by several encoder counts (0.011 deg)
    assert np.degrees(np.max(np.abs(defl))) > 3 * 0.011
    for j, d in enumerate(robot.drives, start=1):
        assert truth["joints"][str(j)]["plant"]["k"] == d.extra["stiffness"]
        assert truth["joints"][str(j)]["k_nominal"] == d.extra["stiffness"]


def test_other_kinds_and_refusals(tmp_path, pa10_dir):
    from ident.cli.main import main
    from mocap.io.campaign import load_campaign

    out, _ = make(tmp_path, kinds=("reversals", "constant_velocity", "coastdown"), vmax=(0.5,), seed=2)
    camp = load_campaign(out)
    assert [t.kind for t in camp.trials] == ["reversals", "constant_velocity", "coastdown"]
    from mocap.io.robotlog import read_robot_log

    cd = read_robot_log(camp.trials[2].log)
    assert set(np.unique(cd.extra["mode_5"])) == {0.0, 1.0}
    # refuses to write into an existing folder unless --overwrite
    args = ["synth", str(out), "--joints", "5", "--loads", "0", "--vmax", "1", "--reps", "1",
            "--duration", "3", "--quiet"]
    assert main(args) == 2
    assert main(args + ["--overwrite"]) == 0
    assert (tmp_path / "camp.truth.json").is_file()
    assert main(["synth", str(tmp_path / "x"), "--joints", "9", "--quiet"]) == 2
    assert main(["synth", str(tmp_path / "y"), "--kinds", "walk", "--quiet"]) == 2


def test_perturbed_robot(tmp_path, pa10_dir):
    pytest.importorskip("mocap.urdf")
    out, _ = make(tmp_path, robot="perturbed", seed=4)
    truth = json.loads((tmp_path / "camp.truth.json").read_text())
    assert truth["robot"]["perturbation"]["seed"] == 4
    assert (tmp_path / "camp.truth.urdf").is_file()
    # the campaign still declares the bundled URDF
    assert (out / "robot/arm.urdf").read_bytes() == (pa10_dir / "pa10.urdf").read_bytes()


def test_label_swaps_and_marker_errors():
    from mocap.kinematics import make_transform
    from mocap.synth import MarkerErrors, MarkerSet, corrupt

    rng = np.random.default_rng(0)
    ms = MarkerSet(("A", "B", "C"), ("l1", "l1", "l2"), np.zeros((3, 3)))
    clean = np.broadcast_to(np.arange(3.0)[None, :, None], (5000, 3, 3)).copy()
    noisy, info = corrupt(clean, ms, rng, MarkerErrors(label_swaps=2))
    ok = np.isfinite(noisy[..., 0])
    assert 0.01 < 1 - ok.mean() < 0.035                      # about 2 % occluded
    lens = [r[2] for r in info["occlusions"]]
    assert min(lens) >= 5 and max(lens) <= 50
    assert len(info["swaps"]) == 2 and all({s[0], s[1]} == {"A", "B"} for s in info["swaps"])
    d = noisy - clean
    unswapped = ok & (np.abs(d[..., 0]) < 0.5)
    rms = np.sqrt(np.mean(np.sum(d[unswapped] ** 2, axis=-1)))
    assert rms == pytest.approx(0.85e-3, rel=0.05)
    assert make_transform(np.eye(3), np.zeros(3)).shape == (4, 4)


def test_several_joints_together_and_sink(tmp_path, pa10_dir):
    from mocap.io.campaign import load_campaign
    from viz.sink import Sink

    class Recorder(Sink):
        enabled = True

        def __init__(self):
            self.calls = []

        def scalars(self, path, *a, **k):
            self.calls.append(("scalars", path))

        def points_over_time(self, path, *a, **k):
            self.calls.append(("points", path))

        def robot(self, path, *a, **k):
            self.calls.append(("robot", path))

        def transform(self, path, *a, **k):
            self.calls.append(("transform", path))

    sink = Recorder()
    cfg = SynthConfig(**{**SMALL, "joints": (4, 5), "vmax": (0.5,), "duration": 3.0}, together=True)
    out = tmp_path / "m"
    CampaignSynth(cfg).write(out, progress=False, sink=sink)
    camp = load_campaign(out)
    assert camp.trials[0].joints == (4, 5)
    npz = np.load(tmp_path / "m.truth.npz")
    tid = camp.trials[0].id
    assert npz[f"{tid}/q"].shape[1] == 2
    assert np.degrees(np.max(np.abs(npz[f"{tid}/qm"] - npz[f"{tid}/q_ref"]))) < 0.25
    kinds = {c[0] for c in sink.calls}
    assert {"scalars", "points", "robot", "transform"} <= kinds
    assert ("scalars", "synth/joint4/torque") in sink.calls


def test_cli_same_command_same_bytes(tmp_path, pa10_dir):
    from ident.cli.main import main

    out = tmp_path / "c"
    args = ["synth", str(out), "--loads", "0", "--vmax", "1", "--reps", "1", "--duration", "3",
            "--effect", "stribeck", "--seed", "9", "--quiet"]
    assert main(args) == 0
    first = file_hashes(out)
    truth = (tmp_path / "c.truth.npz").read_bytes(), (tmp_path / "c.truth.json").read_bytes()
    assert "REGENERATE.md" in first and "--seed 9" in (out / "REGENERATE.md").read_text()
    assert main(args + ["--overwrite"]) == 0
    assert file_hashes(out) == first
    assert ((tmp_path / "c.truth.npz").read_bytes(), (tmp_path / "c.truth.json").read_bytes()) == truth


DEMO = __import__("pathlib").Path(__file__).resolve().parents[1] / "fixtures" / "demo"


def test_committed_demo_is_small_and_valid():
    from mocap.io.campaign import load_campaign

    if not (DEMO / "campaign.toml").is_file():
        pytest.skip("fixtures/demo not generated yet")
    size = sum(p.stat().st_size for p in DEMO.rglob("*") if p.is_file())
    assert size < 5e6
    camp = load_campaign(DEMO)
    assert len(camp.trials) == 12 and {t.joints for t in camp.trials} == {(5,)}
    assert "jointlab synth fixtures/demo" in (DEMO / "REGENERATE.md").read_text()
    truth = json.loads((DEMO.parent / "demo-truth" / "demo.truth.json").read_text())
    assert truth["effect"]["name"] == "stribeck" and truth["effect"]["magnitude"] == 1.0


@pytest.mark.slow
def test_committed_demo_regenerates_within_rounding(tmp_path):
    """Fails when the demo is stale (code, bundled robot or writer changed): regenerate it with
    the command in fixtures/demo/REGENERATE.md."""
    import shlex

    from ident.cli.main import main

    if not (DEMO / "campaign.toml").is_file():
        pytest.skip("fixtures/demo not generated yet")
    cmd = [ln for ln in (DEMO / "REGENERATE.md").read_text().splitlines() if ln.startswith("jointlab")][0]
    argv = shlex.split(cmd)[1:]
    argv[1] = str(tmp_path / "demo")
    i = argv.index("--truth")
    argv[i + 1] = str(tmp_path / "demo")
    argv = [a for a in argv if a != "--overwrite"] + ["--quiet"]
    assert main(argv) == 0
    # Another CPU may round the last bits differently (libm, BLAS): text files are compared
    # cell by cell with tolerances, the truth arrays with allclose; everything else exactly.
    new, old = file_hashes(tmp_path / "demo"), file_hashes(DEMO)
    new.pop("REGENERATE.md")
    old.pop("REGENERATE.md")
    assert sorted(new) == sorted(old)
    for rel in sorted(new):
        if rel.endswith((".csv", ".trc")):
            assert_numeric_text_close(tmp_path / "demo" / rel, DEMO / rel)
        else:
            assert new[rel] == old[rel], rel
    a = np.load(tmp_path / "demo.truth.npz")
    b = np.load(DEMO.parent / "demo-truth" / "demo.truth.npz")
    assert sorted(a.files) == sorted(b.files)
    for key in a.files:
        np.testing.assert_allclose(a[key], b[key], rtol=1e-6, atol=1e-9, err_msg=key)


def assert_numeric_text_close(path_a, path_b):
    """Two text tables agree cell by cell: equal strings, or equal numbers, except for rounding
    flips (the last printed digit, or one encoder step) in at most 0.1 % of the numeric cells,
    each within 0.1 % of its column's scale."""
    rows_a = path_a.read_text().splitlines()
    rows_b = path_b.read_text().splitlines()
    assert len(rows_a) == len(rows_b), path_a.name
    sep = "\t" if path_a.suffix == ".trc" else ","
    cols_a, cols_b, n_cells, n_flips = {}, {}, 0, 0
    for ra, rb in zip(rows_a, rows_b):
        ca, cb = ra.split(sep), rb.split(sep)
        assert len(ca) == len(cb), (path_a.name, ra[:60])
        for k, (x, y) in enumerate(zip(ca, cb)):
            if x == y:
                continue
            try:
                fx, fy = float(x), float(y)
            except ValueError:
                raise AssertionError(f"{path_a.name}: {x!r} != {y!r}") from None
            cols_a.setdefault(k, []).append(fx)
            cols_b.setdefault(k, []).append(fy)
            n_flips += 1
        n_cells += len(ca)
    assert n_flips <= 1e-3 * n_cells, (path_a.name, n_flips, n_cells)
    numbers = np.genfromtxt(path_b, delimiter=sep, skip_header=5 if path_a.suffix == ".trc" else 1)
    numbers = np.atleast_2d(numbers)
    for k in cols_a:
        scale = np.nanmax(np.abs(numbers[:, k])) if k < numbers.shape[1] else 1.0
        diff = np.abs(np.array(cols_a[k]) - np.array(cols_b[k]))
        assert np.all(diff <= 1e-3 * max(scale, 1e-12)), (path_a.name, k, diff.max())
