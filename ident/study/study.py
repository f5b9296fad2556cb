"""Batch studies end to end: calibration, link angles, friction fits, gap diagnosis, report.

One campaign (FORMAT.md) in, one study folder out::

    DIR/calib.json                 camera-to-base calibration (the [[calib]] sweeps, thesis ch. 3)
    DIR/references.json            static-pose marker references (thesis eq. 3-4)
    DIR/angles/<trial id>.csv      link angles per trial (eq. 3-5), FORMAT.md
    DIR/mocap.json                 per-trial solve summary
    DIR/fits/                      fits.json, fits_diagnostics.json, tables/ (Tables 5-1..5-3, A, B),
                                   plots/ (friction vs speed per condition), from eq. 2-4
    DIR/diagnosis/                 diagnosis.json, diagnosis.md and its plots (the gap diagnosis)
    DIR/report.md                  the study report (thesis-style tables, plots, verdicts)
    DIR/plots/                     friction curves per joint, parameter spread over repetitions
    DIR/csv/                       trials.csv (one row per trial and joint), diagnosis_effects.csv
    DIR/study.rrd                  one rerun recording: markers + robot, joint signals, fits, diagnosis
    DIR/.jointlab-study.json       the study's cache manifest: input hashes of every stage item and
                                   the sha256 of every record
    DIR/.jointlab-study/           records of finished items (JSON, :mod:`ident.study.records`), temp files
    DIR/.jointlab-outputs.json     the output manifest (:mod:`ident.outputs`): sha256 and writer of
                                   every output file

Work per trial (the angle solve, the fits) and per joint (the diagnosis) goes through the one
executor seam (:mod:`ident.study.executor`: serial, a local process pool, a Dask cluster). Workers write
their outputs themselves, each to a temporary name then :func:`os.replace` (so an interrupted
study leaves no half-written file, and the items finished before the interruption are kept), and
then a record holding the item's input hash, result and the sha256 of its outputs (JSON, never
pickle: :mod:`ident.study.records`). A rerun skips an item only when its record verifies against
its recorded hashes, has the current input hash, and every output it lists is registered to the
study in the output manifest with the same sha256 as the bytes on disk now; a record that fails
its check is recomputed with one line saying so, an output changed since (edited by hand or by
another program) is recomputed, and a file in the way that another command or the user wrote
is refused with one line naming it (:mod:`ident.outputs`). Input hashes are sha256 over the item's
files (marker file, robot log, campaign.toml, the robot's URDF and drives, upstream outputs such as
calib.json and the angles) and the settings that change the result. With a Dask cluster, the
campaign and the study folder must be on a file system every worker sees at the same path.
"""
from __future__ import annotations

import contextlib
import csv
import dataclasses
from dataclasses import dataclass, field
from functools import lru_cache
import hashlib
import io
import json
import os
from pathlib import Path
import shutil
import sys
import time
from typing import Callable

import numpy as np

from calib.pipeline import CalibResult, calibrate, log_calibration, summary_markdown
from ident.coastdown.campaign_analysis import analyse_campaign, coastdown_table, write_coastdown
from ident.common import to_jsonable as _jsonable
from ident.gap import DiagnosisSettings
from ident.gap.campaign_diagnosis import (CampaignDiagnosis, diagnose_single_joint_campaign, load_angles_dir,
                                          read_angles_csv)
from ident.gap.nominal import check_nominal
from ident.gap.report import make_plots, markdown
from ident.gap.result import JointDiagnosis
from ident.model.multijoint import diagnose_records
from ident.outputs import OutputDir, file_sha256
from ident.pipeline.plan import PipelineSettings
from ident.pipeline.plan import plan as pipeline_plan
from ident.pipeline.stage import Context as StageContext
from ident.pipeline.stage import Runtime, input_key
from ident.settings import SEED, Flag, Interval, Models, OneOf, Settings, check_settings
from ident.signals.smoothing import one_blas_thread
from ident.study.executor import Pending, SerialExecutor, release_free_memory
from ident.study.lock import StudyLock
from ident.study.records import dumps_record, read_record
from ident.study.view import log_campaign
from ident.thesis.campaign_fit import FitsResult, campaign_tasks, fit_trial_joint, log_fits
from ident.workflow import (FitResult, FitSettings, Plan, fit_campaign, join_diagnoses,
                            fit_plans, plan, subset)
from mocap.io.campaign import Campaign, load_campaign
from mocap.io.errors import InputError
from mocap.quality import marker_report
from mocap.references import build_references
from mocap.solve import solve_trial
from viz import make_sink
from viz.plots import new_subplots, save_png, tight_layout, young_garbage

__all__ = ["StudySettings", "StudyResult", "Study", "run_study", "file_sha256", "MANIFEST_NAME"]

MANIFEST_NAME = ".jointlab-study.json"
STATE_DIR = ".jointlab-study"
CACHE_VERSION = 2     # bump when a record's content changes meaning
#: the pipeline's stages the study runs with per-item records (per trial, per joint), in the
#: list's order; every other stage of :func:`ident.pipeline.plan.plan` runs whole
#: (:meth:`Study._whole_stage`)
ITEM_POLICIES = ("calib", "mocap", "fits", "rigidbody", "diagnosis", "coastdown")


# ---------------------------------------------------------------------------------------------
# settings and result
# ---------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class StudySettings(Settings):
    """What a study computes. Everything here that changes a result is part of the input hashes;
    :attr:`constraints` is checked at construction (:mod:`ident.settings`).

    ``models``: friction models of the fits (eq. 2-4); ``n_starts``/``seed``/``sync``: see
    :func:`ident.thesis.campaign_fit.fit_onelink_campaign`; ``calib_method``: see :func:`calib.pipeline.calibrate`;
    ``mocap``/``diagnose``: run those stages; ``plots``: PNG plots; ``rrd``: write the study
    recording; ``rrd_trials``: ``"first"`` logs the first repetition of every (joints, load,
    speed) condition to the recording (keeps it small), ``"all"`` every trial;
    ``calib_urdf_tol_mm``, ``calib_trust_urdf``, ``calib_deflection``: the calibration's declared URDF
    tolerance, trusted J1-J2 geometry and gravity-deflection compensation (``jointlab calib
    --urdf-tol-mm``, ``--trust-urdf``, ``--deflection``; :func:`calib.pipeline.calibrate`);
    ``sim2real``: also the MuJoCo replay stage (:mod:`ident.pipeline.stages.sim2real`,
    ``sim2real/``); ``diagnosis_reps``: the gap diagnosis of a joint reads the first that many repetitions of
    every condition (0: all; None, the default: the most repetitions whose samples stay within
    :data:`DIAGNOSIS_SAMPLES` per joint, at least one). It holds a joint's samples (a few hundred
    bytes each) while it runs; the rest of its memory does not grow with the trials
    (docs/study-memory.md), so the budget keeps a study's memory flat in its number of trials
    (the fits use every trial regardless)."""

    models: tuple = ("cv", "stribeck", "hyperbolic")
    n_starts: int = 8
    seed: int = 0
    sync: str = "clock"
    calib_method: str = "cluster"
    mocap: bool = True
    diagnose: bool = True
    plots: bool = True
    rrd: bool = True
    rrd_trials: str = "first"
    diagnosis_reps: int | None = None
    calib_urdf_tol_mm: float = 0.0
    calib_trust_urdf: bool = False
    calib_deflection: bool = False
    sim2real: bool = False

    def calib_options(self) -> dict:
        """The keyword options of :func:`calib.pipeline.calibrate` these settings ask for."""
        return dict(urdf_tol_mm=float(self.calib_urdf_tol_mm), urdf_model_error=not self.calib_trust_urdf,
                    deflection=bool(self.calib_deflection))

    #: field -> (command-line option of ``jointlab study``, constraint), checked at construction
    constraints = {
        "models": ("--models", Models()),
        "n_starts": ("--starts", Interval(1, integer=True)),
        "seed": ("--seed", SEED),
        "sync": ("--sync", OneOf("clock", "estimate")),
        "calib_method": ("calib_method", OneOf("cluster", "circle")),
        "mocap": ("--no-mocap", Flag()),
        "diagnose": ("--no-diagnosis", Flag()),
        "plots": ("--no-plots", Flag()),
        "rrd": ("--no-rrd", Flag()),
        "rrd_trials": ("--rrd-trials", OneOf("first", "all")),
        "diagnosis_reps": ("--diagnosis-reps", Interval(0, integer=True, none=True, note="(0: all)")),
        "calib_urdf_tol_mm": ("--urdf-tol-mm", Interval(0.0, 1e3, note="mm")),
        "calib_trust_urdf": ("--trust-urdf", Flag()),
        "calib_deflection": ("--deflection", Flag()),
        "sim2real": ("--sim2real", Flag()),
    }

    def validate(self) -> "StudySettings":
        """These settings, checked again (:func:`ident.settings.check_settings`; construction
        already did: kept for callers that chain it)."""
        check_settings(self)
        return self

    def fit_settings(self) -> FitSettings:
        """The :class:`ident.workflow.FitSettings` of ``jointlab fit`` these settings ask for."""
        return FitSettings(n_starts=self.n_starts, seed=self.seed, sync=self.sync)

    def pipeline_settings(self) -> PipelineSettings:
        """The :class:`ident.pipeline.plan.PipelineSettings` of the stages these settings ask
        for (what a stage without a per-item policy reads: the ``sim2real`` stage)."""
        return PipelineSettings(calib_method=self.calib_method, calib_urdf_tol_mm=self.calib_urdf_tol_mm,
                                calib_trust_urdf=self.calib_trust_urdf, calib_deflection=self.calib_deflection,
                                mocap=self.mocap, models=tuple(self.models), fit=self.fit_settings(),
                                plots=self.plots, diagnose=self.diagnose,
                                diagnosis=DiagnosisSettings(seed=self.seed), sim2real=self.sim2real)

    def to_dict(self) -> dict:
        d = dataclasses.asdict(self)
        d["models"] = list(self.models)
        if not self.sim2real:     # studies written before the stage existed keep their hashes
            del d["sim2real"]
        return d


@dataclass(frozen=True)
class StageReport:
    """One stage's bookkeeping in a study: its items computed, reused and failed, the stage's
    wall time ``seconds``, ``work_s`` (the summed wall time of its computed items as the workers
    measured them: ``work_s / (workers * seconds)`` is the parallel efficiency), ``cpu_s`` (their
    summed CPU time, which other load on the machine barely changes) and a note.
    :meth:`to_dict` gives the row of ``jointlab study --json``; ``row["computed"]`` reads a value
    by that name."""

    computed: int = 0
    reused: int = 0
    failed: int = 0
    seconds: float = 0.0
    note: str = ""
    work_s: float = 0.0
    cpu_s: float = 0.0

    def to_dict(self) -> dict:
        return {"computed": self.computed, "reused": self.reused, "failed": self.failed,
                "seconds": self.seconds, "work_s": self.work_s, "cpu_s": self.cpu_s, "note": self.note}

    def __getitem__(self, key: str):
        if key not in self.__dataclass_fields__:
            raise KeyError(key)
        return getattr(self, key)


@dataclass(frozen=True)
class StudyResult:
    """What a study did: per stage the items computed, reused and failed, and the wall time;
    the paths written; the calibration accuracy and the diagnosis verdicts."""

    out: Path
    campaign: str
    n_trials: int
    stages: dict          # stage -> StageReport
    paths: dict           # name -> path (str) of the main outputs
    verdicts: dict        # joint (str) -> verdict
    calib: dict | None = None
    errors: dict = field(default_factory=dict)   # "<stage>/<item>" -> message
    verdict_lines: dict = field(default_factory=dict)   # joint (str) -> the diagnosis's verdict line

    def to_dict(self) -> dict:
        return {"format": 1, "out": str(self.out), "campaign": self.campaign,
                "n_trials": self.n_trials, "stages": {k: v.to_dict() for k, v in self.stages.items()},
                "paths": {k: str(v) for k, v in self.paths.items()}, "verdicts": self.verdicts,
                "verdict_lines": self.verdict_lines, "calib": self.calib, "errors": self.errors}


# ---------------------------------------------------------------------------------------------
# hashing and atomic writes
# ---------------------------------------------------------------------------------------------
class _Hasher:
    """File digests memoised by (path, size, mtime) for one run; combined digests of parts."""

    def __init__(self):
        self._memo: dict = {}

    def file(self, path) -> str:
        if path is None:                   # an optional input left out ([robot] drives)
            return "none"
        p = Path(path)
        if not p.is_file():
            return "missing:" + str(p)
        st = p.stat()
        key = (str(p.resolve()), st.st_size, st.st_mtime_ns)
        if key not in self._memo:
            self._memo[key] = file_sha256(p)
        return self._memo[key]

    @staticmethod
    def combine(*parts) -> str:
        return hashlib.sha256(json.dumps([CACHE_VERSION, *parts], sort_keys=True,
                                         default=str).encode()).hexdigest()


def _tmp_name(tmp_dir: Path, final: Path) -> Path:
    return Path(tmp_dir) / f"{final.name}.{os.getpid()}.{time.monotonic_ns()}.tmp"


def _write_atomic(path: Path, data: bytes | str, tmp_dir: Path) -> Path:
    """Write to a temporary name in ``tmp_dir`` (same file system), then rename into place."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = _tmp_name(tmp_dir, path)
    tmp.parent.mkdir(parents=True, exist_ok=True)
    with open(tmp, "wb") as fh:
        fh.write(data.encode("utf-8") if isinstance(data, str) else data)
    os.replace(tmp, path)
    return path


def _record_name(key: str) -> str:
    """A record's file name from an item key (a trial id is data, never a path)."""
    return hashlib.sha256(key.encode("utf-8")).hexdigest()[:24] + ".json"


