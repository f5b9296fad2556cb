"""The common interface of friction models (used forward by the simulator, fitted by ident).

A model is configured by its parameters (FORMAT.md names, link side, SI) in the constructor.
Static models are memoryless: ``torque(qd)``. Dynamic models (LuGre type) carry an internal
bristle state ``z``; they give ``torque(qd, qdd=..., dt=...)`` for a sampled velocity history
(exact discretisation), and ``state_derivative``/``output`` for a continuous-time integrator.
Fitting lives in estimators (:mod:`ident.friction.fit`), which return new model instances.

:class:`FrictionModel` declares the whole interface the estimators use (no estimator probes a
model for optional methods): the split of the parameters into ``linear_names`` (the torque
is linear in them for fixed others) and the nonlinear rest, ``linear_design`` (the columns
and offset of that split), ``fit_hints`` (data-scaled starts and bounds of the nonlinear
parameters), ``complete_settings`` (settings taken from the data), ``canonical`` (one
representative of equivalent parameter sets), ``design_grad`` and ``vp_grid`` (an analytic
variable-projection Jacobian and a factored start grid; None where a model has none),
``degeneracy`` (the sentence naming a degenerate form), ``violations`` (physically impossible
values) and the thesis-form hooks of the one-link fit (``initial_guess``,
``degenerate_form``, ``report_form``). Defaults describe a model linear in all parameters.
The laws themselves are the functions of :mod:`ident.friction.laws`.
"""
from __future__ import annotations

from typing import ClassVar

import numpy as np

from ident.friction import laws


class FrictionModel:
    """Base class of the friction models: their parameters and the estimators' interface.

    A model holds its parameters (``param_names``, FORMAT.md names, link side, SI) and
    declares everything the estimators of :mod:`ident.friction.fit` use (the module
    docstring lists it); no estimator probes a model for optional methods. Subclasses set
    ``name``, ``param_names``, ``linear_names`` and ``linear_design`` (or ``torque`` for a
    model whose torque is not ``Phi @ linear + offset``) and override the hooks that differ
    from the defaults, which describe a model linear in all its parameters. The laws
    themselves are the functions of :mod:`ident.friction.laws` [1]_ [2]_.

    Parameters
    ----------
    **params : float
        Every name of ``param_names``, by keyword (link side, SI).

    Raises
    ------
    TypeError
        If a parameter of ``param_names`` is missing or an unknown one is given.

    References
    ----------
    .. [1] PA10 thesis (seeds 002), eq. 2-4 to 2-7.
    .. [2] Indri & Trapani 2020 (seeds 001), eq. 1-12, 23-24.
    """

    name: ClassVar[str] = ""
    param_names: ClassVar[tuple[str, ...]] = ()
    #: the parameters the torque is linear in once the others are fixed (default: all)
    linear_names: ClassVar[tuple[str, ...] | None] = None
    dynamic: ClassVar[bool] = False
    #: the estimator strategy of :func:`ident.friction.fit.fit_friction` ("auto": chosen from
    #: the declared interface; "delta_grid": Indri & Trapani's grid search, eq. 27-28)
    fit_method: ClassVar[str] = "auto"

    def __init__(self, **params):
        unknown = set(params) - set(self.param_names)
        missing = set(self.param_names) - set(params)
        if unknown or missing:
            raise TypeError(f"{type(self).__name__} takes parameters {self.param_names}; "
                            f"unknown {sorted(unknown)}, missing {sorted(missing)}")
        self._p = {k: float(params[k]) for k in self.param_names}

    # -- parameters ----------------------------------------------------------------------
    @property
    def params(self) -> dict:
        return dict(self._p)

    @property
    def theta(self) -> np.ndarray:
        return np.array([self._p[k] for k in self.param_names])

    @classmethod
    def linear_params(cls) -> tuple[str, ...]:
        """``linear_names``, or every parameter when the class leaves it None."""
        return cls.param_names if cls.linear_names is None else tuple(cls.linear_names)

    @classmethod
    def nonlinear_params(cls) -> tuple[str, ...]:
        """The parameters the torque is not linear in (``param_names`` order)."""
        lin = cls.linear_params()
        return tuple(p for p in cls.param_names if p not in lin)

    @property
    def nonlinear_names(self) -> tuple[str, ...]:
        return self.nonlinear_params()

    @property
    def settings(self) -> dict:
        """Constructor keywords that are not parameters (e.g. ``Kv``); {} when none."""
        return {}

    @classmethod
    def from_theta(cls, theta, **settings):
        return cls(**dict(zip(cls.param_names, np.asarray(theta, float))), **settings)

    def __getattr__(self, key):
        p = self.__dict__.get("_p")
        if p is not None and key in p:
            return p[key]
        raise AttributeError(key)

    def __repr__(self):
        inner = ", ".join(f"{k}={v:.6g}" for k, v in self._p.items())
        return f"{type(self).__name__}({inner})"

    def to_dict(self) -> dict:
        d = {"model": self.name, "params": self.params}
        if self.settings:
            d["settings"] = dict(self.settings)
        return d

    # -- evaluation ----------------------------------------------------------------------
    def linear_design(self, qd, qdd=None, dt=None):
        """``(Phi (T, len(linear_names)), offset (T,))`` with torque = Phi @ lin + offset."""
        raise NotImplementedError

    def torque(self, qd, qdd=None, dt=None) -> np.ndarray:
        """Friction torque (same shape as ``qd``) opposing motion: positive for qd > 0."""
        phi, off = self.linear_design(qd, qdd, dt)
        lin = np.array([self._p[k] for k in self.linear_params()])
        return phi @ lin + off

    # -- what the estimators need ----------------------------------------------------------
    @classmethod
    def fit_hints(cls, qd, settings: dict) -> tuple[dict, dict]:
        """(initial values, (lo, hi) bounds) of the nonlinear parameters for data ``qd``."""
        return {}, {}

    @classmethod
    def complete_settings(cls, qd, qdd, settings: dict) -> dict:
        """The constructor settings with those the data determine filled in (default: as
        given)."""
        return settings

    @classmethod
    def canonical(cls, params: dict) -> dict:
        """The representative of parameter sets that give the same torque (identity here)."""
        return dict(params)

    @classmethod
    def design_grad(cls, qd, nl: dict):
        """``(Phi, dPhi, cols)``: the linear design and its derivatives with respect to the
        nonlinear parameters (see :class:`ident.friction.static.Stribeck`); None: not
        available."""
        return None

    @classmethod
    def vp_grid(cls, qd, bounds: dict, n: int | None = None):
        """A factored grid over the nonlinear parameters (see
        :meth:`ident.friction.static._StaticModel.vp_grid`); None: no grid."""
        return None

    def degeneracy(self, qd, fit_scale: float) -> str | None:
        """A sentence naming the degenerate form these parameters take on ``qd``, or None.
        ``fit_scale``: the torque scale the parameter sizes are compared with."""
        return None

    def violations(self, form: str | None = None) -> tuple[str, ...]:
        """Physically impossible parameter values (a friction that pushes the motion, a
        negative Coulomb or viscous level), one short sentence each; () when none. ``form``:
        the degenerate form the fit was classified as (some forms carry a level elsewhere)."""
        return ()

    # -- the thesis's one-link fit (ident.model.onelink) -----------------------------------
    @classmethod
    def initial_guess(cls, c: float, v: float, vmax: float) -> dict:
        """Start of a nonlinear fit from a Coulomb + viscous fit ``(c, v)`` and the peak
        speed (thesis: "an initial guess from the Coulomb + Viscous model"); {}: none."""
        return {}

    @classmethod
    def degenerate_form(cls, params: dict, stderr: dict, qd=None, bounds: dict | None = None,
                        fit_scale: float | None = None) -> str | None:
        """The name of the thesis's degenerate form the parameters take
        (:func:`ident.model.onelink.name_degenerate`), or None. ``bounds``: {param: (lo, hi)}
        the fit was given."""
        return None

    @classmethod
    def report_form(cls, params: dict, stderr: dict, cov, names, qd) -> tuple[dict, dict]:
        """``(params, stderr)`` in the form the thesis reports where only a combination is
        identifiable (default: unchanged)."""
        return params, stderr


