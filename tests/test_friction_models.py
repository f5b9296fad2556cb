"""Forward friction models: thesis eq. 2-5 to 2-7, Indri & Trapani eq. 1-2, 5-12, 22, 24, 29-30."""
from __future__ import annotations

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from ident.friction import (MODELS, Arctan, CoulombViscous, Hyperbolic, LuGreDM1, LuGreDM2,
                            Stribeck, linear_scan, s0, s1)

STATIC = [
    Stribeck(Fk=4.0, Fv=1.2, Fs=1.5, Vc=0.08),
    Hyperbolic(g1=2.0, g2=100.0, g3=5.0, g4=4.0, g5=20.0, g6=1.0),
    Arctan(tau_s=4.0, tau_sc=-1.5, tau_v=1.0, tau_nlv=0.1, delta=12.3),
    Arctan(tau_s=0.4012, tau_sc=6.7333e-2, tau_v=2.7662e-3, tau_nlv=-1.5330e-6, delta=0.1),
]
ARCTAN = Arctan(tau_s=3.0, tau_sc=-1.0, tau_v=1.0, tau_nlv=0.1, delta=10.0)


def test_registry_names_match_format():
    assert {k: v.param_names for k, v in MODELS.items()} == {
        "cv": ("c", "v"), "stribeck": ("Fk", "Fv", "Fs", "Vc"),
        "hyperbolic": ("g1", "g2", "g3", "g4", "g5", "g6"),
        "arctan": ("tau_s", "tau_sc", "tau_v", "tau_nlv", "delta"),
        "dm1": ("sigma0", "sigma1"), "dm2": ("sigma0", "alpha", "beta", "gamma")}
    with pytest.raises(TypeError):
        Stribeck(Fk=1.0, Fv=1.0, Fs=1.0)
    with pytest.raises(TypeError):
        Arctan(tau_s=1, tau_sc=0, tau_v=0, tau_nlv=0, delta=1, Kx=3)


@pytest.mark.parametrize("m", STATIC, ids=lambda m: m.name)
def test_static_odd_and_linear_split(m):
    qd = np.linspace(-3, 3, 2001)
    f = m.torque(qd)
    np.testing.assert_allclose(m.torque(-qd), -f, atol=1e-12)
    assert m.torque(np.array([0.0]))[0] == 0.0
    assert np.all(f[qd > 0] > 0)                    # opposes motion for these parameters
    phi, off = m.linear_design(qd)
    lin = np.array([m.params[k] for k in m.linear_names])
    np.testing.assert_allclose(phi @ lin + off, f, atol=1e-12)
    rebuilt = type(m).from_theta(m.theta, **m.settings)
    np.testing.assert_array_equal(rebuilt.torque(qd), f)


@pytest.mark.parametrize("m", STATIC[1:], ids=lambda m: m.name)
def test_smooth_models_are_continuous_at_zero(m):
    eps = np.array([1e-9, 1e-7])
    assert np.all(np.abs(m.torque(eps)) < 1e-3 * np.abs(m.torque(np.array([1.0]))))
    # continuity: the largest step between neighbours shrinks with the grid spacing
    jumps = [np.max(np.abs(np.diff(m.torque(np.linspace(-0.01, 0.01, n))))) for n in (2001, 20001)]
    assert jumps[1] < 0.15 * jumps[0]


def test_stribeck_jump_does_not_shrink():
    m = STATIC[0]
    jumps = [np.max(np.abs(np.diff(m.torque(np.linspace(-0.01, 0.01, n))))) for n in (2000, 20000)]
    np.testing.assert_allclose(jumps, 2 * m.Fk, rtol=0.01)


def test_stribeck_levels_and_discontinuity():
    m = STATIC[0]
    f = m.torque(np.array([1e-12, 50.0, -1e-12]))
    np.testing.assert_allclose(f[0], m.Fk, rtol=1e-9)             # static level at 0+
    np.testing.assert_allclose(f[1], m.Fk - m.Fs + m.Fv * 50.0, rtol=1e-12)  # Fs is the drop
    np.testing.assert_allclose(f[2], -m.Fk, rtol=1e-9)
    qd = np.linspace(1e-6, 3, 300000)
    assert np.max(np.abs(np.diff(m.torque(qd)))) < 1e-3        # continuous away from 0


