"""Fits of the MuJoCo-native joint parameters and of the named effects on training data.

Inverse-dynamics least squares (the start): per joint ``j`` and training sample ``k``

    tau_jk - ID_j(q_k, qd_k, qdd_k) = a_j qdd_jk + b_j qd_jk + c_j s(qd_jk) - sum_e F_e(x_k) theta_e

with ``ID`` MuJoCo's inverse dynamics of the record's model without native friction or armature
(``mj_inverse``), ``a, b, c`` armature, damping and frictionloss (bounded below by 0), ``s`` the
smooth sign of :mod:`ident.sim2real.effects_runtime` and ``F_e`` the named effect's basis
(:func:`ident.sim2real.effects_runtime.features`: ``F_e theta_e`` is the torque the effect puts on
the joint, so the drive carries minus it) whose shape parameters (Stribeck velocity and exponent,
viscous power, ripple order, presliding length, load saturation torque) are tried on a grid and
ranked by the training rollout error. The refinement (:func:`refine`) then minimises the training rollout
position error at the 0.5 s horizon over the native parameters, the amplitudes and the continuous
shape parameters (bounded Levenberg-Marquardt, finite differences batched in one rollout call).
"""
from __future__ import annotations

import numpy as np
from scipy.optimize import lsq_linear

from ident.sim2real import effects_runtime as fx
from ident.sim2real.model import NATIVE
from ident.sim2real.replay import simulate_sets

#: smooth-sign width as a fraction of the joint's speed scale (95th percentile of |qd|)
EPS_FRACTION = 0.005
#: training rows slower than this many smooth-sign widths are left out: at rest the torque is
#: whatever static friction holds, which no sign function predicts
REST_WIDTHS = 2.0
#: effects whose amplitudes are physical only when >= 0 (a friction excess, a presliding force,
#: a friction growing with load)
NONNEGATIVE = ("stribeck", "presliding", "load_dependent")
#: at most this many training samples per record enter the least squares
MAX_ROWS = 12000


def eps_of(qd: np.ndarray) -> np.ndarray:
    """(n,) smooth-sign widths: :data:`EPS_FRACTION` of each joint's speed scale (rad/s)."""
    return np.maximum(EPS_FRACTION * np.percentile(np.abs(qd), 95, axis=0), 1e-4)


def rigid_torque(rp, rows: np.ndarray) -> np.ndarray:
    """(len(rows), n) MuJoCo inverse dynamics of the record at ``rows`` without armature, damping
    or frictionloss (``mj_inverse``; ``qfrc_inverse`` of the chain's dofs)."""
    import mujoco

    sm, rec = rp.sm, rp.rec
    zero = {k: np.zeros(sm.n) for k in NATIVE}
    m = rp.model(zero)
    m.opt.disableflags |= int(mujoco.mjtDisableBit.mjDSBL_ACTUATION) | int(mujoco.mjtDisableBit.mjDSBL_LIMIT)
    d = mujoco.MjData(m)
    out = np.empty((rows.size, sm.n))
    for i, k in enumerate(rows):
        d.qpos[sm.qpos_adr] = rec.q[k]
        d.qvel[sm.dof] = rec.qd[k]
        d.qacc[:] = 0.0
        d.qacc[sm.dof] = rec.qdd[k]
        mujoco.mj_inverse(m, d)
        out[i] = d.qfrc_inverse[sm.dof]
    return out


def presliding_states(qd: np.ndarray, delta: np.ndarray, h: float) -> np.ndarray:
    """(T, len(delta)) Dahl states along a measured velocity (T,) for each presliding length
    (:func:`ident.sim2real.effects_runtime.bristle_step`, one step per sample)."""
    z = np.empty((qd.size, delta.size))
    zk = np.full(delta.size, np.sign(qd[0]))
    for k in range(qd.size):
        z[k] = zk
        zk = fx.bristle_step(zk, qd[k], delta, h)
    return z


