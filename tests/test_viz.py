"""viz: the rerun sink writes what it is given (read back with rerun.chunk.RrdReader), the null sink
imports no rerun, only viz imports rerun, plots render headless, and a campaign logs end to end."""
from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from mocap.io.campaign import load_campaign, write_manifest
from mocap.robot import Robot
from mocap.io.robotlog import RobotLog, write_robot_log
from two_link import URDF

REPO = Path(__file__).resolve().parents[1]


DRIVES = """
[[joint]]
name = "joint1"
max_velocity = 1.0
max_torque = 50.0

[[joint]]
name = "joint2"
max_velocity = 2.0
max_torque = 30.0
"""

TETRA_V = np.array([[0.0, 0.0, 0.0], [0.1, 0.0, 0.0], [0.0, 0.1, 0.0], [0.0, 0.0, 0.1]])
TETRA_F = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])


# ---- reading an .rrd back ----------------------------------------------------------------------
def read_rrd(path):
    """{entity path: {"rows": temporal rows, "static": static rows, "chunks": [record batches]}}."""
    from rerun.chunk import RrdReader

    out = {}
    for ch in RrdReader(path).stream():
        e = out.setdefault(ch.entity_path, {"rows": 0, "static": 0, "chunks": []})
        e["static" if ch.is_static else "rows"] += ch.num_rows
        e["chunks"].append(ch.to_record_batch())
    return out


def column(entity, suffix, temporal=True):
    """All values of the component column ending in ``suffix`` (list per row), and the times (s)."""
    vals, times = [], []
    for rb in entity["chunks"]:
        names = rb.schema.names
        if temporal != ("time" in names):
            continue
        hit = [n for n in names if n.endswith(suffix)]
        if not hit:
            continue
        vals += rb.column(hit[0]).to_pylist()
        if temporal:
            times += list(rb.column("time").cast("int64").to_numpy() * 1e-9)
    if temporal:
        order = np.argsort(times, kind="stable")
        return [vals[k] for k in order], np.asarray(times)[order]
    return vals, None


@pytest.fixture
def rrd(tmp_path):
    return tmp_path / "out.rrd"


def _sink(rrd, **kw):
    from viz.rerun_sink import RerunSink

    return RerunSink(rrd=rrd, **kw)


# ---- the sink, method by method ------------------------------------------------------------------
def test_points_over_time_one_row_per_frame_occlusions_dropped(rrd):
    rng = np.random.default_rng(3)
    T, M = 500, 4
    t = 10.0 + np.arange(T) / 100.0
    P = rng.normal(scale=0.5, size=(T, M, 3))
    occluded = rng.random((T, M)) < 0.1
    P[occluded] = np.nan
    with _sink(rrd) as s:
        s.points_over_time("trials/a/markers", t, P, labels=["A", "B", "C", "D"],
                           colors=np.eye(4)[:, :3], radii=0.01)
    ents = read_rrd(rrd)
    m = ents["/trials/a/markers"]
    assert m["rows"] == T
    pos, times = column(m, "positions")
    np.testing.assert_allclose(times, t, atol=1e-9)
    assert [len(p) for p in pos] == list(M - occluded.sum(axis=1))
    got = np.array([xyz for frame in pos for xyz in frame])
    np.testing.assert_allclose(got, P[~occluded], atol=1e-6)  # float32 storage
    labels, _ = column(m, "labels")
    assert labels[7] == [lb for lb, o in zip("ABCD", occluded[7]) if not o]
    radii, _ = column(m, "radii", temporal=False)
    assert radii == [[pytest.approx(0.01)]]


def test_scalars_named_columns_and_unnamed_block(rrd):
    T = 300
    t = np.linspace(0.0, 3.0, T)
    V = np.c_[np.sin(t), np.cos(t)]
    V[5, 1] = np.nan
    with _sink(rrd) as s:
        s.scalars("sig", t, V, names=["qm_1", "tau_1"])
        s.scalars("block", t, V[:, :1].repeat(3, axis=1))
        s.scalars("single", t, V[:, 0])
    ents = read_rrd(rrd)
    assert ents["/sig/qm_1"]["rows"] == T
    assert ents["/sig/tau_1"]["rows"] == T - 1  # the NaN sample is skipped
    assert ents["/single"]["rows"] == T
    vals, times = column(ents["/sig/qm_1"], "scalars")
    np.testing.assert_allclose([v[0] for v in vals], np.sin(t), atol=1e-12)
    block, _ = column(ents["/block"], "scalars")
    assert ents["/block"]["rows"] == T and all(len(v) == 3 for v in block)
    names, _ = column(ents["/sig/tau_1"], "names", temporal=False)
    assert names == [["tau_1"]]


