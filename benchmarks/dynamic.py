"""Benchmark: the full two-step Indri & Trapani identification (step 1, phases 2-A and 2-B, plus
the DM1 comparison model) on ~10^5 samples of a simulated LuGre-type joint, on one core.

Baseline measured in the same run: the same identification with the bristle-state recursion
(eq. 29-30) solved by a per-sample Python loop instead of the vectorised linear scan (the
coefficients are still computed vectorised; only the recursion loops, the fairest loop).

    python benchmarks/dynamic.py            # ~10^5 samples, loop baselines run in full
    python benchmarks/dynamic.py --quick    # ~4x10^4 samples, loop baselines projected

Per trial kind, DM2 against the static arctan model on a campaign jointlab did not write
(``jointlab fit CAMPAIGN --models arctan,dm1,dm2``; e.g. the foreign world with
``--kinds excitation,constant_velocity,reversals``), with the paper's procedure alone (phase
2-B, no phase 2-C) measured in the same run as the baseline, and sigma0 against the truth
beside the campaign (``<campaign>.truth.json``) when its effect is presliding:

    python benchmarks/dynamic.py --campaign DIR [--quick] [--heldout [rep|load]]
    python benchmarks/dynamic.py --worlds       # every world of WORLDS, then one summary table

(DIR e.g. ``$JOINTLAB_CORPUS/ind6-j3-presliding-m1-s2-r1-kecr``; ``--quick``: repetition-1
trials only; ``--heldout``: fit on the odd repetitions, compare on the even ones;
``--heldout load``: fit on the unloaded trials, compare on the loaded ones.) ``--worlds`` runs
jointlab's own synth (PA10 joint 5, LuGre presliding and no effect, 200 Hz log, coarse
encoder; written to a temporary folder) and the foreign world's ind6 joint 3 campaigns of
WORLDS (presliding in its Dahl and Maxwell-slip forms and an effect-free one; generated once
into ``$JOINTLAB_CORPUS`` by ``benchmarks/_foreign.py``) and prints, per world, DM2 / arctan
RMS per trial kind (median and max over the trials) and the error of sigma0.
:func:`campaign_comparison` and :func:`heldout_comparison` return the numbers for other
benchmarks.
"""
from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("MKL_NUM_THREADS", "1")

import argparse  # noqa: E402
import math  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))   # this checkout's packages

import numpy as np  # noqa: E402

from ident.excitation.profiles import random_knots, static_knots  # noqa: E402
from ident.indri.estimator import IndriTrapani  # noqa: E402
from ident.sim.friction import simulate_friction, simulate_reversal_datasets  # noqa: E402
from ident.friction import Arctan, LuGreDM2, s0, s1  # noqa: E402
from ident.friction import dynamic as dyn  # noqa: E402

STATIC = Arctan(tau_s=5.0, tau_sc=-1.5, tau_v=2.0, tau_nlv=0.3, delta=15.0)
ACCELS = (2.0, 4.0, 8.0, 12.0, 16.0, 20.0)
VMAX = 1.5
TRUTH = LuGreDM2(static=STATIC, sigma0=1.0e4, alpha=50.0, beta=0.5, gamma=1.0,
                 accel_ratio=ACCELS[-1] / VMAX)
NOISE = 0.01 * float(STATIC.torque(np.array([2.0]))[0])


def make_data(quick: bool, seed: int = 0):
    scale = 0.25 if quick else 1.0
    sd = simulate_friction(TRUTH, static_knots(np.geomspace(0.02, 2.0, 10), settle_disp=0.02),
                             noise_std=NOISE, seed=seed + 1, label="static")
    rev = simulate_reversal_datasets(TRUTH, ACCELS, VMAX, noise_std=NOISE, seed=seed + 2,
                                       n_cycles=max(1, int(round(4 * scale))))
    var = simulate_friction(TRUTH, random_knots(40.0 * scale, (0.02, 2.0), (1.0, 20.0),
                                                    seed=seed + 3),
                              noise_std=NOISE, seed=seed + 4, label="variable")
    return sd, rev, var


