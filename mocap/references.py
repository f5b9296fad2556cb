"""Static-pose marker references (thesis eq. 3-4), and the camera pose when it is not given.

Eq. 3-4: with the robot still and its encoder angles known, each marker's position in the frame
of the link it is glued to is ``p_link = T_link_base(q_static) T_base_camera p_camera``, averaged
over the static interval. Several static poses are combined by least squares (a weighted mean per
marker), with a per-marker consistency report (spread of the per-pose estimates).

The camera pose ``T_camera_base``. Given (``calib.json`` from ``jointlab calib``), it is used as
is. Not given, it is estimated from the static poses themselves: between two static poses every
marked link moves rigidly, by ``A`` in the camera frame (Kabsch fit of its markers) and by ``B``
in the base frame (forward kinematics of the encoder angles), so ``A X = X B`` with
``X = T_camera_base`` (a hand-eye problem, solved in closed form from the rotation axes), then
refined by least squares over all static markers with the link-frame positions eliminated
(variable projection). This needs at least two static poses that differ in two non-parallel
joints; with fewer the camera pose is not identifiable and :func:`fit_references` says so
instead of returning a wrong frame. Assumption: the static poses are truly static and the link
angle equals the encoder angle there (joint flexibility ignored, as in the thesis).
"""
from __future__ import annotations

import json
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from mocap.io.errors import InputError, read_text
from mocap.kinematics import (apply_transform, invert_transform, kabsch, make_transform,
                              matrix_to_rotvec, rotvec_to_matrix)

MIN_MARKERS_PER_LINK = 3
INCONSISTENT_M = 1e-3  # a marker whose per-pose link-frame estimates spread more has moved or
#                        is mislabelled in one of the static poses (reported, not fatal)


@dataclass(frozen=True, eq=False)
class StaticPose:
    """One static interval reduced to means: ``p_camera`` (M, 3) NaN where never seen."""

    q: np.ndarray             # (n,) encoder angles, link side
    p_camera: np.ndarray      # (M, 3) mean marker positions, camera frame
    n_frames: np.ndarray      # (M,) frames averaged per marker
    scatter_m: np.ndarray     # (M,) RMS distance of the frames from the mean
    q_range: np.ndarray       # (n,) peak-to-peak encoder motion during the interval
    source: str = ""


