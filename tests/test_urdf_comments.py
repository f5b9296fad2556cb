"""Vendor URDFs as they come (issue 45): XML comments and processing instructions anywhere in a
URDF (xacro output carries them inside ``<geometry>``, ``<joint>``, ...) are not elements and
every URDF reader skips them."""
from __future__ import annotations

import contextlib
import io
import re
import shutil

import numpy as np
import pytest

from ident.cli.main import main
from mocap.robot import Robot
from mocap.urdf import (check_urdf, continuous_as_revolute, load_link_meshes, missing_meshes,
                        perturb_urdf, select_chain, urdf_visuals)
from tests_paths import REPO, SHARED_REAL

_PLAIN = (
    '<?xml version="1.0"?>\n'
    '<robot name="c">'
    '<link name="base"><visual><origin xyz="0 0 0.1"/><geometry><box size="0.1 0.2 0.3"/>'
    '</geometry></visual><collision><geometry><cylinder radius="0.05" length="0.2"/></geometry>'
    '</collision></link>'
    '<link name="l1"><inertial><origin xyz="0.5 0 0"/><mass value="2"/><inertia ixx="1e-3" '
    'iyy="1e-3" izz="1e-3" ixy="0" ixz="0" iyz="0"/></inertial><visual><geometry>'
    '<sphere radius="0.04"/></geometry></visual><collision><geometry>'
    '<mesh filename="package://gone/l1.stl"/></geometry></collision></link>'
    '<link name="l2"><inertial><origin xyz="0.3 0 0"/><mass value="1"/><inertia ixx="1e-3" '
    'iyy="1e-3" izz="1e-3" ixy="0" ixz="0" iyz="0"/></inertial><collision><geometry>'
    '<box size="0.3 0.05 0.05"/></geometry></collision></link>'
    '<joint name="j1" type="revolute"><parent link="base"/><child link="l1"/>'
    '<origin xyz="0 0 0.1"/><axis xyz="0 1 0"/><limit lower="-3" upper="3" effort="10" '
    'velocity="1"/></joint>'
    '<joint name="j2" type="continuous"><parent link="l1"/><child link="l2"/>'
    '<origin xyz="1 0 0"/><axis xyz="0 1 0"/><limit effort="5" velocity="2"/></joint>'
    '</robot>\n')


def _commented(text: str) -> str:
    """``text`` with a comment and a processing instruction after every tag: inside every
    element, before its first child and after its last one."""
    return re.sub(r">(?!\n?$)", "><!-- vendor note --><?vendor-tool keep this?>", text, count=0)


@pytest.fixture
def pair(tmp_path):
    plain, noted = tmp_path / "plain.urdf", tmp_path / "noted.urdf"
    plain.write_text(_PLAIN, encoding="utf-8")
    noted.write_text(_commented(_PLAIN), encoding="utf-8")
    assert noted.read_text().count("<!-- vendor note -->") > 30   # in every element
    assert "<geometry><!-- vendor note --><?vendor-tool keep this?><box" in noted.read_text()
    return plain, noted


def test_comments_and_pis_in_every_element_read_like_the_plain_file(pair, tmp_path):
    plain, noted = pair
    check_urdf(noted)
    assert select_chain(noted) == select_chain(plain)
    assert missing_meshes(noted) == missing_meshes(plain) == ["package://gone/l1.stl"]
    for kind in ("visual", "collision"):
        a = urdf_visuals(plain, kind=kind, missing="skip")
        b = urdf_visuals(noted, kind=kind, missing="skip")
        assert list(a) == list(b)
        for k in a:
            for va, vb in zip(a[k], b[k], strict=True):
                assert va.geometry == vb.geometry
                np.testing.assert_allclose(va.T_link_visual, vb.T_link_visual, atol=1e-15)
    with pytest.warns(UserWarning, match="mesh file"):
        meshes = load_link_meshes(noted, kind="collision", missing="warn")
    assert set(meshes) == {"base", "l2"}
    xml, limits = continuous_as_revolute(noted, ["j2"])
    assert limits == {"j2": (5.0, 2.0)} and "vendor note" not in xml
    ra, rb = Robot.from_urdf(plain), Robot.from_urdf(noted)
    q = np.array([0.3, -0.7])
    np.testing.assert_allclose(rb.gravity_torque(q), ra.gravity_torque(q), rtol=1e-12, atol=1e-12)


def test_perturbed_copy_of_a_commented_urdf_keeps_the_notes_and_perturbs_the_same(pair, tmp_path):
    plain, noted = pair
    a = perturb_urdf(plain, tmp_path / "pa.urdf", seed=3)
    b = perturb_urdf(noted, tmp_path / "pb.urdf", seed=3)
    assert "vendor note" in b.read_text() and "vendor-tool" in b.read_text()
    ra, rb = Robot.from_urdf(a), Robot.from_urdf(b)
    q = np.array([0.2, 0.4])
    np.testing.assert_allclose(rb.gravity_torque(q), ra.gravity_torque(q), rtol=1e-12, atol=1e-12)


def test_tiago_vendor_urdf_with_comments_in_geometry_runs_the_study(tmp_path):
    vendor = SHARED_REAL / "tiago" / "tiago_48_schunk.urdf"
    if not vendor.is_file():
        pytest.skip(f"{vendor} absent")
    assert "<geometry>\n        <!--" in vendor.read_text(encoding="utf-8") or \
        re.search(r"<geometry>\s*<!--", vendor.read_text(encoding="utf-8"))
    camp = tmp_path / "tiago48"
    shutil.copytree(REPO / "fixtures" / "real" / "tiago", camp)
    shutil.copyfile(vendor, camp / "robot" / "tiago.urdf")        # the vendor file unchanged
    vis = urdf_visuals(camp / "robot" / "tiago.urdf", kind="collision", missing="skip")
    assert "gripper_left_finger_link" in vis
    o, e = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(o), contextlib.redirect_stderr(e):
        rc = main(["study", str(camp), "--out", str(tmp_path / "study"), "--quiet"])
    assert rc == 0, e.getvalue()
    assert "unsupported geometry" not in e.getvalue()