def _write_record(path: Path, input_hash: str, result, tmp_dir: Path, outputs=None) -> None:
    """A JSON record (:mod:`ident.study.records`); ``outputs``: {rel path: sha256}."""
    _write_atomic(path, dumps_record(input_hash, result, CACHE_VERSION, outputs), tmp_dir)


# ---------------------------------------------------------------------------------------------
# worker side (top-level, picklable: run by any executor)
# ---------------------------------------------------------------------------------------------
@lru_cache(maxsize=4)
def _campaign_and_robot(manifest: str, stamp: int):
    """The campaign and its robot, loaded once per worker process (keyed by the manifest's mtime)."""

    camp = load_campaign(manifest)
    return camp, camp.load_robot()


def _load(manifest: str):
    return _campaign_and_robot(manifest, Path(manifest).stat().st_mtime_ns)


def _error_text(exc: BaseException) -> str:
    return f"{type(exc).__name__}: {exc}"


@dataclass(frozen=True)
class _MocapJob:
    manifest: str
    trial: str
    references: object
    solve: Callable
    report: Callable | None
    out_csv: str
    out_rel: str
    record: str
    tmp_dir: str
    input_hash: str


def _run_mocap_job(job: _MocapJob) -> dict:
    """Solve one trial's link angles, write the record (with the sha256 of the angles file) and
    then rename ``angles/<id>.csv`` into place (the study registered the path as its own before
    the job ran). OS errors while writing propagate: the run stops with one line."""

    t0, c0 = time.perf_counter(), time.process_time()
    try:
        camp, robot = _load(job.manifest)
        with one_blas_thread():
            res = job.solve(camp, job.trial, job.references, robot=robot)
        summary = _jsonable(res.to_dict())
        if job.report is not None:
            summary["markers"] = _jsonable(job.report(res.solve))
        result = {"ok": True, "summary": summary, "seconds": time.perf_counter() - t0,
                  "cpu_s": time.process_time() - c0}
    except Exception as exc:           # one bad trial fails alone, with its reason
        return {"ok": False, "error": _error_text(exc)}
    tmp = _tmp_name(Path(job.tmp_dir), Path(job.out_csv))
    tmp.parent.mkdir(parents=True, exist_ok=True)
    try:
        res.write_csv(tmp, overwrite=True)
        sha = file_sha256(tmp)
        result["outputs"] = {job.out_rel: sha}
        _write_record(Path(job.record), job.input_hash, result, Path(job.tmp_dir), {job.out_rel: sha})
        Path(job.out_csv).parent.mkdir(parents=True, exist_ok=True)
        os.replace(tmp, job.out_csv)
    finally:
        tmp.unlink(missing_ok=True)
    return result


@dataclass(frozen=True)
class _FitJob:
    trial: str
    tasks: tuple
    record: str
    tmp_dir: str
    input_hash: str
    keep_plot: bool = True      # return the plot samples (else only the record keeps them)


def _chain(parts) -> Pending:
    """One :class:`Pending` over batches submitted one after the other (``parts``: (pending,
    number of items)): the results in the batches' order; ``each()`` yields each batch's items
    as they finish, batch after batch."""

    def each():
        offset = 0
        for p, n in parts:  # loop over the batches
            with contextlib.closing(p.each()) as it:
                for i, r in it:
                    yield offset + i, r
            offset += n

    def wait():
        return [r for p, _ in parts for r in p.result()]

    return Pending(wait, each)


@dataclass(frozen=True)
class FitItem:
    """What one trial's fit item gives (:func:`_run_fit_job`): its fit entries
    (:class:`ident.thesis.campaign_fit.FitEntry`, one per moving joint) and the worker's wall and
    CPU time, or the failure. The record on disk is :meth:`to_record`'s dict (read back by
    :meth:`from_record`, also from records older runs wrote)."""

    ok: bool
    error: str = ""
    entries: tuple = ()
    seconds: float = 0.0
    cpu_s: float = 0.0

    @classmethod
    def from_record(cls, result: dict) -> "FitItem":
        return cls(bool(result.get("ok")), result.get("error", ""), tuple(result.get("entries", ())),
                   float(result.get("seconds", 0.0)), float(result.get("cpu_s", 0.0)))

    def to_record(self) -> dict:
        if not self.ok:
            return {"ok": False, "error": self.error}
        return {"ok": True, "entries": list(self.entries), "seconds": self.seconds, "cpu_s": self.cpu_s}

    def without_plots(self) -> "FitItem":
        """The entries without plot samples and per-sample fit residuals (no output of the study
        reads those; the record keeps them)."""
        if not self.ok:
            return self
        return dataclasses.replace(self, entries=tuple(dataclasses.replace(
            e, plot={}, fits={m: dataclasses.replace(f, residuals=np.empty(0)) for m, f in e.fits.items()})
            for e in self.entries))


def _run_fit_job(job: _FitJob) -> FitItem:
    """Eq. 2-4 fits of every moving joint of one trial (:func:`ident.thesis.campaign_fit.fit_trial_joint`).
    The record holds the whole result; the study gets the plot samples only when it draws or
    logs this trial (``keep_plot``): what it holds stays small however many trials there are."""

    t0, c0 = time.perf_counter(), time.process_time()
    try:
        entries = [fit_trial_joint(t) for t in job.tasks]  # loop over the trial's joints
    except Exception as exc:           # one bad trial fails alone, with its reason
        return FitItem(False, _error_text(exc))
    result = FitItem(True, entries=tuple(entries), seconds=time.perf_counter() - t0,
                     cpu_s=time.process_time() - c0)
    _write_record(Path(job.record), job.input_hash, result.to_record(), Path(job.tmp_dir))
    return result if job.keep_plot else result.without_plots()


#: samples of one joint the study's gap diagnosis reads by default: whole repetitions of every
#: condition, as many as fit (:func:`_within_samples`; docs/study-memory.md)
DIAGNOSIS_SAMPLES = 200_000


def _log_rows(path) -> int:
    """Data rows of a robot log (its line feeds less the header's; a last line without one
    counts), read in blocks of 1 MiB."""
    n, last = 0, b"\n"
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            n += block.count(b"\n")
            last = block[-1:]
    return max(n - 1 + (last != b"\n"), 0)


def _within_samples(trials, budget: int) -> tuple[list, int]:
    """``(trials, R)``: the trials of the first ``R`` repetitions of every condition
    (:func:`_first_repetitions`) for the largest ``R`` whose logs hold at most ``budget`` rows
    together (at least one repetition)."""
    rows = {t.id: _log_rows(t.log) for t in trials}
    reps = max([1] + [t.repetition for t in trials])
    keep = _first_repetitions(trials, reps)
    while reps > 1 and sum(rows[t.id] for t in keep) > budget:
        reps -= 1
        keep = _first_repetitions(trials, reps)
    return keep, reps


def _first_repetitions(trials, n: int) -> list:
    """The trials among the ``n`` lowest repetitions of their condition (joints, load, speed
    range, kind), in campaign order."""
    rank: dict = {}
    keep = set()
    for t in sorted(trials, key=lambda t: t.repetition):   # stable: campaign order on ties
        key = (tuple(t.joints), t.load_kg, t.vmax_frac, t.kind)
        rank[key] = rank.get(key, 0) + 1
        if rank[key] <= n:
            keep.add(t.id)
    return [t for t in trials if t.id in keep]


def _plotted_trials(entries, campaign, which: str, bad=frozenset()) -> set:
    """Ids of the trials whose plot samples the outputs use: per (joint, load, speed range) the
    first of the lowest repetition among ``entries`` (``fits/plots/``, ``plots/``; the order
    :meth:`ident.thesis.campaign_fit.FitsResult.write_plots` and :func:`write_study_plots` pick
    in), and the trials of the recording (:func:`_rrd_trials` of the trials not in ``bad``).
    ``entries``: objects with ``.trial``, ``.joint``, ``.load_kg``, ``.vmax_frac``,
    ``.repetition`` (fit tasks, or ``e.task`` of fit entries)."""
    first: dict = {}
    for e in sorted(entries, key=lambda e: e.repetition):     # stable: entry order on ties
        first.setdefault((e.joint, e.load_kg, e.vmax_frac), e.trial)
    shown = dataclasses.replace(campaign, trials=tuple(t for t in campaign.trials if t.id not in bad))
    return set(first.values()) | {t.id for t in _rrd_trials(shown, which)}


@dataclass(frozen=True)
class _DiagJob:
    manifest: str
    joint: int
    angles_dir: str | None
    settings: object
    record: str
    tmp_dir: str
    input_hash: str
    trials: tuple | None = None     # the ids of the joint's trials to read (None: all)
    plots_dir: str | None = None    # draw the joint's diagnosis PNGs here too (the report's)


def _series_file(record: str | Path) -> Path:
    """The file beside a joint's diagnosis record that holds its per-sample series."""
    return Path(record).with_suffix(".series.npz")


def _store_series(series: dict | None, record: str | Path, tmp_dir: str | Path) -> dict | None:
    """Write a joint's per-sample diagnosis series (``t``, ``qd``, ``q``, ``residual_nominal``,
    ``trial``: what the plots and the recording read) to an ``.npz`` beside its record, and
    return what the record keeps instead: ``{"file": name, "sha256": ..., "spectrum": ...}``
    (the spectrum is small and stays). The study then holds no joint's samples across joints:
    each reader loads one joint's series (:func:`_series_arrays`) when it needs them."""
    if series is None:
        return None
    path = _series_file(record)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = _tmp_name(Path(tmp_dir), path)
    tmp.parent.mkdir(parents=True, exist_ok=True)
    with open(tmp, "wb") as fh:
        np.savez(fh, **{k: np.asarray(v) for k, v in series.items() if k != "spectrum"})
    sha = file_sha256(tmp)
    os.replace(tmp, path)
    return {"file": path.name, "sha256": sha, "spectrum": series.get("spectrum")}


def _series_ref(ref, folder: Path):
    """A stored series reference (:func:`_store_series`) with its file's absolute path, for
    readers in other processes; anything else (series held in memory, None) as it is."""
    if isinstance(ref, dict) and "file" in ref:
        return {**ref, "file": str(Path(folder) / ref["file"])}
    return ref


def _series_ok(ref, folder: Path) -> bool:
    """Whether a stored series' file is still the one its record names (always, for series held
    in the record itself)."""
    if not (isinstance(ref, dict) and "file" in ref):
        return True
    p = Path(folder) / ref["file"]
    return p.is_file() and file_sha256(p) == ref["sha256"]


def _series_arrays(ref):
    """A joint's series as arrays: loaded from its ``.npz`` (checked against the sha256 the
    record keeps; :class:`ValueError` when it differs) when ``ref`` is a stored reference with an
    absolute path (:func:`_series_ref`), else ``ref`` itself."""
    if not (isinstance(ref, dict) and "file" in ref):
        return ref
    path = Path(ref["file"])
    if file_sha256(path) != ref["sha256"]:
        raise ValueError(f"{path}: not the series the study wrote (changed since)")
    with np.load(path, allow_pickle=False) as z:
        out = {k: z[k] for k in z.files}
    out["spectrum"] = ref.get("spectrum")
    return out


@dataclass(frozen=True)
class DiagnosisItem:
    """What one joint's diagnosis item gives (:func:`_run_diag_job`): the joint's
    :class:`ident.gap.result.JointDiagnosis` (None when the joint had nothing to diagnose), the
    stored reference to its series (:func:`_store_series`), whether link angles entered, the
    trials it skipped, the worker's wall and CPU time; ``plots`` (names of the PNGs it drew) and
    ``plots_cpu_s`` are this run's only, not recorded. The record on disk is :meth:`to_record`'s
    dict (the joint as its ``diagnosis.json`` entry under ``report``), read back by
    :meth:`from_record`, also from records older runs wrote."""

    ok: bool
    error: str = ""
    joint: JointDiagnosis | None = None
    series: object = None
    link_angles: bool = False
    skipped_trials: tuple = ()
    seconds: float = 0.0
    cpu_s: float = 0.0
    plots: dict | None = None
    plots_cpu_s: float = 0.0

    @classmethod
    def from_record(cls, result: dict) -> "DiagnosisItem":
        rep = result.get("report")
        return cls(bool(result.get("ok")), result.get("error", ""),
                   None if rep is None else JointDiagnosis.from_dict(rep), result.get("series"),
                   bool(result.get("link_angles")), tuple(result.get("skipped_trials", ())),
                   float(result.get("seconds", 0.0)), float(result.get("cpu_s", 0.0)))

    def to_record(self) -> dict:
        if not self.ok:
            return {"ok": False, "error": self.error}
        return {"ok": True, "report": None if self.joint is None else self.joint.to_dict(),
                "series": self.series, "link_angles": self.link_angles,
                "skipped_trials": list(self.skipped_trials), "seconds": self.seconds, "cpu_s": self.cpu_s}


