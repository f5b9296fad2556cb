"""Coast-down friction identification: the paper's simulation (seeds/000_*, Table 1-2).

J = 0.01 kg m^2, Kv = 0.01203 N m s/rad, Kc = 0.0017 N m, v0 = 10 rad/s, white Gaussian
velocity noise at SNR 90/60/20 dB (SNR = 10 log10(mean(v^2)/sigma^2) over the record),
sampled at FS = 1 kHz from the release to the stop (t_s = 3.552 s, 3553 samples; the
paper states no rate). For each SNR, RUNS Monte Carlo records (seeded) go through:

  TDM        eqs. 4-6, root of eq. 6 refined by Brent (= LS on eq. 4, v0 known)
  TDM-grid   the same with the fixed-step search of Kv (step 1e-5 N m s/rad, random phase)
  FDM@w      eqs. 9-11 on the record's Fourier integral, band 0 < w <= w rad/s
  TDM-meas   TDM with v0 = the measured (noisy) first sample instead of the true 10 rad/s
  FDM-meas   FDM@30 with v0 = the measured first sample
  NLS        ML / nonlinear LS on eq. 4 with the stop time, v0 known (same information
             as TDM/FDM)
  NLS-v0     the same with v0 estimated (noisy first sample not trusted)

and prints the RMS relative error of Kv and Kc, the Cramer-Rao bound (relative std; 2
parameters, or 3 for NLS-v0), the ratio RMS/CRB and Table 2's single-run figure.

A second scenario ("--rest", on by default) keeps logging 1 s after the stop: NLS fits the
whole record (the stop is in its model); TDM and FDM are given the record cut at the first
measured sample <= 0 (eq. 4 has no stop), as :func:`ident.coastdown.estimators.coastdown_from_trial`.

A third part ("--campaigns", on by default) prints the acceptance figures of the campaign
command's estimator (:func:`ident.coastdown.campaign_analysis.analyse_campaign`: coast detection in the
log, J from the URDF, ML on the encoder angle with the declared transmission stiffness, a
trial that cannot separate Kc from Kv reported at the joint's pooled Kv) on seeded campaigns of
the independent numpy world (``tests/coastdown_world.py``: flexible joint with motor-side
friction, encoder quantisation, amplifier lag, controller-rate log) at 200/500/1000 Hz, stiff
and as flexible as the foreign world's joints (0.06-0.1 deg at max torque), and on seeded
``jointlab synth`` coast-down campaigns (PA10 joint 5, link-side friction, gravity compensated
while coasting) at 200 Hz and 1 kHz: median |Kc error|, the share of Kv within 3 reported
standard errors or 20 %, and the coverage of the +-1.96 standard-error intervals (nominal
0.95) against the truth, per (trial, joint) and for the pooled fit per joint. The baseline of
the same run is the per-record TDM (the paper's method on the same coasts).

Run: ``python benchmarks/coastdown.py`` (200 runs, 8 world seeds per setting, 6 synth seeds per
rate; a few minutes) or ``--quick`` (20 runs, 3 world seeds, one synth campaign at 200 Hz);
``--campaigns-only`` skips the Monte Carlo parts.
"""
from __future__ import annotations

import argparse
import math
import os
import sys
import time
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
# benchmarks/ holds scripts named like our packages (benchmarks/mocap.py): keep the script's
# folder off the import path so `import mocap` finds the package
_here = Path(__file__).resolve().parent
sys.path[:] = [p for p in sys.path if Path(p or ".").resolve() != _here]
sys.path.insert(0, str(_here.parent))          # this checkout's packages, not an installed copy

import numpy as np  # noqa: E402

from ident.coastdown.estimators import crb, fdm_batch, nls, simulate_sdof_coastdown, stop_time, tdm  # noqa: E402

J, KV, KC, V0 = 0.01, 0.01203, 0.0017, 10.0
FS = 1000.0
SNRS = (90.0, 60.0, 20.0)
TABLE2 = {  # relative error (fraction) of one run, paper Table 2
    90.0: {"TDM": (8.3e-4, 4.9e-2), "FDM": (6.4e-8, 8.6e-5)},
    60.0: {"TDM": (1.7e-3, 0.219), "FDM": (2.2e-5, 2.6e-2)},
    20.0: {"TDM": (0.282, 0.931), "FDM": (5.1e-5, 6.4e-2)},
}
FDM_BANDS = (3.0, 10.0, 30.0)


