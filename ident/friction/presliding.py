"""Presliding after velocity reversals, from the friction a record shows: the distance each
joint has moved since its last reversal (:func:`reversal_displacement`) and the length over
which the friction rises with it (:func:`presliding_length`), so that static friction laws
(which describe gross sliding) can leave out the rows still in that rise. Used by the
multi-joint fits (:mod:`ident.model.rigidbody`, the data-chosen cut of
:mod:`ident.model.multijoint`) and the one-link fits of the thesis pipeline
(:class:`ident.model.onelink.OneLinkIdentifier`).
"""
from __future__ import annotations

import numpy as np

#: rows the rise is fitted on (longer records: every k-th row)
PRESLIDING_ROWS = 50_000
#: the friction after a reversal is within 0.5 % of its sliding level after this many lengths of
#: an exponential rise with the displacement (1 - exp(-5.3) = 0.995, as the smoothed sign's
#: 3 widths, :data:`ident.model.rigidbody.TRANSITION_WIDTHS`)
PRESLIDING_LENGTHS = float(np.log(200.0))
#: a presliding rise is kept when it explains at least this fraction of the residual sum of
#: squares of the rows above the speed cut (below it the rows after a reversal fit the law)
PRESLIDING_GAIN = 0.01


def reversal_displacement(q, qd, v_floor) -> np.ndarray:
    """Distance each joint has moved since its last velocity reversal, ``(T,)`` for one joint's
    ``(T,)`` signals or ``(T, n)`` for ``(T, n)`` ones: ``|q_t - q_s|`` with ``s`` the first row
    of the current direction run, a run being the rows between two changes of the sign of ``qd``
    among the rows faster than ``v_floor`` (per joint, rad/s; the rows below it, whose direction
    the velocity estimate does not give, belong to the run they continue). The record's first
    run starts at its first row faster than ``v_floor``; the rows before it get 0."""
    q = np.asarray(q, float)
    qd = np.asarray(qd, float)
    if q.ndim == 2:
        fl = np.broadcast_to(np.asarray(v_floor, float), (q.shape[1],))
        return np.column_stack([reversal_displacement(q[:, j], qd[:, j], fl[j])
                                for j in range(q.shape[1])])
    idx = np.arange(q.size)
    d = np.where(np.abs(qd) >= float(v_floor), np.sign(qd), 0.0)
    nz = np.flatnonzero(d)
    if nz.size == 0:
        return np.zeros(q.size)
    last = np.maximum.accumulate(np.where(d != 0, idx, -1))
    run = np.where(last >= 0, d[np.maximum(last, 0)], 0.0)          # direction carried forward
    start = np.zeros(q.size, bool)
    start[nz[0]] = True
    start[1:] |= (run[1:] != run[:-1]) & (run[:-1] != 0)
    first = np.maximum.accumulate(np.where(start, idx, 0))
    return np.where(idx >= nz[0], np.abs(q - q[first]), 0.0)


def shape_line_fits(a, y, shapes) -> tuple[np.ndarray, np.ndarray]:
    """For each shape column ``t`` of ``shapes`` (an iterable of arrays like ``a``): the residual
    sum of squares and ``c`` of the least-squares fit ``y ~ c t + fv a`` (2 x 2 normal
    equations), ``(rss, c)`` arrays; inf and NaN where ``t`` and ``a`` are collinear (or the
    sums are not finite). The grid
    searches of :func:`presliding_length` and of the friction's sign transition
    (:func:`ident.model.rigidbody.friction_transition`) run on it."""
    saa, say, syy = float(a @ a), float(a @ y), float(y @ y)
    rss, cs = [], []
    for t in shapes:                                  # shapes of a grid, the rows vectorised
        stt, sta, sty = float(t @ t), float(t @ a), float(t @ y)
        det = stt * saa - sta * sta
        if not det > 1e-12 * stt * saa:
            rss.append(np.inf)
            cs.append(np.nan)
            continue
        c = (sty * saa - sta * say) / det
        fv = (stt * say - sta * sty) / det
        rss.append(syy - c * sty - fv * say)
        cs.append(c)
    rss = np.array(rss, float)
    return np.where(np.isnan(rss), np.inf, rss), np.array(cs, float)


def presliding_length(disp, qd, friction, v_cut, n_grid: int = 121) -> dict:
    """The displacement over which a joint's friction builds up after each velocity reversal,
    from the friction the record shows on the rows faster than the speed cut ``v_cut``.

    After a reversal the contact deforms elastically before it slides (presliding, Dahl 1968;
    the bristles of LuGre, Canudas de Wit et al. 1995): the friction rises with the displacement
    ``s`` since the reversal (:func:`reversal_displacement`), not with the speed. The rise is
    described by ``y = c (1 - exp(-s / s0)) + fv |qd|`` (``y = sign(qd) f``; ``c`` and ``fv``
    linear at each length ``s0`` of a log-spaced grid from 1e-6 to 0.2 times the 99th-percentile
    displacement) and compared with the Coulomb + viscous line ``c + fv |qd|`` on the same rows.
    The rise is kept when it lowers their residual sum of squares by at least
    :data:`PRESLIDING_GAIN` and its length is inside the grid; the rows within
    ``end = PRESLIDING_LENGTHS s0`` of a reversal (the friction within 0.5 % of its sliding
    level) then do not follow a static law. Returns ``{"length", "gain", "end"}`` (rad; the
    fraction of the residual sum of squares explained), ``length``/``end`` None when no rise is
    kept. Long records: every k-th row (:data:`PRESLIDING_ROWS`)."""
    a = np.abs(np.asarray(qd, float))
    y = np.sign(qd) * np.asarray(friction, float)
    s = np.asarray(disp, float)
    m = (a >= v_cut) & np.isfinite(y) & np.isfinite(s)
    a, y, s = a[m], y[m], s[m]
    step = max(1, a.size // PRESLIDING_ROWS)
    a, y, s = a[::step], y[::step], s[::step]
    none = {"length": None, "gain": 0.0, "end": None}
    if a.size < 20:
        return none
    top = float(np.percentile(s, 99))
    if not top > 0:
        return none
    rss0 = shape_line_fits(a, y, [np.ones_like(a)])[0][0]
    if not (np.isfinite(rss0) and rss0 > 0):
        return none
    grid = np.geomspace(1e-6, 0.2, n_grid) * top
    rss, _ = shape_line_fits(a, y, (-np.expm1(-s / s0) for s0 in grid))
    k = int(np.argmin(rss))
    gain = float(1.0 - rss[k] / rss0)
    if k in (0, n_grid - 1) or gain < PRESLIDING_GAIN:
        return {"length": None, "gain": max(gain, 0.0), "end": None}
    return {"length": float(grid[k]), "gain": gain, "end": PRESLIDING_LENGTHS * float(grid[k])}
