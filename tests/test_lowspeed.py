"""The data-chosen low-speed cut of the multi-joint fit and the bound on its effect on Coulomb
(``low_speed_cut`` in the preprocessing: the Coulomb levels at the noise floor, half, once and
twice the cut), on the synthetic 7-joint arm (pinocchio torques, a sharp Coulomb step: the cut
must not matter) and the real TX40 record (friction below the Coulomb + viscous line at low
speed: the range is wider and says so)."""
from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))

from test_multijoint import C_TRUE, TX40, _write_arm7_campaign  # noqa: E402

pytest.importorskip("pinocchio")


def _auto(camp_dir):
    from mocap.io.campaign import load_campaign
    from ident.model.multijoint import fit_multijoint_campaign

    res = fit_multijoint_campaign(load_campaign(camp_dir), ("cv",), folds=0)
    (tid, by_model), = res.fits.items()
    return res.preprocessing[tid], by_model["cv"]


def test_arm7_coulomb_does_not_depend_on_the_cut(tmp_path):
    _write_arm7_campaign(tmp_path / "c", duration=4.0)
    pre, fit = _auto(tmp_path / "c")
    cut = pre["low_speed_cut"]
    c = np.array(cut["coulomb_over_cuts"]["c"], float)           # (4 cuts, 7 joints)
    assert c.shape == (4, 7) and np.isfinite(c).all()
    # a sharp Coulomb step: every plausible cut gives the simulated level
    assert np.all(np.abs(c / C_TRUE[None, :] - 1) < 0.05), c / C_TRUE
    rng = np.array(cut["coulomb_range"], float)
    assert np.all(rng[:, 0] <= 0) and np.all(rng[:, 1] >= 0) and np.all(np.abs(rng) < 0.03), rng
    # the level at the cut is the fit's own Coulomb (same rows, same law)
    fc = np.array([fit.joints[str(j)]["params"]["c"] for j in range(1, 8)])
    assert np.allclose(c[2], fc, rtol=0.01), (c[2], fc)
    assert np.allclose([fit.joints[str(j)]["v_zero"] for j in range(1, 8)], cut["v_zero"])
    assert "Coulomb from the noise floor to twice the cut" in pre["steps"][-1]


def test_tx40_cut_range_reported_and_wider_than_on_a_sharp_step():
    if not (TX40 / "trials" / "excitation.csv").is_file():
        pytest.skip("TX40 fixture absent")
    pre, fit = _auto(TX40)
    cut = pre["low_speed_cut"]
    v = np.array(cut["coulomb_over_cuts"]["v_zero"], float)
    assert np.all(np.diff(v[[0, 2, 3]], axis=0) >= 0)              # floor <= cut <= 2 cut
    c = np.array(cut["coulomb_over_cuts"]["c"], float)
    # below some speed the real friction is under the Coulomb + viscous line: a lower cut never
    # raises the level on the big joints, and the range shows it
    assert np.all(c[0, :3] <= c[2, :3]) and np.all(c[3, :3] >= c[2, :3] * 0.995)
    rng = np.array(cut["coulomb_range"], float)
    assert rng[:5, 1].max() - rng[:5, 0].min() > 0.03
    line = pre["steps"][-1]
    assert all(f"j{j} " in line for j in range(1, 7))
