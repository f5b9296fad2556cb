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

import time
from contextlib import nullcontext
from dataclasses import asdict, dataclass, replace
from typing import NamedTuple

import numpy as np

from ident.gap.candidates import (REVERSAL_SHAPED, Candidate, SharedIntermediates, candidate_effects,
                                  confounders, level_interactions, selected_levels, shared_intermediates)
from ident.gap.channels import (Channel, _cv, _rms, _torque_channel, _Transmission,
                               _transmission_channel, _undeclared_payloads, nominal_heldout_rms,
                               payload_corrected, undeclared_payload_columns)
from ident.gap.data import JointData
from ident.gap.nominal import nominal_model
from ident.gap.engine import (CVResult, bootstrap_ci, cross_validate, grams, grams_augmented, heldout_leverage,
                              holm, loss_differential_test, loss_test_min_p, own_blocks,
                              repetition_noise_floor, sign_flip_min_p, sign_flip_pvalue, trial_bounds,
                              unexplained_fractions, white_noise_floor)
from ident.gap.result import ChannelResult, DiagnosisResult, EffectTest, SelectionStep
from ident.gap.unnamed import (TORQUE_LOWPASS, UNNAMED, configuration_localisation, prefers_unnamed,
                               unnamed_candidates)
from ident.settings import SEED, AnyOf, Interval, OneOf, PathLike, Settings, Text
from ident.signals.smoothing import one_blas_thread

@dataclass(frozen=True)
class DiagnosisSettings(Settings):
    """Levels, floors and test settings of the gap diagnosis (:class:`GapDiagnosis`).

    :attr:`constraints` is checked at construction (:mod:`ident.settings`). An effect is selected when its held-out improvement passes Holm's correction at ``alpha``
    [1]_ and every floor below; the effect-size floors are in units of the channel's
    noise-floor variance and calibrated on effect-free campaigns of the independent world
    (:func:`effect_size_floor`; calibration: [2]_).

    Attributes
    ----------
    alpha : float
        Family-wise level (Holm) per selection step.
    min_explained : float
        Share of the gap above the noise floor an effect must remove (at later steps: of the
        gap the selected effects left).
    min_reduction : float
        ... and this fraction of the held-out RMS.
    min_effect_to_floor : float
        ... and this share of the torque channel's noise-floor variance, for the families
        shaped at low speed and reversals (``candidates.REVERSAL_SHAPED``): an effect within
        the torque noise is not claimed, however large its relative share.
    min_effect_to_floor_samples : float
        The reversal-shaped floor in the sample-level test of a single record.
    min_effect_to_floor_global : float
        The same floor for the other torque families (time, position, load, direction, gain).
    min_effect_to_floor_transmission : float
        The same floor in the transmission channel.
    max_effects : int
        Forward stepwise selection steps.
    n_perm : int
        Sign flips of the randomisation test.
    n_boot : int
        Bootstrap resamples over trials (stability of the verdict, confidence intervals).
    seed : int
        Seed of the randomisation test and the bootstrap.
    nominal : str
        The nominal model, ``--nominal SPEC`` (:func:`ident.gap.nominal.nominal_model`).
    test : str
        ``"cycles"`` (block sign-flip), ``"samples"`` (HAC loss differential [3]_) or
        ``"auto"``: cycles where they can reach Holm's first threshold.

    References
    ----------
    .. [1] Holm 1979, a simple sequentially rejective multiple test procedure.
    .. [2] jointlab gap diagnosis (docs/gap-diagnosis.md).
    .. [3] Diebold & Mariano 1995, comparing predictive accuracy.
    """

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
    min_effect_to_floor_samples: float = 0.2  # the reversal-shaped floor in the sample-level test of a
    #                                  single record: effect-free foreign single records (36, seeds 4-6
    #                                  of both robots, benchmarks/gap_single.py's kind) reach 0.106
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
    test: str = "auto"               # "cycles" (block sign-flip), "samples" (HAC loss differential) or
    #                                  "auto": cycles where they can reach Holm's first threshold

    #: field -> (option, constraint), checked at construction
    constraints = {
        "alpha": ("alpha", Interval(0, 1, closed="neither")),
        "min_explained": ("min_explained", Interval(0, 1)),
        "min_reduction": ("min_reduction", Interval(0, 1)),
        "min_effect_to_floor": ("min_effect_to_floor", Interval(0)),
        "min_effect_to_floor_samples": ("min_effect_to_floor_samples", Interval(0)),
        "min_effect_to_floor_global": ("min_effect_to_floor_global", Interval(0)),
        "min_effect_to_floor_transmission": ("min_effect_to_floor_transmission", Interval(0)),
        "max_effects": ("max_effects", Interval(0, integer=True)),
        "n_perm": ("n_perm", Interval(1, integer=True)),
        "n_boot": ("n_boot", Interval(1, integer=True)),
        "seed": ("--seed", SEED),
        "nominal": ("--nominal", AnyOf(Text(), PathLike(none=False))),
        "test": ("test", OneOf("auto", "cycles", "samples")),
    }

    def to_dict(self) -> dict:
        return asdict(self)


def _columns(cand: Candidate, d: JointData, hp):
    src = d if cand.channel == "torque" else _Transmission(d)
    return np.asarray(cand.columns(src, hp), float)


#: bytes of candidate columns :class:`_ColumnCache` keeps: a fixed budget, so that the
#: diagnosis' memory does not grow with the samples (columns beyond it are built again)
COLUMN_CACHE_BYTES = 3e7
#: bytes of the intermediates the candidate columns share (:class:`SharedIntermediates`), a
#: fixed budget beside :data:`COLUMN_CACHE_BYTES`
SHARED_BYTES = 2.4e7
#: bytes of the per-block products of candidate columns with themselves and the target, kept
#: across selection steps (they do not change when the model grows)
PRODUCTS_BYTES = 8e6
#: bytes of raw candidate columns prepared for a channel in one call (:meth:`_ColumnCache.get_many`)
PREP_BATCH_BYTES = 4e6


class _ColumnCache:
    """Candidate columns kept across selection steps (they do not change when the model grows),
    up to a memory budget (:data:`COLUMN_CACHE_BYTES`): those that took the longest to build
    per byte are kept (a cheaper one gives way to a costlier one), the others are built again.
    The builds share their intermediates within :data:`SHARED_BYTES`
    (:class:`ident.gap.candidates.SharedIntermediates`)."""

    def __init__(self, budget_bytes: float = COLUMN_CACHE_BYTES, shared_bytes: float = SHARED_BYTES,
                 products_bytes: float = PRODUCTS_BYTES):
        self.store, self.budget, self.left = {}, float(budget_bytes), float(budget_bytes)
        self.shared = SharedIntermediates(shared_bytes)
        self.products, self.products_left = {}, float(products_bytes)

    def keep_products(self, key, g, k: int) -> None:
        """Keep the blocks of a family's own ``k`` columns with themselves and the target
        (:func:`ident.gap.engine.own_blocks`) within :data:`PRODUCTS_BYTES`."""
        nbytes = g.G.shape[0] * (k * k + k) * 8
        if nbytes <= self.products_left:
            self.products[key] = own_blocks(g, k)
            self.products_left -= nbytes

    def get(self, cand: Candidate, d: JointData, ch: Channel, hp) -> np.ndarray:
        """The prepared columns of one shape (:meth:`get_many` of that shape alone)."""
        return self.get_many([(cand, hp)], d, ch)[(cand, hp)]

    def get_many(self, shapes: list, d: JointData, ch: Channel) -> dict:
        """``(candidate, hp) -> ``:meth:`get`'s columns for every shape of ``shapes``: those not
        kept are built one by one and prepared together, :data:`PREP_BATCH_BYTES` of raw
        columns at a time (:meth:`ident.gap.channels.Channel.prep_effect` is column by column,
        so the values are :meth:`get`'s up to rounding; on records its projection reads the
        pooled design once per call, which one call for many columns shares). The columns are
        side by side in one column-major array, so each shape's are contiguous without a copy;
        those the cache keeps are copied out of it. A shape prepared alone (:meth:`get`) has
        the same layout and, without a pooled projection (single-joint trials), the same values
        to the last bit."""
        out, todo = {}, []
        for cand, hp in shapes:
            hit = self.store.get((cand.family, repr(hp)))
            if hit is not None:
                out[(cand, hp)] = hit[0]
            else:
                todo.append((cand, hp))
        i = 0
        while i < len(todo):
            raw, size = [], 0
            c0 = time.process_time()
            with shared_intermediates(self.shared):
                while i < len(todo) and (not raw or size < PREP_BATCH_BYTES):
                    raw.append(_columns(todo[i][0], d, todo[i][1]))
                    size += raw[-1].nbytes
                    i += 1
            widths = [r.shape[1] for r in raw]
            X = np.empty((raw[0].shape[0], sum(widths)), order="F")
            at = np.cumsum([0] + widths)
            for r, a0, w in zip(raw, at, widths):
                X[:, a0:a0 + w] = r
            del raw
            C_all = ch.prep_effect(X)
            cost = (time.process_time() - c0) / max(size, 1)   # the batch's seconds per byte
            for (cand, hp), a0, w in zip(todo[i - len(widths):i], at, widths):
                C = C_all[:, a0:a0 + w]
                out[(cand, hp)] = self._keep((cand.family, repr(hp)), C, cost, copy=True)
        return out

    def _keep(self, key, C: np.ndarray, cost: float, copy: bool = False) -> np.ndarray:
        """Keep ``C`` (build seconds per byte ``cost``) if it fits, making room by dropping
        entries that cost less per byte; ``copy``: keep a copy (``C`` is a view of a larger
        array). Returns ``C`` or the copy kept."""
        if C.nbytes > self.budget:
            return C
        if C.nbytes > self.left:
            cheaper = sorted((v[1], k) for k, v in self.store.items() if v[1] < cost)
            if self.left + sum(self.store[k][0].nbytes for _, k in cheaper) < C.nbytes:
                return C
            for _, k in cheaper:   # cheapest first, until C fits
                self.left += self.store.pop(k)[0].nbytes
                if C.nbytes <= self.left:
                    break
        if copy:
            C = C.copy(order="K")
        self.store[key] = (C, cost)
        self.left -= C.nbytes
        return C