def loop_states(self, qd, dt):
    """Drop-in for ``_LuGre.states`` (first-order hold, the models' default): the same
    coefficients, the recursion as a Python loop."""
    v = np.asarray(qd, float)
    T = v.shape[0]
    steps = np.broadcast_to(np.asarray(dt, float), (max(T - 1, 0),))
    a, _, g = self._ab(v)
    zss = self._zss(v, g)
    x = 0.5 * steps * (a[:-1] + a[1:])
    drive = -np.expm1(-x) * zss[:-1] + (zss[1:] - zss[:-1]) * (1.0 - dyn._phi(x))
    dec = np.exp(-x)
    z0 = float(self.steady_state(v[0])) if self.z0 is None else self.z0
    out = [0.0] * T
    z = z0
    out[0] = z
    dl, dr = dec.tolist(), drive.tolist()
    for k in range(T - 1):                                   # the per-sample loop
        z = dl[k] * z + dr[k]
        out[k + 1] = z
    return np.array(out)


def naive_loop_states(self, qd, dt):
    """Drop-in for ``_LuGre.states``: the first-order-hold step written sample by sample, as
    in the C export (no rest relaxation: rest_speed 0)."""
    v = np.asarray(qd, float).tolist()
    T = len(v)
    steps = np.broadcast_to(np.asarray(dt, float), (max(T - 1, 0),)).tolist()
    st = self.static
    Kv, ts, tsc, de, sg0 = st.Kv, st.tau_s, st.tau_sc, st.delta, self.sigma0
    c = 2.0 / math.pi

    def coef(vk):
        S = c * math.atan(Kv * vk)
        g = ts + tsc * c * math.atan(S * vk * de)
        return sg0 * S * vk / g, S * g / sg0                 # a, steady state

    a0, zs0 = coef(v[0])
    z = zs0 if self.z0 is None else self.z0
    out = [z]
    for k in range(T - 1):                                   # the per-sample loop
        a1, zs1 = coef(v[k + 1])
        x = 0.5 * steps[k] * (a0 + a1)
        phi = 1.0 - 0.5 * x if abs(x) < 1e-12 else -math.expm1(-x) / x
        z = math.exp(-x) * z - math.expm1(-x) * zs0 + (zs1 - zs0) * (1.0 - phi)
        out.append(z)
        a0, zs0 = a1, zs1
    return np.array(out)


def best_of(fn, n):
    """(fastest wall time of n runs, the output of that run)."""
    best, out = np.inf, None
    for _ in range(n):
        t0 = time.perf_counter()
        o = fn()
        dt = time.perf_counter() - t0
        if dt < best:
            best, out = dt, o
    return best, out


def sigma0_truth(campaign_dir, joint: int) -> dict | None:
    """Comparable bristle stiffnesses of a campaign's truth whose effect is presliding (None
    otherwise), from ``<campaign>.truth.json``.

    Foreign world: its forms scale the Coulomb level ``c`` by a presliding state with a
    characteristic displacement ``xp``. LuGre's sigma0 is ``dF/dx`` at zero bristle deflection
    (eq. 5: ``dz/dt = v`` at z = 0); the same slope of the foreign forms is ``c/xp`` for Dahl
    (any exponent) and ``c sum w_k / X_k`` for Maxwell-slip (every element stuck; ``X_k = xp``
    times a log-uniform factor in [0.3, 3], so about 1.3 c/xp). ``c_over_xp`` is the scale the
    task names, ``zero_deflection`` the matched slope. jointlab synth: the plant's own LuGre
    sigma0 (both keys)."""
    import json
    from pathlib import Path

    p = Path(str(campaign_dir).rstrip("/") + ".truth.json")
    if not p.is_file():
        return None
    doc = json.loads(p.read_text())
    if isinstance(doc.get("effect"), dict):                       # jointlab synth
        if doc["effect"].get("name") != "presliding":
            return None
        tj = doc["joints"][str(joint)]
        s0 = float(tj["plant"]["sigma0"])
        c = float(tj["plant"]["c_pos"])
        return {"form": "lugre (jointlab synth)", "c": c, "xp": c / s0, "c_over_xp": s0,
                "zero_deflection": s0}
    eff = [e for e in doc.get("effects", []) if e.get("effect") == "presliding"]
    if not eff:
        return None
    e = eff[0]
    pj = e["per_joint"]
    pj = pj.get(str(joint), pj) if isinstance(pj, dict) else pj

    def val(key):
        x = pj[key]
        return float(x[joint - 1] if isinstance(x, list) else x)

    c = float(doc["joints"][joint - 1]["coulomb"])
    xp = val("xp")
    if e["form"] == "dahl":
        k0 = c / xp
    else:
        k0 = c * sum(val(f"w{i}") / val(f"x{i}") for i in range(int(e["global"]["elements"])))
    return {"form": e["form"], "c": c, "xp": xp, "c_over_xp": c / xp, "zero_deflection": k0}


