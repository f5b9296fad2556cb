"""Excitation: trajectory design (thesis eq. 3-1) and reference trajectories."""
