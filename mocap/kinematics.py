"""The one forward kinematics and the SE(3)/SO(3) helpers of jointlab (numpy, batched).

The chain is extracted once from a pinocchio model (see :mod:`mocap.robot`); the batched
functions here take joint angles ``q`` of shape ``(T, n)`` and return homogeneous transforms
of shape ``(T, n, 4, 4)`` without a Python loop over frames. Rotation helpers (rotation
angles, Kabsch) live here too, and the rotations of :mod:`mocap.numerics` (Rodrigues, rotation
vectors and their logarithm) are re-exported.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from mocap.numerics import rodrigues_combine, rodrigues_terms
from mocap.numerics import (matrix_to_rotvec, rotation_about_axis, rotvec_to_matrix,  # noqa: F401
                            skew)  # re-exported


def unit(v: np.ndarray) -> np.ndarray:
    """``v`` (..., 3) scaled to unit length along the last axis."""
    v = np.asarray(v, float)
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def perp_basis(n: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """An orthonormal pair ``(u, v)`` perpendicular to the unit vector ``n`` (right-handed u, v, n)."""
    n = unit(n)
    e = np.zeros(3)
    e[int(np.argmin(np.abs(n)))] = 1.0
    u = unit(np.cross(n, e))
    v = np.cross(n, u)
    return u, v


def _vee_antisym(R: np.ndarray) -> np.ndarray:
    return np.stack([R[..., 2, 1] - R[..., 1, 2], R[..., 0, 2] - R[..., 2, 0],
                     R[..., 1, 0] - R[..., 0, 1]], -1) / 2.0


def rotation_angle(R: np.ndarray) -> np.ndarray:
    """Rotation angle(s) in radians of rotation matrices (..., 3, 3)."""
    c = (np.trace(R, axis1=-2, axis2=-1) - 1.0) / 2.0
    s = np.linalg.norm(_vee_antisym(R), axis=-1)
    return np.arctan2(s, np.clip(c, -1.0, 1.0))


def angle_about(R: np.ndarray, n: np.ndarray) -> np.ndarray:
    """Signed rotation angle of R (..., 3, 3) about the unit axis ``n`` (right-hand rule)."""
    c = (np.trace(R, axis1=-2, axis2=-1) - 1.0) / 2.0
    return np.arctan2(_vee_antisym(R) @ n, c)


def make_transform(R: np.ndarray, p: np.ndarray) -> np.ndarray:
    R = np.asarray(R, float)
    p = np.asarray(p, float)
    T = np.zeros(R.shape[:-2] + (4, 4))
    T[..., :3, :3] = R
    T[..., :3, 3] = p
    T[..., 3, 3] = 1.0
    return T


def invert_transform(T: np.ndarray) -> np.ndarray:
    """Inverse of homogeneous rigid transforms: ``T_b_a`` from ``T_a_b``.

    ``[R^T, -R^T p]`` without a general matrix inverse; e.g. ``T_base_camera`` from the
    ``T_camera_base`` of the camera-to-base calibration [1]_.

    Parameters
    ----------
    T : array_like
        (..., 4, 4) rigid transforms.

    Returns
    -------
    numpy.ndarray
        (..., 4, 4) their inverses.

    References
    ----------
    .. [1] jointlab data format (docs/format.md), sec. What the workbench writes.

    Examples
    --------
    >>> T = make_transform(rotation_about_axis([0.0, 0.0, 1.0], 0.3), [1.0, 2.0, 3.0])
    >>> np.allclose(invert_transform(T) @ T, np.eye(4))
    True
    """
    T = np.asarray(T, float)
    R = T[..., :3, :3]
    p = T[..., :3, 3]
    Rt = np.swapaxes(R, -1, -2)
    return make_transform(Rt, -np.einsum("...ij,...j->...i", Rt, p))


def apply_transform(T: np.ndarray, p: np.ndarray) -> np.ndarray:
    """Apply transform(s) (..., 4, 4) to points (..., 3) with broadcasting."""
    T = np.asarray(T, float)
    return np.einsum("...ij,...j->...i", T[..., :3, :3], p) + T[..., :3, 3]


def kabsch_batch(ref: np.ndarray, obs: np.ndarray, w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    r"""Weighted least-squares rigid transforms, batched over frames.

    .. math::

        (R_t, t_t) = \arg\min_{R \in SO(3),\, t} \sum_k w_{tk}
        \lVert o_{tk} - (R\, r_k + t) \rVert^2

    by the SVD of the weighted cross-covariance (Kabsch/Umeyama [1]_, with the reflection fix):
    the rigid fit of a link's markers to their references, thesis eq. 3-5 [2]_.

    Parameters
    ----------
    ref : numpy.ndarray
        (M, 3) reference marker positions.
    obs : numpy.ndarray
        (T, M, 3) observed positions (NaN allowed where ``w`` is 0).
    w : numpy.ndarray
        (T, M) non-negative weights.

    Returns
    -------
    R : numpy.ndarray
        (T, 3, 3) rotations; NaN in frames with fewer than 3 weighted markers.
    t : numpy.ndarray
        (T, 3) translations; NaN likewise.

    References
    ----------
    .. [1] Umeyama 1991, least-squares estimation of transformation parameters between two
       point patterns.
    .. [2] PA10 thesis (seeds 002), eq. 3-5.
    """
    w = np.asarray(w, float)
    obs = np.where(w[..., None] > 0, obs, 0.0)
    W = w.sum(axis=1)
    ok = (w > 0).sum(axis=1) >= 3
    Wsafe = np.where(W > 0, W, 1.0)
    cr = np.einsum("tm,mi->ti", w, ref) / Wsafe[:, None]
    co = np.einsum("tm,tmi->ti", w, obs) / Wsafe[:, None]
    H = np.einsum("tm,tmi,tmj->tij", w, obs - co[:, None], ref[None] - cr[:, None])
    U, _, Vt = np.linalg.svd(H)
    d = np.sign(np.linalg.det(U @ Vt))
    D = np.ones((H.shape[0], 3))
    D[:, 2] = d
    R = np.einsum("tij,tj,tjk->tik", U, D, Vt)
    t = co - np.einsum("tij,tj->ti", R, cr)
    R[~ok] = np.nan
    t[~ok] = np.nan
    return R, t


def kabsch(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The rigid transform (4, 4) mapping points ``a`` (K, 3) onto ``b`` (K, 3), least squares."""
    a = np.asarray(a, float)
    b = np.asarray(b, float)
    R, t = kabsch_batch(a, b[None], np.ones((1, a.shape[0])))
    return make_transform(R[0], t[0])