def heldout_comparison(campaign_dir, joint: int | None = None, by: str = "rep") -> dict:
    """Identification on part of the trials, DM2 vs arctan per trial kind on the rest (trials
    the fit never saw): ``by="rep"``: fit on the odd repetitions, compare on the even ones;
    ``by="load"``: fit on the unloaded trials, compare on the loaded ones (a campaign with one
    repetition). Returns ``{"joint", "train": kinds, "heldout": kinds}``."""
    import dataclasses

    from ident.indri.campaign_fit import DynamicFits, joint_dynamic_data
    from mocap.io.campaign import load_campaign

    if by not in ("rep", "load"):
        raise ValueError(f"heldout split by 'rep' or 'load', got {by!r}")
    camp = load_campaign(campaign_dir, check_files=False)
    if joint is None:
        joint = min(j for t in camp.trials for j in t.joints)

    def train(t):
        return t.repetition % 2 == 1 if by == "rep" else t.load_kg == 0

    parts = {k: dataclasses.replace(camp, trials=tuple(t for t in camp.trials if train(t) == r))
             for k, r in (("train", True), ("heldout", False))}
    data = {k: joint_dynamic_data(c, joint) for k, c in parts.items()}
    d = data["train"]
    res = IndriTrapani().fit(d.static, d.reversals, d.variable,
                               refine_datasets=list(d.trials.values()), stiffness=d.stiffness,
                               link_datasets=d.link_reversals)
    out = {"joint": joint}
    for k, dk in data.items():
        out[k] = DynamicFits({joint: res}, {joint: dk}, ("arctan", "dm1", "dm2"),
                             camp.name).compare_by_kind(joint)
    return out


def campaign_comparison(campaign_dir, joint: int | None = None, quick: bool = False) -> dict:
    """DM2 vs arctan per trial kind on a campaign, for jointlab's procedure (phases 2-A, 2-B,
    2-C) and the paper's (2-A, 2-B); plus sigma0 and its truth where known. Returns
    ``{"joint", "kinds": {...}, "paper_kinds": {...}, "sigma0", "truth", "seconds"}`` with the
    kinds as :meth:`ident.indri.campaign_fit.DynamicFits.compare_by_kind` gives them."""
    import dataclasses

    from ident.indri.campaign_fit import DynamicFits, joint_dynamic_data
    from mocap.io.campaign import load_campaign

    camp = load_campaign(campaign_dir, check_files=False)
    if quick:
        camp = dataclasses.replace(camp, trials=tuple(t for t in camp.trials if t.repetition == 1))
    if joint is None:
        joint = min(j for t in camp.trials for j in t.joints)
    t0 = time.perf_counter()
    d = joint_dynamic_data(camp, joint)
    t1 = time.perf_counter()
    out = {"joint": joint, "n_trials": len(d.trials)}
    for key, est in (("kinds", IndriTrapani()), ("paper_kinds", IndriTrapani(refine=False))):
        res = est.fit(d.static, d.reversals, d.variable, refine_datasets=list(d.trials.values()),
                      stiffness=d.stiffness, link_datasets=d.link_reversals)
        fits = DynamicFits({joint: res}, {joint: d}, ("arctan", "dm1", "dm2"), camp.name)
        out[key] = fits.compare_by_kind(joint)
        if key == "kinds":
            out["params"] = {"sigma0": res.sigma0, "alpha": res.alpha, "beta": res.beta,
                             "gamma": res.gamma, "accel_ratio": res.accel_ratio}
            out["bristle"] = (res.refinement or {}).get("bristle", "identified")
            out["sigma0_phase2a"] = res.phase2a[res._slowest].sigma0
            out["stiffness"] = d.stiffness
            out["sigma0_bristle"] = res.sigma0_bristle
            out["sigma0_series_corrected"] = res.sigma0_series_corrected
            out["static_choice"] = res.static.diagnostics.get("static_choice", {}).get("chosen")
            out["tau_v"] = res.static.model.params["tau_v"]
    out["seconds"] = {"data": t1 - t0, "fits": time.perf_counter() - t1}
    out["truth"] = sigma0_truth(campaign_dir, joint)
    return out


