"""The bundled PA10-6C description (fixtures/robots/pa10), mocap.robot.Robot dynamics on it,
and mocap.urdf (perturbed copies, visuals, link meshes)."""
from __future__ import annotations

import dataclasses
import math
import subprocess
import sys
import xml.etree.ElementTree as ET

import numpy as np
import pytest

from mocap.io.errors import InputError
from mocap.kinematics import apply_transform
from mocap.robot import Robot
from mocap.urdf import Primitive, load_link_meshes, perturb_urdf, resolve_mesh_uri, urdf_visuals

LIMITS_DEG = np.array([177.0, 94.0, 165.0, 255.0, 164.0, 255.0])
SPEEDS = np.array([1.00, 1.01, 2.03, 2.00, 2.43, 2.01])   # thesis tables, rad/s
TORQUES = np.array([232.0, 232.0, 100.0, 14.5, 14.5, 14.5])
G = 9.81


@pytest.fixture(scope="module")
def pa10(pa10_dir) -> Robot:
    return Robot.from_urdf(pa10_dir / "pa10.urdf", pa10_dir / "drives.toml")


# ---- the description ------------------------------------------------------------------------------
def test_pa10_loads_with_six_named_joints(pa10):
    assert pa10.n == 6
    assert pa10.joint_names == tuple(f"joint{k}" for k in range(1, 7))
    assert pa10.link_names == ("base_link",) + tuple(f"link{k}" for k in range(1, 7))
    assert [pa10.link_of_joint(j) for j in range(6)] == [f"link{k}" for k in range(1, 7)]
    assert [d.name for d in pa10.drives] == list(pa10.joint_names)


def test_pa10_limits_speeds_and_torques(pa10):
    np.testing.assert_allclose(pa10.upper, np.deg2rad(LIMITS_DEG), rtol=0, atol=1e-12)
    np.testing.assert_allclose(pa10.lower, -np.deg2rad(LIMITS_DEG), rtol=0, atol=1e-12)
    np.testing.assert_allclose(pa10.max_velocity, SPEEDS, rtol=0, atol=1e-12)
    np.testing.assert_allclose(pa10.max_torque, TORQUES, rtol=0, atol=1e-12)
    # the URDF <limit> agrees with drives.toml
    np.testing.assert_allclose(pa10.model.velocityLimit, SPEEDS, rtol=0, atol=1e-12)
    np.testing.assert_allclose(pa10.model.effortLimit, TORQUES, rtol=0, atol=1e-12)


def test_pa10_drives_follow_the_format(pa10):
    for d in pa10.drives:
        assert d.encoder_resolution == pytest.approx(math.radians(0.011), rel=1e-12)  # 0.011 deg
        assert d.encoder_resolution == pytest.approx(1.92e-4, rel=2e-3)
        assert d.gear_ratio >= 50
        # link-side motor inertia J_rotor N^2 of a servo rotor of 1e-6 .. 1e-4 kg m^2
        assert 1e-6 <= d.motor_inertia / d.gear_ratio**2 <= 1e-4
        assert 0 < d.motor_viscous < 5
        assert d.extra["stiffness"] > 1e3
    # bigger drives on the proximal joints
    J = np.array([d.motor_inertia for d in pa10.drives])
    assert J[0] > J[2] > J[4]


def test_pa10_masses_and_inertias_are_physical(pa10):
    masses = np.array([pa10.model.inertias[i].mass for i in range(1, 7)])
    assert 30.0 <= masses.sum() <= 40.0  # PA10 arm about 35-40 kg with its base
    assert np.all(np.diff(masses[1:]) < 0)  # lighter towards the tip from the upper arm on
    for i in range(1, 7):
        I = pa10.model.inertias[i].inertia  # about the centre of mass
        ev = np.linalg.eigvalsh(I)
        assert ev.min() > 0
        assert ev[0] + ev[1] >= ev[2] - 1e-12  # triangle inequality of principal moments
    rng = np.random.default_rng(10)
    for q in rng.uniform(pa10.lower, pa10.upper, size=(5, 6)):
        assert np.linalg.eigvalsh(pa10.mass_matrix(q)).min() > 0


def test_pa10_can_hold_itself_and_the_thesis_load(pa10):
    """Gravity torque with the 33.075 N thesis load stays under the torque limits everywhere."""
    loaded = pa10.with_payload(33.075 / G)
    rng = np.random.default_rng(11)
    Q = rng.uniform(pa10.lower, pa10.upper, size=(200, 6))
    g = np.abs(loaded.gravity_torque(Q))
    assert np.all(g.max(axis=0) < TORQUES)
    assert g[:, 1].max() > 50  # the shoulder does carry a real load


