"""Candidate effects: parametric augmentations of the nominal model, one per vocabulary name.

Each candidate adds regressor columns to one channel's nominal model. Nonlinear shape
parameters (a Stribeck velocity, a ripple harmonic, a warm-up time constant, a bristle length)
are searched over a grid; the amplitudes are linear. The shapes are deliberately generic
families (several exponents, harmonics, time constants), not the simulator's exact forms, so the
diagnosis recognises an effect from its physics rather than from one formula.

Channels: ``torque`` (motor torque against the rigid Coulomb+viscous model) and
``transmission`` (link angle from markers minus motor angle).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

from ident.effects import REGISTRY

V_EPS = 2e-3  # rad/s: width of the smoothed sign used for Coulomb-type terms


def ssign(qd: np.ndarray) -> np.ndarray:
    """Smoothed sign of velocity (Coulomb direction)."""
    return np.tanh(qd / V_EPS)


def bristle_sign(q: np.ndarray, qd: np.ndarray, trial: np.ndarray, x0: float) -> np.ndarray:
    """Normalised bristle deflection ``s = z / x0`` of a LuGre-type contact, driven by the
    joint's displacement: ``ds = (sign(dq) - s) |dq| / x0`` solved exactly between samples,
    ``s[k+1] = e^{-|dq|/x0} s[k] + (1 - e^{-|dq|/x0}) sign(dq)`` (rate independent, so samples
    left out of the channel in between are bridged exactly). Saturated at each trial's start.
    Vectorised with :func:`ident.friction.dynamic.linear_scan`."""
    from ident.friction.dynamic import linear_scan

    n = q.shape[0]
    if n == 0:
        return np.zeros(0)
    dq = np.diff(q)
    new_trial = trial[1:] != trial[:-1]
    sgn = np.sign(dq)
    sgn = np.where(sgn == 0, np.sign(qd[1:]), sgn)
    decay = np.abs(dq) / x0
    decay = np.where(new_trial, 60.0, np.minimum(decay, 60.0))
    sgn = np.where(new_trial, np.where(qd[1:] >= 0, 1.0, -1.0), sgn)
    drive = -np.expm1(-decay) * sgn
    s0 = 1.0 if qd[0] >= 0 else -1.0
    return linear_scan(decay, drive, s0)[:n]


@dataclass(frozen=True)
class Candidate:
    name: str
    channel: str
    grid: tuple
    columns: Callable  # (JointData, hp) -> (N, k)
    describe: Callable = lambda hp: ""  # noqa: E731
    family: str = ""


def _stribeck(d, hp):
    vs, shape = hp
    return (ssign(d.qd) * np.exp(-(np.abs(d.qd) / vs) ** shape))[:, None]


def _presliding(d, hp):
    """Bristle deflection minus the Coulomb direction, and its rate (the bristle damping
    ``sigma1 dz/dt`` of LuGre-type models)."""
    s = bristle_sign(d.q, d.qd, d.trial, hp)
    t = d.t
    ds = np.zeros_like(s)
    if s.size > 2:
        ds[1:-1] = (s[2:] - s[:-2]) / np.maximum(t[2:] - t[:-2], 1e-9)
        edge = np.r_[True, d.trial[1:] != d.trial[:-1]] | np.r_[d.trial[1:] != d.trial[:-1], True]
        ds[edge] = 0.0
        gap = np.r_[False, np.diff(t) > 3 * np.median(np.diff(t))]
        ds[gap | np.r_[gap[1:], False]] = 0.0
    return np.column_stack([s - ssign(d.qd), ds * hp])


def _ripple(d, hp):
    return np.column_stack([np.sin(hp * d.q), np.cos(hp * d.q)])


def _load(d, hp):
    tau = d.tau_grav if hp == "gravity" else d.tau_urdf
    return (ssign(d.qd) * np.abs(tau))[:, None]


def _thermal(d, hp):
    tt = d.t - d.t.min()
    w = np.exp(-tt / hp) if np.isfinite(hp) else 1.0 - tt / max(tt.max(), 1e-9)
    return np.column_stack([ssign(d.qd) * w, d.qd * w])


def _scale(d, hp):
    return d.tau_urdf[:, None]


def _asym(d, hp):
    pos = d.qd > 0
    return np.column_stack([np.abs(ssign(d.qd)), d.qd * pos])


def _nlv(d, hp):
    return (np.sign(d.qd) * np.abs(d.qd) ** hp)[:, None]


def _compliance(d, hp):
    return d.y_m[:, None]


def _backlash(d, hp):
    kind, width = hp
    if kind == "torque":
        scale = width * max(np.percentile(np.abs(d.y_m), 95), 1e-9)
        return np.tanh(d.y_m / scale)[:, None]
    return np.tanh(d.qd_m / width)[:, None]


def _time_offset(d, hp):
    return d.qd_m[:, None]


def _ripple_grid(gear_ratio):
    ks = list(range(1, 49))
    if gear_ratio and gear_ratio > 48:
        ks += [gear_ratio, 2 * gear_ratio]
    return tuple(float(k) for k in ks)


# Candidate families by name; ident.effects declares which effect each one stands for.
# name -> (channel, grid(gear_ratio), columns, describe)
FAMILIES = {
    "stribeck": ("torque",
                 lambda g: tuple((vs, sh) for vs in np.geomspace(0.005, 0.4, 12) for sh in (0.5, 1.0, 2.0)),
                 _stribeck, lambda hp: f"Stribeck velocity {hp[0]:.3g} rad/s, shape exponent {hp[1]:g}"),
    "presliding": ("torque", lambda g: tuple(np.geomspace(1e-4, 3e-2, 12)), _presliding,
                   lambda hp: f"presliding length {hp:.2e} rad"),
    "position_ripple": ("torque", _ripple_grid, _ripple, lambda hp: f"{hp:g} cycles per joint revolution"),
    "load_dependent": ("torque", lambda g: ("gravity", "rigid"), _load,
                       lambda hp: f"Coulomb level growing with |{'gravity' if hp == 'gravity' else 'rigid-body'} torque|"),
    "thermal_drift": ("torque", lambda g: tuple(np.geomspace(20, 5000, 10)) + (np.inf,), _thermal,
                      lambda hp: "linear drift over the campaign" if not np.isfinite(hp)
                      else f"warm-up time constant {hp:.0f} s"),
    "torque_scale": ("torque", lambda g: (None,), _scale, lambda hp: "torque proportional to rigid-body torque"),
    "asymmetry": ("torque", lambda g: (None,), _asym, lambda hp: "direction-dependent Coulomb and viscous"),
    "nonlinear_viscous": ("torque", lambda g: (0.5, 1.5, 2.0, 3.0), _nlv, lambda hp: f"viscous term |qd|^{hp:g}"),
    "compliance": ("transmission", lambda g: (None,), _compliance,
                   lambda hp: "deflection proportional to transmitted torque"),
    "backlash": ("transmission",
                 lambda g: tuple(("torque", w) for w in (0.005, 0.02, 0.05)) + tuple(("motion", w) for w in (0.002, 0.01)),
                 _backlash, lambda hp: f"dead band switching with {hp[0]} sign"),
    "time_offset": ("transmission", lambda g: (None,), _time_offset,
                    lambda hp: "marker clock shifted: q_link(t) = q(t + dt)"),
}


def candidate_effects(gear_ratio: float | None = None) -> list[Candidate]:
    """One candidate per (effect, family) of the registry (:mod:`ident.effects`); a candidate's
    ``name`` is the effect it stands for, ``family`` the form tested."""
    out = []
    for spec in REGISTRY.values():
        for fam in spec.families:
            channel, grid, columns, describe = FAMILIES[fam]
            out.append(Candidate(spec.name, channel, grid(gear_ratio), columns, describe, fam))
    return out


def confounders(name: str) -> tuple[list, str]:
    """(effects confused with ``name``, the experiment that separates them), from the registry."""
    sp = REGISTRY.get(name)
    return (list(sp.confounders), sp.separating_experiment) if sp else ([], "")


#: name -> (confounders, separating experiment), read from the registry
CONFOUNDERS = {n: confounders(n) for n, sp in REGISTRY.items() if sp.families}
