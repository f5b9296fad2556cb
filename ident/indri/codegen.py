"""C export of identified friction models for a controller (Indri & Trapani sec. V-A, Figure 10).

:func:`export_c` writes a dependency-free C99 header and source (double precision, only
``<math.h>``, ``<stddef.h>`` and ``<string.h>``) holding:

* ``jl_friction_params``: every parameter of a model (static arctan part eq. 1-2 / 8-9, the
  Coulomb + viscous model, the LuGre-type dynamic part eq. 5-6 with the damping of eq. 10, 11,
  12, a constant, or eq. 24) plus the sample time ``Ts``;
* one ``const jl_friction_params`` instance per exported model, named ``JL_<NAME>``, and
  ``jl_friction_find(name)``;
* ``jl_friction`` (parameters + the bristle state ``z``), ``jl_friction_init``,
  ``jl_friction_reset`` and ``jl_friction_step(f, v, a)`` returning the friction torque of the
  current sample: with ``hold = 1`` (first-order hold, the default of the Python models, see
  :mod:`ident.friction.dynamic`) it first advances ``z`` from the previous sample to this one
  (it keeps the previous velocity), with ``hold = 0`` it advances ``z`` after the torque by the
  exact discretisation eq. 29-30 with the velocity held over ``Ts``; ``jl_friction_run``
  applies it to arrays.

The step reproduces :meth:`ident.friction.LuGreDM1.torque` / ``LuGreDM2.torque`` (and the
static models' ``torque``) sample by sample: the state starts at ``z0`` or the steady state of
the first velocity, the torque at sample k uses ``z_k``, ``v_k``, ``a_k``. The only difference
is rounding (the Python side solves the recursion block-wise), far below 1e-9 N m.
"""
from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from ident.friction import Arctan, CoulombViscous, FrictionModel, LuGreDM1, LuGreDM2

_DAMPING = {"constant": "JL_DAMP_CONSTANT", "eq10": "JL_DAMP_EQ10", "eq11": "JL_DAMP_EQ11",
            "eq12": "JL_DAMP_EQ12"}
_FIELDS = ("tau_s", "tau_sc", "tau_v", "tau_nlv", "delta", "Kv", "c", "v", "sigma0", "sigma1",
           "alpha", "beta", "gamma", "accel_ratio", "accel_floor", "Ts", "z0", "rest_speed")

_HEADER = """\
/* {name}.h: friction models identified by jointlab (generated; do not edit).
 * Indri & Trapani 2020: static arctan model eq. 1-2, LuGre-type dynamic part eq. 5-9 with
 * bristle damping eq. 10/11/12/constant/eq. 24, exact discretisation eq. 29-30.
 * Link side, SI units (N m, rad/s, rad/s^2). Plain C99, double precision.
 */
#ifndef {guard}
#define {guard}

#include <stddef.h>

#ifdef __cplusplus
extern "C" {{
#endif

enum {{ JL_KIND_CV = 0, JL_KIND_ARCTAN = 1, JL_KIND_LUGRE = 2 }};
enum {{ JL_DAMP_NONE = 0, JL_DAMP_CONSTANT = 1, JL_DAMP_EQ10 = 2, JL_DAMP_EQ11 = 3,
       JL_DAMP_EQ12 = 4, JL_DAMP_EQ24 = 5 }};

typedef struct {{
    const char *name;
    int kind;            /* JL_KIND_* */
    int damping;         /* JL_DAMP_* (LuGre only) */
    /* static arctan part (eq. 1-2, 8-9) */
    double tau_s, tau_sc, tau_v, tau_nlv, delta, Kv;
    /* Coulomb + viscous (thesis eq. 2-5) */
    double c, v;
    /* dynamic part (eq. 5-6, 10-12, 24) */
    double sigma0, sigma1, alpha, beta, gamma, accel_ratio, accel_floor;
    double Ts;           /* sample time, s (eq. 29) */
    int has_z0;          /* 0: z starts at the steady state of the first velocity */
    double z0;
    int hold;            /* 0: velocity held over Ts (eq. 29-30); 1: first-order hold */
    double rest_speed;   /* standstill relaxation speed, rad/s (0: eq. 30 as printed) */
}} jl_friction_params;

typedef struct {{
    jl_friction_params p;
    double z;            /* bristle deflection, rad */
    double a_prev;       /* sigma0 S1/g and steady deflection of the previous sample (hold 1) */
    double zss_prev;
    int started;
}} jl_friction;

/* Copy the parameters and reset the state. */
void jl_friction_init(jl_friction *f, const jl_friction_params *p);
/* Forget the state: the next step starts from z0 or the steady state of its velocity. */
void jl_friction_reset(jl_friction *f);
/* Friction torque at the current sample (velocity v, acceleration a), then advance z by Ts. */
double jl_friction_step(jl_friction *f, double v, double a);
/* jl_friction_step over n samples. */
void jl_friction_run(jl_friction *f, size_t n, const double *v, const double *a, double *tau);
/* sizeof(jl_friction), for foreign-function callers. */
size_t jl_friction_size(void);
/* The exported parameter set called name, or NULL. */
const jl_friction_params *jl_friction_find(const char *name);

{externs}

#ifdef __cplusplus
}}
#endif

#endif /* {guard} */
"""