def test_transforms_over_time_round_trip(rrd):
    from scipy.spatial.transform import Rotation

    rng = np.random.default_rng(7)
    T = 120
    t = np.arange(T) / 60.0
    R = Rotation.from_rotvec(rng.normal(size=(T, 3))).as_matrix()
    Ts = np.tile(np.eye(4), (T, 1, 1))
    Ts[:, :3, :3] = R
    Ts[:, :3, 3] = rng.normal(size=(T, 3))
    with _sink(rrd) as s:
        s.transforms_over_time("world/link", t, Ts)
        s.transform("world", Ts[0])
    ents = read_rrd(rrd)
    e = ents["/world/link"]
    assert e["rows"] == T
    tr, _ = column(e, "translation")
    qu, _ = column(e, "quaternion")
    np.testing.assert_allclose(np.array(tr).reshape(T, 3), Ts[:, :3, 3], atol=1e-6)
    R_back = Rotation.from_quat(np.array(qu).reshape(T, 4)).as_matrix()
    np.testing.assert_allclose(R_back, R, atol=1e-6)
    assert ents["/world"]["static"] == 1


def test_static_content_and_blueprint(rrd):
    from rerun.chunk import RrdReader

    with _sink(rrd) as s:
        s.mesh("robot/link1", TETRA_V, TETRA_F, color=(200, 10, 10))
        s.points("pts", TETRA_V, labels=list("abcd"), radii=0.02)
        s.lines("skeleton", [TETRA_V, TETRA_V[:2]])
        s.arrows("axes", TETRA_V[:2], TETRA_V[1:3], labels=["x", "y"])
        s.text("reports/summary", "# Summary\n\nrms 0.3")
        s.image("plots/fig", np.zeros((8, 10, 3), np.uint8))
        s.layout(series={"angles": ["/sig/qm_1"]})
    ents = read_rrd(rrd)
    for p in ("/robot/link1", "/pts", "/skeleton", "/axes", "/reports/summary", "/plots/fig"):
        assert ents[p]["static"] >= 1 and ents[p]["rows"] == 0, p
    tri, _ = column(ents["/robot/link1"], "triangle_indices", temporal=False)
    assert np.array(tri[0]).tolist() == TETRA_F.tolist()
    text, _ = column(ents["/reports/summary"], "text", temporal=False)
    assert text == [["# Summary\n\nrms 0.3"]]
    # the default blueprint (constructor) and the layout call are in the file
    reader = RrdReader(rrd)
    views = []
    for store in reader.blueprints():
        names = set()
        for ch in reader.stream(store=store):
            rb = ch.to_record_batch()
            for n in rb.schema.names:
                if n.endswith("display_name"):
                    names.update(v[0] for v in rb.column(n).to_pylist() if v)
        views.append(names)
    assert {"world (camera frame)", "signals", "reports"} in views  # default_blueprint()
    assert {"world (camera frame)", "angles", "reports"} in views  # layout(series=...)


def test_robot_meshes_static_transforms_over_time(rrd):
    T = 90
    t = np.arange(T) / 30.0
    Ts = np.tile(np.eye(4), (T, 1, 1))
    Ts[:, 0, 3] = t
    with _sink(rrd, blueprint=False) as s:
        s.robot("arm", {"link1": (TETRA_V, TETRA_F)}, t, {"link1": Ts, "link2": Ts})
    ents = read_rrd(rrd)
    assert ents["/arm/link1"]["rows"] == T and ents["/arm/link2"]["rows"] == T
    mesh, _ = column(ents["/arm/link1"], "vertex_positions", temporal=False)
    assert len(mesh) == 1 and len(mesh[0]) == 4  # logged once, static
    moving, _ = column(ents["/arm/link1"], "vertex_positions", temporal=True)
    assert moving == []  # no mesh copies over time
    tr, _ = column(ents["/arm/link1"], "translation")
    np.testing.assert_allclose(np.array(tr).reshape(T, 3)[:, 0], t, atol=1e-6)
    assert ents["/arm/link2"]["static"] == 1  # axes for the link without a mesh


