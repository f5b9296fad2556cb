"""``jointlab coastdown`` on campaigns: the independent numpy coast-down world
(tests/coastdown_world.py: flexible joint, motor-side friction, encoder quantisation,
controller-rate log) and ``jointlab synth`` coast-down trials, checked against their truth."""
from __future__ import annotations

import json

import numpy as np
import pytest

from coastdown_world import write_campaign
from ident.cli.main import main
from ident.coastdown.angle import coast_angle, coast_speed
from ident.coastdown.campaign_analysis import analyse_campaign
from mocap.io.campaign import load_campaign


def _ml(root):
    rep = analyse_campaign(load_campaign(root))
    assert len(rep.trials) == 1 and rep.trials[0].ml is not None
    return rep.trials[0], rep


def test_coast_angle_integrates_the_coast_speed():
    """The displacement model is the integral of the speed (paper eq. 4) and stops at eq. 3's
    stop time; it stays finite as Kv -> 0 (the pure-Coulomb parabola)."""
    J, Kv, Kc, w = 0.3, 1.7, 4.0, 2.5
    tau = np.linspace(0.0, 0.4, 40001)
    x, ts = coast_angle(tau, J, Kv, Kc, w)
    v = coast_speed(tau, J, Kv, Kc, w)
    np.testing.assert_allclose(np.gradient(x, tau)[1:-1], v[1:-1], atol=2e-4)
    assert ts == pytest.approx(J / Kv * np.log1p(Kv * w / Kc), rel=1e-12)
    assert np.all(v[tau > ts] == 0.0) and x[-1] == pytest.approx(x[np.searchsorted(tau, ts)], abs=1e-9)
    x0, ts0 = coast_angle(np.array([0.05, 1.0]), J, 1e-12, Kc, w)
    assert ts0 == pytest.approx(J * w / Kc, rel=1e-9)
    assert x0[0] == pytest.approx(w * 0.05 - Kc / (2 * J) * 0.05 ** 2, rel=1e-9)
    assert x0[1] == pytest.approx(J * w * w / (2 * Kc), rel=1e-9)


@pytest.mark.parametrize("f_log", [200.0, 1000.0])
def test_stiff_joint_estimates_cover_the_truth(tmp_path, f_log):
    """A stiff joint (the rigid coast-down model holds): over three seeded worlds at a slow and
    a fast log rate, Kc within 2 % and Kv within 10 %, every estimate within 3 of its standard
    errors, and the cut instants within one log interval of the true ones."""
    z = []
    for seed in range(3):
        root = tmp_path / f"w{seed}"
        truth = write_campaign(root, seed, f_log=f_log, stiffness_scale=100.0)
        r, _ = _ml(root)
        ml = r.ml
        assert r.J == pytest.approx(truth["J"], rel=1e-6)
        assert len(ml.coasts) == 6
        t_true = np.array([tc for tc, _ in truth["trials"]["cd-1"]])
        np.testing.assert_allclose([c["t_cut"] for c in ml.coasts], t_true, atol=1.0 / f_log)
        assert abs(ml.Kc / truth["Kc"] - 1) < 0.02, ml.to_dict()
        assert abs(ml.Kv / truth["Kv"] - 1) < 0.10, ml.to_dict()
        assert ml.separable
        z += [(ml.Kc - truth["Kc"]) / ml.stderr["Kc"], (ml.Kv - truth["Kv"]) / ml.stderr["Kv"]]
    assert np.max(np.abs(z)) < 3.0, z


@pytest.mark.parametrize("f_log", [200.0, 500.0])
def test_flexible_joint_deflection_is_modelled(tmp_path, f_log):
    """The world's visibly flexible joint (0.06-0.1 deg at max torque, motor-side friction,
    lightly damped spring): the motor encoder sees the deflection change at the cut and the
    spring's ringing, which bias a rigid fit's Kv by 1-3 % (3-4 of its standard errors at
    500 Hz). With the declared stiffness the fit keeps the flexible transmission, Kc within
    1 %, Kv within 3 %, and both within 2.5 reported standard errors of the truth."""
    z = []
    for seed in (0, 2):
        root = tmp_path / f"f{seed}"
        truth = write_campaign(root, seed, f_log=f_log)
        r = _ml(root)[0]
        ml = r.ml
        assert ml.transmission == "flexible" and r.method == "ml", ml.to_dict()
        assert abs(ml.Kc / truth["Kc"] - 1) < 0.01, ml.to_dict()
        assert abs(ml.Kv / truth["Kv"] - 1) < 0.03, ml.to_dict()
        z += [(ml.Kc - truth["Kc"]) / ml.stderr["Kc"], (ml.Kv - truth["Kv"]) / ml.stderr["Kv"]]
    assert np.max(np.abs(z)) < 2.5, z