def test_single_joint_dynamics_reproduces_rnea(pa10):
    """tau_j = I qdd + a sin q_j + b cos q_j (the one-link model of thesis eq. 2-3/2-4) equals
    pinocchio's RNEA when joint j moves alone, velocity included."""
    rng = np.random.default_rng(12)
    for j in range(6):
        q_rest = rng.uniform(pa10.lower, pa10.upper)
        I, a, b = pa10.single_joint_dynamics(j, q_rest)
        T = 25
        Q = np.tile(q_rest, (T, 1))
        Q[:, j] = rng.uniform(pa10.lower[j], pa10.upper[j], size=T)
        QD = np.zeros((T, 6))
        QDD = np.zeros((T, 6))
        QD[:, j] = rng.uniform(-SPEEDS[j], SPEEDS[j], size=T)
        QDD[:, j] = rng.uniform(-10, 10, size=T)
        tau = pa10.rnea(Q, QD, QDD)[:, j]
        model = I * QDD[:, j] + a * np.sin(Q[:, j]) + b * np.cos(Q[:, j])
        np.testing.assert_allclose(model, tau, rtol=1e-9, atol=1e-9, err_msg=f"joint {j + 1}")
        assert I > 0


def test_held_deflection_is_the_carried_torque_over_the_declared_stiffness(pa10):
    """A held joint's link gives by tau / K (FORMAT.md ``stiffness``): with the arm horizontal, a
    payload adds m g lever to the shoulder's and elbow's torque (levers by hand, as below), so
    their link angles drop by m g lever / K; moving joints and joints without a declared
    stiffness do not give."""
    q = np.array([0.0, np.pi / 2, 0.0, 0.0, 0.0, 0.0])  # arm horizontal along +x
    m = 3.373
    K = pa10.stiffness
    assert np.all(K > 1e3)
    d0 = pa10.held_deflection(q)
    d1 = pa10.with_payload(m).held_deflection(q)
    lever = np.array([0.0, 0.45 + 0.48 + 0.07, 0.48 + 0.07, 0.0, 0.07, 0.0])
    np.testing.assert_allclose(np.abs(d1 - d0), m * G * lever / K, rtol=1e-6, atol=1e-12)
    # sign: a link pulled down by gravity sits below its motor (q_link - q_motor = -tau / K)
    assert d0[1] * pa10.gravity_torque(q)[1] < 0
    # moving joints do not give here (their deflection is the flexible-joint model's)
    Q = np.tile(q, (4, 1))
    QD, QDD = np.zeros_like(Q), np.zeros_like(Q)
    QDD[:, 4] = [0.0, 5.0, -5.0, 10.0]
    d = pa10.held_deflection(Q, QD, QDD, moving=(4,))
    assert np.all(d[:, 4] == 0.0) and d.shape == (4, 6)
    # the wrist's acceleration loads the held elbow (coupling by RNEA), linearly
    assert abs(d[1, 2] - d[0, 2]) > 0 and np.isclose(d[3, 2] - d[0, 2], 2 * (d[1, 2] - d[0, 2]))
    rigid = Robot(pa10.model, tuple(dataclasses.replace(dr, extra={}) for dr in pa10.drives))
    assert np.all(rigid.held_deflection(q) == 0.0)


def test_with_payload_adds_m_g_lever_horizontal_arm(pa10):
    q = np.array([0.0, np.pi / 2, 0.0, 0.0, 0.0, 0.0])  # arm horizontal along +x
    m = 3.373
    dg = pa10.with_payload(m).gravity_torque(q) - pa10.gravity_torque(q)
    lever = np.array([0.0, 0.45 + 0.48 + 0.07, 0.48 + 0.07, 0.0, 0.07, 0.0])
    np.testing.assert_allclose(dg, -m * G * lever, rtol=0, atol=1e-10)
    np.testing.assert_allclose(pa10.with_payload(0.0).gravity_torque(q), pa10.gravity_torque(q), atol=0)


