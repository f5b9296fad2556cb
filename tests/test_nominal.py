"""`jointlab diagnose --nominal` (issue 15, item 6): a registry friction model or a fits.json as
the simulator's nominal, and what the diagnosis then reports.

The campaign is `jointlab synth`'s PA10 with a withheld Stribeck drop on joint 5 (ident.sim's
plant, thesis eq. 2-6 form). A nominal that already contains that friction must no longer report
it, while the Coulomb + viscous nominal does (the control). The Stribeck nominal shares the
plant's equation form by design (that is what "contains the effect" means); the hyperbolic
nominal (tanh hump, thesis eq. 2-7) does not, and must absorb it too. File nominals are written
here from the synth's ground truth, and from the TX40's published parameters
(fixtures/real/tx40/TX40_config.yaml)."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from ident.cli.main import main

TX40 = Path(__file__).resolve().parents[1] / "fixtures" / "real" / "tx40"


@pytest.fixture(scope="module")
def stribeck_campaign(tmp_path_factory):
    root = tmp_path_factory.mktemp("nominal")
    camp = root / "camp"
    assert main(["synth", str(camp), "--effect", "stribeck", "--seed", "7", "--reps", "3",
                 "--duration", "6", "--vmax", "0.5,1.0", "--quiet"]) == 0
    truth = json.loads((root / "camp.truth.json").read_text())["joints"]["5"]["true_models"]
    return root, camp, truth


def _diagnose(root: Path, camp: Path, nominal: str, name: str):
    out = root / name
    assert main(["diagnose", str(camp), "--out", str(out), "--no-markers", "--nominal", nominal]) == 0
    rep = json.loads((out / "diagnosis.json").read_text())
    return rep, rep["joints"]["5"], (out / "diagnosis.md").read_text()


def _row(j, effect):
    return next(e for e in j["effects"] if e["effect"] == effect)


def test_registry_nominal_absorbs_the_effect_it_contains(stribeck_campaign, capsys):
    root, camp, truth = stribeck_campaign
    _, cv, _ = _diagnose(root, camp, "cv", "cv")
    assert cv["verdict"] == "stribeck" and _row(cv, "stribeck")["significant"]   # the control
    rep, st, md = _diagnose(root, camp, "stribeck", "stribeck")
    assert st["verdict"] != "stribeck" and not _row(st, "stribeck")["significant"]
    assert st["heldout_rms_nominal"] < 0.6 * cv["heldout_rms_nominal"]
    assert st["nominal_model"] == "stribeck" and rep["nominal"]["kind"] == "registry"
    vc = st["nominal"]["joint_parameters"]["shape_fitted"]["Vc"]
    assert vc == pytest.approx(truth["stribeck"]["Vc"], rel=0.25)           # the plant's 0.05 rad/s
    assert "shape fitted Vc" in md and "`stribeck` friction of the registry" in md
    _, hy, _ = _diagnose(root, camp, "hyperbolic", "hyperbolic")             # another form
    assert not _row(hy, "stribeck")["significant"]
    assert hy["heldout_rms_nominal"] < 0.6 * cv["heldout_rms_nominal"]
    # a shape held at a wrong value leaves part of the drop for the diagnosis to find
    _, held, _ = _diagnose(root, camp, "stribeck:Vc=0.01", "held")
    assert held["nominal"]["joint_parameters"]["held"] == {"Vc": 0.01}
    assert held["heldout_rms_nominal"] > 1.2 * st["heldout_rms_nominal"]
    capsys.readouterr()


def test_fits_json_nominal_is_fixed_and_reported(stribeck_campaign, capsys):
    root, camp, truth = stribeck_campaign
    fits = root / "published_fits.json"
    other = {"c": 1.0, "v": 1.0}
    fits.write_text(json.dumps({"format": 1, "trials": {
        "published": {"5": {"cv": {"params": truth["cv"]}, "stribeck": {"params": truth["stribeck"]}},
                      "3": {"cv": {"params": other}}}}, "summary": []}))
    rep, st, md = _diagnose(root, camp, f"{fits}:stribeck", "file_stribeck")
    assert st["verdict"] != "stribeck" and not _row(st, "stribeck")["significant"]
    jp = st["nominal"]["joint_parameters"]
    assert jp["fixed_parameters"] == pytest.approx(truth["stribeck"])
    assert jp["from"] == ["trials.published.5.stribeck"]
    assert rep["nominal"]["kind"] == "file" and rep["nominal"]["file"] == str(fits)
    assert str(fits) in md and "nothing of it refitted" in md
    _, cv, _ = _diagnose(root, camp, f"{fits}:cv", "file_cv")
    assert cv["verdict"] == "stribeck" and _row(cv, "stribeck")["significant"]
    # the friction is held, not refitted: a Coulomb level off by its own size stays in the gap
    bad = root / "wrong_fits.json"
    bad.write_text(json.dumps({"format": 1, "trials": {"p": {"5": {"cv": {"params": {
        "c": 2 * truth["cv"]["c"], "v": truth["cv"]["v"]}}}}}}))
    _, wrong, _ = _diagnose(root, camp, str(bad), "file_wrong")
    assert wrong["heldout_rms_nominal"] > 0.5 * truth["cv"]["c"] > 3 * cv["heldout_rms_nominal"]
    capsys.readouterr()


BAD_FILES = {
    "missing_joint": ({"format": 1, "trials": {"p": {"3": {"cv": {"params": {"c": 1, "v": 1}}}}}},
                      "no 'cv' entry for joint 5"),
    "unknown_model": ({"format": 1, "trials": {"p": {"5": {"coulomb": {"params": {"c": 1}}}}}},
                      "unknown friction model 'coulomb'"),
    "negative": ({"format": 1, "trials": {"p": {"5": {"cv": {"params": {"c": -1.0, "v": 1}}}}}},
                 "trials.p.5.cv.params"),
    "missing_param": ({"format": 1, "trials": {"p": {"5": {"cv": {"params": {"c": 1.0}}}}}},
                      "missing ['v']"),
    "text_value": ({"format": 1, "trials": {"p": {"5": {"cv": {"params": {"c": "1", "v": 1}}}}}},
                   "trials.p.5.cv.params.c"),
    "two_models": ({"format": 1, "trials": {"p": {"5": {"cv": {"params": {"c": 1, "v": 1}},
                                                        "stribeck": {"params": {"Fk": 1, "Fv": 1, "Fs": 0.1,
                                                                                "Vc": 0.1}}}}}},
                   "choose one"),
    "not_json": ("{\"format\": 1,", "not JSON"),
}


@pytest.mark.parametrize("case", sorted(BAD_FILES))
def test_bad_fits_json_is_a_one_line_error(stribeck_campaign, capsys, case):
    root, camp, _ = stribeck_campaign
    doc, needle = BAD_FILES[case]
    f = root / f"bad_{case}.json"
    f.write_text(doc if isinstance(doc, str) else json.dumps(doc))
    assert main(["diagnose", str(camp), "--out", str(root / f"o_{case}"), "--nominal", str(f)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and str(f) in err and needle in err, err
    assert not (root / f"o_{case}").exists()                 # refused before any work


@pytest.mark.parametrize("spec,needle", [("coulomb", "neither a friction model"),
                                         ("stribeck:Fk=1", "amplitude"),
                                         ("stribeck:Vc=fast", "must be a number"),
                                         ("hyperbolic:g7=1", "shape parameters"),
                                         ("missing_fits.json", "not found")])
def test_bad_nominal_spec_is_a_one_line_error(stribeck_campaign, capsys, spec, needle):
    root, camp, _ = stribeck_campaign
    assert main(["diagnose", str(camp), "--out", str(root / "o_spec"), "--nominal", spec]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and needle in err, err


def test_tx40_published_model_as_nominal(tmp_path, capsys):
    """The TX40's published friction (TX40_config.yaml: fs, fv per joint) as a fits.json nominal
    on its multi-joint record. The published joint-6 Coulomb level (0.282 N m) leaves out the
    coupled wrist motor's own friction (fsm6 = 1.95 N m, on the motor velocity qd5 + qd6),
    which a Coulomb + viscous nominal fitted on the joint absorbs: with the published model fixed,
    joint 6's held-out gap must be clearly larger."""
    from ident.thesis.campaign_fit import read_tx40_config

    if not (TX40 / "trials" / "excitation.csv").is_file():
        pytest.skip("TX40 fixture absent")
    cfg = read_tx40_config(TX40 / "TX40_config.yaml")
    fits = tmp_path / "tx40_published.json"
    fits.write_text(json.dumps({"format": 1, "trials": {"TX40_config.yaml": {
        str(j + 1): {"cv": {"params": {"c": cfg["fs"][j], "v": cfg["fv"][j]}}} for j in range(6)}}}))
    held = {}
    for nom in ("cv", str(fits)):
        out = tmp_path / ("o_" + Path(nom).stem)
        assert main(["diagnose", str(TX40), "--out", str(out), "--joints", "6", "--nominal", nom]) == 0
        held[nom] = json.loads((out / "diagnosis.json").read_text())["joints"]["6"]
    pub = held[str(fits)]
    assert pub["nominal"]["joint_parameters"]["fixed_parameters"] == pytest.approx(
        {"c": cfg["fs"][5], "v": cfg["fv"][5]})
    assert pub["nominal"]["kind"] == "file" and pub["record"]["trial"] == "excitation"
    assert pub["heldout_rms_nominal"] > 1.15 * held["cv"]["heldout_rms_nominal"]
    assert np.isfinite(pub["heldout_rms_nominal"])
    capsys.readouterr()