def shape_grid(effect: str, drive=None, load_scale: float = 1.0) -> list:
    """Candidate shape parameters of an effect (the grid the training residual chooses on);
    ``load_scale``: the joint's transmitted-torque scale (N m), for ``load_dependent``'s saturation
    torque ``T`` (the last, 1e3 scales, is linear in practice)."""
    if effect == "load_dependent":
        return [{"T": float(f * load_scale)} for f in (0.25, 0.5, 1.0, 2.0, 1e3)]
    if effect == "stribeck":
        return [{"Vs": float(v), "d": float(d)} for v in np.geomspace(0.01, 0.8, 14) for d in (1.0, 2.0)]
    if effect == "nonlinear_viscous":
        return [{"p": p} for p in (1.5, 2.0, 3.0)]     # p > 1: no negative slope at rest
    if effect == "position_ripple":
        ks = set(range(1, 41))
        if drive is not None:
            g = abs(float(drive.gear_ratio))
            ks |= {g, 2 * g} if g > 1 else set()
            ks |= {float(o) for o in (drive.extra or {}).get("ripple_orders", [])}
        return [{"k": float(k)} for k in sorted(ks)]
    if effect == "presliding":
        return [{"delta": float(x)} for x in np.geomspace(5e-5, 2e-2, 14)]
    return [{}]


def speed_weights(qd: np.ndarray, eps: float, n_bins: int = 12) -> np.ndarray:
    """Row weights that give every speed band (log-spaced bins of |qd| above the rest cut) the
    same total weight: a record spends most of its time fast, and the low-speed effects
    (Stribeck, presliding) would otherwise weigh little."""
    a = np.log(np.maximum(np.abs(qd), eps))
    edges = np.linspace(a.min(), a.max() + 1e-9, n_bins + 1)
    b = np.clip(np.digitize(a, edges) - 1, 0, n_bins - 1)
    cnt = np.bincount(b, minlength=n_bins).astype(float)
    w = 1.0 / np.sqrt(cnt[b])
    return w / np.sqrt(np.mean(w ** 2))