@dataclass(frozen=True, eq=False)
class Chain:
    r"""Kinematic description of a serial chain of ``n`` revolute joints.

    The one forward kinematics of jointlab, batched over frames: the pose of joint ``i`` in the
    base frame is

    .. math::

        T_{b,i}(q) = T_{b,i-1}(q)\; P_i \begin{bmatrix} R(a_i, q_i) & 0 \\ 0 & 1
        \end{bmatrix}

    (``P_i`` the fixed placement, ``R`` Rodrigues' rotation about the axis ``a_i``); a marker
    fixed to a link is carried to the base frame by it, thesis eq. 3-3 [1]_. Built from the
    URDF by :class:`mocap.robot.Robot` [2]_.

    Attributes
    ----------
    T_parent_joint : numpy.ndarray
        (n, 4, 4) fixed placement of joint ``i`` in the frame of joint ``i-1`` (joint -1 being
        the base frame).
    axes : numpy.ndarray
        (n, 3) unit rotation axis of each joint in its own frame.
    joint_names : tuple of str
        The joints' names, in chain order.
    frames : dict
        Link (or any named frame) -> ``(joint index, T_joint_frame)``; a joint index of -1
        means the frame is fixed to the base.

    References
    ----------
    .. [1] PA10 thesis (seeds 002), eq. 3-3.
    .. [2] jointlab data format (docs/format.md), sec. Which chain is the arm.
    """

    T_parent_joint: np.ndarray
    axes: np.ndarray
    joint_names: tuple[str, ...]
    frames: dict

    @property
    def n(self) -> int:
        return int(self.axes.shape[0])

    def joint_frames(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Joint frames in the base frame for q (T, n): rotations (T, n, 3, 3), origins (T, n, 3).

        Rodrigues per joint, vectorised over frames; every product with a constant matrix is one
        (3T x 3) @ (3 x 10) GEMM, several times faster than numpy's batched 3x3 matmul."""
        q = np.atleast_2d(np.asarray(q, float))
        T, n = q.shape
        if n != self.n:
            raise ValueError(f"q has {n} columns, the chain has {self.n} joints")
        R = np.empty((T, n, 3, 3))
        o = np.empty((T, n, 3))
        Rprev = None
        oprev = np.zeros((T, 3))
        for i, C in enumerate(self._rodrigues_blocks()):  # joints (n <= ~7), frames vectorised
            P = self.T_parent_joint[i]
            if Rprev is None:
                B = np.broadcast_to(C, (T, 3, 10))
                ob = oprev + P[:3, 3]
            else:
                B = (Rprev.reshape(-1, 3) @ C).reshape(T, 3, 10)
                ob = oprev + B[:, :, 9]
            s = np.sin(q[:, i])[:, None, None]
            c = np.cos(q[:, i])[:, None, None]
            Rprev = rodrigues_combine(B[:, :, 0:3], B[:, :, 3:6], B[:, :, 6:9], s, c)
            oprev = ob
            R[:, i] = Rprev
            o[:, i] = ob
        return R, o

    def _rodrigues_blocks(self) -> list:
        """Per joint ``[Pr, Pr K, Pr K^2, p]`` (3, 10): the joint's placement ``(Pr, p)`` and the
        cross-product matrix ``K`` of its axis, so that ``R_i = R_{i-1} (Pr + sin q Pr K +
        (1 - cos q) Pr K^2)`` (Rodrigues); computed once per chain."""
        blocks = self.__dict__.get("_blocks")
        if blocks is None:
            blocks = []
            for i in range(self.n):
                P = self.T_parent_joint[i]
                blocks.append(np.hstack([*(P[:3, :3] @ rodrigues_terms(self.axes[i])), P[:3, 3:4]]))
            object.__setattr__(self, "_blocks", blocks)       # a cache, not a field
        return blocks

    def joint_frames_soa(self, angles: np.ndarray, first: int = 0,
                         F_prev: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        r"""Joint frames ``first .. first + k - 1`` with the frame index last (structure of arrays).

        The forward kinematics of :meth:`joint_frames` (the class docstring's product, thesis
        eq. 3-3 [1]_) laid out for work over many frames at once: every per-frame quantity is a
        contiguous row over the ``T`` frames, so the chain step
        ``[R_i | o_i] = [R_{i-1} | o_{i-1}] [C_i(q_i) | p_i]`` is one small GEMM per joint and a
        few contiguous elementwise operations (no transposes, no batched 3 x 3 products), with
        ``C_i(q) = Pr_i + sin q Pr_i K_i + (1 - cos q) Pr_i K_i^2`` (Rodrigues). The joint axis in
        the base frame comes with it: ``R_i a_i = R_{i-1} Pr_i a_i`` (``K_i a_i = 0``).

        Parameters
        ----------
        angles : numpy.ndarray
            (k, T) angles of joints ``first .. first + k - 1`` (rad).
        first : int, optional
            The first joint computed.
        F_prev : numpy.ndarray, optional
            (3, 4, T) ``[R | o]`` of joint ``first - 1`` in the base frame (the part of the chain
            before ``first``, computed once by the caller when those joints are held); None: the
            base frame itself (only with ``first == 0``).

        Returns
        -------
        F : numpy.ndarray
            (k, 3, 4, T) ``[R_i | o_i]`` of each joint in the base frame.
        W : numpy.ndarray
            (k, 3, T) each joint's unit axis in the base frame.

        Raises
        ------
        ValueError
            If ``first > 0`` without ``F_prev`` or the joints run past the chain.

        References
        ----------
        .. [1] PA10 thesis (seeds 002), eq. 3-3.
        """
        ang = np.asarray(angles, float)
        k, T = ang.shape
        if first < 0 or first + k > self.n:
            raise ValueError(f"joints {first}..{first + k - 1} are not in the chain's 0..{self.n - 1}")
        if F_prev is None and first > 0:
            raise ValueError("F_prev (the frame of joint first - 1) is needed when first > 0")
        blocks = self._soa_blocks()
        F = np.empty((k, 3, 4, T))
        W = np.empty((k, 3, T))
        tmp = np.empty((3, 3, T))
        prev = F_prev
        sin, cos = np.sin(ang), np.cos(ang)
        for r in range(k):  # joints (n <= ~7), frames vectorised
            Ct = blocks[first + r]                      # (11, 3)
            s = sin[r]
            c = cos[r]
            if prev is None:
                B = Ct.T[:, :, None]                    # (3, 11, 1): the base frame is identity
                F[r, :, 3] = B[:, 9]
            else:
                B = np.matmul(Ct, prev[:, :3])          # (3, 11, T) = R_{i-1} [C blocks | p | Pr a]
                np.add(prev[:, 3], B[:, 9], out=F[r, :, 3])
            W[r] = B[:, 10]
            rodrigues_combine(B[:, 0:3], B[:, 3:6], B[:, 6:9], s, c, out=F[r, :, :3], scratch=tmp)
            prev = F[r]
        return F, W

    def _soa_blocks(self) -> list:
        """Per joint the transposed ``[Pr, Pr K, Pr K^2, p, Pr a]`` (11, 3) of
        :meth:`joint_frames_soa` (``R_i = R_{i-1} (B_0 + sin q B_1 + (1 - cos q) B_2)``, the terms
        of :func:`mocap.numerics.rodrigues_terms`); once per chain."""
        blocks = self.__dict__.get("_blocks_soa")
        if blocks is None:
            blocks = []
            for i in range(self.n):
                P = self.T_parent_joint[i]
                Pr = P[:3, :3]
                blocks.append(np.ascontiguousarray(np.hstack(
                    [*(Pr @ rodrigues_terms(self.axes[i])), P[:3, 3:4], (Pr @ self.axes[i])[:, None]]).T))
            object.__setattr__(self, "_blocks_soa", blocks)   # a cache, not a field
        return blocks

    def joint_transforms(self, q: np.ndarray) -> np.ndarray:
        """``T_base_joint`` for every joint: (T, n, 4, 4) from q (T, n) (or (n,) -> (n, 4, 4))."""
        single = np.asarray(q).ndim == 1
        out = make_transform(*self.joint_frames(q))
        return out[0] if single else out

    def frame_transform(self, name: str, q: np.ndarray) -> np.ndarray:
        """Pose ``T_base_<name>`` of a named frame at the joint angles ``q``.

        The chain product of the class docstring up to the frame's joint, times the frame's
        fixed placement (thesis eq. 3-3 [1]_).

        Parameters
        ----------
        name : str
            A key of :attr:`frames`.
        q : numpy.ndarray
            (n,) or (T, n) joint angles (rad).

        Returns
        -------
        numpy.ndarray
            (4, 4) or (T, 4, 4) homogeneous transforms.

        Raises
        ------
        KeyError
            If the chain has no frame ``name``.

        References
        ----------
        .. [1] PA10 thesis (seeds 002), eq. 3-3.
        """
        if name not in self.frames:
            raise KeyError(f"no frame {name!r} in the chain (frames: {', '.join(self.frames)})")
        j, T_jf = self.frames[name]
        q = np.asarray(q, float)
        if j < 0:
            return np.broadcast_to(T_jf, q.shape[:-1] + (4, 4)).copy()
        Tj = self.joint_transforms(q)[..., j, :, :]
        return Tj @ T_jf

    def joint_axis_lines(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Points on and directions of every joint axis in the base frame: two (n, 3) arrays."""
        Tj = self.joint_transforms(np.asarray(q, float))
        points = Tj[:, :3, 3]
        dirs = np.einsum("nij,nj->ni", Tj[:, :3, :3], self.axes)
        return points, dirs
