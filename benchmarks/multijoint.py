"""Benchmark: a 20k-sample 7-joint record (the hand-written arm of fixtures/arm7, irregular time
stamps, 5 % repeated rows, link-side torques, no markers) through `jointlab fit` and
`jointlab diagnose` (wall and process CPU time of each command in-process, `fit` with its
default models cv, stribeck, hyperbolic and with cv alone, `diagnose` with the default and a
Stribeck nominal; the goal is < 30 s each on 2 cores; on a shared machine compare CPU times),
and the batched joint torque regressor against a per-sample loop over pinocchio's
``computeJointTorqueRegressor`` measured in the same run.

    python benchmarks/multijoint.py            # 20 s at ~1 kHz (about 20k samples)
    python benchmarks/multijoint.py --quick    # 5 s
"""
from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path[:] = [p for p in sys.path if Path(p or ".").resolve() != Path(__file__).resolve().parent]
sys.path[:0] = [str(REPO), str(REPO / "tests")]


def main(argv=None):
    import pinocchio as pin

    import test_multijoint as tm
    from ident.cli import main as cli
    from ident.model.regressor import ChainDynamics

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true")
    a = ap.parse_args(argv)
    duration = 5.0 if a.quick else 20.0
    with tempfile.TemporaryDirectory() as d:
        d = Path(d)
        truth = tm._write_arm7_campaign(d / "c", duration=duration)
        T = truth["t"].size
        print(f"record: {T} rows x 7 joints ({truth['repeated']} repeated), {duration:g} s")
        model = truth["model"]
        ch = ChainDynamics.from_model(model)
        q, qd, qdd = truth["q"], truth["qd"], truth["qdd"]
        t0 = time.perf_counter()
        Y = ch.regressor(q, qd, qdd)
        t_batch = time.perf_counter() - t0
        data = model.createData()
        t0 = time.perf_counter()
        W = np.empty_like(Y)
        for k in range(T):                     # the baseline: one call per sample
            W[k] = pin.computeJointTorqueRegressor(model, data, q[k], qd[k], qdd[k])
        t_loop = time.perf_counter() - t0
        print(f"regressor: batched {t_batch:.2f} s, per-sample pinocchio loop {t_loop:.2f} s "
              f"(ratio loop/batched {t_loop / t_batch:.2f}); max |diff| {np.abs(W - Y).max():.2e}")
        rows = []
        for cmd in (["fit", str(d / "c"), "--out", str(d / "f")],          # default models
                    ["fit", str(d / "c"), "--out", str(d / "f1"), "--models", "cv"],
                    ["diagnose", str(d / "c"), "--out", str(d / "g")],
                    ["diagnose", str(d / "c"), "--out", str(d / "g1"), "--nominal", "stribeck"]):
            t0, c0 = time.perf_counter(), time.process_time()
            rc = cli(cmd)
            rows.append((" ".join(["jointlab", cmd[0]] + cmd[4:]), time.perf_counter() - t0,
                         time.process_time() - c0, rc))
        print(f"{'command (20k-sample 7-joint record)':48s} {'wall s':>7s} {'CPU s':>7s}  exit")
        for name, w, c, rc in rows:
            print(f"{name:48s} {w:7.1f} {c:7.1f}  {rc}   (goal < 30 s on 2 cores)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
