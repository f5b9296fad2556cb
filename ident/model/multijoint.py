"""Multi-joint trials of a campaign (``joints = [1, 2, ...]``, one continuous record) through the
rigid-body identification (:mod:`ident.model.rigidbody`): ``fits.json`` entries (FORMAT.md),
``rigidbody.json`` with every diagnostic, and a Markdown report that says what was done."""
from __future__ import annotations

import json
from dataclasses import dataclass, field
from functools import partial
from pathlib import Path

import numpy as np

from ident.common import to_jsonable
from ident.friction import MODELS
from ident.model.record import RecordSettings, coupling_matrix, load_record, prepare_record
from ident.friction.plausibility import Flag, fmt, meaning_line
from ident.gap import diagnose_joint
from ident.gap.data import build_joint_data_record, campaign_clock, concat_joint_data, standstill
from ident.gap.channels import torque_channel
from ident.gap.engine import cross_validate, grams
from ident.gap.nominal import check_nominal
from ident.model.identified import PooledRigidBody, identify_rigid_body, payload_key, record_rigid_body
from ident.model.regressor import ChainDynamics, base_parameters
from ident.study.executor import progress_bars
from ident.model.rigidbody import (_PREPARED, RigidBodyIdentifier, coulomb_over_cuts,
                                   dynamic_data_note, friction_transition, low_speed_cut,
                                   residual_knee, without_unlogged)
from ident.friction.presliding import presliding_length, reversal_displacement
from mocap.io.errors import warn_input
from mocap.io.robotlog import RobotLog


def _g(x) -> str:
    return "merged" if x is None else f"{x:.4g}"


def param_cell(v, flag: dict | None) -> str:
    """A table cell: the parameter ``v`` with its plausibility flag ``flag`` (a fit's
    ``flags[name]`` entry, or None), as :func:`ident.friction.plausibility.fmt` writes it."""
    return fmt(v, None if not flag else Flag(flag["flag"], flag["reason"]))


def armature_cell(v, flag: dict | None) -> str:
    """A table cell: the fitted armature ``v`` with its flag (:func:`param_cell`), or
    ``merged`` where the armature was merged into the inertia (``v`` None)."""
    return "merged" if v is None else param_cell(v, flag)


def multijoint_trials(campaign) -> tuple:
    """The trials of a campaign that move several joints at once.

    Trials with ``joints = [1, 2, ...]`` [1]_, identified through the rigid-body model of
    thesis eq. 2-1 [2]_ rather than the one-link model of eq. 2-4.

    Parameters
    ----------
    campaign : mocap.io.campaign.Campaign
        The loaded campaign.

    Returns
    -------
    tuple of mocap.io.campaign.Trial
        Those trials, in manifest order.

    References
    ----------
    .. [1] jointlab data format (docs/format.md), sec. campaign.toml.
    .. [2] PA10 thesis (seeds 002), eq. 2-1.
    """
    return tuple(t for t in campaign.trials if len(t.joints) > 1)


