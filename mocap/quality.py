"""Quality of a marker solve: the Cramer-Rao bound of the geometry, errors against a known truth,
per-marker residual reports and the per-campaign summary.

The bound: with independent Gaussian marker noise of ``sigma`` per axis, the Fisher information
of the solved angles in one frame is ``J^T J / sigma^2`` (J: marker positions w.r.t. the angles,
the Jacobian of eq. 3-5's residual), so no unbiased per-frame estimator can beat
``std(q_i) >= sigma * sqrt([(J^T J)^-1]_ii)``.
"""
from __future__ import annotations

import warnings

import numpy as np

from mocap.io.errors import InputError
from mocap.solve import MarkerSolver, _Chain


def cramer_rao_bound(chain, joints, marker_joint, p_joint, q: np.ndarray, sigma_axis: float,
                     visible: np.ndarray | None = None) -> np.ndarray:
    """Per-frame Cramer-Rao lower bound on the std of the solved angles: (T, S).

    ``joints`` 0-based, ``q`` (T, n) the true angles, ``sigma_axis`` the per-axis marker noise
    (3-D RMS / sqrt 3), ``visible`` (T, M) the markers seen in each frame (default: all).

    Parameters
    ----------
    chain : mocap.kinematics.Chain
        The robot's kinematics.
    joints : sequence of int
        The solved joints, 0-based.
    marker_joint : array_like of int
        Joint each marker moves with, (M,).
    p_joint : array_like
        Marker positions in their joint's frame (m), (M, 3).
    q : numpy.ndarray
        True angles (rad), (T, n).
    sigma_axis : float
        Marker noise per axis (m).
    visible : numpy.ndarray, optional
        Markers seen per frame, (T, M) bool.

    Returns
    -------
    numpy.ndarray
        Lower bound on the std of each solved angle (rad), (T, S); inf where the markers
        do not determine the angles.

    References
    ----------
    .. [1] Friction modeling and experimental identification of a Mitsubishi PA10-6CE arm with
       motion capture (thesis, ``../shared/seeds/002_*``), eq. 3-5 (the least squares whose Jacobian this uses).

    Examples
    --------
    One joint about z, three markers 0.1 m from the axis, 1 mm noise per axis: the bound is
    ``sigma / sqrt(sum r^2)``:

    >>> from mocap.kinematics import Chain
    >>> chain = Chain(np.eye(4)[None], np.array([[0.0, 0.0, 1.0]]), ("j1",), {})
    >>> p = np.array([[0.1, 0.0, 0.0], [0.0, 0.1, 0.05], [-0.1, 0.0, 0.1]])
    >>> b = cramer_rao_bound(chain, [0], [0, 0, 0], p, np.zeros((2, 1)), sigma_axis=1e-3)
    >>> b.round(6).tolist(), round(float(1e-3 / np.sqrt(0.03)), 6)
    ([[0.005774], [0.005774]], 0.005774)
    """
    q = np.atleast_2d(np.asarray(q, float))
    solver = MarkerSolver(chain, joints, marker_joint, p_joint)
    model = _Chain(solver, q)
    M = solver.p_joint.shape[0]
    vis = np.ones((q.shape[0], M), bool) if visible is None else np.asarray(visible, bool)
    vis = vis & (solver.marker_joint >= solver.joints[0])[None, :]
    H = model.normal_matrix(q[:, list(solver.joints)], vis)
    S = H.shape[1]
    ok = np.linalg.matrix_rank(H) == S
    Hinv = np.linalg.inv(np.where(ok[:, None, None], H, np.eye(S)))
    out = sigma_axis * np.sqrt(np.diagonal(Hinv, axis1=1, axis2=2))
    out[~ok] = np.inf
    return out


def rms_bound(bound: np.ndarray) -> np.ndarray:
    """RMS over frames of a per-frame std bound (T, S) -> (S,): the bound on an angle RMSE.

    Parameters
    ----------
    bound : array_like
        Per-frame bound (rad), (T, S); frames with a non-finite entry are left out.

    Returns
    -------
    numpy.ndarray
        The bound on the RMSE of each angle (rad), (S,).

    Examples
    --------
    >>> rms_bound(np.array([[3.0], [4.0], [np.inf]])).round(4).tolist()
    [3.5355]
    """
    b = np.asarray(bound, float)
    return np.sqrt(np.mean(b[np.all(np.isfinite(b), axis=1)] ** 2, axis=0))


def angle_errors(q_est: np.ndarray, q_true: np.ndarray) -> dict:
    """RMSE and max error per column over frames where the estimate is finite.

    Parameters
    ----------
    q_est, q_true : numpy.ndarray
        Estimated and true angles (rad), (T, S).

    Returns
    -------
    dict
        ``frames`` (frames compared), ``rmse_rad`` and ``max_rad`` (S,).

    Examples
    --------
    >>> e = angle_errors(np.array([[0.1], [0.2], [np.nan]]), np.array([[0.1], [0.1], [0.0]]))
    >>> e["frames"], e["rmse_rad"].round(4).tolist(), e["max_rad"].round(4).tolist()
    (2, [0.0707], [0.1])
    """
    e = np.asarray(q_est, float) - np.asarray(q_true, float)
    ok = np.all(np.isfinite(e), axis=1)
    e = e[ok]
    return {"frames": int(ok.sum()), "rmse_rad": np.sqrt(np.mean(e ** 2, axis=0)),
            "max_rad": np.max(np.abs(e), axis=0) if e.size else np.full(e.shape[1], np.nan)}


