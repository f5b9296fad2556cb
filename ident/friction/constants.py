"""The named thresholds of friction at and near standstill, one definition each.

``REST_FRAC``
    A sample is *at rest* when its speed is below ``REST_FRAC`` times the peak speed of its
    record (dimensionless). At standstill friction is static (it holds whatever the other
    torques leave), which the kinetic laws of :mod:`ident.friction.laws` do not describe
    (``sign(0) = 0``), and a smoothed speed's sign there is noise; the one-link fit
    (:class:`ident.model.onelink.OneLinkIdentifier`), the link-state estimator and the trimming
    of a trial's rests (:class:`ident.signals.smoothing.FourierSmoother`) leave such samples out.

``SIGN_WIDTH``
    The velocity scale (rad/s) of the smooth sign :func:`ident.friction.laws.smooth_sign`,
    ``tanh(v / SIGN_WIDTH)``: the Coulomb term of the several-joint simulator
    (:func:`ident.sim.plant.simulate_multi`), which linearises its friction implicitly and
    needs a finite slope at zero speed. It equals ``1 / Kv`` of Indri & Trapani's smooth sign
    ``S0`` (eq. 2, ``Kv = 1000``), the arctangent form of the same regularisation.

Data-relative uses (a smooth sign whose width is the rest speed of a record) pass
``REST_FRAC * peak`` as the width.
"""
from __future__ import annotations

#: speed below which a sample is at rest, as a fraction of the record's peak speed
REST_FRAC = 0.01

#: velocity scale of the smooth sign tanh(v / SIGN_WIDTH), rad/s
SIGN_WIDTH = 1e-3

#: Indri & Trapani's Kv (eq. 2), the smooth sign S0's gain, 1/(rad/s)
KV_DEFAULT = 1000.0

__all__ = ["REST_FRAC", "SIGN_WIDTH", "KV_DEFAULT"]
