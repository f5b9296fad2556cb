"""The gap diagnosis on multi-joint, marker-less records of an independent world.

``../shared/worlds/foreign/make_world.py --record multi``: every joint moves at once in one
record, payloads, and effects outside the vocabulary (README of the world). For every robot x
effect x seed the campaign is generated (cached in ``--corpus``), ``jointlab diagnose`` runs on
it, and each joint's verdict is scored against the truth file:

* in-vocabulary friction/torque effects on their joint: named, or named as the first
  alternative where the registry declares the pair confusable (compliance and backlash are
  listed apart: the torque alone does not show a transmission's deflection);
* ``sensor_lag`` with a pure delay (FORMAT.md's ``time_offset``): ``time_offset``; with a
  low-pass: ``unexplained``;
* ``counterbalance`` and ``cable_drag``: ``unexplained`` with the right variable first in the
  configuration-space localisation (q2 for the counterbalance, the other joint's angle for the
  cable);
* ``urdf_inertia_error``, ``payload_inertia``: ``none`` on every joint (the identified nominal
  absorbs them);
* every joint that carries no effect: a verdict with status ``effect`` is a false attribution.

    python benchmarks/gap_multi.py --corpus DIR [--robots ind6,tri3] [--seeds 1,2,3] [--workers 2]
    python benchmarks/gap_multi.py --summarize RESULTS.json

Nothing here reads the world's code; the truth files are read only to score.
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from multiprocessing import get_context
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
# benchmarks/ident.py would shadow the package when this folder is on the path (python benchmarks/...)
sys.path[:] = [p for p in sys.path if Path(p or ".").resolve() != HERE]
WORLD = HERE.parents[1] / "shared" / "worlds" / "foreign"
sys.path.append(str(HERE))   # for _foreign only: benchmarks/ident.py must not shadow the package
from _foreign import diagnose_in_process  # noqa: E402

sys.path.remove(str(HERE))
IN_VOCAB = ("stribeck", "presliding", "position_ripple", "load_dependent", "thermal_drift", "torque_scale",
            "asymmetry", "nonlinear_viscous")
TRANSMISSION = ("compliance", "backlash")
OUTSIDE = ("counterbalance", "cable_drag", "sensor_lag", "urdf_inertia_error", "payload_inertia")
EFFECTS = ("none",) + OUTSIDE + IN_VOCAB + TRANSMISSION


def campaign(corpus: Path, robot: str, effect: str, seed: int, extra: tuple = (), tag: str = "") -> Path:
    """The campaign (generated when missing; a private temporary name renamed into place).
    ``extra``: more ``make_world.py`` options, ``tag`` appended to the name they make."""
    name = f"{robot}-{effect}-s{seed}{tag}"
    out = corpus / name
    if (out / "campaign.toml").is_file() and (corpus / f"{name}.truth.json").is_file():
        return out
    tmp = corpus / f"{name}.tmp{os.getpid()}"
    cmd = [sys.executable, str(WORLD / "make_world.py"), str(tmp), "--seed", str(seed), "--record", "multi",
           "--effect", effect, "--robot", robot, *extra]
    env = dict(os.environ, OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1")
    r = subprocess.run(cmd, capture_output=True, text=True, env=env)
    if r.returncode != 0:
        raise RuntimeError(f"make_world {' '.join(cmd[3:])}: {(r.stderr or r.stdout).strip()[-300:]}")
    for suf in (".truth.json", ".truth.npz"):
        os.replace(f"{tmp}{suf}", corpus / f"{name}{suf}")
    os.replace(tmp, out)
    return out


def diagnose(path: Path) -> tuple[dict | None, float, str | None]:
    """``jointlab diagnose`` in this process: (diagnosis.json, CPU seconds, error)."""
    return diagnose_in_process(path, clock=time.process_time)


def _loc_top(jr: dict) -> list:
    """The variables the residual depends on most (the first, and those the record's motion does
    not tell from it)."""
    loc = jr.get("localisation_configuration") or []
    return [loc[0]["variable"]] + list(loc[0].get("tied_with", [])) if loc else []


#: a ripple whose order covers fewer periods than this over the joint's motion is a smooth function
#: of the angle there (issue 42: a name only for a ripple the data resolve as periodic)
MIN_PERIODS = 2.0


def ripple_periods(e: dict, q_range: float) -> float:
    """Periods of a truth ripple's leading order over the joint's range of motion."""
    pj = e.get("per_joint", {})
    j0 = int(e["joint"]) - 1
    n = pj["gear"][j0] if e.get("form") == "hd_additive" else pj["n1"][j0]
    return float(n) * q_range / (2 * np.pi)


#: an in-vocabulary effect counts as one the record can show when at least this many torque noise
#: variances of it are left by a least-squares fit of the rigid body and Coulomb + viscous + offset
#: (the world's own size metric, :func:`shown_size`); the threshold of ``benchmarks/gap_single.py``
MIN_SIZE = 0.3


def shown_size(corpus: Path, name: str) -> float | None:
    """The truth's size of the effect on its joint in torque noise variances, by the world's own
    size metric (truth.json ``size_metric``): the effect's added logged torque (the truth's
    ``friction - friction_nominal`` plus ``tau_logged_clean - tau_applied``) on the true states,
    about every 10 ms, less its least-squares fit on the arm's rigid-body regressor (pinocchio, the
    campaign's URDF) and ``[sgn qd, qd, 1, qdd]`` of the joint, each half of alternating 2 s blocks
    fitted on the other. None for an effect without a joint."""
    import pinocchio as pin

    truth = json.loads((corpus / f"{name}.truth.json").read_text())
    eff = [e for e in truth["effects"] if e.get("joint")]
    if not eff:
        return None
    j = int(eff[0]["joint"]) - 1
    z = np.load(corpus / f"{name}.truth.npz")
    model = pin.buildModelFromUrdf(str(corpus / name / "robot" / "arm.urdf"))
    data = model.createData()
    A, y, half = [], [], []
    for r in sorted({k.split("/")[0] for k in z.files}):   # loop over the records
        t, q, qd, qdd = (z[f"{r}/{k}"] for k in ("time", "q_link", "qd_link", "qdd_link"))
        d = (z[f"{r}/friction"] - z[f"{r}/friction_nominal"] + z[f"{r}/tau_logged_clean"]
             - z[f"{r}/tau_applied"])[:, j]
        idx = np.arange(0, t.size, max(1, int(round(0.01 / np.median(np.diff(t))))))
        R = np.array([pin.computeJointTorqueRegressor(model, data, q[i], qd[i], qdd[i])[j] for i in idx])
        v = qd[idx, j]
        A.append(np.column_stack([R, np.sign(v), v, np.ones_like(v), qdd[idx, j]]))
        y.append(d[idx])
        half.append(np.floor(t[idx] / 2.0).astype(int) % 2)
    A, y, half = np.vstack(A), np.concatenate(y), np.concatenate(half)
    A = A[:, np.abs(A).max(axis=0) > 1e-12]
    ms = []
    for h in (0, 1):
        c, *_ = np.linalg.lstsq(A[half != h], y[half != h], rcond=None)
        ms.append(np.mean((y[half == h] - A[half == h] @ c) ** 2))
    return float(np.mean(ms) / truth["joints"][j]["torque_noise_std"] ** 2)


def score(truth: dict, rep: dict, q_range: dict | None = None) -> list[dict]:
    """One row per joint: what it carries, its verdict and whether that is right. ``q_range``:
    joint -> range of motion (rad), for the ripples (:func:`ripple_periods`)."""
    effects = {int(e["joint"]): e for e in truth["effects"] if e.get("joint")}
    rows = []
    for js, jr in sorted(rep["joints"].items(), key=lambda kv: int(kv[0])):
        j = int(js)
        e = effects.get(j)
        status, verdict = jr.get("verdict_status"), jr.get("verdict")
        alts = [a.get("effect") for a in jr.get("alternatives", [])]
        row = {"joint": j, "verdict": verdict, "status": status, "alternatives": alts,
               "where": _loc_top(jr), "text": jr.get("verdict_text")}
        name = (e or {}).get("effect")
        if name is None or name == "none":
            row.update(kind="clean", correct=status != "effect")
        elif name in ("urdf_inertia_error", "payload_inertia"):
            row.update(kind="absorbed", correct=status == "none")
        elif name == "sensor_lag" and e.get("form") == "delay":
            row.update(kind="delay", correct=verdict == "time_offset")
        elif name == "sensor_lag":
            row.update(kind="lowpass", correct=status == "unexplained")
        elif name == "counterbalance":
            row.update(kind="counterbalance", correct=status == "unexplained" and "q2" in row["where"],
                       alone=row["where"] == ["q2"])
        elif name == "cable_drag":
            k = int(e["params"]["other_joint"])
            row.update(kind="cable", correct=status == "unexplained" and f"q{k}" in row["where"], other=k,
                       alone=row["where"] == [f"q{k}"])
        elif name == "position_ripple" and q_range and ripple_periods(e, q_range[j]) < MIN_PERIODS:
            row.update(kind="ripple_smooth", correct=status == "unexplained" and f"q{j}" in row["where"],
                       named=verdict == name, periods=ripple_periods(e, q_range[j]))
        elif name in TRANSMISSION:
            row.update(kind="transmission", correct=verdict == name or (alts[:1] == [name]))
        else:
            row.update(kind="in_vocabulary", correct=verdict == name or (alts[:1] == [name]),
                       exact=verdict == name)
        row["effect"] = name or "none"
        row["form"] = (e or {}).get("form")
        rows.append(row)
    # payload / URDF errors: every joint none
    if any(e.get("effect") in ("urdf_inertia_error", "payload_inertia") for e in truth["effects"]):
        for r in rows:
            if r["kind"] == "clean":
                r["kind"], r["correct"] = "absorbed_other", r["status"] == "none"
    return rows


def run_one(job) -> dict:
    corpus, robot, effect, seed = job
    t0 = time.perf_counter()
    try:
        path = campaign(Path(corpus), robot, effect, seed)
    except Exception as exc:
        return {"robot": robot, "effect": effect, "seed": seed, "error": str(exc)}
    gen = time.perf_counter() - t0
    rep, cpu, err = diagnose(path)
    out = {"robot": robot, "effect": effect, "seed": seed, "gen_s": gen, "diagnose_cpu_s": cpu}
    if err:
        out["error"] = err
        return out
    truth = json.loads((Path(corpus) / f"{path.name}.truth.json").read_text())
    q_range = None
    if effect == "position_ripple":
        z = np.load(Path(corpus) / f"{path.name}.truth.npz")
        q = np.concatenate([z[k] for k in z.files if k.endswith("/q_link")])
        q_range = {j + 1: float(np.ptp(q[:, j])) for j in range(q.shape[1])}
    out["rows"] = score(truth, rep, q_range)
    if effect in IN_VOCAB:
        size = shown_size(Path(corpus), path.name)
        for row in out["rows"]:
            if row["kind"] == "in_vocabulary":
                row["size_noise_var"] = size
    out["log_hz"] = truth.get("rates", {}).get("log_hz")
    out["record_s"] = None
    return out


def summarize(results: list) -> dict:
    by = {}
    for r in results:
        for row in r.get("rows", []):
            by.setdefault(row["kind"], []).append((r, row))
    lines, summary = [], {}
    goals = {"in_vocabulary": 0.9, "delay": 0.9, "lowpass": 0.9, "counterbalance": 0.9, "cable": 0.9,
             "absorbed": 0.9, "absorbed_other": 0.9}
    for kind in ("in_vocabulary", "ripple_smooth", "transmission", "delay", "lowpass", "counterbalance", "cable",
                 "absorbed", "absorbed_other", "clean"):
        rows = by.get(kind, [])
        if not rows:
            continue
        ok = sum(1 for _, x in rows if x["correct"])
        summary[kind] = {"correct": ok, "n": len(rows)}
        label = {"clean": "joints without an effect: not attributed",
                 "ripple_smooth": f"position ripples of < {MIN_PERIODS:g} periods over the motion: unexplained, "
                                  "depends on the joint's own angle"}.get(kind, kind)
        goal = (f"; goal >= {goals[kind]:g}" if kind in goals else "; goal: 0 false attributions"
                if kind == "clean" else "")
        lines.append(f"{label}: {ok} of {len(rows)} ({ok / len(rows):.3f}{goal})")
        if kind == "in_vocabulary" and all("size_noise_var" in x for _, x in rows):
            big = [x for _, x in rows if x["size_noise_var"] is not None and x["size_noise_var"] >= MIN_SIZE]
            okb = sum(1 for x in big if x["correct"])
            summary[kind + "_shown"] = {"correct": okb, "n": len(big), "min_size": MIN_SIZE}
            lines.append(f"  of which the record can show (>= {MIN_SIZE:g} noise variances left by the world's "
                         f"size metric): {okb} of {len(big)} ({okb / max(len(big), 1):.3f})")
        if kind in ("counterbalance", "cable"):
            alone = sum(1 for _, x in rows if x["correct"] and x.get("alone"))
            lines.append(f"  of which the right variable alone (not tied with another joint's angle): {alone}")
        if kind in ("clean", "absorbed_other"):
            unx = sum(1 for _, x in rows if x["status"] == "unexplained")
            lines.append(f"  of which unexplained (a gap the nominal leaves, e.g. another joint's effect leaking "
                         f"through the shared inertial parameters): {unx}")
    errs = [r for r in results if r.get("error")]
    cpu = sorted(r["diagnose_cpu_s"] for r in results if "diagnose_cpu_s" in r)
    if cpu:
        lines.append(f"diagnose CPU per campaign: median {cpu[len(cpu) // 2]:.1f} s, max {cpu[-1]:.1f} s "
                     f"({len(cpu)} campaigns)")
    for kind in ("in_vocabulary", "ripple_smooth", "transmission", "delay", "lowpass", "counterbalance", "cable",
                 "absorbed", "absorbed_other", "clean"):
        for r, x in by.get(kind, []):
            if not x["correct"]:
                lines.append(f"  miss [{kind}] {r['robot']}-{r['effect']}-s{r['seed']} joint {x['joint']} "
                             f"({x['effect']}/{x['form']}"
                             + (f", {x['size_noise_var']:.2g} noise variances" if x.get("size_noise_var") is not None
                                else "") + f"): {x['text']}")
    for r in errs:
        lines.append(f"  error {r['robot']}-{r['effect']}-s{r['seed']}: {r['error']}")
    return {"summary": summary, "lines": lines}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--corpus", default=os.environ.get("JOINTLAB_CORPUS", str(Path.home() / ".cache" / "jointlab"
                                                                            / "foreign-multi")))
    ap.add_argument("--robots", default="ind6,tri3")
    ap.add_argument("--seeds", default="1,2,3")
    ap.add_argument("--effects", default=",".join(EFFECTS))
    ap.add_argument("--workers", type=int, default=1)
    ap.add_argument("--out", default=None, help="results JSON (default benchmarks/results/gap/multi-<date>.json)")
    ap.add_argument("--summarize", default=None, help="reprint a results file")
    ap.add_argument("--rescore", action="store_true", help="with --summarize: add the truth's effect sizes "
                    "(shown_size) from --corpus to the file")
    a = ap.parse_args(argv)
    if a.summarize:
        res = json.loads(Path(a.summarize).read_text())
        if a.rescore:   # add the truth's sizes to an earlier results file (no diagnosis re-run)
            for r in res["results"]:
                if r.get("effect") in IN_VOCAB and r.get("rows"):
                    size = shown_size(Path(a.corpus), f"{r['robot']}-{r['effect']}-s{r['seed']}")
                    for row in r["rows"]:
                        if row["kind"] == "in_vocabulary":
                            row["size_noise_var"] = size
            res["summary"] = summarize(res["results"])["summary"]
            Path(a.summarize).write_text(json.dumps(res, indent=1))
        print("\n".join(summarize(res["results"])["lines"]))
        return 0
    corpus = Path(a.corpus)
    corpus.mkdir(parents=True, exist_ok=True)
    jobs = [(str(corpus), r, e, int(s)) for s in a.seeds.split(",") for r in a.robots.split(",")
            for e in a.effects.split(",") if e]
    results = []
    ctx = get_context("spawn")
    with ctx.Pool(a.workers) as pool:
        for i, r in enumerate(pool.imap(run_one, jobs)):
            results.append(r)
            bad = [x for x in r.get("rows", []) if not x["correct"]]
            print(f"[{i + 1}/{len(jobs)}] {r['robot']}-{r['effect']}-s{r['seed']}: "
                  + (r.get("error") or ("ok" if not bad else "; ".join(f"j{x['joint']} {x['text']}" for x in bad))),
                  flush=True)
    summ = summarize(results)
    print("\n".join(summ["lines"]))
    out = Path(a.out) if a.out else HERE / "results" / "gap" / "multi-records.json"
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps({"command": " ".join(["python", "benchmarks/gap_multi.py"] + (argv or sys.argv[1:])),
                               "summary": summ["summary"], "results": results}, indent=1))
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
