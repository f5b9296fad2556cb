"""Signals of one joint over a campaign, prepared for the gap diagnosis.

Everything the diagnosis needs is computed once per trial and concatenated over trials:
motor angle and its derivatives (Savitzky-Golay on the log clock), the torque left for the link
side after the motor side of eq. 2-4 is moved to the right (``y = tau - J qmdd - B qmd``), the
URDF's rigid-body torque for the trial's payload and rest pose, and, where link angles are
available (mocap), the transmission residual ``q_link - q_motor`` on the marker clock.

A joint with a declared ``stiffness`` K (drives.toml) is the two-mass flexible joint of thesis
eq. 2-1, 2-2: the rigid-body torque is taken on the LINK state ``q = qm - tau_s / K``, and the
friction acts on one side of the spring, the data decide which (:func:`build_joint_data`):
at the link (eq. 2-1; the motor equation holds no friction, so ``tau_s = y`` and the friction
columns see the link velocity) or at the motor (the link equation holds none, ``tau_s`` is the
link's rigid-body torque, the friction columns see the motor velocity). Without a declared
stiffness the joint is rigid (everything on the motor state).
"""
from __future__ import annotations

from dataclasses import dataclass, replace
from functools import cached_property
from types import SimpleNamespace

import numpy as np
from scipy.ndimage import gaussian_filter1d
from scipy.signal import bilinear, lfilter, lfilter_zi

from mocap.io.payload import payload_com

from ident.gap.candidates import DELAY_GRID_S, LOWPASS_GRID, ssign
from ident.gap.channels import _transmission_channel, motion_cycles, nominal_heldout_rms
from ident.signals.smoothing import differentiate


def savgol_derivatives(t: np.ndarray, x: np.ndarray, window_s: float = 0.1, polyorder: int = 3):
    """(x_smooth, xd, xdd) of a uniformly sampled signal by the one differentiator
    (:func:`ident.signals.smoothing.differentiate`) at the median sample step."""
    dt = float(np.median(np.diff(t)))
    return tuple(differentiate(x, dt, window_s, k, polyorder) for k in (0, 1, 2))


def standstill(t: np.ndarray, qd: np.ndarray, v_still: float = 2e-3, min_duration: float = 0.05) -> np.ndarray:
    """Samples where the joint rests (|qd| < v_still for at least ``min_duration``): friction is
    then static and indeterminate (anything up to breakaway balances the load), so the torque
    channel leaves them out. Zero crossings during motion are kept."""
    slow = np.abs(qd) < v_still
    if not slow.any():
        return slow
    dt = float(np.median(np.diff(t)))
    n_min = max(int(round(min_duration / dt)), 1)
    edges = np.diff(np.concatenate([[0], slow.astype(np.int8), [0]]))
    starts, ends = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)
    out = np.zeros_like(slow)
    for s0, e0 in zip(starts, ends):  # loop over rest intervals, not samples
        if e0 - s0 >= n_min:
            out[s0:e0] = True
    return out


def fill_nan(t: np.ndarray, x: np.ndarray) -> np.ndarray:
    ok = np.isfinite(x)
    if ok.all():
        return x
    if ok.sum() < 2:
        raise ValueError("too few valid samples")
    return np.interp(t, t[ok], x[ok])


