"""Each withheld effect (ident.sim.effects) shows its signature in the channel it lives in, scales
linearly with the magnitude, and is detectable above the torque noise at M = 0.3."""
from __future__ import annotations

import math

import numpy as np
import pytest

from ident.sim.effects import EFFECTS, Effect, K_NOMINAL, SIZE, truth_models
from ident.excitation.trajectories import reversals
from ident.sim.plant import Controller, JointPlant, simulate_reference

from test_sim import C5, TMAX5, V5, VMAX5, ctrl5, excitation, plant5, rigid_residual

NOISE = 0.08        # N m, torque noise of a PA10 wrist joint in the synthetic logs
ENC = math.radians(0.011)


def fit(r, *cols, seed=0):
    """Least squares of the residual (plus seeded torque noise) on ``cols``: (coef, stderr)."""
    rng = np.random.default_rng(seed)
    y = r + rng.normal(0.0, NOISE, r.shape)
    X = np.column_stack(cols)
    coef, *_ = np.linalg.lstsq(X, y, rcond=None)
    s2 = np.sum((y - X @ coef) ** 2) / max(y.size - X.shape[1], 1)
    cov = s2 * np.linalg.inv(X.T @ X)
    return coef, np.sqrt(np.diag(cov))


def run(effect, M, ref=None, t0=0.0, **kw):
    pl = plant5(effect, M, **kw)
    res = simulate_reference(pl, ctrl5(), ref or excitation(4), t0)
    keep = slice(None, None, 10)   # 200 Hz, like the logs
    return pl, res, rigid_residual(pl, res)[keep], keep


def test_vocabulary_and_linear_sizes():
    assert set(EFFECTS) == {"none", "stribeck", "presliding", "position_ripple", "load_dependent",
                            "thermal_drift", "compliance", "backlash", "torque_scale", "asymmetry",
                            "nonlinear_viscous", "time_offset"}
    for name in EFFECTS:
        p1 = Effect(name, 1.0).joint_params(C5, V5, TMAX5, VMAX5, 0.05)
        p2 = Effect(name, 0.5).joint_params(C5, V5, TMAX5, VMAX5, 0.05)
        assert p1.c_pos + p1.c_neg == pytest.approx(2 * C5)     # the mean Coulomb level is kept
        # the defining size halves with M
        pairs = {"stribeck": lambda p: p.S, "position_ripple": lambda p: p.ripple_A,
                 "load_dependent": lambda p: p.mu, "thermal_drift": lambda p: p.thermal_h,
                 "compliance": lambda p: 1 / p.k - 1 / K_NOMINAL, "backlash": lambda p: p.beta,
                 "torque_scale": lambda p: p.torque_gain - 1, "asymmetry": lambda p: p.c_pos - C5,
                 "nonlinear_viscous": lambda p: p.w, "time_offset": lambda p: p.time_offset,
                 "presliding": lambda p: C5 / p.sigma0}
        if name in pairs:
            a, b = pairs[name](p1), pairs[name](p2)
            assert a > 0 and b == pytest.approx(0.5 * a, rel=1e-9), name
    with pytest.raises(ValueError):
        Effect("bogus", 1.0)
    with pytest.raises(ValueError):
        Effect("stribeck", -1.0)
    tm = truth_models(Effect("stribeck", 1.0).joint_params(C5, V5, TMAX5, VMAX5, 0.05))
    assert tm["stribeck"]["Fk"] - tm["stribeck"]["Fs"] == pytest.approx(C5)


def test_nominal_has_no_signature():
    _, res, r, keep = run("none", 0.0)
    moving = np.abs(res.qd[keep]) > 0.02
    assert np.sqrt(np.mean(r[moving] ** 2)) < 0.25 * NOISE


@pytest.mark.parametrize("M", [0.3, 1.0])
def test_stribeck(M):
    pl, res, r, keep = run("stribeck", M)
    qd = res.qd[keep]
    m = qd != 0
    coef, se = fit(r[m], np.sign(qd[m]) * np.exp(-np.abs(qd[m]) / pl.fx.Vc))
    S = M * SIZE["stribeck"]["static_ratio"] * C5
    # stick-slip at breakaway (static level c + S, then the drop) adds rigid-model error near
    # zero speed, so the residual fit is looser than the true friction (exact in test_sim)
    assert coef[0] == pytest.approx(S, rel=0.3)
    assert coef[0] > 5 * se[0]