@dataclass(frozen=True, eq=False)
class References:
    r"""Marker positions in their link frames and the camera pose they were computed with.

    The static-pose references of thesis eq. 3-4 [1]_,

    .. math::

        {}^n P_m^{static} = {}^n T_c^{static}\; {}^c P_m^{static}

    averaged over the static poses (:func:`build_references`); what the per-frame solve of
    eq. 3-5 compares the markers with (:meth:`for_chain`), written as ``references.json`` [2]_.

    Attributes
    ----------
    labels : tuple of str
        The M marker labels.
    links : tuple of str
        The link carrying each marker.
    p_link : numpy.ndarray
        (M, 3) marker positions in their link frames (m).
    T_camera_base : numpy.ndarray
        (4, 4) base pose in the camera frame used.
    camera_source : str
        ``"given"`` or ``"static_poses"`` (estimated from the static poses).
    consistency_m : numpy.ndarray
        (M,) RMS spread of the per-pose estimates (m; NaN for one pose).
    scatter_m : numpy.ndarray
        (M,) within-pose RMS scatter (m; the noise level seen while still).
    n_poses : numpy.ndarray
        (M,) poses in which the marker was seen.
    fit_rms_m : float
        RMS residual of all static markers after the fit (m).
    camera_std : numpy.ndarray or None
        (6,) standard deviation of ``T_camera_base``: rotation (rad), translation (m).
    poses : tuple of StaticPose
        The reduced static poses.
    meta : dict
        Provenance (files, settings).

    References
    ----------
    .. [1] PA10 thesis (seeds 002), eq. 3-4.
    .. [2] jointlab data format (docs/format.md), sec. What the workbench writes.
    """

    labels: tuple[str, ...]
    links: tuple[str, ...]
    p_link: np.ndarray            # (M, 3)
    T_camera_base: np.ndarray     # (4, 4)
    camera_source: str            # "given" or "static_poses"
    consistency_m: np.ndarray     # (M,) RMS spread of the per-pose estimates (NaN for 1 pose)
    scatter_m: np.ndarray         # (M,) within-pose RMS scatter (noise level seen while still)
    n_poses: np.ndarray           # (M,) poses in which the marker was seen
    fit_rms_m: float              # RMS residual of all static markers after the fit
    camera_std: np.ndarray | None = None  # (6,) std of T_camera_base: rotation (rad), translation (m)
    poses: tuple = ()
    meta: dict = field(default_factory=dict)

    def index(self, label: str) -> int:
        try:
            return self.labels.index(label)
        except ValueError:
            raise InputError(f"marker {label!r} has no static reference", label=label) from None

    def for_chain(self, chain, labels=None) -> tuple[np.ndarray, np.ndarray]:
        """``marker_joint`` (M,) and ``p_joint`` (M, 3) for :class:`mocap.solve.MarkerSolver`.

        Parameters
        ----------
        chain : mocap.kinematics.Chain
            The robot's kinematics.
        labels : sequence of str, optional
            Markers to return, in this order; all by default.

        Returns
        -------
        marker_joint : numpy.ndarray
            Joint each marker moves with (-1: the base), (M,).
        p_joint : numpy.ndarray
            Marker positions in that joint's frame (m), (M, 3).
        """
        labels = self.labels if labels is None else tuple(labels)
        mj = np.empty(len(labels), int)
        pj = np.empty((len(labels), 3))
        for k, lb in enumerate(labels):
            i = self.index(lb)
            j, T_jf = chain.frames[self.links[i]]
            mj[k] = j
            pj[k] = apply_transform(T_jf, self.p_link[i])
        return mj, pj

    def to_dict(self) -> dict:
        return {
            "format": 1,
            "T_camera_base": self.T_camera_base.tolist(),
            "camera_source": self.camera_source,
            "camera_std": None if self.camera_std is None else
            {"rotation_deg": [float(np.degrees(x)) for x in self.camera_std[:3]],
             "translation_mm": [float(1e3 * x) for x in self.camera_std[3:]]},
            "fit_rms_mm": float(1e3 * self.fit_rms_m),
            "markers": {lb: {"link": lk, "p_link": [float(x) for x in p],
                             "consistency_mm": None if not np.isfinite(c) else float(1e3 * c),
                             "scatter_mm": float(1e3 * s), "poses": int(n)}
                        for lb, lk, p, c, s, n in zip(self.labels, self.links, self.p_link,
                                                      self.consistency_m, self.scatter_m,
                                                      self.n_poses)},
            "inconsistent_markers": [lb for lb, c in zip(self.labels, self.consistency_m)
                                     if np.isfinite(c) and c > INCONSISTENT_M],
            "poses": [{"source": p.source, "q": [float(x) for x in p.q],
                       "q_range": [float(x) for x in p.q_range]} for p in self.poses],
            **self.meta,
        }


# ---- pure numerics ---------------------------------------------------------------------------
def reduce_static(positions: np.ndarray, reject_m: float = 0.003):
    """Mean marker positions over a still interval (T, M, 3) -> (M, 3), robustly: frames farther
    than ``reject_m`` from the per-axis median are dropped.

    Parameters
    ----------
    positions : numpy.ndarray
        Marker positions over the interval (m), (T, M, 3), NaN where unseen.
    reject_m : float, optional
        Distance from the median beyond which a frame is dropped (m).

    Returns
    -------
    mean : numpy.ndarray
        Mean position of each marker (m), (M, 3), NaN where never seen.
    n_frames : numpy.ndarray
        Frames averaged per marker, (M,).
    scatter : numpy.ndarray
        RMS distance of the kept frames from the mean (m), (M,).

    Examples
    --------
    A 0.5 m outlier among five frames is dropped:

    >>> pos = np.zeros((5, 1, 3))
    >>> pos[:, 0, 0] = [1.0, 1.0, 1.0, 1.0, 1.5]
    >>> mean, n, scatter = reduce_static(pos)
    >>> mean.tolist(), n.tolist(), scatter.tolist()
    ([[1.0, 0.0, 0.0]], [4], [0.0])
    """
    med = np.nanmedian(positions, axis=0) if positions.shape[0] else \
        np.full(positions.shape[1:], np.nan)
    d = np.linalg.norm(positions - med, axis=2)
    keep = np.isfinite(d) & (d < reject_m)
    n = keep.sum(axis=0)
    mean = np.where(n[:, None] > 0, (np.where(keep[..., None], positions, 0.0)).sum(axis=0)
                    / np.maximum(n, 1)[:, None], np.nan)
    dm = np.linalg.norm(positions - mean, axis=2)
    scatter = np.sqrt((np.where(keep, dm, 0.0) ** 2).sum(axis=0) / np.maximum(n - 1, 1))
    return mean, n, np.where(n > 0, scatter, np.nan)


