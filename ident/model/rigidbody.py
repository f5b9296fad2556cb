"""Multi-joint identification of a continuous record: the URDF's rigid-body base parameters
jointly with per-joint friction, torque offsets, actuator inertias and coupled motors.

Model, per sample and URDF joint j (URDF coordinates, link side, SI)::

    tau_j = Y_b(q, qd, qdd)_j beta + f_j(qd_j) + o_j + Ia_j qdd_j
            + sum_k (C^-T)_jk [ f_m,k(u_k) + Iam_k udd_k ]

``Y_b``: the base columns of the joint torque regressor (:mod:`ident.model.regressor`, all
samples at once); ``f_j``: a friction model of the registry (:data:`ident.friction.MODELS`);
``o_j`` a torque offset; ``Ia_j`` an actuator (armature) inertia; for every *coupled* log
coordinate ``k`` (a row of ``C^-1`` with more than one non-zero: a motor that drives several
URDF joints, like the TX40's wrist motor 6), a Coulomb + viscous motor friction ``f_m,k`` on the
motor's velocity ``u_k = (C^-1 qd)_k`` and a motor inertia ``Iam_k``, mapped to the joints by
``C^-T`` (FORMAT.md "Coupled joints").

Estimation (Gautier's IDIM-WLS): rows of joint j are weighted by ``1/sigma_j``, the residual
standard deviation of an ordinary least-squares pass; rows where ``|qd_j|`` is below
``v_zero`` (a fraction of the joint's speed range) are left out, because at rest the static
friction is anywhere within the breakaway level and no velocity estimate gives the sign of a
reversal exactly. Friction models linear in their parameters (``cv``) are solved in the same
linear system; the others alternate: the linear part with the friction fixed, then per joint
:func:`ident.friction.fit.fit_friction` on the joint's remaining torque with offset and
armature as extra columns, up to ``n_iter`` times (fewer once no joint's friction torque moves
by 1e-4 of its torque level); their row weights come from the Coulomb + viscous pass.
Held-out RMS: contiguous segments of the record (``folds``), each predicted by a fit on the
others (leave-one-segment-out).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ident.friction.base import CoulombViscous
from ident.model.regressor import BaseParameters, ChainDynamics, base_parameters

LINEAR_MODELS = ("cv",)
_PREPARED: dict = {}       # the last record's model-independent design (RigidBodyIdentifier._prepared)


@dataclass(frozen=True, eq=False)
class RigidBodyFit:
    """One friction model's joint fit of a record, with its diagnostics."""

    model: str
    joints: dict                 # "j" -> {"params", "stderr", "rms", "heldout_rms", ...}
    beta: np.ndarray             # base parameters
    base_names: tuple
    offsets: np.ndarray          # (n,)
    armature: np.ndarray         # (n,)
    motors: dict                 # coupled log coordinate "k" -> {"fs", "fv", "Ia"}
    rms: np.ndarray              # (n,) in-sample residual RMS (rows used)
    heldout_rms: np.ndarray      # (n,) leave-one-segment-out
    sigma: np.ndarray            # (n,) row weights 1/sigma
    v_zero: np.ndarray           # (n,)
    n_samples: int
    method: str
    notes: tuple = ()
    diagnostics: dict = field(default_factory=dict)

    def to_dict(self) -> dict:
        return {"model": self.model, "joints": self.joints, "method": self.method,
                "base_parameters": dict(zip(self.base_names, map(float, self.beta))),
                "offsets": self.offsets.tolist(),
                "armature": [float(a) if np.isfinite(a) else None for a in self.armature],
                "coupled_motors": self.motors, "rms": self.rms.tolist(),
                "heldout_rms": self.heldout_rms.tolist(), "sigma": self.sigma.tolist(),
                "v_zero": self.v_zero.tolist(), "n_samples": self.n_samples,
                "notes": list(self.notes), **self.diagnostics}


