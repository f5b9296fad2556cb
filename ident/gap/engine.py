"""Cross-validated comparison of a nominal model against augmented models, per channel.

All fits are linear least squares on per-block Gram matrices (a block: a motion cycle, or a
short unit of one), so leave-one-fold-out cross-validation, grid searches over shape parameters
and bootstrap resampling over blocks cost sums of
small matrices rather than refits on the samples.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


def trial_bounds(trial: np.ndarray, n_trials: int) -> np.ndarray:
    """Start/end sample of each trial in a trial-sorted sample vector: (n_trials, 2)."""
    starts = np.searchsorted(trial, np.arange(n_trials), side="left")
    ends = np.searchsorted(trial, np.arange(n_trials), side="right")
    return np.column_stack([starts, ends])


@dataclass
class Grams:
    G: np.ndarray   # (n_blocks, p, p)
    b: np.ndarray   # (n_blocks, p)
    yy: np.ndarray  # (n_blocks,)
    n: np.ndarray   # (n_blocks,) samples
    # the zero-padded block rows of the columns and target these Grams were built from, kept for
    # the candidates that augment them (_padded_base); short blocks only
    padded: dict | None = field(default=None, repr=False, compare=False)


def _outer_sums(A: np.ndarray, B: np.ndarray, bounds: np.ndarray) -> np.ndarray:
    """Per block ``A_blk^T B_blk``: (n_blocks, p, k). Blocks of many samples (motion cycles):
    one BLAS product per block; many short blocks of similar length: one batched product over
    the blocks zero-padded to the longest; otherwise chunks of the (N, p, k) products summed
    per block."""
    nt, p, k = bounds.shape[0], A.shape[1], B.shape[1]
    out = np.zeros((nt, p, k))
    if nt == 0 or p == 0 or k == 0:
        return out
    step = max(1, int(2e7 // max(p * k, 1)))     # samples per chunk of the (N, p, k) products
    s, e = bounds[:, 0], bounds[:, 1]
    if _per_block(bounds):
        AT = A.T
        for i, (a, b) in enumerate(bounds.tolist()):  # loop over blocks
            if b > a:
                np.dot(AT[:, a:b], B[a:b], out=out[i])
        return out
    if _short_blocks(bounds):
        return _padded_sums(A, B, bounds)
    i0 = 0
    while i0 < nt:   # loop over chunks of whole blocks
        i1 = int(np.searchsorted(e, s[i0] + step, side="right"))
        i1 = max(i1, i0 + 1)
        lo, hi = s[i0], e[i1 - 1]
        P = A[lo:hi, :, None] * B[lo:hi, None, :]
        out[i0:i1] = np.add.reduceat(P, s[i0:i1] - lo, axis=0)
        i0 = i1
    return out


def _short_blocks(bounds: np.ndarray) -> bool:
    """Whether blocks that :func:`_per_block` does not take one by one are of similar length
    (zero-padded to the longest they hold at most twice their rows): :func:`_padded_sums`."""
    lens = bounds[:, 1] - bounds[:, 0]
    return bool(lens.size and lens.min() > 0 and lens.size * int(lens.max()) <= 2 * int(lens.sum()))


def _padding(bounds: np.ndarray, n_rows: int) -> tuple:
    """(rows, pad): the ``(n_blocks, L)`` row of every slot of the zero-padded block stack and
    the slots beyond each block's end (``L`` the longest block)."""
    s, lens = bounds[:, 0], bounds[:, 1] - bounds[:, 0]
    at = np.arange(int(lens.max()))
    return np.minimum(s[:, None] + at[None, :], n_rows - 1), at[None, :] >= lens[:, None]


def _pad(Z: np.ndarray, padding: tuple) -> np.ndarray:
    """``Z``'s rows as the zero-padded ``(n_blocks, L, cols)`` block stack of ``padding``."""
    Zp = Z[padding[0]]
    Zp[padding[1]] = 0.0
    return Zp


