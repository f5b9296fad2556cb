"""URDF utilities without ROS: perturbed copies, visual geometry and link meshes.

* :func:`perturb_urdf` writes a copy of a URDF with randomly perturbed joint origins, joint
  axes and link masses/inertias (a "perturbed variant" for simulators and robustness tests).
* :func:`urdf_visuals` lists each link's visual (or collision) geometry with its placement in
  the link frame, parsed with :mod:`xml.etree.ElementTree`.
* :func:`select_chain` picks the arm out of a larger vendor URDF (FORMAT.md "Which chain is the
  arm": the revolute joints from ``base_link`` to ``tip_link``; every other joint fixed).
* :func:`load_link_meshes` loads those geometries with trimesh and returns one triangle mesh
  per link, in the link frame (the URDF link frame, which is also pinocchio's body frame, so
  ``apply_transform(robot.frame_transform(link, q), vertices)`` places it in the base frame).

Mesh file names resolve relative to the URDF; ``package://pkg/rest`` URIs resolve by looking
for ``pkg/rest`` in the URDF's folder and each parent folder (and for ``rest`` in a parent
folder named ``pkg``); ``file://`` URIs are plain paths. A mesh that cannot be found raises an
:class:`~mocap.io.errors.InputError` naming the URDF and the URI.
"""
from __future__ import annotations

import os
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path
from typing import NamedTuple

import numpy as np

from mocap.io.errors import InputError, warn_input
from mocap.kinematics import make_transform, rotation_about_axis

_MOVING = ("revolute", "continuous", "prismatic")


# ---- small helpers ------------------------------------------------------------------------------
def _parse(urdf: Path, *, keep_comments: bool = False) -> ET.ElementTree:
    """The URDF's element tree; comments and processing instructions are left out of it
    (vendor files carry them anywhere, even inside ``<geometry>``), except with
    ``keep_comments`` (a copy written back, :func:`perturb_urdf`, keeps the vendor's notes;
    its walk looks elements up by tag only)."""
    urdf = Path(urdf)
    if not urdf.is_file():
        raise InputError("URDF not found", path=urdf)
    parser = ET.XMLParser(target=ET.TreeBuilder(insert_comments=keep_comments,
                                                insert_pis=keep_comments))
    try:
        tree = ET.parse(urdf, parser=parser)
    except ET.ParseError as exc:
        raise InputError(f"not valid XML: {exc}", path=urdf, line=exc.position[0]) from None
    if tree.getroot().tag != "robot":
        raise InputError(f"root element is <{tree.getroot().tag}>, expected <robot>", path=urdf)
    return tree


def _elements(parent):
    """The element children of ``parent``, without comments and processing instructions."""
    return (c for c in parent if isinstance(c.tag, str))


def _floats(elem, attr: str, n: int, default: float, urdf: Path, what: str) -> np.ndarray:
    if elem is None or elem.get(attr) is None:
        return np.full(n, float(default))
    text = elem.get(attr)
    try:
        vals = np.array([float(t) for t in text.split()], float)
    except ValueError:
        vals = np.array([])
    if vals.shape != (n,) or not np.all(np.isfinite(vals)):
        raise InputError(f"{what}: attribute {attr}={text!r} is not {n} finite numbers", path=urdf,
                         label=what)
    return vals


def rpy_matrix(rpy) -> np.ndarray:
    """URDF roll-pitch-yaw to a rotation matrix: ``R = Rz(yaw) @ Ry(pitch) @ Rx(roll)``."""
    r, p, y = (float(v) for v in rpy)
    R = rotation_about_axis(np.array([0.0, 0.0, 1.0]), y)
    R = R @ rotation_about_axis(np.array([0.0, 1.0, 0.0]), p)
    return R @ rotation_about_axis(np.array([1.0, 0.0, 0.0]), r)


def matrix_rpy(R) -> np.ndarray:
    """Inverse of :func:`rpy_matrix` (pitch in [-pi/2, pi/2])."""
    from scipy.spatial.transform import Rotation

    return Rotation.from_matrix(np.asarray(R, float)).as_euler("xyz")