def test_degenerate_forms_reduce():
    qd = np.concatenate([np.linspace(-3, -0.05, 500), np.linspace(0.05, 3, 500)])
    cv = CoulombViscous(c=4.0, v=1.2)
    np.testing.assert_allclose(Stribeck(Fk=4.0, Fv=1.2, Fs=0.0, Vc=0.1).torque(qd),
                               cv.torque(qd), atol=1e-12)
    # Vc -> 0: the drop acts as a second Coulomb term, only Fk - Fs matters
    np.testing.assert_allclose(Stribeck(Fk=0.0, Fv=1.2, Fs=-4.0, Vc=1e-5).torque(qd),
                               cv.torque(qd), atol=1e-12)
    np.testing.assert_allclose(Stribeck(Fk=0.0, Fv=1.2, Fs=-4.0, Vc=0.0).torque(qd),
                               cv.torque(qd), atol=1e-12)                  # the limit itself
    with pytest.raises(ValueError, match="Vc"):
        Stribeck(Fk=0.0, Fv=1.2, Fs=-4.0, Vc=-1.0).torque(qd)
    # Vc -> infinity: the drop is linear in qd and merges with the viscous term
    big = Stribeck(Fk=4.0, Fv=1.2, Fs=1e-3 * 1e4, Vc=1e4).torque(qd)
    np.testing.assert_allclose(big, CoulombViscous(c=4.0, v=1.2 - 1e-3).torque(qd), atol=1e-3)
    # hyperbolic: g2 = g3 removes the first term; g5 huge is pure Coulomb
    h = Hyperbolic(g1=7.0, g2=30.0, g3=30.0, g4=4.0, g5=1e6, g6=1.2)
    np.testing.assert_allclose(h.torque(qd), cv.torque(qd), atol=1e-12)
    # arctan: tau_sc = 0 and Kv large gives Coulomb + viscous (+ nonlinear viscous)
    a = Arctan(Kv=1e9, tau_s=4.0, tau_sc=0.0, tau_v=1.2, tau_nlv=0.0, delta=5.0)
    np.testing.assert_allclose(a.torque(qd), cv.torque(qd), atol=1e-7)
    # arctan with Kv = 1000: S0 approximates sign to 1 - S0(0.05) = 1.3%
    a = Arctan(tau_s=4.0, tau_sc=0.0, tau_v=1.2, tau_nlv=0.0, delta=5.0)
    np.testing.assert_allclose(a.torque(qd), cv.torque(qd), rtol=0.013)
    # delta = 0: the Stribeck term vanishes whatever tau_sc
    np.testing.assert_allclose(Arctan(tau_s=4.0, tau_sc=9.0, tau_v=1.2, tau_nlv=0.3,
                                      delta=0.0).torque(qd),
                               Arctan(tau_s=4.0, tau_sc=0.0, tau_v=1.2, tau_nlv=0.3,
                                      delta=3.0).torque(qd), atol=1e-12)


def test_arctan_regressor_is_eq28_and_helpers():
    v = np.array([-2.0, -0.01, 0.0, 0.3, 4.0])
    R = Arctan.regressor(v, 7.0, 1000.0)
    S0 = 2 / np.pi * np.arctan(1000.0 * v)
    np.testing.assert_allclose(R, np.column_stack([S0, 2 / np.pi * np.arctan(7.0 * v), v,
                                                   v ** 2 * S0]), atol=1e-15)
    np.testing.assert_allclose(s1(v), S0 * v)
    assert np.all(s1(v) >= 0)
    m = ARCTAN
    np.testing.assert_allclose(m.g(v), 3.0 - 1.0 * 2 / np.pi * np.arctan(s1(v) * 10.0))
    np.testing.assert_allclose(m.viscous(v), v + 0.1 * v ** 2 * s0(v))


