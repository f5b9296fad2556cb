"""jointlab sim2real: MuJoCo's compile of the URDF against pinocchio, the replay, the exported
model run by a plain script without jointlab, and the command's errors."""
from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

mujoco = pytest.importorskip("mujoco", reason="MuJoCo is an optional extra: pip install '.[mujoco]'")

from mocap.io.campaign import load_campaign  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
TX40 = ROOT / "fixtures" / "real" / "tx40"
ARM7 = ROOT / "fixtures" / "arm7"


@pytest.mark.parametrize("camp", [TX40, ROOT / "fixtures" / "real" / "tiago"])
def test_mujoco_inverse_dynamics_matches_pinocchio(camp, tmp_path):
    """MuJoCo's compile of the campaign's URDF chain (no armature, damping or friction) has the
    same inverse dynamics as pinocchio's RNEA on random states, to 1e-6 relative (pinocchio on the
    URDF with the inertias MuJoCo refuses corrected the same way: TIAGo's arm_1_link breaks the
    triangle inequality, which the model reports)."""
    from mocap.robot import Robot
    from ident.sim2real.model import build_model, urdf_for_mujoco

    c = load_campaign(camp)
    robot = c.load_robot()
    sm = build_model(c, robot)
    corrected = []
    sel = robot.selection
    xml = urdf_for_mujoco(c.urdf, tuple(sel.chain), dict(sel.locked), corrected)
    if corrected:
        assert all(n in sm.notes[0] for n in corrected)
        u = tmp_path / "corrected.urdf"
        u.write_text(xml)
        robot = Robot.from_urdf(u, c.drives, c.gravity, c.base_link, c.tip_link, c.fixed)
    zero = {k: np.zeros(sm.n) for k in ("armature", "damping", "frictionloss")}
    m = sm.compile(1e-3, native=zero)
    m.opt.disableflags |= int(mujoco.mjtDisableBit.mjDSBL_LIMIT)      # random states beyond limits
    d = mujoco.MjData(m)
    rng = np.random.default_rng(3)
    for _ in range(5):
        q, qd, qdd = rng.normal(size=(3, sm.n))
        d.qpos[:] = 0
        d.qpos[sm.qpos_adr] = q
        d.qvel[:] = 0
        d.qvel[sm.dof] = qd
        d.qacc[:] = 0
        d.qacc[sm.dof] = qdd
        mujoco.mj_inverse(m, d)
        ref = robot.rnea(q, qd, qdd)
        got = d.qfrc_inverse[sm.dof]
        assert np.allclose(got, ref, rtol=1e-6, atol=1e-6 * np.abs(ref).max())


def test_payload_body_matches_pinocchio_payload():
    """The payload body at the flange: the same inverse dynamics as pinocchio's point mass."""
    from ident.sim2real.model import build_model

    c = load_campaign(TX40)
    robot = c.load_robot()
    sm = build_model(c, robot)
    zero = {k: np.zeros(sm.n) for k in ("armature", "damping", "frictionloss")}
    com = np.array([0.03, -0.02, 0.05])
    m = sm.compile(1e-3, payload=(2.5, com), native=zero)
    m.opt.disableflags |= int(mujoco.mjtDisableBit.mjDSBL_LIMIT)
    d = mujoco.MjData(m)
    rb = robot.with_payload(2.5, com)
    q, qd, qdd = np.random.default_rng(4).normal(size=(3, sm.n))
    d.qpos[sm.qpos_adr], d.qvel[sm.dof], d.qacc[sm.dof] = q, qd, qdd
    mujoco.mj_inverse(m, d)
    ref = rb.rnea(q, qd, qdd)
    assert np.allclose(d.qfrc_inverse[sm.dof], ref, rtol=1e-6, atol=1e-6 * np.abs(ref).max())