@pytest.mark.parametrize("f_log", [200.0, 500.0])
def test_overdamped_flexible_joint(tmp_path, f_log):
    """The world's flexible joint with an overdamped transmission (damping ratio 3 of the
    two-mass mode: the deflection relaxes instead of ringing, motor-side friction): with the
    declared stiffness and the fitted internal damping, Kc within 1 %, Kv within 3 %, both
    within 3 reported standard errors (a rigid fit, which Schwarz's criterion used to keep
    here, has Kv 2-3 % low at 2-4.4 standard errors)."""
    z = []
    for seed in (0, 2):
        root = tmp_path / f"o{seed}"
        truth = write_campaign(root, seed, f_log=f_log, damping_ratio=3.0)
        ml = _ml(root)[0].ml
        assert ml.transmission == "flexible", ml.to_dict()
        assert abs(ml.Kc / truth["Kc"] - 1) < 0.01, ml.to_dict()
        assert abs(ml.Kv / truth["Kv"] - 1) < 0.03, ml.to_dict()
        z += [(ml.Kc - truth["Kc"]) / ml.stderr["Kc"], (ml.Kv - truth["Kv"]) / ml.stderr["Kv"]]
    assert np.max(np.abs(z)) < 3.0, z


def test_cli_writes_format_outputs_and_paper_methods(tmp_path, capsys):
    root = tmp_path / "camp"
    truth = write_campaign(root, 7, f_log=1000.0, stiffness_scale=100.0)
    out = tmp_path / "out"
    assert main(["coastdown", str(root), "--out", str(out), "--json"]) == 0
    d = json.loads((out / "coastdown.json").read_text())
    e = d["trials"]["cd-1"]["1"]
    assert d["format"] == 1 and e["method"] == "ml"
    for k in ("Kc", "Kv", "J", "stderr", "methods"):
        assert k in e
    assert set(e["methods"]) == {"ml", "tdm", "fdm"}
    assert abs(e["Kc"] / truth["Kc"] - 1) < 0.02 and abs(e["J"] / truth["J"] - 1) < 1e-6
    # at 1 kHz the coasts are long enough for the paper's methods: TDM close to the truth
    assert e["methods"]["tdm"]["n_coasts"] == 6
    assert abs(e["methods"]["tdm"]["Kc"] / truth["Kc"] - 1) < 0.05
    assert abs(e["methods"]["tdm"]["Kv"] / truth["Kv"] - 1) < 0.35    # TDM: eq. 4 on noisy interval velocities
    assert e["methods"]["fdm"]["Kc"] is not None
    assert d["joints"]["1"]["Kc"] == pytest.approx(e["Kc"], rel=1e-3)
    md = (out / "coastdown.md").read_text()
    assert "| cd-1 | 1 |" in md and (out / "plots" / "cd-1-j1.png").stat().st_size > 1000
    json.loads(capsys.readouterr().out)


def test_command_runs_the_pipeline_coastdown_stage(tmp_path, monkeypatch, capsys):
    """``jointlab coastdown`` is the pipeline's ``coastdown`` stage run once (issue 44): its
    estimator call, with ``--joints`` and ``--no-plots`` passed through the stage's settings."""
    import ident.pipeline.stages.coastdown as stage

    seen = []
    real = stage.analyse_campaign

    def spy(camp, settings=None, progress=False):
        seen.append((settings.joints, progress))
        return real(camp, settings=settings, progress=progress)

    monkeypatch.setattr(stage, "analyse_campaign", spy)
    root = tmp_path / "camp"
    write_campaign(root, 3, f_log=200.0)
    out = tmp_path / "out"
    assert main(["coastdown", str(root), "--out", str(out), "--joints", "1", "--no-plots", "--json"]) == 0
    assert seen == [((1,), False)]
    d = json.loads((out / "coastdown.json").read_text())
    assert d["settings"]["joints"] == [1] and set(d["joints"]) == {"1"}
    assert not (out / "plots").exists()
    assert json.loads(capsys.readouterr().out)["out"] == str(out)


