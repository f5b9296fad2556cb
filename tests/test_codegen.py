"""C export (Indri & Trapani sec. V-A): the generated C99 reproduces the Python models (eq. 1-2,
5-12, 24, 29-30) sample by sample on a recorded profile within 1e-9 N m."""
from __future__ import annotations

import ctypes
import shutil
import subprocess

import numpy as np
import pytest

from ident.excitation.profiles import test_profile_knots
from ident.sim.friction import simulate_friction
from ident.indri.codegen import c_identifier, export_c, export_models_c
from ident.friction import (Arctan, CoulombViscous, LuGreDM1, LuGreDM2, Stribeck, fit_arctan)

STATIC = Arctan(tau_s=5.0, tau_sc=-1.5, tau_v=2.0, tau_nlv=0.3, delta=15.0)
DT = 1e-3
MODELS = {
    "dm2": LuGreDM2(static=STATIC, sigma0=1.0e4, alpha=50.0, beta=0.5, gamma=1.0,
                    accel_ratio=13.3),
    "dm1 eq11": LuGreDM1(static=STATIC, damping="eq11", sigma0=1.0e4, sigma1=0.3),
    "dm1-constant": LuGreDM1(static=STATIC, damping="constant", sigma0=8.0e3, sigma1=6.0),
    "dm1_eq10_z0": LuGreDM1(static=STATIC, damping="eq10", sigma0=1.0e4, sigma1=0.05, z0=-2e-4),
    "dm1_eq12": LuGreDM1(static=STATIC, damping="eq12", sigma0=1.0e4, sigma1=4.0),
    "dm2 zero hold": LuGreDM2(static=STATIC, sigma0=1.0e4, alpha=50.0, beta=0.5, gamma=1.0,
                              accel_ratio=13.3, hold="zero"),
    "dm1 stiff": LuGreDM1(static=STATIC, damping="constant", sigma0=1.0e7, sigma1=2.0),
    "dm2 rest": LuGreDM2(static=STATIC, sigma0=1.0e4, alpha=5.0, beta=0.5, gamma=1.0,
                         accel_ratio=13.3, accel_floor=0.5, rest_speed=0.02),
    "arctan": STATIC,
    "cv": CoulombViscous(c=3.0, v=1.5),
}


def _cc():
    for name in ("cc", "gcc", "clang"):
        p = shutil.which(name)
        if p:
            return p
    return None


@pytest.fixture(scope="module")
def lib(tmp_path_factory):
    cc = _cc()
    if cc is None:
        pytest.skip("no C compiler (cc/gcc/clang) found")
    d = tmp_path_factory.mktemp("cgen")
    h, c = export_c(MODELS, d, dt=DT)
    so = d / "libjl.so"
    r = subprocess.run([cc, "-O2", "-std=c99", "-Wall", "-Wextra", "-pedantic", "-Werror",
                        "-shared", "-fPIC", "-o", str(so), str(c), "-lm"],
                       capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    L = ctypes.CDLL(str(so))
    L.jl_friction_size.restype = ctypes.c_size_t
    L.jl_friction_find.restype = ctypes.c_void_p
    L.jl_friction_find.argtypes = [ctypes.c_char_p]
    L.jl_friction_init.argtypes = [ctypes.c_void_p, ctypes.c_void_p]
    L.jl_friction_reset.argtypes = [ctypes.c_void_p]
    L.jl_friction_step.argtypes = [ctypes.c_void_p, ctypes.c_double, ctypes.c_double]
    L.jl_friction_step.restype = ctypes.c_double
    L.jl_friction_run.argtypes = [ctypes.c_void_p, ctypes.c_size_t, ctypes.c_void_p,
                                  ctypes.c_void_p, ctypes.c_void_p]
    return L


@pytest.fixture(scope="module")
def recorded(tmp_path_factory):
    """A recorded profile: simulated, written to a CSV file and read back (as a controller
    replay would), with measurement noise on the velocity and acceleration."""
    d = simulate_friction(MODELS["dm2"], test_profile_knots("random", 8.0, seed=3))
    rng = np.random.default_rng(4)
    qd = d.qd + 1e-3 * rng.standard_normal(d.n)
    qdd = d.qdd + 0.05 * rng.standard_normal(d.n)
    p = tmp_path_factory.mktemp("rec") / "profile.csv"
    np.savetxt(p, np.column_stack([d.time, qd, qdd]), delimiter=",", header="time,qd,qdd",
               fmt="%.17g")
    t, qd, qdd = np.loadtxt(p, delimiter=",", unpack=True)
    return t, np.ascontiguousarray(qd), np.ascontiguousarray(qdd)


def _run_c(L, label, qd, qdd):
    buf = ctypes.create_string_buffer(L.jl_friction_size())
    p = L.jl_friction_find(label.encode())
    assert p, label
    L.jl_friction_init(buf, p)
    out = np.empty_like(qd)
    L.jl_friction_run(buf, qd.size, qd.ctypes.data, qdd.ctypes.data, out.ctypes.data)
    return out, buf


@pytest.mark.parametrize("label", list(MODELS))
def test_c_reproduces_python(lib, recorded, label):
    t, qd, qdd = recorded
    m = MODELS[label]
    ref = m.torque(qd, qdd, DT) if m.dynamic else m.torque(qd)
    out, buf = _run_c(lib, label, qd, qdd)
    np.testing.assert_allclose(out, ref, rtol=0, atol=1e-9)
    assert np.max(np.abs(ref)) > 1.0                             # a real signal was compared
    # reset: the state starts over (steady state of the first sample, or z0)
    lib.jl_friction_reset(buf)
    again = np.array([lib.jl_friction_step(buf, float(v), float(a))
                      for v, a in zip(qd[:50], qdd[:50])])
    np.testing.assert_allclose(again, ref[:50], rtol=0, atol=1e-9)


def test_unknown_name_is_null(lib):
    assert not lib.jl_friction_find(b"nope")


def test_export_validates(tmp_path):
    with pytest.raises(ValueError, match="sample time"):
        export_c({"dm2": MODELS["dm2"]}, tmp_path)
    with pytest.raises(ValueError, match="accel_ratio"):
        export_c({"x": LuGreDM2(static=STATIC, sigma0=1e4, alpha=1, beta=0, gamma=1)}, tmp_path,
                 dt=DT)
    with pytest.raises(ValueError, match="same C name"):
        export_c({"a b": STATIC, "a-b": STATIC}, tmp_path)
    with pytest.raises(ValueError, match="cannot export"):
        export_c({"s": Stribeck(Fk=1, Fv=1, Fs=0.5, Vc=0.1)}, tmp_path)
    assert c_identifier("5-dm2") == "m_5_dm2"


def test_export_models_c_hook(tmp_path):
    qd = np.linspace(-2, 2, 4001)
    fit = fit_arctan(qd, STATIC.torque(qd))
    class OneLinkLike:                       # ident.model.onelink fits expose .friction()
        def friction(self):
            return MODELS["cv"]

    fits = {"5": {"arctan": fit, "dm2": MODELS["dm2"], "cv": OneLinkLike(),
                  "stribeck": Stribeck(Fk=1, Fv=1, Fs=0.5, Vc=0.1)}}
    h, c = export_models_c(fits, tmp_path, dt=DT)
    src = c.read_text()
    assert "JL_5_ARCTAN" in src and "JL_5_DM2" in src and "JL_5_CV" in src
    assert "STRIBECK" not in src
    assert '#include "jl_friction.h"' in src
    assert "JL_5_DM2" in h.read_text()
    # parameters are written with round-trip precision
    assert repr(fit.model.tau_s) in src
