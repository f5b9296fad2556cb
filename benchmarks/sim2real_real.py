"""The three models' held-out rollout errors on the real TX40 and TIAGo records, from their vendor
URDFs as they come (issue 43 acceptance; the table in docs/sim2real.md).

Runs ``jointlab sim2real fixtures/real/<arm> --out OUT/<arm>`` (diagnosis-named effects, mujoco.sysid
beside), or reuses ``OUT/<arm>/sim2real.json`` where it exists, and prints per arm and scored
joint the held-out position RMS at 0.5 s of the model as given, the native fit, mujoco.sysid and
the native fit + the named effects.

    python benchmarks/sim2real_real.py [--out /tmp/s2r-real]
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
MODELS = ("given", "native", "sysid", "native_effects")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--out", type=Path, default=Path("/tmp/s2r-real"))
    a = ap.parse_args(argv)
    from ident.cli.main import main as jl

    print("| arm | joint | named effect | as given | native fit | mujoco.sysid | native + named effects |")
    print("|---|---|---|---|---|---|---|")
    for arm in ("tx40", "tiago"):
        out = a.out / arm
        if not (out / "sim2real.json").is_file():
            jl(["sim2real", str(ROOT / "fixtures" / "real" / arm), "--out", str(out)])
        rep = json.loads((out / "sim2real.json").read_text())
        named = rep["effects"]["named"]
        for j in rep["scored_joints"]:
            cells = []
            for m in MODELS:
                e = (rep["errors"].get(m, {}).get("0.5") or {}).get(str(j))
                cells.append("-" if e is None else f"{e['pos_rms'] * 1e3:.3g}")
            kept = rep["effect_choice"].get(str(j), {}).get("kept")
            nm = ", ".join(named.get(str(j), [])) or "-"
            if nm != "-" and kept is False:
                nm += " (dropped)"
            print(f"| {arm} | {j} | {nm} | " + " | ".join(cells) + " |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
