"""The numerical ground floor (:mod:`mocap.numerics`) is the one definition its users run.

Each home's code is swapped for a perturbed one (``__code__``: every name bound to the
function, wherever it was imported, runs the new code) and every user's result must change; a
user with a private copy of the formula would not. Issue 44."""
from __future__ import annotations

import contextlib

import numpy as np
import pytest

import mocap.numerics as nm
from ident.coastdown.angle import coast_angle
from ident.friction.dynamic import LuGreDM1
from ident.friction.static import Arctan
from ident.model.rigidbody import low_speed_cut
from ident.signals.smoothing import differentiate
from mocap.kinematics import rotation_about_axis as kin_rotation
from mocap.kinematics import skew as kin_skew
from tests_paths import REPO


@contextlib.contextmanager
def perturbed(fn, scale: float = 1.01):
    """``fn`` (a function of :mod:`mocap.numerics`) returns ``scale`` times its value meanwhile."""
    original = fn.__code__
    namespace = {}
    exec(f"def shadow(*a, **k):\n    return {scale!r} * _orig(*a, **k)\n", namespace)   # noqa: S102
    copy = type(fn)(original, fn.__globals__, fn.__name__, fn.__defaults__, fn.__closure__)
    fn.__globals__["_orig"] = copy
    fn.__code__ = namespace["shadow"].__code__.replace(co_name=fn.__name__)
    try:
        yield
    finally:
        fn.__code__ = original
        del fn.__globals__["_orig"]


def _changes(fn, home, *args, **kw) -> bool:
    before = np.asarray(fn(*args, **kw), float)
    with perturbed(home):
        after = np.asarray(fn(*args, **kw), float)
    return not np.allclose(before, after, rtol=1e-6, atol=0)


DM1 = LuGreDM1(static=Arctan(tau_s=3.0, tau_sc=-1.0, tau_v=1.0, tau_nlv=0.1, delta=10.0),
               sigma0=1e4, sigma1=30.0)
QD = 0.3 * np.sin(np.linspace(0, 6, 400))


@pytest.mark.parametrize("hold", ["first", "zero"])
def test_phi_home_drives_both_lugre_steps(hold):
    m = LuGreDM1(static=DM1.static, sigma0=1e4, sigma1=30.0, hold=hold)
    z0 = np.full(QD.size - 1, 1e-5)
    assert _changes(lambda: m.states(QD, 0.005), nm.phi)
    assert _changes(lambda: m.step(z0, QD[:-1], 0.005, QD[1:]), nm.phi)


def test_phi_and_psi_homes_drive_the_coast_down():
    tau = np.linspace(0.01, 2.0, 50)
    assert _changes(lambda: coast_angle(tau, 0.01, 0.02, 0.05, 3.0)[0], nm.phi)
    assert _changes(lambda: coast_angle(tau, 0.01, 0.02, 0.05, 3.0)[0], nm.psi)


def test_savgol_home_drives_every_differentiator():
    t = np.arange(400) * 0.005
    x = np.sin(3 * t) + 0.01 * np.cos(40 * t)
    assert _changes(differentiate, nm.savgol, x, 0.005, 0.05)

    class _Rec:               # the fields low_speed_cut reads of a prepared record
        n, dt, preprocessing = 1, 0.005, {"window_s": {"1": 0.05}}

    class _Log:
        qm = (x + 1e-4 * np.random.default_rng(1).normal(size=x.size))[:, None]

    assert _changes(lambda: low_speed_cut(_Log, _Rec)["sigma_q"], nm.savgol)


def test_rotation_homes_drive_kinematics_the_regressor_and_the_marker_solve():
    assert kin_rotation is nm.rotation_about_axis and kin_skew is nm.skew
    import pinocchio as pin

    from ident.model.regressor import ChainDynamics

    ch = ChainDynamics.from_model(pin.buildModelFromUrdf(str(REPO / "fixtures" / "arm7" / "arm7.urdf")))
    rng = np.random.default_rng(0)
    q, qd, qdd = (rng.standard_normal((4, ch.n)) for _ in range(3))
    assert _changes(ch.regressor, nm.rotation_about_axis, q, qd, qdd)
    assert _changes(ch.regressor, nm.skew, q, qd, qdd)
    # the marker solve's per-frame model (thesis eq. 3-5): Rodrigues on the marker vectors
    a = np.array([0.0, 0.0, 1.0])
    x = rng.standard_normal((3, 3))
    xa = (x @ a)[:, None] * a
    assert _changes(nm.rotate_about_axis, nm.rotate_about_axis, x - xa, np.cross(a, x), xa,
                    np.linspace(0, 1, 4))
    src = (REPO / "mocap" / "solve.py").read_text()
    assert src.count("rotate_about_axis(") >= 2 and "np.cos(qs)" not in src