def rel_rms(est, true):
    est = np.asarray(est, float)
    return float(np.sqrt(np.mean((est / true - 1.0) ** 2)))


def run_snr(snr, runs, seed, rest_s=0.0):
    rng = np.random.default_rng([seed, int(snr), int(rest_s * 1000)])
    dur = None if rest_s == 0.0 else stop_time(J, KV, KC, V0) + rest_s
    sim = simulate_sdof_coastdown(J, KV, KC, V0, FS, dur, snr, rng, runs=runs)
    t = sim.t
    est = {k: ([], []) for k in ("TDM", "TDM-grid", "TDM-meas", "NLS", "NLS-v0")}
    fdm_est = {}
    timing = {k: 0.0 for k in ("TDM", "FDM", "NLS", "NLS-v0")}
    cuts = []
    grid_phase = rng.uniform(0.0, 1e-5, runs)
    for i in range(runs):
        v = sim.v[i]
        if rest_s > 0.0:             # TDM/FDM: cut at the first sample at or below zero speed
            below = np.flatnonzero(v <= 0.0)
            end = int(below[0]) if below.size else v.size
        else:
            end = v.size
        cuts.append(end)
        t0 = time.perf_counter()
        # the grid's phase is random: the true Kv = 0.01203 would lie on a grid of 1e-5 steps
        # from 0, an oracle advantage a real search does not have
        r = tdm(t[:end], v[:end], J, v0=V0, kv_step=1e-5, kv_grid_origin=float(grid_phase[i]))
        timing["TDM"] += time.perf_counter() - t0
        est["TDM-grid"][0].append(r.Kv)
        est["TDM-grid"][1].append(r.Kc)
        est["TDM"][0].append(r.diagnostics["Kv_root"])
        est["TDM"][1].append(r.diagnostics["Kc_root"])
        r = tdm(t[:end], v[:end], J)             # v0 = the measured (noisy) first sample
        est["TDM-meas"][0].append(r.Kv)
        est["TDM-meas"][1].append(r.Kc)
        for name, kw in (("NLS", {"v0": V0}), ("NLS-v0", {})):
            t0 = time.perf_counter()
            r = nls(t, v, J, **kw)
            timing[name] += time.perf_counter() - t0
            est[name][0].append(r.Kv)
            est[name][1].append(r.Kc)
    cuts = np.asarray(cuts)
    t0 = time.perf_counter()
    for w in FDM_BANDS + ("meas",):
        wm, v0 = (FDM_BANDS[-1], sim.v[:, 0]) if w == "meas" else (w, np.full(runs, V0))
        if rest_s == 0.0:
            kv, kc, _ = fdm_batch(t, sim.v, J, v0, w_max=wm)
        else:                        # different cut per run: one call each
            kv, kc = np.empty(runs), np.empty(runs)
            for i in range(runs):
                a, b, _ = fdm_batch(t[:cuts[i]], sim.v[i, :cuts[i]], J, v0[i], w_max=wm)
                kv[i], kc[i] = a[0], b[0]
        fdm_est[w] = (kv, kc)
    timing["FDM"] = time.perf_counter() - t0
    b2 = crb(t, J, KV, KC, V0, sim.sigma)
    b3 = crb(t, J, KV, KC, V0, sim.sigma, estimate_v0=True)
    rows, errs = {}, {}
    for w, (kv, kc) in fdm_est.items():
        est["FDM-meas" if w == "meas" else f"FDM@{w:g}"] = (kv, kc)
    for name, (kv, kc) in est.items():
        rows[name] = (rel_rms(kv, KV), rel_rms(kc, KC))
        errs[name] = (np.asarray(kv) / KV - 1.0, np.asarray(kc) / KC - 1.0)
    return {"sigma": sim.sigma, "n": t.size, "rows": rows, "errs": errs,
            "crb2": (b2.rel["Kv"], b2.rel["Kc"]),
            "crb3": (b3.rel["Kv"], b3.rel["Kc"]), "timing": timing,
            "cut_s": float(np.mean(t[cuts - 1])) if rest_s > 0 else float(t[-1])}


