"""ident.signals.smoothing: Fourier fits (eq. 3-2) with estimated fundamental and harmonics, the
non-periodic fallback, clock offsets and the angles CSV reader (:mod:`mocap.io.angles`), on seeded synthetic data."""
from __future__ import annotations

import numpy as np
import pytest

from ident.signals.fourier import FourierSeries
from ident.signals.smoothing import (FourierSmoother, SavGolSmoother, estimate_fundamental,
                                    estimate_time_offset, select_harmonics)
from ident.model.linkstate import prepare_joint_signals
from mocap.io.angles import read_angles
from mocap.io.errors import InputError

SERIES = FourierSeries(np.array([0.5, -0.3, 0.2, 0.1, -0.05]), np.array([0.2, 0.1, -0.3, 0.05, 0.02]),
                       2 * np.pi / 10, 0.3)


@pytest.mark.parametrize("duration,dt,start", [(10.0, 0.005, 0.0), (30.0, 0.005, 12.3), (23.7, 0.002, -4.0)])
def test_fundamental_harmonics_and_derivatives(duration, dt, start):
    rng = np.random.default_rng(0)
    t = start + np.arange(0, duration, dt)
    q = SERIES.evaluate(t)[0] + rng.normal(0, 1e-4, t.size)
    fit = FourierSmoother().fit(t, q)
    assert fit.method == "fourier"
    assert fit.wf == pytest.approx(SERIES.wf, rel=2e-5)
    assert fit.n_harmonics == 5
    assert fit.rms == pytest.approx(1e-4, rel=0.1)          # the noise, nothing more
    _, qd, qdd = fit.evaluate(t)
    _, qd0, qdd0 = SERIES.evaluate(t)
    assert np.max(np.abs(qd - qd0)) < 1e-4                   # rad/s, peak speed ~1.3
    assert np.max(np.abs(qdd - qdd0)) < 3e-4                 # rad/s^2


def test_select_harmonics_by_bic():
    rng = np.random.default_rng(1)
    t = np.arange(0, 10, 0.005)
    s3 = FourierSeries(SERIES.a[:3], SERIES.b[:3], SERIES.wf, 0.0)
    q = s3.evaluate(t)[0] + rng.normal(0, 1e-4, t.size)
    n, _ = select_harmonics(t, q, SERIES.wf, max_harmonics=12)
    assert n == 3


def test_non_periodic_falls_back_to_smoother():
    rng = np.random.default_rng(2)
    t = np.arange(0, 8, 0.005)
    q = 0.4 * t + 0.2 * np.sin(0.9 * t ** 1.3)          # drifts: not one or more periods
    qd0 = 0.4 + 0.2 * np.cos(0.9 * t ** 1.3) * 0.9 * 1.3 * t ** 0.3
    fit = FourierSmoother().fit(t, q + rng.normal(0, 1e-4, t.size))
    assert fit.method == "savgol"
    inner = (t > 0.2) & (t < 7.8)
    assert np.max(np.abs(fit.evaluate(t)[1][inner] - qd0[inner])) < 1e-2   # SG noise gain ~2e-3 rms


def test_forced_periodic_and_smoother_settings():
    t = np.arange(0, 10, 0.01)
    q = SERIES.evaluate(t)[0]
    assert FourierSmoother(wf=SERIES.wf, n_harmonics=5, periodic=True).fit(t, q).rms < 1e-12
    with pytest.raises(ValueError):
        SavGolSmoother(window_s=-1)


def test_fundamental_of_three_periods():
    rng = np.random.default_rng(3)
    t = np.arange(0, 30, 0.01)
    q = SERIES.evaluate(t)[0] + rng.normal(0, 2e-4, t.size)
    assert estimate_fundamental(t, q) == pytest.approx(SERIES.wf, rel=1e-4)


