"""Coast-down identification of a campaign (FORMAT.md ``kind = "coastdown"`` trials, source 000).

For every coast-down trial (one joint at a time) and its joint:

1. the total inertia ``J``: the joint's diagonal of the URDF mass matrix at the trial's posture
   (the median logged angles of the braked joints) with the payload (``load_kg`` at
   ``payload_com``), plus the drive's ``motor_inertia``; gravity ``a sin q + b cos q`` from
   the same model;
2. the coasts (:func:`ident.coastdown.angle.find_coasts`): the sample after which the drive
   torque is cut and the sample at which the joint comes to rest;
3. ``Kc`` and the total viscous ``Kv`` (link and motor side) by the maximum-likelihood fit on
   the encoder angle (:class:`ident.coastdown.angle.AngleCoastFit`, the reported values,
   ``method = "ml"``), and by the paper's TDM (eqs. 4-6) and FDM (eqs. 7-11) on each coast long
   enough for them (``min_samples`` velocity samples): the velocity record is the release
   ``(t_cut, v_cut)`` of the ML fit followed by the interval-mean velocities of the encoder angle
   (first differences at the interval midpoints, which do not bias eq. 4) of the intervals that
   lie wholly inside the coast; FDM gets it resampled on its uniform grid. Their ``Kc`` is the
   fitted ``Kc - s u`` plus the measured external torque ``s u``; per trial the mean over coasts.

Per joint, all coasts of all its coast-down trials are also fitted together (``joints`` in
``coastdown.json``): several speeds separate ``Kc`` from ``Kv`` where one short record cannot.
A trial that cannot separate them alone (short coasts at a controller rate, one speed) is
reported at the joint's pooled ``Kv`` (``method = "ml-pooled-kv"``: its ``Kc`` fitted with
``Kv`` held there, the standard error including the pooled ``Kv``'s; the trial's own fit under
``trial_only``). The drive's declared ``stiffness`` enters the angle model
(:class:`ident.coastdown.angle.Flex`).
Outputs (:func:`write_coastdown`): ``coastdown.json`` (FORMAT.md keys plus diagnostics),
``coastdown.md`` with a decay-curve figure per trial (``plots/``), and a rerun view.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from mocap.io.payload import payload_com

from mocap.io.errors import InputError

from ident.coastdown.angle import (AngleCoastFit, AngleCoastResult, Flex, coast_speed, find_coasts,
                                   interval_velocity)
from ident.coastdown.estimators import fdm, tdm
from ident.common import to_jsonable
from ident.settings import Interval, Joints, Settings
from mocap.io.robotlog import read_robot_log
from viz.sink import NullSink

__all__ = ["CoastdownSettings", "TrialCoastdown", "CoastdownReport", "analyse_campaign",
           "analyse_trial", "write_coastdown", "coastdown_table", "coastdown_trials"]


@dataclass(frozen=True)
class CoastdownSettings(Settings):
    """``v_min_frac``: slowest cut speed taken as a coast (fraction of ``max_velocity``);
    ``pre_s``/``rest_s``: pre-cut window and rest length (s); ``jump_sigmas``: torque step at
    the cut in noise levels; ``sep_rel``: see :class:`AngleCoastFit`; ``min_samples``: velocity
    samples a coast needs for TDM/FDM; ``joints``: restrict to these joints (1-based).
    :attr:`constraints` is checked at construction (:mod:`ident.settings`)."""

    v_min_frac: float = 0.02
    pre_s: float = 0.15
    rest_s: float = 0.05
    jump_sigmas: float = 8.0
    sep_rel: float = 0.2
    min_samples: int = 4
    joints: tuple = ()

    #: field -> (option, constraint), checked at construction
    constraints = {
        "v_min_frac": ("v_min_frac", Interval(0, 1, closed="left")),
        "pre_s": ("pre_s", Interval(0, closed="right", note="s")),
        "rest_s": ("rest_s", Interval(0, closed="right", note="s")),
        "jump_sigmas": ("jump_sigmas", Interval(0, closed="right")),
        "sep_rel": ("sep_rel", Interval(0, closed="right")),
        "min_samples": ("min_samples", Interval(1, integer=True)),
        "joints": ("--joints", Joints(none=False)),
    }

    def to_dict(self) -> dict:
        return {k: (list(v) if isinstance(v, tuple) else v) for k, v in self.__dict__.items()}


@dataclass(frozen=True)
class TrialCoastdown:
    """The coast-down of one (trial, joint): the ML fit (None when no coast was found), the
    TDM and FDM means over coasts (with per-coast values), ``J`` and notes. ``series`` holds
    the fitted records for plots and the viewer (not serialised)."""

    trial: str
    joint: int
    J: float
    load_kg: float
    vmax_frac: float
    ml: AngleCoastResult | None
    tdm: dict
    fdm: dict
    notes: tuple = ()
    series: dict = field(default_factory=dict, repr=False, compare=False)
    pooled_kv: dict | None = None

    @property
    def Kc(self):
        """The reported Coulomb level: the trial's own ML fit, or, where the trial cannot
        separate Kc from Kv, its Kc at the joint's pooled Kv (``pooled_kv``)."""
        if self.pooled_kv is not None:
            return self.pooled_kv["Kc"]
        return None if self.ml is None else self.ml.Kc

    @property
    def Kv(self):
        if self.pooled_kv is not None:
            return self.pooled_kv["Kv"]
        return None if self.ml is None else self.ml.Kv

    @property
    def stderr(self) -> dict:
        if self.pooled_kv is not None:
            return {"Kc": self.pooled_kv["stderr"]["Kc"], "Kv": self.pooled_kv["stderr"]["Kv"]}
        return {"Kc": None, "Kv": None} if self.ml is None else dict(self.ml.stderr)

    @property
    def method(self) -> str:
        return "ml" if self.pooled_kv is None else "ml-pooled-kv"

    def to_format(self) -> dict:
        """The FORMAT.md entry (``Kc``, ``Kv``, ``J``, ``stderr``, ``method``, ``methods``)
        plus diagnostics. ``method = "ml"``: the trial's own ML fit; ``"ml-pooled-kv"``: the
        trial cannot separate Kc from Kv, so ``Kv`` is the joint's pooled value and ``Kc`` the
        trial's at that ``Kv`` (its standard error includes the pooled Kv's); the trial's own
        fit is under ``trial_only``."""
        ml = self.ml
        d = {"Kc": self.Kc, "Kv": self.Kv, "J": self.J, "stderr": self.stderr, "method": self.method,
             "methods": {"tdm": {"Kc": self.tdm.get("Kc"), "Kv": self.tdm.get("Kv"),
                                 "n_coasts": self.tdm.get("n", 0), "coasts": self.tdm.get("coasts", [])},
                         "fdm": {"Kc": self.fdm.get("Kc"), "Kv": self.fdm.get("Kv"),
                                 "n_coasts": self.fdm.get("n", 0), "coasts": self.fdm.get("coasts", [])}},
             "load_kg": self.load_kg, "vmax_frac": self.vmax_frac, "notes": list(self.notes)}
        if ml is not None:
            d["methods"]["ml"] = {"Kc": ml.Kc, "Kv": ml.Kv, "stderr": dict(ml.stderr)}
            if self.pooled_kv is not None:
                d["trial_only"] = {"Kc": ml.Kc, "Kv": ml.Kv, "stderr": dict(ml.stderr)}
                d["pooled_kv"] = dict(self.pooled_kv)
            d.update({"corr_Kc_Kv": ml.corr, "separable": ml.separable, "n_coasts": len(ml.coasts),
                      "sigma_q": ml.sigma_q, "rms": ml.rms, "converged": ml.converged,
                      "coasts": [dict(c) for c in ml.coasts]})
            d["notes"] = list(self.notes) + list(ml.notes)
        return d


