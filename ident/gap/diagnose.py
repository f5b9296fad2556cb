"""Sim-to-real gap diagnosis of one joint: where the gap lies, which effect, how far it shrinks.

Protocol (per joint, per channel):

1. Nominal model = what a plain simulator has: the declared joint (rigid, or the flexible joint
   of thesis eq. 2-1, 2-2 at the drive's declared ``stiffness``: rigid-body terms on the link
   state, friction at the motor or the link side of the spring, :mod:`ident.gap.data`), URDF
   rigid-body dynamics for the trial's payload (with small base-parameter corrections),
   Coulomb + viscous friction.
2. Held-out residuals by leave-one-repetition-out (or leave-one-trial-out) cross-validation.
3. Each candidate effect augments the nominal model in its channel; its shape parameter is
   chosen on the training folds only. Held-out SSE per trial, before and after.
4. Significance: a sign-flip randomisation test on the held-out SSE reductions of the motion
   cycles of each trial (blocks chosen from the data; autocorrelation within a cycle is
   respected), Holm correction over candidates, an effect-size floor relative to the gap above
   the white-noise floor (at later steps: the gap left), and a floor on the variance removed
   relative to the channel's noise variance (per channel, calibrated on effect-free campaigns;
   the marker noise of the transmission channel averages out over frames). The verdict is the
   transmission channel's first selection when it has one, else the torque channel's.
   Nuisance columns of the nominal: per-trial offsets and a motor-angle gain in the transmission
   channel; free rigid-body corrections of a payload whose COM is not declared, in both.
5. Forward stepwise selection (the selected effect joins the model, the rest are re-tested),
   bootstrap over trials for the stability of the verdict and confidence intervals.
"""
from __future__ import annotations

from dataclasses import asdict, dataclass, replace

import numpy as np

from ident.gap.candidates import Candidate, candidate_effects, confounders, level_interactions, selected_levels
from ident.gap.data import JointData
from ident.gap.nominal import NOMINAL_MODELS, NominalModel, nominal_model
from ident.gap.engine import (CVResult, bootstrap_ci, cross_validate, grams, grams_augmented, holm,
                              repetition_noise_floor, sign_flip_min_p, sign_flip_pvalue, trial_bounds, unexplained_fractions,
                              white_noise_floor)
from ident.gap.result import ChannelResult, DiagnosisResult, EffectTest, SelectionStep

REGIMES = ("low_speed", "high_speed", "reversal", "high_acceleration", "position", "time", "load")


@dataclass(frozen=True)
class DiagnosisSettings:
    alpha: float = 0.01              # family-wise level (Holm) per selection step
    min_explained: float = 0.15      # an effect must remove this share of the gap above the noise floor
    #                                  (at later steps: of the gap the selected effects left)
    min_reduction: float = 0.003     # ... and this fraction of the held-out RMS
    min_effect_to_floor: float = 0.10  # ... and remove at least this share of the torque channel's
    #                                    noise-floor variance (an effect within the torque noise is not
    #                                    claimed, however large its relative share): the families shaped
    #                                    at low speed and reversals (candidates.REVERSAL_SHAPED). Effect-
    #                                    free foreign campaigns (24: two robots, 6 seeds, URDF errors,
    #                                    undeclared payload COM, coloured noise): their best physical
    #                                    candidate removed up to 0.062 of the floor with white noise
    min_effect_to_floor_global: float = 0.03  # the same for the other torque families (time, position,
    #                                    load, direction, gain): at most 0.012 on those campaigns
    min_effect_to_floor_transmission: float = 0.01  # the same floor in the transmission channel (see
    #                                  effect_size_floor): effect-free foreign campaigns (24: two robots, 6
    #                                  seeds, URDF errors, undeclared payload COM, coloured noise) removed at
    #                                  most 0.0034 of it once the braked joints' declared deflection is in
    #                                  the marker solve (mocap.solve.held_placement); 0.195 before
    max_effects: int = 3             # stepwise steps
    n_perm: int = 20000
    n_boot: int = 300
    seed: int = 0
    nominal: str = "cv"              # --nominal SPEC (ident.gap.nominal.nominal_model)

    def to_dict(self) -> dict:
        return asdict(self)


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

    def block_fold(self, fold: np.ndarray) -> np.ndarray:
        """Held-out fold of each block (its trial's fold)."""
        return fold[self.block_trial]

    def prep(self, X: np.ndarray) -> np.ndarray:
        if not self.demean or X.size == 0:
            return X
        out = X.copy()
        for s, e in self.bounds:
            out[s:e] -= out[s:e].mean(axis=0)
        return out