@dataclass(frozen=True, eq=False)
class MultiJointFits:
    """``fits[trial id][model]`` -> :class:`ident.model.rigidbody.RigidBodyFit`, with each trial's
    preprocessing report."""

    fits: dict
    preprocessing: dict
    seconds: dict = field(default_factory=dict)
    loads: dict = field(default_factory=dict)     # trial id -> {"load_kg", "payload_com"}
    payload: dict = field(default_factory=dict)   # pooled identification of free payloads

    def trials_entry(self) -> dict:
        """The ``trials`` part of fits.json: trial -> joint -> model -> params/stderr/rms/..."""
        out = {}
        for tid, by_model in self.fits.items():
            cut = self.preprocessing.get(tid, {}).get("low_speed_cut")
            for m, fit in by_model.items():
                for j, e in fit.joints.items():
                    out.setdefault(tid, {}).setdefault(j, {})[m] = {
                        "params": e["params"], "stderr": e.get("stderr", {}), "rms": e["rms"],
                        "heldout_rms": e["heldout_rms"], "offset": e["offset"],
                        "armature": e["armature"], "stderr_armature": e.get("stderr_armature"),
                        "model": m, "method": "multi-joint rigid-body",
                        "flags": e.get("flags", {}), "v_zero": e.get("v_zero"),
                        **({"x_zero": e["x_zero"]} if "x_zero" in e else {}),
                        **({"low_speed_cut": _joint_cut(cut, int(j) - 1)} if cut else {}),
                        **({"implausible": e["implausible"]} if e.get("implausible") else {})}
        return out

    def summary(self) -> list:
        """fits.json summary rows (mean and coefficient of variation over the multi-joint
        trials; implausible estimates left out)."""
        vals = {}
        for by_model in self.fits.values():
            for m, fit in by_model.items():
                for j, e in fit.joints.items():
                    if e.get("implausible"):
                        continue
                    for k, v in e["params"].items():
                        if k in e.get("flags", {}):      # impossible / not identifiable
                            continue
                        vals.setdefault((int(j), m, k), []).append(float(v))
        rows = []
        for (j, m, k), v in sorted(vals.items()):
            a = np.asarray(v)
            cv = float(100 * a.std(ddof=1) / abs(a.mean())) if a.size > 1 and a.mean() else None
            rows.append({"joint": j, "load_kg": 0.0, "vmax_frac": 1.0, "model": m, "param": k,
                         "mean": float(a.mean()), "cv_percent": cv, "n_trials": int(a.size),
                         "source": "multi-joint rigid-body"})
        return rows

    def to_dict(self) -> dict:
        out = {"format": 1, "trials": {tid: {m: f.to_dict() for m, f in bm.items()}
                                       for tid, bm in self.fits.items()},
               "preprocessing": self.preprocessing, "seconds": self.seconds}
        if self.loads:
            out["loads"] = self.loads
        if self.payload:
            out["payload"] = self.payload
        return out

    def merge_into(self, doc: dict) -> dict:
        """fits.json ``doc`` with these trials and summary rows added."""
        doc = dict(doc)
        doc.setdefault("format", 1)
        trials = dict(doc.get("trials", {}))
        trials.update(self.trials_entry())
        doc["trials"] = trials
        doc["summary"] = list(doc.get("summary", [])) + self.summary()
        return doc

    def report(self) -> str:
        lines = ["# Multi-joint identification", ""]
        lines += loads_report(self.loads, self.payload)
        for tid, by_model in self.fits.items():
            pre = self.preprocessing[tid]
            lines += [f"## Trial `{tid}`", "", "Preprocessing:", ""]
            lines += [f"- {s}" for s in pre.get("steps", [])]
            lines += [f"- warning: {w}" for w in pre.get("warnings", [])]
            for m, fit in by_model.items():
                lines += ["", f"### {m}", "", f"Method: {fit.method}.", ""]
                pn = None
                flagged = []
                for j, e in fit.joints.items():
                    if pn is None:
                        pn = list(e["params"])
                        lines += ["| joint | " + " | ".join(pn) + " | offset | armature | rms | held-out rms |",
                                  "|---" * (len(pn) + 5) + "|"]
                    fl = e.get("flags", {})
                    lines.append(f"| {j} | " + " | ".join(param_cell(e["params"][k], fl.get(k)) for k in pn)
                                 + f" | {e['offset']:.4g} | {armature_cell(e['armature'], fl.get('armature'))}"
                                 f" | {e['rms']:.4g} | {e['heldout_rms']:.4g} |")
                    flagged += [f"joint {j} {k}: {f['flag']} ({f['reason']})" for k, f in fl.items()]
                lines += ["", f"Parameters: {meaning_line(m)}."] if meaning_line(m) else []
                if flagged:
                    lines += ["", "Flagged (not a physical estimate; left out of the summary):", ""]
                    lines += [f"- {x}" for x in flagged]
                lines.append("")
                if fit.motors:
                    lines += ["", "Coupled motors (log coordinates, link side): " + "; ".join(
                        f"motor {k}: " + ", ".join(f"{kk} {vv:.4g}" for kk, vv in v.items())
                        for k, v in fit.motors.items())]
                lines += [f"- note: {n}" for n in fit.notes]
        return "\n".join(lines) + "\n"

    def write(self, out: Path) -> dict:
        out = Path(out)
        out.mkdir(parents=True, exist_ok=True)
        p_json = out / "rigidbody.json"
        p_json.write_text(json.dumps(to_jsonable(self.to_dict()), indent=1, allow_nan=False),
                          encoding="utf-8")
        p_md = out / "rigidbody.md"
        p_md.write_text(self.report(), encoding="utf-8")
        return {"rigidbody": p_json, "rigidbody_report": p_md}


def _com_text(v) -> str:
    return "at the flange origin (absent)" if v is None else v if isinstance(v, str) else (
        "[" + ", ".join(f"{x:.4g}" for x in v) + "] m")


def loads_report(loads: dict, payload: dict) -> list:
    """Markdown lines: which record carries which load, and the pooled payload identification."""
    if not loads:
        return []
    lines = ["## Loads", "", "| record | load kg | payload_com |", "|---|---|---|"]
    lines += [f"| `{tid}` | {v['load_kg']:g} | {_com_text(v.get('payload_com'))} |" for tid, v in loads.items()]
    lines.append("")
    for key, e in payload.items():
        recs = ", ".join(f"`{r}`" for r in e.get("record_ids", []))
        if "com_flange_m" in e:
            com = ", ".join(f"{c * 1e3:.1f} +- {s * 1e3:.1f}" for c, s in zip(e["com_flange_m"], e["com_stderr_m"]))
            lines.append(f"Payload {e['mass_kg']:g} kg on {recs}, identified on every joint of every record at "
                         f"once (its mass as declared, its centre of mass and inertia free): centre of mass in "
                         f"the flange frame [{com}] mm.")
        if e.get("note"):
            lines.append(f"Payload {e['mass_kg']:g} kg on {recs}: {e['note']}.")
    return lines + [""]


