"""A robot log as a continuous multi-joint record in URDF joint coordinates, ready for
identification: real-log preprocessing (repeated rows, irregular time stamps, resampling,
derivatives), coupled joints (FORMAT.md "Coupled joints") and the braked-joint checks.

Every choice is reported in :attr:`MultiJointRecord.preprocessing` (and from there in the fit
and diagnosis reports):

* **repeated rows** (every signal equal to the previous row's under a new time stamp) are stale
  samples: they are dropped, so that the state is not held while time runs on (that would put
  zero velocity and spikes of acceleration into the data);
* **irregular time stamps**: the kept angles are interpolated linearly onto a uniform grid at
  their median step (``resample``) for differentiation, and the smoothed states are
  interpolated back to the logged time stamps; torques are used as logged (interpolating them
  would average their noise and make residuals look smaller than they are). A log already
  uniform within 1 % is left as it is;
* **derivatives**: ``savgol`` differentiates the (resampled) angles with a cubic
  Savitzky-Golay filter of ``window_s`` (``auto``: per joint, :func:`auto_windows`); ``logged`` takes the controller's ``qd_<j>`` for the
  velocity and differentiates it (same filter) for the acceleration. The RMS difference between
  the logged and the differentiated velocity is reported either way;
* **decimation** of long records (``decimate``; ``auto``: records of more than
  :data:`AUTO_DECIMATE_SAMPLES` samples, docs/long-records.md): the uniform angles, torques and
  logged velocities pass a zero-phase anti-alias low-pass FIR and keep every ``D``-th sample.
  The cut-off is chosen from the friction bandwidth (:func:`friction_bandwidth`):
  ``f_c = max(K_HARMONICS * f_v, F_C_MIN)`` where ``f_v`` holds 99 % of the power of the moving
  joints' velocities, so that the first ten harmonics of a Coulomb step ``sgn(qd)`` pass; the
  new rate is at least ``2.5 f_c`` (the filter's stop band starts at the new Nyquist
  frequency). The record then keeps the decimated uniform grid;
* **coupling**: ``q_urdf = C q_log``, ``tau_urdf = C^-T tau_log`` (FORMAT.md); the log
  coordinates are kept (``qd_log``, ``qdd_log``) for friction that acts on motor coordinates.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.signal import firwin, kaiserord, resample_poly, welch

from mocap.io.errors import InputError

from ident.settings import AnyOf, Flag, Interval, OneOf, Settings
from ident.signals.smoothing import differentiate

BRAKED_TOL_RAD = 5e-3          # peak-to-peak motion above which a braked joint "moves"
DERIVATIVES = ("savgol", "logged")
#: ``decimate = auto`` decimates records longer than this many samples (200 s at 1 kHz)
AUTO_DECIMATE_SAMPLES = 200_000
#: the anti-alias cut-off passes this many harmonics of the velocity bandwidth: a Coulomb step
#: ``sgn(qd)`` of a periodic motion keeps about 96 % of its power in its first ten harmonics
K_HARMONICS = 10.0
#: the lowest anti-alias cut-off, Hz: a slow motion still keeps friction transients of 50 ms
F_C_MIN = 10.0
#: the new rate is at least this many times the cut-off (Nyquist 1.25 f_c: room for the filter's
#: transition band)
RATE_PER_CUTOFF = 2.5
#: stop-band attenuation of the anti-alias filter, dB
STOPBAND_DB = 60.0


@dataclass(frozen=True)
class RecordSettings(Settings):
    """Preprocessing of a record: ``derivatives`` ``savgol`` or ``logged`` (see the module
    docstring); Savitzky-Golay ``window_s``; ``resample``: ``auto`` (when irregular) or
    ``never``; ``drop_repeated``; ``braked_tol``: rad, peak to peak; ``decimate``: ``auto`` (records
    longer than :data:`AUTO_DECIMATE_SAMPLES`), ``never``, or a rate in Hz (the cut-off then
    ``rate / 2.5``). :attr:`constraints` is checked at construction (:mod:`ident.settings`)."""

    derivatives: str = "savgol"
    window_s: float | str = "auto"
    resample: str = "auto"
    drop_repeated: bool = True
    braked_tol: float = BRAKED_TOL_RAD
    decimate: str | float = "auto"

    #: field -> (option, constraint), checked at construction
    constraints = {
        "derivatives": ("--derivatives", OneOf(*DERIVATIVES)),
        "window_s": ("--window", AnyOf(OneOf("auto"), Interval(0, closed="right", note="s"))),
        "resample": ("resample", OneOf("auto", "never")),
        "drop_repeated": ("drop_repeated", Flag()),
        "braked_tol": ("braked_tol", Interval(0, closed="right", note="rad")),
        "decimate": ("decimate", AnyOf(OneOf("auto", "never"), Interval(0, closed="right", note="Hz"))),
    }


@dataclass(frozen=True, eq=False)
class MultiJointRecord:
    """Uniformly sampled states and torques of all joints, URDF coordinates, time first."""

    trial_id: str
    t: np.ndarray               # (T,)
    q: np.ndarray               # (T, n) URDF joint angles
    qd: np.ndarray
    qdd: np.ndarray
    tau: np.ndarray             # (T, n) URDF joint torques
    coupling: np.ndarray        # (n, n) C: q_urdf = C q_log
    moving: tuple               # 1-based joints the trial declares moving
    preprocessing: dict = field(default_factory=dict)
    unlogged: tuple = ()        # 1-based moving joints whose torque was not logged (tau NaN)

    @property
    def n(self) -> int:
        return int(self.q.shape[1])

    @property
    def dt(self) -> float:
        """Median sample step (the record keeps the logged time stamps, possibly irregular)."""
        return float(np.median(np.diff(self.t)))

    @property
    def coupled(self) -> bool:
        return not np.allclose(self.coupling, np.eye(self.n))

    @property
    def qd_log(self) -> np.ndarray:
        return np.linalg.solve(self.coupling, self.qd.T).T

    @property
    def qdd_log(self) -> np.ndarray:
        return np.linalg.solve(self.coupling, self.qdd.T).T

    def gap_inputs(self) -> dict:
        """Keyword arguments of ``ident.gap.data.build_joint_data_record`` (all but ``joint``,
        ``robot`` and the settings): the record's ``t, q, qd, qdd, tau`` in URDF coordinates."""
        return {"t": self.t, "q": self.q, "qd": self.qd, "qdd": self.qdd, "tau": self.tau,
                "coupling": self.coupling}