@dataclass(frozen=True)
class CoastdownReport:
    """Every (trial, joint) coast-down of a campaign, the pooled fit per joint and the trials
    left out (id -> reason)."""

    campaign: str
    trials: tuple
    joints: dict
    skipped: dict
    settings: CoastdownSettings

    def to_dict(self) -> dict:
        trials: dict = {}
        for r in self.trials:
            trials.setdefault(r.trial, {})[str(r.joint)] = r.to_format()
        return to_jsonable({"format": 1, "campaign": self.campaign, "trials": trials,
                            "joints": {str(j): res.to_dict() for j, res in self.joints.items()},
                            "skipped": dict(self.skipped), "settings": self.settings.to_dict()})


def coastdown_trials(campaign) -> list:
    """The campaign's ``kind = "coastdown"`` trials."""
    return [tr for tr in campaign.trials if tr.kind == "coastdown"]


def _flex(drive) -> Flex | None:
    """The drive's declared transmission (FORMAT.md ``stiffness``), None for a rigid one."""
    k = drive.extra.get("stiffness")
    if k is None:
        return None
    return Flex(float(k), float(drive.motor_inertia), float(drive.motor_viscous))


def _trial_dynamics(trial, robot, j0: int, qm_all):
    rest = np.nanmedian(np.where(np.isfinite(qm_all), qm_all, np.nan), axis=0)
    rest = np.where(np.isfinite(rest), rest, 0.0)
    p_com = payload_com(trial)
    rb = robot.with_payload(trial.load_kg, p_com) if trial.load_kg > 0 else robot
    I, a, b = rb.single_joint_dynamics(j0, rest)
    return I + float(robot.drives[j0].motor_inertia), a, b