def print_campaign(r: dict, title: str | None = None) -> None:
    print(f"{title or 'campaign comparison'}: joint {r['joint']}, {r['n_trials']} trials "
          f"(data {r['seconds']['data']:.1f} s, fits {r['seconds']['fits']:.1f} s)")
    for key, name in (("kinds", "jointlab (2-A, 2-B, 2-C)"), ("paper_kinds", "paper (2-A, 2-B)")):
        print(f"  {name}: DM2 / arctan RMS per trial kind (median, max over trials)")
        for kind, e in r[key].items():
            print(f"    {kind:18s} n {e['n']:3d}  arctan {e['rms_arctan']:.3f}  dm2 {e['rms_dm2']:.3f}"
                  f"  ratio median {e['ratio_median']:.3f}  max {e['ratio_max']:.3f}")
    p = r["params"]
    print("  dm2: " + ", ".join(f"{k} {v:.4g}" for k, v in p.items())
          + f"; bristle: {r['bristle']} (phase 2-A sigma0 {r['sigma0_phase2a']:.4g})")
    if r.get("stiffness") is not None:
        print(f"  declared stiffness K {r['stiffness']:.6g} N m/rad: sigma0 {p['sigma0']:.4g} is the "
              f"apparent one (motor side, bristle and spring in series); the bristle's own "
              f"(phase 2-A on the link velocity) {r['sigma0_bristle']:.4g}; the series law "
              f"1/(1/sigma0 - 1/K) gives {r['sigma0_series_corrected']:.4g}")
    print(f"  step 1: {r.get('static_choice')} arctan, tau_v {r.get('tau_v', float('nan')):.4g}")
    t = r["truth"]
    if t is not None:
        print(f"  truth ({t['form']}): c {t['c']:.3g} N m, xp {t['xp']:.3g} rad; sigma0 error "
              f"{sigma0_error(r, 'zero_deflection'):+.1f} % of the zero-deflection stiffness "
              f"{t['zero_deflection']:.4g}, {sigma0_error(r, 'c_over_xp'):+.1f} % of c/xp "
              f"{t['c_over_xp']:.4g}")
        if r.get("sigma0_bristle") is not None:
            print(f"  bristle sigma0 (link velocity) error {sigma0_error(r, which='bristle'):+.1f} % "
                  f"of the zero-deflection stiffness, "
                  f"{sigma0_error(r, 'c_over_xp', 'bristle'):+.1f} % of c/xp")


def sigma0_error(r: dict, key: str = "zero_deflection", which: str = "dm2") -> float:
    """sigma0 against the truth's ``key`` stiffness, percent (nan without a presliding truth);
    ``which``: ``"dm2"`` (the DM2's, motor side) or ``"bristle"`` (phase 2-A on the link
    velocity, with a declared stiffness; nan without one)."""
    t = r.get("truth")
    s0 = r["params"]["sigma0"] if which == "dm2" else r.get("sigma0_bristle")
    return float("nan") if t is None or s0 is None else 100.0 * (s0 / t[key] - 1.0)


# worlds of --worlds: (name, kind, arguments); "synth": jointlab synth, "foreign": make_world.py
WORLDS = (
    ("synth PA10 j5 presliding (LuGre) s3, 200 Hz", "synth", ("presliding", 3, "0.5,1.0")),
    ("synth PA10 j5 none s3, 200 Hz", "synth", ("none", 3, "0.3,0.6,1.0")),
    ("foreign ind6 j3 presliding s2 (dahl)", "foreign", ("presliding", 2)),
    ("foreign ind6 j3 presliding s3 (maxwell_slip)", "foreign", ("presliding", 3)),
    ("foreign ind6 j3 none s2", "foreign", ("none", 2)),
)


