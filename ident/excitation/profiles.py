"""Piecewise-linear velocity profiles of the Indri & Trapani 2020 acquisitions (paper 001):
phase 2-A reversals (sec. III-B), the random / medium / low speed test profiles of Table I,
Figure 1's profile and the constant-speed runs of step 1 (sec. III-A), each as velocity knots
``(knots_t, knots_v)`` sampled by :func:`piecewise_linear_velocity`."""
from __future__ import annotations

import numpy as np

__all__ = ["piecewise_linear_velocity", "reversal_knots", "random_knots", "TEST_PROFILES",
           "test_profile_knots", "figure1_knots", "static_knots"]


def piecewise_linear_velocity(knots_t, knots_v, dt: float):
    """Sample a piecewise-linear velocity (knots (K,)) every ``dt``: ``(t, qd, qdd)``; qdd is
    the slope of the segment a sample lies in (the right one at a knot)."""
    kt = np.asarray(knots_t, float)
    kv = np.asarray(knots_v, float)
    if kt.ndim != 1 or kt.shape != kv.shape or kt.size < 2 or np.any(np.diff(kt) <= 0):
        raise ValueError("knots_t must be strictly increasing and match knots_v")
    n = int(np.floor((kt[-1] - kt[0]) / dt + 1e-9)) + 1
    t = kt[0] + dt * np.arange(n)
    qd = np.interp(t, kt, kv)
    slope = np.diff(kv) / np.diff(kt)
    seg = np.clip(np.searchsorted(kt, t, side="right") - 1, 0, slope.size - 1)
    return t, qd, slope[seg]


def reversal_knots(accel: float, vmax: float, n_cycles: int = 3, cruise: float = 0.5):
    """Knots of a cyclic motion between two points (phase 2-A): start at rest, reach +vmax,
    then ``n_cycles`` reversals +vmax -> -vmax -> +vmax at ``accel``, each speed held for
    ``cruise`` s, and back to rest."""
    if not (accel > 0 and vmax > 0 and cruise >= 0 and n_cycles >= 1):
        raise ValueError("reversal_knots: accel, vmax > 0, cruise >= 0, n_cycles >= 1")
    tr = vmax / accel
    kt, kv = [0.0, tr], [0.0, vmax]
    sign = 1.0
    for _ in range(2 * n_cycles):
        kt += [kt[-1] + cruise, kt[-1] + cruise + 2 * tr]
        kv += [sign * vmax, -sign * vmax]
        sign = -sign
    kt += [kt[-1] + cruise, kt[-1] + cruise + tr]
    kv += [sign * vmax, 0.0]
    return np.array(kt), np.array(kv)


def random_knots(duration: float, v_range, a_range, hold_range=(0.1, 0.6), seed: int = 0,
                 p_reverse: float = 0.6):
    """Knots of a random test profile (Tables I-II): successive target speeds drawn in
    ``v_range`` (magnitude, log-uniform) with a sign change with probability ``p_reverse``,
    reached at an acceleration drawn in ``a_range`` and held for a time in ``hold_range``."""
    rng = np.random.default_rng(seed)
    kt, kv = [0.0], [0.0]
    sign = 1.0
    while kt[-1] < duration:
        v = sign * np.exp(rng.uniform(np.log(v_range[0]), np.log(v_range[1])))
        a = np.exp(rng.uniform(np.log(a_range[0]), np.log(a_range[1])))
        kt.append(kt[-1] + abs(v - kv[-1]) / a + 1e-9)
        kv.append(v)
        kt.append(kt[-1] + rng.uniform(*hold_range))
        kv.append(v)
        if rng.uniform() < p_reverse:
            sign = -sign
    a = a_range[1]
    kt.append(kt[-1] + abs(kv[-1]) / a + 1e-9)
    kv.append(0.0)
    return np.array(kt), np.array(kv)


TEST_PROFILES = {
    # name: (speed range rad/s, acceleration range rad/s^2) at the scale of a ~2 rad/s joint
    "random": ((0.02, 2.0), (2.0, 40.0)),
    "medium": ((0.2, 1.0), (0.5, 8.0)),
    "low": ((0.005, 0.05), (0.05, 0.5)),
}


def test_profile_knots(kind: str, duration: float = 10.0, seed: int = 0):
    """Knots of the random / medium / low speed test profiles of Table I (see TEST_PROFILES)."""
    if kind not in TEST_PROFILES:
        raise ValueError(f"unknown test profile {kind!r}; choose from {sorted(TEST_PROFILES)}")
    v_range, a_range = TEST_PROFILES[kind]
    hold = (0.1, 0.6) if kind != "low" else (0.3, 1.5)
    return random_knots(duration, v_range, a_range, hold_range=hold, seed=seed)


test_profile_knots.__test__ = False          # not a pytest test


def figure1_knots(slow: float = 15.0, vmax: float = 1.5, accels=(2.0, 5.0, 10.0, 20.0, 40.0)):
    """Knots like the paper's Figure 1: ``slow`` seconds of very low, slowly growing speed
    reversals (the conditions of the dynamic identification), then reversals at increasing
    accelerations up to ``vmax``."""
    kt, kv = [0.0], [0.0]
    n_slow = 6
    for i in range(n_slow):
        v = 0.01 * (i + 1) * (1 if i % 2 == 0 else -1)
        kt += [kt[-1] + slow / n_slow * 0.5, kt[-1] + slow / n_slow]
        kv += [v, v]
    for a in accels:
        for s in (1.0, -1.0):
            kt += [kt[-1] + abs(s * vmax - kv[-1]) / a, kt[-1] + abs(s * vmax - kv[-1]) / a + 0.6]
            kv += [s * vmax, s * vmax]
    kt.append(kt[-1] + vmax / accels[-1])
    kv.append(0.0)
    return np.array(kt), np.array(kv)


def static_knots(speeds=None, accel: float = 20.0, settle_disp: float = 0.08,
                 min_hold: float = 0.3):
    """Knots of a step-1 acquisition (sec. III-A): constant-speed runs at many speeds, both
    directions, denser at low speed; each held long enough to cover ``settle_disp`` rad."""
    speeds = np.geomspace(0.01, 2.0, 12) if speeds is None else np.asarray(speeds, float)
    kt, kv = [0.0], [0.0]
    for v in speeds:
        for s in (1.0, -1.0):
            tgt = s * v
            kt.append(kt[-1] + abs(tgt - kv[-1]) / accel)
            kv.append(tgt)
            kt.append(kt[-1] + max(min_hold, 2.0 * settle_disp / v))
            kv.append(tgt)
    kt.append(kt[-1] + abs(kv[-1]) / accel)
    kv.append(0.0)
    return np.array(kt), np.array(kv)