def test_time_offset_and_two_clocks(tmp_path):
    """Link angles on a 100 Hz marker clock shifted by 37 ms, motor on a 500 Hz robot clock."""
    rng = np.random.default_rng(4)
    t_log = 100.0 + np.arange(0, 20, 0.002)
    qm = SERIES.evaluate(t_log)[0] + rng.normal(0, 2e-5, t_log.size)
    tau = np.sin(t_log)
    offset = 0.037                                   # t_robot = t_marker + offset
    t_mk = 100.5 + np.arange(0, 18.5, 0.01) - offset
    deflection = 0.002
    q_link = SERIES.evaluate(t_mk + offset)[0] - deflection + rng.normal(0, 5e-4, t_mk.size)
    fm = FourierSmoother().fit(t_log, qm)
    assert estimate_time_offset(t_mk, q_link, fm) == pytest.approx(offset, abs=2e-3)
    sig = prepare_joint_signals(3, t_log, qm, tau, t_mk, q_link, time_offset="estimate")
    assert sig.link_source == "mocap"
    assert sig.time[0] >= t_mk[0] + offset - 1e-9 and sig.time[-1] <= t_mk[-1] + offset + 1e-9
    q_true, qd_true, _ = SERIES.evaluate(sig.time)
    assert np.max(np.abs(sig.q - (q_true - deflection))) < 5e-4
    assert np.max(np.abs(sig.qd - qd_true)) < 5e-3
    assert np.degrees(sig.link_fit.rms) < 0.2 and np.degrees(sig.motor_fit.rms) < 0.05  # thesis bounds
    d = sig.to_dict()
    assert d["link_source"] == "mocap" and d["link_fit"]["method"] == "fourier"
    # no link angles: motor stands in
    sig_m = prepare_joint_signals(3, t_log, qm, tau)
    assert sig_m.link_source == "motor" and np.allclose(sig_m.q, sig_m.qm)


def test_read_angles(tmp_path):
    p = tmp_path / "a.csv"
    p.write_text("time,q_2,q_5,rms_mm,n_markers\n0.0,0.1,,0.4,3\n0.01,0.2,0.3,0.5,4\n", encoding="utf-8")
    a = read_angles(p)
    assert list(a.q) == [2, 5] and np.isnan(a.q[5][0]) and a.q[2][1] == 0.2
    assert a.n_markers.tolist() == [3, 4]
    bad = tmp_path / "b.csv"
    bad.write_text("time,q_1\n0.0,0.1\n0.01,zz\n", encoding="utf-8")
    with pytest.raises(InputError, match="line 3"):
        read_angles(bad)
    back = tmp_path / "c.csv"
    back.write_text("time,q_1\n0.0,0.1\n0.0,0.2\n", encoding="utf-8")
    with pytest.raises(InputError, match="strictly increasing"):
        read_angles(back)


def test_rests_before_and_after_are_trimmed():
    """A trial holds still 0.5 s, runs two periods of eq. 3-2, holds 0.5 s (as real trials do):
    the Fourier fit covers the moving span only and still finds wf."""
    rng = np.random.default_rng(6)
    s0 = FourierSeries(SERIES.a - SERIES.a.mean(),
                       SERIES.b - np.arange(1, 6) * (np.arange(1, 6) @ SERIES.b) / 55.0, SERIES.wf, 0.3)
    t = np.arange(0, 21, 0.005)
    tm = np.clip(t - 0.5, 0, 20.0)                       # moving clock, frozen in the holds
    q = s0.evaluate(tm)[0] + rng.normal(0, 1e-4, t.size)
    fit = FourierSmoother().fit(t, q)
    assert fit.method == "fourier"
    assert fit.wf == pytest.approx(SERIES.wf, rel=1e-4)
    assert fit.t_start < 0.75 and fit.t_end > 20.25       # most of the motion kept
    assert fit.t_start > 0.45 and fit.t_end < 20.55       # the holds left out
    inner = (t > fit.t_start) & (t < fit.t_end)
    assert np.max(np.abs(fit.evaluate(t[inner])[1] - s0.evaluate(tm[inner])[1])) < 2e-3


