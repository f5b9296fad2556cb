"""``jointlab fit --models arctan,dm1,dm2 --export-c``: the Indri & Trapani framework (paper 001)
on a simulated campaign (jointlab synth, withheld effect ``presliding``: LuGre bristles with
sigma0 = c / 2e-3 rad, constant sigma1), checked against the campaign's ground truth.

The joint is flexible at its declared stiffness (drives.toml, PA10 j5: K = 5000 N m/rad) and
the bristles act on the link, behind the spring: the motor encoder sees both in series. The
DM2 (motor velocity) keeps the apparent sigma0; phase 2-A on the link velocity (the motor
encoder's minus the spring's nominal deflection rate, ident.indri.campaign_fit.nominal_link_state)
gives the bristle's own.

Measured (seed 3, declared K): bristle sigma0 1937 vs 1950 (-0.7 %), apparent (motor side)
1543, between the series stiffness 1/(1/1950 + 1/5000) = 1403 and 1950 (the series law
inverted gives 2232: LuGre's local stiffness runs from 2 sigma0 to 0 over a reversal, the law
holds at z = 0 only); static tau_s + tau_sc 3.92 vs c 3.9, tau_v 0.960 vs v + B 0.99 (step 1
without the Stribeck term: the paper's full arctan fit gave tau_v -0.80).
"""
from __future__ import annotations

import ctypes
import dataclasses
import json
import shutil
import subprocess

import numpy as np
import pytest

from ident.excitation.profiles import piecewise_linear_velocity, reversal_knots
from ident.friction import Arctan
from ident.friction.data import FrictionData
from ident.sim.friction import simulate_friction
from ident.cli.main import main
from ident.indri.campaign_fit import fit_campaign_dynamic, split_reversals
from mocap.io.campaign import load_campaign
from mocap.io.errors import InputError

PARAMS = {"arctan": ["tau_s", "tau_sc", "tau_v", "tau_nlv", "delta"],
          "dm1": ["sigma0", "sigma1"], "dm2": ["sigma0", "alpha", "beta", "gamma"],
          "cv": ["c", "v"]}


@pytest.fixture(scope="module")
def camp(tmp_path_factory):
    d = tmp_path_factory.mktemp("dyn")
    c = d / "c"
    assert main(["synth", str(c), "--effect", "presliding", "--seed", "3", "--kinds",
                 "constant_velocity,reversals,excitation", "--reps", "1", "--loads", "0",
                 "--vmax", "0.5,1.0", "--duration", "8", "--quiet"]) == 0
    truth = json.loads((d / "c.truth.json").read_text())
    return c, truth


@pytest.fixture(scope="module")
def fitted(camp, tmp_path_factory):
    c, truth = camp
    d = tmp_path_factory.mktemp("fit")
    out, cdir = d / "out", d / "cexport"
    assert main(["fit", str(c), "--out", str(out), "--models", "cv,arctan,dm1,dm2",
                 "--export-c", str(cdir), "--no-plots"]) == 0
    return out, cdir, json.loads((out / "fits.json").read_text()), truth


def test_fits_json_has_the_three_models_with_format_names(fitted):
    out, _, fits, _ = fitted
    assert fits["format"] == 1
    trials = {tid: e for tid, e in fits["trials"].items() if "5" in e}
    assert len(trials) == 6          # 2 constant-velocity, 2 reversals, 2 excitation trials
    for tid, e in trials.items():
        for m in ("arctan", "dm1", "dm2", "cv"):            # merged with the one-link cv fit
            assert list(e["5"][m]["params"]) == PARAMS[m], (tid, m)
            assert set(e["5"][m]["stderr"]) == set(PARAMS[m])
            assert np.isfinite(e["5"][m]["rms"])
    # the dynamic models predict the reversal trials better than the static model
    rev = fits["trials"]["j5-rev-load0-v50-r1"]["5"]
    assert rev["dm2"]["rms"] < 0.8 * rev["arctan"]["rms"]
    j5 = fits["joints"]["5"]
    assert set(j5["models"]) == {"arctan", "dm1", "dm2"}
    assert len(j5["trials"]["reversals"]) == 2 and len(j5["reversal_datasets"]) >= 6
    assert fits["summary"] and all(r["model"] == "cv" for r in fits["summary"])
    rep = out / "indri" / "joint5"
    for name in ("indri.json", "phase2a.csv", "table1.csv", "table1.md", "indri_fig2.png"):
        assert (rep / name).is_file(), name