# ---------------------------------------------------------------------------------------------
def coupling_matrix(campaign, n: int) -> np.ndarray:
    """``[robot] coupling`` of the campaign (n x n, default identity), validated."""
    C = campaign.coupling
    if C is None:
        return np.eye(n)
    try:
        C = np.array(C, dtype=float)
    except (TypeError, ValueError):
        raise InputError("[robot] coupling must be an n x n list of numbers", path=campaign.manifest,
                         label="coupling") from None
    if C.shape != (n, n):
        raise InputError(f"[robot] coupling is {C.shape[0] if C.ndim else 0} x "
                         f"{C.shape[1] if C.ndim > 1 else 0}, the robot has {n} joints",
                         path=campaign.manifest, label="coupling")
    if abs(np.linalg.det(C)) < 1e-9:
        raise InputError("[robot] coupling is singular", path=campaign.manifest, label="coupling")
    return C


def check_braked(trial, q: np.ndarray, tol: float = BRAKED_TOL_RAD, path=None) -> dict:
    """Peak-to-peak motion of every joint (URDF coordinates, rad); an error naming the joint and
    how far it moved when a joint the trial does not list moves more than ``tol``."""
    q = np.asarray(q, float)
    lo, hi = np.nanpercentile(q, [0.1, 99.9], axis=0)
    p2p = hi - lo
    braked = [j for j in range(1, q.shape[1] + 1) if j not in trial.joints]
    bad = [j for j in braked if p2p[j - 1] > tol]
    if bad:
        j = max(bad, key=lambda k: p2p[k - 1])
        what = ("a multi-joint motion declared single-joint" if len(trial.joints) == 1
                else "a joint declared braked moves")
        raise InputError(f"trial {trial.id!r}: joint {j} is not in joints = {list(trial.joints)} but "
                         f"moves {p2p[j - 1]:.4g} rad ({np.degrees(p2p[j - 1]):.3g} deg) peak to peak "
                         f"({what}; {len(bad)} such joint(s): {bad}); list every moving joint",
                         path=path, label=trial.id)
    return {str(j): float(p2p[j - 1]) for j in range(1, q.shape[1] + 1)}


WINDOWS_S = (0.01, 0.015, 0.02, 0.03, 0.05, 0.07, 0.1, 0.15, 0.2)


