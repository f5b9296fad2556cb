"""Axis fits, base placement and the hand-eye peer on seeded synthetic sweeps (no file I/O)."""
from __future__ import annotations

import numpy as np
import pytest

from calib.axis import CircleAxisEstimator, ClusterAxisEstimator, fit_circle_bcls
from calib.base import place_base, pose_errors
from calib.geometry import chart_coords, chart_line
from mocap.kinematics import kabsch_batch, perp_basis, rotvec_to_matrix
from calib.handeye import HandEyeEstimator
from calib.pipeline import calibrate_sweeps, prepare_sweep
from mocap.io.errors import InputError
from mocap.kinematics import make_transform


@pytest.fixture(scope="module")
def pa10(pa10_dir):
    from mocap.robot import Robot

    return Robot.from_urdf(pa10_dir / "pa10.urdf", pa10_dir / "drives.toml")


def _sim(robot, seed, **kw):
    from calib._synthetic import simulate_sweeps

    kw.setdefault("duration_s", 6.0)
    return simulate_sweeps(robot, seed=seed, **kw)


def _true_axis(robot, sim, sweep):
    T = sim.T_camera_base
    p, d = robot.chain.joint_axis_lines(sim.q_rest)
    return T[:3, :3] @ p[sweep.joint - 1] + T[:3, 3], T[:3, :3] @ d[sweep.joint - 1]


def _moving(sim, sweep):
    keep = [lb for lb in sweep.markers.labels if sweep.joint == 1 or lb.startswith("L2")]
    return sweep.markers.select(keep)


def _axis_errors(fit, p_true, n_true):
    """Chart coordinates of the true axis in the fit's chart (the estimation error)."""
    return chart_coords(p_true, n_true, fit.point, fit.direction, *fit.basis)


# ---- geometry kernels ---------------------------------------------------------------------
def test_chart_roundtrip_and_kabsch():
    rng = np.random.default_rng(0)
    p0, n0 = rng.normal(size=3), rng.normal(size=3)
    n0 /= np.linalg.norm(n0)
    u, v = perp_basis(n0)
    phi = np.array([0.01, -0.02, 0.003, 0.004])
    q, m = chart_line(phi, p0, n0, u, v)
    np.testing.assert_allclose(chart_coords(q + 0.7 * m, -m, p0, n0, u, v), phi, atol=1e-12)
    R = rotvec_to_matrix(rng.normal(size=(5, 3)))
    t = rng.normal(size=(5, 3))
    ref = rng.normal(size=(6, 3))
    obs = np.einsum("tij,mj->tmi", R, ref) + t[:, None]
    w = np.ones((5, 6))
    w[0, :4] = 0.0  # frame 0 keeps 2 markers: undefined
    obs[0, :4] = np.nan
    R2, t2 = kabsch_batch(ref, obs, w)
    assert np.all(np.isnan(R2[0]))
    np.testing.assert_allclose(R2[1:], R[1:], atol=1e-12)
    np.testing.assert_allclose(t2[1:], t[1:], atol=1e-12)


def test_bcls_removes_the_centre_bias():
    """Halvorsen's compensation: on a 120 deg arc of radius 0.1 m with 3 mm noise the plain
    algebraic centre is biased outward by ~3 mm; the compensated one by < 0.4 mm."""
    rng = np.random.default_rng(1)
    r, sig = 0.1, 0.003
    c_bcls, c_plain = [], []
    for _ in range(120):
        th = rng.uniform(-np.pi / 3, np.pi / 3, 200)
        P = np.stack([r * np.cos(th), r * np.sin(th), np.zeros_like(th)], 1) + sig * rng.standard_normal((200, 3))
        c_bcls.append(fit_circle_bcls(P)[0])
        c_plain.append(fit_circle_bcls(P, sigma2=0.0)[0])
    assert abs(np.mean(c_bcls, axis=0)[0]) < 4e-4
    assert np.mean(c_plain, axis=0)[0] > 2e-3


# ---- axis estimators ----------------------------------------------------------------------
@pytest.mark.parametrize("est", [ClusterAxisEstimator(), CircleAxisEstimator()], ids=["cluster", "circle"])
def test_axis_fit_matches_truth_within_its_covariance(pa10, est):
    sim = _sim(pa10, seed=11)
    for sw in sim.sweeps:
        rec = _moving(sim, sw)
        fit = est.fit(rec.positions, rec.labels)
        e = _axis_errors(fit, *_true_axis(pa10, sim, sw))
        chi2 = e @ np.linalg.solve(fit.cov, e)
        assert chi2 < 25.0, (sw.joint, e, chi2)        # 4 dof: P(chi2 > 25) ~ 5e-5
        assert np.degrees(np.hypot(e[0], e[1])) < 0.02
        assert 1e3 * np.hypot(e[2], e[3]) < 0.1
        assert 0.75 < fit.sigma_mm / 0.85 < 1.25       # recovers the simulated noise
        assert fit.converged
        # the covariance is of the order of the bound (cluster: the ML of the same model)
        ratio = np.sqrt(np.trace(fit.cov[2:, 2:]) / np.trace(fit.crb[2:, 2:]))
        assert 0.8 < ratio < (1.2 if est.method == "cluster" else 1.8), ratio
        assert fit.sweep_deg == pytest.approx(120.0, abs=2.0)


