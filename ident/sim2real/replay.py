"""Replay of logged records in MuJoCo: windows that start from the measured state, driven by the
logged joint torques, batched with ``mujoco.rollout``; the multi-step-ahead simulation error.

For a horizon ``H`` the held-out part of a record is cut into consecutive windows of ``H``; each
starts from the measured angle and the smoothed velocity (:func:`ident.model.record.load_record`)
and is driven by the logged torque (URDF coordinates: ``tau_urdf = C^-T tau_log``), held over
each sample step. The error of a joint at horizon ``H`` is the RMS over every sample of every
window of ``q_sim - q_meas`` (and ``qd_sim - qd_meas``), split by the measured motion regime.

Joints the record does not drive by torque (braked, or ``unlogged_torque``) follow their logged
angle through a stiff position servo (:data:`ident.sim2real.model.SERVO_HZ`) and are not scored.

The named effects (:mod:`ident.sim2real.effects_runtime`) depend on the state, so a model with
effects is stepped one step at a time over all windows at once (``mujoco.rollout`` with
``nstep=1``, the effect torque added to ``qfrc_applied``): the same arithmetic as MuJoCo's
passive-force callback of the exported model, which adds it to ``qfrc_passive`` (both are summed
into the same generalised force before the step).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ident.sim2real import effects_runtime as fx
from ident.sim2real.model import MAX_STEP, SERVO_HZ
from mocap.io.payload import payload_com
from ident.model.record import load_record

HORIZONS = (0.1, 0.5, 2.0)
#: measured motion before a window start that the presliding state is integrated over (s)
HISTORY_S = 1.0
REGIMES = ("low_speed", "reversal", "high_speed")


@dataclass(eq=False)
class Record:
    """One record ready to replay: uniform samples, URDF joint coordinates, SI."""

    trial_id: str
    t: np.ndarray
    q: np.ndarray
    qd: np.ndarray
    qdd: np.ndarray
    tau: np.ndarray
    driven: np.ndarray           # (n,) bool: joint replayed from its logged torque
    payload: tuple               # (mass kg, com (3,) in the tip body's frame)
    dt: float
    regimes: dict = field(default_factory=dict)   # name -> (T, n) bool

    @property
    def n(self) -> int:
        return self.q.shape[1]


def regimes_of(qd: np.ndarray, dt: float) -> dict:
    """Motion regimes per sample and joint: ``reversal`` within 50 ms of a velocity sign change,
    ``low_speed`` below 10 % of the joint's speed scale (95th percentile of |qd|) elsewhere,
    ``high_speed`` above 50 %."""
    a = np.abs(qd)
    scale = np.maximum(np.percentile(a, 95, axis=0), 1e-9)
    flip = np.zeros_like(a, bool)
    flip[1:] = np.sign(qd[1:]) != np.sign(qd[:-1])
    flip &= a < 0.2 * scale
    w = max(1, int(round(0.05 / dt)))
    ker = np.ones(2 * w + 1)
    near = np.stack([np.convolve(flip[:, j].astype(float), ker, "same") > 0 for j in range(qd.shape[1])], 1)
    low = (a < 0.1 * scale) & ~near
    return {"low_speed": low, "reversal": near, "high_speed": a > 0.5 * scale}


def records_of(campaign, robot, trials=None) -> list:
    """:class:`Record` of every multi-joint trial (or ``trials``): jointlab's record reader
    (:func:`ident.model.record.load_record`, coupling applied, smoothed derivatives)."""

    out = []
    for tr in (trials if trials is not None else campaign.trials):
        rec = load_record(campaign, tr, robot)
        t = rec.t
        dt = float(np.median(np.diff(t)))
        if np.any(np.abs(np.diff(t) - dt) > 0.01 * dt):       # back onto a uniform grid
            tu = t[0] + dt * np.arange(int((t[-1] - t[0]) / dt + 1e-9) + 1)
            cols = [np.stack([np.interp(tu, t, x[:, j]) for j in range(x.shape[1])], 1)
                    for x in (rec.q, rec.qd, rec.qdd, rec.tau)]
            t, (q, qd, qdd, tau) = tu, cols
        else:
            q, qd, qdd, tau = rec.q, rec.qd, rec.qdd, rec.tau
        driven = np.zeros(rec.n, bool)
        driven[[j - 1 for j in rec.moving if j not in rec.unlogged]] = True
        tau = np.where(np.isfinite(tau), tau, 0.0)
        r = Record(tr.id, t, q, qd, qdd, tau, driven,
                   (float(tr.load_kg), np.array(payload_com(tr))), dt)
        r.regimes = regimes_of(qd, dt)
        out.append(r)
    return out


def substeps(dt: float) -> int:
    """Simulation steps per sample step: the sample step split into steps of at most
    :data:`ident.sim2real.model.MAX_STEP`."""
    return max(1, int(np.ceil(dt / MAX_STEP - 1e-9)))


def servo_gains(sm, robot, rec: Record, native: dict) -> np.ndarray:
    """(n, 2) ``(kp, kv)`` of the servos: critically damped at :data:`SERVO_HZ` on the joint's
    inertia (mass-matrix diagonal at the record's mean posture plus armature), zero on the
    torque-driven joints."""
    g = np.zeros((rec.n, 2))
    if rec.driven.all():
        return g
    Mdiag = np.diag(robot.mass_matrix(rec.q.mean(0))) + np.asarray(native["armature"])
    w = 2 * np.pi * SERVO_HZ
    for k in np.flatnonzero(~rec.driven):
        g[k] = (Mdiag[k] * w * w, 2 * Mdiag[k] * w)
    return g


class Replayer:
    """Rollouts of one record's windows for one compiled model (see the module docstring)."""

    def __init__(self, sm, robot, rec: Record, nthread: int = 1):
        import mujoco

        self.sm, self.rec = sm, rec
        self.sub = substeps(rec.dt)
        self.h = rec.dt / self.sub
        self.gains = servo_gains(sm, robot, rec, sm.given)
        self.nthread = nthread
        self._mj = mujoco

    def model(self, native: dict, nuserdata: int = 0):
        """The record's ``MjModel`` with these native parameters."""
        return self.sm.compile(self.h, self.rec.payload, self.gains, native, nuserdata)

    def windows(self, H: float, mask: np.ndarray, max_windows: int | None = None) -> np.ndarray:
        """Start samples of the consecutive windows of ``H`` seconds that lie in ``mask`` (T,): each
        run of True samples ``[a, b]`` is tiled from ``a`` by windows of ``L + 1`` samples
        (``L = H / dt``) sharing their end points; at most ``max_windows``, evenly spaced."""
        L = max(1, int(round(H / self.rec.dt)))
        m = np.asarray(mask, bool)
        edge = np.diff(np.r_[0, m.astype(np.int8), 0])
        a, b = np.flatnonzero(edge == 1), np.flatnonzero(edge == -1) - 1
        starts = [np.arange(s0, e0 - L + 1, L) for s0, e0 in zip(a, b) if e0 - s0 >= L]
        starts = np.concatenate(starts).astype(int) if starts else np.zeros(0, int)
        if max_windows is not None and starts.size > max_windows:
            starts = starts[np.linspace(0, starts.size - 1, max_windows).round().astype(int)]
        return starts

    @property
    def history_steps(self) -> int:
        """Samples of :data:`HISTORY_S`."""
        return max(1, int(round(HISTORY_S / self.rec.dt)))

    def history(self, starts: np.ndarray, nv: int) -> np.ndarray:
        """(B, :data:`HISTORY_S` / dt, nv) measured velocities before each start, in dof order
        (samples before the record's first repeat it): what the presliding state starts from."""
        M = self.history_steps
        idx = np.maximum(starts[:, None] - M + np.arange(M)[None, :], 0)
        out = np.zeros((starts.size, M, nv))
        out[:, :, self.sm.dof] = self.rec.qd[idx]
        return out

    def _init(self, m, starts):
        mj = self._mj
        d = mj.MjData(m)
        spec = mj.mjtState.mjSTATE_FULLPHYSICS
        x0 = np.empty((starts.size, mj.mj_stateSize(m, spec)))
        for b, k in enumerate(starts):
            d.time = 0.0
            d.qpos[self.sm.qpos_adr] = self.rec.q[k]
            d.qvel[self.sm.dof] = self.rec.qd[k]
            mj.mj_getState(m, d, x0[b], spec)
        return x0

    def _controls(self, m, starts, L):
        """(B, L*sub, nu + nv) servo targets and logged torques (zero-order hold)."""
        rec, sub = self.rec, self.sub
        idx = starts[:, None] + np.arange(L)[None, :]           # sample held over each step
        nu, nv = m.nu, m.nv
        u = np.zeros((starts.size, L, nu + nv))
        u[:, :, :self.sm.n] = rec.q[idx]
        u[:, :, nu + self.sm.dof] = np.where(rec.driven, rec.tau[idx], 0.0)
        return np.repeat(u, sub, axis=1) if sub > 1 else u

    def simulate(self, native: dict, starts: np.ndarray, L: int, effects: dict | None = None):
        """Simulated ``(q, qd)``, each (B, L, n), at the L samples after each start."""
        return simulate_sets([(self, starts, L)], [(native, effects)], self.nthread)[0][0]

    def errors(self, native: dict, H: float, mask: np.ndarray, effects: dict | None = None,
               max_windows: int | None = None):
        """Per-sample errors of the windows of ``H`` in ``mask``: ``(eq, ev, regimes)`` with eq, ev
        (B*L, n) position and velocity errors of the scored joints and the matching regime masks;
        None when no window fits."""
        starts = self.windows(H, mask, max_windows)
        if starts.size == 0:
            return None
        L = max(1, int(round(H / self.rec.dt)))
        q, qd = self.simulate(native, starts, L, effects)
        idx = starts[:, None] + np.arange(1, L + 1)[None, :]
        eq = (q - self.rec.q[idx]).reshape(-1, self.rec.n)
        ev = (qd - self.rec.qd[idx]).reshape(-1, self.rec.n)
        reg = {r: v[idx].reshape(-1, self.rec.n) for r, v in self.rec.regimes.items()}
        return eq, ev, reg, starts


def _active(effects) -> bool:
    return effects is not None and any(jt.get("effects") for jt in effects.get("joints", ()))


def _presliding(effects) -> bool:
    return any(e["effect"] == "presliding" for jt in effects.get("joints", ()) for e in jt.get("effects", ()))


def simulate_sets(items, sets, nthread: int = 1) -> list:
    """Windows of several records simulated for several parameter sets in as few ``mujoco.rollout``
    calls as possible: one call for every window of every record under every set (a list of
    models, one per batch row), or, where a set carries effects, one call per step over all rows.

    Parameters
    ----------
    items : list of (Replayer, starts, L)
        The windows: start samples and length (samples) per record.
    sets : list of (native, effects)
        Parameter sets: native parameters (name -> (n,)) and an effects document or None.
    nthread : int
        ``mujoco.rollout`` threads.

    Returns
    -------
    list (per set) of list (per item) of ``(q, qd)``, each (B, L, n); None for an item without
    windows.
    """
    import mujoco as mj
    from mujoco import rollout

    out = [[None] * len(items) for _ in sets]
    groups = {}
    for i, (rp, starts, L) in enumerate(items):
        if starts.size:
            groups.setdefault(L * rp.sub, []).append(i)
    for N, idx in groups.items():
        models, x0s, us, rows = [], [], [], []
        b0 = 0
        prep = {}
        for p, (native, doc) in enumerate(sets):
            for i in idx:
                rp, starts, L = items[i]
                m = rp.model(native)
                if i not in prep:
                    prep[i] = (rp._init(m, starts), rp._controls(m, starts, L))
                x0, u = prep[i]
                models += [m] * starts.size
                x0s.append(x0)
                us.append(u)
                rows.append((p, i, slice(b0, b0 + starts.size)))
                b0 += starts.size
        x0, u = np.concatenate(x0s), np.concatenate(us)
        m0 = models[0]
        nq, nv, nu = m0.nq, m0.nv, m0.nu
        cspec = mj.mjtState.mjSTATE_CTRL | mj.mjtState.mjSTATE_QFRC_APPLIED
        datas = [mj.MjData(m0) for _ in range(max(1, nthread))]
        stepped = any(_active(doc) for _, doc in sets)
        with rollout.Rollout(nthread=nthread if nthread > 1 else 0) as ro:
            if not stepped:
                state, _ = ro.rollout(models, datas, x0, u, control_spec=cspec)
            else:
                state = _stepped(ro, models, datas, x0, u, cspec, items, sets, rows, nq, nv, nu)
        for p, i, sl in rows:
            rp = items[i][0]
            st = state[sl, rp.sub - 1::rp.sub]
            out[p][i] = (st[:, :, 1:1 + nq][:, :, rp.sm.qpos_adr], st[:, :, 1 + nq:1 + nq + nv][:, :, rp.sm.dof])
    return out


def _stepped(ro, models, datas, x0, u, cspec, items, sets, rows, nq, nv, nu):
    """One step at a time over all rows, each set's effect torque added to ``qfrc_applied``
    (:func:`ident.sim2real.effects_runtime.torque`, the exported callback's arithmetic)."""
    B, N = u.shape[:2]
    ns = x0.shape[1]
    out = np.empty((B, N, ns))
    x = np.array(x0, float, order="C")
    z = fx.initial_state(None, x[:, 1 + nq:1 + nq + nv])
    uk = np.empty((B, 1, nu + nv))
    st = np.empty((B, 1, ns))
    sens = np.empty((B, 1, 0))
    act = []
    for p, i, sl in rows:
        if _active(sets[p][1]):
            rp, starts, _ = items[i]
            if _presliding(sets[p][1]):        # the bristles' state from the measured motion before
                z[sl] = fx.initial_state(sets[p][1], x[sl, 1 + nq:1 + nq + nv],
                                         rp.history(starts, nv), rp.rec.dt)
            nat = np.zeros((3, nv))          # the model's dof_armature, dof_damping, dof_frictionloss
            for r, key in enumerate(("armature", "damping", "frictionloss")):
                nat[r, rp.sm.dof] = sets[p][0][key]
            act.append((sl, sets[p][1], rp, nat))
    for k in range(N):
        uk[:, 0, :] = u[:, k]
        for sl, doc, rp, nat in act:
            qv = np.zeros((sl.stop - sl.start, nv))
            qv[:, rp.sm.dof] = x[sl, 1:1 + nq][:, rp.sm.qpos_adr]
            tau, z[sl] = fx.torque(doc, qv, x[sl, 1 + nq:1 + nq + nv], u[sl, k, nu:], z[sl], rp.h, nat)
            uk[sl, 0, nu:] += tau
        ro.rollout(models, datas, x, uk, control_spec=cspec, skip_checks=True, nstep=1, state=st,
                   sensordata=sens)
        x[:] = st[:, 0]
        out[:, k] = x
    return out
