"""The batched per-frame solve (thesis eq. 3-5) against seeded synthetic truth."""
from __future__ import annotations

import numpy as np
import pytest

from mocap._synthetic import (default_camera_pose, excitation, pa10_robot, place_markers,
                              simulate_markers)
from mocap.kinematics import apply_transform, invert_transform
from mocap.quality import angle_errors, cramer_rao_bound, rms_bound
from mocap.solve import FLAG_NO_GUESS, FLAG_SWAP_REPAIRED, FLAG_TOO_FEW_MARKERS, MarkerSolver

NOISE = 0.85e-3  # 3-D RMS, m
Q_REST = np.array([0.2, 0.4, 0.9, 0.1, 0.6, 0.0])


@pytest.fixture(scope="module")
def robot(tmp_path_factory):
    return pa10_robot(tmp_path_factory.mktemp("arm"))


def _problem(robot, joints, counts, T=3000, seed=0, **noise):
    mk = place_markers(robot, counts, seed=seed + 1)
    t = np.arange(T) / 100.0
    q = excitation(t, robot.n, joints, Q_REST, seed=seed + 2)
    T_cb = default_camera_pose(seed)
    sim = simulate_markers(robot, q, mk, T_cb, seed=seed + 3, **noise)
    p_base = apply_transform(invert_transform(T_cb), sim.p_camera)
    mj, pj = [], []
    for lb in sim.labels:
        link, p = mk[lb]
        j, T_jf = robot.chain.frames[link]
        mj.append(j)
        pj.append(apply_transform(T_jf, p))
    rng = np.random.default_rng(seed + 4)
    q_guess = q + rng.normal(0, 3e-3, q.shape) * np.isin(np.arange(robot.n), joints)  # motor != link
    return q, p_base, np.array(mj), np.array(pj), q_guess, sim


def test_forward_kinematics_matches_pinocchio(robot):
    """The one FK (numpy, batched) against pinocchio's own joint placements."""
    import pinocchio as pin

    q = np.random.default_rng(0).uniform(-2, 2, (40, robot.n))
    R, o = robot.chain.joint_frames(q)
    Tj = robot.chain.joint_transforms(q)
    data = robot.model.createData()
    for t in range(0, 40, 7):  # a few frames: pinocchio is the independent reference
        pin.forwardKinematics(robot.model, data, q[t])
        for i in range(robot.n):
            assert np.allclose(R[t, i], data.oMi[i + 1].rotation, atol=1e-12)
            assert np.allclose(o[t, i], data.oMi[i + 1].translation, atol=1e-12)
    assert np.allclose(Tj[..., :3, :3], R, atol=1e-14) and np.allclose(Tj[..., :3, 3], o, atol=1e-14)


@pytest.mark.parametrize("joints,counts", [((1,), {"link2": 4}),
                                           ((4,), {"link5": 3, "link6": 3}),
                                           ((0, 1, 2, 3, 4, 5), {"link2": 3, "link3": 3, "link4": 3,
                                                                 "link5": 3, "link6": 4})])
def test_noise_free_exact(robot, joints, counts):
    q, p_base, mj, pj, q_guess, _ = _problem(robot, joints, counts, T=300, noise_rms_m=0.0)
    res = MarkerSolver(robot.chain, joints, mj, pj).fit(p_base, q_guess)
    assert res.valid.all()
    assert np.abs(res.q - q).max() < 1e-8


@pytest.mark.parametrize("joints,counts", [((1,), {"link2": 4}),
                                           ((2, 4), {"link3": 3, "link4": 3, "link5": 4}),
                                           ((0, 1, 2, 3, 4, 5), {"link2": 3, "link3": 3, "link4": 3,
                                                                 "link5": 3, "link6": 4})])
