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
def perturbed(fn, scale: float = 1.01, shift: float = 0.0):
    """``fn`` (a function of :mod:`mocap.numerics`) returns ``scale`` times its value plus
    ``shift`` meanwhile (in place where the caller passed ``out=``: the caller may not read the
    return value then). A shift also moves users that a scale cannot (an orthonormalised
    rotation, a fit whose free parameters absorb a scale)."""
    original = fn.__code__
    namespace = {}
    exec("def shadow(*a, **k):\n"                                                       # noqa: S102
         "    r = _orig(*a, **k)\n"
         "    if k.get('out') is not None:\n"
         f"        r *= {scale!r}\n"
         f"        r += {shift!r}\n"
         "        return r\n"
         f"    return {scale!r} * r + {shift!r}\n", namespace)
    copy = type(fn)(original, fn.__globals__, fn.__name__, fn.__defaults__, fn.__closure__)
    fn.__globals__["_orig"] = copy
    fn.__code__ = namespace["shadow"].__code__.replace(co_name=fn.__name__)
    try:
        yield
    finally:
        fn.__code__ = original
        del fn.__globals__["_orig"]


def _changes(fn, home, *args, shift: float = 0.0, **kw) -> bool:
    before = np.asarray(fn(*args, **kw), float)
    with perturbed(home, shift=shift):
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


def test_phi_home_drives_the_record_spectrum_and_the_two_mass_coast():
    """The complex users of phi: the FDM's end half-hats ``(1 - phi(s dt)) / s`` and the
    two-mass coast's modal integrals ``t phi(-lambda t)`` (complex lambda)."""
    from ident.coastdown.angle import two_mass_coast
    from ident.coastdown.estimators import record_spectrum

    t = np.arange(600) / 200.0
    v = 10.0 * np.exp(-t) - 0.1

    def spectrum():
        V = record_spectrum(t, v, w_max=30.0)[1]
        return np.r_[V.real, V.imag]

    assert _changes(spectrum, nm.phi)
    tau = np.linspace(0.0, 1.0, 200)
    for side in ("link", "motor"):          # complex modes (a soft spring) and real ones
        for K in (50.0, 5e3):
            assert _changes(lambda: two_mass_coast(tau, 0.05, 0.04, 0.01, K, 0.01, 0.1, 0.3, 0.05, 0.3,
                                                   2.0, -1.0, side=side)[0], nm.phi), (side, K)


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


def _arm7_chain():
    """A fresh chain of the arm7 fixture (a chain caches its Rodrigues terms on first use)."""
    from mocap.robot import Robot

    return Robot.from_urdf(REPO / "fixtures" / "arm7" / "arm7.urdf").chain


@pytest.mark.parametrize("home", ["rodrigues_terms", "rodrigues_combine"])
def test_rodrigues_homes_drive_both_forward_kinematics(home):
    """Both layouts of :class:`mocap.kinematics.Chain` (frames first and frames last) take the
    joint rotation from the home: its terms and its one combination."""
    q = np.random.default_rng(2).uniform(-1, 1, (5, _arm7_chain().n))
    fn = getattr(nm, home)
    assert _changes(lambda: _arm7_chain().joint_frames(q)[0], fn)
    assert _changes(lambda: _arm7_chain().joint_frames_soa(q.T)[0], fn)
    assert _changes(lambda: nm.rotation_about_axis([0.0, 0.6, 0.8], q[:, 0]), fn)


def _sweep(seed=3):
    """Three markers turning about a tilted axis, with noise: a calibration sweep (T, 3, 3)."""
    rng = np.random.default_rng(seed)
    axis = np.array([0.2, -0.3, 0.9]) / np.linalg.norm([0.2, -0.3, 0.9])
    q = np.linspace(-1.0, 1.0, 60)
    p0 = np.array([[0.15, 0.0, 0.1], [0.0, 0.2, -0.05], [-0.1, -0.12, 0.2]])
    P = np.einsum("tij,mj->tmi", nm.rotation_about_axis(axis, q), p0) + [0.3, 0.1, 1.5]
    return P + rng.normal(scale=2e-4, size=P.shape)


