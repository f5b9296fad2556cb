"""The pipeline's one list of stages, in order, and the settings every stage reads.

``plan(campaign, settings)`` is the list; the commands run a slice of it through
:func:`ident.pipeline.stage.run_stages`, ``jointlab study`` all of it through its resumable
runner (:class:`ident.study.study.Study`). A new stage is one module in
:mod:`ident.pipeline.stages` plus its line in :data:`STAGES`.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from ident.gap import DiagnosisSettings
from ident.pipeline.stages import calib, coastdown, diagnosis, fits, mocap, rigidbody, sim2real
from ident.settings import (Flag, InstanceOf, Interval, Joints, Keys, Models, OneOf, PathLike, Settings,
                            TrialIds)
from ident.workflow import FitSettings, Plan

__all__ = ["STAGES", "PipelineSettings", "plan", "stage_named"]

#: every stage, in the order a study runs them
STAGES: tuple = (
    calib.STAGE,
    mocap.STAGE,
    fits.STAGE,
    rigidbody.STAGE,
    diagnosis.STAGE,
    coastdown.STAGE,
    sim2real.STAGE,
)


@dataclass(frozen=True)
class PipelineSettings(Settings):
    """What the stages read besides the campaign (each stage declares the part it uses);
    :attr:`constraints` is checked at construction (:mod:`ident.settings`; the nested
    ``fit`` and ``diagnosis`` settings check their own).

    ``calib_*``: :func:`ident.workflow.calibrate`'s options; ``mocap``, ``calib_file``,
    ``trials``, ``solver``: the angle solve (on/off, a ``calib.json``, the trials, the settings
    of :func:`mocap.solve.solve_trial`); ``models``, ``fit``, ``fit_plan``, ``angles``,
    ``plots``: the fits (``fit_plan``: a plan :func:`ident.workflow.prepare_fit` already
    checked); ``diagnose``, ``diagnosis``, ``markers``, ``joints``: the gap diagnosis;
    ``sim2real*``: the MuJoCo replay (``jointlab sim2real``'s options).
    """

    calib_method: str = "auto"
    calib_noise_mm: float | None = None
    calib_min_sweep_deg: float = 15.0
    calib_cross_check: bool = False
    calib_urdf_tol_mm: float = 0.0
    calib_trust_urdf: bool = False
    calib_deflection: bool = False
    mocap: bool = True
    calib_file: Path | None = None
    trials: tuple | None = None
    solver: dict = field(default_factory=dict)
    models: tuple | None = None
    fit: FitSettings = FitSettings()
    fit_plan: Plan | None = None
    angles: Path | None = None
    plots: bool = True
    diagnose: bool = True
    diagnosis: DiagnosisSettings = DiagnosisSettings()
    markers: bool = True
    joints: tuple | None = None
    sim2real: bool = False
    sim2real_mjcf: Path | None = None
    sim2real_effects: str | None = None
    sim2real_diagnosis: Path | None = None
    sim2real_sysid: bool = True
    sim2real_threads: int = 1

    #: field -> (command-line option, constraint), checked at construction
    constraints = {
        "calib_method": ("--method", OneOf("auto", "cluster", "circle")),
        "calib_noise_mm": ("--noise-mm", Interval(0, 1e3, closed="right", none=True)),
        "calib_min_sweep_deg": ("--min-sweep-deg", Interval(0.0, 360.0)),
        "calib_cross_check": ("--cross-check", Flag()),
        "calib_urdf_tol_mm": ("--urdf-tol-mm", Interval(0.0, 1e3, note="mm")),
        "calib_trust_urdf": ("--trust-urdf", Flag()),
        "calib_deflection": ("--deflection", Flag()),
        "mocap": ("--no-mocap", Flag()),
        "calib_file": ("--calib", PathLike()),
        "trials": ("--trial", TrialIds()),
        "solver": ("solver", Keys({"min_markers": ("--min-markers", Interval(1, integer=True)),
                                   "reject_sigma": ("--reject-sigma", Interval(0, closed="right")),
                                   "refine": ("--refine", Flag()),
                                   "refine_geometry": ("--refine-geometry", Flag())})),
        "models": ("--models", Models(none=True)),
        "fit": ("fit", InstanceOf(FitSettings)),
        "fit_plan": ("fit_plan", InstanceOf(Plan, none=True)),
        "angles": ("--angles", PathLike()),
        "plots": ("--no-plots", Flag()),
        "diagnose": ("--no-diagnosis", Flag()),
        "diagnosis": ("diagnosis", InstanceOf(DiagnosisSettings)),
        "markers": ("--no-markers", Flag()),
        "joints": ("--joints", Joints()),
        "sim2real": ("--sim2real", Flag()),
        "sim2real_mjcf": ("--mjcf", PathLike()),
        "sim2real_effects": ("--effects", InstanceOf(str, none=True)),
        "sim2real_diagnosis": ("--diagnosis", PathLike()),
        "sim2real_sysid": ("--no-sysid", Flag()),
        "sim2real_threads": ("--threads", Interval(1, integer=True)),
    }


def plan(campaign, settings: PipelineSettings = PipelineSettings()) -> list:
    """The ordered stages the settings ask for (:data:`STAGES`); which of them apply to the
    campaign each stage's ``skip`` says when it is run.

    Parameters
    ----------
    campaign : mocap.io.campaign.Campaign
    settings : PipelineSettings

    Returns
    -------
    list of Stage
    """
    return [st for st in STAGES if st.enabled(settings)]


def stage_named(stages, *names) -> list:
    """The stages of ``stages`` called ``names``, in the list's order (a command's slice)."""
    return [st for st in stages if st.name in names]
