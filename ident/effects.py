"""The effect vocabulary of FORMAT.md, declared once.

Each :class:`EffectSpec` names one effect and carries everything the workbench says about it:
its physical meaning, the channel it lives in, the effects it is confused with and the
experiment that separates them, the form(s) the jointlab simulator gives it
(``sim_form``/``sim_params``, read by :mod:`ident.sim.effects`), and the candidate families the
gap diagnosis tests for it (names of :data:`ident.gap.candidates.FAMILIES`, read by
:func:`ident.gap.candidates.candidate_effects`). Adding an effect is one entry here, its
simulator parameters (a small function below) and, if no existing family fits, a candidate
family in :mod:`ident.gap.candidates`.

The simulator's forms and the diagnosis's families are deliberately not the same equations:
the diagnosis must recognise an effect by its physics (sign, what drives it, where it shows),
so each effect has several generic families with shape parameters searched over wide ranges.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Callable

#: rigid-equivalent transmission stiffness of jointlab's simulator, used only for a joint whose
#: drives.toml declares no ``stiffness`` (FORMAT.md: absent = rigid): the simulator then takes
#: ``max(K_NOMINAL, 2 tau_max / encoder_resolution)`` (deflection at rated torque under half an
#: encoder count, :func:`ident.sim.effects.nominal_stiffness`). A declared stiffness is always used.
K_NOMINAL = 3.0e5   # N m / rad


@dataclass(frozen=True)
class SimContext:
    """Joint constants the simulator's effect forms are sized from (link side, SI)."""

    c: float              # nominal Coulomb level
    v: float              # nominal viscous coefficient
    tau_max: float        # rated link-side torque
    vmax: float           # maximum speed
    inertia: float        # link + motor inertia
    campaign_length_s: float = 600.0
    k0: float = K_NOMINAL  # nominal (declared) transmission stiffness, N m/rad


@dataclass(frozen=True)
class EffectSpec:
    name: str
    channel: str                       # torque | transmission | clock | none (where it shows)
    doc: str                           # physical meaning
    sim_form: str                      # jointlab simulator's form (documentation)
    size: dict                         # simulator sizes at magnitude 1
    confounders: tuple = ()
    separating_experiment: str = ""
    families: tuple = ()               # candidate families (ident.gap.candidates.FAMILIES)
    sim_params: Callable = field(default=lambda M, s, ctx: {}, repr=False)  # -> JointEffects overrides

    def to_dict(self) -> dict:
        return {"name": self.name, "channel": self.channel, "doc": self.doc, "sim_form": self.sim_form,
                "size_at_1": dict(self.size), "confounders": list(self.confounders),
                "separating_experiment": self.separating_experiment, "families": list(self.families)}


def _compliance(M, s, ctx):
    return {"k": 1.0 / (1.0 / ctx.k0 + M * math.radians(s["deflection_deg"]) / ctx.tau_max)}


def _presliding(M, s, ctx):
    if M <= 0:
        return {}
    sigma0 = ctx.c / (M * s["z_ss"])
    return {"sigma0": sigma0, "sigma1": 2.0 * s["zeta"] * math.sqrt(sigma0 * ctx.inertia)}


def _asymmetry(M, s, ctx):
    return {"c_pos": ctx.c * (1.0 + 0.5 * M * s["a"]), "c_neg": ctx.c * (1.0 - 0.5 * M * s["a"]),
            "va": M * s["a"]}