def marker_report(result) -> dict:
    """Per marker: residual RMS over frames where it was used, rejected and missing fractions.

    ``result``: a :class:`mocap.solve.SolveResult`. A marker with a large residual in most frames
    has a wrong reference (moved since the static pose, or mislabelled).

    Parameters
    ----------
    result : mocap.solve.SolveResult
        A trial's solve.

    Returns
    -------
    dict
        Label -> ``rms_mm``, ``rejected_frac``, ``missing_frac``.
    """
    res = result.residual_m
    out = {}
    valid = result.valid
    for k, lb in enumerate(result.labels):
        seen = np.isfinite(res[:, k]) & valid
        used = seen & result.inlier[:, k]
        out[lb] = {
            "rms_mm": float(1e3 * np.sqrt(np.mean(res[used, k] ** 2))) if used.any() else None,
            "rejected_frac": float(np.mean(seen & ~result.inlier[:, k])) if seen.size else 0.0,
            "missing_frac": float(np.mean(~np.isfinite(res[:, k]))),
        }
    return out


def summary(results, references=None) -> dict:
    """The ``mocap`` command's summary document: per trial frames, RMS residual, flagged frames.

    Parameters
    ----------
    results : iterable
        Per-trial results with ``trial_id``, ``solve`` and ``to_dict()``.
    references : mocap.references.References, optional
        The static references used.

    Returns
    -------
    dict
        The ``mocap.json`` document (FORMAT.md).
    """
    doc = {"format": 1, "trials": {}}
    if references is not None:
        doc["references"] = references.to_dict()
    for r in results:
        d = r.to_dict()
        d["markers"] = marker_report(r.solve)
        doc["trials"][r.trial_id] = d
    return doc


# ---------------------------------------------------------------------------------------
def chain_reach(chain) -> float:
    """Sum of the joint-to-joint distances of the chain (m): a bound on the robot's size.

    Parameters
    ----------
    chain : mocap.kinematics.Chain
        The robot's kinematics.

    Returns
    -------
    float
        The reach (m).
    """
    return float(np.linalg.norm(np.asarray(chain.T_parent_joint)[:, :3, 3], axis=1).sum())


def check_marker_units(positions, labels, chain, path=None, joint: int | None = None,
                       check_motion: bool = True) -> None:
    """Refuse a marker cloud that cannot belong to the robot: larger than three times its reach
    plus a metre, or (``check_motion``, a calibration sweep) whose markers all move less than
    2 mm (units suspected: mm read as m or back; a marker that close to the axis could not
    place it anyway).

    Parameters
    ----------
    positions : array_like
        Marker positions (m), (T, M, 3).
    labels : sequence of str
        Marker labels, (M,).
    chain : mocap.kinematics.Chain
        The robot's kinematics.
    path : str or pathlib.Path, optional
        The marker file, named in the error.
    joint : int, optional
        The swept joint (a calibration sweep), named in the error.
    check_motion : bool, optional
        Also refuse markers that barely move.

    Raises
    ------
    mocap.io.errors.InputError
        "units suspected", naming the file and the marker.
    """
    P = np.asarray(positions, float)
    hi, lo = np.nanmax(P, axis=0), np.nanmin(P, axis=0)           # (M, 3) per-marker bounds
    ext = hi - lo                                                 # (M, 3) per-marker extent
    ext_m = np.nanmax(ext, axis=1)
    allx = float(np.nanmax(np.nanmax(hi, axis=0) - np.nanmin(lo, axis=0)))
    reach = chain_reach(chain)
    what = f"sweep of joint {joint}" if joint is not None else "marker cloud"
    if allx > 3.0 * reach + 1.0:
        k = int(np.nanargmax(ext_m))
        raise InputError(f"{what}: the markers span {allx:.3g} m, the robot reaches {reach:.2f} m: units "
                         f"suspected (marker {labels[k]!r} alone moves {ext_m[k]:.3g} m; check the Units "
                         "the marker file declares)", path=path, label=labels[k])
    if check_motion and np.nanmax(ext_m) < 2e-3:
        k = int(np.nanargmax(ext_m))
        raise InputError(f"{what}: the markers move at most {1e3 * ext_m[k]:.3g} mm for a robot that reaches "
                         f"{reach:.2f} m: units suspected (marker {labels[k]!r}; check the Units the marker "
                         "file declares)", path=path, label=labels[k])


def check_marker_extent(markers, labels, chain) -> None:
    """The campaign's markers in a marker file span more than 0.5 % of the robot's reach (they
    sit on links centimetres apart): a smaller cloud is metres declared as millimetres."""
    idx = [k for k, lb in enumerate(markers.labels) if lb in labels]
    if len(idx) < 2:
        return
    P = markers.positions[:, idx]                                 # (T, k, 3)
    f = np.isfinite(P)
    whole = f[..., 0] & f[..., 1] & f[..., 2]                     # points with all 3 axes
    if np.count_nonzero(whole) < 2:
        return
    P = np.where(whole[..., None], P, np.nan).reshape(P.shape[0], -1)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)           # a marker never seen whole
        hi = np.nanmax(np.nanmax(P, axis=0).reshape(-1, 3), axis=0)
        lo = np.nanmin(np.nanmin(P, axis=0).reshape(-1, 3), axis=0)
    ext = float(np.max(hi - lo))
    reach = chain_reach(chain)
    if reach > 0 and ext < 0.005 * reach:
        raise InputError(f"the campaign's {len(idx)} markers span {1e3 * ext:.3g} mm, {ext / reach:.2g} of the "
                         f"robot's reach ({reach:.3g} m): metres declared as {markers.units} suspected "
                         "(check the Units the marker file declares)", path=markers.source, label="Units")
