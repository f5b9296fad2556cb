"""Benchmark: the effect of the low-speed cut on the Coulomb level of the multi-joint fit, on the
real TX40 record (fixtures/real/tx40, figaroh-examples) and the synthetic 7-joint arm of
tests/test_multijoint.py (known truth).

For each record: the cut chosen from the data (``--v-zero auto``: the velocity noise floor, the
residual knee and the end of the friction's sign transition, then the presliding cut after each
velocity reversal, ident.model.multijoint._auto_cut; also without the presliding cut),
then fixed fractions of each joint's 99th-percentile speed (0 .. 5 %); per joint the
Coulomb estimate as a ratio to the reference (TX40: the published figaroh values of
../shared/data/real/README.md, for comparison, not for tuning; arm7: the simulated truth), and
the spread of those ratios over the cuts (the bound on the cut's effect).

The TX40 part then looks at the data below the cut (``analyse``): the rows each cut keeps, the
friction the record shows per speed band as a ratio to the Coulomb + viscous line fitted above
the noise floor, the friction around the moving velocity reversals (time-aligned on the zero
crossing: a torque lag would shift the step, a smooth friction transition is symmetric), the
width of a smoothed-sign fit ``c tanh(|qd|/vs) + fv |qd|`` against the speed range it is fitted
on, and two alternative cut rules (the noise floor alone; the first speed from which the mean
signed residual of each speed band is within the band's own scatter, one pass and iterated).

``--foreign`` adds the foreign world's single-joint excitation records (independent simulator,
true Coulomb level known; tri3 and ind6, no effect, Stribeck, presliding and nonlinear viscous
friction, seeds 1-2): Coulomb / truth with the noise floor and residual knee, the speed cut
(with the friction's transition end), the whole rule (with the presliding cut) and fixed cuts;
then the one-link (thesis eq. 2-4) fits of the same campaigns' excitation trials, loads
included, with and without their presliding cut.

    python benchmarks/lowspeed_cut.py            # TX40 and arm7 (about 1 min)
    python benchmarks/lowspeed_cut.py --quick    # TX40 only
    JOINTLAB_CORPUS=/work/corpus python benchmarks/lowspeed_cut.py --foreign   # + 48 records
"""
from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path[:] = [p for p in sys.path if Path(p or ".").resolve() != Path(__file__).resolve().parent]
sys.path[:0] = [str(REPO), str(REPO / "tests")]

TX40_COULOMB = np.array([7.14, 8.26, 6.34, 2.48, 3.03, 0.282])   # figaroh-examples TX40 config


def _coulomb(camp, v_zero):
    from ident.model.multijoint import fit_multijoint_campaign

    res = fit_multijoint_campaign(camp, ("cv",), v_zero=v_zero, folds=0)
    (tid, by_model), = res.fits.items()
    fit = by_model["cv"]
    n = max(int(j) for j in fit.joints)
    c = np.full(n, np.nan)
    for j, e in fit.joints.items():
        c[int(j) - 1] = e["params"]["c"]
    cut = res.preprocessing[tid].get("low_speed_cut")
    if not cut:
        return c, None, None
    return c, np.asarray(cut["v_zero"]), np.array(cut["coulomb_without_presliding_cut"], float)


def sweep(name, camp, ref):
    from ident.model.record import load_record
    from ident.model.multijoint import multijoint_trials

    robot = camp.load_robot()
    rec = load_record(camp, multijoint_trials(camp)[0], robot)
    sp = np.percentile(np.abs(rec.qd), 99, axis=0)
    c_auto, v_auto, c_speed = _coulomb(camp, "auto")
    rows = [("auto (" + ", ".join(f"{100 * x:.2g}" for x in v_auto / sp) + " %)", c_auto),
            ("auto speed cut, no presliding cut", c_speed)]
    for frac in (0.0, 0.0025, 0.005, 0.01, 0.02, 0.05):
        rows.append((f"{100 * frac:g} % of speed", _coulomb(camp, frac)[0]))
    n = ref.size
    print(f"\n{name}: Coulomb / reference per joint")
    print(f"{'cut':<34}" + "".join(f"  j{j + 1:<5}" for j in range(n)))
    for label, c in rows:
        print(f"{label:<34}" + "".join(f"  {c[j] / ref[j]:.3f}" for j in range(n)))
    ratios = np.array([c[:n] / ref for _, c in rows])
    print(f"{'spread over the cuts (max - min)':<34}"
          + "".join(f"  {x:.3f}" for x in np.nanmax(ratios, 0) - np.nanmin(ratios, 0)))
    print(f"{'auto: |ratio - 1|':<34}" + "".join(f"  {abs(x - 1):.3f}" for x in ratios[0]))
    print(f"{'auto: joints 1-5 within 3 %':<34}  {int(np.sum(np.abs(ratios[0, :5] - 1) <= 0.03))} of "
          f"{min(5, n)}")


