"""Link state of a flexible joint (ident.model.linkstate), the data-chosen derivative bandwidth,
the errors-in-variables bias and the physical-validity flags, on seeded data written here with
plain numpy (closed-form trajectories; no jointlab simulator or smoother code)."""
from __future__ import annotations

import numpy as np
import pytest

from ident.friction.base import CoulombViscous
from ident.friction.fit import eiv_bias
from ident.friction.static import Hyperbolic, Stribeck
from ident.model.linkstate import LinkStateEstimator
from ident.signals.smoothing import SavGolSmoother
from ident.thesis import tables

I_L, MGL, C, V = 0.6, 4.0, 3.0, 1.5          # link inertia, gravity moment, Coulomb, viscous


def _flexible_joint(seed, K=2000.0, log_hz=500.0, marker_hz=100.0, marker_sd=1.5e-3, offset=0.02, eps=0.05):
    """A one-link flexible joint with 1.5 s rests before and after a non-periodic motion (two
    chirp-like bursts of different frequencies): link angle q(t) in closed form; the transmitted
    torque y = I q'' + mgl cos q + c tanh(q'/eps) + v q' (friction on the link side); the motor angle
    qm = q + y / K (spring law), quantised, read by an encoder whose zero is ``offset`` off;
    markers = q + noise at their own rate, with gaps."""
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, 12.0, 1.0 / log_hz)
    # smooth bump envelope (C2) around two bursts, zero outside [1.5, 10.5]
    def env(a, b):
        x = np.clip((t - a) / (b - a), 0, 1)
        return np.sin(np.pi * x) ** 3
    w1, w2 = 2 * np.pi * 0.7, 2 * np.pi * 1.9
    q = 0.4 + 0.8 * env(1.5, 6.0) * np.sin(w1 * (t - 1.5)) + 0.25 * env(6.0, 10.5) * np.sin(w2 * (t - 6.0))
    qd = np.gradient(q, t, edge_order=2)
    qdd = np.gradient(qd, t, edge_order=2)
    y = I_L * qdd + MGL * np.cos(q) + C * np.tanh(qd / eps) + V * qd
    qm = q + y / K
    enc = np.round((qm - offset) / 1e-5) * 1e-5
    tau = y + rng.normal(0, 0.02, t.size)
    tm = np.arange(0.1, 11.9, 1.0 / marker_hz)
    qk = np.interp(tm, t, q) + rng.normal(0, marker_sd, tm.size)
    gaps = rng.random(tm.size) < 0.08
    qk[gaps] = np.nan
    return dict(t=t, q=q, qd=qd, qdd=qdd, y=y, tau=tau, qm=enc, tm=tm, qk=qk, K=K)


def test_link_state_beats_the_marker_noise_and_reports_its_errors():
    d = _flexible_joint(0)
    fm = SavGolSmoother("auto").fit(d["t"], d["qm"])
    inner = (d["t"] > 0.5) & (d["t"] < 11.5)
    st = LinkStateEstimator().fit(d["t"][inner], fm, d["tm"], d["qk"], d["tau"][inner], d["K"])
    assert st.method == "encoder+deflection"
    q0, qd0 = d["q"][inner], d["qd"][inner]
    e_q = st.q - q0
    # the encoder's zero offset is found and the link angle is far better than one marker frame (1.5 mrad)
    assert st.deflection.offset == pytest.approx(0.02, abs=3e-4)
    assert np.sqrt(np.mean(e_q ** 2)) < 2e-4
    assert np.sqrt(np.mean((st.qd - qd0) ** 2)) < 0.01 * np.max(np.abs(qd0))
    # the reported standard deviation of q is of the size of the actual error (not 10x off)
    assert 0.1 < np.sqrt(np.mean(e_q ** 2)) / st.errors["q"] < 10
    assert st.deflection.marker_sigma == pytest.approx(1.5e-3, rel=0.1)


def test_encoder_window_of_a_kinked_motor_angle_is_chosen_with_the_deflection():
    """A sharp Coulomb term (eps 2 mrad/s): the motor angle qm = q + y / K steps by 2c/K at each
    reversal while the link angle stays smooth, so GCV smooths the encoder at a narrow window
    (its velocity noise then biases the Coulomb + viscous fit by > 10 %). The link state
    re-smooths the encoder at the window that, with the deflection's, explains eq. 2-4 best."""
    d = _flexible_joint(0, eps=0.002)
    fm = SavGolSmoother("auto").fit(d["t"], d["qm"])
    assert fm.window_s < 0.03                      # the premise: GCV follows the motor's steps
    inner = (d["t"] > 0.5) & (d["t"] < 11.5)
    st = LinkStateEstimator().fit(d["t"][inner], fm, d["tm"], d["qk"], d["tau"][inner], d["K"],
                                  qm_samples=d["qm"][inner])
    assert st.motor_fit.window_s > 3 * fm.window_s
    e_qd = np.sqrt(np.mean((st.qd - d["qd"][inner]) ** 2))
    assert e_qd < 3e-3                             # the GCV window alone: ~5e-2 rad/s
    assert 0.1 < e_qd / st.errors["qd"] < 10
    tau = d["tau"][inner]
    keep = np.abs(st.qd) > 0.01 * np.max(np.abs(st.qd))
    X = np.hstack([np.column_stack([st.qdd, -np.sin(st.q), np.cos(st.q)]),
                   np.sign(st.qd)[:, None], st.qd[:, None]])[keep]
    b, *_ = np.linalg.lstsq(X, tau[keep], rcond=None)
    assert b[3] == pytest.approx(C, rel=0.02) and b[4] == pytest.approx(V, rel=0.02)