class TrainingSet:
    """The training rows of every record: measured state, torque and the rigid-body torque."""

    def __init__(self, replayers, masks):
        self.parts = []
        for rp, mask in zip(replayers, masks):
            rows = np.flatnonzero(mask)
            if rows.size == 0:
                continue
            # presliding needs every sample in order: the states are computed on the full record
            stride = max(1, int(np.ceil(rows.size / MAX_ROWS)))
            rows = rows[::stride]
            self.parts.append((rp, rows, rigid_torque(rp, rows)))
        qd = np.concatenate([rp.rec.qd[rows] for rp, rows, _ in self.parts])
        self.eps = eps_of(qd)

    def columns(self, j: int, effect: str | None, shape: dict, drive=None):
        """(y, A): the residual torque of joint ``j`` and its regressor, on the training rows of
        the records that drive the joint by its logged torque (a held joint's torque is its
        servo's or brake's, no friction measurement)."""
        ys, As = [], []
        ncol = 3 + (len(fx.amplitude_names(effect)) if effect is not None else 0)
        for rp, rows, tid in self.parts:
            rec = rp.rec
            if not rec.driven[j]:
                continue
            q, qd, qdd = rec.q[rows, j], rec.qd[rows, j], rec.qdd[rows, j]
            cols = [qdd, qd, fx.smooth_sign(qd, self.eps[j])]
            if effect is not None:
                z = None
                if effect == "presliding":
                    z = presliding_states(rec.qd[:, j], np.array([shape["delta"]]), rp.h * rp.sub)[rows, 0]
                # load_dependent: the transmitted torque is the link's rigid-body torque (the
                # simulation's estimate of it: effects_runtime.transmitted)
                F = fx.features(effect, shape, q, qd, tid[:, j], z, self.eps[j])
                # the drive overcomes the friction: the effect's torque on the joint is F theta,
                # so the drive torque carries -F theta (the native columns are +qdd, +qd, +s)
                cols += list((-F).T)
            ys.append(rec.tau[rows, j] - tid[:, j])
            As.append(np.stack(cols, 1))
        if not ys:
            return np.zeros(0), np.zeros((0, ncol))
        return np.concatenate(ys), np.concatenate(As)

    def moving_rows(self, j: int) -> int:
        """How many training rows of joint ``j`` the least squares uses: finite, of a record that
        drives the joint, faster than :data:`REST_WIDTHS` smooth-sign widths."""
        y, A = self.columns(j, None, {})
        return int(np.count_nonzero(np.isfinite(y) & np.isfinite(A).all(1)
                                    & (np.abs(A[:, 1]) > REST_WIDTHS * self.eps[j])))

    def candidates(self, j: int, effect: str | None = None, drive=None) -> list:
        """Least-squares native parameters (and the effect's amplitudes) of joint ``j`` for every
        shape of the effect's grid (:func:`shape_grid`), best training torque residual first;
        empty where the joint has no moving training row (:meth:`moving_rows`)."""
        out = []
        if self.moving_rows(j) == 0:
            return out
        scale = max(float(np.percentile(np.abs(np.concatenate([t[:, j] for _, _, t in self.parts])), 95)), 1e-6)
        for shape in (shape_grid(effect, drive, scale) if effect else [{}]):
            y, A = self.columns(j, effect, shape, drive)
            ok = np.isfinite(y) & np.isfinite(A).all(1) & (np.abs(A[:, 1]) > REST_WIDTHS * self.eps[j])
            y, A = y[ok], A[ok]
            lb = np.r_[[0.0, 0.0, 0.0], np.full(A.shape[1] - 3, -np.inf)]
            if effect in NONNEGATIVE:
                lb[3:] = 0.0
            w = speed_weights(A[:, 1], self.eps[j])
            scale = np.maximum(np.sqrt((A ** 2).mean(0)), 1e-12)
            sol = lsq_linear(A / scale * w[:, None], y * w, bounds=(lb, np.full(A.shape[1], np.inf)),
                             method="bvls")
            x = sol.x / scale
            r = {"native": dict(zip(NATIVE, map(float, x[:3]))), "eps": float(self.eps[j]),
                 "rms": float(np.sqrt(np.mean((y - A @ x) ** 2)))}
            if effect:
                r["effect"] = {"effect": effect, "shape": shape,
                               "amplitudes": dict(zip(fx.amplitude_names(effect), map(float, x[3:])))}
            out.append(r)
        return sorted(out, key=lambda r: r["rms"])

    def fit_joint(self, j: int, effect: str | None = None, drive=None) -> dict | None:
        """The candidate of :meth:`candidates` with the smallest training torque residual (None:
        the joint has no moving training row)."""
        c = self.candidates(j, effect, drive)
        return c[0] if c else None


def fit_native(ts: TrainingSet, n: int, effects_by_joint: dict | None = None, drives=(),
               start: dict | None = None) -> tuple:
    """Native parameters of every joint and the effects document (:mod:`effects_runtime`).

    A joint without a moving training row of a record that drives it (held by the servo in every
    training record, or never faster than the rest cut) keeps its ``start`` value (the given
    model's; zero without ``start``) and its ``per_joint`` entry is None."""
    native = {k: (np.array(start[k], float) if start is not None else np.zeros(n)) for k in NATIVE}
    doc = {"joints": []}
    per_joint = {}
    for j in range(n):
        names = (effects_by_joint or {}).get(j + 1, ())
        eff = names[0] if names else None
        r = ts.fit_joint(j, eff, drives[j] if j < len(drives) else None)
        per_joint[j + 1] = r
        if r is None:
            continue
        for k in NATIVE:
            native[k][j] = r["native"][k]
        if eff:
            doc["joints"].append({"joint": j + 1, "eps": r["eps"], "effects": [r["effect"]]})
    return native, doc, per_joint