def _fit_at(rec, chain, base, v0, x0=None, x_floor=None):
    """(Coulomb per joint, viscous per joint, signed friction residual rows) of the cv fit with
    the speed cut ``v0`` (and the presliding cut ``x0``, reversals above ``x_floor``)."""
    from ident.model.rigidbody import _PREPARED, RigidBodyIdentifier

    idt = RigidBodyIdentifier(chain, base, model="cv", folds=0, v_zero=v0, x_zero=x0,
                              x_floor=x_floor)
    A, names, F, M, _, sigma, idt._dropped = idt._prepared(rec)
    idt._names = names
    sol = idt._solve(rec, A, F, M, np.ones(rec.t.size, bool), sigma=sigma, quick=True)
    resid = rec.tau - idt._predict(rec, A, F, sol)
    _PREPARED.clear()
    return sol["bf"][0::2], sol["bf"][1::2], resid


def _band_effect(qd, r, lo, sp, n_bins=15):
    """Per log-spaced speed band from ``lo`` to ``sp``: mean of sign(qd) r over its scatter."""
    a, y = np.abs(qd), np.sign(qd) * r
    edges = np.geomspace(lo, sp, n_bins + 1)
    k = np.searchsorted(edges, a, side="right") - 1
    ok = (k >= 0) & (k < n_bins)
    cnt = np.bincount(k[ok], minlength=n_bins)
    m1 = np.bincount(k[ok], y[ok], n_bins) / np.maximum(cnt, 1)
    m2 = np.bincount(k[ok], y[ok] ** 2, n_bins) / np.maximum(cnt, 1)
    sd = np.sqrt(np.maximum(m2 - m1 ** 2, 1e-300))
    return edges, np.where(cnt >= 10, m1 / sd, 0.0)


