"""The channels of the gap diagnosis: what is compared, on which samples, against which nominal.

A :class:`Channel` holds one comparison's target, its nominal columns, the trial of each sample
and the units of its held-out error: the **torque** channel (the motor torque left for the link
side against the nominal model's columns, :mod:`ident.gap.nominal`) and the **transmission**
channel (link angle from the markers minus motor angle, beyond the declared stiffness, on the
marker clock). Units are the joint's motion cycles (:func:`motion_cycles`: from one velocity
reversal to the next but one, never across trials); the diagnosis may cut them finer
(:mod:`ident.gap.diagnose`). This module sits below :mod:`ident.gap.data` and
:mod:`ident.gap.diagnose`: it imports neither (a ``JointData`` is only read).
"""
from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from ident.gap.engine import CVResult, cross_validate, grams, trial_bounds
from ident.gap.nominal import NOMINAL_MODELS, NominalModel, nominal_model


def motion_cycles(qd: np.ndarray, v_zero: float = 0.02, min_samples: int = 20,
                  group: np.ndarray | None = None) -> np.ndarray:
    """Block index of each sample: a new block starts at every second velocity reversal (one
    back-and-forth motion cycle per block). The direction is taken from samples faster than
    ``v_zero`` (slow samples inherit the last direction, so jitter at rest makes no reversal);
    cycles shorter than ``min_samples`` join the previous block. With ``group`` (e.g. the trial
    of each sample), the count starts afresh in every group, so that a group's cycles do not
    depend on how many reversals the groups before it had."""
    s = np.where(np.abs(qd) >= v_zero, np.sign(qd), 0.0)
    start = np.zeros(s.shape[0], bool) if group is None else np.r_[True, group[1:] != group[:-1]]
    idx = np.where((s != 0) | start, np.arange(s.shape[0]), 0)   # a group inherits no direction
    idx = np.maximum.accumulate(idx)
    s = s[idx]
    rev = np.r_[False, (s[1:] != s[:-1]) & (s[1:] != 0) & (s[:-1] != 0)] & ~start
    if group is None:
        cyc = np.cumsum(rev) // 2
    else:
        r = np.cumsum(rev)
        local = (r - r[np.maximum.accumulate(np.where(start, np.arange(r.size), 0))]) // 2
        cyc = np.cumsum(np.r_[True, start[1:] | (local[1:] != local[:-1])]) - 1
    # merge cycles that are too short into the previous one, then renumber 0..k-1
    counts = np.bincount(cyc)
    ok = counts >= min_samples
    ok[0] = True
    new_id = np.cumsum(ok) - 1
    return new_id[cyc]



#: a candidate column whose norm the pooled rigid-body fit leaves below this share of its own is
#: absorbed by it (the threshold of :func:`ident.gap.engine.unexplained_fractions`' use)
ABSORBED_NORM = 1e-3


@dataclass
class Channel:
    name: str
    unit: str
    target: np.ndarray
    X0: np.ndarray
    trial: np.ndarray
    bounds: np.ndarray
    demean: bool  # within-trial demeaning (per-trial offsets as nuisance)
    blocks: np.ndarray | None = None       # (n_blocks, 2) sample ranges of the motion cycles
    block_trial: np.ndarray | None = None  # (n_blocks,) trial of each block
    declared: np.ndarray | None = None     # transmission: the declared stiffness's deflection (prepped)
    nuisance: tuple | None = None          # (A, M): columns are tested less A M A^T of them (records)

    def block_fold(self, fold: np.ndarray) -> np.ndarray:
        """Held-out fold of each block (its trial's fold)."""
        return fold[self.block_trial]

    def prep_effect(self, X: np.ndarray) -> np.ndarray:
        """An effect's columns as the channel tests them: :meth:`prep`, after, on records whose
        rigid body was identified on every joint at once, removing what that pooled fit would
        absorb of them (``nuisance = (A, M)``: ``X - A M A^T X``, the Frisch-Waugh-Lovell form of
        fitting them jointly with the identified parameters). A column the pooled fit absorbs
        whole (its norm left below :data:`ABSORBED_NORM` of its own, e.g. a constant torque gain:
        a scale of every identified parameter) is set to zero, not left to rounding: the selection
        then drops it as not identifiable, like a column in the span of the nominal's."""
        if self.nuisance is not None and X.size:
            A, M = self.nuisance
            before = np.sqrt(np.einsum("ij,ij->j", X, X))
            # A (M A^T X) (M None: the identity), as the transpose of a row-major product when X
            # is column-major, so that the result keeps X's layout (its columns stay contiguous)
            Z = A.T @ X if M is None else M @ (A.T @ X)
            X = X - ((Z.T @ A.T).T if X.flags.f_contiguous and not X.flags.c_contiguous else A @ Z)
            gone = np.sqrt(np.einsum("ij,ij->j", X, X)) < ABSORBED_NORM * before
            if gone.any():
                X[:, gone] = 0.0
        return self.prep(X)

    def prep(self, X: np.ndarray) -> np.ndarray:
        """Columns less their within-trial means where the channel demeans (``demean``)."""
        if not self.demean or X.size == 0:
            return X
        out = X.copy(order="K")
        for s, e in self.bounds:
            out[s:e] -= out[s:e].mean(axis=0)
        return out


