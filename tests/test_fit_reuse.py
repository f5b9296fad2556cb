"""The shortcuts of the per-trial fit (design written in place, remembered evaluations, shared
crossfit smoothings, fused Fourier design) give the same numbers, to the bit, as the plain
computation they replace; seeded data written here with plain numpy."""
from __future__ import annotations

import numpy as np
import pytest

from ident.friction import laws
from ident.friction.fit import _ls_svd, _Projector, _Transform, _VarPro
from ident.friction.static import Hyperbolic, Stribeck
from ident.model.linkstate import _crossfit_grids, _crossfit_smooth, _crossfit_windows
from ident.signals.smoothing import _ordered_design_T


def _speeds(seed, T=2000):
    rng = np.random.default_rng(seed)
    t = np.linspace(0.0, 8.0, T)
    return t, 1.3 * np.sin(1.7 * t) + 0.4 * np.sin(4.1 * t + 0.3) + 0.01 * rng.normal(size=T)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_design_grad_into_one_array_is_the_laws_columns(seed):
    _, qd = _speeds(seed)
    rng = np.random.default_rng(seed)
    Vc = float(10 ** rng.uniform(-2, 0))
    A = np.empty((qd.size, 4))
    Phi, dPhi, _ = Stribeck.design_grad(qd, {"Vc": Vc}, out=A)
    assert np.array_equal(Phi, laws.stribeck_columns(qd, Vc))
    a = np.abs(qd)
    assert np.array_equal(dPhi[:, 0], np.sign(qd) * np.exp(-a / Vc) * a / (Vc * Vc))
    assert np.shares_memory(Phi, A) and np.shares_memory(dPhi, A)
    g2, g3, g5 = (float(v) for v in 10 ** rng.uniform(-1, 2, 3))
    B = np.empty((qd.size, 6))
    Phi, dPhi, _ = Hyperbolic.design_grad(qd, {"g2": g2, "g3": g3, "g5": g5}, out=B)
    assert np.array_equal(Phi, laws.hyperbolic_columns(qd, g2, g3, g5))
    sech2 = [1.0 - np.tanh(g * qd) ** 2 for g in (g2, g3, g5)]
    assert np.array_equal(dPhi, np.column_stack([qd * sech2[0], -(qd * sech2[1]), qd * sech2[2]]))
    Phi2, dPhi2, _ = Hyperbolic.design_grad(qd, {"g2": g2, "g3": g3, "g5": g5})
    assert np.array_equal(Phi2, Phi) and np.array_equal(dPhi2, dPhi)


def test_stribeck_design_grad_rejects_a_negative_Vc():
    with pytest.raises(ValueError, match="Vc must be finite"):
        Stribeck.design_grad(np.linspace(-1, 1, 11), {"Vc": -0.1})


@pytest.mark.parametrize("layout", ["view", "C", "F"])
def test_ls_svd_column_norms_and_solution(layout):
    rng = np.random.default_rng(3)
    full = rng.normal(size=(1500, 5)) * np.array([1e-3, 1.0, 50.0, 2.0, 7.0])
    A = {"view": full[:, :3], "C": np.ascontiguousarray(full[:, :3]),
         "F": np.asfortranarray(full[:, :3])}[layout]
    y = A @ np.array([2.0, -1.0, 0.5]) + 0.01 * rng.normal(size=1500)
    b, U, s, V, nrm = _ls_svd(A, y)
    assert np.array_equal(nrm, np.sqrt(np.einsum("ij,ij->j", A, A)))    # the same sums
    assert np.allclose(b, np.linalg.lstsq(A, y, rcond=None)[0], rtol=1e-10, atol=0)
    assert U.flags["F_CONTIGUOUS"] and np.allclose(U.T @ U, np.eye(3), atol=1e-12)


def _varpro(seed):
    _, qd = _speeds(seed)
    rng = np.random.default_rng(seed)
    tau = laws.hyperbolic_columns(qd, 30.0, 3.0, 8.0) @ np.array([0.5, 2.0, 0.3])
    X = np.column_stack([np.cos(qd), np.sin(2 * qd), np.ones_like(qd)])
    tau = tau + X @ np.array([0.1, -0.2, 0.05]) + 0.01 * rng.normal(size=qd.size)
    sw = np.ones(qd.size)
    tr = _Transform(("g2", "g3", "g5"), {k: (1e-2, 1e3) for k in ("g2", "g3", "g5")})
    return _VarPro(Hyperbolic, ("g2", "g3", "g5"), tr, qd, tau, sw, _Projector(X, sw))


def test_remembered_evaluations_equal_fresh_ones():
    vp = _varpro(4)
    us = [np.log([30.0, 3.0, 8.0]) + d for d in (0.0, 0.1, -0.2, 0.3, 0.05, -0.4)]
    first = [vp.resid(u) for u in us]
    J0 = _varpro(4).jac(us[0])                      # fresh: nothing remembered
    r0 = vp.resid(us[-1])
    assert r0 is not first[-1] and np.array_equal(r0, first[-1])
    r0[:] = 0.0                                     # a caller writing into it changes nothing
    assert np.array_equal(vp.resid(us[-1]), first[-1])
    assert np.array_equal(vp.jac(us[0]), J0)        # forgotten by now: evaluated again
    fresh = _varpro(4)
    for u, r in zip(us, first):
        assert np.array_equal(fresh.resid(u), r)
        assert np.array_equal(fresh.jac(u), _varpro(4).jac(u))


def test_crossfit_windows_that_round_alike_give_the_same_smoothing():
    t = np.arange(0.0, 6.0, 0.005)
    x = np.sin(2.3 * t) + 0.001 * np.random.default_rng(5).normal(size=t.size)
    grids = _crossfit_grids(t, x)
    w1, w2 = 0.004, 0.0056                  # both under the shortest window on the half grid
    assert _crossfit_windows(grids, w1) == _crossfit_windows(grids, w2)
    assert _crossfit_windows(grids, w1) != _crossfit_windows(grids, 0.128)
    a, b = _crossfit_smooth(t, x, w1), _crossfit_smooth(t, x, w2)
    assert all(np.array_equal(p, q) for p, q in zip(a.grid, b.grid))
    assert (a.window_s, a.sigma, a.qd_noise, a.rms) == (b.window_s, b.sigma, b.qd_noise, b.rms)


def test_fourier_design_rows():
    t = np.linspace(0.0, 9.0, 777)
    q = np.cos(t)
    wf, n = 0.83, 7
    XT = _ordered_design_T(t, wf, n, q)
    e = np.exp(1j * wf * t)
    Ek = e.copy()
    for k in range(1, n + 1):               # powers of e, one product at a time
        if k > 1:
            Ek = Ek * e
        assert np.array_equal(XT[2 * k - 1], Ek.imag / (wf * k))
        assert np.array_equal(XT[2 * k], -(Ek.real / (wf * k)))
    assert np.array_equal(XT[0], np.ones_like(t)) and np.array_equal(XT[-1], q)
