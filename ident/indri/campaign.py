"""Campaign-level driver of the Indri & Trapani 2020 framework (paper 001; :mod:`ident.indri.framework`):
``jointlab fit CAMPAIGN --models arctan,dm1,dm2``.

Per joint, from the campaign's trials in which that joint moves alone (trials moving several
joints are left out with a note: the residual of eq. 25-26 is built for one moving joint):

1. every trial's robot log goes through :func:`ident.signals.smoothing.prepare_joint_signals` (Fourier
   fit, eq. 3-2, for ``excitation`` trials; the Savitzky-Golay smoother for the others, as in
   :mod:`ident.thesis.campaign`, with a shorter window for the reversals, :data:`REVERSAL_WINDOW_S`)
   and :func:`ident.indri.framework.friction_data_from_signals`: residual torque
   ``tau - tau_dm - J qmdd`` (eq. 25-26) with the braked joints at the median of their logged
   motor angles and the trial's payload (``load_kg`` at the optional ``payload_com`` key, flange
   frame, as in :mod:`ident.gap.data`). With an angles folder the link angle comes from
   ``angles/<trial id>.csv`` (gravity term); the friction velocity is the motor velocity.
2. **step 1** (static arctan model, eq. 1-2, 27-28): the ``constant_velocity`` trials, joined
   end to end (:func:`ident.indri.framework.concat_data`; they start and end at rest);
3. **phase 2-A** (dm1, eq. 5-9 with constant sigma1): the ``reversals`` trials split into data
   sets of one acceleration each by :func:`split_reversals` (the simulator's reversal trials,
   :func:`ident.excitation.trajectories.reversals`, hold several blocks of reversals, each at one constant
   acceleration ``|qdd| = a_k``, separated by rests; the manifest carries no per-block keys);
4. **phase 2-B** (dm2, eq. 23-24): alpha, beta over the phase 2-A sigma1 trend, ``a_max/v_max``
   from the fastest data set, gamma by prediction error on the ``excitation`` trials (joined
   end to end; each starts and ends at rest, so the bristle state is near zero at the joins).

What each model needs (an :class:`mocap.io.errors.InputError` names what is missing):
``arctan``: constant_velocity trials; ``dm1``: also reversals trials; ``dm2``: also reversals
at two or more accelerations and excitation trials.

fits.json (FORMAT.md): these models are identified per joint from several trials, so every
contributing trial gets the same joint-level parameters and standard errors under
``trials/<id>/<joint>/<model>``, with the ``rms`` of that model's prediction on that trial's
residual torque and ``"scope": "joint"``; the joint-level entries themselves (with settings
and the trials used) are under the extra top-level key ``joints/<joint>``. The ``summary`` list
is left to the per-trial models (a joint-level value has no spread over repetitions).

Each joint's Indri report (``indri.json``, ``phase2a.csv``, Table I over the excitation trials
as ``table1.csv``/``.md``, Figures 2/4/5 along the excitation data) goes to
``OUT/indri/joint<j>/`` (:func:`ident.indri.framework.write_report`).
"""
from __future__ import annotations

import json
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from mocap.io.errors import InputError

from ident.indri import framework as I
from ident.signals.smoothing import (FourierSmoother, SavGolSmoother, angles_path, one_blas_thread, prepare_joint_signals,
                      read_angles)

__all__ = ["DYNAMIC_MODELS", "JointDynamicData", "PartialIndriResult", "DynamicFits",
           "split_reversals", "joint_dynamic_data", "fit_campaign_dynamic", "merge_fits_json"]

DYNAMIC_MODELS = ("arctan", "dm1", "dm2")
#: Savitzky-Golay window of the reversals trials, s. Measured (jointlab synth --effect presliding,
#: 200 Hz log, joint 5): the default 0.1 s window smooths away the tracking transient that the
#: friction reversal causes in the velocity and biases phase 2-A's sigma0 by +10 %; 0.05 s: +2 %.
REVERSAL_WINDOW_S = 0.05


