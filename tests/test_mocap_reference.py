"""Static-pose references (thesis eq. 3-4) and the camera pose estimated from static poses."""
from __future__ import annotations

import numpy as np
import pytest

from mocap._synthetic import default_camera_pose, pa10_robot, place_markers, simulate_markers
from mocap.io.errors import InputError
from mocap.io.recording import MarkerRecording
from mocap.kinematics import kabsch
from mocap.references import fit_references, read_static_pose, reduce_static
from mocap.io.robotlog import RobotLog

Q_REST = np.array([0.2, 0.4, 0.9, 0.1, 0.6, 0.0])


@pytest.fixture(scope="module")
def setup(tmp_path_factory):
    robot = pa10_robot(tmp_path_factory.mktemp("arm"))
    mk = place_markers(robot, {"link2": 3, "link3": 4, "link5": 4}, seed=1)
    T_cb = default_camera_pose(0)
    rng = np.random.default_rng(5)
    poses = []
    for k in range(3):
        qs = Q_REST + (rng.uniform(-0.6, 0.6, 6) if k else 0.0)
        sim = simulate_markers(robot, np.tile(qs, (200, 1)), mk, T_cb, seed=10 + k,
                               outlier_frac=0.01, missing_frac=0.1)
        rec = MarkerRecording(np.arange(200) / 100.0, sim.p_camera, sim.labels, 100.0)
        t = np.arange(300) / 150.0 - 0.2
        log = RobotLog(t, np.tile(qs, (300, 1)), np.zeros((300, 6)))
        poses.append(read_static_pose(rec, log, sim.labels))
    labels = tuple(mk)
    links = tuple(mk[lb][0] for lb in labels)
    true = np.array([mk[lb][1] for lb in labels])
    return robot, labels, links, poses, true, T_cb


def test_kabsch_recovers_transform():
    rng = np.random.default_rng(0)
    a = rng.normal(size=(6, 3))
    from scipy.spatial.transform import Rotation

    R = Rotation.from_rotvec([0.3, -0.2, 1.1]).as_matrix()
    b = a @ R.T + [0.1, 0.2, -0.3]
    T = kabsch(a, b)
    assert np.allclose(T[:3, :3], R, atol=1e-12) and np.allclose(T[:3, 3], [0.1, 0.2, -0.3])


def test_reduce_static_rejects_outliers():
    rng = np.random.default_rng(1)
    pos = np.array([0.1, 0.2, 0.3]) + rng.normal(0, 1e-4, (500, 1, 3))
    pos[::50, 0] += 0.05  # 2 % gross outliers
    mean, n, scat = reduce_static(pos)
    assert n[0] == 490
    assert np.linalg.norm(mean[0] - [0.1, 0.2, 0.3]) < 3e-5
    assert scat[0] == pytest.approx(np.sqrt(3) * 1e-4, rel=0.1)


@pytest.mark.parametrize("n_poses", [1, 3])
def test_references_with_given_camera(setup, n_poses):
    robot, labels, links, poses, true, T_cb = setup
    refs = fit_references(robot.chain, labels, links, poses[:n_poses], T_cb)
    # 180 frames x 0.49 mm per axis: the mean is good to ~0.04 mm per axis; 0.25 mm is 6 sigma
    assert np.abs(refs.p_link - true).max() < 0.25e-3
    assert refs.camera_source == "given"
    if n_poses == 1:
        assert np.isnan(refs.consistency_m).all()
    else:
        assert np.all(refs.consistency_m < 0.3e-3)
    d = refs.to_dict()
    assert set(d["markers"]) == set(labels) and d["camera_source"] == "given"


def test_camera_estimated_from_static_poses(setup):
    robot, labels, links, poses, true, T_cb = setup
    refs = fit_references(robot.chain, labels, links, poses, None)
    assert refs.camera_source == "static_poses"
    from scipy.spatial.transform import Rotation

    dR = Rotation.from_matrix(refs.T_camera_base[:3, :3] @ T_cb[:3, :3].T).magnitude()
    assert np.degrees(dR) < 0.05
    assert np.linalg.norm(refs.T_camera_base[:3, 3] - T_cb[:3, 3]) < 0.5e-3
    assert np.abs(refs.p_link - true).max() < 0.5e-3
    assert refs.camera_std is not None and np.all(refs.camera_std < 1e-3)


def test_single_pose_without_camera_is_refused(setup):
    robot, labels, links, poses, _, _ = setup
    with pytest.raises(InputError, match="--calib"):
        fit_references(robot.chain, labels, links, poses[:1], None)
    with pytest.raises(InputError, match="no static pose"):
        fit_references(robot.chain, labels, links, [], None)


def test_moving_robot_in_static_pose_is_refused(setup):
    robot, labels, *_ = setup
    rec = MarkerRecording(np.arange(10) / 10.0, np.zeros((10, len(labels), 3)), labels, 10.0)
    qm = np.tile(Q_REST, (20, 1))
    qm[:, 2] += np.linspace(0, 0.05, 20)
    log = RobotLog(np.arange(20) / 20.0, qm, np.zeros_like(qm))
    with pytest.raises(InputError, match="joint 3 moved"):
        read_static_pose(rec, log, labels)
    log2 = RobotLog(np.arange(20) / 20.0 + 100.0, qm, np.zeros_like(qm))
    with pytest.raises(InputError, match="do not overlap"):
        read_static_pose(rec, log2, labels)


def test_inconsistent_marker_reported(setup):
    """A marker that moved on its link between two static poses is listed as inconsistent."""
    robot, labels, links, poses, true, T_cb = setup
    from dataclasses import replace

    moved = poses[1].p_camera.copy()
    moved[2] += [0.004, 0.0, 0.0]  # 4 mm
    bad = [poses[0], replace(poses[1], p_camera=moved), poses[2]]
    refs = fit_references(robot.chain, labels, links, bad, T_cb)
    d = refs.to_dict()
    assert d["inconsistent_markers"] == [labels[2]]
    assert refs.consistency_m[2] > 1e-3 and np.all(np.delete(refs.consistency_m, 2) < 0.3e-3)
