"""Camera-to-base calibration of a campaign (thesis section 3.2): sweeps -> axes -> base.

:func:`calibrate` reads every ``[[calib]]`` entry of a FORMAT v1 campaign, checks that each
sweep moves its joint alone over at least ``min_sweep_deg``, fits the joint axis from the
markers on the links that joint carries, and places the base with the URDF's axis lines at
the encoder angles held during each sweep (:func:`calib.base.place_base`).
"""
from __future__ import annotations

import json
import warnings
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from mocap.io.errors import InputError
from mocap.quality import chain_reach, check_marker_units  # noqa: F401 (calib's names)

from calib.axis import (MIN_POSES, AxisFit, CircleAxisEstimator, ClusterAxisEstimator,
                        marker_angles)
from calib.base import BasePlacement, place_base, pose_errors
from calib.geometry import chart_line
from calib.handeye import HandEyeEstimator


class AutoAxisEstimator:
    """The cluster estimator where a sweep has 3 or more markers, the circle(-point) estimator
    where it has one or two (settings passed to whichever runs)."""

    method = "auto"

    def __init__(self, min_frames: int = MIN_POSES, **settings):
        self.min_frames = min_frames
        self.settings = settings

    def fit(self, positions, labels=None) -> AxisFit:
        seen = np.all(np.isfinite(np.asarray(positions, float)), axis=2).sum(axis=0) >= self.min_frames
        cls = ClusterAxisEstimator if int(seen.sum()) >= 3 else CircleAxisEstimator
        return cls(min_frames=self.min_frames, **self.settings).fit(positions, labels)


ESTIMATORS = {"auto": AutoAxisEstimator, "cluster": ClusterAxisEstimator, "circle": CircleAxisEstimator}

#: a joint whose encoder range exceeds this (deg) during a sweep counts as moving
MOVING_DEG = 0.5


@dataclass(frozen=True, eq=False)
class SweepData:
    """One calibration sweep ready for the axis fit (camera frame, metres, radians).

    What :func:`prepare_sweep` builds from one ``[[calib]]`` entry of a campaign [2]_: a
    single-joint sweep [1]_ checked to move its joint alone, far enough, with the markers of the
    links the joint carries.

    Attributes
    ----------
    joint : int
        The swept joint, 1-based.
    time : numpy.ndarray
        (T,) marker times (s).
    positions : numpy.ndarray
        (T, M, 3) markers on the links the joint carries (m, camera frame; NaN where occluded).
    labels : tuple of str
        The M marker labels.
    q_held : numpy.ndarray
        (n,) median encoder angles (rad; the swept joint's entry too), at which the URDF gives
        the joint's axis line.
    q_joint : numpy.ndarray
        (T,) the swept joint's encoder angle at the marker frames (rad; NaN outside the log).
    range_deg : float
        Encoder range of the swept joint (deg).
    links : tuple of str
        The links whose markers are used.
    markers_path : pathlib.Path or None, optional
        The marker file (for error messages).
    log_path : pathlib.Path or None, optional
        The robot log (for error messages).
    q_frames : numpy.ndarray or None, optional
        (T, n) all encoder angles at the marker frames (rad; NaN outside the log).

    References
    ----------
    .. [1] PA10 thesis (seeds 002), sec. 3.2 (Estimation of Link Position): rotating one joint
       alone about its fixed axis.
    .. [2] jointlab data format (docs/format.md), sec. campaign.toml.
    """

    joint: int                  # 1-based
    time: np.ndarray            # (T,) marker times
    positions: np.ndarray       # (T, M, 3) markers on the links the joint carries
    labels: tuple
    q_held: np.ndarray          # (n,) median encoder angles (the swept joint's entry too)
    q_joint: np.ndarray         # (T,) the swept joint's encoder angle at the marker frames (NaN outside the log)
    range_deg: float            # encoder range of the swept joint
    links: tuple                # the links whose markers are used
    markers_path: Path | None = None
    log_path: Path | None = None
    q_frames: np.ndarray | None = None   # (T, n) all encoder angles at the marker frames


@dataclass(frozen=True, eq=False)
class CalibResult:
    """``T_camera_base`` with the fitted axes, the base solve and the sweeps' diagnostics.

    What :func:`calibrate` and :func:`calibrate_sweeps` return [1]_ [2]_; :meth:`to_dict` is
    the ``calib.json`` document [3]_ (:func:`write_calib_json`). The properties ``warnings``,
    ``noise_used_mm``, ``origin_std_mm`` and ``rotation_std_deg`` summarise the axes and the
    base solve.

    Attributes
    ----------
    T_camera_base : numpy.ndarray
        (4, 4) homogeneous transform, ``p_camera = T @ p_base`` (m).
    axes : tuple of calib.axis.AxisFit
        The fitted axes (camera frame, labelled and oriented with their joints).
    base : calib.base.BasePlacement
        The base solve: covariance, bound, misfit and budget.
    method : str
        The axis estimator (``"auto"``, ``"cluster"`` or ``"circle"``).
    noise_mm : float or None
        Given 3-D RMS noise (mm), None when estimated from the residuals.
    sweeps : tuple of SweepData, optional
        The sweeps the axes were fitted to.
    extra : dict, optional
        Further sections of ``calib.json`` (``"handeye"``: the cross-check).

    References
    ----------
    .. [1] PA10 thesis (seeds 002), sec. 3.2 (Estimation of Link Position).
    .. [2] jointlab calibration (docs/calibration.md).
    .. [3] jointlab data format (docs/format.md), sec. What the workbench writes.
    """

    T_camera_base: np.ndarray
    axes: tuple
    base: BasePlacement
    method: str
    noise_mm: float | None        # given 3-D RMS noise, None when estimated from the residuals
    sweeps: tuple = ()
    extra: dict = field(default_factory=dict)

    @property
    def warnings(self) -> tuple:
        """Non-convergence of an axis fit and the base solve's model-mismatch warning."""
        out = [f"joint {f.joint}: the {f.method} axis fit stopped at its iteration cap "
               f"({f.iterations}) without converging" for f in self.axes if not f.converged]
        return tuple(out) + tuple(self.base.warnings)

    @property
    def noise_used_mm(self) -> float:
        """The noise behind the Cramer-Rao bound: given, or the axis fits' estimate (RMS)."""
        if self.noise_mm is not None:
            return float(self.noise_mm)
        return float(np.sqrt(np.mean([f.sigma_mm ** 2 for f in self.axes])))

    @property
    def origin_std_mm(self) -> float:
        return self.base.origin_std_mm

    @property
    def rotation_std_deg(self) -> float:
        return self.base.rotation_std_deg

    def to_dict(self) -> dict:
        """The ``calib.json`` document (FORMAT.md keys first, diagnostics after)."""
        b = self.base.to_dict()
        return {
            "format": 1,
            "T_camera_base": [[float(x) for x in row] for row in self.T_camera_base],
            "axes": [f.to_dict() for f in self.axes],
            "origin_std_mm": self.origin_std_mm,
            "rotation_std_deg": self.rotation_std_deg,
            "origin_cov_mm2": (1e6 * self.base.cov[3:, 3:]).tolist(),
            "region95": self.base.region95,
            "warnings": list(self.warnings),
            "crb": {"origin_std_mm": b["crb_origin_std_mm"], "rotation_std_deg": b["crb_rotation_std_deg"],
                    "noise_mm": self.noise_used_mm,
                    "noise_source": "given" if self.noise_mm is not None else "estimated from the residuals",
                    "note": "numerical Cramer-Rao bound of the sweep model at noise_mm "
                            "(3-D RMS), propagated through the base solve"},
            "method": self.method,
            "base_solve": {k: v for k, v in b.items() if k != "T_camera_base"},
            "sweeps": [{"joint": s.joint, "markers": None if s.markers_path is None else str(s.markers_path),
                        "log": None if s.log_path is None else str(s.log_path),
                        "encoder_range_deg": s.range_deg, "q_held": s.q_held.tolist(),
                        "links": list(s.links), "labels": list(s.labels), "n_frames": int(s.time.size)}
                       for s in self.sweeps],
            **self.extra,
        }


