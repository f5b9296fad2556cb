"""Vectorised forward kinematics of a serial revolute chain (numpy, batched over frames).

The chain is extracted once from a pinocchio model (see :mod:`mocap.robot`); the batched
functions here take joint angles ``q`` of shape ``(T, n)`` and return homogeneous transforms
of shape ``(T, n, 4, 4)`` without a Python loop over frames.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np


def rotation_about_axis(axis: np.ndarray, angle: np.ndarray) -> np.ndarray:
    """Rodrigues: rotation matrices (..., 3, 3) for a unit ``axis`` (3,) and angles (...)."""
    a = np.asarray(axis, float)
    angle = np.asarray(angle, float)
    K = np.array([[0.0, -a[2], a[1]], [a[2], 0.0, -a[0]], [-a[1], a[0], 0.0]])
    s = np.sin(angle)[..., None, None]
    c = np.cos(angle)[..., None, None]
    return np.eye(3) + s * K + (1.0 - c) * (K @ K)


def make_transform(R: np.ndarray, p: np.ndarray) -> np.ndarray:
    R = np.asarray(R, float)
    p = np.asarray(p, float)
    T = np.zeros(R.shape[:-2] + (4, 4))
    T[..., :3, :3] = R
    T[..., :3, 3] = p
    T[..., 3, 3] = 1.0
    return T


def invert_transform(T: np.ndarray) -> np.ndarray:
    T = np.asarray(T, float)
    R = T[..., :3, :3]
    p = T[..., :3, 3]
    Rt = np.swapaxes(R, -1, -2)
    return make_transform(Rt, -np.einsum("...ij,...j->...i", Rt, p))


def apply_transform(T: np.ndarray, p: np.ndarray) -> np.ndarray:
    """Apply transform(s) (..., 4, 4) to points (..., 3) with broadcasting."""
    T = np.asarray(T, float)
    return np.einsum("...ij,...j->...i", T[..., :3, :3], p) + T[..., :3, 3]


@dataclass(frozen=True, eq=False)
class Chain:
    """Kinematic description of a serial chain of ``n`` revolute joints.

    ``T_parent_joint[i]`` is the fixed placement of joint ``i`` in the frame of joint ``i-1``
    (joint -1 being the base frame); ``axes[i]`` is the unit rotation axis of joint ``i`` in its
    own frame. ``frames`` maps a link (or any named frame) to ``(joint index, T_joint_frame)``;
    a joint index of -1 means the frame is fixed to the base.
    """

    T_parent_joint: np.ndarray
    axes: np.ndarray
    joint_names: tuple[str, ...]
    frames: dict

    @property
    def n(self) -> int:
        return int(self.axes.shape[0])

    def joint_transforms(self, q: np.ndarray) -> np.ndarray:
        """``T_base_joint`` for every joint: (T, n, 4, 4) from q (T, n) (or (n,) -> (n, 4, 4))."""
        q = np.asarray(q, float)
        single = q.ndim == 1
        Q = np.atleast_2d(q)
        if Q.shape[1] != self.n:
            raise ValueError(f"q has {Q.shape[1]} columns, the chain has {self.n} joints")
        nf = Q.shape[0]
        out = np.zeros((nf, self.n, 4, 4))
        out[..., 3, 3] = 1.0
        R = np.broadcast_to(np.eye(3), (nf, 3, 3))
        p = np.zeros((nf, 3))
        for i in range(self.n):  # loop over joints (n <= ~7), vectorised over frames
            Rp, pp = self.T_parent_joint[i, :3, :3], self.T_parent_joint[i, :3, 3]
            p = p + (R.reshape(-1, 3) @ pp).reshape(nf, 3)
            RRp = (R.reshape(-1, 3) @ Rp).reshape(nf, 3, 3)      # one BLAS call for all frames
            Rj = rotation_about_axis(self.axes[i], Q[:, i])
            R = np.einsum("tij,tjk->tik", RRp, Rj, optimize=False)
            out[:, i, :3, :3] = R
            out[:, i, :3, 3] = p
        return out[0] if single else out

    def frame_transform(self, name: str, q: np.ndarray) -> np.ndarray:
        """``T_base_<name>``: (T, 4, 4) (or (4, 4) for a single q)."""
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
