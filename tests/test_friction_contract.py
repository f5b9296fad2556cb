"""The friction-model contract, checked over every registered model (``ident.friction.MODELS``),
in the style of scikit-learn's estimator checks: each check is one property that the
estimators (:mod:`ident.friction.fit`) and the simulator rely on, run against every model.

A new model passes these checks, or the estimators cannot use it. Parameter values below are
hand-picked physical examples; the test signals are sums of sines written out here.
"""
from __future__ import annotations

import numpy as np
import pytest

from ident.friction import MODELS, Arctan, FrictionModel, fit_friction

T_S, RATE = 3.0, 500.0
STATIC = Arctan(tau_s=2.0, tau_sc=-0.5, tau_v=0.4, tau_nlv=0.05, delta=5.0)
EXAMPLES = {
    "cv": ({"c": 2.0, "v": 0.5}, {}),
    "stribeck": ({"Fk": 3.0, "Fv": 0.5, "Fs": 1.0, "Vc": 0.1}, {}),
    "hyperbolic": ({"g1": 1.0, "g2": 50.0, "g3": 5.0, "g4": 2.0, "g5": 20.0, "g6": 0.5}, {}),
    "arctan": ({"tau_s": 2.0, "tau_sc": -0.5, "tau_v": 0.4, "tau_nlv": 0.05, "delta": 5.0}, {}),
    "dm1": ({"sigma0": 1e4, "sigma1": 5.0}, {"static": STATIC}),
    "dm2": ({"sigma0": 1e4, "alpha": 50.0, "beta": 0.5, "gamma": 1.0},
            {"static": STATIC, "accel_ratio": 10.0}),
}
NAMES = sorted(MODELS)


def signals():
    t = np.arange(0.0, T_S, 1.0 / RATE)
    w1, w2 = 2 * np.pi * 0.7, 2 * np.pi * 1.9
    qd = 1.5 * np.sin(w1 * t) + 0.4 * np.sin(w2 * t + 0.3)
    qdd = 1.5 * w1 * np.cos(w1 * t) + 0.4 * w2 * np.cos(w2 * t + 0.3)
    return qd, qdd, 1.0 / RATE


def make(name):
    params, settings = EXAMPLES[name]
    return MODELS[name](**params, **settings)


def test_every_registered_model_has_an_example():
    assert set(EXAMPLES) == set(MODELS)


@pytest.mark.parametrize("name", NAMES)
def test_declares_its_interface(name):
    cls = MODELS[name]
    assert issubclass(cls, FrictionModel) and cls.name == name
    lin, nl = cls.linear_params(), cls.nonlinear_params()
    assert set(lin) | set(nl) == set(cls.param_names) and not set(lin) & set(nl)
    assert cls.fit_method in ("auto", "delta_grid")
    # every hook of the interface is defined on the class (no estimator probes for it)
    for hook in ("linear_design", "torque", "fit_hints", "complete_settings", "canonical",
                 "design_grad", "vp_grid", "degeneracy", "violations", "initial_guess",
                 "degenerate_form", "report_form", "to_dict"):
        assert callable(getattr(cls, hook)), hook


@pytest.mark.parametrize("name", NAMES)
def test_constructor_checks_parameter_names(name):
    params, settings = EXAMPLES[name]
    with pytest.raises(TypeError):
        MODELS[name](**{**params, "not_a_parameter": 1.0}, **settings)
    with pytest.raises(TypeError):
        MODELS[name](**dict(list(params.items())[1:]), **settings)


@pytest.mark.parametrize("name", NAMES)
def test_torque_is_linear_design(name):
    m = make(name)
    qd, qdd, dt = signals()
    tau = m.torque(qd, qdd, dt)
    Phi, off = m.linear_design(qd, qdd, dt)
    assert tau.shape == qd.shape and np.all(np.isfinite(tau))
    assert Phi.shape == (qd.size, len(m.linear_params())) and off.shape == qd.shape
    lin = np.array([m.params[k] for k in m.linear_params()])
    np.testing.assert_allclose(Phi @ lin + off, tau, rtol=1e-10, atol=1e-10)


@pytest.mark.parametrize("name", NAMES)
def test_friction_opposes_motion_at_speed(name):
    m = make(name)
    qd, qdd, dt = signals()
    tau = m.torque(qd, qdd, dt)
    fast = np.abs(qd) > 0.3
    assert np.all(np.sign(tau[fast]) == np.sign(qd[fast]))