def analyse(camp, ref):
    """What the TX40 record shows below and around the cut (see the module docstring)."""
    from ident.model.multijoint import _auto_cut, multijoint_trials
    from ident.model.record import load_record
    from ident.model.regressor import ChainDynamics, base_parameters

    robot = camp.load_robot()
    chain = ChainDynamics.from_model(robot.model)
    base = base_parameters(chain, robot.lower, robot.upper, seed=0)
    tr = multijoint_trials(camp)[0]
    rec = load_record(camp, tr, robot)
    n, qd = rec.n, rec.qd
    sp = np.percentile(np.abs(qd), 99, axis=0)
    cut = _auto_cut(camp, tr, robot, rec, chain, base, 0, {})
    floor = np.asarray(cut["noise_floor"])
    print("\nTX40 velocity noise: angle noise sigma_q (rad) / sigma_v through the derivative "
          "(rad/s) / 3 sigma_v as % of speed / derivative window (ms)")
    for j in range(n):
        win = 1e3 * rec.preprocessing["window_s"][str(j + 1)]
        print(f"  j{j + 1}: {cut['sigma_q'][j]:.2g} / {cut['sigma_v'][j]:.2g} / "
              f"{100 * floor[j] / sp[j]:.2g} % / {win:.3g}")
    fracs = (0.0, 0.0025, 0.005, 0.01, 0.02, 0.05)
    print("rows kept per cut (of " + str(rec.t.size) + "; the record rests for about "
          f"{int(np.sum(np.all(np.abs(qd) < 0.0025 * sp, axis=1)))} rows at its ends)")
    for f in fracs:
        print(f"  {100 * f:5.2g} %: " + " ".join(f"{int(np.sum(np.abs(qd[:, j]) > f * sp[j])):5d}"
                                                 for j in range(n)))
    c0, v0, r0 = _fit_at(rec, chain, base, floor)
    fr = r0 + c0[None, :] * np.sign(qd) + v0[None, :] * qd        # friction the record shows
    from ident.friction.presliding import reversal_displacement

    def ratio_rows(title, labels, masks, stat, counts):
        """Per joint: friction / (the Coulomb + viscous line) over the rows of each mask."""
        print(title)
        for j in range(min(n, 5)):
            a = np.abs(qd[:, j])
            line = c0[j] + v0[j] * a
            cells = []
            for m in masks(j, a):
                val = f"{stat(np.sign(qd[m, j]) * fr[m, j] / line[m]):.2f}" if m.sum() >= 5 else "-"
                cells.append(f"{val} ({m.sum()})" if counts and val != "-" else val)
            print(f"  j{j + 1}: " + "  ".join(f"{lb}: {c}" for lb, c in zip(labels, cells)))

    bands = (0.001, 0.0025, 0.005, 0.01, 0.02, 0.04, 0.1, 0.16, 0.4, 1.0)
    ratio_rows("friction / (Coulomb + viscous line fitted above the noise floor), per speed band "
               "(% of the 99th-percentile speed; rows)",
               [f"{100 * lo:g}-{100 * hi:g}" for lo, hi in zip(bands[:-1], bands[1:])],
               lambda j, a: [(a >= lo * sp[j]) & (a < hi * sp[j])
                             for lo, hi in zip(bands[:-1], bands[1:])], np.mean, True)
    disp = reversal_displacement(rec.q, qd, floor)
    edges = (0.0, 1e-4, 2e-4, 5e-4, 1e-3, 2e-3, 5e-3, 1e-2, 2e-2, 5e-2, np.inf)
    ratio_rows("friction / (Coulomb + viscous line fitted above the noise floor) against the "
               "displacement since the last velocity reversal (rad; median, rows above the noise "
               "floor)", [f"<{hi:g}" for hi in edges[1:]],
               lambda j, a: [(a >= floor[j]) & (disp[:, j] >= lo) & (disp[:, j] < hi)
                             for lo, hi in zip(edges[:-1], edges[1:])], np.median, False)
    lags = np.arange(-10, 15, 4)
    print("friction / Coulomb at the moving reversals (time from the velocity zero crossing, ms; "
          "sign of the new direction)")
    for j in range(min(n, 5)):
        s = np.sign(qd[:, j])
        z = np.flatnonzero(s[1:] != s[:-1]) + 1
        z = z[(z > 40) & (z < rec.t.size - 40)]
        z = np.array([k for k in z if np.abs(qd[k - 40:k, j]).max() > 0.05 * sp[j]
                      and np.abs(qd[k:k + 40, j]).max() > 0.05 * sp[j]], int)
        if z.size == 0:
            continue
        M = np.array([s[z] * fr[z + k, j] / c0[j] for k in lags]).mean(axis=1)
        print(f"  j{j + 1} ({z.size} reversals): " + " ".join(
            f"{2 * k:+d}: {m:.2f}" for k, m in zip(lags, M)))
    print("smoothed-sign fit c tanh(|qd|/vs) + fv |qd|: vs as % of speed against the upper end "
          "of the fitted range (10, 25, 50, 100 % of speed)")
    for j in range(min(n, 5)):
        a, y = np.abs(qd[:, j]), np.sign(qd[:, j]) * fr[:, j]
        out = []
        for up in (0.1, 0.25, 0.5, 1.0):
            m = (a >= floor[j]) & (a <= up * sp[j])
            best = None
            for vs in np.geomspace(1e-4, 1.0, 161) * sp[j]:        # grid over the width
                X = np.column_stack([np.tanh(a[m] / vs), a[m]])
                b, *_ = np.linalg.lstsq(X, y[m], rcond=None)
                rss = float(np.sum((y[m] - X @ b) ** 2))
                if best is None or rss < best[0]:
                    best = (rss, vs)
            out.append(f"{100 * best[1] / sp[j]:.2g} %")
        print(f"  j{j + 1}: " + ", ".join(out))
    print("alternative rules: Coulomb / reference")
    print(f"  {'noise floor alone':<44}" + "".join(f"  {x:.3f}" for x in c0[:ref.size] / ref))
    v = floor.copy()
    for it in range(3):
        _, _, r = _fit_at(rec, chain, base, v)
        knee = floor.copy()
        for j in range(n):
            edges, eff = _band_effect(qd[:, j], r[:, j], floor[j], sp[j])
            k = 0
            while k < eff.size and eff[k] < -1.0:
                k += 1
            knee[j] = edges[k]
        v = np.maximum(floor, knee)
        c, _, _ = _fit_at(rec, chain, base, v)
        label = f"band mean within its scatter, pass {it + 1}"
        print(f"  {label:<44}" + "".join(f"  {x:.3f}" for x in c[:ref.size] / ref)
              + "   (cut " + ", ".join(f"{100 * x:.2g}" for x in v / sp) + " %)")