def write_calib_json(path, result: CalibResult) -> Path:
    """Write ``calib.json`` (floats at full precision).

    The document is :meth:`CalibResult.to_dict`: the keys of the data format first [1]_,
    the diagnostics after; parent folders are created.

    Parameters
    ----------
    path : str or pathlib.Path
        The file to write.
    result : CalibResult
        The calibration.

    Returns
    -------
    pathlib.Path
        The path written.

    References
    ----------
    .. [1] jointlab data format (docs/format.md), sec. What the workbench writes.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(result.to_dict(), indent=1) + "\n", encoding="utf-8")
    return path


# ---------------------------------------------------------------------------------------
def moving_links(chain, joint: int, marker_links) -> list:
    """Links (of ``marker_links``) carried by joint ``joint`` (1-based): they move in its sweep."""
    return [lk for lk in marker_links if lk in chain.frames and chain.frames[lk][0] >= joint - 1]


def prepare_sweep(joint: int, rec, log, chain, markers: dict, min_sweep_deg: float = 15.0,
                  min_markers: int = 1, min_frames: int = MIN_POSES) -> SweepData:
    """Check one sweep (one joint moving, far enough, enough markers) and select its markers.

    ``rec`` is a :class:`mocap.io.recording.MarkerRecording`, ``log`` a
    :class:`mocap.io.robotlog.RobotLog` (in URDF joints), ``markers`` the campaign's link ->
    labels map. A sweep is continuous or stop-and-go (one marker row per pose, log rows at the
    same instants): a marker is used when it is seen in at least ``min_frames`` frames (poses).
    """
    mpath, lpath = rec.source, log.source
    n = chain.n
    if not 1 <= joint <= n:
        raise InputError(f"calibration sweep of joint {joint}, but the robot has {n} joints", path=lpath)
    # restrict the log to the marker recording's time span (plus a little) when they overlap
    span = (log.time >= rec.time[0] - 0.05) & (log.time <= rec.time[-1] + 0.05)
    qm = log.qm[span] if span.sum() >= 2 else log.qm
    fin = np.isfinite(qm)
    has = fin.any(axis=0)
    hi = np.where(fin, qm, -np.inf).max(axis=0)
    lo = np.where(fin, qm, np.inf).min(axis=0)
    rng = np.where(has, np.degrees(hi - lo), np.nan)
    if not np.isfinite(rng[joint - 1]):
        raise InputError(f"the log has no qm_{joint} values for the swept joint {joint}", path=lpath)
    moving = [j + 1 for j in range(n) if np.isfinite(rng[j]) and rng[j] > MOVING_DEG]
    others = [j for j in moving if j != joint]
    if others and joint not in moving:
        desc = ", ".join(f"joint {j} {rng[j - 1]:.1f} deg" for j in others)
        raise InputError(f"calibration sweep of joint {joint}: the log moves {desc}, not joint {joint} "
                         f"({rng[joint - 1]:.1f} deg)", path=lpath)
    if others:
        desc = ", ".join(f"joint {j} {rng[j - 1]:.1f} deg" for j in [joint] + others)
        raise InputError(f"calibration sweep of joint {joint}: more than one joint moves ({desc}); "
                         f"a sweep must move joint {joint} alone with the others held (a joint logged relative to "
                         "another, e.g. J3 on J2, needs [robot] coupling in campaign.toml)", path=lpath)
    if rng[joint - 1] < min_sweep_deg:
        raise InputError(f"calibration sweep of joint {joint} covers only {rng[joint - 1]:.1f} deg; "
                         f"the axis fit needs at least {min_sweep_deg:g} deg", path=lpath)
    q_held = np.array([np.median(qm[fin[:, j], j]) if has[j] else np.nan for j in range(n)])
    missing_q = [j + 1 for j in range(joint - 1) if not np.isfinite(q_held[j])]
    if missing_q:
        raise InputError(f"the log has no qm_{missing_q[0]} values; joint {joint}'s axis line in the "
                         "base frame depends on it", path=lpath)
    q_held = np.where(np.isfinite(q_held), q_held, 0.0)
    links = moving_links(chain, joint, markers)
    labels = [lb for lk in links for lb in markers[lk] if lb in rec.labels]
    vis_counts = {lb: int(np.all(np.isfinite(rec.marker(lb)), axis=1).sum()) for lb in labels}
    usable = [lb for lb in labels if vis_counts[lb] >= min_frames]
    if len(usable) < min_markers:
        listed = [lb for lk in links for lb in markers[lk]]
        detail = ", ".join(f"{lb} ({vis_counts[lb]} frames)" if lb in vis_counts else f"{lb} (not in file)"
                           for lb in listed) or "none listed in [markers]"
        raise InputError(f"calibration sweep of joint {joint}: only {len(usable)} markers on the links it "
                         f"moves ({', '.join(links) or 'none'}) are seen in at least {min_frames} frames; "
                         f"need {min_markers}. Markers: {detail}", path=mpath)
    sub = rec.select(usable)
    check_marker_units(sub.positions, tuple(usable), chain, mpath, joint)
    inside = (rec.time >= log.time[0]) & (rec.time <= log.time[-1])
    q_frames = np.stack([np.interp(rec.time, log.time, np.where(np.isfinite(log.qm[:, j]), log.qm[:, j], 0.0))
                         for j in range(n)], axis=1)
    q_frames[~inside] = np.nan
    return SweepData(joint=joint, time=rec.time, positions=sub.positions, labels=tuple(usable),
                     q_held=q_held, q_joint=q_frames[:, joint - 1].copy(), range_deg=float(rng[joint - 1]),
                     links=tuple(lk for lk in links if any(lb in usable for lb in markers[lk])),
                     markers_path=mpath, log_path=lpath, q_frames=q_frames)


def load_sweeps(campaign, robot, min_sweep_deg: float = 15.0, joints=(1, 2)) -> list:
    """Read and check the campaign's calibration sweeps of ``joints``."""

    found = {c.joint: c for c in campaign.calib}
    missing = [j for j in joints if j not in found]
    if missing:
        have = ", ".join(str(j) for j in sorted(found)) or "none"
        raise InputError(f"no [[calib]] entry for joint {' and '.join(map(str, missing))} (found: {have}); "
                         f"placing the base needs sweeps of joints {' and '.join(map(str, joints))}",
                         path=campaign.manifest)
    out = []
    for j in joints:
        c = found[j]
        with warnings.catch_warnings():
            # a reflector missing from a whole sweep is reported by the marker check below; numpy's
            # nan-reductions over its empty column must not leak "All-NaN slice" warnings
            warnings.filterwarnings("ignore", message="All-NaN slice", category=RuntimeWarning)
            rec = campaign.read_markers(c, robot)
            log = campaign.read_log(c, robot)
        out.append(prepare_sweep(j, rec, log, robot.chain, campaign.markers, min_sweep_deg))
    return out