# ============================================================================================
# reversal data sets
# ============================================================================================
def split_reversals(data: I.FrictionData, *, rest_speed: float = 0.02, min_rest: float = 0.15,
                    level_tol: float = 0.2, pad: float = 0.2) -> list[I.FrictionData]:
    """Split one reversals acquisition into phase 2-A data sets of one acceleration each.

    A sample is *active* when ``|qd| > rest_speed * max|qd|`` or ``|qdd| > a_eps``
    (``a_eps``: 5 times the median |qdd| of the slow samples, at least 3 % of the 99th
    percentile of |qdd|): at a reversal the speed crosses zero but the acceleration stays at its
    plateau, so only the rests are inactive. Active runs closer than ``min_rest`` s are merged;
    each run's level is the median |qdd| of its samples above half its 90th percentile (the
    plateau of a triangle-wave block). Consecutive runs whose levels agree within
    ``level_tol`` (relative) form one data set, cut ``pad`` s into the rests around it, with
    ``accel`` = the median of its runs' levels. Data sets without a velocity reversal are
    dropped.
    """
    t = np.asarray(data.time, float)
    qd = np.abs(np.asarray(data.qd, float))
    aq = np.abs(np.asarray(data.qdd, float))
    vmax = float(qd.max())
    if vmax <= 0:
        return []
    slow = qd <= rest_speed * vmax
    a99 = float(np.percentile(aq, 99.0))
    a_eps = max(5.0 * float(np.median(aq[slow])) if slow.any() else 0.0, 0.03 * a99)
    active = (qd > rest_speed * vmax) | (aq > a_eps)
    e = np.diff(np.concatenate([[0], active.astype(np.int8), [0]]))
    starts, ends = np.flatnonzero(e == 1), np.flatnonzero(e == -1)   # [s, e) runs
    runs = []
    for s, f in zip(starts, ends):                   # loop over runs (tens)
        if runs and t[s] - t[runs[-1][1] - 1] < min_rest:
            runs[-1][1] = f
        else:
            runs.append([s, f])
    seg = []
    for s, f in runs:
        a = aq[s:f]
        if f - s < 5:
            continue
        plateau = a[a >= 0.5 * np.percentile(a, 90.0)]
        seg.append((s, f, float(np.median(plateau))))
    groups = []
    for s, f, lev in seg:
        if groups and abs(lev - groups[-1]["level"]) <= level_tol * max(lev, groups[-1]["level"]):
            g = groups[-1]
            g["end"] = f
            g["levels"].append(lev)
            g["level"] = float(np.median(g["levels"]))
        else:
            groups.append({"start": s, "end": f, "levels": [lev], "level": lev})
    out = []
    for k, g in enumerate(groups):
        lo = t[g["start"]] - pad
        hi = t[g["end"] - 1] + pad
        if k > 0:
            lo = max(lo, 0.5 * (t[groups[k - 1]["end"] - 1] + t[g["start"]]))
        if k + 1 < len(groups):
            hi = min(hi, 0.5 * (t[g["end"] - 1] + t[groups[k + 1]["start"]]))
        m = (t >= lo) & (t <= hi)
        v = np.asarray(data.qd, float)[m]
        if np.count_nonzero(np.diff(np.sign(v[np.abs(v) > rest_speed * vmax])) != 0) < 1:
            continue
        truth = None if data.truth is None else np.asarray(data.truth)[m]
        out.append(I.FrictionData(t[m], v, np.asarray(data.qdd, float)[m],
                                  np.asarray(data.tau, float)[m],
                                  label=f"{data.label}@a{g['level']:.3g}", accel=g["level"],
                                  truth=truth))
    return out


# ============================================================================================
# per-joint data
# ============================================================================================
@dataclass(frozen=True, eq=False)
class JointDynamicData:
    """One joint's acquisitions for the framework: ``trials`` (trial id -> FrictionData of the
    whole trial, kind in ``kinds``), step 1 data, the phase 2-A data sets and the phase 2-B
    (variable-velocity) data; None / empty where the campaign has no such trials."""

    joint: int
    trials: dict
    kinds: dict
    static: I.FrictionData | None
    reversals: tuple
    variable: I.FrictionData | None
    dt: float
    notes: tuple = ()

    def used(self, kinds) -> list[str]:
        return [tid for tid, k in self.kinds.items() if k in kinds]


