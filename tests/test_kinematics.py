"""Batched numpy forward kinematics (mocap.kinematics.Chain) against pinocchio and against the
documented geometry of the bundled PA10-6C (fixtures/robots/pa10/make_pa10.py)."""
from __future__ import annotations

import numpy as np
import pytest

from mocap.kinematics import apply_transform, invert_transform, make_transform, rotation_about_axis
from mocap.robot import Robot
from mocap.urdf import perturb_urdf

SHOULDER, UPPER, FOREARM, WRIST = 0.317, 0.45, 0.48, 0.07


@pytest.fixture(scope="module")
def pa10(pa10_dir) -> Robot:
    return Robot.from_urdf(pa10_dir / "pa10.urdf", pa10_dir / "drives.toml")


def random_q(robot: Robot, n: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return rng.uniform(robot.lower, robot.upper, size=(n, robot.n))


def assert_fk_matches_pinocchio(robot: Robot, Q: np.ndarray, atol: float = 1e-12) -> None:
    """Every body frame of the chain, batched over Q, equals pinocchio's oMf placement."""
    import pinocchio as pin

    data = robot.model.createData()
    ref = {name: np.empty((Q.shape[0], 4, 4)) for name in robot.chain.frames}
    ids = {name: robot.model.getFrameId(name, pin.FrameType.BODY) for name in robot.chain.frames}
    for k, q in enumerate(Q):
        pin.framesForwardKinematics(robot.model, data, q)
        for name, fid in ids.items():
            ref[name][k] = data.oMf[fid].homogeneous
    assert len(ref) >= robot.n + 1  # the base and one body per joint at least
    for name in robot.chain.frames:
        got = robot.frame_transform(name, Q)
        assert got.shape == (Q.shape[0], 4, 4)
        np.testing.assert_allclose(got, ref[name], rtol=0, atol=atol, err_msg=name)


# ---- transform helpers ----------------------------------------------------------------------------
def test_rotation_about_axis_is_a_batched_rotation():
    rng = np.random.default_rng(0)
    axis = rng.normal(size=3)
    axis /= np.linalg.norm(axis)
    angles = rng.uniform(-np.pi, np.pi, size=50)
    R = rotation_about_axis(axis, angles)
    assert R.shape == (50, 3, 3)
    np.testing.assert_allclose(R @ np.swapaxes(R, -1, -2), np.broadcast_to(np.eye(3), R.shape), atol=1e-14)
    np.testing.assert_allclose(np.linalg.det(R), 1.0, atol=1e-14)
    np.testing.assert_allclose(R @ axis, np.broadcast_to(axis, (50, 3)), atol=1e-14)  # axis is fixed
    # the rotation angle is recovered from the trace
    np.testing.assert_allclose(np.arccos((np.trace(R, axis1=1, axis2=2) - 1) / 2), np.abs(angles), atol=1e-7)


def test_invert_and_apply_transform_round_trip():
    rng = np.random.default_rng(1)
    R = rotation_about_axis(np.array([0.0, 0.6, 0.8]), rng.uniform(-3, 3, size=10))
    T = make_transform(R, rng.normal(size=(10, 3)))
    p = rng.normal(size=(10, 3))
    np.testing.assert_allclose(apply_transform(invert_transform(T), apply_transform(T, p)), p, atol=1e-14)
    np.testing.assert_allclose(invert_transform(T) @ T, np.broadcast_to(np.eye(4), T.shape), atol=1e-14)


# ---- the bundled PA10 ---------------------------------------------------------------------------------
def test_pa10_fk_equals_pinocchio(pa10):
    assert_fk_matches_pinocchio(pa10, random_q(pa10, 40, seed=2))


def test_pa10_batched_fk_equals_single_frames(pa10):
    Q = random_q(pa10, 7, seed=3)
    batch = pa10.chain.joint_transforms(Q)
    assert batch.shape == (7, 6, 4, 4)
    for k in range(7):
        np.testing.assert_allclose(batch[k], pa10.chain.joint_transforms(Q[k]), atol=1e-15)


def test_frames_last_fk_equals_joint_frames(pa10, pa10_dir, tmp_path):
    """Chain.joint_frames_soa (frames last, the solver's layout) is the same forward kinematics:
    from the base and continued from a held prefix, with the joint axes, on the PA10 and on a
    perturbed copy (axes off the joint frames' z)."""
    perturbed = Robot.from_urdf(perturb_urdf(pa10_dir / "pa10.urdf", tmp_path / "p.urdf", seed=5),
                                pa10_dir / "drives.toml")
    for robot in (pa10, perturbed):
        ch = robot.chain
        Q = random_q(robot, 25, seed=11)
        R, o = ch.joint_frames(Q)
        w = np.einsum("tnij,nj->tni", R, ch.axes)
        F, W = ch.joint_frames_soa(Q.T)
        assert F.shape == (6, 3, 4, 25) and W.shape == (6, 3, 25)
        np.testing.assert_allclose(np.moveaxis(F[:, :, :3], 3, 0), R, rtol=0, atol=1e-14)
        np.testing.assert_allclose(np.moveaxis(F[:, :, 3], 2, 0), o, rtol=0, atol=1e-14)
        np.testing.assert_allclose(np.moveaxis(W, 2, 0), w, rtol=0, atol=1e-14)
        F2, W2 = ch.joint_frames_soa(Q[:, 2:5].T, first=2, F_prev=F[1])
        np.testing.assert_allclose(F2, F[2:5], rtol=0, atol=1e-14)
        np.testing.assert_allclose(W2, W[2:5], rtol=0, atol=1e-14)
    with pytest.raises(ValueError):
        pa10.chain.joint_frames_soa(Q[:, 2:5].T, first=2)  # the frame before joint 3 is needed


def test_pa10_zero_pose_is_straight_up(pa10):
    """Documented zero pose: the arm stands along +z, all frames parallel to the base frame."""
    q0 = np.zeros(6)
    expect_height = {"link1": 0.2, "link2": SHOULDER, "link3": SHOULDER + UPPER,
                     "link4": SHOULDER + UPPER + 0.2, "link5": SHOULDER + UPPER + FOREARM,
                     "link6": SHOULDER + UPPER + FOREARM + WRIST}
    for link, z in expect_height.items():
        T = pa10.frame_transform(link, q0)
        np.testing.assert_allclose(T[:3, 3], [0.0, 0.0, z], atol=1e-12, err_msg=link)
        np.testing.assert_allclose(T[:3, :3], np.eye(3), atol=1e-12, err_msg=link)
    assert pa10.frame_transform("link6", q0)[2, 3] == pytest.approx(1.317, abs=1e-12)


@pytest.mark.parametrize("q, flange", [
    ((0, np.pi / 2, 0, 0, 0, 0), (UPPER + FOREARM + WRIST, 0, SHOULDER)),          # arm horizontal, +x
    ((np.pi / 2, np.pi / 2, 0, 0, 0, 0), (0, UPPER + FOREARM + WRIST, SHOULDER)),  # swung to +y
    ((0, 0, np.pi / 2, 0, 0, 0), (FOREARM + WRIST, 0, SHOULDER + UPPER)),          # forearm horizontal
    ((0, 0, 0, 0, np.pi / 2, 0), (WRIST, 0, SHOULDER + UPPER + FOREARM)),          # wrist bent
    ((0, 0, 0, np.pi / 2, np.pi / 2, 0), (0, WRIST, SHOULDER + UPPER + FOREARM)),  # E2 turns the wrist
    ((0, -np.pi / 2, np.pi / 2, 0, 0, 0), (-UPPER, 0, SHOULDER + FOREARM + WRIST)),  # elbow out, forearm up
])
def test_pa10_flange_at_known_poses(pa10, q, flange):
    T = pa10.frame_transform("link6", np.array(q, float))
    np.testing.assert_allclose(T[:3, 3], flange, atol=1e-12)


def test_pa10_roll_joints_do_not_move_the_flange_origin_when_straight(pa10):
    q = np.zeros((5, 6))
    q[:, 3] = np.linspace(-4, 4, 5)
    q[:, 5] = np.linspace(4, -4, 5)
    T = pa10.frame_transform("link6", q)
    np.testing.assert_allclose(T[:, :3, 3], np.broadcast_to([0, 0, 1.317], (5, 3)), atol=1e-12)
    # ... but they turn it about z by q4 + q6
    angle = np.arctan2(T[:, 1, 0], T[:, 0, 0])
    np.testing.assert_allclose(np.cos(angle), np.cos(q[:, 3] + q[:, 5]), atol=1e-12)


def test_pa10_joint1_and_joint2_axes_intersect(pa10):
    """The calibration places the base from the intersection of the joint-1 and joint-2 axes."""
    for q in random_q(pa10, 10, seed=4):
        p, d = pa10.chain.joint_axis_lines(q)
        n = np.cross(d[0], d[1])
        assert np.linalg.norm(n) > 0.99  # perpendicular axes
        assert abs((p[1] - p[0]) @ n) / np.linalg.norm(n) < 1e-12
        # closest points of the two lines coincide at (0, 0, 0.317)
        A = np.stack([d[0], -d[1]], axis=1)
        s, t = np.linalg.lstsq(A, p[1] - p[0], rcond=None)[0]
        np.testing.assert_allclose(p[0] + s * d[0], [0, 0, SHOULDER], atol=1e-12)
        np.testing.assert_allclose(p[1] + t * d[1], [0, 0, SHOULDER], atol=1e-12)


def test_pa10_joint_axes_directions_at_zero(pa10):
    _, d = pa10.chain.joint_axis_lines(np.zeros(6))
    np.testing.assert_allclose(d, [[0, 0, 1], [0, 1, 0], [0, 1, 0], [0, 0, 1], [0, 1, 0], [0, 0, 1]],
                               atol=1e-15)


def test_perturbed_pa10_fk_equals_pinocchio(pa10, pa10_dir, tmp_path):
    dst = perturb_urdf(pa10_dir / "pa10.urdf", tmp_path / "pa10_perturbed.urdf", seed=5)
    robot = Robot.from_urdf(dst, pa10_dir / "drives.toml")
    assert robot.chain.joint_names == pa10.chain.joint_names
    Q = random_q(pa10, 30, seed=6)
    assert_fk_matches_pinocchio(robot, Q)
    # the perturbation is visible but small: a few mm at the flange
    diff = robot.frame_transform("link6", Q)[:, :3, 3] - pa10.frame_transform("link6", Q)[:, :3, 3]
    dist = np.linalg.norm(diff, axis=1)
    assert 1e-4 < dist.max() < 0.08


def test_tx40_fk_equals_pinocchio(real_dir, tmp_path):
    urdf = real_dir / "tx40" / "tx40_mdh_modified.urdf"
    if not urdf.is_file():
        pytest.skip(f"{urdf} is absent")
    robot = Robot.from_urdf(urdf)
    assert robot.n == 6
    assert "tool0" in robot.chain.frames  # frame on a fixed joint, merged by pinocchio
    Q = random_q(robot, 30, seed=7)
    assert_fk_matches_pinocchio(robot, Q)
    # and a perturbed copy of a third-party URDF (package:// meshes, fixed tool joint)
    perturbed = Robot.from_urdf(perturb_urdf(urdf, tmp_path / "tx40_p.urdf", seed=8))
    assert_fk_matches_pinocchio(perturbed, Q)


def test_urdf_rpy_convention_matches_pinocchio_and_round_trips():
    import pinocchio as pin

    from mocap.urdf import matrix_rpy, rpy_matrix

    rng = np.random.default_rng(9)
    for rpy in rng.uniform([-np.pi, -1.5, -np.pi], [np.pi, 1.5, np.pi], size=(20, 3)):
        R = rpy_matrix(rpy)
        np.testing.assert_allclose(R, pin.rpy.rpyToMatrix(*rpy), atol=1e-14)
        np.testing.assert_allclose(matrix_rpy(R), rpy, atol=1e-12)