def foreign_world_dir():
    """../shared/worlds/foreign beside this checkout (or beside a parent folder of it)."""
    for p in Path(__file__).resolve().parents:
        w = p / "shared" / "worlds" / "foreign"
        if (w / "make_world.py").is_file():
            return w
    return None


def world_campaign(kind: str, arg, tmp: Path) -> Path:
    """The campaign folder of one WORLDS entry: jointlab synth into ``tmp`` (the fixture of
    tests/test_fit_dynamic.py), the foreign world through the shared cache."""
    if kind == "synth":
        from ident.cli.main import main as cli

        effect, seed, vmax = arg
        out = tmp / f"synth-{effect}-s{seed}"
        if not (out / "campaign.toml").is_file():
            rc = cli(["synth", str(out), "--effect", effect, "--seed", str(seed), "--kinds",
                      "constant_velocity,reversals,excitation", "--reps", "1", "--loads", "0",
                      "--vmax", vmax, "--duration", "8", "--quiet"])
            if rc != 0:
                raise RuntimeError(f"jointlab synth failed ({rc})")
        return out
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from _foreign import WorldArgs, ensure_campaign

    world = foreign_world_dir()
    if world is None:
        raise RuntimeError("the foreign world (shared/worlds/foreign) was not found")
    effect, seed = arg
    camp, _ = ensure_campaign(WorldArgs(effect, seed, reps=1,
                                        kinds="excitation,constant_velocity,reversals"),
                              world=world)
    return camp