def test_parameters_against_the_truth(fitted):
    _, _, fits, truth = fitted
    tj = truth["joints"]["5"]
    s0_true = tj["true_models"]["dm1"]["sigma0"]
    s1_true = tj["true_models"]["dm1"]["sigma1"]
    c, v, B = tj["plant"]["c_pos"], tj["plant"]["v"], tj["B"]
    m = fits["joints"]["5"]["models"]
    # the bristle's own sigma0: phase 2-A (slowest reversal data set) on the link velocity,
    # corrected for the declared spring: measured -0.7 %
    st = m["dm2"]["settings"]
    K = tj["k_nominal"]
    assert tj["k_declared"] and st["stiffness"] == pytest.approx(K)
    assert st["sigma0_bristle"] == pytest.approx(s0_true, rel=0.10) and st["bristle"] == "identified"
    assert st["sigma0_bristle_stderr"] is not None and st["sigma0_bristle_stderr"] > 0
    # the DM2's (motor velocity) is the apparent one: the bristle in series with the spring,
    # stiffer than the series law's 1403 at z = 0 and softer than the bristle (measured 1543)
    s0 = m["dm2"]["params"]["sigma0"]
    assert st["sigma0_apparent"] == s0
    assert 0.95 / (1.0 / s0_true + 1.0 / K) < s0 < 0.95 * s0_true
    # the damping (true: a constant sigma1) stays bounded by the truth's: phase 2-C keeps only
    # what lowers the pooled prediction error
    p = m["dm2"]["params"]
    assert p["beta"] <= 1.5 * s1_true and p["alpha"] >= 0
    # step 1: the Coulomb level at speed and the viscous slope (link friction + motor B)
    a = m["arctan"]["params"]
    assert a["tau_s"] + a["tau_sc"] == pytest.approx(c, rel=0.03)
    assert a["tau_v"] == pytest.approx(v + B, rel=0.05)


def test_dm2_against_the_static_model(fitted):
    """Issue 13: DM2 is never more than 10 % worse than the static arctan model on any trial and
    better on the median one. On this campaign (jointlab's own LuGre plant behind the declared
    5000 N m/rad spring, 200 Hz log, a coarse 1.9e-4 rad encoder) measured: 0.21-0.33 of
    arctan's RMS on the constant-velocity and reversal trials, 0.32 and 0.46 on the two
    excitation trials, median 0.28 (at 3e5 N m/rad: 0.23-0.42, 0.27 and 0.57). Before the fix of
    phase 2-C (its best grid point was solved with the states of another one: alpha = beta = 0)
    the fast excitation trial, whose motor velocity jumps at each reversal faster than the
    200 Hz derivative follows, was at 1.26x: the damping of eq. 24 compensates that lag."""
    _, _, fits, _ = fitted
    ratios = {tid: e["5"]["dm2"]["rms"] / e["5"]["arctan"]["rms"]
              for tid, e in fits["trials"].items() if "5" in e and "dm2" in e["5"]}
    assert len(ratios) == 6
    assert np.median(list(ratios.values())) < 0.5, ratios
    assert all(r < 0.6 for tid, r in ratios.items() if "-cvel-" in tid or "-rev-" in tid), ratios
    assert max(ratios.values()) <= 1.10, ratios
    assert max(ratios.values()) < 0.9, ratios


