"""One definition per friction law (ident.friction.laws): the simulator and the fit models call
the same functions, so patching one law changes both; the two simulator paths agree at zero
speed."""
from __future__ import annotations

import numpy as np
import pytest

from ident.excitation.trajectories import fourier_excitation
from ident.friction import CoulombViscous, Stribeck, fit_friction, laws
from ident.friction.constants import SIGN_WIDTH
from ident.sim.effects import Effect, JointEffects
from ident.sim.plant import (Controller, JointPlant, JointState, regularised_friction,
                             simulate_multi, simulate_reference, simulate_single)

I5, A5, B5, J5, BM5 = 0.0041, 0.05, -0.65, 0.04, 0.15
C5, V5, TMAX5, VMAX5 = 3.90, 0.84, 14.5, 2.43


def _double_coulomb(monkeypatch):
    """Patch the Coulomb + viscous law so that its Coulomb term is twice as large."""
    orig = laws.coulomb_viscous
    monkeypatch.setattr(laws, "coulomb_viscous",
                        lambda qd, c, v, sign=np.sign: orig(qd, 2.0 * np.asarray(c), v, sign))


def _short_multi(pa10_dir):
    from mocap.robot import Robot

    robot = Robot.from_urdf(pa10_dir / "pa10.urdf", pa10_dir / "drives.toml")
    j = 4
    fxs = [Effect("none").joint_params(C5, V5, robot.max_torque[j], robot.max_velocity[j], 0.1)]
    refs = [fourier_excitation(np.random.default_rng(3), robot.max_velocity[j], 0.5, 0.2, 0.4, 0.6)]
    return lambda: simulate_multi(robot, [j], fxs, [robot.drives[j].motor_inertia],
                                  [robot.drives[j].motor_viscous], (0.0, 0.35, 1.3, 0.4, 0.4, 0.0),
                                  refs)["f"][:, 0]


def test_patching_coulomb_viscous_changes_simulator_and_fit_model(monkeypatch, pa10_dir):
    qd = np.linspace(-2.0, 2.0, 401)
    tau = C5 * np.sign(qd) + V5 * qd                 # written out here, independent of the law
    run_multi = _short_multi(pa10_dir)
    ctrl = Controller.tuned(I5, A5, B5, J5, BM5, C5, V5, 1e5)
    before = (CoulombViscous(c=C5, v=V5).torque(qd), fit_friction(CoulombViscous, qd, tau).params,
              run_multi(), ctrl.feedforward(np.zeros(3), np.array([-1.0, 0.0, 1.0]), np.zeros(3))[0])
    np.testing.assert_allclose(before[0], tau)
    assert before[1]["c"] == pytest.approx(C5) and before[1]["v"] == pytest.approx(V5)

    _double_coulomb(monkeypatch)
    after = (CoulombViscous(c=C5, v=V5).torque(qd), fit_friction(CoulombViscous, qd, tau).params,
             run_multi(), ctrl.feedforward(np.zeros(3), np.array([-1.0, 0.0, 1.0]), np.zeros(3))[0])
    # the model object's torque and the fit (its design columns are the law) both follow the law
    np.testing.assert_allclose(after[0] - before[0], C5 * np.sign(qd))
    assert after[1]["c"] == pytest.approx(C5 / 2.0) and after[1]["v"] == pytest.approx(V5)
    # the several-joint simulator's friction and the controller's feed-forward follow it too
    assert np.max(np.abs(after[2] - before[2])) > 0.5 * C5
    np.testing.assert_allclose(after[3] - before[3], [-C5, 0.0, C5])