# ---------------------------------------------------------------------------------------------
# dynamic models
# ---------------------------------------------------------------------------------------------
def _loop_scan(decay, drive, z0):
    z = np.empty(decay.size + 1)
    z[0] = z0
    for k in range(decay.size):
        z[k + 1] = np.exp(-decay[k]) * z[k] + drive[k]
    return z


@pytest.mark.parametrize("n", [1, 7, 8, 9, 65, 2000, 40000])
def test_linear_scan_matches_loop(n):
    rng = np.random.default_rng(n)
    decay = rng.exponential(0.3, n) * (rng.random(n) < 0.8)
    decay[rng.random(n) < 0.01] = 900.0             # e^-900 underflows: must not break anything
    drive = rng.normal(size=n)
    z = linear_scan(decay, drive, 0.7)
    zr = _loop_scan(decay, drive, 0.7)
    np.testing.assert_allclose(z, zr, rtol=0, atol=1e-12 * max(1.0, np.max(np.abs(zr))))
    # long stretches without decay (v = 0): a pure sum
    np.testing.assert_allclose(linear_scan(np.zeros(n), np.ones(n), 0.0), np.arange(n + 1.0),
                               atol=1e-9)


def _loop_torque(m, qd, qdd, dt):
    """Plain per-sample reference of eq. 29-30 (both branches; ``hold="zero"``) or of the
    first-order hold (``hold="first"``: a averaged over the step, the steady deflection
    S0 g / sigma0 linear in between), and eq. 6."""
    Kv, st = m.static.Kv, m.static
    z = np.empty(qd.size)
    z[0] = m.steady_state(qd[0]) if m.z0 is None else m.z0

    def ab(v):
        S0 = 2 / np.pi * np.arctan(Kv * v)
        g = st.tau_s + st.tau_sc * 2 / np.pi * np.arctan(S0 * v * st.delta)
        return m.sigma0 * S0 * v / g, S0 ** 2 * v, S0 * g / m.sigma0

    for k in range(qd.size - 1):
        a, b, zs = ab(qd[k])
        if m.hold == "first":
            a1, _, zs1 = ab(qd[k + 1])
            x = 0.5 * dt * (a + a1)
            phi = (1 - np.exp(-x)) / x if x > 0 else 1.0
            z[k + 1] = np.exp(-x) * z[k] + (1 - np.exp(-x)) * zs + (zs1 - zs) * (1 - phi)
        elif a != 0:
            z[k + 1] = np.exp(-a * dt) * z[k] + (1 - np.exp(-a * dt)) / a * b
        else:
            z[k + 1] = z[k] + b * dt
    return np.array([m.output(z[k], qd[k], qdd[k]) for k in range(qd.size)]).ravel()


def _reversals(T=2000, dt=1e-3):
    t = np.arange(T) * dt
    w = 2 * np.pi * 1.5
    qd = 0.4 * np.sin(w * t) + 0.05 * np.sin(3.1 * w * t)
    qd[700:760] = 0.0                                # a stop: a_k = 0 branch
    qdd = np.gradient(qd, dt)
    return t, qd, qdd


DYN = [LuGreDM1(static=ARCTAN, sigma0=2e4, sigma1=40.0),
       LuGreDM1(static=ARCTAN, damping="eq10", sigma0=2e4, sigma1=40.0),
       LuGreDM1(static=ARCTAN, damping="eq11", sigma0=2e4, sigma1=0.5),
       LuGreDM1(static=ARCTAN, damping="eq12", sigma0=2e4, sigma1=40.0, z0=0.0),
       LuGreDM2(static=ARCTAN, sigma0=2e4, alpha=6.5, beta=0.1, gamma=1.05, accel_ratio=5.3),
       LuGreDM1(static=ARCTAN, sigma0=2e4, sigma1=40.0, hold="zero"),
       LuGreDM2(static=ARCTAN, sigma0=2e4, alpha=6.5, beta=0.1, gamma=1.05, accel_ratio=5.3,
                hold="zero")]


@pytest.mark.parametrize("m", DYN, ids=lambda m: f"{m.name}-{m.settings.get('damping', '')}-"
                                                f"{m.hold}")