def test_bad_shapes_raise(rrd):
    with _sink(rrd) as s:
        with pytest.raises(ValueError, match="markers"):
            s.points_over_time("m", np.arange(3.0), np.zeros((3, 2, 3)), labels=["a"])
        with pytest.raises(ValueError, match="time"):
            s.scalars("s", np.arange(4.0), np.zeros(3))
        with pytest.raises(ValueError, match="vertices"):
            s.mesh("x", TETRA_V, TETRA_F[:, :2])


def test_closed_sink_refuses_and_close_is_idempotent(rrd):
    s = _sink(rrd)
    s.close()
    s.close()
    with pytest.raises(RuntimeError, match="closed"):
        s.text("x", "y")


def test_two_sinks_coexist(tmp_path):
    a, b = tmp_path / "a.rrd", tmp_path / "b.rrd"
    sa, sb = _sink(a), _sink(b)
    sa.scalars("only_a", np.arange(5.0), np.arange(5.0))
    sb.scalars("only_b", np.arange(7.0), np.arange(7.0))
    sa.close()
    sb.close()
    ea, eb = read_rrd(a), read_rrd(b)
    assert "/only_a" in ea and "/only_b" not in ea and ea["/only_a"]["rows"] == 5
    assert "/only_b" in eb and "/only_a" not in eb and eb["/only_b"]["rows"] == 7


def test_make_sink_gives_rerun_sink(rrd):
    from viz import make_sink
    from viz.rerun_sink import RerunSink

    s = make_sink(rrd=str(rrd))
    assert isinstance(s, RerunSink) and s.enabled
    s.scalars("via_make_sink", np.arange(4.0), np.arange(4.0) ** 2)
    s.close()
    e = read_rrd(rrd)["/via_make_sink"]
    vals, times = column(e, "Scalars:scalars")
    assert e["rows"] == 4 and np.allclose(np.ravel(vals), np.arange(4.0) ** 2)
    assert np.allclose(times, np.arange(4.0))
    assert not make_sink().enabled          # neither file nor viewer: the null sink


# ---- the seam: only viz imports rerun ------------------------------------------------------------
def test_null_sink_imports_no_rerun():
    code = (
        "import sys, numpy as np\n"
        "from viz import make_sink, NullSink\n"
        "import viz.plots, ident.study.view\n"
        "s = make_sink()\n"
        "assert isinstance(s, NullSink) and not s.enabled\n"
        "s.points_over_time('m', np.arange(3.0), np.zeros((3, 2, 3)))\n"
        "s.scalars('s', np.arange(3.0), np.zeros(3)); s.layout(); s.close()\n"
        "bad = sorted(m for m in sys.modules if m.split('.')[0] in ('rerun', 'rerun_bindings'))\n"
        "assert not bad, bad\n"
        "print('ok')\n")
    r = subprocess.run([sys.executable, "-c", code], cwd=REPO, capture_output=True, text=True,
                       timeout=60)
    assert r.returncode == 0 and r.stdout.strip() == "ok", r.stderr


_RERUN_IMPORT = re.compile(r"^\s*(import\s+rerun|from\s+rerun[\s.]|import\s+rerun_bindings)", re.M)


def test_only_viz_imports_rerun():
    offenders = []
    for pkg in ("mocap", "calib", "ident"):
        for f in sorted((REPO / pkg).rglob("*.py")):
            if _RERUN_IMPORT.search(f.read_text(encoding="utf-8")):
                offenders.append(str(f.relative_to(REPO)))
    assert not offenders, f"only viz may import rerun: {offenders}"
    # and the check itself catches an import
    assert _RERUN_IMPORT.search("x = 1\n    import rerun as rr\n")
    assert _RERUN_IMPORT.search("from rerun.chunk import RrdReader\n")
    assert not _RERUN_IMPORT.search("# uses rerun_sink via viz\n")