def test_efficient_within_cramer_rao(robot, joints, counts):
    """RMSE within 10 % of the Cramer-Rao bound of the geometry (3000 frames: the sampling
    error of an RMSE is ~1.3 %, so 1.10 is a 7-sigma margin and a biased solver fails)."""
    q, p_base, mj, pj, q_guess, _ = _problem(robot, joints, counts)
    res = MarkerSolver(robot.chain, joints, mj, pj).fit(p_base, q_guess)
    err = angle_errors(res.q[:, list(joints)], q[:, list(joints)])
    bound = rms_bound(cramer_rao_bound(robot.chain, joints, mj, pj, q, NOISE / np.sqrt(3)))
    assert err["frames"] == q.shape[0]
    ratio = err["rmse_rad"] / bound
    assert np.all(ratio < 1.10), ratio
    assert np.all(ratio > 0.90), ratio  # a bound that is too loose would hide a bug
    # the pooled noise estimate recovers the simulated per-axis sigma
    assert res.sigma_m == pytest.approx(NOISE / np.sqrt(3), rel=0.03)
    # reported standard errors agree with the bound
    assert np.allclose(np.sqrt(np.mean(res.stderr ** 2, axis=0)), bound, rtol=0.05)


def test_closed_form_equals_levenberg_marquardt(robot):
    q, p_base, mj, pj, q_guess, _ = _problem(robot, (2,), {"link3": 3, "link5": 3}, T=500)
    a = MarkerSolver(robot.chain, (2,), mj, pj).fit(p_base, q_guess)
    b = MarkerSolver(robot.chain, (2,), mj, pj, closed_form=False).fit(p_base, q_guess)
    assert a.method == "closed_form_1d" and b.method == "levenberg_marquardt"
    assert np.abs(a.q - b.q).max() < 1e-7


@pytest.mark.parametrize("joints,counts", [((1,), {"link2": 4, "link3": 3}),
                                           ((0, 1, 2, 3, 4, 5), {"link2": 3, "link3": 3, "link4": 3,
                                                                 "link5": 3, "link6": 4})])
def test_missing_and_outliers_within_twice_clean(robot, joints, counts):
    q, p_base, mj, pj, q_guess, _ = _problem(robot, joints, counts, T=2000)
    clean = MarkerSolver(robot.chain, joints, mj, pj).fit(p_base, q_guess)
    e_clean = angle_errors(clean.q[:, list(joints)], q[:, list(joints)])["rmse_rad"]
    q, p_base, mj, pj, q_guess, sim = _problem(robot, joints, counts, T=2000, missing_frac=0.3,
                                               outlier_frac=0.01)
    res = MarkerSolver(robot.chain, joints, mj, pj).fit(p_base, q_guess)
    e = angle_errors(res.q[:, list(joints)], q[:, list(joints)])
    assert np.all(e["rmse_rad"] < 2.0 * e_clean), (e["rmse_rad"], e_clean)
    assert e["frames"] > 0.85 * q.shape[0]
    # every injected outlier (of a used marker, in a valid frame) was rejected
    used = sim.outlier & res.valid[:, None] & np.isfinite(res.residual_m)
    big = used & (np.linalg.norm(sim.p_camera - sim.p_camera_true, axis=2) > 0.01)
    assert big.sum() > 5
    assert not (res.inlier & big).any()


def test_label_swaps_repaired(robot):
    joints, counts = (1,), {"link2": 4, "link3": 4}
    q, p_base, mj, pj, q_guess, sim = _problem(robot, joints, counts, T=2000, swap_frac=0.02)
    res = MarkerSolver(robot.chain, joints, mj, pj).fit(p_base, q_guess)
    swapped_frames = np.flatnonzero(sim.swapped.any(axis=1))
    assert swapped_frames.size > 20
    repaired = {t for t, _, _ in res.swaps}
    assert len(repaired & set(swapped_frames.tolist())) >= 0.9 * swapped_frames.size
    assert not (repaired - set(swapped_frames.tolist()))  # no false repairs
    assert np.all(res.flags[list(repaired)] & FLAG_SWAP_REPAIRED)
    err = np.abs(res.q[swapped_frames, 1] - q[swapped_frames, 1])
    assert err.max() < 0.01
    off = MarkerSolver(robot.chain, joints, mj, pj, detect_swaps=False).fit(p_base, q_guess)
    assert not off.swaps


