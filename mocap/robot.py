"""Robot description: a serial revolute chain loaded from URDF with pinocchio, plus its drives.

``Robot`` is the immutable description (pinocchio's ``model``); pinocchio ``data`` buffers are
created where the work runs. Kinematics for many frames go through :class:`mocap.kinematics.Chain`
(numpy, batched); dynamics go through pinocchio.
"""
from __future__ import annotations

import math
import tomllib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from mocap.io.errors import InputError, read_text
from mocap.io.ranges import check_range
from mocap.kinematics import Chain
from mocap.urdf import continuous_as_revolute, select_chain

_DRIVE_KEYS = ("gear_ratio", "motor_inertia", "motor_viscous", "max_velocity", "max_torque",
               "encoder_resolution")


@dataclass(frozen=True)
class Drive:
    """Motor-side parameters of one joint, referred to the link side.

    One ``[[joint]]`` table of ``robot/drives.toml`` [1]_: the motor inertia ``J`` and viscous
    coefficient ``B`` of the motor side of thesis eq. 2-1 to 2-4 [2]_. ``gear_ratio`` is the
    reduction's magnitude; ``direction`` (+1 or -1) is the sign of the declared ratio (a
    negative ratio only says the motor turns the other way; the angles and torques of a log are
    on the link side already).

    Attributes
    ----------
    name : str
        The URDF joint name.
    gear_ratio : float
        Reduction ratio, magnitude (> 0); default 1.
    motor_inertia : float
        Motor inertia ``J`` referred to the link side (kg m^2); default 0.
    motor_viscous : float
        Motor viscous coefficient ``B`` referred to the link side (N m s/rad); default 0.
    max_velocity : float
        Velocity limit (rad/s, > 0); default infinite.
    max_torque : float
        Torque limit (N m, > 0); default infinite.
    encoder_resolution : float
        Encoder step on the link side (rad); 0: unknown.
    extra : dict
        The table's other keys (e.g. ``stiffness``, N m/rad).
    direction : int
        +1, or -1 where the declared ratio is negative.

    References
    ----------
    .. [1] jointlab data format (docs/format.md), sec. robot/drives.toml.
    .. [2] PA10 thesis (seeds 002), eq. 2-1 to 2-4.
    """

    name: str
    gear_ratio: float = 1.0
    motor_inertia: float = 0.0
    motor_viscous: float = 0.0
    max_velocity: float = float("inf")
    max_torque: float = float("inf")
    encoder_resolution: float = 0.0
    extra: dict = field(default_factory=dict)
    direction: int = 1

    @property
    def signed_gear_ratio(self) -> float:
        """The ratio as declared (``direction * gear_ratio``)."""
        return self.direction * self.gear_ratio

    def to_dict(self) -> dict:
        d = {"name": self.name}
        d.update({k: getattr(self, k) for k in _DRIVE_KEYS})
        d["gear_ratio"] = self.signed_gear_ratio
        d.update(self.extra)
        return d


def read_drives(path: str | Path) -> tuple[Drive, ...]:
    """Read ``robot/drives.toml``: one :class:`Drive` per ``[[joint]]`` table, in file order.

    Parameters
    ----------
    path : str or pathlib.Path
        The drives file [1]_.

    Returns
    -------
    tuple of Drive
        One per ``[[joint]]`` table.

    Raises
    ------
    InputError
        If the file is missing or not TOML, has no ``[[joint]]`` table, a table lacks
        ``name``, or a value is not a number in its range (naming the key).

    References
    ----------
    .. [1] jointlab data format (docs/format.md), sec. robot/drives.toml.
    """
    path = Path(path)
    if not path.is_file():
        raise InputError("drives file not found", path=path)
    try:
        doc = tomllib.loads(read_text(path))
    except tomllib.TOMLDecodeError as exc:
        raise InputError(f"not valid TOML: {exc}", path=path) from None
    joints = doc.get("joint")
    if not isinstance(joints, list) or not joints:
        raise InputError("expected one [[joint]] table per joint", path=path)
    drives = []
    for k, tab in enumerate(joints, start=1):
        if "name" not in tab:
            raise InputError(f"[[joint]] number {k} has no 'name'", path=path)
        vals = {}
        for key in _DRIVE_KEYS:
            if key in tab:
                v = tab[key]
                if not isinstance(v, (int, float)) or isinstance(v, bool):
                    raise InputError(f"joint {tab['name']!r}: {key} must be a number, got {v!r}",
                                     path=path, label=key)
                if key == "gear_ratio" and v < 0:     # only the direction (FORMAT.md)
                    vals["direction"] = -1
                    v = -v
                # mocap.io.ranges.RANGES: finite, > 0 for a ratio, a limit or a step
                vals[key] = check_range("drive", key, v, path=path, where=f"joint {tab['name']!r}")
        if tab.get("stiffness") is not None:
            check_range("drive", "stiffness", tab["stiffness"], path=path,
                        where=f"joint {tab['name']!r}")
        extra = {kk: vv for kk, vv in tab.items() if kk not in _DRIVE_KEYS and kk != "name"}
        drives.append(Drive(name=str(tab["name"]), extra=extra, **vals))
    return tuple(drives)