def _motion_blocks(trial: np.ndarray, qd: np.ndarray, n_trials: int) -> tuple[np.ndarray, np.ndarray]:
    """Blocks of the randomisation test and units of the held-out SSE: the motion cycles of each
    trial (:func:`ident.gap.data.motion_cycles`, chosen from the data, never across trials).
    Residual correlation is short against a cycle, so cycles are nearly exchangeable units, and a
    campaign of 12 trials gives the sign-flip test tens of blocks instead of 12 (whose smallest p,
    times Holm's multiplier, cannot reach the level). Returns (bounds (n_blocks, 2), trial of each)."""
    if trial.size == 0:
        return np.zeros((0, 2), int), np.zeros(0, int)
    cyc = motion_cycles(qd, group=trial)   # counted afresh in each trial
    new = np.r_[True, (trial[1:] != trial[:-1]) | (cyc[1:] != cyc[:-1])]
    starts = np.flatnonzero(new)
    ends = np.r_[starts[1:], trial.size]
    # a short remnant (e.g. a trial's last half cycle) joins the previous block of its trial
    short = (ends - starts) < 20
    keep = ~short | np.r_[True, trial[starts[1:]] != trial[starts[:-1]]]
    starts = starts[keep]
    ends = np.r_[starts[1:], trial.size]
    bt = trial[starts].astype(int)
    return np.column_stack([starts, ends]), bt


def undeclared_payload_columns(d: JointData, which="unknown") -> np.ndarray:
    """Rigid-body corrections of each payload whose centre of mass the lab does not know
    (``payload_com = "unknown"``, FORMAT.md; ``which=None``: the trials where the key is absent,
    which declares it at the flange origin, a declaration the gap diagnosis tests with these
    columns as a nuisance term): the payload's first moments enter the moving joint's gravity
    torque as ``A sin q + B cos q`` and its inertia about the axis linearly in the COM offset, so
    ``[qdd, sin q, cos q]`` on that payload's trials spans a COM error exactly. A torque gain is
    then not identifiable from the payload's torque (these columns free it): the report names the
    gain and the COM as the same term. (N, 3 per such payload); none when there is no such
    payload."""
    cols = [d.urdf_regs[:, :3] * np.isin(d.trial, idx)[:, None] for idx in _undeclared_payloads(d, which)]
    return np.column_stack(cols) if cols else np.zeros((d.trial.shape[0], 0))


def payload_corrected(d: JointData, theta: np.ndarray, extra: np.ndarray | None = None) -> JointData:
    """``d`` with the transmitted torque of the trials whose payload COM is unknown corrected by
    the torque channel's fit of :func:`undeclared_payload_columns` (amplitudes ``theta``, the
    channel's last columns): the spring carries the payload's true rigid-body torque, ``tau_m +
    [qdd, sin q, cos q] theta`` at the marker times, and the declared stiffness's deflection in
    the transmission target ``e = q_link - q_motor + tau_m / K`` moves with it. The torque
    channel pins that correction (its noise over ``K`` is far below the markers'); left free in
    the transmission channel, the same three columns would also take up a softer spring's
    deflection on those trials. ``extra``: the payload columns ``theta`` ends with (default
    :func:`undeclared_payload_columns`). ``d`` itself when there are none or nothing is measured
    at the markers."""
    extra = undeclared_payload_columns(d) if extra is None else extra
    if not extra.shape[1] or not d.e.size:
        return d
    dtau = at_markers(d, extra @ np.asarray(theta, float)[-extra.shape[1]:])
    e = d.e + dtau / d.stiffness if d.stiffness > 0 else d.e
    return replace(d, tau_m=d.tau_m + dtau, e=e)


def _undeclared_payloads(d: JointData, which="unknown") -> list:
    """Trial indices of each payload mass carried with ``payload_com = "unknown"`` (``which``;
    None: absent)."""
    loads = {}
    for i, tr in enumerate(d.trials):
        if tr.load_kg > 0 and (getattr(tr, "extra", None) or {}).get("payload_com") == which:
            loads.setdefault(round(float(tr.load_kg), 9), []).append(i)
    return list(loads.values())


def _compact_nuisance(A: np.ndarray, M: np.ndarray) -> tuple:
    """``(B, None)`` for :meth:`Channel.prep_effect`, with ``B B^T = A M A^T``: ``B = A L``,
    ``M = L L^T`` (symmetric eigendecomposition of the positive semi-definite ``M``, negative
    rounding clipped), on the columns of ``A`` that are not zero on every row (parameters that
    do not act on this joint: their terms are exact zeros). ``A M A^T`` is this joint's block of
    the pooled fit's weighted hat matrix, so ``B``'s singular values are at most one: ``X - B
    (B^T X)`` is as accurate as ``X``, where ``A (M (A^T X))`` passes through the sizes of the
    poorly determined parameter combinations (relative errors of 1e-6 measured on the TX40
    record, enough to move a decision at a threshold). ``B`` is C-contiguous: each of the two
    products with a candidate's columns is one BLAS call, with no copy."""
    live = np.flatnonzero(np.any(A != 0, axis=0))
    M = M[np.ix_(live, live)]
    w, V = np.linalg.eigh(0.5 * (M + M.T))
    return np.ascontiguousarray(A[:, live] @ (V * np.sqrt(np.clip(w, 0.0, None)))), None