@dataclass
class JointData:
    """Samples of one joint concatenated over its trials (log clock), plus per-trial metadata.

    What the gap diagnosis reads, built by :func:`build_joint_data`: the torque left for the
    link side of thesis eq. 2-4 [1]_ after the motor side is moved to the right, the URDF's
    rigid-body torque and, where link angles are available, the transmission residual (module
    docstring). Torque channel arrays have length N (log samples); transmission arrays length
    Nm (marker frames with a valid link angle). ``trial`` / ``trial_m`` index into ``trials``.

    Attributes
    ----------
    joint : int
        The joint, 1-based.
    trials : list
        The :class:`mocap.io.campaign.Trial` entries, manifest order.
    trial : numpy.ndarray
        (N,) trial index of every sample.
    t : numpy.ndarray
        (N,) campaign clock (s).
    t_rel : numpy.ndarray
        (N,) time since the trial's start (s).
    q, qd, qdd : numpy.ndarray
        (N,) joint angle (rad), velocity (rad/s), acceleration (rad/s^2): the motor state, or
        the link state on a declared flexible joint.
    y : numpy.ndarray
        (N,) ``tau - J qmdd - B qmd`` (N m), the torque left for the link side.
    tau_urdf : numpy.ndarray
        (N,) rigid-body torque from the URDF for the trial's payload and rest pose (N m).
    tau_grav : numpy.ndarray
        (N,) its gravity part (N m).
    urdf_regs : numpy.ndarray
        (N, k) the nominal's per-fold corrections: ``[qdd, sin q, cos q]`` (single joint);
        ``[qdd, g_j(q), 1, coupled motors]`` on a record against the URDF, ``[qdd, 1, coupled
        motors]`` against the rigid body identified on every joint (:func:`build_joint_data_record`).
    load : numpy.ndarray
        (N,) payload (kg).
    vmax : float
        The joint's maximum velocity (rad/s).
    tau_max : float
        The joint's largest torque (N m).
    trial_m : numpy.ndarray
        (Nm,) trial index of every marker frame (transmission channel; may be empty).
    e : numpy.ndarray
        (Nm,) ``q_link - q_motor`` at marker times (rad).
    qd_m : numpy.ndarray
        (Nm,) velocity at marker times (rad/s).
    y_m : numpy.ndarray
        (Nm,) ``y`` at marker times (N m).
    t_m : numpy.ndarray
        (Nm,) marker times on the campaign clock (s).
    tau_m : numpy.ndarray
        (Nm,) rigid-body (transmitted) torque at marker times (N m).
    rep : numpy.ndarray
        Per-trial repetition number.
    group : numpy.ndarray
        Per-trial condition index (same load, speed, kind).
    fold : numpy.ndarray
        Per-trial held-out fold.
    deriv_window_s : float
        Savitzky-Golay window of the motor-angle derivatives (s).
    sgn_filtered : numpy.ndarray or None
        (N,) Coulomb direction through the derivative filter; None: the plain smoothed sign.
    sabs_filtered : numpy.ndarray or None
        (N,) ``|ssign(qd)|`` through the derivative filter (used with ``sgn_filtered``).
    q_hf : numpy.ndarray or None
        (N,) encoder reading minus its smoothed value (what feedback sees beyond it).
    friction_side : str
        Where the nominal's friction acts: ``"rigid"`` (no stiffness declared), ``"motor"``
        or ``"link"`` side of the declared spring.
    stiffness : float
        Declared transmission stiffness (drives.toml, N m/rad); 0: rigid.
    tau_m_friction : numpy.ndarray or None
        Link-side friction: the spring torque ``y`` at marker times.
    q_all : numpy.ndarray or None
        (N, n) every joint's angle (continuous multi-joint records: the configuration-space tests).
    delay_cols : numpy.ndarray or None
        (N, len(DELAY_GRID_S)) ``p(t - dt) - p(t)`` of the record's smooth torque model (records).
    lowpass_cols : numpy.ndarray or None
        (N, len(LOWPASS_GRID)) ``LP2(p) - p`` (records).
    nuisance_rows : numpy.ndarray or None
        (N, p) the joint's design rows of the rigid body identified on every joint at once
        (records; :meth:`ident.model.identified.PooledRigidBody.nuisance`).
    nuisance_gain : numpy.ndarray or None
        (p, p) that fit's weighted inverse Gram matrix ``M``: candidate columns are tested less
        ``A M A^T`` of them (:meth:`ident.gap.channels.Channel.prep_effect`).

    References
    ----------
    .. [1] PA10 thesis (seeds 002), eq. 2-1, 2-2, 2-4.
    """

    joint: int                      # 1-based
    trials: list                    # Trial entries (manifest order)
    trial: np.ndarray               # (N,) trial index
    t: np.ndarray                   # (N,) campaign clock, s
    t_rel: np.ndarray               # (N,) time since the trial's start, s
    q: np.ndarray
    qd: np.ndarray
    qdd: np.ndarray
    y: np.ndarray                   # tau - J qmdd - B qmd
    tau_urdf: np.ndarray            # rigid-body torque from the URDF (payload, rest pose)
    tau_grav: np.ndarray            # its gravity part
    urdf_regs: np.ndarray           # (N, k) the nominal's per-fold corrections (see the docstring)
    load: np.ndarray                # (N,) kg
    vmax: float                     # joint max velocity, rad/s
    tau_max: float
    # transmission channel (may be empty)
    trial_m: np.ndarray
    e: np.ndarray                   # q_link - q_motor at marker times
    qd_m: np.ndarray
    y_m: np.ndarray
    t_m: np.ndarray
    tau_m: np.ndarray               # rigid-body (transmitted) torque at marker times
    rep: np.ndarray                 # per-trial repetition number
    group: np.ndarray               # per-trial condition index (same load, speed, kind)
    fold: np.ndarray                # per-trial held-out fold
    deriv_window_s: float = 0.0     # Savitzky-Golay window of the motor-angle derivatives
    sgn_filtered: np.ndarray | None = None  # (N,) Coulomb direction through the derivative filter
    sabs_filtered: np.ndarray | None = None  # (N,) its magnitude |ssign(qd)| through the same filter
    q_hf: np.ndarray | None = None  # (N,) encoder reading minus its smoothed value (what feedback sees beyond it)
    friction_side: str = "rigid"   # "rigid" (no stiffness declared), "motor" or "link": where the
    #                                 nominal's friction acts on the declared flexible joint
    stiffness: float = 0.0          # declared transmission stiffness (drives.toml), N m/rad; 0 = rigid
    tau_m_friction: np.ndarray | None = None  # link-side friction: the spring torque y at marker times
    # continuous multi-joint records only (None elsewhere):
    q_all: np.ndarray | None = None         # (N, n) every joint's angle (configuration-space tests)
    delay_cols: np.ndarray | None = None    # (N, len(DELAY_GRID_S)) p(t - dt) - p(t), p the record's rigid-body fit
    lowpass_cols: np.ndarray | None = None  # (N, len(LOWPASS_GRID)) LP2(p)(t) - p(t)
    nuisance_rows: np.ndarray | None = None  # (N, p) design rows of the identified rigid body (pooled fit)
    nuisance_gain: np.ndarray | None = None  # (p, p) its weighted inverse Gram matrix (M: x - A M A^T x)

    @cached_property
    def sgn(self) -> np.ndarray:
        """Coulomb direction of every sample (many candidate columns use it): the smoothed sign
        of the velocity passed through the same Savitzky-Golay filter as the derivatives when the
        builder had the full-rate signal (``sgn_filtered``), else the plain smoothed sign."""
        if self.sgn_filtered is not None:
            return self.sgn_filtered
        return ssign(self.qd)

    @cached_property
    def sabs(self) -> np.ndarray:
        """Magnitude of the Coulomb direction, the even counterpart of :attr:`sgn`: ``|ssign(qd)|``
        passed through the derivative filter where :attr:`sgn` is (the filter of the magnitude,
        not the magnitude of the filtered direction: 1 at speed, a dip of the smoothed sign's
        width at a reversal), else the plain ``|ssign(qd)|``."""
        if self.sgn_filtered is not None and self.sabs_filtered is not None:
            return self.sabs_filtered
        return np.abs(ssign(self.qd))

    @property
    def n_trials(self) -> int:
        return len(self.trials)

    @property
    def has_transmission(self) -> bool:
        return self.e.size > 0

    def subset_mask(self, trial_ids) -> np.ndarray:
        return np.isin(self.trial, np.asarray(list(trial_ids), int))


def campaign_clock(logs: list) -> list[float]:
    """Offsets that put each trial on one campaign clock.

    If the logs' time ranges do not overlap (one controller clock, the manifest may list the
    trials in another order than they ran), the offsets are 0; otherwise each trial is placed after the previous one (manifest order).
    """
    starts = [float(lg.time[0]) for lg in logs]
    ends = [float(lg.time[-1]) for lg in logs]
    order = np.argsort(starts, kind="stable")
    s_sorted, e_sorted = np.asarray(starts)[order], np.asarray(ends)[order]
    if np.all(s_sorted[1:] >= e_sorted[:-1]):   # one clock, recordings in any manifest order
        return [0.0] * len(logs)
    offsets, clock = [], 0.0
    for s, e in zip(starts, ends):
        offsets.append(clock - s)
        clock += (e - s) + 1.0
    return offsets


