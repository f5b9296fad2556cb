"""Friction models with one interface (see :mod:`ident.friction.base`) and their estimators."""
from ident.friction.base import CoulombViscous, FrictionModel
from ident.friction.dynamic import LuGreDM1, LuGreDM2, linear_scan
from ident.friction.fit import FrictionFit, fit_arctan, fit_friction, predict
from ident.friction.laws import s0, s1
from ident.friction.registry import MODELS, check_models, parse_models
from ident.friction.static import Arctan, Hyperbolic, Stribeck

__all__ = ["FrictionModel", "CoulombViscous", "Stribeck", "Hyperbolic", "Arctan", "LuGreDM1",
           "LuGreDM2", "MODELS", "check_models", "parse_models", "FrictionFit", "fit_friction", "fit_arctan", "predict",
           "linear_scan", "s0", "s1"]
