"""Static (memoryless) friction models: Stribeck (thesis eq. 2-6), hyperbolic (thesis eq. 2-7)
and the arctangent model of Indri & Trapani 2020 (eq. 1-2, identified with eq. 27-28).

All models are link side, SI (N m, rad/s), odd in the velocity, and share the interface of
:class:`ident.friction.base.FrictionModel`. Each splits its parameters into ``linear_names``
(the torque is linear in them once the others are fixed) and the remaining nonlinear ones;
``linear_design(qd)`` returns ``(Phi, offset)`` with ``torque = Phi @ theta_lin + offset`` for
the instance's nonlinear parameters. The estimators in :mod:`ident.friction.fit` use this split
for variable projection.
"""
from __future__ import annotations

import numpy as np

from ident.friction.base import FrictionModel
from ident.friction import laws
from ident.friction.constants import KV_DEFAULT
from ident.friction.laws import _2_PI, s0, s1  # noqa: F401  (s0, s1: still imported from here by ident.gap.nominal)


def _grid_values(lo: float, hi: float, n: int):
    """``n`` grid values strictly inside (lo, hi): log-spaced for lo > 0, else linear; None for
    an infinite bound."""
    lo, hi = float(lo), float(hi)
    if not (np.isfinite(lo) and np.isfinite(hi) and lo < hi) or n < 1:
        return None
    if lo > 0:
        return np.exp(np.linspace(np.log(lo), np.log(hi), n + 2)[1:-1])
    return np.linspace(lo, hi, n + 2)[1:-1]


_STRIBECK_GRAD_COLS = np.array([2])          # Vc -> the drop column
_HYPERBOLIC_GRAD_COLS = np.array([0, 0, 1])   # g2, g3 -> the hump; g5 -> the Coulomb column
LIMIT_RATIO = 1.0001                          # g2 / g3 of the hyperbolic grid's limit-hump starts


class _StaticModel(FrictionModel):
    """Memoryless models whose nonlinear parameters enter one design column each: they give
    the analytic variable-projection Jacobian and the factored start grid."""

    @classmethod
    def design_grad(cls, qd, nl: dict, out=None):
        """``(Phi (T, n_linear), dPhi (T, n_nonlinear), cols (n_nonlinear,))``: the linear
        design for the nonlinear values ``nl`` and its derivatives with respect to them
        (``nonlinear_names`` order), each nonlinear parameter entering one column of ``Phi``
        (column ``cols[j]`` of the design has derivative ``dPhi[:, j]``, the other columns
        none), for an analytic variable-projection Jacobian; None: not available. ``out``: a
        (T, n_linear + n_nonlinear) array that receives ``[Phi, dPhi]`` (then ``Phi`` and
        ``dPhi`` are views of it)."""
        return None

    @classmethod
    def vp_grid(cls, qd, bounds: dict, n: int | None = None):
        """A grid over the nonlinear parameters for the variable-projection search of
        :func:`ident.friction.fit.fit_friction`, factored so that every grid point's design is a
        combination of a few shared columns: ``(B, U, S)`` with ``B`` (T, nb) basis columns,
        ``U`` (K, n_nonlinear) the nonlinear values of each grid point (in ``param_names``
        order) and ``S`` the combination with design ``Phi_k = B @ S_k`` (offset 0). The
        estimator scores all K points from the (nb, nb) Gram matrix of ``B`` (no pass over the
        samples per point). ``S`` is given sparse, as ``(cols, coefs)``, both (K, n_linear, p):
        ``Phi_k[:, a] = sum_p coefs[k, a, p] * B[:, cols[k, a, p]]``. An optional fourth item,
        (K,) integers, splits the points into blocks, each a (partial) tensor grid of its own
        (for the local minima). ``bounds``: {name: (lo, hi)}; None: no grid (infinite bounds,
        or a model without one)."""
        return None


