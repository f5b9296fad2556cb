"""The simulator's model the gap is measured against (``jointlab diagnose --nominal SPEC``).

Every nominal has the same rigid part: the URDF's rigid-body torque with free corrections
(``JointData.urdf_regs``: armature, gravity scale and, for multi-joint records, a torque
offset) and a free gain on the controller's reaction to the encoder's high-frequency part (the
feedback column). What differs is the friction, by ``SPEC``:

* ``cv`` (default), ``cv_asym``: Coulomb + viscous (with a direction-dependent Coulomb level),
  amplitudes free;
* any other model of the friction registry (:data:`ident.friction.MODELS`: ``stribeck``,
  ``hyperbolic``, ``arctan``, ``dm1``, ``dm2``): the model's nonlinear shape parameters (Stribeck
  velocity, tanh rates, arctan delta, bristle stiffness, ...) fitted by the registry's estimator
  (:func:`ident.friction.fit.fit_friction`, jointly with the rigid columns) on the joint's
  samples, then held; the amplitudes it is linear in stay free in every fold.
  ``NAME:k=v,k=v`` holds the named shape parameters at the given values instead;
* a ``fits.json`` (``jointlab fit``, or a published model written in that layout), optionally
  ``FILE:MODEL`` to choose one of its models: the friction of each joint is FIXED to the file's
  parameters (subtracted from the torque, nothing of it refitted); only the rigid part and the
  feedback gain are fitted. The diagnosis then says what that model is missing.
* ``mjcf:PATH``, the MuJoCo model (``PATH`` a campaign folder: its ``[robot] mjcf``, else MuJoCo's
  compile of its URDF with the drives' motor values; or an MJCF file inside a campaign folder),
  read through :func:`ident.sim2real.model.build_model`: each joint's friction FIXED like a
  fits.json's to what MuJoCo simulates, ``damping qd + frictionloss sgn(qd) + armature qdd``
  (viscous, Coulomb, rotor inertia); the rigid part and the feedback gain are fitted as for every
  nominal (its free armature correction stays). The diagnosis then says what *this* simulator
  model is missing. Bare ``mjcf`` does not know the campaign: it is refused with the form to use.

A registry nominal's shape is chosen once on all of the joint's samples (the candidate
effects choose theirs per training fold): its held-out figures include that one choice of 1-3
parameters, which favours the nominal, i.e. is conservative for the effects tested against it.

The Coulomb direction: the data preparation chooses how the sign of the velocity enters (sampled
or through the derivative filter, ``JointData.sgn``); the discontinuous part of every friction
column (its jump at qd = 0) follows that choice, so a model with a sign term is measured on the
same footing as the default nominal.
"""
from __future__ import annotations

import json
from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path
from typing import Callable

import numpy as np

from mocap.io.campaign import load_campaign
from mocap.io.errors import InputError, read_text

from ident.friction import MODELS, laws
from ident.friction.fit import fit_arctan, fit_friction
from ident.friction.static import s0

RIGID_FREE = ("URDF rigid-body corrections (armature, gravity scale; torque offset on multi-joint "
              "records)", "feedback gain on the encoder's high-frequency part")


def _feedback_columns(d) -> list:
    """The logged torque is a feedback controller's command: it reacts to the encoder reading,
    including the part beyond the smoothed trajectory (quantisation steps, small vibration) that
    the smoothed derivatives do not carry. One column, that part of the reading, with a free gain
    (measured on the foreign world's effect-free campaigns: the nominal's held-out RMS over the
    torque noise drops from 1.26 to 1.16 on tri3). Absent on records without the raw reading."""
    if d.q_hf is None or d.q_hf.shape[0] != d.q.shape[0]:
        return []
    scale = float(np.sqrt(np.mean(d.q_hf ** 2)))   # unit scale: the solver's ridge is relative
    return [d.q_hf[:, None] / scale] if scale > 0 else []