def rotation_sense(sw: SweepData, point: np.ndarray, direction: np.ndarray) -> float:
    """+1 when the markers turn positively about ``direction`` as the logged angle grows: each
    marker's angle about the axis against the log's angle at the same frames (any number of
    markers; markers far from the axis count more)."""
    th = marker_angles(sw.positions, point, direction)             # (T, M)
    d = sw.positions - point
    rad = np.nanmedian(np.linalg.norm(d - (d @ direction)[..., None] * direction, axis=2), axis=0)
    score, n_used = 0.0, 0
    for k in range(th.shape[1]):  # loop over markers (few)
        ok = np.isfinite(th[:, k]) & np.isfinite(sw.q_joint)
        if ok.sum() < 2:
            continue
        a, b = th[ok, k] - th[ok, k].mean(), sw.q_joint[ok] - sw.q_joint[ok].mean()
        score += rad[k] ** 2 * float(a @ b)
        n_used += 1
    if n_used == 0:
        raise InputError(f"sweep of joint {sw.joint}: no marker frame falls inside the log's time span; "
                         "cannot tell the direction of rotation", path=sw.markers_path)
    return 1.0 if score >= 0 else -1.0


def fit_axes(sweeps, method: str = "auto", noise_mm: float | None = None, frame_step: int = 1,
             **options) -> list:
    """Fit each sweep's axis with ``method`` and orient it with the joint's positive rotation."""
    if method not in ESTIMATORS:
        raise InputError(f"unknown calibration method {method!r} (expected one of {', '.join(ESTIMATORS)})")
    est = ESTIMATORS[method](noise_mm=noise_mm, **options)

    def one(sw):
        f: AxisFit = est.fit(sw.positions[::frame_step], sw.labels)
        sub = SweepData(sw.joint, sw.time[::frame_step], sw.positions[::frame_step], sw.labels, sw.q_held,
                        sw.q_joint[::frame_step], sw.range_deg, sw.links, sw.markers_path, sw.log_path)
        return f.with_joint(sw.joint, flip=rotation_sense(sub, f.point, f.direction) < 0)

    sweeps = list(sweeps)
    if len(sweeps) < 2:
        return [one(sw) for sw in sweeps]
    # the sweeps' fits are independent: one thread each (their large array products release
    # the interpreter lock), the same numbers as one after the other
    from concurrent.futures import ThreadPoolExecutor

    with ThreadPoolExecutor(len(sweeps)) as pool:
        return list(pool.map(one, sweeps))


#: below this p-value of Bartlett's test the sweeps' noise variances differ and are not pooled (small: with a
#: few poses per sweep, variances 10-100x apart arise by chance from the same noise)
POOL_P = 1e-4