def _origin_transform(elem, urdf: Path, what: str) -> np.ndarray:
    org = None if elem is None else elem.find("origin")
    xyz = _floats(org, "xyz", 3, 0.0, urdf, what)
    rpy = _floats(org, "rpy", 3, 0.0, urdf, what)
    return make_transform(rpy_matrix(rpy), xyz)


def _fmt(v) -> str:
    return " ".join(repr(float(x)) for x in np.asarray(v, float).ravel())


# ---- chain selection ---------------------------------------------------------------------------
@dataclass(frozen=True)
class ChainSelection:
    """The arm of a URDF (FORMAT.md "Which chain is the arm"): ``chain`` the moving joints from
    ``base_link`` to ``tip_link`` (base to tip), ``locked`` every other moving joint with the value
    it is fixed at (rad or m), ``reduced``: False where the URDF's moving joints already are the
    chain (nothing to lock)."""

    base_link: str
    tip_link: str
    chain: tuple
    locked: dict
    reduced: bool


def _urdf_joints(root) -> dict:
    out = {}
    for j in root.findall("joint"):
        par, ch = j.find("parent"), j.find("child")
        lim = j.find("limit")
        lo = hi = None
        if lim is not None and j.get("type") in ("revolute", "prismatic"):
            lo = float(lim.get("lower", "0") or 0.0)
            hi = float(lim.get("upper", "0") or 0.0)
        out[j.get("name")] = {"type": j.get("type"), "parent": None if par is None else par.get("link"),
                              "child": None if ch is None else ch.get("link"), "lower": lo, "upper": hi}
    return out