def _padded_sums(A: np.ndarray, B: np.ndarray, bounds: np.ndarray) -> np.ndarray:
    """:func:`_outer_sums` of short blocks of similar length (the units of the sample-level
    test): each block's rows as one slice of a zero-padded ``(n_blocks, L, .)`` stack (``L`` the
    longest block), all blocks in one batched matmul; the padding's zero rows add exact zeros.
    Memory ``n_blocks L (p + k)`` against the chunks' ``N p k``."""
    padding = _padding(bounds, A.shape[0])
    Ap = _pad(A, padding)
    return np.matmul(Ap.transpose(0, 2, 1), Ap if B is A else _pad(B, padding))


def _padded_base(base: "Grams", X: np.ndarray, r: np.ndarray, bounds: np.ndarray) -> dict:
    """The padded block stacks of the columns ``X`` and target ``r`` that ``base`` was built
    from, made once and kept on ``base`` (every candidate of a selection step augments the same
    ``X``): padding, ``X`` (n_blocks, L, p) and ``r`` (n_blocks, L, 1)."""
    pb = base.padded
    if pb is None or pb["X_src"] is not X or pb["r_src"] is not r or not np.array_equal(pb["bounds"], bounds):
        padding = _padding(bounds, X.shape[0])
        pb = {"X_src": X, "r_src": r, "bounds": bounds.copy(), "padding": padding,
              "XT": _pad(X, padding).transpose(0, 2, 1), "r": _pad(r[:, None], padding)}
        base.padded = pb
    return pb


def _per_block(bounds: np.ndarray) -> bool:
    """Whether :func:`_outer_sums` takes one BLAS product per block: blocks of many samples
    (64 on average), or blocks that do not tile one range."""
    s, e = bounds[:, 0], bounds[:, 1]
    return bool(not (np.all(e > s) and np.all(s[1:] == e[:-1])) or e[-1] - s[0] >= 64 * bounds.shape[0])


def _augmented_sums(X: np.ndarray, C: np.ndarray, r: np.ndarray, bounds: np.ndarray) -> tuple:
    """``_outer_sums`` of ``(X, C)``, ``(C, C)`` and ``(C, r)`` (the same products, block by
    block, in one pass over the blocks)."""
    if bounds.shape[0] == 0 or X.shape[1] == 0 or not _per_block(bounds):
        return (_outer_sums(X, C, bounds), _outer_sums(C, C, bounds),
                _outer_sums(C, r[:, None], bounds)[:, :, 0])
    nt, p, k = bounds.shape[0], X.shape[1], C.shape[1]
    XC, CC, Cr = np.zeros((nt, p, k)), np.zeros((nt, k, k)), np.zeros((nt, k, 1))
    XT, CT, R = X.T, C.T, r[:, None]
    dot = np.dot    # the BLAS products of np.matmul (gemm, syrk, gemv), with less overhead
    for i, (a, b) in enumerate(bounds.tolist()):   # loop over blocks
        if b > a:
            c, ct = C[a:b], CT[:, a:b]
            dot(XT[:, a:b], c, out=XC[i])
            dot(ct, c, out=CC[i])
            dot(ct, R[a:b], out=Cr[i])
    return XC, CC, Cr[:, :, 0]


def grams(X: np.ndarray, r: np.ndarray, bounds: np.ndarray) -> Grams:
    """Per-block Gram matrices ``X^T X``, ``X^T r`` and ``r^T r`` (vectorised over samples)."""
    G = _outer_sums(X, X, bounds)
    b = _outer_sums(X, r[:, None], bounds)[:, :, 0]
    yy = _outer_sums(r[:, None], r[:, None], bounds)[:, 0, 0]
    return Grams(G, b, yy, bounds[:, 1] - bounds[:, 0])