class CoulombViscous(FrictionModel):
    r"""Coulomb + viscous friction of thesis eq. 2-5, linear in both parameters.

    .. math::

        f(\dot{q}) = c \operatorname{sign}(\dot{q}) + v \dot{q}

    evaluated by :func:`ident.friction.laws.coulomb_viscous` [1]_; ``f(0) = 0`` (exact sign).

    Parameters
    ----------
    **params : float
        ``c`` (Coulomb level, N m) and ``v`` (viscous coefficient, N m s/rad), by keyword.

    References
    ----------
    .. [1] PA10 thesis (seeds 002), eq. 2-5.

    Examples
    --------
    >>> CoulombViscous(c=2.0, v=0.5).torque([-1.0, 0.0, 2.0]).tolist()
    [-2.5, 0.0, 3.0]
    """

    name = "cv"
    param_names = ("c", "v")
    linear_names = ("c", "v")

    def linear_design(self, qd, qdd=None, dt=None):
        qd = np.asarray(qd, float)
        return laws.coulomb_viscous_columns(qd), np.zeros(qd.shape)

    def torque(self, qd, qdd=None, dt=None):
        return laws.coulomb_viscous(qd, self._p["c"], self._p["v"])

    def violations(self, form=None):
        out = []
        if self._p["c"] < 0:
            out.append(f"c = {self._p['c']:.3g} < 0: negative Coulomb level")
        if self._p["v"] < 0:
            out.append(f"v = {self._p['v']:.3g} < 0: negative viscous coefficient")
        return tuple(out)

    @staticmethod
    def regressor(qd) -> np.ndarray:
        """(T, 2) columns multiplying (c, v): the model is linear in its parameters."""
        return laws.coulomb_viscous_columns(qd)