def _effect_grams(cands, d: JointData, ch: Channel, X: np.ndarray, base,
                  cache: _ColumnCache | None = None, levels: tuple = (None, None)) -> tuple[dict, dict]:
    """(candidate, hp) -> Grams of ``[X | C]`` over every family and shape parameter of one
    effect, built once. Columns that lie in the span of ``X`` (e.g. a direction-independent
    Coulomb excess when the nominal model has a torque offset) are dropped; a shape with no
    column left is left out. ``cols`` maps each shape to its :class:`_Cols` (which of the
    family's columns are used, for the sign check; the columns themselves are rebuilt on demand,
    so that one effect's grid never holds its samples at once). ``levels``: the Coulomb and
    viscous levels selected so far (torque channel), composed by product with the candidate's
    own (:func:`level_interactions`)."""
    out, cols = {}, {}
    # built shape by shape across the families (families of one effect with one grid, the ripple
    # orders, share their intermediates), returned family by family
    order = [(cand, hp) for cand in cands for hp in cand.grid]
    position = [(i, k) for k, cand in enumerate(cands) for i in range(len(cand.grid))]
    ordered = [order[j] for j in sorted(range(len(order)), key=position.__getitem__)]
    with shared_intermediates(cache.shared) if cache is not None else nullcontext():
        # prepared a batch at a time (one pass over the pooled design per batch, on records)
        batch = max(1, int(PREP_BATCH_BYTES // max(d.qd.shape[0] * 8, 1)))
        for b in range(0, len(ordered), batch):
            chunk = ordered[b:b + batch]
            ready = cache.get_many(chunk, d, ch) if cache is not None else {}
            for key in chunk:
                _effect_gram(key, d, ch, X, base, cache, levels, out, cols, ready.get(key))
    if cache is not None:   # the angle multiples are shared within one sweep over the orders
        cache.shared.discard_below("trig")
        cache.shared.discard_below("trig2")
    return {k: out[k] for k in order if k in out}, {k: cols[k] for k in order if k in cols}


def _effect_gram(key, d: JointData, ch: Channel, X: np.ndarray, base, cache, levels: tuple,
                 out: dict, cols: dict, C: np.ndarray | None = None) -> None:
    """One shape of :func:`_effect_grams`: its Grams into ``out``, its recipe into ``cols``
    (``C``: its prepared columns when they were built already)."""
    p = X.shape[1]
    cand, hp = key
    if C is None:
        C = cache.get(cand, d, ch, hp) if cache is not None else ch.prep_effect(_columns(cand, d, hp))
    raw = C.shape[1]
    composed = level_interactions(C, cand, levels)   # unchanged unless a level was selected
    # the family's own columns: their products with themselves do not change with the model
    plain = cache is not None and composed is C
    own = cache.products.get((cand.family, repr(hp))) if plain else None
    C = composed
    # a finite sum has only finite terms (one pass); otherwise check each term
    if C.shape[0] == 0 or not (np.isfinite(np.add.reduce(C, axis=None)) or np.all(np.isfinite(C))):
        return
    g = grams_augmented(base, X, C, ch.target, ch.blocks, own)
    if plain and own is None:
        cache.keep_products((cand.family, repr(hp)), g, raw)
    keep = unexplained_fractions(g, p) >= 1e-3
    if not keep.any():
        return
    if not keep.all():
        C = C[:, keep]
        g = grams_augmented(base, X, C, ch.target, ch.blocks)
    out[key] = g
    cols[key] = _Cols(cand, hp, levels, keep, raw)


@dataclass(frozen=True)
class _Cols:
    """The columns one shape of a candidate adds to the model, as a recipe: the family's columns
    at ``hp`` (prepared for the channel, composed with the selected ``levels``), those marked in
    ``keep``. :meth:`build` makes them (the same values :func:`_effect_grams` used); only the
    chosen shapes' columns are ever built again, so the grid's columns are never all held."""

    cand: Candidate
    hp: object
    levels: tuple
    keep: np.ndarray
    raw_width: int      # the family's own columns (before the composition with the levels)

    @property
    def composed(self) -> bool:
        """Whether the columns include products with the selected effects' levels."""
        return self.keep.shape[0] > self.raw_width

    def build(self, d: JointData, ch: Channel, cache: _ColumnCache | None = None) -> np.ndarray:
        C = cache.get(self.cand, d, ch, self.hp) if cache is not None else ch.prep_effect(_columns(self.cand, d, self.hp))
        with shared_intermediates(cache.shared) if cache is not None else nullcontext():
            C = level_interactions(C, self.cand, self.levels)
        return C if self.keep.all() else C[:, self.keep]


def _amplitudes(theta: np.ndarray, p: int, keep: np.ndarray) -> np.ndarray:
    """The family's amplitudes from a fit of ``[X | C]`` (zeros for dropped columns)."""
    a = np.zeros(keep.shape[0])
    a[keep] = theta[p:]
    return a


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


def effect_size_floor(channel: str, family: str, settings: "DiagnosisSettings", mode: str = "cycles") -> float:
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
    of it on tri3, whose marker noise is a few times the declared deflection. In the sample-level
    test of a single record (``mode="samples"``) the reversal-shaped families get
    ``min_effect_to_floor_samples``: a single record's nominal error at its reversals is not
    averaged over the speeds and loads of a campaign (calibration: docs/gap-diagnosis.md)."""
    if channel == "transmission":
        return settings.min_effect_to_floor_transmission
    if family in REVERSAL_SHAPED:
        return settings.min_effect_to_floor_samples if mode == "samples" else settings.min_effect_to_floor
    return settings.min_effect_to_floor_global


def _share(removed: float, gap: float) -> float:
    """Share of the gap still above the noise floor that an effect removes: at the first step
    the nominal's gap, later the gap the selected effects left (an effect that explains most of
    what is left is not judged against the part the first one already explained)."""
    return float(removed / gap) if gap > 0 else (float("inf") if removed > 0 else 0.0)


@dataclass
class _Row:
    """Working state of one effect's test in one selection step."""

    effect: str
    test: EffectTest
    cv: CVResult | None = None
    cols: dict | None = None


class _Nuisance(NamedTuple):
    """A contradicted payload declaration that joined a channel's nominal (:data:`PAYLOAD_COM`)."""

    columns: np.ndarray      # its columns on the channel's samples
    amplitudes: np.ndarray   # their fitted amplitudes
    test: EffectTest         # its test at the step it joined
    same_term: tuple         # gain-like effects that explained the same term at that step


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
    design: _TestDesign | None = None
    last_d: dict | None = None    # effect -> per-unit held-out loss differential at the last step
    extrapolated: float = 0.0     # share of held-out samples with leverage > 1 (nominal columns)
    payload: _Nuisance | None = None   # a contradicted payload declaration (joined the nominal)
    unnamed: EffectTest | None = None  # a term outside the vocabulary that led a step (the selection stopped)
    unnamed_step: int = 0              # the step it led

    def powerless(self, alpha: float) -> bool:
        """True when even the most extreme outcome cannot pass Holm's first threshold."""
        return self.n_tested > 0 and self.p_min * self.n_tested >= alpha

    def detectable(self, alpha: float, power: float = 0.8) -> float:
        """The smallest effect this channel's data could have shown beyond the model it reached:
        the held-out variance an effect must remove (per sample, in units of the noise-floor
        variance) for the test to pass Holm's first threshold with probability ``power``, from
        the spread of the last selection step's loss differentials (the median over candidates
        of their standard errors: HAC in the sample-level test, the block standard deviation in
        the sign-flip test). Infinite when the test cannot reach the threshold at all."""
        from scipy.stats import norm, t as student_t

        if self.powerless(alpha) or not self.last_d or not np.isfinite(self.noise_floor_mse) \
                or self.noise_floor_mse <= 0:
            return float("inf")
        n = next(iter(self.last_d.values())).shape[0]   # units (the same for every candidate)
        ses = []
        for dl in self.last_d.values():   # one standard error per candidate
            if self.design is not None and self.design.mode == "samples":
                _, info = loss_differential_test(dl)
                ses.append(info["se"] / max(info.get("hln", 1.0), 1e-12))
            else:
                ses.append(float(np.std(dl, ddof=1) / np.sqrt(n)) if n > 1 else float("inf"))
        # the median over candidates: an effect present inflates its own (and its confounders')
        # loss-differential spread; the others show the spread under the null
        se = float(np.median(ses))
        crit = float(student_t.isf(alpha / max(self.n_tested, 1), df=max(n - 1, 1)))
        mean_d = (crit + float(norm.ppf(power))) * se
        per_sample = mean_d * n / max(float(np.sum(self.n)), 1.0)
        return float(per_sample / self.noise_floor_mse)


NOT_IDENTIFIABLE = ("not identifiable from this campaign: its signature is indistinguishable from the "
                    "nominal model's parameters")


def _sse(X: np.ndarray, y: np.ndarray) -> float:
    th = np.linalg.lstsq(X, y, rcond=None)[0]
    r = y - X @ th
    return float(r @ r)


def _discriminate(sig: list, rows: dict, ch: Channel, X: np.ndarray, d: JointData,
                  cache: _ColumnCache | None = None, floor: float = 0.03) -> "_Row":
    """Choose among significant candidates by their signatures, not only by fit quality.

    For the best-fitting candidate and each of its registered confounders that was tested
    (significant or not), fit both together: each one's *unique* share is the part of its own
    SSE reduction that survives when the other is in the model (an encompassing test: backlash
    keeps a jump at torque reversals that a compliance slope cannot make; load-dependent friction
    keeps a velocity-signed term that a torque gain cannot make; ...). The evidence is recorded on
    both rows; when the leader's signature is explained by a significant confounder while the
    confounder's is not explained by the leader, the confounder is chosen. A payload declaration
    (:data:`PAYLOAD_COM`) and the gain-like effects (:data:`GAIN_LIKE`) are each other's
    confounders. When each explains the
    same term as the other (each keeps less than a third of its reduction given the other, the
    rule that also names it as the alternative) and the simpler one fits the held-out data no
    worse within the test's resolution (:func:`_heldout_tie`), the one with fewer fitted
    parameters (its free columns, plus its shape parameters when a grid was searched) is chosen:
    the data cannot tell them apart, and the simpler explanation is the one to report first
    (parsimony)."""
    best = max(sig, key=lambda r: r.test.explained_share)
    y = ch.target
    s0 = _sse(X, y) if X.shape[1] else float(y @ y)

    def cols(r):
        return r.cols[r.cv.hp_all].build(d, ch, cache)

    choice = best
    Ca = None
    conf = list(confounders(best.effect)[0])
    if best.effect == PAYLOAD_COM:          # a COM error is a gain on the payload's torque
        conf = list(GAIN_LIKE)
    elif best.effect in GAIN_LIKE and PAYLOAD_COM in rows:
        conf.append(PAYLOAD_COM)
    for name in conf:
        other = rows.get(name)
        if other is None or not other.test.identifiable or other.cv is None:
            continue
        if Ca is None:
            Ca = cols(best)
        Cb = cols(other)
        sa, sb = _sse(np.column_stack([X, Ca]), y), _sse(np.column_stack([X, Cb]), y)
        sab = _sse(np.column_stack([X, Ca, Cb]), y)
        ua = (sb - sab) / max(s0 - sa, 1e-300)   # leader's reduction left given the confounder
        ub = (sa - sab) / max(s0 - sb, 1e-300)
        best.test = replace(best.test, evidence={**best.test.evidence, f"unique_share_given_{name}": float(ua)})
        other.test = replace(other.test, evidence={**other.test.evidence,
                                                   f"unique_share_given_{best.effect}": float(ub)})
        if other.test.significant and ua < 0.2 and ub > 0.5 and choice is best:
            choice = other
        elif (other.test.significant and ua < SAME_TERM and ub < SAME_TERM and choice is best
              and _n_params(other, Cb) < _n_params(best, Ca) and _heldout_tie(best, other)):
            choice = other
    return _specific(choice, sig, rows, X, y, s0, cols, floor)


def _specific(choice: "_Row", sig: list, rows: dict, X: np.ndarray, y: np.ndarray, s0: float, cols,
              floor: float) -> "_Row":
    """A named candidate keeps its name only with its own signature (:mod:`ident.gap.unnamed`):
    against each significant term outside the vocabulary, the pair is fitted together; when that
    term explains the named one's (it keeps less than :data:`SAME_TERM` of its reduction) and
    :func:`ident.gap.unnamed.prefers_unnamed` says so, the term outside the vocabulary leads (the
    joint is then unexplained). When such a term leads, a significant named candidate that
    explains it and keeps its own signature, or that the rule prefers, leads instead."""
    unnamed = [rows[n] for n in UNNAMED if n in rows and rows[n].test.significant and rows[n].cv is not None]
    if not unnamed:
        return choice

    def pair(a, b):
        Ca, Cb = cols(a), cols(b)
        sa, sb = _sse(np.column_stack([X, Ca]), y), _sse(np.column_stack([X, Cb]), y)
        sab = _sse(np.column_stack([X, Ca, Cb]), y)
        return (sb - sab) / max(s0 - sa, 1e-300), (sa - sab) / max(s0 - sb, 1e-300)

    def wins(named, u):   # whether u replaces the named candidate
        un, uu = pair(named, u)
        named.test = replace(named.test, evidence={**named.test.evidence, f"unique_share_given_{u.effect}": float(un)})
        margin = (u.test.evidence.get("removed_variance_over_floor", 0.0)
                  - named.test.evidence.get("removed_variance_over_floor", 0.0))
        return prefers_unnamed(u.effect, un, SAME_TERM, _heldout_tie(named, u), _heldout_tie(u, named),
                               margin, floor, named.test.family)

    if choice.effect not in UNNAMED:
        for u in unnamed:
            if wins(choice, u):
                return u
        return choice
    named = [r for r in sig if r.effect not in UNNAMED and r.effect != PAYLOAD_COM]
    keep = [r for r in sorted(named, key=lambda r: -r.test.explained_share) if not wins(r, choice)
            and pair(choice, r)[0] < SAME_TERM]
    return keep[0] if keep else choice


#: the nuisance term of a payload whose centre of mass is absent from its trials (FORMAT.md: at the
#: flange origin): tested beside the effects, it joins the nominal when the data contradict the
#: declaration, and is reported as a note, never as a verdict
PAYLOAD_COM = "payload_com"
#: the effects a payload COM error resembles (a gain on the payload's torque): each is the other's
#: confounder in the selection, and an undeclared COM is named as their alternative
GAIN_LIKE = ("torque_scale", "load_dependent")


def _payload_candidate(d: JointData) -> Candidate | None:
    """The payload-declaration test (:data:`PAYLOAD_COM`): ``[qdd, sin q, cos q]`` on the trials
    of each payload mass without ``payload_com``
    (:func:`ident.gap.channels.undeclared_payload_columns` with ``which=None``), which span what
    a centre of mass away from the flange origin adds to the joint's torque. None when every
    loaded trial declares its COM (or calls it unknown)."""
    if not _undeclared_payloads(d, None):
        return None
    return Candidate(PAYLOAD_COM, "torque", (None,), lambda dd, hp: undeclared_payload_columns(dd, None),
                     lambda hp: "payload centre of mass away from the flange origin (payload_com absent): "
                                "[qdd, sin q, cos q] on the loaded trials", PAYLOAD_COM)


#: each of two candidates keeps less than this share of its reduction given the other: they
#: explain the same term (named as each other's alternative; the simpler one leads)
SAME_TERM = 1 / 3


def _heldout_tie(a: "_Row", b: "_Row", z: float = 1.645) -> bool:
    """Whether ``b`` fits the held-out data no worse than ``a`` within the resolution of the
    test units: the mean paired difference of their held-out squared errors per unit is below
    ``z`` standard errors of that mean (one-sided 5 %)."""
    dl = np.asarray(b.cv.sse, float) - np.asarray(a.cv.sse, float)
    if dl.size < 2:
        return False
    return bool(dl.mean() <= z * dl.std(ddof=1) / np.sqrt(dl.size))


def _n_params(r: "_Row", C: np.ndarray) -> int:
    """Fitted parameters of a candidate's chosen shape: its free columns ``C`` plus its shape
    parameters when its family's grid offered more than one shape."""
    cand, hp = r.cv.hp_all
    n_shape = (len(hp) if isinstance(hp, tuple) else 1) if len(cand.grid) > 1 else 0
    return int(C.shape[1]) + n_shape


def correlation_samples(r: np.ndarray, trial: np.ndarray, max_lag: int = 2000, level: float = 0.1) -> int:
    """The residual's correlation length in samples: the first lag at which its autocorrelation
    (within trials, pooled) falls below ``level`` (at most ``max_lag``). The guard of hv-block
    cross-validation and the unit of the sample-level test are sized by it."""
    r = np.asarray(r, float)
    if r.size < 4:
        return 1
    r = r - r.mean()
    den = float(r @ r)
    if den <= 0:
        return 1
    same = trial[1:] == trial[:-1]
    for k in range(1, min(max_lag, r.size - 1) + 1):   # stops at the first small lag
        ok = trial[k:] == trial[:-k] if k > 1 else same
        num = float(r[k:][ok] @ r[:-k][ok]) * r.size / max(int(ok.sum()), 1)
        if num / den < level:
            return k
    return int(min(max_lag, r.size - 1))


#: fewest samples in a unit of the sample-level test (:func:`_sample_units`)
MIN_UNIT_SAMPLES = 20
#: most units of the sample-level test per channel (Gram matrices are summed per unit)
MAX_UNITS = 600


def _sample_units(blocks: np.ndarray, length: int) -> tuple[np.ndarray, np.ndarray]:
    """Each motion cycle of ``blocks`` cut into ``round(n / length)`` (at least one) equal
    consecutive units. Returns (units (n, 2), parent block of each unit)."""
    units, parent = [], []
    for k, (s, e) in enumerate(blocks):   # loop over cycles
        n = int(e - s)
        m = max(int(round(n / max(length, 1))), 1)
        edges = s + np.round(np.linspace(0, n, m + 1)).astype(int)
        units += list(zip(edges[:-1], edges[1:]))
        parent += [k] * m
    return np.asarray(units, int).reshape(-1, 2), np.asarray(parent, int)


def _guard_masks(units: np.ndarray, unit_trial: np.ndarray, fold: np.ndarray, h: int) -> dict:
    """For each fold, the units of the same trial within ``h`` samples of its test units (not
    tested, left out of that fold's training): hv-block cross-validation (Racine 2000)."""
    out = {}
    if h <= 0:
        return out
    for f in np.unique(fold):
        test = fold == f
        g = np.zeros(fold.shape[0], bool)
        for tr in np.unique(unit_trial[test]):   # loop over the trials the fold touches
            same = (unit_trial == tr) & ~test
            ts, te = units[test & (unit_trial == tr), 0], units[test & (unit_trial == tr), 1]
            # units reaching within h samples of a test unit
            near = np.zeros(fold.shape[0], bool)
            for a, b in zip(ts, te):   # loop over the fold's test units in this trial
                near |= (units[:, 1] > a - h) & (units[:, 0] < b + h)
            g |= same & near
        if g.any():
            out[f] = g
    return out


@dataclass
class _TestDesign:
    """How one channel's held-out error is cut into units, folded and tested."""

    mode: str                 # "cycles" (sign-flip over motion cycles) or "samples" (HAC loss test)
    blocks: np.ndarray        # (n, 2) sample ranges of the units
    fold: np.ndarray          # (n,) held-out fold of each unit
    guard: dict               # fold -> units left out of its training (hv-block)
    n_cycles: int
    text: str = ""


def _test_design(d: JointData, ch: Channel, n_effects: int, settings: "DiagnosisSettings") -> _TestDesign:
    """The units and folds of one channel's test. Campaigns with enough motion cycles keep the
    block sign-flip test over cycles with their repetitions as folds; when that test cannot
    reach Holm's first threshold (a record with a few cycles, a campaign of one or two trials),
    power comes from the samples: each cycle is cut into short units, the folds are the trials
    (or, with one trial, its cycles), the units within the residual's correlation length of a
    test fold are left out of its training (hv-block), and the loss differential is tested with
    a HAC variance (:func:`ident.gap.engine.loss_differential_test`)."""
    fold_c = ch.block_fold(d.fold)
    n_cycles = int(ch.blocks.shape[0])
    p_min = sign_flip_min_p(n_cycles, settings.n_perm)
    if settings.test != "samples" and len(np.unique(fold_c)) >= 2 and (
            settings.test == "cycles" or p_min * max(n_effects, 1) < settings.alpha):
        return _TestDesign("cycles", ch.blocks, fold_c, {}, n_cycles,
                           text=f"block sign-flip test over {n_cycles} motion cycles; folds: "
                                + ("repetitions" if len(np.unique(fold_c)) < n_cycles else "cycles"))
    # the nominal's residual on all data sets the correlation length (guard and unit length)
    X = ch.prep(ch.X0)
    r = ch.target - X @ np.linalg.lstsq(X, ch.target, rcond=None)[0] if X.shape[1] else ch.target
    h = correlation_samples(r, ch.trial)
    n = int(ch.target.shape[0])
    length = max(MIN_UNIT_SAMPLES, h, int(np.ceil(n / MAX_UNITS)))
    units, parent = _sample_units(ch.blocks, length)
    unit_trial = ch.block_trial[parent]
    if len(np.unique(fold_c)) >= 2:
        fold, ftext = fold_c[parent], "trials" if len(np.unique(fold_c)) < n_cycles else "cycles"
    else:
        fold, ftext = parent.copy(), "cycles"
    guard = _guard_masks(units, unit_trial, fold, h)
    return _TestDesign("samples", units, fold, guard, n_cycles,
                       text=f"HAC loss-differential test (Diebold-Mariano, Newey-West, HLN correction) over "
                            f"{units.shape[0]} units of ~{length} samples; folds: {ftext} "
                            f"(hv-block, guard {h} samples: the residual's correlation length)")


def _shape_text(cand: Candidate, hp, amps: np.ndarray) -> str:
    """The chosen shape in words; a torque delay's column scales with its amplitude to first order,
    so its delay is the grid's times the fitted amplitude (the sign says which signal is late)."""
    if cand.family == "torque_delay" and amps.size:
        dl = float(hp) * float(amps[0])
        return (f"the logged torque {'late' if dl > 0 else 'early'} by {abs(dl) * 1e3:.3g} ms against the logged "
                "position")
    return cand.describe(hp)


class _StepReference(NamedTuple):
    """What every effect's test in a selection step is measured against (:func:`_test_effect`)."""

    design: _TestDesign
    settings: "DiagnosisSettings"
    n_tot: int                # held-out samples
    mse_nom: float            # the nominal's held-out mean squared error
    excess_nom: float         # its excess over the white-noise floor
    noise: float              # the white-noise floor (mean squared)
    decl_ms: float            # mean square of the declared stiffness's deflection (transmission)
    p_min: float              # smallest p the test can give


def _test_effect(name: str, group: list, d: JointData, ch: Channel, X: np.ndarray, base, cache,
                 levels: tuple, current_sse: np.ndarray, ref: _StepReference):
    """One effect's test at one selection step: its best shape's held-out fit over every family
    and shape of ``group`` (:func:`_effect_grams`, :func:`_cv`), the test of its per-unit loss
    differential against the current model (block sign-flip over cycles, or the HAC loss test),
    and its size. Returns (the row, the loss differential, p), the last two None where nothing of
    the effect is identifiable."""
    design, settings, n_tot = ref.design, ref.settings, ref.n_tot
    gb, cols = _effect_grams(group, d, ch, X, base, cache, levels)
    if not gb:
        return _Row(name, EffectTest(name, ch.name, False, note=NOT_IDENTIFIABLE)), None, None
    cvr, _ = _cv(ch, X, design.fold, gb, guard=design.guard)
    cand, hp = cvr.hp_all
    amps = _amplitudes(cvr.theta_all, X.shape[1], cols[cvr.hp_all].keep)
    physical = bool(cand.physical(hp, amps, d))
    composed = cols[cvr.hp_all].composed
    dloss = current_sse - cvr.sse
    if design.mode == "cycles":
        p = sign_flip_pvalue(dloss, settings.n_perm, settings.seed)
        se = float(np.std(dloss, ddof=1) / np.sqrt(dloss.size)) if dloss.size > 1 else np.inf
    else:
        p, info = loss_differential_test(dloss)
        se = info["se"] / max(info.get("hln", 1.0), 1e-12) if np.isfinite(info["se"]) else np.inf
    # the size's one-sided 95 % lower bound: the removed variance per sample less 1.645
    # standard errors of its mean over the units
    lcb_mse = float((dloss.sum() - 1.645 * se * dloss.size) / n_tot)
    mse_e = float(cvr.sse.sum() / n_tot)
    mse_cur = float(current_sse.sum() / n_tot)
    mse_nom, excess_nom, noise = ref.mse_nom, ref.excess_nom, ref.noise
    row = _Row(name, EffectTest(
        name, ch.name, True, family=cand.family, physical=physical,
        note="" if physical else f"best fit has the unphysical sign for {name}: not this effect",
        heldout_rms=float(np.sqrt(mse_e)),
        reduction=float(1 - np.sqrt(mse_e / mse_nom)) if mse_nom > 0 else 0.0,
        reduction_step=float(1 - np.sqrt(mse_e / mse_cur)) if mse_cur > 0 else 0.0,
        explained_share=float((mse_cur - mse_e) / excess_nom) if excess_nom > 0 else 0.0,
        share_step=_share(mse_cur - mse_e, mse_cur - noise),
        p_value=p, p_min_attainable=ref.p_min,
        shape=_shape_text(cand, hp, amps) + ("; also times the selected effects' friction levels" if composed else ""),
        evidence={**_size_evidence(mse_cur - mse_e, noise, ref.decl_ms),
                  "removed_variance_over_floor_lcb95": _over_floor(lcb_mse, noise)}), cvr,
        {cvr.hp_all: cols[cvr.hp_all]})   # the chosen shape's recipe (its columns are rebuilt)
    return row, dloss, p


def _mark_significant(rows: dict, pvals: dict, ch: Channel, settings: "DiagnosisSettings", mode: str) -> None:
    """Holm's adjustment over the step's identifiable effects, then each row's significance: a
    physical sign, the adjusted p below ``alpha``, the step's share and reduction above their
    minimums and the removed variance's 95 % lower bound above the effect-size floor
    (:func:`effect_size_floor`)."""
    adj = holm(pvals)
    for name, r in rows.items():
        if not r.test.identifiable:
            continue
        t = r.test
        floor = effect_size_floor(ch.name, t.family, settings, mode)
        r.test = replace(t, p_adjusted=adj[name], evidence={**t.evidence, "effect_size_floor": floor},
                         significant=bool(
            t.physical and adj[name] < settings.alpha and t.share_step >= settings.min_explained
            and t.reduction_step >= settings.min_reduction
            and t.evidence["removed_variance_over_floor_lcb95"] >= floor))


def _channel_stepwise(d: JointData, ch: Channel, cands, settings: DiagnosisSettings) -> _ChannelRun:
    by_effect: dict = {}
    for c in cands:
        if c.channel == ch.name:
            by_effect.setdefault(c.name, []).append(c)
    design = _test_design(d, ch, len(by_effect), settings)
    ch = replace(ch, blocks=design.blocks)
    fold = design.fold
    n_per_trial = ch.blocks[:, 1] - ch.blocks[:, 0]   # per unit (motion cycle or part of one)
    X = ch.prep(ch.X0)
    base = grams(X, ch.target, ch.blocks)
    base_cv, _ = _cv(ch, X, fold, base=base, guard=design.guard)
    extrapolated = (float(np.mean(heldout_leverage(base, X, ch.blocks, fold, design.guard) > 1.0))
                    if X.shape[1] else 0.0)
    nominal_sse = base_cv.sse.copy()
    # residual of the nominal fit on all data -> white-noise floor
    resid_all = ch.target - X @ base_cv.theta_all if X.shape[1] else ch.target
    noise = white_noise_floor(resid_all, ch.trial)
    n_tot = max(n_per_trial.sum(), 1)
    mse_nom = float(nominal_sse.sum() / n_tot)
    excess_nom = max(mse_nom - noise, 0.0)
    steps, tested_first = [], None
    current_sse = nominal_sse
    cache = _ColumnCache()
    n_blocks = int(np.sum(n_per_trial > 0))
    p_min = (sign_flip_min_p(n_blocks, settings.n_perm) if design.mode == "cycles"
             else loss_test_min_p(n_blocks))
    step_d = {}      # effect -> loss differentials of the latest step (power given the model reached)
    decl_ms = float(np.mean(ch.declared ** 2)) if ch.declared is not None and ch.declared.size else 0.0
    levels = (None, None)   # fitted Coulomb / viscous levels of the effects selected so far (torque)
    payload = None
    unnamed, unnamed_step = None, 0
    ref = _StepReference(design, settings, n_tot, mse_nom, excess_nom, noise, decl_ms, p_min)
    for step in range(settings.max_effects + (PAYLOAD_COM in by_effect)):
        if len(steps) >= settings.max_effects:
            break
        rows, pvals = {}, {}
        step_d = {}
        for name, group in by_effect.items():
            rows[name], dloss, p = _test_effect(name, group, d, ch, X, base, cache, levels, current_sse, ref)
            if dloss is not None:
                step_d[name], pvals[name] = dloss, p
        _mark_significant(rows, pvals, ch, settings, design.mode)
        if tested_first is None:
            tested_first = rows
        sig = [r for r in rows.values() if r.test.significant]
        if not sig:
            break
        best = _discriminate(sig, rows, ch, X, d, cache, settings.min_effect_to_floor_global)
        t = best.test
        if best.effect in UNNAMED:   # outside the vocabulary: never a verdict, the selection stops
            hp = best.cv.hp_all[1]
            unnamed, unnamed_step = replace(t, evidence={**t.evidence, "shape_parameter": list(hp) if isinstance(
                hp, tuple) else hp}), step
            break
        C, keep = best.cols[best.cv.hp_all].build(d, ch, cache), best.cols[best.cv.hp_all].keep
        if best.effect == PAYLOAD_COM:   # a wrong declaration, not an effect: it joins the nominal
            same = tuple(n for n in GAIN_LIKE if n in rows and rows[n].test.significant
                         and rows[n].test.evidence.get(f"unique_share_given_{PAYLOAD_COM}", 1.0) < SAME_TERM)
            payload = _Nuisance(C, _amplitudes(best.cv.theta_all, X.shape[1], keep), t, same)
        else:
            steps.append((SelectionStep(t.effect, ch.name, t.heldout_rms, t.reduction, t.p_adjusted,
                                        t.explained_share, t.shape, t.family,
                                        t.evidence["removed_variance_over_floor"]), best.cv.sse))
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
                       current_sse, n_blocks, p_min, n_tested, design, step_d, extrapolated, payload,
                       unnamed, unnamed_step)


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