def grams_augmented(base: Grams, X: np.ndarray, C: np.ndarray, r: np.ndarray,
                    bounds: np.ndarray, own: tuple | None = None) -> Grams:
    """Grams of ``[X | C]`` given the Grams of ``X`` alone (only the new blocks are computed).
    ``own``: the blocks ``C^T C`` and ``C^T r`` of these columns, (n_blocks, k, k) and
    (n_blocks, k), when an earlier call computed them (:func:`own_blocks`)."""
    if C.shape[1] == 0:
        return base
    nt, p, k = bounds.shape[0], X.shape[1], C.shape[1]
    G = np.zeros((nt, p + k, p + k))
    b = np.zeros((nt, p + k))
    G[:, :p, :p] = base.G
    b[:, :p] = base.b
    if p and nt and not _per_block(bounds) and _short_blocks(bounds):
        # the units of the sample-level test: one padded stack of C, X's and r's kept on base
        pb = _padded_base(base, X, r, bounds)
        Cp = _pad(C, pb["padding"])
        CpT = Cp.transpose(0, 2, 1)
        XC = np.matmul(pb["XT"], Cp)
        CC, Cr = own if own is not None else (np.matmul(CpT, Cp), np.matmul(CpT, pb["r"])[:, :, 0])
    elif own is not None:
        XC, (CC, Cr) = _outer_sums(X, C, bounds), own
    else:
        XC, CC, Cr = _augmented_sums(X, C, r, bounds)
    G[:, :p, p:] = XC
    G[:, p:, :p] = np.swapaxes(XC, 1, 2)
    G[:, p:, p:] = CC
    b[:, p:] = Cr
    return Grams(G, b, base.yy, base.n)


def own_blocks(g: Grams, k: int) -> tuple:
    """The blocks of the last ``k`` columns of ``g`` with themselves and with the target (the
    ``own`` of :func:`grams_augmented`)."""
    return g.G[:, -k:, -k:].copy(), g.b[:, -k:].copy()


def _solve(G: np.ndarray, b: np.ndarray) -> np.ndarray:
    lam = 1e-10 * max(np.trace(G), 1e-300) / G.shape[0]
    return np.linalg.solve(G + lam * np.eye(G.shape[0]), b)


def sse_with(theta: np.ndarray, gr: Grams, idx) -> np.ndarray:
    G, b, yy = gr.G[idx], gr.b[idx], gr.yy[idx]
    return yy - 2 * b @ theta + np.einsum("i,nij,j->n", theta, G, theta)


@dataclass
class CVResult:
    sse: np.ndarray            # (n_blocks,) held-out SSE of each block
    hp_per_fold: dict          # fold -> chosen shape parameter
    theta_all: np.ndarray      # fit on all blocks with the hp chosen on all blocks
    hp_all: object
    train_sse_all: float
    theta_per_fold: dict = field(default_factory=dict)  # fold -> theta fitted without it


MIN_SUPPORT = 0.2  # a column's share of its energy on the training blocks, over their share of samples


def _supported(gr: Grams, mask: np.ndarray) -> bool:
    """Whether every column has a fair part of its energy on the ``mask`` blocks: at least
    :data:`MIN_SUPPORT` times their share of the samples. A shape that lives on the held-out
    blocks alone (a warm-up faster than the first trial, fitted on later trials where its column
    is nearly zero) is an extrapolation whose amplitude the training data does not determine."""
    e = np.einsum("nii->ni", gr.G)              # (blocks, columns) column energy per block
    tot = e.sum(axis=0)
    frac_n = gr.n[mask].sum() / max(gr.n.sum(), 1)
    ok = tot <= 0
    ok |= e[mask].sum(axis=0) >= MIN_SUPPORT * frac_n * tot
    return bool(ok.all())


def _best_fit(grams_by_hp: dict, mask: np.ndarray):
    """(training SSE, hp, theta) of the shape parameter with the least SSE on ``mask`` blocks,
    among the shapes the training blocks support (:func:`_supported`; all when none is)."""
    cands = {hp: gr for hp, gr in grams_by_hp.items() if _supported(gr, mask)} if not mask.all() else grams_by_hp
    best = None
    for hp, gr in (cands or grams_by_hp).items():
        Gs, bs = gr.G[mask].sum(0), gr.b[mask].sum(0)
        th = _solve(Gs, bs)
        sse = gr.yy[mask].sum() - 2 * bs @ th + th @ Gs @ th
        if best is None or sse < best[0]:
            best = (float(sse), hp, th)
    return best


