"""The robot's MuJoCo model: the user's MJCF (``[robot] mjcf``), or MuJoCo's own compile of the
campaign's URDF chain; per record the payload at the flange and position servos on the joints
whose torque the record does not drive.

Dynamics (MuJoCo's, per hinge dof ``i``)::

    (M(q) + diag(armature)) qdd + c(q, qd) = tau_applied - damping qd - f_loss + tau_servo

with ``f_loss`` MuJoCo's dry friction constraint of size ``frictionloss`` (a Coulomb friction
that also holds at rest). The URDF compile keeps the link inertials exactly, so that ``M, c`` equal
pinocchio's RNEA on the same URDF (``tests/test_sim2real.py``); ``armature`` starts from the
drives' ``motor_inertia`` and ``damping`` from ``motor_viscous`` (FORMAT.md: both referred to the
link side already).
"""
from __future__ import annotations

import contextlib
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from mocap.io.errors import InputError
from mocap.numerics import rotation_about_axis

#: native parameters of every joint, in the order of the parameter vectors
NATIVE = ("armature", "damping", "frictionloss")
#: bandwidth of the position servo that holds a joint whose torque is not replayed (Hz)
SERVO_HZ = 8.0
#: longest simulation step (s): records logged slower are simulated in sub-steps
MAX_STEP = 1e-3


@contextlib.contextmanager
def captured_warnings(sink: list):
    """MuJoCo's warnings (an unstable simulation, ...) appended to ``sink`` instead of MuJoCo's
    default handler, which writes ``MUJOCO_LOG.TXT`` into the working directory."""
    import mujoco

    prev = mujoco.get_mju_user_warning()
    mujoco.set_mju_user_warning(sink.append)
    try:
        yield sink
    finally:
        mujoco.set_mju_user_warning(prev)


def _rot(axis, a):
    """Rotation by ``a`` (rad) about the URDF joint axis ``axis`` (any length): Rodrigues'
    formula from :func:`mocap.numerics.rotation_about_axis`."""
    axis = np.asarray(axis, float)
    return rotation_about_axis(axis / np.linalg.norm(axis), a)


def _rpy(R):
    from scipy.spatial.transform import Rotation
    return Rotation.from_matrix(R).as_euler("xyz")


def _urdf_rpy(rpy):
    from scipy.spatial.transform import Rotation
    return Rotation.from_euler("xyz", rpy).as_matrix()


def _valid_inertia(inertial) -> bool:
    """An ``<inertial>`` whose inertia matrix MuJoCo refuses (an eigenvalue <= 0, or the triangle
    inequality broken, as vendor files have for massless dummy links) gets its eigenvalues raised to
    at least 1e-9 kg m^2 and to the triangle inequality; a valid one is left exactly as it is."""
    if inertial is None or inertial.find("inertia") is None:
        return False
    e = inertial.find("inertia")
    keys = ("ixx", "ixy", "ixz", "iyy", "iyz", "izz")
    try:
        v = {k: float(e.get(k, 0.0)) for k in keys}
    except ValueError:
        return False
    I = np.array([[v["ixx"], v["ixy"], v["ixz"]], [v["ixy"], v["iyy"], v["iyz"]], [v["ixz"], v["iyz"], v["izz"]]])
    w, V = np.linalg.eigh(I)
    if w.min() > 1e-12 and all(w[i] + w[(i + 1) % 3] >= w[(i + 2) % 3] for i in range(3)):
        return False
    w = np.maximum(w, 1e-9)
    w = np.maximum(w, np.array([abs(w[1] - w[2]), abs(w[0] - w[2]), abs(w[0] - w[1])]) + 1e-9)
    I = V @ np.diag(w) @ V.T
    for k, (a, b) in zip(keys, ((0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2))):
        e.set(k, repr(float(I[a, b])))
    return True


