"""The campaign-level friction fit (thesis 002, ch. 4-5): every trial, every moving joint,
every friction model, then statistics over the repetitions.

Per (trial, joint) — :func:`fit_trial_joint`, a pure function of a picklable
:class:`FitTask`, so any executor can run it:

1. read the robot log (and ``angles/<trial id>.csv`` when an angles folder is given; without
   it, or without that joint's column, the motor angle stands in for the link angle and the
   result says ``link_source = "motor"``);
2. :func:`ident.model.linkstate.prepare_joint_signals`: Fourier fits (eq. 3-2) of ``qm`` and ``q`` on one
   time base (marker time + ``time_offset``: the trial's ``time_offset`` key, 0 by default, or
   estimated when ``sync="estimate"``); trials of a kind other than ``excitation`` use the
   documented smoother;
3. :class:`ident.model.onelink.OneLinkIdentifier`: eq. 2-4 with each friction model.

:func:`fit_onelink_campaign` runs the tasks through ``executor.map`` (serial ``map`` by default),
then :class:`FitsResult` builds ``fits.json`` (FORMAT.md), the thesis tables
(:mod:`ident.thesis.tables`), friction-vs-speed plots and the sink log. Coast-down trials are skipped
(another estimator handles them).
"""
from __future__ import annotations

import dataclasses
import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from mocap.io.errors import InputError, warn_input
from mocap.io.angles import angles_path, read_angles

from ident.thesis import tables as stats
from ident.model.onelink import OneLinkIdentifier, model_class, onelink_regressor, onelink_target
from ident.model.linkstate import prepare_joint_signals
from ident.signals.smoothing import FourierSmoother, SavGolSmoother, one_blas_thread
from ident.friction.plausibility import assess, input_checks, input_warning, marker_clock_check, to_json
from mocap.io.payload import payload_com, payload_com_unknown
from mocap.io.robotlog import read_robot_log
from mocap.robot import Robot

__all__ = ["FitTask", "TrialJointFit", "FitsResult", "fit_trial_joint", "fit_onelink_campaign",
           "campaign_tasks", "log_fits", "read_tx40_config", "load_tx40"]

_PLOT_POINTS = 3000


@dataclass(frozen=True)
class FitTask:
    """Everything one (trial, joint) fit needs, as plain picklable values."""

    trial: str
    joint: int                      # 1-based
    log: str
    angles: str | None
    J: float
    B: float
    n_joints: int
    load_kg: float = 0.0
    vmax_frac: float = 1.0
    repetition: int = 1
    kind: str = "excitation"
    models: tuple = ("cv", "stribeck", "hyperbolic")
    n_starts: int = 8
    seed: int = 0
    time_offset: float | str = 0.0
    max_harmonics: int = 20
    coupling: tuple | None = None   # [robot] coupling (q_urdf = coupling @ q_log)
    K: float = float("nan")         # declared stiffness (drives.toml), N m/rad; NaN: not declared
    link_method: str = "encoder+deflection"
    urdf_dyn: tuple | None = None   # (I, a, b) of the URDF + payload at the trial's posture
    max_torque: float = float("inf")  # the drive's torque limit (drives.toml), N m


@dataclass(frozen=True, eq=False)
class TrialJointFit:
    """The fits of one joint of one trial, with the signal diagnostics and plot samples."""

    task: FitTask
    fits: dict                      # model -> FrictionFit (one-link, eq. 2-4)
    signals: dict                   # JointSignals.to_dict()
    max_abs_tau: float
    peak_speed: float
    notes: tuple = ()
    plot: dict = field(default_factory=dict, repr=False)   # time, qd, y, f_measured, pred_<model>
    param_flags: dict = field(default_factory=dict)  # model -> {param: {"flag", "reason"}}
    input_checks: tuple = ()        # plausibility.InputCheck of the cv fit against its inputs

    def records(self) -> list[dict]:
        t = self.task
        return [{"trial": t.trial, "joint": t.joint, "load_kg": t.load_kg, "vmax_frac": t.vmax_frac,
                 "repetition": t.repetition, "model": m, "params": dict(f.params),
                 "stderr": {k: f.stderr.get(k, float("nan")) for k in f.params}, "rms": f.rms,
                 "max_abs_tau": self.max_abs_tau, "peak_speed": self.peak_speed,
                 "degenerate": f.form, "flags": list(f.flags),
                 "param_flags": self.param_flags.get(m, {}),
                 "input_checks": [c.says for c in self.input_checks] if m == "cv" else [],
                 "eiv_exceeds_se": bool(f.eiv["exceeds_se"]) if f.eiv else None}
                for m, f in self.fits.items()]


