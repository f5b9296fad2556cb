"""ident.excitation.design (thesis eq. 3-1) and `jointlab design`: constraints hold, cond(R) beats random
trajectories scaled to the same constraints, the CLI writes its files."""
from __future__ import annotations

import json

import numpy as np
import pytest

from ident.excitation.design import DesignLimits, ExcitationDesigner, regressor_cond

LIM = DesignLimits(q_lower=-2.86, q_upper=2.86, qd_max=2.43, qdd_max=20.0)


@pytest.mark.parametrize("frac", [1.0, 0.5, 0.25])
def test_constraints_hold(frac):
    d = ExcitationDesigner(n_harmonics=5, period=10.0, n_starts=2, seed=1).fit(LIM, frac, joint=5)
    assert d.feasible
    assert d.peak_speed == pytest.approx(frac * LIM.qd_max, rel=2e-3)   # peak at the fraction
    q0, qd0, qdd0 = d.series.evaluate(np.array([0.0, d.period]))
    assert np.allclose(qd0, 0, atol=1e-12) and np.allclose(qdd0, 0, atol=1e-12)  # both ends
    assert q0[0] == pytest.approx(q0[1])
    t, q, qd, qdd = d.trajectory(n=4001)
    assert q.min() >= LIM.q_lower and q.max() <= LIM.q_upper
    assert np.max(np.abs(qdd)) <= LIM.qdd_max * 1.001
    assert d.to_dict()["n_harmonics"] == 5


def test_cond_beats_random_trajectories():
    """Baseline: 50 seeded random coefficient sets meeting the same end conditions, scaled to
    the same peak speed. The optimum must beat the best of them."""
    des = ExcitationDesigner(n_harmonics=5, period=10.0, n_starts=3, seed=0)
    d = des.fit(LIM, 1.0)
    Na, Nb = des._bases()
    rng = np.random.default_rng(7)
    wf = 2 * np.pi / 10.0
    t = np.linspace(0, 10.0, 400, endpoint=False)
    conds = []
    for _ in range(50):
        out = des._build(rng.normal(size=8), LIM, 1.0, Na, Nb, wf, des._shapes(t, wf))
        _, _, _, q, qd, qdd = out
        if q.min() >= LIM.q_lower and q.max() <= LIM.q_upper and np.max(np.abs(qdd)) <= LIM.qdd_max:
            conds.append(regressor_cond(q, qd, qdd))
    assert conds, "no feasible random trajectory to compare with"
    assert d.cond < min(conds)
    assert d.cond < 4.0


def test_bad_settings():
    with pytest.raises(ValueError):
        DesignLimits(1.0, -1.0, 1.0)
    with pytest.raises(ValueError):
        ExcitationDesigner(n_harmonics=1)
    with pytest.raises(ValueError):
        ExcitationDesigner().fit(LIM, 1.5)


def _write_robot(folder):
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "arm.urdf").write_text("""<?xml version="1.0"?>
<robot name="one">
  <link name="base"/>
  <link name="link1"><inertial><origin xyz="0.1 0 0"/><mass value="2.0"/>
    <inertia ixx="0.01" ixy="0" ixz="0" iyy="0.01" iyz="0" izz="0.02"/></inertial></link>
  <joint name="joint1" type="revolute"><parent link="base"/><child link="link1"/>
    <axis xyz="0 1 0"/><limit lower="-2.5" upper="2.5" velocity="2.0" effort="40"/></joint>
</robot>
""", encoding="utf-8")
    (folder / "drives.toml").write_text("""[[joint]]
name = "joint1"
motor_inertia = 0.35
motor_viscous = 0.9
max_velocity = 2.0
max_torque = 40.0
""", encoding="utf-8")
    return folder / "arm.urdf"


def test_cli_design(tmp_path, capsys):
    from ident.cli.main import main

    urdf = _write_robot(tmp_path / "robot")
    out = tmp_path / "out"
    rc = main(["design", "--robot", str(urdf), "--joint", "1", "--vmax-frac", "0.5", "--out", str(out),
               "--starts", "1", "--amax", "15"])
    assert rc == 0
    d = json.loads((out / "design.json").read_text())
    assert d["peak_speed"] == pytest.approx(1.0, rel=2e-3) and d["limits"]["qdd_max"] == 15.0
    assert d["q_min"] >= -2.5 and d["q_max"] <= 2.5
    rows = np.loadtxt(out / "trajectory.csv", delimiter=",", skiprows=1)
    assert rows.shape[1] == 4 and rows[0, 2] == pytest.approx(0, abs=1e-12)
    assert (out / "design.png").stat().st_size > 1000
    assert main(["design", "--robot", str(urdf), "--joint", "3", "--out", str(out)]) == 2
    assert "joints 1..1" in capsys.readouterr().err