def _heldout_residual(ch: Channel, cv: CVResult, design: _TestDesign) -> np.ndarray:
    """Held-out residual of the nominal model: each fold's samples against the fit without it
    (the thetas of the nominal cross-validation, not refitted). Samples of no tested unit stay 0."""
    r = np.zeros_like(ch.target)
    X = ch.prep(ch.X0)
    for f, th in cv.theta_per_fold.items():
        for s0, e0 in design.blocks[design.fold == f]:   # loop over the fold's units
            r[s0:e0] = ch.target[s0:e0] - X[s0:e0] @ th
    return r


def _channel_result(ch: Channel, res: _ChannelRun, settings: DiagnosisSettings) -> ChannelResult:
    n = res.n
    return ChannelResult(
        ch.name, ch.unit, float(np.sqrt(res.mse_nominal)), bootstrap_ci(res.nominal_sse, n, seed=settings.seed),
        _rms(res.final_sse, n), bootstrap_ci(res.final_sse, n, seed=settings.seed),
        float(np.sqrt(res.noise_floor_mse)), tuple(s for s, _ in res.steps), n_blocks=res.n_blocks,
        p_min_attainable=res.p_min, extrapolated=res.extrapolated,
        nuisance=(PAYLOAD_COM,) if res.payload is not None else ())