_SOURCE = """\
/* {name}.c: friction models identified by jointlab (generated; do not edit). See {name}.h. */
#include "{name}.h"

#include <math.h>
#include <string.h>

#define JL_2_PI {two_pi}

static double jl_s0(double v, double Kv) {{ return JL_2_PI * atan(Kv * v); }}   /* eq. 2 */

static double jl_g(const jl_friction_params *p, double v)                     /* eq. 8 */
{{
    double s1 = jl_s0(v, p->Kv) * v;                                          /* eq. 7 */
    return p->tau_s + p->tau_sc * (JL_2_PI * atan(s1 * p->delta));
}}

static double jl_viscous(const jl_friction_params *p, double v)               /* eq. 9 */
{{
    return p->tau_v * v + p->tau_nlv * v * v * jl_s0(v, p->Kv);
}}

static double jl_phi(double x)                       /* (1 - exp(-x)) / x, 1 at x = 0 */
{{
    if (fabs(x) < 1e-12) return 1.0 - 0.5 * x;
    return -expm1(-x) / x;
}}

void jl_friction_reset(jl_friction *f)
{{
    f->z = f->p.has_z0 ? f->p.z0 : 0.0;
    f->started = 0;
}}

void jl_friction_init(jl_friction *f, const jl_friction_params *p)
{{
    f->p = *p;
    jl_friction_reset(f);
}}

size_t jl_friction_size(void) {{ return sizeof(jl_friction); }}

double jl_friction_step(jl_friction *f, double v, double a)
{{
    const jl_friction_params *p = &f->p;
    double S0, S1, g, ak, bk, zss, zdot, damp, tau, x;
    if (p->kind == JL_KIND_CV)
        return p->c * (double)((v > 0.0) - (v < 0.0)) + p->v * v;
    S0 = jl_s0(v, p->Kv);
    if (p->kind == JL_KIND_ARCTAN)                                          /* eq. 1 */
        return p->tau_s * S0 + p->tau_sc * (JL_2_PI * atan(v * p->delta)) + p->tau_v * v
               + p->tau_nlv * v * v * S0;
    S1 = S0 * v;
    g = jl_g(p, v);
    ak = p->sigma0 * (S1 + p->rest_speed) / g;                              /* eq. 30 */
    bk = S0 * S0 * v;
    zss = S0 * g / p->sigma0;
    if (p->rest_speed > 0.0) zss *= S1 / (S1 + p->rest_speed);
    if (!f->started) {{
        if (!p->has_z0) f->z = zss;                     /* steady state of the first sample */
        f->started = 1;
    }} else if (p->hold == 1) {{                      /* first-order hold from the last sample */
        x = 0.5 * p->Ts * (f->a_prev + ak);
        f->z = exp(-x) * f->z - expm1(-x) * f->zss_prev + (zss - f->zss_prev) * (1.0 - jl_phi(x));
    }}
    f->a_prev = ak;
    f->zss_prev = zss;
    zdot = bk - ak * f->z;                                                  /* eq. 5 */
    switch (p->damping) {{
    case JL_DAMP_CONSTANT: damp = p->sigma1 * zdot; break;
    case JL_DAMP_EQ10: damp = p->sigma1 * (g * S0 - p->sigma0 * f->z); break;   /* g/|v| zdot */
    case JL_DAMP_EQ11: damp = p->sigma1 * (S0 - p->sigma0 * f->z / g); break;   /* 1/|v| zdot */
    case JL_DAMP_EQ12:
        damp = p->sigma1 * ((1.0 - JL_2_PI * atan(S1 * p->delta)) * zdot); break;
    case JL_DAMP_EQ24: {{
        double r = p->accel_ratio * v;
        double den = sqrt(p->gamma * (r * r) + a * a + p->accel_floor * p->accel_floor);
        damp = p->alpha * (zdot / den) + p->beta * zdot;
        break;
    }}
    default: damp = 0.0;
    }}
    tau = damp + (p->sigma0 * f->z + jl_viscous(p, v));                    /* eq. 6 */
    if (p->hold == 0) {{
        x = ak * p->Ts;                                                     /* eq. 29 */
        f->z = exp(-x) * f->z + p->Ts * jl_phi(x) * bk;
    }}
    return tau;
}}

void jl_friction_run(jl_friction *f, size_t n, const double *v, const double *a, double *tau)
{{
    size_t k;
    for (k = 0; k < n; ++k) tau[k] = jl_friction_step(f, v[k], a ? a[k] : 0.0);
}}

{instances}

static const jl_friction_params *const jl_all[] = {{ {all_list} }};

const jl_friction_params *jl_friction_find(const char *name)
{{
    size_t k;
    for (k = 0; k < sizeof(jl_all) / sizeof(jl_all[0]); ++k)
        if (jl_all[k] && strcmp(jl_all[k]->name, name) == 0) return jl_all[k];
    return NULL;
}}
"""


