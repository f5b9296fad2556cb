"""One plausibility layer over every identified friction and drive parameter.

Each parameter of a fit gets at most one flag:

* ``impossible``: the value breaks the physics of its law (a negative Coulomb level, viscous
  coefficient, armature or bristle stiffness; a Stribeck Coulomb level at speed ``Fk - Fs``
  below zero; a friction that pushes the motion somewhere inside the sampled speeds);
* ``unidentifiable``: the data do not determine it (its term vanishes or merges with another
  one on the sampled speeds, its standard error exceeds its size, or its term is more than
  :data:`CANCEL_RATIO` times the torque scale and so cancels another term). A parameter that
  must not be negative but whose negative estimate lies within :data:`SIGN_SE` standard
  errors of zero is this kind too, not ``impossible``: the data do not determine its sign
  (the estimate is consistent with zero or a small positive value);
* ``extrapolated``: it describes speeds outside the range the data cover (a Stribeck speed
  ``Vc`` above the fastest sampled speed, a hyperbolic Coulomb term or an arctan Stribeck
  transition that completes only beyond it).

:func:`assess` returns ``{param: Flag}`` for one fitted model; :func:`assess_armature` one
flag for an actuator inertia; :func:`fmt` prints a value with its flag (an unidentifiable
parameter prints as ``not identifiable``, never as a number); :func:`to_json` is the per-parameter
``flags`` entry of ``fits.json``. :data:`MEANING` names what each parameter of each law is
(the console and the reports print it beside the tables).

Sampled speed range: ``lo``/``hi`` are the 2nd and 98th percentiles of ``|qd|`` over the moving
samples the fit used.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ident.friction import laws
from ident.friction.constants import KV_DEFAULT

KINDS = ("impossible", "unidentifiable", "extrapolated")
CANCEL_RATIO = 100.0     # a term this many times the torque scale cancels another one
#: a negative estimate of a parameter that must not be negative is impossible only beyond this
#: many standard errors below zero (about a two-sided 95 % interval); within it, undetermined
SIGN_SE = 2.0

#: per law, the parameters whose only physical bound is their sign (>= 0): their ``impossible``
#: flag from that bound becomes ``unidentifiable`` within :data:`SIGN_SE` standard errors of 0
SIGN_BOUNDED = {"cv": ("c", "v"), "stribeck": ("Fk", "Fv"),
                "hyperbolic": ("g2", "g3", "g4", "g5", "g6"), "arctan": ("tau_s", "tau_v", "delta"),
                "dm1": ("sigma0", "sigma1"), "dm2": ("sigma0", "beta", "gamma")}

#: what each parameter is (printed beside the tables)
MEANING = {
    "cv": {"c": "Coulomb level (N m)", "v": "viscous coefficient (N m s/rad)"},
    "stribeck": {"Fk": "static (breakaway) level as qd -> 0 (N m)", "Fv": "viscous (N m s/rad)",
                 "Fs": "drop from the static level to the Coulomb level at speed (that level "
                       "is Fk - Fs; N m)",
                 "Vc": "Stribeck speed (rad/s)"},
    "hyperbolic": {"g1": "Stribeck hump height (N m)", "g2": "hump rise rate (s/rad)",
                   "g3": "hump decay rate (s/rad)", "g4": "smooth Coulomb level (N m)",
                   "g5": "Coulomb smoothing rate (s/rad)", "g6": "viscous (N m s/rad)"},
    "arctan": {"tau_s": "static level (N m)", "tau_sc": "Coulomb minus static level (N m)",
               "tau_v": "viscous (N m s/rad)", "tau_nlv": "nonlinear viscous (N m s^2/rad^2)",
               "delta": "Stribeck shape (s/rad)"},
    "dm1": {"sigma0": "bristle stiffness (N m/rad)", "sigma1": "bristle damping (N m s/rad)"},
    "dm2": {"sigma0": "bristle stiffness (N m/rad)", "alpha": "damping, constant part",
            "beta": "damping, acceleration part", "gamma": "damping, acceleration scale"},
}


#: parameters the thesis's degenerate forms of a one-link fit leave undetermined
#: (:func:`ident.model.onelink.name_degenerate`; the same list as the thesis tables use)
_FORM_UNDETERMINED = {"hyperbolic_stribeck_nonunique": ("g1", "g2", "g3"),
                      "stribeck_as_cv": ("Vc",), "stribeck_Vc_at_bound": ("Vc",)}


@dataclass(frozen=True)
class Flag:
    """One parameter's flag: ``kind`` one of :data:`KINDS`, ``reason`` one sentence."""

    kind: str
    reason: str

    def to_dict(self) -> dict:
        return {"flag": self.kind, "reason": self.reason}