def test_fits_json_with_several_trials_takes_the_median_of_the_physical_entries(tmp_path):
    """A `jointlab fit` file has one entry per trial: the nominal takes each parameter's median
    over the entries with physical values and names the ones left out; none physical is an
    error naming the first."""
    from mocap.io.errors import InputError

    from ident.gap.nominal import FitsNominal

    cs, vs = [3.7, 4.1, 3.9, 12.0], [0.80, 0.86, 0.84, 0.5]
    trials = {f"t{k}": {"5": {"cv": {"params": {"c": c, "v": v}}}} for k, (c, v) in enumerate(zip(cs, vs))}
    trials["t9"] = {"5": {"cv": {"params": {"c": -2.0, "v": 0.9}}}}          # impossible
    trials["t8"] = {"5": {"cv": {"params": {"c": 50.0, "v": 0.9}, "valid": False}}}
    f = tmp_path / "fits.json"
    f.write_text(json.dumps({"format": 1, "trials": trials}))
    nom = FitsNominal(f)
    assert nom.models["5"].params == pytest.approx({"c": np.median(cs), "v": np.median(vs)})
    assert set(nom.left_out["5"]) == {"trials.t9.5.cv", "trials.t8.5.cv"}
    f.write_text(json.dumps({"format": 1, "trials": {k: trials[k] for k in ("t9",)} | {
        "t7": {"5": {"cv": {"params": {"c": 1.0, "v": -0.3}}}}}}))
    with pytest.raises(InputError, match=r"trials\.t9\.5\.cv\.params"):
        FitsNominal(f)