def auto_windows(x: np.ndarray, dt: float, ratio: float = 2.0) -> np.ndarray:
    """Per column of ``x`` (uniform samples), the longest Savitzky-Golay window of
    :data:`WINDOWS_S` whose smoothing residual ``rms(x - smooth(x))`` stays within ``ratio``
    times the residual of the shortest window. The residual of a noise-only band saturates at
    the noise level (quantisation, jitter), while a window that starts to bend the motion makes
    it grow like the window's fourth power: longer windows give less noisy accelerations until
    that knee. Columns that do not move get the shortest window."""
    T = x.shape[0]
    cand = [w for w in WINDOWS_S if 5 <= (int(round(w / dt)) | 1) < T]
    if not cand:
        return np.full(x.shape[1], WINDOWS_S[0])
    r0 = np.sqrt(np.mean((x - differentiate(x, dt, cand[0], 0)) ** 2, axis=0))
    out = np.full(x.shape[1], cand[0])
    alive = r0 > 0
    for w in cand[1:]:                        # a handful of candidate windows
        r = np.sqrt(np.mean((x - differentiate(x, dt, w, 0)) ** 2, axis=0))
        alive &= r <= ratio * r0
        out = np.where(alive, w, out)
    return out


def _savgol_cols(x: np.ndarray, dt: float, windows: np.ndarray, deriv: int) -> np.ndarray:
    """Savitzky-Golay per column with its own window (columns sharing a window go together)."""
    out = np.empty_like(x)
    for w in np.unique(windows):
        cols = np.flatnonzero(windows == w)
        out[:, cols] = differentiate(x[:, cols], dt, float(w), deriv)
    return out