def _trial_data(campaign, tr, joint: int, robot, angles_dir,
                reversal_window_s: float = REVERSAL_WINDOW_S) -> tuple[I.FrictionData, list[str]]:
    j0 = joint - 1
    notes = []
    if not Path(tr.log).is_file():
        raise InputError(f"trial {tr.id!r}: log file {tr.log} not found", path=tr.log, label=tr.id)
    log = campaign.read_log(tr, robot)
    qm, tau = log.qm[:, j0], log.tau[:, j0]
    if not np.isfinite(qm).any() or not np.isfinite(tau).any():
        raise InputError(f"trial {tr.id!r}: the log has no qm_{joint}/tau_{joint} data",
                         path=tr.log, label=f"qm_{joint}")
    t_ang = q_link = None
    if angles_dir is not None:
        p = angles_path(angles_dir, tr.id)
        track = read_angles(p)
        if joint in track.q:
            t_ang, q_link = track.time, track.q[joint]
        else:
            notes.append(f"{p} has no q_{joint}: the motor angle is used as the link angle")
    if tr.kind == "reversals":
        smoother = FourierSmoother(periodic=False, fallback=SavGolSmoother(window_s=reversal_window_s))
    else:
        smoother = FourierSmoother(periodic=None if tr.kind == "excitation" else False)
    sig = prepare_joint_signals(joint, log.time, qm, tau, t_ang, q_link,
                                time_offset=tr.extra.get("time_offset", 0.0), smoother=smoother)
    rest = np.nanmedian(np.where(np.isfinite(log.qm), log.qm, np.nan), axis=0)
    rest = np.where(np.isfinite(rest), rest, 0.0)
    p_com = tuple(float(x) for x in tr.extra.get("payload_com", (0.0, 0.0, 0.0)))
    rb = robot.with_payload(tr.load_kg, p_com) if tr.load_kg > 0 else robot
    return I.friction_data_from_signals(sig, rb, rest, label=tr.id), notes


def _needs(models) -> set:
    need = set()
    if models:
        need.add("constant_velocity")
    if {"dm1", "dm2"} & set(models):
        need.add("reversals")
    if "dm2" in models:
        need.add("excitation")
    return need


def joint_dynamic_data(campaign, joint: int, robot=None, angles_dir=None,
                       models=DYNAMIC_MODELS,
                       reversal_window_s: float = REVERSAL_WINDOW_S) -> JointDynamicData:
    """Read, smooth and split the trials of ``joint`` (1-based) that ``models`` need (see the
    module docstring); raises InputError naming the missing trial kinds."""
    robot = robot if robot is not None else campaign.load_robot()
    need = _needs(models)
    trials, kinds, notes = {}, {}, []
    for tr in campaign.trials:
        if joint not in tr.joints or tr.kind not in need:
            continue
        if len(tr.joints) > 1:
            notes.append(f"trial {tr.id!r} moves joints {list(tr.joints)}: left out (the residual "
                         "of eq. 25-26 is built for one moving joint)")
            continue
        with one_blas_thread():
            fd, n = _trial_data(campaign, tr, joint, robot, angles_dir, reversal_window_s)
        trials[tr.id], kinds[tr.id] = fd, tr.kind
        notes += n
    by = {k: [trials[t] for t, kk in kinds.items() if kk == k] for k in need}
    where = f"joint {joint} of campaign {campaign.name!r}"
    if "constant_velocity" in need and not by["constant_velocity"]:
        raise InputError(f"{', '.join(sorted(set(models) & set(DYNAMIC_MODELS)))} need(s) "
                         f"constant_velocity trials (step 1, the static arctan model) of {where}; "
                         "none found (jointlab synth --kinds constant_velocity,...)",
                         path=campaign.manifest)
    rev = []
    if "reversals" in need:
        if not by["reversals"]:
            raise InputError(f"{'dm2' if 'dm2' in models else 'dm1'} needs reversals trials of "
                             f"{where}; none found", path=campaign.manifest)
        for d in by["reversals"]:
            rev += split_reversals(d)
        if not rev:
            raise InputError(f"the reversals trials of {where} hold no velocity reversal",
                             path=campaign.manifest)
        if "dm2" in models and len({round(d.accel, 6) for d in rev}) < 2:
            raise InputError(f"dm2 needs reversals trials at two or more accelerations ({where}: "
                             f"found {sorted({round(d.accel, 3) for d in rev})} rad/s^2)",
                             path=campaign.manifest)
    if "excitation" in need and not by["excitation"]:
        raise InputError(f"dm2 needs excitation trials of {where} (variable-velocity data for gamma, "
                         "eq. 24); none found", path=campaign.manifest)
    static = (I.concat_data(by["constant_velocity"], label="constant_velocity")
              if by.get("constant_velocity") else None)
    variable = (I.concat_data(by["excitation"], label="excitation") if by.get("excitation")
                else None)
    if variable is not None:
        variable = replace(variable, truth=None)
    dts = np.concatenate([d.dt for d in trials.values()]) if trials else np.array([np.nan])
    return JointDynamicData(joint, trials, kinds, static, tuple(rev), variable,
                            float(np.median(dts)), tuple(notes))


