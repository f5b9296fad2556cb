"""The plausibility layer (ident/friction/plausibility.py): hand-picked parameter sets of every
law, then the real logs (TX40, TIAGo), the synthetic 7-joint arm and the demo through `jointlab
fit`: no physically impossible or undetermined parameter printed or stored without its flag.

The physical rules below are written out here from the laws' definitions (FORMAT.md names), not
taken from the module under test."""
from __future__ import annotations

import contextlib
import io
import json
import re

import numpy as np
import pytest

from ident.cli.main import main
from ident.friction.plausibility import Flag, assess, assess_armature, fmt, meaning_line
from tests_paths import DEMO, REPO

QD = np.linspace(-2.0, 2.0, 2001)            # sampled speeds of the hand-picked cases, rad/s


def kinds(flags):
    return {k: f.kind for k, f in flags.items()}


def test_cv_signs():
    assert assess("cv", {"c": 1.0, "v": 0.5}, qd=QD) == {}
    assert kinds(assess("cv", {"c": -0.3, "v": 0.5}, qd=QD)) == {"c": "impossible"}
    assert kinds(assess("cv", {"c": 0.3, "v": -9.27}, qd=QD))["v"] == "impossible"


def test_stribeck_names_and_ranges():
    ok = {"Fk": 2.0, "Fv": 0.5, "Fs": 0.5, "Vc": 0.1}
    assert assess("stribeck", ok, qd=QD) == {}
    # static level below zero, Coulomb level at speed below zero
    assert kinds(assess("stribeck", dict(ok, Fk=-0.2, Fs=-1.0), qd=QD))["Fk"] == "impossible"
    assert kinds(assess("stribeck", dict(ok, Fs=3.0), qd=QD))["Fs"] == "impossible"
    # Vc beyond the sampled speeds (issue: Vc 3.1 rad/s, Fv 221, Fs 620 on speeds up to ~1 rad/s)
    far = kinds(assess("stribeck", {"Fk": 700.0, "Fv": 221.0, "Fs": 620.0, "Vc": 31.0},
                       qd=np.linspace(-1, 1, 501)))
    assert far["Vc"] == "unidentifiable" and far["Fs"] == "unidentifiable"
    near = kinds(assess("stribeck", {"Fk": 2.0, "Fv": 0.5, "Fs": 0.5, "Vc": 1.5},
                        qd=np.linspace(-1, 1, 501)))
    assert near == {"Vc": "extrapolated"}
    assert "static" in meaning_line("stribeck") and "drop" in meaning_line("stribeck")


def test_hyperbolic_equal_rates_leave_the_hump_undetermined():
    p = {"g1": 3.0e5, "g2": 15.13, "g3": 15.13, "g4": 1.0, "g5": 20.0, "g6": 0.5}
    k = kinds(assess("hyperbolic", p, qd=QD))
    assert {k["g1"], k["g2"], k["g3"]} == {"unidentifiable"}
    k = kinds(assess("hyperbolic", dict(p, g1=0.5, g3=2.0, g4=-6.5e9, g6=2.2e7), qd=QD,
                     tau_scale=5.0))
    assert k["g4"] == "impossible" and k["g6"] == "unidentifiable"


def test_transitions_beyond_the_sampled_speeds():
    slow = np.linspace(-0.5, 0.5, 501)
    p = {"g1": 0.5, "g2": 40.0, "g3": 4.0, "g4": 1.0, "g5": 0.2, "g6": 0.5}
    k = kinds(assess("hyperbolic", p, qd=slow))
    assert k["g4"] == "unidentifiable" and k["g5"] == "unidentifiable"
    assert kinds(assess("hyperbolic", dict(p, g5=2.0), qd=slow))["g5"] == "extrapolated"
    a = {"tau_s": 1.0, "tau_sc": -0.3, "tau_v": 0.5, "tau_nlv": 0.0, "delta": 1.0}
    assert kinds(assess("arctan", a, qd=slow)) == {"delta": "extrapolated"}