def test_patching_stribeck_excess_changes_both_simulator_paths(monkeypatch):
    qd = np.array([-1.0, -0.05, 0.05, 1.0])
    fx = Effect("stribeck", 1.0).joint_params(C5, V5, TMAX5, VMAX5, I5 + J5)
    pl = JointPlant(I5, A5, B5, J5, BM5, fx)
    ctrl = Controller.tuned(I5, A5, B5, J5, BM5, C5, V5, 1e5)
    ref = fourier_excitation(np.random.default_rng(1), VMAX5, 1.0, 1.0, 0.6, 1.2)
    f_multi = regularised_friction(qd, fx.c_pos, fx.v, fx.S, fx.Vc, fx.w)[0]
    f_single = simulate_reference(pl, ctrl, ref, 0.0).f
    orig = laws.stribeck_excess
    monkeypatch.setattr(laws, "stribeck_excess", lambda a, S, Vc, exp=np.exp: orig(a, 3.0 * S, Vc, exp))
    f_multi2 = regularised_friction(qd, fx.c_pos, fx.v, fx.S, fx.Vc, fx.w)[0]
    f_single2 = simulate_reference(pl, ctrl, ref, 0.0).f
    ex = fx.S * np.exp(-np.abs(qd) / fx.Vc)
    np.testing.assert_allclose(f_multi2 - f_multi, 2.0 * ex * np.tanh(qd / SIGN_WIDTH))
    moving = np.abs(simulate_reference(pl, ctrl, ref, 0.0).qd) > 1e-6
    assert np.max(np.abs(f_single2 - f_single)[moving]) > 0.1 * fx.S


def test_simulator_paths_agree_at_and_near_zero_speed():
    # asymmetric Coulomb + Stribeck + nonlinear viscous
    fx = JointEffects(c_pos=4.0, c_neg=3.0, v=V5, S=1.2, Vc=0.5, w=0.1, k=1e5, d=10.0)
    # several-joint path: its one-sided limits at zero speed are the single path's stick band
    eps = 10 * SIGN_WIDTH
    F, dF = regularised_friction(np.array([-eps, 0.0, eps]), np.array([fx.c_neg, fx.c_pos, fx.c_pos]),
                                 fx.v, fx.S, fx.Vc, fx.w)
    band = (-(fx.c_neg + fx.S), fx.c_pos + fx.S)
    assert F[1] == 0.0 and np.all(dF >= 0)
    assert F[0] == pytest.approx(band[0], rel=0.02) and F[2] == pytest.approx(band[1], rel=0.02)
    # away from the regularisation both paths give the Stribeck model's torque (per direction)
    v = np.array([0.2, 0.7, 1.5])
    st = Stribeck(Fk=fx.c_pos + fx.S, Fv=fx.v, Fs=fx.S, Vc=fx.Vc)
    Fm = regularised_friction(v, fx.c_pos, fx.v, fx.S, fx.Vc, fx.w)[0]
    np.testing.assert_allclose(Fm, st.torque(v) + fx.w * v * v, rtol=1e-9)
    # single path, open loop without gravity: torques just inside the band hold the joint at
    # rest in both directions, just outside it they move it
    pl = JointPlant(I5, 0.0, 0.0, J5, BM5, fx)
    ctrl = Controller.tuned(I5, 0.0, 0.0, J5, BM5, 3.5, V5, 1e5)
    N = 1500
    z = np.zeros(N)
    for edge in band:
        held = simulate_single(pl, ctrl, z, z, z, True, JointState(), 0.0, 5e-4,
                               input_torque=np.full(N, 0.97 * edge))
        moved = simulate_single(pl, ctrl, z, z, z, True, JointState(), 0.0, 5e-4,
                                input_torque=np.full(N, 1.05 * edge))
        assert np.all(held.qd[-500:] == 0.0)
        assert np.sign(moved.qd[-1]) == np.sign(edge) and abs(moved.qd[-1]) > 1e-3


def test_law_columns_are_the_law_at_unit_parameters():
    qd = np.array([-2.0, -1e-3, 0.0, 1e-3, 2.0])
    X = laws.coulomb_viscous_columns(qd)
    np.testing.assert_array_equal(X, np.column_stack([np.sign(qd), qd]))
    np.testing.assert_allclose(X @ [1.5, 0.3], laws.coulomb_viscous(qd, 1.5, 0.3))
    St = laws.stribeck_columns(qd, 0.1)
    np.testing.assert_allclose(St[:, 2], -np.sign(qd) * (1 - np.exp(-np.abs(qd) / 0.1)))
    z1, dz = laws.lugre_implicit_step(0.0, 0.5, 1e-3, 1e4, 2.0)
    h = 1e-7
    z1h = laws.lugre_implicit_step(0.0, 0.5 + h, 1e-3, 1e4, 2.0)[0]
    assert z1 == pytest.approx(0.5e-3 / (1 + 1e-3 * 1e4 * 0.5 / 2.0))
    assert dz == pytest.approx((z1h - z1) / h, rel=1e-5)