def pooled_payload(robot, trials, recs) -> tuple[dict, dict]:
    """(loads, payload): which trial carries which load, and the pooled identification
    (:func:`identified_rigid_body`) of every payload whose centre of mass is not declared.
    ``recs``: each trial's prepared record."""
    loads = {tr.id: {"load_kg": float(tr.load_kg),
                     "payload_com": (getattr(tr, "extra", None) or {}).get("payload_com")}
             for tr in trials}
    if not any(tr.load_kg > 0 for tr in trials):
        return {}, {}
    if not any(payload_key(tr) is not None for tr in trials):
        return loads, {}
    pooled = identified_rigid_body(robot, [([i], rec) for i, rec in enumerate(recs)], trials)
    payload = {}
    for key, e in pooled.payload.items():
        e = dict(e)
        e["record_ids"] = [trials[k].id for k in e.pop("records")]
        payload[f"{key:g}kg"] = e
    return loads, payload


def fit_multijoint_campaign(campaign, models=("cv",), record: RecordSettings | None = None,
                            seed: int = 0, v_zero="auto", sink=None, **settings) -> MultiJointFits:
    r"""Identify every multi-joint trial of a campaign with every friction model.

    The rigid-body model of thesis eq. 2-1 [1]_ with friction on every joint,

    .. math::

        \tau = Y(q, \dot{q}, \ddot{q})\, \beta + f(\dot{q})

    (``Y beta`` the inverse dynamics linear in the base parameters :func:`base_parameters`,
    Indri & Trapani's residual torques of eq. 25-26 [2]_), one
    :class:`ident.model.rigidbody.RigidBodyIdentifier` per trial and model [3]_.

    Parameters
    ----------
    campaign : mocap.io.campaign.Campaign
        The loaded campaign.
    models : sequence of str, optional
        Friction models by their data-format names (default ``("cv",)``).
    record : ident.model.record.RecordSettings, optional
        How the records are prepared (derivatives, repeated rows); default settings.
    seed : int, optional
        Seed of the base-parameter states and the multi-start fits (default 0).
    v_zero : {"auto"} or float, optional
        ``"auto"`` (default): the low-speed cut of each joint chosen from the data
        (:func:`ident.model.rigidbody.low_speed_cut`, reported in the preprocessing); a number:
        a fraction of each joint's 99th-percentile speed (``v_zero_frac``).
    sink : viz.Sink, optional
        Receives, per trial and joint, the logged and the predicted torques over time and the
        friction against speed (:func:`log_record_fits`).
    **settings
        Keyword settings of :class:`ident.model.rigidbody.RigidBodyIdentifier`.

    Returns
    -------
    MultiJointFits
        ``fits[trial id][model]`` with each trial's preprocessing report and timing.

    References
    ----------
    .. [1] PA10 thesis (seeds 002), eq. 2-1.
    .. [2] Indri & Trapani 2020 (seeds 001), eq. 25-26.
    .. [3] jointlab multi-joint records (docs/multi-joint.md).
    """
    import time

    robot = campaign.load_robot()
    chain = ChainDynamics.from_model(robot.model)
    base = base_parameters(chain, robot.lower, robot.upper, seed=seed)
    fits, pre, secs = {}, {}, {}
    dyn_note = dynamic_data_note(models, {t.kind for t in campaign.trials})
    done = []
    for tr in multijoint_trials(campaign):
        t0 = time.perf_counter()
        rec = without_unlogged(load_record(campaign, tr, robot, record))
        pre[tr.id] = dict(rec.preprocessing)
        if rec.unlogged:
            names = ", ".join(f"{j} ({robot.joint_names[j - 1]})" for j in rec.unlogged)
            pre[tr.id]["unlogged_torque"] = list(rec.unlogged)
            pre[tr.id]["steps"] = list(pre[tr.id].get("steps", [])) + [
                f"torque not logged on joints {names} (unlogged_torque): their angles drive the "
                "kinematics and the other joints' rigid-body torques; no friction, offset or "
                "armature is identified for them"]
        if dyn_note:
            pre[tr.id]["warnings"] = list(pre[tr.id].get("warnings", [])) + [dyn_note]
        kw = dict(settings)
        if v_zero == "auto":
            cut = _auto_cut(campaign, tr, robot, rec, chain, base, seed, settings)
            kw["v_zero"] = cut["v_zero"]
            kw["x_zero"], kw["x_floor"] = cut["x_zero"], cut["noise_floor"]
            pre[tr.id]["low_speed_cut"] = {k: (v.tolist() if hasattr(v, "tolist") else v)
                                           for k, v in cut.items()}
            pre[tr.id]["steps"] = list(pre[tr.id].get("steps", [])) + [_cut_text(cut)]
        else:
            kw["v_zero_frac"] = float(v_zero)
        idts = {m: RigidBodyIdentifier(chain, base, model=m, seed=seed, **kw) for m in models}
        fits[tr.id] = {m: idt.fit(rec) for m, idt in idts.items()}
        if sink is not None and sink.enabled:
            log_record_fits(sink, tr.id, rec, {m: idt.predicted(rec) for m, idt in idts.items()},
                            fits[tr.id], used=idts[models[0]]._mask(rec)[0])
        _PREPARED.clear()                  # the shared design of this record is not needed again
        secs[tr.id] = time.perf_counter() - t0
        done.append((tr, rec))
    loads, payload = pooled_payload(robot, [t for t, _ in done], [r for _, r in done])
    return MultiJointFits(fits, pre, secs, loads, payload)