_SPECS = (
    EffectSpec("none", "none", "no effect: the nominal plant",
               "joint at its declared stiffness (rigid-equivalent if none), Coulomb + viscous", {}),
    EffectSpec(
        "stribeck", "torque",
        "friction above the Coulomb level at low speed, dropping with speed (static > kinetic)",
        "thesis eq. 2-6: f = sign(qd) (c + S exp(-|qd|/Vc)) + v qd", {"static_ratio": 0.45, "Vc": 0.05},
        ("presliding", "nonlinear_viscous"),
        "constant-velocity sweeps at several low speeds (Stribeck curve) against reversals at several "
        "accelerations (presliding)",
        ("stribeck_exponential", "stribeck_rational"),
        lambda M, s, ctx: {"S": M * s["static_ratio"] * ctx.c, "Vc": s["Vc"]}),
    EffectSpec(
        "presliding", "torque",
        "friction building up over a small displacement after each reversal (bristles, elasto-plastic "
        "contact): hysteresis in displacement, not in velocity",
        "LuGre bristles (Indri & Trapani eq. 5-9, DM1): dz/dt = qd - sigma0 |qd| z / c, "
        "f = sigma0 z + sigma1 dz/dt + v qd", {"z_ss": 2e-3, "zeta": 1.0},
        ("stribeck", "backlash"),
        "reversals at several accelerations with small amplitude (presliding hysteresis) and a "
        "marker-based link angle (backlash)",
        ("presliding_bristle", "presliding_maxwell"), _presliding),
    EffectSpec(
        "position_ripple", "torque",
        "torque periodic in the joint angle: an additive ripple (cogging, harmonic-drive orders and "
        "their aliases) or a modulation of the friction level along the angle",
        "tau_r = A sin(n q + phi) on the link", {"ratio": 0.10, "harmonic": 36, "phase": 0.7},
        ("thermal_drift",), "constant-velocity sweeps over the full joint range in both directions",
        ("ripple_additive", "ripple_modulation"),
        lambda M, s, ctx: {"ripple_A": M * s["ratio"] * ctx.c, "ripple_n": int(s["harmonic"]),
                           "ripple_phi": float(s["phase"])}),
    EffectSpec(
        "load_dependent", "torque",
        "Coulomb level growing with the torque the transmission carries (gravity, inertial, payload)",
        "c_eff = c + mu |tau_g(q)|, tau_g the gravity + payload torque", {"mu": 0.08},
        ("torque_scale", "asymmetry"), "the same trajectory at two or more payloads with both gravity signs",
        ("load_transmitted",),
        lambda M, s, ctx: {"mu": M * s["mu"]}),
    EffectSpec(
        "thermal_drift", "torque",
        "friction changing as the joint warms up: driven by time, by motion or by dissipated power",
        "c, v -> (1 + h exp(-(t - t0)/tau)) (c, v) on the campaign clock",
        {"cold_excess": 0.30, "tau_fraction": 1.0 / 3.0},
        ("load_dependent", "position_ripple"),
        "repeat one reference trajectory at the start and the end of the campaign, and after a rest",
        ("thermal",),
        lambda M, s, ctx: {"thermal_h": M * s["cold_excess"],
                           "thermal_tau": max(ctx.campaign_length_s * s["tau_fraction"], 1.0)}),
    EffectSpec(
        "compliance", "transmission",
        "transmission softer than declared: link-motor deflection proportional to (or hardening with) "
        "the transmitted torque",
        "joint stiffness 1/k = 1/k0 + M delta / tau_max, k0 the declared stiffness", {"deflection_deg": 0.4},
        ("backlash", "time_offset"), "quasi-static trials at several payloads (deflection vs torque)",
        ("compliance",), _compliance),
    EffectSpec(
        "backlash", "transmission",
        "lost motion between motor and link at torque reversals, independent of the load",
        "dead band of total width 2 beta in the transmission", {"band_deg": 0.2},
        ("compliance", "presliding"), "slow reversals under low load with markers on the link",
        ("backlash",),
        lambda M, s, ctx: {"beta": 0.5 * M * math.radians(s["band_deg"])}),
    EffectSpec(
        "torque_scale", "torque",
        "logged torque a constant (or direction-dependent) multiple of the applied torque: torque "
        "constant or gear efficiency error",
        "logged torque = (1 + s) u", {"scale_error": 0.15},
        ("load_dependent",), "trials at two or more payloads (a torque scale is invisible with one payload)",
        ("torque_gain",),
        lambda M, s, ctx: {"torque_gain": 1.0 + M * s["scale_error"]}),
    EffectSpec(
        "asymmetry", "torque", "Coulomb and/or viscous friction different in the two directions",
        "c+- = c (1 +- a/2), v+- = v (1 +- a/2)", {"a": 0.25},
        ("position_ripple",), "constant-velocity sweeps in both directions over the joint's full range (a "
        "Coulomb-only asymmetry is a constant offset while moving, which only a wide range tells from a "
        "ripple and the gravity terms)",
        ("asymmetry",), _asymmetry),
    EffectSpec(
        "nonlinear_viscous", "torque", "viscous friction not proportional to speed",
        "f += w qd |qd|", {"ratio": 0.3},
        ("stribeck",), "constant-velocity sweeps up to the maximum speed",
        ("nonlinear_viscous",),
        lambda M, s, ctx: {"w": M * s["ratio"] * ctx.v / ctx.vmax}),
    EffectSpec(
        "time_offset", "clock", "marker clock shifted (and possibly running at another rate) from the robot's",
        "marker clock = controller clock + dt_off", {"offset_s": 0.020},
        ("compliance",), "a fast sinusoid at low load: a clock shift grows with speed, a deflection with torque",
        ("time_offset", "torque_delay"),
        lambda M, s, ctx: {"time_offset": M * s["offset_s"]}),
)

#: name -> spec, in FORMAT.md's order
REGISTRY: dict[str, EffectSpec] = {s.name: s for s in _SPECS}
EFFECTS: tuple = tuple(REGISTRY)


def spec(name: str) -> EffectSpec:
    """The registry entry of one effect of FORMAT.md's vocabulary.

    Parameters
    ----------
    name : str
        Effect name, e.g. ``"stribeck"``.

    Returns
    -------
    EffectSpec
        Its meaning, channel, confounders, simulator form and candidate families.

    Raises
    ------
    ValueError
        For a name outside :data:`EFFECTS`.

    Examples
    --------
    >>> s = spec("backlash")
    >>> s.channel, "compliance" in s.confounders
    ('transmission', True)
    >>> spec("stribeck").channel
    'torque'
    """
    try:
        return REGISTRY[name]
    except KeyError:
        raise ValueError(f"unknown effect {name!r}; choose one of {', '.join(EFFECTS)}") from None