#: horizon (s) of the training rollouts, most windows per record in the refinement and in the
#: ranking of an effect's shapes, and the stride (samples) of the position errors they keep
SELECT_HORIZON = 0.5
TRAIN_WINDOWS = 32
RANK_WINDOWS = 16
RES_STRIDE = 5
#: Levenberg-Marquardt iterations of the rollout refinement and the damping factors each tries
REFINE_ITERS = 5
LM_LAMBDAS = (1e-2, 1e-1, 1.0)
#: the effects' shape parameters the refinement frees: (log or lin, lower, upper)
SHAPE_FREE = {"stribeck": {"Vs": ("log", 1e-3, 5.0), "d": ("lin", 0.4, 3.0)},
              "nonlinear_viscous": {"p": ("lin", 1.05, 4.0)},
              "presliding": {"delta": ("log", 1e-6, 0.1)},
              "load_dependent": {"T": ("log", 1e-3, 1e7)}}


class Rollouts:
    """Training windows of :data:`SELECT_HORIZON` (at most ``max_windows`` per record, evenly
    spaced) and their measured angles; :meth:`residuals` simulates any number of parameter sets
    in one batched call (:func:`ident.sim2real.replay.simulate_sets`)."""

    def __init__(self, replayers, masks, max_windows=TRAIN_WINDOWS, nthread=1, H=SELECT_HORIZON):
        self.items, self.meas, self.nthread = [], [], nthread
        for rp, m in zip(replayers, masks):
            starts = rp.windows(H, m, max_windows)
            if starts.size == 0:
                continue
            L = max(1, int(round(H / rp.rec.dt)))
            idx = starts[:, None] + np.arange(1, L + 1)[None, :]
            self.items.append((rp, starts, L))
            self.meas.append(rp.rec.q[idx][:, RES_STRIDE - 1::RES_STRIDE])
        self.n = replayers[0].rec.n if replayers else 0

    def residuals(self, sets) -> list:
        """Per set, the (M, n) position errors ``q_sim - q_meas`` of every window, every
        :data:`RES_STRIDE`-th sample (non-finite values, a diverged rollout, set to 1 rad)."""
        sims = simulate_sets(self.items, sets, self.nthread)
        out = []
        for per in sims:
            r = np.concatenate([(q[:, RES_STRIDE - 1::RES_STRIDE] - mq).reshape(-1, self.n)
                                for (q, _), mq in zip(per, self.meas)])
            out.append(np.where(np.isfinite(r), r, 1.0))
        return out

    def rms(self, sets) -> np.ndarray:
        """(len(sets), n) position RMS per set and joint."""
        return np.array([np.sqrt(np.mean(r ** 2, axis=0)) for r in self.residuals(sets)])


