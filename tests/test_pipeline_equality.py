"""One pipeline: ``jointlab study`` computes what the commands compute (issue 44).

On four small synthesised campaigns (single-joint trials; Indri & Trapani kinds with the
dynamic models; one multi-joint record; both kinds of trials in one manifest) the study's
``fits.json``/``rigidbody/fits.json`` and ``diagnosis.json`` hold the numbers the plain runner
writes (:func:`ident.pipeline.stage.run_stages` over the ``fits``, ``rigidbody`` and
``diagnosis`` stages of :func:`ident.pipeline.plan.plan`, what ``jointlab fit`` and ``jointlab
diagnose`` run) on the same inputs: the study's link angles where it solved them, the motor
angles where it did not."""
from __future__ import annotations

import json
import math
from pathlib import Path

import pytest

from ident.cli.main import main
from ident.pipeline.plan import PipelineSettings, stage_named
from ident.pipeline.plan import plan as stage_list
from ident.pipeline.stage import Context, Runtime, run_stages
from ident.study.executor import SerialExecutor
from ident.study.study import Study, StudySettings
from ident.workflow import FitSettings, plan
from mocap.io.campaign import load_campaign
from mocap.io.errors import InputError
from synth_campaigns import mixed_campaign, synth

N_STARTS = 2


@pytest.fixture(scope="module")
def campaigns(tmp_path_factory):
    root = tmp_path_factory.mktemp("equality")
    single = synth(root, "single", "--vmax", "0.5,1.0")
    indri = synth(root, "indri", "--kinds", "excitation,reversals,constant_velocity")
    multi = synth(root, "multi", "--joints", "2,3", "--together")
    # mixed: the multi-joint record's manifest with the single-joint trials appended
    mixed = mixed_campaign(single, multi, root / "mixed")
    return {"single": single, "indri": indri, "multi": multi, "mixed": mixed}


def _study(campaign: Path, out: Path, models, mocap: bool):
    s = StudySettings(models=models, n_starts=N_STARTS, mocap=mocap, plots=False, rrd=False)
    res = Study(s, SerialExecutor(progress=False), progress=False).run(campaign, out)
    assert not res.errors, res.errors
    return res


def _plain(camp, folder: Path, stage: str, **settings) -> dict:
    """The document the plain runner writes for ``stage`` (``fits.json`` or ``diagnosis.json``):
    the command's stage of the one list, run once into ``folder``."""
    s = PipelineSettings(fit=FitSettings(n_starts=N_STARTS), plots=False, **settings)
    folder.mkdir(parents=True)
    done = run_stages(stage_named(stage_list(camp, s), stage), Context(camp, s, folder), Runtime())
    assert done.stages[stage].status == "ran", done.stages[stage]
    return _read(folder / ("diagnosis.json" if stage == "diagnosis" else "fits.json"))


def _same(a, b, where=""):
    """Equal JSON documents, floats within a relative 1e-9."""
    if isinstance(a, dict):
        assert isinstance(b, dict) and a.keys() == b.keys(), (where, sorted(a), sorted(b))
        for k in a:
            _same(a[k], b[k], f"{where}/{k}")
    elif isinstance(a, list):
        assert isinstance(b, list) and len(a) == len(b), where
        for i, (x, y) in enumerate(zip(a, b)):
            _same(x, y, f"{where}[{i}]")
    elif isinstance(a, float) and not isinstance(a, bool):
        assert isinstance(b, (int, float)), where
        assert (math.isnan(a) and math.isnan(b)) or b == pytest.approx(a, rel=1e-9, abs=1e-12), where
    else:
        assert a == b, where


def _read(path: Path):
    return json.loads(path.read_text(encoding="utf-8"))


def _jsonish(doc):
    """A document as it reads back from its JSON file."""
    return json.loads(json.dumps(doc, default=float))


def _same_diagnosis(study_doc: dict, cmd_doc: dict) -> None:
    cmd_doc = _jsonish(cmd_doc)
    assert study_doc["joints"], "nothing diagnosed"
    for key in ("joints", "skipped_trials", "multi_joint_trials", "link_angles", "settings"):
        assert (key in study_doc) == (key in cmd_doc), key
        if key in study_doc:
            _same(study_doc[key], cmd_doc[key], key)


def test_single_joint_study_equals_fit_and_diagnose(campaigns, tmp_path):
    out = tmp_path / "study"
    _study(campaigns["single"], out, ("cv", "stribeck"), mocap=True)
    camp = load_campaign(campaigns["single"])
    fits = _plain(camp, tmp_path / "fit", "fits", models=("cv", "stribeck"), angles=out / "angles")
    _same(_read(out / "fits" / "fits.json"), fits)
    diag = _plain(camp, tmp_path / "diag", "diagnosis", angles=out / "angles")
    study_diag = _read(out / "diagnosis" / "diagnosis.json")
    assert study_diag["link_angles"] is True
    _same_diagnosis(study_diag, diag)