def _drop_absorbed(A, names, nb, tol: float = 1e-6):
    """Drop the extra columns (offsets, armatures, motor terms) that the base columns already
    span on these data (e.g. the armature of a joint whose link inertia about its own axis is a
    base parameter of its own: Ia_1 with ZZ_1, Ia_2 with ZZ_2 when axis 1 is perpendicular to
    axis 2): they are merged into the base parameters and reported."""
    T, n, p = A.shape
    A2 = A.reshape(T * n, p)
    step = max(1, T // 4000)                        # a subsample decides collinearity
    S = A.reshape(T, n, p)[::step].reshape(-1, p)
    B = S[:, :nb]
    cn = np.linalg.norm(B, axis=0)
    Bn = B / np.where(cn > 0, cn, 1.0)
    Q, R = np.linalg.qr(Bn)
    keep, dropped = list(range(nb)), []
    for k in range(nb, p):
        a = S[:, k]
        na = float(np.linalg.norm(a))
        if na == 0:
            dropped.append(names[k])
            continue
        r = a - Q @ (Q.T @ a)
        if np.linalg.norm(r) < tol * na:
            dropped.append(names[k])
        else:
            keep.append(k)
    return A2.reshape(T, n, p)[:, :, keep], tuple(names[k] for k in keep), tuple(dropped)


class RigidBodyIdentifier:
    """Settings in the constructor, learning in :meth:`fit` (see the module docstring).

    ``model``: a friction model name of the registry; ``v_zero_frac``: rows slower than this
    fraction of the joint's 99th-percentile speed are left out; ``armature``/``offset``:
    include those columns; ``coupled_motors``: friction and inertia of coupled motors;
    ``n_iter``: alternations for nonlinear friction; ``folds``: contiguous held-out segments
    (0: none); ``n_starts``/``seed``: multi-start of the nonlinear friction fits.
    """

    def __init__(self, chain: ChainDynamics, base: BaseParameters | None = None, model: str = "cv",
                 v_zero_frac: float = 0.02, armature: bool = True, offset: bool = True,
                 coupled_motors: bool = True, n_iter: int = 3, folds: int = 5, n_starts: int = 4,
                 seed: int = 0, lower=None, upper=None):
        from ident.friction import MODELS

        if model not in MODELS:
            raise KeyError(f"unknown friction model {model!r} (known: {', '.join(MODELS)})")
        self.chain = chain
        self.base = base if base is not None else base_parameters(chain, lower, upper, seed=seed)
        self.model = model
        self.model_cls = MODELS[model]
        self.v_zero_frac = float(v_zero_frac)
        self.armature = bool(armature)
        self.offset = bool(offset)
        self.coupled_motors = bool(coupled_motors)
        self.n_iter = int(n_iter)
        self.folds = int(folds)
        self.n_starts = int(n_starts)
        self.seed = int(seed)

    # ---- design ----------------------------------------------------------------------------
    def _design(self, rec, Yb):
        """(T, n, p) linear columns without per-joint friction, their names, and the (T, n, 2)
        per-joint cv columns [sign qd_j, qd_j] on joint j."""
        T, n = rec.q.shape
        blocks, names = [Yb], [f"beta_{k}" for k in range(Yb.shape[2])]
        eye = np.eye(n)
        if self.offset:
            blocks.append(np.broadcast_to(eye, (T, n, n)))
            names += [f"offset_{j + 1}" for j in range(n)]
        if self.armature:
            blocks.append(rec.qdd[:, :, None] * eye[None])
            names += [f"Ia_{j + 1}" for j in range(n)]
        motors = self._coupled(rec)
        if motors:
            CiT = np.linalg.inv(rec.coupling).T
            u, udd = rec.qd_log, rec.qdd_log
            for k in motors:
                for nm, sig in (("fs", np.sign(u[:, k])), ("fv", u[:, k]), ("Ia", udd[:, k])):
                    blocks.append((sig[:, None] * CiT[None, :, k])[:, :, None])
                    names.append(f"{nm}m_{k + 1}")
        A = np.concatenate(blocks, axis=2)
        A, names, dropped = _drop_absorbed(A, names, Yb.shape[2])
        self._dropped = dropped
        F = np.zeros((T, n, 2 * n))
        for j in range(n):
            F[:, j, 2 * j] = np.sign(rec.qd[:, j])
            F[:, j, 2 * j + 1] = rec.qd[:, j]
        return A, tuple(names), F

    def _coupled(self, rec) -> list:
        if not self.coupled_motors or not rec.coupled:
            return []
        Ci = np.linalg.inv(rec.coupling)
        return [k for k in range(rec.n) if np.sum(np.abs(Ci[k]) > 1e-12) > 1]

    def _mask(self, rec):
        sp = np.percentile(np.abs(rec.qd), 99, axis=0)
        v0 = self.v_zero_frac * sp
        moving = np.array([j + 1 in rec.moving for j in range(rec.n)])
        M = (np.abs(rec.qd) >= v0[None, :]) & moving[None, :]
        return M, v0

    # ---- fit -------------------------------------------------------------------------------
    def fit(self, rec) -> RigidBodyFit:
        from ident.signals.blas import one_blas_thread

        with one_blas_thread():
            return self._fit(rec)

    def _prepared(self, rec):
        """The model-independent part of a fit (the batched regressor, the design, the row mask
        and the weights of the ordinary least-squares Coulomb + viscous pass), computed once per
        record and shared by the identifiers of every friction model with the same settings."""
        key = (id(rec), id(self.chain), id(self.base), self.offset, self.armature,
               self.coupled_motors, self.v_zero_frac)
        hit = _PREPARED.get("key")
        if hit is not None and hit[0] == key and hit[1] is rec:
            return hit[2]
        T = rec.q.shape[0]
        Y = self.chain.regressor(rec.q, rec.qd, rec.qdd)
        Yb = Y[:, :, self.base.idx]
        del Y
        A, names, F = self._design(rec, Yb)
        del Yb                              # A holds the columns kept (long records: memory)
        M, v0 = self._mask(rec)
        if not M.any():
            raise ValueError(f"trial {rec.trial_id!r}: no joint moves faster than v_zero")
        self._names = names
        # row weights from an ordinary least-squares pass; for the nonlinear models the linear
        # Coulomb + viscous pass gives them (one cheap solve instead of a whole alternation: the
        # per-joint residual levels differ by a fraction of a percent between the models)
        sigma = self._solve(rec, A, F, M, np.ones(T, bool), sigma=None, linear=True)["sigma"]
        prep = (A, names, F, M, v0, sigma, self._dropped)
        _PREPARED["key"] = (key, rec, prep)
        return prep

    def _fit(self, rec) -> RigidBodyFit:
        T, n = rec.q.shape
        A, names, F, M, v0, sigma, self._dropped = self._prepared(rec)
        self._names = names
        train = np.ones(T, bool)
        sol = self._solve(rec, A, F, M, train, sigma=sigma)
        held = np.full(n, np.nan)
        if self.folds >= 2:
            seg = np.minimum(np.arange(T) * self.folds // T, self.folds - 1)
            sse, cnt = np.zeros(n), np.zeros(n)
            for k in range(self.folds):
                tr = seg != k
                s_k = self._solve(rec, A, F, M, tr, sigma=sigma, quick=True, init=sol)
                pred = self._predict(rec, A, F, s_k)
                r = np.where(M & ~tr[:, None], rec.tau - pred, 0.0)
                sse += np.sum(r ** 2, axis=0)
                cnt += np.sum(M & ~tr[:, None], axis=0)
            held = np.where(cnt > 0, np.sqrt(sse / np.maximum(cnt, 1)), np.nan)
        return self._result(rec, sol, names, sigma, v0, held, M)

    def _predict(self, rec, A, F, s):
        pred = np.einsum("tjp,p->tj", A, s["b"])
        if self.model in LINEAR_MODELS:
            pred += np.einsum("tjp,p->tj", F, s["bf"])
        else:
            pred += np.column_stack([f.model.torque(rec.qd[:, j], rec.qdd[:, j], rec.dt)
                                     if f is not None else np.zeros(rec.t.size)
                                     for j, f in enumerate(s["ff"])])
        return pred

    def _wls(self, A2, y, w):
        """Weighted least squares through the column-scaled normal equations (the design is
        tall and thin: T n rows, about 10 n + 4 n columns); rank deficiency is handled by the
        pseudo-inverse of the small Gram matrix."""
        keep = w > 0
        Aw = A2[keep]                       # a copy, weighted in place
        Aw *= w[keep, None]
        yw = y[keep] * w[keep]
        cn = np.linalg.norm(Aw, axis=0)
        cn = np.where(cn > 0, cn, 1.0)
        An = Aw / cn
        G = An.T @ An
        Gi = np.linalg.pinv(G, rcond=1e-12, hermitian=True)
        b = (Gi @ (An.T @ yw)) / cn
        return b, Aw, yw, (cn, Gi)

    @staticmethod
    def _wls_factor(A2, w):
        """The weighted normal equations of ``A2`` (column-scaled, pseudo-inverted) for
        repeated solves with the same rows and weights and a changing target (the alternation)."""
        w2 = w * w
        G = A2.T @ (A2 * w2[:, None])
        cn = np.sqrt(np.clip(np.diag(G), 0.0, None))
        cn = np.where(cn > 0, cn, 1.0)
        Gi = np.linalg.pinv(G / np.outer(cn, cn), rcond=1e-12, hermitian=True)
        return lambda y: (Gi @ ((A2.T @ (y * w2)) / cn)) / cn

    def _solve(self, rec, A, F, M, train, sigma=None, quick=False, init=None, linear=False) -> dict:
        T, n, p = A.shape
        rows = M & train[:, None]
        sig = np.ones(n) if sigma is None else sigma
        w = (rows / sig[None, :]).reshape(-1)
        if self.model in LINEAR_MODELS or linear:
            A2 = np.concatenate([A, F], axis=2).reshape(T * n, -1)
            b, Aw, yw, cn = self._wls(A2, rec.tau.reshape(-1), w)
            res = (rec.tau.reshape(-1) - A2 @ b).reshape(T, n)
            out = {"b": b[:p], "bf": b[p:], "ff": None}
            if not quick:
                out["cov"] = self._cov(Aw, yw, b, cn)
        else:
            out = self._alternate(rec, A, F, rows, w, quick, init)
            res = rec.tau - self._predict(rec, A, F, out)
        r = np.where(rows, res, 0.0)
        cnt = np.maximum(rows.sum(axis=0), 1)
        out["rms"] = np.sqrt(np.sum(r ** 2, axis=0) / cnt)
        out["sigma"] = np.where(rows.any(axis=0), np.maximum(out["rms"], 1e-12), 1.0)
        return out

    @staticmethod
    def _cov(Aw, yw, b, scale):
        """Covariance of the WLS solution with the weighted residual variance."""
        cn, Gi = scale
        r = yw - Aw @ b
        rank = int(np.linalg.matrix_rank(Gi, hermitian=True))
        s2 = float(r @ r) / max(Aw.shape[0] - rank, 1)
        return Gi * s2 / np.outer(cn, cn)

    def _alternate(self, rec, A, F, rows, w, quick, init=None) -> dict:
        from ident.friction.fit import fit_friction

        T, n, p = A.shape
        A2 = A.reshape(T * n, p)
        ff = [None] * n
        n_iter = max(self.n_iter, 1)
        warm = init is not None and init.get("ff") is not None     # a held-out fold
        if not warm or any(f is None for f in init["ff"]):          # start: the cv solution
            Af = np.concatenate([A, F], axis=2).reshape(T * n, -1)
            bc, *_ = self._wls(Af, rec.tau.reshape(-1), w)
            fric = (np.einsum("tjp,p->tj", F, bc[p:]))
        else:
            fric = np.zeros((T, n))
        if warm:                                                    # warm start
            ff = list(init["ff"])
            for j, f in enumerate(ff):
                if f is not None:
                    fric[:, j] = f.model.torque(rec.qd[:, j], rec.qdd[:, j], rec.dt)
            n_iter = 1
        names = self._names
        own = [[k for k, nm in enumerate(names) if nm in (f"offset_{j + 1}", f"Ia_{j + 1}")]
               for j in range(n)]
        notes = []
        dynamic = getattr(self.model_cls, "dynamic", False)
        solve = self._wls_factor(A2, w)        # same rows and weights in every alternation
        scale = np.sqrt(np.sum(np.where(rows, rec.tau, 0.0) ** 2, axis=0) / np.maximum(rows.sum(0), 1))
        for it in range(n_iter):
            b = solve((rec.tau - fric).reshape(-1))
            lin = (A2 @ b).reshape(T, n)
            fric_before = fric.copy()
            for j in range(n):
                rj = rows[:, j] if not dynamic else np.ones(T, bool)
                if not rows[:, j].any():
                    continue
                cols_own = own[j]
                own_pred = A[:, j, cols_own] @ b[cols_own] if cols_own else 0.0
                yj = rec.tau[:, j] - lin[:, j] + own_pred
                X = A[:, j, cols_own] if cols_own else None
                enames = tuple(names[k] for k in cols_own) if cols_own else ()
                kw = {}
                if dynamic:
                    kw = {"qdd": rec.qdd[:, j], "dt": rec.dt}
                try:
                    f = fit_friction(self.model_cls, rec.qd[rj, j], yj[rj],
                                     X_extra=None if X is None else X[rj], extra_names=enames,
                                     n_starts=1 if (quick or it > 0) else self.n_starts,
                                     seed=self.seed, x0=ff[j].model.params if ff[j] is not None else None,
                                     **({"qdd": kw["qdd"][rj], "dt": kw["dt"]} if kw else {}))
                except (ValueError, RuntimeError) as exc:
                    notes.append(f"joint {j + 1}: {self.model} fit failed ({exc})")
                    continue
                ff[j] = f
                fric[:, j] = f.model.torque(rec.qd[:, j], rec.qdd[:, j], rec.dt)
            # converged: no joint's friction torque moved by 1e-4 of its torque level
            moved = np.sqrt(np.mean(np.where(rows, fric - fric_before, 0.0) ** 2, axis=0))
            if it >= 1 and np.all(moved <= 1e-4 * np.maximum(scale, 1e-12)):
                break
        # final linear pass with the friction fixed
        b = solve((rec.tau - fric).reshape(-1))
        return {"b": b, "bf": None, "ff": ff, "notes": notes}

    # ---- result ----------------------------------------------------------------------------
    def _result(self, rec, sol, names, sigma, v0, held, M) -> RigidBodyFit:
        n = rec.n
        p = len(names)
        b = sol["b"]
        idx = {nm: k for k, nm in enumerate(names)}
        off = np.array([b[idx[f"offset_{j + 1}"]] if f"offset_{j + 1}" in idx else 0.0 for j in range(n)])
        arm = np.array([b[idx[f"Ia_{j + 1}"]] if f"Ia_{j + 1}" in idx else np.nan for j in range(n)])
        motors = {}
        for nm, k in idx.items():
            kind, _, mk = nm.partition("m_")
            if mk and kind in ("fs", "fv", "Ia"):
                motors.setdefault(mk, {})[kind] = float(b[k])
        cov = sol.get("cov")
        joints = {}
        notes = list(sol.get("notes", []))
        if getattr(self, "_dropped", ()):
            notes.append(f"not separable from the rigid-body base parameters on these data, merged into "
                         f"them: {', '.join(self._dropped)}")
        for j in range(n):
            if not M[:, j].any():
                continue
            e = {"rms": float(sol["rms"][j]), "heldout_rms": float(held[j]),
                 "offset": float(off[j]),
                 "armature": float(arm[j]) if np.isfinite(arm[j]) else None,
                 "n_used": int(M[:, j].sum()), "v_zero": float(v0[j])}
            if self.model in LINEAR_MODELS:
                fc, fv = float(sol["bf"][2 * j]), float(sol["bf"][2 * j + 1])
                e["params"] = {"c": fc, "v": fv}
                if cov is not None:
                    se = np.sqrt(np.maximum(np.diag(cov), 0.0))
                    e["stderr"] = {"c": float(se[p + 2 * j]), "v": float(se[p + 2 * j + 1])}
                    e["stderr_offset"] = float(se[idx[f"offset_{j + 1}"]]) if self.offset else None
            else:
                f = sol["ff"][j]
                if f is None:
                    continue
                e["params"] = f.model.params
                e["stderr"] = {k: (float(f.stderr[k]) if np.isfinite(f.stderr[k]) else None)
                               for k in f.model.param_names}
                e["degenerate"] = f.degenerate
                if f.model.to_dict().get("settings"):
                    e["settings"] = f.model.to_dict()["settings"]
            mdl = (CoulombViscous(**e["params"]) if self.model in LINEAR_MODELS
                   else sol["ff"][j].model)
            implaus = _implausible(mdl, rec.qd[M[:, j], j])
            if implaus:
                e["implausible"] = implaus
                notes.append(f"joint {j + 1} {self.model}: {implaus}")
            joints[str(j + 1)] = e
        beta = b[:self.base.n_base]
        method = (f"joint weighted least squares (IDIM-WLS, rows weighted by 1/sigma_j) over all "
                  f"joints: {self.base.n_base} base parameters of the URDF's rigid-body model "
                  "(batched joint torque regressor)"
                  + (", per-joint torque offsets" if self.offset else "")
                  + (", actuator inertias" if self.armature else "")
                  + (f", coupled motors {sorted(motors)} (Coulomb, viscous, inertia through C^-T)"
                     if motors else "")
                  + (f", per-joint {self.model} friction in the same linear system"
                     if self.model in LINEAR_MODELS else
                     f", per-joint {self.model} friction by up to {self.n_iter} alternations with "
                     "the linear part (fit_friction with offset and armature as extra columns; "
                     "row weights from the Coulomb + viscous least-squares pass)")
                  + f"; rows with |qd_j| < {self.v_zero_frac:g} x the joint's 99th-percentile speed "
                  "left out; held-out RMS: leave-one-segment-out over "
                  f"{self.folds} contiguous segments")
        return RigidBodyFit(self.model, joints, beta, tuple(f"beta_{k}" for k in range(beta.size)),
                            off, arm, motors, sol["rms"], held, sigma, v0, int(rec.t.size), method,
                            tuple(notes))


def _implausible(model, qd) -> str | None:
    """A static friction model that feeds energy (``f(v) v < 0``) somewhere within the record's
    speed range is physically impossible; dynamic models are not checked."""
    if getattr(model, "dynamic", False):
        return None
    vmax = float(np.max(np.abs(qd))) if qd.size else 0.0
    if not vmax > 0:
        return None
    v = np.concatenate([-np.geomspace(vmax, 1e-4 * vmax, 200), np.geomspace(1e-4 * vmax, vmax, 200)])
    p = model.torque(v) * v
    if np.any(p < 0):
        k = int(np.argmin(p))
        return (f"friction feeds energy at qd = {v[k]:.3g} rad/s (f = {model.torque(v[k:k + 1])[0]:.3g} "
                "N m against the motion): physically impossible")
    return None


def identify(chain: ChainDynamics, rec, models=("cv",), base: BaseParameters | None = None,
             **settings) -> dict:
    """``{model: RigidBodyFit}`` for every friction model (one shared base-parameter set)."""
    base = base if base is not None else base_parameters(chain, seed=settings.get("seed", 0))
    out = {}
    for m in models:
        out[m] = RigidBodyIdentifier(chain, base, model=m, **settings).fit(rec)
    return out