def test_rodrigues_homes_drive_the_axis_fit():
    """The circle-point sweep fit (:class:`calib.axis.ClusterAxisEstimator`): its model comes from
    the Rodrigues combination, its axis Jacobian (hence the covariance) from
    :func:`mocap.numerics.rodrigues_axis_derivative`."""
    from calib.axis import ClusterAxisEstimator

    P = _sweep()
    est = ClusterAxisEstimator()
    assert _changes(lambda: est.fit(P).cov, nm.rodrigues_axis_derivative)
    assert _changes(lambda: est.fit(P).point, nm.rodrigues_combine, shift=1e-3)


def test_rotation_home_drives_the_mujoco_urdf():
    """``ident.sim2real.model.urdf_for_mujoco`` folds a locked joint's rotation into its origin
    through :func:`mocap.numerics.rotation_about_axis`."""
    import xml.etree.ElementTree as ET

    from ident.sim2real.model import urdf_for_mujoco

    urdf = REPO / "fixtures" / "arm7" / "arm7.urdf"
    names = [j.get("name") for j in ET.parse(urdf).getroot().findall("joint")
             if j.get("type") in ("revolute", "continuous")]
    locked = names[-1]

    def rpy():
        root = ET.fromstring(urdf_for_mujoco(urdf, tuple(names[:-1]), {locked: 0.7}))
        j = next(j for j in root.findall("joint") if j.get("name") == locked)
        return [float(x) for x in j.find("origin").get("rpy").split()]

    assert _changes(rpy, nm.rotation_about_axis, shift=1e-3)


def test_rodrigues_axis_derivative_is_the_derivative():
    """Central differences of ``R(n + eps e, q) d`` (the axis renormalised: ``e`` perpendicular
    to ``n`` leaves its length unchanged to first order) agree with the closed form."""
    rng = np.random.default_rng(5)
    n = nm.rotation_about_axis([1.0, 0.0, 0.0], 0.4) @ np.array([0.0, 0.0, 1.0])
    e = np.cross(n, [1.0, 0.0, 0.0])
    e /= np.linalg.norm(e)
    d = rng.standard_normal((7, 3))
    q = rng.uniform(-2, 2, 7)
    h = 1e-6

    def rotated(eps):
        a = (n + eps * e) / np.linalg.norm(n + eps * e)
        return np.einsum("kij,kj->ki", nm.rotation_about_axis(a, q), d)

    fd = (rotated(h) - rotated(-h)) / (2 * h)
    exact = nm.rodrigues_axis_derivative(e, d, n, np.sin(q)[:, None], np.cos(q)[:, None])
    assert np.allclose(exact, fd, atol=1e-8, rtol=0)


def test_rotation_log_home_drives_the_hand_eye_start():
    """The rotation vectors of the hand-eye start (Park & Martin, :mod:`calib.handeye`) and of the
    static poses' camera pose (:mod:`mocap.references`, through :mod:`mocap.kinematics`) are the
    home's :func:`mocap.numerics.matrix_to_rotvec`."""
    import mocap.kinematics as kin
    import mocap.references as refs
    from calib.handeye import _park_martin

    assert kin.matrix_to_rotvec is nm.matrix_to_rotvec is refs.matrix_to_rotvec
    rng = np.random.default_rng(4)
    X = np.eye(4)
    X[:3, :3], X[:3, 3] = nm.rotvec_to_matrix([0.3, -0.5, 0.9]), [0.2, -0.1, 1.4]
    C = np.tile(np.eye(4), (6, 1, 1))
    C[:, :3, :3] = nm.rotvec_to_matrix(rng.uniform(-0.8, 0.8, (6, 3)))
    C[:, :3, 3] = rng.uniform(-0.3, 0.3, (6, 3))
    A = X @ C @ np.linalg.inv(X)                   # A X = X B with B = C
    Rz, tz = _park_martin(A[:, :3, :3], A[:, :3, 3], C)
    assert np.allclose(Rz, X[:3, :3], atol=1e-9) and np.allclose(tz, X[:3, 3], atol=1e-9)
    assert _changes(lambda: _park_martin(A[:, :3, :3], A[:, :3, 3], C)[0], nm.matrix_to_rotvec,
                    shift=1e-3)