def test_dynamic_vectorised_equals_loop(m):
    t, qd, qdd = _reversals()
    tau = m.torque(qd, qdd, 1e-3)
    ref = _loop_torque(m, qd, qdd, 1e-3)
    np.testing.assert_allclose(tau, ref, rtol=0, atol=1e-12 * np.max(np.abs(ref)))
    phi, off = m.linear_design(qd, qdd, 1e-3)
    np.testing.assert_allclose(phi @ np.array([m.params[k] for k in m.linear_names]) + off, tau,
                               atol=1e-12)


def test_single_step_matches_the_sequence():
    m = DYN[0]
    t, qd, qdd = _reversals(T=300)
    z = m.states(qd, 1e-3)
    np.testing.assert_allclose(m.step(z[:-1], qd[:-1], 1e-3, qd[1:]), z[1:], rtol=1e-12,
                               atol=1e-15)
    mz = LuGreDM1(static=ARCTAN, sigma0=2e4, sigma1=40.0, hold="zero")
    z = mz.states(qd, 1e-3)
    np.testing.assert_allclose(mz.step(z[:-1], qd[:-1], 1e-3), z[1:], rtol=1e-12, atol=1e-15)


@pytest.mark.parametrize("v", [0.02, 0.5, -1.7])
def test_dynamic_steady_state_is_static_curve(v):
    m = LuGreDM1(static=ARCTAN, sigma0=2e4, sigma1=40.0, z0=0.0)
    qd = np.full(3000, v)
    tau = m.torque(qd, np.zeros_like(qd), 1e-3)
    Kv = ARCTAN.Kv
    exact = s0(v, Kv) * ARCTAN.g(v) + ARCTAN.viscous(v)
    np.testing.assert_allclose(tau[-1], exact, rtol=1e-12)
    # the static arctan curve, up to the smooth-sign approximation 1 - S0(v)
    np.testing.assert_allclose(tau[-1], ARCTAN.torque(np.array([v]))[0],
                               rtol=2.5 * (1 - s0(abs(v), Kv)))
    m2 = LuGreDM2(static=ARCTAN, sigma0=2e4, alpha=6.5, beta=0.0, gamma=1.0, accel_ratio=5.0)
    np.testing.assert_allclose(m2.torque(qd, np.zeros_like(qd), 1e-3)[-1], exact, rtol=1e-12)


def test_presliding_hysteresis_at_reversals():
    dt = 1e-4
    t = np.arange(0, 2.0, dt)
    qd = 0.3 * np.cos(2 * np.pi * 1.0 * t)           # reversals at t = 0.25, 0.75, ...
    m = LuGreDM1(static=ARCTAN, sigma0=2e3, sigma1=0.0)
    tau = m.torque(qd, None, dt)
    for tr in (0.25, 0.75, 1.25):
        k = int(round(tr / dt))
        sv = np.sign(qd[k - 5])
        # friction lags: the velocity has reversed, the friction still has the old sign
        after = slice(k + 5, k + 40)
        assert np.all(np.sign(qd[after]) == -sv)
        assert np.all(np.sign(tau[after]) == sv)
        # ... and it crosses zero a bristle-deflection time later, continuously
        cross = k + int(np.argmax(np.sign(tau[k:]) == -sv))
        assert 5 < cross - k < 1500
        assert np.max(np.abs(np.diff(tau[k - 50:k + 1500]))) < 0.05
    # a static model has no lag: its sign flips with the velocity
    st = ARCTAN.torque(qd)
    k = int(round(0.25 / dt))
    assert np.all(np.sign(st[k + 5:k + 40]) == np.sign(qd[k + 5:k + 40]))