def _best_fits(grams_by_hp: dict, masks: np.ndarray) -> list:
    """:func:`_best_fit` for every row of ``masks`` (n_masks, n_blocks) at once, the same choice
    by the same rules: per shape parameter the training sums of every mask are one matrix
    product (``masks @ G``), the supports (:func:`_supported`), the ridge solves and the training
    SSEs are batched over the masks. Only the order of the block sums differs from
    :func:`_best_fit` (rounding). Falls back to :func:`_best_fit` per mask where a shape's Grams
    are not finite (a masked-out infinite block must not enter as ``0 * inf``) or a solve fails."""
    keys = list(grams_by_hp)
    W = masks.astype(float)
    m = W.shape[0]
    every = masks.all(axis=1)           # no support check where every block trains
    sse, sup, thetas = np.empty((len(keys), m)), np.empty((len(keys), m), bool), []
    for i, hp in enumerate(keys):
        gr = grams_by_hp[hp]
        nb, q = gr.G.shape[0], gr.G.shape[1]
        if q == 0 or not (np.isfinite(gr.G).all() and np.isfinite(gr.b).all() and np.isfinite(gr.yy).all()):
            return [_best_fit(grams_by_hp, mk) for mk in masks]
        Gs = (W @ gr.G.reshape(nb, q * q)).reshape(m, q, q)
        bs = W @ gr.b
        e = np.einsum("nii->ni", gr.G)              # (blocks, columns) column energy per block
        tot = e.sum(axis=0)
        frac_n = (W @ gr.n) / max(gr.n.sum(), 1)
        ok = (tot <= 0)[None, :] | ((W @ e) >= MIN_SUPPORT * frac_n[:, None] * tot[None, :])
        sup[i] = ok.all(axis=1) | every
        lam = 1e-10 * np.maximum(np.trace(Gs, axis1=1, axis2=2), 1e-300) / q
        try:
            th = np.linalg.solve(Gs + lam[:, None, None] * np.eye(q), bs[:, :, None])[:, :, 0]
        except np.linalg.LinAlgError:
            return [_best_fit(grams_by_hp, mk) for mk in masks]
        sse[i] = W @ gr.yy - 2 * np.einsum("mi,mi->m", bs, th) + np.einsum("mi,mij,mj->m", th, Gs, th)
        thetas.append(th)
    out = []
    for r in range(m):
        idx = np.flatnonzero(sup[:, r]) if sup[:, r].any() else np.arange(len(keys))
        s = sse[idx, r]
        # the first shape, then any strictly smaller SSE (a NaN first stays, as in _best_fit)
        k = idx[0] if np.isnan(s[0]) else idx[int(np.argmin(np.where(np.isnan(s), np.inf, s)))]
        out.append((float(sse[k, r]), keys[k], thetas[k][r]))
    return out


def _fold_masks(fold: np.ndarray, guard: dict | None = None, fit_mask: np.ndarray | None = None):
    """Per fold ``f``: ``(f, test, train)`` block masks, the training blocks being those of the
    other folds (within ``fit_mask``) less the fold's ``guard`` (hv-block)."""
    for f in np.unique(fold):
        test = fold == f
        train = ~test if fit_mask is None else ~test & fit_mask
        if guard is not None and f in guard:
            train &= ~guard[f]
        yield f, test, train


def cross_validate(grams_by_hp: dict, fold: np.ndarray, fit_blocks: np.ndarray | None = None,
                   guard: dict | None = None) -> CVResult:
    """Leave-one-fold-out: in each fold choose the shape parameter by training SSE, then
    evaluate the held-out blocks. ``grams_by_hp`` maps hp -> Grams (same blocks). ``guard``
    (fold -> boolean mask over blocks): blocks left out of that fold's training although they
    are not tested (the h-blocks of hv-block cross-validation, Racine 2000: the samples within
    the residual's correlation time of the test fold, whose errors are correlated with its own)."""
    nt = fold.shape[0]
    fit_mask = np.ones(nt, bool) if fit_blocks is None else fit_blocks
    sse = np.zeros(nt)
    chosen, thetas = {}, {}
    folds = list(_fold_masks(fold, guard, fit_mask))
    # every fold's fit in one batch (_best_fits)
    fits = _best_fits(grams_by_hp, np.array([train for _, _, train in folds]).reshape(-1, nt)) if folds else []
    for (f, test, _), (_, hp, th) in zip(folds, fits):
        chosen[f] = hp
        thetas[f] = th
        sse[test] = sse_with(th, grams_by_hp[hp], test)
    # the reported shape and fit (on all blocks) as the loop sums them: between shapes whose
    # training SSEs tie to rounding (columns a pooled fit's projection left as rounding noise)
    # the choice then does not move with the order of the block sums
    tr, hp, th = _best_fit(grams_by_hp, fit_mask)
    return CVResult(sse, chosen, th, hp, tr, thetas)