def prepare_record(log, trial, n: int, coupling=None, settings: RecordSettings | None = None,
                   check: bool = True) -> MultiJointRecord:
    """A :class:`MultiJointRecord` from a :class:`mocap.io.robotlog.RobotLog` (see the module
    docstring for each step). ``check``: braked joints must stay still (:func:`check_braked`)."""
    st = settings or RecordSettings()
    C = np.eye(n) if coupling is None else np.asarray(coupling, float)
    stats = log.sampling()
    rep = {"sampling": stats.to_dict(), "settings": {
        "derivatives": st.derivatives, "window_s": st.window_s, "resample": st.resample,
        "drop_repeated": st.drop_repeated}}
    keep = ~log.repeated_rows() if st.drop_repeated else np.ones(log.n_samples, bool)
    if keep.all():                      # no copy of a long log
        t, qm, tau, qd_log = log.time, log.qm, log.tau, log.qd
    else:
        t = log.time[keep]
        qm, tau = log.qm[keep], log.tau[keep]
        qd_log = log.qd[keep] if log.qd is not None else None
    unlogged = tuple(getattr(trial, "unlogged_torque", ()))      # FORMAT.md: tau ignored
    missing = [j + 1 for j in range(n) if np.all(np.isnan(qm[:, j]))
               or (np.all(np.isnan(tau[:, j])) and j + 1 not in unlogged)]
    if missing:
        raise InputError(f"the log has no qm_{missing[0]}/tau_{missing[0]} samples (a multi-joint "
                         "record needs every joint's angle and torque)", path=log.source,
                         label=f"qm_{missing[0]}")
    steps = []
    rep["dropped_repeated_rows"] = int((~keep).sum())
    if rep["dropped_repeated_rows"]:
        steps.append(f"dropped {rep['dropped_repeated_rows']} repeated rows")
    dtk = np.diff(t)
    dt = float(np.median(dtk))
    irregular = bool(np.any(np.abs(dtk - dt) > 0.01 * dt))
    t_keep = t
    sig = [qm, tau] + ([qd_log] if qd_log is not None else [])
    sig = [_interp_cols(t, t, x) for x in sig]          # fills NaN gaps only
    if irregular and st.resample == "auto":
        tu = t[0] + dt * np.arange(int(np.floor((t[-1] - t[0]) / dt + 1e-9)) + 1)
        grid = [_interp_cols(tu, t, x) for x in sig]
        steps.append(f"{t.size} rows at irregular steps ({dtk.min() * 1e3:.3g} .. "
                     f"{dtk.max() * 1e3:.3g} ms): angles resampled linearly onto a uniform "
                     f"{dt * 1e3:.4g} ms grid for differentiation, states interpolated back to the "
                     "logged time stamps; torques used as logged")
    else:
        tu, grid = t, sig
        if irregular:
            steps.append("irregular steps kept as they are (resample = never): derivatives "
                         "assume the median step")
    tau = sig[1]
    q_grid = grid[0]                    # the log is in URDF joints already (Campaign.read_log)
    has_qd = qd_log is not None
    back = (lambda x: x) if tu is t else (lambda x: _interp_cols(t_keep, tu, x))
    dec = _decimation(q_grid, dt, trial, n, st)
    rep["decimation"] = dec
    if dec["factor"] > 1:
        D = dec["factor"]
        taps = dec.pop("_taps")
        tau_grid = tau if tu is t else _interp_cols(tu, t, tau)
        grid = [_decimate(x, D, taps) for x in (grid[0], tau_grid) + tuple(grid[2:])]
        q_grid, tau = grid[0], grid[1]
        if has_qd:
            sig = [None, None, grid[2]]
        t_keep = tu = tu[::D]
        back = (lambda x: x)
        dt = dt * D
        steps.append(dec["text"])
    win = (auto_windows(q_grid, dt) if st.window_s == "auto"
           else np.full(n, float(st.window_s)))
    rep["window_s"] = {str(j + 1): float(win[j]) for j in range(n)}
    wtxt = ("per joint " + ", ".join(f"{w * 1e3:.3g}" for w in win) + " ms" + (
        " (auto: the longest window before the smoothing residual grows past twice the "
        "shortest window's)"
        if st.window_s == "auto" else ""))
    qs = back(_savgol_cols(q_grid, dt, win, 0))
    qd_sg = back(_savgol_cols(q_grid, dt, win, 1))
    if has_qd:
        qd_logged = sig[2]
        ok = np.isfinite(qd_logged)
        diff = np.where(ok, qd_logged - qd_sg, 0.0)
        rep["logged_vs_savgol_velocity_rms"] = {
            str(j + 1): float(np.sqrt(np.mean(diff[ok[:, j], j] ** 2))) if ok[:, j].any() else None
            for j in range(n)}
    if st.derivatives == "logged":
        if not has_qd or not np.isfinite(sig[2]).all():
            raise InputError("derivatives = logged needs a qd_<j> column for every joint",
                             path=log.source, label="qd_1")
        qd = sig[2]
        qdd = back(_savgol_cols(grid[2], dt, win, 1))
        steps.append(f"velocity: the logged qd_<j>; acceleration: cubic Savitzky-Golay derivative "
                     f"of it, windows {wtxt}")
    else:
        qd, qdd = qd_sg, back(_savgol_cols(q_grid, dt, win, 2))
        steps.append(f"velocity and acceleration: cubic Savitzky-Golay derivatives of the angles, "
                     f"windows {wtxt}")
    if not np.allclose(C, np.eye(n)):
        steps.append("coupled joints: q_urdf = C q_log, tau_urdf = C^-T tau_log ([robot] coupling, "
                     "applied when the log was read)")
    tau_u = tau
    rep["steps"] = steps
    rep["warnings"] = stats.warnings
    if check:
        rep["peak_to_peak_rad"] = check_braked(trial, qs, st.braked_tol, path=log.source)
    return MultiJointRecord(trial.id, t_keep, qs, qd, qdd, tau_u, C,
                            tuple(trial.joints), rep, unlogged)


def friction_bandwidth(q: np.ndarray, dt: float, joints) -> tuple[float, float]:
    """``(f_v, f_c)`` Hz: ``f_v`` the frequency below which 99 % of the power of the velocity
    ``diff(q_j) / dt`` lies (Welch periodogram), the largest over the 1-based ``joints``;
    ``f_c = max(K_HARMONICS f_v, F_C_MIN)`` the anti-alias cut-off that keeps the friction
    torque's band (the harmonics a Coulomb step ``sgn(qd)`` adds to the motion's)."""
    fs = 1.0 / dt
    f_v = 0.0
    for j in joints:
        v = np.diff(q[:, j - 1]) * fs
        f, P = welch(v, fs=fs, nperseg=min(v.size, 1 << 15), detrend=False)
        c = np.cumsum(P)
        if c[-1] > 0:
            f_v = max(f_v, float(f[min(np.searchsorted(c, 0.99 * c[-1]), f.size - 1)]))
    return f_v, max(K_HARMONICS * f_v, F_C_MIN)