def _link_transforms(chain, links, q):
    """``T_base_link`` (L, 4, 4) for the named links at one q (n,)."""
    Tj = chain.joint_transforms(np.asarray(q, float))
    out = []
    for lk in links:
        j, T_jf = chain.frames[lk]
        out.append(T_jf if j < 0 else Tj[j] @ T_jf)
    return np.array(out)


def estimate_camera_pose(chain, links, poses, min_spread: float = 0.05) -> np.ndarray:
    """Closed-form ``T_camera_base`` from static poses (hand-eye ``A X = X B``, see module doc).

    Parameters
    ----------
    chain : mocap.kinematics.Chain
        The robot's kinematics.
    links : sequence of str
        Link of each marker, (M,).
    poses : list of StaticPose
        At least two static poses.
    min_spread : float, optional
        Smallest rotation between poses that counts (rad).

    Returns
    -------
    numpy.ndarray
        ``T_camera_base`` (4, 4).

    Raises
    ------
    mocap.io.errors.InputError
        When the poses do not move two non-parallel joint axes.
    """
    from scipy.spatial.transform import Rotation

    links = list(links)
    uniq = sorted(set(links))
    alpha, beta, rows_A, rows_b = [], [], [], []
    base = poses[0]
    T0 = dict(zip(uniq, _link_transforms(chain, uniq, base.q)))
    for pose in poses[1:]:
        Tk = dict(zip(uniq, _link_transforms(chain, uniq, pose.q)))
        for lk in uniq:
            idx = [m for m, l2 in enumerate(links) if l2 == lk and
                   np.all(np.isfinite(base.p_camera[m])) and np.all(np.isfinite(pose.p_camera[m]))]
            if len(idx) < 3:
                continue
            A = kabsch(base.p_camera[idx], pose.p_camera[idx])
            B = Tk[lk] @ invert_transform(T0[lk])
            a, b = matrix_to_rotvec(A[:3, :3]), matrix_to_rotvec(B[:3, :3])
            if np.linalg.norm(b) < 1e-3:
                continue
            alpha.append(a)
            beta.append(b)
            rows_A.append(A)
            rows_b.append(B)
    if len(beta) >= 2:
        sv = np.linalg.svd(np.array(beta), compute_uv=False)
        spread = sv[1] / sv[0]
    else:
        spread = 0.0
    if spread < min_spread:
        raise InputError(
            f"T_camera_base cannot be estimated from {len(poses)} static pose(s): they must differ "
            "in at least two non-parallel joints (relative link rotations found: "
            f"{len(beta)}, axis spread {spread:.3f}). Give --calib calib.json, or record more "
            "static poses")
    R, _ = Rotation.align_vectors(np.array(alpha), np.array(beta))
    RX = R.as_matrix()
    M = np.concatenate([A[:3, :3] - np.eye(3) for A in rows_A])
    rhs = np.concatenate([RX @ B[:3, 3] - A[:3, 3] for A, B in zip(rows_A, rows_b)])
    t = np.linalg.lstsq(M, rhs, rcond=None)[0]
    return make_transform(RX, t)


def _project_refs(chain, links, poses, T_cb):
    """Per-pose link-frame estimates (P, M, 3) and the combined weighted mean (M, 3)."""
    uniq = sorted(set(links))
    li = np.array([uniq.index(lk) for lk in links])
    T_bc = invert_transform(T_cb)
    est = []
    for pose in poses:
        T_lb = invert_transform(_link_transforms(chain, uniq, pose.q))[li]  # (M, 4, 4)
        est.append(apply_transform(T_lb, apply_transform(T_bc, pose.p_camera)))
    est = np.array(est)
    w = np.array([np.where(np.all(np.isfinite(e), axis=1), p.n_frames, 0) for e, p in zip(est, poses)],
                 float)
    wsum = w.sum(axis=0)
    mean = np.where(wsum[:, None] > 0, np.nansum(est * w[..., None], axis=0) / np.maximum(wsum, 1)[:, None],
                    np.nan)
    return est, mean, w


def _static_residuals(chain, links, poses, T_cb):
    est, mean, w = _project_refs(chain, links, poses, T_cb)
    uniq = sorted(set(links))
    li = np.array([uniq.index(lk) for lk in links])
    res = []
    for pose, wp in zip(poses, w):
        T_bl = _link_transforms(chain, uniq, pose.q)[li]
        pred = apply_transform(T_cb @ T_bl, mean)
        r = pred - pose.p_camera
        res.append(np.where((wp > 0)[:, None], r * np.sqrt(wp)[:, None], 0.0))
    return np.concatenate(res).ravel()


