"""Sim-to-real gap diagnosis (see :mod:`ident.gap.diagnose`)."""
from .candidates import CONFOUNDERS, candidate_effects
from .data import JointData, build_joint_data
from .diagnose import REGIMES, DiagnosisSettings, diagnose_joint

__all__ = ["CONFOUNDERS", "candidate_effects", "JointData", "build_joint_data", "REGIMES",
           "DiagnosisSettings", "diagnose_joint"]
