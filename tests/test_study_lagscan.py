"""The fits' clock scans (issue 47): the vectorised lag scans of
:mod:`ident.friction.plausibility` rank the lags as the per-lag regressions do, in blocks of any
size, and the checks built on them report the per-lag regression's figures."""
import numpy as np
import pytest

import ident.friction.plausibility as pl


def _case(seed: int, n: int, dt: float, lag: int):
    """A one-link fit's signals (thesis eq. 2-4, Coulomb + viscous) with the torque ``lag``
    samples late, and marker link angles 0.05 s late on a 100 Hz clock."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) * dt
    q = 0.5 * np.sin(2 * np.pi * 0.2 * t + seed) + 0.1 * np.sin(2 * np.pi * 0.7 * t)
    qd = np.gradient(q, dt)
    qdd = np.gradient(qd, dt)
    tau = 2 * qdd + 5 * np.cos(q) + 3 * np.sign(qd) + 4 * qd
    tau = np.roll(tau, lag) + 0.05 * rng.standard_normal(n)
    tm = np.arange(0.0, t[-1], 0.01) + rng.uniform(-0.3, 0.3)
    ql = np.interp(tm + 0.05, t, q) + 1e-4 * rng.standard_normal(tm.size)
    return t, q, qd, qdd, tau, tm, ql


@pytest.mark.parametrize("seed,n,dt,lag,block", [(0, 3000, 0.005, 12, None), (1, 1500, 0.001, -40, None),
                                                  (2, 400, 0.01, 3, 2000)])
def test_torque_lag_scan_ranks_as_the_regressions(seed, n, dt, lag, block, monkeypatch):
    if block is not None:       # blocks of a few lags: the memory bound on long logs
        monkeypatch.setattr(pl, "_SCAN_BLOCK", block)
    t, q, qd, qdd, tau, _, _ = _case(seed, n, dt, lag)
    X = pl._cv_columns(q, qd, qdd)
    mov = np.abs(qd) > 0.05 * np.max(np.abs(qd))
    smax = int(min(round(0.6 / dt), n // 4))
    lags = np.arange(-smax, smax + 1, max(1, int(round(0.005 / dt))))
    ref = np.array([pl._lag_rss(X, tau, mov, int(s)) for s in lags])   # one regression per lag
    got = pl._lag_scan_rss(X, tau, mov, lags)
    fin = np.isfinite(ref)
    assert np.array_equal(fin, np.isfinite(got))
    np.testing.assert_allclose(got[fin], ref[fin], rtol=1e-6)   # RSS from sums: ranks only
    assert np.argmin(got) == np.argmin(ref)
    assert lags[np.argmin(got)] == lag             # the torque's lag, found
    checks = pl.input_checks(t, q, qd, qdd, tau, params={"c": 3.0, "v": 4.0}, rigid={"I": 2.0},
                             stderr={"I": 0.1})
    lagged = [c for c in checks if c.check == "clock_lag"]
    if abs(lag * dt) > pl.CLOCK_LAG_S:
        assert len(lagged) == 1 and lagged[0].value == pytest.approx(lag * dt, abs=1e-12)
        best, zero = ref[np.argmin(ref)], ref[lags == 0][0]
        assert f"{best / zero:.2g} of the unshifted" in lagged[0].says   # the regression's figures
    else:
        assert not lagged


@pytest.mark.parametrize("block", [None, 1500])
def test_marker_clock_scan_ranks_as_the_line_fits(block, monkeypatch):
    if block is not None:
        monkeypatch.setattr(pl, "_SCAN_BLOCK", block)
    t, q, _, _, _, tm, ql = _case(3, 3000, 0.005, 0)
    lags = np.arange(-0.6, 0.6 + 0.0025, 0.005)
    ref = np.array([pl._marker_rss(tm, ql, t, q, s) for s in lags])
    got = pl._marker_lag_rss(tm, ql, t, q, lags)
    fin = np.isfinite(ref)
    assert np.array_equal(fin, np.isfinite(got))
    np.testing.assert_allclose(got[fin], ref[fin], rtol=1e-6)   # sums of a near-exact line fit
    assert np.argmin(got) == np.argmin(ref)
    (chk,) = pl.marker_clock_check(tm, ql, t, q)
    assert chk.value == pytest.approx(0.05, abs=1e-9)
    k0, kb = int(np.argmin(np.abs(lags))), int(np.argmin(ref))
    assert f"{ref[kb] / ref[k0]:.2g} of the unshifted" in chk.says
