"""Sim-to-real gap diagnosis (see :mod:`ident.gap.diagnose`)."""
from .candidates import CONFOUNDERS, candidates
from .data import JointData, build_joint_data
from .diagnose import REGIMES, DiagnosisSettings, diagnose_joint

__all__ = ["CONFOUNDERS", "candidates", "JointData", "build_joint_data", "REGIMES",
           "DiagnosisSettings", "diagnose_joint"]
