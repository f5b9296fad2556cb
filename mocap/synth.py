"""Synthetic marker recordings: markers glued on link meshes, placed by forward kinematics with
the LINK angles, seen from a camera pose, with the motion-capture errors of the thesis setup
(0.845 mm 3D residual, chapter 4): Gaussian noise, occlusion runs, optional label swaps.

Everything random takes a ``numpy.random.Generator``; the same generator state gives the same
numbers.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from mocap.kinematics import apply_transform, make_transform
from mocap.io.recording import MarkerRecording


@dataclass(frozen=True, eq=False)
class MarkerSet:
    """Markers fixed to links: ``labels[i]`` sits at ``p_link[i]`` in the frame of ``links[i]``."""

    labels: tuple[str, ...]
    links: tuple[str, ...]
    p_link: np.ndarray  # (M, 3) metres

    def by_link(self) -> dict:
        out: dict = {}
        for lb, lk in zip(self.labels, self.links):
            out.setdefault(lk, []).append(lb)
        return out

    def to_dict(self) -> dict:
        return {"labels": list(self.labels), "links": list(self.links),
                "p_link": np.asarray(self.p_link).tolist()}


def _sample_surface(V: np.ndarray, F: np.ndarray, n: int, rng: np.random.Generator):
    """Area-weighted uniform points on a triangle mesh, with their face normals."""
    tri = V[F]
    cross = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    area = 0.5 * np.linalg.norm(cross, axis=1)
    face = rng.choice(F.shape[0], size=n, p=area / area.sum())
    r1, r2 = rng.random(n), rng.random(n)
    s = np.sqrt(r1)
    bary = np.column_stack([1 - s, s * (1 - r2), s * r2])
    pts = np.einsum("nk,nkd->nd", bary, tri[face])
    nrm = cross[face] / np.maximum(np.linalg.norm(cross[face], axis=1, keepdims=True), 1e-30)
    return pts, nrm


def _farthest(points: np.ndarray, k: int, rng: np.random.Generator) -> np.ndarray:
    """Indices of ``k`` well-spread points (greedy farthest-point selection)."""
    idx = [int(rng.integers(points.shape[0]))]
    dist = np.linalg.norm(points - points[idx[0]], axis=1)
    for _ in range(k - 1):
        i = int(np.argmax(dist))
        idx.append(i)
        dist = np.minimum(dist, np.linalg.norm(points - points[i], axis=1))
    return np.array(idx)


def place_markers(meshes: dict, links, rng: np.random.Generator, per_link=(3, 4),
                  marker_radius: float = 0.007, label_fmt: str = "L{j}{letter}") -> MarkerSet:
    """Sample 3-4 spread-out markers on each link's mesh surface (``meshes`` maps link ->
    (V, F) in the link frame), lifted by ``marker_radius`` along the surface normal (the centre
    of a reflective sphere). Labels ``L<j><A..>``, ``j`` the link's 1-based position in
    ``links``."""
    labels, owners, pts = [], [], []
    for j, link in enumerate(links, start=1):
        V, F = meshes[link]
        V = np.asarray(V, float)
        F = np.asarray(F, np.int64)
        k = int(rng.integers(per_link[0], per_link[1] + 1))
        cand, nrm = _sample_surface(V, F, 400, rng)
        # outward normal: away from the mesh centroid
        flip = np.einsum("ij,ij->i", nrm, cand - V.mean(axis=0)) < 0
        nrm[flip] *= -1
        sel = _farthest(cand, k, rng)
        for m, i in enumerate(sel):
            labels.append(label_fmt.format(j=j, letter=chr(ord("A") + m)))
            owners.append(link)
            pts.append(cand[i] + marker_radius * nrm[i])
    return MarkerSet(tuple(labels), tuple(owners), np.array(pts).reshape(-1, 3))


def random_camera_pose(rng: np.random.Generator, distance=(2.5, 3.5), height=(0.5, 1.5)) -> np.ndarray:
    """A random ``T_camera_base`` (4, 4): a lab frame with an arbitrary heading, a small tilt and
    an origin metres away from the robot base (p_camera = T_camera_base @ p_base)."""
    from scipy.spatial.transform import Rotation

    yaw = rng.uniform(-np.pi, np.pi)
    tilt = rng.normal(0.0, np.radians(5.0), size=2)
    R = Rotation.from_euler("zxy", [yaw, tilt[0], tilt[1]]).as_matrix()
    ang = rng.uniform(-np.pi, np.pi)
    r = rng.uniform(*distance)
    p_base_in_camera = np.array([r * np.cos(ang), r * np.sin(ang), rng.uniform(*height)])
    return make_transform(R, p_base_in_camera)


def marker_positions(chain, markers: MarkerSet, q: np.ndarray, T_camera_base: np.ndarray) -> np.ndarray:
    """Noise-free marker positions (T, M, 3) in the camera frame for link angles q (T, n)."""
    q = np.atleast_2d(np.asarray(q, float))
    Tj = chain.joint_transforms(q)                         # (T, n, 4, 4) T_base_joint
    out = np.empty((q.shape[0], len(markers.labels), 3))
    for link in dict.fromkeys(markers.links):              # loop over links (few)
        idx = [i for i, lk in enumerate(markers.links) if lk == link]
        j, T_jf = chain.frames[link]
        T_bl = np.broadcast_to(T_jf, (q.shape[0], 4, 4)) if j < 0 else Tj[:, j] @ T_jf
        T_cl = T_camera_base @ T_bl
        out[:, idx] = apply_transform(T_cl[:, None], markers.p_link[idx][None])
    return out


def add_noise(positions: np.ndarray, noise_rms: float, rng: np.random.Generator) -> np.ndarray:
    """``positions`` plus isotropic Gaussian noise of 3-D RMS ``noise_rms`` (per-axis sigma
    ``noise_rms / sqrt(3)``), the marker noise model of every synthetic recording."""
    return positions + rng.normal(0.0, noise_rms / np.sqrt(3.0), size=np.shape(positions))


def random_orientation(rng: np.random.Generator) -> np.ndarray:
    """A rotation matrix drawn uniformly over SO(3) (a normalised Gaussian quaternion)."""
    q = rng.standard_normal(4)
    w, x, y, z = q / np.linalg.norm(q)
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                     [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                     [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])


@dataclass(frozen=True)
class MarkerErrors:
    """Motion-capture error settings: per-marker Gaussian noise with ``noise_rms`` 3D RMS (m),
    occlusion runs covering about ``occlusion_fraction`` of the samples with run lengths
    uniform in ``run_frames``, and ``label_swaps`` swaps of two markers of one link over
    ``swap_frames`` frames."""

    noise_rms: float = 0.85e-3
    occlusion_fraction: float = 0.02
    run_frames: tuple[int, int] = (5, 50)
    label_swaps: int = 0
    swap_frames: tuple[int, int] = (20, 100)


def corrupt(positions: np.ndarray, markers: MarkerSet, rng: np.random.Generator,
            errors: MarkerErrors = MarkerErrors()) -> tuple[np.ndarray, dict]:
    """Noise, occlusions and label swaps applied to clean positions (T, M, 3). Returns the
    corrupted copy and a dict describing what was done (occluded runs, swaps)."""
    T, M, _ = positions.shape
    out = add_noise(positions, errors.noise_rms, rng)
    runs = []
    lo, hi = errors.run_frames
    mean_run = 0.5 * (lo + hi)
    for m in range(M):  # loop over markers (tens), runs drawn in bulk
        n_runs = int(rng.poisson(errors.occlusion_fraction * T / mean_run))
        if n_runs == 0 or T <= hi:
            continue
        lengths = rng.integers(lo, hi + 1, size=n_runs)
        starts = rng.integers(0, T - hi, size=n_runs)
        for s, ln in zip(starts.tolist(), lengths.tolist()):
            out[s:s + ln, m] = np.nan
            runs.append([markers.labels[m], int(s), int(ln)])
    swaps = []
    groups = [idx for idx in (np.flatnonzero(np.array(markers.links) == lk)
                              for lk in dict.fromkeys(markers.links)) if idx.size >= 2]
    for _ in range(errors.label_swaps):
        if not groups or T <= errors.swap_frames[1]:
            break
        g = groups[int(rng.integers(len(groups)))]
        a, b = rng.choice(g, size=2, replace=False)
        ln = int(rng.integers(errors.swap_frames[0], errors.swap_frames[1] + 1))
        s = int(rng.integers(0, T - ln))
        out[s:s + ln, [a, b]] = out[s:s + ln, [b, a]]
        swaps.append([markers.labels[a], markers.labels[b], s, ln])
    return out, {"occlusions": runs, "swaps": swaps,
                 "occluded_fraction": float(np.mean(~np.isfinite(out[..., 0])))}


def synthesize_recording(chain, markers: MarkerSet, T_camera_base: np.ndarray, time: np.ndarray,
                         q: np.ndarray, rng: np.random.Generator,
                         errors: MarkerErrors = MarkerErrors(), rate_hz: float | None = None,
                         units: str = "mm") -> tuple[MarkerRecording, dict]:
    """A :class:`MarkerRecording` (camera frame, metres) of ``markers`` for link angles
    ``q`` (T, n) at marker ``time`` (T,), with noise, occlusions and swaps from ``rng``."""
    clean = marker_positions(chain, markers, q, T_camera_base)
    noisy, info = corrupt(clean, markers, rng, errors)
    rate = float(rate_hz) if rate_hz else float(1.0 / np.median(np.diff(time)))
    rec = MarkerRecording(np.asarray(time, float), noisy, markers.labels, rate, units=units)
    return rec, info