def run_worlds(quick: bool = False) -> list:
    """Every world of WORLDS through :func:`campaign_comparison`; prints each and a summary.
    Returns [(name, result)]."""
    import tempfile

    out = []
    with tempfile.TemporaryDirectory() as td:
        for name, kind, arg in WORLDS:                    # loop over worlds (five)
            try:
                camp = world_campaign(kind, arg, Path(td))
            except RuntimeError as exc:
                print(f"{name}: skipped ({exc})")
                continue
            t0 = time.process_time()
            r = campaign_comparison(camp, quick=quick)
            r["cpu_s"] = time.process_time() - t0
            print_campaign(r, title=name)
            out.append((name, r))
    print("\nsummary: DM2 / arctan RMS per trial (jointlab's procedure), median / max over the "
          "trials of each kind; sigma0 error against the truth's zero-deflection stiffness "
          "(c/xp in brackets): the DM2's (motor side, apparent) and, with a declared stiffness "
          "K, phase 2-A's on the link velocity (the bristle's own)")
    for name, r in out:
        k = r["kinds"]
        cells = "  ".join(f"{kk[:5]} {k[kk]['ratio_median']:.3f}/{k[kk]['ratio_max']:.3f}"
                          for kk in ("constant_velocity", "reversals", "excitation", "all")
                          if kk in k)
        s0 = (f"  bristle: {r['bristle']}" if r["truth"] is None else
              f"  sigma0 {sigma0_error(r):+.1f} % ({sigma0_error(r, 'c_over_xp'):+.1f} %)")
        if r.get("stiffness") is not None and r.get("sigma0_bristle") is not None:
            s0 += (f" (sigma0 {r['params']['sigma0']:.4g}, link side {r['sigma0_bristle']:.4g})"
                   if r["truth"] is None else
                   f"; link side {sigma0_error(r, which='bristle'):+.1f} % "
                   f"({sigma0_error(r, 'c_over_xp', 'bristle'):+.1f} %)")
            s0 += f", K {r['stiffness']:.4g}"
        print(f"  {name:46s} {cells}{s0}  [{r['cpu_s']:.1f} s CPU]")
    return out


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="short run, loop baseline projected")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--campaign", default=None, help="per-trial-kind DM2 vs arctan on a campaign")
    ap.add_argument("--joint", type=int, default=None)
    ap.add_argument("--heldout", nargs="?", const="rep", choices=("rep", "load"), default=None,
                    help="with --campaign: fit on odd repetitions (or the unloaded trials: "
                         "--heldout load), compare on the even ones (the loaded ones)")
    ap.add_argument("--worlds", action="store_true",
                    help="DM2 vs arctan per trial kind and sigma0 error on every world of WORLDS")
    args = ap.parse_args(argv)
    if args.worlds:
        run_worlds(args.quick)
        return
    if args.campaign and args.heldout:
        r = heldout_comparison(args.campaign, args.joint, args.heldout)
        for k in ("train", "heldout"):
            print(f"  {k} trials: DM2 / arctan RMS per trial kind (median, max over trials)")
            for kind, e in r[k].items():
                print(f"    {kind:18s} n {e['n']:3d}  arctan {e['rms_arctan']:.3f}  dm2 "
                      f"{e['rms_dm2']:.3f}  ratio median {e['ratio_median']:.3f}  max "
                      f"{e['ratio_max']:.3f}")
        return
    if args.campaign:
        print_campaign(campaign_comparison(args.campaign, args.joint, args.quick))
        return

    sd, rev, var = make_data(args.quick)
    n = sd.n + sum(d.n for d in rev) + var.n
    print(f"data: {n} samples at 1 kHz (static {sd.n}, {len(rev)} reversal sets "
          f"{sum(d.n for d in rev)}, variable {var.n}); truth sigma0 {TRUTH.sigma0:g}, "
          f"alpha {TRUTH.alpha:g}, beta {TRUTH.beta:g}, gamma {TRUTH.gamma:g}")
    est = IndriTrapani()

    # ---- the recursion alone ----------------------------------------------------------------
    m = TRUTH
    qd = np.asarray(var.qd)
    t_scan, z_scan = best_of(lambda: m.states(qd, var.dt), args.repeat)
    t_loop, z_loop = best_of(lambda: loop_states(m, qd, var.dt), 1)
    t_naive, z_naive = best_of(lambda: naive_loop_states(m, qd, var.dt), 1)
    print(f"state recursion on {qd.size} samples: vectorised scan {t_scan * 1e3:.1f} ms; Python "
          f"loop over the recursion only {t_loop * 1e3:.1f} ms (ratio {t_loop / t_scan:.1f}x); "
          f"naive per-sample loop {t_naive * 1e3:.1f} ms (ratio {t_naive / t_scan:.1f}x); "
          f"max |dz| {max(np.max(np.abs(z_scan - z_loop)), np.max(np.abs(z_scan - z_naive))):.2e} rad")

    # ---- the full identification --------------------------------------------------------------
    t_fit, res = best_of(lambda: est.fit(sd, rev, var), args.repeat)
    sec = res.diagnostics["seconds"]
    print(f"full identification (vectorised): {t_fit:.2f} s  [step 1 {sec['step1']:.2f}, 2-A "
          f"{sec['phase2a']:.2f}, 2-B {sec['phase2b']:.2f}, DM1 {sec['dm1']:.2f}]; goal < 5 s: "
          f"{'met' if t_fit < 5.0 else 'NOT met'}")
    print(f"  state evaluations {res.diagnostics['n_state_evals']} over "
          f"{res.diagnostics['state_eval_samples']} samples")
    print(f"  sigma0 {res.sigma0:.1f} ({100 * (res.sigma0 / TRUTH.sigma0 - 1):+.1f}%), alpha "
          f"{res.alpha:.2f}, beta {res.beta:.2f}, gamma {res.gamma:.3f}, a_max/v_max "
          f"{res.accel_ratio:.3f}")
    ns = res.diagnostics["state_eval_samples"]
    for name, fn, t_l in (("recursion-only loop", loop_states, t_loop),
                          ("naive per-sample loop", naive_loop_states, t_naive)):
        if args.quick:
            t_base = t_fit + ns * (t_l - t_scan) / qd.size
            how = "projected from its per-sample cost"
        else:
            orig = dyn._LuGre.states
            dyn._LuGre.states = fn
            try:
                t_base, res_loop = best_of(lambda: est.fit(sd, rev, var), 1)
            finally:
                dyn._LuGre.states = orig
            how = (f"measured; same sigma0: {abs(res_loop.sigma0 / res.sigma0 - 1) < 1e-6}, "
                   f"same gamma: {abs(res_loop.gamma / res.gamma - 1) < 1e-6}")
        print(f"full identification with the {name} ({how}): {t_base:.2f} s; "
              f"ratio {t_base / t_fit:.1f}x")

if __name__ == "__main__":
    main()
