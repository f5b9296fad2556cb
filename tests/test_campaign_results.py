"""Typed campaign results (issue 44, item 2): the diagnosis of a campaign is a frozen
:class:`ident.gap.campaign_diagnosis.CampaignDiagnosis` of per-joint
:class:`ident.gap.result.JointDiagnosis`, joined by a method, and ``diagnosis.json`` has one
writer (:meth:`CampaignDiagnosis.to_dict`) that ``jointlab diagnose``, the pipeline stage and
``jointlab study`` all call; the study's job results and stage rows are typed, their records
kept in the on-disk layout.

One small synthesised mixed campaign (single-joint trials of joint 5 and one multi-joint record
of joints 2 and 3, as in ``tests/test_pipeline_equality.py``), torque channel only."""
from __future__ import annotations

import ast
import dataclasses
import json
from pathlib import Path

import pytest

from ident.cli.main import main
from ident.common import to_jsonable
from ident.gap import DiagnosisSettings
from ident.gap.campaign_diagnosis import CampaignDiagnosis, diagnose_single_joint_campaign
from ident.gap.result import JointDiagnosis
from ident.model.multijoint import diagnose_records
from ident.study.study import DiagnosisItem, FitItem, StageReport, Study, StudySettings
from ident.workflow import plan
from mocap.io.campaign import load_campaign
from synth_campaigns import mixed_campaign, synth

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def mixed(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("campaign-results")
    single = synth(root, "single", "--vmax", "0.5,1.0")
    multi = synth(root, "multi", "--joints", "2,3", "--together")
    return mixed_campaign(single, multi, root / "mixed")


@pytest.fixture(scope="module")
def command_doc(mixed, tmp_path_factory) -> tuple:
    """``jointlab diagnose --no-markers``: (the file's bytes, its document)."""
    out = tmp_path_factory.mktemp("diagnose") / "d"
    assert main(["diagnose", str(mixed), "--out", str(out), "--no-markers"]) == 0
    raw = (out / "diagnosis.json").read_bytes()
    return raw, json.loads(raw)


@pytest.fixture(scope="module")
def parts(mixed) -> tuple:
    """(campaign, single-joint diagnosis, records' diagnosis) of the mixed campaign."""
    camp = load_campaign(mixed)
    robot = camp.load_robot()
    s = DiagnosisSettings()
    single = diagnose_single_joint_campaign(camp, robot, None, s)
    records = CampaignDiagnosis.from_records(camp.name, s.to_dict(), diagnose_records(camp, robot, s),
                                             plan(camp).multi_joint)
    return camp, single, records


def _written(doc: dict) -> bytes:
    """What the writer (ident.gap.report.write_report) puts in diagnosis.json for ``doc``."""
    return json.dumps(to_jsonable(doc), indent=1).encode("utf-8")


def test_the_command_writes_the_one_writers_document(command_doc, parts):
    raw, doc = command_doc
    camp, single, records = parts
    joined = single.with_records(records)
    # (a) the file is the writer's document of the typed result, byte for byte
    assert raw == _written(joined.to_dict())
    # the layout FORMAT.md and earlier files have: keys and their order
    assert list(doc) == ["format", "campaign", "settings", "joints", "skipped_trials", "link_angles",
                         "nominal", "multi_joint_trials"]
    core = list(single.joints[5].result.to_dict())
    assert list(doc["joints"]["5"]) == core + ["nominal", "note_transmission"]
    assert list(doc["joints"]["5"]["nominal"])[-1] == "joint_model"
    for j in ("2", "3"):
        assert list(doc["joints"][j])[-2:] == ["nominal", "record"]
    # every joint's entry reads back into a JointDiagnosis that writes it again, keys in order
    for j, entry in doc["joints"].items():
        back = JointDiagnosis.from_dict(entry).to_dict()
        assert back == entry and list(back) == list(entry), j
        assert list(back["nominal"]) == list(entry["nominal"]), j
    # the whole document reads back too (the study's reuse of a written diagnosis.json)
    again = CampaignDiagnosis.from_dict(doc).to_dict()
    assert again == doc and list(again) == list(doc)


def test_merging_single_joint_and_record_diagnoses_gives_the_mixed_campaign(parts, command_doc):
    camp, single, records = parts
    p = plan(camp)
    assert list(single.joints) == [5] and single.skipped_trials == p.multi_joint
    assert single.multi_joint_trials is None and single.nominal is not None
    assert list(records.joints) == [2, 3] and records.nominal is None
    joined = single.with_records(records)
    assert list(joined.joints) == [5, 2, 3]
    assert joined.skipped_trials == () and joined.multi_joint_trials == p.multi_joint
    assert joined.nominal == single.nominal and set(joined.series) == {5, 2, 3}
    # a joint diagnosed on both paths keeps the records' entry, at its place
    both = dataclasses.replace(single, joints={**single.joints, 2: single.joints[5]})
    assert list(both.with_records(records).joints) == [5, 2, 3]
    assert both.with_records(records).joints[2] is records.joints[2]
    doc = command_doc[1]
    assert list(doc["joints"]) == ["5", "2", "3"] and doc["multi_joint_trials"] == list(p.multi_joint)
    # the parts are untouched by the join
    assert list(single.joints) == [5] and single.skipped_trials == p.multi_joint


def test_typed_results_cannot_be_edited_in_place(parts):
    _, single, _ = parts
    with pytest.raises(dataclasses.FrozenInstanceError):
        single.joints = {}
    with pytest.raises(TypeError):
        single.joints[7] = single.joints[5]
    with pytest.raises(TypeError):
        del single.joints[5]
    j5 = single.joints[5]
    with pytest.raises(dataclasses.FrozenInstanceError):
        j5.note_transmission = ""
    with pytest.raises(TypeError):
        j5.nominal["label"] = "other"
    with pytest.raises(TypeError):
        j5.joint_model["kind"] = "flexible"
    with pytest.raises(TypeError):
        single.settings["seed"] = 3
    # the writer hands out a new document each time: editing it changes nothing
    doc = single.to_dict()
    doc["joints"]["5"]["verdict"] = "edited"
    doc["skipped_trials"].append("x")
    doc["joints"]["5"]["nominal"]["joint_model"]["kind"] = "edited"
    fresh = single.to_dict()
    assert fresh["joints"]["5"]["verdict"] == j5.verdict != "edited"
    assert "x" not in fresh["skipped_trials"] and fresh["joints"]["5"]["nominal"]["joint_model"]["kind"] != "edited"


def test_the_study_writes_the_commands_diagnosis_json(mixed, command_doc, tmp_path):
    """Through the same writer, the study's diagnosis.json is the command's, every key
    (``nominal`` included) and byte; its stage rows and verdicts are typed."""
    s = StudySettings(models=("cv",), n_starts=2, mocap=False, plots=False, rrd=False)
    res = Study(s, None, progress=False).run(mixed, tmp_path / "study")
    assert not res.errors, res.errors
    assert (tmp_path / "study" / "diagnosis" / "diagnosis.json").read_bytes() == command_doc[0]
    row = res.stages["diagnosis"]
    assert isinstance(row, StageReport) and row.computed == 1 and row["computed"] == 1
    assert res.to_dict()["stages"]["diagnosis"] == row.to_dict()
    assert list(row.to_dict()) == ["computed", "reused", "failed", "seconds", "work_s", "cpu_s", "note"]
    assert res.verdicts == {j: r["verdict"] for j, r in command_doc[1]["joints"].items()}


def test_job_results_keep_the_record_layout():
    """Records older runs wrote (dicts) read back into the typed job results and are written
    again unchanged."""
    fit_rec = {"ok": True, "entries": [], "seconds": 1.5, "cpu_s": 1.25}
    item = FitItem.from_record(fit_rec)
    assert item.ok and item.entries == () and item.to_record() == fit_rec
    entry = {"verdict": "none", "verdict_text": "none: at the noise floor", "notes": ["n"],
             "nominal": {"label": "cv", "joint_model": {"kind": "rigid"}}, "note_transmission": "t"}
    diag_rec = {"ok": True, "report": entry, "series": {"file": "joint5.series.npz", "sha256": "0" * 64,
                                                        "spectrum": None},
                "link_angles": False, "skipped_trials": ["r1"], "seconds": 2.0, "cpu_s": 1.0}
    d = DiagnosisItem.from_record(diag_rec)
    assert d.joint.verdict == "none" and d.joint.notes == ("n",) and d.joint.joint_model["kind"] == "rigid"
    assert d.to_record() == diag_rec
    assert list(d.to_record()["report"]) == list(entry)
    assert FitItem.from_record({"ok": False, "error": "E: x"}).to_record() == {"ok": False, "error": "E: x"}


def _package_sources():
    for pkg in ("ident", "mocap", "calib", "viz"):
        yield from sorted((ROOT / pkg).rglob("*.py"))


def test_the_diagnosis_json_skeleton_is_written_in_one_place():
    """(c) A dict literal with the document's ``format``, ``campaign`` and a key only
    ``diagnosis.json`` has (``skipped_trials``, ``link_angles``, ``multi_joint_trials``) exists
    once, in the writer; no code sets one of those keys by subscript elsewhere."""
    skeletons, edits = [], []
    for path in _package_sources():
        rel = path.relative_to(ROOT).as_posix()
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.Dict):
                keys = {k.value for k in node.keys if isinstance(k, ast.Constant)}
                if {"format", "campaign"} <= keys and keys & {"skipped_trials", "link_angles", "multi_joint_trials"}:
                    skeletons.append(f"{rel}:{node.lineno}")
            if isinstance(node, (ast.Assign, ast.AugAssign)):
                for t in (node.targets if isinstance(node, ast.Assign) else [node.target]):
                    if (isinstance(t, ast.Subscript) and isinstance(t.slice, ast.Constant)
                            and t.slice.value in ("skipped_trials", "multi_joint_trials", "link_angles")):
                        edits.append(f"{rel}:{node.lineno}")
    assert len(skeletons) == 1 and skeletons[0].startswith("ident/gap/campaign_diagnosis.py:"), skeletons
    assert all(e.startswith("ident/gap/campaign_diagnosis.py:") for e in edits), edits
