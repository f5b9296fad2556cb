"""Plausibility of inputs that parse but are wrong (issue 29): checks run on what the readers
return, before any estimate is computed, so that a unit or a column swap cannot pass silently.

Every check refuses with one :class:`~mocap.io.errors.InputError` line naming the file (or the
option) and the measured ratio. The thresholds are orders of magnitude (a unit off by 1000, a
swap), never a tuning of what a real recording may look like: a 5 kHz industrial log, a 100 Hz
service-robot log and stop-and-go recordings all pass.

* robot logs (:func:`check_log`): one row; all rows identical; a moving joint that never moves;
  time in milliseconds (the sampling interval against a controller's, the joint's peak speed
  against ``vmax_frac`` times ``max_velocity``); torque in mN m (its 99th percentile against
  ``max_torque`` and against the URDF's gravity torque); ``qm_j``/``tau_j`` swapped (an angle
  column that moves faster than the drive and is rougher than the torque column); a coast-down
  trial whose drive torque never cuts.
* drives against the URDF (:func:`check_drives_order`, :func:`check_drives_count`): a table
  count that differs from the URDF, drive names that are the URDF's joint names in another order.
* marker files (:func:`check_marker_time`, :func:`check_marker_extent`,
  :func:`check_marker_timing`, :func:`check_marker_shapes`, :func:`check_trial_rigid_fit`): a
  damaged clock; a cloud smaller than 0.5 % of the robot's reach (metres declared as mm); a time
  span that disagrees with the log's (a changed rate); links whose marker distances differ from
  the static recording (markers collapsed or rescaled); markers of braked links away from where
  the static references put them (a mirrored file).
* other inputs: ``calib.json`` (:func:`check_calib_json`), an ``--angles`` folder
  (:func:`check_angles_dir`), a rerun recording (:func:`check_rrd`), every recording of a
  campaign before a long run (:func:`check_campaign_inputs`).
* option values of the commands without a settings class (``jointlab synth``, ``design``:
  ``check_*_options``, :func:`check_number`, :func:`check_seed`), an option checked against the
  robot (:func:`check_joints_option`; ``jointlab diagnose``'s in
  :func:`ident.gap.campaign_diagnosis.check_diagnose_options`) and the memory an option would
  allocate (:func:`check_allocation`, with the estimate). The options of the commands with
  settings are checked by the settings themselves, at construction (:mod:`ident.settings`).
"""
from __future__ import annotations

import json
import math
import os
import warnings
from pathlib import Path

import numpy as np

from mocap.io.angles import read_angles
from mocap.io.errors import InputError, read_bytes, read_text
from mocap.robot import read_drives
from viz.screenshot import viewer_executable

#: a controller logs at 1 Hz or faster while a joint moves (a trial log): a median step above
#: this is a clock in another unit
MAX_TRIAL_STEP_S = 1.0
#: unit factors are 1000 (ms, mN m): a ratio beyond this is a unit, not a recording
UNIT_RATIO = 30.0


def _p99(x) -> float:
    x = np.abs(np.asarray(x, float))
    x = x[np.isfinite(x)]
    return float(np.percentile(x, 99)) if x.size else float("nan")


def _fmt_ratio(r: float) -> str:
    return f"{r:.3g}"


def check_log(log, rec, robot=None, kind: str = "trial") -> None:
    """Refuse a robot log that parses but cannot be what FORMAT.md says (module docstring).

    ``rec`` is the manifest's recording (a Trial has ``joints``, ``vmax_frac``, ``kind``);
    ``kind`` is ``trial``, ``calib`` or ``static``; ``robot`` gives the drive limits and the
    gravity torque (optional: the checks that need it are skipped)."""
    path = log.source
    T = log.n_samples
    joints = tuple(getattr(rec, "joints", ()) or ())
    if kind == "trial" and T < 2:
        raise InputError(f"the robot log has {T} sample row(s); a trial needs a recording over time",
                         path=path)
    if T < 2:
        return
    _check_time_jump(np.asarray(log.time, float), path, "the robot log's time", log.line_of)
    if kind == "trial":
        X = np.column_stack([log.qm, log.tau])
        same = (X == X[:1]) | (np.isnan(X) & np.isnan(X[:1]))
        if same.all():
            raise InputError(f"all {T} rows hold the same angles and torques: the trial records no "
                             "motion (a stale or repeated sample?)", path=path)
        _check_moving(log, joints, robot, path)
        _check_time_unit(log, rec, joints, robot, path)
        if robot is not None:
            _check_swap(log, joints, robot, path)
            _check_torque_unit(log, joints, robot, path)
        if getattr(rec, "kind", "") == "coastdown":
            _check_torque_cut(log, joints, path)


def _check_time_jump(t, path, what: str, line_of=None) -> None:
    """Refuse one step of the clock beyond a day and 10^5 median steps (a damaged time cell such
    as 1e308, which would otherwise overflow every resampling grid)."""
    dt = np.diff(t)
    dt = dt[np.isfinite(dt)]
    if dt.size < 1:
        return
    med = float(np.median(dt))
    k = int(np.argmax(np.diff(t)))
    big = float(t[k + 1] - t[k])
    if big > max(86400.0, 1e5 * med):
        line = line_of(k + 1) if line_of is not None else None
        raise InputError(f"{what} jumps by {big:.4g} s between two samples (the median step is "
                         f"{med:.3g} s): a damaged time value", path=path, line=line, label="time")