def log_record_fits(sink, trial_id: str, rec, predicted: dict, fits: dict, used=None) -> None:
    """Log one record's multi-joint fits to a rerun sink, under ``fits/<trial>/joint<j>``:
    ``torque`` (the logged torque and each model's prediction over time), ``friction_vs_speed/
    data`` (the friction the record shows: the logged torque less the first model's rigid-body,
    offset and armature part, as (qd, f, 0) points on the rows the fit used),
    ``friction_vs_speed/<model>`` (each model's friction law over the joint's speed range; a
    state-dependent law's value on the rows) and, on a joint with a presliding cut,
    ``friction_vs_reversal_distance`` (``data``: (s, sign(qd) f, 0) on the rows above the speed
    cut against the distance moved since the last velocity reversal, blue where the fit used
    them, red where the presliding cut left them out; ``cut``: a line at the cut). ``predicted``: model ->
    :meth:`ident.model.rigidbody.RigidBodyIdentifier.predicted`; ``used``: the (T, n) rows the
    first model's fit used (default: the rows above each joint's speed cut)."""
    first = next(iter(fits))
    for js, e in fits[first].joints.items():
        j = int(js) - 1
        base = f"fits/{trial_id}/joint{js}"
        names = ["tau_logged"] + [f"pred_{m}" for m in fits]
        sink.scalars(f"{base}/torque", rec.t, np.column_stack(
            [rec.tau[:, j]] + [predicted[m][0][:, j] for m in fits]), names=names)
        pred, fric = predicted[first]
        rows = np.abs(rec.qd[:, j]) >= e["v_zero"] if used is None else used[:, j]
        f_data = rec.tau[rows, j] - (pred[rows, j] - fric[rows, j])
        sink.points(f"{base}/friction_vs_speed/data",
                    np.column_stack([rec.qd[rows, j], f_data, np.zeros(int(rows.sum()))]))
        if e.get("x_zero"):
            _log_presliding(sink, base, rec, j, e, pred[:, j] - fric[:, j])
        top = float(np.max(np.abs(rec.qd[:, j])))
        v = np.linspace(-top, top, 401)
        order = np.argsort(rec.qd[:, j])
        for m, fit in fits.items():
            je = fit.joints.get(js)
            if je is None:                         # not identified on this joint
                continue
            if not MODELS[m].dynamic:
                law = MODELS[m](**je["params"], **je.get("settings", {}))
                curve = np.column_stack([v, law.torque(v), np.zeros_like(v)])
            else:                                  # a state-dependent law: its value on the rows
                curve = np.column_stack([rec.qd[order, j], predicted[m][1][order, j],
                                         np.zeros(rec.t.size)])
            sink.points(f"{base}/friction_vs_speed/{m}", curve)


def _log_presliding(sink, base: str, rec, j: int, e: dict, other) -> None:
    """Joint ``j``'s (0-based) friction against the distance since the last velocity reversal
    (:func:`log_record_fits`); ``other``: the model's torque less its friction, (T,)."""
    above = np.abs(rec.qd[:, j]) >= e["v_zero"]
    s = reversal_displacement(rec.q[:, j], rec.qd[:, j], e["x_floor"])[above]
    y = np.sign(rec.qd[above, j]) * (rec.tau[above, j] - other[above])
    kept = s >= e["x_zero"]
    colors = np.where(kept[:, None], np.array([[60, 120, 220]]), np.array([[220, 80, 60]]))
    sink.points(f"{base}/friction_vs_reversal_distance/data",
                np.column_stack([s, y, np.zeros(s.size)]), colors=colors.astype(np.uint8))
    top = float(np.max(np.abs(y))) if y.size else 1.0
    sink.lines(f"{base}/friction_vs_reversal_distance/cut",
               [np.array([[e["x_zero"], -top, 0.0], [e["x_zero"], top, 0.0]])])