def pool_noise(fits, p_min: float = POOL_P) -> list:
    r"""The axis fits with one noise variance estimated from all their residuals, where the
    sweeps' own estimates agree.

    Each fit's covariance is ``s_j^2 H_j^-1`` with ``s_j^2`` the per-coordinate residual variance
    of its own fit on ``nu_j`` degrees of freedom. The sweeps are measured by the same instrument
    and markers, so the noise is one: the pooled variance
    ``s^2 = sum_j nu_j s_j^2 / sum_j nu_j`` on ``sum_j nu_j`` degrees of freedom (the pooled
    estimate of a one-way layout) replaces each ``s_j^2``. With a few stop-and-go poses per
    sweep (2-10 degrees of freedom each) a single sweep's variance is often several times too
    small, and the base solve then trusts that axis's line beyond what it holds; pooled, the
    estimate is steadier and the weights of the base solve no longer follow its chance.
    Bartlett's test (Snedecor & Cochran 1989, sec. 13.6) checks that the variances agree: below
    ``p_min`` (the noise differs between the sweeps) the fits are returned unchanged, as are
    fits without a residual-based variance (infinite ``dof``: the noise given).

    Parameters
    ----------
    fits : sequence of calib.axis.AxisFit
        The fitted axes.
    p_min : float, optional
        Bartlett p-value below which the variances are kept apart; default :data:`POOL_P`.

    Returns
    -------
    list of calib.axis.AxisFit
        The fits with covariance ``s^2 H_j^-1``, ``sigma_mm`` and ``dof`` of the pooled variance
        and ``extra["noise_pooled"]`` True (:func:`calib.base.place_base` then counts the one
        variance once in the degrees of freedom of the 95 % region).
    """
    from scipy.stats import chi2 as chi2_dist

    fits = list(fits)
    nu = np.array([f.dof for f in fits], float)
    if len(fits) < 2 or not np.all(np.isfinite(nu) & (nu > 0)):
        return fits
    s2 = np.array([(f.sigma_mm * 1e-3) ** 2 / 3.0 for f in fits])
    if not np.all(s2 > 0):
        return fits
    N = nu.sum()
    pooled = float(np.sum(nu * s2) / N)
    # Bartlett: (N ln s^2 - sum nu_j ln s_j^2) / (1 + (sum 1/nu_j - 1/N) / (3 (k - 1))) ~ chi2(k - 1)
    k = len(fits)
    stat = (N * np.log(pooled) - np.sum(nu * np.log(s2))) / (1.0 + (np.sum(1.0 / nu) - 1.0 / N) / (3.0 * (k - 1)))
    if chi2_dist.sf(stat, k - 1) < p_min:
        return fits
    sig = float(1e3 * np.sqrt(3.0 * pooled))
    return [replace(f, cov=f.cov * (pooled / s), sigma_mm=sig, dof=float(N),
                    extra={**f.extra, "noise_pooled": True, "own_sigma_mm": f.sigma_mm, "own_dof": f.dof})
            for f, s in zip(fits, s2)]


#: largest relative difference between the rotation the markers show and the logged swept angle
SCALE_TOL = 0.015
#: a URDF is implausible for the markers when a marker link's origin lies further than this
#: factor times the markers' radius (plus URDF_SLACK_M) from the swept axis
URDF_SCALE_FACTOR = 10.0
URDF_SLACK_M = 1.0


def angle_ratio(sw: SweepData, fit: AxisFit) -> float:
    """The markers' rotation about the fitted axis per unit of logged angle: the least-squares
    slope of each marker's angle on the swept joint's logged angle, pooled over the markers with
    weights ``radius^2`` (1 when the log's scale is right; the axis is oriented with the log)."""
    th = marker_angles(sw.positions, fit.point, fit.direction)              # (T, M)
    d = sw.positions - fit.point
    rad = np.linalg.norm(d - (d @ fit.direction)[..., None] * fit.direction, axis=2)
    num = den = 0.0
    for k in range(th.shape[1]):  # loop over markers (few)
        ok = np.isfinite(th[:, k]) & np.isfinite(sw.q_joint)
        if ok.sum() < 2:
            continue
        a, b = th[ok, k] - th[ok, k].mean(), sw.q_joint[ok] - sw.q_joint[ok].mean()
        w = float(np.median(rad[ok, k])) ** 2
        num += w * float(a @ b)
        den += w * float(b @ b)
    return num / den if den > 0 else float("nan")


def angle_ratio_std(sw: SweepData, fit: AxisFit) -> float:
    """Standard uncertainty of :func:`angle_ratio` from the fitted axis's own uncertainty: the
    ratio's first-order change with the axis's chart coordinates (central differences), through
    the axis covariance ``fit.cov``. It is large where the markers turn close to the axis (a
    reflector a few millimetres off it): the angles about an axis known to a few degrees are
    then no measure of the log's scale."""
    G = np.zeros(4)
    scale = np.sqrt(np.maximum(np.diag(fit.cov), 1e-20))
    for i in range(4):  # loop over the 4 chart coordinates
        e = np.zeros(4)
        e[i] = 1e-3 * scale[i]
        vals = []
        for sgn in (1.0, -1.0):
            q, m = chart_line(sgn * e, fit.point, fit.direction, *fit.basis)
            vals.append(angle_ratio(sw, replace(fit, point=q, direction=m)))
        G[i] = (vals[0] - vals[1]) / (2 * e[i])
    var = float(G @ fit.cov @ G)
    return float(np.sqrt(var)) if np.isfinite(var) else 0.0


def check_angle_scale(sweeps, fits, tol: float = SCALE_TOL) -> None:
    """Refuse a sweep whose logged angle does not turn as the markers do: the ratio off 1 by
    more than ``tol`` plus 3 standard uncertainties of the ratio (:func:`angle_ratio_std`)."""
    for sw, f in zip(sweeps, fits):
        k = angle_ratio(sw, f)
        if np.isfinite(k) and abs(k - 1.0) > tol and abs(k - 1.0) > tol + 3.0 * angle_ratio_std(sw, f):
            enc = float(np.nanmax(sw.q_joint) - np.nanmin(sw.q_joint))
            raise InputError(f"calibration sweep of joint {sw.joint}: the markers turn {np.degrees(k * enc):.2f} deg "
                             f"while the logged angle qm_{sw.joint} sweeps {np.degrees(enc):.2f} deg (measured "
                             f"ratio markers/encoder {k:.4f}, {100 * (k - 1):+.1f} %): the log's angle scale is "
                             "off (gear ratio, [robot] coupling or units)", path=sw.log_path)