# ============================================================================================
# results
# ============================================================================================
@dataclass(frozen=True, eq=False)
class PartialIndriResult:
    """Step 1 (and the DM1 comparison model) alone, when dm2 is not asked for: the same
    ``static``, ``dm1``, ``models``, ``fits_json()``, ``to_dict()`` as
    :class:`ident.indri.framework.IndriResult`."""

    static: object                       # FrictionFit (arctan)
    dm1: object | None = None            # FrictionFit (LuGreDM1) or None
    diagnostics: dict = field(default_factory=dict)

    @property
    def models(self) -> dict:
        out = {} if self.dm1 is None else {"DM1": self.dm1.model}
        out["SM"] = self.static.model
        return out

    def fits_json(self) -> dict:
        out = {"arctan": self.static.to_dict()}
        if self.dm1 is not None:
            out["dm1"] = self.dm1.to_dict()
        return out

    def to_dict(self) -> dict:
        return I._jsonable({"static": self.static.to_dict(),
                            "dm1": None if self.dm1 is None else self.dm1.to_dict(),
                            "diagnostics": self.diagnostics})


_MODEL_KEY = {"arctan": "SM", "dm1": "DM1", "dm2": "DM2"}


def _rms(model, data: I.FrictionData) -> float | None:
    try:
        r = np.asarray(data.tau, float) - I.model_torque(model, data)
    except ValueError:
        return None
    v = float(np.sqrt(np.mean(r ** 2)))
    return v if np.isfinite(v) else None


class DynamicFits(Mapping):
    """Joint (1-based) -> :class:`ident.indri.framework.IndriResult` (or :class:`PartialIndriResult` when
    dm2 is not asked for), with the data behind each fit (``data[joint]``), the asked
    ``models`` and writers for fits.json, the Indri reports and the C export."""

    def __init__(self, results: dict, data: dict, models: tuple, campaign: str = "", sink=None):
        self.sink = sink
        self._r = dict(results)
        self.data = dict(data)
        self.models = tuple(models)
        self.campaign = campaign

    def __getitem__(self, joint):
        return self._r[joint]

    def __iter__(self):
        return iter(self._r)

    def __len__(self):
        return len(self._r)

    def joint_entries(self, joint: int) -> dict:
        """fits.json entries of one joint: model -> {params, stderr, rms, ...} (FORMAT.md names)."""
        fj = self._r[joint].fits_json()
        return {m: fj[m] for m in self.models if m in fj}

    def trial_entries(self) -> dict:
        """``{trial id: {joint: {model: {params, stderr, rms, scope}}}}``: the joint-level
        parameters with each trial's own prediction RMS (see the module docstring)."""
        out: dict = {}
        for j, res in self._r.items():
            models = res.models
            for tid, d in self.data[j].trials.items():
                e = out.setdefault(tid, {}).setdefault(str(j), {})
                for m, ent in self.joint_entries(j).items():
                    e[m] = {"params": ent["params"], "stderr": ent["stderr"],
                            "rms": _rms(models[_MODEL_KEY[m]], d), "scope": "joint"}
        return I._jsonable(out)

    def joints_doc(self) -> dict:
        out = {}
        for j in self._r:
            d = self.data[j]
            ent = self.joint_entries(j)
            out[str(j)] = {"models": ent, "dt": d.dt,
                           "trials": {k: d.used([k]) for k in ("constant_velocity", "reversals",
                                                               "excitation")},
                           "reversal_datasets": [{"label": r.label, "accel": r.accel,
                                                  "v_max": r.v_max, "n": r.n} for r in d.reversals],
                           "notes": list(d.notes)}
        return I._jsonable(out)

    def fits_json(self) -> dict:
        """A complete fits.json document holding only these models."""
        return merge_fits_json({"format": 1, "trials": {}, "summary": []}, self)

    def export_models(self) -> dict:
        """``{"joint<j>": {model: FrictionModel}}`` for :func:`ident.indri.codegen.export_models_c`."""
        out = {}
        for j, res in self._r.items():
            ms = res.models
            out[f"joint{j}"] = {m: ms[_MODEL_KEY[m]] for m in self.models if _MODEL_KEY[m] in ms}
        return out

    def write_reports(self, out_dir, sink=None) -> dict:
        """``OUT/indri/joint<j>/``: :func:`ident.indri.framework.write_report` with Table I over the
        joint's excitation trials and Figures 2/4/5 along its excitation data (full results);
        ``indri.json`` alone for step-1/DM1-only results. ``sink``: default the one given to
        :func:`fit_campaign_dynamic`. Returns joint -> written paths."""
        sink = sink if sink is not None else self.sink
        paths = {}
        for j, res in self._r.items():
            d = self.data[j]
            od = Path(out_dir) / "indri" / f"joint{j}"
            if isinstance(res, I.IndriResult):
                tests = {tid: d.trials[tid] for tid in d.used(["excitation"])}
                tables = {"table1": I.performance_table(res.models, tests)} if tests else {}
                curves = I.figure_curves(res, d.variable) if d.variable is not None else None
                s = _PrefixSink(sink, f"indri/joint{j}") if sink is not None else None
                paths[j] = I.write_report(res, od, tables, curves, sink=s)
            else:
                od.mkdir(parents=True, exist_ok=True)
                p = od / "indri.json"
                p.write_text(json.dumps({"format": 1, "result": res.to_dict()}, indent=1))
                paths[j] = {"json": p}
        return paths


