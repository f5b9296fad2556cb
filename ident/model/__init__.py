"""Models of the robot: the one-link flexible-joint model (thesis eq. 2-1..2-4)."""
