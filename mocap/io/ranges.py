"""The physical range of every number a campaign declares (issue 45), in one table.

``campaign.toml`` and ``robot/drives.toml`` values are checked against :data:`RANGES` when the
files are read (:func:`check_range`): a value outside its range is an
:class:`~mocap.io.errors.InputError` naming the file and the key (exit status 2), before any
computation could turn it into overflow warnings or an error that blames another file.

The bounds are physical, not statistical: finite everywhere, positive where the quantity
cannot be zero (a ratio, a limit, a step), and upper bounds two or more orders of magnitude
beyond any industrial arm (the heaviest payloads are ~2.3 t; link-side speeds of arms are a few
rad/s), so that only a damaged or mis-scaled value is refused (docs/inputs.md, "Declared
ranges").
"""
from __future__ import annotations

import math
from pathlib import Path
from typing import NamedTuple

from mocap.io.errors import InputError


class Range(NamedTuple):
    """The range of one declared value: ``lo`` (``lo_open``: excluded) to ``hi`` inclusive, in
    ``unit``; ``integer``: a TOML integer; ``why``: what a value beyond it would mean."""

    lo: float
    hi: float
    unit: str
    lo_open: bool = False
    integer: bool = False
    why: str = ""


#: ``(table, key) -> Range``: every number of the manifest and the drives file.
RANGES: dict[tuple[str, str], Range] = {
    # campaign.toml
    ("robot", "gravity"): Range(-100.0, 100.0, "m/s^2", why="each component; Earth's is 9.81"),
    ("trial", "load_kg"): Range(0.0, 1e4, "kg", why="the heaviest robot payloads are ~2.3 t"),
    ("trial", "vmax_frac"): Range(0.0, 1.5, "", lo_open=True, why="a fraction of the joint's max speed"),
    ("trial", "repetition"): Range(1, 1e6, "", integer=True, why="repetitions count from 1"),
    ("trial", "time_offset"): Range(-1e6, 1e6, "s", why="marker clock to robot clock"),
    ("trial", "joints"): Range(1, 64, "", integer=True, why="joints are numbered from 1"),
    ("robot", "fixed"): Range(-1e3, 1e3, "rad or m", why="the value a joint off the chain is fixed at"),
    # drives.toml (link side)
    ("drive", "gear_ratio"): Range(0.0, 1e5, "", lo_open=True, why="its magnitude; the sign is the direction"),
    ("drive", "motor_inertia"): Range(0.0, 1e5, "kg m^2", why="rotor inertia times the ratio squared"),
    ("drive", "motor_viscous"): Range(0.0, 1e5, "N m s/rad", why="rotor damping times the ratio squared"),
    ("drive", "max_velocity"): Range(0.0, 1e3, "rad/s", lo_open=True, why="omit the key for no limit"),
    ("drive", "max_torque"): Range(0.0, 1e6, "N m", lo_open=True, why="omit the key for no limit"),
    ("drive", "encoder_resolution"): Range(0.0, 0.1, "rad", lo_open=True,
                                           why="one encoder step; omit the key when it is unknown"),
    ("drive", "stiffness"): Range(0.0, 1e10, "N m/rad", lo_open=True, why="transmission stiffness"),
}


def check_range(table: str, key: str, v, *, path: str | Path, where: str) -> float:
    """``v`` as a float after checking it against ``RANGES[(table, key)]``.

    Parameters
    ----------
    table, key : str
        The entry of :data:`RANGES`.
    v : object
        The value as TOML gave it.
    path : str or pathlib.Path
        The file read (named in the error).
    where : str
        The table or trial it sits in (e.g. ``"trial 'j5-r1'"``, ``"joint 'joint1'"``).

    Raises
    ------
    InputError
        If ``v`` is not a (finite) number, not an integer where one is required, or out of the
        range; one line naming the file and the key.
    """
    r = RANGES[(table, key)]
    kind = "an integer" if r.integer else "a number"
    if isinstance(v, bool) or not isinstance(v, int if r.integer else (int, float)):
        raise InputError(f"{where}: '{key}' must be {kind}, got {v!r}", path=path, label=key)
    if not math.isfinite(v):
        raise InputError(f"{where}: '{key}' must be a finite number, got {v!r}"
                         + (f" ({r.why})" if r.why else ""), path=path, label=key)
    low = v <= r.lo if r.lo_open else v < r.lo
    if low or v > r.hi:
        unit = f" {r.unit}" if r.unit else ""
        lo = f"> {r.lo:g}" if r.lo_open else f">= {r.lo:g}"
        raise InputError(f"{where}: {key} must be {lo} and <= {r.hi:g}{unit}, got {v!r}"
                         + (f" ({r.why})" if r.why else ""), path=path, label=key)
    return float(v)