def select_chain(urdf: str | Path, base_link: str | None = None, tip_link: str | None = None,
                 fixed: dict | None = None, where: Path | None = None) -> ChainSelection:
    """The arm chain of a URDF and the values every other moving joint is fixed at.

    Without ``base_link`` and ``tip_link``, a URDF whose moving joints all lie on one path from
    the root is the chain as it is (links hanging off it on fixed joints are kept as they are)
    [1]_. A joint outside the chain is fixed at ``fixed[name]``, default 0, or the nearer limit
    where 0 lies outside the joint's limits.

    Parameters
    ----------
    urdf : str or pathlib.Path
        The URDF file.
    base_link : str, optional
        First link of the chain; default the URDF's root link.
    tip_link : str, optional
        Last link of the chain; default the root's single leaf link.
    fixed : dict, optional
        {joint name: value (rad or m)} for joints outside the chain.
    where : pathlib.Path, optional
        The file named in errors about ``fixed`` and the link names (the manifest); default
        ``urdf``.

    Returns
    -------
    ChainSelection
        The chain's ends, its joints, the locked joints with their values, and whether the
        URDF had to be reduced.

    Raises
    ------
    InputError
        If a link is unknown, the tip is not below the base, the chain is ambiguous, or
        ``fixed`` names a joint on the chain or an unknown one.

    References
    ----------
    .. [1] jointlab data format (docs/format.md), sec. Which chain is the arm.
    """
    urdf = Path(urdf)
    where = where or urdf
    root_el = _parse(urdf).getroot()
    joints = _urdf_joints(root_el)
    links = [lk.get("name") for lk in root_el.findall("link")]
    by_child = {j["child"]: nm for nm, j in joints.items()}
    children = {}
    for nm, j in joints.items():
        children.setdefault(j["parent"], []).append(nm)
    roots = [lk for lk in links if lk not in by_child]
    fixed = dict(fixed or {})
    moving = [nm for nm, j in joints.items() if j["type"] not in ("fixed", None)]

    def path_to(link):                      # joints from the root to ``link``, root first
        out = []
        while link in by_child:
            nm = by_child[link]
            out.append(nm)
            link = joints[nm]["parent"]
        return out[::-1], link

    for key, lk in (("base_link", base_link), ("tip_link", tip_link)):
        if lk is not None and lk not in links:
            near = ", ".join(x for x in links if x.split("_")[0] == str(lk).split("_")[0])[:300]
            raise InputError(f"[robot] {key} {lk!r} is not a link of {urdf.name}"
                             + (f" (links like it: {near})" if near else ""), path=where, label=key)
    if base_link is None:
        if len(roots) != 1:
            raise InputError(f"{urdf.name} has {len(roots)} root links; name the arm's base in "
                             "[robot] base_link", path=where, label="base_link")
        base_link = roots[0]
    if tip_link is None:
        leaves = [lk for lk in links if lk not in children]
        full = [path_to(lk)[0] for lk in leaves]
        on_one = [lk for lk, pth in zip(leaves, full) if set(moving) <= set(pth)]
        if base_link == roots[0] and on_one and not fixed:
            tip = on_one[-1]
            return ChainSelection(base_link, tip, tuple(m for m in path_to(tip)[0] if m in moving),
                                  {}, False)
        if len(leaves) != 1:
            raise InputError(f"{urdf.name} has {len(leaves)} leaf links (a mobile base, a head, a "
                             "gripper...?); name the arm's last link in [robot] tip_link",
                             path=where, label="tip_link")
        tip_link = leaves[0]
    pth, _ = path_to(tip_link)
    ups, _ = path_to(base_link)
    if pth[:len(ups)] != ups or base_link == tip_link:
        raise InputError(f"[robot] tip_link {tip_link!r} is not below base_link {base_link!r} in "
                         f"{urdf.name}", path=where, label="tip_link")
    chain = tuple(nm for nm in pth[len(ups):] if nm in moving)
    if not chain:
        raise InputError(f"no moving joint between {base_link!r} and {tip_link!r} in {urdf.name}",
                         path=where, label="tip_link")
    odd = [nm for nm in chain if joints[nm]["type"] not in ("revolute", "continuous")]
    if odd:
        after = joints[odd[-1]]["child"]
        raise InputError(f"joint {odd[-1]!r} ({joints[odd[-1]]['type']}) lies in the arm chain {base_link} -> "
                         f"{tip_link}, which may hold revolute joints only: start the chain after it "
                         f"([robot] base_link = {after!r}) and give its value in [robot] fixed",
                         path=where, label="base_link")
    for key in fixed:
        if key not in joints:
            raise InputError(f"[robot] fixed names joint {key!r}, which is not a joint of "
                             f"{urdf.name}", path=where, label=str(key))
        if key in chain:
            raise InputError(f"[robot] fixed names joint {key!r}, which is in the arm chain "
                             f"{base_link} -> {tip_link}", path=where, label=str(key))
    locked = {}
    for nm in moving:
        if nm in chain:
            continue
        j = joints[nm]
        if nm in fixed:
            v = fixed[nm]
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not np.isfinite(v):
                raise InputError(f"[robot] fixed {nm} must be a number (rad or m), got {v!r}",
                                 path=where, label=nm)
            v = float(v)
            if j["lower"] is not None and not (j["lower"] - 1e-9 <= v <= j["upper"] + 1e-9):
                raise InputError(f"[robot] fixed {nm} = {v!r} lies outside the joint's limits "
                                 f"[{j['lower']:g}, {j['upper']:g}] (degrees written as radians?)",
                                 path=where, label=nm)
        else:
            v = 0.0
            if j["lower"] is not None and not j["lower"] <= 0.0 <= j["upper"]:
                v = j["lower"] if abs(j["lower"]) < abs(j["upper"]) else j["upper"]
        locked[nm] = v
    return ChainSelection(base_link, tip_link, chain, locked, True)


