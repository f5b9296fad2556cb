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
reversal exactly; with ``x_zero``, static laws also leave out the rows closer than ``x_zero_j``
to joint j's last velocity reversal, where the friction is still building up (presliding,
:func:`ident.friction.presliding.presliding_length`). Friction models linear in their
parameters (``cv``) are solved in the same linear system; the others alternate: the linear
part with the friction fixed, then per joint :func:`ident.friction.fit.fit_friction` on the
joint's remaining torque with offset and armature as extra columns, up to ``n_iter`` times
(fewer once no joint's friction torque moves by 1e-4 of its torque level); their row weights
come from the Coulomb + viscous pass.
Held-out RMS: contiguous segments of the record (``folds``), each predicted by a fit on the
others (leave-one-segment-out).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ident.friction import MODELS, laws
from ident.friction.fit import fit_friction, param_jacobian
from ident.friction.plausibility import assess, assess_armature, to_json
from ident.friction.presliding import reversal_displacement, shape_line_fits
from ident.friction.base import CoulombViscous
from ident.model.regressor import BaseParameters, ChainDynamics, base_parameters
from ident.signals.blas import one_blas_thread
from mocap.numerics import savgol, savgol_kernel

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


def low_speed_cut(log, rec, drives=(), k: float = 3.0) -> dict:
    """The low-speed cut of each joint chosen from the data: ``k`` standard deviations of the
    noise of the velocity estimate, below which the sign of ``qd`` (and so the direction of the
    Coulomb friction) is not known.

    ``sigma_q`` (angle noise, rad) is the largest of: the declared encoder resolution over
    sqrt(12) (``drives.toml`` ``encoder_resolution``, uniform quantisation), the smallest
    non-zero step of the logged angle over sqrt(12) (the quantum the log shows), and the white
    noise of the logged angle, ``std(q - S7 q) / sqrt(1 - 1/3)`` (``S7``: the 7-sample cubic
    Savitzky-Golay smoother, whose centre weight is 1/3). ``sigma_v = sigma_q ||c||``, with
    ``c`` the cubic Savitzky-Golay first-derivative kernel of the record's window for the joint
    (``rec.preprocessing["window_s"]``) at the record's step: the noise that kernel passes to
    the velocity. Returns ``{"v_zero": (n,), "sigma_q", "sigma_v", "k"}`` (rad, rad/s)."""
    n, dt = rec.n, rec.dt
    sq, sv, v0 = np.zeros(n), np.zeros(n), np.zeros(n)
    win = rec.preprocessing.get("window_s", {})
    for j in range(n):                                   # loop over joints (n <= ~7)
        q = np.asarray(log.qm[:, j], float)
        q = q[np.isfinite(q)]
        enc = float(getattr(drives[j], "encoder_resolution", 0.0) or 0.0) if j < len(drives) else 0.0
        d = np.abs(np.diff(q))
        d = d[d > 1e-12]
        quantum = float(d.min()) if d.size else 0.0
        white = (float(np.std(q - savgol(q, 7, 3))) / np.sqrt(1.0 - 1.0 / 3.0)
                 if q.size >= 7 else 0.0)
        sq[j] = max(enc / np.sqrt(12.0), quantum / np.sqrt(12.0), white)
        w = max(5, int(round(float(win.get(str(j + 1), 5 * dt)) / dt)) | 1)
        c = savgol_kernel(w, 3, 1, dt)
        sv[j] = sq[j] * float(np.linalg.norm(c))
        v0[j] = k * sv[j]
    return {"v_zero": v0, "sigma_q": sq, "sigma_v": sv, "k": float(k)}


def residual_knee(qd, resid, v_floor, n_bins: int = 15, factor: float = 1.5) -> float:
    """The lowest speed from which the Coulomb + viscous law fits as well as at speed: the
    residual ``resid`` of a fit is binned over ``|qd|`` (``n_bins`` log-spaced bins from
    ``v_floor`` to the 99th-percentile speed, bins of fewer than 10 rows skipped); the reference
    level is the median RMS of the bins above the median speed; the knee is the lower edge of
    the first bin, from the slowest up, whose RMS is within ``factor`` times that level (below it
    the friction is not Coulomb + viscous: presliding, a Stribeck rise or a reversal's transient).
    ``v_floor`` when the slowest bin already fits."""
    a = np.abs(np.asarray(qd, float))
    r = np.asarray(resid, float)
    sp = float(np.percentile(a, 99)) if a.size else 0.0
    if not sp > v_floor > 0:
        return float(v_floor)
    edges = np.geomspace(v_floor, sp, n_bins + 1)
    k = np.clip(np.searchsorted(edges, a, side="right") - 1, -1, n_bins)
    ok = (k >= 0) & (k < n_bins)
    cnt = np.bincount(k[ok], minlength=n_bins)
    ss = np.bincount(k[ok], weights=r[ok] ** 2, minlength=n_bins)
    rms = np.where(cnt >= 10, np.sqrt(ss / np.maximum(cnt, 1)), np.nan)
    mid = np.sqrt(edges[:-1] * edges[1:])
    upper = rms[(mid >= np.median(a[a >= v_floor])) & np.isfinite(rms)] if (a >= v_floor).any() \
        else np.array([])
    if upper.size == 0:
        return float(v_floor)
    good = np.flatnonzero(np.isfinite(rms) & (rms <= factor * float(np.median(upper))))
    return float(edges[good[0]]) if good.size else float(v_floor)


#: the transition of a smoothed-sign law is over at this many widths (tanh(3) = 0.995)
TRANSITION_WIDTHS = 3.0
#: a transition width that grows by more than this factor when the fitted speed range doubles
#: scales with the range (the geometric midpoint between a fixed width, 1, and a width
#: proportional to the range, 2): the friction has no finite transition but bends at every speed
TRANSITION_STABLE = float(np.sqrt(2.0))
#: rows the transition width is fitted on (longer records: every k-th row)
TRANSITION_ROWS = 50_000


def _tanh_width(a, y, lo, hi, n_grid: int = 121):
    """Least-squares width ``vs`` of ``y = c tanh(a / vs) + fv a`` (the smoothed sign of
    :func:`ident.friction.laws.smooth_sign` at width ``vs``) on the rows ``lo <= a <= hi``
    (``a = |qd|``, ``y = sign(qd) f``): a grid of log-spaced widths from 1e-4 to 1 times ``hi``,
    ``c`` and ``fv`` linear at each width (2 x 2 normal equations). ``(vs, c)``; vs is NaN when
    the best width is at an end of the grid or fewer than 20 rows take part."""
    m = (a >= lo) & (a <= hi)
    a, y = a[m], y[m]
    if a.size < 20 or not hi > 0:
        return float("nan"), float("nan")
    grid = np.geomspace(1e-4, 1.0, n_grid) * hi
    rss, cs = shape_line_fits(a, y, (laws.smooth_sign(a, vs) for vs in grid))
    k = int(np.argmin(rss))
    if k in (0, n_grid - 1):
        return float("nan"), float("nan")
    return float(grid[k]), float(cs[k])


def friction_transition(qd, friction, v_floor) -> dict:
    """The speed at which the joint's friction has completed its sign transition, from the
    friction the record shows (``friction``: the measured torque less everything but the joint's
    friction). A smoothed-sign law ``c tanh(|qd| / vs) + fv |qd|`` (eq. of a regularised Coulomb
    step, the width ``vs`` covering presliding, a filtered reversal and sign noise alike) is
    fitted on the rows from ``v_floor`` to half and to the whole 99th-percentile speed: a real
    transition keeps its width when the range doubles (``stable``: the whole range's width at
    most :data:`TRANSITION_STABLE` times the half range's; a smaller one only says that the half
    range did not see the transition's end), and is over at ``end = TRANSITION_WIDTHS vs`` on the
    whole range (the friction then within 0.5 % of its sliding level). A width that grows with
    the fitted range says that the friction bends at every speed (e.g. a nonlinear viscous law):
    no transition end, and the Coulomb level of a Coulomb + viscous law depends on the cut
    (``end`` None)."""
    a = np.abs(np.asarray(qd, float))
    y = np.sign(qd) * np.asarray(friction, float)
    sp = float(np.percentile(a, 99)) if a.size else 0.0
    step = max(1, a.size // TRANSITION_ROWS)           # long records: every step-th row
    a, y = a[::step], y[::step]
    vs_half, _ = _tanh_width(a, y, v_floor, 0.5 * sp)
    vs_full, c = _tanh_width(a, y, v_floor, sp)
    ok = np.isfinite(vs_half) and np.isfinite(vs_full) and c > 0
    ratio = vs_full / vs_half if ok else float("nan")
    stable = bool(ok and ratio <= TRANSITION_STABLE)
    return {"width_half": None if not np.isfinite(vs_half) else vs_half,
            "width_full": None if not np.isfinite(vs_full) else vs_full,
            "width_ratio": None if not np.isfinite(ratio) else float(ratio), "stable": stable,
            "end": TRANSITION_WIDTHS * vs_full if stable else None}


def coulomb_over_cuts(idt, rec, A, F, M, sigma, cuts) -> np.ndarray:
    """The Coulomb level of every joint (Coulomb + viscous, in the same weighted linear system as
    the fit) for each per-joint low-speed cut in ``cuts`` (k, n), rad/s: ``(k, n)``, NaN where a
    joint keeps no row. ``A, F, M, sigma``: the design, the cv columns, the row mask and the row
    weights of ``idt`` (a ``cv`` :class:`RigidBodyIdentifier`) at a cut no higher than any of
    ``cuts``; a higher cut only removes rows (``|qd_j| < cut_j``) from ``M``. The spread of
    these levels over plausible cuts bounds the cut's effect on Coulomb."""
    out = np.full((len(cuts), rec.n), np.nan)
    ones = np.ones(rec.t.size, bool)
    for i, cut in enumerate(cuts):                       # a handful of cuts
        Mi = M & (np.abs(rec.qd) >= np.asarray(cut, float)[None, :])
        if not Mi.any():
            continue
        sol = idt._solve(rec, A, F, Mi, ones, sigma=sigma, quick=True, linear=True)
        out[i] = np.where(Mi.any(axis=0), sol["bf"][0::2], np.nan)
    return out


def without_unlogged(rec):
    """``rec`` with the torque of its unlogged joints (``rec.unlogged``, and any joint without a
    single finite torque sample) set to 0 and those joints named in ``unlogged``: the identifier
    leaves their rows out (a record whose torques are all finite is returned as it is)."""
    import dataclasses

    if np.isfinite(rec.tau).all():
        return rec
    bad = {j + 1 for j in range(rec.n) if not np.isfinite(rec.tau[:, j]).any()}
    return dataclasses.replace(rec, tau=np.nan_to_num(rec.tau, nan=0.0, posinf=0.0, neginf=0.0),
                               unlogged=tuple(sorted(set(getattr(rec, "unlogged", ())) | bad)))


class RigidBodyIdentifier:
    """Settings in the constructor, learning in :meth:`fit` (see the module docstring).

    ``model``: a friction model name of the registry; ``v_zero_frac``: rows slower than this
    fraction of the joint's 99th-percentile speed are left out (``v_zero``: per-joint cuts in
    rad/s instead); ``x_zero``/``x_floor``: the presliding cut of static laws (rad, rows closer
    to the last velocity reversal; reversals among the rows faster than ``x_floor``, rad/s,
    default the speed cut); ``armature``/``offset``:
    include those columns; ``coupled_motors``: friction and inertia of coupled motors;
    ``n_iter``: alternations for nonlinear friction; ``folds``: contiguous held-out segments
    (0: none); ``n_starts``/``seed``: multi-start of the nonlinear friction fits.
    """

    def __init__(self, chain: ChainDynamics, base: BaseParameters | None = None, model: str = "cv",
                 v_zero_frac: float = 0.02, armature: bool = True, offset: bool = True,
                 coupled_motors: bool = True, n_iter: int = 3, folds: int = 5, n_starts: int = 4,
                 seed: int = 0, lower=None, upper=None, v_zero=None, x_zero=None, x_floor=None):
        if model not in MODELS:
            raise KeyError(f"unknown friction model {model!r} (known: {', '.join(MODELS)})")
        self.chain = chain
        self.base = base if base is not None else base_parameters(chain, lower, upper, seed=seed)
        self.model = model
        self.model_cls = MODELS[model]
        self.v_zero_frac = float(v_zero_frac)
        # per-joint low-speed cut in rad/s (e.g. :func:`low_speed_cut`); None: the fraction
        self.v_zero = None if v_zero is None else np.asarray(v_zero, float)
        # per-joint presliding cut in rad (ident.friction.presliding): rows closer than this to
        # the joint's last velocity reversal (runs of rows faster than x_floor rad/s, default the
        # low-speed cut) are left out of static laws
        self.x_zero = None if x_zero is None else np.asarray(x_zero, float)
        self.x_floor = None if x_floor is None else np.asarray(x_floor, float)
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
            F[:, j, 2 * j:2 * j + 2] = laws.coulomb_viscous_columns(rec.qd[:, j])
        return A, tuple(names), F

    def _coupled(self, rec) -> list:
        if not self.coupled_motors or not rec.coupled:
            return []
        Ci = np.linalg.inv(rec.coupling)
        return [k for k in range(rec.n) if np.sum(np.abs(Ci[k]) > 1e-12) > 1]

    def _mask(self, rec):
        sp = np.percentile(np.abs(rec.qd), 99, axis=0)
        v0 = self.v_zero_frac * sp if self.v_zero is None else self.v_zero
        unlogged = getattr(rec, "unlogged", ())
        moving = np.array([j + 1 in rec.moving and j + 1 not in unlogged for j in range(rec.n)])
        M = (np.abs(rec.qd) >= v0[None, :]) & moving[None, :]
        if self.x_zero is not None and not self.model_cls.dynamic:
            fl = v0 if self.x_floor is None else self.x_floor
            for j in np.flatnonzero(self.x_zero > 0):          # joints with a presliding cut
                M[:, j] &= reversal_displacement(rec.q[:, j], rec.qd[:, j], fl[j]) >= self.x_zero[j]
        return M, v0

    # ---- fit -------------------------------------------------------------------------------
    def fit(self, rec) -> RigidBodyFit:
        """Fit ``rec`` (a :class:`ident.model.record.MultiJointRecord`). Joints in
        ``rec.unlogged`` (their torque was not logged, FORMAT.md ``unlogged_torque``) keep their
        angles in the regressor of the other joints; their own rows are left out and nothing
        is identified for them."""

        rec = without_unlogged(rec)
        with one_blas_thread():
            return self._fit(rec)

    def _prepared(self, rec):
        """The model-independent part of a fit (the batched regressor, the design, the row mask
        and the weights of the ordinary least-squares Coulomb + viscous pass), computed once per
        record and shared by the identifiers of every friction model with the same settings."""
        key = (id(rec), id(self.chain), id(self.base), self.offset, self.armature,
               self.coupled_motors, self.v_zero_frac,
               None if self.v_zero is None else tuple(self.v_zero),
               None if self.x_zero is None or self.model_cls.dynamic else tuple(self.x_zero),
               None if self.x_floor is None else tuple(self.x_floor))
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
        self._sol = sol
        return self._result(rec, sol, names, sigma, v0, held, M)

    def predicted(self, rec) -> tuple:
        """After :meth:`fit` on ``rec``: ``(tau_model, friction_model)``, each (T, n), the
        torque the fitted model predicts (eq. of the module docstring) and its per-joint
        friction part ``f_j(qd_j)`` (coupled motors' friction stays in ``tau_model``)."""
        rec = without_unlogged(rec)
        A, names, F, M, _, sigma, self._dropped = self._prepared(rec)
        s = self._sol
        pred = self._predict(rec, A, F, s)
        if self.model in LINEAR_MODELS:
            fric = np.einsum("tjp,p->tj", F, s["bf"])
        else:
            fric = np.column_stack([f.model.torque(rec.qd[:, j], rec.qdd[:, j], rec.dt)
                                    if f is not None else np.zeros(rec.t.size)
                                    for j, f in enumerate(s["ff"])])
        return pred, fric

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
        cn, Gi = _scaled_pinv(G)

        def solve(y):
            return (Gi @ ((A2.T @ (y * w2)) / cn)) / cn

        solve.gram = G                          # unscaled A2^T W^2 A2 (_joint_cov)
        return solve

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
        return RigidBodyIdentifier._cov_of(yw - Aw @ b, Aw.shape[0], scale)

    @staticmethod
    def _cov_of(rw, n_rows, scale):
        """``s^2 (A_w^T A_w)^+`` from the weighted residuals ``rw`` of ``n_rows`` rows and the
        column-scaled pseudo-inverse ``scale = (cn, Gi)``; ``s^2 = |rw|^2 / (n_rows - rank)``."""
        cn, Gi = scale
        rank = int(np.linalg.matrix_rank(Gi, hermitian=True))
        s2 = float(rw @ rw) / max(n_rows - rank, 1)
        return Gi * s2 / np.outer(cn, cn)

    def _alternate(self, rec, A, F, rows, w, quick, init=None) -> dict:
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
        notes, failed = [], {}
        dynamic = self.model_cls.dynamic
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
                    failed.setdefault(j + 1, str(exc))      # once per joint, not per alternation
                    continue
                ff[j] = f
                fric[:, j] = f.model.torque(rec.qd[:, j], rec.qdd[:, j], rec.dt)
            # converged: no joint's friction torque moved by 1e-4 of its torque level
            moved = np.sqrt(np.mean(np.where(rows, fric - fric_before, 0.0) ** 2, axis=0))
            if it >= 1 and np.all(moved <= 1e-4 * np.maximum(scale, 1e-12)):
                break
        # final linear pass with the friction fixed
        y = (rec.tau - fric).reshape(-1)
        b = solve(y)
        failed = {j: why for j, why in failed.items() if ff[j - 1] is None}
        if failed:
            notes.append(_failure_note(self.model, failed))
        out = {"b": b, "bf": None, "ff": ff, "notes": notes}
        if not quick:
            out["cov_linear"] = self._joint_cov(rec, A, w, (y - A2 @ b) * w, solve.gram, ff)
        return out

    @staticmethod
    def _joint_cov(rec, A, w, rw, G_AA, ff):
        """The linear parameters' block of the Gauss-Newton covariance of the whole fit (linear
        rigid-body part and every joint's friction parameters together, the friction linearised
        about its fit): ``s^2 (J^T W^2 J)^+`` with ``J = [A | dF/dtheta]``, ``dF/dtheta`` by central
        differences of each joint's fitted law on that joint's rows (:func:`param_jacobian`), ``s^2 = |rw|^2 / (rows -
        rank)``; pseudo-inverted on the column-scaled Gram matrix as :meth:`_wls_factor`."""
        T, n, p = A.shape
        w2 = (w * w).reshape(T, n)
        blocks = []
        for j, f in enumerate(ff):
            if f is None:
                continue
            Bj = param_jacobian(f.model, rec.qd[:, j], rec.qdd[:, j], rec.dt)
            WB = Bj * w2[:, j, None]
            blocks.append((A[:, j, :].T @ WB, Bj.T @ WB))
        q = p + sum(bb.shape[0] for _, bb in blocks)
        G = np.zeros((q, q))
        G[:p, :p] = G_AA
        k0 = p
        for ab, bb in blocks:
            k1 = k0 + bb.shape[0]
            G[:p, k0:k1] = ab
            G[k0:k1, :p] = ab.T
            G[k0:k1, k0:k1] = bb
            k0 = k1
        return RigidBodyIdentifier._cov_of(rw, int(np.count_nonzero(w)), _scaled_pinv(G))[:p, :p]

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
            if self.x_zero is not None and not self.model_cls.dynamic:
                e["x_zero"] = float(self.x_zero[j])
                e["x_floor"] = float(v0[j] if self.x_floor is None else self.x_floor[j])
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

            flags = assess(self.model, e["params"], qd=rec.qd[M[:, j], j],
                           stderr=e.get("stderr"), model=mdl,
                           tau_scale=float(np.max(np.abs(rec.tau[M[:, j], j]))))
            se_arm = None
            # the linear laws: the solve's covariance; the others: the linear block of the
            # Gauss-Newton covariance with the friction parameters (_joint_cov)
            cov_arm = cov if cov is not None else sol.get("cov_linear")
            if cov_arm is not None and f"Ia_{j + 1}" in idx:
                se_arm = float(np.sqrt(max(cov_arm[idx[f"Ia_{j + 1}"], idx[f"Ia_{j + 1}"]], 0.0)))
            if e["armature"] is not None:
                e["stderr_armature"] = se_arm
            fa = assess_armature(e["armature"], se_arm)
            e["flags"] = to_json(flags)
            if fa is not None:
                e["flags"]["armature"] = fa.to_dict()
            # the note repeats an impossible flag in words; a friction that pushes the motion only
            # through a parameter whose sign the data leave open is flagged undetermined instead
            implaus = (_implausible(mdl, rec.qd[M[:, j], j])
                       if any(fl.kind == "impossible" for fl in flags.values()) else None)
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
                  + (f"; rows with |qd_j| < {self.v_zero_frac:g} x the joint's 99th-percentile "
                     "speed left out" if self.v_zero is None else
                     "; rows slower than the low-speed cut chosen from the data left out ("
                     + ", ".join(f"{x:.3g}" for x in self.v_zero) + " rad/s, see the "
                     "preprocessing)")
                  + "; held-out RMS: leave-one-segment-out over "
                  f"{self.folds} contiguous segments")
        return RigidBodyFit(self.model, joints, beta, tuple(f"beta_{k}" for k in range(beta.size)),
                            off, arm, motors, sol["rms"], held, sigma, v0, int(rec.t.size), method,
                            tuple(notes))


def _failure_note(model: str, failed: dict) -> str:
    """One note for the joints whose ``model`` friction could not be fitted on the record, with
    the reason (the first joint's, its per-joint numbers dropped); the missing data set and its
    remedy are named once per record (:func:`dynamic_data_note`)."""
    import re

    joints = sorted(failed)
    why = re.sub(r"\s*\(min [^)]*\)", "", failed[joints[0]])
    why = why.split("; identify the static part first")[0]
    why = re.sub(r"\s*and pass settings=\{.*$", "", why)
    out = f"{model} not identified on joint(s) {', '.join(map(str, joints))}: {why}"
    if model in ("dm1", "dm2"):
        out += " (see the missing data set named in the preprocessing)"
    return out


def dynamic_data_note(models, kinds) -> str | None:
    """One sentence naming the data sets Indri & Trapani's dynamic models (dm1, dm2) need and
    the campaign lacks (``kinds``: the trial kinds it has), with a remedy the command line
    reaches; None when no dynamic model is asked or nothing is missing."""
    dyn = [m for m in models if m in ("dm1", "dm2")]
    if not dyn:
        return None
    miss = [(k, what) for k, what in (("constant_velocity", "constant-velocity moves (Indri & "
                                       "Trapani data set 1: the static arctan part)"),
                                      ("reversals", "velocity reversals (data set 2: the bristle "
                                       "dynamics" + (", at two or more accelerations for dm2"
                                                     if "dm2" in dyn else "") + ")"))
            if k not in kinds]
    if not miss:
        return None
    return (f"{', '.join(dyn)} on this record alone: the campaign has no "
            + " and no ".join(w for _, w in miss)
            + ", so the static part is fitted to the same record and may not be positive. "
            "Remedy: record single-joint trials with kind = "
            + " / ".join(f'"{k}"' for k, _ in miss)
            + " in a campaign of their own and run `jointlab fit CAMPAIGN --models "
            "arctan,dm1,dm2` on it; on this record `jointlab fit CAMPAIGN --models "
            "cv,stribeck,hyperbolic,arctan` fits the static laws")


def _scaled_pinv(G):
    """``(cn, Gi)``: the column norms ``cn = sqrt(diag G)`` (1 where 0) and the pseudo-inverse of
    the column-scaled Gram matrix ``G / (cn cn^T)`` (rank deficiency handled, rcond 1e-12)."""
    cn = np.sqrt(np.clip(np.diag(G), 0.0, None))
    cn = np.where(cn > 0, cn, 1.0)
    return cn, np.linalg.pinv(G / np.outer(cn, cn), rcond=1e-12, hermitian=True)


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