@dataclass(frozen=True)
class JointLog:
    """What the gap diagnosis reads of one trial's robot log for one joint (:func:`joint_log`):
    a trial's few columns instead of the whole log, so that a joint's logs can be held while its
    data are built (:func:`build_joint_data` reads them once per derivative window).

    Attributes
    ----------
    time : numpy.ndarray
        (T,) sample times (s).
    qm : numpy.ndarray
        (T,) the joint's motor angle (rad; NaN where not logged).
    tau : numpy.ndarray
        (T,) the joint's torque (N m; NaN where not logged).
    rest : numpy.ndarray
        (n,) the rest pose of the other joints: each logged column's median (0 where the first
        sample is not logged), 0 for the joint itself (rad).
    """

    time: np.ndarray
    qm: np.ndarray
    tau: np.ndarray
    rest: np.ndarray


def joint_log(lg, joint: int) -> JointLog:
    """The :class:`JointLog` of ``joint`` (1-based) from a :class:`mocap.io.robotlog.RobotLog`
    (or a :class:`JointLog` of that joint, returned as it is)."""
    if isinstance(lg, JointLog):
        return lg
    j0 = joint - 1
    rest = np.where(np.isfinite(lg.qm[0]), np.nanmedian(lg.qm, axis=0), 0.0)
    rest[j0] = 0.0
    # copies: a view would keep the whole log's arrays alive
    return JointLog(lg.time.copy(), lg.qm[:, j0].copy(), lg.tau[:, j0].copy(), rest)


#: derivative windows tried when ``deriv_window_s`` is None (s)
DERIV_WINDOWS = (0.02, 0.04, 0.1)


def build_joint_data(joint: int, trials, logs, robot, angles=None, v_zero: float = 0.01,
                     max_rate_hz: float = 250.0, deriv_window_s: float | None = None) -> JointData:
    """Assemble the :class:`JointData` of one joint from a campaign's trials.

    The torque left for the link side is ``y = tau - J qmdd - B qmd`` (thesis eq. 2-4 [1]_
    with the motor side moved to the right). The Savitzky-Golay window of the motor-angle
    derivatives is ``deriv_window_s`` or, when None, chosen from the data [2]_: the window of
    :data:`DERIV_WINDOWS` whose nominal model has the least held-out torque RMS. (Short
    windows keep friction transients at reversals, which last tens of ms, out of ``J qdd``;
    long ones average encoder quantisation: which wins depends on the drive and the logger,
    not on the effect sought.) The Coulomb direction is chosen the same way: sampled, or
    through the derivative filter. On a joint with a declared stiffness (the flexible joint
    of thesis eq. 2-1, 2-2), the friction side (motor or link of the spring, see the module
    docstring) is chosen the same way, on the samples both sides keep; with friction at the
    link, the spring carries it in the transmission channel too when the torque channel or
    the deflection clearly says so (:data:`LINK_SPRING_MARGIN`,
    :data:`LINK_SPRING_DEFLECTION`).

    Parameters
    ----------
    joint : int
        The joint, 1-based; the trials move only that joint.
    trials : sequence of mocap.io.campaign.Trial
        The campaign's trials (manifest order).
    logs : sequence of mocap.io.robotlog.RobotLog or JointLog
        ``logs[i]`` is the robot log of ``trials[i]`` (or its :func:`joint_log` for ``joint``).
    robot : mocap.robot.Robot
        The robot (URDF and drives.toml): rigid-body dynamics, motor inertia and viscous
        coefficient, declared ``stiffness``.
    angles : dict or None, optional
        Trial id -> ``(t_marker, q_link)`` of the joint (mocap); None: torque channel only.
    v_zero : float, optional
        Torque-channel samples slower than this (rad/s) are left out (three times it on the
        link side of a declared spring); default 0.01.
    max_rate_hz : float, optional
        Samples beyond this rate are decimated (every k-th kept); default 250.
    deriv_window_s : float or None, optional
        Savitzky-Golay window of the derivatives (s); None (default): chosen from the data.

    Returns
    -------
    JointData
        The joint's samples, concatenated over the trials.

    References
    ----------
    .. [1] PA10 thesis (seeds 002), eq. 2-1, 2-2, 2-4.
    .. [2] jointlab gap diagnosis (docs/gap-diagnosis.md).
    """
    stiff = float(robot.drives[joint - 1].extra.get("stiffness", 0.0) or 0.0) > 0
    logs = [joint_log(lg, joint) for lg in logs]
    sides = {}
    for side in (("motor", "link") if stiff else ("rigid",)):
        best = None
        for w in (DERIV_WINDOWS if deriv_window_s is None else (deriv_window_s,)):
            d = _build_joint_data(joint, trials, logs, robot, angles, v_zero, max_rate_hz, w, side)
            # the Coulomb direction as sampled, or through the derivative filter: a torque computed
            # from the motion (inverse dynamics) carries the friction step itself, a feedback
            # controller's command does not (its rotor acceleration does); the data decide
            for variant in (d, replace(d, sgn_filtered=None)):
                rms = nominal_heldout_rms(variant)
                if best is None or rms < best[0]:
                    best = (rms, variant)
        sides[side] = best[1]
    if len(sides) == 1:
        return next(iter(sides.values()))
    # the declared flexible joint: friction at the motor or at the link side of the spring, the
    # held-out nominal RMS decides, on the samples every side keeps (each side leaves out its
    # own slow samples: compared on its own, the stricter one would win by that alone)
    keys = [_sample_keys(d) for d in sides.values()]
    common = keys[0]
    for k in keys[1:]:
        common = common[_member(common, k)] if _increasing(common) else np.intersect1d(common, k)
    scores = {side: nominal_heldout_rms(torque_subset(d, _member(k, common)))
              for (side, d), k in zip(sides.items(), keys)}
    side = min(scores, key=scores.get)
    d = sides[side]
    if side == "link" and d.tau_m_friction is not None and d.e.size:
        # friction at the link: the spring carries it too (the measured motor-side torque y is
        # the spring torque) when the torque channel clearly says so, or when the deflection
        # does (a large friction effect, e.g. a Stribeck hump, can hide the torque channel's
        # preference; its deflection then shows it)
        e_y = d.e + (d.tau_m_friction - d.tau_m) / d.stiffness
        if (scores["link"] < LINK_SPRING_MARGIN * scores["motor"]
                or _deflection_ss(d, e_y) < LINK_SPRING_DEFLECTION * _deflection_ss(d, d.e)):
            d = replace(d, e=e_y, tau_m=d.tau_m_friction)
    return replace(d, tau_m_friction=None)