def _speeds(qd):
    a = np.abs(np.asarray(qd, float).ravel()) if qd is not None else np.zeros(0)
    a = a[np.isfinite(a) & (a > 0)]
    if a.size == 0:
        return None, None
    lo, hi = np.percentile(a, [2.0, 98.0])
    return float(lo), float(hi)


def _put(out: dict, names, kind: str, reason: str) -> None:
    """Flag ``names``; a flag already set is kept when it is at least as severe."""
    for nm in (names if isinstance(names, (list, tuple)) else [names]):
        old = out.get(nm)
        if old is None or KINDS.index(kind) < KINDS.index(old.kind):
            out[nm] = Flag(kind, reason)


def _stribeck(p, lo, hi, scale, out):
    Fk, Fv, Fs, Vc = p["Fk"], p["Fv"], p["Fs"], p["Vc"]
    if Fk < 0:
        _put(out, "Fk", "impossible", f"static level Fk = {Fk:.3g} N m < 0")
    if Fv < 0:
        _put(out, "Fv", "impossible", f"viscous Fv = {Fv:.3g} < 0")
    if Fk - Fs < 0:
        _put(out, "Fs", "impossible", f"Coulomb level at speed Fk - Fs = {Fk - Fs:.3g} N m < 0")
    if Fs < 0 and Fk > 0:
        _put(out, "Fs", "impossible", f"Fs = {Fs:.3g} < 0: a rise of friction with speed, not a "
             "Stribeck drop")
    if not Vc > 0:
        _put(out, "Vc", "impossible", f"Stribeck speed Vc = {Vc:.3g} rad/s is not positive")
    if hi is None:
        return
    if scale and abs(Fs) < 0.02 * scale:
        _put(out, "Vc", "unidentifiable", f"the drop Fs = {Fs:.3g} is ~0: Vc shapes nothing")
    if Vc < lo / 5.0:
        _put(out, ["Fk", "Fs"], "unidentifiable",
             f"Vc = {Vc:.3g} rad/s is below the slowest sampled speeds ({lo:.3g} rad/s): only "
             f"Fk - Fs = {Fk - Fs:.3g} is determined")
        _put(out, "Vc", "unidentifiable", f"Vc = {Vc:.3g} rad/s is below the sampled speeds")
    elif Vc > 3.0 * hi:
        _put(out, ["Fs", "Fv", "Vc"], "unidentifiable",
             f"Vc = {Vc:.3g} rad/s is far beyond the sampled speeds (up to {hi:.3g} rad/s): the "
             "drop is linear in qd there and merges with Fv")
    elif Vc > hi:
        _put(out, "Vc", "extrapolated",
             f"Vc = {Vc:.3g} rad/s is beyond the sampled speeds (up to {hi:.3g} rad/s)")


