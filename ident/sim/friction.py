"""Synthetic friction ground truth: the residual torque of a joint whose friction is any forward
model of :mod:`ident.friction` (dynamic ones through their exact discretisation) along a
piecewise-linear velocity profile (:mod:`ident.excitation.profiles`), simulated 10x finer than
the returned 1 kHz data."""
from __future__ import annotations

import numpy as np

from ident.excitation.profiles import piecewise_linear_velocity, reversal_knots
from ident.friction import FrictionModel
from ident.friction.data import FrictionData

__all__ = ["simulate_friction", "simulate_reversal_datasets"]


def simulate_friction(model: FrictionModel, knots, dt: float = 1e-3, *, noise_std: float = 0.0,
                      seed: int = 0, oversample: int = 10, label: str = "",
                      accel: float | None = None) -> FrictionData:
    """Residual torque of a joint whose friction is ``model`` (any forward model; dynamic ones
    through their exact discretisation) along the piecewise-linear velocity ``knots``, computed
    ``oversample`` times finer than ``dt`` and sampled every ``dt``, plus white noise of
    ``noise_std`` N m (seeded). The noise-free torque is kept in ``truth``."""
    if oversample < 1:
        raise ValueError("oversample must be >= 1")
    kt, kv = knots
    t, qd, qdd = piecewise_linear_velocity(kt, kv, dt / oversample)
    tau = model.torque(qd, qdd, dt / oversample) if model.dynamic else model.torque(qd)
    t, qd, qdd, tau = t[::oversample], qd[::oversample], qdd[::oversample], tau[::oversample]
    rng = np.random.default_rng(seed)
    noisy = tau + noise_std * rng.standard_normal(tau.shape)
    return FrictionData(t, qd, qdd, noisy, label=label, accel=accel, truth=tau)


def simulate_reversal_datasets(model: FrictionModel, accels=(2.0, 4.0, 8.0, 12.0, 16.0, 20.0),
                               vmax: float = 1.5, dt: float = 1e-3, *, n_cycles: int = 2,
                               cruise: float = 0.4, noise_std: float = 0.0, seed: int = 0,
                               oversample: int = 10) -> list[FrictionData]:
    """Phase 2-A acquisitions (sec. III-B): one data set of cyclic reversals per acceleration of
    ``accels`` (rad/s^2) at top speed ``vmax``, simulated with ``model`` (see
    :func:`simulate_friction`); data set ``i`` uses the noise seed ``(seed, i)``."""
    out = []
    for i, a in enumerate(accels):
        ss = int(np.random.SeedSequence([seed, i]).generate_state(1)[0])
        out.append(simulate_friction(model, reversal_knots(a, vmax, n_cycles, cruise), dt,
                                     noise_std=noise_std, seed=ss, oversample=oversample,
                                     label=f"reversals-a{a:g}", accel=float(a)))
    return out