def _lit(x) -> str:
    x = float(x)
    if not np.isfinite(x):
        raise ValueError(f"cannot export a non-finite parameter ({x})")
    s = repr(x)
    return s if ("." in s or "e" in s or "n" in s) else s + ".0"


def c_identifier(name: str) -> str:
    """A C identifier from a model label (non-alphanumerics -> '_', no leading digit)."""
    s = re.sub(r"[^0-9A-Za-z_]", "_", str(name), flags=re.ASCII)
    if not s or s[0].isdigit():
        s = "m_" + s
    return s


def model_params(model: FrictionModel, dt: float | None) -> dict:
    """The ``jl_friction_params`` field values of a model (kind and damping as C names)."""
    p = {k: 0.0 for k in _FIELDS}
    p.update(Kv=1000.0, Ts=0.0, has_z0=0, hold=0, kind="JL_KIND_CV", damping="JL_DAMP_NONE")
    if isinstance(model, CoulombViscous):
        p.update(c=model.c, v=model.v)
        return p
    if isinstance(model, Arctan):
        p.update(kind="JL_KIND_ARCTAN", **model.params, Kv=model.Kv)
        return p
    if isinstance(model, (LuGreDM1, LuGreDM2)):
        if dt is None or not dt > 0:
            raise ValueError(f"{model.name}: a dynamic model needs the controller's sample time dt")
        st = model.static
        p.update(kind="JL_KIND_LUGRE", **st.params, Kv=st.Kv, Ts=float(dt),
                 sigma0=model.sigma0, hold={"zero": 0, "first": 1}[model.hold],
                 rest_speed=model.rest_speed)
        if isinstance(model, LuGreDM1):
            p.update(damping=_DAMPING[model.damping], sigma1=model.sigma1)
        else:
            if model.accel_ratio is None:
                raise ValueError("dm2: export needs a fixed accel_ratio (a_max/v_max of eq. 24)")
            p.update(damping="JL_DAMP_EQ24", alpha=model.alpha, beta=model.beta,
                     gamma=model.gamma, accel_ratio=model.accel_ratio,
                     accel_floor=model.accel_floor)
        if model.z0 is not None:
            p.update(has_z0=1, z0=model.z0)
        return p
    raise ValueError(f"cannot export model {type(model).__name__} ({model.name!r}) to C: "
                     "supported are cv, arctan, dm1, dm2")


def c_string(text: str) -> str:
    """The body of a C string literal holding ``text`` (UTF-8): printable ASCII as is, but
    backslash, double quote and '?' (trigraphs) escaped; every other byte (newlines, controls,
    non-ASCII) as a three-digit octal escape, so no label can end the literal or the line."""
    out = []
    for b in str(text).encode("utf-8", "backslashreplace"):
        ch = chr(b)
        if ch in '\\"?':
            out.append("\\" + ch)
        elif 0x20 <= b < 0x7f:
            out.append(ch)
        else:
            out.append(f"\\{b:03o}")
    return "".join(out)