def test_presliding_is_a_spring():
    """Tiny oscillations (displacement << g/sigma0) give friction ~ sigma0 x: a stiff spring.

    Eq. 5 moves the bristles with S0(v)^2 v, which vanishes for |v| << 1/Kv; the oscillation's
    speeds (~1e-5 rad/s) need a sharper smooth sign than Kv = 1000 to show the spring.
    """
    dt = 1e-5
    t = np.arange(0, 0.2, dt)
    A, w = 3e-7, 2 * np.pi * 20.0
    x = A * np.sin(w * t)
    qd = A * w * np.cos(w * t)
    st = Arctan(Kv=1e8, **ARCTAN.params)
    m = LuGreDM1(static=st, sigma0=1e5, sigma1=0.0, z0=0.0)
    tau = m.torque(qd, None, dt) - st.viscous(qd)
    np.testing.assert_allclose(tau, m.sigma0 * x, atol=0.03 * m.sigma0 * A)
    # with Kv = 1000 the same motion leaves the bristles (almost) still
    m = LuGreDM1(static=ARCTAN, sigma0=1e5, sigma1=0.0, z0=0.0)
    assert np.max(np.abs(m.torque(qd, None, dt) - ARCTAN.viscous(qd))) < 0.01 * m.sigma0 * A


def test_continuous_time_interface_matches_exact_discretisation():
    m = LuGreDM1(static=ARCTAN, sigma0=2e3, sigma1=5.0)
    vel = lambda t: 0.3 * np.sin(2 * np.pi * t)      # noqa: E731
    t_eval = np.linspace(0, 1.0, 1001)
    z0 = 0.0
    sol = solve_ivp(lambda t, z: m.state_derivative(z, vel(t)), (0, 1.0), [z0], t_eval=t_eval,
                    rtol=1e-10, atol=1e-13, method="LSODA")
    tau_ct = m.output(sol.y[0], vel(t_eval))
    dt = 1e-5
    tf = np.arange(0, 1.0 + dt / 2, dt)
    m0 = LuGreDM1(static=ARCTAN, sigma0=2e3, sigma1=5.0, z0=z0)
    tau_dt = m0.torque(vel(tf), None, dt)[::100]
    np.testing.assert_allclose(tau_dt, tau_ct, atol=2e-3 * np.max(np.abs(tau_ct)))


def test_critical_acceleration_eq22():
    st = Arctan(tau_s=0.4012, tau_sc=6.7333e-2, tau_v=2.7662e-3, tau_nlv=-1.5330e-6, delta=0.1)
    m = LuGreDM1(static=st, sigma0=11.655, sigma1=5.8996)
    vm = 2.0
    g = 0.4012 + 6.7333e-2 * 2 / np.pi * np.arctan(s1(vm) * 0.1)
    np.testing.assert_allclose(m.critical_acceleration(vm), 11.655 * vm ** 2 / (np.log(2) * g))
    # eq. 22's meaning: faster than a_crit, w = zdot/v is still >= 1 when v reaches v_m
    m = LuGreDM1(static=ARCTAN, sigma0=2e3, sigma1=0.0)
    vm = 0.5
    ac = float(m.critical_acceleration(vm))
    for factor, above in ((3.0, True), (1 / 30.0, False)):
        a = factor * ac
        dt = (2 * vm / a) / 4000
        qd = np.concatenate([np.full(10, -vm), np.arange(-vm, vm, a * dt), [vm]])
        z = m.states(qd, dt)
        w = m.state_derivative(z[-1], vm) / vm
        assert (w >= 1.0) == above


def test_dynamic_input_errors():
    with pytest.raises(ValueError, match="dt"):
        DYN[0].torque(np.ones(5))
    with pytest.raises(ValueError, match="qdd"):
        LuGreDM2(static=ARCTAN, sigma0=1e3, alpha=1, beta=0, gamma=1).torque(np.ones(5), None, 1e-3)
    bad = Arctan(tau_s=1.0, tau_sc=-3.0, tau_v=0.0, tau_nlv=0.0, delta=10.0)
    with pytest.raises(ValueError, match="positive"):
        LuGreDM1(static=bad, sigma0=1e3, sigma1=1.0).torque(np.full(5, 2.0), None, 1e-3)
    with pytest.raises(ValueError, match="damping"):
        LuGreDM1(static=ARCTAN, damping="eq13", sigma0=1e3, sigma1=1.0)