FOREIGN = [(robot, effect, seed) for robot in ("tri3", "ind6")
           for effect in ("none", "stribeck", "presliding", "nonlinear_viscous") for seed in (1, 2)]


def _load_foreign():
    import importlib.util

    spec = importlib.util.spec_from_file_location("jointlab_bench_foreign",
                                                  Path(__file__).resolve().parent / "_foreign.py")
    mod = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = mod
    spec.loader.exec_module(mod)
    return mod


def _foreign_campaigns(F):
    """(robot, effect, seed, campaign folder, moving joint, its true Coulomb level) of each
    :data:`FOREIGN` campaign (made or found in the cache)."""
    import json

    for robot, effect, seed in FOREIGN:
        wa = F.WorldArgs(effect, seed, robot=robot, reps=1)
        root, _ = F.ensure_campaign(wa)
        truth = json.loads(root.with_name(root.name + ".truth.json").read_text())
        j = wa.moving_joint
        yield robot, effect, seed, root, j, truth["joints"][j - 1]["coulomb"]


def foreign():
    """The cut on the foreign world's single-joint excitation records (no payload; the moving
    joint's true Coulomb level from the truth file; nonlinear_viscous: the Coulomb + viscous
    law does not hold at any speed, its Coulomb level is not defined by the truth). Rules: the
    noise floor and residual knee alone (``floor+knee``), the same with the friction's transition
    end (``auto``), the whole rule with the presliding cut, fixed 1 % and 5 % of the
    99th-percentile speed."""
    from mocap.io.campaign import load_campaign
    from ident.model.multijoint import _auto_cut
    from ident.model.record import load_record
    from ident.model.regressor import ChainDynamics, base_parameters

    F = _load_foreign()
    print(f"\nforeign world ({F.cache_dir()}): Coulomb / truth of the moving joint, "
          "single-joint excitation records without payload")
    print(f"{'record':<46}{'floor+knee':>11}{'speed':>8}{'auto':>8}{'1 %':>8}{'5 %':>8}"
          "   speed cut, transition, presliding end")
    err = {}
    for robot, effect, seed, root, j, c_true in _foreign_campaigns(F):
        camp = load_campaign(root)
        rob = camp.load_robot()
        chain = ChainDynamics.from_model(rob.model)
        base = base_parameters(chain, rob.lower, rob.upper, seed=0)
        for tr in camp.trials:
            if tr.kind != "excitation" or tr.load_kg:
                continue
            rec = load_record(camp, tr, rob)
            sp = np.percentile(np.abs(rec.qd), 99, axis=0)
            cut = _auto_cut(camp, tr, rob, rec, chain, base, 0, {})
            before = np.maximum(cut["noise_floor"], cut["knee"])
            row = []
            for v, x in ((before, None), (cut["v_zero"], None), (cut["v_zero"], cut["x_zero"]),
                         (0.01 * sp, None), (0.05 * sp, None)):
                try:
                    c = _fit_at(rec, chain, base, v, x, cut["noise_floor"])[0][j - 1] / c_true
                except ValueError:                      # no row above the cut
                    c = float("nan")
                row.append(c)
            t = cut["transition"][j - 1] or {}
            tx = (f"end {100 * cut['transition_end'][j - 1] / sp[j - 1]:.2g} %" if t.get("end")
                  else f"none (ratio {t['width_ratio']:.2g})" if t.get("width_ratio") else "none")
            xe = cut["x_zero"][j - 1]
            print(f"{robot}-j{j}-{effect}-s{seed} {tr.id:<24}" + "".join(f"{x:8.3f}" for x in row)
                  + f"   {100 * cut['fraction_of_speed'][j - 1]:.2g} %, {tx}, "
                  + (f"{xe:.2g} rad" if xe > 0 else "none"))
            err.setdefault(effect, []).append(row)
    print("median and worst |ratio - 1| per effect (floor+knee, speed, auto, 1 %, 5 %)")
    for effect, rows in err.items():
        e = np.abs(np.array(rows) - 1)
        print(f"  {effect:<18}" + "".join(f"  {np.nanmedian(e[:, k]):.3f}/{np.nanmax(e[:, k]):.3f}"
                                          for k in range(5)))