def test_stepped_effects_equal_plain_rollout_when_zero():
    """The one-step-at-a-time replay with a zero-amplitude effect equals the single rollout."""
    from ident.sim2real.model import build_model
    from ident.sim2real.replay import Replayer, records_of

    c = load_campaign(TX40)
    robot = c.load_robot()
    sm = build_model(c, robot)
    rec = records_of(c, robot)[0]
    rp = Replayer(sm, robot, rec)
    starts = rp.windows(0.1, np.ones(rec.t.size, bool))[:4]
    doc = {"joints": [{"dof": int(sm.dof[1]), "eps": 0.01, "effects": [
        {"effect": "stribeck", "shape": {"Vs": 0.05, "d": 1.0}, "amplitudes": {"S": 0.0}}]}]}
    nat = {**sm.given, "armature": sm.given["armature"] + 0.05}     # TX40's link 6 is massless
    q1, _ = rp.simulate(nat, starts, 50, None)
    q2, _ = rp.simulate(nat, starts, 50, doc)
    assert np.abs(q1 - q2).max() < 1e-7
    doc["joints"][0]["effects"][0]["amplitudes"]["S"] = 5.0
    q3, _ = rp.simulate(nat, starts, 50, doc)
    assert np.abs(q3 - q1).max() > 1e-5          # the effect acts


def test_effect_torques():
    """Signs and sizes of the runtime effect torques (they oppose motion where they are friction)."""
    from ident.sim2real import effects_runtime as fx

    doc = {"joints": [{"dof": 0, "eps": 1e-3, "effects": [
        {"effect": "stribeck", "shape": {"Vs": 0.1, "d": 1.0}, "amplitudes": {"S": 2.0}}]}]}
    qd = np.array([[0.05], [-0.05]])
    tau, _ = fx.torque(doc, np.zeros((2, 1)), qd, np.zeros((2, 1)), fx.initial_state(None, qd), 1e-3)
    assert tau[0, 0] == pytest.approx(-2.0 * np.exp(-0.5) * np.tanh(50.0), rel=1e-12)
    assert tau[1, 0] == pytest.approx(-tau[0, 0], rel=1e-12)
    z = np.array([-1.0])
    for _ in range(2000):                         # presliding: z settles at sgn(qd)
        z = fx.bristle_step(z, 0.01, 1e-3, 1e-3)
    assert z[0] == pytest.approx(1.0, abs=1e-6)


ARM2 = """<mujoco><option timestep="0.001" integrator="implicitfast"/><worldbody>
<body name="a"><joint name="j1" type="hinge" axis="0 1 0" armature="4" damping="3"/>
<geom type="capsule" fromto="0 0 0 0.5 0 0" size="0.04" mass="6"/>
<body name="b" pos="0.5 0 0"><joint name="j2" type="hinge" axis="0 1 0" armature="1" damping="1"/>
<geom type="capsule" fromto="0 0 0 0.4 0 0" size="0.03" mass="3"/></body></body></worldbody></mujoco>"""


def test_load_dependent_uses_the_transmitted_torque():
    """The load of ``load_dependent`` in MuJoCo's passive callback is the torque the transmission
    carries to the link (the inverse dynamics without armature and damping), not the drive torque:
    on a joint with a large armature the two differ by ``a qdd + b qd``."""
    from ident.sim2real import effects_runtime as fx

    m = mujoco.MjModel.from_xml_string(ARM2.replace("<option", f'<size nuserdata="{fx.nuserdata(2)}"/><option'))
    mu, T = 0.05, 40.0
    doc = {"joints": [{"dof": 0, "eps": 1e-2, "effects": [
        {"effect": "load_dependent", "shape": {"T": T}, "amplitudes": {"mu": mu}}]}]}
    m0 = mujoco.MjModel.from_xml_string(ARM2.replace('armature="4" damping="3"', "")
                                        .replace('armature="1" damping="1"', ""))
    d0 = mujoco.MjData(m0)
    fx.install(m, doc)
    try:
        d = mujoco.MjData(m)
        fx.reset(m, d, doc)
        S = fx.NSTATE * m.nv
        got, want, drive, states = [], [], [], []
        h = m.opt.timestep
        v_prev = d.qvel.copy()
        for k in range(1500):
            d.qfrc_applied[:] = (60 * np.sin(2 * np.pi * 1.3 * k * h) + 20, 8 * np.cos(2 * np.pi * 0.7 * k * h))
            q, v = d.qpos.copy(), d.qvel.copy()        # the state the callback sees at this step
            mujoco.mj_step(m, d)
            if k >= 5:
                states.append((q, v, (v - v_prev) / h, d.qfrc_applied[0]))
                got.append(d.userdata[S + 2 * m.nv])   # joint 1's extra torque at this step
            v_prev = v
    finally:
        mujoco.set_mjcb_passive(None)
    for q, v, a, u in states:
        d0.qpos[:], d0.qvel[:], d0.qacc[:] = q, v, a
        mujoco.mj_inverse(m0, d0)                       # rigid-body torque, no armature/damping
        s = np.tanh(v[0] / 1e-2)
        want.append(-mu * T * np.tanh(abs(d0.qfrc_inverse[0]) / T) * s)
        drive.append(-mu * T * np.tanh(abs(u) / T) * s)
    got, want, drive = map(np.array, (got, want, drive))
    scale = np.abs(want).max()
    assert np.abs(got - want).max() < 0.03 * scale
    assert np.abs(drive - want).max() > 0.1 * scale     # the drive torque would be another load