def _selection_order(chres: dict) -> list:
    """Selected effects, most telling first: each channel's first selection (transmission before
    torque, as for the verdict), then the later steps in the order they joined their models."""
    order = [c for c in ("transmission", "torque") if c in chres]
    firsts = [chres[c].selected[0] for c in order if chres[c].selected]
    return firsts + [s for c in order for s in chres[c].selected[1:]]


class GapDiagnosis:
    """The sim-to-real gap diagnosis of one joint as an estimator.

    ``GapDiagnosis(nominal, families, settings).fit(data) -> DiagnosisResult``: the held-out
    residual of the nominal model (the declared joint, rigid or the flexible joint of thesis
    eq. 2-1, 2-2, with URDF rigid-body dynamics and Coulomb + viscous friction, eq. 2-5 [1]_)
    is tested against every candidate effect by cross-validation, a sign-flip randomisation
    test over motion cycles with Holm's correction [2]_ and effect-size floors, then forward
    stepwise selection and a bootstrap over trials (module docstring; [3]_).

    Parameters
    ----------
    nominal : str
        The simulator's model the gap is measured against (``jointlab diagnose --nominal``;
        :func:`ident.gap.nominal.nominal_model`).
    families : iterable of str, optional
        Candidate families to test (names of :data:`ident.gap.candidates.FAMILIES`); all by default.
    settings : DiagnosisSettings, optional
        Levels, floors and the test (``settings.nominal`` is replaced by ``nominal``).

    References
    ----------
    .. [1] PA10 thesis (seeds 002), eq. 2-1, 2-2, 2-5.
    .. [2] Holm 1979, a simple sequentially rejective multiple test procedure.
    .. [3] jointlab gap diagnosis (docs/gap-diagnosis.md).
    """

    def __init__(self, nominal: str = "cv", families=None, settings: DiagnosisSettings | None = None):
        self.settings = replace(settings or DiagnosisSettings(), nominal=nominal)
        self.families = None if families is None else frozenset(families)

    def fit(self, data: JointData, gear_ratio: float | None = None) -> DiagnosisResult:
        """Diagnose ``data`` (:class:`ident.gap.data.JointData`); ``gear_ratio`` sets the ripple
        orders tested (the wave generator's and its harmonics)."""
        with one_blas_thread():
            return _diagnose_joint(data, self.settings, gear_ratio, self.families)