def test_dm2_without_presliding_is_the_declared_spring(tmp_path):
    """Issue 13, the other side: a jointlab synth campaign with no effect (friction Coulomb +
    viscous, 200 Hz log, coarse encoder, speeds 0.3/0.6/1.0) on the flexible joint at its
    declared stiffness (5000 N m/rad). On the motor velocity the spring's deflection at the
    reversals (2c/K = 0.09 deg) looks like a bristle (phase 2-A: 2.35e4), but one stiffer
    than the spring, which no bristle in series with it can be: phase 2-C's candidate is the
    spring-only model (sigma0 = K, "declared spring"), no bristle is reported behind the
    spring, and DM2 is never worse than arctan (measured 0.55-0.90: the spring's compliance
    seen from the motor is real; before, "identified" with the apparent 2.35e4, 0.67-0.99).
    (At 3e5 N m/rad, before the declared stiffness: phase 2-A ~9e5, whose plain bristle was
    2.33x the static model on the v60 excitation trial.)"""
    c = tmp_path / "c"
    assert main(["synth", str(c), "--effect", "none", "--seed", "3", "--kinds",
                 "constant_velocity,reversals,excitation", "--reps", "1", "--loads", "0",
                 "--vmax", "0.3,0.6,1.0", "--duration", "8", "--quiet"]) == 0
    res = fit_campaign_dynamic(load_campaign(c, check_files=False), joints=[5])
    cmp = res.compare_by_kind(5)
    ratios = {tid: a / b for tid, (a, b) in cmp["all"]["trials"].items()}
    assert len(ratios) == 9
    assert max(ratios.values()) <= 1.0, ratios
    ref = res[5].refinement
    K = res.data[5].stiffness
    assert K == pytest.approx(5000.0)
    assert ref["bristle"] == "declared spring" and "declared spring" in ref["note"]
    assert res[5].sigma0 == K and res[5].sigma0_bristle == np.inf
    assert ref["phase2b"]["sigma0"] > K                  # the apparent bristle (2.35e4)
    dm2 = res.fits_json()["joints"]["5"]["models"]["dm2"]
    assert dm2["stderr"]["sigma0"] is None and dm2["settings"]["bristle"] == "declared spring"
    assert dm2["settings"]["sigma0_bristle"] is None                 # inf: no bristle (JSON null)
    json.dumps(dm2, allow_nan=False)


def _foreign_module():
    """benchmarks/_foreign.py (campaign cache of the independent foreign world) and the world's
    folder (../shared/worlds/foreign beside this checkout or a parent of it), or None."""
    import importlib.util
    import sys
    from pathlib import Path

    here = Path(__file__).resolve()
    world = next((p / "shared" / "worlds" / "foreign" for p in here.parents
                  if (p / "shared" / "worlds" / "foreign" / "make_world.py").is_file()), None)
    if world is None:
        return None, None
    spec = importlib.util.spec_from_file_location("jointlab_bench_foreign",
                                                  here.parents[1] / "benchmarks" / "_foreign.py")
    mod = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = mod
    spec.loader.exec_module(mod)
    return mod, world


@pytest.mark.slow
@pytest.mark.parametrize("effect", ["presliding", "none"])
def test_dm2_on_the_foreign_world(effect, tmp_path_factory):
    """Issue 13 on a campaign jointlab did not write (../shared/worlds/foreign, ind6 joint 3,
    seed 2: Dahl presliding, or no effect; constant-velocity, reversal and excitation trials,
    2 loads x 3 speeds, 500 Hz log): DM2 is never more than 10 % worse than the static arctan
    model and better on the median trial; with presliding sigma0 is within 35 % of the Dahl
    stiffness c/xp of the truth. Measured: presliding median 0.17, max 0.27, sigma0 -17 %;
    none median 0.94, max 0.97. The campaigns are generated once (30-60 s each) into
    $JOINTLAB_CORPUS when set."""
    import os
    from pathlib import Path

    F, world = _foreign_module()
    if F is None:
        pytest.skip("foreign world (shared/worlds/foreign) not found")
    env = os.environ.get("JOINTLAB_CORPUS")
    cache = Path(env) if env else tmp_path_factory.mktemp("foreign-dm2")
    args = F.WorldArgs(effect, 2, reps=1, kinds="excitation,constant_velocity,reversals")
    camp, _ = F.ensure_campaign(args, cache, world=world, nice=0)
    truth = json.loads(camp.with_name(camp.name + ".truth.json").read_text())
    res = fit_campaign_dynamic(load_campaign(camp, check_files=False), joints=[3])
    cmp = res.compare_by_kind(3)
    ratios = {tid: a / b for tid, (a, b) in cmp["all"]["trials"].items()}
    assert len(ratios) == 18
    assert set(cmp) == {"constant_velocity", "reversals", "excitation", "all"}
    assert max(ratios.values()) <= 1.10, ratios
    assert np.median(list(ratios.values())) < 1.0, ratios
    sigma0 = res[3].sigma0
    if effect == "presliding":
        eff = truth["effects"][0]
        assert eff["form"] == "dahl"
        c = truth["joints"][2]["coulomb"]
        xp = eff["per_joint"]["xp"][2]
        assert sigma0 == pytest.approx(c / xp, rel=0.35)
        assert np.median(list(ratios.values())) < 0.4, ratios     # the bristles are captured
    else:
        # no presliding in the plant: a bristle far stiffer than any presliding (steady
        # deflection g/sigma0 below one encoder count), i.e. DM2 near the static model
        g = res[3].static.model.g(np.array([0.0]))[0]
        assert g / sigma0 < truth["joints"][2]["encoder_resolution"]