def continuous_as_revolute(urdf: str | Path, names) -> tuple[str | None, dict]:
    """The URDF's text with the ``continuous`` joints among ``names`` written as ``revolute``
    ones, and their limits (``(None, {})`` where none of ``names`` is continuous).

    A continuous joint is a revolute joint without position limits (URDF specification [1]_);
    pinocchio represents it by ``(cos q, sin q)`` (two configuration coordinates, one velocity),
    a revolute joint by ``q``. Written as revolute, the joint has the same placement, axis,
    inertias and dynamics, one coordinate like every other joint of the chain. The written
    ``<limit>`` holds placeholder position limits (the caller sets them to +-inf); its effort and
    velocity are the original element's, else absent (pinocchio: infinite).

    Parameters
    ----------
    urdf : str or pathlib.Path
        The URDF file.
    names : iterable of str
        The joints to convert where they are continuous (the arm's chain).

    Returns
    -------
    xml : str or None
        The URDF text (the file itself is not touched); None where nothing was converted.
    limits : dict
        {joint name: (effort or None, velocity or None)} of each converted joint.

    References
    ----------
    .. [1] ROS URDF XML specification, <joint> element (http://wiki.ros.org/urdf/XML/joint).
    """
    tree = _parse(Path(urdf))
    wanted = set(names)
    limits = {}
    for j in tree.getroot().findall("joint"):
        if j.get("type") != "continuous" or j.get("name") not in wanted:
            continue
        j.set("type", "revolute")
        lim = j.find("limit")
        if lim is None:
            lim = ET.SubElement(j, "limit")
        eff, vel = lim.get("effort"), lim.get("velocity")
        limits[j.get("name")] = (None if eff is None else float(eff), None if vel is None else float(vel))
        lim.set("lower", "-1")
        lim.set("upper", "1")
        lim.set("effort", eff if eff is not None else "0")
        lim.set("velocity", vel if vel is not None else "0")
    if not limits:
        return None, {}
    return ET.tostring(tree.getroot(), encoding="unicode"), limits


