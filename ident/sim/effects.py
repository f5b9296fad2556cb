"""The withheld effects: what the simulated "real" robot has and the nominal model lacks.

Every name of FORMAT.md's effect vocabulary can be switched on with a magnitude ``M``. At
``M = 1`` the effect has a literature-typical size (below) and is clearly visible above the
measurement noise in the channel it lives in (motor torque against the rigid Coulomb + viscous
model, or link angle from markers against motor angle); ``M = 0.3`` is still detectable; every
size parameter scales linearly with ``M`` (``M = 0`` is the nominal plant).

Physical forms (``c``, ``v``: nominal Coulomb and viscous coefficients of the joint, thesis
eq. 2-5; ``tau_max``: the drive's rated link-side torque; ``vmax``: its maximum speed):

==================  =============================================================  ==========================
name                form added to the plant                                        size at M = 1 (literature)
==================  =============================================================  ==========================
stribeck            thesis eq. 2-6: ``f = sign(qd) (c + S exp(-|qd|/Vc)) + v qd``  S = 0.45 c (30-60 %),
                                                                                   Vc = 0.05 rad/s (0.02-0.1)
presliding          LuGre bristles (Indri & Trapani eq. 5-9, DM1):                 z_ss = c/sigma0 = 2e-3 rad
                    ``dz/dt = qd - sigma0 |qd| z / c``,                            (hysteresis width), sigma1
                    ``f = sigma0 z + sigma1 dz/dt + v qd``                         critical for the link
position_ripple     ``tau_r = A sin(n q + phi)`` on the link (harmonic drive /     A = 0.10 c (5-15 %), n = 36
                    cogging), periodic in the joint angle                          per revolution
load_dependent      ``c_eff = c + mu |tau_g(q)|``, ``tau_g`` the gravity +         mu = 0.08 (0.05-0.1)
                    payload torque the joint transmits (its static load)
thermal_drift       ``c, v -> (1 + h exp(-(t - t0)/tau)) (c, v)`` on the campaign  h = 0.30 (20-40 % cold),
                    clock ``t`` (warm-up)                                          tau = campaign length / 3
compliance          joint stiffness ``1/k = 1/k0 + M delta / tau_max``, ``k0``     delta = 0.4 deg at rated
                    the declared stiffness (softer than declared)                  torque (0.3-0.5 deg)
backlash            dead band of total width ``2 beta`` in the transmission         2 beta = 0.2 deg (0.1-0.3)
torque_scale        logged torque ``= (1 + s) u`` (torque constant error)           s = 0.15 (10-20 %)
asymmetry           ``c+- = c (1 +- a/2)``, ``v+- = v (1 +- a/2)`` by direction     a = 0.25 (+-20-30 %)
nonlinear_viscous   ``f += w qd |qd|``                                             w vmax^2 = 0.3 v vmax
time_offset         marker clock = controller clock + dt_off                       dt_off = 20 ms (10-30 ms)
==================  =============================================================  ==========================

The nominal plant (``none``) is the flexible joint at the robot's DECLARED stiffness ``k0``
(drives.toml ``stiffness``, FORMAT.md: "the joint's nominal stiffness between motor and link, as
a simulator of the flexible joint would use it"), well damped, with thesis Coulomb + viscous
friction. A joint that declares no stiffness is rigid by FORMAT.md; the simulator then uses the
rigid-equivalent :func:`nominal_stiffness` (deflection at rated torque under half an encoder
count) and the campaign's drives.toml keeps it undeclared (absent = rigid, consistently).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

from ident.effects import EFFECTS as _EFFECTS
from ident.effects import K_NOMINAL, REGISTRY, SimContext

#: the vocabulary, the channel each effect lives in and its sizes at magnitude 1 (ident.effects)
EFFECTS = _EFFECTS
CHANNEL = {name: sp.channel for name, sp in REGISTRY.items()}
SIZE = {name: dict(sp.size) for name, sp in REGISTRY.items() if sp.size}

#: joint damping ``d = 2 ZETA_JOINT sqrt(k (I + J))``: harmonic drives are well damped, and a
#: lightly damped joint mode rings at every friction reversal (~1 kHz), which the PD feeds into
#: the torque: that ringing would itself be an unmodelled effect of the nominal plant
#: (measured: 0.04 N m RMS against rigid + CV at zeta 0.05, 0.005 N m here, noise 0.08 N m).
ZETA_JOINT = 1.0


def nominal_stiffness(drive) -> float:
    """The nominal transmission stiffness ``k0`` (N m/rad, link side) of a :class:`mocap.robot.Drive`:
    its declared ``stiffness``, else the rigid-equivalent ``max(K_NOMINAL, 2 tau_max / resolution)``
    (the deflection at rated torque stays under half an encoder count: rigid to measurement
    precision, as FORMAT.md reads an absent stiffness)."""
    k = drive.extra.get("stiffness") if getattr(drive, "extra", None) else None
    if k is not None:
        k = float(k)
        if not (math.isfinite(k) and k > 0):
            raise ValueError(f"drive {drive.name!r}: stiffness must be a positive number, got {k!r}")
        return k
    res = drive.encoder_resolution or math.radians(0.011)
    return max(K_NOMINAL, 2.0 * float(drive.max_torque) / float(res))


@dataclass(frozen=True)
class JointEffects:
    """Effect parameters of one joint, link side, SI. All zero = the nominal plant.

    Friction: ``c_pos``/``c_neg`` Coulomb levels, ``v`` viscous (``v (1 +- va/2)`` by direction), ``S``/``Vc`` Stribeck excess and
    velocity, ``w`` quadratic viscous, ``sigma0``/``sigma1`` LuGre (0 = off), ``ripple_A``/
    ``ripple_n``/``ripple_phi`` position ripple, ``mu`` load dependence, ``thermal_h``/
    ``thermal_tau`` warm-up. Transmission: ``k``, ``d``, ``beta`` (half backlash). Measurement:
    ``torque_gain`` (logged/true), ``time_offset`` (marker - controller clock).
    """

    c_pos: float
    c_neg: float
    v: float
    k: float
    d: float
    va: float = 0.0
    S: float = 0.0
    Vc: float = 0.05
    w: float = 0.0
    sigma0: float = 0.0
    sigma1: float = 0.0
    ripple_A: float = 0.0
    ripple_n: int = 0
    ripple_phi: float = 0.0
    mu: float = 0.0
    thermal_h: float = 0.0
    thermal_tau: float = 1.0
    beta: float = 0.0
    torque_gain: float = 1.0
    time_offset: float = 0.0

    def to_dict(self) -> dict:
        return {k: getattr(self, k) for k in self.__dataclass_fields__}


@dataclass(frozen=True)
class Effect:
    """An effect by name with its magnitude; ``joint_params`` builds the plant parameters."""

    name: str = "none"
    magnitude: float = 1.0
    settings: dict = field(default_factory=dict)

    def __post_init__(self):
        if self.name not in EFFECTS:
            raise ValueError(f"unknown effect {self.name!r}; choose one of {', '.join(EFFECTS)}")
        if not (math.isfinite(self.magnitude) and self.magnitude >= 0):
            raise ValueError(f"effect magnitude must be a finite number >= 0, got {self.magnitude!r}")

    @property
    def channel(self) -> str:
        return CHANNEL[self.name]

    def size(self) -> dict:
        """Sizes at M = 1, with any ``settings`` overrides."""
        s = dict(SIZE.get(self.name, {}))
        s.update(self.settings)
        return s

    def joint_params(self, c: float, v: float, tau_max: float, vmax: float, inertia: float,
                     campaign_length_s: float = 600.0, k0: float = K_NOMINAL) -> JointEffects:
        """Plant parameters of a joint with nominal ``c``, ``v`` and nominal (declared)
        stiffness ``k0`` (N m/rad, :func:`nominal_stiffness`) under this effect.

        ``inertia`` (link + motor, kg m^2) sets the joint damping and the LuGre damping.
        """
        if not (math.isfinite(k0) and k0 > 0):
            raise ValueError(f"nominal stiffness k0 must be a positive number, got {k0!r}")
        M = float(self.magnitude) if self.name != "none" else 0.0
        ctx = SimContext(c=c, v=v, tau_max=tau_max, vmax=vmax, inertia=inertia,
                         campaign_length_s=campaign_length_s, k0=float(k0))
        p = dict(c_pos=c, c_neg=c, v=v, k=float(k0), beta=0.0)
        p.update(REGISTRY[self.name].sim_params(M, self.size(), ctx))
        p["d"] = 2.0 * ZETA_JOINT * math.sqrt(p["k"] * inertia)
        return JointEffects(**p)

    def to_dict(self) -> dict:
        return {"name": self.name, "magnitude": float(self.magnitude), "channel": self.channel,
                "size_at_1": self.size()}


def truth_models(je: JointEffects) -> dict:
    """The true friction in FORMAT.md model names where it is one of them (link side, SI).

    ``stribeck`` follows thesis eq. 2-6 (``Fk`` static level, ``Fs`` the drop to Coulomb);
    ``dm1`` carries the LuGre bristle parameters.
    """
    c = 0.5 * (je.c_pos + je.c_neg)
    out = {"cv": {"c": c, "v": je.v}}
    if je.S > 0:
        out["stribeck"] = {"Fk": c + je.S, "Fv": je.v, "Fs": je.S, "Vc": je.Vc}
    if je.sigma0 > 0:
        out["dm1"] = {"sigma0": je.sigma0, "sigma1": je.sigma1}
    return out