def report(title, runs, seed, rest_s):
    print(f"\n=== {title}: fs = {FS:g} Hz, {runs} Monte Carlo runs per SNR, seed {seed} ===")
    hdr = (f"{'SNR':>4} {'estimator':>10} | {'Kv rms%':>9} {'CRB%':>9} {'ratio':>6} {'Tab2%':>8} |"
           f" {'Kc rms%':>9} {'CRB%':>9} {'ratio':>6} {'Tab2%':>8}")
    print(hdr)
    print("-" * len(hdr))
    summary = {}
    for snr in SNRS:
        out = run_snr(snr, runs, seed, rest_s)
        summary[snr] = out
        for name, (ekv, ekc) in out["rows"].items():
            bkv, bkc = out["crb3"] if name == "NLS-v0" else out["crb2"]
            tab = TABLE2[snr].get(name.split("@")[0].split("-")[0]) if name in ("TDM-grid", "FDM@30") else None
            t_kv = f"{100 * tab[0]:8.2g}" if tab else f"{'':>8}"
            t_kc = f"{100 * tab[1]:8.2g}" if tab else f"{'':>8}"
            print(f"{snr:4.0f} {name:>10} | {100 * ekv:9.3g} {100 * bkv:9.3g} {ekv / bkv:6.2f} {t_kv} |"
                  f" {100 * ekc:9.3g} {100 * bkc:9.3g} {ekc / bkc:6.2f} {t_kc}")
        tm = out["timing"]
        extra = f", TDM/FDM cut at {out['cut_s']:.2f} s on average" if rest_s > 0 else ""
        print(f"     sigma = {out['sigma']:.3g} rad/s, N = {out['n']}{extra}; time per run: "
              + ", ".join(f"{k} {1e3 * v / runs:.1f} ms" for k, v in tm.items()))
    return summary


def verdict(summary):
    print("\nGoal checks (best estimator NLS, v0 known; ratio = RMS / CRB; 'best published' ="
          " the least RMS of TDM, TDM-grid and FDM@3/10/30, each given the true v0):")
    for snr, out in summary.items():
        r = out["rows"]
        nkv, nkc = r["NLS"]
        bkv, bkc = out["crb2"]
        pub = {k: v for k, v in r.items() if k.startswith(("TDM", "FDM")) and not k.endswith("meas")}
        best_pub_kv = max(min(v[0] for v in pub.values()), 1e-300)
        best_pub_kc = max(min(v[1] for v in pub.values()), 1e-300)
        print(f"  {snr:3.0f} dB: NLS/CRB Kv {nkv / bkv:.2f}, Kc {nkc / bkc:.2f} "
              f"(<= 1.2: {'yes' if max(nkv / bkv, nkc / bkc) <= 1.2 else 'NO'}); "
              f"NLS / best published Kv {nkv / best_pub_kv:.3f}, Kc {nkc / best_pub_kc:.3f}")
        # paired on the same runs: relative MSE difference against each parameter's best
        # published method, with its Monte Carlo standard error
        e = out["errs"]
        parts = []
        for j, p in enumerate(("Kv", "Kc")):
            best = min(pub, key=lambda k: pub[k][j])
            d = e["NLS"][j] ** 2 - e[best][j] ** 2
            m = np.mean(e[best][j] ** 2)
            parts.append(f"{p} vs {best}: {100 * d.mean() / m:+.1f} % +- {100 * d.std() / np.sqrt(d.size) / m:.1f} %")
        print("          MSE(NLS) - MSE(best published), paired, relative: " + "; ".join(parts))
        for meth, (tkv, tkc) in TABLE2[snr].items():
            for p, tv, b in (("Kv", tkv, bkv), ("Kc", tkc, bkc)):
                if tv < b:
                    # probability that an unbiased estimator AT the bound (Gaussian error of
                    # std b) errs by at most tv in one run; any worse estimator does less well
                    prob = math.erf(tv / b / math.sqrt(2.0))
                    print(f"          Table 2 {meth} {p} {100 * tv:.2g} % lies BELOW the CRB "
                          f"({100 * b:.3g} %, {b / tv:.3g}x) at {FS:g} Hz: one run that good has "
                          f"P = {prob:.2g} even for an efficient estimator; the bound reaches it "
                          f"only at fs >= {FS * (b / tv) ** 2:.3g} Hz")