def _jnum(x):
    x = float(x)
    return x if np.isfinite(x) else None


def _bridge_missing(time, qm, tau):
    """``tau`` with its empty cells (FORMAT.md: a missing sample) between logged samples
    bridged linearly, and the mask of those cells. The signals of the fit are computed on the
    log's whole grid, so that one missing cell leaves the smoothing windows and the
    derivative bandwidths as they are (an irregular grid would re-shape the whole fit); the
    bridged samples are then dropped (:func:`_drop_samples`): they never enter eq. 2-4."""
    tau = np.asarray(tau, float)
    fin = np.isfinite(tau)
    missing = ~fin & np.isfinite(qm)
    if not missing.any() or fin.sum() < 2:
        return tau, np.zeros(tau.shape, bool)
    inside = missing & (time > time[fin][0]) & (time < time[fin][-1])
    out = tau.copy()
    out[inside] = np.interp(time[inside], time[fin], tau[fin])
    return out, inside


def _drop_samples(sig, times):
    """``sig`` (a :class:`~ident.signals.smoothing.JointSignals`) without the samples at
    ``times`` (the bridged empty cells)."""
    keep = ~np.isin(sig.time, times)
    arrays = {f.name: getattr(sig, f.name)[keep] for f in dataclasses.fields(sig)
              if isinstance(getattr(sig, f.name), np.ndarray) and getattr(sig, f.name).shape == sig.time.shape}
    return dataclasses.replace(sig, **arrays)


def fit_trial_joint(task: FitTask) -> TrialJointFit:
    """Signals + eq. 2-4 fits for one (trial, joint) (see the module docstring)."""
    with one_blas_thread():
        return _fit_trial_joint(task)


