"""Log a whole campaign (FORMAT.md) through a :class:`viz.sink.Sink`: markers, posed robot, signals.

Entity layout (``<kind>`` is ``static``, ``calib`` or ``trial``; ``<id>`` is ``static-1``,
``calib-joint-2`` or the trial id, as :meth:`mocap.io.campaign.Campaign.recordings` names them)::

    campaign                              world = the camera frame of the motion capture
    campaign/<kind>/<id>/markers          marker positions over time (camera frame, metres)
    campaign/<kind>/<id>/robot            the robot base: T_camera_base (identity if not given)
    campaign/<kind>/<id>/robot/<link>     link mesh (static) + T_base_link over time (<= 60 Hz)
    campaign/<kind>/<id>/signals/qm_<j>   motor angle of joint j (rad), from the robot log
    campaign/<kind>/<id>/signals/tau_<j>  motor torque of joint j (N m)
    campaign/README                       a Markdown summary of the campaign

The robot is posed by the log's motor angles ``qm`` (link side), joints without a column held at
0: this shows what the controller believed, which is what a viewer compares with the markers.
This module never imports rerun; it only talks to the sink.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from mocap.urdf import load_link_meshes

MAX_ROBOT_RATE_HZ = 60.0
MARKER_RADIUS_M = 0.008
MESH_COLOR = (200, 200, 205)
# colour of the markers of each link, cycled (tab10)
PALETTE = np.array([[31, 119, 180], [255, 127, 14], [44, 160, 44], [214, 39, 40],
                    [148, 103, 189], [140, 86, 75], [227, 119, 194], [127, 127, 127],
                    [188, 189, 34], [23, 190, 207]], dtype=np.uint8)
UNASSIGNED_COLOR = (90, 90, 90)


def load_meshes(urdf) -> dict:
    """``{link: (vertices, faces)}`` from :func:`mocap.urdf.load_link_meshes`, or ``{}``
    without a URDF (the robot then shows as link frames)."""
    if urdf is None:
        return {}
    return dict(load_link_meshes(Path(urdf), missing="warn"))   # meshes are optional


def decimate_indices(time: np.ndarray, max_rate_hz: float = MAX_ROBOT_RATE_HZ) -> np.ndarray:
    """Indices of the first sample in each ``1/max_rate_hz`` bin of ``time``: at most
    ``duration * max_rate_hz + 1`` samples, all of them actual samples (no interpolation)."""
    t = np.asarray(time, float)
    if t.size == 0:
        return np.zeros(0, dtype=np.int64)
    bins = np.floor((t - t[0]) * max_rate_hz).astype(np.int64)
    return np.flatnonzero(np.r_[True, np.diff(bins) > 0])


def fill_joint_angles(time: np.ndarray, qm: np.ndarray) -> np.ndarray:
    """Motor angles for posing: a joint without any sample is held at 0, missing samples of the
    others are linearly interpolated in time (held at the ends)."""
    q = np.array(qm, float, copy=True)
    for j in range(q.shape[1]):  # loop over joints
        ok = np.isfinite(q[:, j])
        if not ok.any():
            q[:, j] = 0.0
        elif not ok.all():
            q[:, j] = np.interp(time, time[ok], q[ok, j])
    return q


def marker_colors(labels, link_of_label: dict) -> np.ndarray:
    """(M, 3) uint8: one palette colour per link (in the manifest's order), grey if unassigned."""
    links = list(dict.fromkeys(link_of_label.values()))
    out = np.empty((len(labels), 3), dtype=np.uint8)
    for k, lb in enumerate(labels):  # loop over markers (tens)
        link = link_of_label.get(lb)
        out[k] = UNASSIGNED_COLOR if link is None else PALETTE[links.index(link) % len(PALETTE)]
    return out


def log_robot_description(robot, sink, path: str = "robot", meshes: dict | None = None,
                          axis_length: float = 0.1) -> None:
    """A static robot at q = 0: each link's mesh placed at ``T_base_link``, the joint axes as
    labelled arrows under ``path/joint_axes``. ``meshes`` default: loaded from ``robot.urdf``."""
    if meshes is None:
        meshes = load_meshes(getattr(robot, "urdf", None))
    q0 = np.zeros(robot.n)
    for link in robot.chain.frames:  # loop over links
        child = f"{path}/{link}"
        sink.transform(child, robot.chain.frame_transform(link, q0))
        if link in meshes:
            V, F = meshes[link][:2]
            sink.mesh(child, V, F, color=MESH_COLOR)
    points, dirs = robot.chain.joint_axis_lines(q0)
    sink.arrows(f"{path}/joint_axes", points, axis_length * dirs,
                labels=[f"{k + 1}: {nm}" for k, nm in enumerate(robot.joint_names)])


def _summary_markdown(campaign, rows) -> str:
    lines = [f"# Campaign `{campaign.name}`", "",
             f"Manifest: `{campaign.manifest}`", "",
             "| kind | id | marker frames | markers | log samples | log rate (Hz) |",
             "|---|---|---|---|---|---|"]
    for kind, name, nf, nm, ns, rate in rows:
        lines.append(f"| {kind} | {name} | {nf} | {nm} | {ns} | {rate:.1f} |")
    return "\n".join(lines) + "\n"


def log_campaign(campaign, sink, robot=None, T_camera_base=None, meshes: dict | None = None,
                 max_robot_rate_hz: float = MAX_ROBOT_RATE_HZ, max_signal_rate_hz: float | None = None,
                 root: str = "campaign") -> list[str]:
    """Log every recording of ``campaign`` (a :class:`mocap.io.campaign.Campaign`) to ``sink``.

    Parameters
    ----------
    robot : a :class:`mocap.robot.Robot`; default: ``campaign.load_robot()``.
    T_camera_base : (4, 4), maps base-frame points into the camera frame; it places the robot
        base in the world (= camera frame). Default: identity (no calibration yet).
    meshes : ``{link: (vertices, faces)}`` in link frames; default: loaded from the URDF when
        :mod:`mocap.urdf` is available, else the links show as frames.
    max_robot_rate_hz : the robot pose is logged at most at this rate (keeps files small).
    max_signal_rate_hz : the same for the joint signals; ``None`` (default) logs every sample
        (about 22 bytes per sample and column in the .rrd).

    Returns the entity paths of the recordings logged (``root/<kind>/<id>``).
    """
    if not getattr(sink, "enabled", True):  # logging off: read nothing
        return [f"{root}/{kind}/{name}" for kind, name, _ in campaign.recordings()]
    if robot is None:
        robot = campaign.load_robot()
    if meshes is None:
        meshes = load_meshes(campaign.urdf)
    T_cb = np.eye(4) if T_camera_base is None else np.asarray(T_camera_base, float)
    if T_cb.shape != (4, 4):
        raise ValueError(f"T_camera_base must be (4, 4), got {T_cb.shape}")
    mesh_rgb = {lk: (V, F, MESH_COLOR) for lk, (V, F, *_) in meshes.items()}
    link_of_label = campaign.link_of_label()
    logged, rows, qm_paths, tau_paths = [], [], [], []
    for kind, name, rec in campaign.recordings():  # loop over recordings
        base = f"{root}/{kind}/{name}"
        markers = None
        if rec.markers is not None:          # None: a campaign without motion capture
            markers = campaign.read_markers(rec, robot)
            sink.points_over_time(f"{base}/markers", markers.time, markers.positions,
                                  labels=markers.labels,
                                  colors=marker_colors(markers.labels, link_of_label),
                                  radii=MARKER_RADIUS_M)
        log = campaign.read_log(rec, robot)     # URDF joints ([robot] coupling applied)
        # joint signals (full rate unless asked), only the columns the log has
        has_q = np.flatnonzero(np.any(np.isfinite(log.qm), axis=0))
        has_t = np.flatnonzero(np.any(np.isfinite(log.tau), axis=0))
        sig = slice(None) if max_signal_rate_hz is None else \
            decimate_indices(log.time, max_signal_rate_hz)
        if has_q.size:
            sink.scalars(f"{base}/signals", log.time[sig], log.qm[sig][:, has_q],
                         names=[f"qm_{j + 1}" for j in has_q])
            qm_paths += [f"/{base}/signals/qm_{j + 1}" for j in has_q]
        if has_t.size:
            sink.scalars(f"{base}/signals", log.time[sig], log.tau[sig][:, has_t],
                         names=[f"tau_{j + 1}" for j in has_t])
            tau_paths += [f"/{base}/signals/tau_{j + 1}" for j in has_t]
        # the robot, posed by the motor angles, decimated
        idx = decimate_indices(log.time, max_robot_rate_hz)
        t_pose = log.time[idx]
        q = fill_joint_angles(log.time, log.qm)[idx]
        sink.transform(f"{base}/robot", T_cb)
        link_T = {lk: robot.chain.frame_transform(lk, q) for lk in robot.chain.frames}
        sink.robot(f"{base}/robot", mesh_rgb, t_pose, link_T)
        logged.append(base)
        rows.append((kind, name, 0 if markers is None else markers.n_frames,
                     0 if markers is None else markers.n_markers, log.n_samples, log.rate_hz))
    sink.text(f"{root}/README", _summary_markdown(campaign, rows))
    series = {}
    if qm_paths:
        series["motor angles qm (rad)"] = qm_paths
    if tau_paths:
        series["motor torques tau (N m)"] = tau_paths
    sink.layout(series=series or None, world="/", text=f"/{root}")
    return logged