def _row(r, kc, kv):
    """Acceptance figures of one (trial, joint) result against the truth ``kc``, ``kv``:
    Kc error, Kv error, z-scores of the reported values, Kv within 3 standard errors or 20 %,
    the trial-only ML Kc error, TDM's Kc error."""
    se = r.stderr
    tk = r.tdm.get("Kc")
    return [r.Kc / kc - 1, r.Kv / kv - 1, (r.Kc - kc) / se["Kc"], (r.Kv - kv) / se["Kv"],
            abs(r.Kv - kv) <= max(3 * se["Kv"], 0.2 * kv), r.ml.Kc / kc - 1,
            (tk / kc - 1) if tk is not None else np.nan, r.pooled_kv is not None]


def _summarise(name, rows, pooled=()):
    a = np.array(rows, float)
    tdm_kc = a[:, 6][np.isfinite(a[:, 6])]
    line = (f"{name:>28} | {a.shape[0]:3d} {int(a[:, 7].sum()):3d} | {100 * np.median(np.abs(a[:, 0])):6.2f} "
            f"{100 * np.median(np.abs(a[:, 5])):7.2f} {100 * np.median(np.abs(a[:, 1])):6.2f} | "
            f"{np.mean(a[:, 4]):5.2f} | {np.mean(np.abs(a[:, 2]) < 1.96):5.2f} {np.mean(np.abs(a[:, 3]) < 1.96):5.2f} "
            f"{np.sqrt(np.mean(a[:, 2] ** 2)):5.2f} {np.sqrt(np.mean(a[:, 3] ** 2)):5.2f} | "
            f"{100 * np.median(np.abs(tdm_kc)) if tdm_kc.size else float('nan'):6.2f}")
    if len(pooled):
        p = np.array(pooled, float)
        line += (f" | {p.shape[0]:2d} {100 * np.median(np.abs(p[:, 0])):6.2f} {100 * np.median(np.abs(p[:, 1])):6.2f} "
                 f"{np.mean(np.abs(p[:, 2]) < 1.96):5.2f} {np.mean(np.abs(p[:, 3]) < 1.96):5.2f} "
                 f"{np.sqrt(np.mean(p[:, 2] ** 2)):5.2f} {np.sqrt(np.mean(p[:, 3] ** 2)):5.2f}")
    print(line)
    return a