@pytest.mark.parametrize("model", ["arctan", "dm1"])
def test_other_registry_nominals_run_and_absorb_the_drop(stribeck_campaign, capsys, model):
    """Indri & Trapani's static arctan model and the dynamic LuGre DM1 (bristle state through the
    joint's sample times) as nominals: both contain a velocity-weakening static curve."""
    root, camp, _ = stribeck_campaign
    rep, j, md = _diagnose(root, camp, model, model)
    assert not _row(j, "stribeck")["significant"] and j["nominal_model"] == model
    jp = j["nominal"]["joint_parameters"]
    assert set(jp["shape_fitted"]) == ({"delta"} if model == "arctan" else {"sigma0"})
    assert (model == "dm1") == ("static_arctan" in jp)
    capsys.readouterr()


def test_multijoint_fit_output_as_nominal(tmp_path, capsys):
    """`jointlab fit` on a 7-joint record, its fits.json as the nominal of `diagnose` on the same
    record: the friction fixed to the fitted Coulomb + viscous values (true c, v of the record
    within 10 %) must give the held-out RMS of the free Coulomb + viscous nominal within 5 %,
    and the record's torque noise level (no effect in the data) within 10 %."""
    import test_multijoint as tm

    tm._write_arm7_campaign(tmp_path / "c", duration=6.0)
    assert main(["fit", str(tmp_path / "c"), "--out", str(tmp_path / "f"), "--models", "cv"]) == 0
    fits = tmp_path / "f" / "fits.json"
    held = {}
    for nom in ("cv", str(fits)):
        out = tmp_path / ("d_" + Path(nom).stem)
        assert main(["diagnose", str(tmp_path / "c"), "--out", str(out), "--joints", "2,3",
                     "--nominal", nom]) == 0
        held[nom] = json.loads((out / "diagnosis.json").read_text())["joints"]
    for j in ("2", "3"):
        fixed = held[str(fits)][j]
        jp = fixed["nominal"]["joint_parameters"]
        assert jp["from"] == [f"trials.rec.{j}.cv"]
        assert jp["fixed_parameters"]["c"] == pytest.approx(tm.C_TRUE[int(j) - 1], rel=0.10)
        ratio = fixed["heldout_rms_nominal"] / held["cv"][j]["heldout_rms_nominal"]
        assert abs(ratio - 1) < 0.05, ratio
        assert fixed["heldout_rms_nominal"] == pytest.approx(tm.NOISE[int(j) - 1], rel=0.10)
    capsys.readouterr()