def _paper_methods(ml: AngleCoastResult, t, q, windows, J, min_samples: int):
    """TDM and FDM (source 000) per coast on the interval-mean velocities (module docstring)."""
    out = {"tdm": [], "fdm": []}
    why = []
    for c, w in zip(ml.coasts, windows):  # loop over coasts
        s = w.direction
        i0, i1 = w.on + 1, w.rest - 1                  # intervals [i, i+1] wholly in the coast
        tm, v = interval_velocity(t[i0: i1 + 1], q[i0: i1 + 1]) if i1 > i0 else (np.zeros(0), np.zeros(0))
        tr = np.concatenate([[0.0], tm - c["t_cut"]])
        vr = np.concatenate([[abs(c["v_cut"])], s * v])
        if tr.size < min_samples:
            why.append(tr.size)
            continue
        su = s * c["u_measured"]
        for name, fn in (("tdm", tdm), ("fdm", fdm)):
            try:
                if name == "fdm":
                    dt = float(np.median(np.diff(t[i0: i1 + 1])))
                    tu = np.arange(0.0, tr[-1] + 1e-12, dt)
                    r = fn(tu, np.interp(tu, tr, vr), J, v0=vr[0])
                else:
                    r = fn(tr, vr, J, v0=vr[0])
                out[name].append({"Kc": float(r.Kc + su), "Kv": float(r.Kv), "t_cut": c["t_cut"],
                                  "n_samples": int(tr.size)})
            except (InputError, ValueError, FloatingPointError) as exc:
                out[name].append({"Kc": None, "Kv": None, "t_cut": c["t_cut"], "error": str(exc)})
    res = {}
    for name, rows in out.items():
        ok = [r for r in rows if r.get("Kc") is not None and np.isfinite(r["Kc"]) and np.isfinite(r["Kv"])]
        res[name] = {"Kc": float(np.mean([r["Kc"] for r in ok])) if ok else None,
                     "Kv": float(np.mean([r["Kv"] for r in ok])) if ok else None,
                     "n": len(ok), "coasts": rows}
    note = ()
    if why:
        note = (f"TDM/FDM: {len(why)} of {len(windows)} coasts have fewer than {min_samples} velocity "
                f"samples (release included: {', '.join(str(n) for n in why)}) and are left to the ML fit",)
    return res["tdm"], res["fdm"], note


def analyse_trial(trial, robot, settings: CoastdownSettings | None = None, log=None) -> list:
    """The coast-downs of ``trial`` (one :class:`TrialCoastdown` per moving joint; the
    campaign's trials move one joint)."""
    s = settings or CoastdownSettings()
    log = log if log is not None else read_robot_log(trial.log, robot.n)
    out = []
    for j in trial.joints:  # loop over joints (one)
        if s.joints and j not in s.joints:
            continue
        j0 = j - 1
        dr = robot.drives[j0]
        J, a, b = _trial_dynamics(trial, robot, j0, log.qm)
        ok = np.isfinite(log.qm[:, j0]) & np.isfinite(log.tau[:, j0])
        t, q, tau = log.time[ok], log.qm[ok, j0], log.tau[ok, j0]
        res = float(dr.encoder_resolution or 0.0)
        if res <= 0:   # unknown encoder: the smallest step the record shows
            steps = np.abs(np.diff(q))
            res = float(np.min(steps[steps > 0])) if np.any(steps > 0) else 1e-6
        vmax = float(dr.max_velocity) if np.isfinite(dr.max_velocity) else float(np.max(np.abs(np.diff(q) / np.diff(t))))
        windows = find_coasts(t, q, tau, resolution=res, v_min=s.v_min_frac * vmax, J=J,
                              gravity=lambda x: a * np.sin(x) + b * np.cos(x), pre_s=s.pre_s,
                              rest_s=s.rest_s, jump_sigmas=s.jump_sigmas)
        notes = []
        if len(trial.joints) > 1:
            notes.append(f"trial moves joints {list(trial.joints)}; coast-down assumes one joint at a time")
        if not windows:
            notes.append("no coast found: no drive-torque cut followed by a coast to rest")
            out.append(TrialCoastdown(trial.id, j, J, trial.load_kg, trial.vmax_frac, None, {}, {},
                                      tuple(notes)))
            continue
        flex = _flex(dr)
        ml = AngleCoastFit(res, sep_rel=s.sep_rel).fit_records([(t, q, windows, J, flex)])
        td, fd, note = _paper_methods(ml, t, q, windows, J, s.min_samples)
        out.append(TrialCoastdown(trial.id, j, J, trial.load_kg, trial.vmax_frac, ml, td, fd,
                                  tuple(notes) + note,
                                  series={"t": t, "q": q, "tau": tau, "windows": windows,
                                          "resolution": res, "flex": flex}))
    return out