def _check_moving(log, joints, robot, path) -> None:
    for j in joints:
        if j > log.qm.shape[1]:
            continue
        q = log.qm[:, j - 1]
        q = q[np.isfinite(q)]
        if q.size < 2:
            continue
        span = float(q.max() - q.min())
        res = 0.0
        if robot is not None and j <= len(robot.drives):
            res = float(robot.drives[j - 1].encoder_resolution or 0.0)
        if span <= max(2.0 * res, 1e-9):
            raise InputError(f"joint {j} is listed as moving but qm_{j} never moves (range "
                             f"{span:.3g} rad over {q.size} samples)", path=path, label=f"qm_{j}")


def _check_time_unit(log, rec, joints, robot, path) -> None:
    dt = np.diff(log.time)
    dt = dt[np.isfinite(dt) & (dt > 0)]
    if not dt.size:
        return
    step = float(np.median(dt))
    if step > MAX_TRIAL_STEP_S:
        raise InputError(f"the median sampling interval is {step:.4g} s ({1.0 / step:.3g} Hz) in a trial "
                         "log: time in milliseconds suspected (FORMAT.md: seconds)", path=path,
                         label="time")
    if robot is None or step < 0.02:
        return
    vf = float(getattr(rec, "vmax_frac", 1.0) or 1.0)
    for j in joints:
        peak = _peak_speed(log, j, robot, 3)
        if peak is None:
            continue
        v, vmax, _ = peak
        ratio = v / (vf * vmax)
        if ratio < 1.0 / UNIT_RATIO ** 2:
            raise InputError(f"joint {j} peaks at {v:.3g} rad/s, {_fmt_ratio(ratio)} times the declared "
                             f"{vf:g} x max_velocity ({vmax:g} rad/s), with samples {step:.3g} s apart: "
                             "time in milliseconds suspected (FORMAT.md: seconds)", path=path,
                             label="time")


def _peak_speed(log, j: int, robot, min_samples: int):
    """(99th-percentile speed of ``qm_j`` in rad/s, the drive's max_velocity, the finite angles)
    of joint ``j``, or None when the log, the drive or the samples cannot say."""
    if j > log.qm.shape[1] or j > len(robot.drives):
        return None
    vmax = float(robot.drives[j - 1].max_velocity)
    if not (np.isfinite(vmax) and vmax > 0):
        return None
    ok = np.isfinite(log.qm[:, j - 1])
    t, q = log.time[ok], log.qm[ok, j - 1]
    if t.size < min_samples:
        return None
    dt = np.diff(t)
    return _p99(np.diff(q) / np.where(dt > 0, dt, np.nan)), vmax, q


def _roughness(x) -> float:
    """Median absolute second difference over the signal's 1-99 % spread (dimensionless)."""
    x = np.asarray(x, float)
    x = x[np.isfinite(x)]
    if x.size < 5:
        return float("nan")
    spread = float(np.percentile(x, 99) - np.percentile(x, 1))
    if spread <= 0:
        return float("nan")
    return float(np.median(np.abs(np.diff(x, 2)))) / spread


def _check_swap(log, joints, robot, path) -> None:
    for j in joints:
        peak = _peak_speed(log, j, robot, 5) if j <= log.tau.shape[1] else None
        if peak is None:
            continue
        v, vmax, q = peak
        rq, rt = _roughness(q), _roughness(log.tau[:, j - 1])
        if v > 3.0 * vmax and np.isfinite(rq) and np.isfinite(rt) and rq > 3.0 * rt:
            raise InputError(f"qm_{j} changes at {v:.3g} rad/s ({_fmt_ratio(v / vmax)} times max_velocity "
                             f"{vmax:g} rad/s) and is {_fmt_ratio(rq / rt)} times rougher than tau_{j}: "
                             f"qm_{j} and tau_{j} swapped?", path=path, label=f"qm_{j}")


def _check_torque_unit(log, joints, robot, path) -> None:
    n = min(log.tau.shape[1], len(robot.drives))
    for j in joints:
        if j > n:
            continue
        tmax = float(robot.drives[j - 1].max_torque)
        peak = _p99(log.tau[:, j - 1])
        if np.isfinite(tmax) and tmax > 0 and np.isfinite(peak) and peak > UNIT_RATIO * tmax:
            raise InputError(f"tau_{j} reaches {peak:.4g} N m (99th percentile), {_fmt_ratio(peak / tmax)} "
                             f"times the drive's max_torque {tmax:g} N m: torque in mN m suspected "
                             "(FORMAT.md: N m)", path=path, label=f"tau_{j}")
    # against the URDF's gravity torque, at up to 200 logged postures
    if log.qm.shape[1] != robot.n:
        return
    ok = np.flatnonzero(np.isfinite(log.qm).all(axis=1))
    if ok.size < 2:
        return
    pick = ok[np.linspace(0, ok.size - 1, min(200, ok.size)).astype(int)]
    try:
        G = np.atleast_2d(robot.gravity_torque(log.qm[pick]))
    except Exception:   # a posture pinocchio cannot evaluate: no gravity evidence
        return
    for j in joints:
        if j > n:
            continue
        g = float(np.median(np.abs(G[:, j - 1])))
        tau = log.tau[pick, j - 1]
        tau = tau[np.isfinite(tau)]
        if not tau.size or g < 0.5:
            continue
        m = float(np.median(np.abs(tau)))
        if m > UNIT_RATIO * 10.0 * g:
            raise InputError(f"tau_{j} is {m:.4g} N m in the median, {_fmt_ratio(m / g)} times the URDF's "
                             f"gravity torque ({g:.3g} N m) at the logged postures: torque in mN m "
                             "suspected (FORMAT.md: N m)", path=path, label=f"tau_{j}")


