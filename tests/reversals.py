"""The tests' own count of the distance moved since the last velocity reversal (a loop over the
samples, independent of ident.friction.presliding), shared by the presliding tests."""
from __future__ import annotations

import numpy as np


def displacement_by_loop(q, qd, floor):
    """Distance from the last turning point, sample by sample: the turning point is the angle
    where the direction (of the samples faster than ``floor``) last changed."""
    out = np.zeros_like(q)
    ref, direction = None, 0.0
    for t in range(q.size):
        if abs(qd[t]) >= floor:
            d = np.sign(qd[t])
            if d != direction:
                ref, direction = q[t], d
        out[t] = 0.0 if ref is None else abs(q[t] - ref)
    return out