def test_with_payload_matches_jacobian_transpose_of_the_weight(pa10):
    """Extra gravity torque = -(axis_j x (p - p_j)) . (m g) for a mass at an offset from the flange."""
    rng = np.random.default_rng(13)
    m, p_flange = 2.5, np.array([0.01, -0.02, 0.1])
    loaded = pa10.with_payload(m, p_flange)
    for q in rng.uniform(pa10.lower, pa10.upper, size=(5, 6)):
        p = apply_transform(pa10.frame_transform("link6", q), p_flange)
        pts, dirs = pa10.chain.joint_axis_lines(q)
        weight = m * pa10.gravity
        expect = -np.einsum("ni,ni->n", dirs, np.cross(p - pts, weight))
        dg = loaded.gravity_torque(q) - pa10.gravity_torque(q)
        np.testing.assert_allclose(dg, expect, rtol=0, atol=1e-10)


def test_generator_is_deterministic_and_matches_committed_files(pa10_dir, tmp_path):
    script = pa10_dir / "make_pa10.py"
    for out in (tmp_path / "a", tmp_path / "b"):
        subprocess.run([sys.executable, str(script), "--out", str(out)], check=True,
                       capture_output=True)
    names = sorted(p.relative_to(tmp_path / "a").as_posix() for p in (tmp_path / "a").rglob("*")
                   if p.is_file())
    assert "pa10.urdf" in names and "drives.toml" in names and "meshes/link6.stl" in names
    size = 0
    for name in names:
        a = (tmp_path / "a" / name).read_bytes()
        assert a == (tmp_path / "b" / name).read_bytes(), name
        assert a == (pa10_dir / name).read_bytes(), f"{name} differs from the committed file"
        size += len(a)
    assert size < 500_000


# ---- link meshes ------------------------------------------------------------------------------------
def test_pa10_link_meshes_one_per_link_watertight_and_plausible(pa10, pa10_dir):
    import trimesh

    meshes = load_link_meshes(pa10_dir / "pa10.urdf")
    assert tuple(meshes) == pa10.link_names
    inertial = {el.get("name"): el.find("inertial/origin").get("xyz")
                for el in ET.parse(pa10_dir / "pa10.urdf").getroot().findall("link")}
    for link, (V, F) in meshes.items():
        assert V.ndim == 2 and V.shape[1] == 3 and F.shape[1] == 3 and F.max() < len(V)
        mesh = trimesh.Trimesh(V, F)
        assert mesh.is_watertight, link
        extent = V.max(axis=0) - V.min(axis=0)
        assert np.all(extent > 0.01) and np.all(extent < 0.7), (link, extent)
        # the URDF's centre of mass is the centroid of the solid mesh (make_pa10.py)
        np.testing.assert_allclose(mesh.center_mass, [float(x) for x in inertial[link].split()],
                                   atol=1e-6, err_msg=link)
    # placed at q = 0 the flange mesh ends at the flange face, 1.317 m up
    V6 = apply_transform(pa10.frame_transform("link6", np.zeros(6)), meshes["link6"][0])
    assert V6[:, 2].max() == pytest.approx(1.317, abs=1e-9)


def _write(path, text):
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text, encoding="utf-8")
    return path


def _tiny_urdf(mesh_uri: str) -> str:
    return f"""<?xml version="1.0"?>
<robot name="tiny">
  <link name="base">
    <visual><origin xyz="1 0 0" rpy="0 0 1.5707963267948966"/><geometry><box size="0.1 0.2 0.3"/></geometry></visual>
  </link>
  <joint name="j1" type="revolute"><parent link="base"/><child link="arm"/>
    <origin xyz="0 0 0.5"/><axis xyz="0 1 0"/><limit lower="-1" upper="1" velocity="1" effort="1"/></joint>
  <link name="arm">
    <inertial><mass value="2"/><inertia ixx="0.1" ixy="0" ixz="0" iyy="0.1" iyz="0" izz="0.05"/></inertial>
    <visual><geometry><cylinder radius="0.05" length="0.4"/></geometry></visual>
    <visual><origin xyz="0 0 0.4"/><geometry><sphere radius="0.06"/></geometry></visual>
  </link>
  <joint name="j2" type="revolute"><parent link="arm"/><child link="tip"/>
    <origin xyz="0 0 0.4"/><axis xyz="1 0 0"/><limit lower="-1" upper="1" velocity="1" effort="1"/></joint>
  <link name="tip">
    <collision><geometry><mesh filename="{mesh_uri}" scale="2 2 2"/></geometry></collision>
  </link>
</robot>
"""