# ---- plots ----------------------------------------------------------------------------------------
def test_figure_to_rgb_and_save_png(tmp_path):
    import matplotlib.image as mpimg
    from matplotlib.patches import Rectangle

    from viz.plots import figure_to_rgb, new_figure, save_png

    fig = new_figure(3.0, 2.0, dpi=50)
    ax = fig.add_axes((0, 0, 1, 1))
    ax.set_axis_off()
    ax.add_patch(Rectangle((0, 0), 0.5, 1, color=(1.0, 0.0, 0.0), transform=ax.transAxes))
    rgb = figure_to_rgb(fig)
    assert rgb.shape == (100, 150, 3) and rgb.dtype == np.uint8
    assert rgb[50, 10].tolist() == [255, 0, 0]  # left half red
    assert rgb[50, 140].tolist() == [255, 255, 255]  # right half white
    p = save_png(fig, tmp_path / "sub" / "f.png")
    assert mpimg.imread(p).shape[:2] == (100, 150)
    with pytest.raises(FileExistsError):
        save_png(fig, p)
    save_png(fig, p, overwrite=True)


# ---- the campaign view ---------------------------------------------------------------------------
def _write_trc(path, time, positions_m, labels):
    """A TRC in millimetres written with plain text (FORMAT.md), occlusions as empty cells."""
    T, M = positions_m.shape[:2]
    rate = 1.0 / np.median(np.diff(time))
    head = ["PathFileType\t4\t(X/Y/Z)\t" + path.name,
            "DataRate\tCameraRate\tNumFrames\tNumMarkers\tUnits\tOrigDataRate\tOrigDataStartFrame\tOrigNumFrames",
            f"{rate:g}\t{rate:g}\t{T}\t{M}\tmm\t{rate:g}\t1\t{T}",
            "Frame#\tTime\t" + "\t\t\t".join(labels),
            "\t\t" + "\t".join(f"X{i}\tY{i}\tZ{i}" for i in range(1, M + 1)), ""]
    cells = np.char.mod("%.4f", positions_m.reshape(T, -1) * 1000.0)
    cells[~np.isfinite(positions_m.reshape(T, -1))] = ""
    rows = [f"{k + 1}\t{time[k]:.6f}\t" + "\t".join(c) for k, c in enumerate(cells)]
    path.write_text("\n".join(head + rows) + "\n", encoding="utf-8")


@pytest.fixture
def tiny_campaign(tmp_path):
    """Two recordings: a calibration sweep of joint 1 and a trial moving both joints (200 Hz log,
    100 Hz markers, 2.5 s). Ground truth: q1 = 0.8 sin(2 pi 0.4 t), q2 = 0.3 t in the trial."""
    root = tmp_path / "camp"
    (root / "robot").mkdir(parents=True)
    (root / "robot" / "arm.urdf").write_text(URDF)
    (root / "robot" / "drives.toml").write_text(DRIVES)
    rng = np.random.default_rng(11)
    t_log = 5.0 + np.arange(500) / 200.0
    t_mk = 5.0 + np.arange(250) / 100.0
    labels = ["L1A", "L1B", "L2A", "L2B"]
    recs = {}
    for name, moving in (("calib/joint-1", (1,)), ("trials/t1", (1, 2))):
        qm = np.full((t_log.size, 2), np.nan)
        qm[:, 0] = 0.8 * np.sin(2 * np.pi * 0.4 * (t_log - 5.0))
        if 2 in moving:
            qm[:, 1] = 0.3 * (t_log - 5.0)
        tau = np.where(np.isfinite(qm), 0.1 * np.nan_to_num(qm), np.nan)
        write_robot_log(root / f"{name}.csv", RobotLog(t_log, qm, tau))
        P = 0.5 + rng.normal(scale=0.1, size=(t_mk.size, 4, 3))
        P[rng.random((t_mk.size, 4)) < 0.05] = np.nan
        _write_trc(root / f"{name}.trc", t_mk, P, labels)
        recs[name] = (qm, P)
    write_manifest(root / "campaign.toml", {
        "format": 1, "name": "tiny",
        "robot": {"urdf": "robot/arm.urdf", "drives": "robot/drives.toml"},
        "markers": {"link1": ["L1A", "L1B"], "link2": ["L2A", "L2B"]},
        "calib": [{"joint": 1, "markers": "calib/joint-1.trc", "log": "calib/joint-1.csv"}],
        "trial": [{"id": "t1", "joints": [1, 2], "markers": "trials/t1.trc", "log": "trials/t1.csv"}],
    })
    return load_campaign(root), t_log, t_mk, recs


