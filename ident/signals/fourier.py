"""Finite Fourier series (thesis eq. 3-2), evaluated and fitted with analytic derivatives.

``q(t) = q0 + sum_l  a_l/(w l) sin(w l t) - b_l/(w l) cos(w l t)``, so that
``qd(t) = sum_l a_l cos(w l t) + b_l sin(w l t)`` and
``qdd(t) = sum_l -a_l w l sin(w l t) + b_l w l cos(w l t)``.
(The thesis prints the acceleration with the sign of the first term flipped; the derivative
of its own ``qd`` is the one above.)
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class FourierSeries:
    """Coefficients of eq. 3-2: ``a``, ``b`` of shape (N,), fundamental ``wf`` rad/s, offset ``q0``."""

    a: np.ndarray
    b: np.ndarray
    wf: float
    q0: float = 0.0

    @property
    def n_harmonics(self) -> int:
        return int(np.asarray(self.a).shape[0])

    @property
    def period(self) -> float:
        return 2 * np.pi / self.wf

    def _phases(self, t):
        t = np.asarray(t, float)
        l = np.arange(1, self.n_harmonics + 1)
        wl = self.wf * l
        ph = np.multiply.outer(t, wl)
        return np.sin(ph), np.cos(ph), wl

    def evaluate(self, t, order: int = 2):
        """(q, qd, qdd) at times ``t`` (any shape); ``order`` limits how many are computed."""
        s, c, wl = self._phases(t)
        a, b = np.asarray(self.a, float), np.asarray(self.b, float)
        q = self.q0 + s @ (a / wl) - c @ (b / wl)
        out = [q]
        if order >= 1:
            out.append(c @ a + s @ b)
        if order >= 2:
            out.append(-s @ (a * wl) + c @ (b * wl))
        return tuple(out)


def design_matrix(t, wf: float, n_harmonics: int, order: int = 0) -> np.ndarray:
    """Columns multiplying ``[q0, a_1..a_N, b_1..b_N]`` for the ``order``-th derivative of q."""
    if order not in (0, 1, 2):
        raise ValueError("order must be 0, 1 or 2")
    return design_matrices(t, wf, n_harmonics, (order,))[0]


def design_matrices(t, wf: float, n_harmonics: int, orders=(0, 1, 2)) -> tuple:
    """:func:`design_matrix` of each of ``orders`` (0, 1, 2), from one evaluation of the
    sines and cosines of the harmonics at ``t``."""
    t = np.asarray(t, float)
    l = np.arange(1, n_harmonics + 1)
    wl = wf * l
    ph = np.multiply.outer(t, wl)
    s, c = np.sin(ph), np.cos(ph)
    out = []
    for order in orders:  # loop over the (at most three) derivative orders
        one = np.ones((t.shape[0], 1)) if order == 0 else np.zeros((t.shape[0], 1))
        if order == 0:
            A, B = s / wl, -c / wl
        elif order == 1:
            A, B = c, s
        elif order == 2:
            A, B = -s * wl, c * wl
        else:
            raise ValueError("order must be 0, 1 or 2")
        out.append(np.hstack([one, A, B]))
    return tuple(out)


@dataclass(frozen=True)
class FourierFit:
    series: FourierSeries
    rms: float          # residual RMS of q, same unit as q
    max_abs: float
    n_samples: int
    cond: float

    def to_dict(self) -> dict:
        return {"wf": self.series.wf, "q0": self.series.q0, "a": np.asarray(self.series.a).tolist(),
                "b": np.asarray(self.series.b).tolist(), "rms": self.rms, "max_abs": self.max_abs,
                "n_samples": self.n_samples, "cond": self.cond}


def fit_fourier(t, q, wf: float, n_harmonics: int) -> FourierFit:
    """Least-squares fit of eq. 3-2 to samples ``q(t)`` (NaN samples ignored)."""
    t = np.asarray(t, float)
    q = np.asarray(q, float)
    ok = np.isfinite(q) & np.isfinite(t)
    X = design_matrix(t[ok], wf, n_harmonics)
    coef, *_ = np.linalg.lstsq(X, q[ok], rcond=None)
    r = q[ok] - X @ coef
    n = n_harmonics
    series = FourierSeries(coef[1:1 + n], coef[1 + n:], float(wf), float(coef[0]))
    return FourierFit(series, float(np.sqrt(np.mean(r ** 2))), float(np.max(np.abs(r))),
                      int(ok.sum()), float(np.linalg.cond(X)))
