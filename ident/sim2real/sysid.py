"""``mujoco.sysid`` (MuJoCo 4's system-identification toolbox) on the same native parameters as
jointlab's fit (armature, damping, frictionloss of every scored joint), on the same training
windows, from the same start (the inverse-dynamics least squares of :mod:`ident.sim2real.fit`).

What is mujoco.sysid's and what is jointlab's here:

- mujoco.sysid's: the parameters (``mujoco.sysid.Parameter``, box bounds, a modifier writing each
  value into the ``MjSpec``), the model build (``apply_param_modifiers``: spec recompiled per
  candidate), the rollout and residual (``model_residual``: ``sysid_rollout`` over
  ``mujoco.rollout``, its default residual ``measured - predicted`` divided per window and signal by
  ``||measured|| / sqrt(2)``), and the optimiser (``optimize``, its default ``"mujoco"`` backend:
  ``mujoco.minimize.least_squares``, box-constrained Gauss-Newton with finite differences).
- jointlab's: the windows (0.5 s from the measured state, :data:`ident.sim2real.fit.SELECT_HORIZON`,
  at most :data:`ident.sim2real.fit.TRAIN_WINDOWS` per record), the model of each record (payload,
  servos on the joints not driven by torque), the observations (the scored joints' ``qpos``, a
  state signal: no sensor lag) and the drive: the logged link-side torque as ``ctrl`` of one motor
  actuator per joint (gear 1, unlimited; the same force ``qfrc_applied`` gives in the replay), held
  over the sample step (given at every simulation step, so its resampling is exact).

Upper bounds: ``10 x start + 1`` (SI units of each parameter); lower bounds 0.

One call of ``model_residual`` per record rolls out all its windows (and every finite-difference
column) at once: ``mujoco.sysid.residual`` would call it once per window.
"""
from __future__ import annotations

import contextlib
import io
import time

import numpy as np

from ident.sim2real.model import NATIVE
from ident.sim2real.fit import SELECT_HORIZON, TRAIN_WINDOWS

#: iterations of mujoco.sysid's optimiser
SYSID_ITERS = 10


def available() -> str | None:
    """None where ``mujoco.sysid`` imports, else why not."""
    try:
        import mujoco.sysid as ms
        if not hasattr(ms, "optimize"):
            raise ImportError
    except ImportError:
        return "not installed (pip install 'mujoco[sysid]')"
    return None


def _spec(rp, native):
    """The record's spec for mujoco.sysid: payload, servo gains, one motor actuator per chain joint."""
    import mujoco

    sm = rp.sm
    spec = sm.spec_for(rp.h, rp.rec.payload, native)
    for k, (kp, kv) in enumerate(rp.gains):
        a = spec.actuator(f"jointlab_servo_{k + 1}")
        a.gainprm = [kp] + [0.0] * 9
        a.biasprm = [0.0, -kp, -kv] + [0.0] * 7
    for k, nm in enumerate(sm.names):
        spec.add_actuator(name=f"jointlab_motor_{k + 1}", target=nm, trntype=mujoco.mjtTrn.mjTRN_JOINT,
                          gaintype=mujoco.mjtGain.mjGAIN_FIXED, gainprm=[1.0] + [0.0] * 9,
                          biastype=mujoco.mjtBias.mjBIAS_NONE)
    return spec


def _modifier(joint: str, name: str):
    def apply(spec, p):
        jt = spec.joint(joint)
        v = float(np.asarray(p.value).ravel()[0])
        if name == "damping":
            d = np.array(jt.damping, float).ravel()
            d[0] = v
            jt.damping = d
        else:
            setattr(jt, name, v)
    return apply