def heldout_leverage(gr: Grams, X: np.ndarray, bounds: np.ndarray, fold: np.ndarray,
                     guard: dict | None = None) -> np.ndarray:
    """The leverage of every held-out sample under its fold's training design: ``h_i = x_i^T
    (X_tr^T X_tr)^+ x_i`` with ``X_tr`` the rows the fold trains on (the blocks of the other
    folds less the ``guard``, as in :func:`cross_validate`). A training row's leverage is at
    most 1; a held-out row with ``h > 1`` is predicted less well than one measurement could
    tell it, i.e. extrapolated (Montgomery, Peck & Vining, *Introduction to Linear Regression
    Analysis*, sec. 3.8, hidden extrapolation): the training rows do not determine the model
    in a direction that row needs (a direction of motion seen only in the held-out cycle).
    Directions the training design does not span at all (eigenvalues below 1e-12 of the
    largest) give a huge leverage. Returns (len of the held-out samples,) in the order of the
    folds, then of their blocks."""
    rows_all = np.concatenate([np.arange(s, e) for s, e in bounds] or [np.zeros(0, int)])
    block_of = np.repeat(np.arange(bounds.shape[0]), bounds[:, 1] - bounds[:, 0])
    out = []
    for _, test, train in _fold_masks(fold, guard):
        rows = rows_all[test[block_of]]
        if not train.any():
            out.append(np.full(rows.size, np.inf))
            continue
        w, V = np.linalg.eigh(gr.G[train].sum(axis=0))
        w = np.maximum(w, 1e-12 * max(float(w.max()), 1e-300))
        out.append(np.sum((X[rows] @ V) ** 2 / w, axis=1))
    return np.concatenate(out) if out else np.zeros(0)


def unexplained_fractions(gr: Grams, p: int) -> np.ndarray:
    """Per column after the first ``p``: the share of its norm outside the span of the first
    ``p`` columns (0..1), from the pooled Gram matrix (Schur complement)."""
    G = gr.G.sum(axis=0)
    Gcc = G[p:, p:]
    if p:
        Gxx, Gxc = G[:p, :p], G[:p, p:]
        S = Gcc - Gxc.T @ np.linalg.lstsq(Gxx, Gxc, rcond=None)[0]
    else:
        S = Gcc
    return np.sqrt(np.clip(np.diag(S), 0, None) / np.maximum(np.diag(Gcc), 1e-300))


def unexplained_fraction(gr: Grams, p: int) -> float:
    """The least of :func:`unexplained_fractions`: 0 means not identifiable."""
    if gr.G.shape[1] == p:
        return 0.0
    return float(np.min(unexplained_fractions(gr, p)))


#: blocks beyond which :func:`sign_flip_pvalue` takes the normal limit of its randomisation
LARGE_N = 400
#: sign patterns per chunk of :func:`sign_flip_pvalue`'s null distribution. Even: numpy draws two
#: signs per 64-bit word and drops the unused half at the end of a call, so with an even count
#: per chunk the chunks' patterns are those of one draw of all of them (tests/test_gap_engine.py)
SIGN_CHUNK = 1000