def _decimation(q: np.ndarray, dt: float, trial, n: int, st: RecordSettings) -> dict:
    """The decimation of a uniform record (``factor`` 1: none) and its anti-alias FIR: a
    Kaiser-window low-pass (:data:`STOPBAND_DB`) passing ``f_c`` and stopping at the new Nyquist
    frequency; ``text`` says it for the report."""
    T, fs = q.shape[0], 1.0 / dt
    if st.decimate == "never" or (st.decimate == "auto" and T <= AUTO_DECIMATE_SAMPLES):
        why = "never" if st.decimate == "never" else f"{T} samples <= {AUTO_DECIMATE_SAMPLES}"
        return {"factor": 1, "reason": why}
    joints = [j for j in trial.joints if 1 <= j <= n] or list(range(1, n + 1))
    if st.decimate == "auto":
        f_v, f_c = friction_bandwidth(q, dt, joints)
        D = int(np.floor(fs / (RATE_PER_CUTOFF * f_c) * (1 + 1e-9)))   # time-stamp rounding
        how = (f"cut-off {f_c:.3g} Hz = max({K_HARMONICS:g} x the velocity bandwidth {f_v:.3g} Hz "
               f"(99 % of the moving joints' velocity power), {F_C_MIN:g} Hz)")
    else:
        f_v, f_c = None, float(st.decimate) / RATE_PER_CUTOFF
        D = int(np.floor(fs / float(st.decimate) * (1 + 1e-9)))
        how = f"cut-off {f_c:.3g} Hz (decimate = {float(st.decimate):g} Hz / {RATE_PER_CUTOFF:g})"
    if D < 2:
        return {"factor": 1, "reason": f"the log rate {fs:.4g} Hz is below {RATE_PER_CUTOFF:g} x the "
                f"cut-off {f_c:.3g} Hz", "velocity_bandwidth_hz": f_v, "cutoff_hz": f_c}
    nyq_new = fs / (2 * D)
    numtaps, beta = kaiserord(STOPBAND_DB, (nyq_new - f_c) / (fs / 2))
    numtaps |= 1
    taps = firwin(numtaps, f_c, window=("kaiser", beta), fs=fs)
    text = (f"decimated by {D}: {fs:.4g} Hz -> {fs / D:.4g} Hz ({T} -> {-(-T // D)} samples) after a "
            f"zero-phase anti-alias low-pass FIR ({numtaps} taps, Kaiser, {STOPBAND_DB:g} dB from "
            f"{nyq_new:.3g} Hz) on angles, torques and logged velocities; {how}")
    return {"factor": D, "rate_in_hz": fs, "rate_hz": fs / D, "cutoff_hz": f_c,
            "velocity_bandwidth_hz": f_v, "stopband_hz": nyq_new, "stopband_db": STOPBAND_DB,
            "taps": int(numtaps), "text": text, "_taps": taps}


def _decimate(x: np.ndarray, D: int, taps: np.ndarray) -> np.ndarray:
    """Every ``D``-th sample of the columns of ``x`` after the zero-phase FIR ``taps``
    (polyphase, the filter's delay compensated; the ends extended by a straight line)."""
    return resample_poly(x, 1, D, axis=0, window=taps, padtype="line")


def _interp_cols(tu, t, x):
    """Columns of ``x`` (T, k) on ``t`` linearly interpolated at ``tu``; NaN cells skipped
    (``x`` itself when it has no NaN and ``tu`` is ``t``)."""
    if tu is t and not np.isnan(x).any():
        return x
    out = np.empty((tu.size, x.shape[1]))
    for k in range(x.shape[1]):              # loop over joints, not samples
        ok = np.isfinite(x[:, k])
        out[:, k] = np.interp(tu, t[ok], x[ok, k]) if ok.sum() >= 2 else np.nan
    return out


def load_record(campaign, trial, robot, settings: RecordSettings | None = None,
                check: bool = True) -> MultiJointRecord:
    """Read a trial's log and prepare it (:func:`prepare_record`) with the campaign's coupling."""
    log = campaign.read_log(trial, robot)               # URDF joints, limits checked
    return prepare_record(log, trial, robot.n, coupling_matrix(campaign, robot.n), settings, check)


def check_campaign_motion(campaign, n: int, tol: float = BRAKED_TOL_RAD) -> None:
    """:func:`check_braked` on every trial's log (URDF coordinates through the coupling): a joint
    the trial declares braked that moves is an :class:`InputError` naming the trial, the joint and
    how far it moved."""
    for tr in campaign.trials:
        log = campaign.read_log(tr)                     # URDF joints ([robot] coupling applied)
        check_braked(tr, log.qm, tol, path=log.source)
