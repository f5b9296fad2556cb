"""Friction models with one interface (see :mod:`ident.friction.base`)."""
from .base import CoulombViscous, FrictionModel

MODELS = {m.name: m for m in (CoulombViscous,)}

__all__ = ["FrictionModel", "CoulombViscous", "MODELS"]
