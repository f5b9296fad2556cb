"""Benchmark: the thesis chain (eq. 2-4, Coulomb + viscous) on campaigns jointlab did not write.

Issue 13 item 5. Per world and joint it prints the Coulomb and viscous errors against the
truth (median over trials of |estimate / truth - 1|) through

* the MARKER path: ``jointlab mocap`` link angles -> :func:`ident.thesis.campaign_fit.fit_trial_joint`
  (link state = encoder + the deflection the markers support, :mod:`ident.model.linkstate`);
* the ENCODER path: the same fit without angles (encoder + nominal deflection);

their ratio (acceptance: marker path within 3 % and within 1.5x the encoder path, an encoder
error under 0.5 % counting as 0.5 %: the ratio of two near-zero errors is noise), the
derivative method and bandwidths chosen, and how many fits report an errors-in-variables bias
above their standard error.

Viscous basis: the foreign world's friction ``c tanh(qm'/eps) + b qm'`` acts on the motor side
of the spring, beside the motor viscous ``B`` of drives.toml; eq. 2-4 removes ``B qmd`` in its
target, so the fitted ``v`` is compared with ``b`` (link-only basis), not with ``b + B``.

Worlds: the cached foreign campaigns ($JOINTLAB_CORPUS/<name>, default ~/.cache/jointlab/foreign, made by
``../shared/worlds/foreign/make_world.py``, see INDEX.md there) and a ``jointlab synth``
campaign (holds before/after each excitation; made once into the cache folder). Marker angles
are solved once per campaign into the cache folder (``--cache``, default /tmp/jointlab-bench-ident).

    python benchmarks/ident.py                 # all excitation trials of every world
    python benchmarks/ident.py --quick         # 4 trials per world
    python benchmarks/ident.py --worlds ind6-j5-none-s2 --kinds excitation,constant_velocity
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import os
import subprocess
import sys
import time
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from mocap.io.campaign import load_campaign  # noqa: E402
from ident.study.executor import make_executor  # noqa: E402
from ident.thesis.campaign_fit import campaign_tasks, fit_trial_joint  # noqa: E402

FOREIGN = Path(os.environ.get("JOINTLAB_CORPUS", Path.home() / ".cache" / "jointlab" / "foreign"))
FOREIGN_WORLDS = ("ind6-j3-none-s1", "ind6-j5-none-s2", "tri3-j2-none-s4")
SYNTH = dict(name="pa10-j35-none-s7", args=["--effect", "none", "--seed", "7", "--joints", "3,5",
                                             "--loads", "0,3.373", "--vmax", "0.5,1.0", "--reps", "3",
                                             "--kinds", "excitation"])
GOAL_REL = 0.03
GOAL_RATIO = 1.5


def _cli(args, cwd=REPO):
    r = subprocess.run([sys.executable, "-c", "import sys; from ident.cli.main import main; "
                        "sys.exit(main(sys.argv[1:]))", *map(str, args)], cwd=cwd,
                       capture_output=True, text=True)
    if r.returncode != 0:
        raise RuntimeError(f"jointlab {' '.join(map(str, args[:2]))}: {r.stderr.strip()[-400:]}")
    return r


def synth_world(cache: Path) -> tuple[Path, dict] | None:
    """The synth campaign (made once) and its per-joint truth {joint: (c, v)}."""
    camp = cache / SYNTH["name"]
    if not (camp / "campaign.toml").is_file():
        _cli(["synth", camp, *SYNTH["args"], "--quiet"])
    truth = json.loads(camp.with_suffix(".truth.json").read_text()) if camp.with_suffix(".truth.json").is_file() \
        else json.loads(Path(str(camp) + ".truth.json").read_text())
    return camp, _synth_truth(truth)


def _synth_truth(doc) -> dict:
    """{joint: (c, v)} from a ``jointlab synth`` truth file (link-side Coulomb + viscous)."""
    out = {}
    for key in ("joints", "friction"):
        if key in doc and isinstance(doc[key], (list, dict)):
            items = doc[key].items() if isinstance(doc[key], dict) else enumerate(doc[key], 1)
            for j, d in items:
                if isinstance(d, dict) and d.get("studied", True):
                    fr = (d.get("true_models") or {}).get("cv") or d.get("friction", d)
                    c = fr.get("c", fr.get("coulomb"))
                    v = fr.get("v", fr.get("viscous"))
                    if c is not None and v is not None:
                        out[int(d.get("joint", j))] = (float(c), float(v))
            if out:
                return out
    raise KeyError("no per-joint Coulomb/viscous truth found in the synth truth file")


def foreign_truth(name: str) -> dict:
    doc = json.loads((FOREIGN / f"{name}.truth.json").read_text())
    return {int(j["joint"]): (float(j["coulomb"]), float(j["viscous"])) for j in doc["joints"]}


def angles_for(camp: Path, cache: Path, trial_ids) -> Path:
    """``jointlab mocap`` angles of ``trial_ids`` (solved once into the cache)."""
    out = cache / f"mocap-{camp.name}"
    have = {p.stem for p in (out / "angles").glob("*.csv")} if (out / "angles").is_dir() else set()
    todo = [t for t in trial_ids if t not in have]
    if todo:
        tmp = cache / f"mocap-{camp.name}-part{len(have)}"
        args = ["mocap", camp, "--out", tmp]
        for t in todo:
            args += ["--trial", t]
        _cli(args)
        (out / "angles").mkdir(parents=True, exist_ok=True)
        for p in (tmp / "angles").glob("*.csv"):
            p.replace(out / "angles" / p.name)
    return out / "angles"


def run_world(name, camp: Path, truth: dict, cache: Path, kinds, n_trials, executor) -> list[dict]:
    c = load_campaign(camp, check_files=False)
    trials = [t for t in c.trials if t.kind in kinds]
    if n_trials:
        trials = trials[:n_trials]
    sub = dataclasses.replace(c, trials=tuple(trials))
    ids = [t.id for t in trials]
    t0 = time.perf_counter()
    ang = angles_for(camp, cache, ids)
    t_mocap = time.perf_counter() - t0
    rows = []
    for path_name, angles_dir in (("marker", ang), ("encoder", None)):
        tasks, _ = campaign_tasks(sub, angles_dir, models=("cv",))
        tasks = [t for t in tasks if t.trial in set(ids)]
        t0 = time.perf_counter()
        entries = executor.map(fit_trial_joint, tasks, desc=f"{name} {path_name}")
        dt = time.perf_counter() - t0
        for e in entries:
            f = e.fits["cv"]
            c0, v0 = truth[e.task.joint]
            ls = e.signals.get("link_state") or {}
            rows.append({"world": name, "path": path_name, "trial": e.task.trial, "joint": e.task.joint,
                         "kind": e.task.kind, "c_err": f.params["c"] / c0 - 1, "v_err": f.params["v"] / v0 - 1,
                         "motor": f"{e.signals['motor_fit']['method']} {e.signals['motor_fit']['bandwidth_hz']:.0f} Hz",
                         "link": e.signals["link_fit"]["method"] + (
                             f" (encoder {ls['motor_method']} {ls['motor_bandwidth_hz']:.0f} Hz)"
                             if ls.get("motor_bandwidth_hz") is not None else ""),
                         "side": ls.get("friction_side"),
                         "defl_hz": (ls.get("nominal_bandwidth_hz") or float("nan")),
                         "eiv": bool(f.eiv and f.eiv["exceeds_se"]), "seconds": dt / max(len(entries), 1),
                         "mocap_s": t_mocap})
    return rows


def _med(x):
    x = np.asarray(x, float)
    x = x[np.isfinite(x)]
    return float(np.median(x)) if x.size else float("nan")


def report(rows, truths) -> bool:
    ok_all = True
    print(f"{'world':18s} {'joint':>5s} {'kind':>12s} {'n':>3s} | {'marker c':>8s} {'v':>7s} | "
          f"{'encoder c':>9s} {'v':>7s} | {'ratio c':>7s} {'v':>6s} | derivative method (marker path)")
    keys = sorted({(r["world"], r["joint"], r["kind"]) for r in rows})
    for w, j, k in keys:
        m = [r for r in rows if (r["world"], r["joint"], r["kind"], r["path"]) == (w, j, k, "marker")]
        e = [r for r in rows if (r["world"], r["joint"], r["kind"], r["path"]) == (w, j, k, "encoder")]
        mc, mv = _med([abs(r["c_err"]) for r in m]), _med([abs(r["v_err"]) for r in m])
        ec, ev = _med([abs(r["c_err"]) for r in e]), _med([abs(r["v_err"]) for r in e])
        rc, rv = mc / max(ec, 1e-4), mv / max(ev, 1e-4)
        meth = sorted({f"{r['motor']} + {r['link']} (friction {r['side']} side, deflection "
                       f"{r['defl_hz']:.0f} Hz)" for r in m})
        ok = mc <= GOAL_REL and mv <= GOAL_REL and (mc <= GOAL_RATIO * max(ec, 0.005)) \
            and (mv <= GOAL_RATIO * max(ev, 0.005))
        ok_all &= ok
        c0, v0 = truths[w][j]
        print(f"{w:18s} {j:5d} {k:>12s} {len(m):3d} | {100 * mc:7.2f}% {100 * mv:6.2f}% | {100 * ec:8.2f}% "
              f"{100 * ev:6.2f}% | {rc:7.2f} {rv:6.2f} | {'; '.join(meth)}"
              f"  [truth c {c0:.3g} N m, v {v0:.3g} N m s/rad (link-only basis); EIV bias > se in "
              f"{sum(r['eiv'] for r in m)}/{len(m)}]  {'OK' if ok else 'MISSED'}")
    return ok_all


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help="4 trials per world")
    ap.add_argument("--worlds", default=",".join(FOREIGN_WORLDS + (SYNTH["name"],)))
    ap.add_argument("--kinds", default="excitation")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--cache", type=Path, default=Path(os.environ.get("TMPDIR", "/tmp")) / "jointlab-bench-ident")
    ap.add_argument("--synth-dir", type=Path, default=None,
                    help="folder holding the synth campaign (default: the cache)")
    args = ap.parse_args(argv)
    args.cache.mkdir(parents=True, exist_ok=True)
    kinds = tuple(k.strip() for k in args.kinds.split(",") if k.strip())
    n_trials = 4 if args.quick else None
    ex = make_executor(args.workers, progress=False)
    rows, truths = [], {}
    t0 = time.perf_counter()
    try:
        for w in [w.strip() for w in args.worlds.split(",") if w.strip()]:
            try:
                if w == SYNTH["name"]:
                    camp, truth = synth_world(args.synth_dir or args.cache)
                else:
                    camp = FOREIGN / w
                    if not (camp / "campaign.toml").is_file():
                        print(f"{w}: not cached under {FOREIGN} (see INDEX.md there): skipped")
                        continue
                    truth = foreign_truth(w)
                truths[w] = truth
                rows += run_world(w, camp, truth, args.cache, kinds, n_trials, ex)
            except (RuntimeError, KeyError, OSError) as exc:
                print(f"{w}: skipped ({exc})")
    finally:
        ex.close()
    ok = report(rows, truths) if rows else False
    per = _med([r["seconds"] for r in rows])
    print(f"\n{len(rows)} fits in {time.perf_counter() - t0:.0f} s ({per:.2f} s per trial-joint fit, "
          f"{args.workers} workers); acceptance (marker path <= {100 * GOAL_REL:.0f} % and <= "
          f"{GOAL_RATIO}x the encoder path, median over trials): {'met' if ok else 'NOT met'}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