def test_visuals_primitives_package_uri_and_scale(tmp_path):
    import trimesh

    stl = tmp_path / "tiny_description" / "meshes" / "cube.stl"
    stl.parent.mkdir(parents=True)
    stl.write_bytes(trimesh.creation.box(extents=(0.1, 0.1, 0.1)).export(file_type="stl"))
    urdf = _write(tmp_path / "tiny_description" / "urdf" / "tiny.urdf",
                  _tiny_urdf("package://tiny_description/meshes/cube.stl"))
    vis = urdf_visuals(urdf)
    assert list(vis) == ["base", "arm"]
    assert vis["base"][0].geometry == Primitive("box", (0.1, 0.2, 0.3))
    assert [v.geometry.kind for v in vis["arm"]] == ["cylinder", "sphere"]
    col = urdf_visuals(urdf, kind="collision")
    assert col["tip"][0].geometry == stl.resolve()
    np.testing.assert_allclose(col["tip"][0].scale, [2, 2, 2])

    meshes = load_link_meshes(urdf)  # tip has only collision geometry: the fallback
    assert list(meshes) == ["base", "arm", "tip"]
    Vb = meshes["base"][0]  # the box turned 90 deg about z and moved to x = 1
    np.testing.assert_allclose(Vb.min(axis=0), [0.9, -0.05, -0.15], atol=1e-12)
    np.testing.assert_allclose(Vb.max(axis=0), [1.1, 0.05, 0.15], atol=1e-12)
    arm = trimesh.Trimesh(*meshes["arm"])
    cyl, sph = np.pi * 0.05**2 * 0.4, 4 / 3 * np.pi * 0.06**3  # disjoint bodies
    assert 0.95 * (cyl + sph) < arm.volume < cyl + sph
    np.testing.assert_allclose(arm.vertices[:, 2].max(), 0.46, atol=1e-9)
    Vt = meshes["tip"][0]
    np.testing.assert_allclose(Vt.max(axis=0) - Vt.min(axis=0), [0.2, 0.2, 0.2], atol=1e-12)
    assert load_link_meshes(urdf, fallback_collision=False).keys() == {"base", "arm"}


def test_missing_mesh_is_an_input_error_naming_the_file(tmp_path):
    urdf = _write(tmp_path / "r" / "tiny.urdf", _tiny_urdf("package://nowhere/meshes/gone.stl"))
    with pytest.raises(InputError, match=r"tiny\.urdf.*package://nowhere/meshes/gone\.stl"):
        load_link_meshes(urdf)
    assert "tip" not in urdf_visuals(urdf, kind="collision", missing="skip")
    urdf2 = _write(tmp_path / "r" / "rel.urdf", _tiny_urdf("meshes/gone.stl"))
    with pytest.raises(InputError, match=r"gone\.stl"):
        resolve_mesh_uri("meshes/gone.stl", urdf2)
    with pytest.raises(InputError, match="line 3"):
        urdf_visuals(_write(tmp_path / "bad.urdf", "<robot>\n<link name='a'>\n</robot>\n"))


def test_tx40_meshes_are_reported_missing_not_crashing(real_dir):
    urdf = real_dir / "tx40" / "tx40_mdh_modified.urdf"
    if not urdf.is_file():
        pytest.skip(f"{urdf} is absent")
    with pytest.raises(InputError, match="staubli_tx40_description"):
        load_link_meshes(urdf)
    assert urdf_visuals(urdf, missing="skip") == {}
    assert load_link_meshes(urdf, missing="skip") == {}


# ---- perturbed copies -------------------------------------------------------------------------------
def _joint_table(urdf):
    root = ET.parse(urdf).getroot()
    out = {}
    for j in root.iter("joint"):
        if j.get("type") == "revolute":
            out[j.get("name")] = (np.array(j.find("origin").get("xyz").split(), float),
                                  np.array(j.find("axis").get("xyz").split(), float))
    masses = {l.get("name"): float(l.find("inertial/mass").get("value"))
              for l in root.iter("link") if l.find("inertial") is not None}
    return out, masses


