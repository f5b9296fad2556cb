"""The common interface of friction models (used forward by the simulator, fitted by ident).

A model is configured by its parameters (FORMAT.md names, link side, SI) in the constructor.
Static models are memoryless: ``torque(qd)``. Dynamic models (LuGre type) carry an internal
bristle state ``z``; they give ``torque(qd, qdd=..., dt=...)`` for a sampled velocity history
(exact discretisation), and ``state_derivative``/``output`` for a continuous-time integrator.
Fitting lives in estimators (:mod:`ident.friction.fit`), which return new model instances.
"""
from __future__ import annotations

from typing import ClassVar

import numpy as np


class FrictionModel:
    name: ClassVar[str] = ""
    param_names: ClassVar[tuple[str, ...]] = ()
    dynamic: ClassVar[bool] = False

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
        return {"model": self.name, "params": self.params}

    def violations(self, form: str | None = None) -> tuple[str, ...]:
        """Physically impossible parameter values (a friction that pushes the motion, a
        negative Coulomb or viscous level), one short sentence each; () when none. ``form``:
        the degenerate form the fit was classified as (some forms carry a level elsewhere)."""
        return ()

    # -- evaluation ----------------------------------------------------------------------
    def torque(self, qd, qdd=None, dt: float | None = None) -> np.ndarray:
        """Friction torque (same shape as ``qd``) opposing motion: positive for qd > 0."""
        raise NotImplementedError


class CoulombViscous(FrictionModel):
    """Thesis eq. 2-5: ``f = c sign(qd) + v qd``."""

    name = "cv"
    param_names = ("c", "v")

    def torque(self, qd, qdd=None, dt=None):
        qd = np.asarray(qd, float)
        return self._p["c"] * np.sign(qd) + self._p["v"] * qd

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
        qd = np.asarray(qd, float)
        return np.column_stack([np.sign(qd), qd])