# ---- perturbed copies ---------------------------------------------------------------------------
def perturb_urdf(src: str | Path, dst: str | Path, seed: int, length_std: float = 0.005,
                 angle_std_deg: float = 0.5, mass_rel_std: float = 0.05,
                 overwrite: bool = False) -> Path:
    """Write a randomly perturbed copy of the URDF ``src`` to ``dst`` and return ``dst``.

    For every moving joint (revolute, continuous, prismatic), in document order:

    * the origin translation gets independent N(0, ``length_std``) offsets (m) per axis;
    * the origin orientation is post-multiplied by a rotation ``exp([w])`` with
      w ~ N(0, ``angle_std_deg``) per axis (deg), written back as URDF rpy;
    * the joint axis is tilted by ``exp([w_perp])`` with w ~ N(0, ``angle_std_deg``) per axis and
      its component along the axis removed (a tilt, not a spin), then renormalised.

    Every link mass is multiplied by ``f = 1 + mass_rel_std * N(0, 1)`` (clipped at 0.2) and its
    inertia tensor by the same ``f`` (the body is scaled in density; the centre of mass stays).
    Fixed joints are left alone. Relative mesh file names are rewritten relative to ``dst`` so
    the copy still finds its meshes; ``package://`` URIs are kept. Deterministic in ``seed``.
    """
    src, dst = Path(src), Path(dst)
    for name, v in (("length_std", length_std), ("angle_std_deg", angle_std_deg),
                    ("mass_rel_std", mass_rel_std)):
        if not np.isfinite(v) or v < 0:
            raise ValueError(f"{name} must be a finite number >= 0, got {v!r}")
    tree = _parse(src, keep_comments=True)
    if dst.resolve() == src.resolve():
        raise ValueError(f"refusing to overwrite the input URDF {src}")
    if dst.exists() and not overwrite:
        raise FileExistsError(f"{dst} exists; refusing to overwrite")
    rng = np.random.default_rng(seed)
    ang_std = np.deg2rad(angle_std_deg)
    root = tree.getroot()

    for joint in root.iter("joint"):
        jtype = joint.get("type")
        if jtype not in _MOVING:
            continue
        what = f"joint {joint.get('name')!r}"
        d_xyz, w_org, w_axis = rng.standard_normal((3, 3))
        org = joint.find("origin")
        if org is None:
            org = ET.SubElement(joint, "origin")
        xyz = _floats(org, "xyz", 3, 0.0, src, what) + length_std * d_xyz
        R = rpy_matrix(_floats(org, "rpy", 3, 0.0, src, what))
        w = ang_std * w_org
        angle = float(np.linalg.norm(w))
        if angle > 0:
            R = R @ rotation_about_axis(w / angle, angle)
        org.set("xyz", _fmt(xyz))
        org.set("rpy", _fmt(matrix_rpy(R)))
        ax_el = joint.find("axis")
        if ax_el is None:
            ax_el = ET.SubElement(joint, "axis")
        axis = _floats(ax_el, "xyz", 3, 0.0, src, what) if ax_el.get("xyz") else np.array([1.0, 0, 0])
        norm = np.linalg.norm(axis)
        if norm == 0:
            raise InputError(f"{what} has a zero axis", path=src, label=joint.get("name"))
        axis = axis / norm
        w = ang_std * w_axis
        w = w - axis * (w @ axis)
        tilt = float(np.linalg.norm(w))
        if tilt > 0:
            axis = rotation_about_axis(w / tilt, tilt) @ axis
        ax_el.set("xyz", _fmt(axis / np.linalg.norm(axis)))

    for link in root.iter("link"):
        inertial = link.find("inertial")
        if inertial is None:
            continue
        f = max(0.2, 1.0 + mass_rel_std * float(rng.standard_normal()))
        mass = inertial.find("mass")
        if mass is not None and mass.get("value") is not None:
            m = _floats(mass, "value", 1, 0.0, src, f"link {link.get('name')!r} mass")[0]
            mass.set("value", repr(float(m * f)))
        inertia = inertial.find("inertia")
        if inertia is not None:
            for key in ("ixx", "ixy", "ixz", "iyy", "iyz", "izz"):
                if inertia.get(key) is not None:
                    val = _floats(inertia, key, 1, 0.0, src, f"link {link.get('name')!r} inertia")[0]
                    inertia.set(key, repr(float(val * f)))

    for mesh in root.iter("mesh"):
        fn = mesh.get("filename")
        if fn and "://" not in fn and not os.path.isabs(fn):
            target = (src.parent / fn).resolve()
            dst_dir = dst.resolve().parent
            if os.path.commonpath([target, dst_dir]) == target.anchor:
                mesh.set("filename", target.as_posix())  # nothing in common but the root
            else:
                mesh.set("filename", Path(os.path.relpath(target, dst_dir)).as_posix())

    note = ET.Comment(f" perturbed copy of {src.name}: seed={seed}, length_std={length_std!r} m, "
                      f"angle_std_deg={angle_std_deg!r}, mass_rel_std={mass_rel_std!r} "
                      "(mocap.urdf.perturb_urdf) ")
    note.tail = "\n  "
    root.insert(0, note)
    dst.parent.mkdir(parents=True, exist_ok=True)
    tree.write(dst, encoding="utf-8", xml_declaration=True)
    return dst


# ---- visual geometry ----------------------------------------------------------------------------
@dataclass(frozen=True)
class Primitive:
    """A URDF primitive shape centred at its origin: ``box`` (size = x, y, z extents),
    ``cylinder`` (radius, length; axis z) or ``sphere`` (radius,)."""

    kind: str
    size: tuple[float, ...]

    def to_dict(self) -> dict:
        return {"kind": self.kind, "size": list(self.size)}


class Visual(NamedTuple):
    """One geometry of a link: a mesh file path or a :class:`Primitive`, its placement
    ``T_link_visual`` (4x4, maps geometry points into the link frame) and a per-axis scale."""

    geometry: Path | Primitive
    T_link_visual: np.ndarray
    scale: np.ndarray


