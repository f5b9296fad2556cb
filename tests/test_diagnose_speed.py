"""The diagnosis' faster routes (issue 47) give what the plain ones give: the batched fold fits,
the padded block products, the compacted nuisance projection, and plots laid out without
measuring text (benchmarks/diagnose_speed.py times them)."""
from __future__ import annotations

import numpy as np
import pytest

from ident.gap.engine import Grams, _best_fit, _outer_sums, cross_validate, grams


def _grams_by_hp(rng, n=3000, nb=30, k=2, hps=8):
    bounds = np.column_stack([np.arange(nb) * (n // nb), np.arange(1, nb + 1) * (n // nb)])
    X = rng.normal(size=(n, 3))
    r = X @ np.array([1.0, 2.0, 3.0]) + rng.normal(size=n)
    out = {}
    for hp in range(hps):
        C = rng.normal(size=(n, k)) * (1 + hp)
        if hp == 3:
            C[: n // 2] = 0.0   # lives on the late blocks only: unsupported where they are held out
        out[hp] = grams(np.column_stack([X, C]), r, bounds)
    return out, nb


def test_batched_fold_fits_choose_and_fit_what_the_loop_does():
    from ident.gap.engine import _best_fits

    rng = np.random.default_rng(3)
    gb, nb = _grams_by_hp(rng)
    masks = np.array([np.arange(nb) // 3 != f for f in range(10)]
                     + [np.ones(nb, bool), np.arange(nb) >= nb // 2, np.arange(nb) < nb // 2])
    loop, batch = [_best_fit(gb, m) for m in masks], _best_fits(gb, masks)
    assert [x[1] for x in loop] == [x[1] for x in batch]
    for (s0, _, th0), (s1, _, th1) in zip(loop, batch):
        assert s1 == pytest.approx(s0, rel=1e-10)
        np.testing.assert_allclose(th1, th0, rtol=1e-9, atol=1e-12)
    # the shape that lives on the late blocks is not chosen where they are all held out
    assert batch[-1][1] != 3 and _best_fit(gb, masks[-1])[1] != 3


def test_batched_fold_fits_fall_back_on_a_non_finite_block():
    from ident.gap.engine import _best_fits

    rng = np.random.default_rng(4)
    gb, nb = _grams_by_hp(rng, hps=3)
    g = gb[1]
    G = g.G.copy()
    G[0, -1, -1] = np.inf          # one infinite block: never trained on where it is masked out
    gb[1] = Grams(G, g.b, g.yy, g.n)
    masks = np.array([np.arange(nb) != 0, np.arange(nb) > 5])
    loop, batch = [_best_fit(gb, m) for m in masks], _best_fits(gb, masks)
    assert [x[1] for x in loop] == [x[1] for x in batch]
    assert batch[0][0] == pytest.approx(loop[0][0], rel=1e-12)


def test_cross_validation_fits_every_fold_in_one_batch_as_fold_by_fold(monkeypatch):
    import ident.gap.engine as engine

    rng = np.random.default_rng(5)
    gb, nb = _grams_by_hp(rng)
    fold = np.arange(nb) // 3
    guard = {2: (np.abs(np.arange(nb) // 3 - 2) == 1)}
    batches = []
    real = engine._best_fits
    monkeypatch.setattr(engine, "_best_fits", lambda g, masks: batches.append(masks.shape) or real(g, masks))
    cv = cross_validate(gb, fold, guard=guard)
    assert batches == [(10, nb)]     # the 10 folds (the fit on all blocks: _best_fit)
    for f in np.unique(fold):
        train = (fold != f) & ~guard.get(f, np.zeros(nb, bool))
        s, hp, th = _best_fit(gb, train)
        assert cv.hp_per_fold[f] == hp
        np.testing.assert_allclose(cv.theta_per_fold[f], th, rtol=1e-9, atol=1e-12)
    s, hp, th = _best_fit(gb, np.ones(nb, bool))
    assert cv.hp_all == hp and cv.train_sse_all == pytest.approx(s, rel=1e-10)


def test_short_units_take_one_padded_batched_product(monkeypatch):
    """Units of ~40 samples within cycles (the sample-level test's blocks): the per-block products,
    in one batched product over the zero-padded units."""
    import ident.gap.engine as engine

    rng = np.random.default_rng(6)
    n = 8000
    starts = sorted({s for c0 in range(0, n, 800) for s in range(c0, min(c0 + 800, n), 37)})
    bounds = np.column_stack([starts, np.r_[starts[1:], n]])
    calls = []
    real = engine._padded_sums
    monkeypatch.setattr(engine, "_padded_sums", lambda *a: calls.append(1) or real(*a))
    for p, k in [(1, 1), (6, 1), (9, 4), (12, 30)]:
        A, B = rng.normal(size=(n, p)), rng.normal(size=(n, k))
        ref = np.array([A[a:b].T @ B[a:b] for a, b in bounds])
        np.testing.assert_allclose(_outer_sums(A, B, bounds), ref, rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(_outer_sums(A, A, bounds), np.array([A[a:b].T @ A[a:b] for a, b in bounds]),
                                   rtol=1e-12, atol=1e-12)
    assert len(calls) == 8


def test_compacted_nuisance_projects_as_the_full_one():
    from ident.gap.channels import Channel, _compact_nuisance

    rng = np.random.default_rng(7)
    n, p = 2000, 12
    A = np.asfortranarray(rng.normal(size=(n, p)))
    A[:, [1, 4, 5, 11]] = 0.0       # parameters that do not act on this joint
    M = rng.normal(size=(p, p))
    M = M @ M.T
    X = rng.normal(size=(n, 3))
    # the compact form is B = A_live L with M_live = L L^T, applied as X - B (B^T X)
    B, none = _compact_nuisance(A, M)
    assert B.shape == (n, 8) and none is None and B.flags.c_contiguous
    live = [0, 2, 3, 6, 7, 8, 9, 10]
    np.testing.assert_allclose(B @ B.T, A[:, live] @ M[np.ix_(live, live)] @ A[:, live].T, rtol=1e-9,
                               atol=1e-9 * np.abs(M).max() * p)
    full = Channel("torque", "N m", np.zeros(n), np.zeros((n, 0)), np.zeros(n, int), np.array([[0, n]]), False,
                   nuisance=(A, M))
    compact = Channel("torque", "N m", np.zeros(n), np.zeros((n, 0)), np.zeros(n, int), np.array([[0, n]]), False,
                      nuisance=(B, none))
    ref = full.prep_effect(X)
    np.testing.assert_allclose(compact.prep_effect(X), ref, rtol=1e-10, atol=1e-10 * np.abs(ref).max())
    # column-major candidates keep their layout (each shape's columns contiguous in a batch)
    XF = np.asfortranarray(X)
    out = compact.prep_effect(XF)
    assert out.flags.f_contiguous
    np.testing.assert_allclose(out, ref, rtol=1e-10, atol=1e-10 * np.abs(ref).max())


def test_diagnosis_plots_need_no_tight_layout_and_hold_their_labels(tmp_path, monkeypatch):
    """The report's figures are laid out with fixed margins (no text measured for a tight layout),
    and the longest effect name, the axis labels and the title still lie inside the figure."""
    from matplotlib.figure import Figure

    import ident.gap.report as report
    import viz.plots as vp

    def refuse(*a, **k):
        raise AssertionError("tight layout called")

    monkeypatch.setattr(Figure, "tight_layout", refuse)
    figs = []
    real_save = vp.save_png
    monkeypatch.setattr(report, "save_png", lambda fig, path, **kw: figs.append(fig) or real_save(fig, path, **kw))
    rng = np.random.default_rng(8)
    n = 5000
    rep = {"joints": {"2": {
        "localisation": [{"regime": "low speed (|v| < 5 % of max)", "share": 0.6},
                         {"regime": "reversals", "share": 0.4}],
        "effects": [{"effect": "nonlinear_viscous", "reduction": 0.2, "significant": True},
                    {"effect": "position_ripple", "reduction": 0.05, "significant": False}]}}}
    series = {"2": {"qd": rng.normal(size=n), "residual_nominal": rng.normal(size=n),
                    # within one decade: log axes label their minor ticks ("2 x 10^-3"), the widest
                    "spectrum": {"f": np.linspace(0, 500, 200), "psd": 1e-3 * (1 + 2 * rng.random(200)),
                                 "floor": 1.6e-3}}}
    paths = report.make_plots(rep, series, tmp_path)
    assert set(paths) == {"joint2_localisation", "joint2_effects", "joint2_residual", "joint2_spectrum"}
    assert all((tmp_path / f).is_file() for f in paths.values())
    assert len(figs) == 4
    for fig in figs:   # everything drawn on the axes (tick labels, labels, title) inside the figure
        b = fig.axes[0].get_tightbbox(fig.canvas.get_renderer())
        assert b.x0 >= 0 and b.y0 >= 0 and b.x1 <= fig.bbox.width and b.y1 <= fig.bbox.height, b


def test_candidates_of_one_step_share_the_padded_design_of_their_base():
    """On short units every candidate's Gram blocks are those of ``[X | C]``, with ``X``'s padded
    block stack made once per selection step (kept on the base Grams)."""
    from ident.gap.engine import grams_augmented, own_blocks

    rng = np.random.default_rng(9)
    n = 6000
    starts = sorted({s for c0 in range(0, n, 700) for s in range(c0, min(c0 + 700, n), 41)})
    bounds = np.column_stack([starts, np.r_[starts[1:], n]])
    X, r = rng.normal(size=(n, 5)), rng.normal(size=n)
    base = grams(X, r, bounds)
    made = []
    for k in (1, 3):
        C = rng.normal(size=(n, k))
        g = grams_augmented(base, X, C, r, bounds)
        ref = grams(np.column_stack([X, C]), r, bounds)
        np.testing.assert_allclose(g.G, ref.G, rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(g.b, ref.b, rtol=1e-12, atol=1e-12)
        again = grams_augmented(base, X, C, r, bounds, own_blocks(g, k))
        assert np.array_equal(again.G, g.G) and np.array_equal(again.b, g.b)
        made.append(base.padded["XT"])
    assert made[0] is made[1]