@dataclass(frozen=True, eq=False)
class NominalModel:
    """The simulator's model the gap is measured against (see the module docstring).

    ``friction``: JointData -> (N, k) friction columns with free amplitudes; ``fixed``:
    JointData -> (N,) friction torque held as given (subtracted from the target), or None;
    ``details``: JointData -> dict of what was used for that joint (fitted shapes, fixed
    parameters), or None; ``summary``: the description written to diagnosis.json."""

    label: str
    doc: str
    friction: Callable
    fixed: Callable | None = None
    details: Callable | None = None
    summary: dict = field(default_factory=dict)
    check: Callable | None = None     # joints -> None, or an InputError for a joint not covered

    def columns(self, d) -> np.ndarray:
        return np.column_stack([d.urdf_regs, self.friction(d)] + _feedback_columns(d))

    def fixed_torque(self, d) -> np.ndarray:
        return np.zeros(d.y.shape[0]) if self.fixed is None else np.asarray(self.fixed(d), float)

    def target(self, d) -> np.ndarray:
        """The torque the nominal's free columns explain: ``y - tau_urdf - fixed friction``."""
        return d.y - d.tau_urdf - (0.0 if self.fixed is None else self.fixed_torque(d))

    def describe(self, d=None) -> dict:
        """diagnosis.json's ``nominal``: the summary, plus the joint's own parameters with ``d``."""
        out = dict(self.summary)
        if d is not None and self.details is not None:
            out.update(self.details(d))
        return out


def _no_friction(d) -> np.ndarray:
    return np.zeros((d.y.shape[0], 0))


# --------------------------------------------------------------------------------------------
# helpers shared by the registry and the file nominals
# --------------------------------------------------------------------------------------------
def _steps(d) -> np.ndarray:
    """Time steps between the joint's samples for the dynamic models' state (the samples the data
    preparation left out, slow ones around reversals and rests, are bridged by the model's
    discretisation); a step backwards in time (the next trial) or longer than 0.5 s is set to
    1 s, where the bristle state settles: a restart."""
    st = np.diff(np.asarray(d.t, float))
    return np.where((st > 0) & (st <= 0.5), st, 1.0)


def _jump_consistent(phi: np.ndarray, jump: np.ndarray, d) -> np.ndarray:
    """Columns whose jump at qd = 0 follows the data's Coulomb direction ``d.sgn``."""
    if not np.any(jump):
        return phi
    return phi + np.outer(np.asarray(d.sgn, float) - np.sign(d.qd), jump)


def _static_design(model, d) -> np.ndarray:
    phi, _ = model.linear_design(d.qd)
    eps = 1e-12
    pm, _ = model.linear_design(np.array([eps, -eps]))
    return _jump_consistent(np.asarray(phi, float), 0.5 * (pm[0] - pm[1]), d)


def _friction_torque(model, d) -> np.ndarray:
    """Torque of a fixed friction model on the joint's samples (jump consistent, see above)."""
    if getattr(model, "dynamic", False):
        return np.asarray(model.torque(d.qd, d.qdd, _steps(d)), float)
    eps = 1e-12
    tau = np.asarray(model.torque(d.qd), float)
    pm = model.torque(np.array([eps, -eps]))
    return tau + (np.asarray(d.sgn, float) - np.sign(d.qd)) * 0.5 * (pm[0] - pm[1])


def _jsonable_params(model) -> dict:
    return {k: float(v) for k, v in model.params.items()}


class _PerJoint:
    """A small cache of a per-JointData computation (the diagnosis asks for the same joint's
    columns and description several times)."""

    def __init__(self, fn, size: int = 8):
        self.fn, self.size, self.store = fn, size, []

    def __call__(self, d):
        for dd, val in self.store:
            if dd is d:
                return val
        val = self.fn(d)
        self.store.append((d, val))
        del self.store[:-self.size]
        return val