def _motion_blocks(trial: np.ndarray, qd: np.ndarray, n_trials: int) -> tuple[np.ndarray, np.ndarray]:
    """Blocks of the randomisation test and units of the held-out SSE: the motion cycles of each
    trial (:func:`ident.gap.data.motion_cycles`, chosen from the data, never across trials).
    Residual correlation is short against a cycle, so cycles are nearly exchangeable units, and a
    campaign of 12 trials gives the sign-flip test tens of blocks instead of 12 (whose smallest p,
    times Holm's multiplier, cannot reach the level). Returns (bounds (n_blocks, 2), trial of each)."""
    from ident.gap.data import motion_cycles

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


def undeclared_payload_columns(d: JointData) -> np.ndarray:
    """Rigid-body corrections of each payload carried without a declared ``payload_com``
    (FORMAT.md then takes it at the flange origin, which a real payload rarely is): the payload's
    first moments enter the moving joint's gravity torque as ``A sin q + B cos q`` and its inertia
    about the axis linearly in the COM offset, so ``[qdd, sin q, cos q]`` on that payload's trials
    spans a COM error exactly. A torque gain is then not identifiable (its only lever, the
    payload's known torque, is what these columns free): the report says so instead of reading a
    COM error as a torque scale (measured on the foreign world: effect-free ind6 campaigns with
    the COM undeclared went to ``torque_scale``; with the gravity part alone freed, one still
    removed 0.22 of its noise floor). (N, 3 per such payload); none when every loaded trial
    declares its COM."""
    cols = [d.urdf_regs * np.isin(d.trial, idx)[:, None] for idx in _undeclared_payloads(d)]
    return np.column_stack(cols) if cols else np.zeros((d.trial.shape[0], 0))


def _undeclared_payloads(d: JointData) -> list:
    """Trial indices of each payload mass carried without a declared ``payload_com``."""
    loads = {}
    for i, tr in enumerate(d.trials):
        if tr.load_kg > 0 and "payload_com" not in (getattr(tr, "extra", None) or {}):
            loads.setdefault(round(float(tr.load_kg), 9), []).append(i)
    return list(loads.values())


