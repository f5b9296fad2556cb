"""Extra joint torques of the named friction effects, for MuJoCo: standalone (numpy and mujoco only).

This file is copied verbatim into every exported model folder (``jointlab sim2real``), so that a
plain MuJoCo script runs the corrected model without jointlab; jointlab's own replay calls the
same functions, so that both compute the same torques.

Each effect adds a torque on top of MuJoCo's native joint friction (``frictionloss`` ``c``,
``damping`` ``v``, ``armature``); ``s(qd) = tanh(qd / eps)`` is a smooth sign:

==================  ================================================================  =============
effect              extra torque on the joint (N m)                                    parameters
==================  ================================================================  =============
stribeck            ``-S exp(-(|qd| / Vs)^d) s(qd)``  (friction drop, Armstrong eq.)   S, Vs, d
nonlinear_viscous   ``-w |qd|^p s(qd)``, p != 1                                          w, p
position_ripple     ``-(a cos(k q) + b sin(k q)) - (c cos(k q) + e sin(k q)) s(qd)``     a, b, c, e, k
load_dependent      ``-mu T tanh(|L| / T) s(qd)``, L the transmitted torque (below)       mu, T
asymmetry           ``-(ac |s(qd)| + av |qd|)`` (c+ - c- = 2 ac, v+ - v- = 2 av)             ac, av
presliding          ``-F (z - s(qd))``, ``dz/dt = (qd / delta) (1 - z sgn(qd))`` (Dahl)    F, delta
==================  ================================================================  =============

The load of ``load_dependent`` is the torque the transmission carries to the link, not the drive
torque: the drive torque ``u`` (``qfrc_applied``) less what the joint's own armature, damping and
friction take, ``L = u + x - a qdd - b qd - c s(qd)`` (``a, b, c`` the joint's ``armature``,
``damping``, ``frictionloss``; ``x`` the extra torque of this module one step earlier; ``qdd`` the
velocity change over the last step divided by the timestep), which in a rigid model is the link's
rigid-body torque ``M(q) qdd + C(q, qd) qd + g(q)`` (the inverse dynamics without armature and
friction, what jointlab fits the amplitude on). On a gear with a flexible transmission this is the
spring torque, not the motor torque: the two differ by the motor's inertia and friction torques,
which on a large reducer are a fair part of the drive torque. ``T`` saturates the growth (large
``T``: linear in ``|L|``).

The state of every joint (the presliding ``z``, the velocity and the extra torque at the previous
step, :data:`NSTATE` rows of ``nv``) advances with the model's timestep (explicit Euler for ``z``);
in a callback it lives in ``mjData.userdata`` (the exported MJCF declares
``nuserdata = 2 NSTATE nv + 1``, :func:`nuserdata`): ``userdata[:S]`` the committed state,
``userdata[S:2S]`` the next one (``S = NSTATE nv``), ``userdata[2S]`` the time of the last call, so
that repeated calls at one time stamp are idempotent.

Usage in a plain script (the passive-force callback)::

    import json, mujoco, sim2real_effects as fx
    m = mujoco.MjModel.from_xml_path("model.xml")
    fx.install(m, json.load(open("effects.json")))     # mujoco.set_mjcb_passive(...)
"""
from __future__ import annotations

import numpy as np

#: the effects this module implements
EFFECTS = ("stribeck", "nonlinear_viscous", "position_ripple", "load_dependent", "asymmetry",
           "presliding")
#: rows of the per-joint state: presliding z, velocity at the previous step, extra torque at the
#: previous step
NSTATE = 3


def nuserdata(nv: int) -> int:
    """``mjData.userdata`` size the callback needs for ``nv`` dofs."""
    return 2 * NSTATE * nv + 1


def smooth_sign(qd, eps):
    """``tanh(qd / eps)``: the sign of the velocity, smoothed over ``eps`` (rad/s)."""
    return np.tanh(np.asarray(qd) / eps)