def _auto_cut(campaign, tr, robot, rec, chain, base, seed, settings) -> dict:
    """The low-speed cut of each joint chosen from the data (reported in the preprocessing):
    the largest of the velocity noise floor (:func:`ident.model.rigidbody.low_speed_cut`), the
    residual knee of a Coulomb + viscous fit above that floor
    (:func:`ident.model.rigidbody.residual_knee`) and the end of the friction's sign transition
    where it has a stable width (:func:`ident.model.rigidbody.friction_transition`, at most half
    the 99th-percentile speed); then, per joint, the presliding cut: the rows closer to the last
    velocity reversal than the end of the friction's rise with the displacement
    (:func:`ident.friction.presliding.presliding_length` on the rows above the speed cut, 0 where
    there is none); with the Coulomb levels over plausible cuts (noise floor, half, once and
    twice the cut, with the presliding cut) and at the cut without the presliding cut."""

    cut = low_speed_cut(campaign.read_log(tr, robot), rec, robot.drives)
    floor = cut["v_zero"]
    kw = {k: v for k, v in settings.items() if k not in ("folds", "v_zero", "v_zero_frac")}
    idt = RigidBodyIdentifier(chain, base, model="cv", seed=seed, folds=0, v_zero=floor, **kw)
    A, names, F, M, v0, sigma, idt._dropped = idt._prepared(rec)
    idt._names = names
    sol = idt._solve(rec, A, F, M, np.ones(rec.t.size, bool), sigma=sigma, quick=True)
    resid = rec.tau - idt._predict(rec, A, F, sol)
    knee = np.array([residual_knee(rec.qd[:, j], np.where(M[:, j], resid[:, j], 0.0), floor[j])
                     if M[:, j].any() else floor[j] for j in range(rec.n)])
    fric = resid + np.einsum("tjp,p->tj", F, sol["bf"])       # the friction the record shows
    sp = np.percentile(np.abs(rec.qd), 99, axis=0)
    trans = [friction_transition(rec.qd[M[:, j], j], fric[M[:, j], j], floor[j])
             if M[:, j].any() else None for j in range(rec.n)]
    end = np.array([min(t["end"], 0.5 * sp[j]) if t and t["end"] is not None else 0.0
                    for j, t in enumerate(trans)])
    v0 = np.maximum(np.maximum(floor, knee), end)
    # presliding: the rows faster than the speed cut whose friction still rises with the
    # displacement since the last reversal
    # (the friction the record shows under the fit at the speed cut: rows below it, such as a
    # wide presliding transition, would bias the rigid-body part)
    Mv = M & (np.abs(rec.qd) >= v0[None, :])
    if Mv.any():
        sol = idt._solve(rec, A, F, Mv, np.ones(rec.t.size, bool), sigma=sigma, quick=True)
        fric = rec.tau - idt._predict(rec, A, F, sol) + np.einsum("tjp,p->tj", F, sol["bf"])
    # a joint driven through a coupled motor (FORMAT.md coupling: the motor's friction follows
    # the motor's reversals, not the joint's) is not cut
    Ci = np.linalg.inv(rec.coupling)
    shared = {j for k in idt._coupled(rec) for j in np.flatnonzero(np.abs(Ci[k]) > 1e-12)}
    pres, Mx = [], M.copy()
    for j in range(rec.n):                               # loop over joints (n <= ~7)
        if j in shared:
            pres.append({"length": None, "gain": None, "end": None, "coupled_motor": True})
            continue
        if not Mv[:, j].any():
            pres.append(None)
            continue
        disp = reversal_displacement(rec.q[:, j], rec.qd[:, j], floor[j])
        rows = Mv[:, j]
        pres.append(presliding_length(disp[rows], rec.qd[rows, j], fric[rows, j], v0[j]))
        if pres[-1]["end"] is not None:
            Mx[:, j] &= disp >= pres[-1]["end"]
    x0 = np.array([p["end"] if p and p["end"] is not None else 0.0 for p in pres])
    # the cut's effect on Coulomb: the levels at the noise floor, half, once and twice the cut
    # (with the presliding cut), and at the cut without the presliding cut
    cuts = np.stack([floor, np.maximum(floor, 0.5 * v0), v0, 2.0 * v0])
    cc = coulomb_over_cuts(idt, rec, A, F, Mx, sigma, cuts)
    c_nox = (coulomb_over_cuts(idt, rec, A, F, M, sigma, v0[None, :])[0] if np.any(x0 > 0)
             else cc[2])
    _PREPARED.clear()
    ok = np.isfinite(cc).all(axis=0) & (np.abs(cc[2]) > 0)       # joints with rows at every cut
    ref = np.where(ok, np.abs(cc[2]), 1.0)
    lo = np.where(ok, (np.where(ok, cc, 0.0).min(axis=0) - cc[2]) / ref, np.nan)
    hi = np.where(ok, (np.where(ok, cc, 0.0).max(axis=0) - cc[2]) / ref, np.nan)
    return {"v_zero": v0, "noise_floor": floor, "knee": knee, "transition": trans,
            "transition_end": end, "presliding": pres, "x_zero": x0,
            "coulomb_without_presliding_cut": _finite_or_none(c_nox),
            "sigma_q": cut["sigma_q"],
            "sigma_v": cut["sigma_v"], "k": cut["k"],
            "fraction_of_speed": np.where(sp > 0, v0 / np.where(sp > 0, sp, 1.0), 0.0),
            "coulomb_over_cuts": {"cuts": ["noise floor", "0.5 x cut", "cut", "2 x cut"],
                                  "v_zero": cuts.tolist(), "c": _finite_or_none(cc)},
            "coulomb_range": _finite_or_none(np.stack([lo, hi], axis=1))}