def _run_diag_job(job: _DiagJob) -> DiagnosisItem:
    """The gap diagnosis of one joint (:func:`ident.gap.campaign_diagnosis.diagnose_single_joint_campaign`)."""

    t0, c0 = time.perf_counter(), time.process_time()
    try:
        camp, robot = _load(job.manifest)
        if job.trials is not None:
            keep = set(job.trials)
            camp = dataclasses.replace(camp, trials=tuple(t for t in camp.trials if t.id in keep))
        angles = None
        if job.angles_dir is not None:
            trials = [t for t in camp.trials if tuple(t.joints) == (job.joint,)]
            angles = load_angles_dir(job.angles_dir, trials) or None
        with one_blas_thread():
            diag = diagnose_single_joint_campaign(camp, robot, angles, job.settings, joints=[job.joint])
        srs = diag.series.get(job.joint)
        stored = _store_series(srs, job.record, job.tmp_dir)
        joint = diag.joints.get(job.joint)
        if joint is not None and joint.result is not None:   # its samples are in the .npz
            joint = dataclasses.replace(joint, result=dataclasses.replace(joint.result, series={}))
        result = DiagnosisItem(True, joint=joint, series=stored, link_angles=diag.link_angles,
                               skipped_trials=diag.skipped_trials, seconds=time.perf_counter() - t0,
                               cpu_s=time.process_time() - c0)
        del diag
    except Exception as exc:           # one bad trial fails alone, with its reason
        return DiagnosisItem(False, _error_text(exc))
    _write_record(Path(job.record), job.input_hash, result.to_record(), Path(job.tmp_dir))
    if job.plots_dir is not None and result.joint is not None:
        # drawn here, where the joint's series are in memory; the record does not keep the names
        # (the PNGs live in this run's temporary folder)
        p0 = time.process_time()
        key = str(job.joint)
        plots = _run_plot_job(_PlotJob("diagnosis", job.plots_dir,
                                       ({"joints": {key: result.joint.to_dict()}}, {key: srs})))
        result = dataclasses.replace(result, plots=plots, plots_cpu_s=time.process_time() - p0)
    return result


@dataclass(frozen=True)
class _PlotJob:
    """PNGs of one joint drawn by a worker into ``out_dir``: ``kind`` "fits" (``fits/plots/``,
    :meth:`ident.thesis.campaign_fit.FitsResult.write_plots`; ``data`` = (entries, models)), "study"
    (``plots/``, :func:`write_study_plots`; the same ``data``) or "diagnosis"
    (:func:`ident.gap.report.make_plots`; ``data`` = (report, series) of that joint)."""

    kind: str
    out_dir: str
    data: tuple


def _run_plot_job(job: _PlotJob):
    """The file names the job wrote (a list for "fits", {key: name} otherwise)."""
    out = Path(job.out_dir)
    if job.kind == "diagnosis":

        out.mkdir(parents=True, exist_ok=True)
        report, series = job.data
        return make_plots(report, {j: _series_arrays(s) for j, s in series.items()}, out)

    fits = FitsResult(*job.data)
    if job.kind == "fits":
        return [p.name for p in fits.write_plots(out)]
    return write_study_plots(fits, out)


def _planned_trials(ctx, path: str) -> list:
    """The trials the study's :func:`ident.workflow.plan` routes to ``path`` (``single_joint``,
    ``multi_joint`` or ``coastdown``), in campaign order: the study runs what the plan decides."""
    ids = set(getattr(ctx.plan, path))
    return [t for t in ctx.camp.trials if t.id in ids]


def _fit_plan(ctx, path: str) -> Plan | None:
    """The fit plan (:func:`ident.workflow.fit_plans`) whose models include ``path``
    (``single_joint``, ``indri`` or ``multi_joint``), or None."""
    return next((p for p in ctx.fit_plans if p.models.get(path)), None)


def _by_joint(entries) -> dict:
    """Fit entries grouped by joint, in joint order (each group in the entries' order)."""
    out: dict = {}
    for e in entries:
        out.setdefault(e.task.joint, []).append(e)
    return {j: tuple(out[j]) for j in sorted(out)}


# ---------------------------------------------------------------------------------------------
# the mocap stage adapter (the one place that knows the mocap API)
# ---------------------------------------------------------------------------------------------
class _StageUnavailable(Exception):
    """A stage that cannot run (missing module, unidentifiable camera pose): noted and skipped."""


def _mocap_stage(campaign, robot, T_camera_base):
    """Adapter to the mocap stage: static-pose references (thesis eq. 3-4, built here, once) and
    the per-trial solver (eq. 3-5, run by the workers).

    Returns ``(references, solve, report)``: ``solve(campaign, trial_id, references, robot=)`` ->
    an object with ``write_csv(path, overwrite=)``, ``to_dict()`` and ``.solve``;
    ``report(solve)`` -> per-marker summary (or ``None``). Raises :class:`_StageUnavailable` with
    the reason when the stage cannot run (no marker references). Rewire here when the mocap API
    changes."""
    try:
        refs = build_references(campaign, robot, T_camera_base)
    except InputError as exc:
        raise _StageUnavailable(f"no marker references: {exc}") from None
    return refs, solve_trial, marker_report


# ---------------------------------------------------------------------------------------------
# the study
# ---------------------------------------------------------------------------------------------
#: the per-trial numbers of ``mocap.json`` the report and ``csv/trials.csv`` show
_MOCAP_REPORTED = ("frames", "rms_mm", "flagged_frames", "link_minus_motor_rms_rad")


def _tree_ok(ctx, prefix: str, key: str | None = None) -> bool:
    """Every file the study registered under ``prefix`` (a folder 'fits/' or one file) is there
    with the sha256 it was written with, and ``key`` (a rel path) is one of them."""
    own = {r: e for r, e in ctx.od.entries().items()
           if (r.startswith(prefix) if prefix.endswith("/") else r == prefix)
           and e.get("command") == ctx.od.command}
    if not own or (key is not None and key not in own):
        return False
    for r, e in own.items():
        p = ctx.out / r
        if not p.is_file() or p.is_symlink() or e.get("sha256") != ctx.hasher.file(p):
            return False
    return True


def _reuse_stage(ctx, stage: str, h: str, path: Path, n: int, t0: float) -> bool:
    """A whole-stage result is up to date (same input hash, its files as the study wrote them):
    keep it."""
    prev = ctx.old.get("stages", {}).get(stage, {})
    rel = Path(path).relative_to(ctx.out).as_posix()
    if not (prev.get("hash") == h and _tree_ok(ctx, rel.split("/")[0] + "/", rel)):
        return False
    ctx.man["stages"][stage] = prev
    ctx.paths[stage] = path
    ctx.stages[stage] = _stage_row(reused=n, seconds=time.perf_counter() - t0)
    return True


def _fits_note(ctx, by_trial: dict) -> str:
    """The fits stage's note when it had no trial to fit: where the campaign's trials went."""
    if by_trial or _fit_plan(ctx, "indri") is not None:
        return ""
    multi = ctx.plan.multi_joint
    if multi:
        return f"no single-joint trials: the {len(multi)} multi-joint record(s) are fitted in rigidbody/"
    return "no trials to fit"


def _stage_row(computed=0, reused=0, failed=0, seconds=0.0, note="", work=0.0, cpu=0.0) -> StageReport:
    """A :class:`StageReport`, times rounded to the millisecond."""
    return StageReport(computed, reused, failed, round(seconds, 3), note, round(work, 3), round(cpu, 3))


def _work(jobs, done, key, field: str = "seconds") -> float:
    """The summed ``field`` of the computed items' results (a job result, or a mocap dict)."""
    return float(sum(r.get(field, 0.0) if isinstance(r, dict) else getattr(r, field)
                     for r in (done[getattr(j, key)] for j in jobs)))


