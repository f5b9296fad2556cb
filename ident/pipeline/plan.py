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
class PipelineSettings:
    """What the stages read besides the campaign (each stage declares the part it uses).

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