def resolve_mesh_uri(uri: str, urdf: str | Path) -> Path:
    """File path of a mesh ``filename`` of ``urdf``: relative names resolve against the URDF's
    folder, ``package://pkg/rest`` by searching the URDF's folder and its parents, ``file://``
    as a path. Raises :class:`InputError` naming the URDF and URI when no file exists."""
    urdf = Path(urdf).resolve()
    tried = []
    if uri.startswith("package://"):
        rest = uri[len("package://"):]
        pkg, _, sub = rest.partition("/")
        for d in (urdf.parent, *urdf.parent.parents):
            cands = [d / pkg / sub]
            if d.name == pkg:
                cands.append(d / sub)
            for c in cands:
                if c.is_file():
                    return c
        tried.append(f"{pkg}/{sub} in {urdf.parent} and its parent folders")
    else:
        p = Path(uri[len("file://"):]) if uri.startswith("file://") else Path(uri)
        p = p if p.is_absolute() else urdf.parent / p
        if p.is_file():
            return p
        tried.append(str(p))
    raise InputError(f"mesh {uri!r} not found (looked for {'; '.join(tried)})", path=urdf,
                     label=uri)


def urdf_visuals(urdf: str | Path, *, kind: str = "visual", missing: str = "raise") -> dict:
    """``{link: [Visual, ...]}`` for every link of ``urdf`` that has ``<visual>`` (or, with
    ``kind="collision"``, ``<collision>``) geometry, in document order.

    ``missing="raise"`` (default) raises :class:`InputError` for a mesh file that cannot be
    found; ``missing="skip"`` leaves such geometries out.
    """
    if kind not in ("visual", "collision"):
        raise ValueError(f"kind must be 'visual' or 'collision', got {kind!r}")
    if missing not in ("raise", "skip"):
        raise ValueError(f"missing must be 'raise' or 'skip', got {missing!r}")
    urdf = Path(urdf)
    root = _parse(urdf).getroot()
    out: dict[str, list[Visual]] = {}
    for link in root.findall("link"):
        name = link.get("name")
        items = []
        for vis in link.findall(kind):
            what = f"link {name!r} {kind}"
            T = _origin_transform(vis, urdf, what)
            geom = vis.find("geometry")
            shape = None if geom is None else next(_elements(geom), None)
            if shape is None:
                raise InputError(f"{what} has no geometry", path=urdf, label=name)
            scale = np.ones(3)
            if shape.tag == "mesh":
                fn = shape.get("filename")
                if not fn:
                    raise InputError(f"{what}: <mesh> without filename", path=urdf, label=name)
                try:
                    g = resolve_mesh_uri(fn, urdf)
                except InputError:
                    if missing == "skip":
                        continue
                    raise
                if shape.get("scale") is not None:
                    scale = _floats(shape, "scale", 3, 1.0, urdf, what)
            elif shape.tag == "box":
                g = Primitive("box", tuple(_floats(shape, "size", 3, np.nan, urdf, what)))
            elif shape.tag == "cylinder":
                r = _floats(shape, "radius", 1, np.nan, urdf, what)[0]
                h = _floats(shape, "length", 1, np.nan, urdf, what)[0]
                g = Primitive("cylinder", (float(r), float(h)))
            elif shape.tag == "sphere":
                g = Primitive("sphere", (float(_floats(shape, "radius", 1, np.nan, urdf, what)[0]),))
            else:
                raise InputError(f"{what}: unsupported geometry <{shape.tag}>", path=urdf, label=name)
            if isinstance(g, Primitive) and not (np.all(np.isfinite(g.size)) and min(g.size) > 0):
                raise InputError(f"{what}: {g.kind} needs positive sizes, got {g.size}", path=urdf,
                                 label=name)
            items.append(Visual(g, T, scale))
        if items:
            out[name] = items
    return out