def _torque_channel(d: JointData, nominal: NominalModel = None) -> Channel:
    nominal = nominal or NOMINAL_MODELS["cv"]
    X0 = nominal.columns(d)
    extra = undeclared_payload_columns(d)
    if extra.shape[1]:
        X0 = np.column_stack([X0, extra])
    nt = d.n_trials
    blocks, bt = _motion_blocks(d.trial, d.qd, nt)
    return Channel("torque", "N m", nominal.target(d), X0, d.trial, trial_bounds(d.trial, nt), False, blocks, bt)


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
    RMS on an ind6 campaign); and the payload corrections of :func:`undeclared_payload_columns`."""
    nt = d.n_trials
    b = trial_bounds(d.trial_m, nt)
    blocks, bt = _motion_blocks(d.trial_m, d.qd_m, nt)
    qm = at_markers(d, d.q)
    X0 = [qm[:, None]]
    # a payload whose COM is not declared: its torque, and so the declared stiffness's deflection,
    # is uncertain by [qdd, sin q, cos q] on its trials (as in the torque channel)
    loads = _undeclared_payloads(d)
    if loads:
        regs = np.column_stack([at_markers(d, d.qdd), np.sin(qm), np.cos(qm)])
        X0 += [regs * np.isin(d.trial_m, idx)[:, None] for idx in loads]
    X0 = np.column_stack(X0)
    ch = Channel("transmission", "rad", d.e, X0, d.trial_m, b, True, blocks, bt)
    ch.target = ch.prep(d.e[:, None])[:, 0]
    if d.stiffness > 0:
        ch.declared = ch.prep((d.tau_m / d.stiffness)[:, None])[:, 0]
    return ch


class _Transmission:
    """View of JointData whose arrays are the marker-clock ones (for candidate columns)."""

    def __init__(self, d: JointData):
        self.y_m, self.qd_m, self.trial, self.tau_m, self.t_m = d.y_m, d.qd_m, d.trial_m, d.tau_m, d.t_m


def _cv(channel: Channel, X: np.ndarray, fold: np.ndarray, gb: dict | None = None, base=None):
    """Leave-one-fold-out CV of ``X`` augmented by each entry of ``gb`` (hp -> Grams of
    ``[X | C(hp)]``); without ``gb``, of ``X`` alone (``base`` = its Grams, built if None)."""
    if gb is None:
        base = base if base is not None else grams(X, channel.target, channel.blocks)
        if X.shape[1] == 0:
            return CVResult(base.yy.copy(), {}, np.zeros(0), None, float(base.yy.sum())), {None: base}
        gb = {None: base}
    return cross_validate(gb, fold), gb


def _columns(cand: Candidate, d: JointData, hp):
    src = d if cand.channel == "torque" else _Transmission(d)
    return np.asarray(cand.columns(src, hp), float)


class _ColumnCache:
    """Candidate columns kept across selection steps (they do not change when the model grows),
    up to a memory budget."""

    def __init__(self, budget_bytes: float = 3e8):
        self.store, self.left = {}, budget_bytes

    def get(self, cand: Candidate, d: JointData, ch: Channel, hp) -> np.ndarray:
        key = (cand.family, repr(hp))
        C = self.store.get(key)
        if C is None:
            C = ch.prep(_columns(cand, d, hp))
            if C.nbytes <= self.left:
                self.store[key] = C
                self.left -= C.nbytes
        return C


def _effect_grams(cands, d: JointData, ch: Channel, X: np.ndarray, base,
                  cache: _ColumnCache | None = None, levels: tuple = (None, None)) -> tuple[dict, dict]:
    """(candidate, hp) -> Grams of ``[X | C]`` over every family and shape parameter of one
    effect, built once. Columns that lie in the span of ``X`` (e.g. a direction-independent
    Coulomb excess when the nominal model has a torque offset) are dropped; a shape with no
    column left is left out. ``cols`` keeps the columns used and which of the family's columns
    they are (for the sign check). ``levels``: the Coulomb and viscous levels selected so far
    (torque channel), composed by product with the candidate's own (:func:`level_interactions`)."""
    out, cols = {}, {}
    p = X.shape[1]
    for cand in cands:
        for hp in cand.grid:
            C = cache.get(cand, d, ch, hp) if cache is not None else ch.prep(_columns(cand, d, hp))
            C = level_interactions(C, cand, levels)   # unchanged unless a level was selected
            if C.shape[0] == 0 or not np.all(np.isfinite(C)):
                continue
            g = grams_augmented(base, X, C, ch.target, ch.blocks)
            keep = unexplained_fractions(g, p) >= 1e-3
            if not keep.any():
                continue
            if not keep.all():
                C = C[:, keep]
                g = grams_augmented(base, X, C, ch.target, ch.blocks)
            out[(cand, hp)] = g
            cols[(cand, hp)] = (C, keep)
    return out, cols


def _amplitudes(theta: np.ndarray, p: int, keep: np.ndarray) -> np.ndarray:
    """The family's amplitudes from a fit of ``[X | C]`` (zeros for dropped columns)."""
    a = np.zeros(keep.shape[0])
    a[keep] = theta[p:]
    return a