def sign_flip_pvalue(d: np.ndarray, n_perm: int = 20000, seed: int = 0) -> float:
    """One-sided paired test that ``d`` (per-block held-out SSE reduction) is positive.

    Blocks (motion cycles) are the exchangeable units, so autocorrelation inside one does not inflate
    the significance. Randomisation over sign flips of the studentised mean."""
    d = np.asarray(d, float)
    n = d.shape[0]
    if n < 2 or np.all(d == 0):
        return 1.0
    rng = np.random.default_rng(seed)
    tstat = _studentised_mean
    obs = tstat(d)
    if n > LARGE_N:
        # many blocks: the sign-flip distribution of the studentised mean is standard normal to
        # within the randomisation's own resolution (its p cannot go below 1 / (1 + n_perm))
        from scipy.stats import norm

        return float(max(norm.sf(obs), 1.0 / (1 + n_perm)))
    # the null distribution in chunks of SIGN_CHUNK patterns (the same patterns, drawn in the
    # same order, as one (n_perm, n) draw: memory bounded whatever the number of blocks)
    exact = 2 ** n <= n_perm
    total = 2 ** n if exact else n_perm
    hits = 0
    for lo in range(0, total, SIGN_CHUNK):   # loop over chunks of sign patterns
        m = min(SIGN_CHUNK, total - lo)
        if exact:
            signs = 1 - 2 * ((np.arange(lo, lo + m)[:, None] >> np.arange(n)) & 1)
        else:   # rng.choice([-1.0, 1.0], size=(m, n)): the same draws
            signs = _SIGNS[rng.integers(0, 2, size=(m, n), dtype=np.int64)]
        hits += int(np.sum(tstat(signs * d) >= obs - 1e-12))
    return float((1 + hits) / (1 + total))


_SIGNS = np.array([-1.0, 1.0])


def _studentised_mean(x: np.ndarray) -> np.ndarray:
    """``sqrt(n) mean / std`` (``ddof=1``) along the last axis: the operations of ``x.mean`` and
    ``x.std``, the mean taken once."""
    n = x.shape[-1]
    mean = np.add.reduce(x, axis=-1, keepdims=True)
    np.true_divide(mean, n, out=mean)
    dev = x - mean
    np.multiply(dev, dev, out=dev)
    var = np.add.reduce(dev, axis=-1)
    var = np.true_divide(var, n - 1)
    return mean[..., 0] / np.maximum(np.sqrt(var), 1e-300) * np.sqrt(n)


def sign_flip_min_p(n: int, n_perm: int = 20000) -> float:
    """Smallest p-value :func:`sign_flip_pvalue` can return with ``n`` blocks: all ``2^n``
    sign patterns when that is at most ``n_perm`` (the observed pattern and its mirror image
    tie), else ``1 / (1 + n_perm)``."""
    if n < 2:
        return 1.0
    return 2.0 / (1 + 2 ** n) if 2 ** n <= n_perm else 1.0 / (1 + n_perm)


def newey_west_lrv(x: np.ndarray, bandwidth: int | None = None) -> tuple[float, int]:
    """Long-run variance of a (mean-removed) series by the Bartlett-kernel estimator of Newey &
    West (1987), ``gamma_0 + 2 sum_{k<=m} (1 - k/(m+1)) gamma_k``, with Andrews' (1991) AR(1)
    plug-in bandwidth ``m = 1.1447 (a n)^(1/3)``, ``a = 4 rho^2 / ((1 - rho)^2 (1 + rho)^2)``,
    when ``bandwidth`` is None (it grows with the series' autocorrelation, so a smooth loss
    differential gets a long window). Returns (variance, m)."""
    x = np.asarray(x, float)
    n = x.shape[0]
    xc = x - x.mean()
    g0 = float(xc @ xc) / n
    if n < 3 or g0 <= 0:
        return g0, 0
    if bandwidth is None:
        rho = float(np.clip((xc[1:] @ xc[:-1]) / max(xc[:-1] @ xc[:-1], 1e-300), -0.97, 0.97))
        a = 4 * rho ** 2 / ((1 - rho) ** 2 * (1 + rho) ** 2)
        bandwidth = int(np.ceil(1.1447 * (a * n) ** (1 / 3)))
    m = int(min(max(bandwidth, 0), n - 1))
    lrv = g0
    for k in range(1, m + 1):   # loop over lags (m is small against n)
        lrv += 2 * (1 - k / (m + 1)) * float(xc[k:] @ xc[:-k]) / n
    return max(lrv, g0 / n), m


