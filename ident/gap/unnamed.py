"""Terms outside the effect vocabulary, tested beside it on continuous multi-joint records.

FORMAT.md: "A torque that depends on the configuration but is not friction (a spring balancer, a
cable or hose) and a low-pass of the logged torque are not in this vocabulary: a diagnosis reports
them as `unexplained` (with where the residual lies), never under a name of this table."

A name is given only for an effect's own signature. Two generic terms compete with the named
candidates for that:

* :data:`CONFIGURATION`: a torque smooth in one joint's angle ``q_k`` (any joint, the diagnosed
  one included), added to the torque or modulating its Coulomb or viscous level (Legendre
  polynomials of the angle scaled to its range, degrees 1-5 added, 1-3 on the levels). A ripple of
  a few cycles over the motion's range, a friction level following the gravity torque, a
  torque drifting with a slowly moving joint: each is also a smooth function of the configuration
  over a short range. Such a candidate keeps its name only where its own term survives the
  configuration term (at least :data:`ident.gap.diagnose.SAME_TERM` of its reduction), or it fits
  the held-out data better by more than the test's resolution;
* :data:`TORQUE_LOWPASS`: a second-order low-pass of the logged torque. At low frequency it is a
  delay (``time_offset``); the delay keeps its name unless the low-pass fits the held-out data
  better by more than the test's resolution (its attenuation near the cut-off is its own
  signature).

When one of them leads, the joint is ``unexplained`` and :func:`configuration_localisation` says on
which variable the held-out residual depends (held out, by motion-cycle folds).
"""
from __future__ import annotations

import numpy as np

from ident.gap.candidates import LOWPASS_GRID, Candidate, _sg, _vref

#: a torque smooth in the configuration (a spring balancer, a cable or hose, a gravity or URDF error)
CONFIGURATION = "configuration"
#: a low-pass of the logged torque (a filter in the drive or the logger)
TORQUE_LOWPASS = "torque_lowpass"
UNNAMED = (CONFIGURATION, TORQUE_LOWPASS)
#: a joint's angle varies over at least this range (rad) to be a configuration variable
MIN_RANGE = 0.05
#: two configuration variables are told apart when one keeps at least this share of the first's
#: held-out reduction given the other (an excitation moves every joint on one fundamental, so
#: smooth functions of two angles can explain the same residual)
TIE_SHARE = 0.05


def _scaled(x: np.ndarray) -> np.ndarray:
    lo, hi = np.percentile(x, [0.5, 99.5])
    return np.clip(2 * (x - lo) / max(hi - lo, 1e-12) - 1, -1.5, 1.5)


def legendre(x: np.ndarray, deg: int) -> np.ndarray:
    """(N, deg) Legendre polynomials of degrees 1 to ``deg`` of ``x`` (Bonnet's recursion)."""
    out = np.empty((x.shape[0], deg))
    p0, p1 = np.ones_like(x), x
    for n in range(1, deg + 1):
        out[:, n - 1] = p1
        p0, p1 = p1, ((2 * n + 1) * x * p1 - n * p0) / (n + 1)
    return out


def _features(d, k: int) -> np.ndarray:
    """(N, 11) smooth functions of joint ``k``'s angle: added to the torque (degrees 1-5) and on
    the diagnosed joint's Coulomb and viscous levels (degrees 1-3)."""
    x = _scaled(d.q_all[:, k])
    P = legendre(x, 3)
    return np.column_stack([legendre(x, 5), P * _sg(d)[:, None], P * (d.qd / _vref(d))[:, None]])


def _config_columns(d, hp) -> np.ndarray:
    return _features(d, hp)


def _describe_config(hp) -> str:
    return (f"a torque smooth in q{hp + 1}, added or on the friction levels (outside the vocabulary: a "
            "spring, cable or hose, or a rigid-body error)")


def _lowpass_columns(d, hp) -> np.ndarray:
    return d.lowpass_cols[:, [hp]]


def _lowpass_physical(hp, th, d) -> bool:
    return th.shape[0] > 0 and 0.5 < th[0] < 2.0


def configuration_variables(d) -> list[int]:
    """0-based joints whose angle varies over at least :data:`MIN_RANGE` in ``d.q_all``."""
    if getattr(d, "q_all", None) is None:
        return []
    rng = np.ptp(np.percentile(d.q_all, [0.5, 99.5], axis=0), axis=0)
    return [k for k in range(d.q_all.shape[1]) if rng[k] >= MIN_RANGE]


def unnamed_candidates(d) -> list[Candidate]:
    """The terms outside the vocabulary for ``d`` (continuous records only: ``d.q_all``)."""
    ks = configuration_variables(d)
    if not ks:
        return []
    out = [Candidate(CONFIGURATION, "torque", tuple(ks), _config_columns, _describe_config, CONFIGURATION)]
    if getattr(d, "lowpass_cols", None) is not None:
        out.append(Candidate(TORQUE_LOWPASS, "torque", tuple(range(len(LOWPASS_GRID))), _lowpass_columns,
                             lambda hp: (f"logged torque low-passed at {LOWPASS_GRID[hp][0]:g} Hz (damping "
                                         f"{LOWPASS_GRID[hp][1]:g}): outside the vocabulary"),
                             TORQUE_LOWPASS, _lowpass_physical))
    return out