def check_urdf_scale(sweeps, fits, chain, urdf_path=None) -> None:
    """Refuse a URDF whose lengths cannot hold the marker cloud: a marker link's origin far
    further from the swept axis than its markers turn (units suspected, e.g. a URDF in mm)."""
    for sw, f in zip(sweeps, fits):
        p, d = chain.joint_axis_lines(sw.q_held)
        p, d = p[sw.joint - 1], d[sw.joint - 1]
        radii = list(f.marker_radius_m.values())
        if not radii:
            continue
        r_m = float(np.median(radii))
        for lk in sw.links:
            o = chain.frame_transform(lk, sw.q_held)[:3, 3]
            v = o - p
            d_u = float(np.linalg.norm(v - (v @ d) * d))
            if d_u > URDF_SCALE_FACTOR * r_m + URDF_SLACK_M:
                raise InputError(f"calibration sweep of joint {sw.joint}: the URDF puts {lk}'s origin "
                                 f"{d_u:.4g} m from joint {sw.joint}'s axis while its markers turn at "
                                 f"{r_m:.4g} m (ratio {d_u / max(r_m, 1e-9):.3g}): the URDF's lengths do not "
                                 "fit the marker cloud (units suspected: a URDF in millimetres?)",
                                 path=urdf_path if urdf_path is not None else sw.markers_path)


def _on_link(x_base: np.ndarray, T_link: np.ndarray) -> np.ndarray:
    """Points ``(T, M, 3)`` of the base frame in their link's frame at each frame's pose
    ``T_link`` ``(T, 4, 4)``: ``R^T (x - p)``."""
    return np.einsum("tji,tmj->tmi", T_link[:, :3, :3], x_base - T_link[:, None, :3, 3])


def _hypothesis_q(sw: SweepData, q: np.ndarray, flip) -> np.ndarray:
    """Angles ``q`` (..., n) of sweep ``sw`` under a sign hypothesis ``flip``: pairs ``(joint,
    mode)`` (a bare joint number is ``"held"``): ``"held"`` mirrors the joint's logged angle about
    its held value (in every sweep: a constant angle stays), ``"zero"`` negates it in the joint's
    own sweep (the log written with the opposite sign), ``"zero-all"`` in every sweep (the
    controller's convention opposite for all logs)."""
    q = np.array(q, float, copy=True)
    for item in flip:
        j, mode = (item, "held") if np.isscalar(item) else item
        if mode == "held":
            q[..., j - 1] = 2 * sw.q_held[j - 1] - q[..., j - 1]
        elif mode == "zero-all" or (mode == "zero" and sw.joint == j):
            q[..., j - 1] = -q[..., j - 1]
    return q


def marker_offset_m(sweeps, chain, T_camera_base, flip=()) -> float:
    """Median distance of the markers from their link's origin (link frame, averaged over the
    poses) when the base is ``T_camera_base`` and the logged angles follow the sign hypothesis
    ``flip`` (:func:`_hypothesis_q`; a bare joint number mirrors its angle about its held
    value)."""
    Tinv = np.linalg.inv(T_camera_base)
    out = []
    for sw in sweeps:
        if sw.q_frames is None:
            continue
        q = _hypothesis_q(sw, sw.q_frames, flip)
        ok = np.all(np.isfinite(q), axis=1)
        if ok.sum() < 1:
            continue
        xb = sw.positions[ok] @ Tinv[:3, :3].T + Tinv[:3, 3]                # (T, M, 3) base frame
        for lk in sw.links:
            s = _on_link(xb, chain.frame_transform(lk, q[ok]))
            seen = np.all(np.isfinite(s), axis=2)                            # (T, M)
            for k in np.flatnonzero(seen.any(axis=0)):  # loop over markers (few)
                out.append(float(np.linalg.norm(np.median(s[seen[:, k], k], axis=0))))
    out = np.asarray(out, float)
    out = out[np.isfinite(out)]
    return float(np.median(out)) if out.size else float("nan")


def check_angle_sign(sweeps, fits, chain, lines, base: BasePlacement) -> None:
    """Refuse a log whose swept angle turns the wrong way: with the sign of a joint's logged angle
    flipped the base turns 180 deg and the axis lines fit as well, but the markers end up far
    from the links they sit on. Each sign hypothesis is solved - the joint's logged angle
    mirrored about its held value, negated in its own sweep's log, or negated in every log (then
    the later joints' URDF lines move with it), for each swept joint and for all together - and
    a log is refused when the best of them puts the markers less than half as far from their
    links' origins (and at least 5 cm closer), whatever the number of markers."""
    if any(sw.q_frames is None for sw in sweeps):
        return
    with np.errstate(all="ignore"):
        here = marker_offset_m(sweeps, chain, base.T_camera_base)
        if not np.isfinite(here):
            return
        joints = [sw.joint for sw in sweeps]
        modes = ("held", "zero", "zero-all")
        hyps = [((j, mode),) for j in joints for mode in modes]
        if len(joints) > 1:
            hyps += [tuple((j, mode) for j in joints) for mode in modes]
        best = None
        for flip in hyps:
            flipped = {j for j, _ in flip}
            alt_fits = [f.with_joint(f.joint, flip=f.joint in flipped) for f in fits]
            alt_lines = lines
            if any(mode == "zero-all" for _, mode in flip):
                alt_lines = []
                for sw in sweeps:
                    p, d = chain.joint_axis_lines(_hypothesis_q(sw, sw.q_held, flip))
                    alt_lines.append((p[sw.joint - 1], d[sw.joint - 1]))
            try:
                alt = place_base(alt_fits, alt_lines, with_region=False)
            except InputError:
                continue
            there = marker_offset_m(sweeps, chain, alt.T_camera_base, flip)
            if np.isfinite(there) and (best is None or there < best[1]):
                best = (flip, there)
    if best is not None and best[1] < 0.5 * here and here - best[1] > 0.05:
        flip, there = best
        flipped = [j for j, _ in flip]
        sw = next(s for s in sweeps if s.joint == flipped[0])
        which = " and ".join(f"qm_{j}" for j in flipped)
        ratio = angle_ratio(sw, fits[joints.index(sw.joint)])
        verb = "turns" if len(flip) == 1 else "turn"
        raise InputError(f"calibration sweep of joint {sw.joint}: the logged {which} {verb} "
                         f"opposite to the markers (measured ratio markers/encoder {-ratio:.4f}): with the "
                         f"sign as logged the markers sit {here:.3f} m from their links' origins, {there:.3f} m "
                         "with it flipped (sign flipped in the log or in [robot] coupling?)", path=sw.log_path)