def nominal_heldout_rms(d: JointData, nominal: str = "cv") -> float:
    """Held-out torque RMS of the nominal model (leave-one-fold-out), for data-preparation choices."""
    ch = _torque_channel(d, nominal_model(nominal))
    cv, _ = _cv(ch, ch.X0, ch.block_fold(d.fold))
    return _rms(cv.sse, ch.blocks[:, 1] - ch.blocks[:, 0])


def _over_floor(removed_mse: float, noise_mse: float) -> float:
    """Held-out variance an effect removes, in units of its channel's noise-floor variance (the
    one scale on which channels with different units are compared)."""
    if not np.isfinite(noise_mse) or noise_mse <= 0:
        return float("inf") if removed_mse > 0 else 0.0
    return float(removed_mse / noise_mse)


def _size_evidence(removed_mse: float, noise_mse: float, declared_ms: float) -> dict:
    """Effect size: the held-out variance removed over the channel's noise-floor variance, and in
    the transmission channel of a joint with a declared stiffness also the RMS deflection removed
    over the RMS of the declared deflection ``tau / K`` (reported, not gated)."""
    ev = {"removed_variance_over_floor": _over_floor(removed_mse, noise_mse)}
    if declared_ms > 0:
        ev["removed_rms_over_declared_deflection"] = float(np.sqrt(max(removed_mse, 0.0) / declared_ms))
    return ev


def effect_size_floor(channel: str, family: str, settings: "DiagnosisSettings") -> float:
    """The effect-size floor of a candidate family, in units of its channel's noise-floor variance.

    A model error of the nominal leaves a structured residual that a candidate can fit however
    many samples there are, so significance alone would attribute it; the floor is what
    effect-free campaigns of the foreign world reach, with a margin, per group of candidates whose
    columns pick up the same kind of model error: torque families shaped at low speed and
    reversals (``min_effect_to_floor``: 1.6 x their 0.062), the other torque families
    (``min_effect_to_floor_global``: 2.5 x their 0.012), the transmission channel
    (``min_effect_to_floor_transmission``: 2.9 x its 0.0034). The transmission floor is lowest
    because its noise is the marker noise, white per frame, which averages out over the tens of
    thousands of frames of a campaign: a joint 3-5 times softer than declared removes 0.004-0.06
    of it on tri3, whose marker noise is a few times the declared deflection."""
    from ident.gap.candidates import REVERSAL_SHAPED

    if channel == "transmission":
        return settings.min_effect_to_floor_transmission
    return settings.min_effect_to_floor if family in REVERSAL_SHAPED else settings.min_effect_to_floor_global


def _share(removed: float, gap: float) -> float:
    """Share of the gap still above the noise floor that an effect removes: at the first step
    the nominal's gap, later the gap the selected effects left (an effect that explains most of
    what is left is not judged against the part the first one already explained)."""
    return float(removed / gap) if gap > 0 else (float("inf") if removed > 0 else 0.0)


def _rms(sse, n):
    return float(np.sqrt(np.sum(sse) / max(np.sum(n), 1)))


@dataclass
class _Row:
    """Working state of one effect's test in one selection step."""

    effect: str
    test: EffectTest
    cv: CVResult | None = None
    cols: dict | None = None


@dataclass
class _ChannelRun:
    nominal_sse: np.ndarray
    nominal_cv: CVResult
    n: np.ndarray
    noise_floor_mse: float
    mse_nominal: float
    first: dict
    steps: list
    final_sse: np.ndarray
    n_blocks: int = 0
    p_min: float = 1.0            # smallest p the block sign-flip test can give
    n_tested: int = 0             # identifiable candidates (Holm's multiplier at the first step)

    def powerless(self, alpha: float) -> bool:
        """True when even the most extreme outcome cannot pass Holm's first threshold."""
        return self.n_tested > 0 and self.p_min * self.n_tested >= alpha


NOT_IDENTIFIABLE = ("not identifiable from this campaign: its signature is indistinguishable from the "
                    "nominal model's parameters")


def _sse(X: np.ndarray, y: np.ndarray) -> float:
    th = np.linalg.lstsq(X, y, rcond=None)[0]
    r = y - X @ th
    return float(r @ r)