class _Layout:
    """Joint ``j``'s free parameters in the refinement: its native parameters, its effect's
    amplitudes and free shape parameters (:data:`SHAPE_FREE`), in internal coordinates (log for the
    log-scaled shapes)."""

    def __init__(self, j, native, eff):
        self.j, self.eff = j, eff
        self.keys = [("native", k) for k in NATIVE]
        x = [float(native[k][j]) for k in NATIVE]
        lb, ub = [0.0] * 3, [np.inf] * 3
        if eff is not None:
            for nm in fx.amplitude_names(eff["effect"]):
                self.keys.append(("amp", nm))
                x.append(float(eff["amplitudes"][nm]))
                lb.append(0.0 if eff["effect"] in NONNEGATIVE else -np.inf)
                ub.append(np.inf)
            for nm, (kind, lo, hi) in SHAPE_FREE.get(eff["effect"], {}).items():
                self.keys.append((kind, nm))
                v = float(np.clip(eff["shape"][nm], lo, hi))
                x.append(np.log(v) if kind == "log" else v)
                lb.append(np.log(lo) if kind == "log" else lo)
                ub.append(np.log(hi) if kind == "log" else hi)
        self.x0 = np.maximum(np.array(x, float), np.array(lb))
        self.lb, self.ub = np.array(lb), np.array(ub)
        mag = np.abs(self.x0)
        lin = np.array([k[0] in ("native", "amp") for k in self.keys])
        floor = 1e-3 * max(mag[lin].max(), 1e-6)
        # finite-difference steps: 1 % of the value (linear), 0.02 in log or in the exponent
        self.step = np.where(lin, 1e-2 * np.maximum(mag, floor), 2e-2)

    def apply(self, x, native, doc, eps):
        """Write ``x`` into ``native`` (in place) and append the joint's effect to ``doc``."""
        e = None
        for (kind, nm), v in zip(self.keys, x):
            if kind == "native":
                native[nm][self.j] = v
        if self.eff is not None:
            shape = dict(self.eff["shape"])
            amps = {}
            for (kind, nm), v in zip(self.keys, x):
                if kind == "amp":
                    amps[nm] = float(v)
                elif kind == "log":
                    shape[nm] = float(np.exp(v))
                elif kind == "lin":
                    shape[nm] = float(v)
            e = {"effect": self.eff["effect"], "shape": shape, "amplitudes": amps}
            doc["joints"].append({"joint": self.j + 1, "dof": self.dof, "eps": float(eps), "effects": [e]})
        return e


def refine(ro: Rollouts, native: dict, sm, joints, effects: dict | None = None, eps=None,
           iters: int = REFINE_ITERS) -> tuple:
    """The native parameters of ``joints`` (and their effects' amplitudes and free shapes)
    refined on the training rollouts: Levenberg-Marquardt on the position errors of each joint over
    the windows of ``ro``, all joints at once.

    Each iteration is two batched simulations: the current point and one finite-difference column
    per parameter slot (slot k of every joint perturbed together: the Jacobian is taken
    block-diagonal, joint j's errors against joint j's parameters), then the damped Gauss-Newton
    step of every joint for each factor of :data:`LM_LAMBDAS`; each joint keeps the factor with its
    smallest error (or stays) and the best point seen is returned.

    Returns
    -------
    native : dict
    effects : dict
        joint (0-based) -> the refined effect dict (shape and amplitudes).
    rms : numpy.ndarray
        (n,) training rollout position RMS of the returned point.
    """
    effects = effects or {}
    eps = eps if eps is not None else np.full(sm.n, 1e-2)
    lay = {j: _Layout(j, native, effects.get(j)) for j in joints}
    for j, lo in lay.items():
        lo.dof = int(sm.dof[j])
    X = {j: lo.x0.copy() for j, lo in lay.items()}

    def make(Xd):
        nat = {k: np.array(v, float) for k, v in native.items()}
        doc = {"joints": []}
        effs = {j: lay[j].apply(Xd[j], nat, doc, eps[j]) for j in lay}
        return nat, (doc if doc["joints"] else None), effs

    K = max(len(lo.x0) for lo in lay.values())
    best = {j: (np.inf, X[j].copy()) for j in lay}
    for _ in range(iters):
        sets = [make(X)[:2]]
        h = {j: np.where(X[j] + lo.step <= lo.ub, lo.step, -lo.step) for j, lo in lay.items()}
        for k in range(K):
            Xp = {}
            for j in lay:
                x = X[j].copy()
                if k < x.size:
                    x[k] += h[j][k]
                Xp[j] = x
            sets.append(make(Xp)[:2])
        R = ro.residuals(sets)
        r0 = R[0]
        steps = {}
        for j, lo in lay.items():
            c = float(np.sum(r0[:, j] ** 2))
            if c < best[j][0]:
                best[j] = (c, X[j].copy())
            nk = X[j].size
            Jm = np.stack([(R[1 + k][:, j] - r0[:, j]) / h[j][k] for k in range(nk)], 1)
            JtJ, g = Jm.T @ Jm, Jm.T @ r0[:, j]
            D = np.diag(np.maximum(np.diag(JtJ), 1e-12 * max(np.trace(JtJ), 1e-30)))
            steps[j] = []
            for lam in LM_LAMBDAS:
                try:
                    dx = -np.linalg.solve(JtJ + lam * D, g)
                except np.linalg.LinAlgError:
                    dx = np.zeros(nk)
                steps[j].append(np.clip(X[j] + dx, lo.lb, lo.ub))
        trials = [make({j: steps[j][i] for j in lay})[:2] for i in range(len(LM_LAMBDAS))]
        C = np.array([np.sum(r ** 2, axis=0) for r in ro.residuals(trials)])
        for j in lay:
            i = int(np.argmin(C[:, j]))
            if C[i, j] < best[j][0]:
                best[j] = (float(C[i, j]), steps[j][i].copy())
            X[j] = best[j][1].copy()
    nat, _, effs = make({j: best[j][1] for j in lay})
    rms = ro.rms([make({j: best[j][1] for j in lay})[:2]])[0]
    return nat, effs, rms


