"""Settings that own their constraints: one declared table per settings class, checked once.

A settings dataclass derives from :class:`Settings` and declares, at class level, which values
each field may take::

    @dataclass(frozen=True)
    class FitSettings(Settings):
        constraints: ClassVar[dict] = {"n_starts": ("--starts", Interval(1, integer=True)),
                                       "sync": ("--sync", OneOf("clock", "estimate"))}

``__post_init__`` checks every entry (so does :func:`dataclasses.replace`, which constructs
anew): invalid settings cannot exist. A refusal is one :class:`~mocap.io.errors.InputError` line
naming the option as the command line spells it and the settings field, e.g. ``--starts must be
an integer >= 1, got 0 (FitSettings.n_starts)``; the CLI prints it and exits with status 2.
An option that belongs to no settings class (``--workers``, ``--export-dt``) goes through the
same constraints with :func:`check_option`. Friction model names are checked by the model
registry (:func:`ident.friction.registry.check_models`), never by a list kept here.

The pattern is scikit-learn's ``_parameter_constraints`` [1]_: a declared table checked in one
place rather than checks scattered over the callers.

References
----------
.. [1] scikit-learn developer guide, parameter validation (``sklearn.utils._param_validation``).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from numbers import Integral, Real
from pathlib import Path
from typing import ClassVar

from mocap.io.errors import InputError
from mocap.io.ids import TRIAL_ID

from ident.friction.registry import check_models

__all__ = ["Constraint", "Interval", "OneOf", "AnyOf", "Flag", "Text", "PathLike", "Joints",
           "TrialIds", "Models", "InstanceOf", "Keys", "SEED", "Settings", "check_option",
           "check_settings"]


class Constraint:
    """One rule on one value: :meth:`problem` says what is wrong with a value (``None``: nothing).

    Subclasses set :meth:`describe` (what a valid value is, after ``must be``) and :meth:`ok`;
    ``none=True`` also admits ``None`` (an option left unset).
    """

    none: bool = False

    def ok(self, value) -> bool:
        raise NotImplementedError

    def describe(self) -> str:
        raise NotImplementedError

    def problem(self, value) -> str | None:
        """``None`` when ``value`` is valid, else ``"must be <describe>, got <value>"``."""
        if value is None and self.none:
            return None
        if self.ok(value):
            return None
        return f"must be {self.describe()}, got {value!r}"


def _number(value, parse: bool):
    """``value`` as a float, or None when it is no number (a bool is none; a string only when
    ``parse``)."""
    if isinstance(value, bool):
        return None
    if isinstance(value, str):
        if not parse:
            return None
        try:
            return float(value)
        except ValueError:
            return None
    if isinstance(value, Real):
        return float(value)
    return None


def _bound(x) -> str:
    return f"{x:g}" if isinstance(x, float) else str(x)


@dataclass(frozen=True)
class Interval(Constraint):
    """A finite number in ``[lo, hi]`` (``closed``: ``"both"``, ``"left"``, ``"right"`` or
    ``"neither"``; ``None``: no bound on that side). ``integer``: an integer (numpy integers
    too, never a bool); ``parse``: text that ``float`` reads counts as its number (``--window
    0.2``); ``note``: said after the range (``"(0: all)"``); ``text``: the whole description,
    where the bounds would read badly."""

    lo: float | None = None
    hi: float | None = None
    closed: str = "both"
    integer: bool = False
    none: bool = False
    parse: bool = False
    note: str = ""
    text: str = ""

    def ok(self, value) -> bool:
        if self.integer:
            if isinstance(value, bool) or not isinstance(value, Integral):
                return False
            v = int(value)
        else:
            v = _number(value, self.parse)
            if v is None or not math.isfinite(v):
                return False
        if self.lo is not None and (v < self.lo or (v == self.lo and self.closed in ("right", "neither"))):
            return False
        if self.hi is not None and (v > self.hi or (v == self.hi and self.closed in ("left", "neither"))):
            return False
        return True

    def describe(self) -> str:
        if self.text:
            return self.text
        parts = []
        if self.lo is not None:
            parts.append((">= " if self.closed in ("both", "left") else "> ") + _bound(self.lo))
        if self.hi is not None:
            parts.append(("<= " if self.closed in ("both", "right") else "< ") + _bound(self.hi))
        kind = "an integer" if self.integer else "a finite number"
        text = " ".join([kind, " and ".join(parts)]) if parts else kind
        return text + (f" {self.note}" if self.note else "")


#: a random seed: numpy's generators take integers in 0 .. 2**63 - 1
SEED = Interval(0, 2 ** 63 - 1, integer=True, text="an integer >= 0 (below 2**63)")


class OneOf(Constraint):
    """One of the given values (compared with ``==``; ``"auto"``, ``"clock"``, ...)."""

    def __init__(self, *values, none: bool = False):
        self.values, self.none = values, none

    def ok(self, value) -> bool:
        return any(type(value) is type(v) and value == v for v in self.values)

    def describe(self) -> str:
        shown = [repr(v) for v in self.values]
        return shown[0] if len(shown) == 1 else ", ".join(shown[:-1]) + " or " + shown[-1]


class AnyOf(Constraint):
    """Valid when any of the given constraints is (``"auto"`` or a number)."""

    def __init__(self, *constraints: Constraint, none: bool = False):
        self.constraints, self.none = constraints, none

    def ok(self, value) -> bool:
        return any(c.problem(value) is None for c in self.constraints)

    def describe(self) -> str:
        parts = [p for c in self.constraints
                 for p in ([repr(v) for v in c.values] if isinstance(c, OneOf) else [c.describe()])]
        return parts[0] if len(parts) == 1 else ", ".join(parts[:-1]) + " or " + parts[-1]


class Flag(Constraint):
    """``True`` or ``False`` (a switch such as ``--no-plots``)."""

    def ok(self, value) -> bool:
        return isinstance(value, bool)

    def describe(self) -> str:
        return "True or False"


class Text(Constraint):
    """Non-empty text."""

    def __init__(self, none: bool = False):
        self.none = none

    def ok(self, value) -> bool:
        return isinstance(value, str) and value.strip() != ""

    def describe(self) -> str:
        return "non-empty text"


class PathLike(Constraint):
    """A file or folder path (``str`` or :class:`pathlib.Path`, not empty); whether it exists is
    the reader's to say, with the file."""

    def __init__(self, none: bool = True):
        self.none = none

    def ok(self, value) -> bool:
        return isinstance(value, Path) or (isinstance(value, str) and value != "")

    def describe(self) -> str:
        return "a path"