# --------------------------------------------------------------------------------------------
# registry models: shape fitted (or held), amplitudes free
# --------------------------------------------------------------------------------------------
def _registry_nominal(name: str, held: dict | None = None) -> NominalModel:
    cls = MODELS[name]
    held = dict(held or {})
    lin = tuple(getattr(cls, "linear_names", cls.param_names))
    nonlin = tuple(k for k in cls.param_names if k not in lin)
    dynamic = bool(getattr(cls, "dynamic", False))

    def fit(d):
        y = d.y - d.tau_urdf
        X = np.column_stack([d.urdf_regs] + _feedback_columns(d))
        names = tuple(f"rigid_{k + 1}" for k in range(X.shape[1]))
        kw = {"qdd": d.qdd, "dt": _steps(d)} if dynamic else {}
        settings = {}
        if dynamic:   # step 1 of Indri & Trapani: the static arctan curve on the same samples
            settings["static"] = fit_arctan(d.qd, y, X_extra=X, extra_names=names).model
        free = [k for k in nonlin if k not in held]
        if not free:      # every shape held: nothing nonlinear to fit
            if dynamic and hasattr(cls, "ratio_from_data"):
                settings["accel_ratio"] = cls.ratio_from_data(d.qd, d.qdd)
            model = cls(**{k: 0.0 for k in lin}, **held, **settings)
            return model, {"shape_fitted": {}}
        bounds = {k: (v - 1e-9 * max(abs(v), 1e-12), v + 1e-9 * max(abs(v), 1e-12))
                  for k, v in held.items()}
        f = fit_friction(cls, d.qd, y, X_extra=X, extra_names=names, n_starts=4, seed=0,
                         bounds=bounds or None, settings=settings, x0=dict(held) or None, **kw)
        shape = {k: float(f.model.params[k]) for k in free}
        info = {"shape_fitted": shape}
        if dynamic:
            info["static_arctan"] = _jsonable_params(settings["static"])
        if f.degenerate:
            info["shape_note"] = f.degenerate
        return f.model, info

    fitted = _PerJoint(fit)

    def friction(d):
        model, _ = fitted(d)
        if not dynamic:
            return _static_design(model, d)

        st = _steps(d)
        z = model.states(d.qd, st)
        Dm, _ = model._parts(z, d.qd, d.qdd, model._ratio(d.qd, d.qdd))
        v = np.asarray(d.qd, float)
        return np.column_stack([Dm, model.params["sigma0"] * z, v, v * v * s0(v, model.static.Kv)])

    def details(d):
        _, info = fitted(d)
        return {"joint_parameters": {**info, **({"held": held} if held else {})}}

    amps = lin + (("sigma0 z (bristle)", "tau_v", "tau_nlv") if dynamic else ())
    label = name + ("(" + ",".join(f"{k}={v:g}" for k, v in held.items()) + ")" if held else "")
    shape = ", ".join(nonlin) or "none"
    how = ("held at " + ", ".join(f"{k} = {v:g}" for k, v in held.items()) if held and set(held) == set(nonlin)
           else "fitted on the joint's samples, then held" + (
               " (" + ", ".join(f"{k} = {v:g}" for k, v in held.items()) + " held)" if held else ""))
    doc = f"`{name}` friction of the registry: shape ({shape}) {how}; amplitudes ({', '.join(amps)}) free"
    summary = {"spec": name if not held else f"{name}:" + ",".join(f"{k}={v:g}" for k, v in held.items()),
               "kind": "registry", "friction_model": name, "friction": doc,
               "free": list(amps) + list(RIGID_FREE), "shape_parameters": list(nonlin),
               "held": held, "text": doc}
    return NominalModel(label, doc, friction, None, details, summary)


def _builtin(label, doc, fn, amps) -> NominalModel:
    return NominalModel(label, doc, fn, None, None, {
        "spec": label, "kind": "builtin", "friction_model": label, "friction": doc,
        "free": list(amps) + list(RIGID_FREE), "text": f"{doc} friction, amplitudes free"})


