"""Issue 44 item 4: settings own their constraints (a declared table per settings class, checked
at construction, ident.settings), the command line maps its options to settings once, and model
names are checked by the model registry only (ident.friction.registry)."""
from __future__ import annotations

import dataclasses
from pathlib import Path

import pytest

from ident.cli.main import main
from ident.coastdown.campaign_analysis import CoastdownSettings
from ident.friction import registry
from ident.friction.base import CoulombViscous
from ident.gap import DiagnosisSettings
from ident.model.record import RecordSettings
from ident.pipeline.plan import PipelineSettings
from ident.settings import Interval, check_option
from ident.study.study import StudySettings
from ident.workflow import FitSettings
from mocap.io.errors import InputError
from tests_paths import DEMO

# one bad value per declared constraint of every settings class
BAD = {
    StudySettings: dict(models=("cv", "nope"), n_starts=0, seed=-1, sync="later", calib_method="auto",
                        mocap="yes", diagnose=1, plots=None, rrd="no", rrd_trials="some", diagnosis_reps=-1,
                        calib_urdf_tol_mm=float("nan"), calib_trust_urdf="no", calib_deflection=0,
                        sim2real="on"),
    FitSettings: dict(n_starts=1.5, seed=2 ** 63, sync="", derivatives="finite", window="soon",
                      v_zero="1.0"),
    DiagnosisSettings: dict(alpha=0.0, min_explained=1.5, min_reduction=-0.1, min_effect_to_floor=-1.0,
                            min_effect_to_floor_samples=float("inf"), min_effect_to_floor_global="0.1",
                            min_effect_to_floor_transmission=None, max_effects=-1, n_perm=0, n_boot=0,
                            seed=True, nominal="", test="both"),
    PipelineSettings: dict(calib_method="screw", calib_noise_mm=0.0, calib_min_sweep_deg=400.0,
                           calib_cross_check="x", calib_urdf_tol_mm=-1.0, calib_trust_urdf=None,
                           calib_deflection="x", mocap=0, calib_file="", trials=("../escaped",),
                           solver=dict(min_markers=0), models=("cv", "coulomb"), fit=dict(n_starts=2),
                           fit_plan="plan", angles=3, plots="x", diagnose="x", diagnosis={"seed": 0},
                           markers="x", joints=(0,), sim2real="x", sim2real_mjcf=1.0, sim2real_effects=5,
                           sim2real_diagnosis=0, sim2real_sysid="x", sim2real_threads=0),
    RecordSettings: dict(derivatives="fd", window_s=0.0, resample="always", drop_repeated="yes",
                         braked_tol=-1e-3, decimate="often"),
    CoastdownSettings: dict(v_min_frac=1.0, pre_s=0.0, rest_s=-0.05, jump_sigmas=0.0, sep_rel=float("nan"),
                            min_samples=0, joints=(5, 5)),
}

# valid values other than the defaults (text read by the parser, None, a rate, a plain list)
GOOD = {
    StudySettings: dict(models=["cv", "dm1"], diagnosis_reps=0, calib_urdf_tol_mm=1000, seed=2 ** 63 - 1),
    FitSettings: dict(window="0.02", v_zero="0", derivatives="logged", sync="estimate"),
    DiagnosisSettings: dict(nominal=Path("fits.json"), test="samples", max_effects=0, alpha=0.5),
    PipelineSettings: dict(calib_noise_mm=1e3, trials=["j5-r1", 7], joints=[2, 3], models=None,
                           solver=dict(min_markers=1, reject_sigma=0.5, refine=True), sim2real_effects=""),
    RecordSettings: dict(decimate=100, window_s=0.05, resample="never"),
    CoastdownSettings: dict(joints=(1, 5), v_min_frac=0.0, min_samples=1),
}

CLASSES = list(BAD)


@pytest.mark.parametrize("cls", CLASSES, ids=lambda c: c.__name__)
def test_every_field_has_a_constraint_and_the_defaults_pass(cls):
    names = {f.name for f in dataclasses.fields(cls)}
    assert set(cls.constraints) == names           # the table names every field, and only fields
    assert set(BAD[cls]) == names                  # every constraint is exercised below
    default = cls()                                # the defaults and other valid values pass
    assert cls(**GOOD[cls]) != default
    if cls is StudySettings:                       # the old explicit check, kept as a thin alias
        assert default.validate() is default


@pytest.mark.parametrize("cls,field", [(c, f) for c in CLASSES for f in BAD[c]],
                         ids=lambda x: getattr(x, "__name__", x))