def _hyperbolic(p, lo, hi, scale, tau_scale, out):
    if p["g4"] < 0:
        _put(out, "g4", "impossible", f"Coulomb level g4 = {p['g4']:.3g} < 0")
    if p["g6"] < 0:
        _put(out, "g6", "impossible", f"viscous g6 = {p['g6']:.3g} < 0")
    for g in ("g2", "g3", "g5"):
        if p[g] < 0:
            _put(out, g, "impossible", f"rate {g} = {p[g]:.3g} < 0")
    if hi is None:
        return
    v = np.geomspace(max(lo, 1e-6), hi, 200)
    hump = p["g1"] * laws.hyperbolic_columns(v, p["g2"], p["g3"], p["g5"])[:, 0]
    if abs(p["g2"] - p["g3"]) <= 0.05 * max(abs(p["g2"]), abs(p["g3"]), 1e-12) or \
            (scale and np.max(np.abs(hump)) < 0.02 * scale):
        _put(out, ["g1", "g2", "g3"], "unidentifiable",
             "the Stribeck hump g1 (tanh(g2 qd) - tanh(g3 qd)) is ~0 on the sampled speeds "
             "(g2 ~ g3 or g1 ~ 0)")
    if max(p["g2"], p["g3"]) * hi < 0.2:
        _put(out, ["g1", "g2", "g3"], "unidentifiable",
             "g2, g3 so small that the hump is linear in qd on the sampled speeds (merges with g6)")
    if 0 < p["g5"] * hi < 0.2:
        _put(out, ["g4", "g5"], "unidentifiable",
             f"g5 = {p['g5']:.3g}: tanh(g5 qd) is linear on the sampled speeds (up to {hi:.3g} "
             "rad/s), the Coulomb term merges with g6")
    elif 0 < p["g5"] * hi < 2.0:
        _put(out, "g5", "extrapolated",
             f"g5 = {p['g5']:.3g}: the Coulomb term saturates only beyond the sampled speeds "
             f"(up to {hi:.3g} rad/s)")
    if p["g5"] * lo > 5.0:
        _put(out, "g5", "unidentifiable",
             f"g5 = {p['g5']:.3g}: tanh(g5 qd) is a sign function at every sampled speed")
    if tau_scale:
        for g, term in (("g1", abs(p["g1"])), ("g4", abs(p["g4"])), ("g6", abs(p["g6"]) * hi)):
            if term > CANCEL_RATIO * tau_scale:
                _put(out, g, "unidentifiable",
                     f"{g} = {p[g]:.3g} makes a term {term / tau_scale:.3g} times the measured "
                     "torque scale: it cancels another term")


def _arctan(p, lo, hi, scale, out, Kv=1000.0):
    if p["tau_s"] < 0:
        _put(out, "tau_s", "impossible", f"static level tau_s = {p['tau_s']:.3g} < 0")
    if p["tau_s"] + p["tau_sc"] < 0:
        _put(out, "tau_sc", "impossible",
             f"Coulomb level tau_s + tau_sc = {p['tau_s'] + p['tau_sc']:.3g} < 0")
    if p["tau_v"] < 0:
        _put(out, "tau_v", "impossible", f"viscous tau_v = {p['tau_v']:.3g} < 0")
    if p["delta"] < 0:
        _put(out, "delta", "impossible", f"delta = {p['delta']:.3g} < 0")
    if hi is None:
        return
    term = np.max(np.abs(p["tau_sc"] * laws.arctan_columns(np.array([lo, hi]), p["delta"], Kv)[:, 1]))
    if scale and term < 0.02 * scale:
        _put(out, "delta", "unidentifiable",
             "the Stribeck term tau_sc 2/pi arctan(delta v) is ~0 on the sampled speeds")
    if p["delta"] * lo > 30.0:
        _put(out, ["tau_s", "tau_sc"], "unidentifiable",
             f"delta = {p['delta']:.3g}: arctan(delta v) is a sign function at every sampled "
             "speed, only tau_s + tau_sc is determined")
        _put(out, "delta", "unidentifiable", "arctan(delta v) saturated on the sampled speeds")
    if 0 < p["delta"] * hi < 1.0 and "delta" not in out:
        _put(out, "delta", "extrapolated",
             f"delta = {p['delta']:.3g} s/rad: the Stribeck transition (|v| ~ 1/delta = "
             f"{1 / p['delta']:.3g} rad/s) lies beyond the sampled speeds (up to {hi:.3g} rad/s)")
    v = np.geomspace(max(lo, 1e-6), hi, 200)
    visc = laws.arctan_viscous(v, p["tau_v"], p["tau_nlv"], Kv)
    if np.min(visc + p["tau_s"] + p["tau_sc"]) < 0 and p["tau_nlv"] < 0:
        _put(out, "tau_nlv", "impossible",
             "the nonlinear viscous term makes the friction push the motion at the sampled speeds")