def test_log_campaign_entities_rows_and_poses(tiny_campaign, rrd):
    from ident.study.view import log_campaign

    campaign, t_log, t_mk, recs = tiny_campaign
    T_camera_base = np.eye(4)
    T_camera_base[:3, 3] = [1.0, 2.0, 0.5]
    meshes = {"link2": (TETRA_V, TETRA_F)}
    with _sink(rrd) as s:
        logged = log_campaign(campaign, s, T_camera_base=T_camera_base, meshes=meshes)
    assert logged == ["campaign/calib/calib-joint-1", "campaign/trial/t1"]
    ents = read_rrd(rrd)
    n_pose = len(np.unique(np.floor((t_log - t_log[0]) * 60.0)))
    assert n_pose <= (t_log[-1] - t_log[0]) * 60.0 + 1
    for base, name in (("/campaign/calib/calib-joint-1", "calib/joint-1"), ("/campaign/trial/t1", "trials/t1")):
        qm, P = recs[name]
        mk = ents[f"{base}/markers"]
        assert mk["rows"] == t_mk.size
        pos, times = column(mk, "positions")
        np.testing.assert_allclose(times, t_mk, atol=1e-9)
        assert [len(p) for p in pos] == list(np.all(np.isfinite(P), axis=2).sum(axis=1))
        assert ents[f"{base}/signals/qm_1"]["rows"] == t_log.size
        assert ents[f"{base}/signals/tau_1"]["rows"] == t_log.size
        assert (f"{base}/signals/qm_2" in ents) == np.isfinite(qm[:, 1]).any()
        # the base placed in the world with T_camera_base
        tr, _ = column(ents[f"{base}/robot"], "translation", temporal=False)
        np.testing.assert_allclose(tr[0][0], [1.0, 2.0, 0.5], atol=1e-6)
        # link2 rides on joint 1 (about z) then joint 2 (about y): its rotation is
        # Rz(q1) Ry(q2) with q2 held at 0 where the log has no column; origin at z = 0.5
        e = ents[f"{base}/robot/link2"]
        assert e["rows"] == n_pose
        qu, tq = column(e, "quaternion")
        from scipy.spatial.transform import Rotation

        q1 = np.interp(tq, t_log, qm[:, 0])
        q2 = np.interp(tq, t_log, np.nan_to_num(qm[:, 1]))
        R_true = Rotation.from_euler("ZY", np.c_[q1, q2]).as_matrix()
        np.testing.assert_allclose(Rotation.from_quat(np.array(qu).reshape(-1, 4)).as_matrix(), R_true, atol=1e-5)
        tr, _ = column(e, "translation")
        np.testing.assert_allclose(np.array(tr).reshape(-1, 3), np.tile([0.0, 0.0, 0.5], (n_pose, 1)), atol=1e-6)
        assert ents[f"{base}/robot/link2"]["static"] >= 1  # the mesh
    assert "/campaign/README" in ents


def test_log_campaign_signal_decimation_and_null_sink(tiny_campaign, rrd):
    from ident.study.view import log_campaign
    from viz import NullSink

    campaign, t_log, _, _ = tiny_campaign
    with _sink(rrd) as s:
        log_campaign(campaign, s, meshes={}, max_signal_rate_hz=50.0)
    ents = read_rrd(rrd)
    n50 = len(np.unique(np.floor((t_log - t_log[0]) * 50.0)))
    assert n50 == 125
    assert ents["/campaign/trial/t1/signals/qm_2"]["rows"] == n50
    assert ents["/campaign/trial/t1/robot/link1"]["rows"] == 150  # 2.5 s at <= 60 Hz
    assert log_campaign(campaign, NullSink()) == ["campaign/calib/calib-joint-1", "campaign/trial/t1"]


