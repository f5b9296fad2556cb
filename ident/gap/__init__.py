"""Sim-to-real gap diagnosis (see :mod:`ident.gap.diagnose`)."""
from ident.gap.candidates import CONFOUNDERS, candidate_effects
from ident.gap.data import JointData, build_joint_data
from ident.gap.diagnose import DiagnosisSettings, GapDiagnosis, diagnose_joint
from ident.gap.result import DiagnosisResult

__all__ = ["CONFOUNDERS", "candidate_effects", "JointData", "build_joint_data", "DiagnosisSettings",
           "GapDiagnosis", "DiagnosisResult", "diagnose_joint"]