def diagnose_joint(d: JointData, settings: DiagnosisSettings = DiagnosisSettings(),
                   gear_ratio: float | None = None) -> DiagnosisResult:
    """Diagnose the sim-to-real gap of one joint: :class:`GapDiagnosis` with ``settings``.

    ``GapDiagnosis(settings.nominal, None, settings).fit(d, gear_ratio)``: every candidate
    family, the nominal model named by the settings (module docstring; [1]_ [2]_).

    Parameters
    ----------
    d : JointData
        The joint's samples (:func:`ident.gap.data.build_joint_data`).
    settings : DiagnosisSettings, optional
        Levels, floors, the test and the nominal model; default ``DiagnosisSettings()``.
    gear_ratio : float or None, optional
        The joint's gear ratio, which sets the ripple orders tested; None: the generic orders.

    Returns
    -------
    DiagnosisResult
        The verdict, the tests of every candidate, the channels' held-out fits and where the
        gap lies.

    References
    ----------
    .. [1] PA10 thesis (seeds 002), eq. 2-1, 2-2, 2-5.
    .. [2] jointlab gap diagnosis (docs/gap-diagnosis.md).
    """
    return GapDiagnosis(settings.nominal, None, settings).fit(d, gear_ratio)


def _joint_candidates(d: JointData, gear_ratio: float | None, families=None) -> list:
    """The candidates one joint is tested with: the registry's effects (the torque's own delay on
    continuous records only), the terms outside the vocabulary (:mod:`ident.gap.unnamed`) and a
    payload-COM term where a declaration can be wrong; ``families`` keeps only those families."""
    q_range = float(np.ptp(np.percentile(d.q, [0.5, 99.5]))) if d.q.size else None
    cands = [c for c in candidate_effects(gear_ratio, q_range) if families is None or c.family in families]
    if d.delay_cols is None:   # the torque's own delay is tested on continuous records only
        cands = [c for c in cands if c.family != "torque_delay"]
    cands += [c for c in unnamed_candidates(d) if families is None or c.family in families]
    pc = _payload_candidate(d)
    return cands + ([pc] if pc is not None else [])


