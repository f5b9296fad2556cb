"""Sim-to-real gap diagnosis (see :mod:`ident.gap.diagnose`)."""
from ident.gap.candidates import CONFOUNDERS, candidate_effects
from ident.gap.data import JointData, build_joint_data
from ident.gap.diagnose import REGIMES, DiagnosisSettings, diagnose_joint

__all__ = ["CONFOUNDERS", "candidate_effects", "JointData", "build_joint_data", "REGIMES",
           "DiagnosisSettings", "diagnose_joint"]