def c_comment(text: str, limit: int = 120) -> str:
    """``text`` safe inside a C block comment on one line: printable ASCII only (others become
    '?'), no comment delimiters and no trailing backslash, at most ``limit`` characters."""
    s = re.sub(r"[^ -~]", "?", str(text))[:limit]
    s = s.replace("*/", "*_/").replace("/*", "/_*")
    return s.rstrip("\\")


def _instance(cname: str, label: str, p: dict) -> str:
    vals = ",\n".join(f"    .{k} = {_lit(p[k])}" for k in _FIELDS)
    lab = c_string(label)
    return (f"const jl_friction_params JL_{cname.upper()} = {{\n"
            f"    .name = \"{lab}\",\n    .kind = {p['kind']},\n    .damping = {p['damping']},\n"
            f"{vals},\n    .has_z0 = {int(p['has_z0'])},\n    .hold = {int(p['hold'])}\n}};")


def export_c(models: dict, out_dir, *, dt: float | None = None,
             basename: str = "jl_friction") -> tuple[Path, Path]:
    """Write ``<basename>.h`` and ``<basename>.c`` into ``out_dir`` for ``models`` (label ->
    :class:`FrictionModel` or :class:`ident.friction.FrictionFit`); ``dt`` is the controller's
    sample time (required for dynamic models). Returns (header, source)."""
    if not models:
        raise ValueError("export_c: no models to export")
    base = c_identifier(basename)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    seen, inst, externs, names = {}, [], [], []
    for label, m in models.items():
        m = getattr(m, "model", m)
        if not isinstance(m, FrictionModel):
            raise ValueError(f"export_c: {label!r} is not a friction model or fit")
        cname = re.sub(r"[^0-9A-Za-z_]", "_", str(label), flags=re.ASCII) or "model"   # after JL_
        if cname.upper() in seen:
            raise ValueError(f"export_c: labels {seen[cname.upper()]!r} and {label!r} give the same "
                             f"C name JL_{cname.upper()}")
        seen[cname.upper()] = label
        inst.append(_instance(cname, str(label), model_params(m, dt)))
        externs.append(f"extern const jl_friction_params JL_{cname.upper()};   /* {c_comment(label)} */")
        names.append(f"&JL_{cname.upper()}")
    h = out / f"{base}.h"
    c = out / f"{base}.c"
    h.write_text(_HEADER.format(name=base, guard=f"{base.upper()}_H", externs="\n".join(externs)))
    c.write_text(_SOURCE.format(name=base, two_pi=_lit(2.0 / np.pi), instances="\n\n".join(inst),
                                all_list=", ".join(names)))
    return h, c


def _as_model(f):
    """A FrictionModel from a model, a FrictionFit (``.model``) or a one-link fit
    (``.friction()``); None for anything else."""
    if isinstance(f, FrictionModel):
        return f
    m = getattr(f, "model", None)
    if isinstance(m, FrictionModel):
        return m
    fr = getattr(f, "friction", None)
    if callable(fr):
        m = fr()
        if isinstance(m, FrictionModel):
            return m
    return None


def _flatten(tree, prefix=()):
    if isinstance(tree, dict):
        for k, v in tree.items():
            yield from _flatten(v, prefix + (str(k),))
    else:
        yield "_".join(prefix), tree


def export_models_c(fits, out_dir, dt: float | None = None,
                    basename: str = "jl_friction") -> list[Path]:
    """The ``jointlab fit --export-c DIR`` hook: export every fitted model of ``fits`` (a
    mapping, possibly nested, e.g. ``{trial: {joint: {model_name: fit}}}`` with FrictionFit,
    one-link fits (``.friction()``) or models as leaves; labels are the keys joined by '_')
    that C can represent (cv, arctan, dm1, dm2; others are skipped) into
    ``out_dir``. ``dt``: the controller sample time for dynamic models (those are skipped with
    a ValueError if it is missing). Returns the written paths (header, source)."""
    flat = {}
    for label, f in _flatten(fits):
        m = _as_model(f)
        if isinstance(m, (CoulombViscous, Arctan, LuGreDM1, LuGreDM2)):
            flat[label or m.name] = m
    if not flat:
        raise ValueError("export_models_c: none of the fits is a cv, arctan, dm1 or dm2 model")
    return list(export_c(flat, out_dir, dt=dt, basename=basename))
