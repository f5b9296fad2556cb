"""calib: camera-to-robot-base calibration from single-joint rotation sweeps."""