NOMINAL_MODELS = {
    "cv": _builtin("coulomb_viscous", "Coulomb + viscous (thesis eq. 2-5)",
                   lambda d: laws.coulomb_viscous_columns(d.qd, sign=lambda _: d.sgn), ("c", "v")),
    "cv_asym": _builtin("coulomb_viscous_asymmetric",
                        "Coulomb + viscous with a direction-dependent Coulomb level",
                        lambda d: np.column_stack([laws.coulomb_viscous_columns(d.qd, sign=lambda _: d.sgn),
                                                   0.5 * (d.sabs + d.sgn)]), ("c", "v", "c_pos")),
}
NOMINAL_MODELS["cv"].summary["spec"] = "cv"
NOMINAL_MODELS["cv_asym"].summary["spec"] = "cv_asym"


def registry_names() -> tuple:
    """Every friction model name ``--nominal`` takes by name."""
    return tuple(dict.fromkeys(list(NOMINAL_MODELS) + list(MODELS)))


# --------------------------------------------------------------------------------------------
# fits.json: friction fixed per joint
# --------------------------------------------------------------------------------------------
def _num(x, path, key) -> float:
    if isinstance(x, bool) or not isinstance(x, (int, float)) or not np.isfinite(x):
        raise InputError(f"{key} must be a finite number, got {x!r}", path=path, label=key)
    return float(x)


class _Unphysical(InputError):
    """A fits.json entry with physically impossible values."""


def _model_from_entry(name: str, ent: dict, path, key: str):
    """A friction model instance from a fits.json entry ``{"params": ..., "settings": ...}``."""
    if name not in MODELS:
        raise InputError(f"unknown friction model {name!r} (known: {', '.join(MODELS)})", path=path,
                         label=key)
    cls = MODELS[name]
    if not isinstance(ent, dict) or not isinstance(ent.get("params"), dict):
        raise InputError("expected an object with a 'params' object", path=path, label=key)
    p = ent["params"]
    unknown = sorted(set(p) - set(cls.param_names))
    missing = [k for k in cls.param_names if k not in p]
    if unknown or missing:
        raise InputError(f"{name} takes parameters {', '.join(cls.param_names)}"
                         + (f"; unknown {unknown}" if unknown else "")
                         + (f"; missing {missing}" if missing else ""), path=path, label=f"{key}.params")
    vals = {k: _num(p[k], path, f"{key}.params.{k}") for k in cls.param_names}
    st = ent.get("settings") or {}
    if not isinstance(st, dict):
        raise InputError("settings must be an object", path=path, label=f"{key}.settings")
    kw = {}
    try:
        if name == "arctan":
            if "Kv" in st:
                kw["Kv"] = _num(st["Kv"], path, f"{key}.settings.Kv")
        elif getattr(cls, "dynamic", False):
            sd = st.get("static")
            if not isinstance(sd, dict):
                raise InputError(f"{name} needs its static arctan model under settings.static", path=path,
                                 label=f"{key}.settings.static")
            kw["static"] = _model_from_entry("arctan", sd, path, f"{key}.settings.static")
            for k in ("hold", "damping"):
                if st.get(k) is not None:
                    kw[k] = str(st[k])
            for k in ("rest_speed", "z0", "accel_ratio", "accel_floor"):
                if st.get(k) is not None:
                    kw[k] = _num(st[k], path, f"{key}.settings.{k}")
            if name == "dm1":
                kw.pop("accel_ratio", None), kw.pop("accel_floor", None)
            else:
                kw.pop("damping", None)
        model = cls(**vals, **kw)
    except (TypeError, ValueError) as exc:
        if isinstance(exc, InputError):
            raise
        raise InputError(f"{name}: {exc}", path=path, label=key) from None
    neg = [k for k, v in vals.items() if v < 0 and k in ("c", "v", "Fk", "Fv", "g4", "g6", "tau_s",
                                                          "tau_v", "sigma0", "sigma1", "gamma", "delta", "Vc")]
    bad = list(model.violations()) if hasattr(model, "violations") else []
    if neg or bad:
        what = bad[0] if bad else f"{neg[0]} = {vals[neg[0]]:.3g} < 0"
        raise _Unphysical(f"physically impossible {name} friction: {what}", path=path,
                          label=f"{key}.params")
    return model