def test_too_few_markers_and_no_guess_are_nan_and_flagged(robot):
    joints, counts = (1, 2), {"link2": 3, "link3": 3}
    q, p_base, mj, pj, q_guess, sim = _problem(robot, joints, counts, T=200)
    p_base = p_base.copy()
    link3 = np.flatnonzero(mj == 2)
    p_base[10:20][:, link3[:2]] = np.nan   # one marker left distal to joint 3
    q_guess = q_guess.copy()
    q_guess[30:35, 1] = np.nan             # no motor angle (outside the log)
    res = MarkerSolver(robot.chain, joints, mj, pj).fit(p_base, q_guess)
    assert np.all(res.flags[10:20] & FLAG_TOO_FEW_MARKERS)
    assert np.isnan(res.q[10:20][:, [1, 2]]).all()
    assert np.all(res.flags[30:35] & FLAG_NO_GUESS)
    assert np.isnan(res.q[30:35][:, [1, 2]]).all()
    ok = np.ones(200, bool)
    ok[10:20] = ok[30:35] = False
    assert res.valid[ok].all()
    assert np.abs(res.q[ok][:, [1, 2]] - q[ok][:, [1, 2]]).max() < 0.02
    d = res.to_dict()
    assert d["flagged_frames"] == 15 and d["flag_counts"]["too_few_markers"] == 10


def test_bad_arguments(robot):
    with pytest.raises(ValueError, match="joints"):
        MarkerSolver(robot.chain, (7,), [1], [[0, 0, 0]])
    s = MarkerSolver(robot.chain, (1,), [1, 1], [[0.1, 0, 0.1], [0, 0.1, 0.2]])
    with pytest.raises(ValueError, match="p_base"):
        s.fit(np.zeros((5, 3, 3)), np.zeros((5, 6)))


def test_refinement_recovers_marker_positions(robot):
    """References from a short, noisy static pose (5 frames) are biased; re-estimating the marker
    positions over the trial frames, anchored by the static pose, brings them and the angles back
    towards the truth."""
    from mocap.solve import refine_markers

    joints, counts = (1, 2), {"link2": 4, "link3": 4}
    q, p_base, mj, pj, q_guess, sim = _problem(robot, joints, counts, T=3000)
    rng = np.random.default_rng(9)
    sig = NOISE / np.sqrt(3)
    # the static pose: 5 frames at a known pose -> reference error ~ sigma / sqrt(5) per axis
    q_s = Q_REST.copy()
    Rs, os_ = robot.chain.joint_frames(q_s[None])
    p_s_true = os_[0, mj] + np.einsum("mij,mj->mi", Rs[0, mj], pj)
    p_s = p_s_true + rng.normal(0, sig / np.sqrt(5), p_s_true.shape)
    pj_bad = np.einsum("mji,mj->mi", Rs[0, mj], p_s - os_[0, mj])
    before = MarkerSolver(robot.chain, joints, mj, pj_bad).fit(p_base, q_guess)
    ref = refine_markers(robot.chain, joints, mj, pj_bad, p_base, q_guess,
                         static=[(q_s, p_s, np.full(len(mj), 5.0))])
    err_before = np.linalg.norm(pj_bad - pj, axis=1)
    err_after = np.linalg.norm(ref.p_joint - pj, axis=1)
    assert err_after.mean() < 0.5 * err_before.mean()
    e0 = angle_errors(before.q[:, list(joints)], q[:, list(joints)])["rmse_rad"]
    e1 = angle_errors(ref.solve.q[:, list(joints)], q[:, list(joints)])["rmse_rad"]
    assert np.all(e1 <= e0 * 1.001)
    assert ref.rms_history_m[-1] < ref.rms_history_m[0]


def test_bundled_pa10(pa10_dir):
    """The solver on the bundled PA10 description (joint 5 with markers on links 5 and 6)."""
    from mocap.robot import Robot

    robot = Robot.from_urdf(pa10_dir / "pa10.urdf", pa10_dir / "drives.toml")
    joints, counts = (4,), {"link5": 3, "link6": 3}
    q, p_base, mj, pj, q_guess, _ = _problem(robot, joints, counts, T=1000)
    res = MarkerSolver(robot.chain, joints, mj, pj).fit(p_base, q_guess)
    err = angle_errors(res.q[:, [4]], q[:, [4]])["rmse_rad"]
    bound = rms_bound(cramer_rao_bound(robot.chain, joints, mj, pj, q, NOISE / np.sqrt(3)))
    assert err[0] < 1.15 * bound[0]