def fit_sysid(sm, replayers, masks, start: dict, nthread: int = 1, max_iters: int = SYSID_ITERS,
              max_windows: int | None = None) -> dict:
    """Fit the scored joints' native parameters with ``mujoco.sysid`` (module docstring).

    Returns
    -------
    dict
        ``status`` ("fitted" or why not), ``native`` (name -> (n,) array or None), ``iterations``,
        ``windows``, ``seconds``, ``training_cost`` {start, end} (mujoco.sysid's residual, squared
        sum / 2), ``settings``.
    """

    why = available()
    if why is not None:
        return {"status": why, "native": None}
    import mujoco.sysid as ms
    from absl import logging as absl_logging

    t0 = time.perf_counter()
    max_windows = TRAIN_WINDOWS if max_windows is None else max_windows
    records = [rp.rec for rp in replayers]
    scored = [j for j in range(sm.n) if all(r.driven[j] for r in records)]
    params = ms.ParameterDict()
    for j in scored:
        nm = sm.names[j]
        for k in NATIVE:
            v = float(max(start[k][j], 0.0))
            params.add(ms.Parameter(f"{k}[{nm}]", v, 0.0, 10.0 * v + 1.0, modifier=_modifier(nm, k)))
    groups = []
    nwin = 0
    for rp, m in zip(replayers, masks):
        starts = rp.windows(SELECT_HORIZON, m, max_windows)
        if starts.size == 0:
            continue
        spec = _spec(rp, start)
        model = spec.compile()
        L = max(1, int(round(SELECT_HORIZON / rp.rec.dt)))
        x0 = rp._init(model, starts)
        u = rp._controls(model, starts, L)                     # servo targets, then qfrc (nv)
        n, nu = sm.n, model.nu
        ctrl = np.zeros(u.shape[:2] + (nu,))
        ctrl[:, :, :n] = u[:, :, :n]
        ctrl[:, :, n:2 * n] = u[:, :, nu + sm.dof]             # the motors, chain order
        N = ctrl.shape[1]
        tc = rp.h * np.arange(N + 1)
        mapping = {f"{sm.names[j]}_qpos": (ms.SignalType.MjStateQPos, np.array([i]))
                   for i, j in enumerate(scored)}
        trajs = []
        for b, k in enumerate(starts):
            c = ms.TimeSeries(tc, np.vstack([ctrl[b], ctrl[b, -1:]]))
            ts = rp.rec.t[k:k + L + 1] - rp.rec.t[k]
            s = ms.TimeSeries(ts, rp.rec.q[k:k + L + 1][:, scored], signal_mapping=mapping)
            trajs.append((x0[b], c, s))
        nwin += len(trajs)
        groups.append((spec, trajs))
    if not groups:
        return {"status": "no training window", "native": None}
    verb = absl_logging.get_verbosity()
    absl_logging.set_verbosity(absl_logging.ERROR)
    try:
        seqs = [ms.ModelSequences(f"rec{i}", spec, [f"w{b}" for b in range(len(tr))], [t[0] for t in tr],
                                  [t[1] for t in tr], [t[2] for t in tr], allow_missing_sensors=True)
                for i, (spec, tr) in enumerate(groups)]

        def residual_fn(x, p):
            out = []
            for seq in seqs:
                r, _, _ = ms.model_residual(x, p, lambda pp, _s=seq.spec: ms.apply_param_modifiers(pp, _s),
                                            seq.measured_rollout, n_threads=max(1, nthread))
                if np.ndim(x) > 1:          # (rows, n_fd * n_windows) -> (n_windows * rows, n_fd)
                    nfd = x.shape[1]
                    r = r.T.reshape(nfd, -1).T
                out.append(np.where(np.isfinite(r), r, 1e3))
            return out, None, None

        c0 = 0.5 * float(np.sum(np.concatenate(residual_fn(params.as_vector(), params)[0]) ** 2))
        log = io.StringIO()
        with contextlib.redirect_stdout(log):       # the backend prints every iteration
            opt, res = ms.optimize(params, residual_fn, optimizer="mujoco", verbose=False, max_iters=max_iters)
        last = [ln.strip() for ln in log.getvalue().splitlines() if ln.strip()]
        c1 = 0.5 * float(np.sum(np.concatenate(residual_fn(opt.as_vector(), opt)[0]) ** 2))
    finally:
        absl_logging.set_verbosity(verb)
    native = {k: np.array(start[k], float) for k in NATIVE}
    for j in scored:
        for k in NATIVE:
            native[k][j] = float(np.asarray(opt[f"{k}[{sm.names[j]}]"].value).ravel()[0])
    return {"status": "fitted", "native": native, "windows": nwin, "max_iters": max_iters,
            "training_cost": {"start": c0, "end": c1},
            "optimizer_log": last[-2:], "seconds": time.perf_counter() - t0,
            "settings": "mujoco.sysid.optimize(optimizer='mujoco'), default residual (per-window "
                        "normalised qpos error), start: inverse-dynamics least squares"}