def _entries(doc: dict, path) -> dict:
    """joint (str) -> model -> [(key, entry)] from a fits.json document: the joint-level
    ``joints.<j>.models`` (Indri & Trapani) and every ``trials.<trial>.<j>.<model>``."""
    if not isinstance(doc, dict):
        raise InputError("a fits.json holds one JSON object", path=path)
    if doc.get("format", 1) != 1:
        raise InputError(f"unsupported format {doc.get('format')!r} (this workbench reads format 1)",
                         path=path, label="format")
    out: dict = {}
    joints = doc.get("joints", {})
    trials = doc.get("trials", {})
    if not isinstance(joints, dict) or not isinstance(trials, dict):
        raise InputError("'trials' and 'joints' must be objects", path=path, label="trials")
    for j, jd in joints.items():
        models = jd.get("models") if isinstance(jd, dict) else None
        if not isinstance(models, dict):
            raise InputError("expected an object with a 'models' object", path=path, label=f"joints.{j}")
        for m, ent in models.items():
            out.setdefault(str(j), {}).setdefault(m, []).append((f"joints.{j}.models.{m}", ent))
    for tid, td in trials.items():
        if not isinstance(td, dict):
            raise InputError("expected an object of joints", path=path, label=f"trials.{tid}")
        for j, jd in td.items():
            if not isinstance(jd, dict):
                raise InputError("expected an object of models", path=path, label=f"trials.{tid}.{j}")
            for m, ent in jd.items():
                out.setdefault(str(j), {}).setdefault(m, []).append((f"trials.{tid}.{j}.{m}", ent))
    if not out:
        raise InputError("no friction entries (neither trials.<trial>.<joint>.<model> nor "
                         "joints.<joint>.models.<model>)", path=path, label="trials")
    return out


def _usable(ent) -> bool:
    """Entries the fitter itself flagged (physically invalid, implausible) are left out when the
    joint has others."""
    return not (isinstance(ent, dict) and (ent.get("valid") is False or ent.get("implausible")))