def _payload_note(payload: _Nuisance, d: JointData) -> str:
    """The report's note when the loaded trials' torque contradicts their payload-COM declaration."""
    t, same = payload.test, payload.same_term
    return (f"payload_com: the loaded trials' torque contradicts the payload centre of mass at the "
            f"flange origin that their missing payload_com declares (FORMAT.md): a COM away from it "
            f"removes {t.evidence['removed_variance_over_floor']:.3g} noise variances (p {t.p_adjusted:.2g}); "
            f"the diagnosis treats it as unknown (free [qdd, sin q, cos q] on those trials)"
            + ("" if any(getattr(tr, "load_kg", 0) == 0 for tr in d.trials) else
               "; with no unloaded trial to compare, a rigid-body error of the arm's URDF reads the same")
            + (f"; {' and '.join(same)} also explain{'s' if len(same) == 1 else ''} this term (a "
               f"gain on the payload's torque): with the COM declared they separate" if same else "")
            + "; declare the measured payload_com")


def _power(runs: dict, cands: list, settings: DiagnosisSettings) -> dict:
    """Per channel, the smallest effect it could have shown (noise-variance units): its test's
    detectable size, at least the effect-size floor of its least demanding family."""
    power = {}
    for c, r in runs.items():
        floor = min(effect_size_floor(c, fam, settings, r.design.mode if r.design else "cycles") for fam in
                    {cd.family for cd in cands if cd.channel == c} or {""})
        power[c] = max(r.detectable(settings.alpha), floor)
    return power


def _diagnose_joint(d: JointData, settings: DiagnosisSettings, gear_ratio: float | None,
                    families=None) -> DiagnosisResult:
    nominal = nominal_model(settings.nominal)
    cands = _joint_candidates(d, gear_ratio, families)
    channels = [_torque_channel(d, nominal)] + ([None] if d.has_transmission else [])
    effects, chres = [], {}
    runs, notes = {}, []
    for k, ch in enumerate(channels):
        dc = d
        if ch is None:   # the transmission channel, with the payload torque the torque channel fitted
            tr = runs["torque"]
            dc = payload_corrected(d, tr.nominal_cv.theta_all)
            if tr.payload is not None:
                dc = payload_corrected(dc, tr.payload.amplitudes, tr.payload.columns)
            ch = channels[k] = _transmission_channel(dc)
        res = _channel_stepwise(dc, ch, cands, settings)
        runs[ch.name] = res
        stab = _stability(res, settings)
        chres[ch.name] = _channel_result(ch, res, settings)
        if res.payload is not None:
            notes.append(_payload_note(res.payload, d))
        for name, row in res.first.items():
            if name == PAYLOAD_COM or name in UNNAMED:
                continue
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
    tch, tres = channels[0], runs["torque"]
    resid = _heldout_residual(tch, tres.nominal_cv, tres.design)
    localisation, rest = _localise(d, tres.noise_floor_mse, resid)
    dt = float(np.median(np.diff(d.t_rel[:1000]))) if d.t_rel.size > 2 else 0.005
    rep_var = repetition_noise_floor(resid, d.trial, d.t_rel, d.group[:d.n_trials], 1.0 / dt)
    chres["torque"] = replace(chres["torque"], noise_floor_rms_repetitions=(
        float(np.sqrt(rep_var)) if np.isfinite(rep_var) else None))
    # power: the smallest effect each channel could have shown (noise-variance units), at least
    # the effect-size floor of its least demanding family
    power = _power(runs, cands, settings)
    spectrum = residual_spectrum(resid, tch.trial, dt, tres.noise_floor_mse)
    # held-out torque folds that extrapolate the nominal: the torque test cannot judge any effect
    # (a transmission-channel finding has its own folds and nominal, and stands)
    named = verdict
    extrapolated = tres.extrapolated if (tres.extrapolated > EXTRAPOLATED_SHARE and not (
        "transmission" in chres and chres["transmission"].selected)) else 0.0
    if extrapolated:
        verdict = "none"
    status, insufficient, next_exp = _status(verdict, runs, power, settings, d, spectrum, localisation,
                                             named, extrapolated, rep_var)
    config_loc = ()
    if d.q_all is not None and status in ("unexplained", "none", "effect") and not extrapolated:
        status, insufficient, next_exp, config_loc = _unnamed_status(
            d, tres, resid, status, insufficient, next_exp, verdict, notes)
    alternatives = _alternatives(verdict, runs, d)
    if alternatives and not next_exp:
        next_exp = {"why": f"{verdict} and {', '.join(a['effect'] for a in alternatives)} explain the same term",
                    "proposal": alternatives[0]["separate_by"],
                    "command": _design_command(d)}
    effects.sort(key=lambda r: (not r.significant, -(r.reduction or 0.0)))
    return DiagnosisResult(
        verdict=verdict, nominal_model=nominal.label, n_trials=d.n_trials,
        folds=_folds_text(d, runs),
        channels=chres, effects=tuple(effects), insufficient=insufficient,
        selected=tuple(s.effect for s in _selection_order(chres)),
        localisation=tuple(localisation), localisation_rest=rest,
        localisation_method="decomposition of the held-out excess over non-overlapping motion regimes "
                            "(priority " + " > ".join(PARTITION) + "; the remainder is 'rest')",
        status=status, detectable=power, alternatives=alternatives, next_experiment=next_exp,
        spectrum_bands=tuple(spectrum["bands"]) if spectrum else (),
        tests={c: r.design.text for c, r in runs.items() if r.design is not None},
        extrapolated=extrapolated, series=_series(d, resid, spectrum), notes=tuple(notes),
        configuration_localisation=tuple(config_loc))