@pytest.mark.parametrize("M", [0.3, 1.0])
def test_position_ripple(M):
    pl, res, r, keep = run("position_ripple", M)
    q = res.q[keep]
    fx = pl.fx
    coef, se = fit(r, np.sin(fx.ripple_n * q + fx.ripple_phi), np.cos(fx.ripple_n * q + fx.ripple_phi))
    assert coef[0] == pytest.approx(fx.ripple_A, rel=0.1) and abs(coef[1]) < 0.35 * fx.ripple_A
    assert coef[0] > 5 * se[0]
    assert fx.ripple_A == pytest.approx(M * 0.10 * C5)


@pytest.mark.parametrize("M", [0.3, 1.0])
def test_load_dependent(M):
    # the wrist carrying the 3.4 kg payload: gravity torque of a few N m
    fx = Effect("load_dependent", M).joint_params(C5, V5, TMAX5, VMAX5, 0.044)
    pl = JointPlant(0.05, 0.4, -4.0, 0.04, 0.15, fx)
    ctrl = Controller.tuned(0.05, 0.4, -4.0, 0.04, 0.15, C5, V5, K_NOMINAL)
    res = simulate_reference(pl, ctrl, excitation(4), 0.0)
    keep = slice(None, None, 10)
    r = rigid_residual(pl, res)[keep]
    qd, q = res.qd[keep], res.q[keep]
    g = np.abs(0.4 * np.sin(q) - 4.0 * np.cos(q))
    m = qd != 0
    coef, se = fit(r[m], np.sign(qd[m]) * g[m])
    assert coef[0] == pytest.approx(M * SIZE["load_dependent"]["mu"], rel=0.15)
    assert coef[0] > 5 * se[0]


@pytest.mark.parametrize("M", [0.3, 1.0])
def test_asymmetry(M):
    pl, res, r, keep = run("asymmetry", M)
    qd = res.qd[keep]
    m = qd != 0
    coef, se = fit(r[m], np.ones(np.sum(m)), np.abs(qd[m]))
    # f = (c + v|qd|)(1 +- a/2) sign(qd): the rigid residual is (a/2)(c + v|qd|), EVEN in qd
    a = M * SIZE["asymmetry"]["a"]
    assert coef[0] == pytest.approx(0.5 * a * C5, rel=0.1)
    assert coef[1] == pytest.approx(0.5 * a * V5, rel=0.25)
    assert coef[0] > 5 * se[0] and coef[1] > 3 * se[1]


@pytest.mark.parametrize("M", [0.3, 1.0])
def test_nonlinear_viscous(M):
    pl, res, r, keep = run("nonlinear_viscous", M)
    qd = res.qd[keep]
    coef, se = fit(r, qd * np.abs(qd))
    assert coef[0] == pytest.approx(pl.fx.w, rel=0.1) and coef[0] > 5 * se[0]
    # ~30 % of the viscous torque at the maximum speed
    assert pl.fx.w * VMAX5 ** 2 == pytest.approx(M * 0.3 * V5 * VMAX5)


@pytest.mark.parametrize("M", [0.3, 1.0])
def test_thermal_drift(M):
    tau = 200.0
    kw = {"campaign_length_s": 3 * tau}
    _, res_cold, r_cold, keep = run("thermal_drift", M, t0=0.0, **kw)
    _, res_warm, r_warm, _ = run("thermal_drift", M, t0=4 * tau, **kw)
    h = M * SIZE["thermal_drift"]["cold_excess"]
    for res, r, t0 in ((res_cold, r_cold, 0.0), (res_warm, r_warm, 4 * tau)):
        qd = res.qd[keep]
        m = qd != 0
        coef, se = fit(r[m], np.sign(qd[m]), qd[m])
        factor = h * np.mean(np.exp(-res.time[keep] / tau))
        assert coef[0] == pytest.approx(factor * C5, rel=0.1, abs=3 * se[0])
        assert coef[1] == pytest.approx(factor * V5, rel=0.15, abs=3 * se[1])
    assert h * C5 > 10 * NOISE / np.sqrt(len(r_cold))   # visible cold