def refine_camera_pose(chain, links, poses, T_cb0):
    """Least-squares ``T_camera_base`` over all static markers (link positions eliminated).

    Parameters
    ----------
    chain : mocap.kinematics.Chain
        The robot's kinematics.
    links : sequence of str
        Link of each marker, (M,).
    poses : list of StaticPose
        The static poses.
    T_cb0 : numpy.ndarray
        Starting transform (4, 4), e.g. from :func:`estimate_camera_pose`.

    Returns
    -------
    T_camera_base : numpy.ndarray
        The refined transform (4, 4).
    std : numpy.ndarray
        Standard deviation of (rotation vector (rad), translation (m)) from the Jacobian, (6,).
    """
    from scipy.optimize import least_squares

    def T_of(x):
        return make_transform(rotvec_to_matrix(x[:3]) @ T_cb0[:3, :3],
                              T_cb0[:3, 3] + x[3:])

    sol = least_squares(lambda x: _static_residuals(chain, links, poses, T_of(x)), np.zeros(6),
                        x_scale=np.array([1e-2, 1e-2, 1e-2, 1e-2, 1e-2, 1e-2]), method="lm")
    J = sol.jac
    nw = sum(int((p.n_frames > 0).sum()) for p in poses)
    n_par = 6 + 3 * len(links)
    dof = max(3 * nw - n_par, 1)
    s2 = float(sol.fun @ sol.fun) / dof
    try:
        cov = np.linalg.inv(J.T @ J) * s2
        std = np.sqrt(np.maximum(np.diagonal(cov), 0.0))
    except np.linalg.LinAlgError:
        std = np.full(6, np.nan)
    return T_of(sol.x), std


def fit_references(chain, labels, links, poses, T_camera_base=None) -> References:
    """Eq. 3-4 over one or more :class:`StaticPose` (pure numerics; see :func:`build_references`).

    Parameters
    ----------
    chain : mocap.kinematics.Chain
        The robot's kinematics (``chain.frames`` holds every marked link).
    labels : sequence of str
        Marker labels, (M,).
    links : sequence of str
        The link each marker is glued to, (M,).
    poses : list of StaticPose
        The static intervals, reduced to means.
    T_camera_base : numpy.ndarray, optional
        The camera pose (4, 4); estimated from the poses when omitted (at least two poses
        that differ in two non-parallel joints).

    Returns
    -------
    References
        Marker positions in their link frames, the camera pose and the consistency report.

    References
    ----------
    .. [1] PA10 thesis (seeds 002), eq. 3-4.

    Examples
    --------
    Markers seen in one static pose by a camera at a known pose give back their link-frame
    positions:

    >>> from mocap.kinematics import Chain, apply_transform, make_transform
    >>> chain = Chain(np.eye(4)[None], np.array([[0.0, 0.0, 1.0]]), ("j1",),
    ...               {"link1": (0, np.eye(4))})
    >>> p_link = np.array([[0.1, 0.0, 0.0], [0.0, 0.1, 0.05], [-0.1, 0.0, 0.1]])
    >>> T_cb = make_transform(np.eye(3), [1.0, 2.0, 0.5])
    >>> q = np.array([0.3])
    >>> p_camera = apply_transform(T_cb @ chain.joint_transforms(q)[0], p_link)
    >>> pose = StaticPose(q, p_camera, np.full(3, 100), np.zeros(3), np.zeros(1))
    >>> refs = fit_references(chain, ["A", "B", "C"], ["link1"] * 3, [pose], T_camera_base=T_cb)
    >>> bool(np.allclose(refs.p_link, p_link)), refs.camera_source
    (True, 'given')
    """
    labels, links = tuple(labels), tuple(links)
    if not poses:
        raise InputError("no static pose: the marker references (thesis eq. 3-4) need at least one "
                         "[[static]] recording with the robot still")
    std = None
    if T_camera_base is None:
        T0 = estimate_camera_pose(chain, links, poses)
        T_cb, std = refine_camera_pose(chain, links, poses, T0)
        source = "static_poses"
    else:
        T_cb = np.asarray(T_camera_base, float)
        source = "given"
    est, mean, w = _project_refs(chain, links, poses, T_cb)
    npose = (w > 0).sum(axis=0)
    dev = np.linalg.norm(est - mean, axis=2)
    cons = np.sqrt(np.nansum(np.where(w > 0, dev, 0.0) ** 2, axis=0) / np.maximum(npose - 1, 1))
    cons = np.where(npose > 1, cons, np.nan)
    scat = np.array([np.nanmean([p.scatter_m[m] for p in poses if p.n_frames[m] > 0])
                     if npose[m] else np.nan for m in range(len(labels))])
    r = _static_residuals(chain, links, poses, T_cb).reshape(-1, 3)
    nw = float(sum(p.n_frames[p.n_frames > 0].sum() for p in poses))
    fit_rms = float(np.sqrt((r ** 2).sum() / max(nw, 1)))
    return References(labels, links, mean, T_cb, source, cons, scat, npose, fit_rms, std,
                      tuple(poses))


