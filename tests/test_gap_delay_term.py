"""A torque delay's plausibility belongs to its fitted term where two grid points carry the same
column (:func:`ident.gap.candidates._delay_physical`): delays under one sample period interpolate
the samples linearly, so their columns are one column scaled, and which of them carries the fit is
decided by rounding; columns that differ, however little, keep their own amplitude band."""
from __future__ import annotations

from types import SimpleNamespace

import numpy as np

from ident.gap.candidates import DELAY_GRID_S, _delay_physical


def _record(proportional: bool):
    """Delay columns ``p(t - dt) - p(t)`` of a smooth torque model ``p`` logged at 1 kHz: the
    0.5 ms column is half the 1 ms one (linear interpolation between samples), the longer ones
    differ from it; ``proportional=False`` gives the 0.5 ms column a shape of its own."""
    t = np.linspace(0.0, 20.0, 20001)
    p = np.sin(0.7 * t) + 0.3 * np.sin(2.1 * t + 0.4)
    cols = np.column_stack([np.interp(t - dl, t, p) - p for dl in DELAY_GRID_S])
    if not proportional:
        cols[:, 0] = np.random.default_rng(3).standard_normal(t.size) * np.std(cols[:, 0])
    return SimpleNamespace(delay_cols=cols)


def test_the_same_term_on_two_proportional_columns_is_judged_alike():
    d = _record(proportional=True)
    # 2.96 on the 0.5 ms column is the 1 ms column at 1.48: a 1.5 ms delay
    assert _delay_physical(0.0005, np.array([2.96]), d)
    assert _delay_physical(0.001, np.array([1.48]), d)
    # within the band on its own column: a delay, of either sign
    assert _delay_physical(0.002, np.array([-1.0]), d)
    # 2.96 on the 2 ms column: the 3 ms and 5 ms columns are close to it (second order) but not
    # the same column, so its own band decides
    assert not _delay_physical(0.002, np.array([2.96]), d)


def test_an_amplitude_no_grid_column_carries_in_the_band_is_not_a_delay():
    d = _record(proportional=True)
    # 0.1 x 0.5 ms = 0.05 ms: below 0.4 of the shortest grid delay
    assert not _delay_physical(0.0005, np.array([0.1]), d)
    # 40 x 30 ms: beyond 2.5 of the longest
    assert not _delay_physical(0.030, np.array([40.0]), d)


def test_a_column_with_a_shape_of_its_own_keeps_its_own_band():
    d = _record(proportional=False)
    assert not _delay_physical(0.0005, np.array([2.96]), d)
    assert _delay_physical(0.0005, np.array([1.0]), d)
    # no delay columns (single-joint trials): the band on the column alone
    assert not _delay_physical(0.0005, np.array([2.96]), SimpleNamespace(delay_cols=None))
