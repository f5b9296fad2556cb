"""Issue 45: the coast-down input check (mocap.io.plausibility._check_torque_cut) tests the
torque against its noise, not sample by sample: a valid coast-down log whose controller torque
noise is ~1.1 N m RMS (a few per cent of the drive's peak) is accepted, a torque that is never
cut is still refused (tests/test_bad_inputs2.py). The foreign world cannot make coast-downs
(its kinds are excitation, constant_velocity and reversals): the valid data here is the
independent numpy world of tests/coastdown_world.py with white noise added."""
from __future__ import annotations

import json

import numpy as np
import pytest

from coastdown_world import write_campaign
from ident.cli.main import main
from mocap.io.plausibility import torque_noise


def _add_noise(root, sd, seed=0):
    """N(0, sd) N m added to every ``tau_1`` cell of every trial log."""
    rng = np.random.default_rng(seed)
    for log in sorted((root / "trials").glob("*.csv")):
        lines = [ln for ln in log.read_text().split("\n") if ln]
        k = lines[0].split(",").index("tau_1")
        out = [lines[0]]
        for ln in lines[1:]:
            c = ln.split(",")
            c[k] = f"{float(c[k]) + sd * rng.standard_normal():.5f}"
            out.append(",".join(c))
        log.write_text("\n".join(out) + "\n")


@pytest.mark.parametrize("seed", [1, 3])
def test_noisy_valid_coastdown_is_accepted_and_fits_the_truth(tmp_path, capsys, seed):
    root = tmp_path / "camp"
    truth = write_campaign(root, seed, f_log=200.0)
    _add_noise(root, 1.1)
    rc = main(["coastdown", str(root), "--out", str(tmp_path / "out")])
    err = capsys.readouterr().err
    assert rc == 0, err
    assert "never cut" not in err
    r = json.loads((tmp_path / "out" / "coastdown.json").read_text())["trials"]["cd-1"]["1"]
    for key in ("Kc", "Kv"):        # within 4 standard errors and 10 % of the world's truth
        assert abs(r[key] - truth[key]) <= 4.0 * r["stderr"][key] + 0.02 * truth[key], (key, r, truth)
        assert r[key] == pytest.approx(truth[key], rel=0.1)


def test_torque_noise_is_the_white_level_under_a_smooth_signal():
    rng = np.random.default_rng(5)
    t = np.arange(4000) / 200.0
    tau = 8.0 * np.sin(2 * np.pi * 0.3 * t) + np.where(t > 10, 0.0, 5.0) + rng.normal(0, 1.1, t.size)
    assert torque_noise(tau) == pytest.approx(1.1, rel=0.05)