def _campaign_copy(tmp_path, seconds=8.0):
    """The TX40 campaign with its record cut to ``seconds`` (a quick test)."""
    import shutil

    dst = tmp_path / "tx40"
    shutil.copytree(TX40, dst)
    log = dst / "trials" / "excitation.csv"
    lines = log.read_text().splitlines()
    t0 = float(lines[1].split(",")[0])
    keep = [lines[0]] + [ln for ln in lines[1:] if float(ln.split(",")[0]) - t0 <= seconds]
    log.write_text("\n".join(keep) + "\n")
    return dst


@pytest.mark.parametrize("effect", ["6:stribeck", "2:load_dependent", "5:presliding"])
def test_command_and_plain_script_reproduce_heldout_error(tmp_path, effect):
    """``jointlab sim2real`` writes the report and the export; the exported model, run by its
    example script in a subprocess without jointlab on sys.path, reproduces jointlab's held-out
    rollout error within 1 % (load_dependent: the callback's transmitted torque, from the model's
    own armature/damping/frictionloss and its state in ``userdata``, is the replay's)."""
    from ident.cli.main import main

    camp = _campaign_copy(tmp_path, 5.0)
    out = tmp_path / "out"
    rc = main(["sim2real", str(camp), "--out", str(out), "--effects", effect, "--no-sysid"])
    assert rc == 0
    rep = json.loads((out / "sim2real.json").read_text())
    assert set(rep["errors"]) >= {"given", "native", "native_effects"}
    e = rep["errors"]["native"]["0.5"]["1"]
    assert e["pos_rms"] > 0 and np.isfinite(e["vel_rms"])
    assert (out / "sim2real.md").read_text().startswith("# Sim-to-real in MuJoCo")
    model = out / "model"
    fxdoc = json.loads((model / "effects.json").read_text())
    assert [e["effect"] for jt in fxdoc["joints"] for e in jt["effects"]] == [effect.split(":")[1]]
    env = {"PATH": os.environ.get("PATH", ""), "PYTHONNOUSERSITE": "1"}
    code = ("import sys; sys.path = [p for p in sys.path if 'work/main' not in p or 'site-packages' in p]; "
            "import runpy; sys.argv = ['replay_example.py', sys.argv[1]]; "
            "runpy.run_path(sys.argv[1] + '/replay_example.py', run_name='__main__'); "
            "assert 'ident' not in sys.modules and 'mocap' not in sys.modules")
    res = subprocess.run([sys.executable, "-c", code, str(model)], cwd=tmp_path, env=env,
                         capture_output=True, text=True, timeout=300)
    assert res.returncode == 0, res.stderr
    got = json.loads(res.stdout.strip().splitlines()[-1])
    check = json.loads((model / "heldout" / "check.json").read_text())
    n = 0
    for trial, by_h in check["trials"].items():
        for H, entry in by_h.items():
            ref = np.array(entry["pos_rms"])
            assert np.allclose(got[trial][H], ref, rtol=0.01), (trial, H)
            n += 1
    assert n >= 1