def calibrate_sweeps(sweeps, chain, method: str = "auto", noise_mm: float | None = None,
                     frame_step: int = 1, urdf_path=None, checks: bool = True, urdf_tol_mm: float = 0.0,
                     urdf_model_error: bool = True, **options) -> CalibResult:
    """Axes from prepared sweeps, then the base from the URDF axis lines (no file I/O).

    The thesis's camera-to-base step [1]_, generalised: each sweep's axis is fitted with
    ``method`` and oriented with the joint's positive rotation (:func:`fit_axes`), the URDF
    gives the same joints' axis lines in the base frame at the held encoder angles, and
    :func:`calib.base.place_base` maps those onto the measured ones. ``checks`` runs the
    boundary checks that refuse silent mistakes (exit 2) [2]_: the logged swept angle against
    the markers' rotation (:func:`check_angle_scale`), the URDF's lengths against the marker
    cloud (:func:`check_urdf_scale`) and the sign of the logged angles
    (:func:`check_angle_sign`).

    Parameters
    ----------
    sweeps : sequence of SweepData
        Prepared sweeps (:func:`prepare_sweep`), the J1-J2 pair first.
    chain : mocap.kinematics.Chain
        The kinematic chain (URDF), for the axis lines in the base frame.
    method : {"auto", "cluster", "circle"}, optional
        The axis estimator (``ESTIMATORS``); default ``"auto"``.
    noise_mm : float or None, optional
        3-D RMS marker noise for the Cramer-Rao bound (mm); None: estimated from the residuals.
    frame_step : int, optional
        Use every ``frame_step``-th frame; default 1.
    urdf_path : str or pathlib.Path, optional
        The URDF, named by the URDF-scale check's message.
    checks : bool, optional
        Run the boundary checks; default True.
    urdf_tol_mm : float, optional
        Standard uncertainty of the URDF's axis placement (mm; see
        :func:`calib.base.place_base`); default 0.
    urdf_model_error : bool, optional
        False leaves out the model error estimated from the J1-J2 discrepancy (the URDF's J1-J2
        geometry trusted as exact: more precise when it is, biased when it is not [2]_);
        default True.
    **options
        Settings of the axis estimator (e.g. ``robust``, ``min_frames``).

    Returns
    -------
    CalibResult
        ``T_camera_base``, the axes, the base solve and the sweeps.

    Raises
    ------
    mocap.io.errors.InputError
        If ``urdf_tol_mm`` is not a finite length >= 0, ``method`` is unknown, an axis fit or
        the base solve cannot run on the data, or a boundary check refuses a sweep.

    References
    ----------
    .. [1] PA10 thesis (seeds 002), sec. 3.2 (Estimation of Link Position).
    .. [2] jointlab calibration (docs/calibration.md), the checks and the model error.
    """
    if not (np.isfinite(urdf_tol_mm) and urdf_tol_mm >= 0):
        raise InputError(f"--urdf-tol-mm must be a finite length >= 0 (mm), got {urdf_tol_mm}")
    fits = pool_noise(fit_axes(sweeps, method, noise_mm, frame_step, **options))
    if checks:
        check_urdf_scale(sweeps, fits, chain, urdf_path)
        check_angle_scale(sweeps, fits)
    lines = []
    for sw in sweeps:
        p, d = chain.joint_axis_lines(sw.q_held)
        lines.append((p[sw.joint - 1], d[sw.joint - 1]))
    base = place_base(fits, lines, urdf_tol_m=1e-3 * urdf_tol_mm, model_error=urdf_model_error)
    if checks:
        check_angle_sign(sweeps, fits, chain, lines, base)
    return CalibResult(base.T_camera_base, tuple(fits), base, method, noise_mm, tuple(sweeps))


def check_deflection_stiffness(campaign, robot=None) -> None:
    """``--deflection`` needs a declared joint stiffness (drives.toml ``stiffness``): raise
    :class:`mocap.io.errors.InputError` naming the drives file (or campaign.toml) when none is."""
    robot = robot if robot is not None else campaign.load_robot()
    if not np.any(robot.stiffness > 0):
        raise InputError("--deflection needs the joints' stiffness in drives.toml (stiffness = K, N m/rad): "
                         "none is declared", path=campaign.drives or campaign.root / "campaign.toml")


def compensate_deflection(sweeps, robot, markers: dict, T_camera_base: np.ndarray) -> tuple:
    """The sweeps with each marker moved to where it would be if the joints a sweep does not
    move kept their motor-side (logged) angles, undoing their static deflection under gravity.

    A joint of declared stiffness ``K`` (drives.toml) gives under the torque it carries,
    ``q_link - q_motor = -tau(q) / K`` (thesis eq. 2-1; :meth:`mocap.robot.Robot.held_deflection`,
    first order, at the logged angles). Sweeping joint 2 changes the gravity torque on the joints
    beyond it, so a marker on a distal link leaves the circle about the swept axis by the
    changing deflection, and the logged angles do not show it. With the marker's position ``r``
    on its link from a first placement ``T_camera_base`` (median over the frames), the shift of
    frame ``i`` is ``T_link(q_r,i) r - T_link(q_l,i) r`` (base frame, turned into the camera
    frame), with ``q_l`` the deflected angles and ``q_r`` the logged ones except the swept
    joint's (its own deflection only moves the marker along its circle).

    Parameters
    ----------
    sweeps : sequence of SweepData
        Prepared sweeps (with ``q_frames``).
    robot : mocap.robot.Robot
        The robot (URDF inertia for the torques, drives.toml stiffness).
    markers : dict
        The campaign's link -> marker labels.
    T_camera_base : numpy.ndarray
        (4, 4) first placement of the base.

    Returns
    -------
    tuple
        (sweeps with compensated positions, largest shift in mm).
    """
    Tinv = np.linalg.inv(T_camera_base)
    R = T_camera_base[:3, :3]
    out, largest = [], 0.0
    for sw in sweeps:   # loop over the sweeps (two), vectorised over frames
        if sw.q_frames is None:
            out.append(sw)
            continue
        ok = np.all(np.isfinite(sw.q_frames), axis=1)
        qm = sw.q_frames[ok]
        ql = qm + robot.held_deflection(qm)
        qr = qm.copy()
        qr[:, sw.joint - 1] = ql[:, sw.joint - 1]
        pos = sw.positions.copy()
        xb = sw.positions[ok] @ Tinv[:3, :3].T + Tinv[:3, 3]                 # (T, M, 3) base frame
        for lk in sw.links:
            on_link = set(markers.get(lk, ()))
            idx = [k for k, lb in enumerate(sw.labels) if lb in on_link]
            if not idx:
                continue
            Tl, Tr = robot.chain.frame_transform(lk, ql), robot.chain.frame_transform(lk, qr)
            loc = _on_link(xb[:, idx], Tl)
            with warnings.catch_warnings():
                warnings.filterwarnings("ignore", message="All-NaN slice", category=RuntimeWarning)
                r = np.nanmedian(loc, axis=0)                                    # (K, 3) on the link
            shift = (np.einsum("tij,kj->tki", Tr[:, :3, :3] - Tl[:, :3, :3], r)
                     + (Tr[:, None, :3, 3] - Tl[:, None, :3, 3]))                # (T, K, 3) base
            block = pos[ok]
            block[:, idx] += shift @ R.T
            pos[ok] = block
            if np.isfinite(shift).any():
                largest = max(largest, float(1e3 * np.nanmax(np.linalg.norm(shift, axis=2))))
        out.append(replace(sw, positions=pos))
    return tuple(out), largest


