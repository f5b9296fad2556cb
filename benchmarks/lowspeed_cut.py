"""Benchmark: the effect of the low-speed cut on the Coulomb level of the multi-joint fit, on the
real TX40 record (fixtures/real/tx40, figaroh-examples) and the synthetic 7-joint arm of
tests/test_multijoint.py (known truth).

For each record: the cut chosen from the data (``--v-zero auto``: the velocity noise floor and the
residual knee, ident.model.multijoint._auto_cut), then fixed fractions of each joint's
99th-percentile speed (0 .. 5 %) and multiples of the chosen cut (0.5x, 2x); per joint the
Coulomb estimate as a ratio to the reference (TX40: the published figaroh values of
../shared/data/real/README.md, for comparison, not for tuning; arm7: the simulated truth), and
the spread of those ratios over the cuts (the bound on the cut's effect).

    python benchmarks/lowspeed_cut.py            # both records (about 1 min)
    python benchmarks/lowspeed_cut.py --quick    # TX40 only
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
    return c, (np.asarray(cut["v_zero"]) if cut else None)


def sweep(name, camp, ref):
    from ident.model.record import load_record
    from ident.model.multijoint import multijoint_trials

    robot = camp.load_robot()
    rec = load_record(camp, multijoint_trials(camp)[0], robot)
    sp = np.percentile(np.abs(rec.qd), 99, axis=0)
    c_auto, v_auto = _coulomb(camp, "auto")
    rows = [("auto (" + ", ".join(f"{100 * x:.2g}" for x in v_auto / sp) + " %)", c_auto)]
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


def main(argv=None):
    from mocap.io.campaign import load_campaign

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true")
    a = ap.parse_args(argv)
    sweep("TX40 (fixtures/real/tx40, published figaroh values)",
          load_campaign(REPO / "fixtures" / "real" / "tx40"), TX40_COULOMB)
    if not a.quick:
        import test_multijoint as tm

        with tempfile.TemporaryDirectory() as d:
            tm._write_arm7_campaign(Path(d) / "c", duration=10.0)
            sweep("arm7 (synthetic, simulated truth)", load_campaign(Path(d) / "c"), tm.C_TRUE)


if __name__ == "__main__":
    main()