def _cut_text(cut: dict) -> str:
    """The preprocessing line of the data-chosen low-speed cut (:func:`_auto_cut`)."""
    def trans(j, t):
        if t is None:
            return f"j{j + 1} -"
        if t["end"] is not None:
            return f"j{j + 1} {t['end']:.3g}"
        if t["width_ratio"] is not None:
            return f"j{j + 1} none (width x{t['width_ratio']:.2g} over twice the range)"
        return f"j{j + 1} none (no width within the speeds)"

    bent = [j + 1 for j, t in enumerate(cut["transition"])
            if t is not None and t["end"] is None and t["width_ratio"] is not None]
    return ("low-speed cut chosen from the data: rows with |qd_j| below " + ", ".join(
        f"{x:.3g}" for x in cut["v_zero"]) + " rad/s (" + ", ".join(
        f"{100 * x:.2g}" for x in cut["fraction_of_speed"]) + " % of the 99th-percentile speeds) "
        "left out: the largest of the velocity noise floor (3 standard deviations: angle noise "
        + ", ".join(f"{x:.2g}" for x in cut["sigma_q"]) + " rad through the derivative filter, "
        + ", ".join(f"{x:.3g}" for x in cut["noise_floor"]) + " rad/s), the speed below which a "
        "Coulomb + viscous fit's residual grows past 1.5 times its level at speed ("
        + ", ".join(f"{x:.3g}" for x in cut["knee"]) + " rad/s) and the end of the friction's "
        "sign transition (3 widths of c tanh(|qd|/vs) + fv |qd| where the width is the same on "
        "half and on the whole speed range; rad/s: "
        + ", ".join(trans(j, t) for j, t in enumerate(cut["transition"])) + ")"
        + (f"; joint(s) {', '.join(map(str, bent))}: against the speed alone the friction bends "
           "at every speed (no finite transition)" if bent else "")
        + _presliding_text(cut)
        + "; Coulomb from the noise floor to twice the cut, relative to the level at the cut: "
        + ", ".join(f"j{j + 1} {100 * lo:+.0f}/{100 * hi:+.0f} %"
                    for j, (lo, hi) in enumerate(cut["coulomb_range"])
                    if lo is not None and hi is not None)
        + " (docs/vendor.md)")


def _presliding_text(cut: dict) -> str:
    """The preprocessing clause of the presliding cut (:func:`_auto_cut`), empty without one."""
    pres = cut.get("presliding") or []
    x0 = cut.get("x_zero")
    if x0 is None or not np.any(np.asarray(x0) > 0):
        return ("; no joint's friction rises with the displacement after a reversal (presliding) "
                "on the rows above the cut")
    cells = []
    for j, p in enumerate(pres):
        if p is not None and p.get("coupled_motor"):
            cells.append(f"j{j + 1} - (coupled motor)")
        elif p is None or p["end"] is None:
            cells.append(f"j{j + 1} -")
        else:
            c0, c1 = cut["coulomb_without_presliding_cut"][j], cut["coulomb_over_cuts"]["c"][2][j]
            eff = f", Coulomb {100 * (c0 / c1 - 1):+.1f} % without it" if c0 and c1 else ""
            cells.append(f"j{j + 1} {p['end']:.2g} rad (rise {p['length']:.2g} rad, "
                         f"{100 * p['gain']:.0f} % of the residual{eff})")
    return ("; and the rows closer to the joint's last velocity reversal than the end of the "
            "friction's rise with the displacement since the reversal (presliding: "
            "ln 200 lengths s0 of c (1 - exp(-s/s0)) + fv |qd| fitted above the cut, kept where "
            "it explains at least 1 % of the residual): " + ", ".join(cells))


def _joint_cut(cut: dict, j: int) -> dict:
    """Joint ``j``'s (0-based) part of the data-chosen low-speed cut, for fits.json (rad/s; the
    Coulomb range relative to the level at the cut; ``transition_end`` None where the friction
    bends at every speed or shows no transition within the sampled speeds)."""
    t = cut["transition"][j] or {}
    p = (cut.get("presliding") or [None] * (j + 1))[j] or {}
    return {"v_zero": cut["v_zero"][j], "noise_floor": cut["noise_floor"][j],
            "knee": cut["knee"][j], "transition_end": t.get("end"),
            "transition_width_ratio": t.get("width_ratio"),
            "x_zero": float(cut["x_zero"][j]) if "x_zero" in cut else 0.0,
            "presliding_length": p.get("length"), "presliding_gain": p.get("gain"),
            "coulomb_without_presliding_cut": (cut.get("coulomb_without_presliding_cut")
                                               or [None] * (j + 1))[j],
            "coulomb_range": cut["coulomb_range"][j]}


def _finite_or_none(x: np.ndarray) -> list:
    """Nested lists of ``x`` with None for NaN (JSON)."""
    return np.where(np.isfinite(x), x, None).tolist()


def continuous_records(campaign, trials, logs) -> list[list[int]]:
    """Indices of ``trials`` grouped into continuous records: pieces that move the same joints and
    whose logs follow each other on one clock, the next starting after the previous one's last
    sample by no more than a sample step of either (at most three median steps, or the longest
    step inside them), are one record cut into files (a logger that rotates its files); the
    pieces of a record are joined in time order. Other trials are records of their own."""
    order = sorted(range(len(trials)), key=lambda i: float(logs[i].time[0]))
    groups: list[list[int]] = []

    def step(lg):
        dt = np.diff(lg.time)
        return max(3.0 * float(np.median(dt)), float(dt.max())) if dt.size else 0.0

    for i in order:
        if groups:
            prev = groups[-1][-1]
            gap = float(logs[i].time[0] - logs[prev].time[-1])
            if (tuple(trials[i].joints) == tuple(trials[prev].joints)
                    and 0.0 < gap <= max(step(logs[i]), step(logs[prev]))):
                groups[-1].append(i)
                continue
        groups.append([i])
    return groups


