"""The workflow layer (:mod:`ident.workflow`): one plan decides the paths of a campaign, each
task returns its typed result along the planned path, and a command is a shell over it.

Small inputs only: subsets of the demo campaign's trials, the TX40 and TIAGo records (one
multi-joint record each) with one friction model."""
from __future__ import annotations

import dataclasses
import doctest
import importlib
import json
import types

import numpy as np
import pytest

from mocap.io.campaign import load_campaign
from mocap.io.errors import InputError

import ident.workflow as wf
from ident.gap import DiagnosisSettings
from tests_paths import DEMO, FIXTURE_REAL

cli_main = importlib.import_module("ident.cli.main")   # the module (ident.cli.main is also a function)
TX40 = FIXTURE_REAL / "tx40"
TIAGO = FIXTURE_REAL / "tiago"


@pytest.fixture(scope="module")
def demo():
    if not (DEMO / "campaign.toml").is_file():
        pytest.skip("demo campaign absent")
    return load_campaign(DEMO)


@pytest.fixture(scope="module")
def tx40():
    if not (TX40 / "campaign.toml").is_file():
        pytest.skip("TX40 fixture absent")
    return load_campaign(TX40)


def _subset(camp, n: int = 2, **changes):
    """The campaign with its first ``n`` trials; ``changes``: trial index -> fields to replace."""
    trials = list(camp.trials[:n])
    for k, fields in changes.items():
        i = int(k[1:])
        trials[i] = dataclasses.replace(trials[i], **fields)
    return dataclasses.replace(camp, trials=tuple(trials))


# --------------------------------------------------------------------------------------------
# the plan
# --------------------------------------------------------------------------------------------
def test_plan_of_single_joint_campaign(demo):
    p = wf.plan(demo)
    assert p.paths == ("single_joint",)
    assert p.single_joint == tuple(t.id for t in demo.trials)
    assert p.multi_joint == () and p.coastdown == () and not p.mixed
    assert p.kinds == tuple(sorted({t.kind for t in demo.trials}))
    assert p.diagnosis_paths == ("single_joint",)
    assert set(p.reasons) == set(p.paths)
    json.dumps(p.to_dict())                       # plain JSON values


def test_plan_routes_the_models_by_the_trials_kinds(demo):
    assert "constant_velocity" not in {t.kind for t in demo.trials}
    p = wf.plan(demo, ("cv", "arctan", "dm1"))
    # no constant-velocity trial: arctan is fitted per trial, dm1 left out with a note
    assert dict(p.models) == {"single_joint": ("cv", "arctan")}
    assert any(n.startswith("arctan:") for n in p.notes)
    assert any(n.startswith("dm1 not identified") for n in p.notes)
    assert p.uses_angles
    # a constant-velocity trial moves arctan to the Indri & Trapani path
    cv = _subset(demo, 3, t0={"kind": "constant_velocity"})
    q = wf.plan(cv, ("cv", "arctan"))
    assert dict(q.models) == {"single_joint": ("cv",), "indri": ("arctan",)}
    assert q.paths == ("single_joint", "indri") and q.notes == ()
    # only dynamic models and none feasible: refused
    with pytest.raises(InputError, match="dm2 not identified"):
        wf.plan(demo, ("dm2",))


def test_plan_of_multi_joint_records(tx40):
    p = wf.plan(tx40)
    assert p.paths == ("multi_joint",) and p.diagnosis_paths == ("multi_joint",)
    assert p.multi_joint == tuple(t.id for t in tx40.trials if len(t.joints) > 1) != ()
    q = wf.plan(tx40, ("cv", "stribeck"))
    assert dict(q.models) == {"multi_joint": ("cv", "stribeck")} and not q.uses_angles
    with pytest.raises(InputError, match="--export-c is not available"):
        wf.plan(tx40, ("cv",), export_c=True)


def test_plan_refuses_a_fit_of_mixed_trials_but_diagnoses_both(demo, tx40):
    mixed = dataclasses.replace(demo, trials=demo.trials[:1] + tx40.trials)
    p = wf.plan(mixed)
    assert p.mixed and p.paths == ("single_joint", "multi_joint")
    assert p.diagnosis_paths == ("single_joint", "multi_joint")
    with pytest.raises(InputError, match="mixes multi-joint trials"):
        wf.plan(mixed, ("cv",))


def test_plan_names_coastdown_trials(demo):
    camp = _subset(demo, 3, t1={"kind": "coastdown"})
    p = wf.plan(camp)
    assert p.coastdown == (camp.trials[1].id,)
    assert p.paths == ("single_joint", "coastdown")
    assert p.reasons["single_joint"].startswith("2 ")     # the fit leaves the coast-down out


def test_parse_models():
    assert wf.parse_models("cv,,dm1, cv") == ("cv", "dm1")
    with pytest.raises(InputError):
        wf.parse_models(" , ")
    with pytest.raises(InputError):
        wf.parse_models("cv,nosuchmodel")