class Study:
    """A batch study of one campaign (see the module docstring for the folder it writes).

    Parameters
    ----------
    settings : :class:`StudySettings`.
    executor : anything with ``map(fn, items, desc)`` (:func:`ident.study.executor.make_executor`);
        ``None`` runs serially in this process.
    progress : progress bars and stage lines on stderr.
    """

    def __init__(self, settings: StudySettings | None = None, executor=None, progress: bool = True):
        self.settings = (settings or StudySettings()).validate()
        self.executor = executor
        self.progress = progress

    # helpers -------------------------------------------------------------------------------
    def _say(self, msg: str) -> None:
        if self.progress:
            print(f"study: {msg}", file=sys.stderr, flush=True)

    @staticmethod
    def _note(msg: str) -> None:
        """A line the user always sees (a record that failed its check, a changed output)."""
        print(f"jointlab: note: {msg}", file=sys.stderr, flush=True)

    def _record(self, ctx, rel: str, h: str, kind: type = dict):
        """The verified record ``state/rel`` for input hash ``h`` whose result is a ``kind``
        and whose outputs are all still the study's, byte for byte; else ``None`` (with one line
        when the record or an output failed its check)."""
        path = ctx.state / rel
        try:
            rec, problem = read_record(path, h, CACHE_VERSION, ctx.man["records"].get(rel))
        except OSError as exc:
            rec, problem = None, f"unreadable: {exc.strerror or exc}"
        if rec is not None and not isinstance(rec["result"], kind):
            rec, problem = None, f"its result is a {type(rec['result']).__name__}, not a {kind.__name__}"
        if problem:
            self._note(f"study record {path} failed its check ({problem}); recomputing it")
        if rec is None:
            return None
        for out_rel, sha in rec["outputs"].items():
            p = ctx.out / out_rel
            if not ctx.od.matches(out_rel, sha):
                if p.exists() and ctx.od.is_own(out_rel):   # a foreign file is refused later
                    self._note(f"{p} is not what the study wrote (changed since); recomputing it")
                return None
        return rec

    def _keep_record(self, ctx, rel: str) -> None:
        """Remember the sha256 of a record just written (checked when a rerun reads it)."""
        p = ctx.state / rel
        if p.is_file():
            ctx.man["records"][rel] = ctx.hasher.file(p)

    def _map(self, fn, items, desc):
        return self._submit(fn, items, desc).result()

    def _submit(self, fn, items, desc):
        """``fn`` over ``items`` in flight on the executor (its ``submit_map``; an executor with
        ``map`` alone runs when the result is asked for)."""

        if not items:
            return Pending(list)
        ex = self.executor if self.executor is not None else SerialExecutor(self.progress)
        if hasattr(ex, "submit_map"):
            return ex.submit_map(fn, items, desc)
        return Pending(lambda: ex.map(fn, items, desc))

    # main ------------------------------------------------------------------------------------
    def run(self, campaign, out, rrd: str | Path | None = None, spawn: bool = False) -> StudyResult:
        """Run (or resume) the study of ``campaign`` (a folder, a campaign.toml or a loaded
        :class:`mocap.io.campaign.Campaign`) into the folder ``out``. ``rrd``: where to write the
        recording (default ``out/study.rrd`` when ``settings.rrd``); ``spawn``: also stream it to
        a viewer."""

        camp = campaign if isinstance(campaign, Campaign) else load_campaign(campaign)
        # the routing, decided once before any output: a model no path can fit is refused here
        plans = (plan(camp), fit_plans(camp, self.settings.models))
        od = OutputDir(out, "study", inputs=[camp.root])
        out = od.root
        for t in camp.trials:            # ids are data: every id-derived path stays in --out
            od.rel(f"angles/{t.id}.csv")
        state = out / STATE_DIR
        state.mkdir(parents=True, exist_ok=True)
        with StudyLock(state / "lock", self._note):
            try:
                return self._run_locked(camp, out, state, rrd, spawn, od, plans)
            except BaseException:
                shutil.rmtree(state / "tmp", ignore_errors=True)
                raise
            finally:
                od.discard()

    def _run_locked(self, camp, out: Path, state: Path, rrd, spawn, od, plans) -> StudyResult:
        tmp_dir = state / "tmp"
        shutil.rmtree(tmp_dir, ignore_errors=True)   # leftovers of an interrupted run
        tmp_dir.mkdir(parents=True, exist_ok=True)
        robot = camp.load_robot()
        hasher = _Hasher()
        s = self.settings
        base_hash = hasher.combine(hasher.file(camp.manifest), hasher.file(camp.urdf),
                                   hasher.file(camp.drives))
        manifest_path = out / MANIFEST_NAME
        old = _read_manifest(manifest_path, self._note)
        old_records = old.get("records", {})
        man = {"format": 2, "campaign": camp.name, "campaign_root": str(camp.root),
               "settings": s.to_dict(), "stages": {},
               "records": {k: v for k, v in old_records.items() if isinstance(v, str)}}
        stages, errors, paths = {}, {}, {}
        ctx = _Context(camp, robot, out, state, tmp_dir, hasher, base_hash, man, old, stages,
                       errors, paths, od, *plans, pipeline=self.stages(camp))

        prewarm = self._prewarm_hashes(ctx)
        T_cb, calib_res = self._calib(ctx)
        prewarm.join()
        _write_manifest(manifest_path, man, tmp_dir)
        angles_dir, mocap_summary, refs = self._mocap(ctx, T_cb)
        _write_manifest(manifest_path, man, tmp_dir)
        release_free_memory()     # this process holds results from here on, not its temporaries
        # the diagnosis' and the fits' items are queued together, the few long diagnosis items
        # first (longest first balances the workers: the many short fits fill in behind them);
        # while the workers run the last fits, this process writes the multi-joint stage
        diag_run = self._diagnosis_start(ctx, angles_dir)
        fits_run = self._fits_start(ctx, angles_dir)
        self._submit_items(diag_run, fits_run)
        rrd_path = None
        if s.rrd or rrd is not None or spawn:
            rrd_path = Path(rrd).resolve() if rrd is not None else (out / "study.rrd" if s.rrd else None)
        if (rrd_path is not None or spawn) and (fits_run["jobs"] or diag_run.get("jobs")):
            # items to compute: the report will be new; its recording's inputs are logged now
            ctx.recording = self._recording(ctx, calib_res, angles_dir, rrd_path, spawn).start(
                {k.split("/", 1)[1] for k in ctx.errors if k.startswith("mocap/")})
        try:
            fits = self._fits_finish(ctx, fits_run)
            _write_manifest(manifest_path, man, tmp_dir)
            release_free_memory()
            self._rigidbody(ctx)
            _write_manifest(manifest_path, man, tmp_dir)
            diag = self._diagnosis_finish(ctx, diag_run)
            self._fits_commit(ctx)
            _write_manifest(manifest_path, man, tmp_dir)
            self._coast_md = self._coastdown(ctx)
            _write_manifest(manifest_path, man, tmp_dir)
            for st in ctx.pipeline:        # the list's stages without a per-item policy here
                if st.name not in ITEM_POLICIES:
                    self._whole_stage(ctx, st)
                    _write_manifest(manifest_path, man, tmp_dir)
            self._report(ctx, calib_res, refs, mocap_summary, fits, diag, angles_dir, rrd_path, spawn)
        finally:
            if ctx.recording is not None:     # not finished: the study stopped
                ctx.recording.abort()
        _write_manifest(manifest_path, man, tmp_dir)
        shutil.rmtree(tmp_dir, ignore_errors=True)
        paths["manifest"] = manifest_path
        joints = diag.joints.items() if diag is not None else []
        verdicts = {str(j): r.verdict for j, r in joints}
        lines = {str(j): r.verdict_text for j, r in joints}
        calib = None
        if calib_res is not None:
            calib = {"origin_std_mm": float(calib_res.origin_std_mm),
                     "rotation_std_deg": float(calib_res.rotation_std_deg)}
        return StudyResult(out, camp.name, len(camp.trials), stages, paths, verdicts, calib, errors,
                           verdict_lines=lines)

    def stages(self, camp) -> list:
        """The pipeline's stages for this study (:func:`ident.pipeline.plan.plan`), in the order
        it runs them; the names in :data:`ITEM_POLICIES` run with per-item records (the methods
        below), every other stage whole (:meth:`_whole_stage`)."""
        stages = pipeline_plan(camp, self.settings.pipeline_settings())
        names = [st.name for st in stages if st.name in ITEM_POLICIES]
        if names != [n for n in ITEM_POLICIES if n in names]:    # the order below is the list's
            raise RuntimeError(f"the pipeline's order {names} is not the study's {list(ITEM_POLICIES)}")
        return stages

    def _whole_stage(self, ctx, st) -> None:
        """Run one pipeline stage (:class:`ident.pipeline.stage.Stage`) resumably as a whole: the
        key of its declared inputs (:func:`ident.pipeline.stage.input_key`, files by their
        sha256) is its hash; an entry of the same hash whose files are the study's, byte for
        byte, is kept, otherwise the stage runs and its files replace ``<folder>/`` (the first
        component of ``st.output``). A stage that does not apply gets a row saying why; a
        failure is the stage's error, and the study goes on."""
        t0 = time.perf_counter()
        pctx = StageContext(ctx.camp, self.settings.pipeline_settings(), ctx.out, _robot=ctx.robot)
        why = st.skip(pctx)
        if why:
            ctx.stages[st.name] = _stage_row(note=f"skipped: {why}")
            return
        inputs = st.inputs(pctx)
        h = ctx.hasher.combine(st.name, input_key(inputs, ctx.hasher.file))
        folder = st.output.split("/", 1)[0]
        if _reuse_stage(ctx, st.name, h, ctx.out / st.output, 1, t0):
            return
        self._say(f"{st.name}: running")
        try:
            result = st.run(inputs, Runtime(progress=False))
        except (InputError, ValueError, np.linalg.LinAlgError) as exc:
            ctx.errors[st.name] = _error_text(exc)
            ctx.stages[st.name] = _stage_row(failed=1, seconds=time.perf_counter() - t0)
            return
        tmp = ctx.tmp_dir / f"{folder}-new"
        tmp.mkdir(parents=True, exist_ok=True)
        st.write(result, inputs, tmp, Runtime())
        ctx.od.commit(tmp, folder, prune=True)
        ctx.man["stages"][st.name] = {"hash": h, "outputs": [folder + "/"]}
        ctx.paths[st.name] = ctx.out / st.output
        ctx.stages[st.name] = _stage_row(computed=1, seconds=time.perf_counter() - t0)

    @staticmethod
    def _prewarm_hashes(ctx):
        """The trials' marker files and logs hashed by a thread while the calibration runs (the
        digests the stages' input hashes need; :class:`_Hasher` memoises them): sha256 reads
        release the interpreter lock, so this overlaps the calibration's work."""
        import threading

        def run():
            for tr in ctx.camp.trials:  # loop over trials
                for p in (tr.markers, tr.log):
                    try:
                        ctx.hasher.file(p)
                    except OSError:     # the stage that reads it says so, with its path
                        pass

        th = threading.Thread(target=run, name="jointlab-hashes", daemon=True)
        th.start()
        return th

    # stage 1: calibration ----------------------------------------------------------------------
    def _calib(self, ctx):
        t0 = time.perf_counter()
        camp, s = ctx.camp, self.settings
        if not camp.calib:
            if not (s.mocap and camp.has_markers):
                why = "no motion capture in this campaign" if not camp.has_markers else \
                    "the angle solve is switched off"
                note = f"no [[calib]] sweeps; no camera pose needed ({why})"
            elif camp.static:
                note = "no [[calib]] sweeps: the camera pose comes from the static poses"
            else:
                note = "no [[calib]] sweeps and no [[static]] poses: the camera pose is unknown"
            ctx.stages["calib"] = _stage_row(note=note)
            return None, None
        files = [ctx.hasher.file(p) for c in camp.calib for p in (c.markers, c.log)]
        opts = s.calib_options()
        # the default options stay out of the hash: studies written before they existed are reused
        h = ctx.hasher.combine("calib", ctx.base_hash, files, s.calib_method,
                               *([json.dumps(opts, sort_keys=True)] if opts != StudySettings().calib_options() else []))
        path = ctx.out / "calib.json"
        record = "records/calib.json"
        rec = self._record(ctx, record, h, CalibResult)
        if rec is not None and "calib.json" in rec["outputs"]:
            res = rec["result"]
            ctx.stages["calib"] = _stage_row(reused=1, seconds=time.perf_counter() - t0)
        else:

            self._say("calibrating the camera from the [[calib]] sweeps")

            try:
                with one_blas_thread():
                    res = calibrate(camp, ctx.robot, method=s.calib_method, **opts)
            except (InputError, ValueError, np.linalg.LinAlgError) as exc:
                ctx.errors["calib"] = _error_text(exc)
                ctx.stages["calib"] = _stage_row(failed=1, seconds=time.perf_counter() - t0,
                                                 note=_error_text(exc))
                return None, None
            data = json.dumps(_jsonable(res.to_dict()), indent=1).encode("utf-8")
            _write_record(ctx.state / record, h, res, ctx.tmp_dir,
                          {"calib.json": hashlib.sha256(data).hexdigest()})
            ctx.od.write("calib.json", data)
            self._keep_record(ctx, record)
            ctx.stages["calib"] = _stage_row(computed=1, seconds=time.perf_counter() - t0)
        ctx.man["stages"]["calib"] = {"hash": h, "outputs": ["calib.json"]}
        ctx.paths["calib"] = path
        return np.asarray(res.T_camera_base, float), res

    # stage 2: link angles ----------------------------------------------------------------------
    def _mocap(self, ctx, T_cb):
        t0 = time.perf_counter()
        camp, s = ctx.camp, self.settings
        if not s.mocap:
            ctx.stages["mocap"] = _stage_row(note="switched off: motor angles stand in for link angles")
            return None, None, None
        if not camp.has_markers:
            ctx.stages["mocap"] = _stage_row(note="no motion capture in this campaign: the logged "
                                                  "angles are the link angles")
            return None, None, None

        try:
            with one_blas_thread():
                refs, solve, report = _mocap_stage(camp, ctx.robot, T_cb)
        except _StageUnavailable as exc:
            note = f"skipped: {exc}; motor angles stand in for link angles"
            self._say(f"mocap {note}")
            ctx.stages["mocap"] = _stage_row(seconds=time.perf_counter() - t0, note=note)
            return None, None, None
        ctx.od.write("references.json", json.dumps(_jsonable(refs.to_dict()), indent=1))
        refs_hash = ctx.hasher.file(ctx.out / "references.json")
        angles_dir = ctx.out / "angles"
        jobs, hashes, done = [], {}, {}
        for tr in camp.trials:  # loop over trials (hashing and bookkeeping only)
            h = ctx.hasher.combine("mocap", ctx.base_hash, refs_hash, ctx.hasher.file(tr.markers),
                                   ctx.hasher.file(tr.log))
            hashes[tr.id] = h
            rel = ctx.od.rel(f"angles/{tr.id}.csv")
            record = f"records/mocap/{_record_name(tr.id)}"
            rec = self._record(ctx, record, h)
            if rec is not None and rel in rec["outputs"]:
                done[tr.id] = rec["result"]
                continue
            jobs.append(_MocapJob(str(camp.manifest), tr.id, refs, solve, report, str(ctx.out / rel),
                                  rel, str(ctx.state / record), str(ctx.tmp_dir), h))
        ctx.od.claim([j.out_rel for j in jobs])   # refuses a file another command or the user wrote
        self._say(f"link angles: {len(jobs)} trial(s) to solve, {len(done)} reused")
        written = {}
        for job, res in zip(jobs, self._map(_run_mocap_job, jobs, "mocap")):
            done[job.trial] = res
            if res.get("ok"):
                written.update(res["outputs"])
                self._keep_record(ctx, Path(job.record).relative_to(ctx.state).as_posix())
        if written:
            ctx.od.register(written)
        failed = {tid: r["error"] for tid, r in done.items() if not r.get("ok")}
        for tid, msg in failed.items():
            ctx.errors[f"mocap/{tid}"] = msg
        items = {tid: {"hash": hashes[tid], "outputs": [f"angles/{tid}.csv"]}
                 for tid in hashes if tid in done and done[tid].get("ok")}
        ctx.man["stages"]["mocap"] = {"references_hash": refs_hash, "items": items}
        summary = {"format": 1, "camera_from": "calib.json" if T_cb is not None else "static_poses",
                   "references": _jsonable(refs.to_dict()),
                   "trials": {tid: done[tid]["summary"] for tid in hashes if done[tid].get("ok")},
                   "failed": failed}
        ctx.od.write("mocap.json", json.dumps(summary, indent=1))
        # what the report and trials.csv read of it is kept (not each marker's statistics: the
        # study's memory stays flat in the number of trials)
        summary = {**summary, "references": None,
                   "trials": {tid: {k: d[k] for k in _MOCAP_REPORTED if k in d}
                              for tid, d in summary["trials"].items()}}
        ctx.angles_ok = frozenset(items)
        ctx.paths["angles"] = angles_dir
        ctx.paths["mocap"] = ctx.out / "mocap.json"
        ctx.stages["mocap"] = _stage_row(len(jobs) - sum(1 for j in jobs if j.trial in failed),
                                         len(done) - len(jobs), len(failed), time.perf_counter() - t0,
                                         work=_work(jobs, done, "trial"),
                                         cpu=_work(jobs, done, "trial", "cpu_s"))
        return (angles_dir if items else None), summary, refs

    # stage 3: friction fits ------------------------------------------------------------------
    def _fits_start(self, ctx, angles_dir):
        """The fit items to compute (the others are reused from their records), queued."""

        t0 = time.perf_counter()
        camp, s = ctx.camp, self.settings
        one = _fit_plan(ctx, "single_joint")
        models = tuple(one.models["single_joint"]) if one is not None else ()
        tasks, skipped = [], []
        if models:   # the one-link path's trials (the plan's part without the multi-joint records)
            tasks, skipped = campaign_tasks(subset(camp, one.single_joint), None, models, s.n_starts,
                                            s.seed, s.sync, robot=ctx.robot)
        by_trial: dict = {}
        for t in tasks:  # loop over (trial, joint) tasks
            by_trial.setdefault(t.trial, []).append(t)
        jobs, done, hashes = [], {}, {}
        fit_settings = [list(models), s.n_starts, s.seed, s.sync]
        bad = {k.split("/", 1)[1] for k in ctx.errors if k.startswith("mocap/")}
        plotted = _plotted_trials(tasks, camp, s.rrd_trials, bad)
        for tr in camp.trials:  # loop over trials
            if tr.id not in by_trial:
                continue
            ang = None
            if angles_dir is not None and tr.id in ctx.angles_ok:
                ang = ctx.od.path(f"angles/{tr.id}.csv")
            ttasks = tuple(dataclasses.replace(t, angles=None if ang is None else str(ang))
                           for t in by_trial[tr.id])
            h = ctx.hasher.combine("fits", ctx.base_hash, ctx.hasher.file(tr.log),
                                   None if ang is None else ctx.hasher.file(ang), fit_settings,
                                   [dataclasses.asdict(t) | {"log": "", "angles": ""} for t in ttasks])
            hashes[tr.id] = h
            record = f"records/fits/{_record_name(tr.id)}"
            rec = self._record(ctx, record, h)
            if rec is not None:
                item = FitItem.from_record(rec["result"])
                done[tr.id] = item if tr.id in plotted else item.without_plots()
                continue
            jobs.append(_FitJob(tr.id, ttasks, str(ctx.state / record), str(ctx.tmp_dir), h,
                                keep_plot=tr.id in plotted))
        if by_trial:
            self._say(f"friction fits: {len(jobs)} trial(s) to fit, {len(done)} reused")
        elif ctx.plan.multi_joint:
            self._say(f"friction fits: no single-joint trials (the {len(ctx.plan.multi_joint)} "
                      "multi-joint record(s) are fitted by the rigid-body stage)")
        pending = None     # submitted with the diagnosis' items (_submit_items)
        return dict(t0=t0, jobs=jobs, done=done, hashes=hashes, skipped=skipped, pending=pending,
                    by_trial=by_trial, models=models, indri=self._indri_inputs(ctx, angles_dir))

    def _indri_inputs(self, ctx, angles_dir) -> dict | None:
        """The Indri & Trapani path's part of the fits stage (:func:`ident.workflow.fit_campaign`
        on the plan's ``indri`` models, fitted whole when ``fits/`` is rewritten): its plan, the
        angles folder it reads and its input hash; None when the plan routes no model there."""
        p = _fit_plan(ctx, "indri")
        if p is None:
            return None
        trials = [t for t in ctx.camp.trials if t.id in set(p.single_joint)]
        ang = [ctx.hasher.file(angles_dir / f"{t.id}.csv") if angles_dir is not None
               and t.id in ctx.angles_ok else None for t in trials]
        h = ctx.hasher.combine("indri", ctx.base_hash, [ctx.hasher.file(t.log) for t in trials], ang,
                               list(p.models["indri"]))
        return {"plan": dataclasses.replace(p, models={"indri": p.models["indri"]}),
                "angles": angles_dir, "hash": h}

    def _fits_finish(self, ctx, run):
        camp, s = ctx.camp, self.settings
        t0, jobs, done, hashes, skipped = (run[k] for k in ("t0", "jobs", "done", "hashes", "skipped"))
        indri = run["indri"]
        stage_hash = ctx.hasher.combine("fits-stage", sorted(hashes.items()), s.plots,
                                        *([indri["hash"]] if indri is not None else []))
        prev = ctx.old.get("stages", {}).get("fits", {})
        current = prev.get("hash") == stage_hash and _tree_ok(ctx, "fits/", "fits/fits.json")
        tmp = ctx.tmp_dir / "fits-new"
        models = run["models"]
        # each joint's PNGs are drawn by this process as soon as the joint's last item is in
        # (while the workers fit the other joints), not all after the last item
        joints_of = {tid: {t.joint for t in ts} for tid, ts in run["by_trial"].items()}
        left: dict = {}
        for job in jobs:   # loop over the items to compute
            for j in joints_of[job.trial]:
                left[j] = left.get(j, 0) + 1
        drawn: dict = {}
        if s.plots and not current:
            for j in sorted(j for j in {j for js in joints_of.values() for j in js} if j not in left):
                drawn[j] = self._draw_joint_fits(ctx, j, done, hashes, tmp, models)
        with contextlib.closing(run["pending"].each()) as finished:   # stops the workers on an error
            for i, res in finished:
                job = jobs[i]
                done[job.trial] = res
                self._keep_record(ctx, Path(job.record).relative_to(ctx.state).as_posix())
                for j in joints_of[job.trial]:
                    left[j] -= 1
                    if left[j] == 0 and s.plots and not current:
                        # the last joint's two figures: drawn by the (then idle) workers
                        drawn[j] = self._draw_joint_fits(ctx, j, done, hashes, tmp, models,
                                                         pool=not any(left.values()))
        failed = {tid: r.error for tid, r in done.items() if not r.ok}
        for tid, msg in failed.items():
            ctx.errors[f"fits/{tid}"] = msg
        self._plot_samples(ctx, done, hashes, camp.trials)
        entries = tuple(e for tr in camp.trials if tr.id in done and done[tr.id].ok
                        for e in done[tr.id].entries)
        result = FitsResult(entries, models, camp.name, tuple(skipped))
        fits_dir = ctx.out / "fits"
        man = {"hash": stage_hash, "outputs": ["fits/"],
               "items": {tid: {"hash": h} for tid, h in hashes.items() if tid in done and done[tid].ok}}
        ctx.fits_commit = (None, None, man)
        dyn = None
        if indri is not None and not current:
            dyn = self._indri_fit(ctx, indri)
            if dyn is None:       # failed: a hash no rerun matches, so the stage is recomputed
                man = {**man, "hash": "failed:" + stage_hash}
        if not current:
            if entries or dyn is not None:
                tmp.mkdir(parents=True, exist_ok=True)
                fplan = _fit_plan(ctx, "single_joint") or indri["plan"]
                # the writer of jointlab fit: fits.json (the Indri joints merged in) and the reports
                FitResult(fplan, onelink=result if entries else None, indri=dyn).write(tmp, plots=False)
                plots = None
                if s.plots:
                    order = [d.result() if isinstance(d, Pending) else d for d in
                             (drawn[j] for j in sorted(drawn)) if d is not None]
                    plots = Pending(lambda: [o[0] for o in order])
                    ctx.study_plots = Pending(lambda: [o[1] for o in order])
                ctx.fits_commit = (tmp, plots, man)
        if entries or (current and indri is not None) or dyn is not None:
            ctx.paths["fits"] = fits_dir / "fits.json"
        ctx.stages["fits"] = _stage_row(len(jobs) - sum(1 for j in jobs if j.trial in failed),
                                        len(done) - len(jobs), len(failed) + ("fits/indri" in ctx.errors),
                                        time.perf_counter() - t0,
                                        f"skipped (coast-down): {', '.join(skipped)}" if skipped else
                                        _fits_note(ctx, run["by_trial"]),
                                        work=_work(jobs, done, "trial"),
                                        cpu=_work(jobs, done, "trial", "cpu_s"))
        return result

    def _indri_fit(self, ctx, indri: dict):
        """The Indri & Trapani fits (:func:`ident.workflow.fit_campaign` on the plan's ``indri``
        models, the study's link angles), or None with the failure in the stage's errors."""
        self._say(f"dynamic friction models: {', '.join(indri['plan'].models['indri'])}")
        try:
            with one_blas_thread():
                return fit_campaign(ctx.camp, plan=indri["plan"], angles=indri["angles"],
                                    settings=self.settings.fit_settings()).indri
        except (InputError, ValueError, np.linalg.LinAlgError) as exc:
            ctx.errors["fits/indri"] = _error_text(exc)
            return None

    def _plot_samples(self, ctx, done: dict, hashes: dict, trials) -> None:
        """A failed trial hands its place in the plots to the next repetition: read that trial's
        plot samples back from its record (``done`` updated; ``trials``: those to look at)."""
        bad = {k.split("/", 1)[1] for k in ctx.errors if k.startswith(("mocap/", "fits/"))}
        bad |= {tid for tid, r in done.items() if not r.ok}
        ok_entries = [e.task for tr in trials if tr.id in done and done[tr.id].ok
                      for e in done[tr.id].entries]
        for tid in _plotted_trials(ok_entries, ctx.camp, self.settings.rrd_trials, bad):
            if tid in done and done[tid].ok and not all(e.plot for e in done[tid].entries):
                rel = f"records/fits/{_record_name(tid)}"
                rec = self._record(ctx, rel, hashes[tid])
                if rec is not None:
                    done[tid] = FitItem.from_record(rec["result"])

    def _draw_joint_fits(self, ctx, joint: int, done: dict, hashes: dict, tmp: Path, models: tuple,
                         pool: bool = False):
        """The fits' and the study's PNGs of one joint whose items are all in: (names in
        ``fits/plots/``, names in ``plots/``), or None when it has no fit; drawn here, or by the
        executor (``pool``: a :class:`Pending` of that pair)."""
        trials = [tr for tr in ctx.camp.trials if tr.id in done and joint in tr.joints]
        self._plot_samples(ctx, done, hashes, trials)
        group = tuple(e for tr in trials if done[tr.id].ok for e in done[tr.id].entries
                      if e.task.joint == joint)
        if not group:
            return None
        jobs = [_PlotJob("fits", str(tmp / "plots"), (group, models)),
                _PlotJob("study", str(ctx.tmp_dir / "plots-new"), (group, models))]
        if pool:
            return self._submit(_run_plot_job, jobs, "plots")
        return tuple(_run_plot_job(job) for job in jobs)

    def _fits_commit(self, ctx) -> None:
        """Install ``fits/`` once its plots are drawn, then record the stage in the manifest
        (never before: a rerun trusts a recorded stage whose files are the study's)."""
        tmp, plots, man = ctx.fits_commit
        if man is None:
            return
        if tmp is not None:
            if plots is not None:
                plots.result()
            ctx.od.commit(tmp, "fits", prune=True)
            ctx.fits_commit = (None, None, man)
        ctx.man["stages"]["fits"] = man

    # stage 3b: multi-joint records ------------------------------------------------------------
    def _rigidbody(self, ctx):
        """Multi-joint continuous records (``joints = [1, 2, ...]``): the rigid-body
        identification (:mod:`ident.model.multijoint`) with the study's friction models, written
        to ``rigidbody/`` (``fits.json``, ``rigidbody.json``, ``rigidbody.md``); resumed when the
        logs and settings are unchanged."""

        t0 = time.perf_counter()
        camp, s = ctx.camp, self.settings
        p = _fit_plan(ctx, "multi_joint")
        if p is None:
            return None
        trials = _planned_trials(ctx, "multi_joint")
        h = ctx.hasher.combine("rigidbody", ctx.base_hash, [ctx.hasher.file(t.log) for t in trials],
                               list(p.models["multi_joint"]), s.seed, s.n_starts)
        out = ctx.out / "rigidbody"
        if _reuse_stage(ctx, "rigidbody", h, out / "rigidbody.json", len(trials), t0):
            return None
        self._say(f"rigid-body identification: {len(trials)} multi-joint record(s)")
        try:
            # the fit of jointlab fit on the records' part of the campaign
            res = fit_campaign(subset(camp, p.multi_joint), plan=p, settings=s.fit_settings())
        except (InputError, ValueError) as exc:
            ctx.errors["rigidbody"] = _error_text(exc)
            ctx.stages["rigidbody"] = _stage_row(failed=len(trials), seconds=time.perf_counter() - t0)
            return None
        tmp = ctx.tmp_dir / "rigidbody-new"
        tmp.mkdir(parents=True, exist_ok=True)
        res.write(tmp)           # fits.json, rigidbody.json, rigidbody.md (FitResult.write)
        res = res.rigidbody
        ctx.od.commit(tmp, "rigidbody", prune=True)
        ctx.man["stages"]["rigidbody"] = {"hash": h, "outputs": ["rigidbody/"]}
        ctx.paths["rigidbody"] = out / "rigidbody.json"
        ctx.stages["rigidbody"] = _stage_row(computed=len(trials), seconds=time.perf_counter() - t0,
                                             note="multi-joint records: URDF rigid-body model + "
                                                  "per-joint friction, offsets, armatures")
        return res

    # stage 4: gap diagnosis ------------------------------------------------------------------
    def _diagnosis_start(self, ctx, angles_dir):
        """The joints to diagnose (the others are reused from their records), queued (what
        :meth:`_diagnosis_finish` collects)."""

        t0 = time.perf_counter()
        camp, s = ctx.camp, self.settings
        if not s.diagnose:
            return {"off": True}
        dset = DiagnosisSettings(seed=s.seed)
        by_joint: dict = {}
        for t in _planned_trials(ctx, "single_joint"):  # loop over trials
            by_joint.setdefault(int(t.joints[0]), []).append(t)
        if "single_joint" not in ctx.plan.diagnosis_paths:
            return {"records_only": (dset, t0)}
        jobs, done, hashes = [], {}, {}
        n_all = sum(len(v) for v in by_joint.values())
        n_joint = {j: len(v) for j, v in by_joint.items()}
        reps_used: dict = {}
        if s.diagnosis_reps is None:
            for j, v in list(by_joint.items()):
                by_joint[j], reps_used[j] = _within_samples(v, DIAGNOSIS_SAMPLES)
        elif s.diagnosis_reps:
            by_joint = {j: _first_repetitions(v, s.diagnosis_reps) for j, v in by_joint.items()}
        n_read = sum(len(v) for v in by_joint.values())
        for j, trials in sorted(by_joint.items()):  # loop over joints
            files = [[ctx.hasher.file(t.log),
                      ctx.hasher.file(angles_dir / f"{t.id}.csv") if angles_dir is not None else None]
                     for t in trials]
            h = ctx.hasher.combine("diagnosis", ctx.base_hash, j, files, dset.to_dict())
            hashes[j] = h
            record = f"records/diagnosis/joint{j}.json"
            rec = self._record(ctx, record, h)
            item = DiagnosisItem.from_record(rec["result"]) if rec is not None else None
            if item is not None and _series_ok(item.series, (ctx.state / record).parent):
                done[j] = item
                continue
            jobs.append(_DiagJob(str(camp.manifest), j, None if angles_dir is None else str(angles_dir),
                                 dset, str(ctx.state / record), str(ctx.tmp_dir), h,
                                 tuple(t.id for t in trials) if len(trials) < n_joint[j] else None))
        records = self._records_hash(ctx, dset) if "multi_joint" in ctx.plan.diagnosis_paths else None
        if jobs and not self._diagnosis_current(ctx, hashes, records):
            # each job draws its joint's PNGs where its series are in memory
            plots_dir = str(ctx.tmp_dir / "diagnosis-new")
            jobs = [dataclasses.replace(job, plots_dir=plots_dir) for job in jobs]
        self._say(f"gap diagnosis: {len(jobs)} joint(s) to diagnose, {len(done)} reused")
        pending = None     # submitted with the fits' items (_submit_items)
        if n_read == n_all:
            note = ""
        elif s.diagnosis_reps is None:
            cut = ", ".join(f"joint {j}: {r}" for j, r in sorted(reps_used.items())
                            if len(by_joint[j]) < n_joint[j])
            note = (f"the first repetitions of each condition within {DIAGNOSIS_SAMPLES} samples per "
                    f"joint ({cut}; --diagnosis-reps 0 reads all): {n_read} of {n_all} trials")
        else:
            note = (f"the first {s.diagnosis_reps} repetition(s) of each condition: {n_read} of "
                    f"{n_all} trials")
        return dict(dset=dset, jobs=jobs, done=done, hashes=hashes, pending=pending,
                    prep_s=time.perf_counter() - t0, note=note, records=records)

    def _submit_items(self, diag_run: dict, fits_run: dict) -> None:
        """Queue the diagnosis' and the fits' items, interleaved: each of the few long diagnosis
        items followed by an equal share of the many short fits (in campaign order). A long item
        never runs alone at the end, and the diagnosis items, the largest in memory, seldom run
        on all workers at once (what a study's summed peak is made of)."""
        djobs = diag_run.get("jobs") or []
        fjobs = fits_run["jobs"]
        n = max(len(djobs), 1)
        share = -(-len(fjobs) // n)
        dparts, fparts = [], []
        for k in range(n):  # loop over the diagnosis items
            if k < len(djobs):
                dparts.append(self._submit(_run_diag_job, djobs[k:k + 1], "diagnosis"))
            chunk = fjobs[k * share:(k + 1) * share] if k < n - 1 else fjobs[k * share:]
            if chunk:
                fparts.append((self._submit(_run_fit_job, chunk, "fits"), len(chunk)))
        if "jobs" in diag_run:
            diag_run["pending"] = _chain([(p, 1) for p in dparts])
        fits_run["pending"] = _chain(fparts)

    @staticmethod
    def _diagnosis_hash(ctx, hashes: dict, records: str | None = None) -> str:
        """The diagnosis stage's hash: its joints' items and (a campaign with multi-joint records
        beside its single-joint trials) the records' part."""
        return ctx.hasher.combine("diagnosis-stage", sorted(hashes.items()),
                                  *([records] if records is not None else []))

    def _diagnosis_current(self, ctx, hashes: dict, records: str | None = None) -> bool:
        """Whether ``diagnosis/`` is the one these items' hashes wrote (nothing to draw)."""
        prev = ctx.old.get("stages", {}).get("diagnosis", {})
        return (prev.get("hash") == self._diagnosis_hash(ctx, hashes, records)
                and _tree_ok(ctx, "diagnosis/", "diagnosis/diagnosis.json"))

    @staticmethod
    def _records_hash(ctx, dset) -> str:
        """The input hash of the multi-joint records' diagnosis."""
        return ctx.hasher.combine("diagnosis-records", ctx.base_hash,
                                  [ctx.hasher.file(t.log) for t in _planned_trials(ctx, "multi_joint")],
                                  dset.to_dict())

    def _records_part(self, ctx, dset, h: str):
        """``(joints, series)`` of the multi-joint records' diagnosis
        (:func:`ident.model.multijoint.diagnose_records`, the one ``jointlab diagnose`` runs)
        beside the single-joint trials: from its record when up to date, else computed here and
        recorded; None with the failure in the errors."""
        rel = "records/diagnosis/records.json"
        rec = self._record(ctx, rel, h, tuple)
        if rec is not None:
            return rec["result"]
        self._say(f"gap diagnosis: {len(ctx.plan.multi_joint)} multi-joint record(s)")
        try:
            with one_blas_thread():
                part = tuple(diagnose_records(ctx.camp, ctx.robot, dset))
        except (InputError, ValueError) as exc:
            ctx.errors["diagnosis/records"] = _error_text(exc)
            return None
        _write_record(ctx.state / rel, h, part, ctx.tmp_dir)
        self._keep_record(ctx, rel)
        return part

    def _diagnosis_finish(self, ctx, run):
        """Collect the diagnosis items; ``seconds``: the preparation plus the wait beyond the
        stages queued before it (its items run while the fits finish)."""
        if "off" in run:
            ctx.stages["diagnosis"] = _stage_row(note="switched off")
            return None
        if "records_only" in run:
            return self._diagnosis_records(ctx, *run["records_only"])
        t0 = time.perf_counter() - run["prep_s"]
        camp = ctx.camp
        dset, jobs, done, hashes = (run[k] for k in ("dset", "jobs", "done", "hashes"))
        for job, res in zip(jobs, run["pending"].result()):
            done[job.joint] = res
            self._keep_record(ctx, Path(job.record).relative_to(ctx.state).as_posix())
        failed = {j: r.error for j, r in done.items() if not r.ok}
        for j, msg in failed.items():
            ctx.errors[f"diagnosis/joint{j}"] = msg
        ok = {j: r for j, r in sorted(done.items()) if r.ok}
        folder = ctx.state / "records" / "diagnosis"
        # the single-joint part as diagnose_single_joint_campaign gives it, from the joints' items
        single = CampaignDiagnosis(camp.name, dset.to_dict(),
                                   {j: r.joint for j, r in ok.items() if r.joint is not None},
                                   skipped_trials=ctx.plan.multi_joint,
                                   link_angles=any(r.link_angles for r in ok.values()),
                                   nominal=check_nominal(dset.nominal, sorted(ok)).describe(),
                                   series={j: _series_ref(r.series, folder) for j, r in ok.items()})
        records = None
        if run["records"] is not None:     # multi-joint records beside: one report of both
            records = self._records_part(ctx, dset, run["records"])
        diag = join_diagnoses(ctx.plan, dset, single, records)
        stage_hash = self._diagnosis_hash(ctx, hashes, run["records"])
        if records is None and run["records"] is not None:
            stage_hash = "failed:" + stage_hash      # recomputed by a rerun
        diag_dir = ctx.out / "diagnosis"
        if diag.joints and not self._diagnosis_current(ctx, hashes, run["records"]):
            tmp = ctx.tmp_dir / "diagnosis-new"
            plots = {}
            for r in ok.values():   # drawn by the items computed in this run
                plots.update(r.plots or {})
            drawn = {j for j, r in ok.items() if r.plots is not None}
            pending = self._submit(_run_plot_job, [_PlotJob("diagnosis", str(tmp),
                                                            ({"joints": {str(j): r.to_dict()}},
                                                             {str(j): diag.series.get(j)}))
                                                   for j, r in diag.joints.items() if j not in drawn],
                                   "plots")
            self._fits_commit(ctx)       # its plots were queued before these
            for names in pending.result():
                plots.update(names)
            diag.write(tmp, plots=plots)
            ctx.od.commit(tmp, "diagnosis", prune=True)
        ctx.man["stages"]["diagnosis"] = {"hash": stage_hash, "outputs": ["diagnosis/"],
                                          "items": {str(j): {"hash": h} for j, h in hashes.items()
                                                    if j in ok}}
        if diag.joints:
            ctx.paths["diagnosis"] = diag_dir / "diagnosis.json"
        ctx.stages["diagnosis"] = _stage_row(len(jobs) - sum(1 for j in jobs if j.joint in failed),
                                             len(done) - len(jobs),
                                             len(failed) + ("diagnosis/records" in ctx.errors),
                                             time.perf_counter() - t0, run["note"],
                                             work=_work(jobs, done, "joint"),
                                             cpu=_work(jobs, done, "joint", "cpu_s"))
        return diag

    def _diagnosis_records(self, ctx, dset, t0):
        """Diagnosis of multi-joint records (:func:`ident.model.multijoint.diagnose_records`),
        serial, recomputed when the logs or settings change."""

        camp = ctx.camp
        trials = _planned_trials(ctx, "multi_joint")
        if not trials:
            ctx.stages["diagnosis"] = _stage_row(note="no single-joint trials to diagnose")
            return None
        h = self._records_hash(ctx, dset)
        diag_dir = ctx.out / "diagnosis"
        if _reuse_stage(ctx, "diagnosis", h, diag_dir / "diagnosis.json", len(trials), t0):
            return CampaignDiagnosis.from_dict(json.loads((diag_dir / "diagnosis.json").read_text(encoding="utf-8")),
                                               plan=ctx.plan)
        self._say(f"gap diagnosis: {len(trials)} multi-joint record(s)")
        try:
            records = diagnose_records(camp, ctx.robot, dset)
        except (InputError, ValueError) as exc:
            ctx.errors["diagnosis/records"] = _error_text(exc)
            ctx.stages["diagnosis"] = _stage_row(failed=len(trials), seconds=time.perf_counter() - t0)
            return None
        diag = join_diagnoses(ctx.plan, dset, None, records)
        tmp = ctx.tmp_dir / "diagnosis-new"
        diag.write(tmp)
        ctx.od.commit(tmp, "diagnosis", prune=True)
        ctx.man["stages"]["diagnosis"] = {"hash": h, "outputs": ["diagnosis/"]}
        ctx.paths["diagnosis"] = diag_dir / "diagnosis.json"
        ctx.stages["diagnosis"] = _stage_row(computed=len(trials), seconds=time.perf_counter() - t0,
                                             note="multi-joint records, blocks = motion cycles")
        return diag

    # stage: coast-down friction (source 000) on kind = "coastdown" trials ------------------------
    def _coastdown(self, ctx) -> str:
        """Run :mod:`ident.coastdown.campaign_analysis` on the coast-down trials into ``coastdown/``;
        returns the report's section (empty without coast-down trials)."""

        t0 = time.perf_counter()
        trials = _planned_trials(ctx, "coastdown")
        if not trials:      # no stage row: campaigns without coast-downs keep their report
            return ""
        h = ctx.hasher.combine("coastdown", ctx.base_hash, [ctx.hasher.file(t.log) for t in trials],
                               self.settings.plots)
        folder, section = ctx.out / "coastdown", ctx.out / "coastdown" / "section.md"
        prev = ctx.old.get("stages", {}).get("coastdown", {})
        if prev.get("hash") == h and _tree_ok(ctx, "coastdown/", "coastdown/section.md"):
            ctx.man["stages"]["coastdown"] = prev
            ctx.stages["coastdown"] = _stage_row(reused=len(trials), seconds=time.perf_counter() - t0)
            return section.read_text(encoding="utf-8")
        self._say(f"coast-down: {len(trials)} trial(s)")
        try:
            report = analyse_campaign(ctx.camp, ctx.robot)
        except Exception as exc:  # noqa: BLE001 - a failed stage is reported, the study goes on
            ctx.errors["coastdown"] = _error_text(exc)
            ctx.stages["coastdown"] = _stage_row(failed=len(trials), seconds=time.perf_counter() - t0)
            return ""
        tmp = ctx.tmp_dir / "coastdown-new"
        write_coastdown(report, tmp, plots=self.settings.plots)
        text = ("## Coast-down friction (source 000)\n\nML fit on the encoder angle (± standard errors); "
                "per joint all coasts together, then per trial beside the paper's TDM and FDM. Details, "
                "notes and decay curves: `coastdown/coastdown.md`; values: `coastdown/coastdown.json`.\n\n"
                + coastdown_table(report) + "\n")
        (tmp / "section.md").write_text(text, encoding="utf-8")
        ctx.od.commit(tmp, "coastdown", prune=True)
        ctx.paths["coastdown"] = folder / "coastdown.json"
        ctx.man["stages"]["coastdown"] = {"hash": h, "outputs": ["coastdown/"]}
        ctx.stages["coastdown"] = _stage_row(computed=len(report.trials), failed=len(report.skipped),
                                             seconds=time.perf_counter() - t0)
        return text

    # stage 5: report and recording -------------------------------------------------------------
    def _recording(self, ctx, calib_res, angles_dir, rrd_path, spawn) -> "_StudyRecording":
        rrd_inside = rrd_path is not None and ctx.out in Path(rrd_path).resolve().parents
        return _StudyRecording(ctx.camp, ctx.robot, rrd_path, spawn, calib_res, angles_dir, ctx.out,
                               self.settings.rrd_trials, ctx.tmp_dir,
                               install=ctx.od.install if rrd_inside else None)

    def _report(self, ctx, calib_res, refs, mocap_summary, fits, diag, angles_dir, rrd_path, spawn):
        t0 = time.perf_counter()
        s = self.settings
        up = ctx.man["stages"]
        h = ctx.hasher.combine("report", s.to_dict(),
                               {k: v.get("hash") or v.get("items") for k, v in up.items()},
                               str(rrd_path), ctx.errors)
        outputs = ["report.md", "csv/"] + (["plots/"] if s.plots else [])
        prev = ctx.old.get("stages", {}).get("report", {})
        rrd_inside = rrd_path is not None and ctx.out in Path(rrd_path).resolve().parents
        have = (all(_tree_ok(ctx, o) for o in outputs)
                and (rrd_path is None or (_tree_ok(ctx, ctx.od.rel(rrd_path)) if rrd_inside
                                          else rrd_path.is_file())))
        ctx.paths["report"] = ctx.out / "report.md"
        if rrd_path is not None:
            ctx.paths["rrd"] = rrd_path
        if prev.get("hash") == h and have and not spawn:
            if ctx.recording is not None:
                ctx.recording.abort()
                ctx.recording = None
            up["report"] = prev
            ctx.stages["report"] = _stage_row(reused=1, seconds=time.perf_counter() - t0)
            return
        self._say("writing the report" + (" and the recording" if rrd_path or spawn else ""))
        plots = {}
        if s.plots and fits is not None and fits.entries:
            tmp = ctx.tmp_dir / "plots-new"
            if ctx.study_plots is None:     # fits/ was up to date: not drawn with it
                ctx.study_plots = self._submit(_run_plot_job, [_PlotJob("study", str(tmp), (g, fits.models))
                                                               for g in _by_joint(fits.entries).values()],
                                               "plots")
            for names in ctx.study_plots.result():
                plots.update(names)
            ctx.od.commit(tmp, "plots", prune=True)
        tmp = ctx.tmp_dir / "csv-new"
        doc = diag.to_dict() if diag is not None else None     # diagnosis.json, as written
        write_study_csvs(ctx.camp, mocap_summary, fits, doc, tmp)
        ctx.od.commit(tmp, "csv", prune=True)
        later = [MANIFEST_NAME] + ([rrd_path.name] if rrd_path is not None
                                   and rrd_path.resolve().parent == ctx.out.resolve() else [])
        md = report_markdown(ctx.camp, ctx.stages, calib_res, mocap_summary, fits,
                             doc, plots, ctx.out, ctx.errors, will_write=later)
        if getattr(self, "_coast_md", ""):
            md = md.rstrip("\n") + "\n\n" + self._coast_md
        ctx.od.write("report.md", md)
        if rrd_path is not None or spawn:
            bad = {k.split("/", 1)[1] for k in ctx.errors if k.startswith(("mocap/", "fits/"))}
            if ctx.recording is None:
                ctx.recording = self._recording(ctx, calib_res, angles_dir, rrd_path, spawn).start(bad)
            recording, ctx.recording = ctx.recording, None
            # failed trials are in the report only
            recording.finish(fits, None if diag is None else (doc, diag.series_by_key()), md, bad)
        up["report"] = {"hash": h, "outputs": outputs + ([str(rrd_path)] if rrd_path else [])}
        ctx.stages["report"] = _stage_row(computed=1, seconds=time.perf_counter() - t0)


@dataclass
class _Context:
    camp: object
    robot: object
    out: Path
    state: Path
    tmp_dir: Path
    hasher: _Hasher
    base_hash: str
    man: dict
    old: dict
    stages: dict
    errors: dict
    paths: dict
    od: OutputDir
    plan: Plan                                # ident.workflow.plan(camp): the paths
    fit_plans: tuple                          # ident.workflow.fit_plans(camp, models): the fits' routing
    angles_ok: frozenset = frozenset()
    fits_commit: tuple = (None, None, None)   # (tmp folder, its plots in flight, manifest entry)
    study_plots: object = None                # plots/ in flight (ident.study.executor.Pending)
    recording: object = None                  # the recording begun early (_StudyRecording)
    pipeline: list = field(default_factory=list)   # ident.pipeline.plan.plan(camp, settings)


def _read_manifest(path: Path, note=None) -> dict:
    """The study manifest ``path`` as the rest of the study reads it: ``{"stages": {name:
    dict}, "records": {rel: sha256}, ...}``; ``{}`` when there is none. Any damage (unreadable,
    not UTF-8, not JSON, truncated, a value of the wrong type) drops what it touches, with one
    line through ``note``: those items are recomputed, never a traceback."""
    if not path.is_file():
        return {}
    problem = None
    try:
        doc = json.loads(path.read_bytes().decode("utf-8"))
    except OSError as exc:
        doc, problem = {}, f"unreadable: {exc.strerror or type(exc).__name__}"
    except (UnicodeDecodeError, ValueError, RecursionError) as exc:
        doc, problem = {}, f"not valid JSON ({type(exc).__name__})"
    if not isinstance(doc, dict):
        doc, problem = {}, f"a JSON {type(doc).__name__}, not an object"
    stages = doc.get("stages", {})
    if not isinstance(stages, dict) or not all(isinstance(v, dict) for v in stages.values()):
        problem = problem or "its stage list has the wrong type"
        stages = {k: v for k, v in stages.items() if isinstance(v, dict)} if isinstance(stages, dict) else {}
    for name, st in list(stages.items()):
        if any(k in st and not isinstance(st[k], t) for k, t in (("hash", str), ("items", dict), ("outputs", list))):
            problem = problem or f"its stage {name!r} has a value of the wrong type"
            del stages[name]
    records = doc.get("records", {})
    if not isinstance(records, dict) or not all(isinstance(v, str) for v in records.values()):
        problem = problem or "its record list has the wrong type"
        records = {k: v for k, v in records.items() if isinstance(v, str)} if isinstance(records, dict) else {}
    if problem and note is not None:
        note(f"study manifest {path} is damaged ({problem}); recomputing what it described")
    return {**doc, "stages": stages, "records": records}


def _write_manifest(path: Path, man: dict, tmp_dir: Path) -> None:
    _write_atomic(path, json.dumps(_jsonable(man), indent=1), tmp_dir)


def run_study(campaign, out, settings: StudySettings | None = None, executor=None,
              rrd: str | Path | None = None, spawn: bool = False, progress: bool = True) -> StudyResult:
    """``Study(settings, executor, progress).run(campaign, out, rrd, spawn)``."""
    return Study(settings, executor, progress).run(campaign, out, rrd=rrd, spawn=spawn)


# ---------------------------------------------------------------------------------------------
# report pieces
# ---------------------------------------------------------------------------------------------
def _conditions(entries, joint):
    """(load, vmax) -> entries of ``joint``, in thesis order (load down, speed down)."""
    out: dict = {}
    for e in entries:
        if e.task.joint == joint:
            out.setdefault((e.task.load_kg, e.task.vmax_frac), []).append(e)
    return dict(sorted(out.items(), key=lambda kv: (-kv[0][0], -kv[0][1])))


SPREAD_MODELS = ("cv", "stribeck")


def write_study_plots(fits, out_dir: Path) -> dict:
    """Per joint: ``friction_joint<j>.png`` (measured friction vs link speed of the first
    repetition of every condition with its fitted curve, thesis Figs. 5-1/5-2) and
    ``spread_joint<j>.png`` (each parameter of the Coulomb + viscous and Stribeck models over
    the repetitions of every condition: dots, mean and +-1 std). Returns {name: file name}."""

    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    paths = {}
    joints = sorted({e.task.joint for e in fits.entries})
    colors = ["tab:blue", "tab:orange", "tab:green", "tab:red", "tab:purple", "tab:brown",
              "tab:pink", "tab:gray", "tab:olive", "tab:cyan"]
    with young_garbage():   # the figures are freed by one young-generation collection
        for j in joints:  # loop over joints
            conds = _conditions(fits.entries, j)
            fig = new_subplots(7.0, 4.6, dpi=100)
            ax = fig.axes[0]
            curve_model = next((m for m in ("stribeck", "cv") if m in fits.models), fits.models[0])
            for k, ((load, vf), ents) in enumerate(conds.items()):  # loop over conditions
                e = min(ents, key=lambda x: x.task.repetition)
                c = colors[k % len(colors)]
                if e.plot:
                    step = max(1, e.plot["qd"].size // 1500)
                    ax.plot(e.plot["qd"][::step], e.plot["f_measured"][::step], ".", ms=1.2, color=c,
                            alpha=0.35, rasterized=True)
                    lim = float(np.max(np.abs(e.plot["qd"])))
                    v = np.linspace(-lim, lim, 401)
                    if curve_model in e.fits:
                        ax.plot(v, e.fits[curve_model].friction().torque(v), color=c, lw=1.6,
                                label=f"{load:g} kg, {100 * vf:g} % speed ({curve_model})")
            ax.axhline(0, color="0.85", lw=0.8)
            ax.axvline(0, color="0.85", lw=0.8)
            ax.set_xlabel("link speed qd (rad/s)")
            ax.set_ylabel("friction torque (N m)")
            ax.set_title(f"joint {j}: friction vs speed (first repetition of each condition)", fontsize=9)
            ax.legend(fontsize=7, loc="upper left")
            tight_layout(fig)
            name = f"friction_joint{j}.png"
            save_png(fig, out_dir / name, overwrite=True)
            paths[f"friction_joint{j}"] = name

            params = [(m, p) for m in SPREAD_MODELS if m in fits.models
                      for p in _param_names(fits.entries, j, m)]
            if not params:
                continue
            ncol = min(3, len(params))
            nrow = -(-len(params) // ncol)
            fig = new_subplots(3.2 * ncol, 2.5 * nrow + 0.6, dpi=100, nrows=nrow, ncols=ncol, n=len(params))
            labels = [f"{load:g}kg\n{100 * vf:g}%" for (load, vf) in conds]
            for i, (m, p) in enumerate(params):  # loop over parameters
                ax = fig.axes[i]
                dots, bars = [], []   # (condition, values), (condition, mean, std): one artist each
                for k, ents in enumerate(conds.values()):  # loop over conditions
                    vals = np.array([e.fits[m].params.get(p, np.nan) for e in ents if m in e.fits], float)
                    vals = vals[np.isfinite(vals)]
                    if vals.size:
                        dots += [(k, v) for v in vals]
                        bars.append((k + 0.18, vals.mean(), vals.std()))
                if bars:
                    ax.plot(*np.array(dots).T, "o", ms=3, color="tab:blue", alpha=0.6)
                    x, mean, std = np.array(bars).T
                    ax.errorbar(x, mean, yerr=std, fmt="s", ms=4, color="black", capsize=3)
                ax.set_xticks(range(len(labels)))
                ax.set_xticklabels(labels, fontsize=7)
                ax.set_title(f"{m}: {p}", fontsize=9)
            fig.suptitle(f"joint {j}: parameter spread over repetitions (dots: repetitions; "
                         "square: mean +- std)", fontsize=9)
            tight_layout(fig)
            name = f"spread_joint{j}.png"
            save_png(fig, out_dir / name, overwrite=True)
            paths[f"spread_joint{j}"] = name
        fig = ax = None
    return paths


def _param_names(entries, joint, model):
    for e in entries:
        if e.task.joint == joint and model in e.fits:
            return list(e.fits[model].params)
    return []


def write_study_csvs(campaign, mocap_summary, fits, diagnosis, out_dir: Path) -> list[Path]:
    """``trials.csv``: one row per (trial, moving joint): condition, link-angle residual and
    flagged frames, each model's RMS; ``diagnosis_effects.csv``: one row per (joint, candidate
    effect) of the first selection step."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    models = list(fits.models) if fits is not None else []
    fit_of = {(e.task.trial, e.task.joint): e for e in (fits.entries if fits is not None else ())}
    mtrials = (mocap_summary or {}).get("trials", {})
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(["trial", "joint", "kind", "load_kg", "vmax_frac", "repetition", "angles_rms_mm",
                "flagged_frames", "peak_speed", "max_abs_tau"] + [f"rms_{m}" for m in models])
    for tr in campaign.trials:  # loop over trials
        md = mtrials.get(tr.id, {})
        for j in tr.joints:
            e = fit_of.get((tr.id, j))
            row = [tr.id, j, tr.kind, tr.load_kg, tr.vmax_frac, tr.repetition,
                   _cell(md.get("rms_mm")), _cell(md.get("flagged_frames")),
                   _cell(e.peak_speed if e else None), _cell(e.max_abs_tau if e else None)]
            row += [_cell(e.fits[m].rms if e and m in e.fits else None) for m in models]
            w.writerow(row)
    paths = [out_dir / "trials.csv"]
    paths[0].write_text(buf.getvalue(), encoding="utf-8")
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(["joint", "effect", "channel", "heldout_rms", "reduction", "p_adjusted", "significant",
                "verdict"])
    for j, rep in ((diagnosis or {}).get("joints") or {}).items():
        for e in rep.get("effects", []):
            w.writerow([j, e.get("effect"), e.get("channel"), _cell(e.get("heldout_rms")),
                        _cell(e.get("reduction")), _cell(e.get("p_adjusted")), e.get("significant"),
                        rep.get("verdict")])
    paths.append(out_dir / "diagnosis_effects.csv")
    paths[1].write_text(buf.getvalue(), encoding="utf-8")
    return paths


def _cell(x):
    if x is None:
        return ""
    if isinstance(x, (float, np.floating)):
        return "" if not np.isfinite(x) else f"{float(x):.6g}"
    return x


def _f(x, nd=3):
    if x is None:
        return "-"
    if isinstance(x, (float, np.floating)):
        return "-" if not np.isfinite(x) else f"{float(x):.{nd}g}"
    return str(x)


def _multijoint_section(out: Path) -> list:
    """The multi-joint rigid-body fits of ``rigidbody/rigidbody.md`` (written by
    :meth:`ident.model.multijoint.MultiJointFits.report`) with its headings moved two levels
    down, or [] when the stage wrote none."""
    p = out / "rigidbody" / "rigidbody.md"
    if not p.is_file():
        return []
    body = [("##" + ln) if ln.startswith("#") else ln
            for ln in p.read_text(encoding="utf-8").splitlines()]
    if body and body[0].startswith("### Multi-joint"):
        body = body[1:]
    return ["Multi-joint records: the URDF's rigid-body model jointly with per-joint friction, "
            "torque offsets and actuator inertias (all values: `rigidbody/fits.json`, "
            "`rigidbody/rigidbody.json`).", ""] + body


def _existing_files(out: Path, will_write=()) -> str:
    """The Files line of the report: the study's outputs that exist in ``out`` (or that the
    study writes after the report: ``will_write``), each once."""
    cands = [("calib.json", ""), ("references.json", ""), ("angles/", ""), ("mocap.json", ""),
             ("fits/", ""), ("rigidbody/", ""), ("coastdown/", ""), ("diagnosis/", ""),
             ("sim2real/", ""),
             ("plots/", ""), ("csv/trials.csv", ""), ("csv/diagnosis_effects.csv", ""),
             ("study.rrd", " (open with `jointlab view`)"),
             (MANIFEST_NAME, " (input hashes: a rerun skips what is up to date)")]
    keep = [f"`{name}`{note}" for name, note in cands
            if (out / name.rstrip("/")).exists() or name in will_write]
    return ", ".join(keep) + "." if keep else "none."


def report_markdown(campaign, stages, calib_res, mocap_summary, fits, diagnosis, plots, out: Path,
                    errors=None, will_write=()) -> str:
    """The study report: stages, calibration, link-angle quality, the thesis tables (Tables
    5-1..5-3 / A / B of 002), the multi-joint rigid-body fits, the plots and the gap-diagnosis
    verdicts; the Files line names only the outputs that exist (or ``will_write``: written
    after the report)."""
    L = _stages_section(campaign, stages, errors)
    L += ["", "## Camera-to-base calibration", ""]
    if calib_res is not None:
        L += [summary_markdown(calib_res).replace("## ", "### ", 1), "", "Written to `calib.json`."]
    else:
        L.append(getattr(stages.get("calib"), "note", "") or "No calibration.")
    L += ["", "## Link angles from the markers", ""] + _mocap_section(campaign, stages, mocap_summary)
    L += ["", "## Friction identification (thesis eq. 2-4)", ""] + _fits_section(fits, plots, out)
    L += ["", "## Sim-to-real gap", ""] + _gap_section(stages, diagnosis, out)
    L += ["", "## Files", "", _existing_files(out, will_write), ""]
    return "\n".join(L)


def _stages_section(campaign, stages, errors) -> list:
    """The report's title, its campaign line and the stage table (with the failures)."""
    trials = campaign.trials
    joints = sorted({j for t in trials for j in t.joints})
    loads = sorted({t.load_kg for t in trials})
    speeds = sorted({t.vmax_frac for t in trials})
    reps = max((t.repetition for t in trials), default=0)
    L = [f"# Study of campaign `{campaign.name}`", "",
         f"{len(trials)} trials: joint(s) {', '.join(map(str, joints))}; loads "
         f"{', '.join(f'{x:g}' for x in loads)} kg; speed ranges "
         f"{', '.join(f'{100 * x:g} %' for x in speeds)} of the maximum; up to {reps} repetitions.", "",
         "## Stages", "", "| stage | computed | reused | failed | seconds | note |", "|---|---|---|---|---|---|"]
    for name, r in stages.items():
        note = r.note
        if name == "fits" and not (r.computed or r.reused or r.failed) and "rigidbody" in stages:
            note = note or "no single-joint trials: the multi-joint records are fitted in the rigidbody stage"
        L.append(f"| {name} | {r.computed} | {r.reused} | {r.failed} | {r.seconds:.1f} | {note} |")
    if errors:
        L += ["", "Failures:", ""] + [f"- `{k}`: {v}" for k, v in sorted(errors.items())]
    return L


def _mocap_section(campaign, stages, mocap_summary) -> list:
    """The report's link-angle quality table (or the mocap stage's note)."""
    if not (mocap_summary and mocap_summary.get("trials")):
        return [getattr(stages.get("mocap"), "note", "") or "No link angles."]
    L = [f"Camera pose from {mocap_summary['camera_from']}; per-trial CSVs in `angles/`.", "",
         "| trial | joints | frames | RMS residual (mm) | flagged frames | link - motor RMS (mrad) |",
         "|---|---|---|---|---|---|"]
    for tid, d in mocap_summary["trials"].items():
        lm = d.get("link_minus_motor_rms_rad") or []
        lm = ", ".join(_f(None if x is None else 1e3 * x) for x in lm)
        L.append(f"| {tid} | {', '.join(map(str, campaign.trial(tid).joints))} | {d.get('frames')} | {_f(d.get('rms_mm'))} | "
                 f"{d.get('flagged_frames', '-')} | {lm} |")
    return L


def _fits_section(fits, plots, out: Path) -> list:
    """The report's friction section: the rigid-body fits, the thesis tables, the plots."""
    L = []
    tables = out / "fits" / "tables" / "tables.md"
    multi = _multijoint_section(out)
    if multi:
        L += multi + [""]
    if fits is not None and fits.entries and tables.is_file():
        L += [f"{len(fits.entries)} trial-joint fits of {', '.join(fits.models)}; statistics over the "
              "repetitions of each (joint, load, speed range) condition (CV = population std / |mean|).",
              "", tables.read_text(encoding="utf-8"), ""]
        pres = fits.presliding_summary()
        if pres:
            L += [pres, ""]
        for key, name in plots.items():
            L += [f"![{key}](plots/{name})", ""]
        L.append("Per-condition plots: `fits/plots/`; all parameters with standard errors: "
                 "`fits/fits.json`, `fits/fits_diagnostics.json`.")
    elif not multi:
        L.append("No fits.")
    return L


def _gap_section(stages, diagnosis, out: Path) -> list:
    """The report's gap-diagnosis table, notes and plots (or the diagnosis stage's note)."""
    if not (diagnosis and diagnosis.get("joints")):
        return [getattr(stages.get("diagnosis"), "note", "") or "No diagnosis."]
    L = ["| joint | verdict | held-out RMS nominal | best effect | reduction | largest gap share |",
         "|---|---|---|---|---|---|"]
    for j, rep in diagnosis["joints"].items():
        eff = [e for e in rep.get("effects", []) if e.get("identifiable", True)
               and e.get("reduction") is not None]
        best = max(eff, key=lambda e: e["reduction"]) if eff else None
        loc = rep.get("localisation") or []
        top = max(loc, key=lambda r: r["share"]) if loc else None
        L.append(f"| {j} | **{rep.get('verdict_text', rep.get('verdict'))}** | {_f(rep.get('heldout_rms_nominal'))} | "
                 f"{best['effect'] if best else '-'} | {_f(best['reduction']) if best else '-'} | "
                 f"{(top['regime'] + ' ' + _f(top['share'], 2)) if top else '-'} |")
    L.append("")
    for j, rep in diagnosis["joints"].items():
        for n in rep.get("notes", []):
            L += [f"Note on joint {j}: {n}.", ""]
    for j in diagnosis["joints"]:
        for kind in ("localisation", "effects"):
            p = out / "diagnosis" / f"joint{j}_{kind}.png"
            if p.is_file():
                L += [f"![joint {j} {kind}](diagnosis/{p.name})", ""]
    L.append("Full report: `diagnosis/diagnosis.md`, `diagnosis/diagnosis.json`.")
    return L


def _rrd_trials(campaign, which: str):
    if which == "all":
        return list(campaign.trials)
    seen, out = set(), []
    for t in sorted(campaign.trials, key=lambda t: t.repetition):
        key = (tuple(t.joints), t.load_kg, t.vmax_frac, t.kind)
        if key not in seen:
            seen.add(key)
            out.append(t)
    order = {t.id: k for k, t in enumerate(campaign.trials)}
    return sorted(out, key=lambda t: order[t.id])


def _recording_tmp(rrd_path, out, tmp_dir, tag: str = "") -> Path | None:
    """The temporary file a recording is written to before its rename to ``rrd_path`` (its
    folder made): in the study's ``tmp_dir`` when the recording lies inside ``out`` (same file
    system), else beside ``rrd_path``; None without a file."""
    if rrd_path is None:
        return None
    rrd_path = Path(rrd_path)
    rrd_path.parent.mkdir(parents=True, exist_ok=True)
    same_fs = tmp_dir is not None and Path(out).resolve() in rrd_path.resolve().parents
    return (Path(tmp_dir) if same_fs else rrd_path.parent) / f".{rrd_path.name}.{os.getpid()}{tag}.tmp"


def log_study(campaign, robot, rrd_path, spawn, calib_res, angles_dir, fits, diag, report_md, out,
              which: str = "first", tmp_dir: Path | None = None, install=None) -> list[str]:
    """One recording of the study: the campaign (markers in the camera frame, the robot posed
    by the motor angles and placed by the calibration, joint signals), the calibration, the link
    angles, the fits and the diagnosis, with a blueprint showing all of them. Written to a
    temporary file and renamed to ``rrd_path`` when complete (``install(tmp, rrd_path)`` does
    the rename when given: the output folder's checked, registered install)."""
    sub = dataclasses.replace(campaign, trials=tuple(_rrd_trials(campaign, which)))
    ids = {t.id for t in sub.trials}
    tmp = _recording_tmp(rrd_path, out, tmp_dir)
    try:
        logged = _log_study(sub, robot, tmp, spawn, calib_res, angles_dir, fits, diag, report_md, out, ids)
    except BaseException:
        if tmp is not None:
            tmp.unlink(missing_ok=True)
        raise
    if tmp is not None:
        if install is not None:
            install(tmp, rrd_path)
        else:
            os.replace(tmp, rrd_path)
    return logged


def _log_study(sub, robot, tmp, spawn, calib_res, angles_dir, fits, diag, report_md, out, ids):
    with make_sink(str(tmp) if tmp else None, spawn, app_id="jointlab-study") as sink:
        logged = _log_inputs(sink, sub, robot, calib_res, angles_dir)
        _log_results(sink, logged, fits, diag, report_md, out, ids)
    return logged


def _log_inputs(sink, sub, robot, calib_res, angles_dir) -> list[str]:
    """The recording's first part: the campaign (:func:`ident.study.view.log_campaign`), the
    calibration and the link angles of the trials of ``sub``."""
    T_cb = None if calib_res is None else np.asarray(calib_res.T_camera_base, float)
    logged = log_campaign(sub, sink, robot, T_camera_base=T_cb, max_signal_rate_hz=100.0)
    if calib_res is not None:
        log_calibration(sink, calib_res, prefix="campaign/calib")
    if angles_dir is not None:
        for t in sub.trials:  # loop over logged trials
            p = Path(angles_dir) / f"{t.id}.csv"
            if p.is_file():
                ta, q = read_angles_csv(p)
                if q:
                    sink.scalars(f"mocap/{t.id}", ta, np.column_stack([q[j] for j in sorted(q)]),
                                 names=[f"q_{j}" for j in sorted(q)])
    return logged


def _log_results(sink, logged, fits, diag, report_md, out, ids) -> None:
    """The recording's second part: the fits, the diagnosis, the PNGs, the report and the
    blueprint."""
    if fits is not None and fits.entries:

        log_fits(FitsResult(tuple(e for e in fits.entries if e.task.trial in ids), fits.models,
                            fits.campaign, fits.skipped), sink)
    if diag is not None:
        report, series = diag

        diag_dir = Path(out) / "diagnosis"
        plots = {p.stem: p.name for p in sorted(diag_dir.glob("*.png"))}
        sink.text("diagnosis/report", markdown(report, plots))
        for j, srs in series.items():  # loop over joints, one joint's samples at a time
            srs = _series_arrays(srs)
            if srs is not None and "residual_nominal" in srs:
                t = srs["t"] if "t" in srs else np.arange(srs["residual_nominal"].size, dtype=float)
                sink.scalars(f"diagnosis/joint{j}/residual_nominal", t, srs["residual_nominal"])
        _log_pngs(sink, diag_dir, "diagnosis/plots")
    _log_pngs(sink, Path(out) / "plots", "study/plots")
    sink.text("study/report", report_md)  # the text view's one document
    trial_sig = [f"/{b}/signals/**" for b in logged if "/trial/" in b]
    series_views = {"joint signals (robot log)": trial_sig or ["/campaign/**"],
                    "link angles (markers)": ["/mocap/**"],
                    "friction fits (eq. 2-4)": ["/fits/**"],
                    "gap diagnosis": ["/diagnosis/**"]}
    sink.layout(series=series_views, world="/campaign", text="/study")  # one document per text view


class _StudyRecording:
    """The study's recording (:func:`log_study`) begun early: :meth:`start` logs the inputs
    (campaign, calibration, link angles: all known once the link angles are) from a thread of
    this process while the workers fit, :meth:`finish` the results once the report is written.
    When the trials the recording shows are no longer those it began with (a trial failed in
    the fits), :meth:`finish` writes it again from the start, as :func:`log_study` would."""

    def __init__(self, campaign, robot, rrd_path, spawn, calib_res, angles_dir, out, which,
                 tmp_dir, install=None):
        self.args = (campaign, robot, rrd_path, spawn, calib_res, angles_dir, out, which, tmp_dir,
                     install)
        self.thread, self.error, self.sink, self.tmp, self.ids = None, None, None, None, None

    @staticmethod
    def shown(campaign, bad) -> tuple:
        """The recording's trials: :func:`_rrd_trials` of the trials that did not fail."""
        return tuple(t for t in campaign.trials if t.id not in bad)

    def start(self, bad) -> "_StudyRecording":
        import threading

        campaign, robot, rrd_path, spawn, calib_res, angles_dir, out, which, tmp_dir, _ = self.args
        sub = dataclasses.replace(campaign, trials=tuple(_rrd_trials(
            dataclasses.replace(campaign, trials=self.shown(campaign, bad)), which)))
        self.ids = {t.id for t in sub.trials}
        self.tmp = _recording_tmp(rrd_path, out, tmp_dir, ".early")

        def run():
            try:
                self.sink = make_sink(str(self.tmp) if self.tmp else None, spawn, app_id="jointlab-study")
                self.logged = _log_inputs(self.sink, sub, robot, calib_res, angles_dir)
            except BaseException as exc:   # noqa: BLE001 - raised again by finish()
                self.error = exc
            release_free_memory()          # the campaign's marker arrays are gone

        self.thread = threading.Thread(target=run, name="jointlab-recording", daemon=True)
        self.thread.start()
        return self

    def _join(self):
        if self.thread is not None:
            self.thread.join()
            self.thread = None

    def abort(self) -> None:
        """Drop the recording begun (the study stopped, or it is not needed)."""
        self._join()
        if self.sink is not None:
            try:
                self.sink.close()
            except Exception:   # noqa: BLE001 - the partial file is removed next
                pass
            self.sink = None
        if self.tmp is not None:
            self.tmp.unlink(missing_ok=True)

    def finish(self, fits, diag, report_md, bad) -> list[str]:
        """The complete recording in place (what :func:`log_study` writes)."""
        campaign, robot, rrd_path, spawn, calib_res, angles_dir, out, which, tmp_dir, install = self.args
        self._join()
        if self.error is not None:
            self.abort()
            raise self.error
        shown = dataclasses.replace(campaign, trials=self.shown(campaign, bad))
        if {t.id for t in _rrd_trials(shown, which)} != self.ids:
            self.abort()
            return log_study(shown, robot, rrd_path, spawn, calib_res, angles_dir, fits, diag,
                             report_md, out, which, tmp_dir, install=install)
        try:
            _log_results(self.sink, self.logged, fits, diag, report_md, out, self.ids)
            self.sink.close()
            self.sink = None
        except BaseException:
            self.abort()
            raise
        if self.tmp is not None:
            if install is not None:
                install(self.tmp, Path(rrd_path))
            else:
                os.replace(self.tmp, rrd_path)
        return self.logged


def _log_pngs(sink, folder: Path, prefix: str) -> None:
    if not getattr(sink, "enabled", False) or not folder.is_dir():
        return
    import matplotlib.image as mpimg

    for p in sorted(folder.glob("*.png")):  # loop over a handful of plots
        img = mpimg.imread(p)
        if img.dtype != np.uint8:
            img = (np.clip(img[..., :3], 0, 1) * 255).astype(np.uint8)
        sink.image(f"{prefix}/{p.stem}", np.ascontiguousarray(img[..., :3]))
