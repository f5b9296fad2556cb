"""Batched joint torque regressor of a serial chain of revolute joints, and its base parameters.

``tau = Y(q, qd, qdd) @ pi`` with ``pi`` the ten standard inertial parameters of every body in
pinocchio's order (``m, m c_x, m c_y, m c_z, I_xx, I_xy, I_yy, I_xz, I_yz, I_zz``, about the
joint frame's origin), exactly what ``pinocchio.computeJointTorqueRegressor`` returns for one
sample, but for all ``T`` samples at once: the recursive Newton-Euler passes run over the joints
(a short Python loop of length n) and every operation inside is vectorised over samples.

Base parameters: the columns of the regressor that the chain's structure leaves identifiable
(QR with column pivoting on the regressor at random states within the joint limits); the
others are linear combinations of them (``beta = pi_base + K pi_rest``), as in Gautier's
numerical method.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from ident.signals.blas import one_blas_thread
from mocap.numerics import rotation_about_axis, skew
from mocap.robot import joint_axis

PARAM_NAMES = ("m", "mcx", "mcy", "mcz", "Ixx", "Ixy", "Iyy", "Ixz", "Iyz", "Izz")


def _cross(a, b):
    """Row-wise cross product of (T, 3) arrays (faster than np.cross on small last axes)."""
    return np.stack([a[:, 1] * b[:, 2] - a[:, 2] * b[:, 1], a[:, 2] * b[:, 0] - a[:, 0] * b[:, 2],
                     a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]], axis=1)


def _inertia_cols(w: np.ndarray) -> np.ndarray:
    """(T, 3, 6) matrix L(w) with ``I @ w = L(w) @ [Ixx, Ixy, Iyy, Ixz, Iyz, Izz]``."""
    T = w.shape[0]
    L = np.zeros((T, 3, 6))
    wx, wy, wz = w[:, 0], w[:, 1], w[:, 2]
    L[:, 0, 0], L[:, 0, 1], L[:, 0, 3] = wx, wy, wz
    L[:, 1, 1], L[:, 1, 2], L[:, 1, 4] = wx, wy, wz
    L[:, 2, 3], L[:, 2, 4], L[:, 2, 5] = wx, wy, wz
    return L


def _body_regressor(v, w, a, al) -> np.ndarray:
    """(T, 6, 10) spatial force regressor (linear force, moment) of one body at its frame's
    origin from its spatial velocity (v, w) and spatial acceleration (a, al) in that frame:
    ``f = m (a + w x v) + al x h + w x (w x h)``,
    ``n = h x a + w x (h x v) + v x (w x h) + I al + w x (I w)``."""
    T = v.shape[0]
    Y = np.zeros((T, 6, 10))
    Y[:, :3, 0] = a + _cross(w, v)
    e = np.eye(3)
    for k in range(3):                       # the three first moments, loop of 3
        ek = np.broadcast_to(e[k], (T, 3))
        Y[:, :3, 1 + k] = _cross(al, ek) + _cross(w, _cross(w, ek))
        Y[:, 3:, 1 + k] = _cross(ek, a) + _cross(w, _cross(ek, v)) + _cross(v, _cross(w, ek))
    Y[:, 3:, 4:] = _inertia_cols(al) + skew(w) @ _inertia_cols(w)
    return Y


@dataclass(frozen=True, eq=False)
class ChainDynamics:
    r"""The dynamics of a serial revolute chain in the form linear in its inertial parameters.

    .. math::

        \tau = Y(q, \dot{q}, \ddot{q})\, \pi

    the rigid-body part of thesis eq. 2-1 [1]_ with ``pi`` the ten standard inertial
    parameters of every body (:meth:`regressor`, batched over samples); built from a pinocchio
    model by :meth:`from_model`.

    Attributes
    ----------
    placements : numpy.ndarray
        (n, 4, 4) joint placements in their parent joint's frame.
    axes : numpy.ndarray
        (n, 3) unit joint axes.
    pi : numpy.ndarray
        (10 n,) standard parameters of the model, in pinocchio's order
        (``m, m c_x, m c_y, m c_z, I_xx, I_xy, I_yy, I_xz, I_yz, I_zz`` per body).
    gravity : numpy.ndarray
        (3,) gravity in the base frame (m/s^2).
    names : tuple of str
        The joints' names.

    References
    ----------
    .. [1] PA10 thesis (seeds 002), eq. 2-1.
    .. [2] Carpentier et al. 2019, the Pinocchio C++ library.
    """

    placements: np.ndarray          # (n, 4, 4)
    axes: np.ndarray                # (n, 3)
    pi: np.ndarray                  # (10 n,) standard parameters of the model
    gravity: np.ndarray             # (3,)
    names: tuple

    @classmethod
    def from_model(cls, model) -> "ChainDynamics":
        """Build the chain's dynamics from a pinocchio model [1]_ (e.g. ``Robot.model``).

        Parameters
        ----------
        model : pinocchio.Model
            A serial chain of revolute joints.

        Returns
        -------
        ChainDynamics
            Its placements, axes, standard parameters, gravity and joint names.

        References
        ----------
        .. [1] Carpentier et al. 2019, the Pinocchio C++ library.
        """

        n = model.njoints - 1
        pl = np.array([model.jointPlacements[i].homogeneous for i in range(1, n + 1)])
        ax = np.array([joint_axis(model.joints[i]) for i in range(1, n + 1)], float)
        ax /= np.linalg.norm(ax, axis=1, keepdims=True)
        pi = np.concatenate([np.asarray(model.inertias[i].toDynamicParameters()).ravel()
                             for i in range(1, n + 1)])
        return cls(pl.reshape(n, 4, 4), ax.reshape(n, 3), pi, np.array(model.gravity.linear, float),
                   tuple(model.names[1:]))

    @property
    def n(self) -> int:
        return self.axes.shape[0]

    def regressor(self, q, qd, qdd) -> np.ndarray:
        """Joint torque regressor ``Y`` of ``tau = Y pi`` for many states at once.

        The recursive Newton-Euler passes over the joints, vectorised over samples: what
        ``pinocchio.computeJointTorqueRegressor`` returns for one sample [1]_, the rigid-body
        part of thesis eq. 2-1 [2]_.

        Parameters
        ----------
        q, qd, qdd : array_like
            (T, n) joint angles (rad), velocities (rad/s), accelerations (rad/s^2).

        Returns
        -------
        numpy.ndarray
            (T, n, 10 n) regressor.

        Raises
        ------
        ValueError
            If the states do not have the chain's n joints.

        References
        ----------
        .. [1] Carpentier et al. 2019, the Pinocchio C++ library.
        .. [2] PA10 thesis (seeds 002), eq. 2-1.
        """
        q, qd, qdd = (np.atleast_2d(np.asarray(x, float)) for x in (q, qd, qdd))
        T, n = q.shape
        if n != self.n:
            raise ValueError(f"states have {n} joints, the chain {self.n}")
        v = np.zeros((T, 3))
        w = np.zeros((T, 3))
        a = np.broadcast_to(-self.gravity, (T, 3)).copy()   # gravity as a base acceleration
        al = np.zeros((T, 3))
        # axes of joints 0..i as motion vectors in frame i (linear, angular): tau_j gets
        # s_j^T X*_{j<-i} f_i = (X_{i<-j} s_j)^T f_i from body i
        Sv = np.zeros((T, 0, 3))
        Sw = np.zeros((T, 0, 3))
        out = np.zeros((T, n, 10 * n))
        for i in range(n):
            R0, p = self.placements[i, :3, :3], self.placements[i, :3, 3]
            Ei = R0 @ rotation_about_axis(self.axes[i], q[:, i])       # child axes in the parent frame
            Et = np.swapaxes(Ei, 1, 2)
            pb = np.broadcast_to(p, (T, 3))
            v_lin = (Et @ (v + _cross(w, pb))[:, :, None])[:, :, 0]
            w_i = (Et @ w[:, :, None])[:, :, 0]
            a_lin = (Et @ (a + _cross(al, pb))[:, :, None])[:, :, 0]
            al_i = (Et @ al[:, :, None])[:, :, 0]
            s = self.axes[i]
            sw = qd[:, i, None] * s
            # a = X a_parent + S qdd + v x (S qd), motion cross product (v, w) x (0, s qd)
            a_lin = a_lin + _cross(v_lin, sw)
            al_i = al_i + qdd[:, i, None] * s + _cross(w_i, sw)
            w_i = w_i + sw
            v, w, a, al = v_lin, w_i, a_lin, al_i
            # earlier axes into frame i: w' = E^T w, v' = E^T (v + w x p)
            Sv = (Sv + np.cross(Sw, p)) @ Ei
            Sw = Sw @ Ei
            Sv = np.concatenate([Sv, np.zeros((T, 1, 3))], axis=1)
            Sw = np.concatenate([Sw, np.broadcast_to(s, (T, 1, 3))], axis=1)
            Yi = _body_regressor(v, w, a, al)
            out[:, :i + 1, 10 * i:10 * i + 10] = Sv @ Yi[:, :3, :] + Sw @ Yi[:, 3:, :]
        return out


@dataclass(frozen=True, eq=False)
class BaseParameters:
    """Identifiable combinations of the standard inertial parameters (base parameters).

    ``Y @ pi = Y[:, idx] @ beta`` with ``beta = pi[idx] + K @ pi[rest]`` for every state
    [1]_ [2]_; found by :func:`base_parameters`.

    Attributes
    ----------
    idx : numpy.ndarray
        Indices of the independent columns of the regressor.
    rest : numpy.ndarray
        Indices of the dependent columns.
    K : numpy.ndarray
        (len(idx), len(rest)) the dependent columns in terms of the independent ones.

    References
    ----------
    .. [1] Gautier & Khalil 1990, direct calculation of minimum set of inertial parameters of
       serial robots.
    .. [2] Gautier 1991, numerical calculation of the base inertial parameters of robots.
    """

    idx: np.ndarray          # independent columns
    rest: np.ndarray         # dependent columns
    K: np.ndarray            # (len(idx), len(rest))

    def beta(self, pi: np.ndarray) -> np.ndarray:
        return pi[self.idx] + self.K @ pi[self.rest]

    @property
    def n_base(self) -> int:
        return int(self.idx.size)


def base_parameters(chain: ChainDynamics, lower=None, upper=None, n_states: int = 200,
                    seed: int = 0, tol: float = 1e-8) -> BaseParameters:
    """Find the base parameters of a chain by QR with column pivoting of its regressor.

    The regressor stacked over random states (positions within ``lower``/``upper`` or +-pi,
    velocities and accelerations standard normal); the columns QR keeps are independent, the
    others their linear combinations (Gautier's numerical method [1]_ [2]_). One BLAS thread:
    the matrices are small (200 n rows), where threads only add overhead.

    Parameters
    ----------
    chain : ChainDynamics
        The chain.
    lower, upper : array_like, optional
        (n,) joint limits (rad); non-finite or None: +-pi.
    n_states : int, optional
        Random states stacked (default 200).
    seed : int, optional
        Seed of the states (default 0).
    tol : float, optional
        Relative tolerance on the diagonal of R below which a column is dependent.

    Returns
    -------
    BaseParameters
        The independent columns and the combination matrix.

    References
    ----------
    .. [1] Gautier & Khalil 1990, direct calculation of minimum set of inertial parameters of
       serial robots.
    .. [2] Gautier 1991, numerical calculation of the base inertial parameters of robots.
    """

    with one_blas_thread():
        return _base_parameters(chain, lower, upper, n_states, seed, tol)


def _base_parameters(chain, lower, upper, n_states, seed, tol) -> BaseParameters:
    from scipy.linalg import qr

    rng = np.random.default_rng(seed)
    n = chain.n
    lo = np.full(n, -np.pi) if lower is None else np.where(np.isfinite(lower), lower, -np.pi)
    hi = np.full(n, np.pi) if upper is None else np.where(np.isfinite(upper), upper, np.pi)
    q = rng.uniform(lo, hi, (n_states, n))
    W = chain.regressor(q, rng.standard_normal((n_states, n)),
                        rng.standard_normal((n_states, n))).reshape(n_states * n, -1)
    scale = np.linalg.norm(W, axis=0)
    live = scale > tol * max(scale.max(), 1e-300)
    Wn = np.where(live, W / np.where(live, scale, 1.0), 0.0)
    _, R, piv = qr(Wn, mode="economic", pivoting=True)
    d = np.abs(np.diag(R))
    r = int(np.sum(d > tol * d[0]))
    idx, rest = piv[:r], piv[r:]
    # W[:, rest] = W[:, idx] @ K
    K, *_ = np.linalg.lstsq(W[:, idx], W[:, rest], rcond=None)
    order = np.argsort(idx)
    return BaseParameters(idx[order], rest, K[order])
