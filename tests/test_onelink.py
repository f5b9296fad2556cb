"""ident.model.onelink: eq. 2-4 with the three friction models on seeded synthetic one-link data
(closed form: q from eq. 3-2, qm = q, tau = I qdd - mglx sin q + mgly cos q + f(qd) + J qmdd
+ B qmd + noise), and the TX40 real-data fit (slow)."""
from __future__ import annotations

import numpy as np
import pytest

from ident.signals.fourier import FourierSeries
from ident.friction.base import CoulombViscous
from ident.friction.static import Stribeck
from ident.model.onelink import (OneLinkIdentifier, fit_cv_linear, name_degenerate, onelink_regressor,
                           onelink_target)
from ident.model.linkstate import prepare_joint_signals

from reversals import displacement_by_loop

TRUE = {"I": 0.4, "mglx": 3.0, "mgly": 1.0}
J, B = 0.35, 0.9
SERIES = FourierSeries(np.array([1.0, -0.6, 0.4, 0.2, -0.1]), np.array([0.4, 0.2, -0.6, 0.1, 0.04]),
                       2 * np.pi / 10, 0.3)


def one_link_data(friction, seed=0, noise_tau=0.05, noise_q=2e-4, duration=20.0, dt=0.005):
    rng = np.random.default_rng(seed)
    t = np.arange(0, duration, dt)
    q, qd, qdd = SERIES.evaluate(t)
    tau = (TRUE["I"] * qdd - TRUE["mglx"] * np.sin(q) + TRUE["mgly"] * np.cos(q) + friction.torque(qd)
           + J * qdd + B * qd + rng.normal(0, noise_tau, t.size))
    qm = q + rng.normal(0, noise_q, t.size)
    return t, qm, tau


def test_target_and_regressor():
    q = np.array([0.0, np.pi / 2])
    R = onelink_regressor(q, np.array([1.0, 2.0]))
    assert np.allclose(R, [[1, 0, 1], [2, -1, 0]])
    assert np.allclose(onelink_target([5.0], [2.0], [1.0], J, B), [5 - J - 2 * B])


def test_cv_recovers_truth_within_standard_errors():
    fr = CoulombViscous(c=4.1, v=1.2)
    t, qm, tau = one_link_data(fr, seed=1)
    sig = prepare_joint_signals(5, t, qm, tau)
    fit = OneLinkIdentifier(models=("cv",)).fit_signals(sig, J, B)["cv"]
    truth = {**TRUE, "c": 4.1, "v": 1.2}
    for k, v in truth.items():
        est = fit.params.get(k, fit.rigid.get(k))
        assert abs(est - v) < 5 * fit.stderr[k] + 1e-3, (k, est, v, fit.stderr[k])
        assert fit.stderr[k] < 0.02
    assert fit.rms == pytest.approx(0.05, rel=0.1)
    assert fit.degenerate is None and fit.cond < 10
    d = fit.to_dict()
    assert set(d["params"]) == {"c", "v"} and set(d["rigid"]) == set(TRUE)


def test_cv_weights_and_exact_data():
    rng = np.random.default_rng(2)
    q = rng.uniform(-2, 2, 500)
    qd = rng.uniform(-2, 2, 500)
    qdd = rng.normal(0, 1, 500)
    y = onelink_regressor(q, qdd) @ np.array([0.4, 3.0, 1.0]) + 2.0 * np.sign(qd) + 0.5 * qd
    f = fit_cv_linear(q, qd, qdd, y, weights=np.full(500, 2.0))
    assert f.params["c"] == pytest.approx(2.0, abs=1e-10) and f.params["v"] == pytest.approx(0.5, abs=1e-10)


def test_stribeck_recovered_and_beats_cv():
    fr = Stribeck(Fk=5.0, Fv=1.2, Fs=1.0, Vc=0.1)
    t, qm, tau = one_link_data(fr, seed=3)
    sig = prepare_joint_signals(5, t, qm, tau)
    fits = OneLinkIdentifier(models=("cv", "stribeck", "hyperbolic"), n_starts=3).fit_signals(sig, J, B)
    s = fits["stribeck"]
    for k, v in fr.params.items():
        assert s.params[k] == pytest.approx(v, rel=0.05), k
    for k, v in TRUE.items():
        assert s.rigid[k] == pytest.approx(v, rel=0.02), k
    assert s.form is None and s.converged
    assert s.rms == pytest.approx(0.05, rel=0.1)
    assert fits["cv"].rms > 2 * s.rms                        # cv cannot follow the Stribeck dip
    assert fits["hyperbolic"].rms < 1.1 * s.rms              # six parameters fit as well
    assert set(fits["hyperbolic"].params) == {f"g{i}" for i in range(1, 7)}