# --------------------------------------------------------------------------------------------
# the tasks return their typed results along the planned path
# --------------------------------------------------------------------------------------------
def test_fit_campaign_single_joint_path(demo):
    # a relabelled trial fails prepare_fit's log checks (no torque cut): planned directly
    camp = _subset(demo, 3, t2={"kind": "coastdown"})
    res = wf.fit_campaign(camp, models=("cv",), settings=wf.FitSettings(n_starts=2),
                          plan=wf.plan(camp, ("cv",)))
    assert isinstance(res, wf.FitResult)
    assert res.indri is None and res.rigidbody is None
    assert {(e.task.trial, e.task.joint) for e in res.onelink.entries} == {
        (t.id, j) for t in camp.trials[:2] for j in t.joints}
    assert res.onelink.skipped == (camp.trials[2].id,)
    doc = res.to_dict()
    assert set(doc["trials"]) == {t.id for t in camp.trials[:2]}
    for t in camp.trials[:2]:
        fit = doc["trials"][t.id][str(t.joints[0])]["cv"]
        assert np.isfinite(fit["rms"]) and fit["rms"] > 0


def test_fit_campaign_multi_joint_path_and_write(tx40, tmp_path):
    res = wf.fit_campaign(tx40, models=("cv",))
    assert res.onelink is None and res.indri is None
    assert tuple(res.rigidbody.fits) == res.plan.multi_joint
    paths = res.write(tmp_path)
    doc = json.loads(paths["fits"].read_text())
    assert doc == json.loads(json.dumps(res.to_dict()))
    assert set(doc["trials"]) == set(res.plan.multi_joint)
    with pytest.raises(InputError, match="--export-c"):
        res.export_c(tmp_path / "c")
    with pytest.raises(InputError, match="--window"):     # refused when the settings are made
        wf.fit_campaign(tx40, models=("cv",), settings=wf.FitSettings(window="soon"))


def test_diagnose_campaign_records_path(tx40):
    d = wf.diagnose_campaign(tx40, joints=[2], settings=DiagnosisSettings(seed=0), progress=False)
    assert isinstance(d, wf.CampaignDiagnosis)
    assert set(d.report["joints"]) == {"2"}
    assert d.report["multi_joint_trials"] == list(d.plan.multi_joint)
    assert set(d.summary()) == {"2"} and d.summary()["2"]["verdict"] == d.report["joints"]["2"]["verdict"]


def test_diagnose_campaign_single_joint_path_torque_only(demo):
    camp = _subset(demo, 3)
    d = wf.diagnose_campaign(camp, markers=False, progress=False)
    assert set(d.report["joints"]) == {str(camp.trials[0].joints[0])}
    assert d.report["link_angles"] is False and "multi_joint_trials" not in d.report


def test_calibrate_and_solve_angles(demo, tmp_path):
    cal = wf.calibrate(demo)
    assert isinstance(cal, wf.CalibrationResult)
    T = np.asarray(cal.T_camera_base)
    assert T.shape == (4, 4) and np.allclose(T[:3, :3] @ T[:3, :3].T, np.eye(3), atol=1e-9)
    from mocap.references import read_calib

    assert np.allclose(read_calib(cal.write(tmp_path)), T)
    trial = demo.trials[0]
    ang = wf.solve_angles(demo, T_camera_base=T, trials=[trial])
    assert isinstance(ang, wf.CampaignAngles) and ang.camera_from == "calib.json"
    t, q = ang.link_angles()[trial.id]
    assert set(q) == set(trial.joints) and len(t) == len(q[trial.joints[0]])
    assert np.isfinite(q[trial.joints[0]]).mean() > 0.9
    assert set(ang.summary()["trials"]) == {trial.id}


def test_the_workflow_examples_run():
    res = doctest.testmod(wf, optionflags=doctest.NORMALIZE_WHITESPACE)
    assert res.attempted >= 3 and res.failed == 0


# --------------------------------------------------------------------------------------------
# a new command is a shell: register + run over the workflow, nothing else
# --------------------------------------------------------------------------------------------
def _plan_command():
    """A command module written the way a new command is: argument parsing, the workflow call,
    the console. It touches no other file than itself."""
    mod = types.ModuleType("plan_command")

    def register(sub):
        p = sub.add_parser("plan", help="which identification paths apply to a campaign")
        p.add_argument("campaign")
        p.add_argument("--models", default=None)
        cli_main.add_common(p, out=False)
        return p

    def run(args):
        camp = load_campaign(args.campaign)
        models = wf.parse_models(args.models) if args.models else None
        p = wf.plan(camp, models)
        print(json.dumps(p.to_dict()) if args.json else p.describe())
        return 0

    mod.register, mod.run = register, run
    return mod


def test_a_new_command_is_a_thin_shell(monkeypatch, capsys, tx40):
    real = cli_main._command_modules
    monkeypatch.setattr(cli_main, "_command_modules", lambda: [*real(), _plan_command()])
    assert cli_main.main(["plan", str(TX40), "--models", "cv", "--json"]) == 0
    assert json.loads(capsys.readouterr().out) == wf.plan(tx40, ("cv",)).to_dict()
    # the workflow's refusals reach the user as one line and exit 2
    assert cli_main.main(["plan", str(TX40), "--models", "cv,nosuchmodel"]) == 2
    assert "nosuchmodel" in capsys.readouterr().err


def test_info_names_the_planned_paths(capsys, tx40):
    assert cli_main.main(["info", str(TX40), "--json"]) == 0
    d = json.loads(capsys.readouterr().out)
    p = wf.plan(tx40)
    assert list(d["paths"]) == list(p.paths) == ["multi_joint"]
    assert d["paths"]["multi_joint"] == p.reasons["multi_joint"]