@pytest.mark.parametrize("M", [0.3, 1.0])
def test_presliding_hysteresis_at_reversals(M):
    pl, res, r, keep = run("presliding", M, ref=reversals(VMAX5, 0.3, 0.6, 1.0))
    f, qd = res.f, res.qd
    cv = C5 * np.sign(qd) + V5 * qd
    # within the bristle displacement after each reversal, friction lags the Coulomb jump
    rev = np.flatnonzero(np.diff(np.sign(qd)) != 0)
    rev = rev[rev < qd.size - 25]
    rev = rev[np.abs(qd[rev + 20]) > 0]
    assert rev.size >= 6
    lag = np.array([np.mean(np.abs(f[i + 1:i + 6] - cv[i + 1:i + 6])) for i in rev])
    assert np.median(lag) > 0.3 * C5
    # far from reversals it is Coulomb + viscous
    far = np.abs(qd) > 0.3
    np.testing.assert_allclose(f[far], cv[far], rtol=0.02, atol=0.02)
    # presliding displacement scales with M
    assert C5 / pl.fx.sigma0 == pytest.approx(M * SIZE["presliding"]["z_ss"])


@pytest.mark.parametrize("M", [0.3, 1.0])
def test_compliance_deflection_grows_with_transmitted_torque(M):
    pl, res, r, keep = run("compliance", M)
    defl = res.qm - res.q
    slope = np.polyfit(res.tau_t, defl, 1)[0]
    assert slope == pytest.approx(1.0 / pl.fx.k, rel=1e-6)
    # 0.4 deg at rated torque for M = 1
    assert math.degrees(TMAX5 * (1 / pl.fx.k - 1 / K_NOMINAL)) == pytest.approx(M * 0.4, rel=1e-9)
    # visible against the encoder: peak deflection of several encoder steps here
    assert np.max(np.abs(defl)) > 3 * ENC * M
    _, res0, _, _ = run("none", 0.0)
    assert np.max(np.abs(res0.qm - res0.q)) < ENC


@pytest.mark.parametrize("M", [0.3, 1.0])
def test_backlash_lost_motion_at_reversals(M):
    pl, res, r, keep = run("backlash", M, ref=reversals(VMAX5, 0.3, 0.6, 1.0))
    lost = res.qm - res.q - res.tau_t / pl.fx.k      # deflection minus the elastic part
    beta = pl.fx.beta
    assert beta == pytest.approx(0.5 * M * math.radians(0.2))
    assert np.ptp(lost) == pytest.approx(2 * beta, rel=0.05)
    # the link lags by +-beta on either side: both contact sides are used
    assert np.mean(lost > 0.9 * beta) > 0.1 and np.mean(lost < -0.9 * beta) > 0.1


def test_measurement_effects_parameters():
    p = Effect("torque_scale", 1.0).joint_params(C5, V5, TMAX5, VMAX5, 0.05)
    assert p.torque_gain == pytest.approx(1.15)
    p = Effect("time_offset", 0.5).joint_params(C5, V5, TMAX5, VMAX5, 0.05)
    assert p.time_offset == pytest.approx(0.010)


def test_nominal_plant_and_compliance_use_the_declared_stiffness():
    """FORMAT.md: the nominal plant is the joint at its declared stiffness; ``compliance`` is a
    joint softer than declared (1/k = 1/k_declared + M delta / tau_max)."""
    from mocap.robot import Drive
    from ident.sim.effects import nominal_stiffness

    k_decl = 5000.0
    p0 = Effect("none").joint_params(C5, V5, TMAX5, VMAX5, 0.05, k0=k_decl)
    assert p0.k == k_decl
    for M in (0.3, 1.0):
        p = Effect("compliance", M).joint_params(C5, V5, TMAX5, VMAX5, 0.05, k0=k_decl)
        assert p.k < k_decl
        extra = math.degrees(TMAX5 * (1 / p.k - 1 / k_decl))
        assert extra == pytest.approx(M * 0.4, rel=1e-9)
    with pytest.raises(ValueError):
        Effect("none").joint_params(C5, V5, TMAX5, VMAX5, 0.05, k0=0.0)
    common = dict(gear_ratio=100.0, motor_inertia=0.04, motor_viscous=0.15, max_velocity=2.43,
                  max_torque=14.5, encoder_resolution=ENC)
    assert nominal_stiffness(Drive(name="j", extra={"stiffness": 5000}, **common)) == 5000.0
    # undeclared: rigid to measurement precision (under half an encoder count at rated torque)
    k_rigid = nominal_stiffness(Drive(name="j", **common))
    assert common["max_torque"] / k_rigid < 0.5 * ENC
    big = dict(common, max_torque=232.0)
    assert 232.0 / nominal_stiffness(Drive(name="j", **big)) <= 0.5 * ENC * (1 + 1e-12)
