"""Gap diagnosis on single records (issue 25): one excitation trial of a foreign-world campaign,
the others removed from campaign.toml (the shape of the robot logs users bring).

Campaigns come from ../shared/worlds/foreign/make_world.py with ``--reps 1`` (6 excitation trials:
2 loads x 3 speeds), cached under $JOINTLAB_CORPUS (default ~/.cache/jointlab/foreign) by
:mod:`_foreign`. From each, single-record campaigns are cut (campaign.toml with one [[trial]];
every other file linked) and diagnosed only through ``jointlab diagnose`` (read back from
diagnosis.json). Scoring uses the world's truth files alone (:func:`_foreign.truth_reference` on
that one trial, with free rigid-body corrections ``[qdd, sin q, cos q]`` in both of its models:
the URDF's inertial parameters are never exact, and with one payload a torque gain is one of
them): an effect counts as one the record can show when its true structure removes at
least ``--min-size`` (0.3) of the torque noise variance on the record (torque effects), or when
its true deflection / clock error exceeds the transmission channel's noise floor by that much in
variance (compliance, backlash, time_offset).

Prints per effect: records, how many the data can show, named right among those, `insufficient
data` among those; on effect-free records the false attributions; runtime.

    python benchmarks/gap_single.py                      # 3 seeds x 2 robots x 11 effects, 2 records each + controls
    python benchmarks/gap_single.py --quick              # 1 seed, tri3
    python benchmarks/gap_single.py --summarize FILE     # reprint a results file
"""
from __future__ import annotations

import argparse
import importlib.util
import json
import os
import re
import shutil
import subprocess
import sys
import tempfile
import time
from collections import defaultdict
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path[:] = [p for p in sys.path if Path(p or ".").resolve() != HERE]
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")


def _load_foreign():
    spec = importlib.util.spec_from_file_location("jointlab_bench_foreign", HERE / "_foreign.py")
    mod = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = mod
    spec.loader.exec_module(mod)
    return mod


F = _load_foreign()
TRANSMISSION = ("compliance", "backlash", "time_offset")


def single_record(campaign: Path, trial_id: str, dest: Path) -> Path:
    """A copy of ``campaign`` whose manifest lists only ``trial_id`` (files linked, not copied)."""
    text = (campaign / "campaign.toml").read_text()
    head, *blocks = re.split(r"(?m)^\[\[trial\]\]\n", text)
    keep = [b for b in blocks if re.search(rf'(?m)^id = "{re.escape(trial_id)}"$', b)]
    if len(keep) != 1:
        raise RuntimeError(f"{campaign}: trial {trial_id} not found")
    dest.mkdir(parents=True)
    for sub in ("robot", "static", "calib", "trials"):
        if (campaign / sub).exists():
            os.symlink(campaign / sub, dest / sub)
    (dest / "campaign.toml").write_text(head + "[[trial]]\n" + keep[0])
    return dest


def records_of(campaign: Path, per: str) -> list[str]:
    ids = re.findall(r'(?m)^id = "([^"]+)"$', (campaign / "campaign.toml").read_text())
    if per == "all":
        return ids
    return [i for i in ids if "-v100-" in i]


def run_one(job) -> dict:
    wa, tid, cache, min_size = job
    camp, _ = F.ensure_campaign(wa, cache)
    res = {"effect": wa.effect, "robot": wa.robot, "seed": wa.seed, "trial": tid, "name": wa.name}
    with tempfile.TemporaryDirectory(prefix="jl-single-") as wd:
        rec = single_record(camp, tid, Path(wd) / "rec")
        t0 = time.perf_counter()
        r = subprocess.run([sys.executable, "-m", "ident.cli", "diagnose", str(rec), "--out", str(Path(wd) / "out")],
                           capture_output=True, text=True, cwd=HERE.parent,
                           # the record links the campaign's files (docs/inputs.md: allowed explicitly)
                           env=dict(os.environ, PYTHONPATH=str(HERE.parent), JOINTLAB_FOLLOW_LINKS="1"))
        res["diagnose_s"] = time.perf_counter() - t0
        if r.returncode != 0:
            return {**res, "error": (r.stderr or r.stdout).strip().splitlines()[-1:]}
        rep = json.loads((Path(wd) / "out" / "diagnosis.json").read_text())
    jr = rep["joints"][str(wa.moving_joint)]
    res.update(verdict=jr["verdict"], status=jr.get("verdict_status"), text=jr.get("verdict_text"),
               alternatives=[a["effect"] for a in jr.get("alternatives", [])],
               detectable=jr.get("detectable_over_floor"),
               extrapolated=(jr.get("channels", {}).get("torque") or {}).get("heldout_extrapolated_share"))
    ref = F.truth_reference(camp, wa.moving_joint, trial_ids=[tid], rigid_free=True)
    noise = ref.noise_rms ** 2
    res["size_torque"] = (ref.rms_nominal ** 2 - ref.rms_true ** 2) / noise if noise > 0 else float("nan")
    tn = (jr.get("channels", {}).get("transmission") or {}).get("noise_floor_rms")
    if tn:
        res["size_transmission"] = (max(ref.deflection_gap_rms_deg, ref.marker_clock_error_rms_deg
                                        if wa.effect == "time_offset" else 0.0) * 3.141592653589793 / 180) ** 2 / tn ** 2
    size = res.get("size_transmission", 0.0) if wa.effect in TRANSMISSION else res["size_torque"]
    res["size"] = size
    res["showable"] = wa.effect != "none" and size >= min_size
    return res