@pytest.mark.parametrize("name", [n for n in NAMES if not MODELS[n].dynamic])
def test_static_models_are_odd(name):
    m = make(name)
    qd = np.linspace(0.0, 2.0, 50)
    np.testing.assert_allclose(m.torque(-qd), -m.torque(qd), rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize("name", NAMES)
def test_to_dict_round_trip(name):
    m = make(name)
    d = m.to_dict()
    assert d["model"] == name and d["params"] == m.params
    again = MODELS[d["model"]](**d["params"], **m.settings)
    qd, qdd, dt = signals()
    np.testing.assert_array_equal(again.torque(qd, qdd, dt), m.torque(qd, qdd, dt))


@pytest.mark.parametrize("name", NAMES)
def test_fit_hints_cover_the_nonlinear_parameters(name):
    cls = MODELS[name]
    qd, qdd, _ = signals()
    settings = cls.complete_settings(qd, qdd, dict(EXAMPLES[name][1]))
    x0, bounds = cls.fit_hints(qd, settings)
    if cls.fit_method == "delta_grid":
        return                                  # a grid search: no starts or bounds
    assert set(x0) == set(cls.nonlinear_params()) == set(bounds)
    for k, (lo, hi) in bounds.items():
        assert lo < x0[k] < hi, k


@pytest.mark.parametrize("name", NAMES)
def test_canonical_keeps_the_torque(name):
    m = make(name)
    params = dict(m.params)
    if name == "hyperbolic":                    # the swapped representative of the same curve
        params.update(g1=-params["g1"], g2=params["g3"], g3=params["g2"])
    c = type(m).canonical(params)
    qd, qdd, dt = signals()
    other = type(m)(**c, **m.settings)
    np.testing.assert_allclose(other.torque(qd, qdd, dt), m.torque(qd, qdd, dt), rtol=1e-12,
                               atol=1e-12)
    assert type(m).canonical(c) == c


@pytest.mark.parametrize("name", NAMES)
def test_design_grad_matches_finite_differences(name):
    cls = MODELS[name]
    m = make(name)
    qd = signals()[0]
    nl = {k: m.params[k] for k in cls.nonlinear_params()}
    g = cls.design_grad(qd, nl)
    if g is None:
        return
    Phi, dPhi, cols = g
    np.testing.assert_allclose(Phi, m.linear_design(qd)[0], rtol=1e-12, atol=1e-12)
    for j, k in enumerate(cls.nonlinear_params()):
        h = 1e-6 * nl[k]
        up = cls.design_grad(qd, {**nl, k: nl[k] + h})[0][:, cols[j]]
        dn = cls.design_grad(qd, {**nl, k: nl[k] - h})[0][:, cols[j]]
        np.testing.assert_allclose(dPhi[:, j], (up - dn) / (2 * h), rtol=1e-5, atol=1e-6)


@pytest.mark.parametrize("name", NAMES)
def test_vp_grid_reproduces_the_design(name):
    cls = MODELS[name]
    qd = signals()[0]
    settings = dict(EXAMPLES[name][1])
    grid = cls.vp_grid(qd, cls.fit_hints(qd, settings)[1], 4)
    if grid is None:
        return
    B, U, (cols, coefs), *_ = grid
    for k in (0, U.shape[0] // 2, U.shape[0] - 1):
        nl = dict(zip(cls.nonlinear_params(), U[k]))
        lin = {p: 0.0 for p in cls.linear_params()}
        Phi = cls(**lin, **nl, **settings).linear_design(qd)[0]
        Phik = np.einsum("tap,ap->ta", B[:, cols[k]], coefs[k])
        if name == "hyperbolic" and np.isclose(U[k, 0] / U[k, 1], 1.0001):
            continue                            # the limit block: a different column by design
        np.testing.assert_allclose(Phik, Phi, rtol=1e-10, atol=1e-10)


@pytest.mark.parametrize("name", NAMES)
def test_checks_return_their_declared_types(name):
    m = make(name)
    qd = signals()[0]
    deg = m.degeneracy(qd, 3.0)
    assert deg is None or isinstance(deg, str)
    assert m.violations() == ()                 # the examples are physical
    assert isinstance(type(m).initial_guess(2.0, 0.5, 1.5), dict)
    form = type(m).degenerate_form(m.params, {k: 0.01 for k in m.params}, qd, None, 3.0)
    assert form is None or isinstance(form, str)
    p, se = type(m).report_form(m.params, {k: 0.01 for k in m.params}, None, (), qd)
    assert set(p) == set(m.params)


@pytest.mark.parametrize("name", NAMES)
def test_fit_recovers_noise_free_torque(name):
    m = make(name)
    qd, qdd, dt = signals()
    tau = m.torque(qd, qdd, dt)
    settings = {k: v for k, v in EXAMPLES[name][1].items()}
    fit = fit_friction(MODELS[name], qd, tau, qdd=qdd, dt=dt, settings=settings, n_starts=2)
    assert type(fit.model) is MODELS[name]
    assert fit.rms < 1e-3 * np.max(np.abs(tau))