def missing_meshes(urdf: str | Path) -> list[str]:
    """The distinct mesh URIs of a URDF that resolve to no file.

    Visual and collision meshes, in document order; meshes are optional (a vendor URDF often
    ships without them) [1]_.

    Parameters
    ----------
    urdf : str or pathlib.Path
        The URDF file.

    Returns
    -------
    list of str
        The unresolved ``filename`` attributes; empty when every mesh is found.

    References
    ----------
    .. [1] jointlab data format (docs/format.md), sec. Layout.
    """
    urdf = Path(urdf)
    out = []
    for mesh in _parse(urdf).getroot().iter("mesh"):
        fn = mesh.get("filename")
        if not fn or fn in out:
            continue
        try:
            resolve_mesh_uri(fn, urdf)
        except InputError:
            out.append(fn)
    return out


def _primitive_mesh(p: Primitive):
    import trimesh

    if p.kind == "box":
        return trimesh.creation.box(extents=p.size)
    if p.kind == "cylinder":
        return trimesh.creation.cylinder(radius=p.size[0], height=p.size[1], sections=32)
    return trimesh.creation.icosphere(subdivisions=2, radius=p.size[0])


def _load_mesh_file(path: Path, urdf: Path):
    import trimesh

    try:
        mesh = trimesh.load(path, force="mesh")
    except Exception as exc:  # trimesh raises many types for unreadable files
        raise InputError(f"trimesh could not read mesh {path}: {exc}", path=urdf,
                         label=path.name) from None
    if not isinstance(mesh, trimesh.Trimesh) or len(mesh.faces) == 0:
        raise InputError(f"mesh {path} holds no triangles", path=urdf, label=path.name)
    return mesh


def load_link_meshes(urdf: str | Path, *, kind: str = "visual", fallback_collision: bool = True,
                     missing: str = "raise") -> dict:
    """``{link: (vertices (V, 3), faces (F, 3))}``: all geometry of each link merged into one
    triangle mesh in the link frame (metres), links in URDF document order. Links without
    ``kind`` geometry use their collision geometry when ``fallback_collision``; links with
    neither are left out. ``missing`` as in :func:`urdf_visuals` (``"skip"`` drops mesh files
    that cannot be found instead of raising :class:`InputError`; ``"warn"`` drops them with one
    warning for the whole URDF: meshes are optional, FORMAT.md)."""
    urdf = Path(urdf)
    if missing == "warn":
        gone = missing_meshes(urdf)
        if gone:
            warn_input(f"{len(gone)} mesh file(s) not found (first: {gone[0]}); the robot is drawn "
                       "with the URDF's primitive shapes where it has them, else as link frames",
                       path=urdf)
        missing = "skip"
    visuals = urdf_visuals(urdf, kind=kind, missing=missing)
    if fallback_collision and kind == "visual":
        for link, items in urdf_visuals(urdf, kind="collision", missing=missing).items():
            visuals.setdefault(link, items)
    cache: dict[Path, tuple[np.ndarray, np.ndarray]] = {}
    out = {}
    for link, items in visuals.items():
        verts, faces, offset = [], [], 0
        for g, T, scale in items:
            if isinstance(g, Primitive):
                m = _primitive_mesh(g)
                V, F = np.asarray(m.vertices, float), np.asarray(m.faces, np.int64)
            else:
                if g not in cache:
                    m = _load_mesh_file(g, urdf)
                    cache[g] = (np.asarray(m.vertices, float), np.asarray(m.faces, np.int64))
                V, F = cache[g]
            V = (V * scale) @ T[:3, :3].T + T[:3, 3]
            verts.append(V)
            faces.append(F + offset)
            offset += V.shape[0]
        out[link] = (np.concatenate(verts), np.concatenate(faces))
    return out


# ---- validation before a URDF library reads the file (issue 29) -------------------------------
_JOINT_TYPES = ("revolute", "continuous", "prismatic", "fixed", "floating", "planar")