def urdf_for_mujoco(urdf: Path, chain: tuple, locked: dict, corrected: list | None = None) -> str:
    """The URDF as MuJoCo's URDF reader should see it: ``<visual>`` and ``<collision>`` dropped
    (meshes are optional and carry no dynamics), every moving joint off the arm's ``chain`` made
    fixed at its ``locked`` value (its origin composed with the joint's motion), ``<mimic>`` and
    ``<transmission>`` elements dropped; inertias MuJoCo refuses corrected (:func:`_valid_inertia`,
    their links appended to ``corrected``)."""
    tree = ET.parse(urdf)
    root = tree.getroot()
    for link in root.findall("link"):
        for tag in ("visual", "collision"):
            for e in link.findall(tag):
                link.remove(e)
        if _valid_inertia(link.find("inertial")) and corrected is not None:
            corrected.append(link.get("name"))
    for tag in ("transmission", "gazebo"):
        for e in root.findall(tag):
            root.remove(e)
    for j in root.findall("joint"):
        for e in j.findall("mimic"):
            j.remove(e)
        if j.get("type") in ("revolute", "continuous", "prismatic") and j.get("name") not in chain:
            v = float(locked.get(j.get("name"), 0.0))
            org = j.find("origin")
            if org is None:
                org = ET.SubElement(j, "origin")
            xyz = np.array([float(x) for x in org.get("xyz", "0 0 0").split()])
            R = _urdf_rpy([float(x) for x in org.get("rpy", "0 0 0").split()])
            ax_e = j.find("axis")
            axis = np.array([float(x) for x in ax_e.get("xyz").split()]) if ax_e is not None else np.array([1.0, 0, 0])
            if j.get("type") == "prismatic":
                xyz = xyz + R @ (axis / np.linalg.norm(axis)) * v
            else:
                R = R @ _rot(axis, v)
            org.set("xyz", " ".join(repr(float(x)) for x in xyz))
            org.set("rpy", " ".join(repr(float(x)) for x in _rpy(R)))
            j.set("type", "fixed")
            for tag in ("axis", "limit", "dynamics", "safety_controller", "calibration"):
                for e in j.findall(tag):
                    j.remove(e)
    return ET.tostring(root, encoding="unicode")


@dataclass
class SimModel:
    """A compiled base model of the arm and what maps it to jointlab's joints.

    Attributes
    ----------
    spec : mujoco.MjSpec
        The base specification (no payload, no servo gains).
    dof : numpy.ndarray
        (n,) MuJoCo dof index of each chain joint, chain order.
    names : tuple of str
        The chain's joint names.
    source : str
        ``"mjcf"`` or ``"urdf"``, and :attr:`path` the file.
    given : dict
        The native parameters as the model gives them: name -> (n,) array.
    tip_body : str
        The body that carries the payload.
    """

    spec: object
    dof: np.ndarray
    names: tuple
    source: str
    path: Path
    given: dict
    tip_body: str
    qpos_adr: np.ndarray = field(default=None)
    notes: list = field(default_factory=list)

    @property
    def n(self) -> int:
        return len(self.names)

    def spec_for(self, timestep: float, payload=None, native=None, nuserdata: int = 0):
        """A copy of the spec with the ``timestep``, the ``payload`` body and the ``native``
        parameters written on its joints (what the export saves as MJCF)."""
        import mujoco  # noqa: F401

        spec = self.spec.copy()
        spec.option.timestep = float(timestep)
        spec.nuserdata = int(nuserdata)
        if payload is not None and payload[0] > 0:
            b = spec.body(self.tip_body).add_body(name="jointlab_payload", pos=list(map(float, payload[1])))
            b.mass = float(payload[0])
            b.ipos = [0.0, 0.0, 0.0]
            b.iquat = [1.0, 0.0, 0.0, 0.0]
            b.inertia = [1e-9, 1e-9, 1e-9]
            b.explicitinertial = True
        if native is not None:
            for k, nm in enumerate(self.names):
                jt = spec.joint(nm)
                jt.armature = float(native["armature"][k])
                jt.frictionloss = float(native["frictionloss"][k])
                dmp = np.array(jt.damping, float).ravel()      # MuJoCo 4: damping polynomial
                dmp[0] = float(native["damping"][k])
                jt.damping = dmp
        return spec

    def compile(self, timestep: float, payload=None, servo_gains=None, native=None, nuserdata: int = 0):
        """An ``MjModel``: the base spec with the ``timestep``, a point ``payload`` ``(mass, com)``
        in the tip body's frame, ``servo_gains`` (n, 2) ``(kp, kv)`` on the position servos
        (0: the joint is driven by its torque only) and the ``native`` parameters."""
        import mujoco

        # the native parameters go into the spec before compiling: the compiler derives the
        # constraint weights (dof_invweight0, hence frictionloss's softness) from the armature
        m = self.spec_for(timestep, payload, native if native is not None else self.given,
                          nuserdata).compile()
        if servo_gains is not None:
            for k in range(self.n):
                kp, kv = servo_gains[k]
                m.actuator_gainprm[k, 0] = kp
                m.actuator_biasprm[k, :3] = (0.0, -kp, -kv)
        return m


def set_native(m, sm: SimModel, native: dict) -> None:
    """Write the native parameters (name -> (n,) array) into the compiled model ``m``."""
    for name in NATIVE:
        getattr(m, "dof_" + name)[sm.dof] = np.asarray(native[name], float)