def test_arctan_and_lugre_signs():
    base = {"tau_s": 1.0, "tau_sc": -0.3, "tau_v": 0.5, "tau_nlv": 0.0, "delta": 5.0}
    assert assess("arctan", base, qd=QD) == {}
    assert kinds(assess("arctan", dict(base, tau_v=-9.27), qd=QD))["tau_v"] == "impossible"
    assert kinds(assess("dm1", {"sigma0": -1.0, "sigma1": 1.0}))["sigma0"] == "impossible"
    assert kinds(assess("dm1", {"sigma0": 1e4, "sigma1": -3.0}))["sigma1"] == "impossible"
    assert kinds(assess("dm2", {"sigma0": 1e4, "alpha": 1.0, "beta": -2.0, "gamma": 1.0}))["beta"] \
        == "impossible"


def test_standard_error_larger_than_value_is_undetermined():
    k = kinds(assess("cv", {"c": 0.01, "v": 0.5}, qd=QD, stderr={"c": 0.05, "v": 0.01}))
    assert k == {"c": "unidentifiable"}


def test_armature_and_printing():
    assert assess_armature(-0.19).kind == "impossible"
    assert assess_armature(0.1, 0.01) is None and assess_armature(None) is None
    assert fmt(1.234, Flag("unidentifiable", "x")) == "not identifiable"
    assert fmt(-9.27, Flag("impossible", "x")) == "-9.27 [impossible]"
    assert fmt(3.1, Flag("extrapolated", "x")) == "3.1 [outside data]"


# ---- every fit of the real logs and the demo ------------------------------------------------
def _violations(model: str, p: dict) -> set:
    """Parameters that break their law's physics, written out from the definitions."""
    bad = set()
    if model == "cv":
        bad |= {k for k in ("c", "v") if p[k] < 0}
    elif model == "stribeck":
        if p["Fk"] < 0:
            bad.add("Fk")
        if p["Fv"] < 0:
            bad.add("Fv")
        if p["Fk"] - p["Fs"] < 0 and p["Fk"] != 0:
            bad.add("Fs")
    elif model == "hyperbolic":
        bad |= {k for k in ("g4", "g6") if p[k] < 0}
        if abs(p["g2"] - p["g3"]) <= 0.05 * max(abs(p["g2"]), abs(p["g3"])):
            bad |= {"g1", "g2", "g3"}
    elif model == "arctan":
        bad |= {k for k in ("tau_s", "tau_v") if p[k] < 0}
    elif model == "dm1":
        bad |= {k for k, lo in (("sigma0", 0.0), ("sigma1", 0.0)) if p[k] < lo or
                (k == "sigma0" and p[k] == 0)}
    elif model == "dm2":
        bad |= {k for k in ("beta",) if p[k] < 0} | ({"sigma0"} if p["sigma0"] <= 0 else set())
    return bad


def _cli(argv):
    o, e = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(o), contextlib.redirect_stderr(e):
        rc = main(argv)
    assert rc == 0, e.getvalue()
    return o.getvalue()


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """fits.json and the console of `fit` on TX40, TIAGo, the synthetic arm7 and the demo."""
    import test_multijoint as tm

    d = tmp_path_factory.mktemp("plaus")
    tm._write_arm7_campaign(d / "arm7", duration=4.0)
    cases = {"tx40": (REPO / "fixtures" / "real" / "tx40", "cv,stribeck,hyperbolic,arctan"),
             "tiago": (REPO / "fixtures" / "real" / "tiago", "cv,stribeck,hyperbolic,arctan,dm1,dm2"),
             "arm7": (d / "arm7", "cv,stribeck,hyperbolic"),
             "demo": (DEMO, "cv,stribeck,hyperbolic,arctan")}
    out = {}
    for name, (camp, models) in cases.items():
        o = d / f"out-{name}"
        text = _cli(["fit", str(camp), "--out", str(o), "--models", models, "--no-plots"])
        out[name] = (json.loads((o / "fits.json").read_text()), text, o)
    return out