def analyse_campaign(campaign, robot=None, settings: CoastdownSettings | None = None,
                     progress: bool = False) -> CoastdownReport:
    """Coast-down identification of every ``kind = "coastdown"`` trial; raises InputError
    (one line) when the campaign has none."""
    s = settings or CoastdownSettings()
    trials = coastdown_trials(campaign)
    if not trials:
        kinds = sorted({tr.kind for tr in campaign.trials}) or ["none"]
        raise InputError(f"no kind = \"coastdown\" trials in campaign {campaign.name!r} "
                         f"(trial kinds: {', '.join(kinds)})", path=campaign.manifest)
    robot = robot if robot is not None else campaign.load_robot()
    it = trials
    if progress:
        from tqdm import tqdm

        it = tqdm(trials, desc="coastdown", unit="trial", leave=False)
    rows, skipped = [], {}
    for tr in it:  # loop over trials
        try:
            rows.extend(analyse_trial(tr, robot, s))
        except InputError as exc:
            skipped[tr.id] = str(exc)
    joints = {}
    for j in sorted({r.joint for r in rows}):  # loop over joints: pooled fit
        mine = [r for r in rows if r.joint == j and r.ml is not None]
        if mine:
            joints[j] = AngleCoastFit(min(float(r.series["resolution"]) for r in mine),
                                      sep_rel=s.sep_rel).fit_records([_record(r) for r in mine],
                                                                     starts=[r.ml for r in mine])
    rows = [_with_pooled_kv(r, joints.get(r.joint), s) for r in rows]
    return CoastdownReport(campaign.name, tuple(rows), joints, skipped, s)


def _record(r: TrialCoastdown) -> tuple:
    return (r.series["t"], r.series["q"], r.series["windows"], r.J, r.series.get("flex"))


def _with_pooled_kv(r: TrialCoastdown, pooled: AngleCoastResult | None, s: CoastdownSettings):
    """A trial that cannot separate Kc from Kv gets its Kc at the joint's pooled Kv (when the
    pool separates them and holds more coasts than the trial): ``Kc(Kv_pool)`` from the trial's
    fit with Kv held, its standard error ``sqrt(se_cond^2 + (dKc/dKv)^2 se(Kv_pool)^2)`` with
    the slope from the fits at ``Kv_pool +- se(Kv_pool)``. The trial's coasts are part of the
    pool, so the two are not independent; with a few trials per joint the pooled Kv is
    dominated by the separable ones."""
    import dataclasses

    if (r.ml is None or r.ml.separable or pooled is None or not pooled.separable
            or len(pooled.coasts) <= len(r.ml.coasts)):
        return r
    fit = AngleCoastFit(float(r.series["resolution"]), sep_rel=s.sep_rel)
    rec = [_record(r)]
    kv, se_kv = pooled.Kv, pooled.stderr["Kv"]
    try:
        flx = r.ml.transmission == "flexible"
        sk = (r.ml.stick or None) if flx else None
        mid = fit.fit_records(rec, kv_fixed=kv, flexible=flx, stick=sk)
        hi = fit.fit_records(rec, kv_fixed=kv + se_kv, flexible=flx, stick=sk)
        lo = fit.fit_records(rec, kv_fixed=max(kv - se_kv, 0.0), flexible=flx, stick=sk)
    except (InputError, ValueError, np.linalg.LinAlgError):
        return r
    slope = (hi.Kc - lo.Kc) / max(hi.Kv - lo.Kv, 1e-300)
    se_kc = float(np.hypot(mid.stderr["Kc"], slope * se_kv))
    pk = {"Kc": float(mid.Kc), "Kv": float(kv), "stderr": {"Kc": se_kc, "Kv": float(se_kv)},
          "stderr_Kc_given_Kv": float(mid.stderr["Kc"]), "dKc_dKv": float(slope),
          "n_coasts_pooled": len(pooled.coasts)}
    note = (f"the trial alone cannot separate Kc from Kv: Kc = {mid.Kc:.4g} ± {se_kc:.2g} N m at the "
            f"joint's pooled Kv = {kv:.4g} ± {se_kv:.2g} N m s/rad ({len(pooled.coasts)} coasts); the "
            f"trial's own fit: Kc = {r.ml.Kc:.4g} ± {r.ml.stderr['Kc']:.2g}, Kv = {r.ml.Kv:.4g} ± "
            f"{r.ml.stderr['Kv']:.2g}")
    return dataclasses.replace(r, pooled_kv=pk, notes=tuple(r.notes) + (note,))