def _discriminate(sig: list, rows: dict, ch: Channel, X: np.ndarray) -> "_Row":
    """Choose among significant candidates by their signatures, not only by fit quality.

    For the best-fitting candidate and each of its registered confounders that was tested
    (significant or not), fit both together: each one's *unique* share is the part of its own
    SSE reduction that survives when the other is in the model (an encompassing test: backlash
    keeps a jump at torque reversals that a compliance slope cannot make; load-dependent friction
    keeps a velocity-signed term that a torque gain cannot make; ...). The evidence is recorded on
    both rows; when the leader's signature is explained by a significant confounder while the
    confounder's is not explained by the leader, the confounder is chosen."""
    best = max(sig, key=lambda r: r.test.explained_share)
    y = ch.target
    s0 = _sse(X, y) if X.shape[1] else float(y @ y)

    def cols(r):
        return r.cols[r.cv.hp_all][0]

    choice = best
    conf, _ = confounders(best.effect)
    for name in conf:
        other = rows.get(name)
        if other is None or not other.test.identifiable or other.cv is None:
            continue
        Ca, Cb = cols(best), cols(other)
        sa, sb = _sse(np.column_stack([X, Ca]), y), _sse(np.column_stack([X, Cb]), y)
        sab = _sse(np.column_stack([X, Ca, Cb]), y)
        ua = (sb - sab) / max(s0 - sa, 1e-300)   # leader's reduction left given the confounder
        ub = (sa - sab) / max(s0 - sb, 1e-300)
        best.test = replace(best.test, evidence={**best.test.evidence, f"unique_share_given_{name}": float(ua)})
        other.test = replace(other.test, evidence={**other.test.evidence,
                                                   f"unique_share_given_{best.effect}": float(ub)})
        if other.test.significant and ua < 0.2 and ub > 0.5 and choice is best:
            choice = other
    return choice