def campaign_part(seeds, synth_seeds, synth_rates):
    """Acceptance figures of the campaign estimator (module docstring)."""
    import json
    import shutil
    import tempfile

    sys.path.insert(0, str(_here.parent / "tests"))
    from coastdown_world import write_campaign  # noqa: E402

    from ident.coastdown.campaign_analysis import analyse_campaign  # noqa: E402
    from mocap.io.campaign import load_campaign  # noqa: E402

    print("\n=== Campaign estimator (jointlab coastdown) against the truth: acceptance figures ===")
    print("per (trial, joint): n = results, pkv = of them reported at the joint's pooled Kv (method "
          "ml-pooled-kv: the trial alone cannot separate Kc from Kv);\n|eKc| = median |Kc error| of the "
          "reported Kc (ML = the trial-only ML fit), |eKv| likewise; Kv ok = share within 3 reported "
          "standard errors or 20 %;\ncov = share of |error| < 1.96 reported standard errors (nominal 0.95), z = RMS of "
          "error / reported standard error (1 for honest standard errors); "
          "TDM = the paper's method on the same coasts (coasts long enough);\npooled = the joint's fit "
          "over all its coast-down trials, one per campaign (n campaigns, |eKc| |eKv| cov Kc cov Kv z Kc z Kv)")
    hdr = (f"{'setting':>28} | {'n':>3} {'pkv':>3} | {'|eKc|%':>6} {'ML|eKc|':>7} {'|eKv|%':>6} | {'Kv ok':>5} | "
           f"{'covKc':>5} {'covKv':>5} {'zKc':>5} {'zKv':>5} | {'TDM%':>6} | pooled")
    print(hdr)
    print("-" * len(hdr))
    tmp = Path(tempfile.mkdtemp(prefix="cdbench-"))
    cpu0 = time.process_time()
    try:
        for stiff, label in ((100.0, "stiff"), (1.0, "flexible")):
            for f_log in (200.0, 500.0, 1000.0):
                rows, pooled = [], []
                for seed in seeds:  # loop over seeded worlds
                    root = tmp / f"w{int(stiff)}-{int(f_log)}-{seed}"
                    tr = write_campaign(root, seed, f_log=f_log, stiffness_scale=stiff)
                    rep = analyse_campaign(load_campaign(root))
                    rows += [_row(r, tr["Kc"], tr["Kv"]) for r in rep.trials]
                    shutil.rmtree(root)
                _summarise(f"world {label}, {f_log:g} Hz", rows)
        if synth_seeds:
            from ident.sim.campaign_synth import CampaignSynth, SynthConfig

            for rate in synth_rates:
                rows, rows_acc, pooled = [], [], []
                for seed in synth_seeds:  # loop over seeded campaigns
                    out = tmp / f"synth{int(rate)}-{seed}"
                    cfg = SynthConfig(joints=(5,), loads=(0.0, 3.373), vmax=(0.25, 0.625, 1.0), reps=1,
                                      kinds=("coastdown",), seed=seed, log_rate=rate)
                    CampaignSynth(cfg).write(out, progress=False)
                    truth = json.loads((tmp / f"synth{int(rate)}-{seed}.truth.json").read_text())
                    kc = truth["joints"]["5"]["plant"]["c_pos"]
                    kv = truth["joints"]["5"]["plant"]["v"] + truth["joints"]["5"]["B"]
                    rep = analyse_campaign(load_campaign(out))
                    rows += [_row(r, kc, kv) for r in rep.trials]
                    rows_acc += [_row(r, kc, kv) for r in rep.trials if r.vmax_frac >= 0.625]
                    p = rep.joints[5]
                    pooled.append([p.Kc / kc - 1, p.Kv / kv - 1, (p.Kc - kc) / p.stderr["Kc"],
                                   (p.Kv - kv) / p.stderr["Kv"]])
                    shutil.rmtree(out)
                _summarise(f"synth j5 {rate:g} Hz, cut 25-100 %", rows_acc, pooled)
                _summarise(f"synth j5 {rate:g} Hz, all trials", rows)
            print(f"{'':>28}   (synth campaigns: vmax_frac 0.25/0.625/1 x speed fractions 0.4/0.7/1 = cuts at "
                  "10-100 % of max speed, loads 0 and 3.373 kg, seeds " + ", ".join(map(str, synth_seeds))
                  + ";\n" + " " * 31 + "'cut 25-100 %' = the trials with vmax_frac 0.625 and 1 (the acceptance range); "
                  "pooled = over all trials)")
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    print(f"campaign part: CPU {time.process_time() - cpu0:.1f} s")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="20 runs instead of 200")
    ap.add_argument("--runs", type=int, default=None)
    ap.add_argument("--seed", type=int, default=2020)
    ap.add_argument("--no-rest", action="store_true", help="skip the second scenario")
    ap.add_argument("--no-campaigns", action="store_true", help="skip the campaign part")
    ap.add_argument("--campaigns-only", action="store_true", help="only the campaign part")
    args = ap.parse_args(argv)
    runs = args.runs or (20 if args.quick else 200)
    t0 = time.perf_counter()
    if not args.campaigns_only:
        s = report("Paper scenario: record from release to stop", runs, args.seed, 0.0)
        verdict(s)
    if not args.no_rest and not args.campaigns_only:
        s = report("Logging 1 s past the stop (TDM/FDM cut at first v <= 0)", runs, args.seed, 1.0)
        verdict(s)
    if not args.no_campaigns:
        campaign_part(range(3) if args.quick else range(8), (11,) if args.quick else tuple(range(11, 17)),
                      (200.0,) if args.quick else (200.0, 1000.0))
    print(f"\ntotal {time.perf_counter() - t0:.1f} s")


if __name__ == "__main__":
    main()
