"""`jointlab diagnose` end to end on campaigns on disk: the bundled demo (Stribeck withheld) and
a small effect-free simulated campaign; FORMAT.md's diagnosis.json keys; outputs never next to
the inputs."""
import json

import pytest

from ident.cli.main import main
from mocap.io.campaign import load_campaign
from tests_paths import DEMO


@pytest.fixture(scope="module")
def demo_report(tmp_path_factory):
    if not (DEMO / "campaign.toml").is_file():
        pytest.skip("demo campaign absent")
    out = tmp_path_factory.mktemp("diag")
    assert main(["diagnose", str(DEMO), "--out", str(out)]) == 0
    return out, json.loads((out / "diagnosis.json").read_text())


def test_demo_verdict_is_the_withheld_effect(demo_report):
    _, rep = demo_report
    truth = json.loads((DEMO.parent / "demo-truth" / "demo.truth.json").read_text())
    j = rep["joints"]["5"]
    assert j["verdict"] == truth["effect"]["name"] == "stribeck"
    row = next(e for e in j["effects"] if e["effect"] == "stribeck")
    assert row["significant"] and row["reduction"] > 0.2


def test_diagnosis_json_has_the_fixed_keys(demo_report):
    out, rep = demo_report
    assert rep["format"] == 1
    j = rep["joints"]["5"]
    for key in ("nominal_model", "heldout_rms_nominal", "localisation", "effects", "verdict"):
        assert key in j
    for e in j["effects"]:
        assert {"effect", "significant"} <= set(e)
    assert {"torque", "transmission"} <= set(j["channels"])
    md = (out / "diagnosis.md").read_text()
    assert f"verdict **{j['verdict']}**" in md and (out / "joint5_localisation.png").is_file()


def test_effect_free_campaign_gives_none(tmp_path):
    camp = tmp_path / "camp"
    assert main(["synth", str(camp), "--effect", "none", "--seed", "7", "--reps", "3", "--duration", "6",
                 "--vmax", "0.5,1.0", "--quiet"]) == 0
    out = tmp_path / "out"
    assert main(["diagnose", str(camp), "--out", str(out), "--json"]) == 0
    rep = json.loads((out / "diagnosis.json").read_text())
    assert rep["joints"]["5"]["verdict"] == "none"
    assert load_campaign(camp)  # the input is untouched and still valid


def test_refuses_output_inside_the_campaign(tmp_path, capsys):
    camp = tmp_path / "camp"
    assert main(["synth", str(camp), "--reps", "2", "--duration", "3", "--vmax", "1.0", "--loads", "0",
                 "--quiet"]) == 0
    assert main(["diagnose", str(camp), "--out", str(camp / "out")]) == 2
    assert "inside the input folder" in capsys.readouterr().err


def test_report_heading_says_unexplained_or_insufficient_data_not_a_bare_none():
    """A joint whose verdict is ``none`` because the gap stays unexplained (or the record cannot
    tell) is headed so in diagnosis.md; a plain ``none`` stays ``none``."""
    from ident.gap.report import markdown

    joints = {"1": {"verdict": "none", "verdict_status": "unexplained", "note": "x"},
              "2": {"verdict": "none", "verdict_status": "insufficient_data", "note": "x"},
              "3": {"verdict": "none", "verdict_status": "none", "note": "x"},
              "4": {"verdict": "stribeck", "verdict_status": "effect", "note": "x"}}
    md = markdown({"campaign": "c", "joints": joints, "link_angles": True}, {})
    assert "## Joint 1: verdict **none (unexplained)**" in md
    assert "## Joint 2: verdict **none (insufficient data)**" in md
    assert "## Joint 3: verdict **none**\n" in md and "## Joint 4: verdict **stribeck**\n" in md


def test_diagnosis_notes_reach_the_study_report(tmp_path):
    """A diagnosis note (a payload declaration the data contradict) is printed in the study
    report beside the verdict table, as in diagnosis.md."""
    from types import SimpleNamespace

    from ident.study.study import report_markdown

    trial = SimpleNamespace(joints=(2,), load_kg=1.0, vmax_frac=1.0, repetition=1)
    camp = SimpleNamespace(name="c", trials=[trial])
    note = "payload_com: the loaded trials' torque contradicts the payload centre of mass at the flange origin"
    diag = {"joints": {"2": {"verdict": "none", "verdict_text": "none: the gap is at the noise floor",
                             "notes": [note], "effects": [], "localisation": []}}}
    md = report_markdown(camp, {}, None, None, None, diag, {}, tmp_path)
    assert f"Note on joint 2: {note}." in md
    diag["joints"]["2"]["notes"] = []
    assert "Note on joint" not in report_markdown(camp, {}, None, None, None, diag, {}, tmp_path)