# --------------------------------------------------------------------------------------------
class Stribeck(_StaticModel):
    r"""Stribeck friction of thesis eq. 2-6, the four-parameter model.

    .. math::

        f(\dot{q}) = F_k \operatorname{sign}(\dot{q}) + F_v \dot{q}
        - \operatorname{sign}(\dot{q}) F_s \left(1 - e^{-|\dot{q}| / V_c}\right)

    evaluated by :func:`ident.friction.laws.stribeck_columns` [1]_. With this sign convention
    ``Fk`` is the static (breakaway) level reached as qd -> 0 and ``Fs`` is the DROP from that
    level to the Coulomb level at speed: far from zero the model is
    ``(Fk - Fs) sign(qd) + Fv qd``. A physical Stribeck effect has ``Fs > 0`` and a small
    ``Vc > 0`` (rad/s). ``f(0) = 0``; the torque is odd and discontinuous only at qd = 0.
    Linear in (Fk, Fv, Fs) for fixed Vc. Degenerate forms (``Fs`` ~ 0; ``Vc`` below the
    sampled speeds, where only ``Fk - Fs`` is identifiable and the thesis reports its joint-5
    form ``Fk = 0`` with a negative ``Fs``) are named by :meth:`degeneracy` and
    :meth:`degenerate_form`.

    Parameters
    ----------
    **params : float
        ``Fk`` (static level, N m), ``Fv`` (viscous coefficient, N m s/rad), ``Fs`` (drop from
        the static to the Coulomb level, N m) and ``Vc`` (Stribeck velocity, rad/s), by keyword.

    References
    ----------
    .. [1] PA10 thesis (seeds 002), eq. 2-6.

    Examples
    --------
    >>> m = Stribeck(Fk=3.0, Fv=0.5, Fs=1.0, Vc=0.1)
    >>> m.torque([0.0, 1e-6, 10.0]).round(4).tolist()
    [0.0, 3.0, 7.0]
    """

    name = "stribeck"
    param_names = ("Fk", "Fv", "Fs", "Vc")
    linear_names = ("Fk", "Fv", "Fs")

    @staticmethod
    def regressor(qd, Vc: float) -> np.ndarray:
        """(T, 3) columns multiplying (Fk, Fv, Fs) for a fixed ``Vc``
        (:func:`ident.friction.laws.stribeck_columns`)."""
        return laws.stribeck_columns(qd, Vc)

    def linear_design(self, qd, qdd=None, dt=None):
        qd = np.asarray(qd, float)
        return self.regressor(qd, self._p["Vc"]), np.zeros(qd.shape)

    @classmethod
    def fit_hints(cls, qd, settings):
        vmax = float(np.max(np.abs(qd)))
        return {"Vc": 0.05 * vmax}, {"Vc": (1e-4 * vmax, 10.0 * vmax)}

    @classmethod
    def design_grad(cls, qd, nl, out=None):
        Vc = float(nl["Vc"])
        qd = np.asarray(qd, float)
        if Vc < 0 or not np.isfinite(Vc):
            raise ValueError(f"stribeck: Vc must be finite and >= 0, got {Vc}")
        A = np.empty((qd.size, 4)) if out is None else out
        sgn = np.sign(qd)
        A[:, 0] = sgn
        A[:, 1] = qd
        if Vc > 0:
            a = np.abs(qd)
            z = -a / Vc
            np.multiply(sgn, np.expm1(z), out=A[:, 2])        # laws.stribeck_drop
            A[:, 3] = sgn * np.exp(z) * a / (Vc * Vc)         # d/dVc of the drop
        else:                                  # Vc = 0: the limit, a second sign column, derivative 0
            np.negative(sgn, out=A[:, 2])
            A[:, 3] = 0.0
        return A[:, :3], A[:, 3:], _STRIBECK_GRAD_COLS

    @classmethod
    def vp_grid(cls, qd, bounds, n=None):
        vals = _grid_values(*bounds["Vc"], 48 if n is None else n)
        if vals is None:
            return None
        qd = np.asarray(qd, float)
        drops = laws.stribeck_drop(qd[:, None], vals)                     # (T, n)
        B = np.column_stack([np.sign(qd), qd, drops])
        K = vals.size
        cols = np.zeros((K, 3, 1), int)
        cols[:, 1, 0] = 1
        cols[:, 2, 0] = 2 + np.arange(K)
        return B, vals[:, None], (cols, np.ones((K, 3, 1)))

    @classmethod
    def initial_guess(cls, c, v, vmax):
        return {"Fk": 1.1 * c, "Fv": v, "Fs": 0.1 * c, "Vc": 0.05 * vmax}

    @classmethod
    def degenerate_form(cls, params, stderr, qd=None, bounds=None, fit_scale=None):
        """``stribeck_coulomb_in_Fs`` (``Fk`` ~ 0, negative ``Fs``, small ``Vc``: thesis joint
        5), ``stribeck_as_cv`` (``Fs`` ~ 0 or within two standard errors of 0: thesis joint 3)
        or ``stribeck_Vc_at_bound`` (``Vc`` on a bound of ``bounds``)."""
        Fk, Fs, Vc = params["Fk"], params["Fs"], params["Vc"]
        scale = float(fit_scale) if fit_scale else max(abs(Fk), abs(Fs), 1e-9)
        vmax = float(np.max(np.abs(qd))) if qd is not None and np.size(qd) else 1.0
        if abs(Fk) < 0.05 * max(abs(Fk), abs(Fs), 1e-9) and Fs < 0 and Vc < 0.05 * vmax:
            return "stribeck_coulomb_in_Fs"
        se_fs = abs(stderr.get("Fs", np.nan))
        if abs(Fs) < 0.02 * scale or (np.isfinite(se_fs) and abs(Fs) < 2.0 * se_fs):
            return "stribeck_as_cv"
        if bounds is not None and "Vc" in bounds:
            lo, hi = bounds["Vc"]
            if np.isclose(Vc, hi, rtol=1e-3) or np.isclose(Vc, lo, rtol=1e-2):
                return "stribeck_Vc_at_bound"
        return None

    @classmethod
    def report_form(cls, params, stderr, cov, names, qd):
        """When ``Vc`` is below the slowest sampled speeds (2nd percentile of |qd| over 5),
        ``1 - exp(-|qd|/Vc) = 1`` on every sample and only ``Fk - Fs`` is identifiable; report
        the thesis's representative (its joint 5 form): ``Fk = 0``, ``Fs = -(Fk - Fs)``, with
        the standard error of ``Fk - Fs`` on ``Fs`` and NaN on ``Fk``."""
        a = np.abs(np.asarray(qd, float))
        a = a[a > 0]
        if a.size == 0 or not params["Vc"] < np.percentile(a, 2.0) / 5.0:
            return params, stderr
        names = list(names or ())
        var = np.nan
        if cov is not None and "Fk" in names and "Fs" in names:
            i, k = names.index("Fk"), names.index("Fs")
            C = np.asarray(cov, float)
            var = C[i, i] + C[k, k] - 2 * C[i, k]
        out = dict(params)
        out["Fs"] = params["Fs"] - params["Fk"]
        out["Fk"] = 0.0
        se = dict(stderr)
        se["Fs"] = float(np.sqrt(var)) if np.isfinite(var) and var >= 0 else float("nan")
        se["Fk"] = float("nan")
        return out, se

    def violations(self, form=None):
        """Thesis eq. 2-6 physics: static level ``Fk >= 0``, Coulomb level at speed
        ``Fk - Fs >= 0``, ``Fv >= 0`` and a drop ``Fs >= 0`` (except in the thesis's joint-5
        form ``stribeck_coulomb_in_Fs``, ``Fk = 0``, where ``-Fs`` carries the Coulomb level)."""
        Fk, Fv, Fs = self._p["Fk"], self._p["Fv"], self._p["Fs"]
        out = []
        if Fk < 0:
            out.append(f"Fk = {Fk:.3g} < 0: negative static friction level")
        if Fk - Fs < 0:
            out.append(f"Fk - Fs = {Fk - Fs:.3g} < 0: negative Coulomb level at speed")
        if Fv < 0:
            out.append(f"Fv = {Fv:.3g} < 0: negative viscous coefficient")
        if Fs < 0 and form != "stribeck_coulomb_in_Fs" and Fk > 0:
            out.append(f"Fs = {Fs:.3g} < 0: a rise, not a Stribeck drop")
        return tuple(out)

    def degeneracy(self, qd, fit_scale: float) -> str | None:
        a = np.abs(np.asarray(qd, float))
        a = a[a > 0]
        Fk, Fs, Vc = self._p["Fk"], self._p["Fs"], self._p["Vc"]
        if a.size == 0:
            return "no moving samples: nothing is identifiable"
        if abs(Fs) < 0.02 * fit_scale:
            return (f"Fs = {Fs:.3g} is ~0 (under 2% of the torque scale {fit_scale:.3g}): the "
                    "Stribeck term vanishes, the model reduces to Coulomb + viscous and Vc is not "
                    "identifiable")
        lo, hi = np.percentile(a, [2.0, 98.0])
        if Vc < lo / 5.0:
            return (f"Vc = {Vc:.3g} rad/s is below the slowest sampled speeds ({lo:.3g} rad/s): "
                    "1 - exp(-|qd|/Vc) ~ 1, the Stribeck term acts as a second Coulomb term and "
                    f"only Fk - Fs = {Fk - Fs:.3g} is identifiable (the thesis's form with Fk ~ 0 "
                    "and a negative Fs)")
        if Vc > 10.0 * hi:
            return (f"Vc = {Vc:.3g} rad/s is far above the sampled speeds ({hi:.3g} rad/s): the "
                    "Stribeck term is linear in qd, merges with Fv and the model reduces to "
                    "Coulomb + viscous")
        return None