def _fit_trial_joint(task: FitTask) -> TrialJointFit:
    log = read_robot_log(task.log, n_joints=task.n_joints)
    if task.coupling is not None:
        log = log.coupled(task.coupling)
    j0 = task.joint - 1
    notes = []
    t_ang = q_link = None
    if task.angles is not None:
        track = read_angles(task.angles)
        if task.joint in track.q:
            t_ang, q_link = track.time, track.q[task.joint]
        else:
            notes.append(f"{task.angles} has no q_{task.joint}: the motor angle is used as the link angle")
    else:
        notes.append("no angles folder: the motor angle is used as the link angle (rigid-joint approximation)")
    periodic = None if task.kind == "excitation" else False
    # derivative bandwidth from the data: a Fourier fit only when its residual is at the noise
    # level of a GCV-chosen Savitzky-Golay smoother (else that smoother)
    smoother = FourierSmoother(max_harmonics=task.max_harmonics, periodic=periodic,
                               fallback=SavGolSmoother("auto"))
    qm, tau = log.qm[:, j0], log.tau[:, j0]
    if not np.isfinite(qm).any() or not np.isfinite(tau).any():
        raise InputError(f"trial {task.trial!r}: the log has no qm_{task.joint}/tau_{task.joint} data",
                         path=task.log, label=f"qm_{task.joint}")
    tau, missing = _bridge_missing(log.time, qm, tau)
    sig = prepare_joint_signals(task.joint, log.time, qm, tau, t_ang, q_link,
                                time_offset=task.time_offset, smoother=smoother,
                                link_method=task.link_method, drive=(task.J, task.B, task.K))
    if missing.any():
        sig = _drop_samples(sig, log.time[missing])
        notes.append(f"{int(missing.sum())} empty tau_{task.joint} cell(s): those samples are left out of "
                     "the fit (the torque bridged linearly across them only to smooth the deflection)")
    ident = OneLinkIdentifier(task.models, n_starts=task.n_starts, seed=task.seed)
    y = onelink_target(sig.tau, sig.qmd, sig.qmdd, task.J, task.B)
    fits = ident.fit(sig.q, sig.qd, sig.qdd, y, errors=sig.errors)
    # plot samples: measured friction = y - rigid part of the cv fit (or of the first model)
    ref = fits.get("cv") or next(iter(fits.values()))
    X = onelink_regressor(sig.q, sig.qdd)
    rigid = np.array([ref.rigid[k] for k in ("I", "mglx", "mgly")])
    f_meas = y - X @ rigid
    step = max(1, sig.time.size // _PLOT_POINTS)
    plot = {"time": sig.time[::step], "qd": sig.qd[::step], "y": y[::step], "f_measured": f_meas[::step]}
    for m, f in fits.items():
        pr = X @ np.array([f.rigid[k] for k in ("I", "mglx", "mgly")]) + f.friction().torque(sig.qd)
        plot[f"pred_{m}"] = pr[::step]
    sd = sig.to_dict()
    pres = ident.presliding_
    sd["presliding"] = pres
    if pres is not None:
        c_now = float(fits["cv"].params["c"]) if "cv" in fits else float("nan")
        eff = (f"; Coulomb + viscous level {100 * (pres['coulomb_without_cut'] / c_now - 1):+.1f} % "
               "without the cut" if np.isfinite(c_now) and c_now != 0 else "")
        notes.append(f"presliding cut: samples within {pres['end']:.3g} rad of each velocity reversal "
                     f"left out (the friction still rises with the distance moved since the reversal: "
                     f"length {pres['length']:.2g} rad, {100 * pres['gain']:.0f} % of the Coulomb + "
                     f"viscous residual; {100 * pres['kept']:.0f} % of the moving samples kept{eff})")

    raw = {m: assess(m, f.params, qd=sig.qd, stderr=f.stderr, model=f.friction(),
                     form=f.form, tau_scale=float(np.max(np.abs(sig.tau))))
           for m, f in fits.items()}
    pflags = {m: to_json(fl) for m, fl in raw.items()}
    checks = ()
    if "cv" in fits:     # the physical-plausibility layer over the inputs (issue 45)
        cv = fits["cv"]
        checks = tuple(input_checks(sig.time, sig.q, sig.qd, sig.qdd, sig.tau, params=cv.params,
                                    rigid=cv.rigid, stderr=cv.stderr, flags=raw["cv"],
                                    urdf_dyn=task.urdf_dyn, max_torque=task.max_torque))
        if t_ang is not None:   # the marker clock against the robot's (FORMAT.md time_offset)
            checks += tuple(marker_clock_check(np.asarray(t_ang) + float(sig.time_offset), q_link, log.time, qm))
        notes.extend(f"input check: {c.says}" for c in checks)
    return TrialJointFit(task, fits, sd, float(np.max(np.abs(sig.tau))), float(np.max(np.abs(sig.qd))),
                         tuple(notes), plot, pflags, checks)


@dataclass(frozen=True, eq=False)
class FitsResult:
    """All (trial, joint) fits of a campaign plus the statistics over repetitions."""

    entries: tuple
    models: tuple
    campaign: str = ""
    skipped: tuple = ()

    def records(self) -> list[dict]:
        return [r for e in self.entries for r in e.records()]

    def presliding_summary(self) -> str | None:
        """One sentence on the presliding cut of :class:`ident.model.onelink.OneLinkIdentifier`
        over the entries (how many fits left samples out, the cut distances, the Coulomb +
        viscous level without the cut); None when no fit was cut."""
        cut = [(e, e.signals.get("presliding")) for e in self.entries
               if isinstance(e.signals, dict) and e.signals.get("presliding")]
        if not cut:
            return None
        ends = [p["end"] for _, p in cut]
        eff = [100 * (p["coulomb_without_cut"] / e.fits["cv"].params["c"] - 1) for e, p in cut
               if "cv" in e.fits and e.fits["cv"].params["c"]]
        return (f"Presliding cut: {len(cut)} of {len(self.entries)} trial-joint fits left out the "
                f"samples within {min(ends):.2g}-{max(ends):.2g} rad of each velocity reversal, where "
                "the friction still rises with the distance moved since the reversal"
                + (f" (Coulomb + viscous level {min(eff):+.1f} to {max(eff):+.1f} % without the cut)"
                   if eff else "")
                + "; per fit: the notes in `fits/fits_diagnostics.json` (docs/equations.md).")

    @property
    def summary(self) -> list[dict]:
        return stats.summarize(self.records())

    def _fits_parts(self) -> list:
        """``fits.json`` as (key, value) pairs, ``trials`` as a generator of (trial id, that
        trial's document) (:func:`write_json_streamed`)."""
        by_trial: dict = {}
        for e in self.entries:  # loop over entries (references only)
            by_trial.setdefault(e.task.trial, []).append(e)

        def trials():
            for tid, es in by_trial.items():  # loop over trials: one trial's document at a time
                doc: dict = {}
                for e in es:  # loop over the trial's joints
                    tj = doc.setdefault(str(e.task.joint), {})
                    for m, f in e.fits.items():
                        tj[m] = {"params": {k: _jnum(v) for k, v in f.params.items()},
                                 "stderr": {k: _jnum(f.stderr.get(k, np.nan)) for k in f.params},
                                 "rms": _jnum(f.rms), "flags": e.param_flags.get(m, {})}
                        if m == "cv" and e.input_checks:   # ident.friction.plausibility.input_checks
                            tj[m]["input_checks"] = _clean_json([c.to_dict() for c in e.input_checks])
                yield tid, doc

        summ = [{k: r[k] for k in ("joint", "load_kg", "vmax_frac", "model", "param", "mean", "cv_percent")}
                for r in self.summary]    # means over the physically valid fits only (n_excluded: diagnostics)
        return [("format", 1), ("trials", trials()), ("summary", summ)]

    def to_dict(self) -> dict:
        """The ``fits.json`` document (FORMAT.md): trials -> id -> joint -> model ->
        {params, stderr, rms}, and the summary list."""
        return {k: (dict(v) if k == "trials" else v) for k, v in self._fits_parts()}

    def _diagnostics_parts(self) -> list:
        """``fits_diagnostics.json`` as (key, value) pairs, ``trials`` as a generator of
        (trial id, that trial's document): :meth:`write` writes it one trial at a time."""
        recs = self.records()
        summary = stats.summarize(recs)
        head = [("format", 1), ("campaign", self.campaign), ("models", list(self.models)),
                ("skipped", list(self.skipped))]
        tail = [("rms_summary", stats.rms_summary(recs)), ("summary", summary),
                ("excluded", stats.excluded_fits(recs)),
                ("viscous_basis", "link only: v, Fv, g6 exclude the motor viscous B of drives.toml "
                                  "(removed in the eq. 2-4 target); link + motor viscous is v + B")]
        by_trial: dict = {}
        for e in self.entries:  # loop over entries (references only)
            by_trial.setdefault(e.task.trial, []).append(e)

        def trials():
            for tid, es in by_trial.items():  # loop over trials: one trial's document at a time
                yield tid, {str(e.task.joint): {
                    "signals": e.signals, "notes": list(e.notes), "max_abs_tau": e.max_abs_tau,
                    "peak_speed": e.peak_speed, "load_kg": e.task.load_kg, "vmax_frac": e.task.vmax_frac,
                    "repetition": e.task.repetition,
                    "fits": {m: f.to_dict() for m, f in e.fits.items()}} for e in es}

        return head + [("trials", trials())] + tail

    def diagnostics(self) -> dict:
        """Everything else: rigid parameters, conditioning, degenerate forms, signal fits,
        the RMS statistics (``fits_diagnostics.json``)."""
        return {k: (dict(v) if k == "trials" else v) for k, v in self._diagnostics_parts()}

    def write(self, out_dir: str | Path, plots: bool = True) -> dict:
        """Write fits.json, fits_diagnostics.json, tables/ and plots/ into ``out_dir``."""
        out_dir = Path(out_dir)
        out_dir.mkdir(parents=True, exist_ok=True)
        paths = {"fits": out_dir / "fits.json", "diagnostics": out_dir / "fits_diagnostics.json"}
        with open(paths["fits"], "w", encoding="utf-8") as fh:
            write_json_streamed(fh, self._fits_parts())
        with open(paths["diagnostics"], "w", encoding="utf-8") as fh:
            write_json_streamed(fh, self._diagnostics_parts(), clean=_clean_json)
        recs = self.records()
        paths["tables"] = stats.write_tables(recs, out_dir / "tables", self.models) if recs else []
        paths["plots"] = self.write_plots(out_dir / "plots") if plots else []
        return paths

    def write_plots(self, plot_dir: Path) -> list[Path]:
        """One friction-vs-speed PNG per (joint, load, speed range): its first repetition."""
        done, figures = set(), []
        for e in sorted(self.entries, key=lambda e: (e.task.joint, -e.task.load_kg, -e.task.vmax_frac,
                                                    e.task.repetition)):
            key = (e.task.joint, e.task.load_kg, e.task.vmax_frac)
            if key in done or not e.plot:
                continue
            done.add(key)
            models = {m: f.friction() for m, f in e.fits.items()}
            title = (f"joint {e.task.joint}, load {e.task.load_kg:g} kg, {100 * e.task.vmax_frac:g} % "
                     f"speed (trial {e.task.trial})")
            name = f"friction_joint{e.task.joint}_load{e.task.load_kg:g}_v{100 * e.task.vmax_frac:g}.png"
            figures.append((plot_dir / name, e.plot["qd"], e.plot["f_measured"], models, title))
        return stats.plot_friction_vs_speed_many(figures)   # one figure redrawn: the same PNGs


def _json_text(x, depth: int) -> str:
    """``json.dumps(x, indent=1, allow_nan=False)`` as it reads ``depth`` levels down a document
    written with ``indent=1`` (JSON strings hold no raw line feed: each one starts a line)."""
    return json.dumps(x, indent=1, allow_nan=False).replace("\n", "\n" + " " * depth)


def write_json_streamed(fh, parts, clean=lambda x: x) -> None:
    """Write ``json.dumps(clean(doc), indent=1, allow_nan=False)`` of the document whose
    (key, value) pairs are ``parts`` (the same bytes), where a value that is a generator of
    (key, value) pairs is a dictionary written one entry at a time: the whole document is never
    held (a study's per-trial diagnostics of thousands of trials)."""
    import types

    fh.write("{")
    for i, (k, v) in enumerate(parts):  # loop over the document's keys
        fh.write(("," if i else "") + "\n " + json.dumps(str(k)) + ": ")
        if not isinstance(v, types.GeneratorType):
            fh.write(_json_text(clean(v), 1))
            continue
        n = 0
        for k2, v2 in v:  # loop over the entries, one at a time
            fh.write(("," if n else "{") + "\n  " + json.dumps(str(k2)) + ": " + _json_text(clean(v2), 2))
            n += 1
        fh.write("\n }" if n else "{}")
    fh.write("\n}" if parts else "}")


def _clean_json(x):
    if isinstance(x, dict):
        return {str(k): _clean_json(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_clean_json(v) for v in x]
    if isinstance(x, (float, np.floating)):
        return float(x) if np.isfinite(x) else None
    if isinstance(x, np.integer):
        return int(x)
    if isinstance(x, np.ndarray):
        return _clean_json(x.tolist())
    return x


def _urdf_dynamics(trial, robot, j0: int):
    """``(I, a, b)`` of the one-link model of joint ``j0`` (0-based) from the URDF with the
    trial's payload, the other joints at their median logged angles
    (:meth:`mocap.robot.Robot.single_joint_dynamics`); None where it cannot be evaluated."""
    if trial.load_kg > 0 and payload_com_unknown(trial):
        return None                    # the payload's gravity torque is not known
    try:
        log = read_robot_log(trial.log, n_joints=robot.n)
        qm = log.qm if log.qm.shape[1] == robot.n else None
        if qm is None:
            return None
        rest = np.nanmedian(np.where(np.isfinite(qm), qm, np.nan), axis=0)
        rest = np.where(np.isfinite(rest), rest, 0.0)
        rb = robot.with_payload(trial.load_kg, payload_com(trial)) if trial.load_kg > 0 else robot
        return tuple(float(x) for x in rb.single_joint_dynamics(j0, rest))
    except (InputError, ValueError, RuntimeError):   # no URDF evidence: the check is skipped
        return None


def campaign_tasks(campaign, angles_dir=None, models=("cv", "stribeck", "hyperbolic"), n_starts: int = 8,
                   seed: int = 0, sync: str = "clock", robot=None) -> tuple[list[FitTask], list[str]]:
    """The (trial, joint) tasks of a campaign and the ids of skipped (coast-down) trials."""
    robot = robot if robot is not None else campaign.load_robot()
    tasks, skipped = [], []
    for k, tr in enumerate(campaign.trials):
        if tr.kind == "coastdown":
            skipped.append(tr.id)
            continue
        if not Path(tr.log).is_file():
            raise InputError(f"trial {tr.id!r}: log file {tr.log} not found", path=campaign.manifest,
                             label=tr.id)
        ang = None
        if angles_dir is not None:
            ang = str(angles_path(angles_dir, tr.id))
        off = tr.extra.get("time_offset", 0.0)
        if sync == "estimate":
            off = "estimate"
        unl = [j for j in tr.joints if j in tr.unlogged_torque]
        if unl and len(tr.joints) == 1:           # FORMAT.md unlogged_torque: said once
            # (a multi-joint record's unlogged joints are said by the rigid-body stage)

            warn_input(f"trial {tr.id!r}: torque not logged on joint(s) {unl} (unlogged_torque): "
                       "not fitted", path=campaign.manifest)
        for j in tr.joints:
            if j in tr.unlogged_torque:
                continue
            d = robot.drives[j - 1]
            tasks.append(FitTask(tr.id, int(j), str(tr.log), ang, float(d.motor_inertia),
                                 float(d.motor_viscous), robot.n, tr.load_kg, tr.vmax_frac,
                                 tr.repetition, tr.kind, tuple(models), n_starts,
                                 int(seed) + 1000 * k + int(j), off, coupling=campaign.coupling,
                                 K=float(d.extra.get("stiffness", float("nan"))),
                                 urdf_dyn=_urdf_dynamics(tr, robot, j - 1),
                                 max_torque=float(d.max_torque)))
    return tasks, skipped


def fit_onelink_campaign(campaign, angles_dir=None, models=("cv", "stribeck", "hyperbolic"), sink=None,
                 executor=None, n_starts: int = 8, seed: int = 0, sync: str = "clock") -> FitsResult:
    """Fit every (trial, joint) of ``campaign`` (a :class:`mocap.io.campaign.Campaign`) with each
    friction model; ``executor``: anything with ``map(fn, iterable)`` (a
    ``concurrent.futures`` executor, the project's executor seam), default serial.
    ``sync``: ``"clock"`` (marker time + the trial's ``time_offset``) or ``"estimate"``."""
    for m in models:
        model_class(m)
    tasks, skipped = campaign_tasks(campaign, angles_dir, models, n_starts, seed, sync)
    mapper = executor.map if executor is not None else map
    entries = tuple(mapper(fit_trial_joint, tasks))
    res = FitsResult(entries, tuple(models), campaign.name, tuple(skipped))
    why = input_warning([(f"trial {e.task.trial!r} joint {e.task.joint}", e.task.joint, e.input_checks)
                         for e in entries])
    if why:                 # ONE warning naming the input mistakes that would explain them
        warn_input(why, path=campaign.manifest)
    if sink is not None:
        log_fits(res, sink)
    return res


def log_fits(result: FitsResult, sink) -> None:
    """Scalars (eq. 2-4 target and model predictions over time) and points (friction vs speed,
    as (qd, f, 0)) for every (trial, joint) under ``fits/<trial>/joint<j>``."""
    if not getattr(sink, "enabled", False):
        return
    for e in result.entries:
        base = f"fits/{e.task.trial}/joint{e.task.joint}"
        p = e.plot
        names = ["y"] + [f"pred_{m}" for m in e.fits]
        sink.scalars(f"{base}/torque", p["time"], np.column_stack([p[n] for n in names]), names=names)
        pts = np.column_stack([p["qd"], p["f_measured"], np.zeros_like(p["qd"])])
        sink.points(f"{base}/friction_vs_speed/data", pts)
        v = np.linspace(-np.max(np.abs(p["qd"])), np.max(np.abs(p["qd"])), 201)
        for m, f in e.fits.items():
            curve = np.column_stack([v, f.friction().torque(v), np.zeros_like(v)])
            sink.points(f"{base}/friction_vs_speed/{m}", curve)


# ---------------------------------------------------------------------------------------------
# Staubli TX40 (real data, figaroh-examples)
# ---------------------------------------------------------------------------------------------
def read_tx40_config(path: str | Path) -> dict:
    """The few numeric list/scalar keys of ``TX40_config.yaml`` (``fv``, ``fs``, ``Ia``,
    ``offset``, ``reduction_ratio``, ``ts``, ...): a tiny ``key : value`` line parser, no YAML
    dependency."""
    out = {}
    path = Path(path)
    for i, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1):
        s = line.split("#", 1)[0].strip().lstrip("- ").strip()
        if ":" not in s:
            continue
        key, val = (x.strip() for x in s.split(":", 1))
        if not val:
            continue
        try:
            if val.startswith("["):
                out[key] = [float(x) for x in val.strip("[]").split(",") if x.strip()]
            else:
                out[key] = float(val)
        except ValueError:
            continue
    for k in ("fv", "fs", "reduction_ratio", "ts"):
        if k not in out:
            raise InputError(f"no numeric '{k}' key", path=path, label=k)
    return out


def _read_numeric_csv(path: Path) -> np.ndarray:
    try:
        return np.loadtxt(path, delimiter=",", skiprows=1, ndmin=2)
    except ValueError as exc:
        raise InputError(f"not a numeric CSV: {exc}", path=path) from None


def load_tx40(folder: str | Path, decimate: int = 5, window_s: float = 0.02):
    """The Staubli TX40 logs (figaroh-examples) on the joint side: ``(t, q, qd, qdd, tau, robot,
    cfg)``, smoothed with Savitzky-Golay (``window_s``), edges dropped, every ``decimate``-th
    sample.

    Data: ``pos_read_data.csv`` motor positions (rad), ``curr_data.csv`` motor torques, both at
    ``ts`` (0.2 ms). Conversion as in figaroh's TX40 tools: ``q = N^-1 qm`` with the wrist
    coupling ``N[5, 4] = r6``, joint offsets -pi/2 (joint 2) and +pi/2 (joint 3), joint torques
    ``tau = N_tau tau_m`` with ``N_tau[4, 5] = r6``."""
    folder = Path(folder)
    cfg = read_tx40_config(folder / "TX40_config.yaml")
    urdf = next(iter(sorted(folder.glob("*.urdf"))), None)
    if urdf is None:
        raise InputError("no URDF in the TX40 folder", path=folder)
    pos = _read_numeric_csv(folder / "pos_read_data.csv")
    cur = _read_numeric_csv(folder / "curr_data.csv")
    if pos.shape != cur.shape or pos.shape[1] != 6:
        raise InputError(f"position {pos.shape} and torque {cur.shape} tables must both be (T, 6)",
                         path=folder)
    r = np.asarray(cfg["reduction_ratio"], float)
    Nq = np.diag(r)
    Nq[5, 4] = r[5]
    q = np.linalg.solve(Nq, pos.T).T
    q[:, 1] -= np.pi / 2
    q[:, 2] += np.pi / 2
    Nt = np.diag(r)
    Nt[4, 5] = r[5]
    tau = cur @ Nt.T
    t = np.arange(pos.shape[0]) * float(cfg["ts"])
    sm = SavGolSmoother(window_s=window_s, polyorder=3)
    qs, qd, qdd = (np.empty_like(q) for _ in range(3))
    for j in range(6):
        f = sm.fit(t, q[:, j])
        qs[:, j], qd[:, j], qdd[:, j] = f.evaluate(t)
    # drop the filter's edges and decimate
    edge = int(round(window_s / float(cfg["ts"])))
    sl = slice(edge, q.shape[0] - edge, int(decimate))
    robot = Robot.from_urdf(urdf)
    if robot.n != 6:
        raise InputError(f"the TX40 URDF has {robot.n} revolute joints, expected 6", path=urdf)
    return t[sl], qs[sl], qd[sl], qdd[sl], tau[sl], robot, cfg