def _series(d: JointData, resid: np.ndarray, spectrum) -> dict:
    """The samples the plots draw: states, the nominal's held-out residual, its spectrum, and on
    records every joint's angle (the configuration plot)."""
    series = {"t": d.t, "qd": d.qd, "qdd": d.qdd, "q": d.q, "residual_nominal": resid, "trial": d.trial,
              "spectrum": spectrum}
    if d.q_all is not None:
        series["q_all"] = d.q_all
    return series


def _variable_text(row: dict) -> str:
    """``q2``, or ``q1 or q2`` when the record's motion does not tell them apart."""
    return " or ".join([row["variable"]] + list(row.get("tied_with", ())))


def _sample_folds(design: "_TestDesign", n: int) -> tuple[np.ndarray, np.ndarray]:
    """(held-out fold of every sample, mask of the samples of tested units)."""
    fold, tested = np.zeros(n, int), np.zeros(n, bool)
    for (s0, e0), f in zip(design.blocks.tolist(), design.fold.tolist()):   # loop over units
        fold[s0:e0], tested[s0:e0] = f, True
    return fold, tested


def _unnamed_status(d: JointData, tres: "_ChannelRun", resid: np.ndarray, status: str, text: str,
                    next_exp: dict, verdict: str, notes: list) -> tuple:
    """The status when a term outside the vocabulary (:mod:`ident.gap.unnamed`) led a selection
    step, and where an unexplained gap lies in configuration space. A term that led the first
    step makes the joint ``unexplained`` (whatever the size of the gap: it passed every gate of an
    effect); at a later step the verdict stands and a note says what else is there. Returns
    (status, text, next experiment, configuration localisation rows)."""
    u = tres.unnamed
    loc = []
    if status == "unexplained" or u is not None:
        fold, tested = _sample_folds(tres.design, resid.shape[0])
        loc = configuration_localisation(d, resid, fold, tres.noise_floor_mse, tested)
    top = (f"depends on {_variable_text(loc[0])} (held out, {loc[0]['share']:.0%} of the gap's excess)"
           if loc and loc[0]["share"] > 0 else "")

    if u is None:
        if status == "unexplained" and top:
            text = f"{text}; in configuration space it {top}"
        return status, text, next_exp, loc
    size = u.evidence.get("removed_variance_over_floor")
    what = (f"{u.shape}, removing {size:.3g} noise variances held out" if size is not None else u.shape)
    if tres.unnamed_step > 0 or verdict != "none":
        notes.append(f"beside {verdict}: {what}; not a vocabulary effect" + (f"; the residual {top}" if top else ""))
        return status, text, next_exp, loc
    text = (f"a held-out torque gap that no effect of the vocabulary explains: {what}"
            + (f"; it {top}" if top else ""))
    nxt = {"why": "a torque outside the effect vocabulary",
           "proposal": ("check for a spring balancer, a cable or hose, or a rigid-body error on the joints "
                        "named; the residual is plotted against that variable" if u.effect != "torque_lowpass"
                        else "check the torque logging chain's filters (a low-pass of the logged torque "
                             "lags and attenuates it near its cut-off)")}
    return "unexplained", text, nxt, loc


#: the held-out gap above the white-noise floor, in units of the floor's variance, from which a
#: gap that no effect explains is reported as ``unexplained`` rather than ``none``. Effect-free
#: foreign campaigns leave 0.35-0.6 (command jitter through quantisation, the feedback column's
#: residue); a gap of a full noise variance is beyond what an adequate nominal leaves.
UNEXPLAINED_EXCESS = 1.0
#: the share of held-out torque samples with a leverage above 1 under their fold's training rows
#: (:func:`ident.gap.engine.heldout_leverage`) above which the verdict is ``insufficient_data``:
#: the held-out folds extrapolate the nominal model, so the held-out test judges nothing
#: (the shares measured on excitation records and point-to-point logs: docs/gap-diagnosis.md)
EXTRAPOLATED_SHARE = 0.05
#: effect -> the experiment that separates it from its confounders (the registry's)
#: the size (noise-variance units) below which a channel is called powerful enough: an effect
#: removing less than this is what the acceptance calls too small for any method to see
POWER_TARGET = 0.3
#: frequency bands of the held-out residual's spectrum (Hz, upper edges; the last is Nyquist)
BANDS_HZ = (1.0, 3.0, 10.0)


def residual_spectrum(resid: np.ndarray, trial: np.ndarray, dt: float, noise_mse: float) -> dict:
    """Welch spectrum of the held-out nominal residual (each trial's kept samples taken at the
    median step; the few left-out slow samples are bridged) against the white-noise floor's flat
    density ``2 sigma^2 dt``, and the share of the excess power (above the floor) in each band of
    :data:`BANDS_HZ`. Empty when the record is too short."""
    from scipy.signal import welch

    segs = [resid[trial == k] for k in np.unique(trial)]
    segs = [x for x in segs if x.size >= 64]
    if not segs or not np.isfinite(noise_mse) or dt <= 0:
        return {}
    nper = int(min(1024, min(x.size for x in segs)))
    f = None
    acc, wsum = 0.0, 0
    for x in segs:   # loop over trials
        f, pxx = welch(x - x.mean(), fs=1.0 / dt, nperseg=nper)
        acc = acc + pxx * x.size
        wsum += x.size
    pxx = acc / wsum
    floor = 2.0 * noise_mse * dt
    excess = np.clip(pxx - floor, 0, None)
    df = float(f[1] - f[0]) if f.size > 1 else 1.0
    tot = float(excess.sum() * df)
    edges = (0.0,) + BANDS_HZ + (float(f[-1]) + df,)
    bands = []
    for lo, hi in zip(edges[:-1], edges[1:]):
        m = (f >= lo) & (f < hi)
        e = float(excess[m].sum() * df)
        bands.append({"band_hz": [lo, min(hi, float(f[-1]))], "excess_share": e / tot if tot > 0 else 0.0,
                      "excess_over_floor": e / max(noise_mse, 1e-300)})
    return {"f": f, "psd": pxx, "floor": floor, "bands": bands}


def _folds_text(d: JointData, runs: dict) -> str:
    r = runs.get("torque")
    if r is not None and r.design is not None and r.design.mode == "samples":
        return "hv-block: " + r.design.text.split("folds: ", 1)[-1]
    return "leave-one-repetition-out" if len(set(d.fold.tolist())) < d.n_trials else "leave-one-trial-out"