def handeye_cross_check(sweeps, chain, markers: dict, link: str | None = None):
    """The hand-eye / robot-world peer (:class:`calib.handeye.HandEyeEstimator`) on the same
    sweeps: the most distal link with at least 3 markers seen in every sweep, all encoder angles."""

    if link is None:
        cands = [lk for lk in markers if lk in chain.frames
                 and all(sum(lb in sw.labels for lb in markers[lk]) >= 3 for sw in sweeps)]
        if not cands:
            raise InputError("hand-eye cross-check: no link has 3 markers seen in every sweep")
        link = max(cands, key=lambda lk: chain.frames[lk][0])
    labels = [lb for lb in markers[link] if all(lb in sw.labels for sw in sweeps)]
    P = np.concatenate([sw.positions[:, [sw.labels.index(lb) for lb in labels]] for sw in sweeps])
    Q = np.concatenate([sw.q_frames for sw in sweeps])
    return HandEyeEstimator().fit(chain, link, P, Q, labels)


def calibrate(campaign, robot=None, method: str = "auto", sink=None,
              noise_mm: float | None = None, min_sweep_deg: float = 15.0, joints=(1, 2),
              cross_check: bool = False, urdf_tol_mm: float = 0.0, deflection: bool = False,
              **options) -> CalibResult:
    """Calibrate ``T_camera_base`` for a loaded campaign (:func:`mocap.io.campaign.load_campaign`).

    Reads every ``[[calib]]`` entry of ``joints`` [2]_, checks that each sweep moves its joint
    alone over at least ``min_sweep_deg`` (:func:`prepare_sweep`), fits the joint axes from the
    markers on the links each joint carries and places the base with the URDF's axis lines at
    the encoder angles held during each sweep (:func:`calibrate_sweeps`): the thesis's
    intersection of the axes of joints 1 and 2 [1]_, generalised to offset axes and weighted by
    the axes' covariances [3]_.

    Parameters
    ----------
    campaign : mocap.io.campaign.Campaign
        The loaded campaign.
    robot : mocap.robot.Robot, optional
        The robot; default ``campaign.load_robot()``.
    method : {"auto", "cluster", "circle"}, optional
        ``"cluster"`` (rigid-cluster screw axis + ML refinement), ``"circle"`` (per-marker
        Halvorsen circles + common-axis refinement; one marker: the circle-point method) or
        ``"auto"`` (default: cluster with 3 or more markers, circle with fewer).
    sink : viz.Sink, optional
        Receives the marker arcs, the fitted axes and the base frame.
    noise_mm : float or None, optional
        3-D RMS marker noise (mm) of the Cramer-Rao bound; None (default) estimates it from the
        residuals.
    min_sweep_deg : float, optional
        Smallest encoder range a sweep must cover (deg); default 15.
    joints : sequence of int, optional
        The swept joints, 1-based; default ``(1, 2)``.
    cross_check : bool, optional
        Add the hand-eye peer's solve (:class:`calib.handeye.HandEyeEstimator`) and its
        difference under ``extra["handeye"]``; default False.
    urdf_tol_mm : float, optional
        Standard uncertainty of the URDF's axis placement (mm); default 0.
    deflection : bool, optional
        Undo the joints' static deflection under gravity at the stiffness declared in
        drives.toml (:func:`compensate_deflection`: a first placement, the markers moved, a
        second placement); default False.
    **options
        Passed to :func:`calibrate_sweeps` (``frame_step``, ``checks``, ``urdf_model_error``,
        estimator settings).

    Returns
    -------
    CalibResult
        ``T_camera_base``, the axes, the base solve and the sweeps.

    Raises
    ------
    mocap.io.errors.InputError
        If a sweep of ``joints`` is missing or refused (another joint moves, too short a sweep,
        too few markers, a log or URDF that does not fit the markers); the message names the
        file.

    References
    ----------
    .. [1] PA10 thesis (seeds 002), sec. 3.2 (Estimation of Link Position).
    .. [2] jointlab data format (docs/format.md), sec. campaign.toml.
    .. [3] jointlab calibration (docs/calibration.md).
    """
    if robot is None:
        robot = campaign.load_robot()
    sweeps = load_sweeps(campaign, robot, min_sweep_deg, joints)
    if deflection:
        check_deflection_stiffness(campaign, robot)
    settings = dict(urdf_path=getattr(robot, "urdf", None), urdf_tol_mm=urdf_tol_mm, **options)
    result = calibrate_sweeps(sweeps, robot.chain, method, noise_mm, **settings)
    if deflection:
        sweeps, shift_mm = compensate_deflection(sweeps, robot, campaign.markers, result.T_camera_base)
        result = calibrate_sweeps(sweeps, robot.chain, method, noise_mm, **settings)
        result = replace(result, extra={**dict(result.extra),
                                        "deflection": {"compensated": True, "largest_shift_mm": shift_mm}})
    if cross_check:
        result = _with_handeye_check(result, sweeps, robot.chain, campaign.markers)
    if sink is not None:
        log_calibration(sink, result)
    return result


