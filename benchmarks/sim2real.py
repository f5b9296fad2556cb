"""Sim-to-real in MuJoCo over the foreign world's multi-joint records (issue 43 acceptance).

For each withheld effect and seed: generate (or reuse, under --cache) a campaign with
``make_world.py --record multi --robot ind6 --effect E --seed S``, run
:func:`ident.sim2real.pipeline.sim2real_campaign` with the effects jointlab's diagnosis names
(and mujoco.sysid beside), and print the held-out position RMS at the 0.5 s horizon on the effect's
joint (from the campaign's truth) for the native fit, mujoco.sysid on the same parameters, and the
native fit + the named effects, with the ratios the acceptance asks (<= 0.7 against both). Where
the diagnosis does not name the true effect on that joint, a second run gives the true name
(``--effects J:E``, no sysid) and its ratio is printed beside, and the diagnosis's verdict on that
joint is quoted (an ``unexplained`` term names no effect). Effect-free campaigns (``none``):
the RMS over all scored joints and the worst joint's ratio (acceptance <= 1.05).

    python benchmarks/sim2real.py [--effects stribeck,...,none] [--seeds 1,2] [--cache DIR] [--threads N]
"""
from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
MAKE = ROOT.parent / "shared" / "worlds" / "foreign" / "make_world.py"


def campaign(cache: Path, effect: str, seed: int) -> Path:
    d = cache / f"{effect}-s{seed}"
    if not (d / "campaign.toml").is_file():
        subprocess.run([sys.executable, str(MAKE), str(d), "--seed", str(seed), "--record", "multi",
                        "--effect", effect, "--robot", "ind6"], check=True, capture_output=True)
    return d


def pos(rep, model, joints):
    """Held-out position RMS (mrad) at 0.5 s over ``joints`` (pooled), or None."""
    e = rep["errors"].get(model, {}).get("0.5")
    if not e:
        return None
    return 1e3 * float(np.sqrt(np.mean([e[str(j)]["pos_rms"] ** 2 for j in joints])))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--effects", default="stribeck,load_dependent,nonlinear_viscous,position_ripple,presliding,none")
    ap.add_argument("--seeds", default="1,2")
    ap.add_argument("--cache", type=Path, default=Path("/tmp/s2r-corpus"))
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--json", type=Path, help="also write every run's numbers here")
    a = ap.parse_args(argv)
    from mocap.io.campaign import load_campaign
    from ident.sim2real.pipeline import sim2real_campaign

    print("| effect | seed | joint | named by the diagnosis | native | mujoco.sysid | native + named effects | "
          "/ native | / sysid | native + true effect | / native | seconds |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|")
    rows = []
    for eff in a.effects.split(","):
        for seed in (int(s) for s in a.seeds.split(",")):
            d = campaign(a.cache, eff, seed)
            truth = json.loads(Path(str(d) + ".truth.json").read_text())
            ej = next((e.get("joint") for e in truth["effects"] if e["effect"] == eff), None)
            c = load_campaign(d)
            t0 = time.perf_counter()
            rep = sim2real_campaign(c, sysid=True, nthread=a.threads).report
            joints = [ej] if ej else rep["scored_joints"]
            named = rep["effects"]["named"]
            nat, sy, fx = (pos(rep, m, joints) for m in ("native", "sysid", "native_effects"))
            true_cells = ["-", "-"]
            verdict = rep["effects"]["diagnosis_verdicts"].get(str(ej)) if ej else None
            row = {"effect": eff, "seed": seed, "joint": ej, "named": named, "verdict": verdict,
                   "native": nat, "sysid": sy,
                   "native_effects": fx, "effect_choice": rep["effect_choice"], "seconds": rep["seconds"]}
            if ej and named.get(str(ej)) != [eff]:
                rt = sim2real_campaign(c, effects={ej: (eff,)}, sysid=False, nthread=a.threads).report
                te, tn = pos(rt, "native_effects", joints), pos(rt, "native", joints)
                true_cells = [f"{te:.3g}", f"{te / tn:.2f}"]
                row["true_name"] = {"native": tn, "native_effects": te}
            elif ej:
                true_cells = ["(same)", f"{fx / nat:.2f}"]
            sec = time.perf_counter() - t0
            if not ej:       # effect-free: the worst joint's ratio
                worst = max(pos(rep, "native_effects", [j]) / pos(rep, "native", [j]) for j in rep["scored_joints"])
                ratio = f"{fx / nat:.2f} (worst joint {worst:.2f})"
                row["worst_joint_ratio"] = worst
            else:
                ratio = f"{fx / nat:.2f}"
            nm = ", ".join(f"{j}:{v[0]}" for j, v in named.items()) or "none"
            if ej and str(ej) not in named and verdict:     # what the diagnosis said on the joint
                nm += f" (joint {ej}: {verdict.split(';')[0][:90]})"
            print(f"| {eff} | {seed} | {ej or 'all'} | {nm} | {nat:.3g} | "
                  + (f"{sy:.3g}" if sy is not None else "-") + f" | {fx:.3g} | {ratio} | "
                  + (f"{fx / sy:.2f}" if sy else "-") + " | " + " | ".join(true_cells) + f" | {sec:.0f} |",
                  flush=True)
            rows.append(row)
    if a.json:
        a.json.write_text(json.dumps(rows, indent=1, default=float))
    return 0


if __name__ == "__main__":
    sys.exit(main())