def features(effect: str, shape: dict, q, qd, load, z, eps):
    """The effect's torque basis: ``(..., k)`` columns whose linear combination with the
    amplitudes (:func:`amplitude_names`) is the extra torque (each column already carries the
    minus sign of a friction that opposes motion).

    ``q, qd, load, z``: arrays of one joint's angle, velocity, transmitted torque (``load_dependent``:
    the link's rigid-body torque, see the module docstring) and presliding state.
    """
    s = smooth_sign(qd, eps)
    a = np.abs(qd)
    if effect == "stribeck":
        return (-np.exp(-(a / shape["Vs"]) ** shape["d"]) * s)[..., None]
    if effect == "nonlinear_viscous":
        return (-(a ** shape["p"]) * s)[..., None]
    if effect == "position_ripple":
        c, n = np.cos(shape["k"] * q), np.sin(shape["k"] * q)
        return -np.stack([c, n, c * s, n * s], axis=-1)
    if effect == "load_dependent":
        T = float(shape.get("T", np.inf))
        a = np.abs(load)
        return (-(T * np.tanh(a / T) if np.isfinite(T) else a) * s)[..., None]
    if effect == "asymmetry":
        return -np.stack([np.abs(s), a], axis=-1)
    if effect == "presliding":
        return (-(z - s))[..., None]
    raise ValueError(f"unknown effect {effect!r}")


def amplitude_names(effect: str) -> tuple:
    """Names of the linear amplitudes of :func:`features`, in column order."""
    return {"stribeck": ("S",), "nonlinear_viscous": ("w",), "position_ripple": ("a", "b", "c", "e"),
            "load_dependent": ("mu",), "asymmetry": ("ac", "av"), "presliding": ("F",)}[effect]


def bristle_step(z, qd, delta, h):
    """One explicit Euler step of the Dahl presliding state: ``z + h (qd / delta) (1 - z sgn(qd))``,
    clipped to [-1, 1]."""
    z = z + h * (qd / delta) * (1.0 - z * np.sign(qd))
    return np.clip(z, -1.0, 1.0)


def transmitted(load, qd, qd_prev, x_prev, native, h, eps):
    """The torque the transmission carries: ``L = u + x - a qdd - b qd - c s(qd)`` (module
    docstring), ``native = (a, b, c)`` of the joint, ``qdd = (qd - qd_prev) / h``."""
    a, b, c = native
    return load + x_prev - a * (qd - qd_prev) / h - b * qd - c * smooth_sign(qd, eps)


def torque(params: dict, q, qd, load, state, h, native=None):
    """Extra torque of every joint and the next state.

    Parameters
    ----------
    params : dict
        The ``effects.json`` document: ``{"joints": [{"dof": i, "eps": .., "effects":
        [{"effect": name, "shape": {...}, "amplitudes": {...}}]}]}``.
    q, qd, load : ndarray
        ``(..., nv)`` angles, velocities and drive torques (``qfrc_applied``).
    state : ndarray
        ``(..., NSTATE, nv)`` the joints' state (:func:`initial_state`, module docstring).
    h : float
        The timestep (s).
    native : tuple of ndarray, optional
        ``(armature, damping, frictionloss)``, each ``(nv,)`` (the model's ``dof_armature``,
        ``dof_damping``, ``dof_frictionloss``); needed by ``load_dependent`` only (default 0).

    Returns
    -------
    tau, state_next : ndarray
        ``(..., nv)`` extra torque and the state one step later.
    """
    q, qd, load, state = (np.asarray(x, float) for x in (q, qd, load, state))
    tau = np.zeros(np.broadcast_shapes(q.shape, qd.shape))
    nxt = np.array(state, float, copy=True)
    nv = q.shape[-1]
    nat = np.zeros((3, nv)) if native is None else np.asarray(native, float).reshape(3, nv)
    for jt in params.get("joints", ()):
        i = int(jt["dof"])
        eps = float(jt.get("eps", params.get("eps", 1e-2)))
        for e in jt.get("effects", ()):
            amp = np.array([e["amplitudes"][nm] for nm in amplitude_names(e["effect"])], float)
            L = load[..., i]
            if e["effect"] == "load_dependent":
                L = transmitted(L, qd[..., i], state[..., 1, i], state[..., 2, i], nat[:, i], h, eps)
            F = features(e["effect"], e["shape"], q[..., i], qd[..., i], L, state[..., 0, i], eps)
            tau[..., i] += F @ amp
            if e["effect"] == "presliding":
                nxt[..., 0, i] = bristle_step(state[..., 0, i], qd[..., i], e["shape"]["delta"], h)
    nxt[..., 1, :] = qd
    nxt[..., 2, :] = tau
    return tau, nxt