def torque_noise(tau) -> float:
    """The white-noise level (N m) of a logged torque, robust to the signal: the scaled median
    absolute deviation of its second differences, ``1.4826 MAD(d2) / sqrt(6)`` (a smooth drive
    torque has second differences far below the noise's, whose variance is ``6 sigma^2``; jumps
    at a cut are a few samples and do not move the median)."""
    tau = np.asarray(tau, float)
    tau = tau[np.isfinite(tau)]
    if tau.size < 5:
        return 0.0
    d2 = tau[2:] - 2.0 * tau[1:-1] + tau[:-2]
    return float(1.4826 * np.median(np.abs(d2 - np.median(d2))) / np.sqrt(6.0))


def _check_torque_cut(log, joints, path) -> None:
    """FORMAT.md coastdown: the drive torque is cut and the joint coasts to rest on friction, the
    logged torque ~0 from the cut on. Judged against the torque's noise, not sample by sample (a
    controller's torque noise of a few per cent of its peak is a valid coast-down): over a window
    of 0.2 s (at least 10 samples) the torque is ~0 where its mean is within 3 standard errors
    (``sigma / sqrt(n)``, ``sigma`` from :func:`torque_noise`) or 5 % of the 99th percentile of
    |tau| of zero, and its RMS about that mean is at most ``2 sigma`` + 5 % of that percentile
    (noise, not a torque swinging about zero). Refused when no stretch of such windows follows
    motion (the joint moved more than 1 mrad in the 0.1 s before) and ends at rest (it moves less
    than a fifth of that in the stretch's last 0.1 s). A rest before any motion, or a torque
    merely crossing zero while the joint moves on, is no coast."""
    for j in joints:
        if j > log.tau.shape[1] or j > log.qm.shape[1]:
            continue
        ok = np.isfinite(log.tau[:, j - 1]) & np.isfinite(log.qm[:, j - 1])
        t, tau, q = log.time[ok], log.tau[ok, j - 1], log.qm[ok, j - 1]
        if tau.size < 10:
            continue
        floor = 0.05 * _p99(tau)
        sigma = torque_noise(tau)
        dt = float(np.median(np.diff(t)))
        w = int(min(tau.size, max(10, np.ceil(0.2 / dt) if dt > 0 else 10)))
        c1 = np.concatenate([[0.0], np.cumsum(tau)])
        c2 = np.concatenate([[0.0], np.cumsum(tau * tau)])
        mean = (c1[w:] - c1[:-w]) / w
        var = np.maximum((c2[w:] - c2[:-w]) / w - mean * mean, 0.0)
        low = (np.abs(mean) <= max(3.0 * sigma / np.sqrt(w), floor)) & \
            (np.sqrt(var) <= 2.0 * sigma + floor)
        edges = np.diff(np.concatenate([[0], low.astype(np.int8), [0]]))
        starts, ends = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1) + w - 1
        longest, found = 0.0, False
        for s0, e0 in zip(starts, ends):
            longest = max(longest, float(t[e0 - 1] - t[s0]))
            before = q[(t >= t[s0] - 0.1) & (t <= t[s0])]
            tail = q[s0:e0][t[s0:e0] >= t[e0 - 1] - 0.1]
            moved = float(np.ptp(before)) if before.size > 1 else 0.0
            if moved > 1e-3 and float(np.ptp(tail)) < 0.2 * moved:
                found = True
                break
        if not found:
            raise InputError(f"coast-down trial: tau_{j} never averages ~0 while the joint coasts to rest "
                             f"(mean over {w} samples within max(3 standard errors, {floor:.3g} N m) of 0 "
                             f"at noise {sigma:.3g} N m for at most {longest:.3g} s): the drive torque is "
                             "never cut", path=path, label=f"tau_{j}")


def check_drives_order(robot, drives_path) -> None:
    """Drive tables hold one joint each in joint order (FORMAT.md): drive names that are the URDF's
    revolute joint names in another order are refused (a name that is no URDF joint is allowed)."""
    names = tuple(robot.joint_names)
    got = tuple(d.name for d in robot.drives)
    pos = {nm: k for k, nm in enumerate(names)}
    for k, nm in enumerate(got):
        if nm in pos and pos[nm] != k:
            raise InputError(f"[[joint]] number {k + 1} is {nm!r}, which is URDF joint {pos[nm] + 1} "
                             f"({names[k]!r} is joint {k + 1}): the tables are not in joint order",
                             path=drives_path, label=nm)