def test_softer_than_declared_drive_is_seen_by_the_markers():
    """Declared K = 10x the real stiffness: the markers see a deflection 10x the nominal one.
    (A smooth Coulomb term: on so soft a drive a sharp one would make the motor jump.)"""
    d = _flexible_joint(1, K=400.0, marker_sd=5e-4, eps=0.5)
    fm = SavGolSmoother("auto").fit(d["t"], d["qm"])
    st = LinkStateEstimator().fit(d["t"], fm, d["tm"], d["qk"], d["tau"], 4000.0)
    assert st.deflection.gain == pytest.approx(10.0, rel=0.1)
    assert np.sqrt(np.mean((st.q - d["q"]) ** 2)) < 3e-4


def test_gcv_window_follows_the_data():
    """A fast signal with tiny noise gets a short window, a slow noisy one a long window; the
    reported velocity noise matches the Monte-Carlo scatter of the derivative."""
    t = np.arange(0, 4, 0.001)
    fast = np.sin(2 * np.pi * 6 * t)
    slow = np.sin(2 * np.pi * 0.3 * t)
    rng = np.random.default_rng(2)
    w_fast = SavGolSmoother("auto").fit(t, fast + rng.normal(0, 1e-7, t.size)).window_s
    w_slow = SavGolSmoother("auto").fit(t, slow + rng.normal(0, 1e-3, t.size)).window_s
    assert w_fast < 0.02 < w_slow
    fits = [SavGolSmoother(0.05).fit(t, slow + rng.normal(0, 1e-3, t.size)) for _ in range(20)]
    scatter = np.std([f.evaluate(t[2000:2001])[1][0] for f in fits])
    assert fits[0].qd_noise == pytest.approx(scatter, rel=0.5)


def test_eiv_bias_matches_monte_carlo():
    """Noise of known variance in one regressor column attenuates its coefficient as predicted."""
    rng = np.random.default_rng(3)
    n, beta = 4000, np.array([2.0, -1.0])
    x0 = np.column_stack([rng.normal(0, 1, n), np.ones(n)])
    y = x0 @ beta + rng.normal(0, 0.1, n)
    s = 0.5
    est = []
    for _ in range(60):
        X = x0 + np.column_stack([rng.normal(0, s, n), np.zeros(n)])
        est.append(np.linalg.lstsq(X, y, rcond=None)[0])
    mc = np.mean(est, axis=0) - beta
    col_var = np.column_stack([np.full(n, s ** 2), np.zeros(n)])
    X = x0 + np.column_stack([rng.normal(0, s, n), np.zeros(n)])     # the observed regressor
    pred = eiv_bias(X, beta, np.array([0.002, 0.002]), col_var)
    assert pred["bias"][0] == pytest.approx(mc[0], rel=0.1)       # -2 * 0.25 / 1.25 = -0.4
    assert pred["exceeds_se"]


def test_physical_flags():
    assert Stribeck(Fk=-13.2, Fv=1.0, Fs=-17.3, Vc=0.1).violations()
    assert not Stribeck(Fk=5.7, Fv=1.0, Fs=1.8, Vc=0.05).violations()
    assert not Stribeck(Fk=0.0, Fv=1.0, Fs=-4.0, Vc=1e-4).violations("stribeck_coulomb_in_Fs")
    assert Hyperbolic(g1=0.5, g2=30, g3=3, g4=-1.05, g5=20, g6=2.74).violations()
    assert CoulombViscous(c=-0.1, v=1.0).violations()
    assert not CoulombViscous(c=3.0, v=1.0).violations()


def test_flagged_fits_stay_out_of_condition_means(tmp_path):
    base = {"joint": 5, "load_kg": 0.0, "vmax_frac": 1.0, "model": "stribeck", "rms": 0.3,
            "max_abs_tau": 10.0, "peak_speed": 2.0}
    good = [{**base, "trial": f"r{i}", "repetition": i, "params": {"Fk": 5.0 + 0.1 * i, "Fv": 1.0, "Fs": 1.0, "Vc": 0.05},
             "stderr": {}, "flags": []} for i in range(3)]
    bad = {**base, "trial": "r9", "repetition": 9, "params": {"Fk": -13.2, "Fv": 1.0, "Fs": -17.3, "Vc": 0.1},
           "stderr": {}, "flags": list(Stribeck(Fk=-13.2, Fv=1.0, Fs=-17.3, Vc=0.1).violations())}
    summ = {r["param"]: r for r in tables.summarize(good + [bad])}
    assert summ["Fk"]["mean"] == pytest.approx(5.1) and summ["Fk"]["n_excluded"] == 1
    paths = tables.write_tables(good + [bad], tmp_path, ("stribeck",))
    md = (tmp_path / "tables.md").read_text()
    assert "r9" in md and "Excluded" in md and "-13.2" not in md.split("Excluded")[0]
    assert paths


def test_cosine_basis_equals_the_direct_formula():
    from ident.model.linkstate import _cosine_basis

    t = np.linspace(2.0, 27.0, 3001)
    t0, D, M = 2.0, 25.0, 160
    w = np.pi * np.arange(1, M + 1) / D
    ph = np.multiply.outer(t - t0, w)
    for order, ref in ((0, np.cos(ph)), (1, -np.sin(ph) * w), (2, -np.cos(ph) * w ** 2)):
        np.testing.assert_allclose(_cosine_basis(t, t0, D, M, order), ref, rtol=0,
                                   atol=1e-11 * np.max(np.abs(ref)))
    assert _cosine_basis(t, t0, D, 0).shape == (t.size, 0)