# --------------------------------------------------------------------------------------------
class Hyperbolic(_StaticModel):
    r"""Hyperbolic friction of thesis eq. 2-7 (Makkar et al. 2005), the six-parameter model.

    .. math::

        f(\dot{q}) = \gamma_1 \left(\tanh(\gamma_2 \dot{q}) - \tanh(\gamma_3 \dot{q})\right)
        + \gamma_4 \tanh(\gamma_5 \dot{q}) + \gamma_6 \dot{q}

    evaluated by :func:`ident.friction.laws.hyperbolic_columns` [1]_ [2]_. ``g4 tanh(g5 qd)``
    is the smooth Coulomb term, ``g6 qd`` the viscous one, and the first term the Stribeck
    hump (static level ~ g1 + g4). Odd and smooth. Linear in (g1, g4, g6) for fixed
    (g2, g3, g5). The first term is symmetric under (g1, g2, g3) -> (-g1, g3, g2); estimators
    report the representative with g2 >= g3 (:meth:`canonical`).

    Parameters
    ----------
    **params : float
        ``g1`` (hump amplitude, N m), ``g2``, ``g3`` (hump rates, s/rad), ``g4`` (Coulomb
        level, N m), ``g5`` (Coulomb rate, s/rad) and ``g6`` (viscous coefficient,
        N m s/rad), by keyword.

    References
    ----------
    .. [1] PA10 thesis (seeds 002), eq. 2-7.
    .. [2] Makkar et al. 2005, as cited by the PA10 thesis (seeds 002), ch. 2.
    """

    name = "hyperbolic"
    param_names = ("g1", "g2", "g3", "g4", "g5", "g6")
    linear_names = ("g1", "g4", "g6")

    @staticmethod
    def regressor(qd, g2: float, g3: float, g5: float) -> np.ndarray:
        """(T, 3) columns multiplying (g1, g4, g6) for fixed (g2, g3, g5)
        (:func:`ident.friction.laws.hyperbolic_columns`)."""
        return laws.hyperbolic_columns(qd, g2, g3, g5)

    def linear_design(self, qd, qdd=None, dt=None):
        qd = np.asarray(qd, float)
        p = self._p
        return self.regressor(qd, p["g2"], p["g3"], p["g5"]), np.zeros(qd.shape)

    @classmethod
    def fit_hints(cls, qd, settings):
        vmax = float(np.max(np.abs(qd)))
        b = (1e-3 / vmax, 1e4 / vmax)
        return {"g2": 50.0 / vmax, "g3": 5.0 / vmax, "g5": 20.0 / vmax}, {"g2": b, "g3": b, "g5": b}

    @classmethod
    def design_grad(cls, qd, nl, out=None):
        qd = np.asarray(qd, float)
        t = np.tanh(np.multiply.outer([nl["g2"], nl["g3"], nl["g5"]], qd))     # (3, T)
        A = np.empty((qd.size, 6)) if out is None else out
        np.subtract(t[0], t[1], out=A[:, 0])
        A[:, 1] = t[2]
        A[:, 2] = qd
        s = 1.0 - t * t
        for j in range(3):          # d tanh(g qd)/dg = qd sech^2, column by column
            np.multiply(qd, s[j], out=A[:, 3 + j])
        np.multiply(A[:, 4], -1.0, out=A[:, 4])
        return A[:, :3], A[:, 3:], _HYPERBOLIC_GRAD_COLS

    @classmethod
    def vp_grid(cls, qd, bounds, n=None):
        n = 20 if n is None else n
        a, b, c = (_grid_values(*bounds[k], n) for k in ("g2", "g3", "g5"))
        if a is None or b is None or c is None:
            return None
        qd = np.asarray(qd, float)
        gs, inv = np.unique(np.concatenate([a, b, c]), return_inverse=True)
        ia, ib, ic = inv[:a.size], inv[a.size:a.size + b.size], inv[a.size + b.size:]
        B = np.column_stack([np.tanh(np.multiply.outer(qd, gs)), qd])
        i, j, k = (x.ravel() for x in np.meshgrid(np.arange(a.size), np.arange(b.size),
                                                   np.arange(c.size), indexing="ij"))
        keep = a[i] > b[j]                          # the canonical representative, g2 > g3
        i, j, k = i[keep], j[keep], k[keep]
        K = i.size
        cols = np.zeros((K, 3, 2), int)
        coefs = np.zeros((K, 3, 2))
        cols[:, 0, 0], cols[:, 0, 1], coefs[:, 0] = ia[i], ib[j], (1.0, -1.0)   # hump
        cols[:, 1, 0], coefs[:, 1, 0] = ic[k], 1.0                             # Coulomb
        cols[:, 2, 0], coefs[:, 2, 0] = gs.size, 1.0                           # viscous
        U = np.column_stack([a[i], b[j], c[k]])
        # second block: the limit g3 -> g2 of the hump with g1 (g2 - g3) fixed, a hump of shape
        # qd sech^2(g2 qd) that no finite grid point reaches (scored by the limit column,
        # started at g3 = g2 / LIMIT_RATIO, next to the limit)
        lo3, hi3 = bounds["g3"]
        al = a[(a / LIMIT_RATIO > lo3) & (a / LIMIT_RATIO < hi3)]
        if al.size:
            ta = np.tanh(np.multiply.outer(qd, al))
            B = np.column_stack([B, qd[:, None] * (1.0 - ta * ta)])
            il, kl = (x.ravel() for x in np.meshgrid(np.arange(al.size), np.arange(c.size),
                                                     indexing="ij"))
            cl = np.zeros((il.size, 3, 2), int)
            fl = np.zeros((il.size, 3, 2))
            cl[:, 0, 0], fl[:, 0, 0] = gs.size + 1 + il, 1.0
            cl[:, 1, 0], fl[:, 1, 0] = ic[kl], 1.0
            cl[:, 2, 0], fl[:, 2, 0] = gs.size, 1.0
            cols, coefs = np.concatenate([cols, cl]), np.concatenate([coefs, fl])
            U = np.vstack([U, np.column_stack([al[il], al[il] / LIMIT_RATIO, c[kl]])])
        blocks = np.repeat([0, 1], [K, U.shape[0] - K])
        return B, U, (cols, coefs), blocks

    @classmethod
    def initial_guess(cls, c, v, vmax):
        return {"g1": 0.1 * abs(c), "g2": 100.0 / vmax, "g3": 10.0 / vmax, "g4": c,
                "g5": 50.0 / vmax, "g6": v}

    @classmethod
    def degenerate_form(cls, params, stderr, qd=None, bounds=None, fit_scale=None):
        """``hyperbolic_stribeck_nonunique``: the hump ``g1 (tanh(g2 qd) - tanh(g3 qd))`` under
        2 % of ``fit_scale`` on the data, ``g2`` ~ ``g3``, ``g1`` ~ 0, or ``g1``, ``g2``,
        ``g3`` with a relative standard error over 50 % (thesis, hyperbolic model)."""
        rel = lambda k: abs(stderr.get(k, np.nan)) / max(abs(params[k]), 1e-12)  # noqa: E731
        g1, g2, g3 = params["g1"], params["g2"], params["g3"]
        if fit_scale and qd is not None and np.size(qd):
            a = np.abs(np.asarray(qd, float))
            if np.max(np.abs(g1 * (np.tanh(g2 * a) - np.tanh(g3 * a)))) < 0.02 * fit_scale:
                return "hyperbolic_stribeck_nonunique"
        if abs(g2 - g3) < 0.02 * max(abs(g2), abs(g3), 1e-9) or abs(g1) < 1e-9:
            return "hyperbolic_stribeck_nonunique"
        if any(not np.isfinite(rel(k)) or rel(k) > 0.5 for k in ("g1", "g2", "g3")):
            return "hyperbolic_stribeck_nonunique"
        return None

    def violations(self, form=None):
        """Thesis eq. 2-7 signs: the Coulomb term ``g4 >= 0``, the viscous ``g6 >= 0``, and a
        friction that opposes the motion at every speed (``f(v) >= 0`` for 1e-3 <= v <= 10
        rad/s: a static level g1 + g4 below zero, or a hump deeper than the Coulomb level)."""
        p = self._p
        out = []
        if p["g4"] < 0:
            out.append(f"g4 = {p['g4']:.3g} < 0: negative Coulomb term")
        if p["g6"] < 0:
            out.append(f"g6 = {p['g6']:.3g} < 0: negative viscous coefficient")
        v = np.geomspace(1e-3, 10.0, 400)                     # rad/s
        f = self.torque(v)
        if np.min(f) < 0:
            k = int(np.argmin(f))
            out.append(f"f({v[k]:.3g} rad/s) = {f[k]:.3g} < 0: the friction pushes the motion")
        return tuple(out)

    @classmethod
    def canonical(cls, params):
        p = dict(params)
        if p["g2"] < p["g3"]:
            p["g2"], p["g3"], p["g1"] = p["g3"], p["g2"], -p["g1"]
        return p

    def degeneracy(self, qd, fit_scale: float) -> str | None:
        a = np.abs(np.asarray(qd, float))
        a = a[a > 0]
        if a.size == 0:
            return "no moving samples: nothing is identifiable"
        p = self._p
        lo, hi = np.percentile(a, [2.0, 98.0])
        hump = p["g1"] * laws.hyperbolic_columns(a, p["g2"], p["g3"], p["g5"])[:, 0]
        if np.max(np.abs(hump)) < 0.02 * fit_scale:
            why = ("g2 ~ g3" if abs(p["g2"] - p["g3"]) <= 0.05 * max(p["g2"], p["g3"])
                   else "g1 ~ 0" if abs(p["g1"]) < 0.02 * fit_scale
                   else "tanh(g2 qd) ~ tanh(g3 qd) on the sampled speeds")
            return (f"{why}: the Stribeck term g1 (tanh(g2 qd) - tanh(g3 qd)) is under 2% of the "
                    "torque scale, the model reduces to g4 tanh(g5 qd) + g6 qd and g1, g2, g3 are "
                    "not identifiable")
        if p["g5"] * lo > 5.0:
            return (f"g5 = {p['g5']:.3g} is huge for these data (tanh(g5 qd) = sign(qd) at every "
                    f"sampled speed above {lo:.3g} rad/s): the Coulomb term is a pure sign "
                    "function and g5 is not identifiable")
        if max(p["g2"], p["g3"]) * hi < 0.2:
            return ("g2 and g3 are so small that the Stribeck term is linear in qd over the "
                    "sampled speeds: it merges with g6 and g1, g2, g3 are not identifiable")
        return None


