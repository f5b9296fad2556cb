"""Gap diagnosis on real data: the Staubli TX40 logs of figaroh-examples (../shared/data/real/tx40).

One continuous 9 s record of all six joints moving together, motor positions and torques at
5 kHz, no markers: torque channel only, 20 contiguous segments as held-out folds (blocks of the
sign-flip test). Prints, per
joint, the verdict, the held-out RMS before/after, the white-noise floor and the candidates.

    python benchmarks/gap_tx40.py [--folder PATH] [--json FILE]
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

sys.path[:] = [p for p in sys.path if Path(p or ".").resolve() != Path(__file__).resolve().parent]
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

REAL = Path(__file__).resolve().parents[2] / "shared" / "data" / "real" / "tx40"
FIXTURE = Path(__file__).resolve().parents[1] / "fixtures" / "real" / "tx40"


def fit_tx40_campaign(folder: Path = FIXTURE) -> str:
    """The multi-joint identification of the TX40 campaign fixture (what `jointlab fit` does)
    against the published friction of ``TX40_config.yaml``: a table."""
    import numpy as np

    from mocap.io.campaign import load_campaign
    from ident.model.multijoint import fit_multijoint_campaign
    from ident.thesis.campaign_fit import read_tx40_config

    camp = load_campaign(folder)
    cfg = read_tx40_config(folder / "TX40_config.yaml")
    res = fit_multijoint_campaign(camp, ("cv",))
    fit = res.fits[camp.trials[0].id]["cv"]
    m6 = fit.motors.get("6", {})
    lines = [fit.method, "joint  fv_fit   fv_pub  ratio |  fs_fit   fs_pub  ratio",
             ]
    for j in range(6):
        p = fit.joints[str(j + 1)]["params"]
        fv = p["v"] + (m6.get("fv", 0.0) if j >= 4 else 0.0)   # figaroh: fv_5, fv_6 include fvm6
        lines.append(f"{j + 1:5d} {fv:7.3f} {cfg['fv'][j]:7.3f} {fv / cfg['fv'][j]:6.2f} | "
                     f"{p['c']:7.3f} {cfg['fs'][j]:7.3f} {p['c'] / cfg['fs'][j]:6.2f}")
    if m6:
        lines.append(f"motor 6: fsm6 {m6['fs']:.3f} ({cfg.get('fsm6', np.nan):.3f}), fvm6 {m6['fv']:.3f} "
                     f"({cfg.get('fvm6', np.nan):.3f}), Iam6 {m6['Ia']:.4g} ({cfg.get('Iam6', np.nan):.4g})")
    return "\n".join(lines)


def diagnose_tx40(folder: Path, decimate: int = 5, n_segments: int | None = None, seed: int = 0) -> dict:
    import numpy as np

    from ident.thesis.campaign_fit import load_tx40
    from ident.gap import DiagnosisSettings, diagnose_joint
    from ident.gap.data import build_joint_data_record

    t, q, qd, qdd, tau, robot, cfg = load_tx40(folder, decimate=decimate)
    arm = np.asarray(cfg.get("Ia", [0.0] * 6), float)
    out = {}
    for j in range(1, 7):
        d = build_joint_data_record(j, t, q, qd, qdd, tau, robot, armature=arm, n_segments=n_segments)
        out[str(j)] = diagnose_joint(d, DiagnosisSettings(seed=seed)).to_dict()
    return out


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--folder", type=Path, default=REAL)
    ap.add_argument("--json", type=Path)
    a = ap.parse_args(argv)
    if not (a.folder / "pos_read_data.csv").is_file():
        print(f"TX40 data not found in {a.folder}")
        return 1
    if FIXTURE.is_dir():
        t0 = time.perf_counter()
        print(fit_tx40_campaign())
        print(f"TX40 multi-joint fit in {time.perf_counter() - t0:.1f} s")
    t0 = time.perf_counter()
    rep = diagnose_tx40(a.folder)
    print(f"TX40 diagnosis in {time.perf_counter() - t0:.1f} s")
    for j, r in rep.items():
        ch = r["channels"]["torque"]
        top = [(e["effect"], round(e.get("reduction") or 0, 3), e.get("significant"))
               for e in r["effects"][:4]]
        print(f"joint {j}: verdict {r['verdict']:<18} held-out RMS {ch['heldout_rms_nominal']:.3f} -> "
              f"{ch['heldout_rms_final']:.3f} N m (noise floor {ch['noise_floor_rms']:.3f}); selected "
              f"{r['selected']}; top {top}; where: {[(x['regime'], round(x['share'], 2)) for x in r['localisation'][:2]]}")
    if a.json:
        a.json.write_text(json.dumps(rep, indent=1, default=float))
    return 0


if __name__ == "__main__":
    sys.exit(main())