def _energy(model, lo, hi, out, names):
    """Static friction that feeds energy (``f(v) v < 0``) inside the sampled speeds."""
    if model is None or hi is None or model.dynamic:
        return
    v = np.concatenate([-np.geomspace(hi, max(lo, 1e-4 * hi), 200),
                        np.geomspace(max(lo, 1e-4 * hi), hi, 200)])
    try:
        pw = model.torque(v) * v
    except Exception:  # noqa: BLE001 - a model that cannot evaluate is not assessed here
        return
    if np.any(pw < 0) and not any(out.get(n) and out[n].kind == "impossible" for n in names):
        k = int(np.argmin(pw))
        _put(out, names[0], "impossible",
             f"the friction pushes the motion at qd = {v[k]:.3g} rad/s")


def assess(model_name: str, params: dict, *, qd=None, stderr: dict | None = None,
           fit_scale: float | None = None, model=None, form: str | None = None,
           tau_scale: float | None = None) -> dict:
    """``{param: Flag}`` for the fitted ``params`` of law ``model_name`` (see the module
    docstring). ``qd``: the speeds the fit used; ``stderr``: standard errors (None or
    non-finite: not known); ``fit_scale``: the torque scale (N m) term sizes are compared with
    (default: the friction's largest absolute torque on ``qd``); ``model``: the fitted
    :class:`ident.friction.base.FrictionModel` (for the energy check of static laws);
    ``form``: the thesis's degenerate form of a one-link fit
    (:func:`ident.model.onelink.name_degenerate`): in ``stribeck_coulomb_in_Fs`` ``Fk = 0`` is a
    convention and ``-Fs`` the Coulomb level, so only ``Fk`` and ``Vc`` are undetermined;
    ``tau_scale``: the measured torque's scale (N m, e.g. its largest absolute value): a term
    :data:`CANCEL_RATIO` times larger cancels another one (default ``fit_scale``)."""
    p = {k: float(v) for k, v in params.items() if v is not None}
    out: dict = {}
    for k, v in p.items():
        if not np.isfinite(v):
            _put(out, k, "unidentifiable", f"{k} is not a finite number")
    if out:
        return out
    lo, hi = _speeds(qd)
    if fit_scale is None and model is not None and hi is not None \
            and not model.dynamic:
        try:
            fit_scale = float(np.max(np.abs(model.torque(np.array([lo, hi, -lo, -hi])))))
        except Exception:  # noqa: BLE001
            fit_scale = None
    tau_scale = tau_scale if tau_scale else fit_scale
    m = model_name
    if m == "cv":
        if p.get("c", 0.0) < 0:
            _put(out, "c", "impossible", f"Coulomb level c = {p['c']:.3g} N m < 0")
        if p.get("v", 0.0) < 0:
            _put(out, "v", "impossible", f"viscous coefficient v = {p['v']:.3g} < 0")
    elif m == "stribeck" and form == "stribeck_coulomb_in_Fs":
        _put(out, ["Fk", "Vc"], "unidentifiable",
             "Vc below the sampled speeds: the Stribeck term is a second Coulomb term, Fk = 0 by "
             "convention and -Fs carries the Coulomb level")
        if -p["Fs"] < 0:
            _put(out, "Fs", "impossible", f"Coulomb level -Fs = {-p['Fs']:.3g} N m < 0")
        if p["Fv"] < 0:
            _put(out, "Fv", "impossible", f"viscous Fv = {p['Fv']:.3g} < 0")
    elif m == "stribeck" and {"Fk", "Fv", "Fs", "Vc"} <= set(p):
        _stribeck(p, lo, hi, fit_scale, out)
    elif m == "hyperbolic" and {"g1", "g2", "g3", "g4", "g5", "g6"} <= set(p):
        _hyperbolic(p, lo, hi, fit_scale, tau_scale, out)
    elif m == "arctan" and {"tau_s", "tau_sc", "tau_v", "tau_nlv", "delta"} <= set(p):
        _arctan(p, lo, hi, fit_scale, out, KV_DEFAULT if model is None else model.Kv)
    elif m in ("dm1", "dm2"):
        if p.get("sigma0", 1.0) <= 0:
            _put(out, "sigma0", "impossible", f"bristle stiffness sigma0 = {p['sigma0']:.3g} <= 0")
        if m == "dm1" and p.get("sigma1", 0.0) < 0:
            _put(out, "sigma1", "impossible", f"bristle damping sigma1 = {p['sigma1']:.3g} < 0")
        if m == "dm2" and p.get("beta", 0.0) < 0:   # eq. 24: alpha / sqrt(...) + beta -> beta
            _put(out, "beta", "impossible", f"beta = {p['beta']:.3g} < 0: negative bristle "
                 "damping at high acceleration (eq. 24)")
        if m == "dm2" and p.get("gamma", 0.0) < 0:
            _put(out, "gamma", "impossible", f"gamma = {p['gamma']:.3g} < 0")
    for k in _FORM_UNDETERMINED.get(form, ()):
        if k in p:
            _put(out, k, "unidentifiable", f"degenerate form {form}: the fit does not determine it")
    names = {"cv": ("v", "c"), "stribeck": ("Fv", "Fk"), "hyperbolic": ("g6", "g4"),
             "arctan": ("tau_v", "tau_s")}.get(m)
    if names:
        _energy(model, lo, hi, out, names)
    # after the energy check, which a sign flag suppresses: a friction that pushes the motion only
    # through a parameter whose sign the data leave open is not shown to push it either
    bounded = () if form == "stribeck_coulomb_in_Fs" else SIGN_BOUNDED.get(m, ())
    for k in bounded:
        if k in out and out[k].kind == "impossible" and p.get(k, 0.0) < 0:
            flag = _sign_undetermined(k, p[k], (stderr or {}).get(k))
            if flag is not None:
                out[k] = flag
    for k, se in (stderr or {}).items():
        if k in p and se is not None and np.isfinite(se) and se > abs(p[k]) and k not in out:
            _put(out, k, "unidentifiable",
                 f"standard error {se:.3g} exceeds |{k}| = {abs(p[k]):.3g}")
    return out