# ---- campaign level --------------------------------------------------------------------------
def read_static_pose(rec, log, labels, still_tol_rad: float = 2e-3, reject_m: float = 0.003,
                     source: str = "") -> StaticPose:
    """Reduce one static recording (:class:`MarkerRecording` + :class:`RobotLog`) to means.

    Parameters
    ----------
    rec : mocap.io.recording.MarkerRecording
        The static marker recording.
    log : mocap.io.robotlog.RobotLog
        The robot log of the same interval.
    labels : sequence of str
        Marker labels to reduce, (M,).
    still_tol_rad : float, optional
        Largest encoder motion of a still joint (rad).
    reject_m : float, optional
        Outlier distance of :func:`reduce_static` (m).
    source : str, optional
        Name recorded in the result.

    Returns
    -------
    StaticPose
        Mean encoder angles and marker positions.

    Raises
    ------
    mocap.io.errors.InputError
        When the clocks do not overlap, a joint has no angle, or a joint moved.
    """
    t0, t1 = rec.time[0], rec.time[-1]
    if t1 < log.time[0] or t0 > log.time[-1]:
        raise InputError(f"static pose: marker times {t0:.3f}..{t1:.3f} s and robot log times "
                         f"{log.time[0]:.3f}..{log.time[-1]:.3f} s do not overlap", path=rec.source)
    inlog = (log.time >= t0) & (log.time <= t1)
    qm = log.qm[inlog] if inlog.any() else log.qm
    if np.isnan(qm).all(axis=0).any():
        j = int(np.flatnonzero(np.isnan(qm).all(axis=0))[0]) + 1
        raise InputError(f"static pose: the robot log has no qm_{j} values in the static interval",
                         path=log.source, label=f"qm_{j}")
    q = np.nanmean(qm, axis=0)
    q_range = np.nanmax(qm, axis=0) - np.nanmin(qm, axis=0)
    moving = np.flatnonzero(q_range > still_tol_rad)
    if moving.size:
        j = int(moving[0])
        raise InputError(f"static pose: joint {j + 1} moved by {q_range[j]:.4g} rad during the static "
                         f"interval (tolerance {still_tol_rad:g} rad); the robot must stand still",
                         path=log.source, label=f"qm_{j + 1}")
    inm = (rec.time >= log.time[0]) & (rec.time <= log.time[-1])
    pos = np.full((int(inm.sum()), len(labels), 3), np.nan)
    for k, lb in enumerate(labels):  # loop over markers
        if lb in rec.labels:
            pos[:, k] = rec.positions[inm, rec.labels.index(lb)]
    if pos.shape[0] == 0:
        mean, n, scat = np.full((len(labels), 3), np.nan), np.zeros(len(labels), int), \
            np.full(len(labels), np.nan)
    else:
        import warnings

        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)  # all-NaN columns: never-seen markers
            mean, n, scat = reduce_static(pos, reject_m)
    return StaticPose(q, mean, n, scat, q_range, source)


def check_marker_links(campaign) -> None:
    """Every marked link needs at least 3 markers (a rigid body pose, robust to one loss).

    Parameters
    ----------
    campaign : mocap.io.campaign.Campaign
        The campaign whose ``[markers]`` table is checked.

    Raises
    ------
    mocap.io.errors.InputError
        Naming the manifest and the link with too few markers.
    """
    for link, labels in campaign.markers.items():
        if len(labels) < MIN_MARKERS_PER_LINK:
            raise InputError(f"link {link!r} has {len(labels)} marker(s); at least "
                             f"{MIN_MARKERS_PER_LINK} per link are needed", path=campaign.manifest,
                             label=link)