class Joints(Constraint):
    """Joint numbers as in the files: distinct integers >= 1 (whether the robot has them is
    checked against its URDF once it is loaded)."""

    def __init__(self, none: bool = True):
        self.none = none

    def ok(self, value) -> bool:
        if isinstance(value, (str, bytes)) or not hasattr(value, "__iter__"):
            return False
        vals = list(value)
        return (all(isinstance(j, Integral) and not isinstance(j, bool) and j >= 1 for j in vals)
                and len(set(vals)) == len(vals))

    def describe(self) -> str:
        return "distinct joint numbers >= 1"


class TrialIds(Constraint):
    """FORMAT.md trial ids (:data:`mocap.io.ids.TRIAL_ID`: letters, digits, '.', '_' and '-',
    at most 100 characters, not starting with '.')."""

    def __init__(self, none: bool = True):
        self.none = none

    def ok(self, value) -> bool:
        if isinstance(value, (str, bytes)) or not hasattr(value, "__iter__"):
            return False
        return all(not isinstance(t, bool) and isinstance(t, (str, int)) and TRIAL_ID.fullmatch(str(t))
                   for t in value)

    def describe(self) -> str:
        return ("trial ids of letters, digits, '.', '_' and '-' (at most 100 characters, not "
                "starting with '.')")

    def problem(self, value) -> str | None:
        found = super().problem(value)
        if found is None or isinstance(value, (str, bytes)) or not hasattr(value, "__iter__"):
            return found
        bad = next(t for t in value if not (not isinstance(t, bool) and isinstance(t, (str, int))
                                            and TRIAL_ID.fullmatch(str(t))))
        return f"must be {self.describe()}, got {bad!r}"


class Models(Constraint):
    """Friction model names, each known to the model registry
    (:func:`ident.friction.registry.check_models`: a model added there is valid here)."""

    def __init__(self, none: bool = False):
        self.none = none

    def ok(self, value) -> bool:
        return not isinstance(value, (str, bytes)) and hasattr(value, "__iter__")

    def describe(self) -> str:
        return "a list of friction model names"

    def problem(self, value) -> str | None:
        found = super().problem(value)
        if found is not None or value is None:
            return found
        try:
            check_models(value)
        except InputError as exc:
            return f": {exc}"
        return None


class InstanceOf(Constraint):
    """An instance of the given class (nested settings: ``FitSettings``, a checked ``Plan``)."""

    def __init__(self, cls: type, none: bool = False):
        self.cls, self.none = cls, none

    def ok(self, value) -> bool:
        return isinstance(value, self.cls)

    def describe(self) -> str:
        return f"a {self.cls.__name__}"


class Keys(Constraint):
    """A dict whose given keys (where present) follow their own rule, each with its option:
    ``Keys({"min_markers": ("--min-markers", Interval(1, integer=True))})``; other keys pass."""

    def __init__(self, table: dict):
        self.table = table

    def ok(self, value) -> bool:
        return isinstance(value, dict)

    def describe(self) -> str:
        return "a dict"

    def problem(self, value) -> str | None:
        found = super().problem(value)
        if found is not None:
            return found
        for key, (option, rule) in self.table.items():
            if key in value:
                p = rule.problem(value[key])
                if p is not None:
                    return f"{option} {p}"
        return None


def _message(option: str, problem: str) -> str:
    # a rule that names its own subject (Keys: the nested option) is said as it is; one that
    # starts with ":" (the registry's own line) follows the option directly
    if problem.startswith("--"):
        return problem
    return f"{option}{problem}" if problem.startswith(":") else f"{option} {problem}"


def check_option(value, option: str, rule: Constraint):
    """``value`` of a command-line option that belongs to no settings class, checked against
    ``rule``; returns it, or raises one :class:`InputError` line naming ``option``.

    Examples
    --------
    >>> check_option(2, "--workers", Interval(1, integer=True))
    2
    >>> check_option(0, "--workers", Interval(1, integer=True))
    Traceback (most recent call last):
    ...
    mocap.io.errors.InputError: --workers must be an integer >= 1, got 0
    """
    p = rule.problem(value)
    if p is not None:
        raise InputError(_message(option, p))
    return value


def check_settings(obj) -> None:
    """Check every entry of ``type(obj).constraints`` (``{field: (option, Constraint)}``):
    the first value at fault raises one :class:`InputError` line naming its option and
    ``Class.field``."""
    cls = type(obj)
    for name, (option, rule) in cls.constraints.items():
        p = rule.problem(getattr(obj, name))
        if p is not None:
            where = f"{cls.__name__}.{name}"
            raise InputError(f"{_message(option, p)} ({where})")


class Settings:
    """Base of the settings dataclasses: ``constraints`` (``{field: (option, Constraint)}``,
    the option as the command line spells it) is checked at construction
    (:func:`check_settings`). A subclass with its own ``__post_init__`` calls this one."""

    constraints: ClassVar[dict] = {}

    def __post_init__(self):
        check_settings(self)