def check_urdf(urdf) -> None:
    """Validate a URDF before a library reads it.

    Checks XML, unique link and joint names, joints whose parent and child are links, one
    root, known joint types, finite numbers in origins, axes, limits, masses and inertias,
    ``lower <= upper``, non-negative effort, velocity and mass [1]_. (A C++ URDF parser
    otherwise prints several lines of its own, or reads ``xyz="0 0 abc"`` as a number.)

    Parameters
    ----------
    urdf : str or pathlib.Path
        The URDF file.

    Raises
    ------
    InputError
        On the first violation, in one line naming the element.

    References
    ----------
    .. [1] jointlab data format (docs/format.md), sec. Layout.
    """
    urdf = Path(urdf)
    root = _parse(urdf).getroot()
    links = [ln.get("name") for ln in root.findall("link")]
    seen = set()
    for nm in links:
        if not nm or nm in seen:
            raise InputError(f"link name {nm!r} is {'empty' if not nm else 'repeated'}", path=urdf, label=nm)
        seen.add(nm)
    jnames, children = set(), set()
    for j in root.findall("joint"):
        nm, what = j.get("name"), f"joint {j.get('name')!r}"
        if not nm or nm in jnames:
            raise InputError(f"joint name {nm!r} is {'empty' if not nm else 'repeated'}", path=urdf, label=nm)
        jnames.add(nm)
        if j.get("type") not in _JOINT_TYPES:
            raise InputError(f"{what} has type {j.get('type')!r}, not one of {', '.join(_JOINT_TYPES)}",
                             path=urdf, label=nm)
        for tag in ("parent", "child"):
            e = j.find(tag)
            ln = None if e is None else e.get("link")
            if ln not in seen:
                raise InputError(f"{what}: <{tag} link={ln!r}> is not a link of the URDF", path=urdf, label=nm)
        child = j.find("child").get("link")
        if child in children:
            raise InputError(f"{what}: link {child!r} is the child of two joints", path=urdf, label=nm)
        children.add(child)
        _floats(j.find("origin"), "xyz", 3, 0.0, urdf, what)
        _floats(j.find("origin"), "rpy", 3, 0.0, urdf, what)
        _floats(j.find("axis"), "xyz", 3, 1.0, urdf, what)
        lim = j.find("limit")
        if lim is not None:
            vals = {a: _floats(lim, a, 1, 0.0, urdf, what)[0] for a in ("lower", "upper", "effort", "velocity")}
            if lim.get("lower") is not None and lim.get("upper") is not None and vals["lower"] > vals["upper"]:
                raise InputError(f"{what} has limit lower={vals['lower']:g} above upper={vals['upper']:g}",
                                 path=urdf, label=nm)
            for a in ("effort", "velocity"):
                if vals[a] < 0:
                    raise InputError(f"{what}: limit {a}={vals[a]:g} is negative", path=urdf, label=nm)
    roots = [ln for ln in links if ln not in children]
    if len(roots) != 1:
        raise InputError(f"{len(roots)} root links ({', '.join(map(repr, roots[:4]))}); a URDF is one tree",
                         path=urdf)
    for ln in root.findall("link"):
        what = f"link {ln.get('name')!r}"
        for inertial in ln.findall("inertial"):
            _floats(inertial.find("origin"), "xyz", 3, 0.0, urdf, what)
            _floats(inertial.find("origin"), "rpy", 3, 0.0, urdf, what)
            m = _floats(inertial.find("mass"), "value", 1, 0.0, urdf, what)[0]
            if m < 0:
                raise InputError(f"{what} has a negative mass {m:g} kg", path=urdf, label=ln.get("name"))
            ine = inertial.find("inertia")
            for a in ("ixx", "ixy", "ixz", "iyy", "iyz", "izz"):
                _floats(ine, a, 1, 0.0, urdf, what)


def check_urdf_limits(robot, urdf) -> None:
    """Refuse a revolute joint whose URDF ``<limit lower upper>`` is inverted (lower > upper)."""
    lo, hi = np.asarray(robot.lower, float), np.asarray(robot.upper, float)
    bad = np.flatnonzero(lo > hi)
    if bad.size:
        k = int(bad[0])
        raise InputError(f"joint {robot.joint_names[k]!r} has limit lower={lo[k]:g} above upper={hi[k]:g}",
                         path=urdf, label=robot.joint_names[k])