def _status(verdict: str, runs: dict, power: dict, settings: DiagnosisSettings, d: JointData,
            spectrum: dict, localisation, named: str = "none", extrapolated: float = 0.0,
            rep_var: float = float("nan")) -> tuple:
    """(status, text, next experiment) of the verdict: ``effect``; ``none`` (the gap is at the
    noise floor, and the data could have shown an effect of the stated size); ``unexplained``
    (a gap above the floor that no effect of the vocabulary explains: where it lies by regime and
    frequency band); ``insufficient_data`` (the held-out folds extrapolate the nominal model, see
    :data:`EXTRAPOLATED_SHARE`, or the data could not have shown an effect of
    :data:`POWER_TARGET` noise variances: what to record next). ``extrapolated``: the share of
    held-out torque samples that extrapolate, when it decides the verdict (0 otherwise);
    ``named``: the effect the selection named before that set the verdict to ``none``;
    ``rep_var``: the torque noise variance from repetitions of the same trajectory
    (:func:`ident.gap.engine.repetition_noise_floor`, NaN without repetitions): a gap is
    unexplained only above both floors (coloured noise leaves a gap over the white one that the
    repetitions show to be noise)."""
    tr = runs["torque"]
    if extrapolated:
        sel = (f"; the selection named {named} on these folds, which it cannot test" if named != "none" else "")
        text = (f"the record does not repeat its motion: {extrapolated:.0%} of the held-out torque samples "
                "lie where the rest of the record does not determine the nominal model (leverage above 1, e.g. "
                "a direction of motion seen in one motion cycle only), so their held-out gap says nothing about "
                f"unmodelled effects{sel}; record the motion at least twice, or an excitation that reverses "
                "many times")
        return "insufficient_data", text, {
            "kind": "excitation", "why": "the held-out motion cycles extrapolate the nominal model",
            "proposal": "repeat the trajectory (two or more cycles in each direction), or record an excitation",
            "command": _design_command(d)}
    if verdict != "none":
        return "effect", "", {}
    det = power.get("torque", float("inf"))
    # the gap the model leaves: the nominal's, or with a contradicted payload declaration the
    # nominal's with the payload COM joined (it is not an effect, and not unexplained)
    mse = (float(np.sum(tr.final_sse) / max(float(np.sum(tr.n)), 1.0)) if tr.payload is not None
           else tr.mse_nominal)
    excess = (mse / tr.noise_floor_mse - 1.0) if tr.noise_floor_mse > 0 else float("inf")
    excess_rep = (mse / rep_var - 1.0) if np.isfinite(rep_var) and rep_var > 0 else float("inf")
    seconds = float(np.sum(tr.n)) * (float(np.median(np.diff(d.t_rel[:1000]))) if d.t_rel.size > 2 else 0.0)
    if excess > UNEXPLAINED_EXCESS and np.isfinite(excess) and excess_rep > UNEXPLAINED_EXCESS:
        where = ", ".join(f"{r['regime']} {r['share']:.0%}" for r in localisation[:3])
        bands = ", ".join(f"{b['band_hz'][0]:g}-{b['band_hz'][1]:.3g} Hz {b['excess_share']:.0%}"
                          for b in (spectrum.get("bands") or []))
        rep = (f" and {excess_rep:.2g} above the floor from repetitions" if np.isfinite(excess_rep) else "")
        text = (f"a held-out torque gap {excess:.2g} noise variances above the white-noise floor{rep} that no "
                f"effect of the vocabulary explains (by regime: {where or '-'}; by frequency: {bands or '-'})")
        return "unexplained", text, {
            "why": "the nominal model misses something outside the effect vocabulary, or the noise is not white",
            "proposal": "check the rigid-body model (payload, URDF inertias, coupled joints) and the logged torque's "
                        "bandwidth (a controller or structural resonance shows as a band above a few Hz); repeat "
                        "the same trajectory to measure the noise floor from repetitions"}
    if det > POWER_TARGET or all(r.powerless(settings.alpha) for r in runs.values()):
        factor = (det / POWER_TARGET) if np.isfinite(det) else float("inf")
        more = (f"about {factor:.1f}x this record's {seconds:.0f} s of motion" if np.isfinite(factor)
                else "several repetitions or a longer record with more motion cycles")
        text = (f"insufficient data: the smallest effect this record could have shown removes "
                f"{det:.2g} noise variances (goal {POWER_TARGET:g}); record {more}")
        return "insufficient_data", text, {
            "kind": "excitation", "seconds": float(seconds * factor) if np.isfinite(factor) else None,
            "proposal": f"repeat the excitation ({more})", "command": _design_command(d)}
    return "none", "", {}


def _design_command(d: JointData) -> str:
    """The `jointlab design` line that writes an excitation of this joint at full speed."""
    return f"jointlab design --robot CAMPAIGN --joint {d.joint} --vmax-frac 1 --out next-excitation"


def _alternatives(verdict: str, runs: dict, d: JointData) -> tuple:
    """Effects that explain the same term as the verdict within the data's resolution (each keeps
    less than a third of its reduction given the other, both significant), and the payload's
    centre of mass when the verdict is a torque gain or load-dependent friction on trials whose
    payload COM is undeclared (FORMAT.md then puts it at the flange origin: a declaration that
    may be wrong) or unknown. Each: (name, why, how to separate)."""
    out = []
    if verdict == "none":
        return ()
    for r in runs.values():
        row = r.first.get(verdict)
        if not r.steps or r.steps[0][0].effect != verdict or row is None:
            continue
        for k, x in row.test.evidence.items():
            if not k.startswith("unique_share_given_"):
                continue
            other = k[len("unique_share_given_"):]
            if other == PAYLOAD_COM:   # named below, with its own way to separate
                continue
            o = r.first.get(other)
            ub = o.test.evidence.get(f"unique_share_given_{verdict}") if o is not None else None
            if o is not None and o.test.significant and x < SAME_TERM and ub is not None and ub < SAME_TERM:
                out.append({"effect": other, "why": f"explains the same term (unique shares {x:.2f} / {ub:.2f})",
                            "separate_by": confounders(verdict)[1]})
        # a delay read in the torque alone: a transmission softer than declared (or with lost
        # motion) makes the link lag the motor, which the rigid-body torque of the motor angle reads
        # the same way; only the link's own angle (markers) separates them
        if (verdict == "time_offset" and row.cv is not None and row.cv.hp_all[0].family == "torque_delay"
                and not d.has_transmission):
            out.append({"effect": "compliance", "why": "a transmission softer than declared, or backlash, "
                        "lags the link behind the motor like a delay of the torque against the motor angle",
                        "separate_by": "markers on the link (the link-motor deflection follows the torque; "
                                       "a delay does not deflect anything)"})
        # a low-pass of the logged torque (a sensor or current-loop filter) is a delay of its group
        # delay at frequencies well below its cut-off: where the record's motion holds nothing near
        # the cut-off the two are one term (each keeps under SAME_TERM of its reduction given the
        # other); the low-pass is outside the vocabulary, so it is said beside the name
        lp = row.test.evidence.get(f"unique_share_given_{TORQUE_LOWPASS}")
        if verdict == "time_offset" and lp is not None and lp < SAME_TERM:
            out.append({"effect": TORQUE_LOWPASS,
                        "why": "a low-pass of the logged torque (sensor or current-loop filter, outside the "
                               f"vocabulary) is the same term in the band this record excites (unique share "
                               f"{lp:.2f})",
                        "separate_by": "an excitation with content near the filter's cut-off (tens of Hz): a "
                                       "delay keeps the torque's shape, a low-pass attenuates it"})
        # a gear efficiency (FORMAT.md's torque_scale) is friction proportional to the torque the
        # gear passes, i.e. a load-dependent friction in the friction literature: say so when it wins
        if (verdict == "torque_scale" and row.cv is not None and row.cv.hp_all[1] == "efficiency"
                and not any(a["effect"] == "load_dependent" for a in out)):
            out.append({"effect": "load_dependent", "why": "a direction-dependent gear efficiency is friction "
                        "proportional to the torque the gear passes (FORMAT.md names it torque_scale)",
                        "separate_by": confounders("load_dependent")[1]})
    loaded = [tr for tr in d.trials if getattr(tr, "load_kg", 0) > 0]
    com = [(getattr(tr, "extra", None) or {}).get("payload_com") for tr in loaded]
    if verdict in GAIN_LIKE and loaded and any(c is None or c == "unknown" for c in com):
        out.append({"effect": "payload_com", "why": "a payload centre of mass away from its declared place "
                    "changes the payload's torque like a gain on it" + (
                        " (payload_com not declared: FORMAT.md puts it at the flange origin)"
                        if any(c is None for c in com) else ""),
                    "separate_by": "declare the measured payload_com, or run the trajectory without payload and "
                                   "with the payload turned by 180 deg about the flange axis"})
    return tuple(out)