class FitsNominal:
    """The friction of every joint fixed to a fits.json's values (see the module docstring)."""

    def __init__(self, path: Path, model: str | None = None):
        self.path = Path(path)
        text = read_text(self.path)
        try:
            doc = json.loads(text)
        except json.JSONDecodeError as exc:
            raise InputError(f"not JSON: {exc.msg}, column {exc.colno}", path=self.path,
                             line=exc.lineno) from None
        self.entries = _entries(doc, self.path)
        names = sorted({m for by in self.entries.values() for m in by})
        if model is None:
            if len(names) > 1:
                raise InputError(f"holds several friction models ({', '.join(names)}); choose one with "
                                 f"--nominal {self.path}:MODEL", path=self.path, label="trials")
            model = names[0]
        self.model_name = model
        self.models, self.sources, self.left_out = {}, {}, {}
        for j, by in self.entries.items():
            ents = by.get(model)
            if not ents:
                continue
            good = [(k, e) for k, e in ents if _usable(e)] or ents
            inst, unphysical = [], []
            for k, e in good:     # several entries (per-trial fits): impossible ones are left out
                try:
                    inst.append((k, _model_from_entry(model, e, self.path, k)))
                except _Unphysical as exc:
                    if len(good) == 1:
                        raise
                    unphysical.append((k, exc))
            if not inst:
                raise unphysical[0][1]
            self.left_out[j] = [k for k, _ in unphysical] + [k for k, e in ents if (k, e) not in good]
            if len(inst) == 1:
                self.models[j] = inst[0][1]
            else:   # several trials: the median of each parameter (settings of the first)
                cls = type(inst[0][1])
                med = {p: float(np.median([m.params[p] for _, m in inst])) for p in cls.param_names}
                settings = getattr(inst[0][1], "settings", {}) or {}
                self.models[j] = cls(**med, **settings)
                key = f"{inst[0][0]} (and {len(inst) - 1} more)"
                bad = self.models[j].violations() if hasattr(self.models[j], "violations") else ()
                if bad:
                    raise InputError(f"the median of the {model} entries is physically impossible: "
                                     f"{bad[0]}", path=self.path, label=key)
            self.sources[j] = [k for k, _ in inst]
        if not self.models:
            raise InputError(f"no {model!r} entry for any joint (models in the file: {', '.join(names)})",
                             path=self.path, label="trials")

    def check_joints(self, joints) -> None:
        """Every diagnosed joint needs an entry: a one-line error naming the file and the joint."""
        for j in sorted(set(int(x) for x in joints)):
            if str(j) not in self.models:
                have = ", ".join(sorted(self.models, key=int))
                raise InputError(f"no {self.model_name!r} entry for joint {j} (the file has joints {have})",
                                 path=self.path, label=f"trials.*.{j}.{self.model_name}")

    def model_for(self, d):
        m = self.models.get(str(d.joint))
        if m is None:
            self.check_joints([d.joint])
        return m

    def nominal(self, spec: str) -> NominalModel:
        name = self.model_name

        def fixed(d):
            return _friction_torque(self.model_for(d), d)

        def details(d):
            m = self.model_for(d)
            out = {"fixed_parameters": _jsonable_params(m), "from": self.sources[str(d.joint)]}
            if len(out["from"]) > 1:
                out["aggregate"] = f"median of each parameter over the {len(out['from'])} entries"
            if self.left_out.get(str(d.joint)):
                out["left_out"] = self.left_out[str(d.joint)]
                out["left_out_why"] = ("physically impossible values, or flagged invalid or "
                                       "implausible by the fit that wrote them")
            st = m.to_dict().get("settings")
            if st:
                out["fixed_settings"] = json.loads(json.dumps(st, default=lambda o: o.to_dict()))
            return {"joint_parameters": out}

        doc = (f"`{name}` friction fixed per joint to the values of `{self.path}` (nothing of it "
               "refitted); only the rigid-body corrections and the feedback gain are fitted")
        summary = {"spec": spec, "kind": "file", "file": str(self.path), "friction_model": name,
                   "friction": doc, "free": list(RIGID_FREE), "fixed": [f"{name} friction parameters"],
                   "not_used": "offsets and armatures the file may hold (they belong to its own rigid-body "
                               "model; the nominal fits its own corrections)",
                   "text": doc}
        return NominalModel(f"{name} fixed from {self.path.name}", doc, _no_friction, fixed, details,
                            summary, self.check_joints)


# --------------------------------------------------------------------------------------------
def _parse_held(name: str, text: str, spec: str) -> dict:
    cls = MODELS[name]
    lin = tuple(getattr(cls, "linear_names", cls.param_names))
    nonlin = [k for k in cls.param_names if k not in lin]
    held = {}
    for part in text.split(","):
        k, sep, v = part.partition("=")
        k = k.strip()
        if not sep or k not in cls.param_names:
            raise InputError(f"--nominal {spec}: expected {name}:NAME=VALUE,... with NAME among its shape "
                             f"parameters ({', '.join(nonlin) or 'none'})", label=k or spec)
        if k not in nonlin:
            raise InputError(f"--nominal {spec}: {k} is an amplitude of {name} (free in every fold); only "
                             f"shape parameters ({', '.join(nonlin)}) can be held", label=k)
        try:
            val = float(v)
        except ValueError:
            raise InputError(f"--nominal {spec}: {k} must be a number, got {v!r}", label=k) from None
        if not np.isfinite(val):
            raise InputError(f"--nominal {spec}: {k} must be finite", label=k)
        held[k] = val
    return held