@pytest.mark.parametrize("name", ["tx40", "tiago", "arm7", "demo"])
def test_no_impossible_or_undetermined_parameter_stored_unflagged(runs, name):
    doc, _, _ = runs[name]
    n = 0
    for tid, joints in doc["trials"].items():
        for j, by_model in joints.items():
            for m, e in by_model.items():
                flags = e.get("flags")
                assert flags is not None, (tid, j, m)
                p = {k: v for k, v in e["params"].items() if v is not None}
                for k in _violations(m, p):
                    assert k in flags, (name, tid, j, m, k, p[k])
                for k, se in (e.get("stderr") or {}).items():
                    if se is not None and k in p and se > abs(p[k]):
                        assert k in flags, (name, tid, j, m, k, p[k], se)
                if e.get("armature") is not None and e["armature"] < 0:
                    # impossible when significantly negative, else its sign is undetermined
                    se_arm = e.get("stderr_armature")
                    significant = se_arm is None or -e["armature"] >= 2.0 * se_arm
                    assert flags.get("armature", {}).get("flag") == (
                        "impossible" if significant else "unidentifiable"), (name, tid, j, e["armature"], se_arm)
                n += 1
    assert n > 0


_ENTRY = re.compile(r"^\s+joint (\d+) (\w+): (.*?); offset .*?, armature (.*?); rms")


@pytest.mark.parametrize("name", ["tx40", "tiago", "arm7"])
def test_console_prints_no_flagged_value_bare(runs, name):
    _, text, _ = runs[name]
    seen = 0
    for ln in text.splitlines():
        m = _ENTRY.match(ln)
        if not m:
            continue
        seen += 1
        model, body, arm = m.group(2), m.group(3), m.group(4)
        vals, bare = {}, {}
        for item in body.split(", "):
            k, _, v = item.partition(" ")
            if v == "not identifiable":
                continue
            num = float(v.split(" [")[0])
            vals[k] = num
            bare[k] = "[" not in v
        for k in _violations(model, vals) if set(vals) >= _needed(model) else ():
            assert not bare.get(k, False), ln
        if arm not in ("merged", "not identifiable") and float(arm.split(" [")[0]) < 0:
            assert "[impossible]" in arm, ln
    assert seen > 0


def _needed(model):
    return {"cv": {"c", "v"}, "stribeck": {"Fk", "Fv", "Fs"}, "hyperbolic": {"g2", "g3", "g4", "g6"},
            "arctan": {"tau_s", "tau_v"}, "dm1": {"sigma0", "sigma1"},
            "dm2": {"sigma0", "beta"}}.get(model, set())


def test_demo_tables_print_undetermined_parameters_as_such(runs):
    _, text, out = runs["demo"]
    md = (out / "tables" / "tables.md").read_text()
    doc, _, _ = runs["demo"]
    und = [(tid, m) for tid, joints in doc["trials"].items() for by in joints.values()
           for m, e in by.items() if any(f["flag"] == "unidentifiable" for f in e["flags"].values())]
    if und:
        assert "not identifiable" in text or "flagged" in md
    assert "static (breakaway) level" in md and "drop from the static level" in md


def test_negative_estimate_within_two_standard_errors_is_undetermined_not_impossible():
    """A parameter that must not be negative: significantly negative is impossible; a negative
    estimate within 2 standard errors of zero leaves its sign undetermined."""
    qd = np.linspace(0.001, 1.0, 200)
    assert assess("cv", {"c": -0.5, "v": 1.0}, qd=qd, stderr={"c": 0.01, "v": 0.01})["c"].kind == "impossible"
    f = assess("cv", {"c": -0.01, "v": 1.0}, qd=qd, stderr={"c": 0.0086, "v": 0.01})
    assert f["c"].kind == "unidentifiable" and "sign" in f["c"].reason
    assert "v" not in f                          # no energy flag through an undetermined sign
    assert assess("cv", {"c": -0.01, "v": 1.0}, qd=qd)["c"].kind == "impossible"   # no stderr known
    assert assess_armature(-0.0122, 0.0113).kind == "unidentifiable"
    assert assess_armature(-0.576, 0.103).kind == "impossible"
    assert assess_armature(-0.01).kind == "impossible"
