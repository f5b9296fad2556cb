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
load_dependent      ``-mu |L| s(qd)``, L the drive torque on the joint (``qfrc_applied``)  mu
asymmetry           ``-(ac |s(qd)| + av |qd|)`` (c+ - c- = 2 ac, v+ - v- = 2 av)             ac, av
presliding          ``-F (z - s(qd))``, ``dz/dt = (qd / delta) (1 - z sgn(qd))`` (Dahl)    F, delta
==================  ================================================================  =============

The presliding state ``z`` (one per joint) is integrated with the explicit Euler step of the
model's timestep; in a callback it lives in ``mjData.userdata`` (the exported MJCF declares
``nuserdata``): ``userdata[:n]`` the committed ``z``, ``userdata[n:2n]`` the next one,
``userdata[2n]`` the time of the last call, so that repeated calls at one time stamp are
idempotent.

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


def smooth_sign(qd, eps):
    """``tanh(qd / eps)``: the sign of the velocity, smoothed over ``eps`` (rad/s)."""
    return np.tanh(np.asarray(qd) / eps)


def features(effect: str, shape: dict, q, qd, load, z, eps):
    """The effect's torque basis: ``(..., k)`` columns whose linear combination with the
    amplitudes (:func:`amplitude_names`) is the extra torque (each column already carries the
    minus sign of a friction that opposes motion).

    ``q, qd, load, z``: arrays of one joint's angle, velocity, drive torque and presliding state.
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
        return (-np.abs(load) * s)[..., None]
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


def torque(params: dict, q, qd, load, z, h):
    """Extra torque of every joint and the next presliding state.

    Parameters
    ----------
    params : dict
        The ``effects.json`` document: ``{"joints": [{"dof": i, "eps": .., "effects":
        [{"effect": name, "shape": {...}, "amplitudes": {...}}]}]}``.
    q, qd, load, z : ndarray
        ``(..., nv)`` angles, velocities, drive torques (``qfrc_applied``) and presliding states.
    h : float
        The timestep (s).

    Returns
    -------
    tau, z_next : ndarray
        ``(..., nv)`` extra torque and the presliding state one step later.
    """
    q, qd, load, z = (np.asarray(x, float) for x in (q, qd, load, z))
    tau = np.zeros(np.broadcast_shapes(q.shape, qd.shape))
    z_next = np.array(z, float, copy=True)
    for jt in params.get("joints", ()):
        i = int(jt["dof"])
        eps = float(jt.get("eps", params.get("eps", 1e-2)))
        for e in jt.get("effects", ()):
            amp = np.array([e["amplitudes"][nm] for nm in amplitude_names(e["effect"])], float)
            F = features(e["effect"], e["shape"], q[..., i], qd[..., i], load[..., i], z[..., i], eps)
            tau[..., i] += F @ amp
            if e["effect"] == "presliding":
                z_next[..., i] = bristle_step(z[..., i], qd[..., i], e["shape"]["delta"], h)
    return tau, z_next


def initial_state(params: dict, qd, eps=None):
    """Presliding states in steady sliding at velocity ``qd``: ``sgn(qd)`` (0 at rest)."""
    return np.sign(np.asarray(qd, float))


def install(model, params: dict):
    """Set MuJoCo's passive-force callback (``mujoco.set_mjcb_passive``) to add :func:`torque` to
    ``qfrc_passive`` of every ``mjData`` stepped with ``model`` (which must declare
    ``nuserdata >= 2 nv + 1``); returns the callback. ``mjData.userdata`` holds the presliding
    states (see the module docstring); call :func:`reset` after setting a data's state."""
    import mujoco

    nv = model.nv
    if model.nuserdata < 2 * nv + 1:
        raise ValueError(f"the model declares nuserdata={model.nuserdata}; the effects need {2 * nv + 1}")
    h = float(model.opt.timestep)

    def passive(m, d):
        ud = d.userdata
        if ud[2 * nv] != d.time:               # a new step: commit the state computed last time
            ud[:nv] = ud[nv:2 * nv]
            ud[2 * nv] = d.time
        tau, z_next = torque(params, d.qpos[:nv], d.qvel[:nv], d.qfrc_applied[:nv], ud[:nv], h)
        ud[nv:2 * nv] = z_next
        d.qfrc_passive[:nv] += tau

    mujoco.set_mjcb_passive(passive)
    return passive


def reset(model, data, params: dict = None):
    """Presliding states of ``data`` set to steady sliding at its velocity (after a state reset)."""
    nv = model.nv
    z = initial_state(params or {}, data.qvel[:nv])
    data.userdata[:nv] = z
    data.userdata[nv:2 * nv] = z
    data.userdata[2 * nv] = data.time