def nominal_model(spec: str = "cv") -> NominalModel:
    """The :class:`NominalModel` of a ``--nominal`` SPEC (see the module docstring); a bad SPEC
    or file is an :class:`InputError` naming the file and key. The same SPEC gives the same
    instance (a file's while it is unchanged), so per-joint fits are shared within a run."""
    spec = str(spec)
    if spec == MJCF_SPEC or spec.startswith(MJCF_SPEC + ":"):
        return mjcf_nominal(spec)
    if spec in NOMINAL_MODELS:
        return NOMINAL_MODELS[spec]
    name, sep, rest = spec.partition(":")
    if spec in MODELS or (sep and name in MODELS and not Path(spec).is_file()):
        return _named(spec)
    path, model = _file_spec(spec)
    st = path.stat()
    return _from_file(spec, str(path), model, st.st_mtime_ns, st.st_size)


@lru_cache(maxsize=16)
def _named(spec: str) -> NominalModel:
    name, sep, rest = spec.partition(":")
    if not sep:
        return _registry_nominal(name)
    if name == "cv":
        raise InputError(f"--nominal {spec}: cv has no shape parameter to hold", label=spec)
    return _registry_nominal(name, _parse_held(name, rest, spec))


@lru_cache(maxsize=8)
def _from_file(spec, path, model, mtime_ns, size) -> NominalModel:
    return FitsNominal(Path(path), model).nominal(spec)


def _file_spec(spec: str):
    """(path, model or None) of a file SPEC ``FILE`` or ``FILE:MODEL``."""
    path, model = Path(spec), None
    if not path.is_file():
        head, sep, tail = spec.rpartition(":")
        if sep and Path(head).is_file():
            path, model = Path(head), tail or None
        elif not spec.endswith(".json") and "/" not in spec and not sep:
            raise InputError(f"--nominal {spec!r} is neither a friction model ({', '.join(registry_names())}) "
                             "nor a fits.json file", label=spec)
    if not path.is_file():
        raise InputError("fits.json not found (--nominal)", path=path)
    return path, model


def check_nominal(spec: str, joints) -> NominalModel:
    """Resolve ``spec`` and check that a file nominal covers every joint in ``joints``."""
    nm = nominal_model(spec)
    if nm.check is not None:
        nm.check(joints)
    return nm


def check_held_nominal(spec: str) -> None:
    """Held shape parameters of ``--nominal NAME:k=v,...`` are positive scales (a Stribeck
    velocity, tanh slopes, a bristle stiffness, an arctan sharpness)."""
    name, sep, rest = str(spec).partition(":")
    if not sep or name not in MODELS or Path(spec).is_file():
        return
    for part in rest.split(","):
        k, _, v = part.partition("=")
        try:
            val = float(v)
        except ValueError:
            continue                      # the nominal's own parser names it
        if not val > 0:
            raise InputError(f"--nominal {spec}: {k.strip()} is a shape parameter of {name} and must be "
                             f"> 0, got {v.strip()}", label=k.strip())


# --------------------------------------------------------------------------------------------
# the MuJoCo model: friction fixed to the MJCF's joint parameters
# --------------------------------------------------------------------------------------------
MJCF_SPEC = "mjcf"