def test_perturb_urdf_statistics_and_determinism(pa10_dir, tmp_path):
    src = pa10_dir / "pa10.urdf"
    a = perturb_urdf(src, tmp_path / "a.urdf", seed=3, length_std=0.01, angle_std_deg=1.0,
                     mass_rel_std=0.1)
    b = perturb_urdf(src, tmp_path / "sub" / "b.urdf", seed=3, length_std=0.01, angle_std_deg=1.0,
                     mass_rel_std=0.1)
    c = perturb_urdf(src, tmp_path / "c.urdf", seed=4, length_std=0.01, angle_std_deg=1.0,
                     mass_rel_std=0.1)
    ja, ma = _joint_table(a)
    jb, mb = _joint_table(b)
    jc, _ = _joint_table(c)
    j0, m0 = _joint_table(src)
    for name in j0:  # same seed, same numbers (the folder only changes mesh paths)
        np.testing.assert_array_equal(ja[name][0], jb[name][0])
        np.testing.assert_array_equal(ja[name][1], jb[name][1])
    assert ma == mb
    assert any(not np.array_equal(ja[n][0], jc[n][0]) for n in j0)
    d_xyz = np.concatenate([ja[n][0] - j0[n][0] for n in j0])
    assert 0.004 < d_xyz.std() < 0.02          # 18 draws of N(0, 0.01)
    tilts = []
    for n in j0:
        axis = ja[n][1]
        assert np.linalg.norm(axis) == pytest.approx(1.0, abs=1e-12)
        tilts.append(np.degrees(np.arccos(np.clip(axis @ j0[n][1], -1, 1))))
    assert 0.05 < np.mean(tilts) < 3.0 and max(tilts) < 5.0   # Rayleigh, mean 1.25 deg
    ratios = np.array([ma[k] / m0[k] for k in m0])
    assert np.all(np.abs(ratios - 1) < 0.4) and ratios.std() > 0.02
    # the copy in another folder still finds its meshes and loads
    assert set(load_link_meshes(b)) == set(load_link_meshes(src))
    robot = Robot.from_urdf(b, pa10_dir / "drives.toml")
    assert robot.n == 6


def test_perturb_urdf_zero_noise_keeps_the_robot(pa10, pa10_dir, tmp_path):
    dst = perturb_urdf(pa10_dir / "pa10.urdf", tmp_path / "same.urdf", seed=0, length_std=0.0,
                       angle_std_deg=0.0, mass_rel_std=0.0)
    same = Robot.from_urdf(dst, pa10_dir / "drives.toml")
    Q = np.random.default_rng(14).uniform(pa10.lower, pa10.upper, size=(10, 6))
    np.testing.assert_allclose(same.frame_transform("link6", Q), pa10.frame_transform("link6", Q),
                               atol=1e-12)
    np.testing.assert_allclose(same.gravity_torque(Q), pa10.gravity_torque(Q), atol=1e-10)


def test_perturb_urdf_refuses_to_overwrite(pa10_dir, tmp_path):
    src = pa10_dir / "pa10.urdf"
    dst = perturb_urdf(src, tmp_path / "p.urdf", seed=1)
    with pytest.raises(FileExistsError):
        perturb_urdf(src, dst, seed=2)
    assert perturb_urdf(src, dst, seed=2, overwrite=True) == dst
    with pytest.raises(ValueError, match="input"):
        perturb_urdf(src, src, seed=1, overwrite=True)
    with pytest.raises(ValueError, match="length_std"):
        perturb_urdf(src, tmp_path / "q.urdf", seed=1, length_std=-1.0)
    with pytest.raises(InputError, match="not found"):
        perturb_urdf(tmp_path / "none.urdf", tmp_path / "r.urdf", seed=1)


def test_batched_inverse_dynamics_of_a_one_joint_robot_matches_the_pendulum(tmp_path):
    """A single pendulum written out by hand: the batched
    path (many samples in one call) must give every sample, not only the first."""
    urdf = _write(tmp_path / "one.urdf", """<?xml version="1.0"?>
<robot name="one">
  <link name="base"/>
  <joint name="j1" type="revolute"><parent link="base"/><child link="arm"/>
    <axis xyz="0 1 0"/><limit lower="-3" upper="3" velocity="1" effort="100"/></joint>
  <link name="arm">
    <inertial><origin xyz="0.5 0 0"/><mass value="2"/>
      <inertia ixx="0.01" ixy="0" ixz="0" iyy="0.02" iyz="0" izz="0.01"/></inertial>
  </link>
</robot>
""")
    robot = Robot.from_urdf(urdf)
    T = 400
    q = np.linspace(-1.0, 1.0, T)[:, None]
    qd = np.zeros_like(q)
    qdd = np.linspace(2.0, -3.0, T)[:, None]
    tau = robot.rnea(q, qd, qdd)
    # rotation q about +y takes the mass (2 kg, 0.5 m along x) to z = -0.5 sin q: the potential
    # -m g 0.5 sin q gives the gravity torque -m g 0.5 cos q
    I = 0.02 + 2 * 0.5**2
    expect = I * qdd[:, 0] - 2 * 9.81 * 0.5 * np.cos(q[:, 0])
    assert np.asarray(tau).shape == (T, 1)
    np.testing.assert_allclose(np.asarray(tau)[:, 0], expect, rtol=1e-9, atol=1e-9)