#: named families whose columns are themselves smooth functions of the configuration over a short
#: range (a ripple of a few cycles over the motion): against a configuration term that explains the
#: same term they must fit better, beyond the test's resolution and the floor, to keep their name
CONFIGURATION_SHAPED = frozenset({"ripple_additive", "ripple_modulation"})


def prefers_unnamed(unnamed: str, unique_named: float, same_term: float, tie_named_to_unnamed: bool,
                    tie_unnamed_to_named: bool, margin: float, floor: float, family: str = "") -> bool:
    """Whether the unnamed term replaces a named candidate that explains the same term.

    ``unique_named``: the named candidate's reduction left given the unnamed term; below
    ``same_term`` the unnamed term explains it. ``tie_named_to_unnamed``: the unnamed term fits the
    held-out units no worse than the named one (:func:`ident.gap.diagnose._heldout_tie`);
    ``tie_unnamed_to_named``: the named one fits no worse than the unnamed. ``margin``: the held-out
    variance the unnamed term removes beyond the named one (noise variances; negative when it
    removes less); ``floor``: the effect-size floor an effect must remove; ``family``: the named
    candidate's family. Against a named family that is itself a smooth function of the
    configuration (:data:`CONFIGURATION_SHAPED`: a ripple), the configuration term wins unless the
    ripple fits better held out beyond both the test's resolution and the floor (the name must show
    its own signature, a periodicity the smooth term cannot follow). Against any other family (a
    velocity, reversal, load or time signature, one or two columns against the configuration
    term's eleven) and for a low-pass against a delay, the term outside the vocabulary wins only
    when it fits better held out beyond both (the named reading is the simpler one)."""
    if unique_named >= same_term:
        return False
    if unnamed == CONFIGURATION and family in CONFIGURATION_SHAPED:
        return not (not tie_named_to_unnamed and -margin >= floor)
    return (not tie_unnamed_to_named) and margin >= floor


def _variables(d) -> list:
    """(name, features) of every variable the residual may depend on: each joint's angle (added,
    and on the diagnosed joint's Coulomb and viscous levels), the joint's velocity and
    acceleration, and time."""
    out = [(f"q{k + 1}", _features(d, k)) for k in configuration_variables(d)]
    out.append(("velocity", legendre(np.clip(d.qd / _vref(d), -1.5, 1.5), 5)))
    a = d.qdd / max(float(np.percentile(np.abs(d.qdd), 99)), 1e-12)
    out.append(("acceleration", legendre(np.clip(a, -1.5, 1.5), 5)))
    out.append(("time", legendre(_scaled(d.t), 5)))
    return out


def configuration_localisation(d, resid: np.ndarray, fold: np.ndarray, noise_mse: float,
                               tested: np.ndarray | None = None) -> list[dict]:
    """On which variable the held-out residual depends, by a held-out test.

    For each variable of :func:`_variables`, its smooth features are fitted to the nominal's
    held-out residual ``resid`` on all folds but one and evaluated on that one (``fold``: per
    sample, e.g. its motion cycle's held-out fold); the share of the residual's excess over the
    noise floor ``noise_mse`` each removes, held out. Sorted, largest first; ``tested`` masks the
    samples of tested units."""
    m = np.ones(resid.shape[0], bool) if tested is None else np.asarray(tested, bool)
    r, f = resid[m], fold[m]
    excess = max(float(np.mean(r ** 2)) - noise_mse, 1e-300)
    rows = []
    folds = np.unique(f)
    if folds.size < 2:
        return rows
    feats = {name: F[m] for name, F in _variables(d)}

    def heldout_sse(F):
        F = np.column_stack([F, np.ones(F.shape[0])])
        sse = 0.0
        for g in folds:   # loop over folds, vectorised over samples
            te = f == g
            th = np.linalg.lstsq(F[~te], r[~te], rcond=None)[0]
            sse += float(np.sum((r[te] - F[te] @ th) ** 2))
        return sse

    sse = {name: heldout_sse(F) for name, F in feats.items()}
    for name in feats:
        removed = float(np.mean(r ** 2)) - sse[name] / r.size
        rows.append({"variable": name, "share": max(removed, 0.0) / excess,
                     "removed_over_floor": max(removed, 0.0) / noise_mse if noise_mse > 0 else None})
    rows.sort(key=lambda x: -x["share"])
    # motions of an excitation are correlated: variables that explain nearly as much as the first
    # are told apart by an encompassing test, each one's held-out reduction left given the other's
    # features (the variable the term depends on keeps its part, a correlated one does not)
    close = [x for x in rows[1:4] if x["share"] >= 0.8 * rows[0]["share"] > 0]
    a0 = rows[0]["variable"]
    top_removed = max(float(np.sum(r ** 2)) - sse[a0], 1e-300)
    tied = {a0}
    for x in close:
        a, b = rows[0]["variable"], x["variable"]
        both = heldout_sse(np.column_stack([feats[a], feats[b]]))
        ua, ub = sse[b] - both, sse[a] - both    # each one's held-out reduction left given the other
        if a == a0 and max(ua, ub) < TIE_SHARE * top_removed:
            tied.add(b)
        if ub > ua:
            i = rows.index(x)
            rows[0], rows[i] = rows[i], rows[0]
    # variables neither of which keeps TIE_SHARE of the first's held-out reduction given the other:
    # this record's motion does not tell them apart (both are named)
    top = rows[0]["variable"]
    rows[0]["tied_with"] = sorted(tied - {top}) if top in tied else []
    return rows