def _with_handeye_check(result: CalibResult, sweeps, chain, markers) -> CalibResult:
    """``result`` with the hand-eye cross-check (:func:`handeye_cross_check` on the same
    ``sweeps``) and its difference from the axis calibration in ``extra["handeye"]``."""
    he = handeye_cross_check(sweeps, chain, markers)
    dp, dr = pose_errors(he.T_camera_base, result.T_camera_base)
    extra = dict(result.extra)
    extra["handeye"] = {**he.to_dict(), "difference_origin_mm": dp, "difference_rotation_deg": dr}
    return CalibResult(result.T_camera_base, result.axes, result.base, result.method,
                       result.noise_mm, result.sweeps, extra)


def log_calibration(sink, result: CalibResult, prefix: str = "calib") -> None:
    """Marker arcs, fitted axes (camera frame) and the base frame, through a :class:`viz.Sink`."""
    for sw, f in zip(result.sweeps, result.axes):
        root = f"{prefix}/joint-{sw.joint}"
        sink.points_over_time(f"{root}/markers", sw.time, sw.positions, labels=list(sw.labels))
        strips = []
        for k in range(sw.positions.shape[1]):
            x = sw.positions[:, k]
            x = x[np.all(np.isfinite(x), axis=1)]
            if len(x) > 1:
                strips.append(x[:: max(1, len(x) // 400)])
        sink.lines(f"{root}/arcs", strips)
        sink.lines(f"{root}/axis", [np.stack([f.point - 0.6 * f.direction, f.point + 0.6 * f.direction])])
        sink.arrows(f"{root}/axis_direction", f.point[None], 0.2 * f.direction[None],
                    labels=[f"joint {sw.joint}: {f.rms_mm:.2f} mm rms"])
    sink.transform(f"{prefix}/base", result.T_camera_base)
    sink.arrows(f"{prefix}/base/frame", np.zeros((3, 3)), 0.25 * np.eye(3), labels=["x", "y", "z"],
                colors=np.array([[230, 60, 60], [60, 200, 60], [60, 90, 230]], dtype=np.uint8))
    sink.text(f"{prefix}/summary", summary_markdown(result))


def summary_markdown(result: CalibResult, warnings: bool = True) -> str:
    """The calibration's summary (markdown); ``warnings`` appends the warnings (the command line
    prints them once, on stderr, and passes False)."""
    b = result.base
    T = result.T_camera_base
    noise = (f"{result.noise_used_mm:.4f} mm (given)" if result.noise_mm is not None
             else f"{result.noise_used_mm:.4f} mm (estimated from the residuals)")
    chi = (f"chi2 = {b.chi2:.2f} on {b.dof} dof (chi2/dof {b.chi2 / b.dof:.2f}, p = {b.p_value:.2g})"
           if b.dof > 0 else f"chi2 = {b.chi2:.2f} (no redundancy)")
    lines = [f"## Camera-to-base calibration ({result.method})", "",
             "T_camera_base (p_camera = T @ p_base, metres):", "```"]
    lines += ["  ".join(f"{x:+.6f}" for x in row) for row in T]
    lines += ["```", "",
              "| | estimate std | Cramer-Rao bound |", "|---|---|---|",
              f"| origin (mm, 3-D RMS) | {b.origin_std_mm:.4f} | {b.crb_origin_mm:.4f} |",
              f"| rotation (deg) | {b.rotation_std_deg:.5f} | {b.crb_rotation_deg:.5f} |"]
    if b.budget:
        for name, what in (("noise", "of which marker noise"), ("model_error", "of which URDF model error")):
            if name == "model_error" and b.urdf_trusted and b.model_error_mm == 0:
                lines.append(f"| {what} (mm / deg) | not estimated (--trust-urdf) | |")
                continue
            lines.append(f"| {what} (mm / deg) | {b.budget[name]['origin_std_mm']:.4f} / "
                         f"{b.budget[name]['rotation_std_deg']:.5f} | |")
    lines += ["",
              f"marker noise {noise}; base solve {chi}, "
              f"{'converged' if b.converged else 'NOT converged'} in {b.iterations} evaluations"
              + (f"; URDF model error {b.model_error_mm:.3f} mm and {b.model_error_deg:.4f} deg per axis line "
                 f"(docs/calibration.md), std x{b.inflation:.2f}" if b.model_error_mm > 0 else "")
              + ("; the URDF's J1-J2 geometry trusted (--trust-urdf): no model error estimated"
                 if b.urdf_trusted else "")
              + (f"; the joints' static deflection under gravity undone at the declared stiffness "
                 f"(--deflection): markers moved by up to {result.extra['deflection']['largest_shift_mm']:.3f} mm"
                 if result.extra.get("deflection") else ""), ""]
    reg = b.region95 or {}
    if reg:
        dof = {k: reg.get(f"{k}_dof") for k in ("origin", "rotation", "pose")}
        lines += [f"95 % region: Mahalanobis^2 of the origin <= {reg['origin_d2']:.2f}, rotation <= "
                  f"{reg['rotation_d2']:.2f}, 6-D pose <= {reg['pose_d2']:.2f} (effective dof "
                  + ", ".join("inf" if v is None else f"{v:.1f}" for v in dof.values())
                  + f"); one coordinate: +-{reg['origin_k95']:.2f} std", ""]
    lines += ["| joint | method | rms (mm) | sweep (deg) | markers | frames | point std (mm) | dir std (deg) "
              "| iterations |", "|---|---|---|---|---|---|---|---|---|"]
    for f in result.axes:
        lines.append(f"| {f.joint} | {f.method} | {f.rms_mm:.3f} | {f.sweep_deg:.1f} | {len(f.marker_rms_mm)} | "
                     f"{f.n_frames} | {f.point_std_mm:.4f} | {f.direction_std_deg:.5f} | "
                     f"{f.iterations}{'' if f.converged else ' (NOT converged)'} |")
    lines += ["", f"measured axes {b.axis_distance_mm:.3f} mm apart at {b.axis_angle_deg:.3f} deg; "
              f"URDF {b.urdf_axis_distance_mm:.3f} mm at {b.urdf_axis_angle_deg:.3f} deg"]
    if warnings:
        lines += [f"\nwarning: {w}" for w in result.warnings]
    return "\n".join(lines)
