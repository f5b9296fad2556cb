"""Issue 45, silently wrong fits: input mistakes that once gave an impossible or implausible
friction fit with exit 0 and no word. Each case mutates one trial of a copy of the demo campaign
(a one-trial campaign, ``jointlab fit --models cv``) and must end in ONE warning naming the
likely input mistake, the failed checks in ``fits.json``; an empty torque cell (legal by
FORMAT.md) must leave the fit where it is. The mutations are written here from FORMAT.md, not
from the checks (ident.friction.plausibility.input_checks)."""
from __future__ import annotations

import json
import re
import shutil

import numpy as np
import pytest

from ident.cli.main import main
from ident.friction.plausibility import input_checks, input_warning
from test_bad_inputs import _error_lines
from tests_paths import DEMO

TRIAL = "j5-load0-v50-r1"


def _one_trial(tmp_path):
    """A copy of the demo whose manifest keeps only the first trial."""
    root = tmp_path / "camp"
    shutil.copytree(DEMO, root)
    text = (root / "campaign.toml").read_text()
    head, *trials = text.split("[[trial]]")
    keep = [t for t in trials if f'id = "{TRIAL}"' in t]
    (root / "campaign.toml").write_text("[[trial]]".join([head] + keep))
    return root


def _map_tau5(root, fn):
    p = root / "trials" / f"{TRIAL}.csv"
    lines = [ln for ln in p.read_text().split("\n") if ln]
    head = lines[0].split(",")
    k = head.index("tau_5")
    rows = [ln.split(",") for ln in lines[1:]]
    x = np.array([float(r[k]) for r in rows])
    y = fn(x)
    for r, v in zip(rows, y):
        r[k] = "" if np.isnan(v) else repr(float(v))
    p.write_text("\n".join([lines[0]] + [",".join(r) for r in rows]) + "\n")


def _shift(seconds):
    n = int(round(seconds / 0.005))           # the demo logs at 200 Hz
    if n > 0:
        return lambda x: np.concatenate([np.full(n, x[0]), x[:-n]])
    return lambda x: np.concatenate([x[-n:], np.full(-n, x[-1])])


def _swap_drive_values(root, a=1, b=5):
    """drives.toml tables of joints a and b with their values swapped (names kept: the tables
    pass the order check by name)."""
    p = root / "robot" / "drives.toml"
    head, *tabs = p.read_text().split("[[joint]]")
    name = [re.search(r"^name = .*$", t, flags=re.M).group(0) for t in tabs]
    ta, tb = tabs[a - 1], tabs[b - 1]
    tabs[a - 1] = tb.replace(name[b - 1], name[a - 1])
    tabs[b - 1] = ta.replace(name[a - 1], name[b - 1])
    p.write_text("[[joint]]".join([head] + tabs))


def _fit(root, tmp_path, capsys, out="fit"):
    rc = main(["fit", str(root), "--out", str(tmp_path / out), "--models", "cv"])
    cap = capsys.readouterr()
    assert rc == 0, cap.err
    warn = [ln for ln in _error_lines(cap.err) if "physically implausible" in ln]
    cv = json.loads((tmp_path / out / "fits.json").read_text())["trials"][TRIAL]["5"]["cv"]
    return cv, warn, cap.out


@pytest.mark.parametrize("case,mutate,says", [
    ("sign", lambda r: _map_tau5(r, lambda x: -x), "the sign of tau_5"),
    ("scale_0.001", lambda r: _map_tau5(r, lambda x: 1e-3 * x), "the units or scale of tau_5"),
    ("scale_2", lambda r: _map_tau5(r, lambda x: 2.0 * x), "the units or scale of tau_5"),
    ("drives_1_5", _swap_drive_values, "the order of the drives.toml tables"),
    ("torque_late_0.4s", lambda r: _map_tau5(r, _shift(0.4)), "a clock offset"),
    ("torque_early_0.3s", lambda r: _map_tau5(r, _shift(-0.3)), "a clock offset"),
])
def test_input_mistake_gives_one_warning_naming_it_first(tmp_path, capsys, case, mutate, says):
    root = _one_trial(tmp_path)
    mutate(root)
    cv, warn, out = _fit(root, tmp_path, capsys)
    assert len(warn) == 1, warn
    check = warn[0].split("; check ", 1)[1]
    assert check.startswith(says), warn[0]            # the most likely mistake named first
    assert cv.get("input_checks"), cv                 # and the failed checks in fits.json
    assert "input check:" in out                      # and on the console beside the fit
    assert "Input checks failed" in (tmp_path / "fit" / "tables" / "tables.md").read_text()   # and the tables


def test_clean_trial_has_no_input_warning(tmp_path, capsys):
    cv, warn, _ = _fit(_one_trial(tmp_path), tmp_path, capsys)
    assert warn == [] and "input_checks" not in cv


