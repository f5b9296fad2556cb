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


# ---- input checks: an implausible fit names the input mistakes that would explain it (issue 45)
#: the input mistakes a failed check points to, in the order the warning names them
MISTAKES = {
    "sign": "the sign of tau_{j} (a flipped column or torque constant)",
    "scale": "the units or scale of tau_{j} (mN m, a gear ratio or torque constant applied twice or not at all)",
    "columns": "the column order of the log (tau_{j} holding another joint's torque)",
    "drives": "the order of the drives.toml tables (another joint's motor_inertia/motor_viscous subtracted)",
    "clock": "a clock offset between the torque and the angles (time_offset, a shifted column)",
    "urdf": "the URDF's link masses or the trial's load_kg/payload_com",
}
#: the fitted gravity torque may differ from the URDF's by this factor before its scale is
#: doubted (URDF masses are rarely 50 % off; a unit slip is x1000, a doubled ratio x2)
GRAVITY_FACTOR = 1.5
#: a torque/motion lag below this many seconds is a sensor lag, above it a clock offset
CLOCK_LAG_S = 0.02
#: a fit moves "beyond its standard errors" when dropping a block moves it by this many
#: standard errors of the difference
BLOCK_Z = 5.0
#: ... and by more than this fraction of its value (an unmodelled friction effect, e.g. a
#: Stribeck hump, moves a Coulomb + viscous fit by up to ~12 % when a block goes, measured on
#: foreign-world constant-velocity trials, far beyond its iid standard errors)
BLOCK_REL = 0.25


@dataclass(frozen=True)
class InputCheck:
    """One failed input check of a fit: ``check`` its name, ``value`` the measured figure,
    ``says`` one sentence, ``suspects`` the keys of :data:`MISTAKES` that would explain it."""

    check: str
    value: float
    says: str
    suspects: tuple

    def to_dict(self) -> dict:
        return {"check": self.check, "value": float(self.value), "says": self.says,
                "suspects": list(self.suspects)}


def _lsq(X, y):
    """Least squares ``y ~ X theta``: theta, standard errors (residual variance), RSS and the
    covariance."""
    theta, *_ = np.linalg.lstsq(X, y, rcond=None)
    r = y - X @ theta
    rss = float(r @ r)
    dof = max(y.size - X.shape[1], 1)
    try:
        cov = np.linalg.inv(X.T @ X) * rss / dof
        se = np.sqrt(np.maximum(np.diag(cov), 0.0))
    except np.linalg.LinAlgError:
        cov = np.full((X.shape[1], X.shape[1]), np.nan)
        se = np.full(X.shape[1], np.nan)
    return theta, se, rss, cov


#: lags x samples of one block of the vectorised lag scans (bounds their memory on long logs)
_SCAN_BLOCK = 1 << 20
#: most samples x columns^2 of the running sums of :func:`_lag_scan_rss` (8 bytes each: 160 MB);
#: longer logs are scanned one lag at a time, as before, so the memory of long logs stays flat
_SCAN_SUMS = 2e7


def _lag_rss(X, tau, mov, s: int) -> float:
    """The residual mean square of ``tau[k + s] ~ X[k] theta`` over the moving samples ``k``
    (``mov``) that have both rows: one lag of :func:`input_checks`' clock scan (np.inf below 40
    samples)."""
    n = tau.size
    k0, k1 = max(0, -s), min(n, n - s)
    m = mov[k0:k1]
    if m.sum() < 40:
        return np.inf
    return _lsq(X[k0:k1][m], tau[k0 + s:k1 + s][m])[2] / m.sum()


