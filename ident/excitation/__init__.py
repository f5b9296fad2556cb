"""Excitation: trajectory design (thesis eq. 3-1), reference trajectories and the velocity
profiles of Indri & Trapani's acquisitions."""