# --------------------------------------------------------------------------------------------
class Arctan(_StaticModel):
    r"""Arctangent static friction of Indri & Trapani 2020 eq. 1-2.

    .. math::

        \tau_f(v) = \tau_s S_0(v) + \tau_{sc} \frac{2}{\pi} \arctan(\delta v) + \tau_v v
        + \tau_{nlv} v^2 S_0(v), \qquad S_0(v) = \frac{2}{\pi} \arctan(K_v v)

    evaluated by :func:`ident.friction.laws.arctan_columns` [1]_. ``tau_s``: static level;
    ``tau_sc``: difference between Coulomb and static friction (the Stribeck term, negative
    for a drop); ``tau_v``: viscous; ``tau_nlv``: nonlinear viscous; ``delta`` (s/rad) shapes
    the Stribeck term. ``Kv`` is a setting (the paper fixes 1000), not a parameter. Odd and
    continuous. Linear in (tau_s, tau_sc, tau_v, tau_nlv) for fixed delta: the columns are the
    regressor of eq. 28. Identified by the delta grid search of eq. 27-28
    (:func:`ident.friction.fit.fit_arctan`).

    Parameters
    ----------
    Kv : float, optional
        Steepness of the smooth sign ``S0`` (s/rad), > 0; default
        :data:`ident.friction.constants.KV_DEFAULT` (the paper's 1000).
    **params : float
        ``tau_s``, ``tau_sc`` (N m), ``tau_v`` (N m s/rad), ``tau_nlv`` (N m s^2/rad^2) and
        ``delta`` (s/rad), by keyword.

    Raises
    ------
    ValueError
        If ``Kv`` is not positive.

    References
    ----------
    .. [1] Indri & Trapani 2020 (seeds 001), eq. 1-2, 27-28.
    """

    name = "arctan"
    param_names = ("tau_s", "tau_sc", "tau_v", "tau_nlv", "delta")
    linear_names = ("tau_s", "tau_sc", "tau_v", "tau_nlv")
    fit_method = "delta_grid"

    def __init__(self, *, Kv: float = KV_DEFAULT, **params):
        super().__init__(**params)
        if not Kv > 0:
            raise ValueError(f"Arctan: Kv must be positive, got {Kv}")
        self.Kv = float(Kv)

    @property
    def settings(self) -> dict:
        return {"Kv": self.Kv}

    @staticmethod
    def regressor(qd, delta: float, Kv: float = KV_DEFAULT) -> np.ndarray:
        """Indri & Trapani eq. 28: (T, 4) columns multiplying (tau_s, tau_sc, tau_v, tau_nlv)
        (:func:`ident.friction.laws.arctan_columns`)."""
        return laws.arctan_columns(qd, delta, Kv)

    def linear_design(self, qd, qdd=None, dt=None):
        qd = np.asarray(qd, float)
        return self.regressor(qd, self._p["delta"], self.Kv), np.zeros(qd.shape)

    # pieces reused by the dynamic (LuGre-type) models -------------------------------------
    def g(self, v) -> np.ndarray:
        """Indri & Trapani eq. 8: ``g(v) = tau_s + tau_sc 2/pi arctan(S1(v) delta)``
        (:func:`ident.friction.laws.arctan_g`)."""
        p = self._p
        return laws.arctan_g(v, p["tau_s"], p["tau_sc"], p["delta"], self.Kv)

    def viscous(self, v) -> np.ndarray:
        """Indri & Trapani eq. 9: ``tau_fv(v) = tau_v v + tau_nlv v^2 S0(v)``
        (:func:`ident.friction.laws.arctan_viscous`)."""
        return laws.arctan_viscous(v, self._p["tau_v"], self._p["tau_nlv"], self.Kv)

    def degeneracy(self, qd, fit_scale: float) -> str | None:
        p = self._p
        a = np.abs(np.asarray(qd, float))
        a = a[a > 0]
        if a.size == 0:
            return "no moving samples: nothing is identifiable"
        term = np.max(np.abs(p["tau_sc"] * _2_PI * np.arctan(a * p["delta"])))
        if term < 0.02 * fit_scale:
            return (f"the Stribeck term tau_sc 2/pi arctan(delta v) is under 2% of the torque scale "
                    f"(tau_sc = {p['tau_sc']:.3g}, delta = {p['delta']:.3g}): the model reduces to "
                    "tau_s S0 + tau_v v + tau_nlv v^2 S0 and delta is not identifiable")
        lo = np.percentile(a, 2.0)
        if p["delta"] * lo > 30.0:
            return (f"delta = {p['delta']:.3g} makes arctan(delta v) a sign function at every "
                    "sampled speed: tau_sc merges with tau_s (only their sum is identifiable)")
        return None