def loss_differential_test(d: np.ndarray, bandwidth: int | None = None) -> tuple[float, dict]:
    """One-sided test that the held-out loss differential ``d`` (per block, in time order; the
    nominal's squared error minus the augmented model's) has a positive mean: the Diebold &
    Mariano (1995) statistic with a Newey-West long-run variance (:func:`newey_west_lrv`), the
    small-sample correction of Harvey, Leybourne & Newbold (1997)
    ``sqrt((n + 1 - 2h + h (h - 1) / n) / n)`` with ``h = m + 1``, against Student's t with
    ``n - 1`` degrees of freedom. Power comes from the samples (every block counts, however few
    motion cycles the record holds); the dependence between blocks is in the variance. Returns
    (p, details: statistic, n, bandwidth, standard error of the mean)."""
    from scipy.stats import t as student_t

    d = np.asarray(d, float)
    n = d.shape[0]
    if n < 3 or not np.any(d):
        return 1.0, {"n": int(n), "statistic": 0.0, "bandwidth": 0, "se": float("nan")}
    lrv, m = newey_west_lrv(d, bandwidth)
    se = float(np.sqrt(lrv / n))
    h = m + 1
    hln = float(np.sqrt(max(n + 1 - 2 * h + h * (h - 1) / n, 1.0) / n))
    stat = float(d.mean() / max(se, 1e-300) * hln)
    p = float(student_t.sf(stat, df=n - 1))
    return p, {"n": int(n), "statistic": stat, "bandwidth": int(m), "se": se, "hln": hln}


def loss_test_min_p(n: int) -> float:
    """Smallest p :func:`loss_differential_test` is taken to reach with ``n`` blocks: the t tail
    at a statistic of 30 (it has no hard floor; with fewer than 3 blocks it cannot run)."""
    from scipy.stats import t as student_t

    return 1.0 if n < 3 else float(student_t.sf(30.0, df=n - 1))


def holm(pvals: dict) -> dict:
    """Holm-Bonferroni adjusted p-values."""
    items = sorted(pvals.items(), key=lambda kv: kv[1])
    m = len(items)
    out, running = {}, 0.0
    for k, (name, p) in enumerate(items):
        running = max(running, min(1.0, (m - k) * p))
        out[name] = running
    return out


def white_noise_floor(r: np.ndarray, trial: np.ndarray) -> float:
    """Variance of the white part of a residual from its second differences within trials:
    ``var(r[k+1] - 2 r[k] + r[k-1]) = 6 sigma^2`` for white noise; smooth model errors vanish."""
    d2 = r[2:] - 2 * r[1:-1] + r[:-2]
    same = (trial[2:] == trial[:-2])
    d2 = d2[same]
    if d2.size < 10:
        return float("nan")
    # robust scale (MAD) so that a few spikes do not raise the floor
    mad = np.median(np.abs(d2 - np.median(d2))) * 1.4826
    return float(mad ** 2 / 6.0)


def repetition_noise_floor(r: np.ndarray, trial: np.ndarray, t_rel: np.ndarray, group: np.ndarray,
                           rate_hz: float) -> float:
    """Noise variance from repetitions: trials of one condition replay the same reference, so
    the difference of two repetitions' residuals at the same trial time cancels everything
    systematic and leaves twice the noise variance. NaN when no condition has two trials."""
    idx = np.round(t_rel * rate_hz).astype(np.int64)
    num, den = 0.0, 0
    for g in np.unique(group):
        members = np.flatnonzero(group == g)
        for a, b in zip(members[:-1], members[1:]):  # consecutive repetitions (loop over trials)
            ma, mb = trial == a, trial == b
            ia, ib = idx[ma], idx[mb]
            common, pa, pb = np.intersect1d(ia, ib, assume_unique=False, return_indices=True)
            if common.size < 20:
                continue
            d = r[ma][pa] - r[mb][pb]
            num += float(d @ d)
            den += common.size
    return num / (2 * den) if den else float("nan")


def bootstrap_ci(sse: np.ndarray, n: np.ndarray, n_boot: int = 1000, seed: int = 0, level: float = 0.95):
    """Percentile CI of the pooled RMS sqrt(sum sse / sum n) resampling blocks."""
    rng = np.random.default_rng(seed)
    idx = rng.integers(0, sse.shape[0], size=(n_boot, sse.shape[0]))
    rms = np.sqrt(sse[idx].sum(1) / np.maximum(n[idx].sum(1), 1))
    lo, hi = np.quantile(rms, [(1 - level) / 2, (1 + level) / 2])
    return float(lo), float(hi)