def _channel_stepwise(d: JointData, ch: Channel, cands, settings: DiagnosisSettings) -> _ChannelRun:
    fold = ch.block_fold(d.fold)
    n_per_trial = ch.blocks[:, 1] - ch.blocks[:, 0]   # per block (motion cycle)
    X = ch.prep(ch.X0)
    base = grams(X, ch.target, ch.blocks)
    base_cv, _ = _cv(ch, X, fold, base=base)
    nominal_sse = base_cv.sse.copy()
    # residual of the nominal fit on all data -> white-noise floor
    resid_all = ch.target - X @ base_cv.theta_all if X.shape[1] else ch.target
    noise = white_noise_floor(resid_all, ch.trial)
    n_tot = max(n_per_trial.sum(), 1)
    mse_nom = float(nominal_sse.sum() / n_tot)
    excess_nom = max(mse_nom - noise, 0.0)
    steps, tested_first = [], None
    current_sse = nominal_sse
    by_effect: dict = {}
    for c in cands:
        if c.channel == ch.name:
            by_effect.setdefault(c.name, []).append(c)
    cache = _ColumnCache()
    n_blocks = int(np.sum(n_per_trial > 0))
    p_min = sign_flip_min_p(n_blocks, settings.n_perm)
    decl_ms = float(np.mean(ch.declared ** 2)) if ch.declared is not None and ch.declared.size else 0.0
    levels = (None, None)   # fitted Coulomb / viscous levels of the effects selected so far (torque)
    for step in range(settings.max_effects):
        rows, pvals = {}, {}
        for name, group in by_effect.items():
            gb, cols = _effect_grams(group, d, ch, X, base, cache, levels)
            if not gb:
                rows[name] = _Row(name, EffectTest(name, ch.name, False, note=NOT_IDENTIFIABLE))
                continue
            cvr, _ = _cv(ch, X, fold, gb)
            cand, hp = cvr.hp_all
            physical = bool(cand.physical(hp, _amplitudes(cvr.theta_all, X.shape[1], cols[cvr.hp_all][1])))
            composed = cols[cvr.hp_all][1].shape[0] > cache.get(cand, d, ch, hp).shape[1]
            p = sign_flip_pvalue(current_sse - cvr.sse, settings.n_perm, settings.seed)
            pvals[name] = p
            mse_e = float(cvr.sse.sum() / n_tot)
            mse_cur = float(current_sse.sum() / n_tot)
            rows[name] = _Row(name, EffectTest(
                name, ch.name, True, family=cand.family, physical=physical,
                note="" if physical else f"best fit has the unphysical sign for {name}: not this effect",
                heldout_rms=float(np.sqrt(mse_e)),
                reduction=float(1 - np.sqrt(mse_e / mse_nom)) if mse_nom > 0 else 0.0,
                reduction_step=float(1 - np.sqrt(mse_e / mse_cur)) if mse_cur > 0 else 0.0,
                explained_share=float((mse_cur - mse_e) / excess_nom) if excess_nom > 0 else 0.0,
                share_step=_share(mse_cur - mse_e, mse_cur - noise),
                p_value=p, p_min_attainable=p_min,
                shape=cand.describe(hp) + ("; also times the selected effects' friction levels" if composed else ""),
                evidence=_size_evidence(mse_cur - mse_e, noise, decl_ms)), cvr, cols)
        adj = holm(pvals)
        for name, r in rows.items():
            if not r.test.identifiable:
                continue
            t = r.test
            floor = effect_size_floor(ch.name, t.family, settings)
            r.test = replace(t, p_adjusted=adj[name], evidence={**t.evidence, "effect_size_floor": floor},
                             significant=bool(
                t.physical and adj[name] < settings.alpha and t.share_step >= settings.min_explained
                and t.reduction_step >= settings.min_reduction
                and t.evidence["removed_variance_over_floor"] >= floor))
        if tested_first is None:
            tested_first = rows
        sig = [r for r in rows.values() if r.test.significant]
        if not sig:
            break
        best = _discriminate(sig, rows, ch, X)
        t = best.test
        steps.append((SelectionStep(t.effect, ch.name, t.heldout_rms, t.reduction, t.p_adjusted,
                                    t.explained_share, t.shape, t.family,
                                    t.evidence["removed_variance_over_floor"]), best.cv.sse))
        C, keep = best.cols[best.cv.hp_all]
        cand, hp = best.cv.hp_all
        if cand.coulomb or cand.viscous:   # torque-channel families only
            # the selected effect's fitted levels join those later candidates are composed with
            # (its own columns: the products with earlier levels are second-order)
            a = _amplitudes(best.cv.theta_all, X.shape[1], keep)
            own = cache.get(cand, d, ch, hp)
            new = selected_levels(own, a[:own.shape[1]], cand, d)
            levels = tuple(n if o is None else o if n is None else o + n for o, n in zip(levels, new))
        base = grams_augmented(base, X, C, ch.target, ch.blocks)
        X = np.column_stack([X, C])
        current_sse = best.cv.sse
        by_effect.pop(best.effect)
    n_tested = sum(1 for r in (tested_first or {}).values() if r.test.identifiable)
    return _ChannelRun(nominal_sse, base_cv, n_per_trial, noise, mse_nom, tested_first or {}, steps,
                       current_sse, n_blocks, p_min, n_tested)


def _stability(res: _ChannelRun, settings: DiagnosisSettings) -> dict:
    """Bootstrap over trials: how often each first-step candidate gives the largest reduction."""
    first = {k: r for k, r in res.first.items() if r.test.identifiable}
    if not first:
        return {}
    names = list(first)
    D = np.array([res.nominal_sse - first[k].cv.sse for k in names])  # (k, trials)
    rng = np.random.default_rng(settings.seed + 1)
    idx = rng.integers(0, D.shape[1], size=(settings.n_boot, D.shape[1]))
    wins = np.argmax(D[:, idx].sum(axis=2), axis=0)
    return {names[k]: float(np.mean(wins == k)) for k in range(len(names))}