def initial_state(params: dict, qd, qd_history=None, h=None):
    """``(..., NSTATE, nv)`` state at velocity ``qd`` (..., nv): the previous velocity ``qd`` (no
    acceleration at the first step), no extra torque, and the presliding state in steady sliding
    (``sgn(qd)``, 0 at rest), or, given the measured velocities before this instant
    ``qd_history`` (..., T, nv) at steps of ``h`` seconds, the Dahl state of every presliding joint
    of ``params`` integrated along them from ``sgn`` of the first (:func:`bristle_step`): at rest
    or near a reversal the bristles hold what the last motion left, which ``sgn(qd)`` does not
    know."""
    qd = np.asarray(qd, float)
    z = np.sign(qd)
    if qd_history is not None:
        hist = np.asarray(qd_history, float)
        z = np.array(z, float, copy=True)
        for jt in (params or {}).get("joints", ()):
            i = int(jt["dof"])
            for e in jt.get("effects", ()):
                if e["effect"] == "presliding":
                    zi = np.sign(hist[..., 0, i])
                    for k in range(hist.shape[-2]):
                        zi = bristle_step(zi, hist[..., k, i], e["shape"]["delta"], h)
                    z[..., i] = zi
    return np.stack([z, qd, np.zeros_like(qd)], axis=-2)


def install(model, params: dict):
    """Set MuJoCo's passive-force callback (``mujoco.set_mjcb_passive``) to add :func:`torque` to
    ``qfrc_passive`` of every ``mjData`` stepped with ``model`` (which must declare
    ``nuserdata >= 2 NSTATE nv + 1``, :func:`nuserdata`); returns the callback.
    ``mjData.userdata`` holds the joints' state (see the module docstring); call :func:`reset`
    after setting a data's state."""
    import mujoco

    nv = model.nv
    S = NSTATE * nv
    if model.nuserdata < nuserdata(nv):
        raise ValueError(f"the model declares nuserdata={model.nuserdata}; the effects need {nuserdata(nv)}")
    h = float(model.opt.timestep)
    native = np.stack([model.dof_armature, model.dof_damping, model.dof_frictionloss])

    def passive(m, d):
        ud = d.userdata
        if ud[2 * S] != d.time:               # a new step: commit the state computed last time
            ud[:S] = ud[S:2 * S]
            ud[2 * S] = d.time
        tau, nxt = torque(params, d.qpos[:nv], d.qvel[:nv], d.qfrc_applied[:nv],
                          ud[:S].reshape(NSTATE, nv), h, native)
        ud[S:2 * S] = nxt.ravel()
        d.qfrc_passive[:nv] += tau

    mujoco.set_mjcb_passive(passive)
    return passive


def reset(model, data, params: dict = None, qd_history=None, h=None):
    """The joints' state of ``data`` set to :func:`initial_state` at its velocity (after a state
    reset); ``qd_history`` (T, nv), ``h``: the measured velocities before this instant."""
    nv = model.nv
    S = NSTATE * nv
    st = initial_state(params or {}, data.qvel[:nv], qd_history, h).ravel()
    data.userdata[:S] = st
    data.userdata[S:2 * S] = st
    data.userdata[2 * S] = data.time
