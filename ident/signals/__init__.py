"""Signals for identification: the finite Fourier series (thesis eq. 3-2), smoothing and derivatives, synchronisation."""