def foreign_onelink():
    """The presliding cut in the one-link (thesis, eq. 2-4) fits of the same foreign campaigns:
    Coulomb / truth of every excitation trial of the moving joint (loads included), with the cut
    and without it (the Coulomb + viscous level of the rest-cut fit, ``signals.presliding``)."""
    from mocap.io.campaign import load_campaign
    from ident.thesis.campaign_fit import fit_onelink_campaign

    F = _load_foreign()
    print("\none-link (thesis eq. 2-4) fits of the same campaigns, every excitation trial: "
          "Coulomb / truth without and with the presliding cut (min-max; trials cut)")
    err = {}
    for robot, effect, seed, root, j, c_true in _foreign_campaigns(F):
        res = fit_onelink_campaign(load_campaign(root), None, ("cv",))
        now, before, cut = [], [], 0
        for e in res.entries:
            if e.task.kind != "excitation" or e.task.joint != j:
                continue
            c = float(e.fits["cv"].params["c"])
            p = e.signals.get("presliding")
            now.append(c / c_true)
            before.append((p["coulomb_without_cut"] if p else c) / c_true)
            cut += p is not None
        now, before = np.array(now), np.array(before)
        print(f"  {robot}-j{j}-{effect}-s{seed}: without {before.min():.3f}-{before.max():.3f}, "
              f"with {now.min():.3f}-{now.max():.3f} ({cut} of {now.size} cut)")
        err.setdefault(effect, []).append((np.abs(before - 1), np.abs(now - 1)))
    print("median and worst |ratio - 1| per effect (without, with the presliding cut)")
    for effect, rows in err.items():
        b = np.concatenate([r[0] for r in rows])
        w = np.concatenate([r[1] for r in rows])
        print(f"  {effect:<18}  {np.median(b):.3f}/{b.max():.3f}  {np.median(w):.3f}/{w.max():.3f}"
              f"  ({b.size} trials)")


def main(argv=None):
    from mocap.io.campaign import load_campaign

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--foreign", action="store_true",
                    help="also the foreign world's records (JOINTLAB_CORPUS caches them)")
    a = ap.parse_args(argv)
    tx40 = load_campaign(REPO / "fixtures" / "real" / "tx40")
    sweep("TX40 (fixtures/real/tx40, published figaroh values)", tx40, TX40_COULOMB)
    analyse(tx40, TX40_COULOMB)
    if not a.quick:
        import test_multijoint as tm

        with tempfile.TemporaryDirectory() as d:
            tm._write_arm7_campaign(Path(d) / "c", duration=10.0)
            sweep("arm7 (synthetic, simulated truth)", load_campaign(Path(d) / "c"), tm.C_TRUE)
    if a.foreign:
        foreign()
        foreign_onelink()


if __name__ == "__main__":
    main()
