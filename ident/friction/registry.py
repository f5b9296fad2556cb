"""The friction model registry: every friction model by its name, and the one check of names.

:data:`MODELS` maps a name (FORMAT.md's ``fits.json`` names) to its class
(:class:`ident.friction.base.FrictionModel`). Every check of a model name goes through
:func:`check_models` (the ``--models`` option through :func:`parse_models`), so a model added
here is valid for every command and settings class at once; which identification path fits
each model is :func:`ident.workflow.plan`'s decision, not the registry's.
"""
from __future__ import annotations

from mocap.io.errors import InputError

from ident.friction.base import CoulombViscous
from ident.friction.dynamic import LuGreDM1, LuGreDM2
from ident.friction.static import Arctan, Hyperbolic, Stribeck

__all__ = ["MODELS", "model_names", "check_models", "parse_models"]

#: every friction model by its name (thesis eq. 2-4 laws and Indri & Trapani's)
MODELS = {m.name: m for m in (CoulombViscous, Stribeck, Hyperbolic, Arctan, LuGreDM1, LuGreDM2)}


def model_names() -> tuple:
    """The registered model names, in the registry's order."""
    return tuple(MODELS)


def check_models(models) -> tuple:
    """The friction model names checked against the registry, as a tuple.

    Each name must be a key of :data:`MODELS` (a one-link law or a dynamic model); which path
    fits each is :func:`ident.workflow.plan`'s.

    Parameters
    ----------
    models : sequence of str
        Friction model names (FORMAT.md's names).

    Returns
    -------
    tuple of str
        The names, in the order given.

    Raises
    ------
    InputError
        Empty, or an unknown name (named, with the known ones).

    References
    ----------
    .. [1] jointlab data format (docs/format.md), sec. fits.json.

    Examples
    --------
    >>> check_models(["cv", "dm1"])
    ('cv', 'dm1')
    """
    models = tuple(models)
    if not models:
        raise InputError("no friction models given")
    for m in models:
        if not isinstance(m, str) or m not in MODELS:
            raise InputError(f"unknown friction model {m!r} (known: {', '.join(MODELS)})", label=str(m))
    return models


def parse_models(text: str) -> tuple:
    """The ``--models`` list: comma-separated names, duplicates dropped, each a known model.

    Parameters
    ----------
    text : str
        E.g. ``"cv,stribeck,dm1"``.

    Returns
    -------
    tuple of str
        The names in the given order.

    Raises
    ------
    InputError
        Empty, or a name that is not in :data:`MODELS`.

    References
    ----------
    .. [1] PA10 thesis (seeds 002), eq. 2-4 and Tables 5-1 to 5-3.
    .. [2] Indri & Trapani 2020 (seeds 001), sec. III.

    Examples
    --------
    >>> parse_models("cv, stribeck,cv,dm1")
    ('cv', 'stribeck', 'dm1')
    """
    models = tuple(dict.fromkeys(m.strip() for m in text.split(",") if m.strip()))
    if not models:
        raise InputError("--models is empty")
    try:
        return check_models(models)
    except InputError as exc:
        raise InputError(f"--models: {exc}") from None
