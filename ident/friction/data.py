"""One joint's friction acquisition: time, velocity, acceleration and the residual torque
(Indri & Trapani 2020, eq. 25), the data every friction estimator and the friction simulation
(:mod:`ident.sim.friction`) exchange."""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

__all__ = ["FrictionData"]


@dataclass(frozen=True, eq=False)
class FrictionData:
    """One joint's acquisition, time first: ``time`` (T,) s, ``qd`` (T,) rad/s, ``qdd`` (T,)
    rad/s^2 and the residual torque ``tau`` (T,) N m (eq. 25). ``accel``: the nominal reversal
    acceleration of a phase 2-A data set (None: taken from the signal)."""

    time: np.ndarray
    qd: np.ndarray
    qdd: np.ndarray
    tau: np.ndarray
    label: str = ""
    accel: float | None = None
    truth: np.ndarray | None = field(default=None, repr=False)   # noise-free friction (synthetic)

    def __post_init__(self):
        t = np.asarray(self.time, float)
        for name in ("qd", "qdd", "tau"):
            a = np.asarray(getattr(self, name), float)
            if a.shape != t.shape or a.ndim != 1:
                raise ValueError(f"FrictionData {self.label!r}: {name} has shape {a.shape}, "
                                 f"time has {t.shape} (both must be (T,))")
            bad = ~np.isfinite(a)
            if bad.any():
                raise ValueError(f"FrictionData {self.label!r}: {name} is not finite at sample "
                                 f"{int(np.argmax(bad))}")
        if t.size < 3 or np.any(np.diff(t) <= 0):
            raise ValueError(f"FrictionData {self.label!r}: time must be strictly increasing with "
                             "at least 3 samples")

    @property
    def dt(self) -> np.ndarray:
        """The (T-1,) sample steps (the exact discretisation accepts uneven steps)."""
        return np.diff(np.asarray(self.time, float))

    @property
    def n(self) -> int:
        return int(np.asarray(self.time).shape[0])

    @property
    def reversal_accel(self) -> float:
        """``accel`` if given, else the 99th percentile of |qdd| (robust maximum)."""
        if self.accel is not None:
            return float(self.accel)
        return float(np.percentile(np.abs(self.qdd), 99.0))

    @property
    def v_max(self) -> float:
        return float(np.max(np.abs(self.qd)))