def check_drives_count(drives_path, n_urdf: int) -> None:
    """One ``[[joint]]`` table per URDF revolute joint, named by the drives file."""
    dr = read_drives(drives_path)
    if len(dr) != n_urdf:
        raise InputError(f"drives describe {len(dr)} joints but the URDF has {n_urdf} revolute joints",
                         path=drives_path)


def check_marker_timing(markers, log) -> None:
    """A marker file and the robot log of the same recording cover about the same time span
    (FORMAT.md: they need not start or end together): a span ratio beyond 3 is a rate declared
    wrong (a C3D whose point rate was changed, a TRC DataRate edited)."""
    tm, tl = np.asarray(markers.time, float), np.asarray(log.time, float)
    _check_time_jump(tm, markers.source, "the marker file's time")
    _check_time_jump(tl, log.source, "the robot log's time", log.line_of)
    if tm.size < 10 or tl.size < 10:
        return
    sm, sl = float(tm[-1] - tm[0]), float(tl[-1] - tl[0])
    if sm <= 0 or sl <= 0:
        return
    r = sm / sl
    if r > 3.0 or r < 1.0 / 3.0:
        raise InputError(f"the marker file spans {sm:.4g} s ({markers.rate_hz:g} Hz declared), its robot "
                         f"log {log.source.name if log.source else 'log'} {sl:.4g} s (ratio "
                         f"{_fmt_ratio(r)}): the marker rate is wrong", path=markers.source,
                         label="rate")


def check_marker_time(markers) -> None:
    """A marker file's clock: no step beyond a day and 10^5 median steps (a damaged cell)."""
    _check_time_jump(np.asarray(markers.time, float), markers.source, "the marker file's time")