def build_model(campaign, robot, mjcf: Path | None = None) -> SimModel:
    """The arm's MuJoCo model: the user's MJCF (``mjcf``, else ``[robot] mjcf``) or MuJoCo's compile
    of the campaign's URDF chain (see the module docstring).

    Raises
    ------
    InputError
        MuJoCo cannot read the file, or a chain joint is missing from the MJCF or not a hinge.
    """
    import mujoco

    mjcf = mjcf if mjcf is not None else getattr(campaign, "mjcf", None)
    names = tuple(robot.joint_names)
    if mjcf is not None:
        try:
            spec = mujoco.MjSpec.from_file(str(mjcf))
        except (ValueError, RuntimeError) as exc:
            raise InputError(f"MuJoCo could not read the MJCF: {' '.join(str(exc).split())}", path=mjcf) from None
        source, path = "mjcf", Path(mjcf)
    else:
        sel = robot.selection
        chain = tuple(sel.chain) if sel is not None else names
        locked = dict(sel.locked) if sel is not None else {}
        corrected = []
        xml = urdf_for_mujoco(campaign.urdf, chain, locked, corrected)
        try:
            spec = mujoco.MjSpec.from_string(xml)
        except (ValueError, RuntimeError) as exc:
            raise InputError(f"MuJoCo could not read the URDF: {' '.join(str(exc).split())}",
                             path=campaign.urdf) from None
        spec.compiler.inertiafromgeom = mujoco.mjtInertiaFromGeom.mjINERTIAFROMGEOM_FALSE
        spec.compiler.balanceinertia = False
        # a massless link (TX40's link_6) fails MuJoCo's check; bounds far below any real inertia
        spec.compiler.boundmass = 1e-9
        spec.compiler.boundinertia = 1e-12
        spec.compiler.fusestatic = False
        source, path = "urdf", Path(campaign.urdf)
    spec.option.gravity = [float(g) for g in robot.gravity]
    spec.option.integrator = mujoco.mjtIntegrator.mjINT_IMPLICITFAST
    spec.option.disableflags |= int(mujoco.mjtDisableBit.mjDSBL_CONTACT)
    try:
        m0 = spec.compile()
    except ValueError as exc:
        raise InputError(f"MuJoCo could not compile the model: {' '.join(str(exc).split())}", path=path) from None
    dof, qadr = [], []
    for nm in names:
        jid = mujoco.mj_name2id(m0, mujoco.mjtObj.mjOBJ_JOINT, nm)
        if jid < 0:
            raise InputError(f"the arm's joint {nm!r} is not in the MuJoCo model", path=path, label=nm)
        if m0.jnt_type[jid] != mujoco.mjtJoint.mjJNT_HINGE:
            raise InputError(f"joint {nm!r} is not a hinge in the MuJoCo model", path=path, label=nm)
        dof.append(int(m0.jnt_dofadr[jid]))
        qadr.append(int(m0.jnt_qposadr[jid]))
    if source == "urdf" and m0.nv != len(names):
        raise InputError(f"MuJoCo's compile of the URDF has {m0.nv} dofs, the arm {len(names)}", path=path)
    dof = np.array(dof)
    given = {"armature": m0.dof_armature[dof].copy(), "damping": m0.dof_damping[dof].copy(),
             "frictionloss": m0.dof_frictionloss[dof].copy()}
    if source == "urdf":          # the drives' motor side, link-side values (FORMAT.md)
        given["armature"] = given["armature"] + np.array([d.motor_inertia for d in robot.drives])
        given["damping"] = given["damping"] + np.array([d.motor_viscous for d in robot.drives])
    # the body that carries the payload: the chain's last joint's body, or a fixed child fused into it
    last = m0.jnt_bodyid[mujoco.mj_name2id(m0, mujoco.mjtObj.mjOBJ_JOINT, names[-1])]
    tip = mujoco.mj_id2name(m0, mujoco.mjtObj.mjOBJ_BODY, int(last))
    tip_link = robot.tip_link
    if mujoco.mj_name2id(m0, mujoco.mjtObj.mjOBJ_BODY, tip_link) >= 0:
        tip = tip_link
    for k, nm in enumerate(names):            # one servo per chain joint (gains set per record)
        spec.add_actuator(name=f"jointlab_servo_{k + 1}", target=nm,
                          trntype=mujoco.mjtTrn.mjTRN_JOINT, gaintype=mujoco.mjtGain.mjGAIN_FIXED,
                          biastype=mujoco.mjtBias.mjBIAS_AFFINE, gainprm=[0.0] * 10, biasprm=[0.0] * 10)
    notes = []
    if source == "urdf" and corrected:
        notes.append("inertia MuJoCo refuses (an eigenvalue <= 0 or the triangle inequality broken), "
                     "raised to the nearest valid one: " + ", ".join(corrected))
    return SimModel(spec, dof, names, source, path, given, tip, np.array(qadr), notes)