def _lag_scan_rss(X, tau, mov, lags) -> np.ndarray:
    """:func:`_lag_rss` at every lag of ``lags`` (np.inf below 40 samples), vectorised over
    lags (blocks of at most :data:`_SCAN_BLOCK` lags x samples): per lag ``s`` the normal
    equations over its rows ``w`` (moving ``k`` with ``k + s`` inside the log), ``A = X_w^T
    X_w`` from running sums of the rows' outer products, ``b = X_w^T tau_s`` and ``tau_s^T
    tau_s`` as correlations of the torque with the moving rows (columns scaled to unit norm),
    then ``RSS = tau_s^T tau_s - b^T theta``. A lag whose scaled normal matrix is
    near-singular is solved by :func:`_lag_rss` (least squares). The scan only ranks the lags:
    :func:`input_checks` reports the figures of :func:`_lag_rss`."""
    n, p = X.shape
    lags = np.asarray(lags, int)
    out = np.full(lags.size, np.inf)
    if not lags.size:
        return out
    if n * p * p > _SCAN_SUMS:   # a long log: the running sums would not stay small, one lag at a time
        return np.array([_lag_rss(X, tau, mov, int(s)) for s in lags])
    scale = np.sqrt(np.einsum("kc,kc->c", X, X))
    scale[scale == 0] = 1.0
    Xm = np.where(mov[:, None], X / scale, 0.0)                  # the moving rows, scaled
    Z = np.concatenate([np.zeros((1, p * p)), np.cumsum(
        (Xm[:, :, None] * Xm[:, None, :]).reshape(n, p * p), axis=0)])    # running sums of x x^T
    cm = np.concatenate([[0], np.cumsum(mov)])
    pad = int(np.max(np.abs(lags)))
    tp = np.concatenate([np.zeros(pad), tau, np.zeros(pad)])
    win = np.lib.stride_tricks.sliding_window_view(tp, n)        # win[pad + s][k] = tau[k + s]
    win2 = np.lib.stride_tricks.sliding_window_view(tp * tp, n)
    per = max(1, _SCAN_BLOCK // max(n, 1))
    for b0 in range(0, lags.size, per):  # loop over blocks of lags (memory bound)
        ls = lags[b0:b0 + per]
        k0, k1 = np.maximum(0, -ls), np.minimum(n, n - ls)       # rows with both samples
        cnt = cm[k1] - cm[k0]
        A = (Z[k1] - Z[k0]).reshape(ls.size, p, p)
        bvec = win[pad + ls] @ Xm                                # zero padding: rows outside add 0
        yy = win2[pad + ls] @ mov.astype(float)
        ok = cnt >= 40
        if ok.any():
            ok[ok] = np.linalg.cond(A[ok]) < 1e10
        if ok.any():
            theta = np.linalg.solve(A[ok], bvec[ok][..., None])[..., 0]
            rss = np.maximum(yy[ok] - np.einsum("lc,lc->l", theta, bvec[ok]), 0.0)
            out[b0 + np.flatnonzero(ok)] = rss / cnt[ok]
        for i in np.flatnonzero(~ok & (cnt >= 40)):  # loop over the near-singular lags (rare)
            out[b0 + i] = _lag_rss(X, tau, mov, int(ls[i]))
    return out


def _marker_rss(tm, ql, tl, qm, s: float) -> float:
    """One lag of :func:`marker_clock_check`: the residual mean square of the line fit
    ``q_link(t) = a + b q_motor(t + s)`` on the marker samples whose shifted time is inside the
    log (np.inf below 40 samples)."""
    m = (tm + s >= tl[0]) & (tm + s <= tl[-1])
    if m.sum() < 40:
        return np.inf
    X = np.column_stack([np.ones(m.sum()), np.interp(tm[m] + s, tl, qm)])
    r = ql[m] - X @ np.linalg.lstsq(X, ql[m], rcond=None)[0]
    return float(r @ r) / m.sum()


def _marker_lag_rss(tm, ql, tl, qm, lags) -> np.ndarray:
    """:func:`_marker_rss` at every lag of ``lags``, vectorised over lags (blocks of at most
    :data:`_SCAN_BLOCK` lags x samples): per lag the line fit from the sums over its samples,
    ``RSS = S_yy - S_xy^2 / S_xx`` (centred sums); a lag without spread in ``x`` by
    :func:`_marker_rss`. The scan only ranks the lags: :func:`marker_clock_check` reports the
    figures of :func:`_marker_rss`."""
    lags = np.asarray(lags, float)
    out = np.full(lags.size, np.inf)
    per = max(1, _SCAN_BLOCK // max(tm.size, 1))
    yc = ql - ql.mean()                       # centred once: the sums below stay small
    for b0 in range(0, lags.size, per):  # loop over blocks of lags (memory bound)
        ls = lags[b0:b0 + per]
        ts = tm[None, :] + ls[:, None]
        M = (ts >= tl[0]) & (ts <= tl[-1])
        Mf = M.astype(float)
        cnt = Mf.sum(axis=1)
        x = np.interp(ts, tl, qm) * Mf
        c = np.maximum(cnt, 1.0)
        sx, sy = x.sum(axis=1), Mf @ yc
        sxx = np.einsum("lk,lk->l", x, x) - sx * sx / c
        sxy = x @ yc - sx * sy / c
        syy = Mf @ (yc * yc) - sy * sy / c
        ok = (cnt >= 40) & (sxx > 1e-12 * np.maximum(np.einsum("lk,lk->l", x, x), 1e-300))
        rss = np.maximum(syy - sxy * sxy / np.where(ok, sxx, 1.0), 0.0)
        out[b0:b0 + ls.size] = np.where(ok, rss / c, np.inf)
        for i in np.flatnonzero(~ok & (cnt >= 40)):  # loop over lags without spread (rare)
            out[b0 + i] = _marker_rss(tm, ql, tl, qm, ls[i])
    return out


def _cv_columns(q, qd, qdd):
    """Eq. 2-4 with Coulomb + viscous friction, linear in ``(I, mglx, mgly, c, v)``:
    ``[qdd, -sin q, cos q, sign qd, qd]``."""
    return np.column_stack([qdd, -np.sin(q), np.cos(q), np.sign(qd), qd])


def input_checks(time, q, qd, qdd, tau, *, params: dict, rigid: dict, stderr: dict,
                 flags: dict | None = None, urdf_dyn=None, max_torque: float = float("inf"),
                 moving_frac: float = 0.05) -> list:
    """The physical-plausibility checks of one one-link fit (thesis eq. 2-4) against its
    inputs; each failed check names the input mistakes that would explain it (:data:`MISTAKES`).

    * ``impossible``: a Coulomb level or viscous coefficient flagged impossible by
      :func:`assess` (significantly negative);
    * ``negative_inertia``: the fitted inertia ``I`` more than 3 standard errors below 0;
    * ``coulomb_beyond_drive``: the Coulomb level above the drive's ``max_torque``;
    * ``gravity_ratio``: the gravity torque of the Coulomb + viscous regression of eq. 2-4
      (``[qdd, -sin q, cos q, sign qd, qd]`` on the moving samples) projected on the URDF's
      ``a sin q + b cos q`` (``urdf_dyn = (I, a, b)``,
      :meth:`mocap.robot.Robot.single_joint_dynamics`) over the sampled angles: a ratio below 0
      (3 standard errors) or beyond :data:`GRAVITY_FACTOR` either way (3 standard errors from
      1), where the ratio's standard error is below 0.25 x max(1, |ratio|) (the data see the
      URDF's gravity).
      Where the ratio agrees, sign, scale and column order are not suspected by the other
      checks;
    * ``clock_lag``: the lag of the torque against the motion (the Coulomb + viscous regression
      of eq. 2-4 refitted with the torque shifted by whole samples, +-0.6 s) whose residual is
      at least 20 % below the unshifted one, beyond :data:`CLOCK_LAG_S`;
    * ``block_stability``: dropping one of four consecutive blocks of the moving samples moves
      that regression's friction torque ``c + v s`` at the median moving speed ``s`` by more
      than :data:`BLOCK_Z` standard errors of the difference and :data:`BLOCK_REL` of its value.

    Parameters
    ----------
    time, q, qd, qdd, tau : array_like
        The fit's samples (s, rad, rad/s, rad/s^2, N m).
    params, rigid, stderr : dict
        The ``cv`` fit's friction parameters (``c``, ``v``), rigid parameters (``I``, ``mglx``,
        ``mgly``) and their standard errors.
    flags : dict, optional
        :func:`assess`'s flags of that fit.
    urdf_dyn : tuple, optional
        ``(I, a, b)`` of the URDF (with the trial's payload) at the trial's posture.
    max_torque : float
        The drive's torque limit (N m).

    Returns
    -------
    list of InputCheck
        The failed checks (empty: plausible).

    References
    ----------
    .. [1] PA10 thesis (seeds 002), eq. 2-4.
    """
    out = []
    flags = flags or {}
    t = np.asarray(time, float)
    q, qd, qdd, tau = (np.asarray(x, float) for x in (q, qd, qdd, tau))
    for k, name in (("c", "Coulomb level"), ("v", "viscous coefficient")):
        f = flags.get(k)
        if f is not None and getattr(f, "kind", None) == "impossible":
            out.append(InputCheck("impossible", params[k], f"{name} {k} = {params[k]:.3g} < 0",
                                  ("sign", "scale", "drives", "columns", "clock")))
    I, se_I = rigid.get("I"), stderr.get("I")
    if I is not None and se_I is not None and np.isfinite(se_I) and I < -3.0 * se_I:
        out.append(InputCheck("negative_inertia", I, f"fitted inertia I = {I:.3g} kg m^2 < 0",
                              ("drives", "sign", "scale")))
    c = params.get("c")
    if c is not None and np.isfinite(max_torque) and c > max_torque:
        out.append(InputCheck("coulomb_beyond_drive", c / max_torque,
                              f"Coulomb level {c:.3g} N m above the drive's max_torque {max_torque:g} N m",
                              ("scale", "columns")))
    peak = float(np.max(np.abs(qd))) if qd.size else 0.0
    mov = np.abs(qd) > moving_frac * peak
    if peak <= 0 or mov.sum() < 40 or t.size < 40:
        return out
    X = _cv_columns(q, qd, qdd)
    idx = np.flatnonzero(mov)
    th, se, _, cov = _lsq(X[idx], tau[idx])
    gravity_ok = False
    if urdf_dyn is not None:
        # the fitted gravity torque against the URDF's over the sampled angles: its projection
        # k = <G_fit, G_urdf> / <G_urdf, G_urdf>, linear in (mglx, mgly): its standard error
        # from the regression's covariance
        _, a, b = urdf_dyn
        Gu = a * np.sin(q[idx]) + b * np.cos(q[idx])
        uu = float(Gu @ Gu)
        if uu > 0:
            w = np.array([-np.sin(q[idx]) @ Gu, np.cos(q[idx]) @ Gu]) / uu
            k = float(w @ th[1:3])
            se_k = float(np.sqrt(max(w @ cov[1:3, 1:3] @ w, 0.0)))
            if np.isfinite(se_k) and se_k < 0.25 * max(1.0, abs(k)):   # the data see the gravity
                if k < 0 and -k > 3.0 * se_k:
                    out.append(InputCheck("gravity_ratio", k, f"fitted gravity torque {k:.2g} x the "
                                          "URDF's (opposite sign)", ("sign", "urdf")))
                elif (k > GRAVITY_FACTOR or k < 1.0 / GRAVITY_FACTOR) and abs(k - 1.0) > 3.0 * se_k:
                    out.append(InputCheck("gravity_ratio", k, f"fitted gravity torque {k:.3g} x the URDF's",
                                          ("scale", "urdf")))
                else:
                    gravity_ok = True
    if gravity_ok:      # the torque's sign and scale agree with the URDF: not those mistakes
        out = [InputCheck(c.check, c.value, c.says, tuple(x for x in c.suspects
                                                           if x not in ("sign", "scale", "columns"))
                          or c.suspects) for c in out]
    dt = float(np.median(np.diff(t)))
    # torque against motion: shift the torque by s samples (tau[k + s] against X[k])
    n = t.size
    smax = int(min(round(0.6 / dt), n // 4)) if dt > 0 else 0
    step = max(1, int(round(0.005 / dt))) if dt > 0 else 1
    lags = np.arange(-smax, smax + 1, step)
    scan = _lag_scan_rss(X, tau, mov, lags)       # every lag's regression at once
    best_s, best_rss, rss0 = 0, np.inf, np.nan
    if np.isfinite(scan).any():
        best_s = int(lags[int(np.argmin(scan))])  # the first of equal minima, as a loop would
        # the two figures the check reports, from the regression itself
        best_rss = _lag_rss(X, tau, mov, best_s)
        rss0 = _lag_rss(X, tau, mov, 0) if 0 in lags and np.isfinite(scan[lags == 0][0]) else np.nan
    lag = best_s * dt
    if np.isfinite(rss0) and abs(lag) > CLOCK_LAG_S and best_rss < 0.8 * rss0:
        out.append(InputCheck("clock_lag", lag, f"the torque fits the motion best {lag:+.3g} s later "
                              f"(residual {best_rss / rss0:.2g} of the unshifted one)", ("clock",)))
    # the regression with each quarter of the moving samples left out: the friction torque
    # c + v s at the median moving speed s (c and v alone trade off where the speeds cluster)
    s_med = float(np.median(np.abs(qd[idx])))
    g = np.array([0.0, 0.0, 0.0, 1.0, s_med])
    f_full, var_full = float(g @ th), float(g @ cov @ g)
    worst, what = 0.0, ""
    for blk in np.array_split(idx, 4):  # loop over 4 blocks
        keep = np.setdiff1d(idx, blk, assume_unique=True)
        th_d, _, _, cov_d = _lsq(X[keep], tau[keep])
        f_d = float(g @ th_d)
        sd = np.sqrt(max(float(g @ cov_d @ g) - var_full, 0.25 * var_full))
        z = abs(f_d - f_full) / sd if sd > 0 else 0.0
        if abs(f_d - f_full) <= BLOCK_REL * abs(f_full):
            continue            # an unmodelled effect moves it a little, beyond iid errors
        if z > worst:
            worst, what = z, (f"dropping the samples {t[blk[0]] - t[0]:.2f}-{t[blk[-1]] - t[0]:.2f} s of "
                              f"the trial moves the friction at {s_med:.2g} rad/s from {f_full:.3g} to "
                              f"{f_d:.3g} N m ({z:.0f} standard errors)")
    if worst > BLOCK_Z:
        out.append(InputCheck("block_stability", worst, what, ("clock", "columns")))
    return out


def marker_clock_check(t_marker, q_link, t_log, q_motor, max_lag: float = 0.6,
                       step: float = 0.005) -> list:
    """The marker clock against the robot's: the lag ``s`` at which the link angle from the
    markers best follows the encoder angle (``q_link(t) = a + b q_motor(t + s)``, least squares
    over shifts of ``step`` within ``+-max_lag`` s on the marker samples inside the log). The
    link follows the motor within the transmission's deflection (a small fraction of a
    degree), so a lag beyond :data:`CLOCK_LAG_S` whose residual is below 0.8 of the unshifted
    one is a clock offset (FORMAT.md ``time_offset``): one ``marker_clock`` :class:`InputCheck`,
    or none. Arguments: the marker samples' times on the robot clock (``time_offset``
    applied) and link angles, the log's times and motor angles (link side)."""
    tm, ql = np.asarray(t_marker, float), np.asarray(q_link, float)
    tl, qm = np.asarray(t_log, float), np.asarray(q_motor, float)
    ok = np.isfinite(tm) & np.isfinite(ql)
    tm, ql = tm[ok], ql[ok]
    okl = np.isfinite(qm)
    tl, qm = tl[okl], qm[okl]
    if tm.size < 40 or tl.size < 40 or np.ptp(qm) <= 0:
        return []
    lags = np.arange(-max_lag, max_lag + step / 2, step)
    rss = _marker_lag_rss(tm, ql, tl, qm, lags)   # every lag's line fit at once
    k0 = int(np.argmin(np.abs(lags)))
    kb = int(np.argmin(rss))
    # the two figures the check reports, from the line fit itself
    rss[[k0, kb]] = [_marker_rss(tm, ql, tl, qm, lags[k]) for k in (k0, kb)]
    lag = float(lags[kb])
    if np.isfinite(rss[k0]) and abs(lag) > CLOCK_LAG_S and rss[kb] < 0.8 * rss[k0]:
        return [InputCheck("marker_clock", lag, f"the link angle from the markers follows the encoder angle "
                           f"best {lag:+.3g} s later (residual {rss[kb] / rss[k0]:.2g} of the unshifted one)",
                           ("clock",))]
    return []


def input_warning(entries) -> str | None:
    """ONE warning over the failed input checks of a set of fits: which fits, what each
    check says, and the input mistakes that would explain them, most often suspected first.

    ``entries``: ``(label, joint, [InputCheck, ...])`` per fit; None when every check passed."""
    bad = [(lab, j, cs) for lab, j, cs in entries if cs]
    if not bad:
        return None
    count: dict = {}            # each failed check votes 1, shared among the mistakes it suspects
    joints = sorted({j for _, j, _ in bad})
    for _, _, cs in bad:
        for c in cs:
            for s in c.suspects:
                count[s] = count.get(s, 0.0) + 1.0 / len(c.suspects)
    order = sorted(count, key=lambda s: (-count[s], list(MISTAKES).index(s)))
    jj = "/".join(map(str, joints))
    shown = "; ".join(f"{lab}: " + ", ".join(c.says for c in cs) for lab, _, cs in bad[:3])
    more = f"; and {len(bad) - 3} more" if len(bad) > 3 else ""
    return (f"{len(bad)} fit(s) physically implausible ({shown}{more}); check "
            + ", ".join(MISTAKES[s].replace("{j}", jj) for s in order))
