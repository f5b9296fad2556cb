"""calib: camera-to-robot-base calibration from single-joint rotation sweeps."""

from calib.axis import AxisFit, CircleAxisEstimator, ClusterAxisEstimator, fit_circle_bcls, sweep_crb
from calib.base import BasePlacement, place_base, pose_errors
from calib.handeye import HandEyeEstimator, HandEyeResult
from calib.pipeline import CalibResult, SweepData, calibrate, calibrate_sweeps, write_calib_json

__all__ = ["AxisFit", "CircleAxisEstimator", "ClusterAxisEstimator", "fit_circle_bcls", "sweep_crb",
           "BasePlacement", "place_base", "pose_errors", "HandEyeEstimator", "HandEyeResult",
           "CalibResult", "SweepData", "calibrate", "calibrate_sweeps", "write_calib_json"]