def _sign_undetermined(name: str, value: float, stderr) -> Flag | None:
    """The ``unidentifiable`` flag of a negative estimate of a parameter that must not be
    negative when it lies within :data:`SIGN_SE` standard errors of zero (None otherwise: no
    standard error, or the estimate is significantly negative and so impossible)."""
    if stderr is None or not np.isfinite(stderr) or stderr <= 0 or -value >= SIGN_SE * stderr:
        return None
    return Flag("unidentifiable", f"{name} = {value:.3g} < 0 lies within {SIGN_SE:g} standard errors "
                f"({stderr:.3g}) of zero: these data do not determine its sign")


def assess_armature(value, stderr=None) -> Flag | None:
    """An actuator (armature) inertia: negative is impossible (undetermined within
    :data:`SIGN_SE` standard errors of zero); a standard error above its size leaves it
    undetermined; None (merged into the base parameters) is not flagged."""
    if value is None:
        return None
    if not np.isfinite(value):
        return Flag("unidentifiable", "armature is not a finite number")
    if value < 0:
        return (_sign_undetermined("armature", value, stderr)
                or Flag("impossible", f"armature {value:.3g} kg m^2 < 0"))
    if stderr is not None and np.isfinite(stderr) and stderr > abs(value):
        return Flag("unidentifiable", f"standard error {stderr:.3g} exceeds the armature")
    return None


def fmt(value, flag: Flag | None = None, nd: int = 4) -> str:
    """A parameter for a table or the console: ``not identifiable`` for an unidentifiable one,
    else the number with ``[impossible]`` / ``[outside data]`` appended where flagged."""
    if flag is not None and flag.kind == "unidentifiable":
        return "not identifiable"
    if value is None:
        return "-"
    s = f"{float(value):.{nd}g}"
    if flag is None:
        return s
    return s + (" [impossible]" if flag.kind == "impossible" else " [outside data]")


def to_json(flags: dict) -> dict:
    """``{param: {"flag", "reason"}}`` for ``fits.json``."""
    return {k: f.to_dict() for k, f in flags.items()}


def meaning_line(model_name: str) -> str:
    """One line naming each parameter of a law (``Fk`` static level, ``Fs`` drop, ...)."""
    d = MEANING.get(model_name)
    if not d:
        return ""
    return f"{model_name}: " + "; ".join(f"{k} = {v}" for k, v in d.items())