def test_command_errors_are_one_line(tmp_path, capsys):
    from ident.cli.main import main

    camp = _campaign_copy(tmp_path, 3.0)
    assert main(["sim2real", str(camp), "--out", str(tmp_path / "o"), "--effects", "9:stribeck"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "--effects" in err
    assert main(["sim2real", str(camp), "--out", str(tmp_path / "o"), "--mjcf", str(tmp_path / "no.xml")]) == 2
    assert "MJCF not found" in capsys.readouterr().err
    (tmp_path / "m").mkdir()
    bad = tmp_path / "m" / "bad.xml"
    bad.write_text("<mujoco><worldbody><body><joint name='other'/><geom size='0.1'/></body></worldbody></mujoco>")
    assert main(["sim2real", str(camp), "--out", str(tmp_path / "o"), "--mjcf", str(bad), "--no-sysid"]) == 2
    assert "is not in the MuJoCo model" in capsys.readouterr().err


def test_command_reuses_an_earlier_diagnosis(tmp_path, capsys, monkeypatch):
    """``--diagnosis FILE``: the named effects come from the file (no diagnosis is run); a file of
    another campaign or without joints is one line, exit 2. The command is the pipeline's
    ``sim2real`` stage run once (issue 44): its options reach the stage's call."""
    import ident.pipeline.stages.sim2real as stage
    from ident.cli.main import main

    seen = []
    real = stage.sim2real_campaign

    def spy(camp, robot, **kw):
        seen.append(kw)
        return real(camp, robot, **kw)

    monkeypatch.setattr(stage, "sim2real_campaign", spy)

    camp = _campaign_copy(tmp_path, 3.0)
    name = load_campaign(camp).name
    (tmp_path / "d").mkdir()
    diag = tmp_path / "d" / "diagnosis.json"
    diag.write_text(json.dumps({"format": 1, "campaign": name, "joints": {
        "1": {"verdict": "none", "selected": []},
        "2": {"verdict": "stribeck", "selected": [{"effect": "stribeck"}]}}}))
    out = tmp_path / "o"
    assert main(["sim2real", str(camp), "--out", str(out), "--diagnosis", str(diag), "--no-sysid"]) == 0
    assert len(seen) == 1 and seen[0]["sysid"] is False and seen[0]["diagnosis"]["campaign"] == name
    rep = json.loads((out / "sim2real.json").read_text())
    assert rep["effects"]["source"] == "diagnosis file"
    assert rep["effects"]["named"] == {"2": ["stribeck"]}
    assert rep["seconds"]["diagnosis_s"] < 1.0
    assert not (out / "diagnosis.json").exists()         # only a diagnosis this run computed is written
    capsys.readouterr()
    diag.write_text(json.dumps({"campaign": "another", "joints": {}}))
    assert main(["sim2real", str(camp), "--out", str(tmp_path / "o2"), "--diagnosis", str(diag)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "diagnosis.json" in err and "campaign" in err
    diag.write_text("[]")
    assert main(["sim2real", str(camp), "--out", str(tmp_path / "o2"), "--diagnosis", str(diag)]) == 2
    assert "joints" in capsys.readouterr().err


def test_command_replays_records_that_hold_some_joints(tmp_path, capsys):
    """Issue 43: records that move two of the arm's joints (the others held at their logged
    angle) replay: the moving joints are fitted and scored, the held ones keep the given model's
    parameters; records that drive no common joint are one line naming the trials, exit 2."""
    from ident.cli.main import main
    from ident.sim.campaign_synth import CampaignSynth, SynthConfig
    from ident.sim2real.model import build_model

    camp = tmp_path / "j23"
    CampaignSynth(SynthConfig(joints=(2, 3), together=True, reps=1, duration=5.0, loads=(0.0,),
                              vmax=(0.3, 0.6), seed=5)).write(camp, progress=False)
    out = tmp_path / "o"
    assert main(["sim2real", str(camp), "--out", str(out), "--effects", "3:stribeck", "--no-sysid"]) == 0
    rep = json.loads((out / "sim2real.json").read_text())
    assert rep["scored_joints"] == [2, 3]
    c = load_campaign(camp)
    robot = c.load_robot()
    held = [j for j in range(1, robot.n + 1) if j not in (2, 3)]
    assert rep["unfitted_joints"] == held
    given = build_model(c, robot).given
    for k, v in rep["parameters"]["native"].items():
        assert np.allclose([v[j - 1] for j in held], given[k][[j - 1 for j in held]], rtol=1e-12, atol=0)
    for m in ("given", "native", "native_effects"):
        for j in ("2", "3"):
            assert np.isfinite(rep["errors"][m]["0.5"][j]["pos_rms"]), (m, j)
    assert rep["effects"]["named"] == {"3": ["stribeck"]}
    capsys.readouterr()
    single = tmp_path / "j2j3"
    CampaignSynth(SynthConfig(joints=(2, 3), reps=1, duration=3.0, loads=(0.0,), vmax=(0.6,),
                              seed=5)).write(single, progress=False)
    assert main(["sim2real", str(single), "--out", str(tmp_path / "o2"), "--no-sysid"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "campaign.toml" in err and "j2-load0-v60-r1: 2" in err, err


def _tx40_replayer(tmp_path, seconds=6.0):
    from ident.sim2real.model import build_model
    from ident.sim2real.replay import Replayer, records_of

    c = load_campaign(_campaign_copy(tmp_path, seconds))
    robot = c.load_robot()
    sm = build_model(c, robot)
    rec = records_of(c, robot)[0]
    return sm, Replayer(sm, robot, rec), rec


def test_batched_sets_equal_single_simulations(tmp_path):
    """Several parameter sets (with and without an effect) simulated in one batched call give each
    set's own simulation to 1e-10 rad: the finite-difference columns of the refinement are exact."""
    from ident.sim2real.replay import simulate_sets

    sm, rp, rec = _tx40_replayer(tmp_path)
    starts = rp.windows(0.1, np.ones(rec.t.size, bool))[:5]
    L = max(1, int(round(0.1 / rec.dt)))
    base = {**sm.given, "armature": sm.given["armature"] + 0.05}
    other = {**base, "damping": base["damping"] + 0.5, "frictionloss": base["frictionloss"] + 0.5}
    doc = {"joints": [{"dof": int(sm.dof[1]), "eps": 0.01, "effects": [
        {"effect": "stribeck", "shape": {"Vs": 0.05, "d": 1.0}, "amplitudes": {"S": 3.0}}]}]}
    sets = [(base, None), (other, None), (base, doc)]
    got = simulate_sets([(rp, starts, L)], sets)
    for (nat, eff), per in zip(sets, got):
        q_ref, _ = simulate_sets([(rp, starts, L)], [(nat, eff)])[0][0]
        assert np.abs(per[0][0] - q_ref).max() < 1e-10
    assert np.abs(got[0][0][0] - got[1][0][0]).max() > 1e-6      # the sets differ


def test_refine_lowers_training_rollout_error(tmp_path):
    """The batched Levenberg-Marquardt refinement from a detuned start lowers every scored joint's
    training rollout error (never raises one: each joint keeps its best point)."""
    from ident.sim2real.fit import Rollouts, refine

    sm, rp, rec = _tx40_replayer(tmp_path)
    mask = np.ones(rec.t.size, bool)
    ro = Rollouts([rp], [mask], max_windows=6)
    start = {"armature": sm.given["armature"] + 0.05, "damping": sm.given["damping"] * 0.5 + 0.1,
             "frictionloss": np.full(sm.n, 0.5)}
    joints = [j for j in range(sm.n) if rec.driven[j]]
    e0 = ro.rms([(start, None)])[0]
    nat, _, e1 = refine(ro, start, sm, joints, iters=2)
    assert np.all(e1[joints] <= e0[joints] + 1e-12)
    assert np.mean(e1[joints] / e0[joints]) < 0.9


def test_mujoco_sysid_rolls_out_what_the_replay_does(tmp_path):
    """mujoco.sysid, wired to the records (motor actuators for the logged torque, qpos observed),
    simulates exactly jointlab's replay for the same parameters, and its fit lowers its own cost."""
    sysid_mod = pytest.importorskip("mujoco.sysid", reason="pip install 'mujoco[sysid]'")
    from ident.sim2real import sysid as S

    sm, rp, rec = _tx40_replayer(tmp_path)
    nat = {**sm.given, "armature": sm.given["armature"] + 0.05, "frictionloss": np.full(sm.n, 0.3)}
    starts = rp.windows(0.1, np.ones(rec.t.size, bool))[:2]
    L = max(1, int(round(0.1 / rec.dt)))
    m = S._spec(rp, nat).compile()
    x0, u = rp._init(m, starts), rp._controls(m, starts, L)
    ctrl = np.zeros(u.shape[:2] + (m.nu,))
    ctrl[:, :, :sm.n] = u[:, :, :sm.n]
    ctrl[:, :, sm.n:] = u[:, :, m.nu + sm.dof]
    q_ref, _ = rp.simulate(nat, starts, L)
    for b in range(starts.size):
        ts = sysid_mod.TimeSeries(rp.h * np.arange(ctrl.shape[1] + 1), np.vstack([ctrl[b], ctrl[b, -1:]]))
        tr = sysid_mod.sysid_rollout([m], [mujoco.MjData(m)], ts, x0[b])
        q = tr[0].state.data[:, 1:1 + m.nq][:, sm.qpos_adr][rp.sub - 1::rp.sub]
        assert np.abs(q - q_ref[b]).max() < 1e-10
    out = S.fit_sysid(sm, [rp], [np.ones(rec.t.size, bool)], nat, max_iters=2, max_windows=3)
    assert out["status"] == "fitted"
    assert out["training_cost"]["end"] < out["training_cost"]["start"]
    assert set(out["native"]) == {"armature", "damping", "frictionloss"}


WORLD = ROOT.parent / "shared" / "worlds" / "foreign"


@pytest.mark.skipif(not (WORLD / "make_world.py").is_file(), reason=f"foreign world not found at {WORLD}")
def test_diagnosis_against_the_mjcf_names_the_withheld_effect(tmp_path):
    """``jointlab diagnose --nominal mjcf:FILE``: the friction fixed to an MJCF that carries the
    foreign world's true Coulomb + viscous values and rotor inertia; the diagnosis names the
    effect the world withheld (a Stribeck drop on tri3's joint 1, seed 1), and diagnosis.json
    says which values it held."""
    import shutil

    from ident.cli.main import main
    from ident.sim2real.model import build_model

    env = os.environ.get("JOINTLAB_CORPUS")
    root = Path(env) / "multi" if env else tmp_path
    camp0 = root / "tri3-stribeck-s1"
    if not (camp0 / "campaign.toml").is_file():
        subprocess.run([sys.executable, str(WORLD / "make_world.py"), str(camp0), "--seed", "1", "--record",
                        "multi", "--effect", "stribeck", "--robot", "tri3"], check=True, capture_output=True,
                       env=dict(os.environ, OPENBLAS_NUM_THREADS="1"))
    truth = json.loads(camp0.with_name(camp0.name + ".truth.json").read_text())
    camp = tmp_path / "camp"
    shutil.copytree(camp0, camp)
    c = load_campaign(camp)
    sm = build_model(c, c.load_robot())
    J = truth["joints"]
    nat = {"armature": np.array([j["motor_inertia"] for j in J]),
           "damping": np.array([j["motor_viscous"] + j["viscous"] for j in J]),
           "frictionloss": np.array([j["coulomb"] for j in J])}
    spec = sm.spec_for(1e-3, None, nat)
    for k in range(sm.n):                          # jointlab's servos are added when it reads the file
        spec.delete(spec.actuator(f"jointlab_servo_{k + 1}"))
    (camp / "robot" / "arm.xml").write_text(spec.to_xml())
    ej = int(truth["effects"][0]["joint"])
    out = tmp_path / "out"
    assert main(["diagnose", str(camp), "--out", str(out), "--joints", str(ej), "--no-markers",
                 "--nominal", f"mjcf:{camp / 'robot' / 'arm.xml'}"]) == 0
    rep = json.loads((out / "diagnosis.json").read_text())["joints"][str(ej)]
    assert rep["verdict"] == "stribeck", rep["verdict_text"]
    held = rep["nominal"]["joint_parameters"]["fixed_parameters"]
    assert held["coulomb (frictionloss)"] == pytest.approx(J[ej - 1]["coulomb"], rel=1e-5)   # 6 digits in XML
    assert held["viscous (damping)"] == pytest.approx(J[ej - 1]["motor_viscous"] + J[ej - 1]["viscous"], rel=1e-5)
    # a bare `mjcf` is the campaign's own MuJoCo model (here its URDF compiled: the manifest
    # declares no [robot] mjcf)
    assert main(["diagnose", str(camp), "--out", str(tmp_path / "o2"), "--joints", str(ej), "--no-markers",
                 "--nominal", "mjcf"]) == 0
    doc = json.loads((tmp_path / "o2" / "diagnosis.json").read_text())
    assert str(camp) in json.dumps(doc["joints"][str(ej)]["nominal"])


def test_least_squares_effect_amplitudes_have_the_runtime_sign(tmp_path):
    """The inverse-dynamics start recovers the amplitudes the runtime applies: a drive torque that
    overcomes armature, damping, frictionloss and a position ripple whose torque on the joint is
    ``F theta`` (so the drive carries ``-F theta``) gives back ``theta``, not ``-theta``."""
    from ident.sim2real import effects_runtime as fx
    from ident.sim2real.fit import TrainingSet, rigid_torque

    sm, rp, rec = _tx40_replayer(tmp_path)
    j = 1
    ts = TrainingSet([rp], [np.ones(rec.t.size, bool)])
    shape, theta = {"k": 3.0}, np.array([0.4, -0.3, 0.5, 0.2])
    F = fx.features("position_ripple", shape, rec.q[:, j], rec.qd[:, j], None, None, ts.eps[j])
    tid = rigid_torque(rp, np.arange(rec.t.size))[:, j]
    rec.tau[:, j] = (tid + 0.1 * rec.qdd[:, j] + 0.5 * rec.qd[:, j] + 1.0 * fx.smooth_sign(rec.qd[:, j], ts.eps[j])
                     - F @ theta)
    c = next(c for c in ts.candidates(j, "position_ripple") if c["effect"]["shape"] == shape)
    got = np.array([c["effect"]["amplitudes"][k] for k in fx.amplitude_names("position_ripple")])
    assert np.allclose(got, theta, rtol=1e-6, atol=1e-8)
    assert c["native"] == pytest.approx({"armature": 0.1, "damping": 0.5, "frictionloss": 1.0}, rel=1e-6)


def test_presliding_state_starts_from_the_measured_motion():
    """A window that starts at rest after a positive motion starts with the bristles deflected
    forward (z near +1, what the motion left), not at ``sgn(0) = 0``; after a reversal that moved
    less than the presliding length, part way back."""
    from ident.sim2real import effects_runtime as fx

    doc = {"joints": [{"dof": 0, "eps": 1e-3, "effects": [
        {"effect": "presliding", "shape": {"delta": 1e-3}, "amplitudes": {"F": 1.0}}]}]}
    h = 1e-3
    fwd = np.r_[np.full(200, 0.05), np.zeros(50)][:, None]          # 10 mrad forward, then rest
    st = fx.initial_state(doc, np.zeros(1), fwd, h)
    assert st[0, 0] == pytest.approx(1.0, abs=1e-3) and st[1, 0] == 0.0
    back = np.r_[fwd[:, 0], np.full(10, -0.05)][:, None]             # 0.5 mrad back (delta 1 mrad)
    z = fx.initial_state(doc, np.zeros(1), back, h)[0, 0]
    assert -0.9 < z < 0.9
    assert fx.initial_state(doc, np.zeros(1))[0, 0] == 0.0           # without history: sgn(qd)