def _mjcf_target(spec: str) -> tuple:
    """(campaign root, MJCF file or None) of ``mjcf:PATH``: a campaign folder (or its
    ``campaign.toml``): its own model; an MJCF file: that file, with the campaign folder that
    holds it (the nearest parent with a ``campaign.toml``), whose URDF names the joints."""
    _, sep, rest = spec.partition(":")
    if not sep or not rest:
        raise InputError(f"--nominal {spec}: the MuJoCo model needs its campaign: --nominal "
                         "mjcf:CAMPAIGN (its [robot] mjcf, else MuJoCo's compile of its URDF) or "
                         "mjcf:FILE.xml (an MJCF inside the campaign folder)", label=spec)
    path = Path(rest)
    if path.is_dir() and (path / "campaign.toml").is_file():
        return path, None
    if path.is_file() and path.name == "campaign.toml":
        return path.parent, None
    if not path.is_file():
        raise InputError("MJCF or campaign folder not found (--nominal mjcf:PATH)", path=path)
    for parent in path.resolve().parents:
        if (parent / "campaign.toml").is_file():
            return parent, path
    raise InputError("the MJCF is not inside a campaign folder (no campaign.toml above it), so its "
                     "joints cannot be matched to the arm's (--nominal mjcf:PATH)", path=path)


def mjcf_nominal(spec: str) -> NominalModel:
    """The nominal of ``--nominal mjcf:PATH`` (see the module docstring; cached while the files
    are unchanged)."""
    root, mjcf = _mjcf_target(spec)
    stamp = tuple((str(p), p.stat().st_mtime_ns, p.stat().st_size)
                  for p in (root / "campaign.toml", mjcf) if p is not None)
    return _mjcf_cached(spec, str(root), None if mjcf is None else str(mjcf), stamp)


@lru_cache(maxsize=8)
def _mjcf_cached(spec, root, mjcf, stamp) -> NominalModel:

    try:
        import mujoco  # noqa: F401
    except ImportError:
        raise InputError(f"--nominal {spec} needs MuJoCo: pip install 'jointlab[mujoco]'",
                         label=spec) from None
    from ident.sim2real.model import NATIVE, build_model

    campaign = load_campaign(Path(root))
    robot = campaign.load_robot()
    sm = build_model(campaign, robot, None if mjcf is None else Path(mjcf))
    values = {k: np.asarray(sm.given[k], float) for k in NATIVE}
    n = len(sm.names)
    where = str(sm.path)

    def check(joints):
        for j in sorted(set(int(x) for x in joints)):
            if not 1 <= j <= n:
                raise InputError(f"joint {j} is not in the MuJoCo model's arm (joints 1..{n})",
                                 path=sm.path, label=str(j))

    def params(d) -> dict:
        check([d.joint])
        return {k: float(values[k][d.joint - 1]) for k in NATIVE}

    def fixed(d):
        p = params(d)
        sgn = np.asarray(d.sgn, float)       # the data's Coulomb direction (jump consistent)
        return (p["damping"] * np.asarray(d.qd, float) + p["frictionloss"] * sgn
                + p["armature"] * np.asarray(d.qdd, float))

    def details(d):
        return {"joint_parameters": {"fixed_parameters": {"viscous (damping)": params(d)["damping"],
                                                          "coulomb (frictionloss)": params(d)["frictionloss"],
                                                          "armature": params(d)["armature"]},
                                     "from": f"{where}: joint {sm.names[d.joint - 1]!r}"}}

    what = "the MJCF" if sm.source == "mjcf" else "MuJoCo's compile of the URDF (drives' motor values)"
    doc = (f"MuJoCo's joint friction fixed per joint to {what} `{where}`: damping qd + frictionloss "
           "sgn(qd) + armature qdd (nothing of it refitted); only the rigid-body corrections and the "
           "feedback gain are fitted")
    summary = {"spec": spec, "kind": "mjcf", "file": where, "source": sm.source,
               "friction_model": "coulomb_viscous", "friction": doc, "free": list(RIGID_FREE),
               "fixed": ["damping (viscous)", "frictionloss (Coulomb)", "armature"],
               "note": "the rigid part's free armature correction can still move the armature",
               "text": doc}
    return NominalModel(f"MuJoCo model {Path(where).name}", doc, _no_friction, fixed, details,
                        summary, check)