def build_references(campaign, robot, T_camera_base=None, still_tol_rad: float = 2e-3) -> References:
    """Eq. 3-4 for a campaign: read every ``[[static]]`` recording, reduce, combine.

    ``T_camera_base`` (4, 4) from a calibration; ``None`` estimates it from the static poses
    (needs >= 2 poses differing in two non-parallel joints, see the module doc).

    Parameters
    ----------
    campaign : mocap.io.campaign.Campaign
        The campaign (its ``[[static]]`` recordings and ``[markers]`` table).
    robot : mocap.robot.Robot
        The robot (held links are placed at their deflected angles).
    T_camera_base : numpy.ndarray, optional
        The camera pose (4, 4).
    still_tol_rad : float, optional
        Largest encoder motion of a still joint (rad).

    Returns
    -------
    References
        Marker positions in their link frames and the camera pose.

    References
    ----------
    .. [1] PA10 thesis (seeds 002), eq. 3-4.
    """

    check_marker_links(campaign)
    link_of = campaign.link_of_label()
    labels = tuple(link_of)
    links = tuple(link_of[lb] for lb in labels)
    if not campaign.static:
        raise InputError("the campaign has no [[static]] recording: marker references (thesis "
                         "eq. 3-4) need the robot standing still at known encoder angles",
                         path=campaign.manifest)
    poses = []
    for st in campaign.static:
        rec = campaign.read_markers(st, robot)
        log = campaign.read_log(st, robot)
        poses.append(read_static_pose(rec, log, labels, still_tol_rad,
                                      source=str(Path(st.markers).relative_to(campaign.root))))
    # a braked joint's link gives under gravity at its declared stiffness (FORMAT.md): the
    # references are placed at the link angles, as the trials' held joints are (solve.held_placement)
    if (robot.stiffness > 0).any():
        poses = [replace(p, q=p.q + robot.held_deflection(p.q)) if np.all(np.isfinite(p.q)) else p
                 for p in poses]
    seen = np.array([p.n_frames for p in poses]).sum(axis=0)
    if (seen == 0).any():
        lb = labels[int(np.flatnonzero(seen == 0)[0])]
        files = ", ".join(p.source for p in poses)
        raise InputError(f"marker {lb!r} (link {link_of[lb]!r}) is never visible in the static "
                         f"pose(s) ({files}): it has no reference", path=campaign.manifest, label=lb)
    return fit_references(robot.chain, labels, links, poses, T_camera_base)


def read_calib(path: str | Path) -> np.ndarray:
    """Read ``T_camera_base`` from a ``calib.json``, validated as a rigid transform.

    The file the calibration writes [1]_; ``T_camera_base`` maps base-frame points into the
    camera frame, the ``{}^n T_c`` of thesis eq. 3-3, 3-4 inverted [2]_.

    Parameters
    ----------
    path : str or pathlib.Path
        The calibration file.

    Returns
    -------
    numpy.ndarray
        The (4, 4) transform mapping base-frame points into the camera frame.

    Raises
    ------
    mocap.io.errors.InputError
        For a missing file, invalid JSON, or a ``T_camera_base`` that is not 4x4 and rigid.

    References
    ----------
    .. [1] jointlab data format (docs/format.md), sec. What the workbench writes.
    .. [2] PA10 thesis (seeds 002), eq. 3-3, 3-4.

    Examples
    --------
    >>> import tempfile
    >>> with tempfile.TemporaryDirectory() as d:
    ...     path = Path(d) / "calib.json"
    ...     _ = path.write_text(json.dumps({"format": 1, "T_camera_base": np.eye(4).tolist()}))
    ...     read_calib(path).shape
    (4, 4)
    """
    path = Path(path)
    if not path.is_file():
        raise InputError("calibration file not found", path=path)
    try:
        doc = json.loads(read_text(path))
    except json.JSONDecodeError as exc:
        raise InputError(f"not valid JSON: {exc}", path=path, line=exc.lineno) from None
    T = np.asarray(doc.get("T_camera_base", None), dtype=float) if "T_camera_base" in doc else None
    if T is None or T.shape != (4, 4):
        raise InputError("no 4x4 'T_camera_base' in the calibration", path=path, label="T_camera_base")
    R = T[:3, :3]
    if not (np.allclose(R.T @ R, np.eye(3), atol=1e-6) and np.isclose(np.linalg.det(R), 1.0, atol=1e-6)
            and np.allclose(T[3], [0, 0, 0, 1])):
        raise InputError("'T_camera_base' is not a rigid transform (rotation part not orthonormal)",
                         path=path, label="T_camera_base")
    return T