def test_one_empty_torque_cell_leaves_the_fit_where_it_is(tmp_path, capsys):
    """FORMAT.md: a missing sample is an empty cell. It leaves the fit; it does not re-shape the
    derivative windows of the whole trial (it moved the viscous estimate by 22-42 %)."""
    root = _one_trial(tmp_path)
    ref, _, _ = _fit(root, tmp_path, capsys, out="ref")

    def empty(x):
        y = x.copy()
        y[100] = np.nan
        return y

    _map_tau5(root, empty)
    cv, warn, out = _fit(root, tmp_path, capsys)
    for k in ("c", "v"):
        assert cv["params"][k] == pytest.approx(ref["params"][k], abs=0.2 * ref["stderr"][k]), (k, cv, ref)
    assert warn == [] and "1 empty tau_5 cell(s)" in out


# ---- the checks on their own: a one-link joint written out from eq. 2-4 ----------------------
def _joint(seed=0, n=2000, dt=0.005):
    rng = np.random.default_rng(seed)
    t = np.arange(n) * dt
    w = 2 * np.pi * 0.4
    q = 0.6 + 0.5 * np.sin(w * t) + 0.2 * np.sin(2.3 * w * t)
    qd = 0.5 * w * np.cos(w * t) + 0.2 * 2.3 * w * np.cos(2.3 * w * t)
    qdd = -0.5 * w * w * np.sin(w * t) - 0.2 * (2.3 * w) ** 2 * np.sin(2.3 * w * t)
    I, a, b, c, v = 0.3, 0.5, -6.0, 2.0, 0.8
    tau = I * qdd + a * np.sin(q) + b * np.cos(q) + c * np.sign(qd) + v * qd + rng.normal(0, 0.05, n)
    return t, q, qd, qdd, tau, (I, a, b)


def _checks(t, q, qd, qdd, tau, dyn):
    X = np.column_stack([qdd, -np.sin(q), np.cos(q), np.sign(qd), qd])
    th = np.linalg.lstsq(X, tau, rcond=None)[0]
    return input_checks(t, q, qd, qdd, tau, params={"c": th[3], "v": th[4]},
                        rigid={"I": th[0], "mglx": th[1], "mgly": th[2]},
                        stderr={"I": 1e-3, "c": 1e-3, "v": 1e-3}, urdf_dyn=dyn, max_torque=50.0)


def test_checks_pass_a_consistent_joint_and_name_each_mistake():
    t, q, qd, qdd, tau, dyn = _joint()
    assert _checks(t, q, qd, qdd, tau, dyn) == []
    names = lambda cs: {c.check for c in cs}                            # noqa: E731
    assert "gravity_ratio" in names(_checks(t, q, qd, qdd, -tau, dyn))
    assert "gravity_ratio" in names(_checks(t, q, qd, qdd, 2.0 * tau, dyn))
    late = np.concatenate([np.full(80, tau[0]), tau[:-80]])           # 0.4 s late
    got = [c for c in _checks(t, q, qd, qdd, late, dyn) if c.check == "clock_lag"]
    assert len(got) == 1 and got[0].value == pytest.approx(0.4, abs=0.011)
    big = _checks(t, q, qd, qdd, 1000.0 * tau, dyn)
    assert {"gravity_ratio", "coulomb_beyond_drive"} <= names(big)
    w = input_warning([("trial 'x' joint 5", 5, big), ("trial 'y' joint 5", 5, [])])
    assert w.startswith("1 fit(s) physically implausible (trial 'x' joint 5:")
    assert "check the units or scale of tau_5" in w
    assert input_warning([("trial 'y' joint 5", 5, [])]) is None


def test_markers_shifted_in_time_give_one_warning_naming_the_clock(tmp_path, capsys):
    """Issue 45: link angles whose marker clock is 0.4 s off the robot's (a missing
    ``time_offset``) gave an implausible fit without a word. The angles come from `jointlab
    mocap` on the one-trial demo; their time column is shifted here, as a wrong clock would."""
    root = _one_trial(tmp_path)
    ang = tmp_path / "mocap"
    assert main(["mocap", str(root), "--out", str(ang)]) == 0
    good = tmp_path / "fit-good"
    assert main(["fit", str(root), "--out", str(good), "--models", "cv", "--angles", str(ang / "angles")]) == 0
    doc = json.loads((good / "fits.json").read_text())
    checks = doc["trials"][TRIAL]["5"]["cv"].get("input_checks", [])
    assert "marker_clock" not in json.dumps(checks), checks
    p = ang / "angles" / f"{TRIAL}.csv"
    lines = p.read_text().split("\n")
    head = lines[0].split(",")
    k = head.index("time")
    out = [lines[0]]
    for ln in lines[1:]:
        if not ln or ln.startswith("#"):
            out.append(ln)
            continue
        r = ln.split(",")
        r[k] = repr(float(r[k]) + 0.4)
        out.append(",".join(r))
    p.write_text("\n".join(out))
    capsys.readouterr()
    bad = tmp_path / "fit-bad"
    assert main(["fit", str(root), "--out", str(bad), "--models", "cv", "--angles", str(ang / "angles")]) == 0
    err = capsys.readouterr().err
    warn = [ln for ln in err.splitlines() if "physically implausible" in ln]
    assert len(warn) == 1 and "clock offset" in warn[0], err
    doc = json.loads((bad / "fits.json").read_text())
    assert "marker_clock" in json.dumps(doc["trials"][TRIAL]["5"]["cv"]["input_checks"])