def _deflection_ss(d: JointData, e: np.ndarray) -> float:
    """Residual sum of squares of a transmission target ``e`` after the transmission channel's
    nominal (:func:`ident.gap.diagnose._transmission_channel`)."""
    ch = _transmission_channel(d)
    y = ch.prep(e[:, None])[:, 0]
    X = ch.prep(ch.X0)
    r = y - X @ np.linalg.lstsq(X, y, rcond=None)[0]
    return float(r @ r)


#: the spring of the declared flexible joint carries the nominal friction (transmission channel)
#: only when friction at the link gives a held-out torque RMS below this fraction of friction at
#: the motor. Measured: jointlab's simulator (link-side friction) 0.35-0.54; the foreign world
#: (motor-side friction, a stiff joint where the torque channel hardly tells the sides apart)
#: 0.98-1.03. Carrying it on a mere RMS preference put the friction's deflection into the
#: foreign world's transmission nominal: effect-free campaigns read it as a clock offset.
LINK_SPRING_MARGIN = 0.9
#: ... or when the spring torque y leaves the deflection's residual variance below this fraction
#: of the link's rigid-body torque's (measured: a jointlab Stribeck campaign 0.92, whose torque
#: channel the hump masks; foreign campaigns, motor-side friction, 0.99-1.16)
LINK_SPRING_DEFLECTION = 0.95


def _increasing(a: np.ndarray) -> bool:
    return bool(np.all(a[1:] > a[:-1]))