# -- reports -----------------------------------------------------------------------------
def _fmt(x, se=None, digits=4):
    if x is None or not np.isfinite(x):
        return "-"
    if abs(x) < 1e-9:          # at the bound 0
        x = 0.0
    return f"{x:.{digits}g}" + ("" if se is None or not np.isfinite(se) else f" ± {se:.2g}")


def coastdown_table(report: CoastdownReport) -> str:
    """Markdown tables: per joint the pooled fit, per (trial, joint) the ML value with its
    standard errors and whether the record separates Kc from Kv, beside TDM and FDM."""
    lines = ["| joint | coasts | Kc (N m) | Kv (N m s/rad) | corr | separable |",
             "|---|---|---|---|---|---|"]
    for j, r in sorted(report.joints.items()):
        lines.append(f"| {j} | {len(r.coasts)} | {_fmt(r.Kc, r.stderr['Kc'])} | {_fmt(r.Kv, r.stderr['Kv'])} "
                     f"| {r.corr:+.2f} | {'yes' if r.separable else '**no**'} |")
    lines += ["", "Per trial: `ml` = the trial's own fit; `ml-pooled-kv` = the trial alone cannot separate "
              "Kc from Kv, so Kv is the joint's pooled value and Kc the trial's at it (the trial's own "
              "fit in brackets).", "",
              "| trial | joint | load kg | coasts | J (kg m²) | Kc | Kv | method | separable | Kc TDM | Kv TDM "
              "| Kc FDM | Kv FDM |", "|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in report.trials:
        ml = r.ml
        if ml is None:
            lines.append(f"| {r.trial} | {r.joint} | {r.load_kg:g} | 0 | {r.J:.4g} | - | - | - | - | - | - | - | - |")
            continue
        own = "" if r.pooled_kv is None else f" ({_fmt(ml.Kc, ml.stderr['Kc'])})"
        own_v = "" if r.pooled_kv is None else f" ({_fmt(ml.Kv, ml.stderr['Kv'])})"
        lines.append(f"| {r.trial} | {r.joint} | {r.load_kg:g} | {len(ml.coasts)} | {r.J:.4g} "
                     f"| {_fmt(r.Kc, r.stderr['Kc'])}{own} | {_fmt(r.Kv, r.stderr['Kv'])}{own_v} | {r.method} "
                     f"| {'yes' if ml.separable else '**no**'} "
                     f"| {_fmt(r.tdm.get('Kc'))} | {_fmt(r.tdm.get('Kv'))} | {_fmt(r.fdm.get('Kc'))} "
                     f"| {_fmt(r.fdm.get('Kv'))} |")
    return "\n".join(lines)


def _decay_figure(r: TrialCoastdown):
    """Velocity against time since the cut, every coast: interval-mean velocities of the
    encoder angle (dots) and the fitted eq. 4 (lines)."""
    from viz.plots import new_figure  # optional dependency: matplotlib

    fig = new_figure(6.4, 4.0)
    ax = fig.add_subplot(111)
    t, q = r.series["t"], r.series["q"]
    ml = r.ml
    for k, (c, w) in enumerate(zip(ml.coasts, r.series["windows"])):  # loop over coasts
        color = f"C{k % 10}"
        tm, v = interval_velocity(t[w.pre: w.rest + 1], q[w.pre: w.rest + 1])
        ax.plot(1e3 * (tm - c["t_cut"]), w.direction * v, "o", ms=3, color=color)
        tau = np.linspace(-0.3 * max(c["t_stop"], 1e-3), 1.2 * max(c["t_stop"], 1e-3), 200)
        kce = ml.Kc - w.direction * c["u"]
        vm = np.where(tau < 0, abs(c["v_cut"]), coast_speed(np.maximum(tau, 0.0), c["J"], ml.Kv, kce,
                                                             abs(c["v_cut"])))
        ax.plot(1e3 * tau, vm, "-", lw=1, color=color,
                label=f"{'+' if w.direction > 0 else '-'}{abs(c['v_cut']):.2f} rad/s")
    ax.axvline(0.0, color="k", lw=0.5)
    ax.set_xlabel("time since the drive cut (ms)")
    ax.set_ylabel("speed along the coast (rad/s)")
    ax.set_title(f"{r.trial}, joint {r.joint}: Kc = {ml.Kc:.3g} ± {ml.stderr['Kc']:.2g} N m, "
                 f"Kv = {ml.Kv:.3g} ± {ml.stderr['Kv']:.2g} N m s/rad", fontsize=8)
    ax.legend(fontsize=7)
    return fig


def write_coastdown(report: CoastdownReport, out, sink=None, plots: bool = True) -> dict:
    """Write ``coastdown.json``, ``coastdown.md`` and ``plots/<trial>-j<joint>.png`` into
    ``out``; log the decay curves and the report to ``sink``. Returns the paths."""
    import json

    sink = sink or NullSink()
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    paths = {"json": out / "coastdown.json", "md": out / "coastdown.md"}
    paths["json"].write_text(json.dumps(report.to_dict(), indent=1) + "\n", encoding="utf-8")
    md = [f"# Coast-down identification: {report.campaign}", "",
          "Coulomb `Kc` and total viscous `Kv` (link and motor side, link side units) from the coasts "
          "of the `kind = \"coastdown\"` trials (source 000). ML: maximum likelihood on the encoder "
          "angle with the cut instant and the stop (the reported value, ± standard errors); TDM and "
          "FDM: the paper's methods on interval-mean velocities, for coasts long enough. `J` = URDF "
          "inertia at the posture with the payload + motor inertia. Per joint, all coasts together:",
          "", coastdown_table(report), ""]
    notes = [(r.trial, r.joint, n) for r in report.trials for n in r.to_format()["notes"]]
    if notes:
        md += ["## Notes", ""] + [f"- {tid} joint {j}: {n}" for tid, j, n in notes] + [""]
    if report.skipped:
        md += ["## Trials left out", ""] + [f"- {k}: {v}" for k, v in report.skipped.items()] + [""]
    for r in report.trials:  # loop over trials: figures and viewer
        if r.ml is None:
            continue
        base = f"coastdown/{r.trial}/joint{r.joint}"
        t, q = r.series["t"], r.series["q"]
        tm, v = interval_velocity(t, q)
        if sink.enabled:
            sink.scalars(f"{base}/velocity", tm, v[:, None], names=["encoder_interval_velocity"])
            sink.scalars(f"{base}/torque", t, r.series["tau"][:, None], names=["tau_logged"])
            vm = np.full(tm.shape, np.nan)
            for c, w in zip(r.ml.coasts, r.series["windows"]):  # loop over coasts
                sel = (tm >= c["t_cut"]) & (tm <= t[w.rest])
                kce = r.ml.Kc - w.direction * c["u"]
                vm[sel] = w.direction * coast_speed(tm[sel] - c["t_cut"], c["J"], r.ml.Kv, kce,
                                                    abs(c["v_cut"]))
            sink.scalars(f"{base}/velocity_model", tm, vm[:, None], names=["ml_fit"])
        if plots or sink.enabled:
            from viz.plots import figure_to_rgb, save_png  # optional dependency: matplotlib

            fig = _decay_figure(r)
            if plots:
                rel = f"plots/{r.trial}-j{r.joint}.png"
                save_png(fig, out / rel, overwrite=True)
                md += [f"![{r.trial} joint {r.joint}]({rel})", ""]
            if sink.enabled:
                sink.image(f"{base}/decay", figure_to_rgb(fig))
    text = "\n".join(md)
    paths["md"].write_text(text, encoding="utf-8")
    if sink.enabled:
        sink.text("coastdown/report", text)
    return paths