def _regime_masks(d: JointData) -> dict:
    aqd, aqdd = np.abs(d.qd), np.abs(d.qdd)
    vmax = d.vmax if np.isfinite(d.vmax) else np.percentile(aqd, 99)
    masks = {"low_speed": aqd < 0.1 * vmax, "high_speed": aqd > 0.5 * vmax,
             "high_acceleration": aqdd > np.quantile(aqdd, 0.8)}
    sgn = np.sign(d.qd)
    rev = np.zeros_like(aqd, bool)
    flips = np.flatnonzero((sgn[1:] != sgn[:-1]) & (d.trial[1:] == d.trial[:-1]))
    if flips.size:
        dt = float(np.median(np.diff(d.t_rel[:200]))) if d.t_rel.size > 2 else 0.005
        w = max(int(round(0.15 / dt)), 1)
        marks = np.zeros(aqd.shape[0] + 1)
        np.add.at(marks, np.clip(flips - w, 0, None), 1)
        np.add.at(marks, np.clip(flips + w + 1, None, aqd.shape[0]), -1)
        rev = np.cumsum(marks)[:-1] > 0
    masks["reversal"] = rev
    return masks


#: motion regimes in priority order: each held-out sample belongs to the first that holds
PARTITION = ("reversal", "low_speed", "high_acceleration", "high_speed")


def _localise(d: JointData, noise: float, resid: np.ndarray) -> tuple[list, float]:
    """Decomposition of the held-out excess (nominal residual power above the noise floor) over
    non-overlapping motion regimes: every sample is assigned to the first of :data:`PARTITION`
    that holds, the rest (moderate speed, moderate acceleration) to ``rest``. A regime's share is
    its excess ``sum r^2 - n sigma^2`` (clipped at 0) over the total; shares and ``rest`` add
    up to 1. Returns (regime rows sorted by share, rest share)."""
    masks = _regime_masks(d)
    taken = np.zeros(resid.shape[0], bool)
    excess = {}
    r2 = resid ** 2
    for name in PARTITION:
        m = masks[name] & ~taken
        taken |= m
        if m.any():
            excess[name] = max(float(r2[m].sum() - noise * m.sum()), 0.0)
    rest = max(float(r2[~taken].sum() - noise * (~taken).sum()), 0.0)
    tot = sum(excess.values()) + rest
    if tot <= 0:
        return [{"regime": k, "share": 0.0} for k in excess], 0.0
    rows = sorted(({"regime": k, "share": v / tot} for k, v in excess.items()), key=lambda r: -r["share"])
    return rows, rest / tot


def _heldout_residual(d: JointData, ch: Channel, cv: CVResult) -> np.ndarray:
    """Held-out residual of the nominal model: each fold's samples against the fit without it
    (the thetas of the nominal cross-validation, not refitted)."""
    r = np.zeros_like(ch.target)
    for f, th in cv.theta_per_fold.items():
        te = np.isin(ch.trial, np.flatnonzero(d.fold == f))
        r[te] = ch.target[te] - ch.X0[te] @ th
    return r


def _channel_result(ch: Channel, res: _ChannelRun, settings: DiagnosisSettings) -> ChannelResult:
    n = res.n
    return ChannelResult(
        ch.name, ch.unit, float(np.sqrt(res.mse_nominal)), bootstrap_ci(res.nominal_sse, n, seed=settings.seed),
        _rms(res.final_sse, n), bootstrap_ci(res.final_sse, n, seed=settings.seed),
        float(np.sqrt(res.noise_floor_mse)), tuple(s for s, _ in res.steps), n_blocks=res.n_blocks,
        p_min_attainable=res.p_min)


def _selection_order(chres: dict) -> list:
    """Selected effects, most telling first: each channel's first selection (transmission before
    torque, as for the verdict), then the later steps in the order they joined their models."""
    order = [c for c in ("transmission", "torque") if c in chres]
    firsts = [chres[c].selected[0] for c in order if chres[c].selected]
    return firsts + [s for c in order for s in chres[c].selected[1:]]


