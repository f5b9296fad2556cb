"""Multi-joint continuous records (issue 15): batched regressor, real-log preprocessing, braked
joint checks, the rigid-body identification through `jointlab info/fit` on a 7-joint arm the
workbench has never seen (data made here with pinocchio's own inverse dynamics, per sample:
no code shared with the estimator) and on the real Staubli TX40 fixture."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from ident.cli import main

REPO = Path(__file__).resolve().parents[1]
ARM7 = REPO / "fixtures" / "arm7" / "arm7.urdf"
TX40 = REPO / "fixtures" / "real" / "tx40"

# truth of the generated 7-joint record: per-joint Coulomb, viscous, offset (link side)
C_TRUE = np.array([3.0, 4.0, 2.0, 2.5, 0.8, 0.6, 0.3])
V_TRUE = np.array([6.0, 5.0, 3.0, 3.0, 1.0, 0.8, 0.4])
OFF_TRUE = np.array([0.3, -0.5, 0.2, 0.1, -0.05, 0.04, 0.02])
NOISE = np.array([0.4, 0.4, 0.3, 0.3, 0.1, 0.08, 0.05])


def _pin_model(urdf: Path):
    import pinocchio as pin

    return pin.buildModelFromUrdf(str(urdf))


def _trajectory(t, n, seed):
    """Sum-of-sines excitation per joint: angle, velocity, acceleration (analytic)."""
    rng = np.random.default_rng(seed)
    w = 2 * np.pi * np.array([0.1, 0.23, 0.37, 0.51])
    a = rng.uniform(0.1, 0.25, (n, 4)) / np.arange(1, 5)
    ph = rng.uniform(0, 2 * np.pi, (n, 4))
    arg = t[:, None, None] * w[None, None, :] + ph[None]
    q = np.sum(a * np.sin(arg), axis=2)
    qd = np.sum(a * w * np.cos(arg), axis=2)
    qdd = -np.sum(a * w ** 2 * np.sin(arg), axis=2)
    return q, qd, qdd


def _torques(model, q, qd, qdd):
    import pinocchio as pin

    data = model.createData()
    return np.array([pin.rnea(model, data, q[k], qd[k], qdd[k]) for k in range(q.shape[0])])


def _write_arm7_campaign(root: Path, duration: float = 8.0, seed: int = 3) -> dict:
    """A FORMAT campaign without markers: one 7-joint record with irregular time stamps
    (0.7-8.8 ms, median 1 ms), 5 % repeated rows and link-side torques."""
    rng = np.random.default_rng(seed)
    m = int(duration * 1100)
    steps = np.where(rng.random(m) < 0.02, rng.uniform(2e-3, 8.8e-3, m),
                     np.clip(rng.normal(1e-3, 1e-4, m), 0.7e-3, 1.3e-3))
    t = np.concatenate([[0.0], np.cumsum(steps)])
    t = t[t <= duration]
    model = _pin_model(ARM7)
    n = model.nq
    q, qd, qdd = _trajectory(t, n, seed)
    tau = (_torques(model, q, qd, qdd) + C_TRUE * np.sign(qd) + V_TRUE * qd + OFF_TRUE
           + NOISE * rng.standard_normal(q.shape))
    qm = np.round(q / 1e-5) * 1e-5                     # encoder quantisation
    rep = np.flatnonzero(rng.random(t.size) < 0.05)
    rep = rep[rep > 0]
    qm_log, tau_log, qd_log = qm.copy(), tau.copy(), qd.copy()
    qm_log[rep], tau_log[rep], qd_log[rep] = qm_log[rep - 1], tau_log[rep - 1], qd_log[rep - 1]
    (root / "robot").mkdir(parents=True)
    (root / "trials").mkdir()
    (root / "robot" / "arm7.urdf").write_bytes(ARM7.read_bytes())
    (root / "robot" / "drives.toml").write_text("".join(
        f'[[joint]]\nname = "a{j}"\n\n' for j in range(1, n + 1)), encoding="utf-8")
    cols = [t] + list(qm_log.T) + list(tau_log.T) + list(qd_log.T)
    names = (["time"] + [f"qm_{j}" for j in range(1, n + 1)] + [f"tau_{j}" for j in range(1, n + 1)]
             + [f"qd_{j}" for j in range(1, n + 1)])
    body = "\n".join(",".join(f"{x:.9g}" for x in row) for row in np.column_stack(cols))
    (root / "trials" / "rec.csv").write_text(",".join(names) + "\n" + body + "\n", encoding="utf-8")
    (root / "campaign.toml").write_text(
        'format = 1\nname = "arm7"\n\n[robot]\nurdf = "robot/arm7.urdf"\ndrives = "robot/drives.toml"\n\n'
        '[[trial]]\nid = "rec"\njoints = [1, 2, 3, 4, 5, 6, 7]\nlog = "trials/rec.csv"\n',
        encoding="utf-8")
    return {"t": t, "q": q, "qd": qd, "qdd": qdd, "tau": tau, "model": model, "repeated": rep.size}


def _independent_heldout(model, t, q, qd, qdd, tau, folds=5, v_frac=0.02, v_abs=0.0):
    """Reference fit with pinocchio's own per-sample regressor on the true states: rigid body +
    per-joint Coulomb, viscous and offset, ordinary least squares, leave-one-segment-out."""
    import pinocchio as pin

    data = model.createData()
    T, n = q.shape
    W = np.array([pin.computeJointTorqueRegressor(model, data, q[k], qd[k], qdd[k]) for k in range(T)])
    X = np.zeros((T, n, 3 * n))
    for j in range(n):
        X[:, j, 3 * j:3 * j + 3] = np.column_stack([np.sign(qd[:, j]), qd[:, j], np.ones(T)])
    A = np.concatenate([W, X], axis=2)
    use = np.abs(qd) >= (v_abs if v_frac is None else v_frac * np.percentile(np.abs(qd), 99, axis=0))
    seg = np.minimum(np.arange(T) * folds // T, folds - 1)
    sse, cnt = np.zeros(n), np.zeros(n)
    for k in range(folds):
        tr = (seg != k)[:, None] & use
        b, *_ = np.linalg.lstsq(A[tr], tau[tr], rcond=None)
        te = (seg == k)[:, None] & use
        r = np.where(te, tau - A @ b, 0.0)
        sse += np.sum(r ** 2, axis=0)
        cnt += te.sum(axis=0)
    return np.sqrt(sse / cnt)


# ---------------------------------------------------------------------------------------------
@pytest.mark.parametrize("urdf", [ARM7, TX40 / "robot" / "tx40.urdf"], ids=["arm7", "tx40"])
def test_batched_regressor_matches_pinocchio(urdf):
    import pinocchio as pin

    from ident.model.regressor import ChainDynamics, base_parameters

    model = _pin_model(urdf)
    ch = ChainDynamics.from_model(model)
    rng = np.random.default_rng(0)
    q, qd, qdd = (rng.standard_normal((6, model.nq)) for _ in range(3))
    Y = ch.regressor(q, qd, qdd)
    data = model.createData()
    for k in range(6):
        W = pin.computeJointTorqueRegressor(model, data, q[k], qd[k], qdd[k])
        assert np.allclose(Y[k], W, atol=1e-10)
        assert np.allclose(Y[k] @ ch.pi, pin.rnea(model, data, q[k], qd[k], qdd[k]), atol=1e-9)
    bp = base_parameters(ch)
    # the base columns reproduce the full model's torques through beta
    assert np.allclose(Y[:, :, bp.idx] @ bp.beta(ch.pi), Y @ ch.pi, atol=1e-8)
    assert bp.n_base < 10 * model.nq


def test_record_preprocessing_reports_and_recovers_derivatives(tmp_path):
    from mocap.io.campaign import load_campaign
    from ident.model.record import load_record

    truth = _write_arm7_campaign(tmp_path / "c", duration=4.0)
    camp = load_campaign(tmp_path / "c")
    robot = camp.load_robot()
    rec = load_record(camp, camp.trials[0], robot)
    pre = rec.preprocessing
    assert pre["dropped_repeated_rows"] == pre["sampling"]["n_repeated"] > 0
    assert pre["sampling"]["irregular"] and pre["warnings"]
    # the record keeps the logged time stamps of the rows that are not repeats, torques as logged
    assert rec.t.size == truth["t"].size - pre["dropped_repeated_rows"]
    assert any("uniform" in s and "torques used as logged" in s for s in pre["steps"])
    qd_true = np.column_stack([np.interp(rec.t, truth["t"], truth["qd"][:, j]) for j in range(7)])
    inner = slice(50, -50)
    err = np.sqrt(np.mean((rec.qd[inner] - qd_true[inner]) ** 2, axis=0))
    assert np.all(err < 0.01 * np.abs(qd_true).max(axis=0)), err
    assert set(pre["logged_vs_savgol_velocity_rms"]) == {str(j) for j in range(1, 8)}


def test_braked_joint_that_moves_is_a_one_line_error(tmp_path, capsys):
    _write_arm7_campaign(tmp_path / "c", duration=2.0)
    man = tmp_path / "c" / "campaign.toml"
    man.write_text(man.read_text().replace("joints = [1, 2, 3, 4, 5, 6, 7]", "joints = [2]"))
    rc = main(["fit", str(tmp_path / "c"), "--out", str(tmp_path / "o"), "--models", "cv"])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and len(err.splitlines()) == 1
    assert "joint" in err and "rad" in err and "rec" in err
    rc = main(["info", str(tmp_path / "c")])
    out = capsys.readouterr().out
    assert rc == 0 and "warning: " in out and "not in joints = [2]" in out


def test_arm7_record_through_info_and_fit(tmp_path, capsys):
    truth = _write_arm7_campaign(tmp_path / "c")
    assert main(["info", str(tmp_path / "c")]) == 0
    out = capsys.readouterr().out
    assert "repeated rows" in out and "irregular sampling" in out and "markers: none" in out
    assert main(["info", str(tmp_path / "c" / "trials" / "rec.csv")]) == 0
    assert "step min/median/max" in capsys.readouterr().out
    assert main(["fit", str(tmp_path / "c"), "--out", str(tmp_path / "o"), "--models", "cv"]) == 0
    capsys.readouterr()
    fits = json.loads((tmp_path / "o" / "fits.json").read_text())
    ent = fits["trials"]["rec"]
    c = np.array([ent[str(j)]["cv"]["params"]["c"] for j in range(1, 8)])
    v = np.array([ent[str(j)]["cv"]["params"]["v"] for j in range(1, 8)])
    held = np.array([ent[str(j)]["cv"]["heldout_rms"] for j in range(1, 8)])
    assert np.allclose(c, C_TRUE, rtol=0.10, atol=0.05), c
    assert np.allclose(v, V_TRUE, rtol=0.10, atol=0.05), v
    ref = _independent_heldout(truth["model"], truth["t"], truth["q"], truth["qd"], truth["qdd"],
                               truth["tau"])
    assert np.all(np.abs(held / ref - 1) < 0.05), (held, ref)
    report = (tmp_path / "o" / "rigidbody.md").read_text()
    assert "dropped" in report and "resampled" in report and "leave-one-segment-out" in report


def test_tx40_fixture_fit_matches_published_friction(tmp_path, capsys):
    """figaroh's TX40 model: fv_j on the joint's own velocity includes the coupled motor 6's
    viscous term on joints 5 and 6 (tau_5 and tau_6 both carry fvm6 (qd5 + qd6)); published
    Coulomb fs_6 = 0.282 N m is 15 % of the wrist motor's fsm6 = 1.95 and shares its sign
    pattern, so only fsm6 is held to 10 % there (joint 6's own Coulomb to 30 %)."""
    from ident.thesis.campaign_fit import read_tx40_config

    if not (TX40 / "trials" / "excitation.csv").is_file():
        pytest.skip("TX40 fixture absent")
    assert main(["fit", str(TX40), "--out", str(tmp_path / "o"), "--models", "cv"]) == 0
    capsys.readouterr()
    rb = json.loads((tmp_path / "o" / "rigidbody.json").read_text())["trials"]["excitation"]["cv"]
    cfg = read_tx40_config(TX40 / "TX40_config.yaml")
    m6 = rb["coupled_motors"]["6"]
    fv = np.array([rb["joints"][str(j)]["params"]["v"] for j in range(1, 7)])
    fs = np.array([rb["joints"][str(j)]["params"]["c"] for j in range(1, 7)])
    fv[4:] += m6["fv"]
    assert np.all(np.abs(fv / np.array(cfg["fv"]) - 1) < 0.10), fv
    assert np.all(np.abs(fs[:5] / np.array(cfg["fs"][:5]) - 1) < 0.10), fs
    assert abs(fs[5] / cfg["fs"][5] - 1) < 0.30
    assert abs(m6["fs"] / cfg["fsm6"] - 1) < 0.10 and abs(m6["fv"] / cfg["fvm6"] - 1) < 0.10
    assert abs(m6["Ia"] / cfg["Iam6"] - 1) < 0.10
    off = np.array(rb["offsets"])
    assert np.allclose(off, cfg["offset"], atol=0.2)


def test_markerless_manifest_rules(tmp_path):
    from mocap.io.campaign import load_campaign
    from mocap.io.errors import InputError

    _write_arm7_campaign(tmp_path / "c", duration=1.0)
    camp = load_campaign(tmp_path / "c")
    assert not camp.has_markers and camp.trials[0].markers is None
    man = tmp_path / "c" / "campaign.toml"
    man.write_text(man.read_text() + 'markers = "trials/rec.trc"\n')
    with pytest.raises(InputError, match="no \\[markers\\] table"):
        load_campaign(tmp_path / "c", check_files=False)


@pytest.mark.slow
def test_arm7_record_through_diagnose_and_study(tmp_path, capsys):
    """`diagnose` on the marker-less 7-joint record: its nominal held-out RMS matches an
    independent rigid-body + Coulomb/viscous + offset fit (true states, pinocchio's per-sample
    regressor, the same six contiguous segments and |qd| >= 0.02 rad/s) within 5 % per joint,
    and no effect is claimed on data that have none; `study` runs the record end to end."""
    truth = _write_arm7_campaign(tmp_path / "c")
    assert main(["diagnose", str(tmp_path / "c"), "--out", str(tmp_path / "d")]) == 0
    rep = json.loads((tmp_path / "d" / "diagnosis.json").read_text())
    held = np.array([rep["joints"][str(j)]["heldout_rms_nominal"] for j in range(1, 8)])
    ref = _independent_heldout(truth["model"], truth["t"], truth["q"], truth["qd"], truth["qdd"],
                               truth["tau"], folds=6, v_frac=None, v_abs=0.02)
    assert np.all(np.abs(held / ref - 1) < 0.05), (held, ref)
    assert all(rep["joints"][str(j)]["verdict"] == "none" for j in range(1, 8))
    assert rep["multi_joint_trials"] == ["rec"]
    assert main(["study", str(tmp_path / "c"), "--out", str(tmp_path / "s"), "--models", "cv",
                 "--no-rrd"]) == 0
    out = capsys.readouterr().out
    assert "rigidbody" in out
    fits = json.loads((tmp_path / "s" / "rigidbody" / "fits.json").read_text())
    assert set(fits["trials"]["rec"]) == {str(j) for j in range(1, 8)}
    srep = json.loads((tmp_path / "s" / "diagnosis" / "diagnosis.json").read_text())
    assert set(srep["joints"]) == {str(j) for j in range(1, 8)}


def test_tiago_log_sampling_is_reported(capsys):
    """The real TIAGo arm log (fixtures/real/tiago): irregular 100 Hz steps are measured from the
    time stamps, the logged velocities are read as qd_<j>."""
    from mocap.io.robotlog import read_robot_log

    path = REPO / "fixtures" / "real" / "tiago" / "trials" / "arm.csv"
    assert main(["info", str(path), "--json"]) == 0
    d = json.loads(capsys.readouterr().out)
    t = np.loadtxt(path, delimiter=",", skiprows=1, usecols=0)
    steps = np.diff(t)
    sp = d["sampling"]
    assert sp["irregular"] and d["n_joints"] == 7
    assert sp["step_min_s"] == pytest.approx(steps.min()) and sp["step_max_s"] == pytest.approx(steps.max())
    assert sp["step_median_s"] == pytest.approx(np.median(steps))
    log = read_robot_log(path)
    assert log.qd is not None and log.qd.shape == (t.size, 7) and np.isfinite(log.qd).all()


def test_multijoint_fit_logs_torques_and_friction_to_rerun(tmp_path, capsys):
    """``fit --rrd`` on a multi-joint record: per joint the logged and predicted torques and the
    friction against speed; the friction the record shows (logged torque less the fitted
    rigid-body part) scatters around the simulated law by the simulated noise."""
    from rerun.chunk import RrdReader

    from ident.model.multijoint import fit_multijoint_campaign
    from mocap.io.campaign import load_campaign
    from viz import Sink

    class Recorder(Sink):
        enabled = True

        def __init__(self):
            self.calls = {}

        def scalars(self, path, time, values, names=None, timeline="time"):
            self.calls[path] = (np.asarray(time), np.asarray(values), names)

        def points(self, path, positions, **kw):
            self.calls[path] = np.asarray(positions)

    _write_arm7_campaign(tmp_path / "c")
    sink = Recorder()
    fit_multijoint_campaign(load_campaign(tmp_path / "c"), ("cv",), sink=sink)
    for j in range(1, 8):
        base = f"fits/rec/joint{j}"
        t, vals, names = sink.calls[f"{base}/torque"]
        assert names == ["tau_logged", "pred_cv"] and vals.shape == (t.size, 2)
        assert np.sqrt(np.mean((vals[:, 0] - vals[:, 1]) ** 2)) < 2 * NOISE[j - 1]
        data = sink.calls[f"{base}/friction_vs_speed/data"]
        law = C_TRUE[j - 1] * np.sign(data[:, 0]) + V_TRUE[j - 1] * data[:, 0]
        assert np.sqrt(np.mean((data[:, 1] - law) ** 2)) < 2 * NOISE[j - 1], j
        curve = sink.calls[f"{base}/friction_vs_speed/cv"]
        ref = C_TRUE[j - 1] * np.sign(curve[:, 0]) + V_TRUE[j - 1] * curve[:, 0]
        assert np.max(np.abs(curve[:, 1] - ref)) < 0.15 * np.max(np.abs(ref)), j
    rrd = tmp_path / "fit.rrd"
    assert main(["fit", str(tmp_path / "c"), "--out", str(tmp_path / "o"), "--models", "cv",
                 "--rrd", str(rrd)]) == 0
    capsys.readouterr()
    paths = {str(ch.entity_path) for ch in RrdReader(rrd).stream()}
    assert {"/fits/rec/joint7/torque/tau_logged", "/fits/rec/joint7/friction_vs_speed/cv"} <= paths