def _join_logs(logs):
    """One :class:`mocap.io.robotlog.RobotLog` from consecutive pieces of a record (the columns
    that every piece has)."""
    if len(logs) == 1:
        return logs[0]
    keys = [k for k in logs[0].extra if all(k in lg.extra for lg in logs[1:])]
    return RobotLog(time=np.concatenate([lg.time for lg in logs]),
                    qm=np.concatenate([lg.qm for lg in logs]),
                    tau=np.concatenate([lg.tau for lg in logs]),
                    extra={k: np.concatenate([lg.extra[k] for lg in logs]) for k in keys},
                    source=logs[0].source)


#: contiguous held-out segments per record of `jointlab fit`'s rigid-body identification
#: (:class:`ident.model.rigidbody.RigidBodyIdentifier` ``folds``)
FIT_FOLDS = 5


def _contiguous_heldout(d, nominal, folds: int, bounds: np.ndarray) -> float:
    """The nominal's held-out torque RMS on the folds `jointlab fit` reports its held-out RMS on:
    ``folds`` equal-time contiguous segments of each record, cutting through motion cycles as
    `fit`'s do (:class:`ident.model.rigidbody.RigidBodyIdentifier` ``folds``), so the two figures
    compare like with like. ``bounds``: the first trial (motion cycle) of each record in ``d``,
    and the end."""
    ch = torque_channel(d, nominal)
    rec_of_block = np.searchsorted(bounds[1:], ch.block_trial, side="right")
    seg = np.zeros(d.t_rel.shape[0], int)
    for k in np.unique(rec_of_block):   # loop over records: each sample's equal-time segment
        rows = np.concatenate([np.arange(a, b) for a, b in ch.blocks[rec_of_block == k]])
        t = d.t_rel[rows]
        span = max(float(t.max()) + 1e-9, 1e-9)
        seg[rows] = int(k) * folds + np.minimum((t / span * folds).astype(int), folds - 1)
    # the motion-cycle blocks cut where the segment changes: each piece lies in one fold
    cuts = [ch.blocks[:, 0], ch.blocks[:, 1]]
    for a, b in ch.blocks:
        inner = a + 1 + np.flatnonzero(seg[a + 1:b] != seg[a:b - 1])
        cuts.append(inner)
    edges = np.unique(np.concatenate(cuts))
    ends = set(ch.blocks[:, 1].tolist()) - set(ch.blocks[:, 0].tolist())
    pieces = np.array([(a, b) for a, b in zip(edges[:-1], edges[1:]) if a not in ends], int).reshape(-1, 2)
    cv = cross_validate({None: grams(ch.X0, ch.target, pieces)}, seg[pieces[:, 0]])
    return float(np.sqrt(np.sum(cv.sse) / max(float(np.sum(pieces[:, 1] - pieces[:, 0])), 1.0)))


def identified_rigid_body(robot, recs: list, trials) -> PooledRigidBody:
    """The rigid body identified on every joint of every record of a campaign
    (:func:`ident.model.identified.identify_rigid_body`): ``recs`` as ``(trial indices, record)``;
    each joint's moving samples (the diagnosis's: not at a standstill, above 0.02 rad/s)."""
    chain = ChainDynamics.from_model(robot.model)
    rigid = [record_rigid_body(robot, chain, rec.q, rec.qd, rec.qdd, trials[g[0]]) for g, rec in recs]
    keeps = []
    for _, rec in recs:
        kp = np.zeros(rec.q.shape, bool)
        for j in rec.moving:
            if j not in rec.unlogged:
                kp[:, j - 1] = ~standstill(rec.t, rec.qd[:, j - 1]) & (np.abs(rec.qd[:, j - 1]) >= 0.02)
        keeps.append(kp)
    return identify_rigid_body(robot, rigid, [(rec.qd, rec.qdd, rec.tau) for _, rec in recs], keeps)