def diagnose_joint(d: JointData, settings: DiagnosisSettings = DiagnosisSettings(),
                   gear_ratio: float | None = None) -> DiagnosisResult:
    from ident.signals.smoothing import one_blas_thread

    with one_blas_thread():
        return _diagnose_joint(d, settings, gear_ratio)


def _diagnose_joint(d: JointData, settings: DiagnosisSettings, gear_ratio: float | None) -> DiagnosisResult:
    nominal = nominal_model(settings.nominal)
    q_range = float(np.ptp(np.percentile(d.q, [0.5, 99.5]))) if d.q.size else None
    cands = candidate_effects(gear_ratio, q_range)
    channels = [_torque_channel(d, nominal)]
    if d.has_transmission:
        channels.append(_transmission_channel(d))
    effects, chres = [], {}
    runs = {}
    for ch in channels:
        res = _channel_stepwise(d, ch, cands, settings)
        runs[ch.name] = res
        stab = _stability(res, settings)
        chres[ch.name] = _channel_result(ch, res, settings)
        for name, row in res.first.items():
            conf, exp = confounders(name)
            effects.append(replace(row.test, confounded_with=tuple(conf), separating_experiment=exp,
                                   bootstrap_top_share=stab.get(name, 0.0)))
    # verdict: a transmission effect, when one passed its gates, else the torque channel's first
    # selection. A transmission effect (a softer spring, a dead band, a clock shift) changes the
    # motor-side dynamics and so leaves torque-channel disturbances at reversals (presliding- or
    # Stribeck-like), while a friction effect does not change the link-motor deflection (the
    # deflection carries the link-side torque): the transmission channel's finding explains the
    # torque channel's, not the other way round. Its gates (effect size over its own noise floor,
    # share of its gap) keep a marginal transmission finding from overriding a torque one.
    firsts = [chres[c].selected[0] for c in ("transmission", "torque") if c in chres and chres[c].selected]
    verdict = firsts[0].effect if firsts else "none"
    insufficient = ""
    if verdict == "none":
        weak = [(c, r) for c, r in runs.items() if r.powerless(settings.alpha)]
        if weak:
            c, r = weak[0]
            need = int(np.ceil(np.log2(2 * r.n_tested / settings.alpha)))
            insufficient = (f"insufficient data: the {c} channel has {r.n_blocks} independent blocks (trials or "
                            f"motion cycles); the block sign-flip test's smallest p is {r.p_min:.3g}, times "
                            f"{r.n_tested} candidates (Holm) >= alpha {settings.alpha:g}, so no effect could be "
                            f"declared. Record at least {need} blocks (repeat the trajectories, or a longer record "
                            f"with more motion cycles) to settle it.")
    tch, tres = channels[0], runs["torque"]
    resid = _heldout_residual(d, tch, tres.nominal_cv)
    localisation, rest = _localise(d, tres.noise_floor_mse, resid)
    dt = float(np.median(np.diff(d.t_rel[:1000]))) if d.t_rel.size > 2 else 0.005
    rep_var = repetition_noise_floor(resid, d.trial, d.t_rel, d.group[:d.n_trials], 1.0 / dt)
    chres["torque"] = replace(chres["torque"], noise_floor_rms_repetitions=(
        float(np.sqrt(rep_var)) if np.isfinite(rep_var) else None))
    effects.sort(key=lambda r: (not r.significant, -(r.reduction or 0.0)))
    return DiagnosisResult(
        verdict=verdict, nominal_model=nominal.label, n_trials=d.n_trials,
        folds="leave-one-repetition-out" if len(set(d.fold.tolist())) < d.n_trials else "leave-one-trial-out",
        channels=chres, effects=tuple(effects), insufficient=insufficient,
        selected=tuple(s.effect for s in _selection_order(chres)),
        localisation=tuple(localisation), localisation_rest=rest,
        localisation_method="decomposition of the held-out excess over non-overlapping motion regimes "
                            "(priority " + " > ".join(PARTITION) + "; the remainder is 'rest')",
        series={"t": d.t, "qd": d.qd, "q": d.q, "residual_nominal": resid, "trial": d.trial})