def test_stribeck_on_cv_data_is_named_degenerate():
    t, qm, tau = one_link_data(CoulombViscous(c=4.1, v=1.2), seed=4)
    sig = prepare_joint_signals(5, t, qm, tau)
    s = OneLinkIdentifier(models=("stribeck",), n_starts=3).fit_signals(sig, J, B)["stribeck"]
    assert s.form in ("stribeck_as_cv", "stribeck_coulomb_in_Fs")
    # the Coulomb level at speed is still right: Fk - Fs
    assert s.params["Fk"] - s.params["Fs"] == pytest.approx(4.1, rel=0.03)


@pytest.mark.parametrize("model,params,stderr,expected", [
    ("stribeck", {"Fk": 0.001, "Fv": 1.0, "Fs": -4.6, "Vc": 0.005}, {}, "stribeck_coulomb_in_Fs"),
    ("stribeck", {"Fk": 9.18, "Fv": 7.35, "Fs": 0.001, "Vc": 1.0}, {}, "stribeck_as_cv"),
    ("stribeck", {"Fk": 5.0, "Fv": 1.0, "Fs": 0.3, "Vc": 0.1}, {"Fs": 0.2}, "stribeck_as_cv"),
    ("stribeck", {"Fk": 5.0, "Fv": 1.0, "Fs": 1.0, "Vc": 0.1}, {"Fs": 0.01}, None),
    ("hyperbolic", {"g1": 5.0, "g2": 30.0, "g3": 30.2, "g4": 4.0, "g5": 20.0, "g6": 1.0}, {}, "hyperbolic_stribeck_nonunique"),
    ("hyperbolic", {"g1": 5.0, "g2": 160.0, "g3": 5.0, "g4": 5.0, "g5": 4.0, "g6": 0.8},
     {"g1": 4.0, "g2": 5.0, "g3": 0.1}, "hyperbolic_stribeck_nonunique"),
    ("hyperbolic", {"g1": 5.0, "g2": 160.0, "g3": 5.0, "g4": 5.0, "g5": 4.0, "g6": 0.8},
     {"g1": 0.1, "g2": 5.0, "g3": 0.1}, None),
])
def test_name_degenerate(model, params, stderr, expected):
    assert name_degenerate(model, params, stderr, qd=np.array([-2.4, 2.4])) == expected


def _elastic_rise(q, qd, c, xb):
    """A friction that rises linearly with the distance moved since the last reversal and
    saturates at ``c`` after ``xb`` (elastic-plastic; the tests' own sample-by-sample count)."""
    return np.sign(qd) * c * np.minimum(displacement_by_loop(q, qd, 0.0) / xb, 1.0)


def test_presliding_rise_is_cut_and_a_plain_law_is_untouched():
    """One-link data whose friction rises over 0.03 rad after each reversal: the presliding cut
    recovers the sliding Coulomb level within 2 % (the rest cut alone leaves it more than 5 %
    low); data without the rise give the same fit with and without the cut."""
    rng = np.random.default_rng(3)
    t = np.arange(0, 20.0, 0.005)
    q, qd, qdd = SERIES.evaluate(t)
    c, v = 4.1, 1.2
    base = (TRUE["I"] * qdd - TRUE["mglx"] * np.sin(q) + TRUE["mgly"] * np.cos(q) + v * qd
            + rng.normal(0, 0.05, t.size))
    y_rise = base + _elastic_rise(q, qd, c, 0.03)
    cut = OneLinkIdentifier(models=("cv",))
    fit = cut.fit(q, qd, qdd, y_rise)["cv"]
    plain = OneLinkIdentifier(models=("cv",), presliding=False).fit(q, qd, qdd, y_rise)["cv"]
    assert abs(fit.params["c"] / c - 1) < 0.02, fit.params
    assert plain.params["c"] / c < 0.95, plain.params
    assert cut.presliding_["end"] >= 0.03
    y_plain = base + c * np.sign(qd)
    ident = OneLinkIdentifier(models=("cv",))
    a = ident.fit(q, qd, qdd, y_plain)["cv"]
    b = OneLinkIdentifier(models=("cv",), presliding=False).fit(q, qd, qdd, y_plain)["cv"]
    assert ident.presliding_ is None and a.params == b.params


def test_presliding_summary_sentence():
    """The study report's sentence on the presliding cut: counts, cut distances and the level
    without the cut; None when no fit was cut."""
    from types import SimpleNamespace

    from ident.thesis.campaign_fit import FitsResult

    cv = SimpleNamespace(params={"c": 4.0})
    cut = SimpleNamespace(signals={"presliding": {"end": 0.02, "length": 0.004, "gain": 0.5,
                                                  "coulomb_without_cut": 3.0}}, fits={"cv": cv})
    plain = SimpleNamespace(signals={"presliding": None}, fits={"cv": cv})
    text = FitsResult((cut, plain), ("cv",)).presliding_summary()
    assert text.startswith("Presliding cut: 1 of 2 trial-joint fits") and "0.02-0.02 rad" in text
    assert "-25.0 to -25.0 %" in text
    assert FitsResult((plain,), ("cv",)).presliding_summary() is None