def test_study_runs_the_indri_models_like_fit(campaigns, tmp_path):
    models = ("cv", "arctan", "dm1")
    camp = load_campaign(campaigns["indri"])
    assert dict(plan(camp, models).models) == {"single_joint": ("cv",), "indri": ("arctan", "dm1")}
    out = tmp_path / "study"
    _study(campaigns["indri"], out, models, mocap=True)
    fits = _plain(camp, tmp_path / "fit", "fits", models=models, angles=out / "angles")
    doc = _read(out / "fits" / "fits.json")
    assert set(doc["joints"]["5"]["models"]) == {"arctan", "dm1"}
    _same(doc, fits)
    _same_diagnosis(_read(out / "diagnosis" / "diagnosis.json"),
                    _plain(camp, tmp_path / "diag", "diagnosis", angles=out / "angles"))


def test_multi_joint_study_equals_fit_and_diagnose(campaigns, tmp_path):
    out = tmp_path / "study"
    _study(campaigns["multi"], out, ("cv",), mocap=False)
    camp = load_campaign(campaigns["multi"])
    _same(_read(out / "rigidbody" / "fits.json"), _plain(camp, tmp_path / "fit", "rigidbody", models=("cv",)))
    _same_diagnosis(_read(out / "diagnosis" / "diagnosis.json"),
                    _plain(camp, tmp_path / "diag", "diagnosis", markers=False))


def test_mixed_campaign_study_fits_both_parts_and_diagnoses_both(campaigns, tmp_path):
    camp = load_campaign(campaigns["mixed"])
    p = plan(camp)
    assert p.mixed
    out = tmp_path / "study"
    _study(campaigns["mixed"], out, ("cv",), mocap=False)
    # the fits of the two manifests jointlab fit asks for: the list's fits and rigidbody stages
    _same(_read(out / "fits" / "fits.json"), _plain(camp, tmp_path / "fit", "fits", models=("cv",)))
    _same(_read(out / "rigidbody" / "fits.json"), _plain(camp, tmp_path / "rb", "rigidbody", models=("cv",)))
    # one diagnosis of both, as jointlab diagnose writes it
    study_diag = _read(out / "diagnosis" / "diagnosis.json")
    assert set(study_diag["joints"]) == {"2", "3", "5"}
    assert study_diag["multi_joint_trials"] == list(p.multi_joint)
    _same_diagnosis(study_diag, _plain(camp, tmp_path / "diag", "diagnosis", markers=False))


def test_the_study_routes_models_through_the_plan(campaigns, tmp_path):
    # a dynamic model whose data sets are missing is left out, as by jointlab fit; the one-link
    # fits go on (the study builds no dm1 task)
    out = tmp_path / "study"
    _study(campaigns["single"], out, ("cv", "dm1"), mocap=False)
    doc = _read(out / "fits" / "fits.json")
    assert {m for t in doc["trials"].values() for j in t.values() for m in j} == {"cv"}
    # nothing left to fit: refused before any output, like jointlab fit
    with pytest.raises(InputError, match="dm1 not identified"):
        _study(campaigns["single"], tmp_path / "refused", ("dm1",), mocap=False)
    assert not (tmp_path / "refused").exists()
    with pytest.raises(InputError, match="unknown"):
        StudySettings(models=("cv", "nope")).validate()


def test_cli_study_parses_models_like_fit(campaigns, tmp_path, capsys):
    # parse_models (duplicates dropped), then the plan's routing: dm1 is left out, cv fitted
    out = tmp_path / "s"
    rc = main(["study", str(campaigns["single"]), "--out", str(out), "--models", "cv, dm1,cv",
               "--no-mocap", "--no-diagnosis", "--no-rrd", "--no-plots", "--workers", "1", "--quiet",
               "--starts", "1"])
    assert rc == 0, capsys.readouterr()
    assert json.loads((out / ".jointlab-study.json").read_text())["settings"]["models"] == ["cv", "dm1"]
    rc = main(["study", str(campaigns["single"]), "--out", str(tmp_path / "t"), "--models", "cv,,nope",
               "--no-mocap", "--no-diagnosis", "--no-rrd", "--no-plots", "--workers", "1", "--quiet"])
    assert rc == 2
    assert "nope" in capsys.readouterr().err