def _pair_distances(P, i, j) -> np.ndarray:
    """(K,) median over frames of the distances between markers ``i[k]`` and ``j[k]`` of ``P``
    (T, M, 3)."""
    if len(i) == 0:
        return np.empty(0)
    D = np.linalg.norm(P[:, i] - P[:, j], axis=-1)
    with np.errstate(all="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        if D.shape[0] < 600:              # numpy's small-array nanmedian
            return np.nanmedian(D, axis=0)
        holes = np.isnan(D).any(axis=0)
        if not holes.any():               # the median of each column, as nanmedian takes it
            return np.median(D, axis=0)
        out = np.empty(D.shape[1])
        out[~holes] = np.median(D[:, ~holes], axis=0)
        out[holes] = np.nanmedian(D[:, holes], axis=0)
        return out


#: id(reference recording) -> (the recording, its pair indices, their median distances): a
#: static reference is checked against every trial of a campaign; its distances are computed once
_REF_PAIRS: dict = {}


def _reference_pair_distances(reference, i, j) -> np.ndarray:
    key = (tuple(i), tuple(j))
    hit = _REF_PAIRS.get(id(reference))
    if hit is not None and hit[0] is reference and hit[1] == key:
        return hit[2]
    d = _pair_distances(reference.positions, i, j)
    if len(_REF_PAIRS) >= 4:
        _REF_PAIRS.clear()
    _REF_PAIRS[id(reference)] = (reference, key, d)
    return d


def check_marker_shapes(markers, reference, link_labels: dict) -> None:
    """Each link's markers keep the distances they have in the static ``reference`` recording
    (a rigid link): a link whose median distances are off by more than 20 mm RMS (markers
    collapsed to one point, a unit declared wrong) is refused with that residual. The
    ``reference`` is read, never changed (its distances are kept for the next trial)."""
    links, mi, mj, ri, rj = [], [], [], [], []
    for link, labels in link_labels.items():
        idx = [k for k, lb in enumerate(markers.labels) if lb in labels]
        ref = [reference.labels.index(markers.labels[k]) for k in idx
               if markers.labels[k] in reference.labels]
        idx = [k for k in idx if markers.labels[k] in reference.labels]
        if len(idx) < 2:
            continue
        iu = np.triu_indices(len(idx), 1)
        links.append((link, len(mi), len(mi) + len(iu[0])))
        mi += [idx[a] for a in iu[0]]
        mj += [idx[b] for b in iu[1]]
        ri += [ref[a] for a in iu[0]]
        rj += [ref[b] for b in iu[1]]
    if not links:
        return
    A = _pair_distances(markers.positions, mi, mj)
    B = _reference_pair_distances(reference, ri, rj)
    for link, lo, hi in links:
        a, b = A[lo:hi], B[lo:hi]
        ok = np.isfinite(a) & np.isfinite(b)
        if not ok.any() or float(np.max(b[ok])) < 5e-3:
            continue
        rms = float(np.sqrt(np.mean((a[ok] - b[ok]) ** 2)))
        if rms > 0.02 + 0.2 * float(np.max(b[ok])):
            ratio = float(np.median(a[ok]) / np.median(b[ok])) if np.median(b[ok]) > 0 else float("nan")
            raise InputError(f"link {link}: its markers' distances differ from the static recording "
                             f"{reference.source.name if reference.source else ''} by {1e3 * rms:.4g} mm "
                             f"RMS (scale {ratio:.3g}): a rigid fit to the static reference is "
                             "implausible (markers collapsed, or the declared unit wrong)",
                             path=markers.source, label=link)


def check_calib_json(path) -> np.ndarray:
    """``T_camera_base`` of a ``calib.json``: an :class:`InputError` naming the file for
    anything but a finite rigid 4x4 transform with a translation under 1 km."""
    path = Path(path)
    try:
        doc = json.loads(read_text(path))
    except json.JSONDecodeError as exc:
        raise InputError(f"not valid JSON: {exc.msg}", path=path, line=exc.lineno) from None
    except RecursionError:
        raise InputError("not valid JSON (nested too deep)", path=path) from None
    if not isinstance(doc, dict) or "T_camera_base" not in doc:
        raise InputError("no 4x4 'T_camera_base' in the calibration (expected a JSON object)",
                         path=path, label="T_camera_base")
    rows = doc["T_camera_base"]
    ok = (isinstance(rows, list) and len(rows) == 4 and
          all(isinstance(r, list) and len(r) == 4 and
              all(isinstance(x, (int, float)) and not isinstance(x, bool) for x in r) for r in rows))
    if not ok:
        raise InputError("'T_camera_base' must be 4 rows of 4 numbers", path=path, label="T_camera_base")
    T = np.array(rows, float)
    if not np.all(np.isfinite(T)):
        raise InputError("'T_camera_base' holds a NaN or infinite value", path=path, label="T_camera_base")
    R = T[:3, :3]
    err = float(np.max(np.abs(R.T @ R - np.eye(3))))
    if err > 1e-6 or abs(float(np.linalg.det(R)) - 1.0) > 1e-6 or not np.allclose(T[3], [0, 0, 0, 1]):
        raise InputError(f"'T_camera_base' is not a rigid transform (|R^T R - I| = {err:.3g}, det "
                         f"{float(np.linalg.det(R)):.4g})", path=path, label="T_camera_base")
    if float(np.linalg.norm(T[:3, 3])) > 1000.0:
        raise InputError(f"'T_camera_base' puts the base {float(np.linalg.norm(T[:3, 3])):.4g} m from "
                         "the camera (millimetres written as metres?)", path=path, label="T_camera_base")
    return T


def available_memory() -> int:
    """Bytes of memory available now (``MemAvailable``; physical memory where unknown)."""
    try:
        for line in Path("/proc/meminfo").read_text().splitlines():
            if line.startswith("MemAvailable:"):
                return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    try:
        return int(os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES"))
    except (ValueError, OSError, AttributeError):
        return 8 << 30


def check_allocation(n_bytes: float, what: str) -> None:
    """Refuse an option value whose arrays (``n_bytes``, an estimate) exceed the available
    memory: one line with the estimate, naming the option(s) in ``what``."""
    avail = available_memory()
    if not math.isfinite(n_bytes) or n_bytes > avail:
        est = "an unbounded amount" if not math.isfinite(n_bytes) else f"about {n_bytes / 2**30:.3g} GiB"
        raise InputError(f"{what}: the arrays would need {est} of memory, {avail / 2**30:.3g} GiB "
                         "is available; choose a coarser value")


def check_number(value, option: str, lo=None, hi=None, lo_open: bool = False,
                 hi_open: bool = False) -> float:
    """``value`` as a finite float inside [lo, hi] (open ends where asked), else a one-line
    :class:`InputError` naming the option."""
    try:
        v = float(value)
    except (TypeError, ValueError, OverflowError):
        raise InputError(f"{option}: expected a number, got {value!r}") from None
    bad = not math.isfinite(v)
    if lo is not None:
        bad |= v <= lo if lo_open else v < lo
    if hi is not None:
        bad |= v >= hi if hi_open else v > hi
    if bad:
        left = "" if lo is None else ("> " if lo_open else ">= ") + f"{lo:g}"
        right = "" if hi is None else ("< " if hi_open else "<= ") + f"{hi:g}"
        rng = " and ".join(x for x in (left, right) if x) or "finite"
        raise InputError(f"{option} must be a finite number {rng}, got {value!r}")
    return v


#: rerun's .rrd stream: "RRF2", a version and options word, then messages (kind, length) as two
#: little-endian u64 each; kinds 0 (end), 1 (store info), 2 (arrow data), 3 (blueprint activation)
_RRD_MAGIC = b"RRF2"
_RRD_KINDS = (0, 1, 2, 3)


def check_rrd(path, verify: bool = True) -> None:
    """Refuse a damaged rerun recording before a viewer opens it: the stream's framing (magic,
    message kinds and lengths inside the file) and, where the ``rerun`` executable is at hand,
    ``rerun rrd verify`` (one line naming the file with its first complaint)."""
    import struct

    path = Path(path)
    raw = read_bytes(path)
    if raw[:4] != _RRD_MAGIC or len(raw) < 12:
        raise InputError(f"not a rerun recording (the file starts with {raw[:4]!r}, expected "
                         f"{_RRD_MAGIC!r})", path=path)
    pos, n_msg = 12, 0
    while pos + 16 <= len(raw):
        kind, length = struct.unpack_from("<QQ", raw, pos)
        if kind not in _RRD_KINDS or pos + 16 + length > len(raw):
            raise InputError(f"damaged rerun recording: message {n_msg + 1} at byte {pos} "
                             f"({'unknown kind ' + str(kind) if kind not in _RRD_KINDS else f'{length} bytes past the end'})",
                             path=path)
        pos += 16 + length
        n_msg += 1
        if kind == 0:
            break
    else:
        if pos != len(raw) or n_msg == 0:
            raise InputError(f"damaged rerun recording: truncated after {n_msg} messages (byte {pos} of "
                             f"{len(raw)})", path=path)
    if not verify:
        return

    exe = viewer_executable()
    if exe is None:
        return
    import subprocess

    try:
        r = subprocess.run([exe, "rrd", "verify", str(path)], capture_output=True, text=True,
                           timeout=120, stdin=subprocess.DEVNULL,
                           env={**os.environ, "RERUN_ANALYTICS": "0"})
    except (OSError, subprocess.TimeoutExpired):
        return
    if r.returncode != 0:
        why = [ln.strip() for ln in (r.stderr or r.stdout).splitlines() if ln.strip()]
        raise InputError(f"damaged rerun recording: {why[-1] if why else 'rerun rrd verify failed'}",
                         path=path)


def braked_marker_residuals(markers, log, refs, robot, trial, T_camera_base=None):
    """(residuals m, labels) of the markers on links that no joint of ``trial`` moves: the
    distance of each marker's median position from ``T_camera_base @ T_base_link(q) @ p_link``
    at the trial's median logged angles (empty where the trial moves joint 1)."""
    first = min(trial.joints) - 1                                   # 0-based first moving joint
    frames = robot.chain.frames
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)              # a column without values
        q = np.nanmedian(np.where(np.isfinite(log.qm), log.qm, np.nan), axis=0)
    if q.shape[0] != robot.n or not np.all(np.isfinite(q[:max(first, 0)])):
        return [], []
    q = np.where(np.isfinite(q), q, 0.0)
    T_cb = np.asarray(refs.T_camera_base if T_camera_base is None else T_camera_base, float)
    use = [(k, lb, link, markers.labels.index(lb)) for k, (lb, link) in enumerate(zip(refs.labels, refs.links))
           if link in frames and frames[link][0] < first and lb in markers.labels]
    f = np.isfinite(markers.positions[:, [c for *_, c in use]])
    ok = f[..., 0] & f[..., 1] & f[..., 2]                           # (T, markers used)
    whole = ok.all(axis=0)
    # per marker, the median over its frames; of the markers seen in every frame, all at once
    med = np.median(markers.positions[:, [c for (*_, c), w in zip(use, whole) if w]], axis=0)
    res, names, T_link = [], [], {}
    for u, (k, lb, link, c) in enumerate(use):
        if not ok[:, u].any():
            continue
        meas = med[int(np.count_nonzero(whole[:u]))] if whole[u] else \
            np.median(markers.positions[ok[:, u], c], axis=0)
        if link not in T_link:
            T_link[link] = robot.frame_transform(link, q)
        p = T_cb @ T_link[link] @ np.append(refs.p_link[k], 1.0)
        res.append(float(np.linalg.norm(meas - p[:3])))
        names.append(lb)
    return res, names


def _kabsch_rms(A, B) -> np.ndarray:
    """(F,) RMS residuals of the best proper rigid motion (rotation with det +1, translation)
    taking points ``A`` (k, 3) onto each ``B[f]`` (F, k, 3) (Kabsch; a mirror image cannot be
    matched), batched over the F point sets."""
    a, b = A - A.mean(axis=0), B - B.mean(axis=1, keepdims=True)
    U, _, Vt = np.linalg.svd(np.matmul(a.T, b))
    d = np.sign(np.linalg.det(U @ Vt))
    D = np.zeros((len(B), 3, 3))
    D[:, 0, 0] = D[:, 1, 1] = 1.0
    D[:, 2, 2] = np.where(d == 0, 1.0, d)
    X = U @ D @ Vt                                      # the rotation's transpose
    return np.sqrt(np.mean(np.sum((a @ X - b) ** 2, axis=2), axis=1))


def moving_group_residual(markers, log, refs, robot, trial, n_frames: int = 60):
    """(RMS m, markers used) of the markers on the links a single-joint ``trial`` moves (all
    carried rigidly by its one moving joint while the others are braked) against their static
    references posed at the trial's median logged angles: a proper rigid fit per frame at up to
    ``n_frames`` frames (no clock needed), the 10th percentile over the frames. (nan, n) when it
    does not apply (several moving joints, fewer than 4 markers)."""
    if len(trial.joints) != 1:
        return float("nan"), 0
    first = trial.joints[0] - 1
    frames = robot.chain.frames
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        q = np.nanmedian(np.where(np.isfinite(log.qm), log.qm, np.nan), axis=0)
    if q.shape[0] != robot.n or not np.all(np.isfinite(np.delete(q, first))):
        return float("nan"), 0
    q = np.where(np.isfinite(q), q, 0.0)
    ks, pred, T_link = [], [], {}
    for k, (lb, link) in enumerate(zip(refs.labels, refs.links)):
        if link in frames and frames[link][0] >= first and lb in markers.labels:
            ks.append(markers.labels.index(lb))
            if link not in T_link:
                T_link[link] = robot.frame_transform(link, q)
            pred.append((T_link[link] @ np.append(refs.p_link[k], 1.0))[:3])
    if len(ks) < 4:
        return float("nan"), len(ks)
    pred = np.array(pred)
    f = np.isfinite(markers.positions)
    ok = np.flatnonzero((f[..., 0] & f[..., 1] & f[..., 2])[:, ks].all(axis=1))
    if ok.size == 0:
        return float("nan"), len(ks)
    pick = ok[np.linspace(0, ok.size - 1, min(n_frames, ok.size)).astype(int)]
    # the best tenth of the frames: label swaps spoil some frames, a mirrored file every frame
    return float(np.percentile(_kabsch_rms(pred, markers.positions[pick][:, ks]), 10)), len(ks)


def check_trial_rigid_fit(markers, log, refs, robot, trial, T_camera_base=None) -> None:
    """Refuse a trial marker file that no rigid motion fits to the static references, with the
    residual. The markers a single-joint trial's joint carries (:func:`moving_group_residual`)
    must fit within 8 mm and 8 times the markers' noise while still; the markers of links no
    joint of the trial moves stand where the static references put them (``T_camera_base @
    T_base_link(q) @ p_link`` at the median logged angles) within 50 mm and 20 times the static
    fit RMS. A mirrored file, a wrong unit, another robot's markers fail. ``refs``:
    :class:`mocap.references.References`."""
    res, names = braked_marker_residuals(markers, log, refs, robot, trial, T_camera_base)
    tol = max(0.05, 20.0 * float(refs.fit_rms_m or 0.0))
    rms, n = moving_group_residual(markers, log, refs, robot, trial)
    scatter = np.asarray(getattr(refs, "scatter_m", []), float)
    noise = float(np.nanmedian(scatter)) if scatter.size and np.isfinite(scatter).any() else 0.0
    if np.isfinite(rms) and rms > max(0.008, 8.0 * noise):    # 8 x the markers' noise while still
        raise InputError(f"the {n} markers the trial's joint {trial.joints[0]} carries fit their static "
                         f"references by {1e3 * rms:.4g} mm RMS at best (a proper rigid motion per "
                         "frame): a rigid fit to the static reference is implausible (mirrored "
                         "coordinates, a wrong unit, swapped links?)", path=markers.source)
    if len(res) < 3:
        return
    med = float(np.median(res))
    if med > tol:
        k = int(np.argmax(res))
        raise InputError(f"markers of the links the trial does not move ({len(res)} markers) sit "
                         f"{1e3 * med:.4g} mm (median; {names[k]!r} {1e3 * res[k]:.4g} mm) from where the "
                         "static references put them: a rigid fit to the static reference is "
                         "implausible (mirrored coordinates, a wrong unit?)", path=markers.source,
                         label=names[k])


def check_angles_dir(angles_dir, campaign, robot=None) -> None:
    """An ``--angles`` folder (``angles/<trial id>.csv``, FORMAT.md) before any work: a folder,
    holding a readable angles file for at least one trial, each with a ``q_<j>`` column of every
    joint its trial moves, in radians within the URDF's limits (an :class:`InputError` naming
    the folder or the file)."""
    d = Path(angles_dir)
    if not d.is_dir():
        raise InputError("--angles must be a folder of angles/<trial id>.csv files", path=d)
    found = 0
    for t in campaign.trials:
        p = d / f"{t.id}.csv"
        if not p.is_file():
            continue
        found += 1
        read_text(p)                       # names the file for an unreadable or non-UTF-8 one
        try:
            tr = read_angles(p)
        except InputError:
            raise
        except (ValueError, IndexError, TypeError) as exc:
            raise InputError(f"not an angles file ({type(exc).__name__}: {exc})", path=p) from None
        missing = [j for j in t.joints if j not in tr.q]
        if missing:
            raise InputError(f"no q_{missing[0]} column, but trial {t.id!r} moves joint {missing[0]}",
                             path=p, line=1, label=f"q_{missing[0]}")
        if robot is None:
            continue
        for j, q in tr.q.items():
            if not 1 <= j <= robot.n:
                raise InputError(f"column q_{j}: the robot has joints 1..{robot.n}", path=p, line=1,
                                 label=f"q_{j}")
            lo, hi = float(robot.lower[j - 1]), float(robot.upper[j - 1])
            span = hi - lo if np.isfinite(hi - lo) else 0.0
            qq = q[np.isfinite(q)]
            if qq.size and (qq.max() > hi + 0.05 + 0.1 * span or qq.min() < lo - 0.05 - 0.1 * span):
                v = float(qq.max() if qq.max() > hi + 0.05 + 0.1 * span else qq.min())
                raise InputError(f"column q_{j} reaches {v:.4g} rad, beyond the URDF limits [{lo:.3f}, "
                                 f"{hi:.3f}] rad: degrees suspected (FORMAT.md: radians)", path=p,
                                 label=f"q_{j}")
    if not found:
        raise InputError(f"holds no <trial id>.csv for any of the campaign's {len(campaign.trials)} "
                         "trials", path=d)


# ---- option values of the commands (one line naming the option, exit 2) ---------------------
def check_synth_options(*, magnitude, seed, loads, vmax, joints, duration, marker_rate, log_rate, reps, label_swaps) -> None:
    """``jointlab synth``: values in range and one trial's arrays within the available memory
    (log: time + 3 signals x 6 joints; markers: up to 8 x 7 links x 3; float64, a few copies)."""
    check_number(magnitude, "--magnitude", lo=0.0, hi=1e3)
    check_seed(seed)
    for opt, text in (("--loads", loads), ("--vmax", vmax)):
        for x in str(text).split(","):
            try:
                v = float(x)
            except ValueError:
                continue                  # the command's own parser names it
            if not math.isfinite(v):
                raise InputError(f"{opt}: {x.strip()!r} is not a finite number")
    _distinct_tags(joints, "--joints", lambda v: int(float(v)), "")
    _distinct_tags(loads, "--loads", lambda v: int(float(v) * 10 + 1e-9), "load", "tenths of a kg")
    _distinct_tags(vmax, "--vmax", lambda v: int(round(float(v) * 100)), "v", "per cent")
    check_number(duration, "--duration", lo=2.0)
    check_number(marker_rate, "--marker-rate", lo=0.0, lo_open=True)
    check_number(log_rate, "--log-rate", lo=0.0, lo_open=True)
    if not 1 <= reps <= 1000:
        raise InputError(f"--reps must be in 1..1000, got {reps}")
    if label_swaps < 0:
        raise InputError(f"--label-swaps must be >= 0, got {label_swaps}")
    seconds = duration + 2 * 4.0
    n_bytes = 8 * 4 * seconds * (log_rate * 19 + marker_rate * 8 * 7 * 3)
    check_allocation(n_bytes, f"--log-rate {log_rate:g} / --marker-rate {marker_rate:g} "
                              f"over --duration {duration:g} s")


def _distinct_tags(text, option: str, tag, prefix: str, unit: str = "") -> None:
    """Values of a comma-separated synth option that give one trial id tag (a repeated joint,
    loads within a tenth of a kg, speed fractions within a per cent) would write two trials with
    one id: refused."""
    seen = {}
    for x in str(text).split(","):
        if not x.strip():
            continue
        try:
            k = tag(x)
        except (ValueError, OverflowError):
            return                        # the command's own parser names it
        if k in seen:
            how = f" (trial ids carry {prefix}{k}, in {unit})" if unit else ""
            raise InputError(f"{option}: {seen[k]!r} and {x.strip()!r} give the same trial ids{how}")
        seen[k] = x.strip()


def check_seed(seed, option: str = "--seed") -> None:
    """A random seed is an integer in 0 .. 2**63 - 1 (numpy's generators refuse others)."""
    if not 0 <= int(seed) < 2 ** 63:
        raise InputError(f"{option} must be an integer >= 0, got {seed}")


def check_design_options(*, seed, period, harmonics, starts, dt, amax) -> None:
    """``jointlab design``: period, harmonics, starts, dt (and the trajectory's arrays within
    the available memory: t, q, qd, qdd and their copies), amax, seed."""
    check_seed(seed)
    check_number(period, "--period", lo=0.0, lo_open=True, hi=1e5)
    if not 1 <= harmonics <= 200:
        raise InputError(f"--harmonics must be in 1..200, got {harmonics}")
    if not 1 <= starts <= 10000:
        raise InputError(f"--starts must be in 1..10000, got {starts}")
    check_number(dt, "--dt", lo=0.0, lo_open=True, hi=period / 4)
    if amax is not None:
        check_number(amax, "--amax", lo=0.0, lo_open=True)
    check_allocation(8 * 4 * 4 * (period / dt + 1), f"--dt {dt:g} over --period {period:g} s")


def check_joints_option(joints, robot, option: str = "--joints") -> None:
    """Every joint of a ``--joints`` list is a joint of the robot."""
    bad = [j for j in joints or () if not 1 <= j <= robot.n]
    if bad:
        raise InputError(f"{option} {bad[0]}: the robot has joints 1..{robot.n}")


def check_coastdown_campaign(campaign, joints=()) -> None:
    """``jointlab coastdown``: ``--joints`` of the robot, and every ``kind = "coastdown"``
    trial's log through :meth:`Campaign.read_log` (units, swaps, a torque that is never cut)."""
    robot = campaign.load_robot()
    check_joints_option(joints, robot)
    for t in campaign.trials:
        if t.kind == "coastdown":
            campaign.read_log(t, robot)


def check_campaign_inputs(campaign, robot=None, markers: bool = True) -> None:
    """Every recording of ``campaign`` through :meth:`Campaign.read_log` and (``markers``)
    :meth:`Campaign.read_markers` once, before a long computation reads them by other routes:
    the first parseable-but-wrong file ends the run in one line."""
    robot = robot if robot is not None else campaign.load_robot()
    for _, _, rec in campaign.recordings():
        campaign.read_log(rec, robot)
        if markers and rec.markers is not None:
            campaign.read_markers(rec, robot)