# ---------------------------------------------------------------------------------------------
# fast paths (issue 13): the same values as the direct computations
# ---------------------------------------------------------------------------------------------
@pytest.mark.parametrize("w", [5, 13, 41, 81])
def test_cached_savgol_equals_scipy_savgol_filter(w):
    from scipy.signal import savgol_filter

    from mocap.numerics import savgol

    rng = np.random.default_rng(31)
    x = np.cumsum(rng.normal(size=1500)) * 0.01 + np.sin(np.arange(1500) * 0.02)
    for deriv in (0, 1, 2):
        ref = savgol_filter(x, w, 3, deriv=deriv, delta=0.005, mode="interp")
        np.testing.assert_allclose(savgol(x, w, 3, deriv, 0.005), ref, rtol=0,
                                   atol=1e-10 * np.max(np.abs(ref)))


def test_rss_by_harmonics_equals_least_squares_per_N():
    from ident.signals.fourier import design_matrix
    from ident.signals.smoothing import _rss_by_harmonics

    rng = np.random.default_rng(32)
    t = 3.0 + np.arange(0, 17.3, 0.01)
    q = SERIES.evaluate(t)[0] + 0.01 * np.sin(0.37 * t) + rng.normal(0, 1e-3, t.size)
    wf = 2 * np.pi / 9.7                     # off the true fundamental: every N leaves residual
    rss = _rss_by_harmonics(t, q, wf, 12)
    for n in range(1, 13):
        X = design_matrix(t, wf, n)
        r = q - X @ np.linalg.lstsq(X, q, rcond=None)[0]
        assert rss[n - 1] == pytest.approx(float(r @ r), rel=1e-6), n


def test_rss_by_harmonics_near_nyquist_matches_least_squares():
    """Harmonics at and beyond the Nyquist rate make the Gram matrix singular: the QR path
    takes over and the RSS still equals a least-squares fit's."""
    from ident.signals.fourier import design_matrix
    from ident.signals.smoothing import _rss_by_harmonics, _rss_by_harmonics_qr

    rng = np.random.default_rng(5)
    t = np.arange(0, 2.0, 0.05)                     # 20 Hz sampling: Nyquist 10 Hz
    q = np.sin(2 * np.pi * 0.7 * t) + rng.normal(0, 1e-2, t.size)
    wf = 2 * np.pi * 1.0                            # harmonic 10 sits on Nyquist
    rss = _rss_by_harmonics(t, q, wf, 12)
    np.testing.assert_allclose(rss, _rss_by_harmonics_qr(t, q, wf, 12), rtol=1e-6)
    for n in (1, 5, 9):
        X = design_matrix(t, wf, n)
        r = q - X @ np.linalg.lstsq(X, q, rcond=None)[0]
        assert rss[n - 1] == pytest.approx(float(r @ r), rel=1e-6), n


def test_rss_by_harmonics_ignores_a_large_constant_offset():
    """The constant is in the model: an angle far from zero (a motor angle after many turns) has
    the RSS of the same motion about zero, not one lost to cancellation in q^T q."""
    from ident.signals.fourier import design_matrix
    from ident.signals.smoothing import _rss_by_harmonics

    rng = np.random.default_rng(11)
    t = np.arange(0, 20, 0.005)
    q0 = 10 * np.sin(0.7 * t) + 3 * np.cos(1.4 * t + 0.2) + rng.normal(0, 1e-4, t.size)
    X = design_matrix(t, 0.7, 3)
    r = q0 - X @ np.linalg.lstsq(X, q0, rcond=None)[0]
    for offset in (0.0, 1e2, 1e4):
        assert _rss_by_harmonics(t, q0 + offset, 0.7, 6)[2] == pytest.approx(float(r @ r), rel=1e-4), offset