def test_refinement_recovers_joint_placement_offsets(robot):
    """The arm's joint 2 axis is tilted by (0.5, -0.3) deg and shifted by (2, -1) mm against the
    URDF. Static references with the nominal model then give angle errors far above the noise;
    the joint fit of placement offsets and marker positions recovers the offsets and brings the
    angle RMSE to that of a solve with the true geometry."""
    from mocap.solve import _static_model, offset_chain, refine_markers

    ch = robot.chain
    joints = (1,)
    true_off = np.array([[np.radians(0.5), np.radians(-0.3), 2e-3, -1e-3]])
    ch_true = offset_chain(ch, joints, true_off)
    mk = place_markers(robot, {"link2": 4, "link3": 4}, seed=1)
    labels = list(mk)
    mj = np.array([ch.frames[mk[lb][0]][0] for lb in labels])
    pj = np.array([apply_transform(ch.frames[mk[lb][0]][1], mk[lb][1]) for lb in labels])
    t = np.arange(1500) / 100.0
    q = excitation(t, 6, joints, Q_REST, seed=2, amplitude=1.2)
    rng = np.random.default_rng(0)
    sig = NOISE / np.sqrt(3)
    R, o = ch_true.joint_frames(q)
    Y = o[:, mj] + np.einsum("tmij,mj->tmi", R[:, mj], pj) + rng.normal(0, sig, (q.shape[0], len(mj), 3))
    p_s = _static_model(ch_true, mj, pj, Q_REST) + rng.normal(0, sig / np.sqrt(200), (len(mj), 3))
    Rs, os_ = ch.joint_frames(Q_REST[None])
    pj_nominal = np.einsum("mji,mj->mi", Rs[0, mj], p_s - os_[0, mj])  # eq. 3-4, nominal URDF
    qg = q + rng.normal(0, 2e-3, q.shape) * np.isin(np.arange(6), joints)
    e_nom = angle_errors(MarkerSolver(ch, joints, mj, pj_nominal).fit(Y, qg).q[:, [1]], q[:, [1]])
    e_true = angle_errors(MarkerSolver(ch_true, joints, mj, pj).fit(Y, qg).q[:, [1]], q[:, [1]])
    rr = refine_markers(ch, joints, mj, pj_nominal, Y, qg, static=[(Q_REST, p_s, np.full(len(mj), 200.0))],
                        geometry=True, iterations=1, max_frames=800)
    e_ref = angle_errors(rr.solve.q[:, [1]], q[:, [1]])
    assert e_nom["rmse_rad"][0] > 3 * e_true["rmse_rad"][0]
    assert e_ref["rmse_rad"][0] < 1.1 * e_true["rmse_rad"][0]
    assert np.allclose(np.degrees(rr.offsets[0, :2]), [0.5, -0.3], atol=0.03)
    assert np.allclose(1e3 * rr.offsets[0, 2:], [2.0, -1.0], atol=0.3)
    assert "joint_offsets" in rr.to_dict()


@pytest.mark.parametrize("joints,shuffle", [((0, 1, 2, 3, 4, 5), False), ((1, 3, 4), False),
                                            ((1, 3, 4), True)])