def _torque_channel(d: JointData, nominal: NominalModel = None) -> Channel:
    nominal = nominal or NOMINAL_MODELS["cv"]
    X0 = nominal.columns(d)
    extra = undeclared_payload_columns(d)
    if extra.shape[1]:
        X0 = np.column_stack([X0, extra])
    nt = d.n_trials
    blocks, bt = _motion_blocks(d.trial, d.qd, nt)
    nz = None if d.nuisance_rows is None else _compact_nuisance(d.nuisance_rows, d.nuisance_gain)
    return Channel("torque", "N m", nominal.target(d), X0, d.trial, trial_bounds(d.trial, nt), False, blocks, bt,
                   nuisance=nz)


def torque_channel(d: JointData, nominal: NominalModel = None) -> Channel:
    """The torque channel of ``d`` against ``nominal`` (default Coulomb + viscous): its target
    (the logged torque less the fixed part), the nominal's columns and the motion-cycle blocks."""
    return _torque_channel(d, nominal)


def at_markers(d: JointData, x: np.ndarray) -> np.ndarray:
    """A log-clock signal of the torque channel (``d.q``, ``d.qdd`` ...) at the marker times
    (per trial, interpolated on the log clock; rests left out of the log samples are bridged)."""
    out = np.zeros(d.e.shape[0])
    for i in np.unique(d.trial_m):   # loop over trials, vectorised over samples
        m, ml = d.trial_m == i, d.trial == i
        if ml.sum() >= 2:
            out[m] = np.interp(d.t_m[m], d.t[ml], x[ml])
    return out


def _transmission_channel(d: JointData) -> Channel:
    """Link angle from the markers minus motor angle, beyond the declared stiffness. Nominal:
    per-trial offsets (marker frame calibration) and a gain on the motor angle: a link angle
    solved from markers carries a small scale error against the encoder (gear ratio,
    kinematic calibration), a deflection proportional to the angle that no transmission effect
    makes (measured on the foreign world: -0.45 % of the angle, 1.1 of the channel's 1.7 mrad
    RMS on an ind6 campaign). A payload whose centre of mass is not declared enters through the
    transmitted torque, corrected by the torque channel (:func:`payload_corrected`)."""
    nt = d.n_trials
    b = trial_bounds(d.trial_m, nt)
    blocks, bt = _motion_blocks(d.trial_m, d.qd_m, nt)
    X0 = at_markers(d, d.q)[:, None]
    ch = Channel("transmission", "rad", d.e, X0, d.trial_m, b, True, blocks, bt)
    ch.target = ch.prep(d.e[:, None])[:, 0]
    if d.stiffness > 0:
        ch.declared = ch.prep((d.tau_m / d.stiffness)[:, None])[:, 0]
    return ch


class _Transmission:
    """View of JointData whose arrays are the marker-clock ones (for candidate columns)."""

    def __init__(self, d: JointData):
        self.y_m, self.qd_m, self.trial, self.tau_m, self.t_m = d.y_m, d.qd_m, d.trial_m, d.tau_m, d.t_m


def _cv(channel: Channel, X: np.ndarray, fold: np.ndarray, gb: dict | None = None, base=None,
        guard: dict | None = None):
    """Leave-one-fold-out CV of ``X`` augmented by each entry of ``gb`` (hp -> Grams of
    ``[X | C(hp)]``); without ``gb``, of ``X`` alone (``base`` = its Grams, built if None).
    ``guard``: the units each fold leaves out of its training (hv-block)."""
    if gb is None:
        base = base if base is not None else grams(X, channel.target, channel.blocks)
        if X.shape[1] == 0:
            return CVResult(base.yy.copy(), {}, np.zeros(0), None, float(base.yy.sum())), {None: base}
        gb = {None: base}
    return cross_validate(gb, fold, guard=guard), gb


def nominal_heldout_rms(d: JointData, nominal: str = "cv") -> float:
    """Held-out torque RMS of the nominal model (leave-one-fold-out), for data-preparation choices.
    Folds: the trials' (repetitions); with a single fold (one trial), the motion cycles."""
    ch = _torque_channel(d, nominal_model(nominal))
    fold = ch.block_fold(d.fold)
    if len(np.unique(fold)) < 2:
        fold = np.arange(ch.blocks.shape[0])
    cv, _ = _cv(ch, ch.X0, fold)
    return _rms(cv.sse, ch.blocks[:, 1] - ch.blocks[:, 0])


def _rms(sse, n) -> float:
    return float(np.sqrt(np.sum(sse) / max(np.sum(n), 1)))