def _cc():
    for name in ("cc", "gcc", "clang"):
        if shutil.which(name):
            return shutil.which(name)
    return None


def test_exported_c_compiles_and_reproduces_dm2(fitted, camp):
    _, cdir, fits, _ = fitted
    h, c = cdir / "jl_friction.h", cdir / "jl_friction.c"
    assert h.is_file() and c.is_file()
    src = c.read_text()
    for name in ("JL_JOINT5_ARCTAN", "JL_JOINT5_DM1", "JL_JOINT5_DM2", "JL_J5_LOAD0_V100_R1_5_CV"):
        assert name in src
    cc = _cc()
    if cc is None:
        pytest.skip("no C compiler (cc/gcc/clang) found")
    so = cdir / "libjl.so"
    r = subprocess.run([cc, "-O2", "-std=c99", "-Wall", "-Wextra", "-pedantic", "-Werror", "-shared",
                        "-fPIC", "-o", str(so), str(c), "-lm"], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    L = ctypes.CDLL(str(so))
    L.jl_friction_size.restype = ctypes.c_size_t
    L.jl_friction_find.restype = ctypes.c_void_p
    L.jl_friction_find.argtypes = [ctypes.c_char_p]
    L.jl_friction_init.argtypes = [ctypes.c_void_p, ctypes.c_void_p]
    L.jl_friction_run.argtypes = [ctypes.c_void_p, ctypes.c_size_t, ctypes.c_void_p,
                                  ctypes.c_void_p, ctypes.c_void_p]
    p = L.jl_friction_find(b"joint5_dm2")
    assert p
    # the exported DM2 against the Python model on a uniform 5 ms profile
    from ident.friction import Arctan, LuGreDM2

    e = fits["joints"]["5"]["models"]["dm2"]
    st = e["settings"]["static"]["params"]
    model = LuGreDM2(static=Arctan(**st), accel_ratio=e["settings"]["accel_ratio"],
                     accel_floor=e["settings"]["accel_floor"],
                     rest_speed=e["settings"]["rest_speed"], **e["params"])
    assert e["params"]["alpha"] > 0                       # the acceleration term is exercised
    dt = fits["joints"]["5"]["dt"]
    t, qd, qdd = piecewise_linear_velocity(*reversal_knots(5.0, 1.0, 2, 0.2), dt)
    qd, qdd = np.ascontiguousarray(qd), np.ascontiguousarray(qdd)
    buf = ctypes.create_string_buffer(L.jl_friction_size())
    L.jl_friction_init(buf, p)
    out = np.zeros_like(qd)
    L.jl_friction_run(buf, qd.size, qd.ctypes.data, qdd.ctypes.data, out.ctypes.data)
    ref = model.torque(qd, qdd, dt)
    assert np.max(np.abs(out - ref)) < 1e-6


def test_split_reversals_finds_the_reference_accelerations(camp):
    c, truth = camp
    cp = load_campaign(c, check_files=False)
    res = fit_campaign_dynamic(cp, joints=[5], models=("arctan", "dm1", "dm2"))
    got = np.array([d.accel for d in res.data[5].reversals])
    # each trial holds three blocks (factors 1, 2, 4 of its a_min); the 4.92 rad/s^2 level
    # appears in both trials; a block interrupted by a stop may give two data sets
    levels = sorted({round(abs(a), 6) for tid in ("j5-rev-load0-v50-r1", "j5-rev-load0-v100-r1")
                     for a in truth["trials"][tid]["reference"]["acc"] if a})
    assert len(levels) == 5
    near = np.abs(got[:, None] / np.array(levels)[None, :] - 1.0)
    assert np.all(near.min(axis=1) < 0.03), (got, levels)          # every set at a true level
    assert np.all(near.min(axis=0) < 0.03), (got, levels)          # every level found
    for d in res.data[5].reversals:                       # each data set holds reversals
        assert np.any(np.diff(np.sign(d.qd[np.abs(d.qd) > 0.1])) != 0)


def test_split_reversals_without_rests_and_with_dithers():
    """Blocks that follow each other without a rest (the foreign world's reversal trials) and
    small sinusoidal dithers: one data set per block, at the block's acceleration."""
    kt, kv = [0.0, 0.5], [0.0, 1.0]
    for a in (2.0, 8.0):                                  # +-1 rad/s at 2, then 8 rad/s^2
        for target in (-1.0, 1.0, -1.0, 1.0):
            kt += [kt[-1] + abs(target - kv[-1]) / a, kt[-1] + abs(target - kv[-1]) / a + 0.3]
            kv += [target, target]
    kt += [kt[-1] + 0.5, kt[-1] + 1.0]
    kv += [0.0, 0.0]
    dt = 4e-3
    t, qd, qdd = piecewise_linear_velocity(kt, kv, dt)
    td = np.arange(0.0, 3.0, dt)                          # dither: 1 Hz, 0.01 rad amplitude
    w = 2 * np.pi
    t = np.concatenate([t, t[-1] + dt + td])
    qd = np.concatenate([qd, 0.01 * w * np.sin(w * td)])
    qdd = np.concatenate([qdd, 0.01 * w * w * np.cos(w * td)])
    d = FrictionData(t, qd, qdd, np.zeros_like(t), label="x")
    sets = split_reversals(d)
    acc = [s.accel for s in sets]
    assert len(sets) == 3, acc
    np.testing.assert_allclose(acc[:2], [2.0, 8.0], rtol=0.02)
    assert acc[2] == pytest.approx(0.01 * w * w, rel=0.1)


def test_split_reversals_on_an_exact_profile():
    knots_a = reversal_knots(2.0, 1.0, 2, 0.2)
    knots_b = reversal_knots(8.0, 1.0, 2, 0.2)
    # two blocks at 2 and 8 rad/s^2 separated by a 0.5 s rest
    kt = np.concatenate([knots_a[0], knots_a[0][-1] + 0.5 + knots_b[0]])
    kv = np.concatenate([knots_a[1], knots_b[1]])
    d = simulate_friction(Arctan(tau_s=3.0, tau_sc=0.0, tau_v=1.0, tau_nlv=0.0, delta=0.0),
                            (kt, kv), 5e-3, oversample=1, label="x")
    sets = split_reversals(d)
    assert [round(s.accel, 6) for s in sets] == [2.0, 8.0]
    assert sets[0].time[-1] < sets[1].time[0]


def test_missing_kinds_name_what_is_needed(camp):
    c, _ = camp
    cp = load_campaign(c, check_files=False)

    def only(*kinds):
        return dataclasses.replace(cp, trials=tuple(t for t in cp.trials if t.kind in kinds))

    # whatever the trials allow is fitted; the missing data set is named once in the notes
    res = fit_campaign_dynamic(only("constant_velocity", "excitation"))
    assert set(res.joint_entries(5)) == {"arctan"}
    said = [n for n in res.data[5].notes if "not identified" in n]
    assert len(said) == 1 and "dm1, dm2" in said[0] and 'kind = "reversals"' in said[0]
    res = fit_campaign_dynamic(only("constant_velocity", "reversals"))
    assert set(res.joint_entries(5)) == {"arctan", "dm1"}
    said = [n for n in res.data[5].notes if "not identified" in n]
    assert len(said) == 1 and 'kind = "excitation"' in said[0]
    with pytest.raises(InputError, match="constant-velocity moves"):
        fit_campaign_dynamic(only("reversals", "excitation"))
    one = dataclasses.replace(cp, trials=tuple(t for t in cp.trials if t.kind != "reversals"
                                               or t.vmax_frac == 0.5))
    res = fit_campaign_dynamic(one)                        # three levels in the v50 trial: enough
    assert len(res[5].phase2a) == 3
    # arctan alone needs only the constant-velocity trials
    res = fit_campaign_dynamic(only("constant_velocity"), models=("arctan",))
    fj = res.fits_json()
    assert set(fj["trials"]["j5-cvel-load0-v50-r1"]["5"]) == {"arctan"}
    assert fj["joints"]["5"]["models"]["arctan"]["params"]["tau_v"] == pytest.approx(0.99, rel=0.05)


def test_cli_rejects_a_campaign_without_reversals(camp, tmp_path, capsys):
    c, _ = camp
    # a copy of the manifest without the reversals trials, beside the campaign (same files)
    text = (c / "campaign.toml").read_text()
    blocks = text.split("[[trial]]")
    body = blocks[0] + "".join("[[trial]]" + b for b in blocks[1:] if 'kind = "reversals"' not in b)
    for sub in ("robot/", "trials/", "static/", "calib/"):
        body = body.replace(f'"{sub}', f'"{c.name}/{sub}')
    m2 = c.parent / "norev.toml"
    m2.write_text(body)
    assert main(["fit", str(m2), "--out", str(tmp_path / "o"), "--models", "dm2"]) == 2
    err = capsys.readouterr().err
    assert "velocity reversals" in err and 'kind = "reversals"' in err and "settings=" not in err
    assert len(err.strip().splitlines()) == 1


def test_bandwidth_follows_13_hz_reversals_at_200_hz():
    """Issue 13: derivatives that follow fast reversals. A 13 Hz, 100 rad/s^2 reversal motion
    logged at 200 Hz with a quantised encoder (1e-6 rad) and a torque of inertia plus a
    tanh-regularised Coulomb + viscous friction (generator shares no form with the chooser's
    arctan regression): the chosen smoother leaves a residual-torque error near the torque
    noise, where the old fixed 50 ms window left several N m."""
    from ident.indri.campaign_fit import TorqueConsistentBandwidth
    from ident.signals.smoothing import SavGolSmoother

    rng = np.random.default_rng(5)
    dt, J, f = 5e-3, 0.8, 13.0
    t = np.arange(0.0, 4.0, dt)
    w = 2 * np.pi * f
    amp = 100.0 / w ** 2                                   # peak acceleration 100 rad/s^2
    q = amp * np.sin(w * t)
    qd = amp * w * np.cos(w * t)
    qdd_true = -amp * w * w * np.sin(w * t)
    fric = 3.0 * np.tanh(qd / 2e-3) + 0.8 * qd
    noise = 0.05
    tau = J * qdd_true + fric + noise * rng.standard_normal(t.size)
    q_enc = np.round(q / 1e-6) * 1e-6

    def make(sm):
        fit = sm.fit(t, q_enc)
        _, v, a = fit.evaluate(t)
        return FrictionData(t, v, a, tau - J * a, label="fast")

    bw = TorqueConsistentBandwidth()
    d, sm, score, _ = bw.select(make, dt, "reversals")
    inner = (t > 0.2) & (t < t[-1] - 0.2)
    err = np.sqrt(np.mean((d.tau - fric)[inner] ** 2))
    old = make(SavGolSmoother(window_s=0.05))
    err_old = np.sqrt(np.mean((old.tau - fric)[inner] ** 2))
    assert err < 0.005 * J * 100.0, (err, sm.window_s, sm.polyorder)   # 0.5 % of J a_max
    assert err_old > 10 * err