def test_campaign_without_coastdown_trials_is_one_line_exit_2(tmp_path, capsys):
    root = tmp_path / "camp"
    write_campaign(root, 3, f_log=200.0)
    toml = root / "campaign.toml"
    toml.write_text(toml.read_text().replace('kind = "coastdown"', 'kind = "excitation"'))
    assert main(["coastdown", str(root), "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "coastdown" in err[0] and "campaign.toml" in err[0], err


def _synth(tmp_path, loads, vmax, seed):
    from ident.sim.campaign_synth import CampaignSynth, SynthConfig

    out = tmp_path / "cd"
    cfg = SynthConfig(joints=(5,), loads=loads, vmax=vmax, reps=1, kinds=("coastdown",), seed=seed)
    CampaignSynth(cfg).write(out, progress=False)
    truth = json.loads((tmp_path / "cd.truth.json").read_text())
    kc = truth["joints"]["5"]["plant"]["c_pos"]
    kv = truth["joints"]["5"]["plant"]["v"] + truth["joints"]["5"]["B"]
    return out, truth, kc, kv


def test_synth_coastdown_trial(tmp_path):
    """``jointlab synth`` coast-down trials (PA10 joint 5, link-side friction, gravity
    compensated while coasting, 200 Hz log; the coasts last 2-10 samples): each trial's Kc
    within 5 % and Kv within 3 standard errors or 20 %; the two trials pooled separate Kc
    from Kv."""
    out, truth, kc, kv = _synth(tmp_path, (3.373,), (0.6, 1.0), 4)
    rep = analyse_campaign(load_campaign(out))
    for r in rep.trials:
        assert len(r.ml.coasts) == len(truth["trials"][r.trial]["coastdown_releases"])
        assert abs(r.Kc / kc - 1) < 0.05, r.to_format()
        assert abs(r.Kv - kv) < max(3 * r.stderr["Kv"], 0.2 * kv), r.to_format()
    pooled = rep.joints[5]
    assert pooled.separable and abs(pooled.Kc / kc - 1) < 0.03 and abs(pooled.Kv / kv - 1) < 0.2


def test_synth_short_coasts_use_the_pooled_kv(tmp_path):
    """A 200 Hz trial cut at 25 % of max speed (coasts of 2-4 samples of a joint behind the
    declared 5000 N m/rad spring) cannot separate Kc from Kv alone (its own ML Kc is off by tens
    of percent, with a standard error that says so); it is reported at the joint's pooled Kv,
    and coastdown.json says how (method, trial_only, pooled_kv). What such a record holds: the
    exact two-mass coast leaves residuals at the quantisation level, and Kc with Kv held at the
    truth is still +6 % (seeds 4 and 5): the trial's Kc must be within 3 of its standard errors
    and 10 %, with a standard error under 10 % (issue 18 asks a median error of 5 % over
    trials, which benchmarks/coastdown.py measures); the full-speed trial and the pooled joint
    within 5 %."""
    out, truth, kc, kv = _synth(tmp_path, (0.0,), (0.25, 1.0), 4)
    rep = analyse_campaign(load_campaign(out))
    slow = next(r for r in rep.trials if r.vmax_frac == 0.25)
    assert max(c["samples_coasting"] for c in slow.ml.coasts) <= 4
    assert not slow.ml.separable and slow.method == "ml-pooled-kv"
    assert slow.Kv == rep.joints[5].Kv and rep.joints[5].separable
    assert abs(slow.Kc / kc - 1) < 0.10 and abs(slow.Kc - kc) < 3 * slow.stderr["Kc"], slow.to_format()
    assert slow.stderr["Kc"] < 0.10 * kc, slow.to_format()
    assert abs(rep.joints[5].Kc / kc - 1) < 0.05
    assert slow.stderr["Kc"] >= slow.pooled_kv["stderr_Kc_given_Kv"]
    d = slow.to_format()
    assert d["method"] == "ml-pooled-kv" and d["trial_only"]["Kc"] == slow.ml.Kc
    assert d["pooled_kv"]["n_coasts_pooled"] == len(rep.joints[5].coasts)
    fast = next(r for r in rep.trials if r.vmax_frac == 1.0)
    assert fast.method == "ml" and abs(fast.Kc / kc - 1) < 0.05


def test_study_runs_the_coastdown_stage_and_resumes(tmp_path):
    from ident.study.study import Study, StudySettings

    root = tmp_path / "camp"
    truth = write_campaign(root, 5, f_log=500.0, stiffness_scale=100.0)
    s = StudySettings(mocap=False, diagnose=False, rrd=False, plots=False)
    r = Study(s, progress=False).run(root, tmp_path / "study")
    assert r.stages["coastdown"]["computed"] == 1 and not r.errors
    d = json.loads((tmp_path / "study" / "coastdown" / "coastdown.json").read_text())
    assert abs(d["trials"]["cd-1"]["1"]["Kc"] / truth["Kc"] - 1) < 0.02
    assert "## Coast-down friction (source 000)" in (tmp_path / "study" / "report.md").read_text()
    r = Study(s, progress=False).run(root, tmp_path / "study")
    assert r.stages["coastdown"]["reused"] == 1