def write_drives(path: str | Path, drives, overwrite: bool = False) -> Path:
    path = Path(path)
    if path.exists() and not overwrite:
        raise FileExistsError(f"{path} exists; refusing to overwrite")
    out = []
    for d in drives:
        out.append("[[joint]]")
        out.append(f'name = "{d.name}"')
        for k in _DRIVE_KEYS:
            v = d.signed_gear_ratio if k == "gear_ratio" else getattr(d, k)
            if not math.isfinite(v) or (k == "encoder_resolution" and v == 0):
                continue                      # no limit / unknown: the key is left out
            out.append(f"{k} = {float(v)!r}")
        out.append("")
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("\n".join(out), encoding="utf-8")
    return path


def joint_axis(jm) -> np.ndarray | None:
    """The unit axis (3,) of a pinocchio revolute joint model in its joint frame (RX, RY, RZ or
    revolute-unaligned), or None for any other joint type."""
    short = jm.shortname()
    table = {"JointModelRX": (1, 0, 0), "JointModelRY": (0, 1, 0), "JointModelRZ": (0, 0, 1)}
    if short in table:
        return np.array(table[short], float)
    if short == "JointModelRevoluteUnaligned":
        return np.asarray(jm.extract().axis, float).copy()
    return None


def _finite(x) -> float | None:
    """``float(x)``, or None (JSON null) where it is infinite: no limit."""
    x = float(x)
    return x if np.isfinite(x) else None