def test_each_constraint_refuses_at_construction_naming_the_option(cls, field):
    option = cls.constraints[field][0]
    bad = BAD[cls][field]
    with pytest.raises(InputError) as exc:
        cls(**{field: bad})
    msg = str(exc.value)
    said = "--min-markers" if field == "solver" else option     # a nested option names itself
    assert "\n" not in msg and msg.startswith(said), msg
    assert f"({cls.__name__}.{field})" in msg, msg
    # a copy with one field changed is constructed anew: the same check, no way around it
    with pytest.raises(InputError, match=f"{cls.__name__}.{field}"):
        dataclasses.replace(cls(), **{field: bad})


def test_messages_say_the_range_and_the_value():
    with pytest.raises(InputError, match=r"^--starts must be an integer >= 1, got 0 \(FitSettings.n_starts\)$"):
        FitSettings(n_starts=0)
    with pytest.raises(InputError, match=r"^--v-zero must be 'auto' or a finite number >= 0 and < 1, got '1.0'"):
        FitSettings(v_zero="1.0")
    with pytest.raises(InputError, match=r"^--min-markers must be an integer >= 1, got 0"):
        PipelineSettings(solver=dict(min_markers=0, reject_sigma=5.0))
    with pytest.raises(InputError, match=r"^--models: unknown friction model 'nope' \(known: cv, "):
        StudySettings(models=("nope",))
    assert check_option(None, "--workers", Interval(1, integer=True, none=True)) is None
    with pytest.raises(InputError, match=r"^--workers must be an integer >= 1, got 0$"):
        check_option(0, "--workers", Interval(1, integer=True, none=True))


def test_model_names_come_from_the_registry(monkeypatch):
    """A model added to the registry is valid for every settings class and ``--models`` at once:
    no constraint keeps its own list."""
    for make in (lambda: StudySettings(models=("cv", "toy")), lambda: PipelineSettings(models=("toy",)),
                 lambda: registry.parse_models("cv,toy")):
        with pytest.raises(InputError, match="toy"):
            make()
    monkeypatch.setitem(registry.MODELS, "toy", CoulombViscous)
    assert StudySettings(models=("cv", "toy")).models == ("cv", "toy")
    assert PipelineSettings(models=("toy",)).models == ("toy",)
    assert registry.parse_models("cv,toy") == ("cv", "toy")
    assert "toy" in registry.model_names()


# ---- the command line: a bad option exits 2 with one line naming it, before any work
def _one_error_line(capsys) -> str:
    err = [ln.split("\r")[-1].strip() for ln in capsys.readouterr().err.split("\n")]
    err = [ln for ln in err if ln]
    assert len(err) == 1 and err[0].startswith("jointlab: error: "), err
    return err[0]


@pytest.mark.parametrize("argv,says", [
    (["study", "{c}", "--out", "{o}", "--workers", "0"], "--workers must be an integer >= 1, got 0"),
    (["study", "{c}", "--out", "{o}", "--starts", "0"], "--starts must be an integer >= 1, got 0"),
    (["study", "{c}", "--out", "{o}", "--diagnosis-reps", "-1"], "--diagnosis-reps must be an integer >= 0"),
    (["study", "{c}", "--out", "{o}", "--seed", "-3"], "--seed must be an integer >= 0"),
    (["demo", "--out", "{o}", "--urdf-tol-mm", "inf"], "--urdf-tol-mm must be a finite number >= 0"),
    (["fit", "{c}", "--out", "{o}", "--starts", "0"], "--starts must be an integer >= 1, got 0"),
    (["fit", "{c}", "--out", "{o}", "--v-zero", "1.5"], "--v-zero must be 'auto' or a finite number"),
    (["fit", "{c}", "--out", "{o}", "--window", "soon"], "--window must be 'auto' or a finite number > 0"),
    (["fit", "{c}", "--out", "{o}", "--seed", "-1"], "--seed must be an integer >= 0"),
    (["fit", "{c}", "--out", "{o}", "--export-dt", "0"], "--export-dt must be a finite number > 0"),
    (["sim2real", "{c}", "--out", "{o}", "--threads", "0"], "--threads must be an integer >= 1, got 0"),
    (["coastdown", "{c}", "--out", "{o}", "--joints", "2,2"], "--joints must be distinct joint numbers"),
    (["diagnose", "{c}", "--out", "{o}", "--joints", "0"], "--joints must be distinct joint numbers"),
    (["calib", "{c}", "--out", "{o}", "--urdf-tol-mm", "2000"], "--urdf-tol-mm must be a finite number"),
])
def test_cli_bad_option_is_one_line_and_exit_2(argv, says, tmp_path, capsys):
    out = tmp_path / "o"
    assert main([a.format(c=DEMO, o=out) for a in argv]) == 2
    line = _one_error_line(capsys)
    assert says in line, line
    assert not out.exists()                        # refused before any work