def fit_effects(ts: TrainingSet, ro: Rollouts, ro_rank: Rollouts, native: dict, base_rms: np.ndarray,
                named: dict, sm, drives=()) -> tuple:
    """The native parameters refitted with each joint's named effect: the least-squares fits of the
    effect's shape grid (:meth:`TrainingSet.candidates`) ranked by their training rollout error
    (all candidates of all joints in one batched simulation), the best refined on the rollouts
    (:func:`refine`: native parameters, amplitudes and free shape parameters together); a joint keeps
    the effect-free fit (``native``) where its effect does not lower its training rollout error.

    Returns
    -------
    native_fx : dict
        name -> (n,) native parameters.
    doc : dict
        The effects document (:mod:`ident.sim2real.effects_runtime`).
    choice : dict
        joint -> {effect, kept, training_rollout_rms: {effect_free, with_effect}, shapes_tried, shape}.
    """
    native_fx = {k: np.array(v, float) for k, v in native.items()}
    doc = {"joints": []}
    choice = {}
    joints = [j1 - 1 for j1 in sorted(named)]
    if not joints:
        return native_fx, doc, choice
    cands = {j: ts.candidates(j, named[j + 1][0], drives[j] if j < len(drives) else None) for j in joints}
    nset = max(len(c) for c in cands.values())
    sets = []
    for s in range(nset):
        nat = {k: np.array(v, float) for k, v in native.items()}
        d = {"joints": []}
        for j in joints:
            c = cands[j][min(s, len(cands[j]) - 1)]
            for k in NATIVE:
                nat[k][j] = c["native"][k]
            d["joints"].append({"joint": j + 1, "dof": int(sm.dof[j]), "eps": c["eps"], "effects": [c["effect"]]})
        sets.append((nat, d))
    E = ro_rank.rms(sets)
    start = {k: np.array(v, float) for k, v in native.items()}
    effs, eps = {}, np.full(sm.n, 1e-2)
    for j in joints:
        s = int(np.argmin([E[i, j] for i in range(min(nset, len(cands[j])))]))
        c = cands[j][s]
        for k in NATIVE:
            start[k][j] = c["native"][k]
        effs[j], eps[j] = c["effect"], c["eps"]
    nat, effs, rms = refine(ro, start, sm, joints, effs, eps)
    for j in joints:
        kept = bool(rms[j] < base_rms[j])
        choice[j + 1] = {"effect": named[j + 1][0], "kept": kept, "shapes_tried": len(cands[j]),
                         "training_rollout_rms": {"effect_free": float(base_rms[j]), "with_effect": float(rms[j])},
                         "shape": effs[j]["shape"]}
        if kept:
            for k in NATIVE:
                native_fx[k][j] = nat[k][j]
            doc["joints"].append({"joint": j + 1, "dof": int(sm.dof[j]), "name": sm.names[j],
                                  "eps": float(eps[j]), "effects": [effs[j]]})
    return native_fx, doc, choice