def test_decimate_indices_caps_the_rate():
    from ident.study.view import decimate_indices

    rng = np.random.default_rng(5)
    t = np.cumsum(rng.uniform(0.5e-3, 1.5e-3, size=20000))  # ~1 kHz, jittered, 20 s
    idx = decimate_indices(t, 60.0)
    assert idx[0] == 0 and np.all(np.diff(idx) > 0)
    assert len(idx) <= (t[-1] - t[0]) * 60.0 + 1
    assert len(idx) >= (t[-1] - t[0]) * 60.0 - 1
    slow = np.arange(50) / 20.0  # 20 Hz stays whole
    assert decimate_indices(slow, 60.0).tolist() == list(range(50))


def test_log_robot_description_static(rrd):
    from ident.study.view import log_robot_description

    urdf = rrd.parent / "arm.urdf"
    urdf.write_text(URDF)
    robot = Robot.from_urdf(urdf)
    with _sink(rrd) as s:
        log_robot_description(robot, s, meshes={"link1": (TETRA_V, TETRA_F)})
    ents = read_rrd(rrd)
    tr, _ = column(ents["/robot/link2"], "translation", temporal=False)
    np.testing.assert_allclose(tr[0][0], [0.0, 0.0, 0.5], atol=1e-6)
    lab, _ = column(ents["/robot/joint_axes"], "labels", temporal=False)
    assert lab == [["1: joint1", "2: joint2"]]
    vec, _ = column(ents["/robot/joint_axes"], "vectors", temporal=False)
    np.testing.assert_allclose(vec[0], [[0, 0, 0.1], [0, 0.1, 0]], atol=1e-6)
    assert all(v["rows"] == 0 for v in ents.values())


def test_campaign_markers_and_posed_robot_agree_in_the_world(tmp_path, rrd):
    """End to end on a seeded PA10-like campaign with known T_camera_base: in each static pose
    the logged marker positions equal T_camera_base @ T_base_link(qm) @ p_link (composed from
    what the .rrd holds) to within 0.6 mm (simulated noise 0.85 mm RMS per frame; median over 200 frames).
    A wrong frame convention (inverted transform, quaternion order) is off by decimetres."""
    from scipy.spatial.transform import Rotation

    from ident.study.view import log_campaign
    from mocap._synthetic import write_campaign

    for sub in ("static", "trials"):  # (write_trc does not create folders at the time of writing)
        (tmp_path / "camp" / sub).mkdir(parents=True)
    truth = write_campaign(tmp_path / "camp", seed=4, duration_s=1.0, n_static=2)
    campaign = load_campaign(tmp_path / "camp")
    with _sink(rrd) as s:
        log_campaign(campaign, s, T_camera_base=truth["T_camera_base"], meshes={})
    ents = read_rrd(rrd)

    def pose(entity, temporal):
        tr, _ = column(entity, "translation", temporal=temporal)
        qu, _ = column(entity, "quaternion", temporal=temporal)
        T = np.tile(np.eye(4), (len(tr), 1, 1))
        T[:, :3, :3] = Rotation.from_quat(np.array(qu).reshape(-1, 4)).as_matrix()
        T[:, :3, 3] = np.array(tr).reshape(-1, 3)
        return T

    for k in (1, 2):
        base = f"/campaign/static/static-{k}"
        T_cb = pose(ents[f"{base}/robot"], temporal=False)[0]
        np.testing.assert_allclose(T_cb, truth["T_camera_base"], atol=1e-6)
        pos, _ = column(ents[f"{base}/markers"], "positions")
        labels, _ = column(ents[f"{base}/markers"], "labels")
        by_label = {}
        for frame_pos, frame_lab in zip(pos, labels):
            for p, lb in zip(frame_pos, frame_lab):
                by_label.setdefault(lb, []).append(p)
        assert set(by_label) == set(truth["markers"])
        for lb, (link, p_link) in truth["markers"].items():
            T_bl = pose(ents[f"{base}/robot/{link}"], temporal=True)[0]
            p_pred = (T_cb @ T_bl @ np.r_[p_link, 1.0])[:3]
            err = np.linalg.norm(np.median(np.array(by_label[lb]), axis=0) - p_pred)
            assert err < 0.6e-3, (k, lb, err)