def _member(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``np.isin(a, b)``, by binary search when ``b`` is strictly increasing (sample keys are)."""
    if b.size == 0 or not _increasing(b):
        return np.isin(a, b)
    i = np.minimum(np.searchsorted(b, a), b.size - 1)
    return b[i] == a


def _sample_keys(d: JointData) -> np.ndarray:
    """An integer key of each torque-channel sample (trial, time since its start in us)."""
    return d.trial.astype(np.int64) * 10 ** 12 + np.round(d.t_rel * 1e6).astype(np.int64)


def torque_subset(d: JointData, mask: np.ndarray) -> JointData:
    """``d`` with only the torque-channel samples ``mask`` (transmission arrays unchanged)."""
    sub = lambda x: None if x is None else x[mask]  # noqa: E731
    return replace(d, trial=d.trial[mask], t=d.t[mask], t_rel=d.t_rel[mask], q=d.q[mask], qd=d.qd[mask],
                   qdd=d.qdd[mask], y=d.y[mask], tau_urdf=d.tau_urdf[mask], tau_grav=d.tau_grav[mask],
                   urdf_regs=d.urdf_regs[mask], load=d.load[mask], sgn_filtered=sub(d.sgn_filtered),
                   sabs_filtered=sub(d.sabs_filtered), q_hf=sub(d.q_hf))


def _link_states(t, qm, q, qd, qdd, y, single: tuple, k_declared: float, friction_side: str, window_s: float):
    """The states of a declared flexible joint (thesis eq. 2-1, 2-2; ``single``: the joint's
    ``(I, a, b)`` of :meth:`mocap.robot.Robot.single_joint_dynamics`): the link angle is the
    motor angle less the spring's deflection, ``q = qm - tau_s / K``. Friction at the link: the
    motor equation holds no friction, so the spring torque is ``y`` itself and the friction
    states are the link's; at the motor side the spring carries the link's rigid-body torque
    (on the motor state: one fixed-point step). Returns (q, qd, qdd) for the friction and the
    link's (angle, acceleration); a rigid joint's are the motor's."""
    if k_declared > 0 and friction_side == "link":
        dq = savgol_derivatives(t, y / k_declared, window_s=window_s)
        q, qd, qdd = q - dq[0], qd - dq[1], qdd - dq[2]
        return q, qd, qdd, q, qdd
    if k_declared > 0:
        I_u, a_u, b_u = single
        tau_s = I_u * qdd + a_u * np.sin(q) + b_u * np.cos(q)
        ql, _, qldd = savgol_derivatives(t, qm - tau_s / k_declared, window_s=window_s)
        return q, qd, qdd, ql, qldd
    return q, qd, qdd, q, qdd


def _kept_samples(t: np.ndarray, qd: np.ndarray, vz: float, max_rate_hz: float) -> np.ndarray:
    """The torque channel's samples: moving faster than ``vz``, at most ``max_rate_hz`` (its
    information lies below the derivative filter's band, ~10 Hz: samples beyond only add cost,
    so every k-th one is kept)."""
    keep = ~standstill(t, qd) & (np.abs(qd) >= vz)
    step = max(int(np.floor(1.0 / max(max_rate_hz * float(np.median(np.diff(t))), 1e-12))), 1)
    if step > 1:
        thin = np.zeros_like(keep)
        thin[::step] = True
        keep &= thin
    return keep


def _marker_columns(cols: dict, i: int, tr, angles: tuple, off: float, t, qm, qd, y, tau_rb,
                    k_declared: float, friction_side: str) -> None:
    """Trial ``i``'s transmission-channel samples at its marker times into ``cols``: the measured
    link-motor deflection and the log's signals interpolated there (``angles``: the trial's
    ``(t_marker, q_link)``)."""
    tm, q_l = angles
    # marker time is on the robot clock unless the trial declares an offset (FORMAT.md)
    tm = tm + float(getattr(tr, "extra", {}).get("time_offset", 0.0))
    ok = np.isfinite(q_l) & (tm >= t[0]) & (tm <= t[-1])
    tm, q_l = tm[ok], q_l[ok]
    cols["trial_m"].append(np.full(tm.shape, i))
    qm_m = np.interp(tm, t, qm)
    # friction at the link: the motor equation holds none, so the spring torque is y
    # itself (eq. 2-2), friction and any friction effect included (a Stribeck hump at
    # the link deflects the spring too: with the smooth nominal friction in its place,
    # jointlab's simulator's Stribeck campaigns read as compliance). Its torque noise
    # over K is far below the marker noise (PA10 j5: 2e-5 against 1e-3 rad).
    tau_f = y if (k_declared > 0 and friction_side == "link") else tau_rb
    # the declared transmission stiffness (drives.toml ``stiffness``) is part of the
    # nominal model: its deflection q_link - q_motor = -tau / K is taken out below, with
    # the link's rigid-body torque as the spring torque, or y when the friction is
    # clearly at the link (build_joint_data). Not y on the motor side: there y carries
    # the friction the spring does not (measured on a foreign ind6 load_dependent
    # campaign: verdict time_offset with y)
    cols["dq_m"].append(q_l - qm_m)
    cols["tau_m"].append(np.interp(tm, t, tau_rb))
    cols["tau_mf"].append(np.interp(tm, t, tau_f))
    cols["qd_m"].append(np.interp(tm, t, qd))
    cols["y_m"].append(np.interp(tm, t, y))
    cols["t_m"].append(tm + off)


def _single_joint(cache: dict, robot, tr, j0: int, rest) -> tuple:
    """``(I, a, b)`` of joint ``j0`` alone at the other joints' rest angles with the trial's
    payload (:meth:`mocap.robot.Robot.single_joint_dynamics`), computed once per payload and rest."""
    p_com = payload_com(tr)
    key = (round(tr.load_kg, 9), tuple(np.round(rest, 4)), p_com)
    if key not in cache:
        rb = robot.with_payload(tr.load_kg, p_com) if tr.load_kg > 0 else robot
        cache[key] = rb.single_joint_dynamics(j0, rest)
    return cache[key]


def _conditions_and_folds(trials) -> tuple:
    """(repetition of each trial, its condition group (load, speed, kind), its held-out fold):
    leave-one-repetition-out when repetitions exist, else leave-one-trial-out."""
    reps = np.array([tr.repetition for tr in trials])
    conds = [(round(tr.load_kg, 6), round(tr.vmax_frac, 6), tr.kind) for tr in trials]
    uniq = {c: k for k, c in enumerate(dict.fromkeys(conds))}
    group = np.array([uniq[c] for c in conds])
    fold = reps.copy() if len(set(reps.tolist())) > 1 else np.arange(len(trials))
    return reps, group, fold


def _build_joint_data(joint: int, trials, logs, robot, angles=None, v_zero: float = 0.01,
                      max_rate_hz: float = 250.0, deriv_window_s: float = 0.04,
                      friction_side: str = "motor") -> JointData:
    """Assemble :class:`JointData` for ``joint`` (1-based) from trials moving only that joint.

    ``logs[i]`` is the :class:`JointLog` of ``trials[i]``; ``angles`` maps trial id -> (t_marker, q_link)
    of the joint (mocap), or is None. The payload ``load_kg`` is a point mass at the flange
    origin unless the trial carries the optional key ``payload_com = [x, y, z]`` (metres, flange
    frame; an extra manifest key, kept per FORMAT.md). Torque-channel samples slower than ``v_zero`` are left
    out: at a velocity zero crossing the Coulomb term switches by 2c within a sample or two, and
    no velocity estimate places that switch exactly, so those few samples would dominate every
    squared-error comparison without carrying information about any candidate effect.
    """
    j0 = joint - 1
    drive = robot.drives[j0]
    J, B = drive.motor_inertia, drive.motor_viscous
    k_declared = float(drive.extra.get("stiffness", 0.0) or 0.0)
    # friction at the link: the link velocity comes from the motor angle AND the torque, whose
    # noise its derivative carries (measured on the demo against the simulator's truth: error
    # RMS 0.006-0.010 rad/s, motor velocity 0.007-0.011), and the link sticks at a reversal
    # while the spring takes up the Coulomb step (up to 15 ms): samples slower than 3 v_zero
    # (about 3 sigma of that error) have no reliable friction direction and are left out
    vz = 3.0 * v_zero if (k_declared > 0 and friction_side == "link") else v_zero
    offsets = campaign_clock(logs)
    cols = {k: [] for k in ("trial", "t", "t_rel", "q", "qd", "qdd", "sgn", "sabs", "q_hf", "y", "tau_urdf",
                            "tau_grav", "regs", "load", "trial_m", "dq_m", "qd_m", "y_m", "t_m", "tau_m", "tau_mf")}
    cache = {}
    for i, (tr, lg, off) in enumerate(zip(trials, logs, offsets)):
        t = lg.time
        qm = fill_nan(t, lg.qm)
        tau = fill_nan(t, lg.tau)
        # short derivative window: friction transients at reversals last tens of ms, and a
        # longer window smears them into J qdd (measured on the foreign world: a 0.1 s window
        # hid two thirds of a Stribeck drop); at least 11 samples on slow logs
        window_s = max(deriv_window_s, 11 * float(np.median(np.diff(t))))
        q, qd, qdd = savgol_derivatives(t, qm, window_s=window_s)
        q_enc = q
        y = tau - J * qdd - B * qd          # motor side of eq. 2-2 moved to the right
        rest = lg.rest
        I_u, a_u, b_u = _single_joint(cache, robot, tr, j0, rest)
        # the declared flexible joint (thesis eq. 2-1, 2-2): the link angle is the motor angle
        # less the spring's deflection, q = qm - tau_s / K. Friction at the link (eq. 2-1):
        # the motor equation holds no friction, so the spring torque is y itself; friction at
        # the motor side of the spring: the link equation holds none, the spring carries the
        # link's rigid-body torque (URDF, evaluated on the motor state: one fixed-point step)
        q, qd, qdd, ql, qldd = _link_states(t, qm, q, qd, qdd, y, (I_u, a_u, b_u), k_declared, friction_side,
                                            window_s)
        # consistent filtering: J qdd is the filtered rotor acceleration, which at a reversal
        # smears the friction step that the controller's (smooth) command does not contain; the
        # Coulomb direction goes through the same filter, so J S[qm''] + c S[sgn] = S[u] ~ u
        # (measured on the foreign world: the nominal's error at |qd| < 0.1 rad/s halves)
        sgn_f = savgol_derivatives(t, ssign(qd), window_s=window_s)[0]
        sabs_f = savgol_derivatives(t, np.abs(ssign(qd)), window_s=window_s)[0]
        s, c = np.sin(ql), np.cos(ql)
        keep = _kept_samples(t, qd, vz, max_rate_hz)
        cols["trial"].append((np.full(t.shape, i))[keep])
        cols["t"].append((t + off)[keep])
        cols["t_rel"].append((t - t[0])[keep])
        cols["q"].append((q)[keep])
        cols["qd"].append((qd)[keep])
        cols["qdd"].append((qdd)[keep])
        cols["sgn"].append(sgn_f[keep])
        cols["sabs"].append(sabs_f[keep])
        cols["q_hf"].append((qm - q_enc)[keep])
        cols["y"].append((y)[keep])
        tau_rb = I_u * qldd + a_u * s + b_u * c      # link's rigid-body torque, on the link state
        cols["tau_urdf"].append(tau_rb[keep])
        cols["tau_grav"].append((a_u * s + b_u * c)[keep])
        cols["regs"].append((np.column_stack([qldd, s, c]))[keep])
        cols["load"].append((np.full(t.shape, tr.load_kg))[keep])
        if angles is not None and tr.id in angles:
            _marker_columns(cols, i, tr, angles[tr.id], off, t, qm, qd, y, tau_rb, k_declared, friction_side)
    cat = {k: (np.concatenate(v) if v else np.zeros((0, 3) if k == "regs" else 0)) for k, v in cols.items()}
    cat["e"] = cat["dq_m"] + (cat["tau_m"] / k_declared if k_declared else 0.0)
    reps, group, fold = _conditions_and_folds(trials)
    return JointData(joint=joint, trials=list(trials), trial=cat["trial"].astype(int), t=cat["t"],
                     t_rel=cat["t_rel"], q=cat["q"], qd=cat["qd"], qdd=cat["qdd"], y=cat["y"],
                     tau_urdf=cat["tau_urdf"], tau_grav=cat["tau_grav"], urdf_regs=cat["regs"], load=cat["load"],
                     vmax=float(drive.max_velocity), tau_max=float(drive.max_torque),
                     trial_m=cat["trial_m"].astype(int), e=cat["e"], qd_m=cat["qd_m"], y_m=cat["y_m"],
                     t_m=cat["t_m"], tau_m=cat["tau_m"], rep=reps, group=group, fold=fold,
                     deriv_window_s=float(deriv_window_s), sgn_filtered=cat["sgn"],
                     sabs_filtered=cat["sabs"],
                     q_hf=cat["q_hf"], friction_side=friction_side if k_declared > 0 else "rigid",
                     stiffness=k_declared,
                     tau_m_friction=cat["tau_mf"] if (k_declared > 0 and friction_side == "link") else None)


def coupled_motor_columns(joint: int, qd: np.ndarray, qdd: np.ndarray, coupling: np.ndarray | None) -> np.ndarray:
    """The coupled motors' terms in URDF joint ``joint``'s torque (FORMAT.md "Coupled joints";
    the model of :mod:`ident.model.rigidbody`): for every log coordinate ``k`` that drives several
    URDF joints (a row of ``C^-1`` with more than one non-zero) and reaches this joint
    (``(C^-T)_jk != 0``), ``(C^-T)_jk [sgn u_k, u_k, u''_k]`` with the motor velocity
    ``u = C^-1 qd``: Coulomb and viscous friction and inertia of that motor, amplitudes free.
    (N, 3 per such motor); none for an uncoupled robot."""
    n = qd.shape[1]
    if coupling is None or np.allclose(coupling, np.eye(n)):
        return np.zeros((qd.shape[0], 0))
    Ci = np.linalg.inv(coupling)
    CiT = Ci.T
    u, udd = qd @ Ci.T, qdd @ Ci.T
    cols = [CiT[joint - 1, k] * np.column_stack([ssign(u[:, k]), u[:, k], udd[:, k]])
            for k in range(n) if np.sum(np.abs(Ci[k]) > 1e-12) > 1 and abs(CiT[joint - 1, k]) > 1e-12]
    return np.column_stack(cols) if cols else np.zeros((qd.shape[0], 0))


#: most held-out folds of a continuous record: beyond this many motion cycles, the folds are
#: this many groups of consecutive whole cycles (the test's blocks stay the cycles)
MAX_RECORD_FOLDS = 20
#: most samples per joint of a continuous record that the diagnosis keeps (evenly thinned beyond)
MAX_RECORD_SAMPLES = 40000


def build_joint_data_record(joint: int, t: np.ndarray, q: np.ndarray, qd: np.ndarray, qdd: np.ndarray,
                            tau: np.ndarray, robot, armature=None, n_segments: int | None = None,
                            v_zero: float = 0.02, coupling: np.ndarray | None = None,
                            tau_fixed: np.ndarray | None = None, signals: bool = False,
                            nuisance=None, gravity: np.ndarray | None = None) -> JointData:
    """:class:`JointData` for one joint of a continuous record in which several joints move
    together and nothing is repeated (e.g. an industrial controller's log).

    The rigid-body torque is pinocchio's inverse dynamics of the whole arm; the nominal's
    corrections are ``[qdd_j, g_j(q), 1]`` (armature, gravity scale, offset) instead of the
    single-joint ``[qdd, sin q, cos q]``. The exchangeable units of the randomisation test are
    always the joint's motion cycles (from one velocity reversal to the next but one, of the
    samples the diagnosis keeps: the blocks :func:`ident.gap.diagnose._motion_blocks` finds),
    chosen from the data so that the verdict does not hang on a free segment count. The held-out
    folds are the cycles too (``n_segments`` None) or ``n_segments`` groups of consecutive whole
    cycles (each cycle goes to the equal-time segment that holds its first sample; empty
    segments are dropped): a segment boundary never cuts a cycle into two test blocks (measured
    on the TX40 record before: 10, 20 or 40 equal segments cut its 3-7 cycles per joint into
    11-40 blocks and turned `none` into `load_dependent` on joint 3 (10) and `nonlinear_viscous`
    on joints 1 and 2 (20, 40); ``benchmarks/segmentation.py``). Torque channel only.

    ``tau_fixed`` (T,): the rigid-body torque the nominal's corrections correct, default the
    URDF's without payload; :func:`ident.model.multijoint.diagnose_records` passes the rigid body
    identified on every joint of every record (:mod:`ident.model.identified`: the arm's inertial
    parameters and a payload's). ``signals``: the record's rigid-body fit ``p`` (least squares)
    also gives the torque-channel time-offset columns ``p(t - dt) - p(t)``
    (:data:`ident.gap.candidates.DELAY_GRID_S`) and the low-pass columns ``LP2(p) - p``
    (:data:`ident.gap.candidates.LOWPASS_GRID`), and every joint's angle is kept (``q_all``) for
    the configuration-space tests. ``nuisance``: ``rows -> (A, M)`` (e.g.
    :meth:`ident.model.identified.PooledRigidBody.nuisance`), the pooled fit's design rows and
    weighted inverse Gram matrix at the kept samples: every candidate column is then tested less
    what that fit would absorb of it (:meth:`ident.gap.channels.Channel.prep`). ``gravity``: the
    record's (T, n) gravity torque ``robot.gravity_torque(q)`` when the caller has it (one
    computation for every joint of the record).
    """
    j0 = joint - 1
    arm = 0.0 if armature is None else float(np.asarray(armature)[j0])
    tau_rb = robot.rnea(q, qd, qdd)[:, j0] if tau_fixed is None else np.asarray(tau_fixed, float)
    grav = (robot.gravity_torque(q) if gravity is None else np.asarray(gravity, float))[:, j0]
    y = tau[:, j0] - arm * qdd[:, j0]
    keep = ~standstill(t, qd[:, j0]) & (np.abs(qd[:, j0]) >= v_zero)
    if keep.sum() > MAX_RECORD_SAMPLES:
        # an hour-long record: every k-th kept sample (the test's power is far beyond its need;
        # the cost of every candidate's Gram matrices grows with the samples)
        idx = np.flatnonzero(keep)
        keep = np.zeros_like(keep)
        keep[idx[::int(np.ceil(idx.size / MAX_RECORD_SAMPLES))]] = True
    seg = np.zeros(t.shape[0], int)
    if keep.any():
        cyc = motion_cycles(qd[keep, j0], v_zero)
        if n_segments is None and int(cyc.max()) + 1 > MAX_RECORD_FOLDS:
            n_segments = MAX_RECORD_FOLDS   # a long record: folds of whole cycles, not one per cycle
        if n_segments is not None:
            piece = np.minimum((np.flatnonzero(keep) * n_segments) // t.shape[0], n_segments - 1)
            first = np.r_[True, cyc[1:] != cyc[:-1]]
            cyc = np.unique(piece[first], return_inverse=True)[1][cyc]
        seg[keep] = cyc
    n_segments = int(seg.max()) + 1
    trials = [SimpleNamespace(id=f"segment-{k + 1}", joints=(joint,), load_kg=0.0, vmax_frac=1.0,
                              repetition=k + 1, kind="excitation", extra={}) for k in range(n_segments)]
    k = keep
    drive = robot.drives[j0]
    empty = np.zeros(0)
    coupled = coupled_motor_columns(joint, qd, qdd, coupling)
    extra = {}
    # the corrections the nominal fits per fold: armature, offset (and the coupled motors'); a
    # gravity scale only against the URDF's own rigid body: with the rigid body identified on every
    # joint at once its gravity parameters are fitted already, and a per-fold scale of them
    # extrapolates on a record whose folds cover different postures (the real TIAGo record's
    # joint 2: held-out 2.30 N m with it, 0.47 without; `fit` 0.235)
    regs = (np.column_stack([qdd[k, j0], grav[k], np.ones(k.sum()), coupled[k]]) if tau_fixed is None else
            np.column_stack([qdd[k, j0], np.ones(k.sum()), coupled[k]]))
    if signals:
        extra = _record_signal_columns(t, k, y - tau_rb, qd[:, j0], np.column_stack(
            [qdd[:, j0], grav, np.ones(t.shape[0]), coupled]), tau_rb)
        extra["q_all"] = q[k]
    if nuisance is not None:
        nz = nuisance(np.flatnonzero(k))
        if nz is not None:
            extra["nuisance_rows"], extra["nuisance_gain"] = nz
    return JointData(
        joint=joint, trials=trials, trial=seg[k].astype(int), t=t[k], t_rel=(t - t[0])[k],
        q=q[k, j0], qd=qd[k, j0], qdd=qdd[k, j0], y=y[k], tau_urdf=tau_rb[k], tau_grav=grav[k],
        urdf_regs=regs, load=np.zeros(k.sum()), **extra,
        vmax=float(drive.max_velocity) if np.isfinite(drive.max_velocity) else float(np.abs(qd[:, j0]).max()),
        tau_max=float(drive.max_torque), trial_m=np.zeros(0, int), e=empty, qd_m=empty, y_m=empty,
        t_m=empty, tau_m=empty, rep=np.arange(1, n_segments + 1), group=np.zeros(n_segments, int),
        fold=np.arange(1, n_segments + 1))


def _shifted_rows(Z: np.ndarray, s: float, rows: np.ndarray) -> np.ndarray:
    """Rows ``rows`` of ``Z`` (T, ...) delayed by ``s`` samples (fractional: linear interpolation
    between the two neighbouring whole shifts; the first samples repeat the first row)."""
    i0 = int(np.floor(s))
    w = s - i0
    a = Z[np.clip(rows - i0, 0, Z.shape[0] - 1)]
    if w == 0:
        return a
    return (1 - w) * a + w * Z[np.clip(rows - i0 - 1, 0, Z.shape[0] - 1)]


#: most samples of the profile over the delay grid (evenly thinned beyond)
DELAY_PROFILE_SAMPLES = 8000
#: widths (s, Gaussian sigma, zero phase) of the Coulomb step in the record's torque model ``p``: a
#: feedback controller's command crosses a friction reversal over its own response time, and a
#: step sharper than the logged one makes a delay's column a pulse too narrow and too high
COULOMB_WIDTHS_S = (0.0, 0.002, 0.005, 0.010, 0.020)


def _record_signal_columns(t: np.ndarray, keep: np.ndarray, target: np.ndarray, qd: np.ndarray,
                           X: np.ndarray, tau_rb: np.ndarray) -> dict:
    """The time-offset and low-pass columns of one joint of a continuous record.

    ``p`` is the record's rigid-body + Coulomb/viscous model of the logged torque on the states
    at ``t`` (``[tau_rb, X, sgn qd, qd]``, least squares on the kept samples ``keep``), fitted
    with the states delayed by the grid's delay that fits best and the Coulomb step smoothed
    (zero phase) by the width that fits best (a profile over :data:`COULOMB_WIDTHS_S` x
    :data:`ident.gap.candidates.DELAY_GRID_S` and 0, on at most :data:`DELAY_PROFILE_SAMPLES`
    samples): a torque logged late is then modelled by the torque of the states at its true time,
    smooth, without the torque noise. A logged torque late by ``dt`` is ``p(t - dt)``: the
    column ``p(t - dt) - p(t)`` has amplitude 1 at the true ``dt`` (the candidate of
    ``time_offset`` in the torque channel). A second-order low-pass of the logged torque (cut-off
    ``fc``, damping ``zeta``; bilinear with pre-warping) gives ``LP2(p) - p``: the same as a
    delay at low frequency, with its own attenuation near the cut-off (a term outside the
    vocabulary, tested against the delay)."""
    y = target + tau_rb
    dt = float(np.median(np.diff(t))) if t.size > 1 else 1e-3
    rows = np.flatnonzero(keep)
    rows = rows[::max(1, rows.size // DELAY_PROFILE_SAMPLES)]
    best = (np.inf, 0.0, None)
    sg = ssign(qd)
    yr = y[rows]
    for width in COULOMB_WIDTHS_S:   # profile over the Coulomb step's width and the delay grid
        Z = np.column_stack([tau_rb, X, gaussian_filter1d(sg, width / dt, mode="nearest") if width else sg, qd])
        sc = np.sqrt(np.mean(Z[keep] ** 2, axis=0))
        Z = Z / np.where(sc > 0, sc, 1.0)
        for dl in (0.0,) + DELAY_GRID_S:
            Zs = _shifted_rows(Z, dl / dt, rows)
            G, b = Zs.T @ Zs, Zs.T @ yr
            th = np.linalg.lstsq(G, b, rcond=None)[0]
            sse = float(yr @ yr - 2 * th @ b + th @ G @ th)
            if sse < best[0]:
                best = (sse, dl, Z)
    Z = best[2]
    th = np.linalg.lstsq(_shifted_rows(Z, best[1] / dt, np.flatnonzero(keep)), y[keep], rcond=None)[0]
    p = Z @ th
    tk = t[keep]
    pk = p[keep]
    dcols = np.column_stack([np.interp(tk - dl, t, p) - pk for dl in DELAY_GRID_S])
    fs = 1.0 / dt
    lcols = []
    for fc, zeta in LOWPASS_GRID:
        if fc >= 0.4 * fs:
            lcols.append(np.zeros(tk.shape[0]))
            continue
        w = 2 * fs * np.tan(np.pi * fc / fs)       # pre-warped
        b, a = bilinear([w * w], [1.0, 2 * zeta * w, w * w], fs)
        lp = lfilter(b, a, p, zi=lfilter_zi(b, a) * p[0])[0]
        lcols.append(lp[keep] - pk)
    return {"delay_cols": dcols, "lowpass_cols": np.column_stack(lcols)}


def concat_joint_data(parts: list, offsets=None) -> JointData:
    """One :class:`JointData` from the records ``parts`` of one joint (torque channel, e.g. from
    :func:`build_joint_data_record` on separate records): their blocks and held-out folds side by
    side (never across records), times shifted by ``offsets`` onto one clock
    (:func:`campaign_clock`)."""
    if len(parts) == 1:
        return parts[0]
    offsets = [0.0] * len(parts) if offsets is None else list(offsets)
    base = np.cumsum([0] + [p.n_trials for p in parts])
    fbase = np.cumsum([0] + [int(p.fold.max()) if p.fold.size else 0 for p in parts])
    trials = [SimpleNamespace(**{**vars(tr), "repetition": int(base[k]) + i + 1})
              for k, p in enumerate(parts) for i, tr in enumerate(p.trials)]
    cat = lambda f: np.concatenate([getattr(p, f) for p in parts])  # noqa: E731
    empty = np.zeros(0)
    return JointData(
        joint=parts[0].joint, trials=trials,
        trial=np.concatenate([p.trial + base[k] for k, p in enumerate(parts)]).astype(int),
        t=np.concatenate([p.t + off for p, off in zip(parts, offsets)]), t_rel=cat("t_rel"),
        q=cat("q"), qd=cat("qd"), qdd=cat("qdd"), y=cat("y"), tau_urdf=cat("tau_urdf"),
        tau_grav=cat("tau_grav"), urdf_regs=cat("urdf_regs"), load=cat("load"),
        vmax=max(p.vmax for p in parts), tau_max=parts[0].tau_max, trial_m=np.zeros(0, int), e=empty,
        qd_m=empty, y_m=empty, t_m=empty, tau_m=empty, rep=np.arange(1, int(base[-1]) + 1),
        group=np.zeros(int(base[-1]), int),
        fold=np.concatenate([p.fold + fbase[k] for k, p in enumerate(parts)]),
        **{f: cat(f) for f in ("q_all", "delay_cols", "lowpass_cols", "nuisance_rows")
           if all(getattr(p, f) is not None for p in parts)},
        nuisance_gain=parts[0].nuisance_gain if all(p.nuisance_rows is not None for p in parts) else None)