def diagnose_records(campaign, robot, settings, joints=None, record: RecordSettings | None = None,
                     n_segments: int | None = None, progress: bool = False) -> tuple[dict, dict]:
    """Run the gap diagnosis on every moving joint of the campaign's multi-joint trials.

    Trials that are pieces of one continuous record (:func:`continuous_records`: a logger
    that rotated its files) are joined into that record; each record is prepared like `fit` does
    (:func:`ident.model.record.prepare_record`: repeated rows, irregular steps, derivatives,
    coupling, braked-joint check) and handed to ``ident.gap.data.build_joint_data_record``
    (torque channel; blocks = the joint's motion cycles; held-out folds = the cycles, or
    ``n_segments`` groups of whole cycles); the records of one joint are pooled
    (``ident.gap.data.concat_joint_data``: blocks and folds never across records) into one
    ``ident.gap.diagnose_joint`` [1]_. The verdict is therefore one per joint, whatever the
    number of files the record was written to [2]_.

    Parameters
    ----------
    campaign : mocap.io.campaign.Campaign
        The loaded campaign.
    robot : mocap.robot.Robot
        Its robot.
    settings : ident.gap.DiagnosisSettings
        The diagnosis settings (candidates, nominal model).
    joints : sequence of int, optional
        Joints to diagnose (1-based); None: every moving joint.
    record : ident.model.record.RecordSettings, optional
        How the records are prepared; default settings.
    n_segments : int, optional
        Held-out folds as this many groups of whole motion cycles; None: one fold per cycle.
    progress : bool, optional
        A progress bar over the joints on stderr (``tqdm``).

    Returns
    -------
    reports : dict
        ``"<joint>"`` -> the diagnosis report (``DiagnosisResult.to_dict()`` with the nominal
        model, the record's pieces and preprocessing and the folds).
    series : dict
        ``"<joint>"`` -> the diagnosis's time series (for plots).

    References
    ----------
    .. [1] jointlab gap diagnosis (docs/gap-diagnosis.md).
    .. [2] jointlab long records (docs/long-records.md).
    """
    from types import SimpleNamespace

    trials = multijoint_trials(campaign)
    nominal = check_nominal(settings.nominal, [j for tr in trials for j in tr.joints
                                               if not joints or j in joints])
    logs = [campaign.read_log(tr, robot) for tr in trials]
    C = coupling_matrix(campaign, robot.n)
    recs = []
    for g in continuous_records(campaign, trials, logs):
        tr = trials[g[0]]
        rid = tr.id if len(g) == 1 else "+".join(trials[i].id for i in g)
        unl = tuple(sorted({j for i in g for j in trials[i].unlogged_torque}))
        recs.append((g, prepare_record(_join_logs([logs[i] for i in g]),
                                       SimpleNamespace(id=rid, joints=tuple(tr.joints),
                                                       unlogged_torque=unl), robot.n, C,
                                       record)))
    offsets = campaign_clock([SimpleNamespace(time=rec.t) for _, rec in recs])
    pooled = identified_rigid_body(robot, recs, trials)
    reports, series = {}, {}
    moving = sorted({j for g, rec in recs for j in rec.moving})
    unlogged = sorted({j for g, rec in recs for j in rec.unlogged
                       if not joints or j in joints})
    if unlogged:
        warn_input(f"joints {unlogged} ({', '.join(robot.joint_names[j - 1] for j in unlogged)}): "
                   "torque not logged (unlogged_torque); their angles drive the kinematics, they "
                   "are not diagnosed", path=campaign.manifest)
    todo = [j for j in moving if not joints or j in joints]
    if todo and progress_bars(progress):   # a bar on a terminal only, not in captured logs
        from tqdm import tqdm

        todo = tqdm(todo, desc="diagnose", unit="joint", leave=False)
    gravity = {}   # record -> its (T, n) gravity torque, computed once for all its joints
    for j in todo:
        mine = [(k, g, rec) for k, (g, rec) in enumerate(recs)
                if j in rec.moving and j not in rec.unlogged]
        if not mine:
            continue
        for k, _, rec in mine:
            if k not in gravity:
                gravity[k] = robot.gravity_torque(rec.q)
        parts = [build_joint_data_record(j, robot=robot, n_segments=n_segments, tau_fixed=pooled.torque[k][:, j - 1],
                                         signals=True, nuisance=partial(pooled.nuisance, k, j - 1),
                                         gravity=gravity[k], **rec.gap_inputs())
                 for k, _, rec in mine]
        d = concat_joint_data(parts, [offsets[k] for k, _, _ in mine])
        res = diagnose_joint(d, settings, gear_ratio=robot.drives[j - 1].gear_ratio)
        rep = res.to_dict()
        rep["nominal"] = nominal.describe(d)
        folds = ("leave-one-block-out over the joint's motion cycles (blocks chosen from the data)"
                 if n_segments is None else
                 f"leave-one-segment-out ({d.n_trials} segments of whole motion cycles, "
                 f"{n_segments} asked)")
        # the nominal's held-out RMS on each record (a loaded record is diagnosed as well as an
        # unloaded one when the payload is in the identified nominal)
        r_nom, tr_idx = res.series["residual_nominal"], res.series["trial"]
        bounds = np.cumsum([0] + [p.n_trials for p in parts])
        by_rec = {}
        for i, (_, _, rec) in enumerate(mine):
            m = (tr_idx >= bounds[i]) & (tr_idx < bounds[i + 1]) & (r_nom != 0)
            by_rec[rec.trial_id] = float(np.sqrt(np.mean(r_nom[m] ** 2))) if m.any() else None
        if pooled.payload:
            rep["payload_identified"] = {f"{k:g}kg": {**{kk: vv for kk, vv in e.items() if kk != "records"},
                                                      "record_ids": [recs[i][1].trial_id for i in e["records"]]}
                                         for k, e in pooled.payload.items()}
        rep["record"] = {"trial": " | ".join(rec.trial_id for _, _, rec in mine),
                         "heldout_rms_nominal_by_record": by_rec,
                         "heldout_rms_nominal_contiguous": _contiguous_heldout(d, nominal, FIT_FOLDS, bounds),
                         "pieces": [[trials[i].id for i in g] for _, g, _ in mine],
                         "preprocessing": (mine[0][2].preprocessing if len(mine) == 1 else
                                           {rec.trial_id: rec.preprocessing for _, _, rec in mine}),
                         "folds": folds}
        series[str(j)] = res.series
        reports[str(j)] = rep
    return reports, series
