"""The gap diagnosis and the study hold no joint's samples beyond what they need (issue 30):
the sign-flip test draws its null in chunks (the same patterns as one draw), candidate columns
are rebuilt from a recipe (the same values the Grams were built from), a joint's logs are held
as its own columns, and the study keeps each joint's per-sample series in a file beside its
record (checked by hash, recomputed when it changed)."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from ident.cli.main import main
from ident.gap.channels import _torque_channel
from ident.gap.data import JointLog, build_joint_data, joint_log
from ident.gap.diagnose import _Cols, _ColumnCache, _effect_grams
from ident.gap.candidates import candidate_effects
from ident.gap.engine import grams, grams_augmented, sign_flip_pvalue
from ident.study.study import STATE_DIR


def _one_draw_p(d, n_perm, seed):
    """The sign-flip p of a one-sided studentised mean, all patterns drawn at once."""
    d = np.asarray(d, float)
    n = d.size
    rng = np.random.default_rng(seed)
    t = lambda x: x.mean(-1) / np.maximum(x.std(-1, ddof=1), 1e-300) * np.sqrt(n)  # noqa: E731
    if 2 ** n <= n_perm:
        signs = np.array([[1 - 2 * ((k >> i) & 1) for i in range(n)] for k in range(2 ** n)], float)
    else:
        signs = rng.choice([-1.0, 1.0], size=(n_perm, n))
    return (1 + np.sum(t(signs * d) >= t(d) - 1e-12)) / (1 + signs.shape[0])


@pytest.mark.parametrize("n,n_perm,seed", [(11, 20000, 0), (14, 20000, 3), (15, 20000, 1),
                                           (37, 20000, 2), (120, 2500, 4), (399, 1999, 5)])
def test_chunked_sign_flip_equals_one_draw(n, n_perm, seed):
    d = np.random.default_rng(100 + n).normal(0.15, 1.0, n)
    assert sign_flip_pvalue(d, n_perm, seed) == _one_draw_p(d, n_perm, seed)


@pytest.fixture(scope="module")
def campaign(tmp_path_factory):
    camp = tmp_path_factory.mktemp("camp") / "c"
    assert main(["synth", str(camp), "--joints", "5", "--reps", "2", "--duration", "6",
                 "--vmax", "0.5,1.0", "--loads", "0", "--effect", "stribeck", "--seed", "3",
                 "--quiet"]) == 0
    return camp


def _joint_data(camp_dir):
    from mocap.io.campaign import load_campaign

    camp = load_campaign(camp_dir)
    robot = camp.load_robot()
    trials = [t for t in camp.trials if tuple(t.joints) == (5,)]
    return camp, robot, trials


def test_joint_log_gives_the_data_of_the_full_logs(campaign):
    camp, robot, trials = _joint_data(campaign)
    logs = [camp.read_log(t, robot) for t in trials]
    slim = [joint_log(lg, 5) for lg in logs]
    assert all(isinstance(s, JointLog) and s.qm.ndim == 1 and s.qm.base is None for s in slim)
    a = build_joint_data(5, trials, logs, robot)
    b = build_joint_data(5, trials, slim, robot)
    for f in ("t", "q", "qd", "qdd", "y", "tau_urdf", "urdf_regs", "sgn_filtered"):
        assert np.array_equal(getattr(a, f), getattr(b, f)), f
    assert a.deriv_window_s == b.deriv_window_s


def test_column_recipe_rebuilds_the_columns_the_grams_used(campaign):
    camp, robot, trials = _joint_data(campaign)
    d = build_joint_data(5, trials, [camp.read_log(t, robot) for t in trials], robot)
    ch = _torque_channel(d)
    X = ch.prep(ch.X0)
    base = grams(X, ch.target, ch.blocks)
    cands = [c for c in candidate_effects(None, float(np.ptp(d.q))) if c.channel == "torque"][:6]
    for cache in (None, _ColumnCache(0), _ColumnCache(1e9)):
        gb, cols = _effect_grams(cands, d, ch, X, base, cache)
        assert gb and set(gb) == set(cols)
        for key, recipe in cols.items():
            assert isinstance(recipe, _Cols)
            C = recipe.build(d, ch, cache)
            assert C.shape[1] == int(recipe.keep.sum())
            g = grams_augmented(base, X, C, ch.target, ch.blocks)
            assert np.array_equal(g.G, gb[key].G) and np.array_equal(g.b, gb[key].b)


FAST = ["--models", "cv", "--starts", "1", "--no-rrd", "--no-mocap", "--quiet", "--workers", "1"]


def _diagnosis_stage(out, campaign, capsys) -> dict:
    capsys.readouterr()
    assert main(["study", str(campaign), "--out", str(out), "--json"] + FAST) == 0
    return json.loads(capsys.readouterr().out)["stages"]["diagnosis"]


def test_study_keeps_series_beside_the_record_and_recomputes_a_changed_one(campaign, tmp_path, capsys):
    out = tmp_path / "out"
    assert _diagnosis_stage(out, campaign, capsys)["computed"] == 1
    rec_dir = out / STATE_DIR / "records" / "diagnosis"
    rec = json.loads((rec_dir / "joint5.json").read_text())
    series = rec["payload"]["series"]
    assert set(series) == {"file", "sha256", "spectrum"} and series["file"] == "joint5.series.npz"
    assert "__array__" not in json.dumps(series).replace(json.dumps(series["spectrum"]), "")
    with np.load(rec_dir / "joint5.series.npz") as z:
        assert set(z.files) == {"t", "qd", "qdd", "q", "residual_nominal", "trial"}
        n = z["qd"].size
    assert n > 1000 and (out / "diagnosis" / "joint5_residual.png").is_file()
    first = (out / "diagnosis" / "diagnosis.json").read_text()
    # an unchanged rerun reuses the joint; a series file changed behind the study's back is not
    # trusted: the joint is diagnosed again, to the same numbers
    assert _diagnosis_stage(out, campaign, capsys)["reused"] == 1
    np.savez(rec_dir / "joint5.series.npz", qd=np.zeros(3))
    assert _diagnosis_stage(out, campaign, capsys)["computed"] == 1
    with np.load(rec_dir / "joint5.series.npz") as z:
        assert z["qd"].size == n
    assert (out / "diagnosis" / "diagnosis.json").read_text() == first


def test_block_products_are_the_per_block_matmuls():
    """The Gram blocks (one pass over the blocks, kept own products) are the products of
    ``np.matmul`` per block, bit for bit: the diagnosis' numbers do not depend on the route."""
    from ident.gap.engine import _augmented_sums, _outer_sums, own_blocks

    rng = np.random.default_rng(7)
    n = 6000
    cuts = np.sort(rng.choice(np.arange(1, n), 29, replace=False))
    bounds = np.column_stack([np.r_[0, cuts], np.r_[cuts, n]])
    r = rng.normal(size=n)
    for p, k in [(1, 1), (6, 1), (6, 2), (7, 4), (9, 3)]:
        X, C = rng.normal(size=(n, p)), rng.normal(size=(n, k))
        ref = [np.array([np.matmul(A[a:b].T, B[a:b]) for a, b in bounds]) for A, B in
               ((X, C), (C, C), (C, r[:, None]))]
        XC, CC, Cr = _augmented_sums(X, C, r, bounds)
        assert np.array_equal(XC, ref[0]) and np.array_equal(CC, ref[1]) and np.array_equal(Cr, ref[2][:, :, 0])
        assert np.array_equal(_outer_sums(X, C, bounds), ref[0])
        base = grams(X, r, bounds)
        g = grams_augmented(base, X, C, r, bounds)
        g2 = grams_augmented(base, X, C, r, bounds, own_blocks(g, k))
        assert np.array_equal(g.G, g2.G) and np.array_equal(g.b, g2.b)