def test_cluster_is_robust_to_outliers_and_gaps(pa10):
    sim = _sim(pa10, seed=5, outlier_fraction=0.01, gap_fraction=0.2)
    sw = sim.sweeps[1]
    rec = _moving(sim, sw)
    p_true, n_true = _true_axis(pa10, sim, sw)
    robust = ClusterAxisEstimator().fit(rec.positions, rec.labels)
    plain = ClusterAxisEstimator(robust=False, marker_weights=False).fit(rec.positions, rec.labels)
    e_r = _axis_errors(robust, p_true, n_true)
    e_p = _axis_errors(plain, p_true, n_true)
    assert robust.n_outliers > 0
    assert 1e3 * np.hypot(e_r[2], e_r[3]) < 0.15 and np.degrees(np.hypot(e_r[0], e_r[1])) < 0.03
    assert np.linalg.norm(e_r) < np.linalg.norm(e_p)


def test_axis_fit_refuses_too_few_markers(pa10):
    sim = _sim(pa10, seed=2)
    rec = _moving(sim, sim.sweeps[1])
    with pytest.raises(InputError, match="only 2 markers"):
        ClusterAxisEstimator().fit(rec.positions[:, :2], rec.labels[:2])


# ---- base placement -----------------------------------------------------------------------
@pytest.mark.parametrize("offset", [0.0, 0.05])
def test_place_base_exact_lines(offset):
    """Noise-free axes, intersecting (PA10) or offset by 5 cm: the transform is exact."""
    from calib.axis import AxisFit

    rng = np.random.default_rng(3)
    T = make_transform(rotvec_to_matrix(rng.normal(size=3)), rng.normal(size=3))
    urdf = [(np.array([0.0, 0.0, 0.2]), np.array([0.0, 0.0, 1.0])),
            (np.array([offset, 0.0, 0.317]), np.array([0.0, 1.0, 0.0]))]
    fits = []
    for j, (b, m) in enumerate(urdf, 1):
        n = T[:3, :3] @ m
        fits.append(AxisFit(point=T[:3, :3] @ b + T[:3, 3] + 0.3 * n, direction=n, basis=perp_basis(n),
                            cov=np.diag([1e-8, 1e-8, 1e-10, 1e-10]), crb=np.diag([1e-8, 1e-8, 1e-10, 1e-10]),
                            rms_mm=0.0, sigma_mm=0.0, marker_rms_mm={}, marker_radius_m={}, sweep_deg=120.0,
                            n_frames=1, n_observations=1, n_outliers=0, iterations=1, converged=True,
                            cond=1.0, method="test", joint=j))
    base = place_base(fits, urdf)
    dp, dr = pose_errors(base.T_camera_base, T)
    assert dp < 1e-6 and dr < 1e-6
    assert base.axis_distance_mm == pytest.approx(1e3 * offset, abs=1e-6)
    with pytest.raises(InputError, match="parallel"):
        place_base(fits, [urdf[0], (urdf[1][0], np.array([0.0, 0.0, 1.0]))])


def test_calibrate_sweeps_beats_goals_and_handeye(pa10):
    sim = _sim(pa10, seed=7)
    sweeps = [prepare_sweep(sw.joint, sw.markers, sw.log, pa10.chain, sim.markers) for sw in sim.sweeps]
    res = calibrate_sweeps(sweeps, pa10.chain, "cluster")
    dp, dr = pose_errors(res.T_camera_base, sim.T_camera_base)
    assert dp < 0.5 and dr < 0.05
    assert dp < 4.0 * res.base.crb_origin_mm          # one draw: 4x the 3-D RMS bound
    assert 0.8 < res.origin_std_mm / res.base.crb_origin_mm < 1.25
    P = np.concatenate([s.positions[:, [s.labels.index(lb) for lb in sim.markers["link2"]]] for s in sweeps])
    Q = np.concatenate([s.q_frames for s in sweeps])
    he = HandEyeEstimator().fit(pa10.chain, "link2", P, Q, sim.markers["link2"])
    dp_he, dr_he = pose_errors(he.T_camera_base, sim.T_camera_base)
    assert dp_he < 0.5 and dr_he < 0.05
    assert he.rms_mm == pytest.approx(0.85, rel=0.15)
    for lb in sim.markers["link2"]:
        np.testing.assert_allclose(he.p_link[lb], sim.p_link[lb], atol=5e-4)
    # min_markers: frames sharing fewer markers with the reference frame stay out of the
    # initialisation; asking more markers than the link carries leaves no frame
    n_link = len(sim.markers["link2"])
    he4 = HandEyeEstimator(min_markers=n_link).fit(pa10.chain, "link2", P, Q, sim.markers["link2"])
    assert pose_errors(he4.T_camera_base, sim.T_camera_base)[0] < 0.5
    with pytest.raises(InputError, match="share"):
        HandEyeEstimator(min_markers=n_link + 1).fit(pa10.chain, "link2", P, Q, sim.markers["link2"])
    with pytest.raises(InputError, match=">= 3"):
        HandEyeEstimator(min_markers=2)


def test_perturbed_robot_offset_axes(pa10_dir, tmp_path):
    """A perturbed robot (axes 1 and 2 no longer intersect), known to the calibration."""
    from mocap.robot import Robot
    from mocap.urdf import perturb_urdf

    urdf = perturb_urdf(pa10_dir / "pa10.urdf", tmp_path / "p.urdf", seed=4, length_std=0.01, angle_std_deg=1.0)
    robot = Robot.from_urdf(urdf, pa10_dir / "drives.toml")
    sim = _sim(robot, seed=8)
    sweeps = [prepare_sweep(sw.joint, sw.markers, sw.log, robot.chain, sim.markers) for sw in sim.sweeps]
    for method in ("cluster", "circle"):
        res = calibrate_sweeps(sweeps, robot.chain, method)
        dp, dr = pose_errors(res.T_camera_base, sim.T_camera_base)
        assert res.base.urdf_axis_distance_mm > 1.0
        assert res.base.axis_distance_mm == pytest.approx(res.base.urdf_axis_distance_mm, abs=0.2)
        assert dp < 0.5 and dr < 0.05, (method, dp, dr)