class Robot:
    """A serial chain of revolute joints with drives: the rigid-link model of the arm.

    The link side of thesis eq. 2-1 [1]_, ``M(q) qdd + V(q, qd) qd + G(q)``, evaluated by
    pinocchio [2]_ (:meth:`rnea`, :meth:`mass_matrix`, :meth:`gravity_torque`); kinematics for
    many frames go through :class:`mocap.kinematics.Chain` (:attr:`chain`). Usually built with
    :meth:`from_urdf` from the campaign's ``robot/`` folder [3]_.

    Parameters
    ----------
    model : pinocchio.Model
        Built from the URDF (fixed joints merged); every joint revolute, one serial chain.
    drives : sequence of Drive, optional
        One per joint, in joint order; None: defaults from the URDF limits.
    gravity : array_like, optional
        (3,) gravity vector in the base frame (m/s^2); default ``(0, 0, -9.81)``.
    urdf : pathlib.Path, optional
        The URDF file, for messages and :meth:`describe`.
    selection : mocap.urdf.ChainSelection, optional
        How the chain was selected from the URDF; None: the URDF as it is.

    Raises
    ------
    InputError
        If a joint is not revolute, the joints do not form one serial chain, an axis is zero,
        or ``drives`` does not describe every joint.

    References
    ----------
    .. [1] PA10 thesis (seeds 002), eq. 2-1.
    .. [2] Carpentier et al. 2019, the Pinocchio C++ library.
    .. [3] jointlab data format (docs/format.md), sec. Which chain is the arm.
    """

    def __init__(self, model, drives=None, gravity=(0.0, 0.0, -9.81), urdf: Path | None = None,
                 selection=None):
        import pinocchio as pin

        self.model = model
        self.urdf = urdf
        self.selection = selection      # mocap.urdf.ChainSelection (None: the URDF as it is)
        self.model.gravity.linear = np.asarray(gravity, float)
        n = model.njoints - 1
        axes, placements, names = [], [], []
        for i in range(1, model.njoints):
            jm = model.joints[i]
            ax = joint_axis(jm)
            if ax is None or jm.nq != 1:
                raise InputError(f"joint {model.names[i]!r} is {jm.shortname()}; only revolute (and "
                                 "continuous) joints are supported in the arm's chain: choose [robot] "
                                 "base_link/tip_link around it and give its value in [robot] fixed",
                                 path=urdf, label=model.names[i])
            if model.parents[i] != i - 1:
                raise InputError(f"joint {model.names[i]!r} does not continue a serial chain",
                                 path=urdf, label=model.names[i])
            norm = float(np.linalg.norm(ax))
            if not np.isfinite(norm) or norm < 1e-9:
                raise InputError(f"joint {model.names[i]!r} has axis {ax.tolist()}: a revolute axis "
                                 "needs a non-zero direction", path=urdf, label=model.names[i])
            axes.append(ax / norm)
            placements.append(model.jointPlacements[i].homogeneous)
            names.append(model.names[i])
        frames = {}
        for f in model.frames:
            if f.type == pin.FrameType.BODY:
                frames[f.name] = (int(f.parentJoint) - 1, f.placement.homogeneous.copy())
        self.chain = Chain(np.array(placements).reshape(n, 4, 4), np.array(axes).reshape(n, 3),
                           tuple(names), frames)
        if drives is None:
            drives = tuple(Drive(name=nm, max_velocity=float(model.velocityLimit[k]),
                                 max_torque=float(model.effortLimit[k])) for k, nm in enumerate(names))
        drives = tuple(drives)
        if len(drives) != n:
            chain = ("" if selection is None or not selection.reduced else
                     f" in the chain {selection.base_link} -> {selection.tip_link} "
                     f"({', '.join(names)})")
            raise InputError(f"drives describe {len(drives)} joints but the URDF has {n} revolute "
                             f"joints{chain}", path=urdf)
        self.drives = drives

    # ---- construction -------------------------------------------------------------------
    @classmethod
    def from_urdf(cls, urdf: str | Path, drives: str | Path | None = None,
                  gravity=(0.0, 0.0, -9.81), base_link: str | None = None,
                  tip_link: str | None = None, fixed: dict | None = None,
                  where: Path | None = None) -> "Robot":
        """Load the robot of a URDF and its drives file.

        The serial chain from ``base_link`` to ``tip_link`` with every other joint fixed
        (:func:`mocap.urdf.select_chain` [1]_; pinocchio's ``buildReducedModel`` [2]_: the
        bodies beyond a fixed joint are merged into the link that carries them). ``gravity``
        is given in ``base_link``'s frame; the robot's base frame is the URDF's root link (the
        same frame where ``base_link`` is the root).

        Parameters
        ----------
        urdf : str or pathlib.Path
            The URDF file.
        drives : str or pathlib.Path, optional
            ``drives.toml`` (:func:`read_drives`); None: drives from the URDF limits.
        gravity : array_like, optional
            (3,) gravity in ``base_link``'s frame (m/s^2); default ``(0, 0, -9.81)``.
        base_link, tip_link : str, optional
            Ends of the arm's chain (``[robot]`` of ``campaign.toml``); None: the URDF's root
            and its single serial tip.
        fixed : dict, optional
            {joint name: angle (rad)} at which joints off the chain are fixed; default 0.
        where : pathlib.Path, optional
            The file that named the chain (``campaign.toml``), for messages.

        Returns
        -------
        Robot
            The arm, its joints in chain order.

        Raises
        ------
        InputError
            If the URDF is missing or unreadable, the chain cannot be selected, or the drives
            file is invalid or describes another number of joints.

        References
        ----------
        .. [1] jointlab data format (docs/format.md), sec. Which chain is the arm.
        .. [2] Carpentier et al. 2019, the Pinocchio C++ library.
        """
        import pinocchio as pin

        urdf = Path(urdf)
        if not urdf.is_file():
            raise InputError("URDF not found", path=urdf)
        sel = select_chain(urdf, base_link, tip_link, fixed, where=where)
        try:              # continuous joints of the arm: unbounded revolute, one coordinate each
            xml, limits = continuous_as_revolute(urdf, sel.chain)
            model = pin.buildModelFromXML(xml) if xml is not None else pin.buildModelFromUrdf(str(urdf))
        except (RuntimeError, ValueError) as exc:
            raise InputError(f"pinocchio could not read the URDF: {exc}", path=urdf) from None
        for nm, (eff, vel) in limits.items():
            jm = model.joints[model.getJointId(nm)]
            model.lowerPositionLimit[jm.idx_q] = -np.inf
            model.upperPositionLimit[jm.idx_q] = np.inf
            model.effortLimit[jm.idx_v] = np.inf if eff is None else eff
            model.velocityLimit[jm.idx_v] = np.inf if vel is None else vel
        if sel.reduced:
            q0 = pin.neutral(model)
            ids = []
            for nm, v in sel.locked.items():
                if not model.existJointName(nm):
                    continue                    # a mimic or otherwise merged joint
                jid = model.getJointId(nm)
                jm = model.joints[jid]
                if jm.nq == 1:
                    q0[jm.idx_q] = v
                elif jm.nq == 2 and jm.nv == 1:                 # continuous: (cos, sin)
                    q0[jm.idx_q:jm.idx_q + 2] = (math.cos(v), math.sin(v))
                ids.append(jid)
            model = pin.buildReducedModel(model, ids, q0)
            g = np.asarray(gravity, float)
            if model.existBodyName(sel.base_link):
                f = model.frames[model.getBodyId(sel.base_link)]
                if int(f.parentJoint) == 0:
                    g = f.placement.rotation @ g      # base_link's frame -> the root's
            gravity = g
        dr = read_drives(drives) if drives is not None else None
        return cls(model, dr, gravity, urdf, selection=sel)

    # ---- description --------------------------------------------------------------------
    @property
    def n(self) -> int:
        return self.chain.n

    @property
    def joint_names(self) -> tuple[str, ...]:
        return self.chain.joint_names

    @property
    def link_names(self) -> tuple[str, ...]:
        return tuple(self.chain.frames)

    @property
    def lower(self) -> np.ndarray:
        return np.asarray(self.model.lowerPositionLimit, float).copy()

    @property
    def upper(self) -> np.ndarray:
        return np.asarray(self.model.upperPositionLimit, float).copy()

    @property
    def max_velocity(self) -> np.ndarray:
        return np.array([d.max_velocity for d in self.drives])

    @property
    def max_torque(self) -> np.ndarray:
        return np.array([d.max_torque for d in self.drives])

    @property
    def gravity(self) -> np.ndarray:
        return np.asarray(self.model.gravity.linear, float).copy()

    @property
    def tip_link(self) -> str:
        """``[robot] tip_link`` where the chain was selected, else the most distal body frame
        (the flange or tool link of a serial chain)."""
        if self.selection is not None and self.selection.reduced \
                and self.selection.tip_link in self.chain.frames:
            return self.selection.tip_link
        names = [nm for nm, (jj, _) in self.chain.frames.items() if jj == self.n - 1]
        return names[-1]

    def link_of_joint(self, j: int) -> str:
        """Name of the link carried by joint ``j`` (0-based): the body frame at its origin."""
        for name, (jj, T) in self.chain.frames.items():
            if jj == j and np.allclose(T, np.eye(4)):
                return name
        for name, (jj, _) in self.chain.frames.items():
            if jj == j:
                return name
        raise KeyError(f"no link attached to joint {j}")

    def describe(self) -> dict:
        return {
            "urdf": None if self.urdf is None else str(self.urdf),
            "n_joints": self.n,
            "joints": [   # null: no limit (a continuous joint, a URDF limit left out)
                {"name": nm, "lower": _finite(lo), "upper": _finite(up),
                 "max_velocity": _finite(d.max_velocity), "max_torque": _finite(d.max_torque),
                 "link": self.link_of_joint(k)}
                for k, (nm, lo, up, d) in enumerate(zip(self.joint_names, self.lower, self.upper,
                                                        self.drives))
            ],
            "links": list(self.link_names),
            "gravity": self.gravity.tolist(),
            "chain": (None if self.selection is None or not self.selection.reduced else
                      {"base_link": self.selection.base_link, "tip_link": self.selection.tip_link,
                       "fixed": dict(self.selection.locked)}),
            "direction": [d.direction for d in self.drives],
        }

    # ---- kinematics ---------------------------------------------------------------------
    def frame_transform(self, name: str, q) -> np.ndarray:
        """Pose ``T_base_<name>`` of a link frame at the joint angles ``q``.

        The product of joint placements and rotations about the joint axes (Rodrigues), the
        forward kinematics of :meth:`mocap.kinematics.Chain.frame_transform` [1]_.

        Parameters
        ----------
        name : str
            A body frame of the URDF (:attr:`link_names`).
        q : array_like
            (n,) or (T, n) joint angles (rad).

        Returns
        -------
        numpy.ndarray
            (4, 4) or (T, 4, 4) homogeneous transform from the frame to the base.

        References
        ----------
        .. [1] PA10 thesis (seeds 002), eq. 3-3.
        """
        return self.chain.frame_transform(name, q)

    # ---- dynamics (pinocchio) -------------------------------------------------------------
    def with_payload(self, mass: float, p_flange=(0.0, 0.0, 0.0), link: str | None = None) -> "Robot":
        """A copy with a point mass ``mass`` (kg) at ``p_flange`` in the frame of ``link``
        (default: the most distal body frame of the URDF, i.e. the flange or tool link)."""
        import pinocchio as pin

        model = self.model.copy()
        if mass > 0:
            link = link or self.tip_link
            j, T_jf = self.chain.frames[link]
            p_joint = T_jf[:3, :3] @ np.asarray(p_flange, float) + T_jf[:3, 3]
            model.appendBodyToJoint(j + 1, pin.Inertia(float(mass), p_joint, np.zeros((3, 3))),
                                    pin.SE3.Identity())
        return Robot(model, self.drives, self.gravity, self.urdf, self.selection)

    def rnea(self, q, qd, qdd) -> np.ndarray:
        r"""Joint torques of the rigid-body model without friction (inverse dynamics).

        .. math::

            \tau = M(q)\,\ddot{q} + V(q, \dot{q})\,\dot{q} + G(q)

        the link side of thesis eq. 2-1 [1]_ by the recursive Newton-Euler algorithm:
        pinocchio's batched RNEA [2]_ (``rneaInParallel``, one thread; the loop over samples
        runs in C++).

        Parameters
        ----------
        q, qd, qdd : array_like
            (n,) or (T, n) joint angles (rad), velocities (rad/s), accelerations (rad/s^2).

        Returns
        -------
        numpy.ndarray
            (T, n) or (n,) torques (N m).

        References
        ----------
        .. [1] PA10 thesis (seeds 002), eq. 2-1.
        .. [2] Carpentier et al. 2019, the Pinocchio C++ library.
        """
        import pinocchio as pin

        q, qd, qdd = (np.atleast_2d(np.asarray(a, float)) for a in (q, qd, qdd))
        if q.shape[0] == 1:
            out = pin.rnea(self.model, self.model.createData(), q[0], qd[0], qdd[0])[None, :]
        else:
            pool = pin.ModelPool(self.model, 1)
            # column-major output: a (1, T) C-ordered array is not written as a matrix
            out = np.zeros((self.n, q.shape[0]), order="F")
            pin.rneaInParallel(1, pool, np.asfortranarray(q.T), np.asfortranarray(qd.T),
                               np.asfortranarray(qdd.T), out)
            out = out.T
        return out if out.shape[0] > 1 else out[0]

    def mass_matrix(self, q) -> np.ndarray:
        """Joint-space inertia matrix ``M(q)`` of thesis eq. 2-1 [1]_ (pinocchio's CRBA [2]_).

        Parameters
        ----------
        q : array_like
            (n,) joint angles (rad).

        Returns
        -------
        numpy.ndarray
            (n, n) symmetric inertia matrix (kg m^2).

        References
        ----------
        .. [1] PA10 thesis (seeds 002), eq. 2-1.
        .. [2] Carpentier et al. 2019, the Pinocchio C++ library.
        """
        import pinocchio as pin

        data = self.model.createData()
        M = pin.crba(self.model, data, np.asarray(q, float))
        return np.triu(M) + np.triu(M, 1).T

    def gravity_torque(self, q) -> np.ndarray:
        """Generalised gravity torque ``G(q)`` of thesis eq. 2-1 [1]_.

        :meth:`rnea` at zero velocity and acceleration.

        Parameters
        ----------
        q : array_like
            (n,) or (T, n) joint angles (rad).

        Returns
        -------
        numpy.ndarray
            (T, n) or (n,) torques (N m).

        References
        ----------
        .. [1] PA10 thesis (seeds 002), eq. 2-1.
        """
        q = np.atleast_2d(np.asarray(q, float))
        z = np.zeros_like(q)
        out = np.atleast_2d(self.rnea(q, z, z))
        return out if out.shape[0] > 1 else out[0]

    @property
    def stiffness(self) -> np.ndarray:
        """Declared transmission stiffness per joint (``drives.toml`` ``stiffness``, N m/rad,
        FORMAT.md); 0 where none is declared (a rigid joint)."""
        return np.array([float(d.extra.get("stiffness", 0.0) or 0.0) for d in self.drives])

    def held_deflection(self, q, qd=None, qdd=None, moving=()) -> np.ndarray:
        """Static deflection of the held joints under the torque they carry.

        ``q_link - q_motor = -tau / K`` of the joints *not* in ``moving`` at their declared
        stiffness: the spring of thesis eq. 2-1 [1]_ with the motor held (a braked joint's
        motor is held, its link gives under the torque it carries: gravity and the coupling
        from the moving joints, by :meth:`rnea`) [2]_.

        Parameters
        ----------
        q : array_like
            (n,) or (T, n) link angles (rad).
        qd, qdd : array_like, optional
            Velocities (rad/s) and accelerations (rad/s^2) of the same shape; None: zero.
        moving : sequence of int, optional
            The moving joints (0-based); default none.

        Returns
        -------
        numpy.ndarray
            (T, n) or (n,) deflections (rad); zeros for moving joints and joints without a
            declared stiffness.

        References
        ----------
        .. [1] PA10 thesis (seeds 002), eq. 2-1.
        .. [2] jointlab data format (docs/format.md), sec. robot/drives.toml.
        """
        k = self.stiffness
        single = np.ndim(q) == 1
        q = np.atleast_2d(np.asarray(q, float))
        held = (k > 0) & ~np.isin(np.arange(self.n), list(moving))
        out = np.zeros_like(q)
        if held.any() and q.size:
            z = np.zeros_like(q)
            qd = z if qd is None else np.atleast_2d(np.asarray(qd, float))
            qdd = z if qdd is None else np.atleast_2d(np.asarray(qdd, float))
            tau = np.atleast_2d(self.rnea(q, qd, qdd))
            out[:, held] = -tau[:, held] / k[held]
        return out[0] if single else out

    def single_joint_dynamics(self, j: int, q_rest) -> tuple[float, float, float]:
        r"""Constants of the one-link model of a joint moving alone.

        For joint ``j`` moving with the others held at ``q_rest``:

        .. math::

            \tau_j = I \ddot{q}_j + a \sin q_j + b \cos q_j

        exactly (link inertia about the axis is constant; gravity torque is a sinusoid in
        ``q_j``): the link side of thesis eq. 2-2 [1]_ with ``a = -m g l_x``, ``b = m g l_y``.

        Parameters
        ----------
        j : int
            The joint, 0-based.
        q_rest : array_like
            (n,) angles of every joint (rad); entry ``j`` is ignored.

        Returns
        -------
        tuple of float
            ``(I, a, b)``: inertia about the axis (kg m^2), the sine and cosine gravity
            coefficients (N m).

        References
        ----------
        .. [1] PA10 thesis (seeds 002), eq. 2-2.
        """
        q0 = np.array(q_rest, float)
        M = self.mass_matrix(q0)
        I = float(M[j, j])
        qa, qb = q0.copy(), q0.copy()
        qa[j], qb[j] = np.pi / 2, 0.0
        ga = float(self.gravity_torque(qa)[j])
        gb = float(self.gravity_torque(qb)[j])
        return I, ga, gb