def summarize(rows: list, min_size: float) -> dict:
    by = defaultdict(list)
    for r in rows:
        by[r["effect"]].append(r)
    print(f"\nSingle-record gap diagnosis (foreign world, one excitation trial per campaign; "
          f"showable = true structure removes >= {min_size:g} noise variances)\n")
    print("| effect | records | showable | named right | named with alternative | insufficient data | other verdicts |")
    print("|---|---:|---:|---:|---:|---:|---|")
    tot = dict(show=0, right=0, insuf=0)
    for e, rs in sorted(by.items()):
        if e == "none":
            continue
        sh = [r for r in rs if r.get("showable") and "error" not in r]
        right = [r for r in sh if r["verdict"] == e]
        alt = [r for r in sh if r["verdict"] != e and e in r.get("alternatives", [])]
        insuf = [r for r in sh if r.get("status") == "insufficient_data"]
        other = sorted({r["verdict"] if r["verdict"] != "none" else r.get("status", "none") for r in sh
                        if r["verdict"] != e})
        tot["show"] += len(sh)
        tot["right"] += len(right)
        tot["insuf"] += len(insuf)
        print(f"| {e} | {len(rs)} | {len(sh)} | {len(right)} | {len(alt)} | {len(insuf)} | {', '.join(other)} |")
    ctrl = [r for r in by.get("none", []) if "error" not in r]
    fa = [r for r in ctrl if r["verdict"] != "none"]
    st = defaultdict(int)
    for r in ctrl:
        st[r.get("status")] += 1
    errors = [r for r in rows if "error" in r]
    out = {"showable": tot["show"], "named_right": tot["right"],
           "named_right_share": tot["right"] / max(tot["show"], 1), "insufficient_among_showable": tot["insuf"],
           "controls": len(ctrl), "false_attributions": len(fa),
           "false_attribution_share": len(fa) / max(len(ctrl), 1), "control_status": dict(st),
           "errors": len(errors)}
    print(f"\nnamed right among showable: {tot['right']} of {tot['show']} ({out['named_right_share']:.3f}); "
          f"insufficient data among showable: {tot['insuf']}")
    print(f"effect-free records: {len(ctrl)}, false attributions {len(fa)} ({out['false_attribution_share']:.3f}: "
          f"{', '.join(sorted(r['verdict'] for r in fa)) or '-'}); statuses {dict(st)}")
    ex = [r["extrapolated"] for r in rows if r.get("extrapolated") is not None]
    if ex:
        # held-out torque samples that their fold's training rows cannot predict (leverage > 1):
        # above 5 % the verdict is `insufficient data` (the record does not repeat its motion)
        print(f"held-out extrapolation (share of samples with leverage > 1): max {max(ex):.3f} over "
              f"{len(ex)} records; records above 5 %: {sum(x > 0.05 for x in ex)}")
        out["extrapolated_max"] = max(ex)
    if errors:
        print(f"errors: {len(errors)} (first: {errors[0]['name']} {errors[0]['trial']}: {errors[0]['error']})")
    ds = sorted(r["diagnose_s"] for r in rows if "diagnose_s" in r)
    if ds:
        print(f"diagnose per record: median {ds[len(ds) // 2]:.1f} s, max {ds[-1]:.1f} s")
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--robots", default="ind6,tri3")
    ap.add_argument("--effects", default=",".join(F.EFFECTS))
    ap.add_argument("--controls", type=int, default=3, help="effect-free campaigns per robot (every trial a record)")
    ap.add_argument("--min-size", type=float, default=0.3)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--cache", type=Path, default=None)
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--out", type=Path, default=None, help="write the rows as JSON")
    ap.add_argument("--summarize", type=Path, default=None)
    a = ap.parse_args(argv)
    if a.summarize:
        summarize(json.loads(a.summarize.read_text())["rows"], a.min_size)
        return 0
    robots = a.robots.split(",") if not a.quick else ["tri3"]
    seeds = a.seeds if not a.quick else 1
    effects = [e for e in a.effects.split(",") if e]
    jobs = []
    for robot in robots:
        for s in range(1, seeds + 1):
            for e in effects:
                wa = F.WorldArgs(e, s, 1.0, robot, reps=1)
                camp, _ = F.ensure_campaign(wa, a.cache)
                jobs += [(wa, t, a.cache, a.min_size) for t in records_of(camp, "v100")]
        for s in range(1, a.controls + 1):
            wa = F.WorldArgs("none", s, 1.0, robot, reps=1)
            camp, _ = F.ensure_campaign(wa, a.cache)
            jobs += [(wa, t, a.cache, a.min_size) for t in records_of(camp, "all")]
    t0 = time.perf_counter()
    with ProcessPoolExecutor(a.workers) as ex:
        rows = list(ex.map(run_one, jobs))
    print(f"{len(rows)} records in {time.perf_counter() - t0:.0f} s ({a.workers} workers)")
    out = summarize(rows, a.min_size)
    if a.out:
        a.out.write_text(json.dumps({"summary": out, "rows": rows}, indent=1, default=str))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