def test_normal_equations_match_a_finite_difference_jacobian(robot, joints, shuffle):
    """The chain solve's J^T W J and J^T W r (per-joint marker sums, frames last) against the
    Jacobian of the model markers by central differences, with random weights, residuals and a
    marker left out; (1, 3, 4) also has a held prefix, a held joint inside and one beyond; the
    shuffled markers (no contiguous run per link) take the sums' other path."""
    from mocap.solve import _Chain, _symmetrise_lower

    counts = {"link2": 3, "link3": 3, "link4": 3, "link5": 3, "link6": 4}
    q, p_base, mj, pj, q_guess, _ = _problem(robot, joints, counts, T=40)
    if shuffle:
        perm = np.random.default_rng(2).permutation(mj.size)
        mj, pj = mj[perm], pj[perm]
    solver = MarkerSolver(robot.chain, joints, mj, pj)
    ch = _Chain(solver, q_guess)
    assert (ch.runs is None) == shuffle
    idx = np.arange(q.shape[0])
    qs = q_guess[:, list(solver.joints)]
    P, X = ch._eval(qs.T, idx, True)                      # (3, M, T), (6, S, T)
    np.testing.assert_allclose(np.transpose(P, (2, 1, 0)), ch.predict(qs), rtol=0, atol=1e-15)
    rng = np.random.default_rng(5)
    r = rng.normal(size=P.shape)
    w = rng.uniform(0.0, 2.0, P.shape[1:])
    w[4] = 0.0
    H, g = ch._normal(P, X, r, w)
    H = np.moveaxis(_symmetrise_lower(H), 2, 0)
    g = g.T
    assert np.array_equal(ch._normal(P, X, r, w, hess=False)[1].T, g)
    S, eps = len(solver.joints), 1e-6
    J = np.empty((q.shape[0],) + P.shape[1::-1] + (S,))   # (T, M, 3, S)
    for k in range(S):
        d = np.zeros(S)
        d[k] = eps
        J[..., k] = (ch.predict(qs + d) - ch.predict(qs - d)) / (2 * eps)
    Jf = J.reshape(q.shape[0], -1, S)
    W = np.repeat(w.T, 3, axis=1)
    rt = np.transpose(r, (2, 1, 0)).reshape(q.shape[0], -1)
    H_ref = np.einsum("tmk,tm,tml->tkl", Jf, W, Jf)
    g_ref = np.einsum("tmk,tm,tm->tk", Jf, W, rt)
    np.testing.assert_allclose(H, H_ref, rtol=1e-6, atol=1e-8 * np.abs(H_ref).max())
    np.testing.assert_allclose(g, g_ref, rtol=1e-6, atol=1e-8 * np.abs(g_ref).max())


def test_batched_cholesky_solves_and_inverts():
    """The Cholesky factorisation vectorised over frames (frames last) against numpy's LAPACK
    solve and inverse on random symmetric positive-definite 1..6 x 6 systems; a matrix that is
    not positive definite gives NaN (its step is rejected), not a wrong number."""
    from mocap.solve import _cholesky, _cholesky_solve, _spd_inverse

    rng = np.random.default_rng(3)
    for S in range(1, 7):
        A = rng.normal(size=(50, S, S))
        H = A @ np.swapaxes(A, 1, 2) + 0.1 * np.eye(S)
        b = rng.normal(size=(50, S))
        L = _cholesky(np.moveaxis(H, 0, 2).copy())
        x = _cholesky_solve(L, b.T).T
        np.testing.assert_allclose(x, np.linalg.solve(H, b[..., None])[..., 0], rtol=1e-9, atol=1e-9)
        np.testing.assert_allclose(_spd_inverse(H), np.linalg.inv(H), rtol=1e-9, atol=1e-9)
    H[0] = -np.eye(S)
    assert not np.isfinite(_spd_inverse(H)[0]).any() and np.isfinite(_spd_inverse(H)[1:]).all()


def test_stops_at_the_noise_level_after_two_full_iterations(robot):
    """Issue 47: from a motor angle 3 mrad off, two Levenberg-Marquardt iterations with a new
    J^T J reach the minimiser; the third step (below tol) is taken with the second iteration's
    factor instead of a third J^T J. The angles equal a solve iterated to 1e-13 rad (tol) to
    1e-8 rad, 1e5 times below the noise."""
    from mocap.solve import _Chain

    joints = (0, 1, 2, 3, 4, 5)
    counts = {"link2": 3, "link3": 3, "link4": 3, "link5": 3, "link6": 4}
    q, p_base, mj, pj, q_guess, _ = _problem(robot, joints, counts, T=600)
    vis = np.ones(p_base.shape[:2], bool)
    qs0 = q_guess[:, list(joints)]
    fast = _Chain(MarkerSolver(robot.chain, joints, mj, pj), q_guess)
    qs, its = fast.solve(qs0, p_base, vis, loss="linear", scale=1.0, max_iter=30)
    assert its == 2 and fast.converged.all()
    tight = _Chain(MarkerSolver(robot.chain, joints, mj, pj, tol=1e-13), q_guess)
    qt, its_t = tight.solve(qs0, p_base, vis, loss="linear", scale=1.0, max_iter=30)
    assert its_t >= 3
    assert np.abs(qs - qt).max() < 1e-8
    assert np.abs(qs - qs0).max() > 1e-3  # it did move