class _PrefixSink:
    """A sink proxy that files ``indri/...`` paths under ``prefix/...`` (one joint's report)."""

    def __init__(self, sink, prefix: str):
        self._s, self._p = sink, prefix

    def __getattr__(self, name):
        f = getattr(self._s, name)
        if not callable(f):
            return f

        def call(path, *a, **k):
            if isinstance(path, str) and path.startswith("indri/"):
                path = self._p + path[len("indri"):]
            return f(path, *a, **k)
        return call


def merge_fits_json(doc: dict, dyn: DynamicFits) -> dict:
    """Add the dynamic models of ``dyn`` to a fits.json document ``doc`` (e.g.
    :meth:`ident.thesis.campaign.FitsResult.to_dict`): entries under ``trials`` next to the per-trial
    models, and the joint-level entries under ``joints``. Returns a new document."""
    out = {"format": doc.get("format", 1), "trials": json.loads(json.dumps(doc.get("trials", {}))),
           "summary": list(doc.get("summary", []))}
    out.update({k: v for k, v in doc.items() if k not in out})
    for tid, joints in dyn.trial_entries().items():
        tj = out["trials"].setdefault(tid, {})
        for j, models in joints.items():
            tj.setdefault(j, {}).update(models)
    out.setdefault("joints", {}).update(dyn.joints_doc())
    return out


# ============================================================================================
# driver
# ============================================================================================
def fit_campaign_dynamic(campaign, joints=None, angles_dir=None, sink=None, *,
                         models=DYNAMIC_MODELS, estimator: I.IndriTrapani | None = None,
                         reversal_window_s: float = REVERSAL_WINDOW_S) -> DynamicFits:
    """The Indri & Trapani identification of every studied joint of ``campaign`` (a
    :class:`mocap.io.campaign.Campaign`): joint -> :class:`ident.indri.framework.IndriResult` (a
    :class:`DynamicFits` mapping). ``joints``: 1-based joints (default: every joint that some
    trial moves); ``models``: any of arctan, dm1, dm2 (step 1 alone for arctan; step 1 + the DM1
    comparison model on the slowest reversal data set for dm1; everything for dm2);
    ``estimator``: the :class:`ident.indri.framework.IndriTrapani` settings; ``reversal_window_s``: the
    Savitzky-Golay window of the reversals trials (:data:`REVERSAL_WINDOW_S`). ``sink``: Figures 2/4/5 are
    logged when the reports are written (:meth:`DynamicFits.write_reports`)."""
    models = tuple(m for m in DYNAMIC_MODELS if m in set(models))
    unknown = set(models) - set(DYNAMIC_MODELS)
    if not models or unknown:
        raise InputError(f"fit_campaign_dynamic: models must be among {', '.join(DYNAMIC_MODELS)}")
    est = estimator if estimator is not None else I.IndriTrapani()
    robot = campaign.load_robot()
    if joints is None:
        joints = sorted({j for tr in campaign.trials if tr.kind != "coastdown" for j in tr.joints})
    results, data = {}, {}
    for j in joints:                                      # loop over joints (few)
        d = joint_dynamic_data(campaign, int(j), robot, angles_dir, models, reversal_window_s)
        with one_blas_thread():
            try:
                if "dm2" in models:
                    res = est.fit(d.static, d.reversals, d.variable)
                else:
                    st = est.fit_static(d.static)
                    dm1 = None
                    if "dm1" in models:
                        slow = min(d.reversals, key=lambda r: r.accel)
                        dm1 = est.fit_dm1(st.model, slow, est.dm1_damping).fit
                    res = PartialIndriResult(st, dm1, {"dt": d.dt})
            except ValueError as exc:
                raise InputError(f"joint {j}: {exc}", path=campaign.manifest) from None
        results[int(j)], data[int(j)] = res, d
    return DynamicFits(results, data, models, campaign.name, sink)
